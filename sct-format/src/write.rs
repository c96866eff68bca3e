//! Writing SCT files (spec §2–§7).
//!
//! To a plain writer ([`write_scene`]) the scene is encoded in memory section by section
//! (trees in parallel blocks), so every offset is known before the first byte is written.
//! To a path ([`write_scene_file`]) it streams: blocks go to the temporary file as they are
//! encoded and the header, section table and tree indexes are patched in by seeking back,
//! then the file is renamed into place (atomic either way).

use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::Path;

use rayon::prelude::*;

use crate::codec::{encode_children_with_leaves, CodecParams, Profile};
use crate::container::{header_and_table, write_container_minor, SectionOut};
use crate::error::{Error, Result};
use crate::graph::{Generator, GraphNode, Propagation, SceneGraph};
use crate::node::Node;
use crate::raw::cursor::Put;
use crate::raw::{
    tags, BlockEntry, LevelEntry, SectionEntry, TreeHeader, BLOCK_ENTRY_LEN, FILE_HEADER_LEN, LEVEL_ENTRY_LEN, SCT_MAGIC,
    SECTION_ENTRY_LEN, TREE_HEADER_LEN,
};
use crate::samples::put_similarity;
use crate::tree::SceneTree;

/// A complete scene: provenance, graph and the trees the graph refers to.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Scene {
    /// Provenance (first section of the file).
    pub generator: Generator,
    /// The scene graph.
    pub graph: SceneGraph,
    /// Scene trees, referenced by index from the graph.
    pub trees: Vec<SceneTree>,
}

impl Scene {
    /// A scene of one tree.
    pub fn single_tree(generator: Generator, tree: SceneTree) -> Self {
        Scene {
            generator,
            graph: SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }], root: 0 },
            trees: vec![tree],
        }
    }
}

/// zstd level used for the default profile's blocks unless the caller picks one. Measured on
/// the Table-8 bunny samples (2.34 M leaves, BENCHMARKS.md "Node codecs"), with one zstd block
/// per stream: level 1 gives 6.86 B/leaf in 2.9 s, 3 gives 7.03, 9 gives 6.76 at +0.7 s, 19
/// gives 6.65 at +8.9 s. Level 1 keeps compression off the critical path;
/// `--compression-level 19` buys ~3 %.
pub const DEFAULT_ZSTD_LEVEL: i32 = 1;

/// How to encode.
#[derive(Clone, Debug, PartialEq)]
pub struct WriteOptions {
    /// Node profile for every tree.
    pub profile: Profile,
    /// zstd level for tree blocks; `None` uses the profile's default (zstd 1 for the default
    /// profile, no compression for raw and canopy); `Some(0)` disables compression.
    pub compression_level: Option<i32>,
    /// Most nodes per block (rounded down to even, at least 2).
    pub block_nodes: u32,
    /// Default profile only: store centre offsets that move each leaf's centre back onto its
    /// surface along its normal (spec 1.2, tree flag bit 2; about 0.5 bytes a leaf). Files
    /// written without them stay readable by 1.0/1.1 readers.
    pub centre_offsets: bool,
    /// Default profile only: which leaves store a centre step and radius cut (spec 1.4, tree
    /// flag bit 3; about 2–3 bytes a refined leaf). A tree refined whole needs no centre
    /// offsets and stores none.
    pub leaf_refinement: LeafRefinement,
}

/// Which trees of a scene get leaf refinement ([`WriteOptions::leaf_refinement`]).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum LeafRefinement {
    /// No tree (files stay readable by 1.3 readers).
    #[default]
    None,
    /// Every leaf of every tree.
    All,
    /// Every leaf of the trees whose indices (into the scene's trees) are listed; no other.
    Trees(Vec<u32>),
    /// Every leaf of the listed trees; in every other tree (when it has centre offsets) the
    /// leaves that the position code moves off their piece of surface where that may leave
    /// the surface (spec/SCT-profiles.md §3, "leaf refinement where it is needed").
    OffSurface(Vec<u32>),
}

impl LeafRefinement {
    /// Whether every leaf of tree `i` is refined.
    pub fn refines(&self, i: usize) -> bool {
        match self {
            LeafRefinement::None => false,
            LeafRefinement::All => true,
            LeafRefinement::Trees(t) | LeafRefinement::OffSurface(t) => t.iter().any(|&k| k as usize == i),
        }
    }
}

impl Default for WriteOptions {
    fn default() -> Self {
        WriteOptions { profile: Profile::Default, compression_level: None, block_nodes: 16384, centre_offsets: true, leaf_refinement: LeafRefinement::None }
    }
}

impl WriteOptions {
    /// The codec parameters of tree `i`, with (`alpha`) or without translucent nodes.
    fn codec_params(&self, i: usize, alpha: bool) -> CodecParams {
        let default = self.profile == Profile::Default;
        let whole = default && self.leaf_refinement.refines(i);
        let offsets = self.centre_offsets && default && !whole;
        // With offsets, the codec refines only the leaves that need it.
        let where_needed = offsets && matches!(self.leaf_refinement, LeafRefinement::OffSurface(_));
        CodecParams { alpha, centre_offsets: offsets, leaf_refinement: whole || where_needed }
    }

    fn zstd_level(&self) -> Option<i32> {
        match self.compression_level {
            Some(0) => None,
            Some(l) => Some(l),
            None if self.profile.compress_by_default() => Some(DEFAULT_ZSTD_LEVEL),
            None => None,
        }
    }
}

