//! # render-preview
//!
//! A CPU preview renderer for SCT scene files (thesis §3.3, §3.6, §5.8): refinement from
//! the root with screen-space thresholds on the projected size of each node's sphere (the
//! conic section of its view cone, EQ 43–47), view-frustum and normal-cone back-face
//! culling, lazy block decoding (only the blocks the view needs are read), and
//! depth-tested elliptical splats rasterized in parallel screen tiles, drawn 3 × 3 subpixels
//! a pixel and resolved as the reference is ([`zbuffer`](mod@zbuffer)).
//!
//! [`method`] lists the preview methods behind [`RenderOptions::method`]: `zbuffer` (the
//! above, the default), [`gauss`] (Coconu & Hege's elliptical Gaussian splats blended back
//! to front), [`canopy`] (the thesis's image-graph occlusion culling and depth-buffer-free
//! order), [`parilov`] (Parilov & Stuerzlinger's multi-view visibility orderings), [`wald`]
//! (Wald & Seidel: one ray per pixel through the implicit surface of hat-weighted splats) and
//! [`wand`] (the randomized z-buffer: fresh random surface points ∝ projected area each frame,
//! no LOD); each reports [`Work`] counters.
//!
//! [`reference`](mod@reference) renders the source mesh with a triangle rasterizer under the same camera
//! and shading, and [`metrics`] compares the two (PSNR, SSIM, silhouette IoU, holes);
//! [`sweep`] charts speed against accuracy over a range of thresholds, and [`compare`] every
//! method over its knob on [`scenes`] built from meshes, with the error split three ways.
//!
//! ```no_run
//! use render_preview::{render_file, RenderOptions};
//! let out = render_file(std::path::Path::new("bunny.sct"), &RenderOptions::default())?;
//! render_preview::write_png(std::path::Path::new("bunny.png"), &out.frame)?;
//! # Ok::<(), render_preview::Error>(())
//! ```

pub mod camera;
pub mod canopy;
pub mod compare;
pub mod compare_chart;
pub mod error;
pub mod failure_chart;
pub mod failure_map;
pub mod gauss;
pub mod image_file;
mod lod;
pub mod method;
pub mod parilov;
pub mod metrics;
pub mod provenance;
pub mod raster;
pub mod reference;
pub mod scene;
pub mod scenes;
pub mod shade;
pub mod sweep;
pub mod synth;
pub mod wald;
pub mod wand;
pub mod zbuffer;

use std::path::Path;
use std::time::Instant;

pub use camera::{Camera, UpAxis, View, ViewPreset};
pub use canopy::{CanopyOptions, CanopyStats};
pub use error::{Error, Result};
pub use gauss::{GaussOptions, Order, Weighting};
pub use method::{Method, Work};
pub use parilov::{ParilovOptions, ParilovStats};
pub use lod::{LodStats, NODES_EXAMINED, PIXELS_COVERED};
pub use raster::{Frame, Splat};
pub use scene::SceneFiles;
pub use shade::Shading;
pub use wald::{WaldOptions, WaldStats};
pub use wand::{WandOptions, WandStats};

use sct_format::view;
use sct_format::Limits;

/// Splat shape.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SplatShape {
    /// Ellipses oriented by the node normal (circles for wide normal cones).
    #[default]
    Ellipse,
    /// The conservative circle of EQ 46.
    Disc,
}

/// What `--pixel-error` bounds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum LodSize {
    /// The projected radius of the splat drawn for a node: its patch's equal-area disc
    /// (×AREA_COVER, at most the sphere). About 3.4x fewer nodes than `sphere` at the
    /// same threshold, and faster at equal accuracy against the mesh.
    #[default]
    Patch,
    /// The projected radius of the node's bounding sphere (EQ 46, the thesis' test).
    Sphere,
}

/// Splats are drawn with at most this multiple of the radius of the disc whose
/// area equals the node's surface area (see `lod::decide`).
pub const AREA_COVER: f32 = 1.3;

/// The `zbuffer` and `gauss` methods refine internal nodes that may hold part of an outline
/// (their normal cone may turn edge-on to the eye) until their splat is at most this
/// fraction of `--pixel-error`. `canopy` keeps the thesis's cut.
pub const OUTLINE_REFINE: f32 = 0.5;

