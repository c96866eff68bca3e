//! Crafted invalid files: each must produce exactly the expected check id(s), through the
//! binary (`--deep --json`, exit status 1) and in quick mode where the check is structural.

mod common;

use std::path::Path;
use std::process::Command;

use common::*;
use sct_format::{GraphNode, InstanceAttrs, Node, Profile, SceneGraph, SceneTree, Similarity};

fn small_tree() -> SceneTree {
    // 64 bunny leaves keep the corpus fast while using real model points.
    let (v, f) = load_ascii_ply(Path::new(BUNNY));
    let mut leaves = mesh_leaves(&v, &f);
    leaves.truncate(64);
    for l in &mut leaves {
        l.color = [100, 150, 200, 255]; // uniform: edits of area do not move colour means
    }
    kd_tree(leaves)
}

/// Runs the binary and returns (exit status, sorted distinct check ids).
fn check_ids(path: &Path, deep: bool) -> (i32, Vec<String>) {
    let out = Command::new(bin()).arg(path).arg(if deep { "--deep" } else { "--validate" }).arg("--json").output().unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("{e}: stdout {:?} stderr {:?}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr)));
    let mut ids: Vec<String> =
        v["validation"]["issues"].as_array().unwrap().iter().map(|i| i["check"].as_str().unwrap().to_string()).collect();
    ids.sort();
    ids.dedup();
    (out.status.code().unwrap(), ids)
}

fn expect(path: &Path, deep: bool, ids: &[&str]) {
    let (code, got) = check_ids(path, deep);
    assert_eq!(got, ids, "{} (deep {deep})", path.display());
    assert_eq!(code, if ids.is_empty() { 0 } else { 1 });
}

#[test]
fn valid_file_has_no_issues() {
    let d = tmp();
    for p in [Profile::Raw, Profile::Canopy, Profile::Default] {
        let f = path_in(&d, &format!("ok-{}.sct", p.name()));
        write_single(&f, small_tree(), p);
        expect(&f, false, &[]);
        expect(&f, true, &[]);
    }
}

#[test]
fn truncated() {
    let d = tmp();
    let f = path_in(&d, "t.sct");
    write_single(&f, small_tree(), Profile::Raw);
    let b = std::fs::read(&f).unwrap();
    std::fs::write(&f, &b[..b.len() - 100]).unwrap();
    expect(&f, false, &["truncated"]);
    expect(&f, true, &["truncated"]);
}

#[test]
fn bad_checksum() {
    let d = tmp();
    let f = path_in(&d, "c.sct");
    write_single(&f, small_tree(), Profile::Raw);
    let mut b = std::fs::read(&f).unwrap();
    let n = b.len();
    b[n - 3] ^= 0x55; // a colour byte of the last leaf: only the CRCs can notice
    std::fs::write(&f, &b).unwrap();
    expect(&f, false, &["checksum"]);
    expect(&f, true, &["checksum"]);
}

#[test]
fn child_outside_parent() {
    let d = tmp();
    let f = path_in(&d, "o.sct");
    let mut t = small_tree();
    let last = t.len() - 1;
    t.nodes_mut()[last].center[0] += 10.0;
    write_single(&f, t, Profile::Raw);
    expect(&f, true, &["child-outside-parent"]);
    expect(&f, false, &[]); // hierarchical checks are deep only
}

#[test]
fn wrong_area_sum() {
    let d = tmp();
    let f = path_in(&d, "a.sct");
    let mut t = small_tree();
    t.nodes_mut()[1].area *= 1.03;
    write_single(&f, t, Profile::Raw);
    expect(&f, true, &["area-sum"]);
}

#[test]
fn cone_not_containing_child() {
    let d = tmp();
    let f = path_in(&d, "n.sct");
    let mut t = small_tree();
    let last = t.len() - 1;
    let n = &mut t.nodes_mut()[last];
    n.normal = [-n.normal[0], -n.normal[1], -n.normal[2]];
    write_single(&f, t, Profile::Raw);
    expect(&f, true, &["cone-containment"]);
}

#[test]
fn nan_in_any_attribute() {
    let d = tmp();
    type Edit = (&'static str, fn(&mut Node));
    let edits: [Edit; 5] = [
        ("centre", |n| n.center[1] = f32::NAN),
        ("radius", |n| n.radius = f32::NAN),
        ("normal", |n| n.normal[2] = f32::NAN),
        ("cone", |n| n.cone = f32::NAN),
        ("area", |n| n.area = f32::INFINITY),
    ];
    for (name, edit) in edits {
        let f = path_in(&d, &format!("nan-{name}.sct"));
        let mut t = small_tree();
        let last = t.len() - 1;
        edit(&mut t.nodes_mut()[last]);
        write_single(&f, t, Profile::Raw);
        expect(&f, true, &["non-finite"]);
    }
}

#[test]
fn nan_in_tree_root_and_inline_bound() {
    // The root is stored raw in the tree header: quick mode already sees it.
    let d = tmp();
    let f = path_in(&d, "root.sct");
    // The writer refuses a non-finite root, so the root's centre x (the first field of the
    // raw node at offset 32 of the tree header) is patched in a written file.
    write_single(&f, small_tree(), Profile::Raw);
    let bytes = std::fs::read(&f).unwrap();
    std::fs::write(&f, patch_section(&bytes, *b"TREE", |raw| raw[32..36].copy_from_slice(&f32::NAN.to_le_bytes()))).unwrap();
    expect(&f, false, &["non-finite"]);
    expect(&f, true, &["non-finite"]);
    // An inline's recorded bound is in the graph: quick reports it, deep also finds that it
    // does not match the target's root.
    let inner = path_in(&d, "inner.sct");
    let t = small_tree();
    let mut b = bound_of(&t);
    write_single(&inner, t, Profile::Raw);
    b.radius = f32::NAN;
    let f = path_in(&d, "inline.sct");
    write(&f, SceneGraph { nodes: vec![GraphNode::Inline { path: "inner.sct".into(), hash: *blake3_of(&inner), bound: b }], root: 0 }, vec![], Profile::Raw);
    expect(&f, false, &["non-finite"]);
    expect(&f, true, &["inline-bound", "non-finite"]);
}

fn bound_of(t: &SceneTree) -> Node {
    t.nodes()[0]
}

#[test]
fn inline_cycle() {
    let d = tmp();
    let f = path_in(&d, "self.sct");
    let b = bound_of(&small_tree());
    write(&f, SceneGraph { nodes: vec![GraphNode::Inline { path: "self.sct".into(), hash: [0; 32], bound: b }], root: 0 }, vec![], Profile::Raw);
    expect(&f, false, &["inline-cycle"]);
    expect(&f, true, &["inline-cycle"]);
}

#[test]
fn missing_inline_target() {
    let d = tmp();
    let f = path_in(&d, "m.sct");
    let b = bound_of(&small_tree());
    write(&f, SceneGraph { nodes: vec![GraphNode::Inline { path: "sub/gone.sct".into(), hash: [0; 32], bound: b }], root: 0 }, vec![], Profile::Raw);
    expect(&f, false, &["inline-missing"]);
}

#[test]
fn inline_hash_and_valid_inline() {
    let d = tmp();
    let inner = path_in(&d, "inner.sct");
    let t = small_tree();
    let b = bound_of(&t);
    write_single(&inner, t, Profile::Raw);
    let h = *blake3_of(&inner);
    let ok = path_in(&d, "ok.sct");
    write(&ok, SceneGraph { nodes: vec![GraphNode::Inline { path: "inner.sct".into(), hash: h, bound: b }], root: 0 }, vec![], Profile::Raw);
    expect(&ok, true, &[]);
    let bad = path_in(&d, "bad.sct");
    write(&bad, SceneGraph { nodes: vec![GraphNode::Inline { path: "inner.sct".into(), hash: [7; 32], bound: b }], root: 0 }, vec![], Profile::Raw);
    expect(&bad, false, &["inline-hash"]);
}

fn blake3_of(p: &Path) -> Box<[u8; 32]> {
    // The hash the writer of an inline records: BLAKE3 of the target's bytes.
    let hex = sct_format::atomic::hash_file(p).unwrap();
    let mut h = [0u8; 32];
    for (i, b) in h.iter_mut().enumerate() {
        *b = u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).unwrap();
    }
    Box::new(h)
}

/// An instance file whose transform is then patched in the (decompressed, rewritten) graph.
fn instance_file(path: &Path, patch: impl Fn(&mut Vec<u8>)) {
    let t = small_tree();
    let tr = Similarity { translation: [1.0, 2.0, 3.0], rotation: [0.0, 0.0, 0.0, 1.0], scale: 2.0 };
    write(
        path,
        SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }, GraphNode::Instance { child: 0, transform: tr, attrs: InstanceAttrs::default() }], root: 1 },
        vec![t],
        Profile::Raw,
    );
    let b = std::fs::read(path).unwrap();
    std::fs::write(path, patch_section(&b, *b"GRPH", patch)).unwrap();
}

