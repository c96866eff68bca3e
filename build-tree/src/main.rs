//! `sct-build-tree`: samples or meshes → SCT scene tree file, or a directory of meshes →
//! a directory of SCT files. Parses flags, runs the library ([`build_tree::pipeline`],
//! [`build_tree::convert`], [`build_tree::batch`]), prints the summary or the error once.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use build_tree::batch::{self, run_batch, BatchOptions, Shard};
use build_tree::progress::{format_duration, BatchProgress};
use build_tree::convert::{convert_meshes_checked, is_mesh_path, ConvertReport};
use build_tree::pipeline::{run, run_samples, Config, Refinement, Report, Upstream};
use build_tree::{BuildOptions, Weld};
use clap::{Args, CommandFactory, FromArgMatches, Parser};
use sct_format::samples::SamplesFile;
use sct_format::Profile;
use voxelize::args::SamplingArgs;

const EXAMPLES: &str = "Examples:
  sct-build-tree bunny.samples -o bunny.sct                  # samples from sct-voxelize
  sct-build-tree model.glb -o model.sct                      # one step: mesh -> SCT (voxelizes in memory)
  sct-build-tree spot.obj --texture spot.png --screen-error 0.5 -o spot.sct
  sct-build-tree assets/ -o sct/ --json                      # batch: a library, folders mirrored
  sct-build-tree assets/ -o sct/ --shard $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT
  sct-build-tree bunny.samples -o bunny.sct --profile canopy --json
  sct-build-tree bunny.samples -o grid.sct --scene grid.json
  sct-build-tree --scene shards.json -o city.sct             # a scene of inlines only
  sct-build-tree assets/ -o sct/ --strict --json             # CI: a warning (missing texture) fails its asset
  echo '{\"texture\": \"spot.png\"}' > assets/spot.obj.options.json   # batch: one asset's own options

Input: mesh files (OBJ, glTF/GLB, PLY, by extension or content, sampled in one grid with
the sampling options below), a samples file, or a directory (batch mode: -o is a
directory). STL, FBX and SCT scene files are refused, naming what they are.

Exit status: 0 success, 1 bad input (mesh, samples, scene or inlined file; in batch mode:
any input failed), 2 usage or I/O error.";

