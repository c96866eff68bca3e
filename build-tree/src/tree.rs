//! Scene tree construction (thesis §5.3.2): top-down BSP partition at the centre of the
//! largest extent, duplicate welding (§5.3.4), breadth-first layout, bottom-up attributes
//! (§5.1 via [`sct_format::geometry`]).
//!
//! Memory layout, chosen to keep the peak near the size of the output tree (issue #4:
//! at most 100 bytes per sample including the writer):
//! - the samples vector is owned and freed before the internal nodes exist: the leaves are
//!   welded straight into their breadth-first places at the front of the output vector,
//!   which grows to the whole tree only afterwards. The peak is therefore about the finished
//!   tree (with `SceneTree`'s own arrays about 82 bytes per leaf), not samples + partition
//!   arrays + tree as before;
//! - `items`: 16 bytes per sample (centre + source index), partitioned in place; only
//!   their source indices (4 bytes) are kept for the layout;
//! - `slots`: one `u32` per tree node in an implicit pre-order layout: a subtree over the
//!   `m` items `[lo, hi)` whose root is slot `s` owns slots `[s, s + 2m - 1)`; its left
//!   child over `[lo, mid)` is slot `s + 1` and its right child slot `s + 2(mid - lo)`. The
//!   root slot stores `mid` for an internal node and `hi` for a leaf (possibly welded), so
//!   disjoint subtrees write disjoint slices and rayon needs no synchronisation;
//! - the layout numbers the nodes breadth first without a breadth-first walk: within a
//!   level, breadth-first order is depth-first order, so chunks of the tree (subtrees, and
//!   single nodes above them) count their nodes per level, the counts give every chunk its
//!   own slices of every level, and the chunks number themselves in parallel. It keeps only
//!   each leaf's source in breadth-first leaf order (4 bytes a leaf; the first item of
//!   every leaf range is marked in the source indices), so the slots are freed before the
//!   leaves exist;
//! - the output nodes in breadth-first order: the leaves welded in parallel at the front,
//!   then spread to their node indices, then the internal nodes filled level by level from
//!   the bottom.
//!
//! Everything is deterministic: the partition of a range depends only on its contents, so
//! the result is identical for any number of threads.

use std::time::Instant;

use rayon::prelude::*;
use sct_format::geometry::parent_of;
use sct_format::{Node, SceneTree};

use crate::error::BuildError;

/// Below this many items a subtree is built on the current thread (rayon overhead).
const PAR_ITEMS: usize = 16 * 1024;
/// Parents computed per rayon task in the bottom-up pass.
const PAR_NODES: usize = 8 * 1024;
/// Subtrees of at most this many items are numbered by one task in the layout.
const CHUNK_ITEMS: usize = 16 * 1024;
/// Nodes per task when the leaves move to their node places.
const SPREAD: usize = 4096;

/// How close samples must be to be welded into one leaf.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Weld {
    /// Never weld; coincident samples are split arbitrarily (but deterministically).
    Off,
    /// Weld a set whose centres' bounding box is at most this wide on every axis
    /// (0 welds exact duplicates only).
    Absolute(f32),
    /// Like `Absolute`, with the tolerance this fraction of the mean leaf radius.
    RelativeToMeanRadius(f32),
}

/// Options of [`build_tree`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BuildOptions {
    /// Duplicate welding.
    pub weld: Weld,
    /// Depth limit above ⌈log2 n⌉: a centre split that would exceed it is moved to the
    /// nearest split that keeps it (a median split in the worst case).
    pub depth_slack: u32,
    /// Most grid cells (instances) over all grids of one `scene.json`
    /// ([`crate::scene::MAX_GRID_CELLS`] by default).
    pub max_grid_cells: u64,
    /// Bake every affine placement of the samples file into its own copy of the samples
    /// (as before format 1.3) instead of keeping it as an affine instance node (spec §7).
    /// Placements an affine instance cannot hold (a condition number above
    /// [`sct_format::affine::MAX_CONDITION`]) are baked either way.
    pub bake_affine: bool,
}

impl Default for BuildOptions {
    fn default() -> Self {
        BuildOptions { weld: Weld::RelativeToMeanRadius(0.01), depth_slack: 4, max_grid_cells: crate::scene::MAX_GRID_CELLS, bake_affine: false }
    }
}

/// Figures about one build.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct BuildStats {
    /// Input samples.
    pub samples: u64,
    /// Leaves after welding.
    pub leaves: u64,
    /// Nodes (2 × leaves − 1).
    pub nodes: u64,
    /// Levels below the root (a single leaf has depth 0).
    pub depth: u32,
    /// Samples removed by welding (`samples - leaves`).
    pub welded: u64,
    /// Welding tolerance actually used (absolute; negative when welding is off).
    pub weld_tolerance: f64,
    /// Splits moved away from the centre to respect the depth limit.
    pub forced_splits: u64,
    /// Seconds spent partitioning.
    pub partition_s: f64,
    /// Seconds spent laying the tree out breadth first.
    pub layout_s: f64,
    /// Seconds spent computing internal attributes.
    pub attributes_s: f64,
}

/// A sample in the partition: its centre in lanes 0–2 and its source index, as raw bits, in
/// lane 3. One 16-byte vector, so the split loop loads, tests, boxes and swaps it whole
/// (as a struct of a centre and a `u32` it was moved as four scalars). Lane 3 is only ever
/// moved, and moves keep bits, so the index comes back exactly.
#[derive(Clone, Copy)]
struct Item([f32; 4]);

impl Item {
    fn new(c: [f32; 3], idx: u32) -> Item {
        Item([c[0], c[1], c[2], f32::from_bits(idx)])
    }

