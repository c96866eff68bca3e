//! `sct-render-preview`: preview images of SCT files, with an optional mesh reference.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use clap::builder::TypedValueParser;
use clap::{Args, Parser, Subcommand};
use sct_format::error::print_stdout;
use render_preview::{metrics, reference, sweep, synth, CanopyOptions, Error, GaussOptions, LodSize, Method, RenderOptions, Shading, SplatShape, UpAxis, ViewPreset, Weighting};
use sct_format::view;

const EXAMPLES: &str = "\
Examples:
  sct-render-preview bunny.sct -o bunny.png
  sct-render-preview bunny.sct -o iso.png --view iso --width 640 --height 480 --pixel-error 2
  sct-render-preview scene.sct -o close.png --eye 0.1,0.2,0.3 --target 0,0.1,0 --fov 30
  sct-render-preview bunny.sct -o b.png --reference bun_zipper.ply --json
  sct-render-preview duck.sct -o g.png --method gauss --reference Duck.glb --json
  sct-render-preview duck.sct -o g.png --method gauss --gauss-weighting normalized --gauss-lowpass 0
  sct-render-preview pair.sct -o c.png --method canopy --canopy-t3 1.7 --canopy-occ-cull 1.9 --json
  sct-render-preview bunny.sct -o p.png --method parilov --parilov-threshold 45 --json
  sct-render-preview bunny.sct -o w.png --method wald --wald-radius-scale 1.2 --wald-k 8 --json
  sct-render-preview bunny.sct -o w.png --method wand --wand-d 2 --wand-seed 7 --json
  sct-render-preview spot.sct -o s.png --reference spot_triangulated.obj --min-psnr 30 --min-iou 0.97
  sct-render-preview scan.sct -o scan.png --up z --view iso
  sct-render-preview sweep --model bunny.sct=bun_zipper.ply --pixel-errors 0.5,1,2,4,8 -o chart
  sct-render-preview compare --scene one:Duck.glb --scene pair:bun_zipper.ply,dragon.ply -o cmp
  sct-render-preview compare --scene block:bun_zipper_res4.ply:8 --knobs 1,2,4 --orbit 16 -o dense
  sct-render-preview synth bun_zipper.ply -o bunny.sct --spacing 0.0005

The default camera looks at the model's front (+Z; with --up z, from -Y), upright, at the
distance where its projected extent fills 90 % of the frame (sct_format::view).

Exit status: 0 success; 1 invalid input (malformed file, degenerate camera), nothing drawn
(unless --allow-empty), an empty reference, or a --min-psnr / --min-iou check failed; 2 usage
or I/O error.";

#[derive(Parser, Debug)]
#[command(name = "sct-render-preview", version, about = "Render a preview image of an SCT scene file on the CPU (LOD splatting: --method zbuffer, gauss, canopy; visibility orders: parilov; ray tracing: wald; randomized z-buffer: wand).", after_help = EXAMPLES, args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    /// SCT file to render.
    #[arg(required = true)]
    file: Option<PathBuf>,
    /// Output image (written atomically): PNG (.png) or JPEG (.jpg, .jpeg), by extension.
    #[arg(short, long, required = true, value_parser = parse_image_output)]
    output: Option<PathBuf>,
    #[command(flatten)]
    render: RenderArgs,
    /// Also render this mesh (OBJ, glTF, PLY; a point cloud is drawn as discs) as a
    /// reference and write metrics JSON and a difference image next to the output
    /// (OUTPUT.metrics.json, OUTPUT.diff.png, OUTPUT.reference.png). Textures are bound as
    /// the SCT file's provenance records they were when it was sampled.
    #[arg(long, value_name = "MESH")]
    reference: Option<PathBuf>,
    /// Bind this image as every material's base-colour texture in the reference (overrides
    /// the texture recorded in the SCT file's provenance).
    #[arg(long, value_name = "IMAGE", requires = "reference")]
    reference_texture: Option<PathBuf>,
    /// Fail (exit 1) when the foreground PSNR against the reference is below DB.
    #[arg(long, value_name = "DB", requires = "reference")]
    min_psnr: Option<f64>,
    /// Fail (exit 1) when the silhouette IoU against the reference is below X.
    #[arg(long, value_name = "X", requires = "reference")]
    min_iou: Option<f64>,
    /// Accept an image in which nothing was drawn (and an empty reference) instead of
    /// exiting 1.
    #[arg(long)]
    allow_empty: bool,
    /// Print a JSON summary on stdout (spec/render-preview-json.md).
    #[arg(long)]
    json: bool,
}

