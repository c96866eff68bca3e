//! `sct-inspect`: statistics, dumps and validation of SCT files.
//!
//! Exit status: 0 valid, 1 invalid (issues found or the file cannot be parsed), 2 usage or
//! I/O error. Results go to stdout, diagnostics to stderr.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use inspect::coverage::{DEFAULT_MIN_COVERAGE, DEFAULT_POINTS, DEFAULT_SEED};
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
  sct-inspect bunny.sct --dump root/0/1 --levels 2
                                         print the graph and two levels below node root/0/1
  sct-inspect bunny.sct --against bunny.ply --min-coverage 0.99
                                         fraction of 10^5 random surface points of the mesh inside
                                         some leaf sphere (exit 1 below the threshold)
  sct-inspect bunny.samples --export-ply samples.ply
  sct-inspect bunny.sct --export-ply level12.ply --export-level 12
                                         PLY point clouds for MeshLab / CloudCompare";

/// Statistics, dumps and validation of SCT scene-tree files.
#[derive(Parser, Debug)]
#[command(name = "sct-inspect", version, after_help = EXAMPLES)]
struct Cli {
    /// The SCT file (or, with --export-ply, a samples file).
    file: PathBuf,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
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
    /// below the cutoff, fully transparent BLEND): such models cover less than 100 %.
    #[arg(long, value_name = "MESH", conflicts_with_all = ["dump", "export_ply"])]
    against: Option<PathBuf>,
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

fn run(cli: &Cli) -> Result<i32, InspectError> {
    let limits = Limits::default();
    let mut out = std::io::stdout().lock();
    if let Some(ply) = &cli.export_ply {
        let e = inspect::export::export_ply(&cli.file, ply, cli.export_level, cli.max_points, &limits, cli.allow_outside_inlines)?;
        if cli.json {
            serde_json::to_writer_pretty(&mut out, &e).map_err(std::io::Error::from)?;
            writeln!(out)?;
        } else {
            writeln!(out, "{}: {} points from {} placements, {} bytes", ply.display(), e.points, e.placements, e.bytes)?;
        }
        return Ok(0);
    }
    if let Some(p) = &cli.dump {
        dump(&cli.file, p, cli.levels, &limits, cli.allow_outside_inlines, &mut out)?;
        return Ok(0);
    }
    let validation = if cli.validate || cli.deep {
        Some(validate_file(&cli.file, &ValidateOptions { deep: cli.deep, limits: limits.clone(), allow_outside_inlines: cli.allow_outside_inlines })?)
    } else {
        None
    };
    let invalid = validation.as_ref().is_some_and(|v| !v.is_valid());
    match summarize_with(&cli.file, &limits, cli.allow_outside_inlines) {
        Ok(mut s) => {
            s.validation = validation;
            if let Some(mesh) = &cli.against {
                let opts = AgainstOptions {
                    points: cli.points,
                    seed: cli.seed,
                    min_coverage: cli.min_coverage,
                    limits: limits.clone(),
                    allow_outside_inlines: cli.allow_outside_inlines,
                    max_use_queries: cli.max_use_queries,
                    ..Default::default()
                };
                s.coverage = Some(coverage_against(&cli.file, mesh, &opts)?);
            }
            if cli.json {
                write_json(&s, &mut out)?;
            } else {
                write_text(&s, &mut out)?;
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
                serde_json::to_writer_pretty(&mut out, &serde_json::json!({"schema": inspect::SCHEMA, "file": cli.file, "error": e.to_string(), "validation": v})).map_err(std::io::Error::from)?;
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
    match run(&cli) {
        Ok(code) => ExitCode::from(code as u8),
        Err(e) => {
            let code = e.exit_code();
            eprintln!("sct-inspect: {:#}", anyhow::Error::new(e));
            ExitCode::from(code as u8)
        }
    }
}