    fn idx(&self) -> u32 {
        self.0[3].to_bits()
    }
}

/// An axis-aligned box in four lanes, so that growing it by an [`Item`] is one packed
/// `minps`/`maxps` pair instead of six scalar compare-and-selects (the partition spends
/// most of its instructions on boxes). Lane 3 (grown by the items' index bits) means
/// nothing and is never read.
#[derive(Clone, Copy)]
struct Aabb {
    min: [f32; 4],
    max: [f32; 4],
}

impl Aabb {
    const EMPTY: Aabb = Aabb { min: [f32::INFINITY; 4], max: [f32::NEG_INFINITY; 4] };

    /// Grows the box to hold `it`'s centre. A compare-and-select is one `minss`/`maxss` where
    /// `f32::min`/`max` add a NaN fix-up; the results are the same here: centres are
    /// finite (checked on input) and the bounds in lanes 0–2 never NaN, so only the sign of a zero tie
    /// could differ, and no split decision sees that (`mid`, `extent` and the comparisons
    /// made with them are the same for ±0). For the same reason the box of a set does not
    /// depend on the order its members are added in. The box is the first operand, as in
    /// `minps box, item`, so the result stays in the box's register (with the item first,
    /// each side of the split loop copied the item and moved both results back: 3
    /// instructions an item).
    #[inline]
    #[allow(clippy::needless_range_loop)] // indexed: the four lanes become one packed op
    fn add(&mut self, it: &Item) {
        let v = it.0;
        for k in 0..4 {
            self.min[k] = if self.min[k] < v[k] { self.min[k] } else { v[k] };
            self.max[k] = if self.max[k] > v[k] { self.max[k] } else { v[k] };
        }
    }

    /// The box holding both (the same compare-and-select as [`Aabb::add`]).
    fn union(mut self, o: Aabb) -> Aabb {
        for k in 0..4 {
            self.min[k] = if self.min[k] < o.min[k] { self.min[k] } else { o.min[k] };
            self.max[k] = if self.max[k] > o.max[k] { self.max[k] } else { o.max[k] };
        }
        self
    }

    fn of(items: &[Item]) -> Aabb {
        let mut b = Aabb::EMPTY;
        for it in items {
            b.add(it);
        }
        b
    }

    fn extent(&self) -> [f32; 3] {
        [self.max[0] - self.min[0], self.max[1] - self.min[1], self.max[2] - self.min[2]]
    }
}

struct Ctx {
    tol: f32,
    weld: bool,
    max_depth: u32,
}

fn ceil_log2(n: usize) -> u32 {
    if n <= 1 {
        0
    } else {
        usize::BITS - (n - 1).leading_zeros()
    }
}

/// Builds the scene tree over `samples` (leaf nodes, cone usually 0).
///
/// Returns the tree in breadth-first order and build figures. Copies the samples first;
/// [`build_tree_owned`] consumes them instead and needs less memory.
pub fn build_tree(samples: &[Node], opts: &BuildOptions) -> Result<(SceneTree, BuildStats), BuildError> {
    build_tree_owned(samples.to_vec(), opts)
}

/// [`build_tree`] over samples it may consume: they are freed as soon as the leaves are
/// welded, before the internal nodes exist, so the peak is about the output tree (the
/// samples and partition arrays never coexist with it).
pub fn build_tree_owned(samples: Vec<Node>, opts: &BuildOptions) -> Result<(SceneTree, BuildStats), BuildError> {
    build_tree_impl(samples, opts, false).map(|(t, s, _)| (t, s))
}

/// [`build_tree`], plus the leaf of every sample (breadth-first node index).
pub fn build_tree_with_map(
    samples: &[Node],
    opts: &BuildOptions,
) -> Result<(SceneTree, BuildStats, Vec<u32>), BuildError> {
    build_tree_impl(samples.to_vec(), opts, true)
}

/// [`build_tree_with_map`] over samples it may consume.
pub(crate) fn build_tree_with_map_owned(
    samples: Vec<Node>,
    opts: &BuildOptions,
) -> Result<(SceneTree, BuildStats, Vec<u32>), BuildError> {
    build_tree_impl(samples, opts, true)
}

/// Marks a leaf's root slot once the layout has replaced its `hi` by the leaf's
/// breadth-first index (both are below 2^31, see the size check).
const LEAF: u32 = 1 << 31;

/// Moves the leaves `leaves[first..]`, in order, to the leaf places of `out` (nodes whose
/// flags start `flags`). Internal places are left as they are: [`compute_attributes`]
/// writes every internal node, so a default written here (40 bytes a node, half the tree)
/// was overwritten anyway.
fn spread(out: &mut [Node], flags: &[bool], leaves: &[Node], first: usize) {
    let mut from = leaves.get(first..).unwrap_or_default().iter();
    for (node, _) in out.iter_mut().zip(flags).filter(|(_, &f)| !f) {
        if let Some(leaf) = from.next() {
            *node = *leaf;
        }
    }
}

/// Every chunk's slices of `all`, an array in breadth-first order over the nodes (`at` 0)
/// or the leaves (`at == levels`): per level, the chunks' shares in chunk order.
fn split_levels<'a, T>(all: &'a mut [T], counts: &[Vec<u32>], at: usize, levels: usize) -> Vec<Vec<&'a mut [T]>> {
    let mut parts: Vec<Vec<&mut [T]>> = counts.iter().map(|_| Vec::with_capacity(levels)).collect();
    let mut rest = all;
    for d in 0..levels {
        for (c, p) in counts.iter().zip(&mut parts) {
            let (a, b) = std::mem::take(&mut rest).split_at_mut(c[at + d] as usize);
            p.push(a);
            rest = b;
        }
    }
    parts
}

