//! Hostile files whose checksums are all valid: readers must catch them by meaning, and no
//! input may crash, hang or exhaust memory. Every file is built here (crafted byte by byte
//! with [`common::craft`], or written and patched), never committed. Memory and time bounds
//! are asserted through the error a limit produces before the expensive step (inflating,
//! allocating, expanding), not by measuring.

mod common;

use std::path::{Path, PathBuf};

use common::craft::{self, Sec, G};
use sct_format::export::{samples_file_to_ply, scene_to_ply, scene_to_ply_holding};
use sct_format::geometry::parent_of;
use sct_format::raw::{tags, BlockEntry, LevelEntry, TreeHeader, SAMPLES_MAGIC, SCT_MAGIC};
use sct_format::samples::SamplesFile;
use sct_format::traverse::{Traversal, TraverseErrorKind, TraverseOptions};
use sct_format::validate::{validate_bytes, validate_file, CheckId, ValidateOptions};
use sct_format::{
    write_scene, write_scene_file, Error, Generator, GraphNode, InstanceAttrs, Limits, Node, Profile, Scene, SceneGraph, SceneTree, SctReader,
    Similarity, WriteOptions,
};

fn leaf(x: f32, c: u8) -> Node {
    Node { center: [x, 0.0, 0.0], radius: 0.5, normal: [0.0, 0.0, 1.0], cone: 0.0, area: 1.0, color: [c, c, c, 255] }
}

/// A consistent 3-leaf tree: root -> (p, c), p -> (a, b).
fn box_tree(x: f32) -> SceneTree {
    let (a, b, c) = (leaf(x, 10), leaf(x + 1.0, 20), leaf(x + 3.0, 30));
    let p = parent_of(&a, &b);
    let r = parent_of(&p, &c);
    SceneTree::from_bfs(vec![r, p, c, a, b], vec![true, true, false, false, false]).expect("tree")
}

/// A consistent group tree of two leaves standing for children of bound `a` and `b`.
fn pair_tree(a: Node, b: Node) -> SceneTree {
    SceneTree::from_bfs(vec![parent_of(&a, &b), a, b], vec![true, false, false]).expect("tree")
}

fn raw() -> WriteOptions {
    WriteOptions { profile: Profile::Raw, ..Default::default() }
}

fn write(path: &Path, graph: SceneGraph, trees: Vec<SceneTree>) -> PathBuf {
    write_scene_file(path, &Scene { generator: Generator::default(), graph, trees }, &raw()).expect("write");
    path.to_path_buf()
}

fn bytes(graph: SceneGraph, trees: Vec<SceneTree>, opts: &WriteOptions) -> Vec<u8> {
    let mut out = Vec::new();
    write_scene(&Scene { generator: Generator::default(), graph, trees }, opts, &mut out).expect("write");
    out
}

fn hash(p: &Path) -> [u8; 32] {
    *blake3::hash(&std::fs::read(p).expect("read")).as_bytes()
}

/// The stored bytes of the first TREE section of a file the writer made.
fn tree_section_of(file: &[u8]) -> Vec<u8> {
    let r = SctReader::from_bytes(file.to_vec(), &Limits::default()).expect("valid");
    let e = r.sections().iter().find(|e| e.tag == tags::TREE).expect("tree").clone();
    file[e.offset as usize..(e.offset + e.stored_len) as usize].to_vec()
}

fn malformed(r: Result<impl std::fmt::Debug, Error>, needle: &str) {
    match r {
        Err(Error::Malformed { what, .. }) => assert!(what.contains(needle), "{what:?} should mention {needle:?}"),
        other => panic!("expected malformed ({needle}), got {other:?}"),
    }
}

fn limit(r: Result<impl std::fmt::Debug, Error>, quantity: &str) {
    match r {
        Err(Error::LimitExceeded { what, .. }) => assert_eq!(what, quantity),
        other => panic!("expected the {quantity:?} limit, got {other:?}"),
    }
}

/// Item 1: a tree of no nodes (allowed, spec §6.2) reached from the graph, directly, through
/// an instance and beside a box in a group: valid, and exports without panicking (the level
/// cut used to index level 0 of the empty tree).
#[test]
fn empty_tree_reached_from_the_graph_validates_and_exports() {
    let dir = tempfile::tempdir().expect("tempdir");
    let bx = box_tree(0.0);
    let b = bx.nodes()[0];
    let t = Similarity { translation: [1.0, 2.0, 3.0], ..Similarity::IDENTITY };
    let cases = [
        ("root", SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }], root: 0 }, vec![SceneTree::default()], [0, 0]),
        (
            "instance",
            SceneGraph {
                nodes: vec![GraphNode::Tree { tree: 0 }, GraphNode::Instance { child: 0, transform: t, attrs: InstanceAttrs::default() }],
                root: 1,
            },
            vec![SceneTree::default()],
            [0, 0],
        ),
        (
            "group",
            SceneGraph {
                nodes: vec![GraphNode::Tree { tree: 0 }, GraphNode::Tree { tree: 1 }, GraphNode::Group { children: vec![0, 1], tree: 2 }],
                root: 2,
            },
            vec![SceneTree::default(), bx.clone(), pair_tree(b, b)],
            [3, 1],
        ),
    ];
    for (name, graph, trees, [leaves, roots]) in cases {
        let p = write(&dir.path().join(format!("{name}.sct")), graph, trees);
        for deep in [false, true] {
            let r = validate_file(&p, &ValidateOptions { deep, ..Default::default() }).expect("validate");
            assert!(r.is_valid(), "{name}: {:?}", r.issues);
        }
        let out = dir.path().join(format!("{name}.ply"));
        for (level, want) in [(None, leaves), (Some(0), roots), (Some(1), leaves.min(2)), (Some(7), leaves)] {
            let s = scene_to_ply(&p, level, &out, TraverseOptions::default(), 1000).expect("export");
            assert_eq!(s.points, want, "{name} at level {level:?}");
            // Holding no placement (a second traversal writes them) gives the same file.
            let again = dir.path().join(format!("{name}-again.ply"));
            let t = scene_to_ply_holding(&p, level, &again, TraverseOptions::default(), 1000, 0).expect("export");
            assert_eq!((t.points, t.placements), (s.points, s.placements), "{name} at level {level:?}");
            assert_eq!(std::fs::read(&again).expect("ply"), std::fs::read(&out).expect("ply"), "{name} at level {level:?}");
        }
    }
}

