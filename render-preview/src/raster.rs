//! Depth-tested splat rasterizer: splats are binned to horizontal bands of the image, and
//! bands are rasterized in parallel with rayon. Each pixel keeps the nearest splat; ties go
//! to the splat that comes first in the input, so the output does not depend on the number
//! of threads.

use rayon::prelude::*;

/// Rows per band: a band of a 1280-pixel-wide frame (colour + depth) is 160 KiB, which
/// stays in a core's L2 cache while its splats are drawn.
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
}

impl Splat {
    /// A circular splat of radius `r` pixels.
    pub fn disc(x: f32, y: f32, z: f32, r: f32, color: [u8; 4]) -> Splat {
        let r = r.max(1e-6);
        let inv = 1.0 / (r * r);
        Splat { x, y, z, ux: 1.0, uy: 0.0, inv_a2: inv, inv_b2: inv, bounds: pixel_bounds(x, y, r, r), color }
    }

    /// An elliptical splat: major radius `b`, minor radius `a` along unit `(ux, uy)`.
    #[allow(clippy::too_many_arguments)]
    pub fn ellipse(x: f32, y: f32, z: f32, b: f32, a: f32, ux: f32, uy: f32, color: [u8; 4]) -> Splat {
        let b = b.max(1e-6);
        let a = a.clamp(1e-6, b);
        let ex = ((a * ux).powi(2) + (b * uy).powi(2)).sqrt();
        let ey = ((a * uy).powi(2) + (b * ux).powi(2)).sqrt();
        Splat { x, y, z, ux, uy, inv_a2: 1.0 / (a * a), inv_b2: 1.0 / (b * b), bounds: pixel_bounds(x, y, ex, ey), color }
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

/// Rasterizes `splats` into `frame` (depth-tested against what the frame holds).
pub fn rasterize(frame: &mut Frame, splats: &[Splat]) {
    let (w, h) = (frame.width, frame.height);
    if w == 0 || h == 0 || splats.is_empty() {
        return;
    }
    let nbands = h.div_ceil(BAND);
    let (wm, hm) = (w as i32 - 1, h as i32 - 1);
    let clip = |s: &Splat| -> Option<[i32; 4]> {
        let [x0, x1, y0, y1] = s.bounds.map(i32::from);
        let b = [x0.max(0), x1.min(wm), y0.max(0), y1.min(hm)];
        (b[0] <= b[1] && b[2] <= b[3]).then_some(b)
    };
    // One pass per chunk pushes each splat's index to the bands it touches. Chunks keep
    // input order and a band walks them in order, so ties resolve to the earliest splat
    // whatever the thread count.
    let threads = rayon::current_num_threads().max(1);
    let chunk_len = (splats.len() / (threads * 2)).max(16384);
    let bins: Vec<Vec<Vec<u32>>> = splats
        .par_chunks(chunk_len)
        .map(|chunk| {
            let mut bands: Vec<Vec<u32>> = (0..nbands).map(|_| Vec::with_capacity(2 * chunk.len() / nbands + 16)).collect();
            for (i, s) in chunk.iter().enumerate() {
                if let Some(b) = clip(s) {
                    for band in &mut bands[b[2] as usize / BAND..=b[3] as usize / BAND] {
                        band.push(i as u32);
                    }
                }
            }
            bands
        })
        .collect();

    let band_px = BAND * w;
    frame.color.par_chunks_mut(band_px).zip(frame.depth.par_chunks_mut(band_px)).enumerate().for_each(|(band, (color, depth))| {
        let y_lo = (band * BAND) as i32;
        let y_hi = y_lo + (color.len() / w) as i32 - 1;
        for (ci, b) in bins.iter().enumerate() {
            let chunk = &splats[ci * chunk_len..];
            for &i in &b[band] {
                let s = &chunk[i as usize];
                if let Some(bb) = clip(s) {
                    draw(s, bb[0] as usize, bb[1] as usize, (bb[2].max(y_lo), bb[3].min(y_hi)), color, depth, w, y_lo);
                }
            }
        }
    });
}

/// Fills isolated background pixels (at least three of four neighbours covered) from the
/// nearest covered neighbour: cracks between thin splats, never silhouette growth.
pub fn fill_holes(frame: &mut Frame) {
    let (w, h) = (frame.width, frame.height);
    if w < 3 || h < 3 {
        return;
    }
    let mut fills = Vec::new();
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let i = y * w + x;
            if frame.depth[i].is_finite() {
                continue;
            }
            let nb = [i - 1, i + 1, i - w, i + w];
            let mut n = 0;
            let mut best = usize::MAX;
            for &j in &nb {
                if frame.depth[j].is_finite() {
                    n += 1;
                    if best == usize::MAX || frame.depth[j] < frame.depth[best] {
                        best = j;
                    }
                }
            }
            if n >= 3 {
                fills.push((i, best));
            }
        }
    }
    for (i, j) in fills {
        frame.depth[i] = frame.depth[j];
        frame.color[i] = frame.color[j];
    }
}

