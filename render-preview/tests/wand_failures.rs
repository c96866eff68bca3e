//! Where `wand` fails (Wand et al. §2, §5.1.2, §5.2, §5.3; preview-methods.md C4): each
//! documented failure mode gets a scene, a measurement, and the behaviour it shows asserted
//! with the bound measured when the test was written. Every frame here samples every leaf
//! (`large = ∞`) so that the random part of the method is what is measured; each
//! measurement is printed (`--nocapture`).

mod common;
use common::{shared};

use std::path::{Path, PathBuf};

use render_preview::reference::{render_reference, WorldMesh};
use render_preview::{metrics, render_file, synth, Frame, Method, RenderOptions, Shading, View, WandOptions};
use sct_format::write::WriteOptions;

fn luma(c: [u8; 4]) -> f64 {
    0.299 * c[0] as f64 + 0.587 * c[1] as f64 + 0.114 * c[2] as f64
}

fn sampled(o: RenderOptions, d: u32) -> RenderOptions {
    RenderOptions { method: Method::Wand, wand: WandOptions { d, large: f32::INFINITY, ..WandOptions::default() }, ..o }
}

/// Fraction of the pixels where `refr` shows white (luma ≥ 250, and 2 px around too) that
/// `f` shows dark (luma drop > 64).
fn dark_in_white(f: &Frame, refr: &Frame) -> f64 {
    let (w, h) = (f.width, f.height);
    let white = |x: usize, y: usize| luma(refr.color[y * w + x]) >= 250.0;
    let (mut dark, mut n) = (0usize, 0usize);
    for y in 2..h - 2 {
        for x in 2..w - 2 {
            if white(x, y) && white(x - 2, y) && white(x + 2, y) && white(x, y - 2) && white(x, y + 2) {
                dark += (255.0 - luma(f.color[y * w + x]) > 64.0) as usize;
                n += 1;
            }
        }
    }
    assert!(n > 100, "too few interior pixels: {n}");
    dark as f64 / n as f64
}

fn write(mesh: &WorldMesh, spacing: f32, dir: &Path, name: &str) -> PathBuf {
    let p = dir.join(name);
    synth::write_mesh_sct(mesh, spacing, &p, &WriteOptions::default()).unwrap();
    p
}

/// A square of half-side `h` at depth `z` facing +z (corners counter-clockwise from +z), or
/// facing −z with `back`.
fn quad(z: f32, h: f32, back: bool) -> [[f32; 3]; 4] {
    let q = [[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]];
    if back {
        [q[0], q[3], q[2], q[1]]
    } else {
        q
    }
}

