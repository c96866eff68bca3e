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
    // most 2^20 + 1 cells, below); see `plan_cells`.
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
    let xc = XCells::new(kp, width.div_ceil(1 << 20).max(1) as i64);
    let (ncells, cell) = (xc.count, xc.cell);
    let (cells, diff, total) = plan_cells(pp, kp, xc, ntris);
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
    let lists = SlabLists::new(&cells, &slab_of_cell, slab_x.len(), list_chunk(ntris));
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
        let (list, (x0, x1)) = (lists.get(slab), slab_x[slab]);
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
        let first_cell = xc.of(x0) as u32;
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

/// The grid's x cells: `count` cells of `cell` voxels each, from `lo` (`kp.lo[0]`).
#[derive(Clone, Copy)]
struct XCells {
    lo: i64,
    cell: i64,
    count: usize,
}

impl XCells {
    fn new(kp: &KeyPack, cell: i64) -> XCells {
        XCells { lo: kp.lo[0], cell, count: ((kp.hi[0] - kp.lo[0]) / cell + 1) as usize }
    }

    /// The cell of voxel column `x` (in `kp.lo[0]..=kp.hi[0]`).
    fn of(&self, x: i64) -> usize {
        ((x - self.lo) / self.cell) as usize
    }
}

/// Per triangle (numbered over the primitives in order) its x cells `xc`; the cells'
/// expected samples as a difference array (each triangle's spread evenly over its cells);
/// and the expected samples in all. The sums are added in triangle order, the bits of a
/// serial loop on any number of threads.
fn plan_cells(pp: &[Prepared], kp: &KeyPack, xc: XCells, ntris: usize) -> (Vec<(u32, u32)>, Vec<f64>, f64) {
    let mut diff = vec![0.0f64; xc.count + 1];
    let mut total = 0.0f64;
    let mut cells: Vec<(u32, u32)> = Vec::with_capacity(ntris);
    // Planned a block at a time (bounded memory: a block's terms, not the mesh's), and
    // pipelined: while one thread adds block k into `diff` and `total` (in triangle order,
    // the serial part), the others plan block k + 1.
    let blocks: Vec<(usize, std::ops::Range<usize>)> = pp
        .iter()
        .enumerate()
        .flat_map(|(pi, p)| {
            let n = p.prim.triangles.len();
            (0..n).step_by(PLAN_BLOCK).map(move |start| (pi, start..(start + PLAN_BLOCK).min(n)))
        })
        .collect();
    let plan = |(pi, range): &(usize, std::ops::Range<usize>), out: &mut Vec<Planned>| {
        let p = &pp[*pi];
        range
            .clone()
            .into_par_iter()
            .map(|ti| {
                let [a, b, c] = p.prim.triangles[ti].map(|v| p.pos[v as usize]);
                let lo = (a[0].min(b[0]).min(c[0]).floor() as i64).clamp(kp.lo[0], kp.hi[0]);
                let hi = (a[0].max(b[0]).max(c[0]).floor() as i64).clamp(kp.lo[0], kp.hi[0]);
                let est = 0.5 * norm(cross(sub(b, a), sub(c, a))) + 0.5 * (norm(sub(b, a)) + norm(sub(c, b)) + norm(sub(a, c))) + 1.0;
                let (c0, c1) = (xc.of(lo) as u32, xc.of(hi) as u32);
                Planned { c0, c1, per: est / (c1 - c0 + 1) as f64, est }
            })
            .collect_into_vec(out);
    };
    let (mut this, mut next) = (Vec::new(), Vec::new());
    if let Some(b) = blocks.first() {
        plan(b, &mut this);
    }
    for k in 0..blocks.len() {
        rayon::join(
            || {
                for t in &this {
                    diff[t.c0 as usize] += t.per;
                    diff[t.c1 as usize + 1] -= t.per;
                    total += t.est;
                    cells.push((t.c0, t.c1));
                }
            },
            || {
                if let Some(b) = blocks.get(k + 1) {
                    plan(b, &mut next);
                }
            },
        );
        std::mem::swap(&mut this, &mut next);
    }
    (cells, diff, total)
}

/// Triangles planned per parallel call (their cells and estimates: 768 KiB, two blocks held:
/// one being added while the next is planned).
const PLAN_BLOCK: usize = 1 << 15;

/// A triangle's planned x cells `c0..=c1`, its expected samples, and their share per cell.
struct Planned {
    c0: u32,
    c1: u32,
    per: f64,
    est: f64,
}

/// The triangles of every slab, each slab's in triangle order, in one array: slab `s` holds
/// `tris[start[s]..start[s + 1]]`.
#[derive(Debug, PartialEq)]
struct SlabLists {
    start: Vec<usize>,
    tris: Vec<u32>,
}

