//! # render-preview
//!
//! A CPU preview renderer for SCT scene files (thesis §3.3, §3.6, §5.8): refinement from
//! the root with screen-space thresholds on the projected size of each node's sphere (the
//! conic section of its view cone, EQ 43–47), view-frustum and normal-cone back-face
//! culling, lazy block decoding (only the blocks the view needs are read), and
//! depth-tested elliptical splats rasterized in parallel screen tiles.
//!
//! [`reference`] renders the source mesh with a triangle rasterizer under the same camera
//! and shading, and [`metrics`] compares the two (PSNR, SSIM, silhouette IoU, holes);
//! [`sweep`] charts speed against accuracy over a range of thresholds.
//!
//! ```no_run
//! use render_preview::{render_file, RenderOptions};
//! let out = render_file(std::path::Path::new("bunny.sct"), &RenderOptions::default())?;
//! render_preview::write_png(std::path::Path::new("bunny.png"), &out.frame)?;
//! # Ok::<(), render_preview::Error>(())
//! ```

pub mod camera;
pub mod error;
mod lod;
pub mod metrics;
pub mod raster;
pub mod reference;
pub mod scene;
pub mod shade;
pub mod sweep;
pub mod synth;

use std::path::Path;
use std::time::Instant;

pub use camera::{Camera, UpAxis, View, ViewPreset};
pub use error::{Error, Result};
pub use lod::LodStats;
pub use raster::{Frame, Splat};
pub use scene::SceneFiles;
pub use shade::Shading;

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

/// Internal splats are drawn with at most this multiple of the radius of the disc whose
/// area equals the node's surface area (see `lod::decide`).
pub const AREA_COVER: f32 = 1.3;

/// Everything that controls a render.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOptions {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Viewing direction used when no eye is given.
    pub view: ViewPreset,
    /// Vertical field of view, degrees.
    pub fov_y_deg: f64,
    /// Explicit eye (otherwise the root sphere is framed from `view`).
    pub eye: Option<[f64; 3]>,
    /// Explicit target (otherwise the root sphere's centre).
    pub target: Option<[f64; 3]>,
    /// Explicit up vector (otherwise the preset's).
    pub up: Option<[f64; 3]>,
    /// World up axis the view presets are turned to (`Auto`: from the file).
    pub up_axis: UpAxis,
    /// LOD threshold: a node is drawn once its projected size (see [`LodSize`]) is at most
    /// this many pixels.
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
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            width: 1280,
            height: 720,
            view: ViewPreset::Front,
            fov_y_deg: 40.0,
            eye: None,
            target: None,
            up: None,
            up_axis: UpAxis::Auto,
            pixel_error: 1.0,
            shading: Shading::Lambert,
            splat: SplatShape::Ellipse,
            lod_size: LodSize::Patch,
            backface_culling: true,
            background: [24, 24, 28],
            limits: Limits::default(),
            allow_outside_inlines: false,
        }
    }
}

impl RenderOptions {
    /// The frame the view presets are taken in: an explicit `up` vector keeps the presets
    /// as documented (y-up frame) and only sets the camera's up; otherwise the axis, with
    /// [`UpAxis::Auto`] replaced by `auto_up`.
    fn up_frame(&self, auto_up: UpAxis) -> UpAxis {
        match (self.up, self.up_axis) {
            (Some(_), _) => UpAxis::Y,
            (None, UpAxis::Auto) => auto_up,
            (None, a) => a,
        }
    }

    /// Whether framing needs the scene's guessed up axis (which reads part of the root
    /// tree): only for [`UpAxis::Auto`] without an explicit up vector.
    fn needs_auto_up(&self) -> bool {
        self.up.is_none() && self.up_axis == UpAxis::Auto
    }

    /// The camera for a scene whose root sphere is `bound` (`None` for an empty scene);
    /// `auto_up` replaces [`UpAxis::Auto`].
    pub fn camera(&self, bound: Option<([f64; 3], f64)>, auto_up: UpAxis) -> Camera {
        let (center, radius) = bound.unwrap_or(([0.0; 3], 1.0));
        let up = self.up_frame(auto_up);
        let framed = Camera::framing(self.target.unwrap_or(center), radius, self.view, up, self.fov_y_deg, self.width, self.height);
        Camera { eye: self.eye.unwrap_or(framed.eye), up: self.up.unwrap_or(framed.up), ..framed }
    }
}

/// Seconds spent per phase.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Phases {
    /// Opening the file (index only).
    pub open: f64,
    /// Refinement, block decoding and splat setup.
    pub traverse: f64,
    /// Rasterization.
    pub raster: f64,
    /// Everything, PNG encoding excluded.
    pub total: f64,
}

/// Counters of a render.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct RenderStats {
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
}

/// Bounding sphere of a scene as (centre, radius).
pub fn scene_bound(files: &SceneFiles) -> Option<([f64; 3], f64)> {
    files.root_bound().map(|n| (n.center.map(f64::from), n.radius as f64))
}

