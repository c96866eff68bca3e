use super::*;
use crate::geometry::parent_of;
use crate::write::{write_scene, Scene, WriteOptions};

fn leaf(x: f32, y: f32) -> Node {
    Node { center: [x, y, 0.0], radius: 0.25, normal: [0.0, 0.0, 1.0], cone: 0.1, area: 0.5, color: [(x * 40.0) as u8, 90, 200, 255] }
}

/// A consistent tree over `n` leaves, built by pairing neighbours bottom-up (not
/// balanced when `n` is not a power of two).
fn build(n: usize) -> SceneTree {
    // Build top-down with a queue of index ranges, collecting BFS order.
    let leaves: Vec<Node> = (0..n).map(|i| leaf(i as f32 * 0.7, (i % 3) as f32)).collect();
    fn bound(ls: &[Node]) -> Node {
        if ls.len() == 1 {
            return ls[0];
        }
        let m = ls.len() / 2;
        parent_of(&bound(&ls[..m]), &bound(&ls[m..]))
    }
    let mut nodes = Vec::new();
    let mut flags = Vec::new();
    let mut q = std::collections::VecDeque::from([(0usize, n)]);
    while let Some((a, b)) = q.pop_front() {
        nodes.push(bound(&leaves[a..b]));
        flags.push(b - a > 1);
        if b - a > 1 {
            let m = a + (b - a) / 2;
            q.push_back((a, m));
            q.push_back((m, b));
        }
    }
    SceneTree::from_bfs(nodes, flags).unwrap()
}

fn bytes_of(tree: SceneTree, profile: Profile) -> Vec<u8> {
    let mut out = Vec::new();
    let scene = Scene::single_tree(Generator::default(), tree);
    write_scene(&scene, &WriteOptions { profile, block_nodes: 4, ..Default::default() }, &mut out).unwrap();
    out
}

fn deep() -> ValidateOptions {
    ValidateOptions { deep: true, ..Default::default() }
}

#[test]
fn consistent_trees_are_valid() {
    for profile in [Profile::Raw, Profile::Canopy, Profile::Default] {
        for n in [1, 2, 3, 7, 33] {
            let r = validate_bytes(&bytes_of(build(n), profile), &deep());
            assert!(r.is_valid(), "{profile:?} {n}: {:#?}", r.issues);
            assert_eq!(r.nodes, 2 * n as u64 - 1);
        }
    }
}

#[test]
fn names_paths_of_bad_nodes() {
    let mut t = build(8);
    t.nodes_mut().iter_mut().for_each(|n| n.color = [9, 9, 9, 255]); // keep colours consistent under any weights
    // Node 4 is level 2 index 1: path root/0/1. Break its area (parent reported) and a child.
    t.nodes_mut()[4].area += 0.25;
    let r = validate_bytes(&bytes_of(t, Profile::Raw), &deep());
    let got: Vec<(String, &str)> = r.issues.iter().map(|i| (i.path.clone(), i.check.as_str())).collect();
    assert!(got.contains(&("root/0".into(), "area-sum")), "{got:?}");
    assert!(got.contains(&("root/0/1".into(), "area-sum")), "{got:?}");
    assert_eq!(r.check_ids(), vec![CheckId::AreaSum]);
}

/// A deep leaf broken in an unbalanced tree of many 4-node blocks: the wavefront must
/// decode every block once and name the leaf's real path.
#[test]
fn wavefront_names_deep_paths_across_blocks() {
    let mut t = build(300);
    let leaves: Vec<usize> = t.leaves().collect();
    let paths = crate::traverse::leaf_paths(&t, "root");
    let j = 217;
    t.nodes_mut()[leaves[j]].center[0] += 100.0;
    let r = validate_bytes(&bytes_of(t, Profile::Raw), &deep());
    assert_eq!(r.nodes, 599);
    let got: Vec<(String, &str)> = r.issues.iter().map(|i| (i.path.clone(), i.check.as_str())).collect();
    assert_eq!(got, vec![(paths[j].clone(), "child-outside-parent")]);
    assert!(paths[j].matches('/').count() >= 8, "{}", paths[j]);
}

