//! Hostile affine instances (format 1.3), file level: bad matrices and references are
//! refused by the reader at the record's offset and named by validation with their check;
//! matrices that pass one by one but compose past f32 and f64 along deep chains read,
//! validate and traverse without panicking, and bounds stay sound where they are finite.

mod common;

use common::craft::{self, Sec, G};
use sct_format::raw::{tags, SCT_MAGIC, SECTION_ENTRY_LEN};
use sct_format::graph::InstanceAttrs;
use sct_format::traverse::{graph_bound, Traversal, TraversalState, TraverseOptions};
use sct_format::validate::{validate_bytes, CheckId, ValidateOptions};
use sct_format::geometry::parent_of;
use sct_format::{write_scene, Affine, Error, Generator, Limits, Node, Profile, Scene, SceneTree, SctReader, Transform, WriteOptions};

const ID: [[f64; 4]; 3] = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]];

fn diag(x: f64, y: f64, z: f64) -> [[f64; 4]; 3] {
    [[x, 0.0, 0.0, 0.0], [0.0, y, 0.0, 0.0], [0.0, 0.0, z, 0.0]]
}

/// A consistent tree of 16 leaves on a unit sphere, outward normals.
fn ball() -> SceneTree {
    let mut r = sct_format::rng::SplitMix64(3);
    let mut level: Vec<Node> = (0..16)
        .map(|i| {
            let n = common::Rng(sct_format::rng::SplitMix64(r.next_u64())).unit();
            Node { center: n, radius: 0.1, normal: n, cone: 0.0, area: 0.03, color: [i * 16, 90, 200, 255] }
        })
        .collect();
    let mut levels = vec![level.clone()];
    while level.len() > 1 {
        level = level.chunks(2).map(|p| parent_of(&p[0], &p[1])).collect();
        levels.insert(0, level.clone());
    }
    let internal = levels.iter().enumerate().flat_map(|(d, l)| std::iter::repeat_n(d + 1 < levels.len(), l.len())).collect();
    SceneTree::from_bfs(levels.concat(), internal).expect("tree")
}

/// The stored bytes of `tree`'s TREE section (raw profile).
fn tree_section_of(tree: SceneTree) -> Vec<u8> {
    let scene = Scene::single_tree(Generator::default(), tree);
    let mut b = Vec::new();
    write_scene(&scene, &WriteOptions { profile: Profile::Raw, ..Default::default() }, &mut b).expect("write");
    let r = SctReader::from_bytes(b.clone(), &Limits::default()).expect("valid");
    let e = r.sections().iter().find(|e| e.tag == tags::TREE).expect("tree").clone();
    assert!(!e.compressed());
    b[e.offset as usize..(e.offset + e.stored_len) as usize].to_vec()
}

fn tree_section() -> Vec<u8> {
    tree_section_of(ball())
}

/// A file of that tree and `graph` (stored plain, so record offsets are file offsets), and
/// the offset of the graph section.
fn file(graph: &[G], root: u32) -> (Vec<u8>, u64) {
    let b = craft::container(SCT_MAGIC, &[Sec::plain(tags::GENR, craft::genr()), Sec::plain(tags::GRPH, craft::graph_bytes(graph, root)), Sec::plain(tags::TREE, tree_section())]);
    let e = 64 + SECTION_ENTRY_LEN;
    assert_eq!(&b[e..e + 4], b"GRPH");
    (b.clone(), u64::from_le_bytes(b[e + 8..e + 16].try_into().expect("8 bytes")))
}

fn affine(child: u32, m: [[f64; 4]; 3]) -> G {
    G::Affine(child, m, 0, [255; 4])
}

/// Quick and deep validation's issues, as (check, message).
fn issues(b: &[u8]) -> Vec<(CheckId, String)> {
    let mut out = Vec::new();
    for deep in [false, true] {
        let r = validate_bytes(b, &ValidateOptions { deep, ..Default::default() });
        out.extend(r.issues.into_iter().map(|i| (i.check, i.message)));
    }
    out
}

