//! `sct-voxelize`: meshes → samples file. Flag parsing only; the work is in the library.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use voxelize::args::SamplingArgs;
use voxelize::Options;

/// Sample textured meshes (OBJ/MTL, glTF/GLB, PLY) into SCT surface samples (thesis §5.2).
///
/// The voxel size comes from --voxel-size, else from a viewing target (--screen-error with
/// --distance), else from the intended view (default: the model as sct-render-preview frames
/// it by default, voxels 1.5 pixels wide) or EQ 16 (--density eq16, --k, --gamma).
#[derive(Parser)]
#[command(name = "sct-voxelize", version, after_help = "EXAMPLES:
  sct-voxelize bunny.obj -o bunny.samples                      # leaves ~1 px in the default view
  sct-voxelize bunny.obj -o bunny.samples --screen-error 0.5    # twice as fine
  sct-voxelize bunny.obj -o bunny.samples --density eq16        # thesis EQ 16 (k=3, γ=2)
  sct-voxelize scene.glb -o scene.samples --voxel-size 0.01
  sct-voxelize spot.obj --texture spot_texture.png -o spot.samples --k 2 --gamma 4
  sct-voxelize city.gltf -o city.samples --screen-error 1 --resolution 1920 --distance 50
  sct-voxelize dragon.ply -o dragon.samples --method vertex --json

Inputs are recognised by extension or content (a GLB, PLY or OBJ without its extension loads);
STL, FBX and SCT files are refused, naming what they are. Ctrl-C or SIGTERM removes the
temporary output file before exiting (status 130 or 143).

EXIT STATUS: 0 success, 1 bad input (unreadable mesh, a file that is not a mesh), 2 usage or I/O error.")]
struct Cli {
    /// Input mesh files (.obj, .gltf, .glb, .ply); several are sampled in one grid.
    #[arg(required = true)]
    inputs: Vec<PathBuf>,
    /// Output samples file (written atomically). Omit with --dry-run.
    #[arg(short, long, required_unless_present = "dry_run")]
    output: Option<PathBuf>,
    /// Sample and report, but write nothing.
    #[arg(long)]
    dry_run: bool,
    /// Worker threads (default: all cores; RAYON_NUM_THREADS also works).
    #[arg(long, value_name = "N")]
    threads: Option<usize>,
    /// Print a JSON summary on stdout (schema: spec/voxelize-json.md).
    #[arg(long)]
    json: bool,
    // Last, so its help heading does not swallow the options above.
    #[command(flatten)]
    sampling: SamplingArgs,
}

fn main() -> ExitCode {
    sct_format::memory::map_large_allocations();
    let cli = Cli::parse();
    voxelize::interrupt::remove_temp_files_on_signal("sct-voxelize");
    if let Some(t) = cli.threads {
        if let Err(e) = rayon::ThreadPoolBuilder::new().num_threads(t).build_global() {
            eprintln!("sct-voxelize: cannot set threads: {e}");
            return ExitCode::from(2);
        }
    }
    let opts = Options {
        inputs: cli.inputs.clone(),
        output: if cli.dry_run { None } else { cli.output.clone() },
        load: cli.sampling.load_options(),
        sample: cli.sampling.sample_options(),
    };
    let bar = std::io::stderr().is_terminal().then(|| {
        let b = indicatif::ProgressBar::new(0);
        b.set_style(
            indicatif::ProgressStyle::with_template("{spinner} sampling [{bar:40}] {pos}/{len} triangles {eta}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        b
    });
    let progress = |done: u64, total: u64| {
        if let Some(b) = &bar {
            b.set_length(total);
            b.set_position(done);
        }
    };
    let result = voxelize::run(&opts, &progress);
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    match result {
        Ok(summary) => {
            for w in &summary.warnings {
                eprintln!("sct-voxelize: warning: {w}");
            }
            if cli.json {
                match serde_json::to_string_pretty(&summary) {
                    Ok(s) => {
                        if let Err(e) = sct_format::error::print_stdout(&s) {
                            eprintln!("sct-voxelize: error: writing to stdout: {e}");
                            return ExitCode::from(2);
                        }
                    }
                    Err(e) => {
                        eprintln!("sct-voxelize: {e}");
                        return ExitCode::from(2);
                    }
                }
            } else {
                eprintln!(
                    "sct-voxelize: {} samples ({} before merging) from {} triangles in {:.2}s; voxel {:.6} ({})",
                    summary.samples, summary.samples_before_merge, summary.triangles_read, summary.seconds_total, summary.voxel_size, summary.voxel_size_reason
                );
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            // Every variant's message already names its cause: print it once.
            eprintln!("sct-voxelize: error: {e}");
            ExitCode::from(e.exit_code() as u8)
        }
    }
}