#[derive(Args, Debug, Clone)]
struct RenderArgs {
    /// Preview method: zbuffer (opaque splats, depth buffer), gauss (elliptical Gaussian
    /// splats blended back to front, no depth buffer; Coconu & Hege; both refine the LOD cut
    /// of --pixel-error), canopy (the thesis: image-graph occlusion culling, discs in
    /// reverse occlusion-mask order; knobs --canopy-*), parilov (Parilov & Stuerzlinger: one
    /// pixel per sample in kept per-cell visibility orders, no depth buffer; knob
    /// --parilov-threshold), wald (Wald & Seidel: one ray per pixel through the implicit
    /// surface of hat-weighted splats of every leaf; knobs --wald-*) or wand (the randomized
    /// z-buffer of Wand et al.: fresh random surface points ∝ projected area as d × d squares;
    /// knobs --wand-*).
    #[arg(long, value_enum, default_value_t = Method::Zbuffer)]
    method: Method,
    /// gauss: blend (alpha blending back to front, EQ 1) or normalized (EQ 2 over the
    /// front surface found by a per-pixel visibility pass).
    #[arg(long, value_enum, default_value_t = Weighting::Blend)]
    gauss_weighting: Weighting,
    /// gauss: the back-to-front order from a per-frame depth sort, or from canopy's occlusion
    /// mask reversed (its stages 1–2 run first, with the --canopy-* settings).
    #[arg(long, value_enum, default_value_t = render_preview::Order::Depth)]
    gauss_order: render_preview::Order,
    /// gauss: isotropic low-pass variance added to every kernel, px² (0: none).
    #[arg(long, default_value_t = render_preview::gauss::DEFAULT_LOWPASS)]
    gauss_lowpass: f32,
    /// gauss: opacity at the edge of a kernel's support (the alpha test), in (0, 0.5].
    #[arg(long, default_value_t = render_preview::gauss::DEFAULT_ALPHA_MIN)]
    gauss_alpha_min: f32,
    /// canopy: stage-1 threshold, projected view-cone radius in px (default: the thesis's
    /// 2.5° at the default camera).
    #[arg(long, default_value_t = CanopyOptions::default().t1)]
    canopy_t1: f32,
    /// canopy: stage-2 (occlusion mask) threshold, px (default: 1.0°).
    #[arg(long, default_value_t = CanopyOptions::default().t2)]
    canopy_t2: f32,
    /// canopy: stage-3 threshold, px, the method's quality knob (default: 0.1°).
    #[arg(long, default_value_t = CanopyOptions::default().t3)]
    canopy_t3: f32,
    /// canopy: t_OccCull, the occlusion estimate above which a node is culled; "off" culls
    /// nothing.
    #[arg(long, default_value = "1.9", value_parser = parse_cull)]
    canopy_occ_cull: f32,
    /// canopy: t_OccClip, occluders weaker than this add no occlusion.
    #[arg(long, default_value_t = 0.0)]
    canopy_occ_clip: f32,
    /// canopy: draw the stage-3 discs through a depth buffer instead of in reverse mask order.
    #[arg(long)]
    canopy_zbuffer: bool,
    /// parilov: largest angle (degrees) between the view vector to a cell and the axis its
    /// samples are sorted along before they are re-sorted (45: no visibility artifacts; 70:
    /// the paper's practice, artifacts at most a pixel wide).
    #[arg(long, value_name = "DEG", default_value_t = 70.0)]
    parilov_threshold: f32,
    /// wald: support radius of each splat as a multiple of its leaf's radius, in (0, 8] (the
    /// method's quality knob; 1: the radii as stored, as the paper uses its radii; a ray
    /// meets about scale² as many splats).
    #[arg(long, default_value_t = render_preview::WaldOptions::default().radius_scale)]
    wald_radius_scale: f32,
    /// wald: samples of the implicit function per ray interval, both ends included (the
    /// paper's k = 4); more find roots that small k steps over.
    #[arg(long, default_value_t = render_preview::WaldOptions::default().k)]
    wald_k: u32,
    /// wand: side of each sample's square, pixels (1 = per-pixel reconstruction), the
    /// method's quality knob.
    #[arg(long, default_value_t = render_preview::WandOptions::default().d, value_parser = clap::value_parser!(u32).range(1..=i64::from(render_preview::wand::MAX_D)))]
    wand_d: u32,
    /// wand: box selection's depth accuracy ε (> 1): a sampling box's far/near depth ratio is
    /// at most √ε.
    #[arg(long, default_value_t = render_preview::WandOptions::default().eps)]
    wand_eps: f32,
    /// wand: seed of the frame's random numbers (same seed, same image, on any thread count).
    #[arg(long, default_value_t = render_preview::WandOptions::default().seed)]
    wand_seed: u64,
    /// wand: multiple of the paper's large-leaf threshold d / ln(pixels) px² above which a
    /// leaf is drawn as a splat instead of sampled ("inf": sample every leaf).
    #[arg(long, default_value_t = render_preview::WandOptions::default().large)]
    wand_large: f32,
    /// wand: multiple of the ln(pixels / d²) samples per d × d cell.
    #[arg(long, default_value_t = render_preview::WandOptions::default().oversample)]
    wand_oversample: f32,
    /// Image width in pixels (1 to 16384).
    #[arg(long, default_value_t = view::DEFAULT_WIDTH, value_parser = clap::value_parser!(u32).range(1..=i64::from(render_preview::camera::MAX_SIDE)))]
    width: u32,
    /// Image height in pixels (1 to 16384).
    #[arg(long, default_value_t = view::DEFAULT_HEIGHT, value_parser = clap::value_parser!(u32).range(1..=i64::from(render_preview::camera::MAX_SIDE)))]
    height: u32,
    /// Viewing direction when no --eye is given: front (eye on +Z), back, left (eye on
    /// -X), right, top (eye on +Y) or iso (eye along +X+Y+Z), named for a +Y-up world and
    /// turned to the --up axis.
    #[arg(long, default_value = "front", value_parser = clap::builder::PossibleValuesParser::new(ViewPreset::NAMES).try_map(|s| s.parse::<ViewPreset>()))]
    view: ViewPreset,
    /// Eye position x,y,z.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    eye: Option<[f64; 3]>,
    /// Target x,y,z (default: the framing's; with --eye, the middle of the model).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    target: Option<[f64; 3]>,
    /// World up axis for the --view presets: x, y or z, or an explicit camera up vector
    /// x,y,z (the presets then stay in the +Y-up frame). Default: the up axis recorded in
    /// the file's provenance, else y (glTF is +Y up; so are OBJ and PLY unless they say
    /// otherwise). With z up, front looks along +Y.
    #[arg(long, value_parser = parse_up, allow_hyphen_values = true)]
    up: Option<Up>,
    /// Fraction of the frame (its tighter dimension) the model's projected extent fills.
    #[arg(long, default_value_t = view::DEFAULT_FILL, value_parser = positive_f64)]
    fill: f64,
    /// Vertical field of view in degrees, in (0.01, 179).
    #[arg(long, default_value_t = view::DEFAULT_FOV_Y_DEG, value_parser = fov_degrees)]
    fov: f64,
    /// LOD threshold: largest projected splat radius in pixels (see --lod-size); wald:
    /// internal nodes whose sphere projects to at most half of it stand for their leaves.
    #[arg(long, default_value_t = render_preview::DEFAULT_PIXEL_ERROR, value_parser = positive_f32)]
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
    /// Most tree nodes one render examines (over every use of every tree); past it the
    /// render fails with "limit exceeded" instead of taking unbounded time and memory.
    #[arg(long, value_name = "N", default_value_t = render_preview::DEFAULT_MAX_NODES)]
    max_nodes: u64,
    /// Most pixels under all splats of one render (bounding boxes clipped to the image).
    #[arg(long, value_name = "N", default_value_t = render_preview::DEFAULT_MAX_SPLAT_PIXELS)]
    max_splat_pixels: u64,
    /// zbuffer: N × N subpixels a pixel (odd, 1-7), resolved as the --reference image is:
    /// coverage from the middle subpixel, colour the mean of the covered ones. 1 is about
    /// 6x faster to rasterize and aliases thin texture lines; frames past 2^25 subpixels
    /// use 1.
    #[arg(long, value_name = "N", default_value_t = render_preview::DEFAULT_SUPERSAMPLE, value_parser = clap::value_parser!(u32).range(1..=7))]
    supersample: u32,
}

