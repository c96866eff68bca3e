//! The deep check's wavefront: every block decoded once, a few blocks' nodes per level in
//! memory at a time, batches decoded in parallel and their issues kept in a fixed order.

use super::*;

/// Blocks decoded per batch of the deep check. Fixed, not derived from the thread count:
/// the batch size decides the order levels are interleaved in, hence the order issues are
/// found in, which of them survive [`MAX_ISSUES`], and how far a tree with a failing block
/// got, and the report must be the same on 1 and N threads. 32 keeps 16 threads busy with
/// two blocks each while holding only a couple of batches of nodes per level.
const WAVEFRONT_BATCH: usize = 32;

/// The decoded internal nodes of one level that the next level has not consumed yet.
#[derive(Default)]
pub(super) struct Front {
    pub(super) queue: std::collections::VecDeque<Node>,
    /// Rank among the level's internal nodes of `queue[0]`.
    pub(super) first_rank: u64,
    /// Next block of the level to decode, and the end of its blocks.
    pub(super) next_block: usize,
    pub(super) end_block: usize,
}

impl Front {
    fn produced(&self) -> u64 {
        self.first_rank + self.queue.len() as u64
    }
}

/// Streaming deep check of one tree. Level `d`'s blocks are decoded in order, a batch at a
/// time (in parallel), when level `d + 1` needs their internal nodes as parents; parents are
/// dropped once consumed. Each level then holds at most about two batches of internal
/// nodes, instead of whole levels (the old level-by-level pass held ~18 bytes per node of a
/// 10 M-node tree).
pub(super) struct Wavefront<'a> {
    pub(super) idx: &'a TreeIndex,
    pub(super) limits: &'a Limits,
    pub(super) batch: usize,
    pub(super) fronts: Vec<Front>,
    pub(super) bits: Vec<LevelBits>,
    pub(super) pending: Vec<(usize, u64, CheckId, String)>,
    /// Issues that may still be kept ([`MAX_ISSUES`] less those already reported).
    pub(super) room: usize,
    pub(super) omitted: u64,
    pub(super) nodes: u64,
    pub(super) blocks: u64,
}

impl<'a> Wavefront<'a> {
    pub(super) fn new(idx: &'a TreeIndex, limits: &'a Limits, room: usize) -> Self {
        let fronts = (0..idx.levels.len())
            .map(|d| {
                let r = idx.level_blocks(d);
                Front { next_block: r.start, end_block: r.end, ..Default::default() }
            })
            .collect();
        let bits = (0..idx.levels.len()).map(|_| LevelBits::default()).collect();
        Wavefront { idx, limits, batch: WAVEFRONT_BATCH, fronts, bits, pending: Vec::new(), room, omitted: 0, nodes: 0, blocks: 0 }
    }

    /// Keeps level `d`'s issues while there is room, counts the rest.
    pub(super) fn keep(&mut self, d: usize, issues: Vec<(u64, CheckId, String)>) {
        for (i, k, m) in issues {
            if self.pending.len() < self.room {
                self.pending.push((d, i, k, m));
            } else {
                self.omitted += 1;
            }
        }
    }

    /// Decodes and checks the next batch of level `d`'s blocks, first pulling the parents
    /// they need from level `d - 1`.
    pub(super) fn advance(&mut self, src: &Source<'_>, d: usize) -> Result<(), (usize, Problem)> {
        let idx = self.idx;
        let (b0, b1) = (self.fronts[d].next_block, (self.fronts[d].next_block + self.batch).min(self.fronts[d].end_block));
        let Some(last) = idx.blocks[b0..b1].last() else {
            return Err((d, (CheckId::BlockDecode, "the next level needs more parents than this level has".into())));
        };
        let need = (last.first_node + last.node_count as u64) / 2;
        while self.fronts[d - 1].produced() < need {
            if self.fronts[d - 1].next_block >= self.fronts[d - 1].end_block {
                return Err((d, (CheckId::BlockDecode, format!("block {} refers to parents that do not exist", b1 - 1))));
            }
            self.advance(src, d - 1)?;
        }
        let parents = &mut self.fronts[d - 1];
        let base = parents.first_rank;
        let ps = parents.queue.make_contiguous();
        let limits = self.limits;
        let results: Vec<Result<BlockOut, Problem>> = (b0..b1)
            .into_par_iter()
            .map(|b| {
                let e = &idx.blocks[b];
                let lo = (e.first_node / 2).checked_sub(base).map(|x| x as usize);
                let ps = lo
                    .and_then(|lo| ps.get(lo..lo + e.node_count as usize / 2))
                    .ok_or((CheckId::BlockDecode, format!("block {b} refers to parents that do not exist")))?;
                check_block(src, idx, b, ps, limits)
            })
            .collect();
        // Parents below `need` have been consumed by this level's blocks so far.
        let consumed = need.saturating_sub(base).min(parents.queue.len() as u64) as usize;
        parents.queue.drain(..consumed);
        parents.first_rank += consumed as u64;
        for r in results {
            let out = r.map_err(|p| (d, p))?;
            self.blocks += 1;
            self.nodes += out.flags.len() as u64;
            out.flags.iter().for_each(|&f| self.bits[d].push(f));
            self.fronts[d].queue.extend(out.internal_nodes);
            self.keep(d, out.issues);
        }
        self.fronts[d].next_block = b1;
        Ok(())
    }
}