/// Node 1, an affine instance of tree node 0, with a matrix the reader must refuse: refused
/// at the record's file offset (graph head 12 bytes, node 0 five), and named by validation
/// as `non-finite` or `affine` at graph node 1.
#[test]
fn bad_matrices_are_refused_at_their_record() {
    let big = f32::MAX as f64;
    let mut cases: Vec<([[f64; 4]; 3], CheckId, &str)> = Vec::new();
    for (r, c, v) in [(0, 0, f64::NAN), (1, 2, f64::INFINITY), (2, 3, f64::NEG_INFINITY), (0, 3, f64::NAN)] {
        let mut m = ID;
        m[r][c] = v;
        cases.push((m, CheckId::NonFinite, "non-finite"));
    }
    cases.push(([[0.0; 4]; 3], CheckId::Affine, "singular"));
    cases.push(([[1.0, 2.0, 3.0, 0.0], [2.0, 4.0, 6.0, 0.0], [0.0, 0.0, 1.0, 0.0]], CheckId::Affine, "singular"));
    cases.push((diag(1e-110, 1e-110, 1e-110), CheckId::Affine, "singular"));
    cases.push((diag(1e39, 1e39, 1e39), CheckId::Affine, "f32 range"));
    cases.push((diag(big * 2.0, 1.0, 1.0), CheckId::Affine, "f32 range"));
    let mut far = ID;
    far[1][3] = 1e300;
    cases.push((far, CheckId::Affine, "f32 range"));
    cases.push((diag(1e38, 1.0, 1.0), CheckId::Affine, "condition number"));
    cases.push((diag(1e38, -1e38, 1e-38), CheckId::Affine, "condition number"));
    cases.push((diag(1.0, 1.0, 1e-7), CheckId::Affine, "condition number"));
    for (m, check, why) in cases {
        let (b, grph) = file(&[G::Tree(0), affine(0, m)], 1);
        match SctReader::from_bytes(b.clone(), &Limits::default()) {
            Err(Error::Malformed { offset, what }) => {
                assert_eq!(offset, grph + 12 + 5, "{what}");
                assert!(what.contains("affine instance 1") && what.contains(why), "{why}: {what}");
            }
            other => panic!("{why} {m:?}: {:?}", other.map(|_| ())),
        }
        let found = issues(&b);
        assert!(found.iter().any(|(k, msg)| *k == check && msg.contains("graph node 1")), "{why} {m:?}: {found:?}");
    }
}

/// An affine instance naming itself, a later node or no node, and one over a tree reference
/// the file lacks: refused at the record, named as `graph` issues; the graph never loops.
#[test]
fn bad_references_are_refused_at_their_record() {
    for (graph, root, at, why) in [
        (vec![G::Tree(0), affine(1, ID)], 1, 17, "not an earlier node"),
        (vec![G::Tree(0), affine(2, ID), affine(0, ID)], 1, 17, "not an earlier node"),
        (vec![G::Tree(0), affine(u32::MAX, ID)], 1, 17, "not an earlier node"),
        (vec![affine(0, ID), G::Tree(0)], 0, 12, "not an earlier node"),
        (vec![G::Tree(5), affine(0, ID)], 1, 12, "refers to tree 5"),
    ] {
        let (b, grph) = file(&graph, root);
        match SctReader::from_bytes(b.clone(), &Limits::default()) {
            Err(Error::Malformed { offset, what }) => {
                assert_eq!(offset, grph + at, "{what}");
                assert!(what.contains(why), "{why}: {what}");
            }
            other => panic!("{why}: {:?}", other.map(|_| ())),
        }
        let found = issues(&b);
        assert!(found.iter().any(|(k, msg)| *k == CheckId::Graph && msg.contains(why)), "{why}: {found:?}");
    }
    // A root past the end.
    let (b, _) = file(&[G::Tree(0), affine(0, ID)], 2);
    assert!(matches!(SctReader::from_bytes(b.clone(), &Limits::default()), Err(Error::Malformed { .. })));
    assert!(!validate_bytes(&b, &ValidateOptions::default()).is_valid());
}

/// An affine record cut at every length, and a record whose kind byte claims an affine
/// instance in a graph too short for one: malformed, never a panic.
#[test]
fn truncated_affine_records_are_malformed() {
    let full = craft::graph_bytes(&[G::Tree(0), affine(0, diag(2.0, 1.0, 0.5))], 1);
    for len in 12..full.len() {
        let b = craft::container(SCT_MAGIC, &[Sec::plain(tags::GENR, craft::genr()), Sec::plain(tags::GRPH, full[..len].to_vec()), Sec::plain(tags::TREE, tree_section())]);
        let err = SctReader::from_bytes(b.clone(), &Limits::default()).err().unwrap_or_else(|| panic!("graph cut at {len} read"));
        assert!(err.is_invalid_input(), "{len}: {err}");
        assert!(!validate_bytes(&b, &ValidateOptions::default()).is_valid(), "{len}");
    }
}

