//! Camera, view transform and the per-node screen-space tests: frustum and back-face
//! culling and the projected size of a sphere (thesis §5.8.1, EQ 43–47).

use crate::error::{Error, Result};

/// Largest image side accepted (keeps buffers bounded).
pub const MAX_SIDE: u32 = 16384;

pub use sct_format::view::{UpAxis, ViewPreset};

/// A pinhole camera.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Camera {
    /// Centre of projection.
    pub eye: [f64; 3],
    /// Point looked at (centre of the image).
    pub target: [f64; 3],
    /// Approximate up direction.
    pub up: [f64; 3],
    /// Vertical field of view in degrees.
    pub fov_y_deg: f64,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
}

impl Camera {
    /// The camera of a [`Framing`](sct_format::view::Framing) for a `width`×`height` image.
    pub fn from_framing(f: &sct_format::view::Framing, fov_y_deg: f64, width: u32, height: u32) -> Camera {
        Camera { eye: f.eye, target: f.target, up: f.up, fov_y_deg, width, height }
    }
}

/// A camera prepared for rendering: an orthonormal camera frame (x right, y up, z forward)
/// and the focal length in pixels.
#[derive(Clone, Copy, Debug)]
pub struct View {
    /// Eye in world space.
    pub eye: [f64; 3],
    /// Rows of the world-to-camera rotation: right, up, forward.
    pub basis: [[f64; 3]; 3],
    /// Focal length in pixels.
    pub focal: f32,
    /// Image centre.
    pub cx: f32,
    /// Image centre.
    pub cy: f32,
    /// Image size.
    pub width: u32,
    /// Image size.
    pub height: u32,
    /// Near distance: geometry closer than this along the view axis is not drawn.
    pub near: f32,
    /// Subpixels per output pixel side: 1, or the factor of [`View::supersampled`].
    pub subpixels: u32,
    /// tan of the half field of view, horizontally and vertically.
    tan_half: [f32; 2],
    /// 1 / sqrt(1 + tan²) for the side-plane distances.
    inv_norm: [f32; 2],
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
fn norm(a: [f64; 3]) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}
fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

impl View {
    /// Validates `cam` and builds the view; `near` is the near distance (world units).
    pub fn new(cam: &Camera, near: f64) -> Result<View> {
        let all = cam.eye.iter().chain(&cam.target).chain(&cam.up).chain(std::iter::once(&cam.fov_y_deg));
        if !all.clone().all(|v| v.is_finite()) {
            return Err(Error::Camera("eye, target, up and fov must be finite numbers".into()));
        }
        if cam.width == 0 || cam.height == 0 || cam.width > MAX_SIDE || cam.height > MAX_SIDE {
            return Err(Error::Camera(format!("image size {}x{} must be 1..={MAX_SIDE} on each side", cam.width, cam.height)));
        }
        if !(cam.fov_y_deg > 0.01 && cam.fov_y_deg < 179.0) {
            return Err(Error::Camera(format!("field of view {}° must lie in (0.01, 179)", cam.fov_y_deg)));
        }
        let f = sub(cam.target, cam.eye);
        let fl = norm(f);
        let scene_scale = norm(cam.eye).max(norm(cam.target)).max(1e-30);
        if fl <= 1e-12 * scene_scale {
            return Err(Error::Camera("eye and target coincide: no viewing direction".into()));
        }
        let fwd = scale(f, 1.0 / fl);
        let r = cross(fwd, cam.up);
        let rl = norm(r);
        if norm(cam.up) == 0.0 || rl <= 1e-9 * norm(cam.up) {
            return Err(Error::Camera("up vector is zero or parallel to the viewing direction".into()));
        }
        let right = scale(r, 1.0 / rl);
        let up = cross(right, fwd);
        let focal = (cam.height as f64 / 2.0) / (cam.fov_y_deg.to_radians() / 2.0).tan();
        let tx = (cam.width as f64 / 2.0) / focal;
        let ty = (cam.height as f64 / 2.0) / focal;
        Ok(View {
            eye: cam.eye,
            basis: [right, up, fwd],
            focal: focal as f32,
            cx: cam.width as f32 / 2.0,
            cy: cam.height as f32 / 2.0,
            width: cam.width,
            height: cam.height,
            near: near.max(1e-30) as f32,
            subpixels: 1,
            tan_half: [tx as f32, ty as f32],
            inv_norm: [(1.0 / (1.0 + tx * tx).sqrt()) as f32, (1.0 / (1.0 + ty * ty).sqrt()) as f32],
        })
    }

