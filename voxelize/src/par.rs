//! Parallel loops whose results do not depend on the thread count: sums added in index
//! order (the bits of the serial loop they replace), the terms computed in parallel.

use rayon::prelude::*;

/// Terms computed per block: enough to amortise a parallel call (a few µs), few enough to
/// stay in L2 (32 k × 4 f64 = 1 MiB at most).
const BLOCK: usize = 1 << 15;

/// `acc` plus Σ `term(i)` over `0..n`, each of the `K` sums added in index order, exactly as
/// `for i in 0..n { acc[k] += term(i)[k] }` would add them (floating-point sums depend on
/// their order; this one is the serial order whatever the thread count), with the terms
/// computed in parallel a block at a time.
pub(crate) fn ordered_sum<const K: usize>(n: usize, mut acc: [f64; K], term: impl Fn(usize) -> [f64; K] + Sync) -> [f64; K] {
    let mut buf: Vec<[f64; K]> = Vec::with_capacity(BLOCK.min(n));
    for start in (0..n).step_by(BLOCK) {
        let end = (start + BLOCK).min(n);
        (start..end).into_par_iter().map(&term).collect_into_vec(&mut buf);
        for t in &buf {
            for k in 0..K {
                acc[k] += t[k];
            }
        }
    }
    acc
}

/// Drops `x` on a pool thread rather than this one: freeing a large buffer (unmapping its
/// pages, about 0.15 ms per MB) then overlaps the work that follows instead of holding it up.
pub(crate) fn drop_later<T: Send + 'static>(x: T) {
    rayon::spawn(move || drop(x));
}

/// Axis-aligned bounds: per axis the least and the greatest coordinate.
pub(crate) type Bounds = ([f64; 3], [f64; 3]);

/// Bounds of no point: what a point's coordinates replace.
pub(crate) const NO_BOUNDS: Bounds = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);

/// `a.min(b)` as `f64::min` compiles on x86-64: NaN ignored, and of equal values (+0 and
/// -0) the first. Spelled out because `f64::min` leaves the choice between equal zeros open:
/// with ties going to the first, combining partial bounds left to right gives the bits of the
/// serial loop whatever their grouping.
#[inline(always)]
fn min_first(a: f64, b: f64) -> f64 {
    if b < a || a.is_nan() {
        b
    } else {
        a
    }
}

/// [`min_first`] for the greatest value.
#[inline(always)]
fn max_first(a: f64, b: f64) -> f64 {
    if b > a || a.is_nan() {
        b
    } else {
        a
    }
}

/// `b` added to bounds `a`, per axis: the serial loop's step `lo = lo.min(p); hi = hi.max(p)`
/// (see [`min_first`]), and the join of two partial bounds.
#[inline(always)]
fn join_bounds(a: Bounds, b: Bounds) -> Bounds {
    (std::array::from_fn(|k| min_first(a.0[k], b.0[k])), std::array::from_fn(|k| max_first(a.1[k], b.1[k])))
}

/// `acc` joined with the bounds of `point(i)` over `0..n`, as the serial loop
/// `for i in 0..n { let p = point(i); lo[k] = lo[k].min(p[k]); hi[k] = hi[k].max(p[k]) }`
/// gives them (NaN coordinates ignored; of +0 and -0, the first met), the points taken on
/// every thread: the least and the greatest do not depend on the order they are found in,
/// and ties go to the earlier part.
pub(crate) fn bounds(n: usize, acc: Bounds, point: impl Fn(usize) -> [f64; 3] + Sync) -> Bounds {
    // A few points (scenes of many small meshes) are not worth a parallel call.
    if n < BOUNDS_MIN_LEN {
        return (0..n).fold(acc, |b, i| {
            let p = point(i);
            join_bounds(b, (p, p))
        });
    }
    let found = (0..n)
        .into_par_iter()
        .with_min_len(BOUNDS_MIN_LEN)
        .fold(|| NO_BOUNDS, |b, i| {
            let p = point(i);
            join_bounds(b, (p, p))
        })
        .reduce(|| NO_BOUNDS, join_bounds);
    join_bounds(acc, found)
}

