//! The default view of a scene: named viewing directions, the world up axis, and the
//! framing that places a pinhole camera so that a model's projected extent fills a set
//! fraction of the image.
//!
//! This is the one definition of "the intended view" shared by the tools: the preview
//! renderer frames its default camera with [`frame_points`], and the voxelizer chooses its
//! default sample density from [`default_pixel_size`] so that leaves are about one pixel
//! wide in that view. Pure math, no I/O.
//!
//! ```
//! use sct_format::view::{self, UpAxis, ViewPreset};
//!
//! let corners = view::box_corners([-1.0; 3], [1.0; 3]);
//! let f = view::frame_points(&corners, ViewPreset::Front, UpAxis::Y, view::DEFAULT_FOV_Y_DEG, 1280, 720, view::DEFAULT_FILL);
//! assert!(f.eye[2] > 1.0 && f.eye[0].abs() < 1e-9); // looking down -Z at the box
//! let px = view::default_pixel_size([-1.0; 3], [1.0; 3], UpAxis::Y);
//! assert!(px > 0.0 && px < 2.0 / 400.0, "{px}");
//! ```

use std::fmt;
use std::str::FromStr;

/// Default image width in pixels.
pub const DEFAULT_WIDTH: u32 = 1280;
/// Default image height in pixels.
pub const DEFAULT_HEIGHT: u32 = 720;
/// Default vertical field of view, degrees.
pub const DEFAULT_FOV_Y_DEG: f64 = 40.0;
/// Default fraction of the frame (in its tighter dimension) that the model's projected
/// extent fills.
pub const DEFAULT_FILL: f64 = 0.9;

/// A named viewing direction, named for a +Y-up world (see [`UpAxis::rotate`] for others).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ViewPreset {
    /// Eye on +Z looking down −Z (the model's front, by the glTF convention).
    #[default]
    Front,
    /// Eye on −Z looking down +Z.
    Back,
    /// Eye on −X.
    Left,
    /// Eye on +X.
    Right,
    /// Eye on +Y looking down, −Z up on screen.
    Top,
    /// Eye along (1, 1, 1).
    Iso,
}

impl ViewPreset {
    /// Every preset, in the order of their names in [`ViewPreset::NAMES`].
    pub const ALL: [ViewPreset; 6] =
        [ViewPreset::Front, ViewPreset::Back, ViewPreset::Left, ViewPreset::Right, ViewPreset::Top, ViewPreset::Iso];
    /// The lowercase names accepted by [`FromStr`].
    pub const NAMES: [&'static str; 6] = ["front", "back", "left", "right", "top", "iso"];

    /// The lowercase name.
    pub fn name(self) -> &'static str {
        Self::NAMES[self as usize]
    }

    /// (unit direction from the target to the eye, up on screen) in a +Y-up world.
    pub fn directions(self) -> ([f64; 3], [f64; 3]) {
        let s = 1.0 / 3f64.sqrt();
        match self {
            ViewPreset::Front => ([0.0, 0.0, 1.0], [0.0, 1.0, 0.0]),
            ViewPreset::Back => ([0.0, 0.0, -1.0], [0.0, 1.0, 0.0]),
            ViewPreset::Left => ([-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
            ViewPreset::Right => ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
            ViewPreset::Top => ([0.0, 1.0, 0.0], [0.0, 0.0, -1.0]),
            ViewPreset::Iso => ([s, s, s], [0.0, 1.0, 0.0]),
        }
    }
}

impl fmt::Display for ViewPreset {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for ViewPreset {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let t = s.trim().to_ascii_lowercase();
        Self::NAMES
            .iter()
            .position(|n| *n == t)
            .map(|i| Self::ALL[i])
            .ok_or_else(|| format!("unknown view {s:?} (expected one of {})", Self::NAMES.join(", ")))
    }
}

/// Which world axis points up. The presets are named for +Y up and turned to the axis by
/// [`UpAxis::rotate`]. +Y is the default: glTF fixes it, and OBJ and PLY files are +Y up
/// unless they say otherwise.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum UpAxis {
    /// +X up.
    X,
    /// +Y up (glTF, most OBJ/PLY files and scans).
    #[default]
    Y,
    /// +Z up (CAD, many scans): `front` looks along +Y from −Y.
    Z,
}

impl UpAxis {
    /// The unit vector of the axis.
    pub fn vector(self) -> [f64; 3] {
        match self {
            UpAxis::X => [1.0, 0.0, 0.0],
            UpAxis::Y => [0.0, 1.0, 0.0],
            UpAxis::Z => [0.0, 0.0, 1.0],
        }
    }