/// Sizes of one encoded tree.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct TreeStats {
    /// Nodes.
    pub nodes: u64,
    /// Leaves.
    pub leaves: u64,
    /// Levels.
    pub levels: u32,
    /// Blocks.
    pub blocks: u32,
    /// Bytes of the whole `TREE` section.
    pub section_bytes: u64,
    /// Bytes of header, level table and block table.
    pub index_bytes: u64,
    /// Uncompressed bytes of the child-flag bitmasks.
    pub flag_bytes: u64,
    /// Uncompressed bytes of codec payloads.
    pub payload_bytes: u64,
    /// Blocks of each level (level 0, the root in the header, has none). A block is our
    /// "container": a run of at most `block_nodes` consecutive nodes of one level.
    pub blocks_per_level: Vec<u32>,
    /// Stored block bytes by what they encode: `topology` (has-children masks), then
    /// `position_radius`, `normal`, `cone`, `color`, `area` (see [`crate::codec::streams`];
    /// exact for the default profile's streams, split by field width for record profiles).
    /// Their sum plus `index_bytes` is `section_bytes`.
    pub attribute_bytes: Vec<(String, u64)>,
}

/// What was written.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct WriteStats {
    /// Total file size.
    pub bytes: u64,
    /// `(tag, stored bytes)` per section in file order.
    pub sections: Vec<(String, u64)>,
    /// Per-tree statistics.
    pub trees: Vec<TreeStats>,
}

/// The minor version a scene file of `trees` trees is labelled with: the newest whose
/// features it uses (1.4: leaf refinement; 1.3: affine instances; 1.2: centre offsets; 1.1:
/// two-sided trees), so that files without them stay byte-for-byte files of the older version.
fn scene_minor(trees: usize, two_sided: bool, affine: bool, opts: &WriteOptions) -> u16 {
    if (0..trees).any(|i| opts.codec_params(i, false).leaf_refinement) {
        4
    } else if affine {
        3
    } else if (0..trees).any(|i| opts.codec_params(i, false).centre_offsets) {
        2
    } else {
        two_sided as u16
    }
}

/// Whether the graph holds an affine instance (a 1.3 feature).
fn has_affine(g: &SceneGraph) -> bool {
    g.nodes.iter().any(|n| matches!(n, GraphNode::Affine { .. }))
}

/// Encodes and writes `scene` to `w`.
pub fn write_scene<W: Write>(scene: &Scene, opts: &WriteOptions, w: W) -> Result<WriteStats> {
    check_graph(scene)?;
    let genr = serde_json::to_vec(&scene.generator).map_err(|e| Error::Misuse(format!("generator: {e}")))?;
    let mut sections = vec![SectionOut::plain(tags::GENR, genr), SectionOut::zstd(tags::GRPH, &encode_graph(&scene.graph), 3)?];
    let mut tree_stats = Vec::with_capacity(scene.trees.len());
    for (i, tree) in scene.trees.iter().enumerate() {
        let (bytes, stats) = encode_tree_at(i, tree, opts)?;
        tree_stats.push(stats);
        sections.push(SectionOut::plain(tags::TREE, bytes));
    }
    let (bytes, _) = write_container_minor(SCT_MAGIC, scene_minor(scene.trees.len(), scene.trees.iter().any(SceneTree::is_two_sided), has_affine(&scene.graph), opts), &sections, w)?;
    Ok(WriteStats {
        bytes,
        sections: sections.iter().map(|s| (s.tag.escape_ascii().to_string(), s.stored.len() as u64)).collect(),
        trees: tree_stats,
    })
}

/// Encodes and writes `scene` to `path` atomically.
///
/// Produces the same bytes as [`write_scene`], but streams: each tree's blocks go to the
/// (temporary) file as they are encoded, and the parts whose contents are only known at the
/// end (file header, section table, each tree's index) are reserved as zeros and written by
/// seeking back. So no whole encoded tree is ever held in memory.
pub fn write_scene_file(path: &Path, scene: &Scene, opts: &WriteOptions) -> Result<WriteStats> {
    check_graph(scene)?;
    let trees = scene.trees.iter().map(TreeInput::borrowed);
    crate::atomic::write_atomic(path, |w| {
        stream_scene(&scene.generator, &scene.graph, trees, opts, w).map_err(|e| with_path(e, path))
    })
}

/// [`write_scene_file`] consuming the scene: every tree's nodes are released block by block
/// as they are written, so the memory held falls while the file grows (a builder that hands
/// its finished tree to the writer peaks at about the tree, not the tree plus the writer's
/// decoded parents). Same bytes as [`write_scene_file`].
pub fn write_scene_file_owned(path: &Path, scene: Scene, opts: &WriteOptions) -> Result<WriteStats> {
    check_graph(&scene)?;
    let Scene { generator, graph, trees } = scene;
    let trees = trees.into_iter().map(TreeInput::owned);
    crate::atomic::write_atomic(path, |w| stream_scene(&generator, &graph, trees, opts, w).map_err(|e| with_path(e, path)))
}

/// Most nodes per block as used (even, at least 2).
fn block_nodes(opts: &WriteOptions) -> usize {
    (opts.block_nodes.max(2) & !1) as usize
}

/// Gives an I/O error from the streaming writer the output's name (the temporary file is
/// an implementation detail).
fn with_path(e: Error, path: &Path) -> Error {
    match e {
        Error::Io { path: None, source } => Error::io(path, source),
        e => e,
    }
}

/// Stored blocks at least this long go around the writer's buffer.
const UNBUFFERED_BLOCK: usize = 64 << 10;

/// Writes one stored block. A long one goes straight to the file after what is buffered:
/// copying it into the buffer first would be one more pass over the bytes for nothing (a
/// block a few times shorter than the buffer is about as few system calls either way).
fn write_block<W: Write>(w: &mut BufWriter<W>, block: &[u8]) -> Result<()> {
    if block.len() >= UNBUFFERED_BLOCK {
        w.flush()?;
        w.get_mut().write_all(block)?;
    } else {
        w.write_all(block)?;
    }
    Ok(())
}

