//! `sct-render-preview`: preview images of SCT files, with an optional mesh reference.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use clap::{Args, Parser, Subcommand};
use render_preview::{metrics, reference, sweep, synth, LodSize, RenderOptions, Shading, SplatShape, UpAxis, ViewPreset};

const EXAMPLES: &str = "\
Examples:
  sct-render-preview bunny.sct -o bunny.png
  sct-render-preview bunny.sct -o iso.png --view iso --width 640 --height 480 --pixel-error 2
  sct-render-preview scene.sct -o close.png --eye 0.1,0.2,0.3 --target 0,0.1,0 --fov 30
  sct-render-preview bunny.sct -o b.png --reference bun_zipper.ply --json
  sct-render-preview sweep --model bunny.sct=bun_zipper.ply --pixel-errors 0.5,1,2,4,8 -o chart
  sct-render-preview synth bun_zipper.ply -o bunny.sct --spacing 0.0005

Exit status: 0 success, 1 invalid input (malformed file, degenerate camera), 2 usage or I/O error.";

#[derive(Parser, Debug)]
#[command(name = "sct-render-preview", version, about = "Render a preview image of an SCT scene file on the CPU (LOD splatting).", after_help = EXAMPLES, args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    /// SCT file to render.
    #[arg(required = true)]
    file: Option<PathBuf>,
    /// Output PNG (written atomically).
    #[arg(short, long, required = true)]
    output: Option<PathBuf>,
    #[command(flatten)]
    render: RenderArgs,
    /// Also render this mesh (OBJ, glTF, PLY) as a reference and write metrics JSON and a
    /// difference image next to the output (OUTPUT.metrics.json, OUTPUT.diff.png,
    /// OUTPUT.reference.png).
    #[arg(long, value_name = "MESH")]
    reference: Option<PathBuf>,
    /// Print a JSON summary (splats, nodes, bytes read, file size, seconds per phase).
    #[arg(long)]
    json: bool,
}

#[derive(Args, Debug, Clone)]
struct RenderArgs {
    /// Image width.
    #[arg(long, default_value_t = 1280)]
    width: u32,
    /// Image height.
    #[arg(long, default_value_t = 720)]
    height: u32,
    /// Viewing direction when no --eye is given (the root sphere is framed).
    #[arg(long, value_enum, default_value_t = ViewPreset::Front)]
    view: ViewPreset,
    /// Eye position x,y,z.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    eye: Option<[f64; 3]>,
    /// Target x,y,z (default: centre of the root sphere).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    target: Option<[f64; 3]>,
    /// World up for the --view presets: auto, x, y or z, or an explicit camera up vector
    /// x,y,z. auto picks y for glTF sources (the format is +Y up), z when the model is
    /// at least 1.5x taller along Z than it is wide along X and Y (a standing object
    /// modelled Z-up), y otherwise; with z up, front looks along +Y.
    #[arg(long, default_value = "auto", value_parser = parse_up, allow_hyphen_values = true)]
    up: Up,
    /// Vertical field of view in degrees.
    #[arg(long, default_value_t = 40.0)]
    fov: f64,
    /// LOD threshold: largest projected splat radius in pixels (see --lod-size).
    #[arg(long, default_value_t = 1.0)]
    pixel_error: f32,
    /// Lambert + ambient headlight, or the stored colour only.
    #[arg(long, value_enum, default_value_t = Shading::Lambert)]
    shading: Shading,
    /// Splat shape.
    #[arg(long, value_enum, default_value_t = SplatShape::Ellipse)]
    splat: SplatShape,
    /// What --pixel-error bounds: the drawn splat (patch: the node's equal-area disc) or
    /// the node's bounding sphere (sphere: EQ 46, refines about 3.4x more nodes at the same threshold).
    #[arg(long, value_enum, default_value_t = LodSize::Patch)]
    lod_size: LodSize,
    /// Keep nodes whose normal cone faces away from the eye.
    #[arg(long)]
    no_backface_culling: bool,
    /// Background colour as RRGGBB hex.
    #[arg(long, default_value = "18181c", value_parser = parse_hex)]
    background: [u8; 3],
    /// Follow inlines whose target lies outside the scene file's directory.
    #[arg(long)]
    allow_outside_inlines: bool,
}