/// Item 2: a level table claiming 1 + 2 + … + 2^31 nodes, every level within the caps and
/// every block 0 bytes, all checksums valid. Each block's raw length must be what its node
/// count needs, so the index is refused before a block is read (the reader used to accept
/// it, and reading it reserved 171 GB for the claimed nodes).
#[test]
fn claimed_node_counts_need_their_bytes() {
    let levels: Vec<LevelEntry> = (0..32u32)
        .map(|d| LevelEntry { node_count: 1 << d, first_block: d.saturating_sub(1), block_count: (d > 0) as u32 })
        .collect();
    let data_at = craft::index_len(32, 31);
    let blocks: Vec<BlockEntry> = (1..32u32)
        .map(|d| BlockEntry { level: d, node_count: 1 << d, first_node: 0, internal_before: 0, offset: data_at, stored_len: 0, raw_len: 0, crc: 0, flags: 0 })
        .collect();
    let header = TreeHeader {
        profile: 0,
        flags: 0,
        root_internal: 1,
        level_count: 32,
        node_count: (1 << 32) - 1,
        leaf_count: 1 << 31,
        block_count: 31,
        root: leaf(0.0, 1),
    };
    let tree = craft::tree_section(&header, &levels, &blocks, &[]);
    let file = craft::container(
        SCT_MAGIC,
        &[Sec::plain(tags::GENR, craft::genr()), Sec::zstd(tags::GRPH, &craft::graph_bytes(&[G::Tree(0)], 0)), Sec::plain(tags::TREE, tree)],
    );
    malformed(SctReader::from_bytes(file.clone(), &Limits::default()).map(|_| ()), "raw length 0, its 2 nodes take");
    let r = validate_bytes(&file, &ValidateOptions::default());
    assert_eq!(r.check_ids(), vec![CheckId::TreeIndex], "{:?}", r.issues);
}

/// The GRPH of a group of about 2^30 children (one 131 KB frame inflating to 4 GiB): refused
/// by its raw length before anything is inflated, by the reader and the validator (which
/// used to inflate it and then build one path string per child: 8.4 GB).
#[test]
fn huge_group_is_refused_before_inflating() {
    let k: u64 = ((4u64 << 30) - 30) / 4;
    let mut head = Vec::new();
    head.extend_from_slice(&2u64.to_le_bytes());
    head.extend_from_slice(&1u32.to_le_bytes());
    head.extend_from_slice(&[0, 0, 0, 0, 0]); // node 0: tree 0
    head.push(1); // node 1: group over tree 0 …
    head.extend_from_slice(&0u32.to_le_bytes());
    head.extend_from_slice(&k.to_le_bytes()); // … of k children, all node 0 (zero bytes)
    let raw_len = head.len() as u64 + 4 * k;
    assert!(raw_len <= 4 << 30);
    let frame = craft::rle_frame(&head, 0, raw_len);
    assert!(frame.len() < 200_000, "{}", frame.len());
    let file = craft::container(SCT_MAGIC, &[Sec::plain(tags::GENR, craft::genr()), Sec::frame(tags::GRPH, frame, raw_len)]);
    limit(SctReader::from_bytes(file.clone(), &Limits::default()).map(|_| ()), "scene graph section bytes");
    let r = validate_bytes(&file, &ValidateOptions::default());
    assert!(r.check_ids().contains(&CheckId::Limit), "{:?}", r.issues);
}

/// A group whose tree has fewer leaves than it has children is reported once, and its
/// children (all the same node) are walked once, not named one by one.
#[test]
fn group_child_count_is_checked_before_naming_children() {
    let bx = box_tree(0.0);
    let b = bx.nodes()[0];
    let k = 200_000u32;
    let graph = craft::graph_bytes(&[G::Tree(0), G::Group(1, vec![0; k as usize])], 1);
    let file = bytes(SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }], root: 0 }, vec![bx.clone(), pair_tree(b, b)], &raw());
    let r = SctReader::from_bytes(file.clone(), &Limits::default()).expect("valid");
    // The same trees with the crafted graph.
    let mut secs: Vec<Sec> = Vec::new();
    for e in r.sections() {
        let stored = file[e.offset as usize..(e.offset + e.stored_len) as usize].to_vec();
        secs.push(if e.tag == tags::GRPH { Sec::zstd(tags::GRPH, &graph) } else { Sec { tag: e.tag, flags: e.flags, at: None, stored, raw_len: e.raw_len } });
    }
    let file = craft::container(SCT_MAGIC, &secs);
    for deep in [false, true] {
        let r = validate_bytes(&file, &ValidateOptions { deep, ..Default::default() });
        let graph_issues: Vec<_> = r.issues.iter().filter(|i| i.check == CheckId::Graph).collect();
        assert_eq!(graph_issues.len(), 1, "{:?}", r.issues);
        assert!(graph_issues[0].message.contains("has 200000 children, its tree 1 has 2 leaves"), "{}", graph_issues[0]);
    }
}

