//! The thesis' scan-line sampler: one sample per grid column whose centre lies inside the
//! triangle projected along its dominant normal axis, in the voxel that holds the plane
//! point above that centre; EQ 17 areas (triangle area / the triangle's sample count).
//!
//! A triangle is rasterized row by row: each row's run of inside column centres comes from
//! the three edges (a division per edge and row, nothing per column), so the triangle's
//! sample count is a sum over rows, and a slab's call visits only the columns of its own
//! voxels. Counting and emitting read the same spans, so every slab divides by the same
//! count and the slabs' samples partition the triangle's.

use super::{face_axes, shade_color, unit_or, KeyPack, Mat, Planes, Rec, RecSink, Tri};
use crate::mesh::{floor_i64, norm};

/// `x.ceil() as i64` (saturating, NaN → 0) without a libm call, like [`floor_i64`].
#[inline]
fn ceil_i64(x: f64) -> i64 {
    floor_i64(-x).saturating_neg()
}

/// One edge of the projected triangle as a bound on b along a row: the edge's line is
/// `b = b0 + (a − a0)·db/da`, and inside lies above it (`Lower`), below it (`Upper`), or,
/// for an edge along b, on one side of `a = a0` (`Side`: inside where `(a − a0)·sign ≥ 0`).
#[derive(Clone, Copy)]
enum Edge {
    Lower { a0: f64, b0: f64, da: f64, db: f64 },
    Upper { a0: f64, b0: f64, da: f64, db: f64 },
    Side { a0: f64, sign: f64 },
}

/// The column centres inside a projected triangle, row by row (rows along a, columns along
/// b; column `(ia, ib)` has its centre at `(ia + ½, ib + ½)`). A centre on an edge is inside.
struct Spans {
    edges: [Edge; 3],
    /// Rows `first..=last` whose centres lie within the triangle's a range (clamped to the key
    /// range; empty when `first > last`).
    rows: (i64, i64),
    /// Columns within its b range (clamped to the key range).
    cols: (i64, i64),
}

impl Spans {
    /// The spans of triangle `q` (corners in the projection plane); `ra`, `rb` = the key
    /// range along a and b (loops never run beyond it, whatever the coordinates). A triangle
    /// that projects to a line or a point has no spans.
    fn new(q: &[[f64; 2]; 3], ra: (i64, i64), rb: (i64, i64)) -> Spans {
        let det = (q[1][0] - q[0][0]) * (q[2][1] - q[0][1]) - (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]);
        let orient = if det > 0.0 { 1.0 } else { -1.0 };
        let edges = std::array::from_fn(|i| {
            let (p0, p1) = (q[i], q[(i + 1) % 3]);
            let (da, db) = (p1[0] - p0[0], p1[1] - p0[1]);
            // Inside: orient · (da·(b − b0) − db·(a − a0)) ≥ 0.
            if da * orient > 0.0 {
                Edge::Lower { a0: p0[0], b0: p0[1], da, db }
            } else if da * orient < 0.0 {
                Edge::Upper { a0: p0[0], b0: p0[1], da, db }
            } else {
                Edge::Side { a0: p0[0], sign: -db * orient }
            }
        });
        let range = |k: usize, r: (i64, i64)| {
            let lo = q.iter().fold(f64::INFINITY, |m, p| m.min(p[k]));
            let hi = q.iter().fold(f64::NEG_INFINITY, |m, p| m.max(p[k]));
            (ceil_i64(lo - 0.5).max(r.0), floor_i64(hi - 0.5).min(r.1))
        };
        let (mut rows, cols) = (range(0, ra), range(1, rb));
        if !(det != 0.0) {
            rows = (1, 0);
        }
        Spans { edges, rows, cols }
    }

    /// The columns `first..=last` of row `ia` (empty when `first > last`).
    #[inline]
    fn row(&self, ia: i64) -> (i64, i64) {
        let a = ia as f64 + 0.5;
        let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
        for e in &self.edges {
            // Dividing (not multiplying by a slope) keeps the bound exact whenever the
            // centre lies exactly on the edge and the arithmetic is exact.
            match *e {
                Edge::Lower { a0, b0, da, db } => lo = lo.max(b0 + (a - a0) * db / da),
                Edge::Upper { a0, b0, da, db } => hi = hi.min(b0 + (a - a0) * db / da),
                Edge::Side { a0, sign } => {
                    if !((a - a0) * sign >= 0.0) {
                        return (1, 0);
                    }
                }
            }
        }
        (ceil_i64(lo - 0.5).max(self.cols.0), floor_i64(hi - 0.5).min(self.cols.1))
    }

    /// The number of inside column centres.
    #[cfg(test)]
    fn count(&self) -> u64 {
        self.count_keeping(&mut [])
    }

    /// [`Spans::count`], keeping the spans of the first rows in `first_rows` (row
    /// `rows.0 + i` at `i`), so the emission need not compute them again.
    fn count_keeping(&self, first_rows: &mut [(i64, i64)]) -> u64 {
        let mut kept = first_rows.iter_mut();
        let mut n = 0;
        for ia in self.rows.0..=self.rows.1 {
            let (f, l) = self.row(ia);
            if let Some(k) = kept.next() {
                *k = (f, l);
            }
            if l >= f {
                n += l.abs_diff(f).saturating_add(1);
            }
        }
        n
    }
}

