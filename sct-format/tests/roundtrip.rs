//! Writer → reader round trips: structure exact, attributes exact (raw) or within the
//! codec's bounds (canopy, default).

mod common;

use sct_format::read::SctReader;
use sct_format::{write_scene, Generator, LeafRefinement, Limits, Node, Profile, Scene, SceneTree, WriteOptions};

fn write(tree: &SceneTree, profile: Profile) -> Vec<u8> {
    write_with(tree, WriteOptions { profile, block_nodes: 4096, ..Default::default() })
}

fn write_with(tree: &SceneTree, opts: WriteOptions) -> Vec<u8> {
    let scene = Scene::single_tree(Generator { tool: "test".into(), version: "0".into(), ..Default::default() }, tree.clone());
    let mut bytes = Vec::new();
    let stats = write_scene(&scene, &opts, &mut bytes).expect("write");
    assert_eq!(stats.bytes as usize, bytes.len());
    bytes
}

fn dist(a: [f32; 3], b: [f32; 3]) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn check_within_bounds(orig: &SceneTree, got: &SceneTree, profile: Profile) {
    assert_eq!(orig.internal_flags(), got.internal_flags(), "structure must be exact");
    let depth: Vec<usize> = (0..orig.level_count()).flat_map(|d| orig.level(d).map(move |_| d)).collect();
    let mut rel_sum = 0f64;
    for (i, (a, b)) in orig.nodes().iter().zip(got.nodes()).enumerate() {
        if profile == Profile::Raw {
            assert_eq!(a, b, "raw node {i}");
            continue;
        }
        // The decoded sphere contains the original one (f32 rounding allowance).
        let slack = 1e-4 * a.radius.max(1e-3) + 1e-5;
        assert!(dist(a.center, b.center) + a.radius <= b.radius + slack, "node {i}: decoded {b:?} does not contain {a:?}");
        // Colour within 5-bit quantisation.
        for ch in 0..3 {
            assert!((a.color[ch] as i32 - b.color[ch] as i32).abs() <= 8, "node {i} colour {:?} vs {:?}", a.color, b.color);
        }
        assert!(b.cone + 1e-4 >= a.cone.min(std::f32::consts::PI), "node {i}: cone shrank");
        let rel = (a.area - b.area).abs() / a.area.max(1e-12);
        rel_sum += rel as f64;
        // Default: each level moves a child's area by at most half an 8-code step of the
        // parent's, 4/4096 (≤ 0.49 % of a child holding ≥ 20 % as in `random_tree`); the
        // errors of the levels above add up (spec/SCT-profiles.md §4).
        let bound = if profile == Profile::Default { 0.0049 * depth[i] as f32 + 1e-4 } else { 1e-6 };
        assert!(rel < bound || (a.area - b.area).abs() < 1e-6, "node {i} (depth {}): area {} vs {}", depth[i], a.area, b.area);
    }
    // They add up like a random walk, not linearly: small on average.
    let mean = rel_sum / orig.len() as f64;
    assert!(mean < if profile == Profile::Default { 0.005 } else { 1e-6 }, "mean relative area error {mean}");
}

#[test]
fn million_node_tree_round_trips_in_every_profile() {
    let tree = common::random_tree(7, 1_000_001, false);
    assert!(tree.len() >= 1_000_000);
    for profile in [Profile::Raw, Profile::Canopy, Profile::Default] {
        let bytes = write(&tree, profile);
        let r = SctReader::from_bytes(bytes, &Limits::default()).expect("read");
        r.verify_checksums().expect("checksums");
        let got = r.read_tree(0).expect("decode");
        check_within_bounds(&tree, &got, profile);
    }
}

#[test]
fn alpha_trees_round_trip() {
    let tree = common::random_tree(11, 5000, true);
    for profile in [Profile::Raw, Profile::Canopy, Profile::Default] {
        let r = SctReader::from_bytes(write(&tree, profile), &Limits::default()).expect("read");
        check_within_bounds(&tree, &r.read_tree(0).expect("decode"), profile);
    }
}

#[test]
fn first_levels_read_without_deeper_blocks() {
    let tree = common::random_tree(3, 200_000, false);
    let bytes = write(&tree, Profile::Default);
    let file_len = bytes.len() as u64;
    let r = SctReader::from_bytes(bytes, &Limits::default()).expect("read");
    let before = r.bytes_read();
    let prefix = r.read_tree_levels(0, 4).expect("prefix");
    assert_eq!(prefix.level_count(), 4);
    let full = r.read_tree(0).expect("full");
    assert_eq!(&full.nodes()[..prefix.len()], prefix.nodes(), "prefix decodes identically");
    // Four levels are a small fraction of the file.
    assert!(r.bytes_read() - before < file_len, "read {} of {file_len}", r.bytes_read() - before);
    let idx = &r.trees()[0];
    let prefix_blocks: u64 = (1..4).flat_map(|d| idx.level_blocks(d)).map(|b| idx.blocks[b].stored_len as u64).sum();
    assert!(prefix_blocks * 10 < file_len, "prefix blocks {prefix_blocks} vs file {file_len}");
}