/// Item 4: a DAG of shared groups (group k uses group k - 1 twice), 40 levels: 2^40 paths in
/// a few hundred bytes. Validation follows distinct nodes; every path-expanding consumer stops
/// at the visit limit with a limit-exceeded error.
#[test]
fn shared_groups_are_bounded_by_the_visit_limit() {
    let dir = tempfile::tempdir().expect("tempdir");
    let bx = box_tree(0.0);
    let b = bx.nodes()[0];
    let mut nodes = vec![GraphNode::Tree { tree: 0 }];
    for k in 1..=40u32 {
        nodes.push(GraphNode::Group { children: vec![k - 1, k - 1], tree: 1 });
    }
    let p = write(&dir.path().join("dag.sct"), SceneGraph { nodes, root: 40 }, vec![bx, pair_tree(b, b)]);
    let r = validate_file(&p, &ValidateOptions { deep: true, ..Default::default() }).expect("validate");
    assert_eq!(r.trees, 2);

    let mut opts = TraverseOptions::default();
    opts.limits.max_traversal_visits = 10_000;
    let items: Vec<_> = Traversal::open(&p, opts.clone()).expect("open").collect();
    let last = items.last().expect("items").as_ref().expect_err("ends with the limit");
    assert!(last.is_visit_limit(), "{last}");
    assert!(items[..items.len() - 1].iter().all(|i| i.is_ok()));
    assert!(items.len() <= 10_001, "one item per visit at most, then the error: {}", items.len());
    let out = dir.path().join("dag.ply");
    match scene_to_ply(&p, None, &out, opts, u64::MAX) {
        Err(Error::LimitExceeded { what, limit, .. }) => assert_eq!((what, limit), (sct_format::traverse::VISITS, 10_000)),
        other => panic!("{other:?}"),
    }
    assert!(!out.exists());
    assert_eq!(Limits::default().max_traversal_visits, 10_000_000);

    // The group tree shared by every path is decoded once per traversal, not once per path
    // (at 10^7 visits, decoding per path took an export 26 s): its blocks are read once.
    let reader = std::sync::Arc::new(SctReader::open(&p, &Limits::default()).expect("open"));
    let at_open = reader.bytes_read();
    let canon = std::fs::canonicalize(&p).expect("canonical");
    let mut opts = TraverseOptions::default();
    opts.limits.max_traversal_visits = 10_000;
    let reached = Traversal::from_reader(reader.clone(), canon, opts).filter(|i| i.is_ok()).count();
    assert!(reached > 1000, "{reached}");
    let per_read = {
        let before = reader.bytes_read();
        reader.read_tree(1).expect("group tree");
        reader.read_tree(0).expect("leaf tree");
        reader.bytes_read() - before
    };
    assert!(reader.bytes_read() - at_open <= 2 * per_read, "read {} bytes for {reached} items", reader.bytes_read() - at_open);
}

/// Runs `f` on a thread and waits for it: a call that blocks forever (opening a FIFO used
/// to) fails the test instead of hanging it.
#[cfg(unix)]
fn returns<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx.recv_timeout(std::time::Duration::from_secs(120)).expect("the call blocked (a FIFO was opened for reading?)")
}

#[cfg(unix)]
fn mkfifo(p: &Path) {
    let ok = std::process::Command::new("mkfifo").arg(p).status().expect("mkfifo").success();
    assert!(ok, "mkfifo {}", p.display());
}

fn not_regular(r: Result<impl std::fmt::Debug, Error>, what: &str) {
    match r {
        Err(Error::Io { source, path: Some(_) }) => assert!(source.to_string().contains(what), "{source}"),
        other => panic!("expected an I/O error about {what}, got {other:?}"),
    }
}

/// Item 5: FIFOs and devices, as inputs and as inline targets (also behind a symlink), are
/// refused at once instead of blocking in `open` or reading forever.
#[cfg(unix)]
#[test]
fn fifos_and_devices_are_refused_without_blocking() {
    let dir = tempfile::tempdir().expect("tempdir");
    let fifo = dir.path().join("pipe.sct");
    mkfifo(&fifo);
    let link = dir.path().join("link.sct");
    std::os::unix::fs::symlink(&fifo, &link).expect("symlink");
    for p in [fifo.clone(), link.clone()] {
        let q = p.clone();
        not_regular(returns(move || SctReader::open(&q, &Limits::default()).map(|_| ())), "FIFO");
        let q = p.clone();
        not_regular(returns(move || SamplesFile::read_file(&q, &Limits::default()).map(|_| ())), "FIFO");
        let q = p.clone();
        not_regular(returns(move || validate_file(&q, &ValidateOptions::default()).map(|_| ())), "FIFO");
        let q = p.clone();
        not_regular(returns(move || sct_format::fsio::read_regular(&q, 1 << 20).map(|_| ())), "FIFO");
    }
    not_regular(returns(|| SctReader::open(Path::new("/dev/zero"), &Limits::default()).map(|_| ())), "device");
    not_regular(returns(|| sct_format::fsio::open_regular(Path::new("/dev/null")).map(|_| ())), "device");

    // Inline targets: the FIFO and the symlink to it.
    let b = box_tree(0.0).nodes()[0];
    let nodes = vec![
        GraphNode::Inline { path: "pipe.sct".into(), hash: [0; 32], bound: b },
        GraphNode::Inline { path: "link.sct".into(), hash: [0; 32], bound: b },
        GraphNode::Group { children: vec![0, 1], tree: 0 },
    ];
    let top = write(&dir.path().join("top.sct"), SceneGraph { nodes, root: 2 }, vec![pair_tree(b, b)]);
    let t = top.clone();
    let items: Vec<_> = returns(move || Traversal::open(&t, TraverseOptions::default()).expect("open").collect::<Vec<_>>());
    let missing = items.iter().filter(|i| matches!(i, Err(e) if matches!(e.kind, TraverseErrorKind::InlineMissing { .. }))).count();
    assert_eq!(missing, 2, "{items:?}");
    let t = top.clone();
    let r = returns(move || validate_file(&t, &ValidateOptions::default()).expect("validate"));
    let ids: Vec<CheckId> = r.issues.iter().map(|i| i.check).collect();
    assert_eq!(ids, vec![CheckId::InlineMissing, CheckId::InlineMissing], "{:?}", r.issues);
}

