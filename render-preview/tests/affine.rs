//! Affine instances (SCT 1.3) under every method: a sphere's tree placed by a stretching
//! and a mirroring matrix draws like the same samples baked through the matrix into their
//! own tree, seen from the same camera.

use std::path::Path;

use render_preview::{render_file, Method, RenderOptions, ViewPreset};
use sct_format::graph::InstanceAttrs;
use sct_format::write::{write_scene_file, Scene, WriteOptions};
use sct_format::{Affine, AffineMap, Generator, GraphNode, Profile, SceneGraph};

fn write(path: &Path, graph: SceneGraph, trees: Vec<sct_format::SceneTree>) {
    let scene = Scene { generator: Generator { tool: "test".into(), ..Default::default() }, graph, trees };
    write_scene_file(path, &scene, &WriteOptions { profile: Profile::Raw, ..Default::default() }).expect("write");
}

#[test]
fn affine_instances_draw_like_baked_copies_in_every_method() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mesh = render_preview::synth::uv_sphere([0.0, 0.0, 0.0], 1.0, 48, [0.8, 0.5, 0.3, 1.0]);
    let leaves = render_preview::synth::sample_mesh(&mesh, 0.03);
    for (name, a) in [
        ("stretch", Affine { matrix: [[2.2, 0.4, 0.0, 0.3], [0.0, 0.6, 0.0, 0.0], [0.2, 0.0, 1.3, -0.2]] }),
        ("mirror", Affine { matrix: [[-1.8, 0.0, 0.0, 0.0], [0.0, 0.9, 0.3, 0.0], [0.0, 0.0, 1.0, 0.0]] }),
    ] {
        let map = AffineMap::new(a);
        let kept = dir.path().join(format!("{name}-kept.sct"));
        let tree = render_preview::synth::build_tree(leaves.clone()).expect("tree");
        let nodes = vec![GraphNode::Tree { tree: 0 }, GraphNode::Affine { child: 0, transform: a, attrs: InstanceAttrs::default() }];
        write(&kept, SceneGraph { nodes, root: 1 }, vec![tree]);
        let baked = dir.path().join(format!("{name}-baked.sct"));
        let tree = render_preview::synth::build_tree(leaves.iter().map(|n| map.apply_node(n)).collect()).expect("tree");
        write(&baked, SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }], root: 0 }, vec![tree]);
        for method in [Method::Zbuffer, Method::Gauss, Method::Canopy, Method::Parilov, Method::Wald, Method::Wand] {
            let opts = RenderOptions { method, width: 160, height: 120, view: ViewPreset::Iso, ..RenderOptions::default() };
            let want = render_file(&baked, &opts).expect("render baked");
            let opts = RenderOptions { eye: Some(want.camera.eye), target: Some(want.camera.target), ..opts };
            let got = render_file(&kept, &opts).expect("render kept");
            let m = render_preview::metrics::compare(&got.frame, &want.frame);
            let db = m.fg_psnr_db.unwrap_or(0.0);
            assert!(m.silhouette_iou >= 0.95 && db >= 25.0, "{name} {method:?}: IoU {}, {db:.2} dB against the baked copy", m.silhouette_iou);
        }
    }
}

/// A box (flat faces, sharp edges) under stretching affine instances, drawn by `parilov`
/// with samples wider than a pixel: against the mesh through the matrix, at most 1 dB
/// (foreground PSNR) below the mesh sampled in the world (`--bake-affine`). Wide samples
/// were drawn as discs of their mapped area, which stick out across the short axis of a
/// stretched patch, over the box's edges (flatten, 320 × 240: 22.2 dB kept, 24.5 baked;
/// now 30.7), and cells were sized by that area, not by the samples' width.
#[test]
fn parilov_draws_stretched_boxes_like_baked_copies() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = |x: f32, y: f32, z: f32| [x, y, z];
    let faces = [
        ([p(0., 0., 0.), p(0., 1., 0.), p(1., 1., 0.), p(1., 0., 0.)], [0.9, 0.2, 0.2, 1.0]),
        ([p(0., 0., 1.), p(1., 0., 1.), p(1., 1., 1.), p(0., 1., 1.)], [0.2, 0.9, 0.2, 1.0]),
        ([p(0., 0., 0.), p(0., 0., 1.), p(0., 1., 1.), p(0., 1., 0.)], [0.2, 0.2, 0.9, 1.0]),
        ([p(1., 0., 0.), p(1., 1., 0.), p(1., 1., 1.), p(1., 0., 1.)], [0.9, 0.9, 0.2, 1.0]),
        ([p(0., 0., 0.), p(1., 0., 0.), p(1., 0., 1.), p(0., 0., 1.)], [0.2, 0.9, 0.9, 1.0]),
        ([p(0., 1., 0.), p(0., 1., 1.), p(1., 1., 1.), p(1., 1., 0.)], [0.9, 0.2, 0.9, 1.0]),
    ];
    let mesh = render_preview::synth::quads(&faces);
    let leaves = render_preview::synth::sample_mesh(&mesh, 0.02);
    for (name, a) in [
        ("stretch", Affine { matrix: [[2.6, 0.5, 0.0, 0.0], [0.0, 0.5, 0.3, 0.0], [0.4, 0.0, 1.1, 0.0]] }),
        ("flatten", Affine { matrix: [[0.4, 0.0, 0.0, 0.0], [0.0, 2.4, 0.0, 0.0], [0.0, 0.3, 1.8, 0.0]] }),
    ] {
        let map = AffineMap::new(a);
        let kept = dir.path().join(format!("{name}-kept.sct"));
        let tree = render_preview::synth::build_tree(leaves.clone()).expect("tree");
        let nodes = vec![GraphNode::Tree { tree: 0 }, GraphNode::Affine { child: 0, transform: a, attrs: InstanceAttrs::default() }];
        write(&kept, SceneGraph { nodes, root: 1 }, vec![tree]);
        // The box's mesh through the matrix: sampled in the world for the baked copy (as
        // `--bake-affine` builds it; spacing scaled by |det|^⅓), drawn exactly as the reference.
        let mapped: Vec<_> = faces.iter().map(|(q, c)| (q.map(|v| map.affine.apply_point(v.map(f64::from)).map(|x| x as f32)), *c)).collect();
        let mapped = render_preview::synth::quads(&mapped);
        let baked = dir.path().join(format!("{name}-baked.sct"));
        let spacing = 0.02 * a.determinant().abs().cbrt() as f32;
        let tree = render_preview::synth::build_tree(render_preview::synth::sample_mesh(&mapped, spacing)).expect("tree");
        write(&baked, SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }], root: 0 }, vec![tree]);
        for (w, h) in [(160, 120), (320, 240)] {
            let opts = RenderOptions { method: Method::Parilov, width: w, height: h, view: ViewPreset::Iso, ..RenderOptions::default() };
            let want = render_file(&baked, &opts).expect("render baked");
            let opts = RenderOptions { eye: Some(want.camera.eye), target: Some(want.camera.target), ..opts };
            let got = render_file(&kept, &opts).expect("render kept");
            let view = render_preview::View::new(&want.camera, want.near).expect("view");
            let reference = render_preview::reference::render_reference(&mapped, &view, opts.shading, opts.background);
            let db = |f| render_preview::metrics::compare(f, &reference).fg_psnr_db.unwrap_or(0.0);
            let (k, b) = (db(&got.frame), db(&want.frame));
            assert!(k >= b - 1.0, "{name} {w}×{h}: kept {k:.2} dB, baked {b:.2} dB against the mesh");
        }
    }
}