/// A piece of the tree numbered by one task: the whole subtree over the items `[lo, hi)`
/// whose root is slot `slot` at `depth`, or (`whole == false`) only that root, an internal
/// node above the chunks.
struct Chunk {
    lo: u32,
    hi: u32,
    slot: u32,
    depth: u32,
    whole: bool,
}

/// The chunks of the subtree at `slot`, depth first.
fn collect_chunks(slots: &[u32], lo: u32, hi: u32, slot: u32, depth: u32, out: &mut Vec<Chunk>) {
    let v = slots[slot as usize];
    let whole = v == hi || (hi - lo) as usize <= CHUNK_ITEMS;
    out.push(Chunk { lo, hi, slot, depth, whole });
    if !whole {
        collect_chunks(slots, lo, v, slot + 1, depth + 1, out);
        collect_chunks(slots, v, hi, slot + 2 * (v - lo), depth + 1, out);
    }
}

/// Visits the nodes of chunk `c` depth first: `visit(depth, lo, hi, internal)`.
fn walk(slots: &[u32], c: &Chunk, stack: &mut Vec<(u32, u32, u32, u32)>, mut visit: impl FnMut(u32, u32, u32, bool)) {
    if !c.whole {
        visit(c.depth, c.lo, c.hi, true);
        return;
    }
    stack.clear();
    stack.push((c.lo, c.hi, c.slot, c.depth));
    while let Some((lo, hi, slot, d)) = stack.pop() {
        let v = slots[slot as usize];
        if v == hi {
            visit(d, lo, hi, false);
        } else {
            visit(d, lo, hi, true);
            stack.push((v, hi, slot + 2 * (v - lo), d + 1));
            stack.push((lo, v, slot + 1, d + 1));
        }
    }
}

