//! `sct-inspect`: statistics, dumps and validation of SCT files.
//!
//! Exit status: 0 valid, 1 invalid (issues found or the file cannot be parsed), 2 usage or
//! I/O error. Results go to stdout, diagnostics to stderr.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{CommandFactory, Parser};
use inspect::coverage::{DEFAULT_MIN_COVERAGE, DEFAULT_POINTS, DEFAULT_SEED};
use inspect::many::{validate_many, write_many_text};
use inspect::{
    coverage_against, dump, summarize_with, validate_file, write_coverage, write_json, write_text, write_validation, AgainstOptions, InspectError,
    ValidateOptions,
};
use sct_format::Limits;

const EXAMPLES: &str = "\
Examples:
  sct-inspect bunny.sct                  report counts, sizes and the root node
  sct-inspect bunny.sct --json           the same as JSON (schema sct-inspect/1, spec/inspect-json.md)
  sct-inspect bunny.sct --validate       quick structural validation (exit 1 when invalid)
  sct-inspect bunny.sct --deep --json    decode every block and check hierarchical consistency
  sct-inspect a.sct b.sct out/ --validate --quiet
                                         CI: validate files and every .sct below out/, one
                                         verdict per file (--quiet: only failures) and a summary;
                                         exit 1 if any is invalid, 2 if one cannot be read
  sct-inspect out/ --deep --json         the same as one JSON document (sct-inspect-validate/1)
  sct-inspect bunny.sct --dump root/0/1 --levels 2
                                         print the graph and two levels below node root/0/1
  sct-inspect bunny.sct --against bunny.ply --min-coverage 0.99
                                         fraction of 10^5 random surface points of the mesh inside
                                         some leaf sphere (exit 1 below the threshold)
  sct-inspect leaf.sct --against leaf.glb --exclude-alpha-dropped
                                         the same for an alpha-masked asset: only surfaces the
                                         voxelizer keeps are tested
  sct-inspect bunny.samples --export-ply samples.ply
  sct-inspect bunny.sct --export-ply level12.ply --export-level 12
                                         PLY point clouds for MeshLab / CloudCompare";

/// Statistics, dumps and validation of SCT scene-tree files.
#[derive(Parser, Debug)]
#[command(name = "sct-inspect", version, after_help = EXAMPLES)]
struct Cli {
    /// The SCT file (or, with --export-ply, a samples file). With --validate or --deep:
    /// any number of files and directories (every *.sct file below a directory).
    #[arg(required = true, value_name = "FILE")]
    files: Vec<PathBuf>,
    /// Print the report as JSON (errors too: `{"error": …}` on stdout).
    #[arg(long)]
    json: bool,
    /// Print only the validation verdict and issues (several files: only the files that
    /// fail, and the summary); no statistics.
    #[arg(long, short)]
    quiet: bool,
    /// Quick validation: structure, checksums, graph, transforms, inline targets.
    #[arg(long)]
    validate: bool,
    /// Deep validation: also decode every block and check hierarchical consistency (implies --validate).
    #[arg(long)]
    deep: bool,
    /// Print the scene graph and the scene tree below PATH (abstract path, default root).
    #[arg(long, value_name = "PATH", num_args = 0..=1, default_missing_value = "root")]
    dump: Option<String>,
    /// Levels printed by --dump.
    #[arg(long, value_name = "N", default_value_t = 3, requires = "dump")]
    levels: usize,
    /// Coverage of a source mesh (OBJ, glTF/GLB, PLY): the fraction of random surface points
    /// inside some leaf sphere, leaves in world space (instances and inlines applied). Points
    /// are drawn on every triangle, including surfaces the voxelizer drops by alpha (glTF MASK
    /// below the cutoff, fully transparent BLEND): such models cover less than 100 % unless
    /// --exclude-alpha-dropped leaves those out.
    #[arg(long, value_name = "MESH", conflicts_with_all = ["dump", "export_ply"])]
    against: Option<PathBuf>,
    /// With --against: draw points only where the voxelizer keeps samples, leaving out
    /// surfaces it drops by alpha (MASK below the cutoff, fully transparent BLEND), so
    /// alpha-masked assets can be gated at full coverage too.
    #[arg(long, requires = "against")]
    exclude_alpha_dropped: bool,
    /// Surface points tested by --against (at least 1).
    #[arg(long, value_name = "N", default_value_t = DEFAULT_POINTS, requires = "against", value_parser = positive)]
    points: usize,
    /// Seed of the --against points (same seed, same points).
    #[arg(long, value_name = "S", default_value_t = DEFAULT_SEED, requires = "against")]
    seed: u64,
    /// Exit 1 when the covered fraction (0..1) is below this.
    #[arg(long, value_name = "F", default_value_t = DEFAULT_MIN_COVERAGE, requires = "against", value_parser = fraction)]
    min_coverage: f64,
    /// Most leaf-tree queries of --against over all points (a point queries each placed tree
    /// whose bound may hold a nearer leaf); past it the check fails with "limit exceeded".
    #[arg(long, value_name = "N", default_value_t = inspect::coverage::MAX_USE_QUERIES, requires = "against")]
    max_use_queries: u64,
    /// Write a PLY point cloud (position, normal, colour, radius; world space) and exit: all
    /// samples of a samples file, or an SCT file's leaves (or its cut at --export-level).
    #[arg(long, value_name = "OUT.ply")]
    export_ply: Option<PathBuf>,
    /// Export the cut at this tree level (nodes at the level plus shallower leaves).
    #[arg(long, value_name = "N", requires = "export_ply")]
    export_level: Option<usize>,
    /// Refuse exports of more points than this.
    #[arg(long, value_name = "N", default_value_t = inspect::export::DEFAULT_MAX_POINTS, requires = "export_ply")]
    max_points: u64,
    /// Follow inlines whose target (symlinks resolved) lies outside the file's directory. Off
    /// by default: such inlines are reported (inline-outside) and their targets not opened.
    #[arg(long)]
    allow_outside_inlines: bool,
    /// Most scene-graph nodes one traversal visits (a node shared by several paths counts once
    /// per path): --export-ply, --against, --dump and validation stop past it with "limit
    /// exceeded" instead of expanding a DAG of shared groups path by path.
    #[arg(long, value_name = "N", default_value_t = Limits::default().max_traversal_visits)]
    max_visits: u64,
}

