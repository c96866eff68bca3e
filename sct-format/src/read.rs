//! Reading SCT files lazily (spec §2–§7).
//!
//! [`SctReader::open`] opens the file (regular files only, [`crate::fsio::open_regular`])
//! and reads only the header, section table, generator, scene graph and each tree's index;
//! node data is read and decoded block by block on request. [`SctReader::read_tree_levels`]
//! reads the first `L` levels of a tree without touching deeper blocks (progressive
//! loading); [`SctReader::decode_block`] gives random access at block granularity.
//! [`SctReader::bytes_read`] counts the bytes actually used.
//!
//! The file is read with positioned reads, not memory-mapped: a mapped file that another
//! process truncates kills the reader with SIGBUS when it touches the lost pages, while a
//! read past the new end is an I/O error. The cost is the copy out of the page cache, about
//! 0.2 s of system time per GB. Measured on the dragon at 12.1 M leaves (raw profile, 973 MB,
//! in the page cache, 2 busy cores, 3 alternating runs each): `sct-inspect --deep` 3.5–3.9 s
//! mapped and 3.7–4.1 s read (CPU 3.4 and 3.6 s; peak RSS 1.2 GB and 0.27 GB, as mapped pages
//! count), `--export-ply` of every leaf 2.2–2.9 s and 2.3–3.1 s; the default profile's 62 MB
//! file validates deep in 5.2–5.5 s and 5.0–5.2 s. Within run-to-run noise, about 5 % at most.

use std::borrow::Cow;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::OnceLock;

use crate::codec::{block_raw_len, decode_children, CodecParams, Profile};
use crate::container::{decompress, parse_header, parse_table, single_in};
use crate::error::{Error, Result};
use crate::fsio::Source;
use crate::graph::{Generator, GraphNode, InstanceAttrs, Propagation, SceneGraph};
use crate::limits::Limits;
use crate::node::Node;
use crate::raw::{
    tags, BlockEntry, Cursor, FileHeader, LevelEntry, SectionEntry, TreeHeader, BLOCK_ENTRY_LEN, FILE_HEADER_LEN, LEVEL_ENTRY_LEN, SCT_MAGIC,
    SECTION_ENTRY_LEN, TREE_HEADER_LEN,
};
use crate::samples::{parse_generator, read_similarity};
use crate::tree::SceneTree;
use crate::write::kind;

/// Bytes one scene-graph node counts against [`Limits::max_graph_bytes`]: its in-memory size,
/// and at least [`AFFINE_RECORD_BYTES`], the largest fixed-size record (an affine
/// instance's), so that no record counts less than its stored bytes and the limit also
/// bounds the decompressed section.
pub const GRAPH_NODE_BYTES: u64 = {
    let m = std::mem::size_of::<GraphNode>() as u64;
    if m > AFFINE_RECORD_BYTES {
        m
    } else {
        AFFINE_RECORD_BYTES
    }
};

/// Stored bytes of an affine instance record (spec §7): kind, child, 12 × f64, flags, tint.
pub const AFFINE_RECORD_BYTES: u64 = 1 + 4 + 96 + 1 + 4;

/// The quantity [`Limits::max_graph_bytes`] caps, as errors name it.
const GRAPH_MEMORY: &str = "scene graph memory (bytes)";

/// Bytes of the `GRPH` section's head (node count u64, root u32).
const GRAPH_HEAD_BYTES: u64 = 12;

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
    src: Source<'static>,
    path: Option<PathBuf>,
    limits: Limits,
    header: FileHeader,
    sections: Vec<SectionEntry>,
    skipped: Vec<String>,
    generator: Generator,
    graph: SceneGraph,
    trees: Vec<TreeIndex>,
    bytes_read: AtomicU64,
    /// BLAKE3 of the file, once computed.
    hash: OnceLock<[u8; 32]>,
}

impl std::fmt::Debug for SctReader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SctReader").field("path", &self.path).field("bytes", &self.src.len()).finish_non_exhaustive()
    }
}