fn build_tree_impl(
    samples: Vec<Node>,
    opts: &BuildOptions,
    want_map: bool,
) -> Result<(SceneTree, BuildStats, Vec<u32>), BuildError> {
    let n = samples.len();
    if n == 0 {
        return Err(BuildError::Input("no samples to build a tree from".into()));
    }
    // Slots and item indices are u32 with the top bit free (LEAF); SceneTree allows fewer
    // than 2^32 - 1 nodes.
    if n > (u32::MAX / 2) as usize {
        return Err(BuildError::Input(format!("{n} samples exceed the 2^31 - 1 a tree can hold")));
    }
    let want_sum = matches!(opts.weld, Weld::RelativeToMeanRadius(_));
    let (valid, radius_sum) = check_and_sum_radii(&samples, want_sum);
    if !valid {
        let i = samples.iter().position(|s| !s.is_finite()).unwrap_or_default();
        return Err(BuildError::Input(format!("sample {i} has a non-finite or out-of-range attribute: {:?}", samples[i])));
    }
    let tol = match opts.weld {
        Weld::Off => -1.0,
        Weld::Absolute(t) => t.max(0.0),
        Weld::RelativeToMeanRadius(f) => {
            let mean = radius_sum / n as f64;
            (mean * f.max(0.0) as f64) as f32
        }
    };
    let mut stats = BuildStats { samples: n as u64, weld_tolerance: tol as f64, ..Default::default() };

    // Pass 1: partition.
    let t0 = Instant::now();
    let mut items: Vec<Item> =
        samples.par_iter().enumerate().map(|(i, s)| Item::new(s.center, i as u32)).collect();
    let mut slots = vec![0u32; 2 * n - 1];
    let ctx = Ctx { tol, weld: !matches!(opts.weld, Weld::Off), max_depth: ceil_log2(n) + opts.depth_slack };
    // In parallel: the root's box is the one pass over all items that no split shares.
    let bbox = items
        .par_chunks(PAR_ITEMS)
        .map(Aabb::of)
        .reduce(|| Aabb::EMPTY, Aabb::union);
    let (forced, max_depth) = partition(&ctx, &mut items, &mut slots, 0, bbox, 0);
    stats.forced_splits = forced;
    stats.partition_s = t0.elapsed().as_secs_f64();

    // Pass 2: layout. Only the source indices of the partition are needed from here on (4
    // of the 16 bytes per item).
    let t1 = Instant::now();
    let mut src: Vec<u32> = items.par_iter().map(Item::idx).collect();
    drop(items);

    // 2a: cut the tree into chunks numbered by one task each, and count every chunk's nodes
    // and leaves per level (a level's nodes are in depth-first order within it, so the
    // chunks' counts place every chunk's share of a level).
    let levels = max_depth as usize + 1;
    let mut chunks = Vec::new();
    collect_chunks(&slots, 0, n as u32, 0, 0, &mut chunks);
    let counts: Vec<Vec<u32>> = chunks
        .par_iter()
        .map_init(Vec::new, |stack, c| {
            let mut count = vec![0u32; 2 * levels];
            walk(&slots, c, stack, |d, _, _, internal| {
                count[d as usize] += 1;
                if !internal {
                    count[levels + d as usize] += 1;
                }
            });
            count
        })
        .collect();
    let (mut total, mut leaves) = (0usize, 0usize);
    for c in &counts {
        total += c[..levels].iter().map(|&k| k as usize).sum::<usize>();
        leaves += c[levels..].iter().map(|&k| k as usize).sum::<usize>();
    }
    if total != 2 * leaves - 1 {
        return Err(BuildError::Internal(format!("layout gave {total} nodes for {leaves} leaves")));
    }

    // 2b: every chunk gets, per level, its own slices of the breadth-first flags and of the
    // leaves' sources, and its own items; so the chunks number themselves in parallel. A
    // leaf's source is its sample (one member) or `LEAF | lo`, its first item; the first
    // item of every leaf gets the `LEAF` bit in `src`, which ends the previous range.
    let mut internal = vec![false; total];
    let mut leaf_src = vec![0u32; leaves];
    let flag_parts = split_levels(&mut internal, &counts, 0, levels);
    let leaf_parts = split_levels(&mut leaf_src, &counts, levels, levels);
    let mut src_parts: Vec<&mut [u32]> = Vec::with_capacity(chunks.len());
    let mut src_rest = src.as_mut_slice();
    for c in &chunks {
        let k = if c.whole { (c.hi - c.lo) as usize } else { 0 };
        let (a, b) = std::mem::take(&mut src_rest).split_at_mut(k);
        src_parts.push(a);
        src_rest = b;
    }
    chunks.par_iter().zip(flag_parts).zip(leaf_parts).zip(src_parts).for_each_init(
        Vec::new,
        |stack, (((c, fp), lp), sp)| {
            // Each level's next place is its cursor's next item (one bounds check a node,
            // where indexing by a per-level count took three).
            let mut flags: Vec<_> = fp.into_iter().map(|s| s.iter_mut()).collect();
            let mut leaf_at: Vec<_> = lp.into_iter().map(|s| s.iter_mut()).collect();
            walk(&slots, c, stack, |d, lo, hi, internal| {
                let d = d as usize;
                if let Some(f) = flags[d].next() {
                    *f = internal;
                }
                if !internal {
                    let first = &mut sp[(lo - c.lo) as usize];
                    if let Some(l) = leaf_at[d].next() {
                        *l = if hi - lo == 1 { *first } else { LEAF | lo };
                    }
                    *first |= LEAF;
                }
            });
        },
    );
    drop(slots);

    // 2c: every leaf welded in its breadth-first leaf place (in parallel over the chunks;
    // a welded leaf's members in item order). Only the leaves are made now; the vector's
    // capacity is the whole tree's, so growing it once the samples are freed neither copies
    // nor overlaps them. Peak here: samples 40 + leaves 40 + src 4 + leaf sources 4 + flags
    // 2 bytes per sample.
    let mut nodes: Vec<Node> = Vec::with_capacity(total);
    // Filled on every thread: the first touch of these pages (half the tree's) is a page
    // fault each, which `resize` took on one thread while the other waited.
    nodes.par_extend(rayon::iter::repeat_n(Node::default(), leaves));
    // By chunk (each chunk's leaves level by level): a chunk's samples lie close together
    // in memory far more often than a whole level's.
    chunks
        .par_iter()
        .zip(split_levels(&mut nodes, &counts, levels, levels))
        .zip(split_levels(&mut leaf_src, &counts, levels, levels))
        .for_each_init(Vec::new, |members, ((_, np), lp)| {
            for (out, from) in np.into_iter().zip(lp) {
                for (node, &v) in out.iter_mut().zip(from.iter()) {
                    *node = if v & LEAF == 0 {
                        samples[v as usize]
                    } else {
                        let lo = (v & !LEAF) as usize;
                        members.clear();
                        members.push(samples[(src[lo] & !LEAF) as usize]);
                        members.extend(
                            src[lo + 1..].iter().take_while(|&&i| i & LEAF == 0).map(|&i| samples[i as usize]),
                        );
                        weld(members)
                    };
                }
            }
        });
    let mut map = Vec::new();
    if want_map {
        map = vec![u32::MAX; n];
        let node_of_leaf = internal.iter().enumerate().filter(|(_, &f)| !f).map(|(i, _)| i as u32);
        for (node, &v) in node_of_leaf.zip(&leaf_src) {
            if v & LEAF == 0 {
                map[v as usize] = node;
            } else {
                let lo = (v & !LEAF) as usize;
                map[(src[lo] & !LEAF) as usize] = node;
                for &i in src[lo + 1..].iter().take_while(|&&i| i & LEAF == 0) {
                    map[i as usize] = node;
                }
            }
        }
    }
    drop(leaf_src);
    drop(src);
    drop(samples);

    // 2d: grow to the whole tree and move every leaf to its node index. Leaf `j` lands at
    // index >= j: the leaves bound for `[f(e), e)` (`f(p)`: leaves before index `p`) come
    // from `[f(f(e)), f(e))`, wholly before it, so that span is filled in parallel, then
    // the one before it, about halving each time.
    nodes.par_extend(rayon::iter::repeat_n(Node::default(), total - leaves));
    // Leaves before every SPREAD-th index.
    let mut leaf_before: Vec<usize> = Vec::with_capacity(total / SPREAD + 2);
    leaf_before.push(0);
    for k in internal.par_chunks(SPREAD).map(|b| b.iter().filter(|&&f| !f).count()).collect::<Vec<_>>() {
        leaf_before.push(leaf_before[leaf_before.len() - 1] + k);
    }
    let leaves_before = |p: usize| {
        let b = p / SPREAD;
        leaf_before[b] + internal[b * SPREAD..p].iter().filter(|&&f| !f).count()
    };
    let mut end = total;
    loop {
        let start = leaves_before(end);
        if start >= end {
            break;
        }
        let (head, tail) = nodes.split_at_mut(start);
        // Up to the next multiple of SPREAD here, then whole blocks in parallel.
        let aligned = start.next_multiple_of(SPREAD).min(end);
        let (first, rest) = tail[..end - start].split_at_mut(aligned - start);
        spread(first, &internal[start..], head, leaves_before(start));
        rest.par_chunks_mut(SPREAD).enumerate().for_each(|(k, out)| {
            let p = aligned + k * SPREAD;
            spread(out, &internal[p..], head, leaf_before[p / SPREAD]);
        });
        end = start;
    }
    let depth = max_depth;
    let leaves = leaves as u32;
    stats.layout_s = t1.elapsed().as_secs_f64();

    // Pass 3: parents bottom-up, one level at a time (a level depends only on the next).
    let t2 = Instant::now();
    let level_sizes: Vec<usize> = (0..levels).map(|d| counts.iter().map(|c| c[d] as usize).sum()).collect();
    compute_attributes(&mut nodes, &internal, &level_sizes);
    let tree = SceneTree::from_bfs(nodes, internal).map_err(|e| BuildError::Internal(e.to_string()))?;
    stats.attributes_s = t2.elapsed().as_secs_f64();

    stats.leaves = leaves as u64;
    stats.nodes = tree.len() as u64;
    stats.depth = depth;
    stats.welded = n as u64 - leaves as u64;
    Ok((tree, stats, map))
}

