//! `gauss`: elliptical Gaussian splats composited back to front without a depth buffer
//! (Coconu & Hege 2002, §5.4).
//!
//! Each node of the LOD cut becomes a Gaussian on its tangent disc, projected exactly through
//! the Jacobian of the perspective projection at its centre (the 2002 linearised ellipse,
//! EQ 4–5, is not needed on a CPU) and widened along the minor axis by the normal cone. The
//! disc is the one the `zbuffer` method draws opaque, which the LOD cut makes hole-free: a
//! leaf's covering radius, an internal node's `AREA_COVER ×` equal-area radius (at most its
//! sphere). Its edge is the kernel's half-opacity contour, as in the paper: "the splat size
//! should be chosen such that α = 1/2 at d_t/2 distance from center", `d_t` being the opaque
//! splat size that guarantees a hole-free surface. An optional isotropic low-pass (variance in
//! px²) keeps sub-pixel kernels from aliasing, as in EWA splatting. Kernels are drawn as
//! [`Splat`]s whose ellipse is the support (where α falls to `alpha_min`), so
//! α = `alpha_min`^q with `q` the squared normalised distance.
//!
//! Compositing follows EQ 1, `col = col_splat·α + col·(1 − α)`, in linear light, in a
//! per-frame depth order (far to near; ties by cut order, so the image is repeatable), or
//! ([`Order::Mask`]) in the reverse order of the `canopy` occlusion mask. The
//! option [`Weighting::Normalized`] is the ideal reconstruction of EQ 2 instead: a visibility
//! pass finds the front surface per pixel, and the kernels within their own support depth of
//! it are averaged with normalised weights (this needs a per-pixel depth, like an A-buffer);
//! the surface is opaque where the weights sum to ½ and fades with their sum at the outline.
//!
//! Alpha blending does not make a surface opaque: where only a kernel's half-opacity edge
//! reaches a pixel, the layer behind shows through (the paper's "small amount of background
//! color", §5.4). With sub-pixel kernels on a white plate over a black one, up to 41 % of the
//! black shows at `--pixel-error 0.5` (tests/methods.rs measures it); `normalized` shows none.
//! Internal nodes' colours are area-weighted averages of their subtree (EQ 14), so a cut
//! drawn above the leaves already uses prefiltered ("mip") colours.
//!
//! A pixel counts as covered (finite depth) when the accumulated opacity reaches ½.

use rayon::prelude::*;

use crate::raster::{Frame, Splat, BAND};
use crate::shade::{linear_to_srgb8, srgb_to_linear_lut};

/// How overlapping kernels are combined.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Weighting {
    /// Alpha blending back to front (Coconu & Hege EQ 1; the result is EQ 3): no depth buffer.
    #[default]
    Blend,
    /// Normalised weights over the front surface (EQ 2), with a per-pixel visibility pass.
    Normalized,
}

/// Where the back-to-front order comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Order {
    /// A per-frame sort of the cut by depth (ties by cut order).
    #[default]
    Depth,
    /// The `canopy` occlusion mask, reversed: each mask node's kernels in tree order (its
    /// stages 1–2 run first, with their occlusion culling; see [`crate::canopy`]).
    Mask,
}

/// The `gauss` method's settings.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct GaussOptions {
    /// Blending rule.
    pub weighting: Weighting,
    /// Order source.
    pub order: Order,
    /// Isotropic low-pass variance added to every kernel, px² (0: none).
    pub lowpass: f32,
    /// Opacity at the edge of a kernel's support (the alpha test).
    pub alpha_min: f32,
}

impl Default for GaussOptions {
    fn default() -> Self {
        GaussOptions { weighting: Weighting::Blend, order: Order::Depth, lowpass: DEFAULT_LOWPASS, alpha_min: DEFAULT_ALPHA_MIN }
    }
}

