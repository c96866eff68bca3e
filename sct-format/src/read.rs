//! Reading SCT files lazily (spec §2–§7).
//!
//! [`SctReader::open`] memory-maps the file and parses only the header, section table,
//! generator, scene graph and each tree's index; node data is decoded block by block on
//! request. [`SctReader::read_tree_levels`] reads the first `L` levels of a tree without
//! touching deeper blocks (progressive loading); [`SctReader::decode_block`] gives random
//! access at block granularity. [`SctReader::bytes_read`] counts the bytes actually used.

use std::ops::Deref;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::codec::{decode_children, CodecParams, Profile};
use crate::container::{decompress, slice, Container};
use crate::error::{Error, Result};
use crate::graph::{Generator, GraphNode, InstanceAttrs, Propagation, SceneGraph};
use crate::limits::Limits;
use crate::node::Node;
use crate::raw::{
    tags, BlockEntry, Cursor, FileHeader, LevelEntry, SectionEntry, TreeHeader, BLOCK_ENTRY_LEN, LEVEL_ENTRY_LEN, SCT_MAGIC,
    TREE_HEADER_LEN,
};
use crate::samples::{parse_generator, read_similarity};
use crate::tree::SceneTree;
use crate::write::kind;

/// The bytes of an open file.
enum Data {
    Mapped(memmap2::Mmap),
    Owned(Vec<u8>),
}

impl Deref for Data {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            Data::Mapped(m) => m,
            Data::Owned(v) => v,
        }
    }
}

/// The index of one tree: enough to locate and decode any block.
#[derive(Clone, Debug, PartialEq)]
pub struct TreeIndex {
    /// The `TREE` section entry.
    pub section: SectionEntry,
    /// Tree header (root node included).
    pub header: TreeHeader,
    /// Node profile.
    pub profile: Profile,
    /// Codec parameters.
    pub params: CodecParams,
    /// Level table.
    pub levels: Vec<LevelEntry>,
    /// Block table.
    pub blocks: Vec<BlockEntry>,
}

impl TreeIndex {
    /// Blocks of level `d`.
    pub fn level_blocks(&self, d: usize) -> std::ops::Range<usize> {
        match self.levels.get(d) {
            Some(l) => l.first_block as usize..(l.first_block as usize + l.block_count as usize),
            None => 0..0,
        }
    }

    /// Whether the tree's surfaces are seen from both sides (spec §6.2, flag bit 1, 1.1).
    pub fn two_sided(&self) -> bool {
        self.header.flags & 2 != 0
    }

    /// The block of level `d` holding node `i` of that level.
    pub fn block_of(&self, d: usize, i: u64) -> Option<usize> {
        let r = self.level_blocks(d);
        let blocks = &self.blocks[r.clone()];
        let k = blocks.partition_point(|b| b.first_node <= i).checked_sub(1)?;
        (i < blocks[k].first_node + blocks[k].node_count as u64).then_some(r.start + k)
    }

    /// Internal nodes of block `b`, from the index alone (the next block's `internal_before`,
    /// or the next level's parent count after a level's last block).
    pub fn internal_in_block(&self, b: usize) -> u64 {
        let Some(e) = self.blocks.get(b) else { return 0 };
        let end = self.level_blocks(e.level as usize).end;
        let next = if b + 1 < end {
            self.blocks[b + 1].internal_before
        } else {
            self.levels.get(e.level as usize + 1).map_or(0, |l| l.node_count / 2)
        };
        next.saturating_sub(e.internal_before)
    }

    /// The block of level `d` holding the `rank`-th internal node of that level.
    pub fn block_of_internal(&self, d: usize, rank: u64) -> Option<usize> {
        let r = self.level_blocks(d);
        let blocks = &self.blocks[r.clone()];
        let k = blocks.partition_point(|b| b.internal_before <= rank).checked_sub(1)?;
        Some(r.start + k)
    }
}

/// A decoded block.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DecodedBlock {
    /// Nodes, in level order.
    pub nodes: Vec<Node>,
    /// "Has children" flag per node.
    pub internal: Vec<bool>,
}