    /// Maps a direction of the +Y-up preset frame to this axis' frame by a rotation that
    /// takes +Y to the up axis (Z up: front looks along +Y and right stays +X, so a Z-up
    /// model is seen from its front, upright).
    pub fn rotate(self, v: [f64; 3]) -> [f64; 3] {
        match self {
            UpAxis::Y => v,
            UpAxis::Z => [v[0], -v[2], v[1]],
            UpAxis::X => [v[1], -v[0], v[2]],
        }
    }
}

impl fmt::Display for UpAxis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            UpAxis::X => "x",
            UpAxis::Y => "y",
            UpAxis::Z => "z",
        })
    }
}

impl FromStr for UpAxis {
    type Err = String;
    /// `x`, `y` or `z`, optionally signless `+x` etc. (case-insensitive).
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().trim_start_matches('+').to_ascii_lowercase().as_str() {
            "x" => Ok(UpAxis::X),
            "y" => Ok(UpAxis::Y),
            "z" => Ok(UpAxis::Z),
            _ => Err(format!("unknown up axis {s:?} (expected x, y or z)")),
        }
    }
}

/// The eye stays at least this fraction of the points' depth range in front of the
/// nearest point (see [`frame_points`]).
pub const NEAR_CLEARANCE: f64 = 0.1;

/// A camera placement produced by [`frame_points`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Framing {
    /// Centre of projection.
    pub eye: [f64; 3],
    /// Point looked at: on the view axis, at the depth of the middle of the points' depth
    /// range.
    pub target: [f64; 3],
    /// Unit up vector, perpendicular to the viewing direction.
    pub up: [f64; 3],
    /// Distance from the eye to the target.
    pub distance: f64,
    /// World size of one pixel at the target's depth: 2·distance·tan(fov_y/2)/height.
    pub pixel_size: f64,
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
fn unit(a: [f64; 3]) -> [f64; 3] {
    let l = dot(a, a).sqrt();
    [a[0] / l, a[1] / l, a[2] / l]
}