/// Everything that controls a render.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOptions {
    /// How the LOD cut is drawn.
    pub method: Method,
    /// Settings of [`Method::Gauss`].
    pub gauss: GaussOptions,
    /// Settings of [`Method::Canopy`].
    pub canopy: CanopyOptions,
    /// Settings of [`Method::Parilov`].
    pub parilov: ParilovOptions,
    /// Settings of [`Method::Wald`].
    pub wald: WaldOptions,
    /// Settings of [`Method::Wand`].
    pub wand: WandOptions,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Viewing direction used when no eye is given.
    pub view: ViewPreset,
    /// Vertical field of view, degrees.
    pub fov_y_deg: f64,
    /// Explicit eye (otherwise the model is framed from `view`, see [`sct_format::view`]).
    pub eye: Option<[f64; 3]>,
    /// Explicit target (otherwise the framing's, or the model's centre when only the eye
    /// is given).
    pub target: Option<[f64; 3]>,
    /// Explicit camera up vector (otherwise the preset's); the presets then stay in the
    /// +Y-up frame.
    pub up: Option<[f64; 3]>,
    /// World up axis the view presets are turned to; `None`: the one recorded in the
    /// file's provenance, else +Y.
    pub up_axis: Option<UpAxis>,
    /// Fraction of the frame (tighter dimension) the model's projected extent fills.
    pub fill: f64,
    /// LOD threshold: a node is drawn once its projected size (see [`LodSize`]) is at most
    /// this many pixels ([`DEFAULT_PIXEL_ERROR`]).
    pub pixel_error: f32,
    /// Lighting.
    pub shading: Shading,
    /// Splat shape.
    pub splat: SplatShape,
    /// What the LOD threshold bounds.
    pub lod_size: LodSize,
    /// Cull nodes whose normal cone faces away from the eye.
    pub backface_culling: bool,
    /// Background colour (sRGB).
    pub background: [u8; 3],
    /// Reader limits.
    pub limits: Limits,
    /// Follow inlines whose target lies outside the scene file's directory.
    pub allow_outside_inlines: bool,
    /// Most tree nodes one render examines, summed over every use of every tree; each may
    /// become a splat (44 bytes), so this bounds memory and time for any scene
    /// ([`DEFAULT_MAX_NODES`]).
    pub max_nodes: u64,
    /// Most pixels under the splats of one render, each splat counted by its bounding box
    /// clipped to the image: the raster's work ([`DEFAULT_MAX_SPLAT_PIXELS`]).
    pub max_splat_pixels: u64,
    /// `zbuffer`: subpixels per pixel side, odd ([`DEFAULT_SUPERSAMPLE`]). A pixel is
    /// covered when its middle subpixel is, and has the mean colour of its covered
    /// subpixels in linear light, as the mesh reference resolves its pixels: colour edges
    /// inside a surface (texture lines, text, a decal's border) are antialiased, outlines
    /// stay as one sample a pixel draws them. The LOD cut and its limits stay in output
    /// pixels. A frame that would pass [`MAX_SUPERSAMPLED_PIXELS`] is drawn with one
    /// sample a pixel.
    pub supersample: u32,
}

/// Default [`RenderOptions::pixel_error`]: splats of at most 0.75 px radius, 1.5 px across,
/// the default build's voxel at the default view. The default build samples pieces whose
/// colour varies at half the voxel (texture lines, text, a decal's border); at 1 px the cut
/// merged those quarters back in pairs, and the detail they hold was lost (AlphaBlendModeTest,
/// front: 24.9 dB at 1 px, 25.7 dB at 0.75 px), for 2–6 % more splats at the default view.
pub const DEFAULT_PIXEL_ERROR: f32 = 0.75;

/// Default [`RenderOptions::supersample`]: 3 × 3. Opaque splats of about a pixel draw a
/// texture's line of 1.4 px as two black pixels where the reference shows 131, 0, 121:
/// AlphaBlendModeTest (thin frames and labels) scores 21.3 dB with one sample a pixel and
/// 24.9 dB with 3 × 3. The frame is drawn in screen tiles ([`zbuffer::zbuffer_tiled`]), so
/// that 9× the samples cost 1.7–2.0× the raster time of one sample a pixel at 1280 × 720
/// (0.10–0.16 s against 0.055–0.079 s, 2 shared cores under load; drawn whole-frame they took
/// 0.46–0.58 s; BENCHMARKS.md, "Accuracy at default settings").
pub const DEFAULT_SUPERSAMPLE: u32 = 3;

/// Most subpixels of a supersampled frame: 2^25 (a 1920 × 1080 frame at 3 × 3 is 18.7 M).
/// The preview keeps only a tile's subpixels at a time, but the mesh reference draws its
/// whole subframe (8 bytes a subpixel, and 8 more per raster worker for point clouds).
pub const MAX_SUPERSAMPLED_PIXELS: u64 = 1 << 25;

