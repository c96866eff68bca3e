//! Structure-aware fuzzing of whole SCT and samples files. The input is a recipe: it builds a
//! valid file (scene trees of every profile, graphs of trees, instances, groups and inlines;
//! samples files of meshes, similarity and affine placements in SMPS, SMPC or SMPL chunks),
//! then mutates it by meaning (counts, offsets, table entries, graph records, block and chunk
//! payloads, zstd frames that inflate far, sections that alias others) and recomputes every
//! checksum, so the readers only see files they must reject by what the bytes mean.
//!
//! Any error is fine. Findings are panics, hangs (-timeout), memory past -rss_limit_mb, and
//! inconsistencies: a file deep validation calls valid that the reader then refuses or cannot
//! decode, or a decoded tree whose size differs from its header.
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "../../sct-format/tests/common/craft.rs"]
mod craft;

use std::path::PathBuf;
use std::sync::OnceLock;

use craft::Sec;
use sct_format::geometry::parent_of;
use sct_format::raw::{tags, BlockEntry, LevelEntry, SectionEntry, TreeHeader, SAMPLES_MAGIC, SCT_MAGIC, SECTION_ENTRY_LEN};
use sct_format::samples::{AffineInstance, MeshEntry, SampleInstance, SamplesFile};
use sct_format::traverse::{Traversal, TraverseOptions};
use sct_format::validate::{validate_bytes, validate_file, ValidateOptions};
use sct_format::{
    write_scene, Affine, Generator, GraphNode, InstanceAttrs, LeafRefinement, Limits, Node, Profile, Propagation, Scene, SceneGraph, SceneTree,
    SctReader, Similarity, Transform, WriteOptions,
};

/// Reads the recipe; zeros once it is used up.
struct Recipe<'a>(&'a [u8]);

impl Recipe<'_> {
    fn byte(&mut self) -> u8 {
        match self.0.split_first() {
            Some((&b, rest)) => {
                self.0 = rest;
                b
            }
            None => 0,
        }
    }
    fn below(&mut self, n: usize) -> usize {
        if n <= 1 {
            return 0;
        }
        let v = if n > 256 { (self.byte() as usize) << 8 | self.byte() as usize } else { self.byte() as usize };
        v % n
    }
    fn bool(&mut self) -> bool {
        self.byte() & 1 == 1
    }
    fn u64(&mut self) -> u64 {
        (0..8).fold(0u64, |a, _| a << 8 | self.byte() as u64)
    }
    /// A value worth trying for a field that holds `cur`.
    fn interesting(&mut self, cur: u64, other: u64) -> u64 {
        match self.below(18) {
            0 => 0,
            1 => 1,
            2 => 2,
            3 => cur.wrapping_add(1),
            4 => cur.wrapping_sub(1),
            5 => cur.wrapping_add(2),
            6 => cur.wrapping_mul(2),
            7 => cur / 2,
            8 => u32::MAX as u64,
            9 => u32::MAX as u64 + 1,
            10 => u64::MAX,
            11 => 1 << 31,
            12 => 1 << 20,
            13 => other,
            14 => other.wrapping_add(1),
            15 => cur ^ (1 << self.below(64)),
            16 => 65_536,
            _ => self.u64(),
        }
    }
}

fn limits() -> Limits {
    Limits {
        max_decompressed_bytes: 1 << 24,
        max_tree_nodes: 1 << 20,
        max_graph_nodes: 1 << 16,
        max_graph_bytes: 1 << 23,
        max_traversal_visits: 20_000,
        max_samples: 1 << 20,
        max_sample_bytes: 1 << 25,
        // A low floor, so that the decoded-size bound (ratio × file size) decides often.
        decoded_floor: 1 << 16,
        ..Limits::default()
    }
}

fn leaf(r: &mut Recipe) -> Node {
    let c = |r: &mut Recipe| (r.byte() as i8) as f32 * 0.25;
    let axes = [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, -0.6, 0.8]];
    Node {
        center: [c(r), c(r), c(r)],
        radius: 0.05 + r.byte() as f32 / 128.0,
        normal: axes[r.below(4)],
        cone: 0.0,
        area: 0.01 + r.byte() as f32 / 64.0,
        color: [r.byte(), r.byte(), r.byte(), if r.below(4) == 0 { r.byte() } else { 255 }],
    }
}