/// The reader limits, with the caps the flags set.
fn limits_of(cli: &Cli) -> Limits {
    Limits { max_traversal_visits: cli.max_visits, ..Limits::default() }
}

fn fraction(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if (0.0..=1.0).contains(&v) => Ok(v),
        _ => Err(format!("{s:?} is not a fraction in [0, 1]")),
    }
}

/// `--points`: 0 points would pass vacuously (fraction 1 of nothing), so it is a usage error.
fn positive(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(v) if v > 0 => Ok(v),
        _ => Err(format!("{s:?} is not a positive number of points")),
    }
}

/// `sct-inspect A B DIR/ --validate`: one result per file and a summary.
fn run_many(cli: &Cli) -> Result<i32, InspectError> {
    let opts = ValidateOptions { deep: cli.deep, limits: limits_of(cli), allow_outside_inlines: cli.allow_outside_inlines };
    let report = validate_many(&cli.files, &opts);
    let mut out = std::io::stdout().lock();
    if cli.json {
        serde_json::to_writer_pretty(&mut out, &report).map_err(std::io::Error::from)?;
        writeln!(out)?;
    } else {
        write_many_text(&report, cli.quiet, &mut out)?;
    }
    out.flush()?;
    Ok(report.exit_code())
}

/// Flag combinations clap cannot express: several inputs only for validation, --quiet
/// only where there is a verdict.
fn check_usage(cli: &Cli) -> Result<(), String> {
    let validating = cli.validate || cli.deep;
    let many = cli.files.len() > 1 || cli.files.iter().any(|f| f.is_dir());
    if many && !validating {
        let what = match cli.files.iter().find(|f| f.is_dir()) {
            Some(d) => format!("{} is a directory", d.display()),
            None => format!("{} files were given", cli.files.len()),
        };
        return Err(format!("{what}: add --validate (or --deep) to validate every SCT file; statistics, dumps and exports take one file"));
    }
    if many && (cli.dump.is_some() || cli.against.is_some() || cli.export_ply.is_some()) {
        return Err("--dump, --against and --export-ply take one file".into());
    }
    if cli.quiet && !validating && cli.against.is_none() {
        return Err("--quiet applies to --validate, --deep and --against (it prints only their verdicts)".into());
    }
    Ok(())
}