/// The subpixels per side a render of `opts` draws: [`RenderOptions::supersample`] for
/// `zbuffer` while the frame stays within [`MAX_SUPERSAMPLED_PIXELS`], else 1.
pub fn supersample_used(opts: &RenderOptions) -> u32 {
    let s = opts.supersample.max(1);
    let subpixels = u64::from(opts.width) * u64::from(opts.height) * u64::from(s) * u64::from(s);
    if opts.method == Method::Zbuffer && subpixels <= MAX_SUPERSAMPLED_PIXELS {
        s
    } else {
        1
    }
}

/// Default [`RenderOptions::max_nodes`]: 10^7 nodes, at most 0.44 GB of splats. Default
/// 1280 × 720 previews examine 0.2–1.4 M (BENCHMARKS.md: a 3.7 M-leaf bunny, 600 × 600
/// instances); a finer `--pixel-error` or larger image may ask for more with `--max-nodes`.
pub const DEFAULT_MAX_NODES: u64 = 10_000_000;
/// Default [`RenderOptions::max_splat_pixels`]: 2^31, a few seconds of rasterizing; an
/// ordinary preview covers each of its 0.9 M pixels a few times.
pub const DEFAULT_MAX_SPLAT_PIXELS: u64 = 1 << 31;

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            method: Method::Zbuffer,
            gauss: GaussOptions::default(),
            canopy: CanopyOptions::default(),
            parilov: ParilovOptions::default(),
            wald: WaldOptions::default(),
            wand: WandOptions::default(),
            width: view::DEFAULT_WIDTH,
            height: view::DEFAULT_HEIGHT,
            view: ViewPreset::Front,
            fov_y_deg: view::DEFAULT_FOV_Y_DEG,
            eye: None,
            target: None,
            up: None,
            up_axis: None,
            fill: view::DEFAULT_FILL,
            pixel_error: DEFAULT_PIXEL_ERROR,
            shading: Shading::Lambert,
            splat: SplatShape::Ellipse,
            lod_size: LodSize::Patch,
            backface_culling: true,
            background: [24, 24, 28],
            limits: Limits::default(),
            allow_outside_inlines: false,
            max_nodes: DEFAULT_MAX_NODES,
            max_splat_pixels: DEFAULT_MAX_SPLAT_PIXELS,
            supersample: DEFAULT_SUPERSAMPLE,
        }
    }
}

impl RenderOptions {
    /// The frame the view presets are taken in: an explicit `up` vector keeps the presets
    /// as documented (+Y-up frame) and only sets the camera's up; otherwise the option's
    /// axis, else `recorded` (the file's provenance), else +Y.
    pub fn up_frame(&self, recorded: Option<UpAxis>) -> UpAxis {
        match (self.up, self.up_axis) {
            (Some(_), _) => UpAxis::Y,
            (None, Some(a)) => a,
            (None, None) => recorded.unwrap_or_default(),
        }
    }

    /// The camera for a scene whose extent is given by world-space `spheres` (centre,
    /// radius; none for an empty scene), seen from the preset in the `up` frame: the
    /// spheres' extremes along the camera's axes are framed with
    /// [`view::frame_points`], then the explicit eye, target and up replace the framing's.
    pub fn camera(&self, spheres: &[([f64; 3], f64)], up: UpAxis) -> Camera {
        let points = framing_points(spheres, self.view, up);
        let f = view::frame_points(&points, self.view, up, self.fov_y_deg, self.width, self.height, self.fill);
        let framed = Camera::from_framing(&f, self.fov_y_deg, self.width, self.height);
        let back: [f64; 3] = std::array::from_fn(|k| f.eye[k] - f.target[k]);
        let (eye, target) = match (self.eye, self.target) {
            (None, None) => (framed.eye, framed.target),
            // Same direction and distance as the framing, about the given target.
            (None, Some(t)) => (std::array::from_fn(|k| t[k] + back[k]), t),
            // Looking at the middle of the model.
            (Some(e), None) => (e, bbox_center(&points).unwrap_or(f.target)),
            (Some(e), Some(t)) => (e, t),
        };
        Camera { eye, target, up: self.up.unwrap_or(framed.up), ..framed }
    }
}