// GRPH layout: u64 count, u32 root; node 0 (tree): kind u8 + u32; node 1 (instance) starts at
// byte 17: kind, child u32, translation 3×f64 (22..46), rotation 4×f64 (46..78), scale f64 (78..86).
const ROT_W: usize = 70;
const SCALE: usize = 78;

#[test]
fn non_unit_quaternion() {
    let d = tmp();
    let f = path_in(&d, "q.sct");
    instance_file(&f, |g| g[ROT_W..ROT_W + 8].copy_from_slice(&1.5f64.to_le_bytes()));
    expect(&f, false, &["quaternion"]);
    expect(&f, true, &["quaternion"]);
    // The unpatched rewrite is valid: the patch tool itself changes nothing else.
    let ok = path_in(&d, "q-ok.sct");
    instance_file(&ok, |_| {});
    expect(&ok, true, &[]);
}

#[test]
fn non_positive_scale_and_nan_transform() {
    let d = tmp();
    let f = path_in(&d, "s.sct");
    instance_file(&f, |g| g[SCALE..SCALE + 8].copy_from_slice(&(-2.0f64).to_le_bytes()));
    expect(&f, false, &["scale"]);
    let f = path_in(&d, "tn.sct");
    instance_file(&f, |g| g[22..30].copy_from_slice(&f64::NAN.to_le_bytes()));
    expect(&f, false, &["non-finite"]);
}