/// The streaming writer behind [`write_scene_file`]. Mirrors [`write_container`]'s layout
/// (header, section table, sections in order), which needs every section in memory.
/// The graph must have been checked ([`check_graph`]).
fn stream_scene<'a, W: Write + Seek + Send>(
    generator: &Generator,
    graph: &SceneGraph,
    trees: impl ExactSizeIterator<Item = TreeInput<'a>>,
    opts: &WriteOptions,
    w: &mut BufWriter<W>,
) -> Result<WriteStats> {
    let genr = serde_json::to_vec(generator).map_err(|e| Error::Misuse(format!("generator: {e}")))?;
    let small = [SectionOut::plain(tags::GENR, genr), SectionOut::zstd(tags::GRPH, &encode_graph(graph), 3)?];
    let section_count = small.len() + trees.len();
    let table_len = section_count * SECTION_ENTRY_LEN;
    let start = w.stream_position()?;
    // Header and table are filled in last; everything after them is written once, in order.
    w.write_all(&vec![0u8; FILE_HEADER_LEN + table_len])?;
    let mut offset = (FILE_HEADER_LEN + table_len) as u64;
    let mut entries = Vec::with_capacity(section_count);
    for s in &small {
        w.write_all(&s.stored)?;
        entries.push(s.entry(offset));
        offset += s.stored.len() as u64;
    }
    let mut tree_stats = Vec::with_capacity(section_count);
    let mut two_sided = false;
    let tree_count = trees.len();
    for (i, tree) in trees.enumerate() {
        two_sided |= tree.two_sided;
        let index_len = tree.index_len(block_nodes(opts));
        w.write_all(&vec![0u8; index_len])?;
        let params = opts.codec_params(i, tree.alpha);
        let st = stream_tree(tree, params, opts, &mut |b| write_block(w, b))?;
        let end = start + offset + st.stats.section_bytes;
        // The index lies in front of the blocks; its CRC is combined with the blocks' so the
        // section CRC equals that of the bytes in file order without reading them back.
        w.seek(SeekFrom::Start(start + offset))?;
        w.write_all(&st.index)?;
        w.seek(SeekFrom::Start(end))?;
        let mut crc = crc32fast::Hasher::new();
        crc.update(&st.index);
        crc.combine(&st.blocks_crc);
        entries.push(SectionEntry {
            tag: tags::TREE,
            flags: SectionEntry::REQUIRED,
            offset,
            stored_len: st.stats.section_bytes,
            raw_len: st.stats.section_bytes,
            crc: crc.finalize(),
        });
        offset += st.stats.section_bytes;
        tree_stats.push(st.stats);
    }
    w.seek(SeekFrom::Start(start))?;
    w.write_all(&header_and_table(SCT_MAGIC, scene_minor(tree_count, two_sided, has_affine(graph), opts), &entries, offset))?;
    w.seek(SeekFrom::Start(start + offset))?;
    Ok(WriteStats {
        bytes: offset,
        sections: entries.iter().map(|e| (e.tag.escape_ascii().to_string(), e.stored_len)).collect(),
        trees: tree_stats,
    })
}

fn check_graph(scene: &Scene) -> Result<()> {
    let g = &scene.graph;
    if g.nodes.is_empty() {
        return Err(Error::Misuse("the scene graph has no nodes".into()));
    }
    if g.root as usize >= g.nodes.len() {
        return Err(Error::Misuse(format!("root {} out of range ({} graph nodes)", g.root, g.nodes.len())));
    }
    let tree_ok = |t: u32| -> Result<&SceneTree> {
        scene.trees.get(t as usize).ok_or_else(|| Error::Misuse(format!("graph refers to tree {t}, there are {}", scene.trees.len())))
    };
    for (i, n) in g.nodes.iter().enumerate() {
        let earlier = |c: u32| -> Result<()> {
            if c as usize >= i {
                return Err(Error::Misuse(format!("graph node {i} refers to node {c}; references must point to earlier nodes")));
            }
            Ok(())
        };
        match n {
            GraphNode::Tree { tree } => {
                tree_ok(*tree)?;
            }
            GraphNode::Group { children, tree } => {
                let t = tree_ok(*tree)?;
                children.iter().try_for_each(|&c| earlier(c))?;
                if t.leaf_count() != children.len() {
                    return Err(Error::Misuse(format!(
                        "group {i} has {} children but its tree has {} leaves",
                        children.len(),
                        t.leaf_count()
                    )));
                }
            }
            GraphNode::Instance { child, transform, .. } => {
                earlier(*child)?;
                if !transform.is_valid(1e-6) {
                    return Err(Error::Misuse(format!("instance {i} has an invalid transform ({transform})")));
                }
            }
            GraphNode::Affine { child, transform, .. } => {
                earlier(*child)?;
                if let Some(why) = transform.problem() {
                    return Err(Error::Misuse(format!("affine instance {i}: {why}")));
                }
            }
            GraphNode::Inline { path, .. } => {
                if path.is_empty() || path.contains('\\') || path.starts_with('/') {
                    return Err(Error::Misuse(format!("inline {i} path {path:?} must be relative with '/' separators")));
                }
            }
        }
    }
    for (i, t) in scene.trees.iter().enumerate() {
        if t.level_count() > 0 && t.leaf_count() * 2 != t.len() + 1 {
            return Err(Error::Misuse(format!("tree {i} is truncated (not all levels are present)")));
        }
        // The reader refuses such a file at open. A group tree built over instances whose
        // placements reach past f32 (an affine entry near f32::MAX, a huge scale) gets one.
        if let Some(root) = t.nodes().first().filter(|r| !r.is_finite()) {
            return Err(Error::Misuse(format!("tree {i} has a root with non-finite or out-of-range attributes ({root})")));
        }
    }
    Ok(())
}

/// Graph record kinds (spec §7).
pub(crate) mod kind {
    pub const TREE: u8 = 0;
    pub const GROUP: u8 = 1;
    pub const INSTANCE: u8 = 2;
    pub const INLINE: u8 = 3;
    pub const AFFINE: u8 = 4;
}

/// An instance's flags byte (spec §7): bit 0 size push-down, bit 1 colour push-down, bit 2
/// tint present.
fn instance_flags(attrs: &crate::graph::InstanceAttrs) -> u8 {
    let mut flags = 0u8;
    if attrs.size == Propagation::PushDown {
        flags |= 1;
    }
    if attrs.color == Propagation::PushDown {
        flags |= 2;
    }
    if attrs.tint.is_some() {
        flags |= 4;
    }
    flags
}

