//! Passes over a drawn frame that close cracks: background pixels inside a surface
//! ([`fill_holes`]) and pits through which a farther surface shows ([`fill_depth_pits`]).

use super::Frame;

/// Fills isolated background pixels from the nearest covered neighbour: cracks between thin
/// splats, never silhouette growth. A pixel is filled when at least three of its four edge
/// neighbours and seven of all eight neighbours are covered. The edge test alone also filled
/// the notches of an outline's staircase (a notch has three edge neighbours covered but at
/// most six of eight): that grew outlines on the reference's background and cost 0.4–0.6 dB
/// of foreground PSNR on models with long outlines (spot's control mesh, the sphere grid).
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
            if n >= 3 && n + [i - w - 1, i - w + 1, i + w - 1, i + w + 1].iter().filter(|&&j| frame.depth[j].is_finite()).count() >= 7 {
                fills.push((i, best));
            }
        }
    }
    for (i, j) in fills {
        frame.depth[i] = frame.depth[j];
        frame.color[i] = frame.color[j];
    }
}

/// Depth pits narrower than a pixel's neighbourhood, as a share of depth: a covered pixel
/// whose depth lies this far behind all four of its neighbours shows a farther surface
/// through a crack of the nearer one (2 · 10⁻³: about three pixel footprints at the default
/// 1280-pixel, 40° view; a smooth surface has nearer neighbours on one side only).
pub const PIT_DEPTH: f32 = 2e-3;

/// Closes cracks through which a farther surface shows (the holes [`fill_holes`] cannot see,
/// as the crack pixel is covered): each covered pixel lying more than [`PIT_DEPTH`] of its
/// depth behind all four of its neighbours takes the nearest neighbour's colour and depth.
/// Three of four would close more of a crack (the plates of BENCHMARKS.md: 0.1–1.0 % of the
/// front plate dark) but also eats single pixels of a farther model seen
/// between nearer ones (0.1 dB and 0.01 SSIM on the 30 × 30 grid and the 8³ block); all four
/// leaves those scenes within 0.02 dB. Returns the pixels filled.
pub fn fill_depth_pits(frame: &mut Frame) -> usize {
    let (w, h) = (frame.width, frame.height);
    if w < 3 || h < 3 {
        return 0;
    }
    let mut fills = Vec::new();
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let i = y * w + x;
            let d = frame.depth[i];
            if !d.is_finite() {
                continue;
            }
            let far = d * (1.0 - PIT_DEPTH);
            let mut n = 0;
            let mut best = i;
            for j in [i - 1, i + 1, i - w, i + w] {
                if frame.depth[j] < far {
                    n += 1;
                    if frame.depth[j] < frame.depth[best] {
                        best = j;
                    }
                }
            }
            if n == 4 {
                fills.push((i, best));
            }
        }
    }
    for &(i, j) in &fills {
        frame.depth[i] = frame.depth[j];
        frame.color[i] = frame.color[j];
    }
    fills.len()
}

#[cfg(test)]
mod tests {
    use super::*;

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

    /// The notch of a staircase outline (three edge neighbours covered, the outside
    /// diagonals not) stays background: filling it grows the outline.
    #[test]
    fn fill_holes_leaves_outline_notches() {
        let mut f = Frame::new(8, 8, [0; 4]);
        // Columns 0-3 of rows 1-6 covered, row 3 to x = 5 and row 5 to x = 4: (4, 4) is a
        // notch with its left, upper and lower neighbours covered, its right-hand ones not.
        let covered = |x: usize, y: usize| x < 4 || (y == 3 && x < 6) || (y == 5 && x < 5);
        for y in 1..7 {
            for x in 0..8 {
                if covered(x, y) {
                    f.depth[y * 8 + x] = 1.0;
                }
            }
        }
        let notch = 4 * 8 + 4;
        assert!(!f.depth[notch].is_finite() && f.depth[notch - 1].is_finite() && f.depth[notch - 8].is_finite() && f.depth[notch + 8].is_finite());
        let before = f.covered();
        fill_holes(&mut f);
        assert_eq!(f.covered(), before, "an outline notch was filled");
    }

    #[test]
    fn depth_pits_take_the_nearer_surface_but_slopes_do_not() {
        let mut f = Frame::new(8, 8, [0; 4]);
        // A near plane at depth 1 with one pixel showing a plane at 1.05 behind it, and a
        // ramp (row 6) whose pixels step back by 1 % each: nearer on one side only.
        for i in 0..64 {
            f.depth[i] = 1.0;
            f.color[i] = [200, 0, 0, 255];
        }
        f.depth[3 * 8 + 3] = 1.05;
        f.color[3 * 8 + 3] = [0, 0, 9, 255];
        for x in 0..8 {
            f.depth[6 * 8 + x] = 1.0 + 0.01 * x as f32;
        }
        let before = f.clone();
        assert_eq!(fill_depth_pits(&mut f), 1);
        assert_eq!((f.depth[3 * 8 + 3], f.color[3 * 8 + 3]), (1.0, [200, 0, 0, 255]));
        assert_eq!(f.depth[6 * 8..7 * 8], before.depth[6 * 8..7 * 8]);
    }
}