/// Item 7: TREE entries aliasing one tree's bytes (each would be decoded again: 4,094 of
/// them fit in 420 KB over one zstd bomb) are refused as overlapping sections.
#[test]
fn aliased_sections_are_refused() {
    let file = bytes(SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }], root: 0 }, vec![box_tree(0.0)], &raw());
    let tree = tree_section_of(&file);
    let mut secs = vec![Sec::plain(tags::GENR, craft::genr()), Sec::zstd(tags::GRPH, &craft::graph_bytes(&[G::Tree(0)], 0)), Sec::plain(tags::TREE, tree.clone())];
    let clean = craft::container(SCT_MAGIC, &secs);
    SctReader::from_bytes(clean.clone(), &Limits::default()).expect("one copy is fine");
    let r = SctReader::from_bytes(clean, &Limits::default()).expect("valid");
    let at = r.sections()[2].offset;
    for _ in 0..15 {
        secs.push(Sec::alias(tags::TREE, at, tree.len() as u64, sct_format::raw::SectionEntry::REQUIRED));
    }
    let aliased = craft::container(SCT_MAGIC, &secs);
    malformed(SctReader::from_bytes(aliased.clone(), &Limits::default()).map(|_| ()), "sections must not overlap");
    assert_eq!(validate_bytes(&aliased, &ValidateOptions::default()).check_ids(), vec![CheckId::SectionTable]);
    // A section overlapping the header or the section table is refused too.
    let mut secs = secs[..3].to_vec();
    secs.push(Sec::alias(*b"XTRA", 10, 100, 0));
    malformed(SctReader::from_bytes(craft::container(SCT_MAGIC, &secs), &Limits::default()).map(|_| ()), "overlaps the file header");
}

/// Item 7: two blocks of one tree aliasing the same stored bytes are refused.
#[test]
fn aliased_blocks_are_refused() {
    // 8 leaves in blocks of 2 nodes: level 2 has two blocks of two internal nodes each.
    let leaves: Vec<Node> = (0..8).map(|i| leaf(i as f32, 9)).collect();
    let tree = {
        let l1: Vec<Node> = leaves.chunks(2).map(|p| parent_of(&p[0], &p[1])).collect();
        let l2: Vec<Node> = l1.chunks(2).map(|p| parent_of(&p[0], &p[1])).collect();
        let r = parent_of(&l2[0], &l2[1]);
        let mut nodes = vec![r];
        nodes.extend(&l2);
        nodes.extend(&l1);
        nodes.extend(&leaves);
        let flags = (0..15).map(|i| i < 7).collect();
        SceneTree::from_bfs(nodes, flags).expect("tree")
    };
    let opts = WriteOptions { block_nodes: 2, ..raw() };
    let mut file = bytes(SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }], root: 0 }, vec![tree], &opts);
    let r = SctReader::from_bytes(file.clone(), &Limits::default()).expect("valid");
    let t = &r.trees()[0];
    let lvl2 = t.level_blocks(2);
    assert_eq!(lvl2.len(), 2);
    let (b0, b1) = (lvl2.start, lvl2.start + 1);
    let entry_at = |b: usize| (t.section.offset + craft::index_len(t.levels.len(), b)) as usize;
    // Block b1 takes b0's stored bytes (offset 24, length 32, raw 36, CRC 40 of the entry).
    let (e0, e1) = (entry_at(b0), entry_at(b1));
    let copy: Vec<u8> = file[e0 + 24..e0 + 44].to_vec();
    file[e1 + 24..e1 + 44].copy_from_slice(&copy);
    craft::fix_crcs(&mut file);
    malformed(SctReader::from_bytes(file.clone(), &Limits::default()).map(|_| ()), "blocks must not overlap");
    assert_eq!(validate_bytes(&file, &ValidateOptions::default()).check_ids(), vec![CheckId::TreeIndex]);
}

/// Item 10: a block whose zstd frame inflates to 2^32 - 1 bytes (131 KB stored) is refused
/// by its raw length, which its node count fixes, before anything is inflated (the buffer
/// used to grow to the claimed length first: 4.2 GB per block and thread).
#[test]
fn block_bomb_is_refused_before_inflating() {
    let frame = craft::rle_frame(&[], 0, u32::MAX as u64);
    let header = TreeHeader { profile: 0, flags: 0, root_internal: 1, level_count: 2, node_count: 3, leaf_count: 2, block_count: 1, root: leaf(0.0, 1) };
    let levels = [LevelEntry { node_count: 1, first_block: 0, block_count: 0 }, LevelEntry { node_count: 2, first_block: 0, block_count: 1 }];
    let block = BlockEntry {
        level: 1,
        node_count: 2,
        first_node: 0,
        internal_before: 0,
        offset: craft::index_len(2, 1),
        stored_len: frame.len() as u32,
        raw_len: u32::MAX,
        crc: 0,
        flags: 1,
    };
    let tree = craft::tree_section(&header, &levels, &[block], &frame);
    let file = craft::container(
        SCT_MAGIC,
        &[Sec::plain(tags::GENR, craft::genr()), Sec::zstd(tags::GRPH, &craft::graph_bytes(&[G::Tree(0)], 0)), Sec::plain(tags::TREE, tree)],
    );
    malformed(SctReader::from_bytes(file.clone(), &Limits::default()).map(|_| ()), "raw length 4294967295, its 2 nodes take 81 bytes");
    let r = validate_bytes(&file, &ValidateOptions { deep: true, ..Default::default() });
    assert_eq!(r.check_ids(), vec![CheckId::TreeIndex], "{:?}", r.issues);
}

/// Item 10: GENR and GRPH claiming 2^32 - 1 raw bytes are refused by their caps before they
/// are inflated. The frames are garbage inside, so a reader that inflated first would report
/// corrupt data instead of the limit.
#[test]
fn section_bombs_are_refused_before_inflating() {
    let big = u32::MAX as u64;
    let graph = Sec::zstd(tags::GRPH, &craft::graph_bytes(&[G::Tree(0)], 0));
    let file = craft::container(SCT_MAGIC, &[Sec::frame(tags::GENR, craft::corrupt_frame(big), big), graph]);
    limit(SctReader::from_bytes(file.clone(), &Limits::default()).map(|_| ()), "generator size");
    assert!(validate_bytes(&file, &ValidateOptions::default()).check_ids().contains(&CheckId::Limit));
    let file = craft::container(SCT_MAGIC, &[Sec::plain(tags::GENR, craft::genr()), Sec::frame(tags::GRPH, craft::corrupt_frame(big), big)]);
    limit(SctReader::from_bytes(file.clone(), &Limits::default()).map(|_| ()), "scene graph section bytes");
    assert!(validate_bytes(&file, &ValidateOptions::default()).check_ids().contains(&CheckId::Limit));
}