fn encode_graph(g: &SceneGraph) -> Vec<u8> {
    let mut out = Vec::new();
    out.put_u64(g.nodes.len() as u64);
    out.put_u32(g.root);
    for n in &g.nodes {
        match n {
            GraphNode::Tree { tree } => {
                out.put_u8(kind::TREE);
                out.put_u32(*tree);
            }
            GraphNode::Group { children, tree } => {
                out.put_u8(kind::GROUP);
                out.put_u32(*tree);
                out.put_u64(children.len() as u64);
                children.iter().for_each(|c| out.put_u32(*c));
            }
            GraphNode::Instance { child, transform, attrs } => {
                out.put_u8(kind::INSTANCE);
                out.put_u32(*child);
                put_similarity(&mut out, transform);
                out.put_u8(instance_flags(attrs));
                out.extend_from_slice(&attrs.tint.unwrap_or([255; 4]));
            }
            GraphNode::Affine { child, transform, attrs } => {
                out.put_u8(kind::AFFINE);
                out.put_u32(*child);
                transform.matrix.iter().flatten().for_each(|v| out.put_f64(*v));
                out.put_u8(instance_flags(attrs));
                out.extend_from_slice(&attrs.tint.unwrap_or([255; 4]));
            }
            GraphNode::Inline { path, hash, bound } => {
                out.put_u8(kind::INLINE);
                out.put_str(path);
                out.extend_from_slice(hash);
                crate::codec::raw::write_node(bound, &mut out);
            }
        }
    }
    out
}

/// One zstd frame of `payload`, ending a zstd block at every stream boundary of `lens`, so
/// that each block's entropy tables (Huffman literals, FSE) fit one stream instead of a mix.
/// Any zstd decoder reads it as before (a frame of several blocks); only the bytes shrink.
/// Also returns the stored bytes of each stream (the frame's end goes to the last).
fn compress_streams(payload: &[u8], lens: &[usize], level: i32) -> Result<(Vec<u8>, Vec<usize>)> {
    use zstd::stream::raw::{Encoder, Operation};
    thread_local! {
        /// Each worker's zstd context (with its level) and output buffer, reused from block
        /// to block: a fresh context per block costs its allocation and first-touch page
        /// faults. zstd's output depends only on the parameters, not on the context's past.
        static CONTEXT: std::cell::RefCell<Option<(i32, Encoder<'static>, Vec<u8>)>> = const { std::cell::RefCell::new(None) };
    }
    CONTEXT.with(|cell| {
        let mut cell = cell.borrow_mut();
        let (enc, buf) = match &mut *cell {
            Some((l, enc, buf)) if *l == level => (enc, buf),
            slot => {
                let ctx = (level, Encoder::new(level)?, vec![0u8; zstd::zstd_safe::CCtx::out_size().max(1 << 17)]);
                let (_, enc, buf) = slot.insert(ctx);
                (enc, buf)
            }
        };
        // A block that failed half way must not leave its frame open.
        enc.reinit()?;
        compress_streams_with(enc, buf, payload, lens)
    })
}

/// [`compress_streams`] with a given context and output buffer.
fn compress_streams_with(
    enc: &mut zstd::stream::raw::Encoder<'static>,
    buf: &mut [u8],
    payload: &[u8],
    lens: &[usize],
) -> Result<(Vec<u8>, Vec<usize>)> {
    use zstd::stream::raw::{InBuffer, Operation, OutBuffer};
    enc.set_pledged_src_size(Some(payload.len() as u64))?;
    let mut out: Vec<u8> = Vec::with_capacity(payload.len() / 2 + 1024);
    let mut sizes = Vec::with_capacity(lens.len());
    let mut at = 0usize;
    let mut done = 0usize;
    for (k, &len) in lens.iter().enumerate() {
        let end = (at + len).min(payload.len());
        let mut inb = InBuffer::around(&payload[at..end]);
        while inb.pos() < inb.src.len() {
            let mut ob = OutBuffer::around(&mut *buf);
            enc.run(&mut inb, &mut ob)?;
            out.extend_from_slice(ob.as_slice());
        }
        at = end;
        let last = k + 1 == lens.len();
        loop {
            let mut ob = OutBuffer::around(&mut *buf);
            let left = if last { enc.finish(&mut ob, true)? } else { enc.flush(&mut ob)? };
            out.extend_from_slice(ob.as_slice());
            if left == 0 {
                break;
            }
        }
        sizes.push(out.len() - done);
        done = out.len();
    }
    if at != payload.len() {
        return Err(Error::Misuse(format!("streams cover {at} of {} payload bytes (bug)", payload.len())));
    }
    Ok((out, sizes))
}

/// One encoded block, as a worker returns it.
struct EncodedBlock {
    stored: Vec<u8>,
    /// CRC-32 of `stored`.
    crc: u32,
    flags: u32,
    mask_len: u64,
    payload_len: u64,
    /// Stored bytes per [`TreeStats::attribute_bytes`] entry.
    attribute_bytes: [u64; 7],
    /// The block's decoded internal nodes: parents of the next level.
    parents: Vec<Node>,
}

/// Splits `bytes` over the attributes in proportion to `widths` (remainder to the first).
fn split_bytes(bytes: usize, widths: &[u32; 6], into: &mut [u64; 7]) {
    let total: u64 = widths.iter().map(|&w| w as u64).sum();
    if total == 0 {
        into[6] += bytes as u64;
        return;
    }
    let mut given = 0;
    for (k, &w) in widths.iter().enumerate() {
        let share = bytes as u64 * w as u64 / total;
        into[k + 1] += share;
        given += share;
    }
    if let Some(k) = widths.iter().position(|&w| w > 0) {
        into[k + 1] += bytes as u64 - given;
    }
}

/// Encodes one block, keeping its decoded nodes with children (`internal` of them).
fn encode_block(
    opts: &WriteOptions,
    params: CodecParams,
    parents: &[Node],
    nodes: &[Node],
    flags: &[bool],
    internal: usize,
) -> Result<EncodedBlock> {
    let profile = opts.profile;
    let m = nodes.len();
    let mask_len = m.div_ceil(8);
    let mut payload: Vec<u8> = flags.chunks(8).map(|c| c.iter().rev().fold(0u8, |b, &f| b << 1 | f as u8)).collect();
    let decoded = encode_children_with_leaves(profile, params, parents, nodes, Some(flags), &mut payload)?;
    let raw_len = payload.len();
    let streams = crate::codec::streams(profile, params, m);
    let mut attribute_bytes = [0u64; 7];
    let (stored, bflags) = match opts.zstd_level() {
        Some(l) => {
            let lens: Vec<usize> = std::iter::once(mask_len).chain(streams.iter().map(|s| s.len)).collect();
            let (stored, sizes) = compress_streams(&payload, &lens, l)?;
            attribute_bytes[0] = sizes[0] as u64;
            for (st, &sz) in streams.iter().zip(&sizes[1..]) {
                split_bytes(sz, &st.widths, &mut attribute_bytes);
            }
            (stored, 1u32)
        }
        None => {
            attribute_bytes[0] = mask_len as u64;
            for st in &streams {
                split_bytes(st.len, &st.widths, &mut attribute_bytes);
            }
            (payload, 0u32)
        }
    };
    // Sized exactly, so the segment holds no more than the internal nodes.
    let mut next_parents = Vec::with_capacity(internal);
    next_parents.extend(decoded.iter().zip(flags).filter(|(_, &f)| f).map(|(n, _)| *n));
    Ok(EncodedBlock {
        crc: crc32fast::hash(&stored),
        stored,
        flags: bflags,
        mask_len: mask_len as u64,
        payload_len: (raw_len - mask_len) as u64,
        attribute_bytes,
        parents: next_parents,
    })
}

/// Blocks encoded at once per level, per worker thread: enough to keep every worker busy
/// while only this many stored blocks (not a whole level) wait in memory to be written.
const BLOCKS_IN_FLIGHT_PER_THREAD: usize = 2;

/// A tree as the streaming writer consumes it: its shape, and its nodes either borrowed or
/// owned, in which case they are released batch by batch as they are encoded.
struct TreeInput<'a> {
    flags: std::borrow::Cow<'a, [bool]>,
    /// Node index range of every level.
    levels: Vec<std::ops::Range<usize>>,
    leaves: usize,
    root: Option<Node>,
    alpha: bool,
    two_sided: bool,
    nodes: NodeSource<'a>,
}

