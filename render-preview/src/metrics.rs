//! Image comparison of a splat render with its mesh reference: PSNR and SSIM over the
//! foreground (the union of the pixels either image covers; background pixels are left
//! out, so an empty pair is not a perfect score), silhouette IoU, missing, extra and hole
//! pixels, and a difference image. `spec/render-preview-json.md` documents the fields.

use crate::raster::Frame;

/// Which of the compared images covers no pixel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Empty {
    /// The splat render is empty.
    Test,
    /// The mesh reference is empty.
    Reference,
    /// Both are.
    Both,
}

/// How a splat render compares with its mesh reference.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Metrics {
    /// PSNR over the RGB channels of the foreground pixels (covered by either image), dB;
    /// 99 when they are identical. `None` when either image is empty.
    pub fg_psnr_db: Option<f64>,
    /// SSIM of luma over the foreground (see [`fg_ssim`] for the rule). `None` when either
    /// image is empty.
    pub fg_ssim: Option<f64>,
    /// Foreground pixels: covered by either image.
    pub fg_pixels: u64,
    /// Intersection over union of the covered-pixel masks (0 when both are empty).
    pub silhouette_iou: f64,
    /// Fraction of reference-covered pixels that the splats leave uncovered while at least
    /// three of their four neighbours are covered: holes, not silhouette erosion.
    pub hole_fraction: f64,
    /// Fraction of reference-covered pixels the splats leave uncovered (any reason).
    pub missing_fraction: f64,
    /// Fraction of splat-covered pixels the reference does not cover (silhouette growth).
    pub extra_fraction: f64,
    /// Pixels covered by the reference.
    pub reference_pixels: u64,
    /// Pixels covered by the splat render.
    pub test_pixels: u64,
    /// Set when an image is empty: the comparison is then not scored.
    pub empty: Option<Empty>,
}

/// PSNR of a summed squared error over `n` pixels × 3 channels, capped at 99 dB.
fn psnr(se: f64, n: u64) -> f64 {
    let mse = se / (n.max(1) as f64 * 3.0);
    if mse <= 0.0 {
        99.0
    } else {
        (10.0 * (255.0f64 * 255.0 / mse).log10()).min(99.0)
    }
}

/// Compares `test` with `reference` (same size).
pub fn compare(test: &Frame, reference: &Frame) -> Metrics {
    assert_eq!((test.width, test.height), (reference.width, reference.height), "frames must have the same size");
    let (w, h) = (test.width, test.height);
    let ct = test.coverage();
    let cr = reference.coverage();
    let mut se_fg = 0f64;
    let (mut inter, mut uni, mut holes, mut missing, mut extra, mut nref, mut ntest) = (0u64, 0u64, 0u64, 0u64, 0u64, 0u64, 0u64);
    let mut fg = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            if ct[i] || cr[i] {
                se_fg += (0..3).map(|k| (test.color[i][k] as f64 - reference.color[i][k] as f64).powi(2)).sum::<f64>();
                uni += 1;
                fg[i] = true;
            }
            if ct[i] {
                ntest += 1;
            }
            if ct[i] && cr[i] {
                inter += 1;
            }
            if cr[i] {
                nref += 1;
                if !ct[i] {
                    missing += 1;
                    let nb = [(x > 0).then(|| i - 1), (x + 1 < w).then(|| i + 1), (y > 0).then(|| i - w), (y + 1 < h).then(|| i + w)];
                    if nb.iter().filter(|n| n.is_some_and(|j| ct[j])).count() >= 3 {
                        holes += 1;
                    }
                }
            } else if ct[i] {
                extra += 1;
            }
        }
    }
    let frac = |a: u64, b: u64| if b == 0 { 0.0 } else { a as f64 / b as f64 };
    let empty = match (ntest == 0, nref == 0) {
        (true, true) => Some(Empty::Both),
        (true, false) => Some(Empty::Test),
        (false, true) => Some(Empty::Reference),
        (false, false) => None,
    };
    let scored = empty.is_none();
    Metrics {
        fg_psnr_db: scored.then(|| psnr(se_fg, uni)),
        fg_ssim: if scored { fg_ssim(test, reference, &fg) } else { None },
        fg_pixels: uni,
        silhouette_iou: frac(inter, uni),
        hole_fraction: frac(holes, nref),
        missing_fraction: frac(missing, nref),
        extra_fraction: frac(extra, ntest),
        reference_pixels: nref,
        test_pixels: ntest,
        empty,
    }
}