/// Default low-pass variance, px²: none. The kernels' half-opacity contour is already the
/// hole-free opaque splat; a 0.25 px² low-pass thickened the bunny's outline (IoU 0.997 →
/// 0.984) and cost 8 dB of foreground PSNR at 512².
pub const DEFAULT_LOWPASS: f32 = 0.0;
/// Default opacity at the edge of the support: 1/16, within Coconu & Hege's alpha test
/// (0.1–0.2) side; against 1/64 it cut the fragments by a third at the same accuracy
/// (bunny, Duck and fuze at 512² within ±0.5 dB).
pub const DEFAULT_ALPHA_MIN: f32 = 1.0 / 16.0;
/// Distance from a kernel's centre, in radii of its disc, where its opacity is ½ (Coconu &
/// Hege §5.4: α = ½ at `d_t/2`, the radius of the hole-free opaque splat).
pub const HALF_OPACITY_RADIUS: f32 = 1.0;

/// What the LOD traversal needs to shape a kernel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Kernel {
    /// Squared support radius in standard deviations: `2 ln(1/alpha_min)`.
    pub q_cut: f32,
    /// Low-pass variance, px².
    pub lowpass: f32,
}

impl Kernel {
    pub(crate) fn new(o: &GaussOptions) -> Kernel {
        let a = o.alpha_min.clamp(1e-6, 0.5);
        Kernel { q_cut: 2.0 * (1.0 / a).ln(), lowpass: o.lowpass.max(0.0) }
    }

    /// The support ellipse of the Gaussian of the tangent disc of radius `rho` (camera
    /// space, centre `c`, unit normal `n`, normal-cone half-angle `cone`) projected at
    /// `(x, y)` with focal length `focal` px.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn splat(&self, c: [f32; 3], n: [f32; 3], rho: f32, cone: f32, focal: f32, x: f32, y: f32, color: [u8; 4]) -> Splat {
        let z = c[2];
        let fz = focal / z;
        // Rows of the projection's Jacobian (screen y points down).
        let jx = [fz, 0.0, -fz * c[0] / z];
        let jy = [0.0, -fz, fz * c[1] / z];
        let (t1, t2) = tangent_basis(n);
        let dot = |a: [f32; 3], b: [f32; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let (m11, m12, m21, m22) = (dot(jx, t1) * rho, dot(jx, t2) * rho, dot(jy, t1) * rho, dot(jy, t2) * rho);
        // The disc's screen ellipse d = M u, |u| ≤ 1: dᵀ (M Mᵀ)⁻¹ d ≤ 1.
        let (a, b, cc) = (m11 * m11 + m12 * m12, m11 * m21 + m12 * m22, m21 * m21 + m22 * m22);
        let mean = 0.5 * (a + cc);
        let dev = (0.25 * (a - cc) * (a - cc) + b * b).sqrt();
        let (l1, l2) = (mean + dev, (mean - dev).max(0.0));
        // Minor-axis direction.
        let (mut ux, mut uy) = if b.abs() > 1e-12 * mean.max(1e-30) { (b, l2 - a) } else if a <= cc { (1.0, 0.0) } else { (0.0, 1.0) };
        let ul = (ux * ux + uy * uy).sqrt();
        if ul > 0.0 && ul.is_finite() {
            (ux, uy) = (ux / ul, uy / ul);
        } else {
            (ux, uy) = (1.0, 0.0);
        }
        // A patch whose normals spread over the cone is wider across than its disc.
        let spread = if cone >= std::f32::consts::FRAC_PI_2 { 1.0 } else { cone.sin() };
        let l2 = (l2 + spread * spread * l1).min(l1);
        // Gaussian variances: α = ½ at HALF_OPACITY_RADIUS·ρ (the disc's edge), i.e. σ² = h² λ / (2 ln 2).
        let k = HALF_OPACITY_RADIUS * HALF_OPACITY_RADIUS / (2.0 * std::f32::consts::LN_2);
        let (v1, v2) = (l1 * k + self.lowpass, l2 * k + self.lowpass);
        let (rb, ra) = ((self.q_cut * v1).sqrt(), (self.q_cut * v2).sqrt());
        Splat::ellipse(x, y, z, rb, ra, ux, uy, color)
    }
}