/// Where [`stream_tree`] gets each batch's nodes.
enum NodeSource<'a> {
    /// All nodes, breadth first.
    Borrowed(&'a [Node]),
    /// The nodes not yet encoded, in reverse breadth-first order: those encoded next are at
    /// the end, so they are released by shrinking the vector, without copying the rest.
    Reversed { rest: Vec<Node>, total: usize },
}

impl<'a> TreeInput<'a> {
    fn shape(tree: &SceneTree) -> (Vec<std::ops::Range<usize>>, usize, Option<Node>, bool) {
        let levels = (0..tree.level_count()).map(|d| tree.level(d)).collect();
        // On every thread: for an opaque tree this reads every node.
        let alpha = tree.nodes().par_iter().any(|n| n.color[3] != 255);
        (levels, tree.leaf_count(), tree.nodes().first().copied(), alpha)
    }

    fn borrowed(tree: &'a SceneTree) -> Self {
        let (levels, leaves, root, alpha) = Self::shape(tree);
        let two_sided = tree.is_two_sided();
        TreeInput { flags: tree.internal_flags().into(), levels, leaves, root, alpha, two_sided, nodes: NodeSource::Borrowed(tree.nodes()) }
    }

    /// Takes the tree's nodes, reversed in place (no second allocation); the root, which
    /// the tree header holds, is dropped.
    fn owned(tree: SceneTree) -> Self {
        let (levels, leaves, root, alpha) = Self::shape(&tree);
        let two_sided = tree.is_two_sided();
        let (mut rest, flags) = tree.into_parts();
        let total = rest.len();
        let (front, back) = rest.split_at_mut(total / 2);
        front.par_iter_mut().zip(back.par_iter_mut().rev()).with_min_len(1 << 12).for_each(|(a, b)| std::mem::swap(a, b));
        rest.pop();
        TreeInput { flags: flags.into(), levels, leaves, root, alpha, two_sided, nodes: NodeSource::Reversed { rest, total } }
    }

    fn len(&self) -> usize {
        self.levels.last().map_or(0, |r| r.end)
    }

    /// Bytes of the tree's index (header, level table, block table): known before any
    /// block is encoded, so a streaming writer can reserve it and fill it in afterwards.
    fn index_len(&self, block_nodes: usize) -> usize {
        let block_count: usize = self.levels.iter().skip(1).map(|r| r.len().div_ceil(block_nodes)).sum();
        TREE_HEADER_LEN + self.levels.len() * LEVEL_ENTRY_LEN + block_count * BLOCK_ENTRY_LEN
    }
}

impl NodeSource<'_> {
    /// Nodes `range` (breadth-first indices) of one batch; batches are asked for in file
    /// order. Owned nodes are moved into `buf` and released from the tree.
    fn batch<'b>(&'b mut self, range: std::ops::Range<usize>, buf: &'b mut Vec<Node>) -> Result<&'b [Node]> {
        let bug = || Error::Misuse(format!("nodes {range:?} requested out of order (bug)"));
        match self {
            NodeSource::Borrowed(all) => all.get(range.clone()).ok_or_else(bug),
            NodeSource::Reversed { rest, total } => {
                if rest.len() + range.start != *total || range.end > *total {
                    return Err(bug());
                }
                let keep = *total - range.end;
                buf.clear();
                buf.par_extend(rest[keep..].par_iter().rev().copied());
                rest.truncate(keep);
                // Shrinking costs a realloc (for a large vector an mremap that frees the
                // pages); once per this many bytes of surplus capacity.
                const SHRINK_BYTES: usize = 4 << 20;
                if (rest.capacity() - rest.len()) * std::mem::size_of::<Node>() >= SHRINK_BYTES {
                    rest.shrink_to_fit();
                }
                Ok(buf)
            }
        }
    }
}