    /// The same camera on an image `s` times as wide and high (each pixel split into `s × s`
    /// subpixels): what a supersampled render draws before it is resolved.
    pub fn supersampled(&self, s: u32) -> View {
        let k = s as f32;
        View { focal: self.focal * k, cx: self.cx * k, cy: self.cy * k, width: self.width * s, height: self.height * s, subpixels: self.subpixels * s, ..*self }
    }

    /// World point to camera space (f64 in, f32 out).
    pub fn to_camera(&self, p: [f64; 3]) -> [f32; 3] {
        let d = sub(p, self.eye);
        let b = &self.basis;
        [
            (b[0][0] * d[0] + b[0][1] * d[1] + b[0][2] * d[2]) as f32,
            (b[1][0] * d[0] + b[1][1] * d[1] + b[1][2] * d[2]) as f32,
            (b[2][0] * d[0] + b[2][1] * d[1] + b[2][2] * d[2]) as f32,
        ]
    }

    /// World direction to camera space.
    pub fn dir_to_camera(&self, v: [f64; 3]) -> [f64; 3] {
        let b = &self.basis;
        [
            b[0][0] * v[0] + b[0][1] * v[1] + b[0][2] * v[2],
            b[1][0] * v[0] + b[1][1] * v[1] + b[1][2] * v[2],
            b[2][0] * v[0] + b[2][1] * v[1] + b[2][2] * v[2],
        ]
    }

    /// Screen position of a camera-space point in front of the eye (pixel units, y down;
    /// pixel `(i, j)` covers `[i, i+1) × [j, j+1)`).
    #[inline]
    pub fn project(&self, c: [f32; 3]) -> [f32; 2] {
        let s = self.focal / c[2];
        [self.cx + c[0] * s, self.cy - c[1] * s]
    }

    /// True when a camera-space sphere lies entirely outside the view frustum (behind the
    /// near plane or beyond one of the four side planes).
    #[inline]
    pub fn outside(&self, c: [f32; 3], r: f32) -> bool {
        if c[2] + r <= self.near {
            return true;
        }
        let [tx, ty] = self.tan_half;
        let [nx, ny] = self.inv_norm;
        (c[0].abs() - c[2] * tx) * nx > r || (c[1].abs() - c[2] * ty) * ny > r
    }

    /// Projected radius in pixels of a camera-space sphere: the semi-major axis of the
    /// conic section of its view cone with the image plane (EQ 43–46), measured from the
    /// projected centre M, i.e. the radius of the conservative circle centred at M.
    /// `f32::INFINITY` when the cone reaches the eye plane (eye inside the sphere, or the
    /// sphere straddling the plane through the eye).
    #[inline]
    pub fn projected_radius(&self, c: [f32; 3], r: f32) -> f32 {
        let d2 = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
        if d2 <= r * r || c[2] <= 0.0 {
            return f32::INFINITY;
        }
        let d = d2.sqrt();
        // α: view-cone semi-angle; β: angle between the view vector V and the view-plane
        // normal. EQ 44–46 reduce to s = f·sin α / (cos β · cos(α + β)).
        let sa = r / d;
        let ca = (1.0 - sa * sa).max(0.0).sqrt();
        let cb = c[2] / d;
        let sb = (1.0 - cb * cb).max(0.0).sqrt();
        let cab = ca * cb - sa * sb;
        if cab <= 1e-6 {
            return f32::INFINITY;
        }
        self.focal * sa / (cb * cab)
    }