/// Item 11: a GRPH of 2^20 five-byte tree records (a few KB stored) is refused by the graph
/// memory it would take (about 100 bytes a node) before the nodes are allocated; the
/// defaults refuse the 2^26 nodes of the node cap the same way (6.8 GB before).
#[test]
fn graph_memory_is_charged_before_allocating() {
    let n = 1u64 << 20;
    let mut head = n.to_le_bytes().to_vec();
    head.extend_from_slice(&0u32.to_le_bytes());
    let raw_len = 12 + 5 * n;
    let file = bytes(SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }], root: 0 }, vec![box_tree(0.0)], &raw());
    let tree = tree_section_of(&file);
    let file = craft::container(
        SCT_MAGIC,
        &[Sec::plain(tags::GENR, craft::genr()), Sec::frame(tags::GRPH, craft::rle_frame(&head, 0, raw_len), raw_len), Sec::plain(tags::TREE, tree)],
    );
    let small = Limits { max_graph_bytes: 64 << 20, ..Limits::default() };
    limit(SctReader::from_bytes(file.clone(), &small).map(|_| ()), "scene graph memory (bytes)");
    let r = validate_bytes(&file, &ValidateOptions { limits: small, ..Default::default() });
    assert_eq!(r.check_ids(), vec![CheckId::Limit], "{:?}", r.issues);
    // Within the defaults the same graph reads.
    assert_eq!(SctReader::from_bytes(file, &Limits::default()).expect("reads").graph().nodes.len(), n as usize);
    assert!((1u64 << 26) * sct_format::read::GRAPH_NODE_BYTES > Limits::default().max_graph_bytes);
}

/// A samples file of `chunks` SMPS chunks of `n` samples, each chunk's frame `frame(n)`, one
/// mesh over all of them placed once.
fn samples_file(chunks: usize, n: u32, frame: impl Fn(u32) -> Vec<u8>) -> Vec<u8> {
    let mut smps = Vec::new();
    for _ in 0..chunks {
        let f = frame(n);
        smps.extend_from_slice(&n.to_le_bytes());
        smps.extend_from_slice(&(f.len() as u32).to_le_bytes());
        smps.extend_from_slice(&f);
    }
    let total = chunks as u64 * n as u64;
    container_samples(total, Sec::plain(*b"SMPS", smps))
}

fn container_samples(total: u64, samples: Sec) -> Vec<u8> {
    container_samples_with(total, samples, Vec::new())
}

/// [`container_samples`] with `extra` sections after the samples.
fn container_samples_with(total: u64, samples: Sec, extra: Vec<Sec>) -> Vec<u8> {
    let mut mesh = 1u64.to_le_bytes().to_vec();
    mesh.extend_from_slice(&0u64.to_le_bytes());
    mesh.extend_from_slice(&total.to_le_bytes());
    mesh.extend_from_slice(&0u32.to_le_bytes());
    let mut inst = 1u64.to_le_bytes().to_vec();
    inst.extend_from_slice(&0u32.to_le_bytes());
    for v in [0.0f64, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0] {
        inst.extend_from_slice(&v.to_le_bytes());
    }
    let mut secs = vec![Sec::plain(tags::GENR, craft::genr()), Sec::plain(tags::MESH, mesh), Sec::zstd(tags::INST, &inst), samples];
    secs.extend(extra);
    craft::container(SAMPLES_MAGIC, &secs)
}

/// Item 12: 1,820 chunks of 65,536 samples in 250 KB (each chunk a frame of zeros) would
/// decode to 4.8 GB of samples: refused by the decoded-sample cap while the chunk headers are
/// walked, before anything is decoded (sct-build-tree reached 7.8 GB).
#[test]
fn sample_totals_are_refused_before_decoding() {
    let file = samples_file(1820, 65_536, |n| craft::rle_frame(&[], 0, 36 * n as u64));
    assert!(file.len() < 300_000, "{}", file.len());
    limit(SamplesFile::read(&file, &Limits::default()).map(|_| ()), "decoded sample bytes");
    // A few such chunks are an ordinary (if dull) file.
    let small = samples_file(3, 65_536, |n| craft::rle_frame(&[], 0, 36 * n as u64));
    assert_eq!(SamplesFile::read(&small, &Limits::default()).expect("reads").samples.len(), 3 * 65_536);
    let tight = Limits { max_sample_bytes: 40 * 65_536, ..Limits::default() };
    limit(SamplesFile::read(&small, &tight).map(|_| ()), "decoded sample bytes");
}

/// Item 12: a legacy SMPL section whose frame inflates to 4 GiB (131 KB stored) is refused by
/// the sample count its length implies, before it is inflated (9.8 GB before: the columns and
/// the samples); within the limits it decodes as it inflates, and its count must agree with
/// its length.
#[test]
fn legacy_samples_are_counted_before_inflating() {
    let n: u64 = ((4u64 << 30) - 8) / 36;
    let raw_len = 8 + 36 * n;
    let smpl = Sec::frame(tags::SMPL, craft::rle_frame(&n.to_le_bytes(), 0, raw_len), raw_len);
    limit(SamplesFile::read(&container_samples(n, smpl), &Limits::default()).map(|_| ()), "decoded sample bytes");

    let good = |count_field: u64, n: u64, tail: &[u8]| {
        let raw_len = 8 + 36 * n;
        let mut frame = craft::rle_frame(&count_field.to_le_bytes(), 0, raw_len);
        frame.extend_from_slice(tail);
        container_samples(n, Sec::frame(tags::SMPL, frame, raw_len))
    };
    assert_eq!(SamplesFile::read(&good(1000, 1000, b""), &Limits::default()).expect("reads").samples.len(), 1000);
    malformed(SamplesFile::read(&good(999, 1000, b""), &Limits::default()).map(|_| ()), "by its count");
    malformed(SamplesFile::read(&good(1000, 1000, b"xx"), &Limits::default()).map(|_| ()), "follow the chunk's zstd frame");
}

