//! A unit's sampling in slabs along x: triangles dealt to slabs, each slab rasterized,
//! sorted and merged by its thread, slab outputs handed on in slab order.

use rayon::prelude::*;
use sct_format::Node;

use crate::mesh::*;

use super::in_order::make_in_order;
use super::keys::{KeyPack, Rec, RecSink};
use super::merge::{merge_sorted, NodeShape};
use super::prepare::Prepared;
use super::sort::sort_order;
use super::voxel::{voxel_triangle, ALL_X};
use super::{scanline, AreaMode, Method, SampleOptions, Sink};

/// Samples a unit's triangles slab by slab and merges same-voxel samples.
///
/// The grid is cut into slabs along x holding about equal numbers of expected samples;
/// each slab voxelizes the triangles overlapping it, keeping only its own voxels, then
/// radix-sorts and merges them in buffers reused by its thread. Voxel keys are x-major, so
/// concatenating slabs in order gives the globally sorted result, and equal voxels (always in
/// one slab) merge in triangle order whatever the thread count: deterministic output, no
/// global sort, and memory for a window of slabs rather than per scene: slab outputs go to
/// `emit` in slab order as soon as each is the next, then their buffers serve later slabs.
/// Returns
/// (samples before merging, alpha-dropped samples), or the first error of `emit`.
pub(super) fn sample_slabs<E: Send>(
    pp: &[Prepared],
    kp: &KeyPack,
    h: f64,
    opts: &SampleOptions,
    progress: &(dyn Fn(u64) + Sync),
    emit: &mut Sink<'_, E>,
) -> Result<(u64, u64), E> {
    // Triangles are numbered over the primitives in order (`gi`); `first[pi]` is primitive
    // `pi`'s first number. Per triangle only its x-cell range is kept (8 bytes: there are at
    // most 2^20 + 1 cells, below), its expected samples go straight into the cells' difference
    // array and the total, added in triangle order (the same bits on any thread count).
    let mut first = Vec::with_capacity(pp.len() + 1);
    let mut ntris = 0usize;
    for p in pp {
        first.push(ntris);
        ntris += p.prim.triangles.len();
    }
    first.push(ntris);
    if ntris == 0 {
        return Ok((0, 0));
    }
    // Expected samples per x cell (difference array), cells of `cell` voxels (coarser only
    // for enormous grids: at most 2^20 + 1 cells), then slab boundaries at equal quantiles.
    let width = (kp.hi[0] - kp.lo[0] + 1) as u64;
    let cell = width.div_ceil(1 << 20).max(1) as i64;
    let ncells = ((kp.hi[0] - kp.lo[0]) / cell + 1) as usize;
    let cell_of = |x: i64| ((x - kp.lo[0]) / cell) as usize;
    let mut diff = vec![0.0f64; ncells + 1];
    let mut total = 0.0f64;
    let mut cells: Vec<(u32, u32)> = Vec::with_capacity(ntris);
    let mut block: Vec<(u32, u32, f64)> = Vec::new();
    for p in pp {
        let n = p.prim.triangles.len();
        for start in (0..n).step_by(PLAN_BLOCK) {
            (start..(start + PLAN_BLOCK).min(n))
                .into_par_iter()
                .map(|ti| {
                    let [a, b, c] = p.prim.triangles[ti].map(|v| p.pos[v as usize]);
                    let lo = (a[0].min(b[0]).min(c[0]).floor() as i64).clamp(kp.lo[0], kp.hi[0]);
                    let hi = (a[0].max(b[0]).max(c[0]).floor() as i64).clamp(kp.lo[0], kp.hi[0]);
                    let est = 0.5 * norm(cross(sub(b, a), sub(c, a))) + 0.5 * (norm(sub(b, a)) + norm(sub(c, b)) + norm(sub(a, c))) + 1.0;
                    (cell_of(lo) as u32, cell_of(hi) as u32, est)
                })
                .collect_into_vec(&mut block);
            for &(c0, c1, e) in &block {
                let per = e / (c1 - c0 + 1) as f64;
                diff[c0 as usize] += per;
                diff[c1 as usize + 1] -= per;
                total += e;
                cells.push((c0, c1));
            }
        }
    }
    drop(block);
    // The slabs must not depend on the thread count: a triangle is cut to its slab's x band
    // before it is swept, which moves the pieces' vertices by rounding.
    let slabs = ((total / slab_target()).ceil() as usize).clamp(MIN_SLABS, 16_384).min(ncells);
    let mut slab_of_cell = vec![0u32; ncells];
    let mut slab_x: Vec<(i64, i64)> = Vec::with_capacity(slabs);
    let (mut acc, mut run, mut start) = (0.0, 0.0, 0usize);
    for c in 0..ncells {
        run += diff[c];
        acc += run;
        slab_of_cell[c] = slab_x.len() as u32;
        let last = c + 1 == ncells;
        if last || acc >= (slab_x.len() + 1) as f64 * total / slabs as f64 {
            let x0 = kp.lo[0] + start as i64 * cell;
            let x1 = if last { kp.hi[0] } else { kp.lo[0] + (c as i64 + 1) * cell - 1 };
            slab_x.push((x0, x1));
            start = c + 1;
        }
    }
    let mut lists: Vec<Vec<u32>> = vec![Vec::new(); slab_x.len()];
    for (gi, r) in cells.iter().enumerate() {
        for l in &mut lists[slab_of_cell[r.0 as usize] as usize..=slab_of_cell[r.1 as usize] as usize] {
            l.push(gi as u32);
        }
    }
    let per_slab = total / slab_x.len() as f64;
    // A voxel-method record's piece lies in its voxel; a scan-line record's column of plane
    // need not.
    let shape = NodeShape::new(kp, h, opts.method == Method::Voxel);
    #[derive(Default)]
    struct Bufs {
        recs: Vec<Rec>,
        parts: SlabParts,
        items: Vec<u64>,
        tmp: Vec<u64>,
    }
    // Output buffers of emitted slabs serve later slabs: no fresh pages are faulted in and
    // zeroed once the first few exist.
    let outs: std::sync::Mutex<Vec<Vec<Node>>> = std::sync::Mutex::new(Vec::new());
    let make = |bufs: &mut Bufs, slab: usize| -> (Vec<Node>, u64, u64) {
        let (list, (x0, x1)) = (&lists[slab], slab_x[slab]);
        bufs.parts.reset(kp, (x0, x1), per_slab);
        let mut dropped = 0u64;
        for &gi in list {
            let gi = gi as usize;
            // The primitive holding triangle `gi`: the last to start at or before it.
            let pi = first.partition_point(|&f| f <= gi) - 1;
            let p = &pp[pi];
            let t = p.tri(gi - first[pi]);
            let mat = p.mat.view();
            if opts.method == Method::Scanline {
                // Per-triangle areas (EQ 17) need the whole triangle's sample count:
                // counted row by row, while only this slab's voxels are shaded and
                // kept (each voxel, hence each alpha drop, belongs to one slab).
                // Straight into the parts: nothing rescales its records afterwards.
                dropped += scanline::scanline_triangle(&t, &mat, kp, (x0, x1), &mut bufs.parts);
                continue;
            }
            // The voxel method rescales a triangle's EQ 17 areas once it has them
            // all, so its records (few, in L1) pass through `recs` to the parts.
            bufs.recs.clear();
            dropped += if (opts.method, opts.area) == (Method::Voxel, AreaMode::Exact) {
                voxel_triangle(&t, &mat, AreaMode::Exact, kp, (x0, x1), ALL_X, &mut bufs.recs)
            } else {
                voxel_triangle(&t, &mat, opts.area, kp, ALL_X, (x0, x1), &mut bufs.recs)
            };
            bufs.parts.extend(&bufs.recs);
        }
        // Progress counts a triangle once, in its first slab.
        let first_cell = cell_of(x0) as u32;
        progress(list.iter().filter(|&&gi| cells[gi as usize].0 >= first_cell).count() as u64);
        let before = bufs.parts.len();
        let mut out = outs.lock().ok().and_then(|mut o| o.pop()).unwrap_or_default();
        out.clear();
        out.reserve(if opts.merge { before * 4 / 5 } else { before });
        for (i, part) in bufs.parts.parts.iter().enumerate() {
            let idx_mask = sort_order(part, bufs.parts.key_range(i), &mut bufs.items, &mut bufs.tmp);
            merge_sorted(&bufs.items, idx_mask, part, &shape, opts.merge, &mut out);
        }
        (out, before as u64, dropped)
    };
    // Slabs are made on every thread and emitted in slab order as soon as each is the next
    // (the sink's work, a file write, overlaps the making of later slabs; see
    // `in_order`). At most 8 slabs per thread are made ahead of the next to emit: enough
    // that one slow slab does not stop the others, few enough to bound the memory held.
    let (mut before, mut dropped) = (0u64, 0u64);
    let mut emit_slab = |(mut out, b, d): (Vec<Node>, u64, u64)| -> Result<(), E> {
        emit(&out)?;
        before += b;
        dropped += d;
        out.clear();
        if let Ok(mut o) = outs.lock() {
            o.push(out);
        }
        Ok(())
    };
    make_in_order(slab_x.len(), 8 * rayon::current_num_threads(), &Bufs::default, &make, &mut emit_slab)?;
    Ok((before, dropped))
}

