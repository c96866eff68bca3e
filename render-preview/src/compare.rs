//! `sct-render-preview compare`: every method over a sweep of its quality knob on a set of
//! scenes, timed and scored against the mesh reference, with the error split three ways,
//! temporal stability along an orbit and work counters. `spec/render-preview-compare-json.md`
//! documents the JSON; [`crate::compare_chart`] draws the chart.
//!
//! Error split, per point:
//! - representation: `zbuffer` at the same knob against the mesh (the `zbuffer` points'
//!   `metrics`);
//! - ordering: `gauss` and `parilov` against the same LOD cut drawn by `zbuffer` with one
//!   sample a pixel (the *ordering twin*, [`ordering_twin`]), `canopy` against its own discs
//!   drawn through a depth buffer (`vs_zbuffer`); `wand` (knob: its square side `d`,
//!   rounded) against the twin at the same knob value;
//! - culling: `canopy` against the same frame without occlusion culling (`culling`).
//!
//! The ordering twin is drawn as those methods draw, one sample a pixel, whatever
//! `supersample` says: `zbuffer` resolves 3 × 3 subpixels a pixel by default, and the split
//! compares one cut under two visibility rules, not under two samplings as well. It is one
//! extra untimed render per knob, made only when a method needs it (a one-sample `zbuffer`
//! point serves as its own twin). Its figures are not higher than against the 3 × 3 frame:
//! an antialiased frame lies nearer any other frame (on the Duck, fuze and 30 × 30 grid at
//! 320 × 240, knob 1, 7 of 9 method–scene figures dropped by 0.3–1.7 dB, parilov and wand
//! on the fuze rose 0.6 dB); what changes is that two frames of one sampling are compared.
//!
//! `wand` draws fresh random points every frame, so each of its points is also drawn with
//! several seeds and scored each time (`seeds`: least, median and greatest error).

use std::path::{Path, PathBuf};

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::method::{Method, Work};
use crate::metrics::{self, Metrics};
use crate::reference::render_reference;
use crate::scenes::{self, BuiltScene, SceneSpec};
use crate::{render_file, Frame, RenderOptions, Rendered, View};

/// Schema of the comparison JSON.
pub const SCHEMA: &str = "sct-render-preview-compare/1";

/// What to compare.
#[derive(Clone, Debug)]
pub struct CompareOptions {
    /// Scenes to build and render.
    pub scenes: Vec<SceneSpec>,
    /// Methods, in chart order.
    pub methods: Vec<Method>,
    /// Knob values (each method's own knob: `pixel_error`, canopy's `t3`, wand's `d`).
    pub knobs: Vec<f32>,
    /// Timed frames per point after one warm-up frame (the median counts).
    pub repeat: u32,
    /// Frames of the stability orbit (0: none).
    pub orbit_frames: usize,
    /// Degrees the eye turns about the target between orbit frames.
    pub orbit_step_deg: f64,
    /// Knob of the orbit renders.
    pub orbit_knob: f32,
    /// Seeds per `wand` point: the point's frame and `wand_seeds − 1` more, scored for the
    /// spread of its error (`seeds`; below 2: none).
    pub wand_seeds: u32,
    /// Leaves per model radius.
    pub density: f64,
    /// Where the scenes' SCT files are written.
    pub work_dir: PathBuf,
    /// Everything else (size, shading, method settings); `method`, `pixel_error` and `view`
    /// are set per point and scene.
    pub base: RenderOptions,
}

/// One method at one knob value.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Point {
    /// The knob's value.
    pub knob: f32,
    /// Median wall time per frame, seconds (open, refine, draw).
    pub seconds: f64,
    /// Fastest frame, seconds.
    pub seconds_min: f64,
    /// Median drawing time (rasterization or compositing), seconds.
    pub raster_seconds: f64,
    /// Against the mesh reference.
    pub metrics: Metrics,
    /// The ordering (and compositing) error: `gauss`, `parilov` and `wand` against `zbuffer`
    /// drawing the same cut with one sample a pixel ([`ordering_twin`]), `canopy` against its
    /// discs through a depth buffer; null for `zbuffer` and `wald`.
    pub vs_zbuffer: Option<Metrics>,
    /// The culling error: `canopy` against the same frame without occlusion culling; null for
    /// the other methods.
    pub culling: Option<Metrics>,
    /// Work counters of the median frame.
    pub work: Work,
    /// On the scene's Pareto front of time against foreground PSNR.
    pub pareto: bool,
    /// `wand`'s error over several seeds; null for the other methods.
    pub seeds: Option<SeedSpread>,
}

