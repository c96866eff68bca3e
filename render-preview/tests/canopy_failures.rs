//! Where `canopy` fails (thesis §3.3.7, §3.7, §5.7.1, §6.9; preview-methods.md A4 and B4):
//! each documented failure mode gets a scene, a measurement (printed with `--nocapture`) and
//! the behaviour it shows asserted with the bound measured when the test was written.

use render_preview::reference::render_reference;
use render_preview::{metrics, render_file, synth, CanopyOptions, Frame, Method, RenderOptions, Shading, View};
use sct_format::write::WriteOptions;

fn canopy(o: RenderOptions) -> RenderOptions {
    RenderOptions { method: Method::Canopy, ..o }
}

fn write(mesh: &render_preview::reference::WorldMesh, spacing: f32, dir: &std::path::Path) -> std::path::PathBuf {
    let p = dir.join("s.sct");
    synth::write_mesh_sct(mesh, spacing, &p, &WriteOptions::default()).unwrap();
    p
}

/// Fraction of the unculled frame's covered pixels that the culled frame leaves uncovered
/// or changes by more than 24 levels.
fn culled_error(on: &Frame, off: &Frame) -> f64 {
    let (mut bad, mut n) = (0usize, 0usize);
    for i in 0..off.color.len() {
        if off.depth[i].is_finite() {
            n += 1;
            let d = (0..3).map(|k| (on.color[i][k] as i32 - off.color[i][k] as i32).abs()).max().unwrap_or(0);
            bad += (!on.depth[i].is_finite() || d > 24) as usize;
        }
    }
    bad as f64 / n.max(1) as f64
}

/// §3.7: occlusion culling "causing self occlusion in surfaces, particularly when viewed at
/// grazing angles". One 4 × 4 plate seen from 2°, 5°, 10° and 20° elevation, 256², default
/// thresholds: pixels wrongly culled against the same frame without culling. Measured when
/// set: nothing occluded at any elevation (a plane's nodes relate as intersecting or
/// contained, which add no occlusion, or are too weak), so no pixel lost; bound 0.5 %.
#[test]
fn grazing_self_occlusion_on_a_plane() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = synth::quads(&[([[-2.0, 0.0, 2.0], [2.0, 0.0, 2.0], [2.0, 0.0, -2.0], [-2.0, 0.0, -2.0]], [0.6, 0.7, 0.8, 1.0])]);
    let sct = write(&mesh, 0.01, dir.path());
    for deg in [2.0f64, 5.0, 10.0, 20.0] {
        let (s, c) = deg.to_radians().sin_cos();
        let o = canopy(RenderOptions { width: 256, height: 256, eye: Some([0.0, 3.0 * s, 3.0 * c]), target: Some([0.0; 3]), ..RenderOptions::default() });
        let on = render_file(&sct, &o).unwrap();
        let off = render_file(&sct, &RenderOptions { canopy: CanopyOptions { occ_cull: f32::INFINITY, ..o.canopy }, ..o.clone() }).unwrap();
        let e = culled_error(&on.frame, &off.frame);
        let cs = on.stats.canopy.unwrap();
        eprintln!("plane at {deg}°: wrongly culled {:.4} of covered, {} nodes occluded", e, cs.occluded);
        assert!(e <= GRAZING_BOUND, "{deg}°: {e}");
    }
}

/// See [`grazing_self_occlusion_on_a_plane`].
const GRAZING_BOUND: f64 = 0.005;

/// §5.7.1: "when looking along a row of objects at a shallow angle, a large number of
/// contributions may be made, even though the occluders are weak". Twelve spheres in a line
/// along the view axis, the eye 8° above it, 256²: pixels the culled frame changes against
/// the unculled one. Measured when set: t_OccCull 1.0 occludes 49 nodes and draws 12,076 of
/// 22,926 discs, 1.9 occludes 60 and draws 15,352, and neither changes a pixel: the spheres
/// hide each other fully, so the many weak contributions cull correctly here. Bound 0.5 %.
#[test]
fn row_of_models_at_a_shallow_angle() {
    let dir = tempfile::tempdir().unwrap();
    let mut leaves = Vec::new();
    for k in 0..12 {
        let m = synth::uv_sphere([0.0, 0.0, -3.0 * k as f32], 1.0, 16, [0.3 + 0.05 * k as f32, 0.6, 0.4, 1.0]);
        leaves.extend(synth::sample_mesh(&m, 0.03));
    }
    let tree = synth::build_tree(leaves).unwrap();
    let sct = dir.path().join("row.sct");
    sct_format::write::write_scene_file(&sct, &sct_format::write::Scene::single_tree(Default::default(), tree), &WriteOptions::default()).unwrap();
    let (s, c) = 8f64.to_radians().sin_cos();
    let o = canopy(RenderOptions { width: 256, height: 256, eye: Some([0.0, 6.0 * s, 4.0 + 6.0 * c]), target: Some([0.0, 0.0, -4.0]), ..RenderOptions::default() });
    let off = render_file(&sct, &RenderOptions { canopy: CanopyOptions { occ_cull: f32::INFINITY, ..o.canopy }, ..o.clone() }).unwrap();
    for cull in [1.0f32, 1.9] {
        let on = render_file(&sct, &RenderOptions { canopy: CanopyOptions { occ_cull: cull, ..o.canopy }, ..o.clone() }).unwrap();
        let e = culled_error(&on.frame, &off.frame);
        let cs = on.stats.canopy.unwrap();
        eprintln!("row, t_OccCull {cull}: wrongly culled {e:.4}, occluded {}, discs {} of {}", cs.occluded, cs.nodes_rasterized, off.stats.splats);
        assert!(e <= ROW_BOUND, "t_OccCull {cull}: {e}");
        assert!(cs.occluded > 0 && cs.nodes_rasterized < off.stats.splats, "{cs:?}");
    }
}