impl RenderArgs {
    fn options(&self) -> RenderOptions {
        RenderOptions {
            method: self.method,
            gauss: GaussOptions { weighting: self.gauss_weighting, order: self.gauss_order, lowpass: self.gauss_lowpass, alpha_min: self.gauss_alpha_min },
            canopy: CanopyOptions {
                t1: self.canopy_t1,
                t2: self.canopy_t2,
                t3: self.canopy_t3,
                occ_cull: self.canopy_occ_cull,
                occ_clip: self.canopy_occ_clip,
                zbuffer: self.canopy_zbuffer,
            },
            parilov: render_preview::ParilovOptions { threshold_deg: self.parilov_threshold },
            wald: render_preview::WaldOptions { radius_scale: self.wald_radius_scale, k: self.wald_k },
            wand: render_preview::WandOptions { d: self.wand_d, eps: self.wand_eps, seed: self.wand_seed, large: self.wand_large, oversample: self.wand_oversample },
            width: self.width,
            height: self.height,
            view: self.view,
            fov_y_deg: self.fov,
            eye: self.eye,
            target: self.target,
            up: match self.up {
                Some(Up::Vector(v)) => Some(v),
                _ => None,
            },
            up_axis: match self.up {
                Some(Up::Axis(a)) => Some(a),
                _ => None,
            },
            fill: self.fill,
            pixel_error: self.pixel_error,
            shading: self.shading,
            splat: self.splat,
            lod_size: self.lod_size,
            backface_culling: !self.no_backface_culling,
            background: self.background,
            allow_outside_inlines: self.allow_outside_inlines,
            max_nodes: self.max_nodes,
            max_splat_pixels: self.max_splat_pixels,
            supersample: self.supersample,
            ..RenderOptions::default()
        }
    }
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Render models over a series of --pixel-error values and chart time against foreground PSNR
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
    /// Compare every method over a sweep of its knob on scenes built from meshes: time per
    /// frame against foreground PSNR and SSIM with the Pareto front (OUTPUT.png, OUTPUT.svg),
    /// the error split, orbit stability and work counters (OUTPUT.json,
    /// spec/render-preview-compare-json.md), a table on stdout.
    Compare {
        /// Scene: one:MESH, pair:FRONT,BACK (FRONT in front of BACK), grid:MESH:N (jittered
        /// N×N instances) or block:MESH:N[:S] (dense N×N×N instances, S model radii apart, default 2); repeat per scene.
        #[arg(long = "scene", required = true)]
        scenes: Vec<render_preview::scenes::SceneSpec>,
        /// Methods to compare: zbuffer, gauss, canopy, parilov, wald, wand (the ordering error
        /// of gauss, parilov and wand is measured against zbuffer drawn with one sample a
        /// pixel, rendered for that whether or not zbuffer is listed).
        #[arg(long, value_delimiter = ',', default_values_t = Method::ALL)]
        methods: Vec<Method>,
        /// Knob values (--pixel-error for zbuffer, gauss and parilov, --canopy-t3 for canopy,
        /// --wald-radius-scale for wald, --wand-d rounded, at least 1, for wand).
        #[arg(long, value_delimiter = ',', default_values_t = [0.5f32, 1.0, 2.0, 4.0])]
        knobs: Vec<f32>,
        /// Timed frames per point after a warm-up frame (the median counts).
        #[arg(long, default_value_t = 3)]
        repeat: u32,
        /// Frames of the stability orbit per method (0: none).
        #[arg(long, default_value_t = 0)]
        orbit: usize,
        /// Degrees between orbit frames.
        #[arg(long, default_value_t = 1.0)]
        orbit_step: f64,
        /// Leaves per model radius when sampling the scenes.
        #[arg(long, default_value_t = 200.0)]
        density: f64,
        /// Seeds per wand point (--wand-seed and the ones after it): the spread of its error
        /// (min / median / max; 1: the timed frame only).
        #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=1000))]
        wand_seeds: u32,
        /// Directory for the scenes' SCT files (default: OUTPUT.scenes/).
        #[arg(long)]
        work_dir: Option<PathBuf>,
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

/// `--pixel-error`: a finite number above 0 (0 would refine to every leaf and draw nothing
/// coarser; a usage error, exit 2).
fn positive_f32(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        Ok(v) => Err(format!("must be a finite number above 0, got {v}")),
        Err(e) => Err(format!("{s:?}: {e}")),
    }
}

/// `--fill`: a finite number above 0.
fn positive_f64(s: &str) -> Result<f64, String> {
    positive_f32(s)?;
    s.trim().parse::<f64>().map_err(|e| e.to_string())
}

/// `--fov`: degrees in (0.01, 179), as the camera accepts.
fn fov_degrees(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v > 0.01 && v < 179.0 => Ok(v),
        Ok(v) => Err(format!("must lie in (0.01, 179) degrees, got {v}")),
        Err(e) => Err(format!("{s:?}: {e}")),
    }
}