fn luma(f: &Frame) -> Vec<f64> {
    f.color.iter().map(|c| 0.299 * c[0] as f64 + 0.587 * c[1] as f64 + 0.114 * c[2] as f64).collect()
}

/// SSIM window side, pixels.
pub const SSIM_WINDOW: usize = 8;
/// SSIM window stride, pixels.
pub const SSIM_STRIDE: usize = 4;

/// Window origins along a side of `n` pixels: every `SSIM_STRIDE` from 0, plus one flush
/// with the far edge so that every pixel is in some window (one origin 0 when the side is
/// shorter than a window, whose window is clipped).
fn window_starts(n: usize) -> Vec<usize> {
    if n <= SSIM_WINDOW {
        return vec![0];
    }
    let last = n - SSIM_WINDOW;
    let mut v: Vec<usize> = (0..=last).step_by(SSIM_STRIDE).collect();
    if v.last() != Some(&last) {
        v.push(last);
    }
    v
}

/// Foreground SSIM of luma: over the `SSIM_WINDOW`² windows at stride `SSIM_STRIDE` (plus
/// windows flush with the right and bottom edges), each window's SSIM (K1 = 0.01,
/// K2 = 0.03, L = 255) is computed from the means, population variances and covariance of
/// its foreground pixels (`mask`) only, and the result is the mean of the window values
/// weighted by each window's count of foreground pixels. Windows without foreground do not
/// count. `None` when `mask` is empty.
pub fn fg_ssim(a: &Frame, b: &Frame, mask: &[bool]) -> Option<f64> {
    let (w, h) = (a.width, a.height);
    let (la, lb) = (luma(a), luma(b));
    let c1 = (0.01f64 * 255.0).powi(2);
    let c2 = (0.03f64 * 255.0).powi(2);
    let (mut total, mut weight) = (0.0, 0u64);
    let (xs, ys) = (window_starts(w), window_starts(h));
    for &y in &ys {
        for &x in &xs {
            let (mut sa, mut sb, mut saa, mut sbb, mut sab, mut m) = (0.0, 0.0, 0.0, 0.0, 0.0, 0u64);
            for yy in y..(y + SSIM_WINDOW).min(h) {
                for xx in x..(x + SSIM_WINDOW).min(w) {
                    let i = yy * w + xx;
                    if !mask[i] {
                        continue;
                    }
                    let (p, q) = (la[i], lb[i]);
                    sa += p;
                    sb += q;
                    saa += p * p;
                    sbb += q * q;
                    sab += p * q;
                    m += 1;
                }
            }
            if m == 0 {
                continue;
            }
            let n = m as f64;
            let (ma, mb) = (sa / n, sb / n);
            // Rounding can make a zero variance slightly negative.
            let va = (saa / n - ma * ma).max(0.0);
            let vb = (sbb / n - mb * mb).max(0.0);
            let cov = sab / n - ma * mb;
            let s = ((2.0 * ma * mb + c1) * (2.0 * cov + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2));
            total += n * s;
            weight += m;
        }
    }
    (weight > 0).then(|| total / weight as f64)
}