/// Decoded internal nodes of one level in the order the next level consumes them, as one
/// segment per encoded block. Segments are dropped as soon as the next level's batches have
/// used them, so a level's parents shrink while its children grow: the two levels together
/// hold about the larger of them (plus a batch) instead of their sum.
#[derive(Default)]
struct ParentQueue {
    segments: std::collections::VecDeque<Vec<Node>>,
    /// Index within the level of the first node of `segments[0]`.
    first: usize,
}

impl ParentQueue {
    /// Parents `from..to` (callers ask for consecutive ranges): borrowed when one segment
    /// holds them all (the usual case: a block's parents are about half as many nodes as
    /// the block above them that decoded them), else copied together.
    fn range(&self, from: usize, to: usize) -> Result<std::borrow::Cow<'_, [Node]>> {
        let mut at = self.first;
        for seg in &self.segments {
            if from >= at && to <= at + seg.len() {
                return Ok(std::borrow::Cow::Borrowed(&seg[from - at..to - at]));
            }
            at += seg.len();
            if at > from {
                break;
            }
        }
        let mut out = Vec::with_capacity(to.saturating_sub(from));
        let mut at = self.first;
        for seg in &self.segments {
            let (lo, hi) = (from.max(at), to.min(at + seg.len()));
            if lo < hi {
                out.extend_from_slice(&seg[lo - at..hi - at]);
            }
            at += seg.len();
            if at >= to {
                break;
            }
        }
        if out.len() != to - from {
            return Err(Error::Misuse(format!("parents {from}..{to} requested, {} available (bug)", out.len())));
        }
        Ok(std::borrow::Cow::Owned(out))
    }

    /// Drops the segments that end by `to`.
    fn release(&mut self, to: usize) {
        while let Some(seg) = self.segments.front() {
            if self.first + seg.len() > to {
                break;
            }
            self.first += seg.len();
            self.segments.pop_front();
        }
    }
}

/// A tree whose blocks went to a sink: the index to put in front of them and the CRC-32
/// state of the block bytes (so the section CRC needs no second pass over them).
struct StreamedTree {
    index: Vec<u8>,
    blocks_crc: crc32fast::Hasher,
    stats: TreeStats,
}