#[test]
fn group_leaf_must_bound_instanced_child() {
    let d = tmp();
    let f = path_in(&d, "g.sct");
    let t = small_tree();
    let tr = Similarity { translation: [5.0, 0.0, 0.0], rotation: [0.0, 0.0, 0.0, 1.0], scale: 2.0 };
    // Group leaves: the untransformed root twice, so leaf 1 misses the instance's transform.
    let r = t.nodes()[0];
    let gt = SceneTree::from_bfs(vec![sct_format::geometry::parent_of(&r, &r), r, r], vec![true, false, false]).unwrap();
    let nodes = vec![
        GraphNode::Tree { tree: 0 },
        GraphNode::Instance { child: 0, transform: tr, attrs: InstanceAttrs::default() },
        GraphNode::Group { children: vec![0, 1], tree: 1 },
    ];
    // The default profile's group-leaf area slack (its coding bound) must not hide a leaf
    // that lacks the instance's scale² (area off by 4×).
    for profile in [Profile::Raw, Profile::Default] {
        write(&f, SceneGraph { nodes: nodes.clone(), root: 2 }, vec![t.clone(), gt.clone()], profile);
        expect(&f, false, &[]);
        let (code, ids) = check_ids(&f, true);
        assert_eq!(code, 1);
        assert!(ids.contains(&"child-outside-parent".to_string()) && ids.contains(&"area-sum".to_string()), "{profile:?}: {ids:?}");
    }
}