/// The camera looking from `preset` (turned to `up`) at `points` so that their projected
/// extent is centred in a `width`×`height` image and fills `fill` of it in the tighter
/// dimension (perspective, exact for the given points: a point touches each side of the
/// tighter dimension's `fill` frame). The one exception is a model more than about ten
/// times deeper than it is wide seen end-on: the eye is kept [`NEAR_CLEARANCE`] of its
/// depth in front of it, and it fills less.
///
/// Degenerate inputs never panic: non-finite points are ignored; no points frames a unit
/// sphere at the origin; points that all coincide are framed as a small box around them;
/// a non-finite or non-positive `fill` is [`DEFAULT_FILL`], a field of view outside
/// (0.01°, 179°) is [`DEFAULT_FOV_Y_DEG`], and zero sizes count as one pixel.
pub fn frame_points(points: &[[f64; 3]], preset: ViewPreset, up: UpAxis, fov_y_deg: f64, width: u32, height: u32, fill: f64) -> Framing {
    let fill = if fill.is_finite() && fill > 0.0 { fill } else { DEFAULT_FILL };
    let fov = if fov_y_deg.is_finite() && fov_y_deg > 0.01 && fov_y_deg < 179.0 { fov_y_deg } else { DEFAULT_FOV_Y_DEG };
    let (w, h) = (width.max(1) as f64, height.max(1) as f64);
    let tan_y = (fov.to_radians() / 2.0).tan();
    let tan_x = tan_y * w / h;

    let (dir, vup) = preset.directions();
    let (back, vup) = (up.rotate(dir), up.rotate(vup));
    // Camera frame: right, up, forward (forward = from the eye towards the target).
    let fwd = [-back[0], -back[1], -back[2]];
    let right = unit(cross(fwd, vup));
    let cup = cross(right, fwd);

    let finite: Vec<[f64; 3]> = points.iter().copied().filter(|p| p.iter().all(|v| v.is_finite())).collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for p in &finite {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    // Work relative to the box centre so that far-from-origin models keep precision.
    let (origin, pts) = if finite.is_empty() {
        ([0.0; 3], box_corners([-1.0; 3], [1.0; 3]))
    } else {
        // Halves before the sum: the sum of two huge coordinates can overflow.
        let c: [f64; 3] = std::array::from_fn(|k| 0.5 * lo[k] + 0.5 * hi[k]);
        let diag = dot(std::array::from_fn(|k| hi[k] - lo[k]), std::array::from_fn(|k| hi[k] - lo[k])).sqrt();
        let scale = dot(c, c).sqrt();
        if diag.is_finite() && diag > 1e-12 * scale && diag > 0.0 {
            (c, finite.iter().map(|p| std::array::from_fn(|k| p[k] - c[k])).collect())
        } else {
            // All points coincide (or the box overflows): frame a box around the centre
            // sized to the position, so that the eye stays distinguishable from the target.
            let r = if scale.is_finite() { (1e-3 * scale).max(1e-3) } else { 1.0 };
            let c = if c.iter().all(|v| v.is_finite()) { c } else { [0.0; 3] };
            (c, box_corners([-r; 3], [r; 3]))
        }
    };
    // Camera-frame coordinates: a (across), b (up), z (depth).
    let a: Vec<f64> = pts.iter().map(|p| dot(*p, right)).collect();
    let b: Vec<f64> = pts.iter().map(|p| dot(*p, cup)).collect();
    let z: Vec<f64> = pts.iter().map(|p| dot(*p, fwd)).collect();

    let (tx, ty) = (fill * tan_x, fill * tan_y);
    let (ax, zx) = tight_apex(&a, &z, tx);
    let (by, zy) = tight_apex(&b, &z, ty);
    // The tighter dimension needs the eye further back; the other is then centred at
    // that depth.
    let (zmin, zmax) = z.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| (l.min(v), h.max(v)));
    // A model much deeper than it is wide (a rod seen end-on) would be framed with the eye
    // at its nearest point, which the far points' wedge allows; keep a clearance so that
    // the near plane does not cut it and the perspective stays readable.
    let clear = zmin - NEAR_CLEARANCE * (zmax - zmin);
    let (ex, ey, ez) = if zx.min(zy) > clear {
        (centred(&a, &z, clear), centred(&b, &z, clear), clear)
    } else if zx <= zy {
        (ax, centred(&b, &z, zx), zx)
    } else {
        (centred(&a, &z, zy), by, zy)
    };

    let extent = a.iter().chain(&b).chain(&z).fold(0f64, |m, v| m.max(v.abs()));
    let distance = (0.5 * (zmin + zmax) - ez).max(1e-9 * extent.max(1e-300));
    let eye: [f64; 3] = std::array::from_fn(|k| origin[k] + ex * right[k] + ey * cup[k] + ez * fwd[k]);
    let target: [f64; 3] = std::array::from_fn(|k| eye[k] + distance * fwd[k]);
    Framing { eye, target, up: cup, distance, pixel_size: 2.0 * distance * tan_y / h }
}

/// The smallest [`Framing::pixel_size`] of the default `front` and `iso` views framing the
/// box's 8 corners at [`DEFAULT_WIDTH`]×[`DEFAULT_HEIGHT`], [`DEFAULT_FOV_Y_DEG`] and
/// [`DEFAULT_FILL`].
///
/// This is "the intended view" that the voxelizer's default sample density targets: with
/// leaves about this wide they are about one pixel wide there, so a default preview is
/// neither blocky nor wastefully dense.
pub fn default_pixel_size(bbox_min: [f64; 3], bbox_max: [f64; 3], up: UpAxis) -> f64 {
    let corners = box_corners(bbox_min, bbox_max);
    [ViewPreset::Front, ViewPreset::Iso]
        .into_iter()
        .map(|p| frame_points(&corners, p, up, DEFAULT_FOV_Y_DEG, DEFAULT_WIDTH, DEFAULT_HEIGHT, DEFAULT_FILL).pixel_size)
        .fold(f64::INFINITY, f64::min)
}

/// The 8 corners of an axis-aligned box.
pub fn box_corners(lo: [f64; 3], hi: [f64; 3]) -> Vec<[f64; 3]> {
    (0..8).map(|i| std::array::from_fn(|k| if i >> k & 1 == 0 { lo[k] } else { hi[k] })).collect()
}