/// `-o`: the image format must follow from the extension (PNG or JPEG), checked before
/// anything is rendered.
fn parse_image_output(s: &str) -> Result<PathBuf, String> {
    let p = PathBuf::from(s);
    render_preview::image_file::image_kind(&p)?;
    Ok(p)
}

fn parse_cull(s: &str) -> Result<f32, String> {
    if s == "off" {
        return Ok(f32::INFINITY);
    }
    s.parse::<f32>().map_err(|e| format!("{s:?}: {e} (a number or off)"))
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
    match s.parse::<UpAxis>() {
        Ok(a) => Ok(Up::Axis(a)),
        Err(_) => Ok(Up::Vector(parse_vec3(s).map_err(|e| format!("expected x, y, z or a vector x,y,z: {e}"))?)),
    }
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

fn run(mut cli: Cli) -> anyhow::Result<()> {
    match cli.command.take() {
        Some(Command::Sweep { models, pixel_errors, repeat, output, render }) => {
            let result = sweep::run(&models, &pixel_errors, repeat.max(1), &render.options())?;
            sweep::write_outputs(&result, &output)?;
            print_stdout(&serde_json::to_string_pretty(&result)?)?;
            Ok(())
        }
        Some(Command::Compare { scenes, methods, knobs, repeat, orbit, orbit_step, density, wand_seeds, work_dir, output, render }) => {
            let base = render.options();
            let o = render_preview::compare::CompareOptions {
                scenes,
                methods,
                knobs,
                repeat: repeat.max(1),
                orbit_frames: orbit,
                orbit_step_deg: orbit_step,
                orbit_knob: base.pixel_error,
                wand_seeds,
                density,
                work_dir: work_dir.unwrap_or_else(|| sibling(&output, "scenes")),
                base,
            };
            let result = render_preview::compare::run(&o, |line| eprintln!("{line}"))?;
            render_preview::compare::write_outputs(&result, &output)?;
            print_stdout(render_preview::compare::table(&result).trim_end_matches('\n'))?;
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
            print_stdout(&format!("{}: {n} leaves, {} bytes", output.display(), stats.bytes))?;
            Ok(())
        }
        None => {
            let (Some(file), Some(output)) = (cli.file.clone(), cli.output.clone()) else {
                anyhow::bail!("usage: sct-render-preview FILE -o OUTPUT.png (see --help)");
            };
            preview(&cli, &file, &output)
        }
    }
}

/// Schema of the `--json` summary and of OUTPUT.metrics.json.
const SCHEMA: &str = "sct-render-preview/2";

/// Renders `file` to `output`, with the reference comparison and checks when asked.
fn preview(cli: &Cli, file: &Path, output: &Path) -> anyhow::Result<()> {
    let opts = cli.render.options();
    let out = render_preview::render_file(file, &opts)?;
    render_preview::write_png(output, &out.frame)?;
    let empty = out.empty_reason();
    let extent = out.frame.covered_box().map(|[x0, y0, x1, y1]| {
        [(x1 + 1 - x0) as f64 / opts.width.max(1) as f64, (y1 + 1 - y0) as f64 / opts.height.max(1) as f64]
    });
    let mut summary = serde_json::json!({
        "schema": SCHEMA,
        "file": file,
        "output": output,
        "camera": out.camera,
        "up_axis": out.up_axis,
        "width": opts.width,
        "height": opts.height,
        "pixel_error": opts.pixel_error,
        "method": opts.method,
        "supersample": out.stats.supersample,
        "gauss": (opts.method == Method::Gauss).then_some(opts.gauss),
        "canopy": out.stats.canopy.map(|s| serde_json::json!({ "options": opts.canopy, "stats": s })),
        "parilov": out.stats.parilov.map(|s| serde_json::json!({ "options": opts.parilov, "stats": s })),
        "wald": out.stats.wald.map(|s| serde_json::json!({ "options": opts.wald, "stats": s })),
        "wand": out.stats.wand.map(|s| serde_json::json!({ "options": opts.wand, "stats": s })),
        "work": out.stats.work,
        "splats": out.stats.splats,
        "nodes_visited": out.stats.lod.nodes_visited,
        "lod": out.stats.lod,
        "bytes_read": out.stats.bytes_read,
        "file_size": out.stats.file_size,
        "files_opened": out.stats.files,
        "covered_pixels": out.stats.covered_pixels,
        "extent": extent,
        "empty": empty,
        "seconds": out.stats.seconds,
    });
    // The first failed check, reported after the outputs are written.
    let mut failure: Option<Error> = None;
    if let (Some(reason), false) = (&empty, cli.allow_empty) {
        failure = Some(Error::Empty(reason.clone()));
    }
    if let Some(mesh_path) = &cli.reference {
        let (mesh, load) = reference::load_for(file, mesh_path, &out.provenance, cli.reference_texture.as_deref())?;
        if mesh.is_empty() {
            return Err(Error::Invalid(format!("{}: the reference has no triangles and no points to draw", mesh_path.display())).into());
        }
        let view = render_preview::View::new(&out.camera, out.near)?;
        let t = std::time::Instant::now();
        let refr = reference::render_reference_bounded(&mesh, &view, opts.shading, opts.background, opts.max_splat_pixels / reference::REFERENCE_PIXEL_COST)?;
        let ref_secs = t.elapsed().as_secs_f64();
        let m = metrics::compare(&out.frame, &refr);
        let (mj, dp, rp) = (sibling(output, "metrics.json"), sibling(output, "diff.png"), sibling(output, "reference.png"));
        render_preview::write_png(&rp, &refr)?;
        render_preview::write_rgb_png(&dp, &metrics::difference_image(&out.frame, &refr))?;
        let doc = serde_json::json!({
            "schema": SCHEMA,
            "file": file,
            "reference": mesh_path,
            "reference_load": load,
            "pixel_error": opts.pixel_error,
            "method": opts.method,
            "metrics": m,
            "reference_seconds": ref_secs,
            "difference_image": dp,
            "reference_image": rp,
        });
        let text = serde_json::to_vec_pretty(&doc)?;
        sct_format::atomic::write_atomic(&mj, |w| {
            use std::io::Write;
            w.write_all(&text).map_err(sct_format::Error::from)
        })?;
        summary["metrics"] = serde_json::to_value(m)?;
        summary["reference_load"] = serde_json::to_value(&load)?;
        summary["metrics_file"] = serde_json::to_value(&mj)?;
        if failure.is_none() {
            failure = check(&m, cli.min_psnr, cli.min_iou, cli.allow_empty);
        }
    }
    if cli.json {
        print_stdout(&serde_json::to_string_pretty(&summary)?)?;
    }
    match failure {
        Some(e) => Err(e.into()),
        None => Ok(()),
    }
}

/// The `--min-psnr` / `--min-iou` gates and the empty-reference rule: the first failure,
/// as a one-line reason.
fn check(m: &metrics::Metrics, min_psnr: Option<f64>, min_iou: Option<f64>, allow_empty: bool) -> Option<Error> {
    if m.empty == Some(metrics::Empty::Reference) && !allow_empty {
        return Some(Error::Empty("the reference render is empty (the mesh is outside the view or culled)".into()));
    }
    if let Some(min) = min_psnr {
        match m.fg_psnr_db {
            None => return Some(Error::Check(format!("foreground PSNR is not scored (an image is empty), --min-psnr {min} not met"))),
            Some(db) if db < min => return Some(Error::Check(format!("foreground PSNR {db:.2} dB is below --min-psnr {min}"))),
            _ => {}
        }
    }
    if let Some(min) = min_iou {
        if m.empty.is_some() || m.silhouette_iou < min {
            return Some(Error::Check(format!("silhouette IoU {:.4} is below --min-iou {min}", m.silhouette_iou)));
        }
    }
    None
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    voxelize::interrupt::remove_temp_files_on_signal("sct-render-preview");
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("sct-render-preview: error: {}", sct_format::error::one_line(e.as_ref()));
            let invalid = e.chain().any(|c| {
                c.downcast_ref::<render_preview::Error>().is_some_and(|e| e.is_invalid_input())
                    || c.downcast_ref::<sct_format::Error>().is_some_and(|e| e.is_invalid_input())
            });
            ExitCode::from(if invalid { 1 } else { 2 })
        }
    }
}
