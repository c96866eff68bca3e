//! Failure regions of the preview methods (issue 20 §5): each failure scene of the method
//! tests (tests/*failures*.rs, tests/methods.rs) swept over its parameter for every method,
//! with one error measure per scene and a stated bound. A method *holds* at a parameter
//! value when its measure is within the bound and *breaks* where it is not; the result is
//! written as a Markdown table (per method and scene, the values where it holds and where it
//! breaks) and a chart (one panel per scene, measure against parameter, the bound dashed).
//!
//! The scenes are synthetic (no shared models), so the map can be rebuilt anywhere:
//!
//! | scene | parameter | measure | bound |
//! |---|---|---|---|
//! | grazing overlap: a white plate 1 leaf spacing S before a black one | angle from the normal | share of the white plate's interior darker by > 64 levels | ≤ 1 % |
//! | plate gap: the same plates at 60° | gap in S | same | ≤ 1 % |
//! | thin two-sided leaf card | angle from its normal | silhouette IoU against the mesh | ≥ 0.9 |
//! | grazing plane (self-occlusion) | eye elevation | silhouette IoU against the mesh | ≥ 0.9 |
//! | close-up: a sphere dollied in | leaf width in pixels | holes (background pixels inside the mesh's outline) | ≤ 0.5 % |

use std::path::Path;

use crate::reference::{render_reference, WorldMesh};
use crate::{metrics, render_file, synth, Frame, Method, RenderOptions, Shading, View};
use crate::error::{Error, Result};

/// One failure scene swept over its parameter.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Mode {
    /// Coconu & Hege §5.2: a white plate one leaf spacing before a black one, by angle.
    GrazingOverlap,
    /// §5.2 / thesis §3.3.7: the plates at 60°, by gap.
    PlateGap,
    /// A thin two-sided leaf card, by angle from its normal (edge-on at 90°).
    ThinLeaf,
    /// Thesis §3.7: one large plane, by eye elevation.
    GrazingPlane,
    /// Close-ups (F4, D4): leaves a few pixels wide, by leaf width.
    CloseUp,
}

impl Mode {
    /// Every mode, in table order.
    pub const ALL: [Mode; 5] = [Mode::GrazingOverlap, Mode::PlateGap, Mode::ThinLeaf, Mode::GrazingPlane, Mode::CloseUp];

    /// Short description for tables and charts.
    pub fn title(self) -> &'static str {
        match self {
            Mode::GrazingOverlap => "grazing overlap (plates 1 S apart)",
            Mode::PlateGap => "plate gap at 60°",
            Mode::ThinLeaf => "thin two-sided leaf",
            Mode::GrazingPlane => "grazing plane",
            Mode::CloseUp => "close-up",
        }
    }

    /// The parameter's name and unit.
    pub fn parameter(self) -> &'static str {
        match self {
            Mode::GrazingOverlap | Mode::ThinLeaf => "angle from the normal, °",
            Mode::PlateGap => "gap, leaf spacings",
            Mode::GrazingPlane => "eye elevation, °",
            Mode::CloseUp => "leaf width, px",
        }
    }

    /// The default sweep.
    pub fn values(self) -> &'static [f64] {
        match self {
            Mode::GrazingOverlap => &[0.0, 45.0, 70.0, 80.0, 85.0],
            Mode::PlateGap => &[0.25, 0.5, 1.0, 2.0, 4.0],
            Mode::ThinLeaf => &[0.0, 60.0, 80.0, 85.0, 88.0],
            Mode::GrazingPlane => &[2.0, 5.0, 10.0, 20.0],
            Mode::CloseUp => &[1.0, 2.0, 4.0, 8.0, 16.0],
        }
    }

    /// The measure's name.
    pub fn measure(self) -> &'static str {
        match self {
            Mode::GrazingOverlap | Mode::PlateGap => "front plate darkened, %",
            Mode::ThinLeaf | Mode::GrazingPlane => "silhouette IoU",
            Mode::CloseUp => "holes, %",
        }
    }

    /// The bound and whether the measure must stay at most (true) or at least (false) it.
    pub fn bound(self) -> (f64, bool) {
        match self {
            Mode::GrazingOverlap | Mode::PlateGap => (1.0, true),
            Mode::ThinLeaf | Mode::GrazingPlane => (0.9, false),
            Mode::CloseUp => (0.5, true),
        }
    }

    /// Whether `value` is within the bound.
    pub fn holds(self, value: f64) -> bool {
        let (b, at_most) = self.bound();
        if at_most {
            value <= b
        } else {
            value >= b
        }
    }
}

