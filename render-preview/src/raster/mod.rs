//! Depth-tested splat rasterizer: workers draw chunks of splats into private layers that
//! are merged band by band in parallel with rayon. Each pixel keeps the nearest splat; ties
//! go to the splat that comes first in the input, so the output does not depend on the
//! number of threads.
//!
//! This file holds the splat and frame types; the drawing itself is in `draw.rs`, the
//! crack-filling passes over a drawn frame in `fill.rs`.

mod draw;
mod fill;

pub use draw::{rasterize, rasterize_blended};
pub(crate) use draw::{blend_over, depth_key, key_depth};
pub use fill::{fill_depth_pits, fill_holes, PIT_DEPTH};

/// Rows per band, the unit in which layers are merged and skipped when a worker drew
/// nothing there.
pub const BAND: usize = 16;

/// One screen-space splat: an ellipse (a circle when both radii agree).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Splat {
    /// Centre, pixel units (pixel `(i, j)` covers `[i, i+1) × [j, j+1)`).
    pub x: f32,
    /// Centre row coordinate (down).
    pub y: f32,
    /// Depth (camera-space distance along the view axis), smaller is nearer.
    pub z: f32,
    /// Unit direction of the minor axis. (Kept apart from the radii rather than expanded
    /// into a quadratic form, which loses all precision for very thin ellipses.)
    pub ux: f32,
    /// Unit direction of the minor axis.
    pub uy: f32,
    /// 1 / minor radius².
    pub inv_a2: f32,
    /// 1 / major radius².
    pub inv_b2: f32,
    /// Pixels whose centre lies in the bounding box, inclusive and unclipped (saturated to
    /// the i16 range): `[x0, x1, y0, y1]`, computed once when the splat is made so that
    /// binning and drawing do no float-to-int conversions. `x0 > x1` when there are none.
    pub bounds: [i16; 4],
    /// sRGB colour, straight alpha (alpha < 255 is drawn with an ordered-dither screen door).
    pub color: [u8; 4],
    /// Depth added at the rim of the splat, growing with the square of the normalised
    /// distance from its centre: a paraboloid instead of a flat disc (0 for a flat disc;
    /// `zbuffer` sets it to one radius in the world). The depth test and the frame's depth
    /// take it in.
    pub rim: f32,
}

impl Splat {
    /// A circular splat of radius `r` pixels.
    pub fn disc(x: f32, y: f32, z: f32, r: f32, color: [u8; 4]) -> Splat {
        let r = r.max(1e-6);
        let inv = 1.0 / (r * r);
        Splat { x, y, z, ux: 1.0, uy: 0.0, inv_a2: inv, inv_b2: inv, bounds: pixel_bounds(x, y, r, r), color, rim: 0.0 }
    }

    /// An elliptical splat: major radius `b`, minor radius `a` along unit `(ux, uy)`.
    #[allow(clippy::too_many_arguments)]
    pub fn ellipse(x: f32, y: f32, z: f32, b: f32, a: f32, ux: f32, uy: f32, color: [u8; 4]) -> Splat {
        let b = b.max(1e-6);
        let a = a.clamp(1e-6, b);
        let ex = ((a * ux).powi(2) + (b * uy).powi(2)).sqrt();
        let ey = ((a * uy).powi(2) + (b * ux).powi(2)).sqrt();
        Splat { x, y, z, ux, uy, inv_a2: 1.0 / (a * a), inv_b2: 1.0 / (b * b), bounds: pixel_bounds(x, y, ex, ey), color, rim: 0.0 }
    }