/// See [`row_of_models_at_a_shallow_angle`].
const ROW_BOUND: f64 = 0.005;

/// §3.3.7: "Artifacts will be least likely when … each Rm only has one depth layer". Two
/// parallel plates half a t2-node apart, seen at 60° from their normal, 256², flat shading:
/// reverse-mask-order discs against the same discs through a depth buffer. Measured when
/// set: 19.6 dB between the two (the painter lets back-plate discs of a set cover front-plate
/// ones); against the mesh 15.4 dB painted, 16.3 dB depth-buffered (the 0.05 gap is under the
/// discs' own size, so both fail). Floor 18.5 dB.
#[test]
fn several_depth_layers_inside_one_refined_set() {
    let dir = tempfile::tempdir().unwrap();
    let q = |z: f32, c: [f32; 4]| ([[-1.0, -1.0, z], [1.0, -1.0, z], [1.0, 1.0, z], [-1.0, 1.0, z]], c);
    let mesh = synth::quads(&[q(0.0, [1.0, 1.0, 1.0, 1.0]), q(-0.05, [0.0, 0.0, 0.0, 1.0])]);
    let sct = write(&mesh, 0.01, dir.path());
    let (s, c) = 60f64.to_radians().sin_cos();
    let o = canopy(RenderOptions { width: 256, height: 256, shading: Shading::Flat, eye: Some([0.0, 3.0 * s, 3.0 * c]), target: Some([0.0; 3]), ..RenderOptions::default() });
    let painted = render_file(&sct, &o).unwrap();
    let zb = render_file(&sct, &RenderOptions { canopy: CanopyOptions { zbuffer: true, ..o.canopy }, ..o.clone() }).unwrap();
    let m = metrics::compare(&painted.frame, &zb.frame);
    let view = View::new(&zb.camera, zb.near).unwrap();
    let refr = render_reference(&mesh, &view, o.shading, o.background);
    let (mp, mz) = (metrics::compare(&painted.frame, &refr), metrics::compare(&zb.frame, &refr));
    eprintln!("layers: painter vs its depth buffer {:?} dB; vs mesh painter {:?} dB, depth buffer {:?} dB", m.fg_psnr_db, mp.fg_psnr_db, mz.fg_psnr_db);
    assert!(m.fg_psnr_db.unwrap() >= LAYERS_FLOOR_DB, "{m:?}");
}

/// See [`several_depth_layers_inside_one_refined_set`].
const LAYERS_FLOOR_DB: f64 = 18.5;

/// §3.3.4: intersecting nodes are ordered only by a probable nearest-first rule. A red and a
/// blue sphere overlapping by half a radius, 256², flat shading: reverse-mask-order discs
/// against the same discs through a depth buffer. Measured when set: 28.9 dB, 152 of 28,194
/// covered pixels (0.54 %) show the other sphere in front, along the intersection curve.
/// Bound 1 %.
#[test]
fn interpenetrating_models() {
    let dir = tempfile::tempdir().unwrap();
    let a = synth::uv_sphere([-0.25, 0.0, 0.0], 0.5, 32, [0.9, 0.1, 0.1, 1.0]);
    let b = synth::uv_sphere([0.25, 0.0, 0.1], 0.5, 32, [0.1, 0.1, 0.9, 1.0]);
    let mut leaves = synth::sample_mesh(&a, 0.01);
    leaves.extend(synth::sample_mesh(&b, 0.01));
    let sct = dir.path().join("x.sct");
    sct_format::write::write_scene_file(&sct, &sct_format::write::Scene::single_tree(Default::default(), synth::build_tree(leaves).unwrap()), &WriteOptions::default()).unwrap();
    let o = canopy(RenderOptions { width: 256, height: 256, shading: Shading::Flat, ..RenderOptions::default() });
    let painted = render_file(&sct, &o).unwrap();
    let zb = render_file(&sct, &RenderOptions { canopy: CanopyOptions { zbuffer: true, ..o.canopy }, ..o.clone() }).unwrap();
    let m = metrics::compare(&painted.frame, &zb.frame);
    let wrong = painted.frame.color.iter().zip(&zb.frame.color).filter(|(x, y)| (x[0] > x[2]) != (y[0] > y[2]) && (x[0] as i32 - x[2] as i32).abs() > 100).count();
    eprintln!("interpenetrating: painter vs depth buffer {:?} dB, wrong-front {wrong} of {}", m.fg_psnr_db, zb.frame.covered());
    assert!((wrong as f64) <= INTERPENETRATING_BOUND * zb.frame.covered() as f64, "{wrong}");
}

