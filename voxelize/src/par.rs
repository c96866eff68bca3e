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

#[cfg(test)]
mod tests {
    use super::*;

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