/// Points whose extent is the spheres': each centre ± radius along the camera axes of
/// `preset` (turned to `up`), the sphere's extremes in the image plane and in depth.
pub fn framing_points(spheres: &[([f64; 3], f64)], preset: ViewPreset, up: UpAxis) -> Vec<[f64; 3]> {
    let (back, vup) = preset.directions();
    let (back, vup) = (up.rotate(back), up.rotate(vup));
    let right = [vup[1] * back[2] - vup[2] * back[1], vup[2] * back[0] - vup[0] * back[2], vup[0] * back[1] - vup[1] * back[0]];
    let l = (right[0] * right[0] + right[1] * right[1] + right[2] * right[2]).sqrt();
    // The presets' up is never parallel to their direction, so l > 0.
    let right = right.map(|v| v / l);
    let mut out = Vec::with_capacity(spheres.len() * 6);
    for &(c, r) in spheres {
        let r = if r.is_finite() && r > 0.0 { r } else { 0.0 };
        for axis in [right, vup, back] {
            for s in [-r, r] {
                out.push(std::array::from_fn(|k| c[k] + s * axis[k]));
            }
        }
    }
    out
}

/// Centre of the points' bounding box (`None` without finite points).
fn bbox_center(points: &[[f64; 3]]) -> Option<[f64; 3]> {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points.iter().filter(|p| p.iter().all(|v| v.is_finite())) {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    lo[0].is_finite().then(|| std::array::from_fn(|k| 0.5 * lo[k] + 0.5 * hi[k]))
}

/// Seconds spent per phase.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Phases {
    /// Opening the file (index only).
    pub open: f64,
    /// Choosing the camera (reading the framing cut; included in `traverse`).
    pub frame: f64,
    /// Refinement, block decoding and splat setup.
    pub traverse: f64,
    /// Rasterization (for `gauss`: compositing, the depth sort included).
    pub raster: f64,
    /// The per-frame depth sort (`gauss`; 0 for `zbuffer`), part of `raster`.
    pub sort: f64,
    /// Everything, PNG encoding excluded.
    pub total: f64,
}

/// Counters of a render.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct RenderStats {
    /// The method that drew the frame.
    pub method: Method,
    /// Work counters comparable across methods.
    pub work: Work,
    /// The thesis's Table 14 columns (`canopy` only).
    pub canopy: Option<CanopyStats>,
    /// Cells, re-sorts and samples (`parilov` only).
    pub parilov: Option<ParilovStats>,
    /// Per-ray counters (`wald` only).
    pub wald: Option<WaldStats>,
    /// Samples, boxes and splat-path counters (`wand` only).
    pub wand: Option<WandStats>,
    /// Subpixels per pixel side drawn ([`RenderOptions::supersample`]; 1 for the methods
    /// that do not supersample).
    pub supersample: u32,
    /// Splats rasterized.
    pub splats: u64,
    /// Refinement counters.
    pub lod: LodStats,
    /// Bytes of SCT data read (headers, indices and decoded blocks).
    pub bytes_read: u64,
    /// Total size of the SCT files opened.
    pub file_size: u64,
    /// Files opened (1 + inlines reached).
    pub files: usize,
    /// Pixels covered.
    pub covered_pixels: u64,
    /// Timings.
    pub seconds: Phases,
}

/// A finished render.
#[derive(Clone, Debug)]
pub struct Rendered {
    /// The image.
    pub frame: Frame,
    /// The camera used.
    pub camera: Camera,
    /// Counters and timings.
    pub stats: RenderStats,
    /// Near distance used (the reference renderer must use the same).
    pub near: f64,
    /// The world up axis the view presets were turned to.
    pub up_axis: UpAxis,
    /// What the main file's provenance says (up axis, texture binding).
    pub provenance: provenance::Provenance,
}

impl Rendered {
    /// Why nothing was drawn, or `None` when some pixel is covered. Read from the
    /// refinement counters: no nodes at all, every node outside the view frustum, the rest
    /// culled as back-facing, or splats that cover no pixel centre.
    pub fn empty_reason(&self) -> Option<String> {
        if self.stats.covered_pixels > 0 {
            return None;
        }
        let l = &self.stats.lod;
        Some(if l.nodes_visited == 0 {
            "the file has no geometry (no tree reached from the scene graph's root has nodes)".to_string()
        } else if self.stats.splats > 0 {
            format!("all {} splats fall outside the image or between pixel centres", self.stats.splats)
        } else if l.backface_culled == 0 {
            "every node lies outside the view frustum: the camera looks away from the model, or the model is behind it (check --eye and --target)"
                .to_string()
        } else if l.frustum_culled == 0 {
            "back-face culling removed every node: the camera sees only the back of the surface, e.g. from inside a closed model (--no-backface-culling draws back faces)".to_string()
        } else {
            format!(
                "{} nodes lie outside the view frustum and back-face culling removed the other {} (camera inside the model or looking at its back; --no-backface-culling draws back faces)",
                l.frustum_culled, l.backface_culled
            )
        })
    }
}