/// Two unit vectors spanning the plane perpendicular to unit `n`.
fn tangent_basis(n: [f32; 3]) -> ([f32; 3], [f32; 3]) {
    let a = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let cross = |u: [f32; 3], v: [f32; 3]| [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
    let t1 = cross(n, a);
    let l = (t1[0] * t1[0] + t1[1] * t1[1] + t1[2] * t1[2]).sqrt().max(1e-30);
    let t1 = t1.map(|v| v / l);
    (t1, cross(n, t1))
}

/// Counters of one composite.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct GaussStats {
    /// Kernel–pixel pairs evaluated inside a support (fragments blended).
    pub fragments: u64,
    /// Seconds spent sorting the cut by depth.
    pub sort_seconds: f64,
}

const LUT_N: usize = 1024;

/// `alpha_min^q` for `q` in [0, 1], sampled at `LUT_N + 1` points.
fn falloff(alpha_min: f32) -> Vec<f32> {
    (0..=LUT_N).map(|i| alpha_min.powf(i as f32 / LUT_N as f32)).collect()
}

/// The back-to-front order of `splats`: indices sorted by decreasing depth, ties by index.
pub fn depth_order(splats: &[Splat]) -> Vec<u32> {
    let mut keys: Vec<u64> = splats
        .par_iter()
        .enumerate()
        .map(|(i, s)| {
            // Drawn splats lie beyond the near plane (positive depth): their bit patterns
            // sort like the values. Anything else goes first (farthest).
            let zb = if s.z > 0.0 && s.z.is_finite() { s.z.to_bits() } else { u32::MAX };
            (((u32::MAX - zb) as u64) << 32) | i as u64
        })
        .collect();
    keys.par_sort_unstable();
    keys.into_iter().map(|k| k as u32).collect()
}

/// Composites `splats` (support ellipses from `Kernel::splat`) into `frame` in `order`
/// (far to near), blending over the frame's colours; `focal` (px) converts a kernel's
/// screen support to a depth tolerance for [`Weighting::Normalized`]. Deterministic for
/// any number of threads: each pixel sees its kernels in `order`.
pub fn composite(frame: &mut Frame, splats: &[Splat], order: &[u32], o: &GaussOptions, focal: f32) -> GaussStats {
    let (w, h) = (frame.width, frame.height);
    if w == 0 || h == 0 {
        return GaussStats::default();
    }
    let lut = falloff(o.alpha_min.clamp(1e-6, 0.5));
    let bands = h.div_ceil(BAND);
    // Bin the ordered kernels by band, keeping the order.
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); bands];
    for &i in order {
        let s = &splats[i as usize];
        let [x0, x1, y0, y1] = s.bounds.map(i32::from);
        if x0 > x1 || y0 > y1 || x1 < 0 || y1 < 0 || x0 >= w as i32 || y0 >= h as i32 || s.z.is_nan() || s.z <= 0.0 {
            continue;
        }
        let (b0, b1) = (y0.max(0) as usize / BAND, (y1 as usize).min(h - 1) / BAND);
        for bin in &mut bins[b0..=b1] {
            bin.push(i);
        }
    }
    let srgb = srgb_to_linear_lut();
    let bg: Vec<[f32; 3]> = frame.color.iter().map(|c| [srgb[c[0] as usize], srgb[c[1] as usize], srgb[c[2] as usize]]).collect();
    let results: Vec<(Vec<[u8; 4]>, Vec<f32>, u64)> = bins
        .par_iter()
        .enumerate()
        .map(|(b, bin)| {
            let (r0, r1) = (b * BAND, ((b + 1) * BAND).min(h));
            let mut band = Band::new(&bg[r0 * w..r1 * w], w, r0, r1);
            match o.weighting {
                Weighting::Blend => band.blend(splats, bin, &lut),
                Weighting::Normalized => band.normalized(splats, bin, &lut, focal),
            }
            band.finish()
        })
        .collect();
    let mut fragments = 0;
    for (b, (col, dep, n)) in results.into_iter().enumerate() {
        let r0 = b * BAND * w;
        frame.color[r0..r0 + col.len()].copy_from_slice(&col);
        frame.depth[r0..r0 + dep.len()].copy_from_slice(&dep);
        fragments += n;
    }
    GaussStats { fragments, sort_seconds: 0.0 }
}

