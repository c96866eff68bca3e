//! Image comparison: PSNR, SSIM (luma, 8×8 box windows), silhouette IoU, hole pixels and
//! a difference image.

use crate::raster::Frame;

/// How a splat render compares with its mesh reference.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Metrics {
    /// PSNR over all pixels and RGB channels, dB (∞ when identical, capped at 99).
    pub psnr_db: f64,
    /// PSNR over the pixels covered by either image only, dB.
    pub psnr_covered_db: f64,
    /// Mean SSIM of the luma channel over 8×8 windows (stride 4).
    pub ssim: f64,
    /// Intersection over union of the covered-pixel masks.
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
}

fn psnr(se: f64, n: u64) -> f64 {
    if n == 0 {
        return 99.0;
    }
    let mse = se / (n as f64 * 3.0);
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
    let (mut se_all, mut se_cov, mut n_cov) = (0f64, 0f64, 0u64);
    let (mut inter, mut uni, mut holes, mut missing, mut extra, mut nref, mut ntest) = (0u64, 0u64, 0u64, 0u64, 0u64, 0u64, 0u64);
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let e: f64 = (0..3).map(|k| (test.color[i][k] as f64 - reference.color[i][k] as f64).powi(2)).sum();
            se_all += e;
            if ct[i] || cr[i] {
                se_cov += e;
                n_cov += 1;
                uni += 1;
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
    Metrics {
        psnr_db: psnr(se_all, (w * h) as u64),
        psnr_covered_db: psnr(se_cov, n_cov),
        ssim: ssim(test, reference),
        silhouette_iou: if uni == 0 { 1.0 } else { inter as f64 / uni as f64 },
        hole_fraction: frac(holes, nref),
        missing_fraction: frac(missing, nref),
        extra_fraction: frac(extra, ntest),
        reference_pixels: nref,
    }
}

fn luma(f: &Frame) -> Vec<f64> {
    f.color.iter().map(|c| 0.299 * c[0] as f64 + 0.587 * c[1] as f64 + 0.114 * c[2] as f64).collect()
}

/// Mean SSIM of luma over 8×8 windows with stride 4 (standard constants K1 = 0.01,
/// K2 = 0.03, L = 255); 1.0 for images smaller than a window that are identical.
pub fn ssim(a: &Frame, b: &Frame) -> f64 {
    let (w, h) = (a.width, a.height);
    let (la, lb) = (luma(a), luma(b));
    const WIN: usize = 8;
    let c1 = (0.01f64 * 255.0).powi(2);
    let c2 = (0.03f64 * 255.0).powi(2);
    let (mut total, mut count) = (0.0, 0u64);
    let mut y = 0;
    while y + WIN <= h {
        let mut x = 0;
        while x + WIN <= w {
            let (mut sa, mut sb, mut saa, mut sbb, mut sab) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for dy in 0..WIN {
                for dx in 0..WIN {
                    let i = (y + dy) * w + x + dx;
                    let (p, q) = (la[i], lb[i]);
                    sa += p;
                    sb += q;
                    saa += p * p;
                    sbb += q * q;
                    sab += p * q;
                }
            }
            let n = (WIN * WIN) as f64;
            let (ma, mb) = (sa / n, sb / n);
            let va = saa / n - ma * ma;
            let vb = sbb / n - mb * mb;
            let cov = sab / n - ma * mb;
            total += ((2.0 * ma * mb + c1) * (2.0 * cov + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2));
            count += 1;
            x += 4;
        }
        y += 4;
    }
    if count == 0 {
        return if la == lb { 1.0 } else { 0.0 };
    }
    total / count as f64
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

    #[test]
    fn identical_frames_score_perfectly() {
        let mut f = Frame::new(16, 16, [0, 0, 0, 255]);
        for i in 0..100 {
            f.color[i] = [200, 100, i as u8, 255];
            f.depth[i] = 1.0;
        }
        let m = compare(&f, &f);
        assert_eq!(m.psnr_db, 99.0);
        assert!((m.ssim - 1.0).abs() < 1e-9);
        assert_eq!(m.silhouette_iou, 1.0);
        assert_eq!(m.hole_fraction, 0.0);
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
