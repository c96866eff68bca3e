//! Hostile scenes through the renderer's own graph walk: a DAG of shared groups stops at the
//! traversal visit limit, and inlines stay inside the scene's directory unless allowed.

use std::path::{Path, PathBuf};

use render_preview::{render_file, Error, RenderOptions};
use sct_format::geometry::parent_of;
use sct_format::graph::{Generator, GraphNode, SceneGraph};
use sct_format::traverse::TraverseErrorKind;
use sct_format::write::{write_scene_file, Scene, WriteOptions};
use sct_format::{Node, SceneTree};

fn leaf(x: f32) -> Node {
    Node { center: [x, 0.0, 0.0], radius: 0.5, normal: [0.0, 0.0, 1.0], cone: 0.0, area: 1.0, color: [200, 100, 50, 255] }
}

fn pair(a: Node, b: Node) -> SceneTree {
    SceneTree::from_bfs(vec![parent_of(&a, &b), a, b], vec![true, false, false]).expect("tree")
}

fn write(path: &Path, nodes: Vec<GraphNode>, root: u32, trees: Vec<SceneTree>) -> PathBuf {
    let scene = Scene { generator: Generator::default(), graph: SceneGraph { nodes, root }, trees };
    write_scene_file(path, &scene, &WriteOptions::default()).expect("write");
    path.to_path_buf()
}

fn small() -> RenderOptions {
    RenderOptions { width: 64, height: 48, ..RenderOptions::default() }
}

/// Group k uses group k - 1 twice, 40 levels: 2^40 paths. The walk stops at the visit limit
/// with a limit-exceeded error instead of expanding every path.
#[test]
fn shared_groups_stop_at_the_visit_limit() {
    let dir = tempfile::tempdir().expect("tempdir");
    let t = pair(leaf(0.0), leaf(1.0));
    let b = t.nodes()[0];
    let mut nodes = vec![GraphNode::Tree { tree: 0 }];
    for k in 1..=40u32 {
        nodes.push(GraphNode::Group { children: vec![k - 1, k - 1], tree: 1 });
    }
    let p = write(&dir.path().join("dag.sct"), nodes, 40, vec![t, pair(b, b)]);
    let mut opts = small();
    opts.limits.max_traversal_visits = 5_000;
    // Drawn from close by, so that the LOD refines every group leaf.
    opts.pixel_error = 1e-6;
    match render_file(&p, &opts) {
        Err(Error::Sct { source: sct_format::Error::LimitExceeded { what, limit, .. }, .. }) => {
            assert_eq!((what, limit), (sct_format::traverse::VISITS, 5_000))
        }
        other => panic!("{:?}", other.map(|r| r.stats.splats)),
    }
}

/// An inline naming a file outside the scene's directory is not opened unless allowed.
#[test]
fn inline_outside_the_scene_directory_needs_permission() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scene_dir = dir.path().join("scene");
    std::fs::create_dir_all(&scene_dir).expect("dir");
    let t = pair(leaf(0.0), leaf(1.0));
    let b = t.nodes()[0];
    let outside = write(&dir.path().join("outside.sct"), vec![GraphNode::Tree { tree: 0 }], 0, vec![t]);
    let hash = *blake3::hash(&std::fs::read(&outside).expect("read")).as_bytes();
    let top = write(&scene_dir.join("top.sct"), vec![GraphNode::Inline { path: "../outside.sct".into(), hash, bound: b }], 0, vec![]);
    let mut opts = small();
    opts.pixel_error = 1e-6;
    match render_file(&top, &opts) {
        Err(Error::Inline { kind, .. }) => assert!(matches!(*kind, TraverseErrorKind::InlineOutside { .. }), "{kind}"),
        other => panic!("{:?}", other.map(|r| r.stats.splats)),
    }
    let allowed = render_file(&top, &RenderOptions { allow_outside_inlines: true, ..opts }).expect("allowed");
    assert_eq!(allowed.stats.files, 2);
}