/// Triangles planned per parallel call (their cells and estimates: 512 KiB).
const PLAN_BLOCK: usize = 1 << 15;

/// Slabs made at least (whatever the thread count), so that the threads share the last
/// ones: at 8, the 100k-triangle dragon made 9 slabs of about 30 ms, and on 2 threads one
/// thread made the 9th alone (the slabs ran 1.83× faster on 2 threads than on 1). Each slab
/// boundary costs the triangles crossing it a cut and a second call, so meshes that make
/// many slabs anyway keep their size: at 32 the dragon's run costs 0.7 % more
/// instructions; at 4 × as many slabs for every mesh (slabs of 32,768 expected samples) the
/// 4.4 M-triangle subdivided bunny cost 4.6 % more.
const MIN_SLABS: usize = 32;

/// Expected samples per slab (unit tests lower it to get many slabs, more than the window of
/// slabs made ahead, from small meshes).
#[cfg(not(test))]
pub(super) fn slab_target() -> f64 {
    131_072.0
}
#[cfg(test)]
pub(super) static SLAB_TARGET: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(131_072);
#[cfg(test)]
pub(super) fn slab_target() -> f64 {
    SLAB_TARGET.load(std::sync::atomic::Ordering::Relaxed) as f64
}

/// Records per part of a slab (about): a part's records (40 B each) and sort items stay in
/// a core's L2 (512 KiB) while they are sorted and merged, so the merge's gathers in key
/// order hit L2 rather than L3, where a whole slab's records (about 5 MB) would lie.
/// (2k and 4k records per part, or 8-bit radix digits, measured slower; 16k the same.)
pub(super) const PART_RECS: f64 = 8192.0;