/// Builds a compressed SCT scene tree (thesis §5.3) from a samples file or directly from
/// meshes, composes scenes of groups, instances and inlines (§5.10) from a scene.json
/// file, and batch-converts whole asset libraries.
#[derive(Parser, Debug)]
#[command(name = "sct-build-tree", version, after_help = EXAMPLES)]
struct Cli {
    /// Samples file, mesh file(s), or one directory of meshes (batch mode). May be
    /// omitted with --scene when the scene uses only inlines.
    #[arg(required_unless_present = "scene")]
    inputs: Vec<PathBuf>,
    /// Output SCT file (written atomically); in batch mode, the output directory.
    #[arg(short, long)]
    output: PathBuf,
    /// Node profile: default (compressed streams), canopy (thesis 86-bit nodes) or raw.
    #[arg(long, default_value = "default")]
    profile: Profile,
    /// zstd level for tree blocks (0 disables; default: the profile's own).
    #[arg(long)]
    compression_level: Option<i32>,
    /// Leave out the centre offsets that put the default profile's leaves back on their
    /// surface (SCT 1.2), so that SCT 1.0/1.1 readers can read the file.
    #[arg(long)]
    no_centre_offsets: bool,
    /// Which leaves store their centre and radius to 1/256 of their own radius (SCT 1.4,
    /// about 2–3 bytes a leaf more): `auto` every leaf of point clouds, whose points each
    /// carry their own colour, and in meshes the leaves the position grid moves off their
    /// piece of surface past a face's edge or a crease (+1.4–1.9 % bytes on planar models,
    /// +1–17 % on the others, median 10 %); `on` every leaf (meshes gain 0.2–0.5 dB for
    /// 1.36–1.75× the bytes); `off` none.
    #[arg(long, value_enum, default_value_t = Refinement::Auto)]
    leaf_refinement: Refinement,
    /// Weld samples whose centres' bounding box is at most this wide (absolute units;
    /// 0 = exact duplicates only). Default: 1% of the mean sample radius.
    #[arg(long, conflicts_with = "no_weld")]
    weld_tolerance: Option<f32>,
    /// Keep every sample, even exact duplicates.
    #[arg(long)]
    no_weld: bool,
    /// Allowed tree depth above ceil(log2 leaves).
    #[arg(long, default_value_t = 4)]
    depth_slack: u32,
    /// Bake non-similarity (non-uniformly scaled, sheared, mirrored) placements into their
    /// own trees instead of writing them as affine instances (format 1.3), so that readers
    /// of format 1.2 can open the file (with `--leaf-refinement off`: refinement is 1.4).
    #[arg(long)]
    bake_affine: bool,
    /// Scene description (spec/scene-json.md); inline paths are relative to the output.
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Most grid cells (instances) over all grids of the --scene file; each costs about 280
    /// bytes while composing.
    #[arg(long, value_name = "N", default_value_t = build_tree::scene::MAX_GRID_CELLS, requires = "scene")]
    max_grid_cells: u64,
    /// Batch: convert even outputs that are up to date.
    #[arg(long)]
    force: bool,
    /// Batch: convert only shard K of N (a stable hash of each relative path), e.g. 3/16.
    #[arg(long, value_name = "K/N")]
    shard: Option<Shard>,
    /// Batch: files converted at the same time (default: the number of cores).
    #[arg(long, value_name = "N")]
    jobs: Option<usize>,
    /// Print a JSON summary on stdout (batch: schema sct-build-tree-batch/1).
    #[arg(long)]
    json: bool,
    /// Progress display on stderr: auto (only when stderr is a terminal), always (redrawn
    /// with ANSI escapes even into a pipe or a log: terminals that hide their tty, tests),
    /// never.
    #[arg(long, value_enum, default_value_t = ProgressMode::Auto)]
    progress: ProgressMode,
    /// Fail on warnings (a missing texture or MTL, a mesh left out, skipped primitives):
    /// nothing is written and the exit status is 1; in batch mode the asset fails.
    #[arg(long, visible_alias = "deny-warnings")]
    strict: bool,
    // Last, so its help heading does not swallow the options above.
    #[command(flatten)]
    sampling: SamplingArgs,
}

/// The first sampling flag given on the command line, if any.
fn sampling_flag_given(m: &clap::ArgMatches) -> Option<String> {
    let group = SamplingArgs::augment_args(clap::Command::new("sampling"));
    let ids: Vec<String> = group.get_arguments().map(|a| a.get_id().to_string()).collect();
    ids.into_iter().find(|id| m.value_source(id) == Some(clap::parser::ValueSource::CommandLine)).map(|id| id.replace('_', "-"))
}

/// What the positional inputs are.
enum Mode {
    Samples(PathBuf),
    Meshes(Vec<PathBuf>),
    Batch(PathBuf),
    SceneOnly,
}

/// A usage or input error found before any work: its message and exit status.
type Refusal = (String, u8);

/// Whether `path` is read as a mesh: by extension, or else by content (an extension-less
/// GLB, PLY or OBJ). Other content is refused naming what it is (STL, FBX, an SCT scene
/// file), except a samples file (`Ok(false)`) or a file that cannot be read (`Ok(false)`:
/// the samples reader says why).
fn is_mesh_input(path: &std::path::Path, several: bool) -> Result<bool, Refusal> {
    use voxelize::load::sniff::{sniff_path, FileKind};
    if is_mesh_path(path) {
        return Ok(true);
    }
    let refuse = |what: String| Err((format!("{}: {what}", path.display()), 1));
    match sniff_path(path) {
        None => Ok(false),
        Some(k) if k.is_mesh() => Ok(true),
        Some(FileKind::SctSamples) if !several => Ok(false),
        Some(FileKind::SctSamples) => refuse("a samples file cannot be combined with other inputs; give it alone".into()),
        Some(FileKind::SctScene) => refuse(
            "this is an SCT scene file, not a samples file; to place it in a new scene, name it as an inline in a --scene file (spec/scene-json.md)".into(),
        ),
        Some(k) => match k.unsupported_mesh_hint() {
            Some(hint) => refuse(format!("this is {}; {hint}", k.describe())),
            None if k == FileKind::Unknown => {
                refuse("neither a samples file (from sct-voxelize) nor a mesh this tool reads (OBJ, glTF/GLB or PLY, by extension or content)".into())
            }
            None => refuse(format!("this is {}, neither a samples file (from sct-voxelize) nor a mesh", k.describe())),
        },
    }
}