/// Near-parallel surfaces (§5.1.2, "the hidden surface B might shine through with up to
/// 50 % probability"): a white plate over a black one `gap` behind, both facing the eye,
/// seen at 60° from 3 units, leaves of 0.01 (≈ 0.5 px), 200², flat shading; the fraction of
/// the white plate's interior showing black, for gaps of 0.1 %, 1 % and 10 % of the
/// distance, d = 1 and 2, against `zbuffer`. Measured when set:
///
/// | gap | d = 1 | d = 2 | zbuffer |
/// |---|---|---|---|
/// | 0.1 % | 1.68 % | 10.57 % | 99.93 % (internal splats merge both plates) |
/// | 1 % | 0 | 0 | 5.11 % (cracks between splats) |
/// | 10 % | 0 | 0 | 5.07 % |
///
/// A d × d square carries one depth over d pixels of a slanted plate, so the far plate wins
/// where its square is nearer than the near plate's: the leak grows with d. Bounds: at
/// 0.1 % between 0.5 and 5 % (d = 1) and 5 and 20 % (d = 2); at 1 % and 10 % under 0.1 %.
#[test]
fn near_parallel_surfaces_shine_through() {
    let dir = tempfile::tempdir().unwrap();
    let (sn, cs) = 60f64.to_radians().sin_cos();
    let opts = RenderOptions {
        width: 200,
        height: 200,
        shading: Shading::Flat,
        eye: Some([0.0, 3.0 * sn, 3.0 * cs]),
        target: Some([0.0; 3]),
        background: [0, 0, 0],
        ..RenderOptions::default()
    };
    for rel in [0.001f32, 0.01, 0.1] {
        let gap = 3.0 * rel;
        let mesh = synth::quads(&[(quad(0.0, 1.0, false), [1.0; 4]), (quad(-gap, 1.5, false), [0.0, 0.0, 0.0, 1.0])]);
        let sct = write(&mesh, 0.01, dir.path(), &format!("p{rel}.sct"));
        let z = render_file(&sct, &opts).unwrap();
        let refr = render_reference(&mesh, &View::new(&z.camera, z.near).unwrap(), opts.shading, opts.background);
        let d1 = dark_in_white(&render_file(&sct, &sampled(opts.clone(), 1)).unwrap().frame, &refr);
        let d2 = dark_in_white(&render_file(&sct, &sampled(opts.clone(), 2)).unwrap().frame, &refr);
        let zb = dark_in_white(&z.frame, &refr);
        eprintln!("gap {:.1} % of the distance: black shows through on {:.2} % (d=1), {:.2} % (d=2), zbuffer {:.2} %", rel * 100.0, d1 * 100.0, d2 * 100.0, zb * 100.0);
        if rel < 0.005 {
            assert!((0.005..0.05).contains(&d1) && (0.05..0.2).contains(&d2) && d2 > d1, "gap {rel}: {d1} {d2}");
        } else {
            assert!(d1 < 0.001 && d2 < 0.001, "gap {rel}: {d1} {d2}");
        }
    }
}

/// Fuzzy silhouettes (§5.1.2: "This situation leads only to 'fuzzy' object boundaries"):
/// the bunny (res2, leaves r/200) at 384² on the dark background, every leaf sampled, d = 1,
/// 2, 4 against the mesh: a sample colours the whole pixel (or d × d square) it falls in,
/// so the outline grows by about d/2 px while nothing goes missing. Measured when set
/// (IoU / extra / missing fraction of the reference's pixels): zbuffer 0.9966 / 0.0023 /
/// 0.0011; d = 1 0.9878 / 0.0122 / 0; d = 2 0.9771 / 0.0229 / 0; d = 4 0.9561 / 0.0439 / 0.
/// Bounds: extra grows with d and stays under 0.016 / 0.03 / 0.055; missing under 0.002.
#[test]
fn silhouettes_grow_with_the_square() {
    let Some(path) = shared("scans/stanford-bunny-original-ply/bun_zipper_res2.ply") else { return };
    let mesh = WorldMesh::load(&path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (_, r) = mesh.bound().unwrap();
    let sct = write(&mesh, (r / 200.0) as f32, dir.path(), "b.sct");
    let base = RenderOptions { width: 384, height: 384, ..RenderOptions::default() };
    let z = render_file(&sct, &base).unwrap();
    let refr = render_reference(&mesh, &View::new(&z.camera, z.near).unwrap(), base.shading, base.background);
    let zm = metrics::compare(&z.frame, &refr);
    eprintln!("zbuffer: IoU {:.4} extra {:.4} missing {:.4}", zm.silhouette_iou, zm.extra_fraction, zm.missing_fraction);
    let mut last = zm.extra_fraction;
    for (d, max_extra) in [(1, 0.016), (2, 0.03), (4, 0.055)] {
        let m = metrics::compare(&render_file(&sct, &sampled(base.clone(), d)).unwrap().frame, &refr);
        eprintln!("d = {d}: IoU {:.4} extra {:.4} missing {:.4}", m.silhouette_iou, m.extra_fraction, m.missing_fraction);
        assert!(m.extra_fraction > last && m.extra_fraction < max_extra && m.missing_fraction < 0.002, "d {d}: {m:?}");
        last = m.extra_fraction;
    }
}

/// Thin two-sided objects (§5.1.2: "These have dark backsides which can leak through if the
/// relative distance to the camera is large enough"; the cure is back-face culling, fig. 6):
/// a leaf plate, white on the front and black on the back (two quads 0.002 apart, facing
/// away from each other), seen at 60° from 2, 4, 8 and 16 units at 200², flat shading, d = 2,
/// with back-face culling on and off. Measured when set (black fraction of the white
/// interior): with culling 0 at every distance; without, 0.95 / 1.09 / 1.20 / 1.18 % at 2 /
/// 4 / 8 / 16 (the back's samples win where a square of the back is nearer than the front's
/// squares over it). Bounds: under 0.1 % with culling, over 0.3 % without.
#[test]
fn dark_backsides_leak_without_back_face_culling() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = synth::quads(&[(quad(0.0, 1.0, false), [1.0; 4]), (quad(-0.002, 1.0, true), [0.0, 0.0, 0.0, 1.0])]);
    let sct = write(&mesh, 0.01, dir.path(), "leaf.sct");
    let (sn, cs) = 60f64.to_radians().sin_cos();
    for dist in [2.0, 4.0, 8.0, 16.0] {
        let opts = RenderOptions {
            width: 200,
            height: 200,
            shading: Shading::Flat,
            eye: Some([0.0, dist * sn, dist * cs]),
            target: Some([0.0; 3]),
            fov_y_deg: 40.0 * 2.0 / dist,
            background: [0, 0, 0],
            ..RenderOptions::default()
        };
        let on = render_file(&sct, &sampled(opts.clone(), 2)).unwrap();
        let refr = render_reference(&mesh, &View::new(&on.camera, on.near).unwrap(), opts.shading, opts.background);
        let off = render_file(&sct, &sampled(RenderOptions { backface_culling: false, ..opts.clone() }, 2)).unwrap();
        let (a, b) = (dark_in_white(&on.frame, &refr), dark_in_white(&off.frame, &refr));
        eprintln!("distance {dist}: black on {:.2} % with culling, {:.2} % without", a * 100.0, b * 100.0);
        assert!(a < 0.001, "culling on, distance {dist}: {a}");
        assert!(b > 0.003, "culling off, distance {dist}: {b}");
    }
}