/// One band of rows being composited.
struct Band {
    w: usize,
    r0: usize,
    r1: usize,
    col: Vec<[f32; 3]>,
    /// Transmittance: the product of (1 − α) so far.
    t: Vec<f32>,
    depth: Vec<f32>,
    fragments: u64,
}

impl Band {
    fn new(bg: &[[f32; 3]], w: usize, r0: usize, r1: usize) -> Band {
        let n = bg.len();
        Band { w, r0, r1, col: bg.to_vec(), t: vec![1.0; n], depth: vec![f32::INFINITY; n], fragments: 0 }
    }

    /// Calls `f(pixel index in band, q)` for every pixel centre of the band inside the
    /// support of `s`.
    #[inline(always)]
    fn each(&self, s: &Splat, mut f: impl FnMut(usize, f32)) {
        let [x0, x1, y0, y1] = s.bounds.map(i32::from);
        let (xa, xb) = (x0.max(0), x1.min(self.w as i32 - 1));
        let (ya, yb) = (y0.max(self.r0 as i32), y1.min(self.r1 as i32 - 1));
        if xa > xb || ya > yb {
            return;
        }
        let x0f = xa as f32 + 0.5 - s.x;
        for py in ya..=yb {
            let dy = py as f32 + 0.5 - s.y;
            let (ay, by) = (dy * s.uy, dy * s.ux);
            let row = (py as usize - self.r0) * self.w;
            for k in 0..=(xb - xa) as usize {
                let dx = x0f + k as f32;
                let (a, b) = (dx * s.ux + ay, by - dx * s.uy);
                let q = a * a * s.inv_a2 + b * b * s.inv_b2;
                if q <= 1.0 {
                    f(row + xa as usize + k, q);
                }
            }
        }
    }

    /// EQ 1, far to near.
    fn blend(&mut self, splats: &[Splat], bin: &[u32], lut: &[f32]) {
        let srgb = srgb_to_linear_lut();
        let mut n = 0u64;
        let (mut col, mut t, mut depth) = (std::mem::take(&mut self.col), std::mem::take(&mut self.t), std::mem::take(&mut self.depth));
        for &i in bin {
            let s = &splats[i as usize];
            let c = [srgb[s.color[0] as usize], srgb[s.color[1] as usize], srgb[s.color[2] as usize]];
            let ca = s.color[3] as f32 / 255.0;
            self.each(s, |p, q| {
                let a = lut[(q * LUT_N as f32) as usize] * ca;
                let px = &mut col[p];
                for k in 0..3 {
                    px[k] += (c[k] - px[k]) * a;
                }
                t[p] *= 1.0 - a;
                depth[p] = s.z;
                n += 1;
            });
        }
        (self.col, self.t, self.depth, self.fragments) = (col, t, depth, n);
    }