/// [`Planes::shade`] along one row (fixed a): each varying channel's part up to the a term
/// (`value at o + d/da·Δa`) is taken once per row, so a sample adds only `d/db·Δb` — the same
/// operations in the same order, hence the same values bit for bit. Channels the material
/// ignores (texture coordinates without a texture) are not evaluated, and vertex colours
/// equal at the three corners are used as they are ([`Planes`]' `vc`).
struct RowShade<'p, 'm> {
    planes: &'p Planes<'m>,
    /// Per channel (value at the row's a, d/db).
    n: [[f32; 2]; 3],
    c: [[f32; 2]; 4],
    uv: [[f32; 2]; 2],
    uv2: [[f32; 2]; 2],
}

impl<'p, 'm> RowShade<'p, 'm> {
    fn new(planes: &'p Planes<'m>) -> Self {
        RowShade { planes, n: [[0.0; 2]; 3], c: [[0.0; 2]; 4], uv: [[0.0; 2]; 2], uv2: [[0.0; 2]; 2] }
    }

    /// Moves to the row through `a`.
    #[inline]
    fn row(&mut self, a: f64) {
        let p = self.planes;
        let da = (a - p.o[0]) as f32;
        let rebase = |pl: &[f32; 3]| [pl[0] + pl[1] * da, pl[2]];
        if p.flat_n.is_none() {
            self.n = p.n.each_ref().map(rebase);
        }
        if p.flat_c.is_none() {
            if p.vc.is_none() {
                self.c = p.c.each_ref().map(rebase);
            }
            if p.mat.tex.is_some() {
                self.uv = p.uv.each_ref().map(rebase);
            }
            if p.mat.alpha_tex.is_some() {
                self.uv2 = p.uv2.each_ref().map(rebase);
            }
        }
    }

    /// (colour or `None` = dropped by alpha, unit normal) at `b` on the row.
    #[inline(always)]
    fn shade(&self, b: f64) -> (Option<[f32; 4]>, [f32; 3]) {
        let p = self.planes;
        let db = (b - p.o[1]) as f32;
        let at = |r: &[f32; 2]| r[0] + r[1] * db;
        let c = match p.flat_c {
            Some(c) => c,
            None => {
                let vc = p.vc.unwrap_or_else(|| self.c.each_ref().map(at));
                let uv = if p.mat.tex.is_some() { self.uv.each_ref().map(at) } else { [0.0; 2] };
                let uv2 = if p.mat.alpha_tex.is_some() { self.uv2.each_ref().map(at) } else { [0.0; 2] };
                shade_color(vc, uv, uv2, p.mat)
            }
        };
        let n = match p.flat_n {
            Some(n) => n,
            None => unit_or(self.n.each_ref().map(at), p.face_n),
        };
        (c, n)
    }
}

/// The first `i` in `lo..=hi` where `pred` holds, `pred` being false then true along the
/// range (`hi + 1` when it never holds; i128 so that no bound of a key range overflows).
fn partition_point(lo: i64, hi: i64, pred: impl Fn(i64) -> bool) -> i128 {
    let (mut lo, mut hi) = (i128::from(lo), i128::from(hi) + 1);
    while lo < hi {
        let mid = lo + (hi - lo) / 2;
        // `lo ≤ mid < hi ≤ i64::MAX + 1`: `mid` is an i64.
        if pred(mid as i64) {
            hi = mid;
        } else {
            lo = mid + 1;
        }
    }
    lo
}

