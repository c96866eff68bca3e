//! Writing SCT files (spec §2–§7).
//!
//! To a plain writer ([`write_scene`]) the scene is encoded in memory section by section
//! (trees in parallel blocks), so every offset is known before the first byte is written.
//! To a path ([`write_scene_file`]) it streams: blocks go to the temporary file as they are
//! encoded and the header, section table and tree indexes are patched in by seeking back,
//! then the file is renamed into place (atomic either way).
//!
//! The scene-graph section is encoded in `graph.rs`, trees block by block in `tree.rs`;
//! this file holds the options, statistics and the file layout.

mod graph;
mod tree;

use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::Path;

use crate::codec::{CodecParams, Profile};
use crate::container::{header_and_table, write_container_minor, SectionOut};
use crate::error::{Error, Result};
use crate::graph::{Generator, GraphNode, SceneGraph};
use crate::raw::{tags, SectionEntry, FILE_HEADER_LEN, SCT_MAGIC, SECTION_ENTRY_LEN};
use crate::tree::SceneTree;

use graph::{check_graph, encode_graph};
pub(crate) use graph::kind;
pub use tree::encode_tree;
use tree::{encode_tree_at, stream_tree, TreeInput};

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
/// the voxelized bunny (412,889 leaves, `scripts/peers.sh` samples), one zstd block per stream
/// and no match shorter than 7 bytes: level 1 gives 7.04 B/leaf with the whole build in
/// 0.36 s, 3 gives 7.03, 9 gives 6.91, 19 gives 6.81 in 0.95 s. Level 1 keeps compression
/// off the critical path; `--compression-level 19` buys ~3 %.
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::parent_of;
    use crate::node::Node;

    /// A perfect tree over `2^levels` leaves on a helix, breadth first.
    pub(super) fn perfect_tree(levels: u32) -> SceneTree {
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

}