/// Least, median and greatest value of a metric over frames.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Spread {
    /// Least value.
    pub min: f64,
    /// Median (the upper one of an even count).
    pub median: f64,
    /// Greatest value.
    pub max: f64,
}

impl Spread {
    /// The spread of `v`, or `None` when it is empty.
    pub fn of(mut v: Vec<f64>) -> Option<Spread> {
        if v.is_empty() {
            return None;
        }
        let median = median(&mut v);
        Some(Spread { min: v[0], median, max: v[v.len() - 1] })
    }
}

/// `wand`'s error at one knob value over several seeds. Its image is random, so one frame's
/// score is one draw: the spread says how far a single frame can be trusted, and whether two
/// methods' scores differ by more than the noise of the random points.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SeedSpread {
    /// The seeds, the point's own (`--wand-seed`) first, then the ones after it.
    pub seeds: Vec<u64>,
    /// Foreground PSNR against the mesh, dB, over the seeds (null when no frame has one).
    pub fg_psnr_db: Option<Spread>,
    /// Foreground SSIM against the mesh over the seeds (null when no frame has one).
    pub fg_ssim: Option<Spread>,
    /// Silhouette IoU against the mesh over the seeds.
    pub silhouette_iou: Spread,
}

/// Mean absolute difference between consecutive frames of an orbit.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Temporal {
    /// Frames rendered.
    pub frames: usize,
    /// Degrees between frames.
    pub step_deg: f64,
    /// Knob used.
    pub knob: f32,
    /// Mean over pixels and RGB channels of |frame_t − frame_{t−1}| (8-bit), averaged over t.
    pub mean_abs_diff: f64,
    /// The same for the mesh reference.
    pub reference_mean_abs_diff: f64,
    /// `mean_abs_diff − reference_mean_abs_diff`: flicker and popping beyond the motion.
    pub excess: f64,
}

/// One method on one scene.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MethodResult {
    /// The method.
    pub method: Method,
    /// Name of its knob.
    pub knob: &'static str,
    /// One point per knob value.
    pub points: Vec<Point>,
    /// Orbit stability (null without `--orbit`).
    pub temporal: Option<Temporal>,
}

/// One scene.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SceneResult {
    /// Short name.
    pub name: String,
    /// How it was built.
    pub spec: SceneSpec,
    /// Its SCT file.
    pub sct: PathBuf,
    /// Leaves of its tree and instances of it.
    pub leaves: usize,
    /// Instances.
    pub instances: usize,
    /// Reference triangles.
    pub triangles: usize,
    /// SCT file size, bytes.
    pub file_size: u64,
    /// The camera.
    pub camera: Camera,
    /// Time to render the mesh reference, seconds.
    pub reference_seconds: f64,
    /// Per method.
    pub methods: Vec<MethodResult>,
}

/// The whole comparison.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CompareResult {
    /// [`SCHEMA`].
    pub schema: &'static str,
    /// Image size.
    pub width: u32,
    /// Image size.
    pub height: u32,
    /// Timed frames per point.
    pub repeat: u32,
    /// Worker threads.
    pub threads: usize,
    /// Per scene.
    pub scenes: Vec<SceneResult>,
}

/// `base` with method `m` at knob value `k` (`pixel_error`, canopy's `t3`, wald's
/// `radius_scale`, or wand's square side `d`: the knob rounded, at least 1).
fn with_knob(base: &RenderOptions, m: Method, k: f32) -> RenderOptions {
    match m {
        Method::Zbuffer | Method::Gauss | Method::Parilov => RenderOptions { method: m, pixel_error: k, ..base.clone() },
        Method::Canopy => {
            let c = base.canopy;
            RenderOptions { method: m, canopy: crate::CanopyOptions { t3: k, t2: c.t2.max(k), t1: c.t1.max(k), ..c }, ..base.clone() }
        }
        Method::Wald => RenderOptions { method: m, wald: crate::WaldOptions { radius_scale: k, ..base.wald }, ..base.clone() },
        Method::Wand => {
            let d = if k.is_finite() { k.round().clamp(1.0, crate::wand::MAX_D as f32) as u32 } else { 1 };
            RenderOptions { method: m, wand: crate::WandOptions { d, ..base.wand }, ..base.clone() }
        }
    }
}