/// Past the cap, issues are counted, not kept; the report is still invalid.
#[test]
fn issues_beyond_the_cap_are_counted() {
    let mut t = build(40);
    let leaves: Vec<usize> = t.leaves().collect();
    for &l in &leaves {
        t.nodes_mut()[l].radius = f32::NAN;
    }
    let bytes = bytes_of(t, Profile::Raw);
    let full = validate_bytes(&bytes, &deep());
    assert_eq!(full.issues.len(), 40);
    assert_eq!(full.issues_omitted, 0);
    let opts = deep();
    let mut v = Validator::new(&opts);
    v.max_issues = 15;
    v.file(&Source::Bytes(std::borrow::Cow::Borrowed(&bytes)), None, "root", "");
    let r = v.finish();
    assert_eq!((r.issues.len(), r.issues_omitted), (15, 25));
    assert_eq!(r.issues[..], full.issues[..15]);
    assert!(!r.is_valid());
}

/// Runs a deep validation of `bytes` on a pool of `threads` threads, keeping at most
/// `cap` issues.
fn deep_on(threads: usize, bytes: &[u8], cap: usize) -> Report {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| {
        let opts = deep();
        let mut v = Validator::new(&opts);
        v.max_issues = cap;
        v.file(&Source::Bytes(std::borrow::Cow::Borrowed(bytes)), None, "root", "");
        v.finish()
    })
}

fn same_report(a: &Report, b: &Report) {
    assert_eq!(a.issues, b.issues);
    assert_eq!((a.nodes, a.blocks, a.issues_omitted), (b.nodes, b.blocks, b.issues_omitted));
}

/// The order issues are found in, hence which ones survive the cap, and how far a failed
/// tree got, must not depend on the thread count (the batch size used to).
#[test]
fn report_does_not_depend_on_threads() {
    let mut t = build(600);
    // Issues on every level: areas that do not add up at every internal node.
    for (i, n) in t.nodes_mut().iter_mut().enumerate() {
        n.area += (i % 7) as f32 * 0.125;
    }
    let bytes = bytes_of(t, Profile::Raw);
    for cap in [usize::MAX, 40] {
        let one = deep_on(1, &bytes, cap);
        assert!(one.issues.len() >= 40, "{}", one.issues.len());
        same_report(&one, &deep_on(3, &bytes, cap));
    }
    // A corrupt block deep in the tree: the nodes checked before the failure must agree.
    let mut broken = bytes.clone();
    let n = broken.len();
    broken[n * 3 / 4] ^= 0x55;
    same_report(&deep_on(1, &broken, usize::MAX), &deep_on(3, &broken, usize::MAX));
}

/// Graph problems (reader problems and transform checks alike) stop being kept at the
/// room left under the cap, and are counted instead.
#[test]
fn graph_problems_are_capped() {
    use crate::raw::cursor::Put;
    let n = 50u64;
    let mut b = Vec::new();
    b.put_u64(n + 1);
    b.put_u32(0);
    b.put_u8(crate::write::kind::TREE);
    b.put_u32(0);
    for i in 0..n {
        b.put_u8(crate::write::kind::INSTANCE);
        b.put_u32(if i % 2 == 0 { 0 } else { 999 }); // every other one a bad reference too
        for v in [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, -1.0] {
            b.put_f64(v);
        }
        b.put_u8(0);
        b.extend_from_slice(&[255; 4]);
    }
    let (mut issues, mut omitted) = (Vec::new(), 0);
    let g = parse_graph(&b, 0, &Limits::default(), 10, &mut issues, &mut omitted).unwrap();
    let kept: usize = g.node_problems.values().map(Vec::len).sum();
    assert_eq!((kept + issues.len(), omitted), (10, n + n / 2 - 10));
}