    /// Calls `f` with the index (`y × w + x`) of every pixel of a `w × h` frame whose centre
    /// lies in the splat; nothing for a splat at NaN or infinite depth. The plain scalar
    /// loop: methods that paint in order or count fragments use it, not the binned
    /// rasterizer.
    pub fn for_each_pixel(&self, w: usize, h: usize, mut f: impl FnMut(usize)) {
        if w == 0 || h == 0 || self.z.is_nan() || self.z == f32::INFINITY {
            return;
        }
        let [x0, x1, y0, y1] = self.bounds.map(i32::from);
        let (xa, xb, ya, yb) = (x0.max(0), x1.min(w as i32 - 1), y0.max(0), y1.min(h as i32 - 1));
        for py in ya..=yb {
            let dy = py as f32 + 0.5 - self.y;
            for px in xa..=xb {
                let dx = px as f32 + 0.5 - self.x;
                let (a, b) = (dx * self.ux + dy * self.uy, dy * self.ux - dx * self.uy);
                if a * a * self.inv_a2 + b * b * self.inv_b2 <= 1.0 {
                    f(py as usize * w + px as usize);
                }
            }
        }
    }

    /// How many pixel centres of a `w × h` frame lie in the splat: [`Splat::for_each_pixel`]'s
    /// count (up to rounding at the rim), from each row's span where the ellipse's
    /// quadratic is at most 1 rather than a test per pixel. A work counter for splats of
    /// several pixels (a supersampled frame's), where testing every pixel cost as much as
    /// drawing them.
    pub fn pixels_covered(&self, w: usize, h: usize) -> u64 {
        if w == 0 || h == 0 || self.z.is_nan() || self.z == f32::INFINITY {
            return 0;
        }
        let [x0, x1, y0, y1] = self.bounds.map(i32::from);
        let (xa, xb, ya, yb) = (x0.max(0), x1.min(w as i32 - 1), y0.max(0), y1.min(h as i32 - 1));
        if xa > xb || ya > yb {
            return 0;
        }
        // q(dx) = A dx² + B dx + C for the row at dy, in f64 so that the roots are exact
        // enough to agree with the f32 test but at the rim.
        let (ux, uy, ia, ib) = (f64::from(self.ux), f64::from(self.uy), f64::from(self.inv_a2), f64::from(self.inv_b2));
        let a = ux * ux * ia + uy * uy * ib;
        // A NaN or non-positive leading coefficient: no span.
        if a.is_nan() || a <= 0.0 {
            return 0;
        }
        let mut n = 0u64;
        for py in ya..=yb {
            let dy = f64::from(py) + 0.5 - f64::from(self.y);
            let (ay, by) = (dy * uy, dy * ux);
            let b = 2.0 * (ux * ay * ia - uy * by * ib);
            let c = ay * ay * ia + by * by * ib - 1.0;
            let disc = b * b - 4.0 * a * c;
            if disc < 0.0 {
                continue;
            }
            let r = disc.sqrt();
            let (lo, hi) = ((-b - r) / (2.0 * a), (-b + r) / (2.0 * a));
            // Pixel px holds dx = px + 0.5 − x.
            let x = f64::from(self.x) - 0.5;
            let first = ceil_i64(lo + x).max(i64::from(xa));
            let last = floor_i64(hi + x).min(i64::from(xb));
            n += (last - first + 1).max(0) as u64;
        }
        n
    }
}

/// Inclusive pixel bounds `[x0, x1, y0, y1]` of the pixels whose centre lies in the box of
/// half extents `ex`, `ey` around `(x, y)`. Splats are sampled at pixel centres like the
/// mesh reference's triangles: a splat that contains no pixel centre draws nothing
/// (forcing its centre pixel grew every silhouette by about half a pixel), and the cracks
/// that can leave inside a surface are closed by [`fill_holes`].
fn pixel_bounds(x: f32, y: f32, ex: f32, ey: f32) -> [i16; 4] {
    let c = |v: i32| v.clamp(i16::MIN as i32, i16::MAX as i32) as i16;
    [c(iceil(x - ex - 0.5)), c(ifloor(x + ex - 0.5)), c(iceil(y - ey - 0.5)), c(ifloor(y + ey - 0.5))]
}

// Without SSE4.1 `f32::floor` is a libm call; these stay inline. Inputs are clamped so
// the casts saturate harmlessly for splats far off screen.
#[inline(always)]
fn ifloor(v: f32) -> i32 {
    let v = v.clamp(-1e9, 1e9);
    let i = v as i32;
    i - ((i as f32) > v) as i32
}