/// Whether every sample passes [`in_range`], and (when `want_sum`) the sum of the radii,
/// in one parallel pass over the samples (it was two). The sum is taken per fixed chunk and
/// the chunks' sums added in order: a float sum's rounding depends on its grouping, and
/// rayon's own `sum` groups by how the work happened to be split, so the mean radius, and
/// with it the weld tolerance, could differ between runs and thread counts.
fn check_and_sum_radii(samples: &[Node], want_sum: bool) -> (bool, f64) {
    let parts: Vec<(bool, f64)> = samples
        .par_chunks(PAR_NODES)
        .map(|c| {
            let ok = c.iter().fold(true, |ok, s| ok & in_range(s));
            let sum = if want_sum { c.iter().map(|s| s.radius as f64).sum() } else { 0.0 };
            (ok, sum)
        })
        .collect();
    parts.iter().fold((true, 0.0), |(ok, sum), &(k, s)| (ok & k, sum + s))
}

/// [`Node::is_finite`] as comparisons without short cuts, which the compiler vectorises
/// (the check is a pass over every sample): `|v| <= MAX` is false exactly for infinities
/// and NaN, and a NaN fails every range test.
#[inline]
fn in_range(s: &Node) -> bool {
    let finite = s.center.iter().chain(&s.normal).fold(true, |ok, v| ok & (v.abs() <= f32::MAX));
    finite
        & (s.radius >= 0.0)
        & (s.radius <= f32::MAX)
        & (s.area >= 0.0)
        & (s.area <= f32::MAX)
        & (s.cone >= 0.0)
        & (s.cone <= std::f32::consts::PI)
}

/// Where each of consecutive runs of `sizes` starts: `0, s₀, s₀ + s₁, …`.
fn exclusive_sums(sizes: impl Iterator<Item = usize>) -> Vec<usize> {
    sizes
        .scan(0usize, |at, k| {
            let start = *at;
            *at += k;
            Some(start)
        })
        .collect()
}

/// Fills every internal node of a breadth-first tree (`level_sizes` nodes per level) from
/// its children, bottom level first. Everything runs on every thread: the chunks' child
/// offsets come from per-chunk counts made in parallel (a serial count over every flag of a
/// level, and a copy of them, left one thread idle before each level).
fn compute_attributes(nodes: &mut [Node], internal: &[bool], level_sizes: &[usize]) {
    let starts = exclusive_sums(level_sizes.iter().copied());
    for d in (0..level_sizes.len().saturating_sub(1)).rev() {
        let range = starts[d]..starts[d] + level_sizes[d];
        let child_start = starts[d + 1];
        let flags = &internal[range.clone()];
        let per_chunk: Vec<usize> = flags.par_chunks(PAR_NODES).map(|ch| ch.iter().filter(|&&b| b).count()).collect();
        // Offset (in the child level) of each chunk's first child, so chunks run independently.
        let chunk_firsts = exclusive_sums(per_chunk.iter().map(|&k| 2 * k));
        let (head, children) = nodes.split_at_mut(child_start);
        let children: &[Node] = children;
        head[range]
            .par_chunks_mut(PAR_NODES)
            .zip(flags.par_chunks(PAR_NODES))
            .zip(chunk_firsts.par_iter())
            .for_each(|((parents, fl), &first)| {
                let mut c = first;
                for (p, &is_int) in parents.iter_mut().zip(fl) {
                    if is_int {
                        *p = parent_of(&children[c], &children[c + 1]);
                        c += 2;
                    }
                }
            });
    }
}

/// One leaf from the samples `members` (Table 2): mean position, a radius that covers
/// every member, the hierarchical merge of cones and colours, and the *sum* of areas (we
/// keep the total surface area invariant, so EQ 13 holds for the whole tree).
fn weld(members: &[Node]) -> Node {
    // The partition never makes an empty leaf; the default only keeps this total.
    let Some(&first) = members.first() else { return Node::default() };
    if members.len() == 1 {
        return first;
    }
    let mut acc = first;
    let mut mean = [0f64; 3];
    for (i, s) in members.iter().enumerate() {
        if i > 0 {
            acc = parent_of(&acc, s);
        }
        for (m, &v) in mean.iter_mut().zip(&s.center) {
            *m += v as f64;
        }
    }
    let inv = 1.0 / members.len() as f64;
    let center = [(mean[0] * inv) as f32, (mean[1] * inv) as f32, (mean[2] * inv) as f32];
    let mut r = 0f64;
    for s in members {
        let d: f64 = (0..3).map(|k| (s.center[k] as f64 - center[k] as f64).powi(2)).sum::<f64>().sqrt();
        r = r.max(d + s.radius as f64);
    }
    let r = r * (1.0 + 1e-15);
    let mut radius = r as f32;
    if (radius as f64) < r {
        radius = radius.next_up();
    }
    Node { center, radius, ..acc }
}