fn mode(inputs: &[PathBuf]) -> Result<Mode, Refusal> {
    match inputs {
        [] => Ok(Mode::SceneOnly),
        [one] if one.is_dir() => Ok(Mode::Batch(one.clone())),
        [one] if !is_mesh_input(one, false)? => Ok(Mode::Samples(one.clone())),
        [one] => Ok(Mode::Meshes(vec![one.clone()])),
        many => {
            if let Some(dir) = many.iter().find(|p| p.is_dir()) {
                return Err((format!("{}: a directory (batch mode) must be the only input", dir.display()), 2));
            }
            for p in many {
                if !is_mesh_input(p, true)? {
                    return Err((format!("{}: with several inputs every one must be a mesh (OBJ, glTF/GLB or PLY)", p.display()), 2));
                }
            }
            Ok(Mode::Meshes(many.to_vec()))
        }
    }
}

fn print_json<T: serde::Serialize>(v: &T) -> bool {
    match serde_json::to_string_pretty(v) {
        Ok(s) => print_out(&s),
        Err(e) => {
            eprintln!("error: {e}");
            false
        }
    }
}

/// Data to stdout; false (after saying why) when it cannot be written.
fn print_out(text: &str) -> bool {
    match sct_format::error::print_stdout(text) {
        Ok(()) => true,
        Err(e) => {
            eprintln!("error: writing to stdout: {e}");
            false
        }
    }
}

fn print_build(rep: &Report) {
    eprintln!(
        "{}: {} leaves, {} nodes, depth {}, {} welded, {} bytes ({:.2} B/leaf), {:.2} s",
        rep.output, rep.leaves, rep.nodes, rep.depth, rep.welded, rep.bytes, rep.bytes_per_leaf, rep.seconds.total
    );
}