impl RecSink for SlabParts {
    /// Appends a record to the part of its key.
    #[inline]
    fn push(&mut self, r: Rec) {
        let i = self.part_of(r.key);
        if let Some(p) = self.parts.get_mut(i) {
            p.push(r);
        }
    }
    /// The part of `lo..=hi` when both ends (and so every key between, parts being key
    /// ranges in order) fall in it.
    #[inline]
    fn run(&mut self, lo: u64, hi: u64) -> Option<&mut Vec<Rec>> {
        let i = self.part_of(lo);
        if i == self.part_of(hi) { self.parts.get_mut(i) } else { None }
    }
}

/// A slab's records in parts by key: part `i` holds the keys `base + i·2^shift ..` (clamped
/// to the first and last part), where `base` is the key of the slab's first x with the
/// lowest y and z. The parts are in key order and each key lies in one part, in the order
/// its records came: sorting and merging the parts one by one equals doing it for the whole
/// slab.
#[derive(Default)]
pub(super) struct SlabParts {
    pub(super) parts: Vec<Vec<Rec>>,
    pub(super) base: u64,
    pub(super) shift: u32,
    pub(super) last: u64,
}

impl SlabParts {
    /// Empties the parts and sizes them for a slab of x range `xs` expecting `expected` records
    /// (at most 2^8 parts: their write streams stay in L1).
    pub(super) fn reset(&mut self, kp: &KeyPack, xs: (i64, i64), expected: f64) {
        let base = kp.pack([xs.0, kp.lo[1], kp.lo[2]]);
        let span = kp.pack([xs.1, kp.hi[1], kp.hi[2]]).saturating_sub(base);
        let want = (expected / PART_RECS).clamp(1.0, 256.0) as u64;
        let mut shift = 0;
        while span.checked_shr(shift).unwrap_or(0) >= want {
            shift += 1;
        }
        let count = span.checked_shr(shift).unwrap_or(0) as usize + 1;
        self.parts.truncate(count);
        self.parts.iter_mut().for_each(Vec::clear);
        self.parts.resize_with(count, Vec::new);
        // A shift of 64 (one part) becomes 63: `part_of`'s `min` still gives part 0, and
        // the shift needs no check there.
        (self.base, self.shift, self.last) = (base, shift.min(63), count as u64 - 1);
    }