/// The frame the ordering error of `gauss`, `parilov` and `wand` at knob `k` is measured
/// against: `zbuffer` at the same knob with one sample a pixel ([`RenderOptions::supersample`]
/// 1). Those methods draw one sample a pixel; against `zbuffer`'s supersampled frame the
/// split would also count its antialiasing of colour edges as their ordering error.
pub fn ordering_twin(base: &RenderOptions, k: f32) -> RenderOptions {
    RenderOptions { supersample: 1, ..with_knob(base, Method::Zbuffer, k) }
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        0.0
    } else {
        v[v.len() / 2]
    }
}

/// Renders `repeat` timed frames after a warm-up; returns the median frame and timings.
fn timed(sct: &Path, opts: &RenderOptions, repeat: u32) -> Result<(Rendered, f64, f64, f64)> {
    let mut best = render_file(sct, opts)?;
    let (mut totals, mut rasters) = (Vec::new(), Vec::new());
    for _ in 0..repeat.max(1) {
        let r = render_file(sct, opts)?;
        totals.push(r.stats.seconds.total);
        rasters.push(r.stats.seconds.raster);
        best = r;
    }
    let min = totals.iter().copied().fold(f64::INFINITY, f64::min);
    Ok((best, median(&mut totals), min, median(&mut rasters)))
}

/// Mean absolute per-channel difference of two frames (8-bit).
pub fn mean_abs_diff(a: &Frame, b: &Frame) -> f64 {
    let n = a.color.len().max(1) as f64 * 3.0;
    a.color.iter().zip(&b.color).map(|(x, y)| (0..3).map(|k| (x[k] as f64 - y[k] as f64).abs()).sum::<f64>()).sum::<f64>() / n
}

/// The camera turned about its up vector through the target by `deg`.
fn orbit(c: &Camera, deg: f64) -> Camera {
    let u = c.up;
    let ul = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt().max(1e-30);
    let k = u.map(|v| v / ul);
    let v: [f64; 3] = std::array::from_fn(|i| c.eye[i] - c.target[i]);
    let (s, co) = deg.to_radians().sin_cos();
    let kv = [k[1] * v[2] - k[2] * v[1], k[2] * v[0] - k[0] * v[2], k[0] * v[1] - k[1] * v[0]];
    let kd = k[0] * v[0] + k[1] * v[1] + k[2] * v[2];
    // Rodrigues.
    let r: [f64; 3] = std::array::from_fn(|i| v[i] * co + kv[i] * s + k[i] * kd * (1.0 - co));
    Camera { eye: std::array::from_fn(|i| c.target[i] + r[i]), ..*c }
}

fn temporal(scene: &BuiltScene, cam: &Camera, near: f64, opts: &RenderOptions, o: &CompareOptions) -> Result<(f64, f64)> {
    let (mut prev, mut prev_ref) = (None::<Frame>, None::<Frame>);
    let (mut sum, mut sum_ref) = (0.0, 0.0);
    for f in 0..o.orbit_frames {
        let c = orbit(cam, f as f64 * o.orbit_step_deg);
        let fo = RenderOptions { eye: Some(c.eye), target: Some(c.target), up: Some(c.up), ..opts.clone() };
        let frame = render_file(&scene.sct, &fo)?.frame;
        let refr = render_reference(&scene.mesh, &View::new(&c, near)?, opts.shading, opts.background);
        if let (Some(p), Some(pr)) = (&prev, &prev_ref) {
            sum += mean_abs_diff(p, &frame);
            sum_ref += mean_abs_diff(pr, &refr);
        }
        (prev, prev_ref) = (Some(frame), Some(refr));
    }
    let n = o.orbit_frames.saturating_sub(1).max(1) as f64;
    Ok((sum / n, sum_ref / n))
}