    /// EQ 2 over the front surface. A visibility pass takes per pixel the nearest kernel
    /// that reaches opacity ¼ there (so a crack between two half-opacity edges still finds
    /// its surface), else the nearest kernel. In order, the kernels farther than their own
    /// support radius behind it are blended (EQ 1) into the layer behind, those within it
    /// are averaged with normalised weights, and nearer ones (weak tails of a nearer
    /// surface) are blended over the result.
    fn normalized(&mut self, splats: &[Splat], bin: &[u32], lut: &[f32], focal: f32) {
        let srgb = srgb_to_linear_lut();
        let n = self.col.len();
        let (mut core, mut any) = (vec![f32::INFINITY; n], vec![f32::INFINITY; n]);
        let q_quarter = lut.iter().position(|&a| a < 0.25).unwrap_or(LUT_N) as f32 / LUT_N as f32;
        for &i in bin {
            let s = &splats[i as usize];
            self.each(s, |p, q| {
                any[p] = any[p].min(s.z);
                if q <= q_quarter {
                    core[p] = core[p].min(s.z);
                }
            });
        }
        let front: Vec<f32> = core.iter().zip(&any).map(|(&c, &a)| if c.is_finite() { c } else { a }).collect();
        let (mut sw, mut swc) = (vec![0f32; n], vec![[0f32; 3]; n]);
        // The layer behind (EQ 1 over the background) and the premultiplied layer over.
        let mut behind = std::mem::take(&mut self.col);
        let (mut over, mut t_over) = (vec![[0f32; 3]; n], vec![1f32; n]);
        let mut frags = 0u64;
        for &i in bin {
            let s = &splats[i as usize];
            let tol = (1.0 / s.inv_b2.max(1e-30)).sqrt() * s.z / focal.max(1e-30);
            let c = [srgb[s.color[0] as usize], srgb[s.color[1] as usize], srgb[s.color[2] as usize]];
            let ca = s.color[3] as f32 / 255.0;
            self.each(s, |p, q| {
                frags += 1;
                let a = lut[(q * LUT_N as f32) as usize] * ca;
                if s.z > front[p] + tol {
                    for k in 0..3 {
                        behind[p][k] += (c[k] - behind[p][k]) * a;
                    }
                } else if s.z >= front[p] - tol {
                    sw[p] += a;
                    for k in 0..3 {
                        swc[p][k] += a * c[k];
                    }
                } else {
                    for k in 0..3 {
                        over[p][k] = over[p][k] * (1.0 - a) + c[k] * a;
                    }
                    t_over[p] *= 1.0 - a;
                }
            });
        }
        let mut t = vec![1f32; n];
        let mut col = behind;
        for p in 0..n {
            if sw[p] > 0.0 {
                // Separated visibility makes the surface opaque wherever a kernel reaches
                // half opacity (Coconu & Hege: α = ½ at d_t/2 "guarantees opaque surfaces …
                // for an A-buffer approach"); the outline fades with the summed weight.
                let a = (2.0 * sw[p]).min(1.0);
                for k in 0..3 {
                    col[p][k] = swc[p][k] / sw[p] * a + col[p][k] * (1.0 - a);
                }
                self.depth[p] = front[p];
                // Covered where the weights sum to ½ (the depth-buffer splat's outline).
                t[p] = 1.0 - sw[p].min(1.0);
            }
            if t_over[p] < 1.0 {
                for k in 0..3 {
                    col[p][k] = over[p][k] + t_over[p] * col[p][k];
                }
            }
        }
        self.col = col;
        self.t = t;
        self.fragments = frags;
    }

    fn finish(self) -> (Vec<[u8; 4]>, Vec<f32>, u64) {
        let col = self.col.iter().map(|c| [linear_to_srgb8(c[0]), linear_to_srgb8(c[1]), linear_to_srgb8(c[2]), 255]).collect();
        let depth = self.depth.iter().zip(&self.t).map(|(&d, &t)| if 1.0 - t >= COVERED_OPACITY { d } else { f32::INFINITY }).collect();
        (col, depth, self.fragments)
    }
}

/// The accumulated opacity at which a pixel counts as covered (kernels leave no cracks to
/// fill, so `raster::fill_holes` is not run).
pub const COVERED_OPACITY: f32 = 0.5;

#[cfg(test)]
mod tests {
    use super::*;

    fn kernel() -> Kernel {
        Kernel::new(&GaussOptions::default())
    }

    #[test]
    fn facing_disc_projects_to_a_circle_with_half_opacity_at_its_edge() {
        let k = Kernel { lowpass: 0.0, ..kernel() };
        // A disc of radius 1 at depth 10 facing the eye, focal 100: 10 px on screen.
        let s = k.splat([0.0, 0.0, 10.0], [0.0, 0.0, -1.0], 1.0, 0.0, 100.0, 50.0, 50.0, [255; 4]);
        assert!((s.inv_a2 - s.inv_b2).abs() < 1e-6 * s.inv_a2, "{s:?}");
        // α(r) = alpha_min^(r²·inv): ½ at 0.886·10 px.
        let r = HALF_OPACITY_RADIUS * 10.0;
        let a = DEFAULT_ALPHA_MIN.powf(r * r * s.inv_a2);
        assert!((a - 0.5).abs() < 1e-3, "{a}");
    }