/// A consistent tree over `leaves` (balanced, breadth first).
fn tree_of(leaves: &[Node]) -> SceneTree {
    if leaves.is_empty() {
        return SceneTree::default();
    }
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

/// A scratch directory for file-based checks (traversal, inlines, FIFO-free regular files).
fn scratch() -> &'static (PathBuf, [u8; 32]) {
    static DIR: OnceLock<(PathBuf, [u8; 32])> = OnceLock::new();
    DIR.get_or_init(|| {
        let base = if std::path::Path::new("/dev/shm").is_dir() { PathBuf::from("/dev/shm") } else { std::env::temp_dir() };
        let dir = base.join(format!("sct-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("scratch dir");
        // A valid file the recipes' inlines can name ("other.sct"), with its hash.
        let leaves: Vec<Node> = (0..5).map(|i| Node { center: [i as f32, 0.0, 0.0], radius: 0.5, normal: [0.0, 0.0, 1.0], cone: 0.0, area: 1.0, color: [9, 9, 9, 255] }).collect();
        let scene = Scene::single_tree(Generator::default(), tree_of(&leaves));
        let mut bytes = Vec::new();
        write_scene(&scene, &WriteOptions::default(), &mut bytes).expect("write");
        std::fs::write(dir.join("other.sct"), &bytes).expect("write");
        (dir, *blake3_like(&bytes))
    })
}

/// The inline hash of `bytes` (sct-format's own, so the fuzz crate needs no blake3).
fn blake3_like(bytes: &[u8]) -> &'static [u8; 32] {
    let r = SctReader::from_bytes(bytes.to_vec(), &Limits::default()).expect("valid");
    Box::leak(Box::new(r.content_hash().expect("hash")))
}

// ---------------------------------------------------------------- scene files

/// An affine map the writer accepts: from a menu of shapes near the limits the reader
/// enforces (entries near f32::MAX or tiny, condition near 10⁶, mirrors, shears), or read
/// from the recipe (kept when valid, else a plain stretch).
fn affine_of(r: &mut Recipe) -> Affine {
    let big = f32::MAX as f64;
    let diag = |x: f64, y: f64, z: f64, t: f64| Affine { matrix: [[x, 0.0, 0.0, t], [0.0, y, 0.0, -t], [0.0, 0.0, z, t]] };
    let a = match r.below(10) {
        0 => diag(big, big, big, 0.0),
        1 => diag(-big, big, big, big),
        2 => diag(999.0, 1.0, 1e-3, 0.0),
        3 => diag(1e-30, 1e-30, 1e-30, 1e-30),
        4 => Affine { matrix: [[1.0, 900.0, 0.0, 1e30], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, -1e30]] },
        5 => diag(-1.0, 2.0, 0.5, 3.0),
        _ => {
            let mut m = [[0.0; 4]; 3];
            for v in m.iter_mut().flatten() {
                *v = (r.byte() as i8) as f64 / 16.0;
            }
            Affine { matrix: m }
        }
    };
    if a.is_valid() {
        a
    } else {
        diag(2.0, 1.0, 0.5, 1.0)
    }
}

/// Where each affine instance record starts in a decoded graph (spec §7 record layout), as
/// far as the records parse.
fn affine_records(g: &[u8]) -> Vec<usize> {
    let u32_at = |at: usize| g.get(at..at + 4).map(|s| u32::from_le_bytes(s.try_into().unwrap_or([0; 4])) as usize);
    let u64_at = |at: usize| g.get(at..at + 8).map(|s| u64::from_le_bytes(s.try_into().unwrap_or([0; 8])));
    let mut out = Vec::new();
    let Some(n) = u64_at(0) else { return out };
    let mut at = 12;
    for _ in 0..n.min(1 << 16) {
        let len = match g.get(at) {
            Some(0) => 5,
            Some(1) => match u64_at(at + 5) {
                Some(k) if k < 1 << 20 => 13 + 4 * k as usize,
                _ => break,
            },
            Some(2) => 1 + 4 + 64 + 1 + 4,
            Some(3) => match u32_at(at + 1) {
                // Path, hash, then the bound as a raw node record (40 bytes).
                Some(l) => 5 + l + 32 + 40,
                None => break,
            },
            Some(4) => {
                out.push(at);
                1 + 4 + 96 + 1 + 4
            }
            _ => break,
        };
        at += len;
    }
    out
}

/// Rewrites part of an affine instance record with a hostile value: a matrix entry (NaN,
/// ±inf, zero, past f32::MAX, subnormal, scaled far), a row copied over another (singular),
/// or the child reference (itself, a later node, none).
fn mutate_affine(r: &mut Recipe, g: &mut [u8], node_count: usize) {
    let recs = affine_records(g);
    if recs.is_empty() {
        return;
    }
    let at = recs[r.below(recs.len())];
    let entry = |k: usize| at + 5 + 8 * k;
    let get = |g: &[u8], k: usize| f64::from_le_bytes(g[entry(k)..entry(k) + 8].try_into().unwrap_or([0; 8]));
    match r.below(4) {
        0 | 1 => {
            let k = r.below(12);
            let cur = get(g, k);
            let v = match r.below(14) {
                0 => f64::NAN,
                1 => f64::INFINITY,
                2 => f64::NEG_INFINITY,
                3 => 0.0,
                4 => -cur,
                5 => f32::MAX as f64,
                6 => (f32::MAX as f64).next_up(),
                7 => 1e38,
                8 => -1e38,
                9 => 5e-324,
                10 => cur * 1e6,
                11 => cur * 1e-6,
                12 => 1e300,
                _ => get(g, r.below(12)),
            };
            g[entry(k)..entry(k) + 8].copy_from_slice(&v.to_le_bytes());
        }
        2 => {
            let (a, b) = (r.below(3), r.below(3));
            let row: Vec<u8> = g[entry(4 * a)..entry(4 * a) + 32].to_vec();
            g[entry(4 * b)..entry(4 * b) + 32].copy_from_slice(&row);
        }
        _ => {
            let v = [node_count as u32, u32::MAX, (node_count as u32).wrapping_sub(1), 0][r.below(4)];
            g[at + 1..at + 5].copy_from_slice(&v.to_le_bytes());
        }
    }
}