/// Bounding sphere of a scene as (centre, radius).
pub fn scene_bound(files: &SceneFiles) -> Option<([f64; 3], f64)> {
    files.root_bound().map(|n| (n.center.map(f64::from), n.radius as f64))
}

/// The camera, near distance, view and refinement parameters of a render of `files` with
/// `opts` (shared by [`render`] and [`collect_splats`]).
fn setup(files: &SceneFiles, opts: &RenderOptions) -> Result<(Camera, f64, View, lod::LodParams, UpAxis, f64)> {
    let t0 = Instant::now();
    let up = opts.up_frame(files.provenance().up);
    // Framing reads a few shallow levels; an explicit eye and target need none of it.
    let spheres = if opts.eye.is_some() && opts.target.is_some() { Vec::new() } else { files.framing_spheres() };
    let camera = opts.camera(&spheres, up);
    // Near distance scaled to the scene so that close-ups keep depth precision.
    let bound = scene_bound(files);
    let near = bound.map_or(1e-6, |(_, r)| (r * 1e-5).max(1e-12));
    let view = View::new(&camera, near)?;
    let params = lod::LodParams {
        max_nodes: opts.max_nodes,
        max_splat_pixels: opts.max_splat_pixels,
        pixel_error: opts.pixel_error,
        shading: opts.shading,
        ellipses: opts.splat == SplatShape::Ellipse,
        backface: opts.backface_culling,
        max_radius: 2.0 * opts.width.max(opts.height) as f32,
        area_cover: AREA_COVER,
        lod_size: opts.lod_size,
        outline_refine: OUTLINE_REFINE,
        kernel: (opts.method == Method::Gauss).then(|| gauss::Kernel::new(&opts.gauss)),
        leaves: (opts.method == Method::Wald).then_some(opts.wald.radius_scale),
        matrix_splats: matches!(opts.method, Method::Parilov | Method::Zbuffer),
        rims: opts.method == Method::Zbuffer,
    };
    Ok((camera, near, view, params, up, t0.elapsed().as_secs_f64()))
}

/// The subpixels per side a render of `opts` draws ([`supersample_used`]), and the view and
/// refinement parameters on its subframe (the cut kept in output pixels).
fn supersampled(opts: &RenderOptions, view: &View, params: lod::LodParams) -> (u32, View, lod::LodParams) {
    let ss = supersample_used(opts);
    let fine_params = lod::LodParams { pixel_error: params.pixel_error * ss as f32, max_radius: params.max_radius * ss as f32, ..params };
    (ss, view.supersampled(ss), fine_params)
}