/// An open SCT file.
pub struct SctReader {
    data: Data,
    path: Option<PathBuf>,
    limits: Limits,
    header: FileHeader,
    sections: Vec<SectionEntry>,
    skipped: Vec<String>,
    generator: Generator,
    graph: SceneGraph,
    trees: Vec<TreeIndex>,
    bytes_read: AtomicU64,
}

impl std::fmt::Debug for SctReader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SctReader").field("path", &self.path).field("bytes", &self.data.len()).finish_non_exhaustive()
    }
}

impl SctReader {
    /// Opens and memory-maps `path`.
    pub fn open(path: &Path, limits: &Limits) -> Result<Self> {
        let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
        let data = if len == 0 {
            Data::Owned(Vec::new())
        } else {
            // SAFETY: the map is read-only; the SCT tools never modify a file in place
            // (outputs are replaced by rename), so the bytes cannot change under us.
            #[allow(unsafe_code)]
            let map = unsafe { memmap2::Mmap::map(&file) }.map_err(|e| Error::io(path, e))?;
            Data::Mapped(map)
        };
        Self::parse(data, Some(path.to_path_buf()), limits)
    }

    /// Parses a file held in memory.
    pub fn from_bytes(bytes: Vec<u8>, limits: &Limits) -> Result<Self> {
        Self::parse(Data::Owned(bytes), None, limits)
    }

    fn parse(data: Data, path: Option<PathBuf>, limits: &Limits) -> Result<Self> {
        let known = [tags::GENR, tags::GRPH, tags::TREE];
        let c = Container::parse(&data, SCT_MAGIC, "SCT scene", &known, limits)?;
        let mut read = (crate::raw::FILE_HEADER_LEN + c.sections.len() * crate::raw::SECTION_ENTRY_LEN) as u64;
        if c.sections.first().map(|e| e.tag) != Some(tags::GENR) {
            return Err(Error::malformed(c.header.section_table_offset, "the first section must be the generator (GENR)"));
        }
        let genr = c.single(tags::GENR)?;
        let generator = parse_generator(&c.section_bytes(genr, limits)?, genr.offset, limits)?;
        read += genr.stored_len;
        let grph = c.single(tags::GRPH)?;
        let mut trees = Vec::new();
        for e in c.sections_with(tags::TREE) {
            let t = parse_tree_index(c.stored(e)?, e, limits)?;
            if !t.header.root.is_finite() && t.header.node_count > 0 {
                return Err(Error::malformed(e.offset + 32, "root node has non-finite or out-of-range attributes"));
            }
            read += (TREE_HEADER_LEN + t.levels.len() * LEVEL_ENTRY_LEN + t.blocks.len() * BLOCK_ENTRY_LEN) as u64;
            trees.push(t);
        }
        // After the tree indices, so that a bad tree reference is reported at its node.
        let leaves: Vec<u64> = trees.iter().map(|t| t.header.leaf_count).collect();
        let graph = parse_graph(&c.section_bytes(grph, limits)?, grph.offset, limits, OnProblem::Fail, Some(&leaves))?.0;
        read += grph.stored_len;
        let (header, sections, skipped) = (c.header.clone(), c.sections.clone(), c.skipped.clone());
        Ok(SctReader { data, path, limits: limits.clone(), header, sections, skipped, generator, graph, trees, bytes_read: AtomicU64::new(read) })
    }