/// The bytes of section `e` after its CRC check and (if flagged) decompression, refusing a
/// raw length over `max_raw` (named `what`) before anything is read or inflated: the caller
/// knows what the section can mean, and a frame inflates only as far as its claim.
pub(crate) fn section_bytes_in<'s>(src: &'s Source<'_>, e: &SectionEntry, max_raw: u64, what: &'static str, limits: &Limits) -> Result<Cow<'s, [u8]>> {
    Limits::check(what, e.raw_len, max_raw)?;
    let stored = src.read(e.offset, e.stored_len, "section data")?;
    let computed = crate::container::crc32(&stored);
    if computed != e.crc {
        return Err(Error::Checksum { what: format!("section {}", e.tag_str()), offset: e.offset, stored: e.crc, computed });
    }
    if !e.compressed() {
        return Ok(stored);
    }
    decompress(&stored, e.raw_len, e.offset, limits).map(Cow::Owned)
}

/// What a scene file stands for once decoded, for [`Limits::check_decoded`]: 40 bytes (a raw
/// node record, about a decoded node's memory) per node of the trees whose counts are
/// `node_counts`, plus the raw lengths of `GENR` and `GRPH` (skipped sections are never
/// inflated). Saturates: a sum past `u64::MAX` is refused like any other too large.
pub(crate) fn scene_decoded_size(sections: &[SectionEntry], node_counts: impl Iterator<Item = u64>) -> u64 {
    let tables = sections.iter().filter(|e| e.tag == tags::GENR || e.tag == tags::GRPH).fold(0u64, |s, e| s.saturating_add(e.raw_len));
    node_counts.fold(tables, |s, n| s.saturating_add(n.saturating_mul(crate::codec::raw::NODE_BYTES as u64)))
}

/// Largest raw length of a `GRPH` section that can parse within `limits` (see
/// [`GRAPH_NODE_BYTES`]).
pub(crate) fn max_graph_section(limits: &Limits) -> u64 {
    limits.max_graph_bytes.saturating_add(GRAPH_HEAD_BYTES)
}

/// The header and section table of an SCT file in `src` (spec §2).
pub(crate) fn parse_container(src: &Source<'_>, limits: &Limits) -> Result<(FileHeader, Vec<SectionEntry>, Vec<String>)> {
    let len = src.len();
    let head = src.read(0, len.min(FILE_HEADER_LEN as u64), "file header")?;
    let header = parse_header(&head, len, SCT_MAGIC, "SCT scene")?;
    Limits::check("section count", header.section_count as u64, limits.max_sections as u64)?;
    let table = src.read(header.section_table_offset, header.section_count as u64 * SECTION_ENTRY_LEN as u64, "section table")?;
    let (sections, skipped) = parse_table(&header, &table, len, &[tags::GENR, tags::GRPH, tags::TREE], limits)?;
    Ok((header, sections, skipped))
}

impl SctReader {
    /// Opens `path` (a regular file; see [`crate::fsio::open_regular`]) and reads its index.
    pub fn open(path: &Path, limits: &Limits) -> Result<Self> {
        Self::parse(Source::open(path)?, Some(path.to_path_buf()), limits)
    }

    /// Parses a file held in memory.
    pub fn from_bytes(bytes: Vec<u8>, limits: &Limits) -> Result<Self> {
        Self::parse(Source::Bytes(Cow::Owned(bytes)), None, limits)
    }

