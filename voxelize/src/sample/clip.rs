//! Convex polygons in the projection plane and their clipping by grid lines and depth planes.


pub(super) const MAXV: usize = 10;

/// A convex polygon in the projection plane (coordinates along axes a, b).
#[derive(Clone, Copy)]
pub(super) struct Poly2 {
    pub(super) v: [[f64; 2]; MAXV],
    pub(super) n: usize,
}

impl Poly2 {
    /// Makes this the unit square at (x, y), in place (vertices past `n` are never read).
    pub(super) fn set_square(&mut self, x: f64, y: f64) {
        self.v[..4].copy_from_slice(&[[x, y], [x + 1.0, y], [x + 1.0, y + 1.0], [x, y + 1.0]]);
        self.n = 4;
    }
    /// An empty polygon (a buffer for the `_into` clips).
    pub(super) fn empty() -> Poly2 {
        Poly2 { v: [[0.0; 2]; MAXV], n: 0 }
    }
    /// Keeps `x[axis] ∈ [lo, hi]`.
    pub(super) fn clip_axis(&self, axis: usize, lo: f64, hi: f64) -> Poly2 {
        let (mut tmp, mut out) = (Poly2::empty(), Poly2::empty());
        self.clip_axis_into(axis, lo, hi, &mut tmp, &mut out);
        out
    }
    /// [`Poly2::clip_axis`] into `out` (`tmp` holds the half-way polygon): the hot loops
    /// reuse two buffers instead of zeroing and copying fresh polygons.
    #[inline]
    pub(super) fn clip_axis_into(&self, axis: usize, lo: f64, hi: f64, tmp: &mut Poly2, out: &mut Poly2) {
        self.clip_half_into(|p| p[axis] - lo, Some((axis, lo)), tmp);
        tmp.clip_half_into(|p| hi - p[axis], Some((axis, hi)), out);
    }
    /// Splits at `x[AXIS] = c` into the parts `x[AXIS] ≤ c` (`below`) and `≥ c` (`above`) in
    /// one pass: the polygons of the two clips, with each cut point computed once and shared,
    /// so the parts meet exactly. `AXIS` is a constant so that the coordinate reads and the
    /// exact cut coordinate need no runtime index.
    #[inline]
    pub(super) fn split_axis_into<const AXIS: usize>(&self, c: f64, below: &mut Poly2, above: &mut Poly2) {
        let axis = AXIS;
        below.n = 0;
        above.n = 0;
        if self.n == 0 {
            return;
        }
        let mut prev = self.v[self.n - 1];
        let mut fp = prev[axis] - c;
        // The previous vertex's sides, carried so each vertex is compared once.
        let (mut prev_above, mut prev_below) = (fp >= 0.0, fp <= 0.0);
        for i in 0..self.n {
            let cur = self.v[i];
            let fc = cur[axis] - c;
            let (cur_above, cur_below) = (fc >= 0.0, fc <= 0.0);
            let (cross_above, cross_below) = (cur_above != prev_above, cur_below != prev_below);
            if cross_above || cross_below {
                let t = fp / (fp - fc);
                let mut x = [prev[0] + t * (cur[0] - prev[0]), prev[1] + t * (cur[1] - prev[1])];
                x[axis] = c;
                if cross_above && above.n < MAXV {
                    above.v[above.n] = x;
                    above.n += 1;
                }
                if cross_below && below.n < MAXV {
                    below.v[below.n] = x;
                    below.n += 1;
                }
            }
            if cur_above && above.n < MAXV {
                above.v[above.n] = cur;
                above.n += 1;
            }
            if cur_below && below.n < MAXV {
                below.v[below.n] = cur;
                below.n += 1;
            }
            prev = cur;
            fp = fc;
            (prev_above, prev_below) = (cur_above, cur_below);
        }
    }
    /// Splits where the vertex values `vals` (an affine function's, one per vertex) cross `c`
    /// into the parts `≤ c` (`below`) and `≥ c` (`above`) in one pass: the polygons of
    /// [`Poly2::clip_half_by_index_into`] by `c − vals[i]` and by `vals[i] − c`, bit for bit
    /// (the cut points are the same numbers either way), each cut point computed once. The
    /// parts' vertex values go to `below_vals` and `above_vals` (`c` at the cut points).
    #[inline(always)]
    pub(super) fn split_values_into(&self, vals: &[f64; MAXV], c: f64, (below, below_vals): (&mut Poly2, &mut [f64; MAXV]), (above, above_vals): (&mut Poly2, &mut [f64; MAXV])) {
        below.n = 0;
        above.n = 0;
        if self.n == 0 {
            return;
        }
        let mut prev = self.v[self.n - 1];
        // Signs as the clip by `c − vals[i]` takes them: `fp` is its value negated, and the
        // cut's parameter `fp / (fp − fc)` is the same for both signs.
        let mut fp = c - vals[self.n - 1];
        let (mut prev_below, mut prev_above) = (fp >= 0.0, -fp >= 0.0);
        for (&cur, &val) in self.v[..self.n].iter().zip(vals) {
            let fc = c - val;
            let (cur_below, cur_above) = (fc >= 0.0, -fc >= 0.0);
            let (cross_below, cross_above) = (cur_below != prev_below, cur_above != prev_above);
            if cross_below || cross_above {
                let t = fp / (fp - fc);
                let x = [prev[0] + t * (cur[0] - prev[0]), prev[1] + t * (cur[1] - prev[1])];
                if cross_below && below.n < MAXV {
                    (below.v[below.n], below_vals[below.n]) = (x, c);
                    below.n += 1;
                }
                if cross_above && above.n < MAXV {
                    (above.v[above.n], above_vals[above.n]) = (x, c);
                    above.n += 1;
                }
            }
            if cur_below && below.n < MAXV {
                (below.v[below.n], below_vals[below.n]) = (cur, val);
                below.n += 1;
            }
            if cur_above && above.n < MAXV {
                (above.v[above.n], above_vals[above.n]) = (cur, val);
                above.n += 1;
            }
            prev = cur;
            fp = fc;
            (prev_below, prev_above) = (cur_below, cur_above);
        }
    }
    /// Keeps the side `f(p) >= 0` of a line (`f` affine). `exact` = (axis, value) for
    /// axis-aligned lines: intersections get that coordinate exactly, so neighbouring clips
    /// agree bit for bit.
    #[inline]
    pub(super) fn clip_half(&self, f: impl Fn(&[f64; 2]) -> f64, exact: Option<(usize, f64)>) -> Poly2 {
        let mut out = Poly2::empty();
        self.clip_half_into(f, exact, &mut out);
        out
    }
    /// [`Poly2::clip_half`] into `out` (its old vertices are overwritten).
    #[inline]
    pub(super) fn clip_half_into(&self, f: impl Fn(&[f64; 2]) -> f64, exact: Option<(usize, f64)>, out: &mut Poly2) {
        self.clip_half_by_index_into(|_, p| f(p), exact, out);
    }
    /// [`Poly2::clip_half_into`] with `f` also given the vertex's index, so it can read values
    /// already computed per vertex.
    #[inline]
    pub(super) fn clip_half_by_index_into(&self, f: impl Fn(usize, &[f64; 2]) -> f64, exact: Option<(usize, f64)>, out: &mut Poly2) {
        out.n = 0;
        if self.n == 0 {
            return;
        }
        let mut prev = self.v[self.n - 1];
        let mut fp = f(self.n - 1, &prev);
        let mut prev_in = fp >= 0.0; // carried: each vertex is compared once
        for i in 0..self.n {
            let cur = self.v[i];
            let fc = f(i, &cur);
            let cur_in = fc >= 0.0;
            if cur_in != prev_in && out.n < MAXV {
                let t = fp / (fp - fc);
                let mut x = [prev[0] + t * (cur[0] - prev[0]), prev[1] + t * (cur[1] - prev[1])];
                if let Some((axis, c)) = exact {
                    x[axis] = c;
                }
                out.v[out.n] = x;
                out.n += 1;
            }
            if cur_in && out.n < MAXV {
                out.v[out.n] = cur;
                out.n += 1;
            }
            prev = cur;
            fp = fc;
            prev_in = cur_in;
        }
    }
    /// (area, centroid) of the polygon (shoelace, relative to the first vertex for precision).
    /// Inlined: it runs once or twice per boundary or depth-crossing column.
    #[inline(always)]
    pub(super) fn area_centroid(&self) -> (f64, [f64; 2]) {
        let o = self.v[0];
        let (mut a2, mut cx, mut cy) = (0.0, 0.0, 0.0);
        for i in 1..self.n.saturating_sub(1) {
            let (p, q) = ([self.v[i][0] - o[0], self.v[i][1] - o[1]], [self.v[i + 1][0] - o[0], self.v[i + 1][1] - o[1]]);
            let cr = p[0] * q[1] - q[0] * p[1];
            a2 += cr;
            cx += cr * (p[0] + q[0]);
            cy += cr * (p[1] + q[1]);
        }
        if a2 != 0.0 {
            (0.5 * a2.abs(), [o[0] + cx / (3.0 * a2), o[1] + cy / (3.0 * a2)])
        } else {
            let n = self.n.max(1) as f64;
            let m = self.v[..self.n].iter().fold([0.0; 2], |m, p| [m[0] + p[0] / n, m[1] + p[1] / n]);
            (0.0, m)
        }
    }
    /// (min, max) of `f` over the vertices; NaN values are ignored. Plain comparisons: one
    /// instruction each where `f64::min`/`max` add NaN handling (they may differ only in the
    /// sign of a zero, which compares and floors alike).
    pub(super) fn range(&self, f: impl Fn(&[f64; 2]) -> f64) -> (f64, f64) {
        self.range_keeping(f, &mut [0.0; MAXV])
    }
    /// [`Poly2::range`] that also stores each vertex's value in `vals`.
    #[inline]
    pub(super) fn range_keeping(&self, f: impl Fn(&[f64; 2]) -> f64, vals: &mut [f64; MAXV]) -> (f64, f64) {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for (p, v) in self.v[..self.n].iter().zip(vals.iter_mut()) {
            let x = f(p);
            *v = x;
            (lo, hi) = (if x < lo { x } else { lo }, if x > hi { x } else { hi });
        }
        (lo, hi)
    }
}