impl RenderArgs {
    fn options(&self) -> RenderOptions {
        RenderOptions {
            width: self.width,
            height: self.height,
            view: self.view,
            fov_y_deg: self.fov,
            eye: self.eye,
            target: self.target,
            up: match self.up {
                Up::Vector(v) => Some(v),
                Up::Axis(_) => None,
            },
            up_axis: match self.up {
                Up::Axis(a) => a,
                // The explicit vector is the camera's up; presets stay in the y-up frame.
                Up::Vector(_) => UpAxis::Y,
            },
            pixel_error: self.pixel_error,
            shading: self.shading,
            splat: self.splat,
            lod_size: self.lod_size,
            backface_culling: !self.no_backface_culling,
            background: self.background,
            allow_outside_inlines: self.allow_outside_inlines,
            ..RenderOptions::default()
        }
    }
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Render models over a series of --pixel-error values and chart time against PSNR
    /// (OUTPUT.png, OUTPUT.svg, OUTPUT.json).
    Sweep {
        /// MODEL.sct=MESH pairs (the mesh is the accuracy reference); repeat per model.
        #[arg(long = "model", required = true, value_parser = parse_pair)]
        models: Vec<(PathBuf, PathBuf)>,
        /// Thresholds to render at.
        #[arg(long, value_delimiter = ',', default_values_t = [0.5f32, 1.0, 2.0, 4.0, 8.0])]
        pixel_errors: Vec<f32>,
        /// Timed repetitions per point (the fastest counts).
        #[arg(long, default_value_t = 3)]
        repeat: u32,
        /// Output path without extension.
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        render: RenderArgs,
    },
    /// Make a test SCT file from a mesh: one leaf per sub-triangle of side ≤ --spacing,
    /// median-split tree (a stand-in for sct-voxelize + sct-build-tree).
    Synth {
        /// Mesh file.
        mesh: PathBuf,
        /// Output SCT file.
        #[arg(short, long)]
        output: PathBuf,
        /// Largest sub-triangle side, in model units (default: 1/400 of the bounding diameter).
        #[arg(long)]
        spacing: Option<f32>,
        /// Replace the model by an N×N grid of tinted instances of it (a group tree on top).
        #[arg(long)]
        grid: Option<usize>,
        /// Node profile: raw, canopy or default.
        #[arg(long, default_value = "default")]
        profile: sct_format::Profile,
    },
}

fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s.split(',').map(|p| p.trim().parse::<f64>().map_err(|e| format!("{p:?}: {e}"))).collect::<Result<_, _>>()?;
    <[f64; 3]>::try_from(v).map_err(|_| format!("expected x,y,z, got {s:?}"))
}

/// `--up`: a named world axis or an explicit vector.
#[derive(Clone, Copy, Debug)]
enum Up {
    Axis(UpAxis),
    Vector([f64; 3]),
}

fn parse_up(s: &str) -> Result<Up, String> {
    Ok(match s.trim().to_ascii_lowercase().as_str() {
        "auto" => Up::Axis(UpAxis::Auto),
        "x" => Up::Axis(UpAxis::X),
        "y" => Up::Axis(UpAxis::Y),
        "z" => Up::Axis(UpAxis::Z),
        _ => Up::Vector(parse_vec3(s).map_err(|e| format!("expected auto, x, y, z or x,y,z: {e}"))?),
    })
}

fn parse_hex(s: &str) -> Result<[u8; 3], String> {
    let s = s.trim_start_matches('#');
    if s.len() != 6 {
        return Err(format!("expected RRGGBB, got {s:?}"));
    }
    let v = u32::from_str_radix(s, 16).map_err(|e| e.to_string())?;
    Ok([(v >> 16) as u8, (v >> 8) as u8, v as u8])
}

fn parse_pair(s: &str) -> Result<(PathBuf, PathBuf), String> {
    let (a, b) = s.split_once('=').ok_or_else(|| format!("expected MODEL.sct=MESH, got {s:?}"))?;
    Ok((PathBuf::from(a), PathBuf::from(b)))
}