/// Item 12: exporting a samples file checks the point limit on its tables, before decoding:
/// these chunks' frames are garbage inside, so an export that decoded first failed on them.
#[test]
fn export_checks_max_points_before_decoding() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("s.samples");
    std::fs::write(&p, samples_file(2, 65_536, |n| craft::corrupt_frame(36 * n as u64))).expect("write");
    let out = dir.path().join("s.ply");
    match samples_file_to_ply(&p, &out, 1000, &Limits::default()) {
        Err(Error::LimitExceeded { what: "PLY export points", value, limit: 1000 }) => assert_eq!(value, 131_072),
        other => panic!("{other:?}"),
    }
    malformed(samples_file_to_ply(&p, &out, u64::MAX, &Limits::default()), "corrupt");
    assert!(!out.exists());
}

/// Item 20: a zstd section or block followed by other bytes is not one frame: refused.
#[test]
fn bytes_after_a_zstd_frame_are_refused() {
    let graph = craft::graph_bytes(&[G::Tree(0)], 0);
    let mut stored = zstd::bulk::compress(&graph, 3).expect("compress");
    stored.extend_from_slice(b"trailing");
    let file = bytes(SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }], root: 0 }, vec![box_tree(0.0)], &raw());
    let tree = tree_section_of(&file);
    let secs = [Sec::plain(tags::GENR, craft::genr()), Sec::frame(tags::GRPH, stored, graph.len() as u64), Sec::plain(tags::TREE, tree)];
    malformed(SctReader::from_bytes(craft::container(SCT_MAGIC, &secs), &Limits::default()).map(|_| ()), "follow the zstd frame");

    // A block: one zstd-compressed block of two raw children, then trailing bytes.
    let (a, b) = (leaf(0.0, 1), leaf(1.0, 2));
    let mut payload = vec![0u8];
    for n in [a, b] {
        craft::node_bytes(&n, &mut payload);
    }
    let mut frame = zstd::bulk::compress(&payload, 3).expect("compress");
    frame.extend_from_slice(b"junk");
    let header = TreeHeader { profile: 0, flags: 0, root_internal: 1, level_count: 2, node_count: 3, leaf_count: 2, block_count: 1, root: parent_of(&a, &b) };
    let levels = [LevelEntry { node_count: 1, first_block: 0, block_count: 0 }, LevelEntry { node_count: 2, first_block: 0, block_count: 1 }];
    let block = BlockEntry {
        level: 1,
        node_count: 2,
        first_node: 0,
        internal_before: 0,
        offset: craft::index_len(2, 1),
        stored_len: frame.len() as u32,
        raw_len: payload.len() as u32,
        crc: 0,
        flags: 1,
    };
    let tree = craft::tree_section(&header, &levels, &[block], &frame);
    let graph = Sec::zstd(tags::GRPH, &craft::graph_bytes(&[G::Tree(0)], 0));
    let file = craft::container(SCT_MAGIC, &[Sec::plain(tags::GENR, craft::genr()), graph, Sec::plain(tags::TREE, tree)]);
    let r = SctReader::from_bytes(file, &Limits::default()).expect("index is fine");
    malformed(r.read_tree(0).map(|_| ()), "follow the zstd frame");
}

/// Item 20: inline targets stay under the scene's directory (symlinks resolved) unless the
/// caller allows more; a target outside is neither opened nor hashed, so the validator
/// cannot be made to print the hash of an arbitrary file.
#[test]
fn inline_targets_stay_in_the_scene_directory() {
    let dir = tempfile::tempdir().expect("tempdir");
    let scene_dir = dir.path().join("scene");
    std::fs::create_dir_all(scene_dir.join("sub")).expect("dirs");
    let graph = || SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }], root: 0 };
    let outside = write(&dir.path().join("outside.sct"), graph(), vec![box_tree(0.0)]);
    let inside = write(&scene_dir.join("sub").join("inside.sct"), graph(), vec![box_tree(0.0)]);
    #[cfg(unix)]
    std::os::unix::fs::symlink(&outside, scene_dir.join("to-outside.sct")).expect("symlink");
    let b = box_tree(0.0).nodes()[0];
    let secret = sct_format::traverse::hex(&hash(&outside));
    // The scene is the top file; its directory is scene_dir.
    let top_with = |name: &str, rel: &str, h: [u8; 32]| {
        let nodes = vec![GraphNode::Inline { path: rel.into(), hash: h, bound: b }];
        write(&scene_dir.join(name), SceneGraph { nodes, root: 0 }, vec![])
    };
    let mut cases = vec![
        ("up.sct", "../outside.sct", hash(&outside), false),
        ("ok.sct", "sub/inside.sct", hash(&inside), true),
        ("dots.sct", "sub/../sub/inside.sct", hash(&inside), true),
    ];
    if cfg!(unix) {
        cases.push(("link.sct", "to-outside.sct", hash(&outside), false));
    }
    for (name, rel, h, inside_ok) in cases {
        let top = top_with(name, rel, h);
        // Traversal: refused (not opened) unless allowed.
        let items: Vec<_> = Traversal::open(&top, TraverseOptions::default()).expect("open").collect();
        match (&items[..], inside_ok) {
            ([Ok(r)], true) => assert_eq!(r.inline_depth, 1),
            ([Err(e)], false) => assert!(matches!(e.kind, TraverseErrorKind::InlineOutside { .. }), "{e}"),
            (other, _) => panic!("{name}: {other:?}"),
        }
        let allow = TraverseOptions { allow_outside_inlines: true, ..Default::default() };
        assert!(Traversal::open(&top, allow).expect("open").all(|i| i.is_ok()), "{name} allowed");
        // Validation: an inline-outside issue, and no hash of the target anywhere.
        let r = validate_file(&top, &ValidateOptions::default()).expect("validate");
        if inside_ok {
            assert!(r.is_valid(), "{name}: {:?}", r.issues);
        } else {
            assert_eq!(r.check_ids(), vec![CheckId::InlineOutside], "{name}");
            assert!(r.issues.iter().all(|i| !i.message.contains(&secret)), "{:?}", r.issues);
            assert_eq!(r.files.len(), 1, "the target is not opened");
            let allowed = validate_file(&top, &ValidateOptions { allow_outside_inlines: true, ..Default::default() }).expect("validate");
            assert!(allowed.is_valid(), "{name}: {:?}", allowed.issues);
        }
    }
}