struct TreeM {
    header: TreeHeader,
    levels: Vec<LevelEntry>,
    /// Entry, payload (decompressed), and an optional stored-bytes override (a hostile frame).
    blocks: Vec<(BlockEntry, Vec<u8>, Option<Vec<u8>>)>,
}

struct SceneM {
    genr: Vec<u8>,
    graph: Vec<u8>,
    graph_zstd: bool,
    /// A hostile GRPH frame and its claimed raw length, instead of `graph`.
    graph_frame: Option<(Vec<u8>, u64)>,
    trees: Vec<TreeM>,
}

fn build_scene(r: &mut Recipe) -> Option<SceneM> {
    let mut trees = Vec::new();
    let mut nodes = Vec::new();
    let mut bounds: Vec<Option<Node>> = Vec::new();
    for _ in 0..1 + r.below(3) {
        let n = if r.below(8) == 0 { 0 } else { 1 + r.below(40) };
        let leaves: Vec<Node> = (0..n).map(|_| leaf(r)).collect();
        let t = tree_of(&leaves);
        bounds.push(t.nodes().first().copied());
        nodes.push(GraphNode::Tree { tree: trees.len() as u32 });
        trees.push(t);
    }
    let unit = [[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.7071067811865476, 0.7071067811865476], [1.0, 0.0, 0.0, 0.0], [0.5, 0.5, 0.5, 0.5]];
    for _ in 0..r.below(7) {
        let k = nodes.len();
        match r.below(5) {
            4 => {
                // An affine instance (format 1.3): a placement the writer accepts; hostile
                // matrices come from [`mutate_affine`] on the bytes.
                let child = r.below(k) as u32;
                let a = affine_of(r);
                let tint = r.bool().then(|| [r.byte(), r.byte(), r.byte(), r.byte()]);
                let attrs = InstanceAttrs {
                    size: if r.bool() { Propagation::PushDown } else { Propagation::PullUp },
                    color: if r.bool() { Propagation::PushDown } else { Propagation::PullUp },
                    tint,
                };
                bounds.push(bounds[child as usize].map(|b| sct_format::traverse::TraversalState::IDENTITY.push(&Transform::from(a), &attrs).apply(&b)));
                nodes.push(GraphNode::Affine { child, transform: a, attrs });
            }
            0 => {
                let child = r.below(k) as u32;
                let t = Similarity {
                    translation: [r.byte() as f64 - 128.0, r.byte() as f64, 0.5],
                    rotation: unit[r.below(4)],
                    scale: [0.5, 1.0, 2.0, 3.25][r.below(4)],
                };
                let tint = r.bool().then(|| [r.byte(), r.byte(), r.byte(), r.byte()]);
                let attrs = InstanceAttrs {
                    size: if r.bool() { Propagation::PushDown } else { Propagation::PullUp },
                    color: if r.bool() { Propagation::PushDown } else { Propagation::PullUp },
                    tint,
                };
                bounds.push(bounds[child as usize].map(|b| sct_format::traverse::TraversalState::IDENTITY.push_instance(&t, &attrs).apply(&b)));
                nodes.push(GraphNode::Instance { child, transform: t, attrs });
            }
            1 => {
                let children: Vec<u32> = (0..1 + r.below(4)).map(|_| r.below(k) as u32).collect();
                let fallback = Node { radius: 1.0, normal: [0.0, 0.0, 1.0], area: 1.0, color: [1, 2, 3, 255], ..Node::default() };
                let leaves: Vec<Node> = children.iter().map(|&c| bounds[c as usize].unwrap_or(fallback)).collect();
                let t = tree_of(&leaves);
                bounds.push(t.nodes().first().copied());
                nodes.push(GraphNode::Group { children, tree: trees.len() as u32 });
                trees.push(t);
            }
            2 => {
                let (path, hash) = match r.below(4) {
                    0 => ("self.sct", [0; 32]),
                    1 => ("../outside.sct", [1; 32]),
                    _ => ("other.sct", scratch().1),
                };
                let b = bounds[r.below(k)].unwrap_or_default();
                bounds.push(Some(b));
                nodes.push(GraphNode::Inline { path: path.into(), hash, bound: b });
            }
            _ => {
                let t = r.below(trees.len()) as u32;
                bounds.push(trees[t as usize].nodes().first().copied());
                nodes.push(GraphNode::Tree { tree: t });
            }
        }
    }
    let root = (nodes.len() - 1 - r.below(2).min(nodes.len() - 1)) as u32;
    let profile = [Profile::Raw, Profile::Canopy, Profile::Default][r.below(3)];
    let opts = WriteOptions {
        profile,
        compression_level: [None, Some(0), Some(1)][r.below(3)],
        block_nodes: 2 + 2 * r.below(12) as u32,
        centre_offsets: r.bool(),
        leaf_refinement: [LeafRefinement::None, LeafRefinement::All, LeafRefinement::Trees(vec![0])][r.below(3)].clone(),
    };
    let mut bytes = Vec::new();
    write_scene(&Scene { generator: Generator::default(), graph: SceneGraph { nodes, root }, trees }, &opts, &mut bytes).ok()?;
    // The file as a model: sections, and each tree's tables and decompressed payloads.
    let rd = SctReader::from_bytes(bytes.clone(), &Limits::default()).expect("the writer's file reads");
    let sec = |tag| rd.sections().iter().find(|e| e.tag == tag).cloned();
    let (genr, grph) = (sec(tags::GENR)?, sec(tags::GRPH)?);
    let stored = |e: &SectionEntry| bytes[e.offset as usize..(e.offset + e.stored_len) as usize].to_vec();
    let graph = if grph.compressed() { zstd::bulk::decompress(&stored(&grph), grph.raw_len as usize).ok()? } else { stored(&grph) };
    let mut tms = Vec::new();
    for t in rd.trees() {
        let mut blocks = Vec::new();
        for b in &t.blocks {
            let at = (t.section.offset + b.offset) as usize;
            let s = &bytes[at..at + b.stored_len as usize];
            let payload = if b.flags & 1 != 0 { zstd::bulk::decompress(s, b.raw_len as usize).ok()? } else { s.to_vec() };
            blocks.push((*b, payload, None));
        }
        tms.push(TreeM { header: t.header.clone(), levels: t.levels.clone(), blocks });
    }
    Some(SceneM { genr: stored(&genr), graph, graph_zstd: grph.compressed(), graph_frame: None, trees: tms })
}