    /// The path the file was opened from.
    pub fn path(&self) -> Option<&Path> {
        self.path.as_deref()
    }
    /// File size in bytes.
    pub fn file_len(&self) -> u64 {
        self.data.len() as u64
    }
    /// The whole file's bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.data
    }
    /// The limits in force.
    pub fn limits(&self) -> &Limits {
        &self.limits
    }
    /// File header.
    pub fn header(&self) -> &FileHeader {
        &self.header
    }
    /// Known sections in table order.
    pub fn sections(&self) -> &[SectionEntry] {
        &self.sections
    }
    /// Tags of unknown optional sections that were skipped.
    pub fn skipped_sections(&self) -> &[String] {
        &self.skipped
    }
    /// Provenance.
    pub fn generator(&self) -> &Generator {
        &self.generator
    }
    /// Scene graph.
    pub fn graph(&self) -> &SceneGraph {
        &self.graph
    }
    /// Tree indices.
    pub fn trees(&self) -> &[TreeIndex] {
        &self.trees
    }
    /// Bytes read so far: headers, tables, graph and every block decoded (a block decoded
    /// twice counts twice).
    pub fn bytes_read(&self) -> u64 {
        self.bytes_read.load(Ordering::Relaxed)
    }

    /// Verifies the CRC of every section (reads the whole file).
    pub fn verify_checksums(&self) -> Result<()> {
        let c = self.container();
        self.sections.iter().try_for_each(|e| c.verify(e))
    }

    fn container(&self) -> Container<'_> {
        Container { data: &self.data, header: self.header.clone(), sections: self.sections.clone(), skipped: Vec::new() }
    }

    /// Decodes block `b` of tree `t`; `parents` are the decoded parents of its sibling
    /// pairs (the internal nodes of the previous level with ranks
    /// `first_node / 2 .. (first_node + node_count) / 2`).
    pub fn decode_block(&self, t: usize, b: usize, parents: &[Node]) -> Result<DecodedBlock> {
        let tree = self.trees.get(t).ok_or_else(|| Error::Misuse(format!("no tree {t}")))?;
        let e = tree.blocks.get(b).ok_or_else(|| Error::Misuse(format!("tree {t} has no block {b}")))?;
        self.bytes_read.fetch_add(e.stored_len as u64, Ordering::Relaxed);
        decode_block_in(&self.data, tree, b, parents, &self.limits).map_err(|e| match e {
            Error::Checksum { offset, stored, computed, .. } => Error::Checksum { what: format!("tree {t} block {b}"), offset, stored, computed },
            e => e,
        })
    }

    /// Reads the first `max_levels` levels of tree `t` (all of them with `usize::MAX`),
    /// decoding only the blocks of those levels.
    pub fn read_tree_levels(&self, t: usize, max_levels: usize) -> Result<SceneTree> {
        let tree = self.trees.get(t).ok_or_else(|| Error::Misuse(format!("no tree {t}")))?;
        read_levels(tree, max_levels, |b, ps| self.decode_block(t, b, ps))
    }

    /// Reads all of tree `t`.
    pub fn read_tree(&self, t: usize) -> Result<SceneTree> {
        self.read_tree_levels(t, usize::MAX)
    }

    /// Decodes tree `t` level by level without building a [`SceneTree`]: every block of
    /// levels 1 and deeper goes to `visit(block, decoded)` in breadth-first block order (the
    /// root is [`TreeIndex::header`]`.root`). Only one level of parents is held, so a caller
    /// keeping a part of each block (its leaves, say) needs far less memory than
    /// [`SctReader::read_tree`]. Blocks are decoded in parallel a few at a time.
    pub fn walk_tree(&self, t: usize, visit: impl FnMut(usize, DecodedBlock) -> Result<()>) -> Result<()> {
        let tree = self.trees.get(t).ok_or_else(|| Error::Misuse(format!("no tree {t}")))?;
        walk_levels(tree, usize::MAX, |b, ps| self.decode_block(t, b, ps), visit)
    }
}