/// The camera, near distance, view and refinement parameters of a render of `files` with
/// `opts` (shared by [`render`] and [`collect_splats`]).
fn setup(files: &SceneFiles, opts: &RenderOptions) -> Result<(Camera, f64, View, lod::LodParams)> {
    let bound = scene_bound(files);
    let auto_up = if opts.needs_auto_up() { files.auto_up() } else { UpAxis::Y };
    let camera = opts.camera(bound, auto_up);
    // Near distance scaled to the scene so that close-ups keep depth precision.
    let near = bound.map_or(1e-6, |(_, r)| (r * 1e-5).max(1e-12));
    let view = View::new(&camera, near)?;
    let params = lod::LodParams {
        pixel_error: opts.pixel_error,
        shading: opts.shading,
        ellipses: opts.splat == SplatShape::Ellipse,
        backface: opts.backface_culling,
        max_radius: 2.0 * opts.width.max(opts.height) as f32,
        area_cover: AREA_COVER,
        lod_size: opts.lod_size,
    };
    Ok((camera, near, view, params))
}

/// Renders an open scene.
pub fn render(files: &mut SceneFiles, opts: &RenderOptions) -> Result<Rendered> {
    let t0 = Instant::now();
    if !(opts.pixel_error.is_finite() && opts.pixel_error > 0.0) {
        return Err(Error::Invalid(format!("pixel error {} must be a positive number", opts.pixel_error)));
    }
    let (camera, near, view, params) = setup(files, opts)?;
    let (splats, lod) = files.collect(&view, &params)?;
    let t1 = Instant::now();
    let [r, g, b] = opts.background;
    let mut frame = Frame::new(opts.width as usize, opts.height as usize, [r, g, b, 255]);
    raster::rasterize(&mut frame, &splats);
    raster::fill_holes(&mut frame);
    let t2 = Instant::now();
    let stats = RenderStats {
        splats: splats.len() as u64,
        lod,
        bytes_read: files.bytes_read(),
        file_size: files.file_len(),
        files: files.file_count(),
        covered_pixels: frame.covered() as u64,
        seconds: Phases { open: 0.0, traverse: (t1 - t0).as_secs_f64(), raster: (t2 - t1).as_secs_f64(), total: (t2 - t0).as_secs_f64() },
    };
    Ok(Rendered { frame, camera, stats, near })
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

/// Writes a frame as PNG, atomically (a temporary file renamed over `path`).
pub fn write_png(path: &Path, frame: &Frame) -> Result<()> {
    write_rgb_png(path, &frame.to_rgb_image())
}

/// Writes an RGB image as PNG, atomically.
pub fn write_rgb_png(path: &Path, img: &image::RgbImage) -> Result<()> {
    let fail = |m: String| Error::Output { path: path.to_path_buf(), message: m };
    sct_format::atomic::write_atomic(path, |w| {
        img.write_to(w, image::ImageFormat::Png)
            .map_err(|e| sct_format::Error::Io { path: Some(path.to_path_buf()), source: std::io::Error::other(e) })
    })
    .map_err(|e| fail(e.to_string()))
}

/// The splats a render would rasterize (for benchmarks and tests).
pub fn collect_splats(files: &mut SceneFiles, opts: &RenderOptions) -> Result<Vec<Splat>> {
    let (_, _, view, params) = setup(files, opts)?;
    Ok(files.collect(&view, &params)?.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: an explicit up vector used to leave the preset rotated by the scene's
    /// auto-detected axis, so `--view front --up 0,1,0` on a Z-tall model looked along the
    /// up vector and failed ("up vector parallel").
    #[test]
    fn explicit_up_vector_keeps_the_presets_in_the_y_up_frame() {
        let opts = RenderOptions { up: Some([0.0, 1.0, 0.0]), up_axis: UpAxis::Y, ..Default::default() };
        assert!(!opts.needs_auto_up());
        let cam = opts.camera(Some(([0.0; 3], 1.0)), UpAxis::Z);
        assert!(cam.eye[2] > 1.0 && cam.eye[0].abs() < 1e-9 && cam.eye[1].abs() < 1e-9, "front view eye on +Z: {:?}", cam.eye);
        assert_eq!(cam.up, [0.0, 1.0, 0.0]);
        // A library caller that leaves the axis on Auto gets the same.
        let lib = RenderOptions { up: Some([0.0, 1.0, 0.0]), ..Default::default() };
        assert_eq!(lib.camera(Some(([0.0; 3], 1.0)), UpAxis::Z).eye, cam.eye);
        // Without a vector, Auto follows the detected axis (z-up: the eye is not on +Z).
        let auto = RenderOptions::default();
        assert!(auto.needs_auto_up());
        assert!(auto.camera(Some(([0.0; 3], 1.0)), UpAxis::Z).eye[2].abs() < 1e-9);
    }
}