fn main() -> ExitCode {
    let matches = Cli::command().get_matches();
    voxelize::interrupt::remove_temp_files_on_signal("sct-build-tree");
    let cli = match Cli::from_arg_matches(&matches) {
        Ok(c) => c,
        Err(e) => e.exit(),
    };
    let weld = match (cli.no_weld, cli.weld_tolerance) {
        (true, _) => Weld::Off,
        (false, Some(t)) if t.is_finite() && t >= 0.0 => Weld::Absolute(t),
        (false, Some(t)) => {
            eprintln!("error: --weld-tolerance must be a finite number >= 0, got {t}");
            return ExitCode::from(2);
        }
        (false, None) => BuildOptions::default().weld,
    };
    let mode = match mode(&cli.inputs) {
        Ok(m) => m,
        Err((e, code)) => {
            eprintln!("error: {e}");
            return ExitCode::from(code);
        }
    };
    // Sampling flags on a samples-file input would be silently ignored: refuse them.
    let not_meshes = match &mode {
        Mode::Samples(p) => Some(format!("{} (a samples file)", p.display())),
        Mode::SceneOnly => Some("a scene without inputs".to_string()),
        _ => None,
    };
    if let (Some(what), Some(flag)) = (not_meshes, sampling_flag_given(&matches)) {
        eprintln!("error: --{flag} applies to mesh inputs, not to {what}");
        return ExitCode::from(2);
    }
    if !matches!(mode, Mode::Batch(_)) {
        let batch_only = [(cli.force, "--force"), (cli.shard.is_some(), "--shard"), (cli.jobs.is_some(), "--jobs")];
        if let Some((_, flag)) = batch_only.iter().find(|(given, _)| *given) {
            eprintln!("error: {flag} applies to batch mode (a directory as the input)");
            return ExitCode::from(2);
        }
    }
    let build = BuildOptions { weld, depth_slack: cli.depth_slack, max_grid_cells: cli.max_grid_cells, bake_affine: cli.bake_affine };
    if let Mode::Batch(dir) = &mode {
        if cli.scene.is_some() {
            eprintln!("error: --scene does not apply to a directory of meshes");
            return ExitCode::from(2);
        }
        // One texture for a whole library re-textures every asset: per asset, an options
        // file says it.
        if cli.sampling.texture.is_some() {
            eprintln!(
                "error: --texture does not apply to a directory (it would texture every asset); give the asset its own options file, e.g. {}",
                dir.join("spot.obj.options.json").display()
            );
            eprintln!("       holding {{\"texture\": \"spot_texture.png\"}} (paths relative to the asset's folder)");
            return ExitCode::from(2);
        }
        // A library holds assets far finer than any view needs: each gets a sample budget
        // unless one is given, and every asset it coarsens is named in a warning.
        let mut sampling = cli.sampling.clone();
        sampling.sample_budget.get_or_insert(batch::DEFAULT_SAMPLE_BUDGET);
        let opts = BatchOptions {
            input_dir: dir.clone(),
            output_dir: cli.output.clone(),
            sampling,
            profile: cli.profile,
            compression_level: cli.compression_level,
            centre_offsets: !cli.no_centre_offsets,
            leaf_refinement: cli.leaf_refinement,
            build,
            force: cli.force,
            shard: cli.shard,
            jobs: cli.jobs.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get())),
            deny_warnings: cli.strict,
        };
        return run_batch_cli(&opts, cli.json, cli.progress);
    }
    let cfg = Config {
        samples: match &mode {
            Mode::Samples(p) => p.clone(),
            _ => PathBuf::new(),
        },
        output: cli.output,
        scene: cli.scene,
        profile: cli.profile,
        compression_level: cli.compression_level,
        centre_offsets: !cli.no_centre_offsets,
        leaf_refinement: cli.leaf_refinement,
        build,
    };
    // A spinner only for a person watching: never in pipes or logs (unless asked).
    let bar = progress_target(cli.progress).map(|t| {
        let b = indicatif::ProgressBar::with_draw_target(None, t);
        b.set_style(indicatif::ProgressStyle::default_spinner());
        b.enable_steady_tick(std::time::Duration::from_millis(120));
        b
    });
    let mut phase = |msg: &str| {
        if let Some(b) = &bar {
            b.set_message(msg.to_string());
        }
    };
    let result = match mode {
        Mode::Meshes(meshes) => convert_meshes_checked(&meshes, &cli.sampling, &cfg, None, cli.strict, &mut phase)
            .map(|c| Outcome::Converted(Box::new(c)))
            .map_err(|e| (e.to_string(), e.exit_code())),
        Mode::SceneOnly => run_samples(&cfg, SamplesFile::default(), Upstream::None, Instant::now(), &mut phase)
            .map(|r| Outcome::Built(Box::new(r)))
            .map_err(|e| (e.to_string(), e.exit_code())),
        _ => run(&cfg, &mut phase).map(|r| Outcome::Built(Box::new(r))).map_err(|e| (e.to_string(), e.exit_code())),
    };
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    match result {
        Ok(outcome) => {
            let (rep, warnings) = match &outcome {
                Outcome::Built(r) => (&**r, &[][..]),
                Outcome::Converted(c) => (&c.build, &c.sampling.warnings[..]),
            };
            for w in warnings {
                eprintln!("warning: {w}");
            }
            let printed = match (&outcome, cli.json) {
                (_, false) => {
                    print_build(rep);
                    true
                }
                (Outcome::Built(r), true) => print_json(&**r),
                (Outcome::Converted(c), true) => print_json(&**c),
            };
            if printed {
                ExitCode::SUCCESS
            } else {
                ExitCode::from(2)
            }
        }
        Err((e, code)) => {
            eprintln!("error: {e}");
            ExitCode::from(code as u8)
        }
    }
}

/// When the progress display is drawn (`--progress`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
enum ProgressMode {
    /// Only when stderr is a terminal: never in pipes or logs.
    #[default]
    Auto,
    /// Always, as on a terminal.
    Always,
    /// Never.
    Never,
}