/// Decodes block `b` of `tree` from the whole file's bytes `data` (see
/// [`SctReader::decode_block`]); shared with the validator, which has no reader for files
/// the reader rejects.
pub(crate) fn decode_block_in(data: &[u8], tree: &TreeIndex, b: usize, parents: &[Node], limits: &Limits) -> Result<DecodedBlock> {
    let e = tree.blocks.get(b).ok_or_else(|| Error::Misuse(format!("no block {b}")))?;
    if parents.len() * 2 != e.node_count as usize {
        return Err(Error::Misuse(format!("block {b} needs {} parents, {} given", e.node_count / 2, parents.len())));
    }
    let section = slice(data, tree.section.offset, tree.section.stored_len, "tree section")?;
    let abs = tree.section.offset + e.offset;
    let stored = slice(section, e.offset, e.stored_len as u64, "block").map_err(|_| Error::malformed(abs, format!("block {b} lies outside its section")))?;
    let computed = crc32fast::hash(stored);
    if computed != e.crc {
        return Err(Error::Checksum { what: format!("block {b} (level {})", e.level), offset: abs, stored: e.crc, computed });
    }
    let owned;
    let payload: &[u8] = if e.flags & 1 != 0 {
        owned = decompress(stored, e.raw_len as u64, abs, limits)?;
        &owned
    } else {
        if e.raw_len != e.stored_len {
            return Err(Error::malformed(abs, format!("uncompressed block {b} with raw length != stored length")));
        }
        stored
    };
    let n = e.node_count as usize;
    let mask_len = n.div_ceil(8);
    let mask = payload.get(..mask_len).ok_or_else(|| Error::malformed(abs, format!("block {b} is shorter than its child-flag mask")))?;
    let internal: Vec<bool> = (0..n).map(|i| mask[i / 8] >> (i % 8) & 1 == 1).collect();
    if n % 8 != 0 && mask[mask_len - 1] >> (n % 8) != 0 {
        return Err(Error::malformed(abs, format!("block {b}: padding bits of the child-flag mask are not zero")));
    }
    let mut nodes = Vec::with_capacity(n);
    decode_children(tree.profile, tree.params, parents, &payload[mask_len..], abs, &mut nodes)?;
    if nodes.len() != n {
        return Err(Error::malformed(abs, format!("block {b} decoded to {} nodes, expected {n}", nodes.len())));
    }
    // The next block's internal_before must agree with this block's flags.
    let here = internal.iter().filter(|&&f| f).count() as u64;
    if here != tree.internal_in_block(b) {
        return Err(Error::malformed(abs, format!("block {b} has {here} internal nodes, the index implies {}", tree.internal_in_block(b))));
    }
    Ok(DecodedBlock { nodes, internal })
}

/// The first `max_levels` levels of `tree`, each block decoded by `decode(block, parents)`.
pub(crate) fn read_levels(tree: &TreeIndex, max_levels: usize, decode: impl Fn(usize, &[Node]) -> Result<DecodedBlock> + Sync) -> Result<SceneTree> {
    let levels = tree.levels.len().min(max_levels);
    if levels == 0 {
        let mut t = SceneTree::default();
        t.set_two_sided(tree.two_sided());
        return Ok(t);
    }
    let total: u64 = tree.levels[..levels].iter().map(|l| l.node_count).sum();
    let mut nodes = Vec::with_capacity(total as usize);
    let mut internal = Vec::with_capacity(total as usize);
    nodes.push(tree.header.root);
    internal.push(tree.header.root_internal == 1);
    walk_levels(tree, levels, decode, |_, blk| {
        nodes.extend_from_slice(&blk.nodes);
        internal.extend_from_slice(&blk.internal);
        Ok(())
    })?;
    let mut t = SceneTree::from_bfs(nodes, internal).map_err(|e| Error::malformed(tree.section.offset, format!("tree structure: {e}")))?;
    t.set_two_sided(tree.two_sided());
    Ok(t)
}

/// Decodes levels `1..max_levels` of `tree` breadth-first and hands each decoded block to
/// `visit(block, decoded)` in block order (the root, level 0, is in the tree header). Blocks
/// are decoded a few at a time in parallel (`decode(block, parents)`); only the previous
/// level's internal nodes are kept, as the parents of the next level, so a caller that keeps
/// less than every node (the leaves, say) holds less than the whole tree.
pub(crate) fn walk_levels(
    tree: &TreeIndex,
    max_levels: usize,
    decode: impl Fn(usize, &[Node]) -> Result<DecodedBlock> + Sync,
    mut visit: impl FnMut(usize, DecodedBlock) -> Result<()>,
) -> Result<()> {
    use rayon::prelude::*;
    let levels = tree.levels.len().min(max_levels);
    let mut parents: Vec<Node> = if tree.header.root_internal == 1 { vec![tree.header.root] } else { Vec::new() };
    let batch = 2 * rayon::current_num_threads().max(1);
    for d in 1..levels {
        let mut next = Vec::new();
        let blocks: Vec<usize> = tree.level_blocks(d).collect();
        for chunk in blocks.chunks(batch) {
            let decoded: Vec<Result<DecodedBlock>> = chunk
                .par_iter()
                .map(|&b| {
                    let e = &tree.blocks[b];
                    let lo = (e.first_node / 2) as usize;
                    let ps = parents
                        .get(lo..lo + e.node_count as usize / 2)
                        .ok_or_else(|| Error::malformed(tree.section.offset + e.offset, "block refers to parents that do not exist"))?;
                    decode(b, ps)
                })
                .collect();
            for (&b, blk) in chunk.iter().zip(decoded) {
                let blk = blk?;
                next.extend(blk.nodes.iter().zip(&blk.internal).filter(|(_, &f)| f).map(|(n, _)| *n));
                visit(b, blk)?;
            }
        }
        parents = next;
    }
    Ok(())
}

