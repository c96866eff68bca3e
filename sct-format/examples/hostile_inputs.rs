//! Writes the worst inputs of under 1 MB that the default limits accept, to measure what each
//! tool costs on them (README, "Resource bounds per tool"):
//!
//! ```text
//! cargo run --release -p sct-format --example hostile_inputs -- DIR
//! ```
//!
//! Every file is valid (passes `sct-inspect --deep`) or is refused only by what it means, and
//! compresses as far as zstd allows: trees of identical nodes, samples all at one point. The
//! decoded-size bound (spec §2.3) lets a file stand for `max(256 MiB, 256 × its size)`, so
//! a file under 1 MB stands for at most 268 MB, 6.7 M nodes or samples at 40 bytes: each
//! file below asks for close to that. They are padded to just under 1 MB with a section
//! readers skip (unknown, not required), which is what the ratio alone would need.
//!
//! - `tree-identical.sct`: two perfect trees of identical nodes (4.2 M and 2.1 M nodes, blocks
//!   of 2 M nodes, 84 MB each inflated), 252 MB decoded; the graph reaches the first.
//! - `dag.sct`: 60 groups, each using the previous one twice (2^60 paths).
//! - `inlines.sct`: a group of 65,536 inlines of `tree-identical.sct`.
//! - `samples-coincident.samples`: 6.3 M identical samples at one point.
//! - `samples-line.samples`: 6.3 M distinct samples on a line, as compressible.
//! - `samples-inst.samples`: one sample placed 3.7 M times (identical similarity placements).
//! - `samples-affine.samples`: a mesh of 65,536 samples placed by 95 affine matrices (6.2 M
//!   baked samples).

#[path = "../tests/common/craft.rs"]
mod craft;

use std::path::Path;

use sct_format::container::Container;
use sct_format::geometry::parent_of;
use sct_format::raw::{tags, SAMPLES_MAGIC, SCT_MAGIC};
use sct_format::samples::{AffineInstance, SampleInstance, SamplesFile};
use sct_format::{write_scene, Generator, GraphNode, Limits, Node, Profile, Scene, SceneGraph, SceneTree, Similarity, WriteOptions};

/// The size every padded file is brought to: under 1 MB (10^6 bytes).
const PADDED: usize = 999_000;

fn node(area: f32) -> Node {
    Node { center: [0.0; 3], radius: 0.5, normal: [0.0, 0.0, 1.0], cone: 0.0, area, color: [200, 100, 50, 255] }
}

/// A perfect tree of depth `depth` whose nodes on each level are identical (so each level's
/// block compresses to almost nothing) and consistent: a parent of two identical children
/// is the child with twice the area.
fn identical_tree(depth: u32) -> SceneTree {
    let (mut nodes, mut internal) = (Vec::new(), Vec::new());
    for d in 0..=depth {
        let n = node(2f32.powi((depth - d) as i32));
        nodes.extend(std::iter::repeat_n(n, 1 << d));
        internal.extend(std::iter::repeat_n(d < depth, 1 << d));
    }
    SceneTree::from_bfs(nodes, internal).expect("perfect tree")
}

/// A balanced tree over `leaves`, breadth first, parents by [`parent_of`].
fn balanced(leaves: &[Node]) -> SceneTree {
    fn bound(ls: &[Node]) -> Node {
        if ls.len() == 1 {
            return ls[0];
        }
        let m = ls.len() / 2;
        parent_of(&bound(&ls[..m]), &bound(&ls[m..]))
    }
    let mut q = std::collections::VecDeque::from([(0usize, leaves.len())]);
    let (mut nodes, mut flags) = (Vec::new(), Vec::new());
    while let Some((a, b)) = q.pop_front() {
        nodes.push(bound(&leaves[a..b]));
        flags.push(b - a > 1);
        if b - a > 1 {
            let m = a + (b - a) / 2;
            q.push_back((a, m));
            q.push_back((m, b));
        }
    }
    SceneTree::from_bfs(nodes, flags).expect("balanced tree")
}

fn scene_bytes(graph: SceneGraph, trees: Vec<SceneTree>) -> Vec<u8> {
    let opts = WriteOptions { profile: Profile::Raw, compression_level: Some(3), block_nodes: 1 << 21, ..Default::default() };
    let mut out = Vec::new();
    write_scene(&Scene { generator: Generator::default(), graph, trees }, &opts, &mut out).expect("write scene");
    out
}