/// Reads, validates deep, bounds and traverses a file whose graph is a chain of affine
/// instances over the tree; returns the world root the traversal reached.
fn read_chain(chain: &[[[f64; 4]; 3]]) -> Option<sct_format::Node> {
    let mut graph = vec![G::Tree(0)];
    graph.extend(chain.iter().enumerate().map(|(k, m)| affine(k as u32, *m)));
    let (b, _) = file(&graph, chain.len() as u32);
    let r = SctReader::from_bytes(b.clone(), &Limits::default()).expect("every record is valid");
    let report = validate_bytes(&b, &ValidateOptions { deep: true, ..Default::default() });
    assert!(report.is_valid(), "{:?}", report.issues);
    let bound = graph_bound(&r, r.graph().root);
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("chain.sct");
    std::fs::write(&p, &b).expect("write");
    let reached: Vec<_> = Traversal::open(&p, TraverseOptions::default()).expect("opens").collect::<Result<_, _>>().expect("traverses");
    assert_eq!(reached.len(), 1);
    let world = reached[0].world_root();
    assert_eq!(world.map(|n| n.center.map(f32::to_bits)), bound.map(|n| n.center.map(f32::to_bits)), "the traversal and graph_bound compose alike");
    // A group over the chain, its one leaf the chain's bound mapped one instance at a time
    // (as a tree builder makes group leaves): deep validation compares them (valid where
    // the bound is finite; never a panic where it is not).
    graph.push(G::Group(1, vec![chain.len() as u32]));
    let stepwise = chain.iter().fold(r.read_tree(0).expect("tree").nodes()[0], |b, m| {
        TraversalState::IDENTITY.push(&Transform::from(Affine { matrix: *m }), &InstanceAttrs::default()).apply(&b)
    });
    let leaf = Some(stepwise).filter(|n| n.is_finite()).unwrap_or(Node { radius: 1.0, normal: [0.0, 0.0, 1.0], area: 1.0, color: [1, 2, 3, 255], ..Node::default() });
    let secs = [
        Sec::plain(tags::GENR, craft::genr()),
        Sec::plain(tags::GRPH, craft::graph_bytes(&graph, chain.len() as u32 + 1)),
        Sec::plain(tags::TREE, tree_section()),
        Sec::plain(tags::TREE, tree_section_of(SceneTree::from_bfs(vec![leaf], vec![false]).expect("one leaf"))),
    ];
    let b = craft::container(SCT_MAGIC, &secs);
    SctReader::from_bytes(b.clone(), &Limits::default()).expect("reads");
    let report = validate_bytes(&b, &ValidateOptions { deep: true, ..Default::default() });
    assert!(report.is_valid() || !stepwise.is_finite(), "{:?}", report.issues);
    world
}

/// Matrices that pass one by one but whose products reach the edges of f32 and f64: the
/// file reads, validates deep and traverses (the world root may be non-finite; no panic),
/// and a long chain whose product stays tame keeps a finite world root.
#[test]
fn chains_composing_past_the_float_range_read_and_traverse() {
    let big = f32::MAX as f64;
    let shear = [[1.0, 900.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]];
    let cases: Vec<(&str, Vec<[[f64; 4]; 3]>)> = vec![
        ("f32max", vec![diag(big, big, big)]),
        ("f32max-mirror", vec![diag(-big, big, -big)]),
        ("up-past-f64", vec![diag(big, big, big); 12]),
        ("aniso-past-f64", vec![diag(1e3, 1.0, 1e-2); 200]),
        ("down-past-f64", vec![diag(1e-30, 1e-30, 1e-30); 20]),
        ("shear", vec![shear; 60]),
        ("mirrors", (0..64).map(|k| if k % 2 == 0 { diag(-2.0, 0.5, 1.0) } else { diag(1.0, -3.0, 0.25) }).collect()),
        // A long chain that composes to the identity and back: the world root stays finite.
        ("long", (0..20_000).map(|k| if k % 2 == 0 { diag(4.0, 0.5, 1.0) } else { diag(0.25, 2.0, 1.0) }).collect()),
    ];
    for (name, chain) in cases {
        let world = read_chain(&chain);
        if name == "long" {
            let w = world.expect("a root");
            assert!(w.is_finite() && w.radius > 0.0, "{name}: {w}");
        }
    }
}

/// Regression (structured fuzzing): a group over an affine instance with entries near
/// f32::MAX has an infinite leaf, so its tree's root is not finite. The writer wrote that
/// file and the reader refused it at open; the writer now refuses it.
#[test]
fn writer_refuses_a_group_tree_whose_root_overflows() {
    let big = f32::MAX as f64;
    let a = Affine { matrix: diag(big, big, big) };
    let t = ball();
    let bound = TraversalState::IDENTITY.push(&Transform::from(a), &InstanceAttrs::default()).apply(&t.nodes()[0]);
    assert!(!bound.is_finite());
    let group = SceneTree::from_bfs(vec![parent_of(&t.nodes()[0], &bound), t.nodes()[0], bound], vec![true, false, false]).expect("tree");
    let nodes = vec![
        sct_format::GraphNode::Tree { tree: 0 },
        sct_format::GraphNode::Affine { child: 0, transform: a, attrs: InstanceAttrs::default() },
        sct_format::GraphNode::Group { children: vec![0, 1], tree: 1 },
    ];
    let scene = Scene { generator: Generator::default(), graph: sct_format::SceneGraph { nodes, root: 2 }, trees: vec![t, group] };
    match write_scene(&scene, &WriteOptions::default(), Vec::new()) {
        Err(Error::Misuse(m)) => assert!(m.contains("tree 1") && m.contains("non-finite"), "{m}"),
        other => panic!("{:?}", other.map(|_| ())),
    }
    // The affine instance alone (its world nodes overflow, its file is fine) is written.
    let scene = Scene { trees: vec![scene.trees[0].clone()], graph: sct_format::SceneGraph { nodes: scene.graph.nodes[..2].to_vec(), root: 1 }, ..scene };
    let mut b = Vec::new();
    write_scene(&scene, &WriteOptions::default(), &mut b).expect("valid");
    SctReader::from_bytes(b, &Limits::default()).expect("reads");
}