fn flip(r: &mut Recipe, v: &mut [u8]) {
    if !v.is_empty() {
        let i = r.below(v.len());
        match r.below(3) {
            0 => v[i] ^= 1 << r.below(8),
            1 => v[i] = r.byte(),
            _ => v[i] = [0, 0xFF, 0x80, 0x7F][r.below(4)],
        }
    }
}

/// Mutations of the model's content (before layout).
fn mutate_model(r: &mut Recipe, m: &mut SceneM) {
    for _ in 0..r.below(5) {
        let nt = m.trees.len();
        match r.below(13) {
            12 => {
                let n = m.graph.get(..8).map_or(0, |s| u64::from_le_bytes(s.try_into().unwrap_or([0; 8]))) as usize;
                mutate_affine(r, &mut m.graph, n);
            }
            0 => flip(r, &mut m.graph),
            1 => {
                // A graph record's reference or count: a u32 somewhere after the head.
                if m.graph.len() > 16 {
                    let at = 12 + r.below(m.graph.len() - 15);
                    let cur = u32::from_le_bytes(m.graph[at..at + 4].try_into().unwrap_or([0; 4])) as u64;
                    let v = r.interesting(cur, m.graph.len() as u64) as u32;
                    m.graph[at..at + 4].copy_from_slice(&v.to_le_bytes());
                }
            }
            2 => {
                // The node count or the root.
                let (at, len) = if r.bool() { (0, 8) } else { (8, 4) };
                if m.graph.len() >= at + len {
                    let cur = m.graph[at..at + len].iter().rev().fold(0u64, |a, &b| a << 8 | b as u64);
                    let v = r.interesting(cur, 1 << 30).to_le_bytes();
                    m.graph[at..at + len].copy_from_slice(&v[..len]);
                }
            }
            3 if nt > 0 => {
                let t = &mut m.trees[r.below(nt)];
                if !t.blocks.is_empty() {
                    let b = r.below(t.blocks.len());
                    flip(r, &mut t.blocks[b].1);
                }
            }
            4 if nt > 0 => {
                // A block's payload shortened or lengthened (its raw length follows).
                let t = &mut m.trees[r.below(nt)];
                if !t.blocks.is_empty() {
                    let b = r.below(t.blocks.len());
                    let p = &mut t.blocks[b].1;
                    if r.bool() {
                        p.truncate(p.len().saturating_sub(1 + r.below(8)));
                    } else {
                        p.extend((0..1 + r.below(8)).map(|_| 0u8));
                    }
                }
            }
            5 if nt > 0 => {
                // A zstd bomb for a block: an RLE frame claiming far more than its nodes need.
                let t = &mut m.trees[r.below(nt)];
                if !t.blocks.is_empty() {
                    let b = r.below(t.blocks.len());
                    let claim = [u32::MAX as u64, 1 << 24, 1 << 28, t.blocks[b].1.len() as u64 + 1][r.below(4)];
                    t.blocks[b].0.flags |= 1;
                    t.blocks[b].0.raw_len = claim as u32;
                    t.blocks[b].2 = Some(craft::rle_frame(&[], r.byte(), claim));
                }
            }
            6 => {
                let claim = [u32::MAX as u64, (1 << 30) + 13, 1 << 23][r.below(3)];
                m.graph_frame = Some((craft::rle_frame(&m.graph[..m.graph.len().min(12)], 0, claim.max(12)), claim.max(12)));
            }
            7 if nt > 0 => {
                let t = &mut m.trees[r.below(nt)];
                if !t.blocks.is_empty() {
                    let b = r.below(t.blocks.len());
                    t.blocks[b].0.flags ^= 1; // stored plain <-> zstd
                }
            }
            8 => m.graph_zstd = !m.graph_zstd,
            9 => flip(r, &mut m.genr),
            10 if nt > 1 => {
                // Two trees swapped (references now meet the wrong trees).
                let (a, b) = (r.below(nt), r.below(nt));
                m.trees.swap(a, b);
            }
            _ if nt > 0 => {
                // A block's trailing bytes after its zstd frame.
                let t = &mut m.trees[r.below(nt)];
                if !t.blocks.is_empty() {
                    let b = r.below(t.blocks.len());
                    let p = &t.blocks[b].1;
                    let mut f = zstd::bulk::compress(p, 1).unwrap_or_default();
                    f.extend_from_slice(b"xx");
                    let raw = p.len() as u32;
                    t.blocks[b].0.flags |= 1;
                    t.blocks[b].0.raw_len = raw;
                    t.blocks[b].2 = Some(f);
                }
            }
            _ => {}
        }
    }
}