/// `wand` at `opts` with `n` seeds from `opts.wand.seed` on, each frame scored against
/// `refr`; `first` is the score of the point's own frame (the first seed), not drawn again.
/// The extra frames are not timed. `None` below two seeds.
fn seed_spread(sct: &Path, opts: &RenderOptions, n: u32, first: &Metrics, refr: &Frame) -> Result<Option<SeedSpread>> {
    if n < 2 {
        return Ok(None);
    }
    let base = opts.wand.seed;
    let seeds: Vec<u64> = (0..u64::from(n)).map(|k| base.wrapping_add(k)).collect();
    let mut all = vec![*first];
    for &seed in &seeds[1..] {
        let o = RenderOptions { wand: crate::WandOptions { seed, ..opts.wand }, ..opts.clone() };
        all.push(metrics::compare(&render_file(sct, &o)?.frame, refr));
    }
    Ok(Some(SeedSpread {
        seeds,
        fg_psnr_db: Spread::of(all.iter().filter_map(|m| m.fg_psnr_db).collect()),
        fg_ssim: Spread::of(all.iter().filter_map(|m| m.fg_ssim).collect()),
        silhouette_iou: Spread::of(all.iter().map(|m| m.silhouette_iou).collect()).unwrap_or(Spread { min: 0.0, median: 0.0, max: 0.0 }),
    }))
}

/// The table line of a point's seed spread, if it has one.
fn seed_line(scene: &str, m: &MethodResult, p: &Point) -> Option<String> {
    let s = p.seeds.as_ref()?;
    let f = |v: Option<Spread>, d: usize| v.map_or("-".to_string(), |v| format!("{:.d$} / {:.d$} / {:.d$}", v.min, v.median, v.max));
    let iou = s.silhouette_iou;
    Some(format!(
        "{:<28} {:<8} {}={} over {} seeds, min / median / max: PSNR {}  SSIM {}  IoU {:.4} / {:.4} / {:.4}\n",
        scene,
        m.method.name(),
        m.knob,
        p.knob,
        s.seeds.len(),
        f(s.fg_psnr_db, 2),
        f(s.fg_ssim, 4),
        iou.min,
        iou.median,
        iou.max
    ))
}

/// Marks the points no other point beats in both time and foreground PSNR.
fn mark_pareto(methods: &mut [MethodResult]) {
    let all: Vec<(f64, f64)> =
        methods.iter().flat_map(|m| m.points.iter().map(|p| (p.seconds, p.metrics.fg_psnr_db.unwrap_or(f64::NEG_INFINITY)))).collect();
    for m in methods.iter_mut() {
        for p in &mut m.points {
            let (t, q) = (p.seconds, p.metrics.fg_psnr_db.unwrap_or(f64::NEG_INFINITY));
            p.pareto = q.is_finite() && !all.iter().any(|&(t2, q2)| t2 <= t && q2 >= q && (t2 < t || q2 > q));
        }
    }
}