/// One measured point.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Sample {
    /// The parameter value.
    pub param: f64,
    /// The measure.
    pub value: f64,
    /// Within the bound.
    pub holds: bool,
}

/// One method's sweep of one mode.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Sweep {
    /// The scene.
    pub mode: Mode,
    /// The method.
    pub method: Method,
    /// The points, in parameter order.
    pub samples: Vec<Sample>,
}

/// A scene built for one parameter value: the SCT file, its mesh and the camera.
struct Built {
    mesh: WorldMesh,
    sct: std::path::PathBuf,
    opts: RenderOptions,
}

fn luma(c: [u8; 4]) -> f64 {
    0.299 * c[0] as f64 + 0.587 * c[1] as f64 + 0.114 * c[2] as f64
}

/// Share of the pixels where `refr` shows white with white 2 px around (the front plate's
/// interior) that `f` shows darker by more than 64 levels, in percent.
fn darkened(f: &Frame, refr: &Frame) -> Result<f64> {
    let (w, h) = (f.width, f.height);
    let white = |x: usize, y: usize| luma(refr.color[y * w + x]) >= 250.0;
    let (mut dark, mut n) = (0usize, 0usize);
    for y in 2..h.saturating_sub(2) {
        for x in 2..w.saturating_sub(2) {
            if white(x, y) && white(x - 2, y) && white(x + 2, y) && white(x, y - 2) && white(x, y + 2) {
                dark += (255.0 - luma(f.color[y * w + x]) > 64.0) as usize;
                n += 1;
            }
        }
    }
    if n < 100 {
        return Err(Error::Invalid(format!("failure map: only {n} interior pixels of the front plate in view")));
    }
    Ok(100.0 * dark as f64 / n as f64)
}

/// Builds the scene of `mode` at `param` in `dir`, `size` pixels square.
fn build(mode: Mode, param: f64, size: u32, dir: &Path) -> Result<Built> {
    let base = RenderOptions { width: size, height: size, ..RenderOptions::default() };
    let sct = dir.join(format!("{mode:?}-{param}.sct"));
    let opts_eye = |eye: [f64; 3], o: RenderOptions| RenderOptions { eye: Some(eye), target: Some([0.0; 3]), ..o };
    match mode {
        Mode::GrazingOverlap | Mode::PlateGap => {
            // tests/gauss_failures.rs: leaves of side S = 0.02, white plate over black.
            let s = 0.02f32;
            let (gap, deg) = if mode == Mode::PlateGap { (param as f32, 60.0f64) } else { (1.0, param) };
            let q = |z: f32, h: f32| [[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]];
            let mesh = synth::quads(&[(q(0.0, 1.0), [1.0; 4]), (q(-gap * s, 1.5), [0.0, 0.0, 0.0, 1.0])]);
            synth::write_mesh_sct(&mesh, s, &sct, &Default::default())?;
            let (sn, cs) = deg.to_radians().sin_cos();
            let o = RenderOptions { shading: Shading::Flat, background: [0, 0, 0], ..base };
            Ok(Built { mesh, sct, opts: opts_eye([0.0, 3.0 * sn, 3.0 * cs], o) })
        }
        Mode::ThinLeaf => {
            // tests/method_failures.rs: a 1 × 0.4 card, two-sided.
            let mesh = synth::quads(&[([[-0.5, -0.2, 0.0], [0.5, -0.2, 0.0], [0.5, 0.2, 0.0], [-0.5, 0.2, 0.0]], [0.2, 0.6, 0.2, 1.0])]);
            let mut tree = synth::build_tree(synth::sample_mesh(&mesh, 0.005))?;
            tree.set_two_sided(true);
            sct_format::write::write_scene_file(&sct, &sct_format::write::Scene::single_tree(Default::default(), tree), &Default::default()).map_err(|e| Error::sct(&sct, e))?;
            let (s, c) = param.to_radians().sin_cos();
            Ok(Built { mesh, sct, opts: opts_eye([0.0, 1.5 * s, 1.5 * c], base) })
        }
        Mode::GrazingPlane => {
            // tests/canopy_failures.rs: one 4 × 4 plate.
            let mesh = synth::quads(&[([[-2.0, 0.0, 2.0], [2.0, 0.0, 2.0], [2.0, 0.0, -2.0], [-2.0, 0.0, -2.0]], [0.6, 0.7, 0.8, 1.0])]);
            synth::write_mesh_sct(&mesh, 0.01, &sct, &Default::default())?;
            let (s, c) = param.to_radians().sin_cos();
            Ok(Built { mesh, sct, opts: opts_eye([0.0, 3.0 * s, 3.0 * c], base) })
        }
        Mode::CloseUp => {
            // tests/method_failures.rs dollies the bunny in; a sphere needs no shared model.
            let mesh = synth::uv_sphere([0.0; 3], 1.0, 48, [0.8, 0.6, 0.4, 1.0]);
            let spacing = 1.0 / 200.0;
            synth::write_mesh_sct(&mesh, spacing as f32, &sct, &Default::default())?;
            let focal = size as f64 / 2.0 / (base.fov_y_deg / 2.0).to_radians().tan();
            let d = focal * spacing / param;
            Ok(Built { mesh, sct, opts: RenderOptions { eye: Some([0.0, 0.0, 1.0 + d]), target: Some([0.0; 3]), pixel_error: 0.5, ..base } })
        }
    }
}