/// Item 6: many inlines naming one target read, hash and validate it once (each used to
/// map and hash it again: 65,536 inlines of an 11 MB file took 400 s).
#[test]
fn each_inline_target_is_read_once() {
    use crate::write::write_scene_file;
    let dir = tempfile::tempdir().expect("tempdir");
    let target = dir.path().join("target.sct");
    let tree = build(5);
    let bound = tree.nodes()[0];
    write_scene_file(&target, &Scene::single_tree(Generator::default(), tree), &WriteOptions::default()).expect("write");
    let hash = *blake3::hash(&std::fs::read(&target).expect("read")).as_bytes();
    let k = 300usize;
    // A group of k inline nodes, all naming the target.
    let mut nodes: Vec<GraphNode> = (0..k).map(|_| GraphNode::Inline { path: "target.sct".into(), hash, bound }).collect();
    nodes.push(GraphNode::Group { children: (0..k as u32).collect(), tree: 0 });
    let leaves: Vec<Node> = vec![bound; k];
    let gtree = {
        // Balanced over k equal leaves, breadth first.
        let mut q = std::collections::VecDeque::from([(0usize, k)]);
        let (mut ns, mut fl) = (Vec::new(), Vec::new());
        fn bound_of(ls: &[Node]) -> Node {
            if ls.len() == 1 {
                return ls[0];
            }
            let m = ls.len() / 2;
            parent_of(&bound_of(&ls[..m]), &bound_of(&ls[m..]))
        }
        while let Some((a, b)) = q.pop_front() {
            ns.push(bound_of(&leaves[a..b]));
            fl.push(b - a > 1);
            if b - a > 1 {
                let m = a + (b - a) / 2;
                q.push_back((a, m));
                q.push_back((m, b));
            }
        }
        SceneTree::from_bfs(ns, fl).expect("tree")
    };
    let top = dir.path().join("top.sct");
    let scene = Scene { generator: Generator::default(), graph: SceneGraph { nodes, root: k as u32 }, trees: vec![gtree] };
    write_scene_file(&top, &scene, &WriteOptions::default()).expect("write");
    for deep in [false, true] {
        let before = crate::fsio::OPENS.with(|c| c.get());
        let r = validate_file(&top, &ValidateOptions { deep, ..Default::default() }).expect("validate");
        assert!(r.is_valid(), "{:?}", r.issues);
        assert_eq!(r.files.len(), 2);
        assert_eq!(crate::fsio::OPENS.with(|c| c.get()) - before, 2, "the top file and the target, once each");
        // A wrong hash is still reported at every inline that records it.
    }
    let mut bad = scene;
    if let GraphNode::Inline { hash, .. } = &mut bad.graph.nodes[7] {
        hash[0] ^= 1;
    }
    write_scene_file(&top, &bad, &WriteOptions::default()).expect("write");
    let r = validate_file(&top, &ValidateOptions::default()).expect("validate");
    assert_eq!(r.check_ids(), vec![CheckId::InlineHash]);
    assert_eq!(r.issues.len(), 1);
}

#[test]
fn level_bits_select() {
    let mut b = LevelBits::default();
    for i in 0..200 {
        b.push(i % 3 == 0);
    }
    b.finish();
    assert_eq!(b.select(0), Some(0));
    assert_eq!(b.select(22), Some(66));
    assert_eq!(b.select(66), Some(198));
    assert_eq!(b.select(67), None);
}

#[test]
fn transform_checks() {
    let mut t = Similarity::IDENTITY;
    t.rotation = [0.0, 0.0, 0.0, 2.0];
    t.scale = -1.0;
    let ids: Vec<CheckId> = transform_problems(&t).into_iter().map(|p| p.0).collect();
    assert_eq!(ids, vec![CheckId::Quaternion, CheckId::Scale]);
    t.translation[0] = f64::NAN;
    assert_eq!(transform_problems(&t)[0].0, CheckId::NonFinite);
}

/// Affine instances are checked like similarity instances: a NaN entry is `non-finite`, a
/// singular or ill-conditioned matrix `affine`, each at its graph node.
#[test]
fn affine_matrices_are_checked() {
    use crate::raw::cursor::Put;
    let id = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]];
    let mut nan = id;
    nan[0][0] = f64::NAN;
    let mut singular = id;
    singular[1] = [0.0; 4];
    let mut flat = id;
    flat[2][2] = 1e-8;
    let mats = [id, nan, singular, flat];
    let mut b = Vec::new();
    b.put_u64(mats.len() as u64 + 1);
    b.put_u32(0);
    b.put_u8(crate::write::kind::TREE);
    b.put_u32(0);
    for m in &mats {
        b.put_u8(crate::write::kind::AFFINE);
        b.put_u32(0);
        m.iter().flatten().for_each(|v| b.put_f64(*v));
        b.put_u8(0);
        b.extend_from_slice(&[255; 4]);
    }
    let (mut issues, mut omitted) = (Vec::new(), 0);
    let g = parse_graph(&b, 0, &Limits::default(), 100, &mut issues, &mut omitted).expect("parses");
    let ids = |i: u32| g.node_problems.get(&i).map(|p| p.iter().map(|(k, _)| *k).collect::<Vec<_>>()).unwrap_or_default();
    assert_eq!(ids(1), vec![]);
    assert_eq!(ids(2), vec![CheckId::NonFinite]);
    assert_eq!(ids(3), vec![CheckId::Affine]);
    assert_eq!(ids(4), vec![CheckId::Affine]);
}