/// Partitions `items` (global offset `lo`) into the subtree whose slots are `slots`
/// (`slots.len() == 2 * items.len() - 1`); returns the number of forced splits and the
/// depth of the deepest leaf.
fn partition(ctx: &Ctx, items: &mut [Item], slots: &mut [u32], lo: usize, bbox: Aabb, depth: u32) -> (u64, u32) {
    let m = items.len();
    let hi = (lo + m) as u32;
    if m == 1 {
        slots[0] = hi;
        return (0, depth);
    }
    let Some(SplitPlane { axis, widest, mid }) = split_plane(ctx, &bbox) else {
        slots[0] = hi;
        return (0, depth);
    };
    // Largest child the depth budget allows: a subtree at depth d + 1 may hold 2^(D - d - 1).
    let cap = 1usize.checked_shl(ctx.max_depth.saturating_sub(depth + 1)).unwrap_or(usize::MAX);
    let (mut l, mut lb, mut rb) = if widest > 0.0 {
        split_at_plane(items, axis, mid)
    } else {
        (0, Aabb::EMPTY, Aabb::EMPTY)
    };
    let mut forced = 0;
    if l == 0 || l == m || l > cap || m - l > cap {
        // Degenerate or too unbalanced: split at the rank closest to the centre split that
        // the depth budget allows (the median when everything coincides).
        let target = if l == 0 || l == m { m / 2 } else { l };
        let lo_ok = m.saturating_sub(cap).max(1);
        let hi_ok = cap.min(m - 1);
        l = target.clamp(lo_ok, hi_ok);
        items.select_nth_unstable_by(l, |a, b| forced_order(axis, a, b));
        lb = Aabb::of(&items[..l]);
        rb = Aabb::of(&items[l..]);
        forced = 1;
    }
    slots[0] = (lo + l) as u32;
    let (li, ri) = items.split_at_mut(l);
    let (ls, rs) = slots[1..].split_at_mut(2 * l - 1);
    let ((fa, da), (fb, db)) = if m >= PAR_ITEMS {
        rayon::join(
            || partition(ctx, li, ls, lo, lb, depth + 1),
            || partition(ctx, ri, rs, lo + l, rb, depth + 1),
        )
    } else {
        (child(ctx, li, ls, lo, lb, depth + 1), child(ctx, ri, rs, lo + l, rb, depth + 1))
    };
    (forced + fa + fb, da.max(db))
}

/// Where a set with box `bbox` splits (§5.3.2): its widest axis (the first of equal
/// extents), that extent and the box's centre on it.
struct SplitPlane {
    axis: usize,
    widest: f32,
    mid: f32,
}

/// The [`SplitPlane`] of `bbox`, or `None` when its members weld into one leaf (shared by
/// [`partition`] and [`pair`], so both decide alike).
#[inline(always)]
fn split_plane(ctx: &Ctx, bbox: &Aabb) -> Option<SplitPlane> {
    let ext = bbox.extent();
    let widest = ext[0].max(ext[1]).max(ext[2]);
    if ctx.weld && widest <= ctx.tol {
        return None;
    }
    let axis = if ext[0] >= ext[1] && ext[0] >= ext[2] {
        0
    } else if ext[1] >= ext[2] {
        1
    } else {
        2
    };
    Some(SplitPlane { axis, widest, mid: 0.5 * (bbox.min[axis] + bbox.max[axis]) })
}

/// The order of a forced split's ranks: position on `axis`, then input index.
#[inline(always)]
fn forced_order(axis: usize, a: &Item, b: &Item) -> std::cmp::Ordering {
    a.0[axis].total_cmp(&b.0[axis]).then(a.idx().cmp(&b.idx()))
}

/// [`partition`] of a child: a single item (half of all calls) becomes its leaf without
/// the call, and two items (41 % of the remaining calls on the bunny) take [`pair`].
#[inline(always)]
fn child(ctx: &Ctx, items: &mut [Item], slots: &mut [u32], lo: usize, bbox: Aabb, depth: u32) -> (u64, u32) {
    match items.len() {
        1 => {
            slots[0] = (lo + 1) as u32;
            (0, depth)
        }
        2 => pair(ctx, items, slots, lo, bbox, depth),
        _ => partition(ctx, items, slots, lo, bbox, depth),
    }
}

/// [`partition`] of two items: the same decisions, leaf or split, and the same order of the
/// two, without the split loop's setup and without the children's boxes, which single items
/// never read. The two-pointer loop puts `b` first exactly when `a` is not left of the
/// plane; a split with both on one side (or no extent) is forced to the median, which for
/// two items sorts them by the forced split's key.
fn pair(ctx: &Ctx, items: &mut [Item], slots: &mut [u32], lo: usize, bbox: Aabb, depth: u32) -> (u64, u32) {
    let ([a, b], [root, left, right]) = (items, slots) else {
        return (0, depth); // never: two items own three slots
    };
    let hi = (lo + 2) as u32;
    let Some(SplitPlane { axis, widest, mid }) = split_plane(ctx, &bbox) else {
        *root = hi;
        return (0, depth);
    };
    let (a_left, b_left) = (widest > 0.0 && a.0[axis] < mid, widest > 0.0 && b.0[axis] < mid);
    let forced = a_left == b_left;
    let b_first = if forced { forced_order(axis, a, b).is_gt() } else { !a_left };
    if b_first {
        std::mem::swap(a, b);
    }
    (*root, *left, *right) = (hi - 1, hi - 1, hi);
    (forced as u64, depth + 1)
}

