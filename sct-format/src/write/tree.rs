//! Tree (`TREE`) sections: a tree encoded block by block, a level's blocks in parallel,
//! each block's streams compressed as one zstd frame, handed to a sink in file order.

use rayon::prelude::*;

use crate::codec::{encode_children_with_leaves, CodecParams};
use crate::error::{Error, Result};
use crate::node::Node;
use crate::raw::{BlockEntry, LevelEntry, TreeHeader, BLOCK_ENTRY_LEN, LEVEL_ENTRY_LEN, TREE_HEADER_LEN};
use crate::tree::SceneTree;

use super::{block_nodes, TreeStats, WriteOptions};

/// zstd's shortest match for tree blocks (its largest setting).
const MIN_MATCH: u32 = 7;

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
                let mut enc = Encoder::new(level)?;
                // The streams are one byte per symbol with short repeats: matches of 5 or 6
                // bytes cost more as sequences than as Huffman-coded literals. Any zstd decoder
                // reads the frame as before; files are about 1 % smaller.
                enc.set_parameter(zstd::zstd_safe::CParameter::MinMatch(MIN_MATCH))?;
                let ctx = (level, enc, vec![0u8; zstd::zstd_safe::CCtx::out_size().max(1 << 17)]);
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
/// A batch ends with its slowest block, so the threads wait up to a block's time for the
/// last one every batch: with 2 blocks per thread the 2 threads of an 8.3 M-leaf build sat
/// idle about 7 % of their time, with 8 or 32 about 5.5 % (`/proc/stat`); 8 costs the
/// 458 k-leaf dragon 3 MB more memory.
const BLOCKS_IN_FLIGHT_PER_THREAD: usize = 8;

/// A tree as the streaming writer consumes it: its shape, and its nodes either borrowed or
/// owned, in which case they are released batch by batch as they are encoded.
pub(super) struct TreeInput<'a> {
    flags: std::borrow::Cow<'a, [bool]>,
    /// Node index range of every level.
    levels: Vec<std::ops::Range<usize>>,
    leaves: usize,
    root: Option<Node>,
    pub(super) alpha: bool,
    pub(super) two_sided: bool,
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

    pub(super) fn borrowed(tree: &'a SceneTree) -> Self {
        let (levels, leaves, root, alpha) = Self::shape(tree);
        let two_sided = tree.is_two_sided();
        TreeInput { flags: tree.internal_flags().into(), levels, leaves, root, alpha, two_sided, nodes: NodeSource::Borrowed(tree.nodes()) }
    }

    /// Takes the tree's nodes, reversed in place (no second allocation); the root, which
    /// the tree header holds, is dropped.
    pub(super) fn owned(tree: SceneTree) -> Self {
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
    pub(super) fn index_len(&self, block_nodes: usize) -> usize {
        let block_count: usize = self.levels.iter().skip(1).map(|r| r.len().div_ceil(block_nodes)).sum();
        TREE_HEADER_LEN + self.levels.len() * LEVEL_ENTRY_LEN + block_count * BLOCK_ENTRY_LEN
    }
}

impl<'a> NodeSource<'a> {
    /// Nodes `range` (breadth-first indices) of one batch; batches are asked for in file
    /// order. Owned nodes are moved into `buf` and dropped from the tree (their memory goes
    /// back in [`NodeSource::release`]).
    fn batch<'b>(&mut self, range: std::ops::Range<usize>, buf: &'b mut Vec<Node>) -> Result<&'b [Node]>
    where
        'a: 'b,
    {
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
                Ok(buf)
            }
        }
    }

    /// Gives the memory of the nodes taken so far back to the system, once per
    /// [`SHRINK_BYTES`] of them. Freeing pages takes a while (unmapping them, and flushing
    /// every thread's TLB): the writer does it beside a batch's encoding, not between batches.
    fn release(&mut self) {
        if let NodeSource::Reversed { rest, .. } = self {
            if (rest.capacity() - rest.len()) * std::mem::size_of::<Node>() >= SHRINK_BYTES {
                rest.shrink_to_fit();
            }
        }
    }
}

/// Shrinking costs a realloc (for a large vector an mremap that frees the pages); once per
/// this many bytes of surplus capacity.
const SHRINK_BYTES: usize = 4 << 20;

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
pub(super) struct StreamedTree {
    pub(super) index: Vec<u8>,
    pub(super) blocks_crc: crc32fast::Hasher,
    pub(super) stats: TreeStats,
}

/// Encodes one tree, handing its stored blocks to `sink` in file order as they are encoded
/// (the index, which goes in front of them, comes back at the end).
///
/// Blocks of a level are encoded in parallel (each needs only its decoded parents), a bounded
/// batch at a time and levels in order, so memory holds at most one batch of stored blocks
/// besides the tree, and of decoded nodes with children, the part of one level not yet used
/// as parents and the part of the next already written (see [`ParentQueue`]).
pub(super) fn stream_tree(
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
            // While this batch is encoded, the previous one goes to the sink and the memory of
            // the nodes taken for this one goes back to the system.
            let nodes = &mut tree.nodes;
            let (written, encoded) = rayon::join(
                || {
                    nodes.release();
                    pending.drain(..).try_for_each(|b| sink(&b))
                },
                || {
                    // One block per task: rayon otherwise hands out runs of blocks, and a
                    // batch ended with one thread finishing a run of several alone.
                    batch_chunks
                        .par_iter()
                        .zip(batch_internal)
                        .with_max_len(1)
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
/// of work; [`write_scene_file`](super::write_scene_file) streams the same bytes to the file
/// instead). The tree is encoded as a scene's first tree (for
/// [`WriteOptions::leaf_refinement`]).
pub fn encode_tree(tree: &SceneTree, opts: &WriteOptions) -> Result<(Vec<u8>, TreeStats)> {
    encode_tree_at(0, tree, opts)
}

/// [`encode_tree`] for tree `i` of a scene.
pub(super) fn encode_tree_at(i: usize, tree: &SceneTree, opts: &WriteOptions) -> Result<(Vec<u8>, TreeStats)> {
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
    use crate::codec::Profile;
    use crate::graph::Generator;
    use crate::write::tests::perfect_tree;
    use crate::write::{write_scene, Scene};

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
    /// Tree blocks are compressed with no match shorter than [`MIN_MATCH`] bytes: a payload
    /// whose only repeats are 6-byte words (500 of them, each followed by two random bytes)
    /// stays about its own size, while zstd's level-1 default codes the words as matches.
    #[test]
    fn blocks_use_no_match_shorter_than_min_match() {
        let mut rng = crate::rng::SplitMix64(7);
        let words: Vec<[u8; 6]> = (0..500).map(|_| rng.next_u64().to_le_bytes()[..6].try_into().expect("6 bytes")).collect();
        let mut payload = Vec::new();
        for _ in 0..8000 {
            let r = rng.next_u64();
            payload.extend_from_slice(&words[(r % 500) as usize]);
            payload.extend_from_slice(&(r >> 32).to_le_bytes()[..2]);
        }
        let (stored, _) = compress_streams(&payload, &[payload.len()], 1).expect("compress");
        let default = zstd::bulk::compress(&payload, 1).expect("compress");
        assert!(default.len() * 10 < payload.len() * 7, "the words repeat: level 1 stores {} of {} bytes", default.len(), payload.len());
        assert!(stored.len() * 10 > payload.len() * 9, "stored {} of {} bytes", stored.len(), payload.len());
        assert_eq!(zstd::bulk::decompress(&stored, payload.len()).expect("decompress"), payload);
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
