//! `sct-build-tree`: samples → SCT scene tree file. Parses flags, runs
//! [`build_tree::pipeline::run`], prints the summary or the error once.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

use build_tree::pipeline::{run, Config};
use build_tree::{BuildOptions, Weld};
use clap::Parser;
use sct_format::Profile;

const EXAMPLES: &str = "Examples:
  sct-build-tree bunny.samples -o bunny.sct
  sct-build-tree bunny.samples -o bunny.sct --profile canopy --json
  sct-build-tree bunny.samples -o grid.sct --scene grid.json
  sct-build-tree scan.samples -o scan.sct --weld-tolerance 0.0001

Exit status: 0 success, 1 bad input (samples, scene or inlined file), 2 usage or I/O error.";

/// Builds a compressed SCT scene tree from a samples file (thesis §5.3), optionally
/// composing a scene of groups, instances and inlines (§5.10) from a scene.json file.
#[derive(Parser, Debug)]
#[command(name = "sct-build-tree", version, after_help = EXAMPLES)]
struct Cli {
    /// Samples file written by sct-voxelize.
    samples: PathBuf,
    /// Output SCT file (written atomically).
    #[arg(short, long)]
    output: PathBuf,
    /// Node profile: default (compressed streams), canopy (thesis 86-bit nodes) or raw.
    #[arg(long, default_value = "default")]
    profile: Profile,
    /// zstd level for tree blocks (0 disables; default: the profile's own).
    #[arg(long)]
    compression_level: Option<i32>,
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
    /// Scene description (spec/scene-json.md); inline paths are relative to the output.
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    json: bool,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let weld = match (cli.no_weld, cli.weld_tolerance) {
        (true, _) => Weld::Off,
        (false, Some(t)) if t.is_finite() && t >= 0.0 => Weld::Absolute(t),
        (false, Some(t)) => {
            eprintln!("error: --weld-tolerance must be a finite number >= 0, got {t}");
            return ExitCode::from(2);
        }
        (false, None) => BuildOptions::default().weld,
    };
    let cfg = Config {
        samples: cli.samples,
        output: cli.output,
        scene: cli.scene,
        profile: cli.profile,
        compression_level: cli.compression_level,
        build: BuildOptions { weld, depth_slack: cli.depth_slack },
    };
    // A spinner only for a person watching: never in pipes or logs.
    let bar = std::io::stderr().is_terminal().then(|| {
        let b = indicatif::ProgressBar::new_spinner();
        b.enable_steady_tick(std::time::Duration::from_millis(120));
        b
    });
    let result = run(&cfg, &mut |msg| {
        if let Some(b) = &bar {
            b.set_message(msg.to_string());
        }
    });
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    match result {
        Ok(rep) => {
            if cli.json {
                match serde_json::to_string_pretty(&rep) {
                    Ok(s) => println!("{s}"),
                    Err(e) => {
                        eprintln!("error: {e}");
                        return ExitCode::from(2);
                    }
                }
            } else {
                eprintln!(
                    "{}: {} leaves, {} nodes, depth {}, {} welded, {} bytes ({:.2} B/leaf), {:.2} s",
                    rep.output, rep.leaves, rep.nodes, rep.depth, rep.welded, rep.bytes, rep.bytes_per_leaf, rep.seconds.total
                );
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(e.exit_code() as u8)
        }
    }
}