/// `bytes` (a container with `magic` whose sections are `known`) with an extra section that
/// readers skip (tag `PADD`, not required), making the file `len` bytes long.
fn pad(bytes: &[u8], magic: [u8; 8], known: &[[u8; 4]], len: usize) -> Vec<u8> {
    let c = Container::parse(bytes, magic, "container", known, &Limits::unlimited()).expect("parse own file");
    let mut secs: Vec<craft::Sec> = c
        .sections
        .iter()
        .map(|e| craft::Sec { tag: e.tag, flags: e.flags, at: None, stored: c.stored(e).expect("stored").to_vec(), raw_len: e.raw_len })
        .collect();
    let now = craft::container(magic, &secs).len();
    assert!(now + 40 <= len, "{now} bytes already");
    secs.push(craft::Sec { tag: *b"PADD", flags: 0, at: None, stored: vec![0x5A; len - now - 40], raw_len: (len - now - 40) as u64 });
    let out = craft::container(magic, &secs);
    assert_eq!(out.len(), len);
    out
}

fn write(dir: &Path, name: &str, bytes: &[u8]) {
    std::fs::write(dir.join(name), bytes).expect("write");
    println!("{name}: {} bytes", bytes.len());
}

fn samples_bytes(f: &SamplesFile) -> Vec<u8> {
    let mut out = Vec::new();
    f.write_to(&mut out).expect("write samples");
    out
}

fn main() {
    let dir = std::env::args().nth(1).expect("usage: hostile_inputs DIR");
    let dir = Path::new(&dir);
    std::fs::create_dir_all(dir).expect("mkdir");
    let scene_known = [tags::GENR, tags::GRPH, tags::TREE];

    // Two perfect trees of identical nodes; the graph reaches the first (export and render
    // work on it), deep validation checks both.
    let big = scene_bytes(SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }], root: 0 }, vec![identical_tree(21), identical_tree(20)]);
    let big = pad(&big, SCT_MAGIC, &scene_known, PADDED);
    write(dir, "tree-identical.sct", &big);

    // 60 groups, group k over [k-1, k-1]; every bound is the same node.
    let b = node(1.0);
    let mut nodes = vec![GraphNode::Tree { tree: 0 }];
    for k in 1..=60u32 {
        nodes.push(GraphNode::Group { tree: 1, children: vec![k - 1, k - 1] });
    }
    let single = SceneTree::from_bfs(vec![b], vec![false]).expect("leaf");
    let dag = scene_bytes(SceneGraph { nodes, root: 60 }, vec![single, balanced(&[b, b])]);
    write(dir, "dag.sct", &dag);

    // 65,536 inlines of the big file, in one group.
    let hash = *blake3::hash(&big).as_bytes();
    let root = sct_format::SctReader::from_bytes(big.clone(), &Limits::default()).expect("reads").trees()[0].header.root;
    let n = 65_536u32;
    let mut nodes: Vec<GraphNode> = (0..n).map(|_| GraphNode::Inline { path: "tree-identical.sct".into(), hash, bound: root }).collect();
    nodes.push(GraphNode::Group { tree: 0, children: (0..n).collect() });
    let inl = scene_bytes(SceneGraph { nodes, root: n }, vec![balanced(&vec![root; n as usize])]);
    write(dir, "inlines.sct", &inl);

    let samples_known = [tags::GENR, tags::MESH, tags::INST, *b"SMPS", *b"AFFI"];
    let sample = node(1e-4);
    // Samples all at one point.
    let f = SamplesFile::single_mesh(Generator::default(), "point", vec![sample; 6_300_000]);
    write(dir, "samples-coincident.samples", &pad(&samples_bytes(&f), SAMPLES_MAGIC, &samples_known, PADDED));

    // Distinct samples on a line whose x coordinates step by 64 units in the last place:
    // their centres' differences are constant, so they compress as well as one point.
    let line: Vec<Node> = (0..6_300_000u32).map(|i| Node { center: [f32::from_bits(0x3F80_0000 + 64 * i), 0.0, 0.0], ..sample }).collect();
    let f = SamplesFile::single_mesh(Generator::default(), "line", line);
    write(dir, "samples-line.samples", &pad(&samples_bytes(&f), SAMPLES_MAGIC, &samples_known, PADDED));

    // One sample placed many times, identically.
    let mut f = SamplesFile::single_mesh(Generator::default(), "point", vec![sample]);
    f.instances = vec![SampleInstance { mesh: 0, transform: Similarity::IDENTITY }; 3_700_000];
    write(dir, "samples-inst.samples", &pad(&samples_bytes(&f), SAMPLES_MAGIC, &samples_known, PADDED));

    // A mesh of one chunk, baked once per affine placement.
    let mut f = SamplesFile::single_mesh(Generator::default(), "chunk", vec![sample; 65_536]);
    let m = AffineInstance { mesh: 0, matrix: [[2.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]] };
    f.affine_instances = vec![m; 95];
    write(dir, "samples-affine.samples", &pad(&samples_bytes(&f), SAMPLES_MAGIC, &samples_known, PADDED));
}