    /// Back-face test with a normal cone (camera space): true when every normal of the cone
    /// faces away from every point of the sphere's view cone, i.e. the angle between the
    /// axis and the direction to the eye exceeds 90° + cone + view-cone semi-angle. Cones of
    /// 90° or more are never culled.
    #[inline]
    pub fn backfacing(&self, c: [f32; 3], r: f32, n: [f32; 3], cone: f32) -> bool {
        if cone >= std::f32::consts::FRAC_PI_2 {
            return false;
        }
        let d2 = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
        if d2 <= r * r {
            return false;
        }
        let d = d2.sqrt();
        // cos of the angle γ between n and the direction from the centre to the eye (−c/d).
        let cg = -(n[0] * c[0] + n[1] * c[1] + n[2] * c[2]) / d;
        // γ > 90° + cone + α with t = cone + α, without inverse trigonometry (it was 5 % of
        // a preview): never when t ≥ 90°, else cos γ < cos(90° + t) = −sin t.
        let sa = (r / d).min(1.0);
        let ca = (1.0 - sa * sa).max(0.0).sqrt();
        let (sc, cc) = cone.sin_cos();
        if cc * ca - sc * sa <= 0.0 {
            return false;
        }
        cg < -(sc * ca + cc * sa)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(w: u32, h: u32) -> View {
        let cam = Camera { eye: [0.0, 0.0, 10.0], target: [0.0; 3], up: [0.0, 1.0, 0.0], fov_y_deg: 60.0, width: w, height: h };
        View::new(&cam, 1e-3).unwrap()
    }

    #[test]
    fn centre_projects_to_image_centre() {
        let v = view(200, 100);
        let c = v.to_camera([0.0, 0.0, 0.0]);
        assert!((c[2] - 10.0).abs() < 1e-6);
        let p = v.project(c);
        assert!((p[0] - 100.0).abs() < 1e-4 && (p[1] - 50.0).abs() < 1e-4);
        // +x world is right, +y world is up (smaller row).
        let p = v.project(v.to_camera([1.0, 1.0, 0.0]));
        assert!(p[0] > 100.0 && p[1] < 50.0);
    }

    #[test]
    fn projected_radius_matches_tangent_geometry() {
        let v = view(200, 200);
        // On axis: f tan α.
        let s = v.projected_radius([0.0, 0.0, 10.0], 1.0);
        let expect = v.focal * (1.0f32 / 10.0).asin().tan();
        assert!((s - expect).abs() < 1e-3 * expect);
        // Off axis: distance from M to the far edge of the conic = f (tan(β+α) − tan β).
        let c = [3.0f32, 0.0, 10.0];
        let d = (9.0f32 + 100.0).sqrt();
        let (a, b) = ((1.0 / d).asin(), (3.0f32 / 10.0).atan());
        let expect = v.focal * ((a + b).tan() - b.tan());
        let s = v.projected_radius(c, 1.0);
        assert!((s - expect).abs() < 1e-3 * expect, "{s} vs {expect}");
        // Grows off axis, infinite when the eye is inside.
        assert!(s > v.projected_radius([0.0, 0.0, 10.0], 1.0));
        assert!(v.projected_radius([0.0, 0.0, 0.5], 1.0).is_infinite());
    }

    #[test]
    fn frustum_culling() {
        let v = view(100, 100);
        assert!(!v.outside([0.0, 0.0, 10.0], 1.0));
        assert!(v.outside([0.0, 0.0, -5.0], 1.0));
        // tan(30°)·10 ≈ 5.77: a unit sphere at x = 6.5 still touches, at x = 7 it does not.
        assert!(!v.outside([6.5, 0.0, 10.0], 1.0));
        assert!(v.outside([8.0, 0.0, 10.0], 1.0));
        assert!(v.outside([0.0, -8.0, 10.0], 1.0));
    }

    #[test]
    fn backface_culling_with_cones() {
        let v = view(100, 100);
        let c = [0.0, 0.0, 10.0];
        // Normal pointing away from the eye (+z in camera space).
        assert!(v.backfacing(c, 0.1, [0.0, 0.0, 1.0], 0.1));
        assert!(!v.backfacing(c, 0.1, [0.0, 0.0, -1.0], 0.1));
        // Grazing normal is kept; obtuse cones are never culled.
        assert!(!v.backfacing(c, 0.1, [1.0, 0.0, 0.0], 0.0));
        assert!(!v.backfacing(c, 0.1, [0.0, 0.0, 1.0], 1.7));
        // Axis straight away: a 1.5 rad cone still faces away entirely (its best normal is
        // 1.64 rad from the eye direction); 1.565 rad plus the view cone reaches it.
        assert!(v.backfacing(c, 0.1, [0.0, 0.0, 1.0], 1.5));
        assert!(!v.backfacing(c, 0.1, [0.0, 0.0, 1.0], 1.565));
    }

    #[test]
    fn degenerate_cameras_are_errors() {
        let ok = Camera { eye: [0.0, 0.0, 1.0], target: [0.0; 3], up: [0.0, 1.0, 0.0], fov_y_deg: 45.0, width: 10, height: 10 };
        assert!(View::new(&ok, 1e-3).is_ok());
        for bad in [
            Camera { target: ok.eye, ..ok },
            Camera { up: [0.0, 0.0, 1.0], ..ok },
            Camera { up: [0.0; 3], ..ok },
            Camera { fov_y_deg: 0.0, ..ok },
            Camera { fov_y_deg: 180.0, ..ok },
            Camera { width: 0, ..ok },
            Camera { eye: [f64::NAN, 0.0, 0.0], ..ok },
        ] {
            assert!(matches!(View::new(&bad, 1e-3), Err(Error::Camera(_))), "{bad:?}");
        }
    }
}