impl SlabLists {
    /// The lists of triangles whose cells `cells[gi]` (first, last) lie in slabs
    /// `slab_of_cell[first]..=slab_of_cell[last]`, made on every thread: chunks of `chunk`
    /// triangles count their triangles per slab, each chunk's part of each slab starts where
    /// the earlier chunks' parts end (slab by slab), and the chunks fill their parts, each in
    /// triangle order. The lists are the same for any `chunk`.
    fn new(cells: &[(u32, u32)], slab_of_cell: &[u32], slabs: usize, chunk: usize) -> SlabLists {
        let chunk = chunk.max(1);
        let slab_range = |r: &(u32, u32)| slab_of_cell[r.0 as usize] as usize..=slab_of_cell[r.1 as usize] as usize;
        let counts: Vec<Vec<u32>> = cells
            .par_chunks(chunk)
            .map(|c| {
                let mut n = vec![0u32; slabs];
                for r in c {
                    n[slab_range(r)].iter_mut().for_each(|k| *k += 1);
                }
                n
            })
            .collect();
        let mut start = Vec::with_capacity(slabs + 1);
        let mut at = 0usize;
        for s in 0..slabs {
            start.push(at);
            at += counts.iter().map(|n| n[s] as usize).sum::<usize>();
        }
        start.push(at);
        // Zeroed pages come from the kernel untouched: the fill below faults them in on
        // every thread.
        let mut tris = vec![0u32; at];
        // Each chunk's parts, slab by slab.
        let mut parts: Vec<Vec<&mut [u32]>> = counts.iter().map(|_| Vec::with_capacity(slabs)).collect();
        let mut rest: &mut [u32] = &mut tris;
        for s in 0..slabs {
            for (n, part) in counts.iter().zip(&mut parts) {
                let (mine, later) = std::mem::take(&mut rest).split_at_mut(n[s] as usize);
                part.push(mine);
                rest = later;
            }
        }
        parts.into_par_iter().zip(cells.par_chunks(chunk)).enumerate().for_each(|(ci, (mut part, c))| {
            for (i, r) in c.iter().enumerate() {
                let gi = (ci * chunk + i) as u32;
                for s in slab_range(r) {
                    // The counts sized every part for its triangles: there is always a place.
                    if let Some((first, later)) = std::mem::take(&mut part[s]).split_first_mut() {
                        *first = gi;
                        part[s] = later;
                    }
                }
            }
        });
        SlabLists { start, tris }
    }

    /// Slab `s`'s triangles.
    fn get(&self, s: usize) -> &[u32] {
        &self.tris[self.start[s]..self.start[s + 1]]
    }
}