    fn parse(src: Source<'static>, path: Option<PathBuf>, limits: &Limits) -> Result<Self> {
        let (header, sections, skipped) = parse_container(&src, limits)?;
        let mut read = (FILE_HEADER_LEN + sections.len() * SECTION_ENTRY_LEN) as u64;
        if sections.first().map(|e| e.tag) != Some(tags::GENR) {
            return Err(Error::malformed(header.section_table_offset, "the first section must be the generator (GENR)"));
        }
        let genr = single_in(&sections, tags::GENR, header.section_table_offset)?;
        let bytes = section_bytes_in(&src, genr, limits.max_string_bytes as u64, "generator size", limits)?;
        let generator = parse_generator(&bytes, genr.offset, limits)?;
        read += genr.stored_len;
        let grph = single_in(&sections, tags::GRPH, header.section_table_offset)?;
        let mut trees = Vec::new();
        for e in sections.iter().filter(|e| e.tag == tags::TREE) {
            let t = parse_tree_index(&src, e, limits)?;
            if !t.header.root.is_finite() && t.header.node_count > 0 {
                return Err(Error::malformed(e.offset + 32, "root node has non-finite or out-of-range attributes"));
            }
            read += (TREE_HEADER_LEN + t.levels.len() * LEVEL_ENTRY_LEN + t.blocks.len() * BLOCK_ENTRY_LEN) as u64;
            trees.push(t);
        }
        // Before the graph is inflated or any block decoded: what the file stands for must be
        // in proportion to its size (spec §2.4). The graph's own cap first, as its message is
        // the more precise.
        Limits::check("scene graph section bytes", grph.raw_len, max_graph_section(limits))?;
        limits.check_decoded(scene_decoded_size(&sections, trees.iter().map(|t| t.header.node_count)), src.len())?;
        // After the tree indices, so that a bad tree reference is reported at its node.
        let leaves: Vec<u64> = trees.iter().map(|t| t.header.leaf_count).collect();
        let bytes = section_bytes_in(&src, grph, max_graph_section(limits), "scene graph section bytes", limits)?;
        let graph = parse_graph(&bytes, grph.offset, limits, OnProblem::Fail, Some(&leaves))?.0;
        drop(bytes);
        read += grph.stored_len;
        Ok(SctReader {
            src,
            path,
            limits: limits.clone(),
            header,
            sections,
            skipped,
            generator,
            graph,
            trees,
            bytes_read: AtomicU64::new(read),
            hash: OnceLock::new(),
        })
    }