/// A perfect tree whose nodes on each level are identical (consistent: a parent of two equal
/// children is the child with twice the area), so no node ever projects smaller than its
/// root: the LOD refines to every leaf, and every leaf covers much of the frame.
fn identical_tree(depth: u32) -> SceneTree {
    let (mut nodes, mut internal) = (Vec::new(), Vec::new());
    for d in 0..=depth {
        let n = Node { area: 2f32.powi((depth - d) as i32), ..leaf(0.0) };
        nodes.extend(std::iter::repeat_n(n, 1 << d));
        internal.extend(std::iter::repeat_n(d < depth, 1 << d));
    }
    SceneTree::from_bfs(nodes, internal).expect("perfect tree")
}

fn limit_of(r: Result<render_preview::Rendered, Error>) -> (&'static str, u64) {
    match r {
        Err(Error::Sct { source: sct_format::Error::LimitExceeded { what, limit, .. }, .. }) => (what, limit),
        other => panic!("{:?}", other.map(|r| r.stats.splats)),
    }
}

/// Nodes that never shrink below the pixel error: a 999 KB file of such trees (4 M nodes)
/// rendered for more than two minutes, every leaf a splat over much of the frame. The render
/// now stops at its node limit before decoding the level that would pass it, and at its
/// pixel limit before rasterizing; within both it draws.
#[test]
fn renders_stop_at_their_node_and_pixel_limits() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = write(&dir.path().join("same.sct"), vec![GraphNode::Tree { tree: 0 }], 0, vec![identical_tree(12)]);
    let opts = small();
    let r = render_file(&p, &opts).expect("within the defaults");
    assert_eq!(r.stats.lod.leaf_splats, 1 << 12);
    assert_eq!(limit_of(render_file(&p, &RenderOptions { max_nodes: 5_000, ..opts.clone() })), (render_preview::NODES_EXAMINED, 5_000));
    let pixels = RenderOptions { max_splat_pixels: 1_000_000, ..opts.clone() };
    assert_eq!(limit_of(render_file(&p, &pixels)), (render_preview::PIXELS_COVERED, 1_000_000));
}

/// Regression: canopy relates every pair of image nodes whose view cones overlap. On a
/// 999 KB tree of identical nodes every pair overlaps: it listed 2^41 candidate pairs and was
/// killed at 23 GB after 68 s. Candidates are now counted before they are listed, and image
/// nodes and relations have caps, so it refuses at once, naming the knobs.
#[test]
fn canopy_refuses_an_image_graph_beyond_its_caps() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = write(&dir.path().join("same.sct"), vec![GraphNode::Tree { tree: 0 }], 0, vec![identical_tree(19)]);
    let opts = RenderOptions { method: render_preview::Method::Canopy, ..small() };
    let t = std::time::Instant::now();
    match render_file(&p, &opts) {
        Err(Error::Invalid(msg)) => assert!(msg.contains("--canopy-t1"), "{msg}"),
        other => panic!("{:?}", other.map(|r| r.stats.splats)),
    }
    assert!(t.elapsed().as_secs() < 30, "took {:?}", t.elapsed());
    // Within the caps it draws.
    let p = write(&dir.path().join("small.sct"), vec![GraphNode::Tree { tree: 0 }], 0, vec![identical_tree(8)]);
    let r = render_file(&p, &opts).expect("a small pile draws");
    assert!(r.stats.splats > 0);
}

/// `parilov` walks the scene node by node: on a tree of identical nodes (which never shrink)
/// it stops at the same node and pixel limits as the other methods, without holding a
/// virtual sample per pixel (6.8 GB before that was fixed).
#[test]
fn parilov_stops_at_the_render_limits() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = write(&dir.path().join("same.sct"), vec![GraphNode::Tree { tree: 0 }], 0, vec![identical_tree(16)]);
    let opts = RenderOptions { method: render_preview::Method::Parilov, ..small() };
    let (what, _) = limit_of(render_file(&p, &RenderOptions { max_nodes: 20_000, ..opts.clone() }));
    assert!(what == render_preview::NODES_EXAMINED || what == render_preview::PIXELS_COVERED, "{what}");
    // A quarter of the cap for the pixels it paints one by one.
    assert_eq!(limit_of(render_file(&p, &RenderOptions { max_splat_pixels: 100_000, ..opts.clone() })).1, 25_000);
}