/// Lays the model out: tree sections with fresh block offsets, the container, CRCs. Returns
/// the bytes and where each tree section starts.
fn layout(m: &SceneM, r: &mut Recipe) -> (Vec<u8>, Vec<u64>) {
    let mut secs = vec![Sec::plain(tags::GENR, m.genr.clone())];
    secs.push(match (&m.graph_frame, m.graph_zstd) {
        (Some((f, raw)), _) => Sec::frame(tags::GRPH, f.clone(), *raw),
        (None, true) => Sec::zstd(tags::GRPH, &m.graph),
        (None, false) => Sec::plain(tags::GRPH, m.graph.clone()),
    });
    for t in &m.trees {
        let base = craft::index_len(t.levels.len(), t.blocks.len());
        let mut data = Vec::new();
        let mut entries = Vec::new();
        for (e, payload, over) in &t.blocks {
            let mut e = *e;
            let stored = match over {
                Some(f) => f.clone(),
                None if e.flags & 1 != 0 => {
                    e.raw_len = payload.len() as u32;
                    zstd::bulk::compress(payload, 1).unwrap_or_default()
                }
                None => {
                    e.raw_len = payload.len() as u32;
                    payload.clone()
                }
            };
            e.offset = base + data.len() as u64;
            e.stored_len = stored.len() as u32;
            data.extend_from_slice(&stored);
            entries.push(e);
        }
        secs.push(Sec::plain(tags::TREE, craft::tree_section(&t.header, &t.levels, &entries, &data)));
    }
    // Sometimes an entry aliasing another section's bytes.
    if r.below(8) == 0 && secs.len() > 2 {
        let first = 64 + (secs.len() + 1) as u64 * SECTION_ENTRY_LEN as u64;
        let mut at = first;
        let k = r.below(secs.len());
        for s in &secs[..k] {
            at += s.stored.len() as u64;
        }
        let len = secs[k].stored.len() as u64;
        secs.push(Sec::alias(if r.bool() { tags::TREE } else { *b"XTRA" }, at, len, SectionEntry::REQUIRED));
    }
    let bytes = craft::container(SCT_MAGIC, &secs);
    let count = secs.len();
    let mut starts = Vec::new();
    for i in 0..count {
        let e = 64 + i * SECTION_ENTRY_LEN;
        if bytes[e..e + 4] == tags::TREE {
            starts.push(u64::from_le_bytes(bytes[e + 8..e + 16].try_into().unwrap_or([0; 8])));
        }
    }
    (bytes, starts)
}