/// Parses and checks a tree's index (header, level table, block table), so decoding can
/// trust it. Shared by the reader and the validator: a block past its section is reported
/// as lying "past the end", an oversized block through [`Limits::check`], so the validator
/// can tell truncation and limits from other inconsistencies.
pub(crate) fn parse_tree_index(section: &[u8], e: &SectionEntry, limits: &Limits) -> Result<TreeIndex> {
    let mut c = Cursor::new(section, e.offset);
    let header = TreeHeader::parse(&mut c)?;
    let at = e.offset;
    let profile = Profile::from_id(header.profile).ok_or_else(|| Error::malformed(at, format!("unknown profile id {}", header.profile)))?;
    if header.flags & !3 != 0 || header.root_internal > 1 {
        return Err(Error::malformed(at + 1, "reserved tree flag bits set"));
    }
    Limits::check("tree levels", header.level_count as u64, limits.max_tree_levels as u64)?;
    Limits::check("tree nodes", header.node_count, limits.max_tree_nodes)?;
    let levels_bytes = c.take(header.level_count as usize * LEVEL_ENTRY_LEN, "level table")?;
    let blocks_len = (header.block_count as usize).checked_mul(BLOCK_ENTRY_LEN).ok_or_else(|| Error::malformed(at, "block count overflows"))?;
    let block_bytes = c.take(blocks_len, "block table")?;
    let mut lc = Cursor::new(levels_bytes, at + TREE_HEADER_LEN as u64);
    let levels: Vec<LevelEntry> = (0..header.level_count).map(|_| LevelEntry::parse(&mut lc)).collect::<Result<_>>()?;
    let mut bc = Cursor::new(block_bytes, lc.offset());
    let blocks: Vec<BlockEntry> = (0..header.block_count).map(|_| BlockEntry::parse(&mut bc)).collect::<Result<_>>()?;

    // Structural consistency of the index, so decoding can trust it.
    let node_sum = levels.iter().try_fold(0u64, |s, l| s.checked_add(l.node_count)).ok_or_else(|| Error::malformed(at, "level counts overflow"))?;
    if node_sum != header.node_count {
        return Err(Error::malformed(at, format!("levels hold {node_sum} nodes, header says {}", header.node_count)));
    }
    if header.node_count > 0 && header.node_count != header.leaf_count.saturating_mul(2).saturating_sub(1) {
        return Err(Error::malformed(at, format!("{} nodes cannot form a full binary tree of {} leaves", header.node_count, header.leaf_count)));
    }
    if header.node_count == 0 && (header.level_count != 0 || header.block_count != 0) {
        return Err(Error::malformed(at, "empty tree with levels or blocks"));
    }
    let mut next_block = 0u32;
    for (d, l) in levels.iter().enumerate() {
        let where_ = at + (TREE_HEADER_LEN + d * LEVEL_ENTRY_LEN) as u64;
        if d == 0 {
            if l.node_count != 1 || l.block_count != 0 {
                return Err(Error::malformed(where_, "level 0 must hold exactly the root and no blocks"));
            }
            if (header.root_internal == 1) != (levels.len() > 1) {
                return Err(Error::malformed(at + 2, "root internal flag disagrees with the level count"));
            }
            continue;
        }
        if l.node_count == 0 || l.node_count % 2 != 0 || l.first_block != next_block || l.block_count == 0 {
            return Err(Error::malformed(where_, format!("level {d} entry is inconsistent")));
        }
        next_block = next_block.checked_add(l.block_count).ok_or_else(|| Error::malformed(where_, "block counts overflow"))?;
        if next_block > header.block_count {
            return Err(Error::malformed(where_, format!("level {d} refers to blocks past the block table")));
        }
        let mut first = 0u64;
        let mut internal_before = 0u64;
        for (k, b) in blocks[l.first_block as usize..next_block as usize].iter().enumerate() {
            let bw = lc.offset() + ((l.first_block as usize + k) * BLOCK_ENTRY_LEN) as u64;
            let bi = l.first_block as usize + k;
            if b.offset.checked_add(b.stored_len as u64).is_none_or(|end| end > e.stored_len) {
                return Err(Error::malformed(bw, format!("block {bi} (level {d}) extends past the end of its tree section")));
            }
            let ok = b.level == d as u32
                && b.first_node == first
                && b.node_count > 0
                && b.node_count % 2 == 0
                && b.internal_before >= internal_before
                && b.internal_before <= b.first_node
                && b.flags & !1 == 0;
            if !ok {
                return Err(Error::malformed(bw, format!("block entry {bi} of level {d} is inconsistent ({b:?})")));
            }
            Limits::check("block decompressed bytes", b.raw_len as u64, limits.max_decompressed_bytes)?;
            first += b.node_count as u64;
            internal_before = b.internal_before;
        }
        if first != l.node_count {
            return Err(Error::malformed(where_, format!("blocks of level {d} hold {first} nodes, the level {}", l.node_count)));
        }
        let prev = &levels[d - 1];
        if l.node_count > prev.node_count.saturating_mul(2) {
            return Err(Error::malformed(where_, format!("level {d} has more nodes than its parents can have")));
        }
    }
    if next_block != header.block_count {
        return Err(Error::malformed(at, "block table has blocks no level uses"));
    }
    Ok(TreeIndex {
        section: e.clone(),
        params: CodecParams { alpha: header.flags & 1 == 1 },
        header,
        profile,
        levels,
        blocks,
    })
}