/// Encodes one tree, handing its stored blocks to `sink` in file order as they are encoded
/// (the index, which goes in front of them, comes back at the end).
///
/// Blocks of a level are encoded in parallel (each needs only its decoded parents), a bounded
/// batch at a time and levels in order, so memory holds at most one batch of stored blocks
/// besides the tree, and of decoded nodes with children, the part of one level not yet used
/// as parents and the part of the next already written (see [`ParentQueue`]).
fn stream_tree(
    mut tree: TreeInput<'_>,
    params: CodecParams,
    opts: &WriteOptions,
    sink: &mut (dyn FnMut(&[u8]) -> Result<()> + Send),
) -> Result<StreamedTree> {
    let profile = opts.profile;
    let block_nodes = block_nodes(opts);
    let levels = tree.levels.len();
    let node_count = tree.len();
    let mut level_table = vec![LevelEntry::default(); levels];
    let mut stats = TreeStats { nodes: node_count as u64, leaves: tree.leaves as u64, levels: levels as u32, ..Default::default() };
    let flags: &[bool] = &tree.flags;
    let index_len = tree.index_len(block_nodes);
    let block_count = (index_len - TREE_HEADER_LEN - levels * LEVEL_ENTRY_LEN) / BLOCK_ENTRY_LEN;
    let batch = rayon::current_num_threads().max(1) * BLOCKS_IN_FLIGHT_PER_THREAD;
    // Block offsets are relative to the section start, which the index occupies.
    let mut at = index_len as u64;
    let mut blocks_crc = crc32fast::Hasher::new();
    let mut blocks: Vec<BlockEntry> = Vec::with_capacity(block_count);
    let mut attribute_bytes = [0u64; 7];
    // Decoded internal nodes of the previous level: the parents of the current one.
    let mut parents = ParentQueue::default();
    // The nodes of one batch when they are owned (see [`NodeSource::batch`]).
    let mut batch_nodes: Vec<Node> = Vec::new();
    // Stored blocks of the last batch encoded, not yet handed to the sink.
    let mut pending: Vec<Vec<u8>> = Vec::new();
    if let (true, Some(root)) = (levels > 0, tree.root) {
        level_table[0] = LevelEntry { node_count: 1, first_block: 0, block_count: 0 };
        if flags[0] {
            parents.segments.push_back(vec![root]);
        }
        stats.blocks_per_level.push(0);
    }
    for (d, entry) in level_table.iter_mut().enumerate().skip(1) {
        let range = tree.levels[d].clone();
        let level_len = range.len();
        let level_flags = &flags[range.clone()];
        let chunks: Vec<(usize, usize)> =
            (0..level_len).step_by(block_nodes).map(|s| (s, (s + block_nodes).min(level_len))).collect();
        let internal: Vec<usize> =
            chunks.par_iter().map(|&(s, e)| level_flags[s..e].iter().filter(|&&f| f).count()).collect();
        entry.node_count = level_len as u64;
        entry.first_block = blocks.len() as u32;
        entry.block_count = chunks.len() as u32;
        stats.blocks_per_level.push(chunks.len() as u32);
        let mut internal_before = 0u64;
        let mut next_parents = ParentQueue::default();
        for (batch_chunks, batch_internal) in chunks.chunks(batch).zip(internal.chunks(batch)) {
            let (Some(&(first, _)), Some(&(_, last))) = (batch_chunks.first(), batch_chunks.last()) else { continue };
            let level_nodes = tree.nodes.batch(range.start + first..range.start + last, &mut batch_nodes)?;
            // The previous batch goes to the sink while this one is encoded.
            let (written, encoded) = rayon::join(
                || pending.drain(..).try_for_each(|b| sink(&b)),
                || {
                    batch_chunks
                        .par_iter()
                        .zip(batch_internal)
                        .map(|(&(s, e), &k)| {
                            // The block's parents, contiguous as the codec wants them (copied
                            // here, on its worker, when they span segments).
                            let p = parents.range(s / 2, e / 2)?;
                            let nodes = &level_nodes[s - first..e - first];
                            encode_block(opts, params, &p, nodes, &level_flags[s..e], k)
                        })
                        .collect::<Vec<Result<EncodedBlock>>>()
                },
            );
            written?;
            parents.release(last / 2);
            for ((&(s, e), r), &k) in batch_chunks.iter().zip(encoded).zip(batch_internal) {
                let mut b = r?;
                // Each block's parents are a segment of their own (no copy into a batch's).
                next_parents.segments.push_back(std::mem::take(&mut b.parents));
                stats.flag_bytes += b.mask_len;
                stats.payload_bytes += b.payload_len;
                for (t, v) in attribute_bytes.iter_mut().zip(b.attribute_bytes) {
                    *t += v;
                }
                let len = b.stored.len() as u64;
                blocks.push(BlockEntry {
                    level: d as u32,
                    node_count: (e - s) as u32,
                    first_node: s as u64,
                    internal_before,
                    offset: at,
                    stored_len: len as u32,
                    raw_len: (b.mask_len + b.payload_len) as u32,
                    crc: b.crc,
                    flags: b.flags,
                });
                blocks_crc.combine(&crc32fast::Hasher::new_with_initial_len(b.crc, len));
                pending.push(b.stored);
                at += len;
                internal_before += k as u64;
            }
        }
        if !parents.segments.is_empty() {
            return Err(Error::Misuse(format!("level {d} left parents unused (bug)")));
        }
        parents = next_parents;
    }
    pending.drain(..).try_for_each(|b| sink(&b))?;
    drop(parents);
    let mut index = Vec::with_capacity(index_len);
    TreeHeader {
        profile: profile.id(),
        flags: params.alpha as u8 | (tree.two_sided as u8) << 1
            | (params.centre_offsets as u8) << 2
            | (params.leaf_refinement as u8) << 3,
        root_internal: flags.first().copied().unwrap_or(false) as u8,
        level_count: levels as u32,
        node_count: node_count as u64,
        leaf_count: tree.leaves as u64,
        block_count: blocks.len() as u32,
        root: tree.root.unwrap_or_default(),
    }
    .write(&mut index);
    level_table.iter().for_each(|l| l.write(&mut index));
    blocks.iter().for_each(|b| b.write(&mut index));
    if index.len() != index_len {
        return Err(Error::Misuse(format!("tree index is {} bytes, {index_len} were reserved (bug)", index.len())));
    }
    stats.blocks = blocks.len() as u32;
    stats.index_bytes = index_len as u64;
    stats.attribute_bytes = std::iter::once("topology")
        .chain(crate::codec::ATTRIBUTES)
        .zip(attribute_bytes)
        .filter(|&(name, b)| name != "other" || b > 0)
        .map(|(name, b)| (name.to_string(), b))
        .collect();
    stats.section_bytes = at;
    Ok(StreamedTree { index, blocks_crc, stats })
}

/// Encodes one tree as a `TREE` section body, in memory (see [`stream_tree`] for the order
/// of work; [`write_scene_file`] streams the same bytes to the file instead). The tree is
/// encoded as a scene's first tree (for [`WriteOptions::leaf_refinement`]).
pub fn encode_tree(tree: &SceneTree, opts: &WriteOptions) -> Result<(Vec<u8>, TreeStats)> {
    encode_tree_at(0, tree, opts)
}

