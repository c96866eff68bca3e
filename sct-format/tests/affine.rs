//! Affine instances in scene files (spec §7, format 1.3): round trips, the version label,
//! and bounds that hold the mapped geometry through nested instances and groups.

use sct_format::geometry::parent_of;
use sct_format::graph::{InstanceAttrs, Propagation};
use sct_format::traverse::{graph_bound, ReachedKind, Traversal, TraversalState, TraverseOptions};
use sct_format::validate::{validate_file, ValidateOptions};
use sct_format::{write_scene, write_scene_file, Affine, Generator, GraphNode, Limits, Node, Profile, Scene, SceneGraph, SceneTree, SctReader, Similarity, Transform, WriteOptions};

/// A balanced tree over `leaves` (a power of two), breadth first.
fn balanced(leaves: Vec<Node>) -> SceneTree {
    let mut levels = vec![leaves];
    while levels[0].len() > 1 {
        let up: Vec<Node> = levels[0].chunks(2).map(|p| parent_of(&p[0], &p[1])).collect();
        levels.insert(0, up);
    }
    let depth = levels.len();
    let mut nodes = Vec::new();
    let mut internal = Vec::new();
    for (d, l) in levels.into_iter().enumerate() {
        internal.extend(std::iter::repeat_n(d + 1 < depth, l.len()));
        nodes.extend(l);
    }
    SceneTree::from_bfs(nodes, internal).expect("tree")
}

/// 64 samples of a spherical cap (z > 0.3) with outward normals: internal cones stay narrow,
/// so cone bounds are tested for real.
fn cap() -> SceneTree {
    let mut r = sct_format::rng::SplitMix64(7);
    let leaves = (0..64)
        .map(|i| {
            let z = 0.3 + 0.7 * r.next_f32();
            let phi = r.next_f32() * std::f32::consts::TAU;
            let s = (1.0 - z * z).sqrt();
            let n = [s * phi.cos(), s * phi.sin(), z];
            Node { center: n.map(|v| v * 2.0), radius: 0.05, normal: n, cone: 0.0, area: 0.01, color: [i as u8 * 4, 100, 200, 255] }
        })
        .collect();
    balanced(leaves)
}

fn stretch() -> Affine {
    Affine { matrix: [[3.0, 0.5, 0.0, 10.0], [0.0, 0.5, 0.0, -1.0], [0.0, 0.2, 1.5, 2.0]] }
}

fn mirror() -> Affine {
    Affine { matrix: [[-1.0, 0.0, 0.0, -4.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 2.0, 0.0]] }
}

fn turn() -> Similarity {
    Similarity { translation: [0.0, 5.0, 0.0], rotation: [0.0, 0.0, 0.382_683_432_365_089_8, 0.923_879_532_511_286_7], scale: 1.5 }
}

/// A scene of `cap()` used four times: plain, under an affine instance, under a similarity
/// of an affine instance (nested), and under a mirroring affine instance of a similarity;
/// a group over them whose leaves are the children's bounds.
fn scene() -> Scene {
    let tree = cap();
    let tint = InstanceAttrs { size: Propagation::PullUp, color: Propagation::PushDown, tint: Some([255, 128, 0, 255]) };
    let nodes = vec![
        GraphNode::Tree { tree: 0 },
        GraphNode::Affine { child: 0, transform: stretch(), attrs: tint },
        GraphNode::Instance { child: 1, transform: turn(), attrs: InstanceAttrs::default() },
        GraphNode::Instance { child: 0, transform: turn(), attrs: InstanceAttrs::default() },
        GraphNode::Affine { child: 3, transform: mirror(), attrs: InstanceAttrs::default() },
    ];
    let root = tree.nodes()[0];
    let mut bounds = vec![root];
    for n in &nodes[1..] {
        let (child, t, attrs) = n.instance().expect("instance");
        bounds.push(TraversalState::IDENTITY.push(&t, &attrs).apply(&bounds[child as usize]));
    }
    let group = balanced(vec![bounds[0], bounds[1], bounds[2], bounds[4]]);
    let mut nodes = nodes;
    nodes.push(GraphNode::Group { children: vec![0, 1, 2, 4], tree: 1 });
    Scene { generator: Generator { tool: "test".into(), ..Default::default() }, graph: SceneGraph { root: 5, nodes }, trees: vec![tree, group] }
}