/// `v.ceil() as i64` for every `v` (NaN gives 0, and out-of-range values saturate), inline:
/// without SSE4.1 `f64::ceil` is a libm call, 2 % of a supersampled preview's time in
/// [`Splat::pixels_covered`].
#[inline(always)]
fn ceil_i64(v: f64) -> i64 {
    let i = v as i64;
    if (i as f64) < v { i.saturating_add(1) } else { i }
}

/// `v.floor() as i64` for every `v`, inline (see [`ceil_i64`]).
#[inline(always)]
fn floor_i64(v: f64) -> i64 {
    let i = v as i64;
    if (i as f64) > v { i.saturating_sub(1) } else { i }
}

#[inline(always)]
fn iceil(v: f32) -> i32 {
    let v = v.clamp(-1e9, 1e9);
    let i = v as i32;
    i + ((i as f32) < v) as i32
}

/// A rendered image with depth.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// RGBA8 per pixel, row major, top row first.
    pub color: Vec<[u8; 4]>,
    /// Depth per pixel, `f32::INFINITY` where nothing was drawn.
    pub depth: Vec<f32>,
}

impl Frame {
    /// A frame filled with `background` and infinite depth.
    pub fn new(width: usize, height: usize, background: [u8; 4]) -> Frame {
        Frame { width, height, color: vec![background; width * height], depth: vec![f32::INFINITY; width * height] }
    }

    /// Coverage mask: true where something was drawn.
    pub fn coverage(&self) -> Vec<bool> {
        self.depth.iter().map(|d| d.is_finite()).collect()
    }

    /// Number of covered pixels.
    pub fn covered(&self) -> usize {
        self.depth.iter().filter(|d| d.is_finite()).count()
    }

    /// Inclusive pixel box `[x0, y0, x1, y1]` of the covered pixels (`None` when empty).
    pub fn covered_box(&self) -> Option<[usize; 4]> {
        let w = self.width.max(1);
        let mut b: Option<[usize; 4]> = None;
        for (y, row) in self.depth.chunks(w).enumerate() {
            let (Some(x0), Some(x1)) = (row.iter().position(|d| d.is_finite()), row.iter().rposition(|d| d.is_finite())) else {
                continue;
            };
            b = Some(match b {
                None => [x0, y, x1, y],
                Some([a0, b0, a1, _]) => [a0.min(x0), b0, a1.max(x1), y],
            });
        }
        b
    }

    /// The colour image as an `image` buffer (alpha forced opaque).
    pub fn to_rgb_image(&self) -> image::RgbImage {
        let mut buf = Vec::with_capacity(self.width * self.height * 3);
        for c in &self.color {
            buf.extend_from_slice(&c[..3]);
        }
        image::RgbImage::from_raw(self.width as u32, self.height as u32, buf).unwrap_or_default()
    }
}

/// 4×4 ordered-dither thresholds in (0, 255): a pixel of a splat with alpha `a` is drawn
/// when `a > BAYER[..]`, so alpha 255 always draws and the density follows alpha.
pub const BAYER: [u8; 16] = [8, 136, 40, 168, 200, 72, 232, 104, 56, 184, 24, 152, 248, 120, 216, 88];