/// Renders an open scene.
pub fn render(files: &mut SceneFiles, opts: &RenderOptions) -> Result<Rendered> {
    let t0 = Instant::now();
    if !(opts.pixel_error.is_finite() && opts.pixel_error > 0.0) {
        return Err(Error::Invalid(format!("pixel error {} must be a positive number", opts.pixel_error)));
    }
    if !(opts.fill.is_finite() && opts.fill > 0.0) {
        return Err(Error::Invalid(format!("fill {} must be a positive number (0.9: the model fills 90 % of the frame)", opts.fill)));
    }
    if opts.method == Method::Gauss {
        let g = &opts.gauss;
        if !(g.alpha_min > 0.0 && g.alpha_min <= 0.5) {
            return Err(Error::Invalid(format!("gauss alpha_min {} must lie in (0, 0.5]", g.alpha_min)));
        }
        if !(g.lowpass.is_finite() && g.lowpass >= 0.0) {
            return Err(Error::Invalid(format!("gauss low-pass variance {} must be a finite number ≥ 0", g.lowpass)));
        }
    }
    if opts.method == Method::Parilov && !(opts.parilov.threshold_deg > 0.0 && opts.parilov.threshold_deg <= 90.0) {
        return Err(Error::Invalid(format!("parilov threshold {}° must lie in (0, 90]", opts.parilov.threshold_deg)));
    }
    if opts.method == Method::Canopy || (opts.method == Method::Gauss && opts.gauss.order == gauss::Order::Mask) {
        let c = &opts.canopy;
        if ![c.t1, c.t2, c.t3].iter().all(|t| t.is_finite() && *t > 0.0) || c.t2 > c.t1 || c.t3 > c.t2 {
            return Err(Error::Invalid(format!("canopy thresholds t1 {} ≥ t2 {} ≥ t3 {} must be positive pixel sizes", c.t1, c.t2, c.t3)));
        }
        if c.occ_cull.is_nan() || !(c.occ_clip.is_finite() && c.occ_clip >= 0.0) {
            return Err(Error::Invalid(format!("canopy t_OccCull {} and t_OccClip {} must be numbers (t_OccClip ≥ 0)", c.occ_cull, c.occ_clip)));
        }
    }
    if opts.supersample % 2 == 0 || opts.supersample > 7 {
        return Err(Error::Invalid(format!("supersample {} must be odd and at most 7 (a pixel's middle subpixel is its centre)", opts.supersample)));
    }
    if opts.method == Method::Wald {
        opts.wald.validate().map_err(Error::Invalid)?;
    }
    if opts.method == Method::Wand {
        opts.wand.check().map_err(Error::Invalid)?;
    }
    let (camera, near, view, params, up_axis, frame_secs) = setup(files, opts)?;
    if opts.method == Method::Wald {
        let (surfels, lod) = files.collect_surfels(&view, &params)?;
        let t1 = Instant::now();
        let bvh = wald::Bvh::build(surfels);
        let t2 = Instant::now();
        let [r, g, b] = opts.background;
        let mut frame = Frame::new(opts.width as usize, opts.height as usize, [r, g, b, 255]);
        let mut ws = wald::trace(&mut frame, &bvh, &view, &opts.wald, opts.shading);
        let t3 = Instant::now();
        ws.collect_seconds = (t1 - t0).as_secs_f64() - frame_secs;
        ws.build_seconds = (t2 - t1).as_secs_f64();
        let covered = frame.covered() as u64;
        let stats = RenderStats {
            method: opts.method,
            work: Work::new(lod.nodes_visited, ws.splats, wald::fragments(&ws), covered, files.bytes_read()),
            canopy: None,
            parilov: None,
            wald: Some(ws),
            wand: None,
            supersample: 1,
            splats: ws.splats,
            lod,
            bytes_read: files.bytes_read(),
            file_size: files.file_len(),
            files: files.file_count(),
            covered_pixels: covered,
            seconds: Phases { open: 0.0, frame: frame_secs, traverse: (t2 - t0).as_secs_f64(), raster: (t3 - t2).as_secs_f64(), sort: 0.0, total: (t3 - t0).as_secs_f64() },
        };
        return Ok(Rendered { frame, camera, stats, near, up_axis, provenance: files.provenance() });
    }
    if opts.method == Method::Wand {
        let [r, g, b] = opts.background;
        let mut frame = Frame::new(opts.width as usize, opts.height as usize, [r, g, b, 255]);
        let (ws, lod, fragments, primitives) = wand::render(files, &view, &params, &opts.wand, &mut frame)?;
        let t2 = Instant::now();
        let covered = frame.covered() as u64;
        let draw = ws.draw_seconds;
        let total = (t2 - t0).as_secs_f64();
        let stats = RenderStats {
            method: opts.method,
            work: Work::new(lod.nodes_visited, primitives, fragments, covered, files.bytes_read()),
            canopy: None,
            parilov: None,
            wald: None,
            wand: Some(ws),
            supersample: 1,
            splats: primitives,
            lod,
            bytes_read: files.bytes_read(),
            file_size: files.file_len(),
            files: files.file_count(),
            covered_pixels: covered,
            seconds: Phases { open: 0.0, frame: frame_secs, traverse: total - draw, raster: draw, sort: 0.0, total },
        };
        return Ok(Rendered { frame, camera, stats, near, up_axis, provenance: files.provenance() });
    }
    let mask_order = opts.method == Method::Gauss && opts.gauss.order == gauss::Order::Mask;
    if opts.method == Method::Canopy || mask_order {
        let [r, g, b] = opts.background;
        let mut frame = Frame::new(opts.width as usize, opts.height as usize, [r, g, b, 255]);
        let draw = if mask_order { canopy::Draw::Gauss(&opts.gauss) } else { canopy::Draw::Discs };
        let (cs, lod, fragments) = canopy::render(files, &view, &params, &opts.canopy, draw, &mut frame)?;
        let t2 = Instant::now();
        let covered = frame.covered() as u64;
        let draw = cs.stage_seconds[3];
        let stats = RenderStats {
            method: opts.method,
            work: Work::new(lod.nodes_visited, cs.nodes_rasterized, fragments, covered, files.bytes_read()),
            canopy: Some(cs),
            parilov: None,
            wald: None,
            wand: None,
            supersample: 1,
            splats: cs.nodes_rasterized,
            lod,
            bytes_read: files.bytes_read(),
            file_size: files.file_len(),
            files: files.file_count(),
            covered_pixels: covered,
            seconds: Phases { open: 0.0, frame: frame_secs, traverse: (t2 - t0).as_secs_f64() - draw, raster: draw, sort: 0.0, total: (t2 - t0).as_secs_f64() },
        };
        return Ok(Rendered { frame, camera, stats, near, up_axis, provenance: files.provenance() });
    }
    if opts.method == Method::Parilov {
        let [r, g, b] = opts.background;
        let mut frame = Frame::new(opts.width as usize, opts.height as usize, [r, g, b, 255]);
        let (ps, lod) = parilov::render(files, &view, &params, &opts.parilov, &mut frame)?;
        let t2 = Instant::now();
        let covered = frame.covered() as u64;
        let stats = RenderStats {
            method: opts.method,
            // One pixel write per sample streamed, and one per hole filled.
            work: Work::new(lod.nodes_visited, ps.samples, ps.samples + ps.holes_filled, covered, files.bytes_read()),
            canopy: None,
            parilov: Some(ps),
            wald: None,
            wand: None,
            supersample: 1,
            splats: ps.samples,
            lod,
            bytes_read: files.bytes_read(),
            file_size: files.file_len(),
            files: files.file_count(),
            covered_pixels: covered,
            seconds: Phases { open: 0.0, frame: frame_secs, traverse: (t2 - t0).as_secs_f64(), raster: 0.0, sort: 0.0, total: (t2 - t0).as_secs_f64() },
        };
        return Ok(Rendered { frame, camera, stats, near, up_axis, provenance: files.provenance() });
    }
    // `zbuffer` draws `ss × ss` subpixels a pixel, the cut and the pixel limit kept in
    // output pixels.
    let (ss, fine, fine_params) = supersampled(opts, &view, params);
    let area = u64::from(ss * ss);
    let (splats, lod) = files.collect(&fine, &fine_params)?;
    let t1 = Instant::now();
    let [r, g, b] = opts.background;
    let mut sort = 0.0;
    let (frame, fragments) = match opts.method {
        Method::Gauss => {
            let mut frame = Frame::new(fine.width as usize, fine.height as usize, [r, g, b, 255]);
            let ts = Instant::now();
            let order = gauss::depth_order(&splats);
            sort = ts.elapsed().as_secs_f64();
            let fragments = gauss::composite(&mut frame, &splats, &order, &opts.gauss, view.focal).fragments;
            (frame, Some(fragments))
        }
        // `Canopy`, `Parilov`, `Wald` and `Wand` returned above.
        _ => (zbuffer::zbuffer_tiled(fine.width as usize, fine.height as usize, &splats, ss as usize, [r, g, b, 255]), None),
    };
    let t2 = Instant::now();
    // The depth buffer's fragments are counted after the clock stops (the tuned
    // rasterizer does not count them).
    let fragments = fragments.unwrap_or_else(|| method::count_fragments(&splats, fine.width as usize, fine.height as usize) / area);
    let covered = frame.covered() as u64;
    let stats = RenderStats {
        method: opts.method,
        work: Work::new(lod.nodes_visited, splats.len() as u64, fragments, covered, files.bytes_read()),
        canopy: None,
        parilov: None,
        wald: None,
        wand: None,
        supersample: ss,
        splats: splats.len() as u64,
        lod,
        bytes_read: files.bytes_read(),
        file_size: files.file_len(),
        files: files.file_count(),
        covered_pixels: covered,
        seconds: Phases { open: 0.0, frame: frame_secs, traverse: (t1 - t0).as_secs_f64(), raster: (t2 - t1).as_secs_f64(), sort, total: (t2 - t0).as_secs_f64() },
    };
    Ok(Rendered { frame, camera, stats, near, up_axis, provenance: files.provenance() })
}