/// Runs the comparison; `progress` gets one line per point.
pub fn run(o: &CompareOptions, mut progress: impl FnMut(&str)) -> Result<CompareResult> {
    if o.methods.is_empty() || o.knobs.is_empty() {
        return Err(Error::Invalid("compare needs at least one method and one knob value".into()));
    }
    if let Some(k) = o.knobs.iter().find(|k| !(k.is_finite() && **k > 0.0)) {
        return Err(Error::Invalid(format!("knob value {k} must be a positive number")));
    }
    std::fs::create_dir_all(&o.work_dir).map_err(|e| Error::Output { path: o.work_dir.clone(), message: e.to_string() })?;
    let mut scenes = Vec::new();
    for spec in &o.scenes {
        let scene = scenes::build(spec, &o.work_dir, o.density)?;
        let base = RenderOptions { view: scene.view, ..o.base.clone() };
        // The camera of the first render frames every point (it does not depend on the method).
        let first = render_file(&scene.sct, &RenderOptions { method: Method::Zbuffer, pixel_error: o.knobs[0], ..base.clone() })?;
        let view = View::new(&first.camera, first.near)?;
        let t = std::time::Instant::now();
        let refr = render_reference(&scene.mesh, &view, base.shading, base.background);
        let reference_seconds = t.elapsed().as_secs_f64();
        // The ordering twins: `zbuffer` at each knob with one sample a pixel, drawn the first
        // time a method needs one (a one-sample `zbuffer` point of its own serves as well).
        // `zbuffer` first, so that such a point is there before it is needed.
        let mut twins: Vec<Option<Frame>> = vec![None; o.knobs.len()];
        let mut order: Vec<Method> = o.methods.iter().copied().filter(|&m| m == Method::Zbuffer).take(1).collect();
        order.extend(o.methods.iter().copied().filter(|&m| m != Method::Zbuffer));
        let mut results = Vec::new();
        for m in order {
            let mut points = Vec::new();
            for (ki, &k) in o.knobs.iter().enumerate() {
                let opts = with_knob(&base, m, k);
                let (r, secs, min, raster) = timed(&scene.sct, &opts, o.repeat)?;
                let mt = metrics::compare(&r.frame, &refr);
                let seeds = if m == Method::Wand { seed_spread(&scene.sct, &opts, o.wand_seeds, &mt, &refr)? } else { None };
                let (vs, culling) = match m {
                    // `wald` draws no LOD cut: it has no depth-buffered twin to order against.
                    Method::Zbuffer | Method::Wald => (None, None),
                    // Against zbuffer's depth-buffered LOD cut at the same knob, one sample a
                    // pixel as these methods draw: what the compositing, the orders or the
                    // random points add to or take from it, without zbuffer's antialiasing.
                    Method::Gauss | Method::Parilov | Method::Wand => {
                        if twins[ki].is_none() {
                            twins[ki] = Some(render_file(&scene.sct, &ordering_twin(&base, k))?.frame);
                        }
                        (twins[ki].as_ref().map(|z| metrics::compare(&r.frame, z)), None)
                    }
                    Method::Canopy => {
                        // Ordering: the same discs through a depth buffer; culling: the same
                        // frame without occlusion culling.
                        let c = opts.canopy;
                        let z = render_file(&scene.sct, &RenderOptions { canopy: crate::CanopyOptions { zbuffer: true, ..c }, ..opts.clone() })?;
                        let all = render_file(&scene.sct, &RenderOptions { canopy: crate::CanopyOptions { occ_cull: f32::INFINITY, ..c }, ..opts.clone() })?;
                        (Some(metrics::compare(&r.frame, &z.frame)), Some(metrics::compare(&r.frame, &all.frame)))
                    }
                };
                progress(&format!(
                    "{:<28} {:<8} {}={:<5} {:>9.1} ms  PSNR {:>6}  SSIM {:>6}  IoU {:.4}  vs zbuffer {:>6}  overdraw {:>5.1}",
                    scene.name,
                    m.name(),
                    m.knob(),
                    k,
                    secs * 1e3,
                    mt.fg_psnr_db.map_or("-".into(), |v| format!("{v:.2}")),
                    mt.fg_ssim.map_or("-".into(), |v| format!("{v:.4}")),
                    mt.silhouette_iou,
                    vs.and_then(|v| v.fg_psnr_db).map_or("-".into(), |v| format!("{v:.2}")),
                    r.stats.work.overdraw
                ));
                if m == Method::Zbuffer && crate::supersample_used(&opts) == 1 && twins[ki].is_none() {
                    twins[ki] = Some(r.frame.clone());
                }
                points.push(Point { knob: k, seconds: secs, seconds_min: min, raster_seconds: raster, metrics: mt, vs_zbuffer: vs, culling, work: r.stats.work, pareto: false, seeds });
            }
            let temporal = if o.orbit_frames >= 2 {
                let opts = with_knob(&base, m, o.orbit_knob);
                let (d, dr) = temporal(&scene, &first.camera, first.near, &opts, o)?;
                Some(Temporal { frames: o.orbit_frames, step_deg: o.orbit_step_deg, knob: o.orbit_knob, mean_abs_diff: d, reference_mean_abs_diff: dr, excess: d - dr })
            } else {
                None
            };
            if o.methods.contains(&m) {
                results.push(MethodResult { method: m, knob: m.knob(), points, temporal });
            }
        }
        results.sort_by_key(|r| o.methods.iter().position(|&m| m == r.method));
        mark_pareto(&mut results);
        scenes.push(SceneResult {
            name: scene.name.clone(),
            spec: spec.clone(),
            sct: scene.sct.clone(),
            leaves: scene.leaves,
            instances: scene.instances,
            triangles: scene.mesh.tris.len(),
            file_size: first.stats.file_size,
            camera: first.camera,
            reference_seconds,
            methods: results,
        });
    }
    Ok(CompareResult { schema: SCHEMA, width: o.base.width, height: o.base.height, repeat: o.repeat, threads: rayon::current_num_threads(), scenes })
}