fn run(cli: &Cli) -> Result<i32, InspectError> {
    if cli.files.len() > 1 || cli.files.iter().any(|f| f.is_dir()) {
        return run_many(cli);
    }
    let file = &cli.files[0];
    let limits = limits_of(cli);
    let mut out = std::io::stdout().lock();
    if let Some(ply) = &cli.export_ply {
        let e = inspect::export::export_ply(file, ply, cli.export_level, cli.max_points, &limits, cli.allow_outside_inlines)?;
        if cli.json {
            serde_json::to_writer_pretty(&mut out, &e).map_err(std::io::Error::from)?;
            writeln!(out)?;
        } else {
            writeln!(out, "{}: {} points from {} placements, {} bytes", ply.display(), e.points, e.placements, e.bytes)?;
        }
        return Ok(0);
    }
    if let Some(p) = &cli.dump {
        dump(file, p, cli.levels, &limits, cli.allow_outside_inlines, &mut out)?;
        return Ok(0);
    }
    let validation = if cli.validate || cli.deep {
        Some(validate_file(file, &ValidateOptions { deep: cli.deep, limits: limits.clone(), allow_outside_inlines: cli.allow_outside_inlines })?)
    } else {
        None
    };
    let invalid = validation.as_ref().is_some_and(|v| !v.is_valid());
    match summarize_with(file, &limits, cli.allow_outside_inlines) {
        Ok(mut s) => {
            s.validation = validation;
            if let Some(mesh) = &cli.against {
                let opts = AgainstOptions {
                    points: cli.points,
                    seed: cli.seed,
                    min_coverage: cli.min_coverage,
                    limits: limits.clone(),
                    allow_outside_inlines: cli.allow_outside_inlines,
                    exclude_alpha_dropped: cli.exclude_alpha_dropped,
                    max_use_queries: cli.max_use_queries,
                    ..Default::default()
                };
                s.coverage = Some(coverage_against(file, mesh, &opts)?);
            }
            if cli.json {
                write_json(&s, &mut out)?;
            } else {
                if !cli.quiet {
                    write_text(&s, &mut out)?;
                }
                if let Some(v) = &s.validation {
                    write_validation(v, &mut out)?;
                }
                if let Some(c) = &s.coverage {
                    write_coverage(c, &mut out)?;
                }
            }
            out.flush()?;
            let uncovered = s.coverage.as_ref().is_some_and(|c| !c.passed);
            Ok(if invalid || uncovered { 1 } else { 0 })
        }
        // An unparsable file still gets its issues printed when validating.
        Err(e) if e.exit_code() == 1 && validation.is_some() => {
            let v = validation.clone().unwrap_or_default();
            if cli.json {
                serde_json::to_writer_pretty(&mut out, &serde_json::json!({"schema": inspect::SCHEMA, "file": file, "error": e.to_string(), "validation": v})).map_err(std::io::Error::from)?;
                writeln!(out)?;
            } else {
                write_validation(&v, &mut out)?;
            }
            Ok(1)
        }
        Err(e) => Err(e),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    voxelize::interrupt::remove_temp_files_on_signal("sct-inspect");
    if let Err(e) = check_usage(&cli) {
        let mut cmd = Cli::command();
        cmd.error(clap::error::ErrorKind::ArgumentConflict, e).exit();
    }
    match run(&cli) {
        Ok(code) => ExitCode::from(code as u8),
        // The reader of stdout went away (`| head`): it has what it wanted.
        Err(e) if sct_format::error::is_broken_pipe(&e) => ExitCode::SUCCESS,
        Err(e) => {
            let code = e.exit_code();
            let message = sct_format::error::one_line(&e);
            eprintln!("sct-inspect: {message}");
            if cli.json {
                // A pipeline reading stdout gets a JSON answer whatever happened.
                let doc = serde_json::json!({"schema": inspect::SCHEMA, "file": cli.files.first(), "error": message, "exit_code": code});
                let _ = sct_format::error::print_stdout(&serde_json::to_string_pretty(&doc).unwrap_or_default());
            }
            ExitCode::from(code as u8)
        }
    }
}