/// Written and read back: the matrices bit for bit, the attributes, and version 1.3 only
/// for a file that has an affine instance.
#[test]
fn affine_instances_round_trip_and_label_the_file_1_3() {
    let s = scene();
    for profile in [Profile::Raw, Profile::Default] {
        let mut bytes = Vec::new();
        write_scene(&s, &WriteOptions { profile, ..Default::default() }, &mut bytes).expect("write");
        let r = SctReader::from_bytes(bytes, &Limits::default()).expect("read");
        assert_eq!((r.header().major, r.header().minor), (1, 3));
        assert_eq!(r.graph(), &s.graph);
    }
    let plain = Scene::single_tree(Generator::default(), cap());
    let mut bytes = Vec::new();
    write_scene(&plain, &WriteOptions { profile: Profile::Raw, ..Default::default() }, &mut bytes).expect("write");
    assert!(SctReader::from_bytes(bytes, &Limits::default()).expect("read").header().minor < 3);
    // A writer refuses what a reader would refuse.
    let mut bad = scene();
    bad.graph.nodes[1] = GraphNode::Affine { child: 0, transform: Affine { matrix: [[0.0; 4]; 3] }, attrs: InstanceAttrs::default() };
    assert!(write_scene(&bad, &WriteOptions::default(), &mut Vec::new()).is_err());
}

/// Every point of every leaf sphere, mapped through the world transform the traversal
/// composes (nested instances included), lies in the mapped leaf, in the tree's world root
/// and in the scene's bound; every mapped leaf normal lies in the mapped root cone; and the
/// file validates deep (group leaves equal the mapped child bounds).
#[test]
fn bounds_contain_the_mapped_leaves() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("affine.sct");
    write_scene_file(&path, &scene(), &WriteOptions { profile: Profile::Default, ..Default::default() }).expect("write");
    let report = validate_file(&path, &ValidateOptions { deep: true, limits: Limits::default(), allow_outside_inlines: false }).expect("validate");
    assert!(report.issues.is_empty(), "{:?}", report.issues);
    let reader = SctReader::open(&path, &Limits::default()).expect("open");
    let scene_bound = graph_bound(&reader, reader.graph().root).expect("bound");
    let mut r = sct_format::rng::SplitMix64(3);
    let mut affine_uses = 0;
    let mut uses = 0;
    for reached in Traversal::open(&path, TraverseOptions::default()).expect("traverse") {
        let reached = reached.expect("reached");
        if reached.kind != ReachedKind::Tree {
            continue;
        }
        uses += 1;
        affine_uses += matches!(reached.state.transform, Transform::Affine(_)) as usize;
        let t = reached.file.read_tree(reached.tree).expect("tree");
        let world_root = reached.world_root().expect("root");
        for i in t.leaves() {
            let leaf = t.nodes()[i];
            let w = reached.state.apply(&leaf);
            assert!(sct_format::geometry::normal_in_cone(world_root.normal, world_root.cone, w.normal, 1e-4), "leaf {i} normal outside the root cone");
            for _ in 0..50 {
                let d = [r.next_f64() * 2.0 - 1.0, r.next_f64() * 2.0 - 1.0, r.next_f64() * 2.0 - 1.0];
                let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1.0);
                let p: [f64; 3] = std::array::from_fn(|k| f64::from(leaf.center[k]) + d[k] / l * f64::from(leaf.radius));
                let q = reached.state.transform.apply_point(p);
                for (what, s) in [("leaf", w), ("tree root", world_root), ("scene", scene_bound)] {
                    let dist = (0..3).map(|k| (q[k] - f64::from(s.center[k])).powi(2)).sum::<f64>().sqrt();
                    assert!(dist <= f64::from(s.radius) * (1.0 + 1e-6), "a point of leaf {i} lies outside the {what} bound");
                }
            }
        }
    }
    assert_eq!((uses, affine_uses), (4, 3));
}