#[test]
fn random_access_by_block_matches_full_decode() {
    let tree = common::random_tree(5, 100_000, false);
    let r = SctReader::from_bytes(write(&tree, Profile::Canopy), &Limits::default()).expect("read");
    let full = r.read_tree(0).expect("full");
    let idx = &r.trees()[0];
    // Decode the last block of the deepest level with parents taken from the full decode.
    let d = idx.levels.len() - 1;
    let b = idx.level_blocks(d).end - 1;
    let e = idx.blocks[b];
    let prev = full.level(d - 1);
    let parents: Vec<Node> = full.nodes()[prev].iter().zip(&full.internal_flags()[full.level(d - 1)]).filter(|(_, &f)| f).map(|(n, _)| *n).collect();
    let lo = (e.first_node / 2) as usize;
    let blk = r.decode_block(0, b, &parents[lo..lo + e.node_count as usize / 2]).expect("block");
    let start = full.level(d).start + e.first_node as usize;
    assert_eq!(blk.nodes, full.nodes()[start..start + e.node_count as usize]);
    assert_eq!(idx.block_of(d, e.first_node), Some(b));
}

#[test]
fn single_leaf_and_empty_trees() {
    let leaf = SceneTree::from_bfs(vec![Node { radius: 1.0, area: 1.0, color: [1, 2, 3, 255], ..Default::default() }], vec![false]).expect("tree");
    for profile in [Profile::Raw, Profile::Canopy, Profile::Default] {
        let r = SctReader::from_bytes(write(&leaf, profile), &Limits::default()).expect("read");
        assert_eq!(r.read_tree(0).expect("decode"), leaf);
    }
    let empty = SceneTree::from_bfs(vec![], vec![]).expect("tree");
    let r = SctReader::from_bytes(write(&empty, Profile::Default), &Limits::default()).expect("read");
    assert!(r.read_tree(0).expect("decode").is_empty());
}

#[test]
fn output_is_identical_with_one_and_two_threads() {
    let tree = common::random_tree(9, 300_000, false);
    let run = |threads| {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool").install(|| write(&tree, Profile::Default))
    };
    assert_eq!(run(1), run(2));
}

#[test]
fn two_sided_flag_round_trips_and_labels_the_file_1_1() {
    let mut tree = common::random_tree(11, 2_001, false);
    let v10 = |profile| WriteOptions { profile, block_nodes: 4096, centre_offsets: false, ..Default::default() };
    let one_sided = write_with(&tree, v10(Profile::Default));
    // Without a two-sided tree (or centre offsets) the file is a 1.0 file, byte for byte as before.
    assert_eq!(u16::from_le_bytes([one_sided[10], one_sided[11]]), 0, "minor version");
    let r = SctReader::from_bytes(one_sided, &Limits::default()).expect("read");
    assert!(!r.trees()[0].two_sided() && !r.read_tree(0).expect("decode").is_two_sided());

    tree.set_two_sided(true);
    for profile in [Profile::Raw, Profile::Canopy, Profile::Default] {
        let bytes = write_with(&tree, v10(profile));
        assert_eq!(u16::from_le_bytes([bytes[10], bytes[11]]), 1, "minor version ({profile:?})");
        let r = SctReader::from_bytes(bytes, &Limits::default()).expect("read");
        assert!(r.trees()[0].two_sided(), "{profile:?}");
        assert!(r.read_tree(0).expect("decode").is_two_sided(), "{profile:?}");
    }
    // The streaming file writer labels the same way.
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("two.sct");
    let scene = Scene::single_tree(Generator { tool: "test".into(), version: "0".into(), ..Default::default() }, tree.clone());
    sct_format::write::write_scene_file(&path, &scene, &WriteOptions { centre_offsets: false, ..Default::default() }).expect("write file");
    let r = SctReader::open(&path, &Limits::default()).expect("open");
    assert_eq!(r.header().minor, 1);
    assert!(r.trees()[0].two_sided());
}

