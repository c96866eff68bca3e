//! The default (`zbuffer`) method's frame, from splats to pixels: the depth test
//! (translucent splats blended), cracks closed, and `s × s` subpixels resolved into a pixel
//! as the mesh reference resolves its own. The reference draws point clouds through the
//! same steps, so that a lossless tree of a point cloud matches its reference.

use crate::raster::{fill_depth_pits, fill_holes, rasterize_blended, Frame, Splat};
use crate::shade;

/// Draws `splats` into `sub` (`s × s` subpixels a pixel, already holding what was drawn
/// before them), and returns the resolved frame with its cracks closed: between thin splats
/// at the subpixel level, a pixel wide after resolving (three subpixels wide, past what the
/// first fill closes: 0.05 % of spot's pixels stayed background, costing it 2 dB), and depth
/// pits, where a farther surface shows through a crack of a nearer one (BENCHMARKS.md,
/// "Where every method fails"; covered, so the hole fill leaves them).
pub fn zbuffer_frame(mut sub: Frame, splats: &[Splat], s: usize, bg: [u8; 4]) -> Frame {
    rasterize_blended(&mut sub, splats);
    fill_holes(&mut sub);
    let mut frame = if s > 1 {
        let mut frame = resolve(&sub, s, bg);
        fill_holes(&mut frame);
        frame
    } else {
        sub
    };
    fill_depth_pits(&mut frame);
    frame
}

/// One pixel per `s × s` block of `sub` (`s` odd): covered exactly when its middle
/// subpixel, the pixel's centre, is (so silhouettes, coverage, IoU and holes are those of
/// one sample per pixel, a hard edge as the previews draw it), with that subpixel's depth
/// and the mean colour of the block's covered subpixels in linear light; the background
/// elsewhere.
pub fn resolve(sub: &Frame, s: usize, bg: [u8; 4]) -> Frame {
    let (w, h) = (sub.width / s, sub.height / s);
    let lin = shade::srgb_to_linear_lut();
    let mut out = Frame::new(w, h, bg);
    for y in 0..h {
        for x in 0..w {
            let centre = (y * s + s / 2) * sub.width + x * s + s / 2;
            if !sub.depth[centre].is_finite() {
                continue;
            }
            let (mut n, mut sum) = (0usize, [0f32; 3]);
            for sy in 0..s {
                let row = (y * s + sy) * sub.width + x * s;
                for i in row..row + s {
                    if sub.depth[i].is_finite() {
                        n += 1;
                        for (acc, &c) in sum.iter_mut().zip(&sub.color[i][..3]) {
                            *acc += lin[c as usize];
                        }
                    }
                }
            }
            let i = y * w + x;
            out.depth[i] = sub.depth[centre];
            let [r, g, b] = sum.map(|c| shade::linear_to_srgb8(c / n as f32));
            out.color[i] = [r, g, b, 255];
        }
    }
    out
}