/// Field patches at known positions of the laid-out file, then every checksum again.
fn patch_fields(r: &mut Recipe, b: &mut Vec<u8>, m: &SceneM, starts: &[u64]) {
    let put = |b: &mut Vec<u8>, at: usize, v: u64, len: usize| {
        if at + len <= b.len() {
            b[at..at + len].copy_from_slice(&v.to_le_bytes()[..len]);
        }
    };
    let get = |b: &Vec<u8>, at: usize, len: usize| -> u64 { b.get(at..at + len).map_or(0, |s| s.iter().rev().fold(0u64, |a, &x| a << 8 | x as u64)) };
    for _ in 0..r.below(4) {
        let (at, len) = match r.below(5) {
            0 => {
                // A section-table field: offset, stored length, raw length or flags.
                let n = b.get(16..20).map_or(0, |s| u32::from_le_bytes(s.try_into().unwrap_or([0; 4]))) as usize;
                let e = 64 + r.below(n.max(1)) * SECTION_ENTRY_LEN;
                [(e + 8, 8), (e + 16, 8), (e + 24, 8), (e + 4, 4)][r.below(4)]
            }
            1 if !starts.is_empty() => {
                // A tree-header field: flags, root flag, level count, node count, leaf count, block count.
                let s = starts[r.below(starts.len())] as usize;
                [(s, 1), (s + 1, 1), (s + 2, 1), (s + 4, 4), (s + 8, 8), (s + 16, 8), (s + 24, 4), (s + 32 + 4 * r.below(10), 4)][r.below(8)]
            }
            2 if !starts.is_empty() => {
                // A level-table field.
                let k = r.below(starts.len());
                let t = m.trees.get(k).map_or(0, |t| t.levels.len());
                let e = starts[k] as usize + 80 + 16 * r.below(t.max(1));
                [(e, 8), (e + 8, 4), (e + 12, 4)][r.below(3)]
            }
            3 if !starts.is_empty() => {
                // A block-table field.
                let k = r.below(starts.len());
                let (l, nb) = m.trees.get(k).map_or((0, 0), |t| (t.levels.len(), t.blocks.len()));
                let e = starts[k] as usize + 80 + 16 * l + 48 * r.below(nb.max(1));
                [(e, 4), (e + 4, 4), (e + 8, 8), (e + 16, 8), (e + 24, 8), (e + 32, 4), (e + 36, 4), (e + 44, 4)][r.below(8)]
            }
            _ => [(16, 4), (24, 8), (32, 8), (8, 2), (12, 4)][r.below(5)],
        };
        let cur = get(b, at, len);
        let other = get(b, r.below(b.len().max(1)) & !7, 8);
        let v = r.interesting(cur, other);
        put(b, at, v, len);
    }
    craft::fix_crcs(b);
    if r.below(4) != 0 {
        craft::fix_length(b);
        craft::fix_crcs(b);
    }
}

fn exercise_scene(bytes: &[u8], file_checks: bool) {
    let lim = limits();
    let quick = validate_bytes(bytes, &ValidateOptions { limits: lim.clone(), ..Default::default() });
    let deep = validate_bytes(bytes, &ValidateOptions { deep: true, limits: lim.clone(), ..Default::default() });
    match SctReader::from_bytes(bytes.to_vec(), &lim) {
        Ok(rd) => {
            let _ = rd.verify_checksums();
            for t in 0..rd.trees().len() {
                let full = rd.read_tree(t);
                if let Ok(tree) = &full {
                    assert_eq!(tree.len() as u64, rd.trees()[t].header.node_count, "tree {t} decoded to another size than its header's");
                    for level in [0, 1, 3, usize::MAX - 1] {
                        let _ = sct_format::export::level_cut(tree, level);
                    }
                    let _ = sct_format::traverse::GroupLeaves::new(tree.clone()).path(0, "root");
                }
                assert!(!deep.is_valid() || full.is_ok(), "deep validation said valid, reading tree {t} failed: {:?}", full.err());
                let _ = rd.read_tree_levels(t, 2);
                let _ = rd.walk_tree(t, |_, _| Ok(()));
            }
            for i in 0..rd.graph().nodes.len().min(256) {
                let _ = sct_format::traverse::graph_bound(&rd, i as u32);
            }
        }
        Err(e) => {
            assert!(!quick.is_valid(), "quick validation said valid, the reader refused: {e}");
            assert!(!deep.is_valid(), "deep validation said valid, the reader refused: {e}");
        }
    }
    if file_checks {
        let (dir, _) = scratch();
        let path = dir.join("self.sct");
        if std::fs::write(&path, bytes).is_err() {
            return;
        }
        let topts = TraverseOptions { limits: lim.clone(), ..Default::default() };
        if let Ok(t) = Traversal::open(&path, topts.clone()) {
            for item in t {
                if let Ok(reached) = item {
                    let _ = reached.world_root();
                }
            }
        }
        let _ = validate_file(&path, &ValidateOptions { deep: true, limits: lim.clone(), ..Default::default() });
        let _ = sct_format::export::scene_to_ply(&path, None, &dir.join("out.ply"), topts, 100_000);
    }
}

// ---------------------------------------------------------------- samples files