/// [`encode_tree`] for tree `i` of a scene.
fn encode_tree_at(i: usize, tree: &SceneTree, opts: &WriteOptions) -> Result<(Vec<u8>, TreeStats)> {
    let tree = TreeInput::borrowed(tree);
    let index_len = tree.index_len(block_nodes(opts));
    let mut out = vec![0u8; index_len];
    let params = opts.codec_params(i, tree.alpha);
    let st = stream_tree(tree, params, opts, &mut |b| {
        out.extend_from_slice(b);
        Ok(())
    })?;
    out[..index_len].copy_from_slice(&st.index);
    Ok((out, st.stats))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::parent_of;

    /// A perfect tree over `2^levels` leaves on a helix, breadth first.
    fn perfect_tree(levels: u32) -> SceneTree {
        let n = 1usize << levels;
        let leaves: Vec<Node> = (0..n)
            .map(|i| {
                let t = i as f32 * 0.1;
                Node {
                    center: [t.cos(), t.sin(), 0.05 * t],
                    radius: 0.02,
                    normal: [t.cos(), t.sin(), 0.3],
                    cone: 0.0,
                    area: 1e-3 * (1.0 + (i % 7) as f32),
                    color: [(i * 37 % 256) as u8, (i * 11 % 256) as u8, 90, 255],
                }
            })
            .collect();
        let mut rows = vec![leaves];
        while rows.last().map_or(0, Vec::len) > 1 {
            let below = rows.last().map(|r| r.chunks(2).map(|p| parent_of(&p[0], &p[1])).collect()).unwrap_or_default();
            rows.push(below);
        }
        let nodes: Vec<Node> = rows.iter().rev().flatten().copied().collect();
        let internal = (0..nodes.len()).map(|i| i < n - 1).collect();
        SceneTree::from_bfs(nodes, internal).expect("tree")
    }

    #[test]
    fn stats_account_for_every_byte() {
        let tree = perfect_tree(10);
        for profile in [Profile::Raw, Profile::Canopy, Profile::Default] {
            for level in [None, Some(0), Some(3)] {
                let opts = WriteOptions { profile, compression_level: level, block_nodes: 64, ..Default::default() };
                let (bytes, st) = encode_tree(&tree, &opts).expect("encode");
                let attrs: u64 = st.attribute_bytes.iter().map(|a| a.1).sum();
                assert_eq!(attrs + st.index_bytes, st.section_bytes, "{profile:?} {level:?}: {:?}", st.attribute_bytes);
                assert_eq!(st.section_bytes as usize, bytes.len());
                assert_eq!(st.blocks_per_level.len(), 11);
                // Level d holds 2^d nodes: ⌈2^d / 64⌉ blocks.
                for (d, &b) in st.blocks_per_level.iter().enumerate().skip(1) {
                    assert_eq!(b as usize, (1usize << d).div_ceil(64), "level {d}");
                }
                assert!(st.attribute_bytes.iter().all(|a| a.1 > 0), "{:?}", st.attribute_bytes);
            }
        }
    }

    /// The streaming file writer (seek-back patching, batched blocks, several trees) must
    /// produce exactly the bytes of the in-memory writer.
    #[test]
    fn file_writer_streams_the_same_bytes() {
        let scene = Scene {
            generator: Generator::default(),
            graph: SceneGraph {
                nodes: vec![GraphNode::Tree { tree: 0 }, GraphNode::Tree { tree: 1 }, GraphNode::Tree { tree: 2 }],
                root: 1,
            },
            // A single-node tree too: no blocks at all.
            trees: vec![perfect_tree(11), perfect_tree(7), perfect_tree(0)],
        };
        let path = std::env::temp_dir().join(format!("sct-write-stream-{}.sct", std::process::id()));
        for profile in [Profile::Raw, Profile::Canopy, Profile::Default] {
            // Small blocks: many batches per level, segments of parents that straddle blocks.
            let opts = WriteOptions { profile, block_nodes: 6, ..Default::default() };
            let mut mem = Vec::new();
            let st_mem = write_scene(&scene, &opts, &mut mem).expect("write");
            let st_file = write_scene_file(&path, &scene, &opts).expect("write file");
            let file = std::fs::read(&path).expect("read back");
            assert!(file == mem, "{profile:?}: streamed file differs");
            assert_eq!(st_file, st_mem, "{profile:?}");
            // The consuming writer (nodes split into per-block vectors, freed as written).
            let st_owned = write_scene_file_owned(&path, scene.clone(), &opts).expect("write owned");
            let owned = std::fs::read(&path).expect("read back");
            assert!(owned == mem, "{profile:?}: consuming writer's file differs");
            assert_eq!(st_owned, st_mem, "{profile:?}");
        }
        let _ = std::fs::remove_file(&path);
    }

    /// Parents are borrowed from a segment that holds the whole range, copied across
    /// segments (empty ones too), and released segment by segment.
    #[test]
    fn parent_ranges_borrow_or_copy() {
        let node = |i: usize| Node { area: i as f32, ..Node::default() };
        let lens = [3usize, 0, 5, 1, 0, 4];
        let all: Vec<Node> = (0..lens.iter().sum()).map(node).collect();
        let mut q = ParentQueue { first: 0, segments: Default::default() };
        let mut at = 0;
        for &l in &lens {
            q.segments.push_back(all[at..at + l].to_vec());
            at += l;
        }
        let bounds = [0, 3, 3, 8, 9, 9, 13];
        for from in 0..all.len() {
            for to in from + 1..=all.len() {
                let got = q.range(from, to).expect("range");
                assert!(got[..] == all[from..to], "{from}..{to}");
                let inside = bounds.windows(2).any(|w| w[0] <= from && to <= w[1]);
                assert_eq!(matches!(got, std::borrow::Cow::Borrowed(_)), inside, "{from}..{to}");
            }
        }
        q.release(8);
        assert_eq!((q.first, q.segments.len()), (8, 3));
        assert!(q.range(9, 13).expect("range")[..] == all[9..13]);
        assert!(q.range(2, 9).is_err(), "released parents are gone");
    }

    /// Blocks that go around the buffer land in order with the buffered ones.
    #[test]
    fn long_blocks_bypass_the_buffer_in_order() {
        let blocks: Vec<Vec<u8>> = [10, UNBUFFERED_BLOCK, 3, UNBUFFERED_BLOCK - 1, 3 * UNBUFFERED_BLOCK, 0, 7]
            .iter()
            .enumerate()
            .map(|(k, &len)| (0..len).map(|i| (i * 31 + k * 7) as u8).collect())
            .collect();
        let mut w = BufWriter::with_capacity(2 * UNBUFFERED_BLOCK, Vec::new());
        for (k, b) in blocks.iter().enumerate() {
            write_block(&mut w, b).expect("write");
            if k == 1 {
                assert_eq!(w.get_ref().len(), 10 + UNBUFFERED_BLOCK, "went around the buffer, after what was in it");
            }
        }
        let out = w.into_inner().expect("flush");
        assert!(out == blocks.concat());
    }

    #[test]
    fn stream_split_compression_round_trips() {
        let tree = perfect_tree(12);
        let scene = Scene::single_tree(Generator::default(), tree.clone());
        let mut buf = Vec::new();
        write_scene(&scene, &WriteOptions { block_nodes: 512, compression_level: Some(5), ..Default::default() }, &mut buf).expect("write");
        let r = crate::SctReader::from_bytes(buf, &crate::Limits::default()).expect("read");
        let back = r.read_tree(0).expect("decode");
        assert_eq!(back.internal_flags(), tree.internal_flags());
        // Same nodes as encoding without compression: zstd is lossless whatever its blocks.
        let mut plain = Vec::new();
        write_scene(&scene, &WriteOptions { block_nodes: 512, compression_level: Some(0), ..Default::default() }, &mut plain).expect("write");
        let r0 = crate::SctReader::from_bytes(plain, &crate::Limits::default()).expect("read");
        assert_eq!(r0.read_tree(0).expect("decode").nodes(), back.nodes());
    }
}