/// Item 21: a file truncated by another process while a reader has it open makes the reader
/// fail with an I/O error on the lost bytes (a memory-mapped reader died of SIGBUS).
#[test]
fn file_shrunk_under_the_reader_is_an_io_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let tree = common::random_tree(7, 20_000, false);
    let p = write(&dir.path().join("big.sct"), SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }], root: 0 }, vec![tree]);
    let r = SctReader::open(&p, &Limits::default()).expect("open");
    let len = std::fs::metadata(&p).expect("meta").len();
    std::fs::OpenOptions::new().write(true).open(&p).expect("rw").set_len(len / 2).expect("truncate");
    match r.read_tree(0) {
        Err(Error::Io { path: Some(q), .. }) => assert_eq!(q, p),
        other => panic!("{:?}", other.map(|t| t.len())),
    }
    assert!(matches!(r.verify_checksums(), Err(Error::Io { .. })));
    assert!(matches!(r.content_hash(), Err(Error::Io { .. })));
}

/// A samples file's generator and tables claiming huge raw lengths are refused by their caps
/// before they are inflated (the frames are garbage inside: inflating first reported that).
#[test]
fn samples_table_bombs_are_refused_before_inflating() {
    let big = u32::MAX as u64;
    let smps = || {
        let f = zstd::bulk::compress(&[0u8; 36], 1).expect("compress");
        let mut s = 1u32.to_le_bytes().to_vec();
        s.extend_from_slice(&(f.len() as u32).to_le_bytes());
        s.extend_from_slice(&f);
        Sec::plain(*b"SMPS", s)
    };
    let mut mesh = 1u64.to_le_bytes().to_vec();
    mesh.extend_from_slice(&0u64.to_le_bytes());
    mesh.extend_from_slice(&1u64.to_le_bytes());
    mesh.extend_from_slice(&0u32.to_le_bytes());
    let file = craft::container(
        SAMPLES_MAGIC,
        &[Sec::frame(tags::GENR, craft::corrupt_frame(big), big), Sec::plain(tags::MESH, mesh.clone()), Sec::frame(tags::INST, craft::corrupt_frame(64), 64), smps()],
    );
    limit(SamplesFile::read(&file, &Limits::default()).map(|_| ()), "generator size");
    let file = craft::container(
        SAMPLES_MAGIC,
        &[Sec::plain(tags::GENR, craft::genr()), Sec::plain(tags::MESH, mesh), Sec::frame(tags::INST, craft::corrupt_frame(big), big), smps()],
    );
    let tight = Limits { max_sample_bytes: 1 << 30, ..Limits::default() };
    limit(SamplesFile::read(&file, &tight).map(|_| ()), "samples table bytes");
}

/// Found by the structured fuzzer: an unreachable graph node naming a tree the file lacks
/// (or a group whose tree has too few leaves) was valid to the validator, which checked tree
/// references only on the paths it walked, while the reader refuses the file.
#[test]
fn unreachable_nodes_with_bad_tree_references_are_invalid() {
    let file = bytes(SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }], root: 0 }, vec![box_tree(0.0)], &raw());
    let tree = tree_section_of(&file);
    for (graph, needle) in [
        (craft::graph_bytes(&[G::Tree(65_536), G::Tree(0)], 1), "unreachable graph node 0 refers to tree 65536, the file has 1"),
        (craft::graph_bytes(&[G::Tree(0), G::Group(0, vec![0, 0]), G::Tree(0)], 2), "unreachable graph node 1 is a group of 2 children, its tree 0 has 3 leaves"),
    ] {
        let file = craft::container(SCT_MAGIC, &[Sec::plain(tags::GENR, craft::genr()), Sec::zstd(tags::GRPH, &graph), Sec::plain(tags::TREE, tree.clone())]);
        assert!(SctReader::from_bytes(file.clone(), &Limits::default()).is_err());
        for deep in [false, true] {
            let r = validate_bytes(&file, &ValidateOptions { deep, ..Default::default() });
            assert_eq!(r.check_ids(), vec![CheckId::Graph], "{:?}", r.issues);
            assert!(r.issues[0].message.contains(needle), "{}", r.issues[0]);
            assert!(r.issues[0].path.starts_with("graph/"), "{}", r.issues[0]);
        }
    }
}

/// A raw-profile tree of levels 0..=`depth`, level `d` holding 2^d nodes in one block whose
/// frame inflates to zeros: a few KB standing for 2^(depth+1) - 1 nodes. The index is
/// consistent, so only what the nodes stand for can refuse it before decoding.
fn claimed_tree_file(depth: u32) -> Vec<u8> {
    let levels: Vec<LevelEntry> =
        (0..=depth).map(|d| LevelEntry { node_count: 1 << d, first_block: d.saturating_sub(1), block_count: (d > 0) as u32 }).collect();
    let mut at = craft::index_len(levels.len(), depth as usize);
    let (mut blocks, mut data) = (Vec::new(), Vec::new());
    for d in 1..=depth {
        let m = 1u64 << d;
        let raw_len = m.div_ceil(8) + 40 * m;
        let frame = craft::rle_frame(&[], 0, raw_len);
        blocks.push(BlockEntry { level: d, node_count: m as u32, first_node: 0, internal_before: 0, offset: at, stored_len: frame.len() as u32, raw_len: raw_len as u32, crc: 0, flags: 1 });
        at += frame.len() as u64;
        data.extend_from_slice(&frame);
    }
    let header = TreeHeader {
        profile: 0,
        flags: 0,
        root_internal: 1,
        level_count: depth + 1,
        node_count: (1 << (depth + 1)) - 1,
        leaf_count: 1 << depth,
        block_count: depth,
        root: leaf(0.0, 1),
    };
    let tree = craft::tree_section(&header, &levels, &blocks, &data);
    craft::container(
        SCT_MAGIC,
        &[Sec::plain(tags::GENR, craft::genr()), Sec::zstd(tags::GRPH, &craft::graph_bytes(&[G::Tree(0)], 0)), Sec::plain(tags::TREE, tree)],
    )
}