/// Opens `path` and renders it; the open time is included in the timings.
pub fn render_file(path: &Path, opts: &RenderOptions) -> Result<Rendered> {
    let t0 = Instant::now();
    let mut files = SceneFiles::open(path, &opts.limits)?;
    files.set_allow_outside_inlines(opts.allow_outside_inlines);
    let open = t0.elapsed().as_secs_f64();
    let mut out = render(&mut files, opts)?;
    out.stats.seconds.open = open;
    out.stats.seconds.total += open;
    Ok(out)
}

/// Writes a frame atomically (a temporary file renamed over `path`), as PNG or JPEG by
/// the extension (see [`write_rgb_png`]).
pub fn write_png(path: &Path, frame: &Frame) -> Result<()> {
    write_rgb_png(path, &frame.to_rgb_image())
}

/// Writes an RGB image atomically, in the format the path's extension names: PNG (`.png`
/// or none) or JPEG (`.jpg`, `.jpeg`); other extensions are refused
/// ([`image_file::write_rgb_image`]).
pub fn write_rgb_png(path: &Path, img: &image::RgbImage) -> Result<()> {
    image_file::write_rgb_image(path, img)
}

/// The splats a render would rasterize (for benchmarks and tests).
pub fn collect_splats(files: &mut SceneFiles, opts: &RenderOptions) -> Result<Vec<Splat>> {
    let (_, _, view, params, _, _) = setup(files, opts)?;
    Ok(files.collect(&view, &params)?.0)
}