/// Points per task of [`bounds`]: a few µs of work, against a task's cost of about 1 µs.
const BOUNDS_MIN_LEN: usize = 1 << 13;

#[cfg(test)]
mod tests {
    use super::*;

    /// Bounds on several threads have the bits of the serial loop with `f64::min` and
    /// `f64::max`, on points with NaN, infinities, signed zeros (the first met wins on both
    /// sides), across many tasks; none and all-NaN points leave `acc` as it was.
    #[test]
    fn bounds_are_the_serial_loops() {
        let mut rng = sct_format::rng::SplitMix64(11);
        let specials = [0.0, -0.0, f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e-310, -1e-310, f64::MAX];
        for (n, special_every) in [(0, 1), (1, 1), (7, 1), (3 * BOUNDS_MIN_LEN + 5, 3), (5 * BOUNDS_MIN_LEN, 50), (200_000, 1_000_000)] {
            let pts: Vec<[f64; 3]> = (0..n)
                .map(|_| {
                    std::array::from_fn(|_| {
                        if rng.next_u64() % special_every == 0 {
                            specials[(rng.next_u64() % specials.len() as u64) as usize]
                        } else {
                            (rng.next_f64() - 0.5) * 1e3
                        }
                    })
                })
                .collect();
            for acc in [NO_BOUNDS, ([-0.0, 0.0, 5.0], [0.0, -0.0, -5.0])] {
                let (mut lo, mut hi) = acc;
                for p in &pts {
                    for k in 0..3 {
                        lo[k] = lo[k].min(p[k]);
                        hi[k] = hi[k].max(p[k]);
                    }
                }
                let bits = |b: Bounds| (b.0.map(f64::to_bits), b.1.map(f64::to_bits));
                for threads in [1, 2, 3] {
                    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
                    let got = pool.install(|| bounds(pts.len(), acc, |i| pts[i]));
                    assert_eq!(bits(got), bits((lo, hi)), "n {n}, {threads} threads");
                }
            }
        }
        // Signed zeros only: the first met wins, on either side of a task boundary.
        for first in [0.0f64, -0.0] {
            let pts: Vec<[f64; 3]> = (0..4 * BOUNDS_MIN_LEN).map(|i| [if i < 3 * BOUNDS_MIN_LEN { f64::NAN } else { first }; 3]).chain([[-first; 3]]).collect();
            let got = bounds(pts.len(), NO_BOUNDS, |i| pts[i]);
            assert_eq!((got.0[0].to_bits(), got.1[0].to_bits()), (first.to_bits(), first.to_bits()));
        }
        assert_eq!(bounds(3, NO_BOUNDS, |_| [f64::NAN; 3]).0, [f64::INFINITY; 3]);
    }

    /// Terms over many magnitudes, where the order of additions changes the bits: the
    /// parallel sum is the serial one on 1, 2 and 3 threads, across block boundaries.
    #[test]
    fn ordered_sum_is_the_serial_sum() {
        let term = |i: usize| {
            let x = (i as f64 * 0.618_033_988_7).fract();
            [x * 10f64.powi((i % 23) as i32 - 11), (i % 7) as f64 * 1e-3 + x]
        };
        for n in [0, 1, 5, BLOCK - 1, BLOCK, 3 * BLOCK + 17] {
            let mut want = [0.25, -1.0];
            for i in 0..n {
                let t = term(i);
                want[0] += t[0];
                want[1] += t[1];
            }
            for threads in [1, 2, 3] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
                let got = pool.install(|| ordered_sum(n, [0.25, -1.0], term));
                assert_eq!(got.map(f64::to_bits), want.map(f64::to_bits), "n {n}, {threads} threads");
            }
        }
        // Summed in pieces (as a parallel reduction would) the same terms differ in the
        // last bits: the test above can fail.
        let n = 3 * BLOCK + 17;
        let serial = (0..n).fold(0.0, |s, i| s + term(i)[0]);
        let pieces = (0..n).step_by(1000).map(|a| (a..(a + 1000).min(n)).fold(0.0, |s, i| s + term(i)[0])).fold(0.0, |s, p| s + p);
        assert_ne!(serial.to_bits(), pieces.to_bits());
    }
}