/// A scene file of a few KB whose blocks (each within every cap, each raw length what its
/// nodes need) stand for 8.4 M nodes, 335 MB decoded: refused by the decoded-size bound from
/// the index, before any block is inflated, by the reader and the validator. Such files
/// multiply: a 1 MB file held 1 G nodes, minutes of `--deep` and gigabytes of `--export-ply`.
#[test]
fn decoded_size_is_bounded_by_the_file_size() {
    let file = claimed_tree_file(22);
    assert!(file.len() < 20_000, "{}", file.len());
    limit(SctReader::from_bytes(file.clone(), &Limits::default()).map(|_| ()), sct_format::limits::DECODED_SIZE);
    for deep in [false, true] {
        let r = validate_bytes(&file, &ValidateOptions { deep, ..Default::default() });
        assert_eq!(r.check_ids(), vec![CheckId::Limit], "{:?}", r.issues);
    }
    // A caller that trusts the file raises the bound; a tree within the floor always opens.
    let trusting = Limits { max_decoded_ratio: u64::MAX, ..Limits::default() };
    assert_eq!(SctReader::from_bytes(file, &trusting).expect("opens").trees()[0].header.node_count, (1 << 23) - 1);
    assert!(SctReader::from_bytes(claimed_tree_file(21), &Limits::default()).is_ok());

    // Samples: 110 chunks of zeros (10 KB) stand for 7.2 M samples, 288 MB decoded.
    let samples = samples_file(110, 65_536, |n| craft::rle_frame(&[], 0, 36 * n as u64));
    assert!(samples.len() < 20_000, "{}", samples.len());
    limit(SamplesFile::read(&samples, &Limits::default()).map(|_| ()), sct_format::limits::DECODED_SIZE);
    let small = samples_file(3, 65_536, |n| craft::rle_frame(&[], 0, 36 * n as u64));
    let tight = Limits { decoded_floor: 1 << 20, ..Limits::default() };
    limit(SamplesFile::read(&small, &tight).map(|_| ()), sct_format::limits::DECODED_SIZE);
    let trusting = Limits { max_decoded_ratio: u64::MAX, ..tight };
    assert_eq!(SamplesFile::read(&small, &trusting).expect("reads").samples.len(), 3 * 65_536);
    // And 4.2 M placements (68 bytes each) in a few KB of INST (item 13's file); refused
    // before the frame (garbage inside) is inflated.
    let n = 4_200_000u64;
    let raw_len = 8 + 68 * n;
    let inst = craft::rle_frame(&n.to_le_bytes(), 0, raw_len);
    let mut mesh = 1u64.to_le_bytes().to_vec();
    mesh.extend_from_slice(&0u64.to_le_bytes());
    mesh.extend_from_slice(&1u64.to_le_bytes());
    mesh.extend_from_slice(&0u32.to_le_bytes());
    let one = zstd::bulk::compress(&[0u8; 36], 1).expect("compress");
    let mut smps = 1u32.to_le_bytes().to_vec();
    smps.extend_from_slice(&(one.len() as u32).to_le_bytes());
    smps.extend_from_slice(&one);
    let file = craft::container(
        SAMPLES_MAGIC,
        &[Sec::plain(tags::GENR, craft::genr()), Sec::plain(tags::MESH, mesh), Sec::frame(tags::INST, inst, raw_len), Sec::plain(*b"SMPS", smps)],
    );
    assert!(file.len() < 20_000, "{}", file.len());
    limit(SamplesFile::read(&file, &Limits::default()).map(|_| ()), sct_format::limits::DECODED_SIZE);

    // Affine placements: each is baked into a copy of its mesh, so 110 placements of one
    // 65,536-sample chunk stand for 288 MB, though the file holds 2.6 MB decoded; 10 read.
    let affine = |placements: u64| {
        let f = craft::rle_frame(&[], 0, 36 * 65_536);
        let mut smps = 65_536u32.to_le_bytes().to_vec();
        smps.extend_from_slice(&(f.len() as u32).to_le_bytes());
        smps.extend_from_slice(&f);
        let mut affi = placements.to_le_bytes().to_vec();
        for _ in 0..placements {
            affi.extend_from_slice(&0u32.to_le_bytes());
            for v in [2.0f64, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
                affi.extend_from_slice(&v.to_le_bytes());
            }
        }
        container_samples_with(65_536, Sec::plain(*b"SMPS", smps), vec![Sec::zstd(*b"AFFI", &affi)])
    };
    let file = affine(110);
    assert!(file.len() < 10_000, "{}", file.len());
    limit(SamplesFile::read(&file, &Limits::default()).map(|_| ()), sct_format::limits::DECODED_SIZE);
    assert_eq!(SamplesFile::read(&affine(10), &Limits::default()).expect("reads").affine_instances.len(), 10);
}

/// The bound is the larger of the floor and the ratio times the file's size.
#[test]
fn decoded_bound_is_floor_or_ratio() {
    let l = Limits { max_decoded_ratio: 10, decoded_floor: 1000, ..Limits::default() };
    assert!(l.check_decoded(1000, 1).is_ok());
    assert!(l.check_decoded(1001, 1).is_err());
    assert!(l.check_decoded(5000, 500).is_ok());
    match l.check_decoded(5001, 500) {
        Err(Error::LimitExceeded { value: 5001, limit: 5000, .. }) => {}
        other => panic!("{other:?}"),
    }
    assert!(Limits::unlimited().check_decoded(u64::MAX, 0).is_ok());
}