/// The splats a `zbuffer` render of `opts` draws on its subframe, the subframe's size and
/// its subpixels per pixel side: what [`zbuffer::zbuffer_tiled`] takes (for benchmarks and
/// tests).
pub fn collect_zbuffer_splats(files: &mut SceneFiles, opts: &RenderOptions) -> Result<(Vec<Splat>, [usize; 2], u32)> {
    let (_, _, view, params, _, _) = setup(files, opts)?;
    let (ss, fine, fine_params) = supersampled(opts, &view, params);
    Ok((files.collect(&fine, &fine_params)?.0, [fine.width as usize, fine.height as usize], ss))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_cube() -> Vec<([f64; 3], f64)> {
        view::box_corners([-1.0; 3], [1.0; 3]).into_iter().map(|c| (c, 0.0)).collect()
    }

    /// Regression: an explicit up vector used to leave the preset rotated by the scene's
    /// up axis, so `--view front --up 0,1,0` on a Z-up model looked along the up vector and
    /// failed ("up vector parallel").
    #[test]
    fn explicit_up_vector_keeps_the_presets_in_the_y_up_frame() {
        let opts = RenderOptions { up: Some([0.0, 1.0, 0.0]), up_axis: Some(UpAxis::Z), ..Default::default() };
        let up = opts.up_frame(Some(UpAxis::Z));
        assert_eq!(up, UpAxis::Y);
        let cam = opts.camera(&unit_cube(), up);
        assert!(cam.eye[2] > 1.0 && cam.eye[0].abs() < 1e-9 && cam.eye[1].abs() < 1e-9, "front view eye on +Z: {:?}", cam.eye);
        assert_eq!(cam.up, [0.0, 1.0, 0.0]);
    }

    #[test]
    fn up_axis_is_the_option_then_the_provenance_then_y() {
        let d = RenderOptions::default();
        assert_eq!(d.up_frame(None), UpAxis::Y);
        assert_eq!(d.up_frame(Some(UpAxis::Z)), UpAxis::Z);
        let x = RenderOptions { up_axis: Some(UpAxis::X), ..Default::default() };
        assert_eq!(x.up_frame(Some(UpAxis::Z)), UpAxis::X);
        // Z up: the front view looks along +Y, upright.
        let cam = d.camera(&unit_cube(), UpAxis::Z);
        assert!(cam.eye[1] < -1.0 && cam.eye[0].abs() < 1e-9 && cam.eye[2].abs() < 1e-9, "{:?}", cam.eye);
        assert_eq!(cam.up, [0.0, 0.0, 1.0]);
    }

    #[test]
    fn explicit_eye_or_target_replace_the_framing() {
        let d = RenderOptions::default();
        let framed = d.camera(&unit_cube(), UpAxis::Y);
        // Target only: same offset from it as the framing.
        let t = RenderOptions { target: Some([5.0, 0.0, 0.0]), ..Default::default() }.camera(&unit_cube(), UpAxis::Y);
        assert_eq!(t.target, [5.0, 0.0, 0.0]);
        assert!((t.eye[0] - 5.0).abs() < 1e-9 && (t.eye[2] - framed.eye[2]).abs() < 1e-9, "{t:?}");
        // Eye only: looks at the model's centre.
        let e = RenderOptions { eye: Some([3.0, 4.0, 5.0]), ..Default::default() }.camera(&unit_cube(), UpAxis::Y);
        assert_eq!((e.eye, e.target), ([3.0, 4.0, 5.0], [0.0; 3]));
    }

    #[test]
    fn framing_points_are_the_spheres_extremes_on_the_camera_axes() {
        let p = framing_points(&[([1.0, 2.0, 3.0], 0.5)], ViewPreset::Front, UpAxis::Y);
        assert_eq!(p.len(), 6);
        assert!(p.contains(&[0.5, 2.0, 3.0]) && p.contains(&[1.5, 2.0, 3.0]) && p.contains(&[1.0, 2.0, 3.5]));
        // A degenerate radius keeps the centre.
        let p = framing_points(&[([0.0; 3], f64::NAN)], ViewPreset::Iso, UpAxis::Z);
        assert!(p.iter().all(|q| *q == [0.0; 3]));
    }
}