/// The apex (lateral, depth) of the narrowest-backed symmetric wedge of half-slope `t`
/// containing the points `(a, z)`: its two sides are the support lines `a − t·z = max` and
/// `a + t·z = min`, so a point touches each side and the eye at the apex sees them at
/// exactly ±t.
fn tight_apex(a: &[f64], z: &[f64], t: f64) -> (f64, f64) {
    let c_right = a.iter().zip(z).map(|(a, z)| a - t * z).fold(f64::NEG_INFINITY, f64::max);
    let c_left = a.iter().zip(z).map(|(a, z)| a + t * z).fold(f64::INFINITY, f64::min);
    (0.5 * (c_right + c_left), (c_left - c_right) / (2.0 * t))
}

/// The lateral offset that centres the points' projections for an eye at depth `ez` (all
/// points in front of it, at distances `w = z − ez`): the apex of the narrowest wedge
/// `|a − x| ≤ t·w` containing them. With `U(t) = max (a − t·w)` and `V(t) = min (a + t·w)`,
/// the least `t` with `U(t) ≤ V(t)` is the root of the convex, decreasing, piecewise-linear
/// `U − V`, which Newton's method reaches from `t = 0` without overshooting, exactly after a
/// few passes (each step adopts a new pair of active points); then `x = U(t) = V(t)`.
fn centred(a: &[f64], z: &[f64], ez: f64) -> f64 {
    let (lo, hi) = a.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| (l.min(v), h.max(v)));
    // No spread (or no points): nothing to centre.
    if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
        return if lo.is_finite() { lo } else { 0.0 };
    }
    let w: Vec<f64> = z.iter().map(|z| (z - ez).max(1e-300)).collect();
    let eval = |t: f64| {
        let (mut u, mut v, mut wu, mut wv) = (f64::NEG_INFINITY, f64::INFINITY, 0.0, 0.0);
        for (a, w) in a.iter().zip(&w) {
            let (p, q) = (a - t * w, a + t * w);
            if p > u {
                (u, wu) = (p, *w);
            }
            if q < v {
                (v, wv) = (q, *w);
            }
        }
        (u, v, wu + wv)
    };
    let mut t = 0.0;
    let (mut u, mut v, mut slope) = eval(t);
    for _ in 0..100 {
        if u <= v || slope <= 0.0 {
            break;
        }
        let next = t + (u - v) / slope;
        if next <= t {
            break;
        }
        t = next;
        (u, v, slope) = eval(t);
    }
    0.5 * (u + v)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pixel bounds (min x, max x, min y, max y) of the points' projections.
    fn projected(points: &[[f64; 3]], f: &Framing, fov: f64, w: u32, h: u32) -> [f64; 4] {
        let fwd = unit([f.target[0] - f.eye[0], f.target[1] - f.eye[1], f.target[2] - f.eye[2]]);
        let right = unit(cross(fwd, f.up));
        let up = cross(right, fwd);
        let focal = (h as f64 / 2.0) / (fov.to_radians() / 2.0).tan();
        let mut r = [f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY];
        for p in points {
            let d = [p[0] - f.eye[0], p[1] - f.eye[1], p[2] - f.eye[2]];
            let (x, y, z) = (dot(d, right), dot(d, up), dot(d, fwd));
            assert!(z > 0.0, "point {p:?} behind the eye {f:?}");
            let (px, py) = (w as f64 / 2.0 + focal * x / z, h as f64 / 2.0 - focal * y / z);
            r = [r[0].min(px), r[1].max(px), r[2].min(py), r[3].max(py)];
        }
        r
    }

    /// Asserts that the projection is centred and fills `fill` of the tighter dimension
    /// within a pixel, and at most that of the other.
    fn check_fill(points: &[[f64; 3]], preset: ViewPreset, up: UpAxis, w: u32, h: u32) {
        let f = frame_points(points, preset, up, DEFAULT_FOV_Y_DEG, w, h, DEFAULT_FILL);
        let [x0, x1, y0, y1] = projected(points, &f, DEFAULT_FOV_Y_DEG, w, h);
        let (fx, fy) = ((x1 - x0) / w as f64, (y1 - y0) / h as f64);
        let err_px = ((fx - DEFAULT_FILL) * w as f64).abs().min(((fy - DEFAULT_FILL) * h as f64).abs());
        assert!(err_px < 1.0, "{preset:?}: fills {fx:.4} x {fy:.4}");
        assert!(fx <= DEFAULT_FILL + 1.0 / w as f64 && fy <= DEFAULT_FILL + 1.0 / h as f64, "{preset:?}: overfills {fx} x {fy}");
        // Centred in both dimensions.
        assert!(((x0 + x1) / 2.0 - w as f64 / 2.0).abs() < 0.5, "{preset:?}: x centre {}", (x0 + x1) / 2.0);
        assert!(((y0 + y1) / 2.0 - h as f64 / 2.0).abs() < 0.5, "{preset:?}: y centre {}", (y0 + y1) / 2.0);
        // The pixel size is as documented.
        let expect = 2.0 * f.distance * (DEFAULT_FOV_Y_DEG.to_radians() / 2.0).tan() / h as f64;
        assert!((f.pixel_size - expect).abs() <= 1e-12 * expect);
    }

    #[test]
    fn a_box_fills_the_frame_from_every_preset() {
        let corners = box_corners([1.0, 2.0, -3.0], [3.0, 2.5, -2.0]);
        for preset in ViewPreset::ALL {
            for up in [UpAxis::X, UpAxis::Y, UpAxis::Z] {
                check_fill(&corners, preset, up, DEFAULT_WIDTH, DEFAULT_HEIGHT);
                check_fill(&corners, preset, up, 300, 800);
            }
        }
    }

    #[test]
    fn a_long_thin_object_fills_the_frame() {
        // A rod along X, 100 units long and 0.1 thick, off the origin; and a deep rod
        // along the view axis, whose near end dominates the perspective.
        let rod: Vec<[f64; 3]> = (0..=100).map(|i| [1000.0 + i as f64, 5.0 + 0.1 * (i % 2) as f64, 7.0]).collect();
        let deep: Vec<[f64; 3]> = (0..=100).map(|i| [0.3 * (i % 2) as f64, 0.2, -(i as f64)]).collect();
        use ViewPreset::*;
        for (pts, across, end_on) in [(&rod, [Front, Back, Top, Iso], [Left, Right]), (&deep, [Left, Right, Top, Iso], [Front, Back])] {
            for preset in across {
                check_fill(pts, preset, UpAxis::Y, DEFAULT_WIDTH, DEFAULT_HEIGHT);
            }
            // End-on, the eye keeps its clearance from the near tip, centred, and the rod
            // fits.
            for preset in end_on {
                let f = frame_points(pts, preset, UpAxis::Y, DEFAULT_FOV_Y_DEG, DEFAULT_WIDTH, DEFAULT_HEIGHT, DEFAULT_FILL);
                let fwd = unit([f.target[0] - f.eye[0], f.target[1] - f.eye[1], f.target[2] - f.eye[2]]);
                let nearest = pts.iter().map(|p| dot([p[0] - f.eye[0], p[1] - f.eye[1], p[2] - f.eye[2]], fwd)).fold(f64::INFINITY, f64::min);
                assert!((nearest - NEAR_CLEARANCE * 100.0).abs() < 1e-9, "{preset:?}: {nearest} {f:?}");
                let [x0, x1, y0, y1] = projected(pts, &f, DEFAULT_FOV_Y_DEG, DEFAULT_WIDTH, DEFAULT_HEIGHT);
                assert!(x1 - x0 <= DEFAULT_FILL * DEFAULT_WIDTH as f64 && y1 - y0 <= DEFAULT_FILL * DEFAULT_HEIGHT as f64);
                assert!(((x0 + x1) / 2.0 - 640.0).abs() < 0.5 && ((y0 + y1) / 2.0 - 360.0).abs() < 0.5, "{preset:?}");
            }
        }
    }

    #[test]
    fn a_random_cloud_fills_the_frame() {
        // A deterministic cloud in a skewed blob (LCG), so that many points compete for
        // each extreme.
        let mut state = 12345u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let cloud: Vec<[f64; 3]> = (0..20_000).map(|_| [3.0 * next() + 7.0, next() * next() * 4.0, 2.0 * next()]).collect();
        for preset in ViewPreset::ALL {
            check_fill(&cloud, preset, UpAxis::Y, DEFAULT_WIDTH, DEFAULT_HEIGHT);
        }
    }

    #[test]
    fn front_view_looks_down_minus_z_and_z_up_front_looks_along_plus_y() {
        let corners = box_corners([-1.0; 3], [1.0; 3]);
        let f = frame_points(&corners, ViewPreset::Front, UpAxis::Y, 40.0, 1280, 720, 0.9);
        assert!(f.eye[2] > 1.0 && f.eye[0].abs() < 1e-9 && f.eye[1].abs() < 1e-9, "{:?}", f.eye);
        assert_eq!(f.up, [0.0, 1.0, 0.0]);
        let f = frame_points(&corners, ViewPreset::Front, UpAxis::Z, 40.0, 1280, 720, 0.9);
        assert!(f.eye[1] < -1.0 && f.eye[0].abs() < 1e-9 && f.eye[2].abs() < 1e-9, "{:?}", f.eye);
        assert_eq!(f.up, [0.0, 0.0, 1.0]);
    }

    #[test]
    fn degenerate_inputs_give_a_usable_camera() {
        let usable = |f: &Framing| {
            let all = f.eye.iter().chain(&f.target).chain(&f.up).chain([&f.distance, &f.pixel_size]);
            assert!(all.clone().all(|v| v.is_finite()), "{f:?}");
            assert!(f.distance > 0.0 && f.pixel_size > 0.0, "{f:?}");
            let d = [f.target[0] - f.eye[0], f.target[1] - f.eye[1], f.target[2] - f.eye[2]];
            let scale = dot(f.eye, f.eye).sqrt().max(dot(f.target, f.target).sqrt());
            assert!(dot(d, d).sqrt() > 1e-9 * scale, "eye and target coincide: {f:?}");
        };
        let nan = [f64::NAN, 0.0, 0.0];
        let inf = [f64::INFINITY, 1.0, 1.0];
        let big = [f64::MAX, -f64::MAX, 0.0];
        for pts in [vec![], vec![[0.0; 3]], vec![[5.0, 5.0, 5.0]; 4], vec![nan, inf], vec![nan, [1.0, 2.0, 3.0]], vec![big, [-f64::MAX, f64::MAX, 1.0]]] {
            for preset in ViewPreset::ALL {
                usable(&frame_points(&pts, preset, UpAxis::Y, 40.0, 1280, 720, 0.9));
            }
            usable(&frame_points(&pts, ViewPreset::Front, UpAxis::Z, f64::NAN, 0, 0, f64::NAN));
            usable(&frame_points(&pts, ViewPreset::Iso, UpAxis::X, 180.0, 1, 1, -1.0));
        }
        // A single point is centred.
        let f = frame_points(&[[5.0, 5.0, 5.0]], ViewPreset::Front, UpAxis::Y, 40.0, 1280, 720, 0.9);
        assert!((f.target[0] - 5.0).abs() < 1e-9 && (f.target[1] - 5.0).abs() < 1e-9, "{f:?}");
        // Degenerate boxes (flat, a line, a point) still give a pixel size.
        for (lo, hi) in [([0.0; 3], [1.0, 1.0, 0.0]), ([0.0; 3], [0.0, 0.0, 1.0]), ([2.0; 3], [2.0; 3])] {
            let px = default_pixel_size(lo, hi, UpAxis::Y);
            assert!(px.is_finite() && px > 0.0, "{lo:?} {hi:?}: {px}");
        }
    }

    #[test]
    fn default_pixel_size_is_the_finer_of_front_and_iso() {
        let (lo, hi) = ([-1.0, -0.5, -0.25], [1.0, 0.5, 0.25]);
        let c = box_corners(lo, hi);
        let front = frame_points(&c, ViewPreset::Front, UpAxis::Y, 40.0, 1280, 720, 0.9).pixel_size;
        let iso = frame_points(&c, ViewPreset::Iso, UpAxis::Y, 40.0, 1280, 720, 0.9).pixel_size;
        assert_eq!(default_pixel_size(lo, hi, UpAxis::Y), front.min(iso));
        // The front face is 2 wide over 90 % of 1280 pixels; the target, half the depth
        // behind it, has pixels a little larger.
        let approx = 2.0 / (0.9 * 1280.0);
        assert!(front > approx && front < 1.2 * approx, "{front} vs {approx}");
        // Scales with the model.
        let big = default_pixel_size(lo.map(|v| v * 10.0), hi.map(|v| v * 10.0), UpAxis::Y);
        assert!((big / default_pixel_size(lo, hi, UpAxis::Y) - 10.0).abs() < 1e-9);
    }

    #[test]
    fn names_round_trip() {
        for p in ViewPreset::ALL {
            assert_eq!(p.name().parse::<ViewPreset>(), Ok(p));
            assert_eq!(p.to_string(), p.name());
        }
        for a in [UpAxis::X, UpAxis::Y, UpAxis::Z] {
            assert_eq!(a.to_string().parse::<UpAxis>(), Ok(a));
        }
        assert!("sideways".parse::<ViewPreset>().is_err());
        assert!("w".parse::<UpAxis>().is_err());
    }
}