/// Byte planes of `s` (spec §8, SMPS): each sample's 36-byte record with the centre's bits
/// as differences from the previous sample's, byte k of sample i at k·n + i.
fn planes(s: &[Node]) -> Vec<u8> {
    let n = s.len();
    let mut out = vec![0u8; 36 * n];
    let mut prev = [0u32; 3];
    for (i, x) in s.iter().enumerate() {
        let mut rec = [0u8; 36];
        for c in 0..3 {
            let bits = x.center[c].to_bits();
            rec[4 * c..4 * c + 4].copy_from_slice(&bits.wrapping_sub(prev[c]).to_le_bytes());
            prev[c] = bits;
        }
        rec[12..16].copy_from_slice(&x.radius.to_le_bytes());
        for c in 0..3 {
            rec[16 + 4 * c..20 + 4 * c].copy_from_slice(&x.normal[c].to_le_bytes());
        }
        rec[28..32].copy_from_slice(&x.area.to_le_bytes());
        rec[32..36].copy_from_slice(&x.color);
        for (k, &v) in rec.iter().enumerate() {
            out[k * n + i] = v;
        }
    }
    out
}

/// Columns of `s` (SMPC chunks and SMPL): centres, radii, normals, areas, colours.
fn columns(s: &[Node]) -> Vec<u8> {
    let mut out = Vec::with_capacity(36 * s.len());
    s.iter().for_each(|x| x.center.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes())));
    s.iter().for_each(|x| out.extend_from_slice(&x.radius.to_le_bytes()));
    s.iter().for_each(|x| x.normal.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes())));
    s.iter().for_each(|x| out.extend_from_slice(&x.area.to_le_bytes()));
    s.iter().for_each(|x| out.extend_from_slice(&x.color));
    out
}