/// Samples one triangle, emitting only the voxels whose x index (clamped to the key range)
/// lies in `keep` (the caller's slab); the others still count in the EQ 17 area. A
/// triangle that covers no column centre gets one sample at its centroid. Returns the
/// number of alpha-dropped samples among those emitted.
pub(super) fn scanline_triangle(t: &Tri, mat: &Mat, kp: &KeyPack, keep: (i64, i64), out: &mut impl RecSink) -> u64 {
    let (fnrm, d, _, _) = face_axes(t);
    // One copy per depth axis: the axis indices become constants.
    match d {
        0 => scanline_axis::<0, _>(t, fnrm, mat, kp, keep, out),
        1 => scanline_axis::<1, _>(t, fnrm, mat, kp, keep, out),
        _ => scanline_axis::<2, _>(t, fnrm, mat, kp, keep, out),
    }
}

/// [`scanline_triangle`] with depth axis `D` (`fnrm` = the face normal of [`face_axes`]).
fn scanline_axis<const D: usize, S: RecSink>(t: &Tri, fnrm: [f64; 3], mat: &Mat, kp: &KeyPack, keep: (i64, i64), out: &mut S) -> u64 {
    let (a, b) = ((D + 1) % 3, (D + 2) % 3);
    let q = t.p.map(|p| [p[a], p[b]]);
    let spans = Spans::new(&q, (kp.lo[a], kp.hi[a]), (kp.lo[b], kp.hi[b]));
    // Small triangles (most of them) are rasterized once: counting keeps their spans.
    let mut kept = [(0i64, 0i64); 32];
    let total = spans.count_keeping(&mut kept);
    let in_slab = |x: i64| (keep.0..=keep.1).contains(&x.clamp(kp.lo[0], kp.hi[0]));
    // A point inside the triangle lies in the voxels of the corners' range along each axis
    // (up to rounding, which must not move a sample out of the slabs that hold the triangle).
    let cells: [(i64, i64); 3] = std::array::from_fn(|k| {
        let (lo, hi) = t.p.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), p| (l.min(p[k]), h.max(p[k])));
        (floor_i64(lo), floor_i64(hi))
    });
    let (klo, khi) = cells[D];
    let planes = Planes::new(t, &q, fnrm, mat);
    let area = 0.5 * norm(fnrm);
    let mut dropped = 0;
    let mut push = |out: &mut S, key: [i64; 3], shaded: (Option<[f32; 4]>, [f32; 3]), each: f32| match shaded {
        (Some(color), normal) => out.push(Rec { key: kp.pack(key), area: each, normal, color }),
        (None, _) => dropped += 1,
    };
    if total == 0 {
        let cen: [f64; 3] = std::array::from_fn(|k| (t.p[0][k] + t.p[1][k] + t.p[2][k]) / 3.0);
        let key: [i64; 3] = std::array::from_fn(|k| floor_i64(cen[k]).clamp(cells[k].0, cells[k].1));
        if in_slab(key[0]) {
            push(out, key, planes.shade([cen[a], cen[b]]), area as f32);
        }
        return dropped;
    }
    let mut shade = RowShade::new(&planes);
    let each = (area / total as f64) as f32;
    // Depth plane through corner 0: depth = p0 + ga·(a − a0) + gb·(b − b0).
    let (ga, gb) = (-fnrm[a] / fnrm[D], -fnrm[b] / fnrm[D]);
    let p0 = t.p[0];
    // Most triangles lie in one slab: no row needs cutting to it.
    let whole_in_slab = in_slab(cells[0].0) && in_slab(cells[0].1);
    let mut rows = spans.rows;
    if a == 0 {
        rows = (rows.0.max(keep.0), rows.1.min(keep.1));
    }
    for ia in rows.0..=rows.1 {
        let (mut first, mut last) = usize::try_from(ia.abs_diff(spans.rows.0)).ok().and_then(|i| kept.get(i)).copied().unwrap_or_else(|| spans.row(ia));
        if first > last {
            continue;
        }
        let ca = ia as f64 + 0.5;
        let drow = p0[D] + ga * (ca - p0[a]);
        // The same expression (and so the same voxel) in every slab's call.
        let depth_key = |ib: i64| floor_i64(drow + gb * ((ib as f64 + 0.5) - p0[b])).clamp(klo, khi);
        if b == 0 {
            (first, last) = (first.max(keep.0), last.min(keep.1));
        } else if D == 0 && !whole_in_slab {
            // Depth is x here: the slab's columns are those whose depth voxel lies in it. The
            // computed depth is monotone along the row (rounding is monotone), so they form
            // one run: the whole row or none of it when its ends say so, else found by
            // bisection on the exact keys.
            let x = |ib: i64| depth_key(ib).clamp(kp.lo[0], kp.hi[0]);
            let (x_first, x_last) = (x(first), x(last));
            if x_first.max(x_last) < keep.0 || x_first.min(x_last) > keep.1 {
                continue;
            }
            let (from, to) = if x_first.min(x_last) >= keep.0 && x_first.max(x_last) <= keep.1 {
                (i128::from(first), i128::from(last) + 1) // the whole run
            } else if gb >= 0.0 {
                (partition_point(first, last, |ib| x(ib) >= keep.0), partition_point(first, last, |ib| x(ib) > keep.1))
            } else {
                (partition_point(first, last, |ib| x(ib) <= keep.1), partition_point(first, last, |ib| x(ib) < keep.0))
            };
            if from >= to {
                continue;
            }
            // `first ≤ from < to ≤ last + 1`: both fit in i64.
            (first, last) = (from as i64, (to - 1) as i64);
        }
        if first > last {
            continue;
        }
        shade.row(ca);
        for ib in first..=last {
            let mut key = [0i64; 3];
            key[a] = ia;
            key[b] = ib;
            key[D] = depth_key(ib);
            push(out, key, shade.shade(ib as f64 + 0.5), each);
        }
    }
    dropped
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whether centre `c` is inside triangle `q` by the edge functions (a centre on an edge
    /// is inside), and its smallest distance to an edge line.
    fn inside_exact(q: &[[f64; 2]; 3], c: [f64; 2]) -> (bool, f64) {
        let det = (q[1][0] - q[0][0]) * (q[2][1] - q[0][1]) - (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]);
        let orient = if det > 0.0 { 1.0 } else { -1.0 };
        let mut inside = true;
        let mut dist = f64::INFINITY;
        for i in 0..3 {
            let (p0, p1) = (q[i], q[(i + 1) % 3]);
            let (da, db) = (p1[0] - p0[0], p1[1] - p0[1]);
            let e = orient * (da * (c[1] - p0[1]) - db * (c[0] - p0[0]));
            inside &= e >= 0.0;
            dist = dist.min(e.abs() / (da * da + db * db).sqrt());
        }
        (inside, dist)
    }

    /// Random triangles (large and small, thin, some with corners and edges on column
    /// centres): the spans hold exactly the column centres the edge-function test puts
    /// inside, except for centres within 1e-9 of an edge, which are rare; and exactly
    /// those (no exception) when the coordinates are on a 1/8 grid (exact arithmetic, many
    /// centres on edges and corners).
    #[test]
    fn spans_hold_exactly_the_inside_column_centres() {
        let mut rng = sct_format::rng::SplitMix64(17);
        let (mut near, mut checked, mut on_edge) = (0u64, 0u64, 0u64);
        for i in 0..20_000 {
            let snapped = i % 2 == 0;
            let scale = [0.7, 3.0, 12.0, 40.0][i % 4];
            let o = [rng.next_f64() * 100.0 - 50.0, rng.next_f64() * 100.0 - 50.0];
            let mut q: [[f64; 2]; 3] = std::array::from_fn(|_| [o[0] + rng.next_f64() * scale, o[1] + rng.next_f64() * scale]);
            if snapped {
                q = q.map(|p| p.map(|x| (x * 8.0).round() / 8.0));
            }
            if i % 7 == 0 {
                q[2] = [q[0][0] + 1e-3 * (q[1][0] - q[0][0]), q[1][1]]; // thin
            }
            if (q[1][0] - q[0][0]) * (q[2][1] - q[0][1]) == (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]) {
                continue; // snapped to a line
            }
            let spans = Spans::new(&q, (-1000, 1000), (-1000, 1000));
            let mut count = 0u64;
            let (lo, hi) = q.iter().fold(([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]), |(l, h), p| {
                ([l[0].min(p[0]), l[1].min(p[1])], [h[0].max(p[0]), h[1].max(p[1])])
            });
            for ia in lo[0].floor() as i64 - 1..=hi[0].floor() as i64 + 1 {
                let (f, l) = if (spans.rows.0..=spans.rows.1).contains(&ia) { spans.row(ia) } else { (1, 0) };
                count += if l >= f { (l - f + 1) as u64 } else { 0 };
                for ib in lo[1].floor() as i64 - 1..=hi[1].floor() as i64 + 1 {
                    let c = [ia as f64 + 0.5, ib as f64 + 0.5];
                    let (want, dist) = inside_exact(&q, c);
                    checked += 1;
                    on_edge += u64::from(dist == 0.0);
                    if want != (f..=l).contains(&ib) {
                        assert!(!snapped && dist < 1e-9, "{q:?}: centre {c:?} inside {want}, distance {dist:e}");
                        near += 1;
                    }
                }
            }
            assert_eq!(count, spans.count(), "{q:?}");
        }
        assert!(on_edge > 1000, "{on_edge} centres on edges");
        assert!(near * 100_000 < checked, "{near} of {checked} near-edge mismatches");
    }

    /// Random triangles in every orientation (so x is a row, column and depth axis), cut
    /// into slabs of 1 to 4 voxels: the slabs' samples are the whole triangle's, each in
    /// exactly one slab, with the same EQ 17 area (the whole triangle's count), and the
    /// areas add up to the triangle's area (also for triangles covering no column centre,
    /// whose one centroid sample lands in one slab).
    #[test]
    fn slabs_partition_a_triangles_samples() {
        let mut rng = sct_format::rng::SplitMix64(23);
        let mat = Mat { base: [0.5, 0.6, 0.7, 1.0], tex: None, alpha_tex: None, alpha: crate::mesh::AlphaMode::Opaque };
        let kp = KeyPack::new([-80.0; 3], [80.0; 3]).expect("keys");
        let key_fields = |r: &Rec| (r.key, r.area.to_bits(), r.normal.map(f32::to_bits), r.color.map(f32::to_bits));
        let (mut axes, mut centroid_only) = ([0; 3], 0);
        for i in 0..3000 {
            let scale = [0.8, 4.0, 30.0][i % 3];
            let o: [f64; 3] = std::array::from_fn(|_| rng.next_f64() * 80.0 - 40.0);
            let p: [[f64; 3]; 3] = std::array::from_fn(|_| std::array::from_fn(|k| o[k] + rng.next_f64() * scale));
            let n: [[f32; 3]; 3] = std::array::from_fn(|_| std::array::from_fn(|_| rng.next_f64() as f32 - 0.5));
            let t = Tri { p, n, c: [[1.0; 4]; 3], uv: [[0.0; 2]; 3], uv2: [[0.0; 2]; 3] };
            let (fnrm, d, _, _) = face_axes(&t);
            axes[d] += 1;
            let mut whole = Vec::new();
            assert_eq!(scanline_triangle(&t, &mat, &kp, (i64::MIN, i64::MAX), &mut whole), 0);
            let width = 1 + (i % 4) as i64;
            let mut parts = Vec::new();
            let mut x0 = kp.lo[0];
            while x0 <= kp.hi[0] {
                let before = parts.len();
                scanline_triangle(&t, &mat, &kp, (x0, x0 + width - 1), &mut parts);
                assert!(parts[before..].iter().all(|r| (x0..x0 + width).contains(&kp.unpack(r.key)[0])));
                x0 += width;
            }
            let (mut w, mut s): (Vec<_>, Vec<_>) = (whole.iter().map(key_fields).collect(), parts.iter().map(key_fields).collect());
            w.sort_unstable();
            s.sort_unstable();
            assert_eq!(w, s, "{p:?}");
            let sum: f64 = whole.iter().map(|r| f64::from(r.area)).sum();
            let area = 0.5 * norm(fnrm);
            assert!((sum - area).abs() <= 1e-6 * area, "{p:?}: {sum} vs {area}");
            centroid_only += u32::from(whole.len() == 1 && whole[0].area == area as f32);
        }
        assert!(axes.iter().all(|&n| n > 500), "{axes:?}");
        assert!(centroid_only > 20, "{centroid_only} triangles without a column centre");
    }

    /// Triangles that project to a line have no spans (they get the centroid sample).
    #[test]
    fn flat_projection_has_no_spans() {
        let q = [[0.5, 0.5], [2.5, 2.5], [4.5, 4.5]];
        assert_eq!(Spans::new(&q, (-10, 10), (-10, 10)).count(), 0);
    }
}
