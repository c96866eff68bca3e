//! Where `gauss` fails (Coconu & Hege §5.2, §5.4; preview-methods.md F4): each documented
//! failure mode gets a scene, a measurement, and the behaviour it shows asserted with the
//! bound measured when the test was written. Each measurement is printed (`--nocapture`).

use render_preview::reference::render_reference;
use render_preview::{metrics, render_file, synth, Frame, Method, RenderOptions, Shading, View};
use sct_format::write::WriteOptions;

fn luma(c: [u8; 4]) -> f64 {
    0.299 * c[0] as f64 + 0.587 * c[1] as f64 + 0.114 * c[2] as f64
}

/// Mean luma drop of `f` over the pixels where `refr` shows white (luma ≥ 250) with white
/// at every pixel 2 px away too (the plate's interior), and the fraction of those pixels
/// darker by more than 64.
fn white_drop(f: &Frame, refr: &Frame) -> (f64, f64) {
    let (w, h) = (f.width, f.height);
    let white = |x: usize, y: usize| luma(refr.color[y * w + x]) >= 250.0;
    let (mut sum, mut dark, mut n) = (0.0, 0usize, 0usize);
    for y in 2..h - 2 {
        for x in 2..w - 2 {
            if white(x, y) && white(x - 2, y) && white(x + 2, y) && white(x, y - 2) && white(x, y + 2) {
                let d = 255.0 - luma(f.color[y * w + x]);
                sum += d;
                dark += (d > 64.0) as usize;
                n += 1;
            }
        }
    }
    assert!(n > 100, "too few interior pixels: {n}");
    (sum / n as f64, dark as f64 / n as f64)
}

/// Grazing overlap (§5.2): "surfels from a far surface may overlap previously drawn surfels
/// from a near surface and alter its color". A white plate over a black one `gap` behind,
/// seen at `deg` from the normal, 200×200, flat shading, leaves of side `S` = 0.02.
fn plates(gap_in_s: f32, deg: f64) -> ((f64, f64), (f64, f64)) {
    let s = 0.02f32;
    let dir = tempfile::tempdir().unwrap();
    let q = |z: f32, h: f32| [[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]];
    let mesh = synth::quads(&[(q(0.0, 1.0), [1.0; 4]), (q(-gap_in_s * s, 1.5), [0.0, 0.0, 0.0, 1.0])]);
    let sct = dir.path().join("p.sct");
    synth::write_mesh_sct(&mesh, s, &sct, &WriteOptions::default()).unwrap();
    let (sn, cs) = deg.to_radians().sin_cos();
    let opts = RenderOptions {
        width: 200,
        height: 200,
        shading: Shading::Flat,
        eye: Some([0.0, 3.0 * sn, 3.0 * cs]),
        target: Some([0.0; 3]),
        background: [0, 0, 0],
        ..RenderOptions::default()
    };
    let g = render_file(&sct, &RenderOptions { method: Method::Gauss, ..opts.clone() }).unwrap();
    let z = render_file(&sct, &opts).unwrap();
    let refr = render_reference(&mesh, &View::new(&z.camera, z.near).unwrap(), opts.shading, opts.background);
    (white_drop(&g.frame, &refr), white_drop(&z.frame, &refr))
}

/// Measured when set (mean luma drop over the white plate's interior / fraction of it darker
/// by more than 64), `gauss` then `zbuffer`:
///
/// | gap | 0° | 45° | 70° | 80° |
/// |---|---|---|---|---|
/// | 1 S, gauss | 5.16 / 0.0000 | 4.74 / 0.0000 | 4.93 / 0.0002 | 7.31 / 0.0039 |
/// | 1 S, zbuffer | 6.35 / 0.0380 | 5.42 / 0.0269 | 8.85 / 0.0399 | 16.87 / 0.0764 |
/// | 0.5 S, gauss | 17.60 / 0.0257 | 18.93 / 0.0811 | 13.21 / 0.0431 | 12.74 / 0.0398 |
/// | 0.5 S, zbuffer | 27.44 / 0.2192 | 20.17 / 0.1523 | 18.50 / 0.1224 | 22.53 / 0.1371 |
///
/// The zbuffer rows are from before `raster::fill_depth_pits`; with it, zbuffer at 1 S:
/// 1.35 / 0.0096, 1.27 / 0.0092, 1.58 / 0.0106, 3.75 / 0.0244; at 0.5 S: 26.82 / 0.2153,
/// 19.30 / 0.1488, 15.37 / 0.1101, 15.57 / 0.1102 (the mean drop at 1 S now under gauss's,
/// the dark share still 3–8× gauss's).
///
/// (Leaf splats drawn at their patch's size rather than their covering sphere made these
/// worse, most at grazing angles: zbuffer at 80° was 7.14 / 0.0378 with covering leaves;
/// the same change took 1–4 dB of outline error off single models in the accuracy table.)
///
/// One spacing apart the plates stay apart for both (blending only tints the front plate by
/// a few levels; the depth buffer shows the back plate through cracks between internal
/// splats); half a spacing apart the cut merges them and both fail, blending less. Bounds:
/// the worst figure per gap with a margin, and blending never darker than the depth buffer.
#[test]
fn grazing_plates_blend_the_far_one_in() {
    for gap in [1.0f32, 0.5] {
        for deg in [0.0, 45.0, 70.0, 80.0] {
            let ((gm, gd), (zm, zd)) = plates(gap, deg);
            eprintln!("gap {gap} S, {deg}°: gauss mean drop {gm:.2} dark {gd:.4} | zbuffer {zm:.2} {zd:.4}");
            let (max_mean, max_dark) = if gap >= 1.0 { (8.5, 0.01) } else { (22.0, 0.12) };
            assert!(gm <= max_mean && gd <= max_dark, "gap {gap} S at {deg}°: gauss {gm} {gd}");
            assert!(gd <= zd, "gap {gap} S at {deg}°: gauss dark {gd} vs zbuffer {zd}");
        }
    }
}