/// Large squares on fine detail (§5.2: d > 2 "may lead to objectionable visual
/// artifacts"): black and white stripes ≈ 5 px wide facing the eye, 240 × 240, d = 1, 2, 4,
/// 8, against the mesh. Measured when set (PSNR dB, full-contrast edges every 5 px):
/// zbuffer 12.60 (its white splats bleed into the black stripes), d = 1 13.09, d = 2 10.06,
/// d = 4 6.99, d = 8 4.01. Bounds: PSNR falls with d; d = 1 at least 12.1 dB, d = 4 at
/// least 5 dB below it, d = 8 at most 5 dB.
#[test]
fn large_squares_blur_fine_detail() {
    let dir = tempfile::tempdir().unwrap();
    // 40 stripes across 2 units: at 240 px wide and the camera below, 3 px each.
    let n = 40;
    let w = 2.0 / n as f32;
    let stripes: Vec<_> = (0..n)
        .map(|i| {
            let x0 = -1.0 + i as f32 * w;
            let c = if i % 2 == 0 { [1.0; 4] } else { [0.0, 0.0, 0.0, 1.0] };
            ([[x0, -1.0, 0.0], [x0 + w, -1.0, 0.0], [x0 + w, 1.0, 0.0], [x0, 1.0, 0.0]], c)
        })
        .collect();
    let mesh = synth::quads(&stripes);
    let sct = write(&mesh, 0.005, dir.path(), "stripes.sct");
    let fov = 2.0 * (1.0f64 / 2.4).atan().to_degrees() * 1.2;
    let opts = RenderOptions { width: 240, height: 240, shading: Shading::Flat, eye: Some([0.0, 0.0, 2.4]), target: Some([0.0; 3]), fov_y_deg: fov, ..RenderOptions::default() };
    let z = render_file(&sct, &opts).unwrap();
    let refr = render_reference(&mesh, &View::new(&z.camera, z.near).unwrap(), opts.shading, opts.background);
    eprintln!("zbuffer: {:.2} dB", metrics::compare(&z.frame, &refr).fg_psnr_db.unwrap());
    let mut psnr = Vec::new();
    for d in [1, 2, 4, 8] {
        let m = metrics::compare(&render_file(&sct, &sampled(opts.clone(), d)).unwrap().frame, &refr);
        let p = m.fg_psnr_db.unwrap();
        eprintln!("d = {d}: {p:.2} dB");
        assert!(psnr.last().is_none_or(|&l| p < l), "d {d}: {p} after {psnr:?}");
        psnr.push(p);
    }
    assert!(psnr[0] >= 12.1 && psnr[2] <= psnr[0] - 5.0 && psnr[3] <= 5.0, "{psnr:?}");
}