/// In-place two-pointer partition: centres below `mid` on `axis` first. Returns the left
/// count and both sides' boxes, classifying every item exactly once. (A branch-free form
/// was slower: the samples arrive in spatial order, so the branch is mostly predicted.)
fn split_at_plane(items: &mut [Item], axis: usize, mid: f32) -> (usize, Aabb, Aabb) {
    match axis {
        0 => split_on::<0>(items, mid),
        1 => split_on::<1>(items, mid),
        _ => split_on::<2>(items, mid),
    }
}

/// [`split_at_plane`] on a fixed axis (the key's offset a constant).
///
/// The unclassified items `[i, j)` are the slice `rest`, shrunk from the front or the back,
/// so no access needs a bounds check (indexing `items[i]` and `items[j]` took two per item).
fn split_on<const AXIS: usize>(items: &mut [Item], mid: f32) -> (usize, Aabb, Aabb) {
    let (mut lb, mut rb) = (Aabb::EMPTY, Aabb::EMPTY);
    let mut left = 0usize;
    let mut rest = items;
    // One load of the item serves the test, its box and the swap.
    while let Some(&it) = rest.first() {
        let r = std::mem::take(&mut rest);
        // `r` holds `it`, so both indexings below are in bounds and compile to no check.
        if it.0[AXIS] < mid {
            lb.add(&it);
            left += 1;
            rest = &mut r[1..];
        } else {
            // `items[i] = items[j - 1]; items[j - 1] = it` (one item left: it stays, as
            // both stores write it back).
            let last = r.len() - 1;
            r[0] = r[last];
            r[last] = it;
            rb.add(&it);
            rest = &mut r[..last];
        }
    }
    (left, lb, rb)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The two-pointer partition as it was (scalar boxes, runtime axis), without the boxes:
    /// the reference for [`split_at_plane`]'s permutation.
    fn split_at_plane_reference(items: &mut [Item], axis: usize, mid: f32) -> usize {
        let mut i = 0usize;
        let mut j = items.len();
        while i < j {
            if items[i].0[axis] < mid {
                i += 1;
            } else {
                j -= 1;
                items.swap(i, j);
            }
        }
        i
    }

    /// The radius sum is the chunks' serial sums added in chunk order, whatever the number
    /// of threads, on radii spread over many magnitudes (where the grouping changes the
    /// rounding).
    #[test]
    fn radius_sum_does_not_depend_on_threads() {
        let mut rng = sct_format::rng::SplitMix64(11);
        let samples: Vec<Node> = (0..5 * PAR_NODES + 123)
            .map(|_| {
                let radius = rng.next_f32() * 10f32.powi((rng.next_u64() % 12) as i32 - 6);
                Node { center: [0.0; 3], radius, normal: [0.0, 0.0, 1.0], cone: 0.0, area: 1.0, color: [0; 4] }
            })
            .collect();
        let want: f64 = samples.chunks(PAR_NODES).map(|c| c.iter().map(|s| s.radius as f64).sum::<f64>()).sum();
        for threads in [1, 2, 3, 4] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let (ok, sum) = pool.install(|| check_and_sum_radii(&samples, true));
            assert!(ok);
            assert_eq!(sum.to_bits(), want.to_bits(), "{threads} threads");
        }
        let mut bad = samples.clone();
        bad[3 * PAR_NODES + 7].radius = f32::NAN;
        assert!(!check_and_sum_radii(&bad, false).0);
    }

    /// [`pair`] decides as [`partition`] does on two items: leaf or split, their order, the
    /// slots, the forced count and the depth; over ties, coincident and welded pairs, ±0,
    /// indices whose bits are NaN patterns, and every depth budget.
    #[test]
    fn pair_matches_partition() {
        let mut rng = sct_format::rng::SplitMix64(0x9A12);
        let grid = [0.0f32, -0.0, 0.5, 1.0, 1.0 + f32::EPSILON, 1e-7];
        for case in 0..200_000 {
            let coord = |rng: &mut sct_format::rng::SplitMix64| match case % 3 {
                0 => grid[(rng.next_u64() % grid.len() as u64) as usize],
                _ => rng.next_f32() * 2.0 - 1.0,
            };
            let ca = [coord(&mut rng), coord(&mut rng), coord(&mut rng)];
            let cb = if case % 5 == 0 { ca } else { [coord(&mut rng), coord(&mut rng), coord(&mut rng)] };
            let ia = (rng.next_u64() % (1 << 31)) as u32;
            let ib = if case % 2 == 0 { ia ^ 1 } else { (ia + 1 + (rng.next_u64() % 1000) as u32) % (1 << 31) };
            let items = [Item::new(ca, ia), Item::new(cb, ib)];
            let (tol, weld) = match case % 4 {
                0 => (-1.0, false),
                1 => (0.0, true),
                _ => (rng.next_f32() * 0.5, true),
            };
            let ctx = Ctx { tol, weld, max_depth: (rng.next_u64() % 4) as u32 };
            let depth = (rng.next_u64() % 5) as u32;
            let lo = (rng.next_u64() % 1000) as usize;
            let (mut want, mut got) = (items, items);
            let (mut want_slots, mut got_slots) = ([0u32; 3], [0u32; 3]);
            let w = partition(&ctx, &mut want, &mut want_slots, lo, Aabb::of(&items), depth);
            let g = pair(&ctx, &mut got, &mut got_slots, lo, Aabb::of(&items), depth);
            assert_eq!(g, w, "case {case}");
            assert_eq!(got.map(|it| it.idx()), want.map(|it| it.idx()), "case {case}");
            // A leaf writes only its root slot.
            assert_eq!(got_slots, want_slots, "case {case}");
        }
    }

    /// Every internal node is exactly `parent_of` its children, so none keeps what the
    /// layout left in its place ([`spread`] no longer clears internal places; welded and
    /// forced-split trees included).
    #[test]
    fn every_internal_node_is_its_childrens_parent() {
        let mut rng = sct_format::rng::SplitMix64(3);
        let samples: Vec<Node> = (0..40_000)
            .map(|i| {
                // Every 7th sample repeats its predecessor's grid cell, so some leaves weld.
                let k = if i % 7 == 6 { i - 1 } else { i } as f32;
                let center = [(k * 0.618).fract(), (k * 0.414).fract(), rng.next_f32() * 1e-3];
                let color = [(i % 251) as u8, (i % 13) as u8, 7, 255];
                Node { center, radius: 1e-3, normal: [0.0, 0.6, 0.8], cone: 0.0, area: 1e-6, color }
            })
            .collect();
        for (weld, depth_slack) in [(Weld::Absolute(2e-3), 4), (Weld::Off, 0), (Weld::RelativeToMeanRadius(0.5), 1)] {
            let (tree, stats) = build_tree(&samples, &BuildOptions { weld, depth_slack, ..Default::default() }).unwrap();
            let nodes = tree.nodes();
            for i in 0..nodes.len() {
                if let Some([a, b]) = tree.children(i) {
                    assert_eq!(format!("{:?}", nodes[i]), format!("{:?}", parent_of(&nodes[a], &nodes[b])), "node {i}");
                }
            }
            assert!(stats.leaves > 1);
        }
    }

    /// The vectorisable check accepts exactly what [`Node::is_finite`] accepts.
    #[test]
    fn in_range_is_node_is_finite() {
        let special = [
            0.0, -0.0, 1.0, -1.0, 3.0, std::f32::consts::PI, std::f32::consts::PI.next_up(), f32::MAX, f32::MIN,
            f32::MIN_POSITIVE, -f32::MIN_POSITIVE, 1e-45, -1e-45, f32::INFINITY, f32::NEG_INFINITY, f32::NAN, -f32::NAN,
        ];
        let mut rng = sct_format::rng::SplitMix64(7);
        for _ in 0..200_000 {
            let mut v = [0f32; 9];
            for x in &mut v {
                *x = match rng.next_u64() % 4 {
                    0 => f32::from_bits(rng.next_u64() as u32),
                    1 => rng.next_f32() * 4.0 - 0.5,
                    _ => special[(rng.next_u64() % special.len() as u64) as usize],
                };
            }
            // Mostly valid nodes with one attribute replaced, so every test is reached.
            let mut n = Node { center: [1.0, 2.0, 3.0], radius: 0.5, normal: [0.0, 0.0, 1.0], cone: 0.1, area: 0.2, color: [0; 4] };
            match rng.next_u64() % 7 {
                0 => n.center = [v[0], v[1], v[2]],
                1 => n.normal = [v[3], v[4], v[5]],
                2 => n.radius = v[6],
                3 => n.area = v[7],
                4 => n.cone = v[8],
                5 => {}
                _ => n = Node { center: [v[0], v[1], v[2]], radius: v[6], normal: [v[3], v[4], v[5]], cone: v[8], area: v[7], color: [0; 4] },
            }
            assert_eq!(in_range(&n), n.is_finite(), "{n:?}");
        }
    }

    fn scalar_box(items: &[Item]) -> ([f32; 3], [f32; 3]) {
        let mut b = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for it in items {
            for k in 0..3 {
                b.0[k] = b.0[k].min(it.0[k]);
                b.1[k] = b.1[k].max(it.0[k]);
            }
        }
        b
    }

    /// Same permutation as the old partition, and the boxes of both sides, over random
    /// sets with many ties at the plane.
    #[test]
    fn split_matches_reference() {
        let mut rng = sct_format::rng::SplitMix64(0x5EED);
        for case in 0..3000 {
            let m = 1 + (rng.next_u64() % 200) as usize;
            let coarse = case % 3 == 0;
            let items: Vec<Item> = (0..m as u32)
                .map(|idx| {
                    let mut c = [0f32; 3];
                    for v in &mut c {
                        let f = rng.next_f32();
                        *v = if coarse { (f * 4.0).floor() } else { f * 2.0 - 1.0 };
                    }
                    // Half the cases with the largest indices a tree allows, whose bits
                    // are NaN patterns in the item's fourth lane.
                    Item::new(c, if case % 2 == 1 { u32::MAX / 2 - idx } else { idx })
                })
                .collect();
            let mut want: Vec<u32> = items.iter().map(Item::idx).collect();
            want.sort_unstable();
            let axis = case % 3;
            let mid = if coarse { 2.0 } else { rng.next_f32() * 2.0 - 1.0 };
            let (mut a, mut b) = (items.clone(), items);
            let (l, lb, rb) = split_at_plane(&mut a, axis, mid);
            assert_eq!(l, split_at_plane_reference(&mut b, axis, mid), "case {case}");
            assert!(a.iter().zip(&b).all(|(x, y)| x.idx() == y.idx()), "case {case}: permutation differs");
            let mut got: Vec<u32> = a.iter().map(Item::idx).collect();
            got.sort_unstable();
            assert_eq!(got, want, "case {case}: indices not kept");
            for (bx, part) in [(lb, &a[..l]), (rb, &a[l..])] {
                if part.is_empty() {
                    continue;
                }
                let (lo, hi) = scalar_box(part);
                assert_eq!((&bx.min[..3], &bx.max[..3]), (&lo[..], &hi[..]), "case {case}");
            }
        }
    }
}