/// A problem of one graph node that does not stop [`parse_graph`] in [`OnProblem::Keep`]
/// mode: the validator reports it (at the node's path when reachable) and goes on; the
/// reader rejects the file at the first one.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct GraphProblem {
    /// The graph node, `None` for the section as a whole.
    pub node: Option<u32>,
    /// Byte offset of the node.
    pub offset: u64,
    /// What is wrong.
    pub message: String,
}

impl GraphProblem {
    fn into_error(self) -> Error {
        let what = match self.node {
            Some(i) => format!("graph node {i}: {}", self.message),
            None => self.message,
        };
        Error::malformed(self.offset, what)
    }
}

/// What [`parse_graph`] does with a [`GraphProblem`].
#[derive(Clone, Copy, Debug)]
pub(crate) enum OnProblem {
    /// Fail at the first one (the reader), also on an invalid instance transform. Failing
    /// fast matters: a 4 GiB GRPH of bad group children would otherwise build one message
    /// per child, ~25 times the input, only to report the first.
    Fail,
    /// Keep at most this many and count the rest (the validator, which keeps at most
    /// [`crate::validate::MAX_ISSUES`] issues anyway).
    Keep(usize),
}

/// The problems [`parse_graph`] kept, and how many more it found.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct GraphProblems {
    pub list: Vec<GraphProblem>,
    pub omitted: u64,
}