    /// The path the file was opened from.
    pub fn path(&self) -> Option<&Path> {
        self.path.as_deref()
    }
    /// File size in bytes.
    pub fn file_len(&self) -> u64 {
        self.src.len()
    }
    /// BLAKE3 hash of the whole file (what an inline records), read in pieces (memory stays
    /// small) the first time and remembered.
    pub fn content_hash(&self) -> Result<[u8; 32]> {
        if let Some(h) = self.hash.get() {
            return Ok(*h);
        }
        let h = self.src.blake3()?;
        Ok(*self.hash.get_or_init(|| h))
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

    /// Verifies the CRC of every section (reads the whole file, a piece at a time).
    pub fn verify_checksums(&self) -> Result<()> {
        for e in &self.sections {
            let computed = self.src.crc32(e.offset, e.stored_len, "section data")?;
            if computed != e.crc {
                return Err(Error::Checksum { what: format!("section {}", e.tag_str()), offset: e.offset, stored: e.crc, computed });
            }
        }
        Ok(())
    }

    /// Decodes block `b` of tree `t`; `parents` are the decoded parents of its sibling
    /// pairs (the internal nodes of the previous level with ranks
    /// `first_node / 2 .. (first_node + node_count) / 2`).
    pub fn decode_block(&self, t: usize, b: usize, parents: &[Node]) -> Result<DecodedBlock> {
        let tree = self.trees.get(t).ok_or_else(|| Error::Misuse(format!("no tree {t}")))?;
        let e = tree.blocks.get(b).ok_or_else(|| Error::Misuse(format!("tree {t} has no block {b}")))?;
        self.bytes_read.fetch_add(e.stored_len as u64, Ordering::Relaxed);
        decode_block_in(&self.src, tree, b, parents, &self.limits).map_err(|e| match e {
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

/// Decodes block `b` of `tree` from the file `src` (see [`SctReader::decode_block`]); shared
/// with the validator, which has no reader for files the reader rejects. The index was
/// checked by [`parse_tree_index`], so the block lies inside its section and its raw length
/// is what its node count needs: nothing here inflates or allocates past that.
pub(crate) fn decode_block_in(src: &Source<'_>, tree: &TreeIndex, b: usize, parents: &[Node], limits: &Limits) -> Result<DecodedBlock> {
    let e = tree.blocks.get(b).ok_or_else(|| Error::Misuse(format!("no block {b}")))?;
    if parents.len() * 2 != e.node_count as usize {
        return Err(Error::Misuse(format!("block {b} needs {} parents, {} given", e.node_count / 2, parents.len())));
    }
    let abs = tree.section.offset + e.offset;
    if e.offset.checked_add(e.stored_len as u64).is_none_or(|end| end > tree.section.stored_len) {
        return Err(Error::malformed(abs, format!("block {b} lies outside its section")));
    }
    src.read_with(abs, e.stored_len as u64, "block", |stored| decode_stored(stored, tree, b, parents, abs, limits))?
}

/// [`decode_block_in`] once the block's stored bytes are read.
fn decode_stored(stored: &[u8], tree: &TreeIndex, b: usize, parents: &[Node], abs: u64, limits: &Limits) -> Result<DecodedBlock> {
    let e = tree.blocks.get(b).ok_or_else(|| Error::Misuse(format!("no block {b}")))?;
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
    // No reservation from the level table: its counts are claims, and a table claiming 2^32
    // nodes of empty blocks once made this reserve 171 GB before the first block failed.
    // The vectors grow with the nodes actually decoded.
    let mut nodes = Vec::new();
    let mut internal = Vec::new();
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
pub(crate) fn parse_tree_index(src: &Source<'_>, e: &SectionEntry, limits: &Limits) -> Result<TreeIndex> {
    let head = src.read(e.offset, e.stored_len.min(TREE_HEADER_LEN as u64), "tree header")?;
    let mut c = Cursor::new(&head, e.offset);
    let header = TreeHeader::parse(&mut c)?;
    let at = e.offset;
    let profile = Profile::from_id(header.profile).ok_or_else(|| Error::malformed(at, format!("unknown profile id {}", header.profile)))?;
    if header.flags & !15 != 0 || header.root_internal > 1 {
        return Err(Error::malformed(at + 1, "reserved tree flag bits set"));
    }
    if header.flags & 4 != 0 && profile != Profile::Default {
        return Err(Error::malformed(at + 1, format!("centre offsets (tree flag bit 2) need the default profile, not {}", profile.name())));
    }
    if header.flags & 8 != 0 && profile != Profile::Default {
        return Err(Error::malformed(at + 1, format!("leaf refinement (tree flag bit 3) needs the default profile, not {}", profile.name())));
    }
    Limits::check("tree levels", header.level_count as u64, limits.max_tree_levels as u64)?;
    Limits::check("tree nodes", header.node_count, limits.max_tree_nodes)?;
    // The tables must fit in the section before they are read (their counts are claims).
    let mut left = e.stored_len.saturating_sub(TREE_HEADER_LEN as u64);
    let tables_at = at + TREE_HEADER_LEN as u64;
    let mut table_len = 0u64;
    for (what, len) in [("level table", header.level_count as u64 * LEVEL_ENTRY_LEN as u64), ("block table", header.block_count as u64 * BLOCK_ENTRY_LEN as u64)] {
        if len > left {
            return Err(Error::malformed(tables_at + table_len, format!("unexpected end of data reading {what} ({len} bytes needed, {left} left)")));
        }
        left -= len;
        table_len += len;
    }
    let tables = src.read(tables_at, table_len, "tree tables")?;
    let mut lc = Cursor::new(&tables, tables_at);
    let levels: Vec<LevelEntry> = (0..header.level_count).map(|_| LevelEntry::parse(&mut lc)).collect::<Result<_>>()?;
    let blocks_at = lc.offset();
    let blocks: Vec<BlockEntry> = (0..header.block_count).map(|_| BlockEntry::parse(&mut lc)).collect::<Result<_>>()?;
    drop(tables);
    // Offsets are relative to the section; block data starts after the tables.
    let index_len = TREE_HEADER_LEN as u64 + table_len;
    let params = CodecParams::from_tree_flags(header.flags);

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
            let bw = blocks_at + ((l.first_block as usize + k) * BLOCK_ENTRY_LEN) as u64;
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
            // A block's raw length follows from its node count (spec §6.3): checked here, so
            // no block can make a reader inflate (or hold) more than its nodes need, and a
            // table of empty blocks claiming billions of nodes fails before any is decoded.
            let need = block_raw_len(profile, params, b.node_count as u64)
                .ok_or_else(|| Error::malformed(bw, format!("block {bi} node count overflows")))?;
            if b.raw_len as u64 != need {
                return Err(Error::malformed(
                    bw,
                    format!("block {bi} (level {d}) has raw length {}, its {} nodes take {need} bytes in the {} profile", b.raw_len, b.node_count, profile.name()),
                ));
            }
            if b.flags & 1 == 0 && b.stored_len != b.raw_len {
                return Err(Error::malformed(bw, format!("uncompressed block {bi} (level {d}) has stored length {} != raw length {}", b.stored_len, b.raw_len)));
            }
            if b.offset < index_len && b.stored_len > 0 {
                return Err(Error::malformed(bw, format!("block {bi} (level {d}) at {} overlaps the tree's header and tables ({index_len} bytes)", b.offset)));
            }
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
    // Blocks must not overlap (spec §6.2): aliased blocks would be read, inflated and checked
    // once per alias, so a small file could stand for unbounded work.
    let mut ranges: Vec<(u64, u64, usize)> =
        blocks.iter().enumerate().filter(|(_, b)| b.stored_len > 0).map(|(i, b)| (b.offset, b.offset + b.stored_len as u64, i)).collect();
    ranges.sort_unstable();
    for w in ranges.windows(2) {
        let ((s0, e0, i0), (s1, e1, i1)) = (w[0], w[1]);
        if s1 < e0 {
            return Err(Error::malformed(
                blocks_at + (i1 * BLOCK_ENTRY_LEN) as u64,
                format!("block {i1} (bytes {s1}..{e1} of its section) overlaps block {i0} (bytes {s0}..{e0}): blocks must not overlap"),
            ));
        }
    }
    Ok(TreeIndex {
        section: e.clone(),
        params,
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
    // Every node costs at least GRAPH_NODE_BYTES in memory, however few bytes its record
    // takes: checked for all of them before any is parsed, then grown by what the records
    // add (group children, inline paths) before those are allocated.
    let mut memory = (n as u64).saturating_mul(GRAPH_NODE_BYTES);
    Limits::check(GRAPH_MEMORY, memory, limits.max_graph_bytes)?;
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
                memory = memory.saturating_add(4 * k as u64);
                Limits::check(GRAPH_MEMORY, memory, limits.max_graph_bytes)?;
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
                    return Err(Error::malformed(at, format!("instance {i} transform is not finite, not unit or not positive: {transform}")));
                }
                let prop = |bit: u8| if flags & bit != 0 { Propagation::PushDown } else { Propagation::PullUp };
                let attrs = InstanceAttrs { size: prop(1), color: prop(2), tint: (flags & 4 != 0).then_some(tint) };
                GraphNode::Instance { child, transform, attrs }
            }
            kind::AFFINE => {
                let r = c.u32("affine instance child")?;
                let child = earlier(r, "affine instance child")?;
                let mut matrix = [[0f64; 4]; 3];
                for v in matrix.iter_mut().flatten() {
                    *v = c.f64("affine matrix")?;
                }
                let transform = crate::affine::Affine { matrix };
                let flags = c.u8("instance flags")?;
                let tint = c.array::<4>("tint")?;
                if flags & !7 != 0 {
                    problem(format!("reserved instance flag bits set ({flags:#04x})"))?;
                }
                if matches!(on_problem, OnProblem::Fail) {
                    if let Some(why) = transform.problem() {
                        // At the record's own offset, so the bad bytes can be found.
                        return Err(Error::malformed(at, format!("affine instance {i}: {why}")));
                    }
                }
                let prop = |bit: u8| if flags & bit != 0 { Propagation::PushDown } else { Propagation::PullUp };
                let attrs = InstanceAttrs { size: prop(1), color: prop(2), tint: (flags & 4 != 0).then_some(tint) };
                GraphNode::Affine { child, transform, attrs }
            }
            kind::INLINE => {
                let path = c.string(limits.max_string_bytes, "inline path")?;
                memory = memory.saturating_add(path.len() as u64);
                Limits::check(GRAPH_MEMORY, memory, limits.max_graph_bytes)?;
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

    /// Item 2: the level table's counts are claims; reading reserves nothing for them (a
    /// claim of 2^40 nodes used to be reserved before the first block was decoded).
    #[test]
    fn read_levels_reserves_nothing_from_claims() {
        let e = SectionEntry { tag: tags::TREE, flags: 1, offset: 0, stored_len: 0, raw_len: 0, crc: 0 };
        let header = TreeHeader { profile: 0, flags: 0, root_internal: 1, level_count: 2, node_count: (1 << 40) + 1, leaf_count: 1 << 39, block_count: 1, root: Node::default() };
        let levels = vec![LevelEntry { node_count: 1, first_block: 0, block_count: 0 }, LevelEntry { node_count: 1 << 40, first_block: 0, block_count: 1 }];
        let blocks = vec![BlockEntry { level: 1, node_count: 2, ..Default::default() }];
        let tree = TreeIndex { section: e, header, profile: Profile::Raw, params: CodecParams::default(), levels, blocks };
        let r = read_levels(&tree, usize::MAX, |_, _| Err(Error::malformed(7, "no such block")));
        assert!(matches!(r, Err(Error::Malformed { offset: 7, .. })), "{r:?}");
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

    /// A graph of a tree and one affine instance of it with `matrix`; node 1 starts at
    /// `AT + 17`.
    fn affine_graph(matrix: [[f64; 4]; 3]) -> Vec<u8> {
        let mut b = tree_then_one_node();
        b.put_u8(kind::AFFINE);
        b.put_u32(0);
        matrix.iter().flatten().for_each(|v| b.put_f64(*v));
        b.put_u8(2 | 4);
        b.extend_from_slice(&[200, 100, 50, 255]);
        b
    }

    /// Affine instance records parse to their matrix and attributes; hostile matrices (NaN,
    /// singular, huge, ill-conditioned) are refused at the record's offset, and the
    /// validator's mode keeps them for its own checks.
    #[test]
    fn affine_records_and_hostile_matrices() {
        let good = [[2.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.5, 0.0], [0.0, 0.0, -1.0, 3.0]];
        let b = affine_graph(good);
        assert_eq!(b.len() as u64, 17 + AFFINE_RECORD_BYTES);
        let (g, _) = parse_graph(&b, AT, &Limits::default(), OnProblem::Fail, None).expect("valid");
        match &g.nodes[1] {
            GraphNode::Affine { child: 0, transform, attrs } => {
                assert_eq!(transform.matrix, good);
                assert_eq!((attrs.size, attrs.color, attrs.tint), (Propagation::PullUp, Propagation::PushDown, Some([200, 100, 50, 255])));
            }
            other => panic!("{other:?}"),
        }
        let id = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]];
        let mut nan = id;
        nan[2][1] = f64::NAN;
        let mut singular = id;
        singular[2] = [0.0, 0.0, 0.0, 5.0];
        let mut huge = id;
        huge[0][3] = 1e300;
        let mut flat = id;
        flat[1][1] = 1e-9;
        for (m, why) in [(nan, "non-finite"), (singular, "singular"), (huge, "f32 range"), (flat, "condition number")] {
            match parse_graph(&affine_graph(m), AT, &Limits::default(), OnProblem::Fail, None) {
                Err(Error::Malformed { offset, what }) => {
                    assert_eq!(offset, AT + 12 + 5, "{what}");
                    assert!(what.contains("affine instance 1") && what.contains(why), "{what}");
                }
                other => panic!("{why}: {other:?}"),
            }
            assert!(parse_graph(&affine_graph(m), AT, &Limits::default(), OnProblem::Keep(10), None).is_ok());
        }
        // Truncated inside the matrix: malformed, no panic.
        let b = affine_graph(good);
        assert!(matches!(parse_graph(&b[..60], AT, &Limits::default(), OnProblem::Fail, None), Err(Error::Malformed { .. })));
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