/// Centre offsets (1.2, the default) put the leaves of a plane back on the plane: without
/// them the position code leaves them up to about a fifth of their parent's radius off it.
/// Raw and canopy files never carry them; a file with them is labelled 1.2 by both writers.
#[test]
fn centre_offsets_put_leaves_on_their_plane_and_label_the_file_1_2() {
    let tree = common::planar_tree(5, 20_001);
    let worst = |bytes: Vec<u8>| {
        let r = SctReader::from_bytes(bytes, &Limits::default()).expect("read");
        let t = r.read_tree(0).expect("decode");
        let mut worst = 0f32;
        for i in 0..t.len() {
            if !t.is_internal(i) {
                // Relative to the leaf's own radius: the leaves are of every size.
                let (n, k) = (t.nodes()[i], common::PLANE_NORMAL);
                let off = (n.center[0] - 1.0) * k[0] + (n.center[1] + 2.0) * k[1] + (n.center[2] - 3.0) * k[2];
                worst = worst.max(off.abs() / n.radius);
            }
        }
        worst
    };
    let with = write_with(&tree, WriteOptions { block_nodes: 4096, ..Default::default() });
    assert_eq!(u16::from_le_bytes([with[10], with[11]]), 2, "minor version");
    let without = write_with(&tree, WriteOptions { block_nodes: 4096, centre_offsets: false, ..Default::default() });
    assert_eq!(u16::from_le_bytes([without[10], without[11]]), 0, "minor version");
    let (w, wo) = (worst(with), worst(without));
    assert!(w <= 0.01, "with centre offsets leaves lie up to {w} of their radius off the plane");
    assert!(wo >= 0.05, "without centre offsets the position code alone was expected to err (worst {wo})");
    for profile in [Profile::Raw, Profile::Canopy] {
        let bytes = write(&tree, profile);
        assert_eq!(u16::from_le_bytes([bytes[10], bytes[11]]), 0, "minor version ({profile:?})");
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("offsets.sct");
    let scene = Scene::single_tree(Generator { tool: "test".into(), version: "0".into(), ..Default::default() }, tree);
    sct_format::write::write_scene_file(&path, &scene, &WriteOptions::default()).expect("write file");
    assert_eq!(SctReader::open(&path, &Limits::default()).expect("open").header().minor, 2);
}

#[test]
fn leaf_refinement_puts_leaves_at_their_place_and_size_and_labels_the_file_1_4() {
    let tree = common::planar_tree(7, 20_001);
    let orig = tree.nodes().to_vec();
    // Per leaf: centre error and radius, both relative to the original leaf's radius.
    let errors = |bytes: &[u8]| {
        let r = SctReader::from_bytes(bytes.to_vec(), &Limits::default()).expect("read");
        let t = r.read_tree(0).expect("decode");
        let leaves = t.nodes().iter().zip(&orig).enumerate().filter(|&(i, _)| !t.is_internal(i));
        leaves.map(|(_, (d, o))| (dist(d.center, o.center) / o.radius, d.radius / o.radius)).collect::<Vec<_>>()
    };
    let refined = write_with(&tree, WriteOptions { block_nodes: 4096, leaf_refinement: LeafRefinement::All, ..Default::default() });
    assert_eq!(u16::from_le_bytes([refined[10], refined[11]]), 4, "minor version");
    let plain = write_with(&tree, WriteOptions { block_nodes: 4096, ..Default::default() });
    assert_eq!(u16::from_le_bytes([plain[10], plain[11]]), 2, "minor version");
    let (r, p) = (errors(&refined), errors(&plain));
    let worst = |v: &[(f32, f32)], f: fn(&(f32, f32)) -> f32| v.iter().map(f).fold(0f32, f32::max);
    let mean = |v: &[(f32, f32)], f: fn(&(f32, f32)) -> f32| v.iter().map(f).sum::<f32>() / v.len() as f32;
    // Every leaf: within √3/256 of its decoded radius per axis, radius cut to within a step.
    assert!(worst(&r, |e| e.0) <= 0.02, "refined centre error up to {} radii", worst(&r, |e| e.0));
    assert!(worst(&r, |e| e.1) <= 1.03, "refined radius up to {}× the original", worst(&r, |e| e.1));
    assert!(mean(&p, |e| e.1) >= 1.1 && worst(&p, |e| e.0) >= 0.1, "without refinement the state alone was expected to err");
    // Only the listed trees are refined; raw and canopy never are.
    let other = write_with(&tree, WriteOptions { block_nodes: 4096, leaf_refinement: LeafRefinement::Trees(vec![1]), ..Default::default() });
    assert_eq!(other, plain, "tree 0 is not listed");
    for profile in [Profile::Raw, Profile::Canopy] {
        let bytes = write_with(&tree, WriteOptions { profile, leaf_refinement: LeafRefinement::All, ..Default::default() });
        assert_eq!(u16::from_le_bytes([bytes[10], bytes[11]]), 0, "minor version ({profile:?})");
    }
}