/// Triangles per chunk of [`SlabLists::new`]: 4 chunks per thread (one slow chunk does not
/// hold the others up) but at most 64 (each holds a count and a part per slab), and at least
/// 16,384 triangles each (a chunk's counts cost a pass over the slabs).
fn list_chunk(ntris: usize) -> usize {
    ntris.div_ceil((4 * rayon::current_num_threads()).min(64)).max(1 << 14)
}

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
    use super::super::prepare::MatOwned;
    use super::*;

    /// The planner before its pipeline: the terms of a block in parallel, then added into
    /// the difference array and the total in triangle order.
    fn plan_cells_serial(pp: &[Prepared], kp: &KeyPack, cell: i64) -> (Vec<(u32, u32)>, Vec<f64>, f64) {
        let ncells = ((kp.hi[0] - kp.lo[0]) / cell + 1) as usize;
        let cell_of = |x: i64| ((x - kp.lo[0]) / cell) as usize;
        let (mut diff, mut total, mut cells) = (vec![0.0f64; ncells + 1], 0.0f64, Vec::new());
        for p in pp {
            for t in &p.prim.triangles {
                let [a, b, c] = t.map(|v| p.pos[v as usize]);
                let lo = (a[0].min(b[0]).min(c[0]).floor() as i64).clamp(kp.lo[0], kp.hi[0]);
                let hi = (a[0].max(b[0]).max(c[0]).floor() as i64).clamp(kp.lo[0], kp.hi[0]);
                let e = 0.5 * norm(cross(sub(b, a), sub(c, a))) + 0.5 * (norm(sub(b, a)) + norm(sub(c, b)) + norm(sub(a, c))) + 1.0;
                let (c0, c1) = (cell_of(lo) as u32, cell_of(hi) as u32);
                let per = e / (c1 - c0 + 1) as f64;
                diff[c0 as usize] += per;
                diff[c1 as usize + 1] -= per;
                total += e;
                cells.push((c0, c1));
            }
        }
        (cells, diff, total)
    }

    /// The pipelined planner gives the cells and the bits of the difference array and the
    /// total of the serial one, on 1, 2 and 3 threads: primitives of several blocks, of a
    /// partial block and empty ones, triangles of every size (some spanning most cells, some
    /// beyond the grid on either side), magnitudes far apart (the sums' order shows), cells of
    /// one and of several voxels.
    #[test]
    fn plan_cells_equal_the_serial_planner() {
        let mut rng = sct_format::rng::SplitMix64(9);
        let kp = KeyPack::new([0.0; 3], [4000.0, 60.0, 60.0]).expect("keys");
        let sizes = [2 * PLAN_BLOCK + 123, 0, 7, PLAN_BLOCK, 1000];
        let prims: Vec<Primitive> = sizes
            .iter()
            .map(|&n| Primitive { triangles: (0..n).map(|_| std::array::from_fn(|_| (rng.next_u64() % 3000) as u32)).collect(), ..Default::default() })
            .collect();
        let pos: Vec<Vec<[f64; 3]>> = prims
            .iter()
            .map(|_| {
                (0..3000)
                    .map(|i| {
                        let scale = 10f64.powi((rng.next_u64() % 7) as i32 - 3);
                        let x = if i % 97 == 0 { rng.next_f64() * 4400.0 - 200.0 } else { 2000.0 + (rng.next_f64() - 0.5) * 3000.0 };
                        [x, rng.next_f64() * 60.0 * scale.min(1.0), rng.next_f64() * scale]
                    })
                    .collect()
            })
            .collect();
        let pp: Vec<Prepared> = prims
            .iter()
            .zip(pos)
            .map(|(prim, pos)| Prepared {
                prim,
                mat: MatOwned { base: [1.0; 4], tex: None, alpha_tex: None, alpha: AlphaMode::Opaque },
                pos,
                nrm: None,
                computed: None,
                baked: None,
                flip: false,
            })
            .collect();
        let ntris = sizes.iter().sum();
        let bits = |(cells, diff, total): (Vec<(u32, u32)>, Vec<f64>, f64)| (cells, diff.iter().map(|d| d.to_bits()).collect::<Vec<_>>(), total.to_bits());
        for cell in [1, 3] {
            let want = bits(plan_cells_serial(&pp, &kp, cell));
            assert!(want.0.iter().any(|c| c.1 > c.0 + 100), "wide triangles");
            for threads in [1, 2, 3] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
                let got = bits(pool.install(|| plan_cells(&pp, &kp, XCells::new(&kp, cell), ntris)));
                assert!(got == want, "cell {cell}, {threads} threads");
            }
        }
    }

    /// The lists one vector per slab, pushed triangle by triangle (what the planner did
    /// before `SlabLists`).
    fn lists_per_slab(cells: &[(u32, u32)], slab_of_cell: &[u32], slabs: usize) -> Vec<Vec<u32>> {
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); slabs];
        for (gi, r) in cells.iter().enumerate() {
            for l in &mut lists[slab_of_cell[r.0 as usize] as usize..=slab_of_cell[r.1 as usize] as usize] {
                l.push(gi as u32);
            }
        }
        lists
    }

    /// `SlabLists` holds, slab by slab, the lists pushed triangle by triangle, for chunks of
    /// any size (one triangle, sizes that do not divide the count, one chunk, more than all)
    /// on 1 to 3 threads: slabs of one cell and of many, empty slabs, one slab, triangles
    /// spanning one cell, one slab or all of them, and no triangles.
    #[test]
    fn slab_lists_equal_a_list_per_slab() {
        let mut rng = sct_format::rng::SplitMix64(21);
        for (ntris, ncells, slabs) in [(0usize, 10usize, 3usize), (1, 1, 1), (5000, 300, 1), (20_000, 1000, 37), (70_000, 5000, 400), (3000, 40, 40)] {
            // Slab boundaries at random cells (some slabs empty of triangles when narrow).
            let mut cuts: Vec<usize> = (1..slabs).map(|_| (rng.next_u64() % ncells as u64) as usize).collect();
            cuts.sort_unstable();
            let slab_of_cell: Vec<u32> = (0..ncells).map(|c| cuts.partition_point(|&k| k <= c) as u32).collect();
            let cells: Vec<(u32, u32)> = (0..ntris)
                .map(|i| {
                    let c0 = (rng.next_u64() % ncells as u64) as u32;
                    let span = match i % 50 {
                        0 => ncells as u64,
                        1..=5 => 1 + rng.next_u64() % 60,
                        _ => 1 + rng.next_u64() % 3,
                    };
                    (c0, (c0 as u64 + rng.next_u64() % span).min(ncells as u64 - 1) as u32)
                })
                .collect();
            let want = lists_per_slab(&cells, &slab_of_cell, slabs);
            for chunk in [1, 7, 1000, 16_384, ntris.max(1), 10 * ntris + 1] {
                for threads in [1, 2, 3] {
                    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
                    let got = pool.install(|| SlabLists::new(&cells, &slab_of_cell, slabs, chunk));
                    assert_eq!(got.start.len(), slabs + 1);
                    assert_eq!(got.tris.len(), want.iter().map(Vec::len).sum::<usize>());
                    for (s, w) in want.iter().enumerate() {
                        assert_eq!(got.get(s), &w[..], "{ntris} triangles, slab {s}, chunk {chunk}, {threads} threads");
                    }
                }
            }
        }
    }

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