/// Stderr as a terminal whatever it is: indicatif hides its bars on a stderr that is not a
/// terminal, so `--progress always` draws through this with plain ANSI escapes.
#[derive(Debug)]
struct AnsiStderr;

impl AnsiStderr {
    fn put(&self, s: &str) -> std::io::Result<()> {
        use std::io::Write;
        std::io::stderr().write_all(s.as_bytes())
    }
}

impl indicatif::TermLike for AnsiStderr {
    fn width(&self) -> u16 {
        100
    }
    fn move_cursor_up(&self, n: usize) -> std::io::Result<()> {
        if n > 0 { self.put(&format!("\x1b[{n}A")) } else { Ok(()) }
    }
    fn move_cursor_down(&self, n: usize) -> std::io::Result<()> {
        if n > 0 { self.put(&format!("\x1b[{n}B")) } else { Ok(()) }
    }
    fn move_cursor_right(&self, n: usize) -> std::io::Result<()> {
        if n > 0 { self.put(&format!("\x1b[{n}C")) } else { Ok(()) }
    }
    fn move_cursor_left(&self, n: usize) -> std::io::Result<()> {
        if n > 0 { self.put(&format!("\x1b[{n}D")) } else { Ok(()) }
    }
    fn write_line(&self, s: &str) -> std::io::Result<()> {
        self.put(&format!("{s}\n"))
    }
    fn write_str(&self, s: &str) -> std::io::Result<()> {
        self.put(s)
    }
    fn clear_line(&self) -> std::io::Result<()> {
        self.put("\r\x1b[2K")
    }
    fn flush(&self) -> std::io::Result<()> {
        use std::io::Write;
        std::io::stderr().flush()
    }
}

/// Where a progress display draws under `mode`; `None`: no display.
fn progress_target(mode: ProgressMode) -> Option<indicatif::ProgressDrawTarget> {
    match mode {
        ProgressMode::Auto => std::io::stderr().is_terminal().then(indicatif::ProgressDrawTarget::stderr),
        ProgressMode::Always => Some(indicatif::ProgressDrawTarget::term_like(Box::new(AnsiStderr))),
        ProgressMode::Never => None,
    }
}

/// A single build's report: from samples, or sampling + build (one step).
enum Outcome {
    Built(Box<Report>),
    Converted(Box<ConvertReport>),
}

/// `ETA 3 min · converting a.glb, b.obj (+2)`: the time left and the inputs running now.
fn progress_message(p: &BatchProgress<'_>) -> String {
    let eta = p.eta_seconds.map_or_else(|| "ETA …".to_string(), |s| format!("ETA {}", format_duration(s)));
    let mut names: Vec<&str> = p.running.iter().take(3).map(String::as_str).collect();
    let more = p.running.len().saturating_sub(names.len());
    if names.is_empty() {
        names.push("-");
    }
    let more = if more > 0 { format!(" (+{more})") } else { String::new() };
    format!("{eta} · converting {}{more}", names.join(", "))
}

fn run_batch_cli(opts: &BatchOptions, json: bool, progress: ProgressMode) -> ExitCode {
    let bar = progress_target(progress).map(|t| {
        let b = indicatif::ProgressBar::with_draw_target(Some(0), t);
        b.set_style(
            indicatif::ProgressStyle::with_template("{spinner} {pos}/{len} files [{bar:30}] {msg}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        b.enable_steady_tick(std::time::Duration::from_millis(200));
        b
    });
    let show = |p: &BatchProgress<'_>| {
        if let Some(b) = &bar {
            b.set_length(p.total as u64);
            b.set_position(p.finished as u64);
            b.set_message(progress_message(p));
        }
    };
    let result = run_batch(opts, &show);
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    match result {
        Ok(rep) => {
            if json {
                if !print_json(&rep) {
                    return ExitCode::from(2);
                }
            } else if !print_out(batch::format_table(&rep).trim_end_matches('\n')) {
                return ExitCode::from(2);
            }
            if rep.failed > 0 {
                ExitCode::from(1)
            } else {
                ExitCode::SUCCESS
            }
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(e.exit_code() as u8)
        }
    }
}