/// Difference image: |test − reference| × 4 in grey, with coverage disagreements marked
/// (red: splats only, blue: reference only).
pub fn difference_image(test: &Frame, reference: &Frame) -> image::RgbImage {
    let (w, h) = (test.width, test.height);
    let mut buf = Vec::with_capacity(w * h * 3);
    for i in 0..w * h {
        let (ct, cr) = (test.depth[i].is_finite(), reference.depth[i].is_finite());
        let px = match (ct, cr) {
            (true, false) => [255, 40, 40],
            (false, true) => [40, 80, 255],
            _ => {
                let d = (0..3).map(|k| (test.color[i][k] as i32 - reference.color[i][k] as i32).unsigned_abs()).max().unwrap_or(0);
                let g = (d * 4).min(255) as u8;
                [g, g, g]
            }
        };
        buf.extend_from_slice(&px);
    }
    image::RgbImage::from_raw(w as u32, h as u32, buf).unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame_with(n: usize, bg: [u8; 4]) -> Frame {
        let mut f = Frame::new(16, 16, bg);
        for i in 0..n {
            f.color[i] = [200, 100, i as u8, 255];
            f.depth[i] = 1.0;
        }
        f
    }

    #[test]
    fn identical_frames_score_perfectly() {
        let f = frame_with(100, [0, 0, 0, 255]);
        let m = compare(&f, &f);
        assert_eq!(m.fg_psnr_db, Some(99.0));
        assert!((m.fg_ssim.unwrap() - 1.0).abs() < 1e-9);
        assert_eq!(m.silhouette_iou, 1.0);
        assert_eq!(m.hole_fraction, 0.0);
        assert_eq!((m.fg_pixels, m.test_pixels, m.reference_pixels, m.empty), (100, 100, 100, None));
    }

    /// Regression: two empty images scored 65 dB and SSIM 1.0 over their identical
    /// background; an empty image is now reported, not scored.
    #[test]
    fn empty_images_are_reported_not_scored() {
        let bg = [24, 24, 28, 255];
        let empty = Frame::new(16, 16, bg);
        let full = frame_with(50, bg);
        for (t, r, e) in [(&empty, &empty, Empty::Both), (&empty, &full, Empty::Test), (&full, &empty, Empty::Reference)] {
            let m = compare(t, r);
            assert_eq!(m.empty, Some(e));
            assert_eq!((m.fg_psnr_db, m.fg_ssim), (None, None), "{m:?}");
            assert_eq!(m.silhouette_iou, 0.0);
        }
    }

    /// An 8×5 object at the top left of a `side`² frame; `flip` inverts its texture.
    fn object(side: usize, flip: bool) -> Frame {
        let mut f = Frame::new(side, side, [0, 0, 0, 255]);
        for y in 0..5 {
            for x in 0..8 {
                let v = if ((x + y) % 2 == 0) != flip { 220 } else { 40 };
                f.color[y * side + x] = [v, v, v, 255];
                f.depth[y * side + x] = 1.0;
            }
        }
        f
    }

    /// The background does not dilute the score: the same wrong object scores the same in
    /// a small frame and in a large one (the old whole-frame PSNR rose with the frame).
    #[test]
    fn background_is_left_out() {
        let small = compare(&object(16, true), &object(16, false));
        let large = compare(&object(64, true), &object(64, false));
        // Every pixel off by 180 in all channels.
        let expect = 10.0 * (255.0f64 * 255.0 / (180.0 * 180.0)).log10();
        assert!((small.fg_psnr_db.unwrap() - expect).abs() < 1e-9, "{small:?}");
        assert_eq!(small.fg_psnr_db, large.fg_psnr_db);
        assert!((small.fg_ssim.unwrap() - large.fg_ssim.unwrap()).abs() < 1e-12);
        assert!(small.fg_ssim.unwrap() < 0.0, "inverted texture: {small:?}");
        // A pixel only one image covers counts, with the other's background colour.
        let r = object(16, false);
        let mut grown = r.clone();
        grown.color[200] = [220, 220, 220, 255];
        grown.depth[200] = 1.0;
        let m = compare(&grown, &r);
        assert_eq!(m.fg_pixels, 41);
        assert!(m.fg_psnr_db.unwrap() < 99.0 && (m.extra_fraction - 1.0 / 41.0).abs() < 1e-12, "{m:?}");
    }

    #[test]
    fn ssim_windows_reach_every_edge() {
        assert_eq!(window_starts(16), vec![0, 4, 8]);
        assert_eq!(window_starts(18), vec![0, 4, 8, 10]);
        assert_eq!(window_starts(5), vec![0]);
        // A foreground pixel in the last column still counts.
        let bg = [0, 0, 0, 255];
        let mut r = Frame::new(18, 9, bg);
        r.color[17] = [255, 255, 255, 255];
        r.depth[17] = 1.0;
        let mut t = r.clone();
        t.color[17] = [0, 0, 0, 255];
        assert!(compare(&t, &r).fg_ssim.unwrap() < 0.1);
    }

    #[test]
    fn a_hole_is_detected() {
        let mut r = Frame::new(8, 8, [0; 4]);
        r.depth.iter_mut().for_each(|d| *d = 1.0);
        let mut t = r.clone();
        t.depth[3 * 8 + 3] = f32::INFINITY;
        let m = compare(&t, &r);
        assert!((m.hole_fraction - 1.0 / 64.0).abs() < 1e-12);
        assert!((m.silhouette_iou - 63.0 / 64.0).abs() < 1e-12);
    }
}
