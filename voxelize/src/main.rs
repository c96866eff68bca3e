//! `sct-voxelize`: meshes → samples file. Flag parsing only; the work is in the library.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, ValueEnum};
use voxelize::{AreaMode, Density, LoadOptions, Method, Options, SampleOptions};

#[derive(Clone, Copy, ValueEnum)]
enum MethodArg {
    /// Conservative scan-line voxelization: every voxel a triangle crosses (coverage guaranteed).
    Voxel,
    /// The thesis' scan-line: one sample per covered grid-column centre.
    Scanline,
    /// QSplat vertex patches: one sample per vertex, radius = longest incident edge.
    Vertex,
}

#[derive(Clone, Copy, ValueEnum)]
enum AreaArg {
    /// Exact area of triangle ∩ voxel.
    Exact,
    /// Thesis EQ 17: triangle area / samples of the triangle.
    Eq17,
}

/// Sample textured meshes (OBJ/MTL, glTF/GLB, PLY) into SCT surface samples (thesis §5.2).
///
/// The voxel size comes from --voxel-size, else from a viewing target (--screen-error with
/// --distance), else automatically from EQ 16 (--k, --gamma).
#[derive(Parser)]
#[command(name = "sct-voxelize", version, after_help = "EXAMPLES:
  sct-voxelize bunny.obj -o bunny.samples                      # automatic EQ 16 (k=3, γ=2)
  sct-voxelize scene.glb -o scene.samples --voxel-size 0.01
  sct-voxelize spot.obj --texture spot_texture.png -o spot.samples --k 2 --gamma 4
  sct-voxelize city.gltf -o city.samples --screen-error 1 --resolution 1920 --distance 50
  sct-voxelize dragon.ply -o dragon.samples --method vertex --json

EXIT STATUS: 0 success, 1 bad input (unreadable mesh, unsupported extension), 2 usage or I/O error.")]
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
    /// Sampler.
    #[arg(long, value_enum, default_value = "voxel")]
    method: MethodArg,
    /// Voxel edge length in world units (overrides everything else).
    #[arg(long, value_name = "LEN")]
    voxel_size: Option<f64>,
    /// EQ 16: standard deviations below the mean edge length.
    #[arg(long, default_value_t = 3.0)]
    k: f64,
    /// EQ 16: samples per base length.
    #[arg(long, default_value_t = 2.0)]
    gamma: f64,
    /// EQ 16: minimum base length β (default 1e-4 × scene diagonal).
    #[arg(long, value_name = "LEN")]
    min_base: Option<f64>,
    /// Viewing target: largest projected sample diameter in pixels (needs --distance).
    #[arg(long, value_name = "PX", requires = "distance")]
    screen_error: Option<f64>,
    /// Viewing target: image width in pixels.
    #[arg(long, value_name = "PX", default_value_t = 1920.0)]
    resolution: f64,
    /// Viewing target: nearest viewing distance in world units.
    #[arg(long, value_name = "LEN")]
    distance: Option<f64>,
    /// Viewing target: horizontal field of view in degrees.
    #[arg(long, value_name = "DEG", default_value_t = 60.0)]
    fov: f64,
    /// How samples get their area.
    #[arg(long, value_enum, default_value = "exact")]
    area: AreaArg,
    /// Keep one sample per triangle per voxel (no merging of samples sharing a voxel).
    #[arg(long)]
    no_merge: bool,
    /// Crease angle (degrees) for normals computed when a mesh has none.
    #[arg(long, value_name = "DEG", default_value_t = 60.0)]
    crease: f32,
    /// Bind this image as the base-colour texture (OBJ without MTL, e.g. spot).
    #[arg(long, value_name = "IMAGE")]
    texture: Option<PathBuf>,
    /// Ignore textures (colours from factors and vertex colours).
    #[arg(long)]
    no_textures: bool,
    /// Refuse runs estimated to make more samples than this.
    #[arg(long, value_name = "N", default_value_t = 400_000_000)]
    max_samples: u64,
    /// Worker threads (default: all cores; RAYON_NUM_THREADS also works).
    #[arg(long, value_name = "N")]
    threads: Option<usize>,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    json: bool,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if let Some(t) = cli.threads {
        if let Err(e) = rayon::ThreadPoolBuilder::new().num_threads(t).build_global() {
            eprintln!("sct-voxelize: cannot set threads: {e}");
            return ExitCode::from(2);
        }
    }
    let density = if let Some(h) = cli.voxel_size {
        Density::VoxelSize(h)
    } else if let (Some(px), Some(d)) = (cli.screen_error, cli.distance) {
        Density::Screen { pixels: px, resolution: cli.resolution, distance: d, fov_deg: cli.fov }
    } else {
        Density::Auto { k: cli.k, gamma: cli.gamma, min_base: cli.min_base }
    };
    let opts = Options {
        inputs: cli.inputs.clone(),
        output: if cli.dry_run { None } else { cli.output.clone() },
        load: LoadOptions { texture_override: cli.texture.clone(), load_textures: !cli.no_textures, ..Default::default() },
        sample: SampleOptions {
            method: match cli.method {
                MethodArg::Voxel => Method::Voxel,
                MethodArg::Scanline => Method::Scanline,
                MethodArg::Vertex => Method::Vertex,
            },
            density,
            area: match cli.area {
                AreaArg::Exact => AreaMode::Exact,
                AreaArg::Eq17 => AreaMode::Eq17,
            },
            merge: !cli.no_merge,
            crease_deg: cli.crease,
            max_samples: cli.max_samples,
        },
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
                    Ok(s) => println!("{s}"),
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
            let e = anyhow::Error::from(e);
            eprintln!("sct-voxelize: error: {e:#}");
            let code = e.downcast_ref::<voxelize::Error>().map_or(2, |e| e.exit_code());
            ExitCode::from(code as u8)
        }
    }
}