/// The stdout table: one line per scene and method at each knob, plus stability.
pub fn table(r: &CompareResult) -> String {
    let mut s = String::new();
    s.push_str(&format!("{:<28} {:<8} {:>6} {:>9} {:>7} {:>7} {:>7} {:>8} {:>8} {:>7}\n", "scene", "method", "knob", "ms", "PSNR", "SSIM", "IoU", "vs zbuf", "overdraw", "pareto"));
    for sc in &r.scenes {
        for m in &sc.methods {
            for p in &m.points {
                let f = |v: Option<f64>, d: usize| v.map_or("-".to_string(), |v| format!("{v:.d$}"));
                s.push_str(&format!(
                    "{:<28} {:<8} {:>6} {:>9.1} {:>7} {:>7} {:>7.4} {:>8} {:>8.1} {:>7}\n",
                    sc.name,
                    m.method.name(),
                    p.knob,
                    p.seconds * 1e3,
                    f(p.metrics.fg_psnr_db, 2),
                    f(p.metrics.fg_ssim, 4),
                    p.metrics.silhouette_iou,
                    f(p.vs_zbuffer.and_then(|v| v.fg_psnr_db), 2),
                    p.work.overdraw,
                    if p.pareto { "*" } else { "" }
                ));
            }
            for p in &m.points {
                s.push_str(&seed_line(&sc.name, m, p).unwrap_or_default());
            }
            if let Some(t) = &m.temporal {
                s.push_str(&format!(
                    "{:<28} {:<8} orbit {} frames × {}°: mean |Δ| {:.3} (mesh {:.3}, excess {:+.3})\n",
                    sc.name,
                    m.method.name(),
                    t.frames,
                    t.step_deg,
                    t.mean_abs_diff,
                    t.reference_mean_abs_diff,
                    t.excess
                ));
            }
        }
    }
    s
}

/// Writes `base.json`, `base.png` and `base.svg`.
pub fn write_outputs(r: &CompareResult, base: &Path) -> Result<()> {
    let with = |ext: &str| {
        let mut p = base.as_os_str().to_owned();
        p.push(format!(".{ext}"));
        PathBuf::from(p)
    };
    let json = serde_json::to_vec_pretty(r).map_err(|e| Error::Invalid(e.to_string()))?;
    let jp = with("json");
    sct_format::atomic::write_atomic(&jp, |w| {
        use std::io::Write;
        w.write_all(&json).map_err(sct_format::Error::from)
    })
    .map_err(|e| Error::Output { path: jp.clone(), message: e.to_string() })?;
    crate::compare_chart::write(r, &with("png"), &with("svg"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orbit_keeps_distance_and_turns_about_up() {
        let c = Camera { eye: [0.0, 0.0, 5.0], target: [0.0; 3], up: [0.0, 1.0, 0.0], fov_y_deg: 40.0, width: 10, height: 10 };
        let o = orbit(&c, 90.0);
        assert!((o.eye[0] - 5.0).abs() < 1e-9 && o.eye[1].abs() < 1e-9 && o.eye[2].abs() < 1e-9, "{:?}", o.eye);
    }

    fn point(t: f64, q: f64) -> Point {
        Point {
            knob: 1.0,
            seconds: t,
            seconds_min: t,
            raster_seconds: 0.0,
            metrics: Metrics { fg_psnr_db: Some(q), ..Default::default() },
            vs_zbuffer: None,
            culling: None,
            work: Work::default(),
            pareto: false,
            seeds: None,
        }
    }

    #[test]
    fn spread_is_min_median_max() {
        assert_eq!(Spread::of(vec![3.0, 1.0, 2.0, 5.0, 4.0]), Some(Spread { min: 1.0, median: 3.0, max: 5.0 }));
        assert_eq!(Spread::of(vec![2.0, 1.0]), Some(Spread { min: 1.0, median: 2.0, max: 2.0 }));
        assert_eq!(Spread::of(Vec::new()), None);
    }

    #[test]
    fn pareto_front_keeps_the_undominated() {
        let mut m = vec![
            MethodResult { method: Method::Zbuffer, knob: "pixel_error", points: vec![point(1.0, 30.0), point(2.0, 29.0)], temporal: None },
            MethodResult { method: Method::Gauss, knob: "pixel_error", points: vec![point(1.5, 31.0), point(0.5, 20.0)], temporal: None },
        ];
        mark_pareto(&mut m);
        let flags: Vec<bool> = m.iter().flat_map(|m| m.points.iter().map(|p| p.pareto)).collect();
        assert_eq!(flags, vec![true, false, true, true]);
    }
}