/// No occlusion culling (§2: the cost is linear in projected area, hidden area included):
/// k plates stacked 0.2 apart behind a front plate, all facing the eye, 160²; the samples
/// drawn grow with k while the covered pixels do not. Measured when set (samples per
/// covered pixel for 1, 2, 4, 8 plates): 2.4, 4.6, 8.5, 14.6 over 12,520 ± 10 covered
/// pixels (the plates behind are farther, so each adds a little less). Bounds: with n plates
/// at least 0.6 n times the single plate's samples, covered pixels within 1 %.
#[test]
fn hidden_area_costs_samples() {
    let dir = tempfile::tempdir().unwrap();
    let opts = RenderOptions { width: 160, height: 160, shading: Shading::Flat, eye: Some([0.0, 0.0, 4.0]), target: Some([0.0; 3]), ..RenderOptions::default() };
    let mut per = Vec::new();
    let mut covered = Vec::new();
    for k in [0usize, 1, 3, 7] {
        let quads: Vec<_> = (0..=k).map(|i| (quad(-0.2 * i as f32, 1.0, false), [1.0; 4])).collect();
        let sct = write(&synth::quads(&quads), 0.02, dir.path(), &format!("stack{k}.sct"));
        let out = render_file(&sct, &sampled(opts.clone(), 2)).unwrap();
        let s = out.stats.wand.unwrap();
        eprintln!("{} plates: {} samples, {:.1} per covered pixel, {} covered", k + 1, s.samples, s.samples_per_covered_pixel, out.stats.covered_pixels);
        per.push((k + 1, s.samples as f64));
        covered.push(out.stats.covered_pixels as f64);
    }
    for &(n, samples) in &per[1..] {
        assert!(samples >= 0.6 * n as f64 * per[0].1, "{per:?}");
    }
    assert!(covered.iter().all(|c| (c / covered[0] - 1.0).abs() < 0.01), "{covered:?}");
}

/// PSNR (dB, luma) of `f` against `g` over the pixels `keep` selects.
fn psnr_where(f: &Frame, g: &Frame, keep: impl Fn(usize) -> bool) -> f64 {
    let (mut se, mut n) = (0.0, 0usize);
    for i in (0..f.color.len()).filter(|&i| keep(i)) {
        let d = luma(f.color[i]) - luma(g.color[i]);
        se += d * d;
        n += 1;
    }
    10.0 * (255.0f64 * 255.0 / (se / n.max(1) as f64).max(1e-12)).log10()
}