/// Measures `method` on a built scene.
fn measure(mode: Mode, b: &Built, method: Method) -> Result<f64> {
    let o = RenderOptions { method, ..b.opts.clone() };
    let out = render_file(&b.sct, &o)?;
    let view = View::new(&out.camera, out.near)?;
    let refr = render_reference(&b.mesh, &view, o.shading, o.background);
    Ok(match mode {
        Mode::GrazingOverlap | Mode::PlateGap => darkened(&out.frame, &refr)?,
        Mode::ThinLeaf | Mode::GrazingPlane => metrics::compare(&out.frame, &refr).silhouette_iou,
        Mode::CloseUp => 100.0 * metrics::compare(&out.frame, &refr).hole_fraction,
    })
}

/// Sweeps every mode of `modes` over its values (or `values` when given) for every method of
/// `methods`, at `size` pixels square, building the scenes in `dir`.
pub fn run(modes: &[Mode], methods: &[Method], values: Option<&[f64]>, size: u32, dir: &Path) -> Result<Vec<Sweep>> {
    let mut out = Vec::new();
    for &mode in modes {
        let vals = values.unwrap_or(mode.values());
        let mut sweeps: Vec<Sweep> = methods.iter().map(|&method| Sweep { mode, method, samples: Vec::new() }).collect();
        for &param in vals {
            let b = build(mode, param, size, dir)?;
            for s in &mut sweeps {
                let value = measure(mode, &b, s.method)?;
                s.samples.push(Sample { param, value, holds: mode.holds(value) });
            }
        }
        out.extend(sweeps);
    }
    Ok(out)
}

fn fmt_param(v: f64) -> String {
    format!("{v}")
}

/// The values where a sweep holds and where it breaks, as "a, b, c" (or "–").
pub fn regions(s: &Sweep) -> (String, String) {
    let list = |holds: bool| {
        let v: Vec<String> = s.samples.iter().filter(|p| p.holds == holds).map(|p| fmt_param(p.param)).collect();
        if v.is_empty() {
            "–".to_string()
        } else {
            v.join(", ")
        }
    };
    (list(true), list(false))
}

/// The Markdown table: one row per mode and method, with the measure at each value.
pub fn markdown(sweeps: &[Sweep]) -> String {
    let mut s = String::from("| failure scene (parameter; measure, bound) | method | holds at | breaks at | measured |\n|---|---|---|---|---|\n");
    for sw in sweeps {
        let (b, at_most) = sw.mode.bound();
        let (holds, breaks) = regions(sw);
        let measured: Vec<String> = sw.samples.iter().map(|p| format!("{}: {}", fmt_param(p.param), if sw.mode.measure().contains('%') { format!("{:.2}", p.value) } else { format!("{:.3}", p.value) })).collect();
        s += &format!(
            "| {} ({}; {} {} {}) | {} | {} | {} | {} |\n",
            sw.mode.title(),
            sw.mode.parameter(),
            sw.mode.measure(),
            if at_most { "≤" } else { "≥" },
            b,
            sw.method,
            holds,
            breaks,
            measured.join("; ")
        );
    }
    s
}