/// Screen-door alpha test shared with the reference rasterizer.
#[inline]
pub fn alpha_passes(alpha: u8, x: usize, y: usize) -> bool {
    alpha == 255 || alpha > BAYER[(x & 3) | ((y & 3) << 2)]
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    #[test]
    fn disc_covers_expected_pixels() {
        let mut f = Frame::new(16, 16, [0, 0, 0, 255]);
        rasterize(&mut f, &[Splat::disc(8.0, 8.0, 1.0, 3.0, [255, 0, 0, 255])]);
        let n = f.covered();
        // Pixel centres within radius 3 of (8, 8): about π·9 ≈ 28.
        assert!((24..=32).contains(&n), "{n}");
        assert_eq!(f.color[8 * 16 + 8], [255, 0, 0, 255]);
        assert_eq!(f.color[0], [0, 0, 0, 255]);
    }

    #[test]
    fn tiny_splats_are_sampled_at_pixel_centres() {
        let mut f = Frame::new(8, 8, [0; 4]);
        rasterize(&mut f, &[Splat::disc(3.01, 5.99, 1.0, 0.01, [9, 9, 9, 255]), Splat::disc(1.5, 2.5, 1.0, 0.01, [7, 7, 7, 255])]);
        // The first misses every pixel centre, the second sits on one.
        assert_eq!(f.covered(), 1);
        assert_eq!(f.color[2 * 8 + 1], [7, 7, 7, 255]);
    }

    #[test]
    fn far_and_huge_splats_saturate_their_bounds() {
        let mut f = Frame::new(16, 8, [0; 4]);
        // Far off screen either way: nothing; centred far away but huge: everything.
        rasterize(&mut f, &[Splat::disc(1e7, 4.0, 1.0, 2.0, [1; 4]), Splat::disc(-1e7, -1e7, 1.0, 2.0, [1; 4])]);
        assert_eq!(f.covered(), 0);
        rasterize(&mut f, &[Splat::disc(-5e4, 4.0, 1.0, 6e4, [2, 2, 2, 255])]);
        assert_eq!(f.covered(), 16 * 8);
    }

    /// The span count agrees with the per-pixel test but for a pixel at the rim now and then.
    #[test]
    fn span_counts_agree_with_the_pixel_test() {
        let mut seed = 7u32;
        let mut rnd = || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (seed >> 8) as f32 / (1 << 24) as f32
        };
        let (mut exact, mut off, mut total) = (0, 0u64, 0u64);
        for i in 0..2000 {
            let (x, y, r) = (rnd() * 60.0 - 5.0, rnd() * 50.0 - 5.0, rnd() * 6.0 + 0.05);
            let t = rnd() * std::f32::consts::TAU;
            let s = if i % 2 == 0 { Splat::ellipse(x, y, 1.0, r, r * rnd(), t.cos(), t.sin(), [1; 4]) } else { Splat::disc(x, y, 1.0, r, [1; 4]) };
            let mut n = 0u64;
            s.for_each_pixel(50, 40, |_| n += 1);
            let m = s.pixels_covered(50, 40);
            exact += (n == m) as u32;
            off += n.abs_diff(m);
            total += n;
        }
        assert!(exact >= 1990 && off * 1000 <= total, "{exact} of 2000 exact, {off} of {total} pixels off");
    }

    /// The inline roundings agree with the library's on every kind of value.
    #[test]
    fn inline_roundings_match_the_library() {
        let mut v = vec![0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 1.5, -1.5, 2.5e-300, -2.5e-300, 4503599627370495.5, -4503599627370495.5, 9.3e18, -9.3e18, 9223372036854775807.0, -9223372036854775808.0, f64::MAX, f64::MIN, f64::INFINITY, f64::NEG_INFINITY, f64::NAN, -f64::NAN];
        let mut seed = 3u64;
        for _ in 0..100_000 {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            v.push(f64::from_bits(seed));
            v.push((seed >> 11) as f64 / (1u64 << 40) as f64 - 4096.0);
        }
        for x in v {
            assert_eq!(ceil_i64(x), x.ceil() as i64, "ceil {x:e}");
            assert_eq!(floor_i64(x), x.floor() as i64, "floor {x:e}");
        }
    }

    #[test]
    fn ellipse_is_thin_along_minor_axis() {
        let mut f = Frame::new(32, 32, [0; 4]);
        rasterize(&mut f, &[Splat::ellipse(16.0, 16.0, 1.0, 8.0, 1.0, 0.0, 1.0, [5, 5, 5, 255])]);
        // Wide in x, thin in y.
        assert!(f.depth[16 * 32 + 22].is_finite());
        assert!(!f.depth[20 * 32 + 16].is_finite());
    }

    /// A small deterministic generator of floats in [0, 1] (xorshift32), for the raster
    /// and the tiled frame's tests.
    pub(crate) fn xorshift(mut s: u32) -> impl FnMut() -> f32 {
        move || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            s as f32 / u32::MAX as f32
        }
    }
}