    /// The part of a voxel key.
    #[inline]
    pub(super) fn part_of(&self, key: u64) -> usize {
        // `shift ≤ 63` (see `reset`).
        (key.saturating_sub(self.base) >> self.shift).min(self.last) as usize
    }

    /// Appends records, each to the part of its key (record by record: copying runs of one
    /// part at once measured slower, most runs being short).
    pub(super) fn extend(&mut self, recs: &[Rec]) {
        for r in recs {
            self.push(*r);
        }
    }

    pub(super) fn len(&self) -> usize {
        self.parts.iter().map(Vec::len).sum()
    }

    /// (lowest key, key bits) of part `i`'s keys when known from its place: the first and
    /// last parts also hold clamped strays, so only the parts between them.
    pub(super) fn key_range(&self, i: usize) -> Option<(u64, u32)> {
        let i = i as u64;
        if i == 0 || i >= self.last {
            return None;
        }
        let lo = (i << self.shift).checked_add(self.base)?;
        Some((lo, self.shift))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Records dealt to a slab's parts (x inside the slab, and strays beyond it on both sides)
    /// and then sorted part by part come out in the order of one stable sort of them all by
    /// key; there are several parts, and their keys ascend from part to part.
    #[test]
    fn slab_parts_sorted_one_by_one_equal_one_stable_sort() {
        let kp = KeyPack::new([0.0; 3], [300.0, 40.0, 40.0]).expect("keys");
        let mut rng = sct_format::rng::SplitMix64(5);
        let mut parts = SlabParts::default();
        for (xs, expected) in [((100, 163), 60_000.0), ((0, 0), 30_000.0), ((5, 300), 1.0e7), ((10, 20), 100.0)] {
            parts.reset(&kp, xs, expected);
            let mut all = Vec::new();
            for _ in 0..50 {
                let tri: Vec<Rec> = (0..rng.next_u64() % 200)
                    .map(|i| {
                        let x = xs.0 - 3 + (rng.next_u64() % (xs.1 - xs.0 + 7) as u64) as i64;
                        let key = kp.pack([x, (rng.next_u64() % 40) as i64, (rng.next_u64() % 40) as i64]);
                        Rec { key, area: 0.5, normal: [(all.len() + i as usize) as f32; 3], color: [0.0; 4], off: [0.0; 3], r: 0.0 }
                    })
                    .collect();
                all.extend_from_slice(&tri);
                parts.extend(&tri);
            }
            assert_eq!(parts.len(), all.len());
            if expected > 50_000.0 {
                assert!(parts.parts.iter().filter(|p| !p.is_empty()).count() > 2, "{xs:?}");
            }
            let mut by_parts = Vec::new();
            let mut last_key = 0;
            for (pi, p) in parts.parts.iter().enumerate() {
                let (mut items, mut tmp) = (Vec::new(), Vec::new());
                // A middle part's place bounds its keys: its sort skips the scan for them.
                if let Some((lo, bits)) = parts.key_range(pi) {
                    assert!(p.iter().all(|r| (r.key - lo) >> bits == 0), "{xs:?}: part {pi}");
                }
                let mask = sort_order(p, parts.key_range(pi), &mut items, &mut tmp);
                assert!(p.iter().all(|r| r.key >= last_key));
                last_key = p.iter().map(|r| r.key).max().unwrap_or(last_key);
                by_parts.extend(items.iter().map(|&it| p[(it & mask) as usize].normal[0]));
            }
            all.sort_by_key(|r| r.key);
            assert_eq!(by_parts, all.iter().map(|r| r.normal[0]).collect::<Vec<_>>(), "{xs:?}");
        }
    }
}