fn sibling(out: &Path, suffix: &str) -> PathBuf {
    let stem = out.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "preview".into());
    out.with_file_name(format!("{stem}.{suffix}"))
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Some(Command::Sweep { models, pixel_errors, repeat, output, render }) => {
            let result = sweep::run(&models, &pixel_errors, repeat.max(1), &render.options())?;
            sweep::write_outputs(&result, &output)?;
            println!("{}", serde_json::to_string_pretty(&result)?);
            Ok(())
        }
        Some(Command::Synth { mesh, output, spacing, grid, profile }) => {
            let m = reference::WorldMesh::load(&mesh)?;
            let (_, r) = m.bound().context("the mesh has no triangles")?;
            let spacing = spacing.unwrap_or((2.0 * r / 400.0) as f32);
            let leaves = synth::sample_mesh(&m, spacing);
            let n = leaves.len();
            let tree = synth::build_tree(leaves)?;
            let scene = match grid {
                None => sct_format::Scene::single_tree(Default::default(), tree),
                Some(g) => synth::instance_grid(tree, g, g, 2.2 * r, |i| {
                    let h = (i as u32).wrapping_mul(2654435761);
                    Some([128 + (h & 127) as u8, 128 + (h >> 8 & 127) as u8, 128 + (h >> 16 & 127) as u8, 255])
                })?,
            };
            let wopts = sct_format::WriteOptions { profile, ..Default::default() };
            let stats = sct_format::write_scene_file(&output, &scene, &wopts).with_context(|| format!("writing {}", output.display()))?;
            println!("{}: {n} leaves, {} bytes", output.display(), stats.bytes);
            Ok(())
        }
        None => {
            let (Some(file), Some(output)) = (cli.file, cli.output) else {
                anyhow::bail!("usage: sct-render-preview FILE -o OUTPUT.png (see --help)");
            };
            let opts = cli.render.options();
            let out = render_preview::render_file(&file, &opts)?;
            render_preview::write_png(&output, &out.frame)?;
            let mut summary = serde_json::json!({
                "file": file,
                "output": output,
                "camera": out.camera,
                "width": opts.width,
                "height": opts.height,
                "pixel_error": opts.pixel_error,
                "splats": out.stats.splats,
                "nodes_visited": out.stats.lod.nodes_visited,
                "lod": out.stats.lod,
                "bytes_read": out.stats.bytes_read,
                "file_size": out.stats.file_size,
                "files_opened": out.stats.files,
                "covered_pixels": out.stats.covered_pixels,
                "seconds": out.stats.seconds,
            });
            if let Some(mesh_path) = &cli.reference {
                let mesh = reference::WorldMesh::load(mesh_path)?;
                let view = render_preview::View::new(&out.camera, out.near)?;
                let t = std::time::Instant::now();
                let refr = reference::render_reference(&mesh, &view, opts.shading, opts.background);
                let ref_secs = t.elapsed().as_secs_f64();
                let m = metrics::compare(&out.frame, &refr);
                let (mj, dp, rp) = (sibling(&output, "metrics.json"), sibling(&output, "diff.png"), sibling(&output, "reference.png"));
                render_preview::write_png(&rp, &refr)?;
                render_preview::write_rgb_png(&dp, &metrics::difference_image(&out.frame, &refr))?;
                let doc = serde_json::json!({ "file": file, "reference": mesh_path, "pixel_error": opts.pixel_error, "metrics": m, "reference_seconds": ref_secs, "difference_image": dp, "reference_image": rp });
                let text = serde_json::to_vec_pretty(&doc)?;
                sct_format::atomic::write_atomic(&mj, |w| {
                    use std::io::Write;
                    w.write_all(&text).map_err(sct_format::Error::from)
                })?;
                summary["metrics"] = serde_json::to_value(m)?;
                summary["metrics_file"] = serde_json::to_value(&mj)?;
            }
            if cli.json {
                println!("{}", serde_json::to_string_pretty(&summary)?);
            }
            Ok(())
        }
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("sct-render-preview: error: {e:#}");
            let invalid = e.chain().any(|c| {
                c.downcast_ref::<render_preview::Error>().is_some_and(|e| e.is_invalid_input())
                    || c.downcast_ref::<sct_format::Error>().is_some_and(|e| e.is_invalid_input())
            });
            ExitCode::from(if invalid { 1 } else { 2 })
        }
    }
}