    #[test]
    fn tilted_disc_is_thin_along_its_screen_normal() {
        let k = Kernel { lowpass: 0.0, ..kernel() };
        // Normal tilted 60° about the x axis: the screen ellipse is cos 60° = ½ as tall as wide.
        let (s60, c60) = 60f32.to_radians().sin_cos();
        let s = k.splat([0.0, 0.0, 10.0], [0.0, s60, -c60], 1.0, 0.0, 100.0, 50.0, 50.0, [255; 4]);
        assert!(s.uy.abs() > 0.999, "minor axis is vertical: {s:?}");
        let ratio = (s.inv_b2 / s.inv_a2).sqrt();
        assert!((ratio - 0.5).abs() < 0.01, "{ratio}");
        // A wide normal cone rounds it.
        let s = k.splat([0.0, 0.0, 10.0], [0.0, s60, -c60], 1.0, 1.6, 100.0, 50.0, 50.0, [255; 4]);
        assert!((s.inv_a2 - s.inv_b2).abs() < 1e-5 * s.inv_a2);
    }

    #[test]
    fn back_to_front_blending_lets_the_near_kernel_win_at_its_centre() {
        let k = kernel();
        let far = k.splat([0.0, 0.0, 20.0], [0.0, 0.0, -1.0], 2.0, 0.0, 100.0, 10.5, 10.5, [255, 0, 0, 255]);
        let near = k.splat([0.0, 0.0, 10.0], [0.0, 0.0, -1.0], 1.0, 0.0, 100.0, 10.5, 10.5, [0, 0, 255, 255]);
        // Given near first: the order still draws it last.
        let splats = [near, far];
        let order = depth_order(&splats);
        assert_eq!(order, vec![1, 0]);
        let mut f = Frame::new(20, 20, [0, 0, 0, 255]);
        let st = composite(&mut f, &splats, &order, &GaussOptions::default(), 100.0);
        assert_eq!(f.color[10 * 20 + 10], [0, 0, 255, 255]);
        assert!(f.depth[10 * 20 + 10] == 10.0);
        assert!(st.fragments > 200);
        // The same splats through the normalised rule: the front surface alone.
        let mut g = Frame::new(20, 20, [0, 0, 0, 255]);
        composite(&mut g, &splats, &order, &GaussOptions { weighting: Weighting::Normalized, ..Default::default() }, 100.0);
        assert_eq!(g.color[10 * 20 + 10], [0, 0, 255, 255]);
    }

    #[test]
    fn composite_is_the_same_on_one_thread() {
        let k = kernel();
        let mut splats = Vec::new();
        let mut s = 12345u32;
        let mut rnd = move || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            s as f32 / u32::MAX as f32
        };
        for i in 0..20_000 {
            let c = [rnd() * 2.0 - 1.0, rnd() * 2.0 - 1.0, 5.0 + rnd()];
            let n = [rnd() - 0.5, rnd() - 0.5, -1.0];
            let l = (n[0] * n[0] + n[1] * n[1] + 1.0f32).sqrt();
            let [x, y] = [50.0 + c[0] * 100.0 / c[2] * 5.0, 40.0 - c[1] * 100.0 / c[2] * 5.0];
            splats.push(k.splat(c, n.map(|v| v / l), 0.01 + 0.02 * rnd(), 0.0, 500.0, x, y, [(i % 251) as u8, 90, 200, 255]));
        }
        let order = depth_order(&splats);
        let mut a = Frame::new(100, 80, [0; 4]);
        composite(&mut a, &splats, &order, &GaussOptions::default(), 500.0);
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let mut b = Frame::new(100, 80, [0; 4]);
        pool.install(|| composite(&mut b, &splats, &order, &GaussOptions::default(), 500.0));
        assert_eq!(a, b);
        assert!(a.covered() > 2000);
    }
}