/// See [`interpenetrating_models`].
const INTERPENETRATING_BOUND: f64 = 0.01;

/// §3.8: changing the order between frames causes popping. A sphere, 8 frames × 1°, 160²:
/// the mean absolute difference between consecutive frames beyond the mesh's own. Measured
/// when set: 0.547 levels (zbuffer 0.437, gauss 1.605 in tests/gauss_failures.rs): the
/// repeatable order inside each set keeps it near the depth buffer's. Bound 0.8.
#[test]
fn popping_along_an_orbit() {
    let mesh = synth::uv_sphere([0.0; 3], 1.0, 24, [0.8, 0.5, 0.2, 1.0]);
    let dir = tempfile::tempdir().unwrap();
    let sct = write(&mesh, 0.01, dir.path());
    let (mut prev, mut prev_ref, mut sum, mut sum_ref) = (None::<Frame>, None::<Frame>, 0.0, 0.0);
    for f in 0..8 {
        let a = (f as f64).to_radians();
        let o = canopy(RenderOptions { width: 160, height: 160, eye: Some([3.0 * a.sin(), 0.5, 3.0 * a.cos()]), target: Some([0.0; 3]), ..RenderOptions::default() });
        let out = render_file(&sct, &o).unwrap();
        let refr = render_reference(&mesh, &View::new(&out.camera, out.near).unwrap(), o.shading, o.background);
        if let (Some(p), Some(pr)) = (&prev, &prev_ref) {
            sum += render_preview::compare::mean_abs_diff(p, &out.frame);
            sum_ref += render_preview::compare::mean_abs_diff(pr, &refr);
        }
        (prev, prev_ref) = (Some(out.frame), Some(refr));
    }
    let excess = (sum - sum_ref) / 7.0;
    eprintln!("canopy orbit: mean |Δ| {:.3}, mesh {:.3}, excess {excess:.3}", sum / 7.0, sum_ref / 7.0);
    assert!(excess <= POPPING_BOUND, "{excess}");
}

/// See [`popping_along_an_orbit`].
const POPPING_BOUND: f64 = 0.8;

/// The culling ceiling (`hidden_mask_nodes`, BENCHMARKS.md "the dense block"): with the
/// discs drawn through a depth buffer, the unculled row of twelve spheres along the view axis
/// (as in [`row_of_models_at_a_shallow_angle`]) has mask nodes that show no pixel, and they
/// hold discs; the painter's order counts none.
#[test]
fn hidden_mask_nodes_are_counted_through_the_depth_buffer() {
    let dir = tempfile::tempdir().unwrap();
    let mut leaves = Vec::new();
    for k in 0..12 {
        let m = synth::uv_sphere([0.0, 0.0, -3.0 * k as f32], 1.0, 16, [0.3 + 0.05 * k as f32, 0.6, 0.4, 1.0]);
        leaves.extend(synth::sample_mesh(&m, 0.03));
    }
    let tree = synth::build_tree(leaves).unwrap();
    let sct = dir.path().join("row.sct");
    sct_format::write::write_scene_file(&sct, &sct_format::write::Scene::single_tree(Default::default(), tree), &WriteOptions::default()).unwrap();
    let (s, c) = 8f64.to_radians().sin_cos();
    let o = canopy(RenderOptions { width: 256, height: 256, eye: Some([0.0, 6.0 * s, 4.0 + 6.0 * c]), target: Some([0.0, 0.0, -4.0]), ..RenderOptions::default() });
    let off = CanopyOptions { occ_cull: f32::INFINITY, ..o.canopy };
    let zb = render_file(&sct, &RenderOptions { canopy: CanopyOptions { zbuffer: true, ..off }, ..o.clone() }).unwrap().stats.canopy.unwrap();
    let painted = render_file(&sct, &RenderOptions { canopy: off, ..o.clone() }).unwrap().stats.canopy.unwrap();
    eprintln!("row unculled: {} of {} mask nodes hidden, {} of {} discs", zb.hidden_mask_nodes, zb.nodes_stage2, zb.hidden_rasterized, zb.nodes_rasterized);
    assert!(zb.hidden_mask_nodes > 0 && zb.hidden_mask_nodes < zb.nodes_stage2, "{zb:?}");
    assert!(zb.hidden_rasterized > 0 && zb.hidden_rasterized < zb.nodes_rasterized, "{zb:?}");
    assert_eq!((painted.hidden_mask_nodes, painted.hidden_rasterized), (0, 0));
}