/// Aliasing and noise (§5.3, fig. 7: "similar artifacts only in the medium depth interval and
/// unstructured noise for the polygons far away"; "the aliasing disappears for unstructured
/// noise (which can be removed by averaging)"): a checkerboard floor of unit squares to 40
/// units away, 160 × 120, d = 1, seeds 0–15, against the mesh rendered at 4 × 4 samples per
/// pixel and box-filtered. In the far half of the floor (where a pixel spans several
/// squares) each frame carries noise: the per-pixel spread across seeds is twice the near
/// half's, and the mean of the 16 frames is nearer the filtered image than any one frame.
/// Measured when set (luma PSNR, far half): single frames 11.49–11.70 dB, mean of 16
/// 12.58 dB, `zbuffer` 13.58 dB; per-pixel standard deviation across seeds near 4.8, far 9.7.
/// The mean does not reach `zbuffer`: averaging removes the noise but not a bias, consistent
/// with the depth test keeping the nearest of a pixel's ≈ ln v samples, which on a receding
/// floor lies at the pixel's near edge. Bounds: the mean at least 0.6 dB over the best
/// frame, the far spread at least 1.5 × the near.
#[test]
fn far_field_error_is_noise_that_averages_out() {
    let dir = tempfile::tempdir().unwrap();
    let mut quads = Vec::new();
    let s = 1.0f32;
    for i in 0..8 {
        for j in 0..40 {
            let (x0, z0) = (-4.0 + i as f32 * s, -(j as f32) * s);
            let c = if (i + j) % 2 == 0 { [1.0; 4] } else { [0.0, 0.0, 0.0, 1.0] };
            // Facing +y (up), counter-clockwise seen from above.
            quads.push(([[x0, 0.0, z0], [x0 + s, 0.0, z0], [x0 + s, 0.0, z0 - s], [x0, 0.0, z0 - s]], c));
        }
    }
    let mesh = synth::quads(&quads);
    let sct = write(&mesh, 0.05, dir.path(), "floor.sct");
    let opts = RenderOptions { width: 160, height: 120, shading: Shading::Flat, eye: Some([0.0, 1.0, 1.0]), target: Some([0.0, 0.0, -6.0]), ..RenderOptions::default() };
    let z = render_file(&sct, &opts).unwrap();
    // The filtered reference: 4 × 4 point samples per pixel, averaged.
    let cam4 = render_preview::Camera { width: 640, height: 480, ..z.camera };
    let r4 = render_reference(&mesh, &View::new(&cam4, z.near).unwrap(), opts.shading, opts.background);
    let mut refr = Frame::new(160, 120, [0, 0, 0, 255]);
    for y in 0..120 {
        for x in 0..160 {
            let mut acc = [0.0f64; 3];
            let mut covered = 0;
            for dy in 0..4 {
                for dx in 0..4 {
                    let i = (4 * y + dy) * 640 + 4 * x + dx;
                    for (a, c) in acc.iter_mut().zip(r4.color[i]) {
                        *a += c as f64 / 16.0;
                    }
                    covered += r4.depth[i].is_finite() as usize;
                }
            }
            let i = y * 160 + x;
            refr.color[i] = [acc[0].round() as u8, acc[1].round() as u8, acc[2].round() as u8, 255];
            // Only pixels the floor covers entirely count.
            refr.depth[i] = if covered == 16 { 1.0 } else { f32::INFINITY };
        }
    }
    let frames: Vec<Frame> = (0..16u64)
        .map(|seed| {
            let o = sampled(opts.clone(), 1);
            render_file(&sct, &RenderOptions { wand: WandOptions { seed, ..o.wand }, ..o }).unwrap().frame
        })
        .collect();
    let n = refr.color.len();
    let mut mean = refr.clone();
    let mut sd = vec![0.0; n];
    for (i, sd) in sd.iter_mut().enumerate() {
        let l: Vec<f64> = frames.iter().map(|f| luma(f.color[i])).collect();
        let m = l.iter().sum::<f64>() / l.len() as f64;
        *sd = (l.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / l.len() as f64).sqrt();
        for k in 0..3 {
            mean.color[i][k] = (frames.iter().map(|f| f.color[i][k] as f64).sum::<f64>() / frames.len() as f64).round() as u8;
        }
    }
    // The floor's rows: its far half is the upper half of the rows it covers.
    let rows: Vec<usize> = (0..120).filter(|&y| (0..160).any(|x| refr.depth[y * 160 + x].is_finite())).collect();
    let mid = rows[rows.len() / 2];
    let far = |i: usize| refr.depth[i].is_finite() && i / 160 < mid;
    let near = |i: usize| refr.depth[i].is_finite() && i / 160 >= mid;
    let mean_sd = |keep: &dyn Fn(usize) -> bool| {
        let v: Vec<f64> = (0..n).filter(|&i| keep(i)).map(|i| sd[i]).collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    let (sd_near, sd_far) = (mean_sd(&near), mean_sd(&far));
    let single: Vec<f64> = frames.iter().map(|f| psnr_where(f, &refr, far)).collect();
    let best = single.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let avg = psnr_where(&mean, &refr, far);
    let zb = psnr_where(&z.frame, &refr, far);
    eprintln!(
        "far half: single frames {:.2}–{best:.2} dB, mean of 16 {avg:.2} dB, zbuffer {zb:.2} dB; per-pixel sd near {sd_near:.1}, far {sd_far:.1}",
        single.iter().copied().fold(f64::INFINITY, f64::min)
    );
    assert!(avg >= best + 0.6, "{avg} {best}");
    assert!(sd_far >= 1.5 * sd_near, "{sd_far} {sd_near}");
}

/// Worst-case geometry (§6.2.4, fig. 9: "regular hierarchical subdivision cannot handle
/// worst-case scenes at bounded error and running time"): a quad tilted 45° alone, then with
/// a pile of 21 horizontal quads beside it, nearly edge-on to the eye (they add little
/// projected area but much surface area, and boxes that mix them with the tilted quad take
/// its orientation bound). 160², d = 2, every leaf sampled. Measured when set: alone 14,188
/// samples over 5,712 covered pixels (2.5 each, 696 boxes); with the pile 23,053 samples (315
/// back-facing) over 7,700 pixels (3.0 each, 5,872 boxes). The paper's octree boxes bound
/// only the distance factor; here each box's normal cone also bounds `cos β`, and the
/// overcost stays at +20 % per covered pixel on this scene. Bounds: more than the quad alone, at most
/// 1.5 × as many samples per covered pixel.
#[test]
fn edge_on_pile_costs_samples_for_few_pixels() {
    let dir = tempfile::tempdir().unwrap();
    let (s, c) = std::f32::consts::FRAC_PI_4.sin_cos();
    // x ∈ [-1, 0.2], tilted 45° about the x axis, facing the eye on +z.
    let tilted = ([[-1.0, -c, s], [0.2, -c, s], [0.2, c, -s], [-1.0, c, -s]], [1.0; 4]);
    let mut with_pile = vec![tilted];
    for k in 0..21 {
        let y = -0.5 + k as f32 * 0.05;
        // Facing +y, counter-clockwise seen from above.
        with_pile.push(([[0.4, y, 0.5], [1.4, y, 0.5], [1.4, y, -0.5], [0.4, y, -0.5]], [0.2, 0.6, 1.0, 1.0]));
    }
    let opts = RenderOptions { width: 160, height: 160, eye: Some([0.0, 0.0, 4.0]), target: Some([0.0; 3]), ..RenderOptions::default() };
    let mut per = Vec::new();
    for (name, quads) in [("alone", vec![tilted]), ("with the pile", with_pile)] {
        let sct = write(&synth::quads(&quads), 0.02, dir.path(), &format!("{}.sct", per.len()));
        let out = render_file(&sct, &sampled(opts.clone(), 2)).unwrap();
        let st = out.stats.wand.unwrap();
        eprintln!("{name}: {} samples ({} back-facing), {} covered pixels, {:.1} per covered pixel, {} boxes", st.samples, st.backfacing, out.stats.covered_pixels, st.samples_per_covered_pixel, st.boxes);
        per.push(st.samples_per_covered_pixel);
    }
    assert!(per[1] > per[0] && per[1] <= 1.5 * per[0], "{per:?}");
}