fn exercise_samples_recipe(r: &mut Recipe) {
    let nmesh = 1 + r.below(3);
    let mut meshes = Vec::new();
    let mut samples = Vec::new();
    for m in 0..nmesh {
        let n = r.below(300);
        // Mesh 1 two-sided, so that files with a SIDE section are mutated too.
        meshes.push(MeshEntry { name: format!("m{m}"), first: samples.len() as u64, count: n as u64, two_sided: m == 1 });
        samples.extend((0..n).map(|_| leaf(r)));
    }
    let mut instances: Vec<SampleInstance> = (0..nmesh).map(|m| SampleInstance { mesh: m as u32, transform: Similarity::IDENTITY }).collect();
    let mut affine = Vec::new();
    if r.bool() {
        affine.push(AffineInstance { mesh: r.below(nmesh) as u32, matrix: [[1.0, 0.3, 0.0, 1.0], [0.0, 2.0, 0.0, 0.0], [0.0, 0.0, 0.5, 0.0]] });
    }
    // Mutations of the tables.
    for _ in 0..r.below(3) {
        match r.below(6) {
            0 => {
                let k = r.below(meshes.len());
                meshes[k].first = r.interesting(meshes[k].first, samples.len() as u64);
            }
            1 => {
                let k = r.below(meshes.len());
                meshes[k].count = r.interesting(meshes[k].count, samples.len() as u64);
            }
            2 if !instances.is_empty() => {
                let k = r.below(instances.len());
                instances[k].mesh = r.interesting(instances[k].mesh as u64, nmesh as u64) as u32;
            }
            3 if !instances.is_empty() => {
                let k = r.below(instances.len());
                instances[k].transform.scale = [0.0, -1.0, f64::NAN, f64::INFINITY, 1e300][r.below(5)];
            }
            4 => affine.push(AffineInstance { mesh: 0, matrix: [[0.0; 4]; 3] }),
            5 => instances.clear(),
            _ => {}
        }
    }
    let genr = craft::genr();
    let mut mesh = (meshes.len() as u64).to_le_bytes().to_vec();
    for m in &meshes {
        mesh.extend_from_slice(&m.first.to_le_bytes());
        mesh.extend_from_slice(&m.count.to_le_bytes());
        mesh.extend_from_slice(&(m.name.len() as u32).to_le_bytes());
        mesh.extend_from_slice(m.name.as_bytes());
    }
    let mut inst = (instances.len() as u64).to_le_bytes().to_vec();
    for i in &instances {
        inst.extend_from_slice(&i.mesh.to_le_bytes());
        for v in i.transform.translation.iter().chain(&i.transform.rotation) {
            inst.extend_from_slice(&v.to_le_bytes());
        }
        inst.extend_from_slice(&i.transform.scale.to_le_bytes());
    }
    let layout = r.below(3);
    let samples_sec = if layout == 2 {
        // Legacy SMPL: the count, then columns, one frame.
        let mut raw = (samples.len() as u64).to_le_bytes().to_vec();
        raw.extend(columns(&samples));
        match r.below(6) {
            0 => flip(r, &mut raw),
            1 => {
                let claim = [u32::MAX as u64, 8 + 36 * (1 << 22), 8 + 36 * 3][r.below(3)];
                let f = craft::rle_frame(&raw[..8], 0, claim);
                return exercise_samples(&craft::container(SAMPLES_MAGIC, &[Sec::plain(tags::GENR, genr), Sec::plain(tags::MESH, mesh), Sec::zstd(tags::INST, &inst), Sec::frame(tags::SMPL, f, claim)]));
            }
            _ => {}
        }
        Sec::zstd(tags::SMPL, &raw)
    } else {
        // Chunks of any size 1..=65536 (writers use 65536; readers accept any).
        let mut sec = Vec::new();
        let mut at = 0;
        let step = 1 + r.below(200);
        while at < samples.len() {
            let n = step.min(samples.len() - at);
            let chunk = &samples[at..at + n];
            let mut raw = if layout == 0 { planes(chunk) } else { columns(chunk) };
            let mut count = n as u32;
            let mut frame = match r.below(10) {
                0 => {
                    flip(r, &mut raw);
                    zstd::bulk::compress(&raw, 1).unwrap_or_default()
                }
                1 => craft::rle_frame(&[], r.byte(), [36 * 65_536, 1 << 26, 36 * n as u64 + 36][r.below(3)]),
                2 => craft::corrupt_frame(36 * n as u64),
                3 => {
                    count = r.interesting(count as u64, 65_536) as u32;
                    zstd::bulk::compress(&raw, 1).unwrap_or_default()
                }
                _ => zstd::bulk::compress(&raw, 1).unwrap_or_default(),
            };
            if r.below(16) == 0 {
                frame.extend_from_slice(b"tail");
            }
            sec.extend_from_slice(&count.to_le_bytes());
            sec.extend_from_slice(&(frame.len() as u32).to_le_bytes());
            sec.extend_from_slice(&frame);
            at += n;
        }
        if r.below(8) == 0 {
            // Many chunks of zeros claiming the most samples a chunk can hold.
            for _ in 0..r.below(600) {
                let f = craft::rle_frame(&[], 0, 36 * 65_536);
                sec.extend_from_slice(&65_536u32.to_le_bytes());
                sec.extend_from_slice(&(f.len() as u32).to_le_bytes());
                sec.extend_from_slice(&f);
            }
        }
        let mut s = Sec::plain(if layout == 0 { *b"SMPS" } else { *b"SMPC" }, sec);
        if r.below(16) == 0 {
            s.flags |= SectionEntry::ZSTD;
        }
        s
    };
    let mut secs = vec![Sec::plain(tags::GENR, genr), Sec::plain(tags::MESH, mesh), Sec::zstd(tags::INST, &inst), samples_sec];
    if !affine.is_empty() {
        let mut a = (affine.len() as u64).to_le_bytes().to_vec();
        for x in &affine {
            a.extend_from_slice(&x.mesh.to_le_bytes());
            x.matrix.iter().flatten().for_each(|v| a.extend_from_slice(&v.to_le_bytes()));
        }
        secs.push(Sec::zstd(*b"AFFI", &a));
    }
    if r.below(16) == 0 {
        let k = r.below(secs.len());
        secs.swap(0, k);
    }
    let mut bytes = craft::container(SAMPLES_MAGIC, &secs);
    for _ in 0..r.below(3) {
        let n = secs.len();
        let e = 64 + r.below(n) * SECTION_ENTRY_LEN;
        let (at, len) = [(e + 8, 8), (e + 16, 8), (e + 24, 8), (e + 4, 4)][r.below(4)];
        let cur = bytes[at..at + len].iter().rev().fold(0u64, |a, &x| a << 8 | x as u64);
        let v = r.interesting(cur, bytes.len() as u64);
        bytes[at..at + len].copy_from_slice(&v.to_le_bytes()[..len]);
        craft::fix_crcs(&mut bytes);
    }
    exercise_samples(&bytes);
}

fn exercise_samples(bytes: &[u8]) {
    if let Ok(f) = SamplesFile::read(bytes, &limits()) {
        let mut next = 0u64;
        for (i, m) in f.meshes.iter().enumerate() {
            assert_eq!(m.first, next, "meshes must tile the samples");
            next += m.count;
            assert_eq!(f.mesh_samples(i).len() as u64, m.count);
        }
        assert_eq!(next, f.samples.len() as u64);
        assert!(f.instances.iter().all(|i| (i.mesh as usize) < f.meshes.len() && i.transform.is_valid(1e-6)));
        assert!(f.affine_instances.iter().all(|a| (a.mesh as usize) < f.meshes.len() && a.is_valid()));
    }
}

fuzz_target!(|data: &[u8]| {
    let mut r = Recipe(data);
    match r.below(4) {
        0 => exercise_samples_recipe(&mut r),
        _ => {
            let Some(mut m) = build_scene(&mut r) else { return };
            let pristine = r.below(16) == 0;
            if !pristine {
                mutate_model(&mut r, &mut m);
            }
            let (mut bytes, starts) = layout(&m, &mut r);
            if !pristine {
                patch_fields(&mut r, &mut bytes, &m, &starts);
            }
            let file_checks = r.below(4) == 0;
            exercise_scene(&bytes, file_checks);
        }
    }
});
