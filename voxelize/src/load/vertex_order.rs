//! Vertices numbered in the order the corners first use them, on every thread.
//!
//! An OBJ names positions, not vertices: a scan's positions-only triangles get one vertex
//! per position used, numbered in the order of first use, as the file-order walk numbers
//! them (so a triangle's new vertices are the next numbers, and the passes that read
//! vertices triangle by triangle read them nearly in order).

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering::Relaxed};

use rayon::prelude::*;

/// The vertices `0..nv` in the order corners `0..n` first use them (`vertex(c) < nv` is
/// corner `c`'s vertex): `order[new] = old` for the vertices used, and `renumber[old] = new`
/// (`u32::MAX` for a vertex no corner uses); `None` when `n` does not fit below `u32::MAX`.
///
/// On every thread: each vertex's first corner is a parallel minimum (a corner past the
/// vertex's known first skips the atomic minimum, so about one per vertex is taken), the
/// first corners are marked in a bitmap of the corners, and the vertices in order are those
/// of the marked corners, collected chunk by chunk in order; their slots then take the new
/// numbers.
pub(crate) fn first_use_order(nv: usize, n: usize, vertex: impl Fn(usize) -> u32 + Sync) -> Option<(Vec<u32>, Vec<AtomicU32>)> {
    const CHUNK: usize = 1 << 16;
    if n >= u32::MAX as usize {
        return None;
    }
    let first: Vec<AtomicU32> = (0..nv).into_par_iter().map(|_| AtomicU32::new(u32::MAX)).collect();
    (0..n).into_par_iter().with_min_len(CHUNK).for_each(|c| {
        let slot = &first[vertex(c) as usize];
        if (c as u32) < slot.load(Relaxed) {
            slot.fetch_min(c as u32, Relaxed);
        }
    });
    let marks: Vec<AtomicU64> = (0..n.div_ceil(64)).into_par_iter().map(|_| AtomicU64::new(0)).collect();
    first.par_iter().with_min_len(CHUNK).for_each(|f| {
        let c = f.load(Relaxed) as usize;
        if c < n {
            marks[c / 64].fetch_or(1 << (c % 64), Relaxed);
        }
    });
    let order: Vec<u32> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .flat_map_iter(|i| (i * CHUNK..n.min((i + 1) * CHUNK)).filter(|&c| marks[c / 64].load(Relaxed) >> (c % 64) & 1 == 1).map(&vertex))
        .collect();
    drop(marks);
    // Unused vertices keep u32::MAX: there are fewer than u32::MAX used ones.
    order.par_iter().enumerate().for_each(|(new, &old)| first[old as usize].store(new as u32, Relaxed));
    Some((order, first))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Random corners over chunk boundaries, some vertices unused: the order and the
    /// numbers of a serial walk.
    #[test]
    fn first_use_is_the_serial_walks_order() {
        let mut rng = sct_format::rng::SplitMix64(11);
        for (nv, n) in [(1, 0), (1, 3), (10, 30), (5000, 3000), (70_000, 300_000)] {
            let corners: Vec<u32> = (0..n).map(|_| (rng.next_u64() % nv as u64) as u32).collect();
            let (mut want, mut number) = (Vec::new(), vec![u32::MAX; nv]);
            for &v in &corners {
                if number[v as usize] == u32::MAX {
                    number[v as usize] = want.len() as u32;
                    want.push(v);
                }
            }
            let (order, renumber) = first_use_order(nv, n, |c| corners[c]).expect("fits");
            assert_eq!(order, want, "{nv} vertices, {n} corners");
            assert_eq!(renumber.into_iter().map(AtomicU32::into_inner).collect::<Vec<_>>(), number);
        }
        assert!(first_use_order(1, u32::MAX as usize, |_| 0).is_none());
    }
}