/// The polygon at `r` of a ping-pong pair (to read) and the other one (to write).
pub(super) fn ping(pair: &mut [Poly2; 2], r: usize) -> (&Poly2, &mut Poly2) {
    let (a, b) = pair.split_at_mut(1);
    if r == 0 { (&a[0], &mut b[0]) } else { (&b[0], &mut a[0]) }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One-pass splitting gives the polygons of the two clips bit for bit (vertices on the cut
    /// line included), so swept strips and columns meet exactly.
    #[test]
    fn split_equals_two_clips() {
        let mut rng = sct_format::rng::SplitMix64(5);
        for i in 0..20_000 {
            // Random triangles, some with vertices on the cut line.
            let mut p = Poly2::empty();
            p.n = 3;
            for v in &mut p.v[..3] {
                *v = [(rng.next_f64() * 8.0).floor() / 2.0, rng.next_f64() * 4.0];
            }
            let (axis, c) = (i % 2, if i % 3 == 0 { 2.0 } else { rng.next_f64() * 4.0 });
            let (mut below, mut above) = (Poly2::empty(), Poly2::empty());
            if axis == 0 {
                p.split_axis_into::<0>(c, &mut below, &mut above);
            } else {
                p.split_axis_into::<1>(c, &mut below, &mut above);
            }
            let want_below = p.clip_half(|q| c - q[axis], Some((axis, c)));
            let want_above = p.clip_half(|q| q[axis] - c, Some((axis, c)));
            for (got, want) in [(below, want_below), (above, want_above)] {
                assert_eq!(got.n, want.n);
                assert_eq!(got.v[..got.n], want.v[..want.n]);
            }
        }
    }

    #[test]
    fn clip_by_kept_depths_equals_clip_by_depth() {
        // The voxel method clips a piece with depths kept by range_keeping: same polygons.
        let mut rng = sct_format::rng::SplitMix64(11);
        for _ in 0..5_000 {
            let mut p = Poly2::empty();
            p.n = 3 + (rng.next_f64() * 3.0) as usize;
            for v in &mut p.v[..p.n] {
                *v = [rng.next_f64() * 3.0, rng.next_f64() * 3.0];
            }
            let (ga, gb, kf) = (rng.next_f64() * 2.0 - 1.0, rng.next_f64() * 2.0 - 1.0, rng.next_f64() * 2.0);
            let depth = |q: &[f64; 2]| 0.25 + ga * q[0] + gb * q[1];
            let mut dv = [0.0; MAXV];
            let kept = p.range_keeping(depth, &mut dv);
            let want = p.range(depth);
            assert_eq!((kept.0.to_bits(), kept.1.to_bits()), (want.0.to_bits(), want.1.to_bits()));
            let (mut got, mut want) = (Poly2::empty(), Poly2::empty());
            p.clip_half_by_index_into(|i, _| kf - dv[i], None, &mut got);
            p.clip_half_into(|q| kf - depth(q), None, &mut want);
            assert_eq!(got.n, want.n);
            for (a, b) in got.v[..got.n].iter().zip(&want.v[..want.n]) {
                assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits));
            }
        }
    }

    /// Splitting by vertex values gives the polygons of the two clips bit for bit (vertices on
    /// the cut included): the voxel method's depth split is the lower clip it replaced.
    #[test]
    fn split_by_values_equals_two_clips() {
        let mut rng = sct_format::rng::SplitMix64(13);
        for i in 0..20_000 {
            let mut p = Poly2::empty();
            p.n = 3 + i % 4;
            for v in &mut p.v[..p.n] {
                *v = [(rng.next_f64() * 8.0).floor() / 4.0, (rng.next_f64() * 8.0).floor() / 4.0];
            }
            let (ga, gb) = (rng.next_f64() * 2.0 - 1.0, [0.0, 0.5, -1.0, rng.next_f64()][i % 4]);
            let mut vals = [0.0; MAXV];
            for (v, q) in vals.iter_mut().zip(&p.v[..p.n]) {
                *v = 0.25 + ga * q[0] + gb * q[1];
            }
            let c = if i % 3 == 0 { vals[i % p.n] } else { rng.next_f64() * 2.0 - 0.5 };
            let (mut below, mut above) = (Poly2::empty(), Poly2::empty());
            let (mut below_vals, mut above_vals) = ([f64::NAN; MAXV], [f64::NAN; MAXV]);
            p.split_values_into(&vals, c, (&mut below, &mut below_vals), (&mut above, &mut above_vals));
            // A part's values are its vertices' (of the polygon) or `c` (at the cut points).
            for (part, part_vals) in [(&below, &below_vals), (&above, &above_vals)] {
                for (q, &v) in part.v[..part.n].iter().zip(part_vals) {
                    let own = p.v[..p.n].iter().position(|x| x == q).map(|i| vals[i]);
                    assert!(own == Some(v) || v == c, "{q:?}: {v} (own {own:?}, cut {c})");
                }
            }
            let (mut want_below, mut want_above) = (Poly2::empty(), Poly2::empty());
            p.clip_half_by_index_into(|i, _| c - vals[i], None, &mut want_below);
            p.clip_half_by_index_into(|i, _| vals[i] - c, None, &mut want_above);
            for (got, want) in [(below, want_below), (above, want_above)] {
                assert_eq!(got.n, want.n);
                for (a, b) in got.v[..got.n].iter().zip(&want.v[..want.n]) {
                    assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits));
                }
            }
        }
    }

    #[test]
    fn polygon_range_is_min_and_max_ignoring_nan() {
        let mut p = Poly2::empty();
        p.set_square(2.0, -3.0);
        assert_eq!(p.range(|v| v[0]), (2.0, 3.0));
        assert_eq!(p.range(|v| v[1] * 2.0), (-6.0, -4.0));
        assert_eq!(p.range(|v| if v[0] == 3.0 { f64::NAN } else { v[1] }), (-3.0, -2.0));
        p.n = 0;
        assert_eq!(p.range(|v| v[0]), (f64::INFINITY, f64::NEG_INFINITY));
    }
}