/// Interpenetrating objects (§5.2: an order "may not exist … if objects intersect each
/// other"): a red and a blue sphere overlapping by half a radius, seen across the
/// intersection; gauss against the same cut through the depth buffer: the error stays on
/// the intersection curve.
#[test]
fn interpenetrating_spheres_order_error() {
    let dir = tempfile::tempdir().unwrap();
    let a = synth::uv_sphere([-0.25, 0.0, 0.0], 0.5, 32, [0.9, 0.1, 0.1, 1.0]);
    let b = synth::uv_sphere([0.25, 0.0, 0.1], 0.5, 32, [0.1, 0.1, 0.9, 1.0]);
    let mut leaves = synth::sample_mesh(&a, 0.01);
    leaves.extend(synth::sample_mesh(&b, 0.01));
    let tree = synth::build_tree(leaves).unwrap();
    let sct = dir.path().join("x.sct");
    sct_format::write::write_scene_file(&sct, &sct_format::write::Scene::single_tree(Default::default(), tree), &WriteOptions::default()).unwrap();
    let opts = RenderOptions { width: 256, height: 256, shading: Shading::Flat, ..RenderOptions::default() };
    let g = render_file(&sct, &RenderOptions { method: Method::Gauss, ..opts.clone() }).unwrap();
    let z = render_file(&sct, &opts).unwrap();
    let m = metrics::compare(&g.frame, &z.frame);
    // Wrong-front pixels: blue where the depth buffer shows red or the reverse.
    let wrong = g.frame.color.iter().zip(&z.frame.color).filter(|(a, b)| (a[0] > a[2]) != (b[0] > b[2]) && (a[0] as i32 - a[2] as i32).abs() > 100).count();
    let covered = z.frame.covered();
    eprintln!("interpenetrating: gauss vs zbuffer {m:?}, wrong-front {wrong} of {covered}");
    // Measured: 28.8 dB against the depth buffer, 105 wrong-front pixels of 27,197 (0.39 %),
    // along the intersection curve where kernel centres of both spheres share a depth.
    assert!(m.fg_psnr_db.unwrap() >= 27.5, "{m:?}");
    assert!((wrong as f64) <= 0.005 * covered as f64, "{wrong} of {covered}");
}

/// Popping (§6.2.3) and order changes along an orbit: the mean absolute difference between
/// consecutive frames beyond the mesh's own, 8 frames × 1°, 160², a sphere of 1/100-radius
/// leaves. Measured: zbuffer 0.437, gauss 1.605 levels: the per-frame depth sort reorders
/// neighbouring kernels of one surface, and the last drawn dominates each pixel, so blending
/// flickers about 3.7× as much as the depth buffer (which itself pops as the cut changes).
#[test]
fn orbit_flicker_beyond_the_mesh() {
    let mesh = synth::uv_sphere([0.0; 3], 1.0, 24, [0.8, 0.5, 0.2, 1.0]);
    let dir = tempfile::tempdir().unwrap();
    let sct = dir.path().join("s.sct");
    synth::write_mesh_sct(&mesh, 0.01, &sct, &WriteOptions::default()).unwrap();
    for method in [Method::Zbuffer, Method::Gauss] {
        let (mut prev, mut prev_ref, mut sum, mut sum_ref) = (None::<Frame>, None::<Frame>, 0.0, 0.0);
        for f in 0..8 {
            let a = (f as f64).to_radians();
            let opts = RenderOptions { method, width: 160, height: 160, eye: Some([3.0 * a.sin(), 0.5, 3.0 * a.cos()]), target: Some([0.0; 3]), ..RenderOptions::default() };
            let out = render_file(&sct, &opts).unwrap();
            let refr = render_reference(&mesh, &View::new(&out.camera, out.near).unwrap(), opts.shading, opts.background);
            if let (Some(p), Some(pr)) = (&prev, &prev_ref) {
                sum += render_preview::compare::mean_abs_diff(p, &out.frame);
                sum_ref += render_preview::compare::mean_abs_diff(pr, &refr);
            }
            (prev, prev_ref) = (Some(out.frame), Some(refr));
        }
        let excess = (sum - sum_ref) / 7.0;
        eprintln!("{method}: orbit mean |Δ| {:.3}, mesh {:.3}, excess {excess:.3}", sum / 7.0, sum_ref / 7.0);
        let bound = if method == Method::Gauss { 2.2 } else { 0.7 };
        assert!(excess <= bound, "{method}: excess {excess}");
    }
}