/// Draws one splat over columns `xa..=xb` and image rows `ya..=yb` (inside the band
/// starting at image row `y_base`).
#[inline]
#[allow(clippy::too_many_arguments)]
fn draw(s: &Splat, xa: usize, xb: usize, (ya, yb): (i32, i32), color: &mut [[u8; 4]], depth: &mut [f32], w: usize, y_base: i32) {
    let opaque = s.color[3] == 255;
    let x0 = xa as f32 + 0.5 - s.x;
    if xa == xb && ya == yb {
        // Most splats of a preview hold one pixel centre or two: no loops for those.
        let dy = ya as f32 + 0.5 - s.y;
        let (a, b) = (x0 * s.ux + dy * s.uy, dy * s.ux - x0 * s.uy);
        let i = (ya - y_base) as usize * w + xa;
        if let (Some(d), true) = (depth.get_mut(i), a * a * s.inv_a2 + b * b * s.inv_b2 <= 1.0) {
            if s.z < *d && (opaque || alpha_passes(s.color[3], xa, ya as usize)) {
                *d = s.z;
                if let Some(c) = color.get_mut(i) {
                    *c = s.color;
                }
            }
        }
        return;
    }
    for py in ya..=yb {
        let dy = py as f32 + 0.5 - s.y;
        let (ay, by) = (dy * s.uy, dy * s.ux);
        let row = (py - y_base) as usize * w;
        // Row slices: no per-pixel bounds checks.
        let (drow, crow) = (&mut depth[row + xa..=row + xb], &mut color[row + xa..=row + xb]);
        for (k, (d, c)) in drow.iter_mut().zip(crow.iter_mut()).enumerate() {
            let dx = x0 + k as f32;
            let (a, b) = (dx * s.ux + ay, by - dx * s.uy);
            if a * a * s.inv_a2 + b * b * s.inv_b2 <= 1.0 && s.z < *d && (opaque || alpha_passes(s.color[3], xa + k, py as usize)) {
                *d = s.z;
                *c = s.color;
            }
        }
    }
}

#[cfg(test)]
mod tests {
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

    #[test]
    fn fill_holes_closes_cracks_but_not_outlines() {
        let mut f = Frame::new(8, 8, [0; 4]);
        // A 4×4 square with its centre-ish pixel (3, 3) missing, and a lone pixel at (6, 6).
        for y in 2..6 {
            for x in 2..6 {
                if (x, y) != (3, 3) {
                    f.depth[y * 8 + x] = 1.0 + x as f32;
                    f.color[y * 8 + x] = [x as u8, 0, 0, 255];
                }
            }
        }
        f.depth[6 * 8 + 6] = 1.0;
        let before = f.covered();
        fill_holes(&mut f);
        assert_eq!(f.covered(), before + 1);
        // Filled from the nearest neighbour, (2, 3).
        assert_eq!((f.depth[3 * 8 + 3], f.color[3 * 8 + 3]), (3.0, [2, 0, 0, 255]));
    }

    #[test]
    fn nearest_wins_and_ties_keep_first() {
        let mut f = Frame::new(8, 8, [0; 4]);
        rasterize(
            &mut f,
            &[
                Splat::disc(4.0, 4.0, 2.0, 2.0, [1, 0, 0, 255]),
                Splat::disc(4.0, 4.0, 1.0, 1.0, [2, 0, 0, 255]),
                Splat::disc(4.0, 4.0, 1.0, 1.0, [3, 0, 0, 255]),
            ],
        );
        assert_eq!(f.color[4 * 8 + 4][0], 2);
        assert_eq!(f.color[2 * 8 + 4][0], 1);
    }

    #[test]
    fn ellipse_is_thin_along_minor_axis() {
        let mut f = Frame::new(32, 32, [0; 4]);
        rasterize(&mut f, &[Splat::ellipse(16.0, 16.0, 1.0, 8.0, 1.0, 0.0, 1.0, [5, 5, 5, 255])]);
        // Wide in x, thin in y.
        assert!(f.depth[16 * 32 + 22].is_finite());
        assert!(!f.depth[20 * 32 + 16].is_finite());
    }

    #[test]
    fn splats_across_tiles_and_clipping_are_deterministic() {
        let mut splats = Vec::new();
        let mut s = 12345u32;
        let mut rnd = || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            s as f32 / u32::MAX as f32
        };
        for i in 0..50_000 {
            let c = [(i % 251) as u8, (i % 13) as u8, 7, 255];
            splats.push(Splat::disc(rnd() * 120.0 - 10.0, rnd() * 90.0 - 10.0, (rnd() * 8.0).floor(), rnd() * 4.0, c));
        }
        let mut a = Frame::new(100, 70, [0; 4]);
        rasterize(&mut a, &splats);
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let mut b = Frame::new(100, 70, [0; 4]);
        pool.install(|| rasterize(&mut b, &splats));
        assert_eq!(a, b);
    }
}