/// Parses the scene graph. Structural failures (truncation, unknown node kind, counts, root
/// out of range) are errors; a bad reference (kept as `u32::MAX` so a group's leaf `j` still
/// maps to child `j`), reserved flag bits, a malformed inline path or trailing bytes are
/// [`GraphProblem`]s, handled as `on_problem` says. In [`OnProblem::Keep`] mode transforms
/// and inline bounds are returned as stored for the caller to check (the validator names
/// each failing check); in [`OnProblem::Fail`] mode an invalid instance transform is an
/// error at the instance's offset.
///
/// With `tree_leaves` (the leaf count of each tree in the file), tree references are checked
/// too: they must name an existing tree, and a group's tree must have one leaf per child.
pub(crate) fn parse_graph(
    bytes: &[u8],
    offset: u64,
    limits: &Limits,
    on_problem: OnProblem,
    tree_leaves: Option<&[u64]>,
) -> Result<(SceneGraph, GraphProblems)> {
    let mut c = Cursor::new(bytes, offset);
    let n = c.count(5, "graph node count")?;
    Limits::check("graph nodes", n as u64, limits.max_graph_nodes)?;
    let root = c.u32("graph root")?;
    let mut nodes = Vec::with_capacity(n);
    let mut problems = GraphProblems::default();
    let mut report = |p: GraphProblem| -> Result<()> {
        match on_problem {
            OnProblem::Fail => return Err(p.into_error()),
            OnProblem::Keep(cap) if problems.list.len() < cap => problems.list.push(p),
            OnProblem::Keep(_) => problems.omitted = problems.omitted.saturating_add(1),
        }
        Ok(())
    };
    for i in 0..n {
        let at = c.offset();
        let node = Some(i as u32);
        let mut problem = |message: String| report(GraphProblem { node, offset: at, message });
        let mut earlier = |r: u32, what: &str| -> Result<u32> {
            if r as usize >= i {
                problem(format!("{what} {r} is not an earlier node (references must point backwards)"))?;
                Ok(u32::MAX)
            } else {
                Ok(r)
            }
        };
        let node = match c.u8("graph node kind")? {
            kind::TREE => GraphNode::Tree { tree: c.u32("tree index")? },
            kind::GROUP => {
                let tree = c.u32("group tree")?;
                let k = c.count(4, "group child count")?;
                let mut children = Vec::with_capacity(k);
                for _ in 0..k {
                    let r = c.u32("group child")?;
                    children.push(earlier(r, "group child")?);
                }
                GraphNode::Group { children, tree }
            }
            kind::INSTANCE => {
                let r = c.u32("instance child")?;
                let child = earlier(r, "instance child")?;
                let transform = read_similarity(&mut c)?;
                let flags = c.u8("instance flags")?;
                let tint = c.array::<4>("tint")?;
                if flags & !7 != 0 {
                    problem(format!("reserved instance flag bits set ({flags:#04x})"))?;
                }
                if matches!(on_problem, OnProblem::Fail) && !transform.is_valid(1e-6) {
                    // At the instance's own offset, not the section's, so the bad bytes
                    // can be found.
                    return Err(Error::malformed(at, format!("instance {i} transform is not finite, not unit or not positive: {transform:?}")));
                }
                let prop = |bit: u8| if flags & bit != 0 { Propagation::PushDown } else { Propagation::PullUp };
                let attrs = InstanceAttrs { size: prop(1), color: prop(2), tint: (flags & 4 != 0).then_some(tint) };
                GraphNode::Instance { child, transform, attrs }
            }
            kind::INLINE => {
                let path = c.string(limits.max_string_bytes, "inline path")?;
                let hash = c.array::<32>("inline hash")?;
                let bound = crate::codec::raw::read_node(&c.array("inline bound")?);
                if path.is_empty() || path.starts_with('/') || path.contains('\\') || path.contains('\0') {
                    problem(format!("inline path {path:?} is not a relative '/'-separated path"))?;
                }
                GraphNode::Inline { path, hash, bound }
            }
            k => return Err(Error::malformed(at, format!("graph node {i} has unknown kind {k}"))),
        };
        if let (Some(leaves), GraphNode::Tree { tree } | GraphNode::Group { tree, .. }) = (tree_leaves, &node) {
            match (leaves.get(*tree as usize), &node) {
                (None, _) => problem(format!("graph node {i} refers to tree {tree}, the file has {}", leaves.len()))?,
                (Some(&l), GraphNode::Group { children, .. }) if l != children.len() as u64 => {
                    problem(format!("group {i} has {} children, its tree {tree} has {l} leaves", children.len()))?
                }
                _ => {}
            }
        }
        nodes.push(node);
    }
    if let Err(e) = c.finish("scene graph") {
        report(GraphProblem { node: None, offset: c.offset(), message: e.to_string() })?;
    }
    if n == 0 || root as usize >= n {
        return Err(Error::malformed(offset, format!("graph root {root} out of range ({n} nodes)")));
    }
    Ok((SceneGraph { nodes, root }, problems))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raw::cursor::Put;

    const AT: u64 = 1000;

    /// The head of a two-node graph (root 1) and node 0, a tree node for tree 0; the caller
    /// appends node 1 (12-byte head + 5-byte node: node 1 starts at `AT + 17`).
    fn tree_then_one_node() -> Vec<u8> {
        let mut b = Vec::new();
        b.put_u64(2);
        b.put_u32(1);
        b.put_u8(kind::TREE);
        b.put_u32(0);
        b
    }

    /// A graph of a tree (node 0) and a group (node 1) whose `k` children all point forward.
    fn bad_group(k: u64) -> Vec<u8> {
        let mut b = tree_then_one_node();
        b.put_u8(kind::GROUP);
        b.put_u32(0);
        b.put_u64(k);
        (0..k).for_each(|_| b.put_u32(7));
        b
    }

    /// The reader fails at the first bad child, naming it; it does not collect the others.
    #[test]
    fn strict_graph_fails_at_the_first_problem() {
        let e = parse_graph(&bad_group(5000), AT, &Limits::default(), OnProblem::Fail, None).err();
        match e {
            Some(Error::Malformed { offset, what }) => {
                assert_eq!(offset, AT + 12 + 5, "node 1 follows the 12-byte head and node 0");
                assert!(what.starts_with("graph node 1: group child 7"), "{what}");
            }
            other => panic!("{other:?}"),
        }
    }

    /// The validator's mode keeps at most its cap and counts the rest.
    #[test]
    fn lenient_graph_caps_and_counts_problems() {
        let (g, p) = parse_graph(&bad_group(5000), AT, &Limits::default(), OnProblem::Keep(10), None).unwrap();
        assert_eq!((p.list.len(), p.omitted), (10, 4990));
        assert!(matches!(&g.nodes[1], GraphNode::Group { children, .. } if children.len() == 5000));
    }

    /// A bad instance transform is reported at the instance's offset, not the section's.
    #[test]
    fn bad_transform_is_reported_at_the_instance() {
        let mut b = tree_then_one_node();
        b.put_u8(kind::INSTANCE);
        b.put_u32(0);
        for v in [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, -2.0] {
            b.put_f64(v); // negative scale
        }
        b.put_u8(0);
        b.extend_from_slice(&[255; 4]);
        match parse_graph(&b, AT, &Limits::default(), OnProblem::Fail, None).map(|(g, _)| g) {
            Err(Error::Malformed { offset, what }) => {
                assert_eq!(offset, AT + 12 + 5, "{what}");
                assert!(what.contains("instance 1 transform"), "{what}");
            }
            other => panic!("{other:?}"),
        }
    }

    /// Regression: bad tree references used to be reported at the GRPH section's offset.
    #[test]
    fn bad_tree_references_are_reported_at_their_node() {
        // Tree 0 has 4 leaves, the group (node 1) has 2 children.
        let mut b = tree_then_one_node();
        b.put_u8(kind::GROUP);
        b.put_u32(0);
        b.put_u64(2);
        b.put_u32(0);
        b.put_u32(0);
        match parse_graph(&b, AT, &Limits::default(), OnProblem::Fail, Some(&[4])) {
            Err(Error::Malformed { offset, what }) => {
                assert_eq!(offset, AT + 12 + 5, "{what}");
                assert!(what.contains("group 1 has 2 children, its tree 0 has 4 leaves"), "{what}");
            }
            other => panic!("{other:?}"),
        }
        match parse_graph(&b, AT, &Limits::default(), OnProblem::Fail, Some(&[])) {
            Err(Error::Malformed { offset, what }) => {
                assert_eq!(offset, AT + 12, "node 0 follows the 12-byte head: {what}");
                assert!(what.contains("refers to tree 0, the file has 0"), "{what}");
            }
            other => panic!("{other:?}"),
        }
        assert!(parse_graph(&b, AT, &Limits::default(), OnProblem::Fail, Some(&[2])).is_ok());
    }
}
