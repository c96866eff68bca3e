//! The thesis' scan-line sampler: one sample per grid column whose centre lies inside the
//! triangle projected along its dominant normal axis, in the voxel that holds the plane
//! point above that centre; EQ 17 areas (triangle area / the triangle's sample count).
//!
//! A triangle is rasterized row by row: each row's run of inside column centres comes from
//! the three edges (a division per edge and row, nothing per column), so the triangle's
//! sample count is a sum over rows, and a slab's call visits only the columns of its own
//! voxels. Counting and emitting read the same spans, so every slab divides by the same
//! count and the slabs' samples partition the triangle's.

use super::keys::{offset_reach, up_f32, KeyPack, Rec, RecSink};
use super::shade::{face_axes, has_plane, near_face, shade_color, unit_or, Mat, Planes, Tri};
use super::texture::Tex;
use crate::mesh::AlphaMode;
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
                // Selects rather than `f64::max`/`min` (no NaN fix-ups): a NaN bound is
                // skipped all the same.
                Edge::Lower { a0, b0, da, db } => {
                    let v = b0 + (a - a0) * db / da;
                    lo = if v > lo { v } else { lo };
                }
                Edge::Upper { a0, b0, da, db } => {
                    let v = b0 + (a - a0) * db / da;
                    hi = if v < hi { v } else { hi };
                }
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

    /// `b − o` as the planes take it.
    #[inline(always)]
    fn db(&self, b: f64) -> f32 {
        (b - self.planes.o[1]) as f32
    }

    /// The unit normal at `db` ([`RowShade::db`]) on the row.
    #[inline(always)]
    fn normal(&self, db: f32) -> [f32; 3] {
        let p = self.planes;
        match p.flat_n {
            Some(n) => n,
            None => near_face(unit_or(self.n.each_ref().map(|r| r[0] + r[1] * db), p.face_n), p.face_n),
        }
    }
}

/// The shading of a row's column centres: [`RowShade`] for any material, or a copy of it
/// specialised to a common one (chosen once per triangle, so the sample loop carries no
/// material branches). Every implementation gives [`Planes::shade`]'s values bit for bit.
trait ColumnShade {
    /// Moves to the row through `a`.
    fn row(&mut self, a: f64);
    /// (colour or `None` = dropped by alpha, unit normal) at `b` on the row.
    fn at(&self, b: f64) -> (Option<[f32; 4]>, [f32; 3]);
}

impl ColumnShade for RowShade<'_, '_> {
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

    #[inline(always)]
    fn at(&self, b: f64) -> (Option<[f32; 4]>, [f32; 3]) {
        let p = self.planes;
        let db = self.db(b);
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
        (c, self.normal(db))
    }
}

/// A colour that is the same all over the triangle and kept by alpha ([`Planes`]' `flat_c`;
/// untextured meshes).
struct FlatColour<'p, 'm> {
    rows: RowShade<'p, 'm>,
    c: [f32; 4],
}

impl ColumnShade for FlatColour<'_, '_> {
    #[inline]
    fn row(&mut self, a: f64) {
        self.rows.row(a);
    }

    #[inline(always)]
    fn at(&self, b: f64) -> (Option<[f32; 4]>, [f32; 3]) {
        (Some(self.c), self.rows.normal(self.rows.db(b)))
    }
}

/// An opaque material with one colour texture, untransformed and with decoded texels, and
/// a vertex colour shared by the corners (textured OBJ and most textured glTF):
/// [`shade_color`] and [`Tex::sample`] without their material branches, base × vertex
/// colour taken once per triangle (the same product).
struct TexturedOpaque<'p, 'm> {
    rows: RowShade<'p, 'm>,
    tex: Tex<'m>,
    /// The texture's decoded texels.
    lin: &'m [[f32; 4]],
    /// `base[k] · vc[k]`.
    tint: [f32; 4],
}

impl<'p, 'm> TexturedOpaque<'p, 'm> {
    /// The specialisation for `planes`, when their material and triangle fit it.
    fn new(planes: &'p Planes<'m>) -> Option<Self> {
        let mat = planes.mat;
        let (Some(tex), None, AlphaMode::Opaque, Some(vc), None) = (mat.tex, &mat.alpha_tex, mat.alpha, planes.vc, planes.flat_c) else {
            return None;
        };
        let lin = tex.img.linear.filter(|_| tex.plain)?;
        Some(TexturedOpaque { rows: RowShade::new(planes), tex, lin, tint: std::array::from_fn(|k| mat.base[k] * vc[k]) })
    }
}

impl ColumnShade for TexturedOpaque<'_, '_> {
    #[inline]
    fn row(&mut self, a: f64) {
        self.rows.row(a);
    }

    #[inline(always)]
    fn at(&self, b: f64) -> (Option<[f32; 4]>, [f32; 3]) {
        let db = self.rows.db(b);
        let uv = self.rows.uv.each_ref().map(|r| r[0] + r[1] * db);
        // `Tex::sample` of an untransformed binding with decoded texels.
        let s = self.tex.interior_in(self.lin, uv).unwrap_or_else(|| self.tex.sample(uv));
        // Opaque: alpha is 1 whatever the texel's.
        let c = [self.tint[0] * s[0], self.tint[1] * s[1], self.tint[2] * s[2], 1.0];
        (Some(c), self.rows.normal(db))
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
    if !has_plane(fnrm, d) {
        return 0;
    }
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
    // Small triangles (most of them) are rasterized once: counting keeps their spans. 128
    // rows: dense textured meshes' triangles (about 65 rows at spot 4.5e-4, over ~5 slabs)
    // fit too (32 → 128: −1.8 % instructions there; the 2 KiB clear is cheap).
    let mut kept = [(0i64, 0i64); 128];
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
    if total == 0 {
        let cen: [f64; 3] = std::array::from_fn(|k| (t.p[0][k] + t.p[1][k] + t.p[2][k]) / 3.0);
        let key: [i64; 3] = std::array::from_fn(|k| floor_i64(cen[k]).clamp(cells[k].0, cells[k].1));
        if !in_slab(key[0]) {
            return 0;
        }
        return match planes.shade([cen[a], cen[b]]) {
            (Some(color), normal) => {
                // The sample stands for the whole triangle: at its centroid, reaching its corners.
                let reach = t.p.iter().map(|p| norm([p[0] - cen[0], p[1] - cen[1], p[2] - cen[2]])).fold(0.0, f64::max);
                let v = kp.clamp(key);
                let (off, r) = offset_reach(cen, v, reach);
                out.push(Rec { key: kp.pack_in_range(v), area: area as f32, normal, color, off, r });
                0
            }
            (None, _) => 1,
        };
    }
    let each = (area / total as f64) as f32;
    // Depth plane through corner 0: depth = p0 + ga·(a − a0) + gb·(b − b0).
    let (ga, gb) = (-fnrm[a] / fnrm[D], -fnrm[b] / fnrm[D]);
    // A sample stands for its column's square lifted onto the plane, centred on the plane
    // point above the column centre: its corners lie √(½ + (depth change to a corner)²) away.
    let half = 0.5 * (ga.abs() + gb.abs());
    let rows = TriRows::<D> {
        spans: &spans,
        kept: &kept,
        kp,
        keep,
        depth_cells: (klo, khi),
        ga,
        gb,
        p0: t.p[0],
        each,
        reach: (0.5 + half * half).sqrt(),
        // Most triangles lie in one slab: no row needs cutting to it.
        whole_in_slab: in_slab(cells[0].0) && in_slab(cells[0].1),
        fast: FastKeys::new::<D>(t, fnrm, kp, (klo, khi)),
    };
    if let Some(Some(c)) = planes.flat_c {
        rows.emit(FlatColour { rows: RowShade::new(&planes), c }, out)
    } else if let Some(tex) = TexturedOpaque::new(&planes) {
        rows.emit(tex, out)
    } else {
        rows.emit(RowShade::new(&planes), out)
    }
}

/// `1.5·2^52`: adding it to an `f64` of magnitude below 2^51 rounds that to an integer, which
/// then sits in the low bits of the sum's representation.
const ROUND_MAGIC: f64 = 6_755_399_441_055_744.0;

/// `floor(x) + ROUND_MAGIC.to_bits()` (wrapping) for `|x| < 2^50`: the floor without the
/// saturation and NaN fix-ups of an `as i64` conversion (which this range never needs); and
/// the floor as an `f64`.
#[inline(always)]
fn floor_biased(x: f64) -> (u64, f64) {
    let z = x + ROUND_MAGIC;
    // `z − ROUND_MAGIC` is exact: `x` rounded to an integer, one above the floor when `x`
    // was rounded up.
    let r = z - ROUND_MAGIC;
    let up = r > x;
    (z.to_bits().wrapping_sub(u64::from(up)), r - f64::from(u8::from(up)))
}

/// Largest magnitude of a voxel index or coordinate (grid units) for [`FastKeys`]: column
/// centres `ib + ½` and depths stay exact, finite, and in [`floor_biased`]'s range.
const FAST_LIMIT: f64 = (1u64 << 50) as f64;

/// [`KeyPack::pack`] of a row's samples as a running sum: the key of `(ia, ib, depth)` is a
/// row part plus `ib` and the biased depth floor shifted into their fields (wrapping), with
/// no clamps per sample. Valid because every index is already in the key range (rows and
/// columns are clamped to it by [`Spans`], the depth by clamping its float to the triangle's
/// depth cells intersected with the key range), and all values are small enough for exact
/// column centres and [`floor_biased`]. `None` (the exact per-sample path) otherwise.
struct FastKeys {
    /// Minus the b field's and the biased depth field's zero points (wrapping).
    offset: u64,
    shift_b: u32,
    shift_d: u32,
    /// The depth cells `klo..=khi` within the key range, as `[klo, khi + ½]`: clamping the
    /// depth to these before the floor equals clamping the floor to `klo..=khi`.
    lo: f64,
    hi: f64,
}

impl FastKeys {
    fn new<const D: usize>(t: &Tri, fnrm: [f64; 3], kp: &KeyPack, (klo, khi): (i64, i64)) -> Option<FastKeys> {
        let b = (D + 2) % 3;
        let small = |v: f64| v.abs() < FAST_LIMIT;
        let key_range_small = (0..3).all(|k| small(kp.lo[k] as f64) && small(kp.hi[k] as f64));
        // |fnrm[D]| is the largest component: the depth slopes are at most 1 in magnitude,
        // so depths along the (small) rows stay small and finite.
        let plane_small = t.p.iter().flatten().all(|&v| small(v)) && fnrm[D].is_finite() && fnrm[D] != 0.0;
        if !(key_range_small && plane_small && klo <= khi) {
            return None;
        }
        // Clamping to `klo..=khi` and then to the key range is clamping to these.
        let cells = [klo, khi].map(|k| k.max(kp.lo[D]).min(kp.hi[D]));
        let (shift_b, shift_d) = (kp.shift(b), kp.shift(D));
        let depth_zero = (ROUND_MAGIC.to_bits() as i64).wrapping_add(kp.lo[D]) as u64;
        let offset = 0u64.wrapping_sub((kp.lo[b] as u64) << shift_b).wrapping_sub(depth_zero << shift_d);
        Some(FastKeys { offset, shift_b, shift_d, lo: cells[0] as f64, hi: cells[1] as f64 + 0.5 })
    }

    /// The depth field of a key for `depth` (not NaN): its voxel clamped to the triangle's
    /// depth cells and the key range, biased by `ROUND_MAGIC` (which `offset` takes back).
    #[inline(always)]
    fn depth_field(&self, depth: f64) -> u64 {
        self.depth_cell(depth).0
    }

    /// [`FastKeys::depth_field`] and the index of that voxel as an `f64`.
    #[inline(always)]
    fn depth_cell(&self, depth: f64) -> (u64, f64) {
        let depth = if depth < self.lo { self.lo } else { depth };
        let depth = if depth > self.hi { self.hi } else { depth };
        let (biased, floor) = floor_biased(depth);
        (biased << self.shift_d, floor)
    }
}

/// One triangle's rows as a slab's call emits them ([`scanline_axis`], depth axis `D`).
struct TriRows<'s, 'k, const D: usize> {
    spans: &'s Spans,
    /// The spans of the first rows, kept by the count.
    kept: &'s [(i64, i64)],
    kp: &'k KeyPack,
    keep: (i64, i64),
    /// The depth voxels a point of the triangle can lie in.
    depth_cells: (i64, i64),
    ga: f64,
    gb: f64,
    p0: [f64; 3],
    /// EQ 17 area of a sample.
    each: f32,
    /// How far a sample's piece (its column's square on the plane) reaches from its point.
    reach: f64,
    whole_in_slab: bool,
    fast: Option<FastKeys>,
}

impl<const D: usize> TriRows<'_, '_, D> {
    /// A sample's offset and radius for its plane point at depth `depth` in depth voxel `k`
    /// (the column centre's offsets are exactly 0 where [`FastKeys`] apply).
    #[inline(always)]
    fn depth_offset(&self, depth: f64, k: f64) -> ([f32; 3], f32) {
        let o = depth - k - 0.5;
        let o32 = o as f32;
        let mut off = [0.0; 3];
        off[D] = o32;
        (off, up_f32(self.reach + (f64::from(o32) - o).abs()))
    }

    /// Emits the slab's samples row by row, shaded by `shade`; returns the number dropped
    /// by alpha.
    fn emit<S: RecSink>(&self, shade: impl ColumnShade, out: &mut S) -> u64 {
        let (a, b) = ((D + 1) % 3, (D + 2) % 3);
        // Every key lies between those of the corners of the box of rows, columns and depth
        // cells (a key is monotone in each coordinate): when both go to one buffer, all do.
        let corner = |row: i64, col: i64, depth: i64| {
            let mut k = [0i64; 3];
            (k[a], k[b], k[D]) = (row, col, depth);
            self.kp.pack(k)
        };
        let (rows, cols, depth) = (self.spans.rows, self.spans.cols, self.depth_cells);
        match out.run(corner(rows.0, cols.0, depth.0), corner(rows.1, cols.1, depth.1)) {
            Some(run) => self.emit_rows(shade, run),
            None => self.emit_rows(shade, out),
        }
    }

    /// [`Self::emit`] once the triangle is known to cross buffers (or not).
    fn emit_rows<S: RecSink>(&self, mut shade: impl ColumnShade, out: &mut S) -> u64 {
        let (a, b) = ((D + 1) % 3, (D + 2) % 3);
        let (kp, keep, p0, (ga, gb)) = (self.kp, self.keep, self.p0, (self.ga, self.gb));
        let (klo, khi) = self.depth_cells;
        let spans = self.spans;
        let mut dropped = 0;
        let mut rows = spans.rows;
        if a == 0 {
            rows = (rows.0.max(keep.0), rows.1.min(keep.1));
        }
        for ia in rows.0..=rows.1 {
            let (mut first, mut last) =
                usize::try_from(ia.abs_diff(spans.rows.0)).ok().and_then(|i| self.kept.get(i)).copied().unwrap_or_else(|| spans.row(ia));
            if first > last {
                continue;
            }
            let ca = ia as f64 + 0.5;
            let drow = p0[D] + ga * (ca - p0[a]);
            // The same expression (and so the same voxel) in every slab's call.
            let depth_key = |ib: i64| floor_i64(drow + gb * ((ib as f64 + 0.5) - p0[b])).clamp(klo, khi);
            if b == 0 {
                (first, last) = (first.max(keep.0), last.min(keep.1));
            } else if D == 0 && !self.whole_in_slab {
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
            let Some(f) = &self.fast else {
                for ib in first..=last {
                    let mut key = [0i64; 3];
                    key[a] = ia;
                    key[b] = ib;
                    key[D] = depth_key(ib);
                    match shade.at(ib as f64 + 0.5) {
                        (Some(color), normal) => {
                            // The plane point above the column centre, from the voxel of its key.
                            let cb = ib as f64 + 0.5;
                            let mut p = [0.0; 3];
                            (p[a], p[b], p[D]) = (ca, cb, drow + gb * (cb - p0[b]));
                            let v = kp.clamp(key);
                            let (off, r) = offset_reach(p, v, self.reach);
                            out.push(Rec { key: kp.pack_in_range(v), area: self.each, normal, color, off, r });
                        }
                        (None, _) => dropped += 1,
                    }
                }
                continue;
            };
            // `kp.pack` of the row's first column at the zero points of the b and depth
            // fields, then those fields added per sample.
            let mut zero = [0i64; 3];
            zero[a] = ia;
            zero[b] = kp.lo[b];
            zero[D] = kp.lo[D];
            let key_b = kp.pack(zero).wrapping_add(f.offset).wrapping_add((first as u64) << f.shift_b);
            // `last − first < 2^51`.
            let n = last.abs_diff(first) + 1;
            // The depth expression of `depth_key` (never NaN here), at `ib + ½` counted in
            // f64 (exact below 2^50).
            // With the sample's offset and radius: the plane point's depth from its voxel.
            let depth = |cb: f64| {
                let depth = drow + gb * (cb - p0[b]);
                let (field, k) = f.depth_cell(depth);
                let (off, r) = self.depth_offset(depth, k);
                (field, off, r)
            };
            let row = FastRow { key_b, step: 1 << f.shift_b, cb: first as f64 + 0.5, n, each: self.each };
            // The row's keys lie between its first column at the lowest depth and its last
            // at the highest (a key is monotone in each field).
            let key_b_last = key_b.wrapping_add((n - 1) << f.shift_b);
            let (lo, hi) = (key_b.wrapping_add(f.depth_field(f.lo)), key_b_last.wrapping_add(f.depth_field(f.hi)));
            dropped += match out.run(lo, hi) {
                Some(run) => row.emit(&shade, depth, run),
                None => row.emit(&shade, depth, out),
            };
        }
        dropped
    }
}

/// A row of the fast path ([`FastKeys`]): its first column's key without the depth field,
/// the key step per column, the first column centre and the column count.
struct FastRow {
    key_b: u64,
    step: u64,
    cb: f64,
    n: u64,
    each: f32,
}

impl FastRow {
    /// Pushes the row's samples to `out` (`depth` = the depth field, offset and radius at a
    /// column centre); returns the number dropped by alpha.
    #[inline(always)]
    fn emit<S: RecSink>(self, shade: &impl ColumnShade, depth: impl Fn(f64) -> (u64, [f32; 3], f32), out: &mut S) -> u64 {
        let (mut key_b, mut cb, mut dropped) = (self.key_b, self.cb, 0);
        for _ in 0..self.n {
            match shade.at(cb) {
                (Some(color), normal) => {
                    let (field, off, r) = depth(cb);
                    out.push(Rec { key: key_b.wrapping_add(field), area: self.each, normal, color, off, r });
                }
                (None, _) => dropped += 1,
            }
            key_b = key_b.wrapping_add(self.step);
            cb += 1.0;
        }
        dropped
    }
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
        let key_fields = |r: &Rec| (r.key, r.area.to_bits(), r.normal.map(f32::to_bits), r.color.map(f32::to_bits), r.off.map(f32::to_bits), r.r.to_bits());
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

    /// `floor_biased` is the floor over its whole range: integers, halves, their neighbours,
    /// ±0, the ends of the range and random values of every magnitude.
    #[test]
    fn floor_biased_is_the_floor() {
        let mut rng = sct_format::rng::SplitMix64(31);
        let mut xs = vec![0.0, -0.0, FAST_LIMIT.next_down(), -FAST_LIMIT.next_down(), 0.5, -0.5];
        for i in -40i64..=40 {
            let x = i as f64 * 0.5;
            xs.extend([x, x.next_up(), x.next_down()]);
        }
        for _ in 0..200_000 {
            let x = (rng.next_f64() * 2.0 - 1.0) * 2f64.powi((rng.next_u64() % 51) as i32);
            xs.extend([x, x.floor(), x.floor().next_down()]);
        }
        for x in xs {
            assert_eq!(floor_biased(x).0.wrapping_sub(ROUND_MAGIC.to_bits()) as i64, floor_i64(x), "{x:e}");
            assert_eq!(floor_biased(x).1, x.floor(), "{x:e}");
        }
    }

    /// The depth field clamps like the exact path: the floor clamped to the triangle's
    /// depth cells, then to the key range (cells inside, across and beyond it; depths far
    /// outside the cells, on their edges and at half voxels).
    #[test]
    fn depth_field_clamps_like_the_exact_path() {
        let mut rng = sct_format::rng::SplitMix64(41);
        let kp = KeyPack::new([-50.0; 3], [50.0; 3]).expect("keys");
        let t = Tri { p: [[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], n: [[0.0; 3]; 3], c: [[1.0; 4]; 3], uv: [[0.0; 2]; 3], uv2: [[0.0; 2]; 3] };
        let fnrm = [0.0, 0.0, 1.0];
        for _ in 0..20_000 {
            let klo = (rng.next_u64() % 140) as i64 - 70;
            let khi = klo + (rng.next_u64() % 6) as i64;
            let f = FastKeys::new::<2>(&t, fnrm, &kp, (klo, khi)).expect("fast");
            let x = klo as f64 - 3.0 + rng.next_f64() * ((khi - klo) as f64 + 6.0);
            for x in [x, x.floor(), x.floor().next_down(), x.floor() + 0.5, (khi + 1) as f64, (khi + 1) as f64 - 0.5, (khi + 1) as f64 - 0.25, (klo as f64).next_down()] {
                let want = floor_i64(x).clamp(klo, khi).clamp(kp.lo[2], kp.hi[2]);
                let got = f.depth_field(x).wrapping_sub(ROUND_MAGIC.to_bits()) as i64;
                assert_eq!(got, want, "{x} in {klo}..={khi}");
                assert_eq!(f.depth_cell(x).1, want as f64, "{x} in {klo}..={khi}");
            }
        }
    }

    /// A whole triangle's samples by the definitions, column by column: the depth voxel from
    /// `floor_i64` clamped to the triangle's cells, `KeyPack::pack` with its clamps, and
    /// `Planes::shade` — the emission's reference (test only). `None` for a triangle without
    /// column centres; else the records and the number dropped by alpha.
    fn reference(t: &Tri, mat: &Mat, kp: &KeyPack) -> Option<(Vec<Rec>, u64)> {
        let (fnrm, d, a, b) = face_axes(t);
        let q = t.p.map(|p| [p[a], p[b]]);
        let spans = Spans::new(&q, (kp.lo[a], kp.hi[a]), (kp.lo[b], kp.hi[b]));
        let total = spans.count();
        if total == 0 {
            return None;
        }
        let planes = Planes::new(t, &q, fnrm, mat);
        let (lo, hi) = t.p.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), p| (l.min(p[d]), h.max(p[d])));
        let (ga, gb, p0) = (-fnrm[a] / fnrm[d], -fnrm[b] / fnrm[d], t.p[0]);
        let each = (0.5 * norm(fnrm) / total as f64) as f32;
        let reach = (0.5 + (0.5 * (ga.abs() + gb.abs())).powi(2)).sqrt();
        let (mut recs, mut dropped) = (Vec::new(), 0);
        for ia in spans.rows.0..=spans.rows.1 {
            let (first, last) = spans.row(ia);
            let ca = ia as f64 + 0.5;
            let drow = p0[d] + ga * (ca - p0[a]);
            for ib in first..=last {
                let cb = ib as f64 + 0.5;
                let mut key = [0; 3];
                (key[a], key[b]) = (ia, ib);
                let depth = drow + gb * (cb - p0[b]);
                key[d] = floor_i64(depth).clamp(floor_i64(lo), floor_i64(hi));
                // At the plane point above the column centre, from the voxel of the key.
                let mut p = [0.0; 3];
                (p[a], p[b], p[d]) = (ca, cb, depth);
                let (off, r) = offset_reach(p, kp.clamp(key), reach);
                match planes.shade([ca, cb]) {
                    (Some(color), normal) => recs.push(Rec { key: kp.pack(key), area: each, normal, color, off, r }),
                    (None, _) => dropped += 1,
                }
            }
        }
        Some((recs, dropped))
    }

    /// The emission (running keys, float-clamped depth floors, specialised shading) gives the
    /// reference's records bit for bit and in its order: random triangles in every
    /// orientation, flat and varying normals and colours, opaque textures (plain and
    /// transformed, coordinates inside and beyond the image), blended, masked and
    /// alpha-textured materials; and with a key range too large for the running keys, where
    /// the exact per-sample path runs (also for corners beyond 2^50).
    #[test]
    fn rows_match_the_per_sample_definition() {
        use super::super::slabs::SlabParts;
        use super::super::texture::{decode_textures, TexImage};
        use crate::mesh::{Image, LoadedScene, Material, TextureRef, Wrap};
        let mut rng = sct_format::rng::SplitMix64(37);
        let (w, h) = (9u32, 6u32);
        let rgba: Vec<[u8; 4]> = (0..w * h).map(|_| std::array::from_fn(|_| (rng.next_u64() >> 56) as u8)).collect();
        let plain = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let tr = |transform| TextureRef { image: 0, tex_coord: 0, transform, wrap_s: Wrap::Repeat, wrap_t: Wrap::MirroredRepeat };
        let scene = LoadedScene {
            images: vec![Image { width: w, height: h, rgba, source: "test".into() }],
            materials: vec![Material { texture: Some(tr(plain)), ..Default::default() }],
            ..Default::default()
        };
        let linear = decode_textures(&scene);
        let img = TexImage { img: &scene.images[0], linear: linear[0].as_deref() };
        let (tr_plain, tr_moved) = (tr(plain), tr([[0.5, 0.1, 0.25], [0.0, 0.7, 0.1]]));
        let tex = |r| Some(Tex::new(img, r));
        let base = [0.9, 0.8, 0.7, 0.6];
        let mats = [
            Mat { base, tex: None, alpha_tex: None, alpha: AlphaMode::Opaque },
            Mat { base, tex: tex(&tr_plain), alpha_tex: None, alpha: AlphaMode::Opaque },
            Mat { base, tex: tex(&tr_moved), alpha_tex: None, alpha: AlphaMode::Opaque },
            Mat { base, tex: tex(&tr_plain), alpha_tex: None, alpha: AlphaMode::Blend },
            Mat { base, tex: tex(&tr_plain), alpha_tex: None, alpha: AlphaMode::Mask(0.4) },
            Mat { base, tex: None, alpha_tex: tex(&tr_plain), alpha: AlphaMode::Mask(0.3) },
        ];
        let small = KeyPack::new([-80.0; 3], [80.0; 3]).expect("keys");
        let huge = KeyPack::new([-1e16, -6.0, -6.0], [1e16, 6.0, 6.0]).expect("keys");
        let bits = |r: &Rec| (r.key, r.area.to_bits(), r.normal.map(f32::to_bits), r.color.map(f32::to_bits), r.off.map(f32::to_bits), r.r.to_bits());
        let (mut fast, mut exact, mut dropped_any, mut compared) = (0, 0, 0, 0);
        let (mut one_part, mut many_parts) = (0, 0);
        for i in 0..6000 {
            let mat = &mats[i % mats.len()];
            let (kp, o, scale): (&KeyPack, [f64; 3], f64) = if i % 5 == 4 {
                let far = if i % 2 == 0 { 2f64.powi(51) } else { 1000.5 };
                (&huge, [far + rng.next_f64() * 100.0, rng.next_f64() * 6.0 - 4.0, rng.next_f64() * 6.0 - 4.0], 1.5)
            } else {
                (&small, std::array::from_fn(|_| rng.next_f64() * 80.0 - 40.0), [0.8, 4.0, 30.0][i % 3])
            };
            let p: [[f64; 3]; 3] = std::array::from_fn(|_| std::array::from_fn(|k| o[k] + rng.next_f64() * scale));
            let flat_n = i % 7 == 0;
            let n0: [f32; 3] = std::array::from_fn(|_| rng.next_f64() as f32 - 0.5);
            let n = std::array::from_fn(|_| if flat_n { n0 } else { std::array::from_fn(|_| rng.next_f64() as f32 - 0.5) });
            let shared_c = i % 3 != 0;
            let c0 = [0.5, 0.25, 1.0, 0.75];
            let c = std::array::from_fn(|_| if shared_c { c0 } else { std::array::from_fn(|_| rng.next_f64() as f32) });
            let uv = std::array::from_fn(|_| [(rng.next_f64() * 1.4 - 0.2) as f32, (rng.next_f64() * 1.4 - 0.2) as f32]);
            let t = Tri { p, n, c, uv, uv2: uv };
            let Some((want, want_dropped)) = reference(&t, mat, kp) else {
                continue;
            };
            let (fnrm, d, _, _) = face_axes(&t);
            let cells = t.p.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), p| (l.min(p[d]), h.max(p[d])));
            let cells = (floor_i64(cells.0), floor_i64(cells.1));
            let takes_fast = match d {
                0 => FastKeys::new::<0>(&t, fnrm, kp, cells).is_some(),
                1 => FastKeys::new::<1>(&t, fnrm, kp, cells).is_some(),
                _ => FastKeys::new::<2>(&t, fnrm, kp, cells).is_some(),
            };
            assert_eq!(takes_fast, std::ptr::eq(kp, &small));
            (fast, exact) = if takes_fast { (fast + 1, exact) } else { (fast, exact + 1) };
            let mut got = Vec::new();
            let got_dropped = scanline_triangle(&t, mat, kp, (i64::MIN, i64::MAX), &mut got);
            assert_eq!(got_dropped, want_dropped, "{p:?}");
            assert_eq!(got.iter().map(bits).collect::<Vec<_>>(), want.iter().map(bits).collect::<Vec<_>>(), "{p:?} material {}", i % mats.len());
            dropped_any += u32::from(got_dropped > 0);
            compared += got.len();
            // Straight into slab parts (whole triangles or rows at a time when they fall in
            // one part) equals record by record.
            let (mut direct, mut one_by_one) = (SlabParts::default(), SlabParts::default());
            for parts in [&mut direct, &mut one_by_one] {
                parts.reset(kp, (kp.lo[0], kp.hi[0]), 2.0e6);
            }
            scanline_triangle(&t, mat, kp, (i64::MIN, i64::MAX), &mut direct);
            one_by_one.extend(&got);
            let by_part = |sp: &SlabParts| sp.parts.iter().map(|p| p.iter().map(bits).collect::<Vec<_>>()).collect::<Vec<_>>();
            assert_eq!(by_part(&direct), by_part(&one_by_one), "{p:?}");
            let used = direct.parts.iter().filter(|p| !p.is_empty()).count();
            (one_part, many_parts) = (one_part + u32::from(used == 1), many_parts + u32::from(used > 1));
        }
        assert!(fast > 2000 && exact > 300 && dropped_any > 500 && compared > 50_000, "{fast} {exact} {dropped_any} {compared}");
        assert!(one_part > 500 && many_parts > 500, "{one_part} {many_parts}");
    }

    /// Triangles that project to a line have no spans (they get the centroid sample).
    #[test]
    fn flat_projection_has_no_spans() {
        let q = [[0.5, 0.5], [2.5, 2.5], [4.5, 4.5]];
        assert_eq!(Spans::new(&q, (-10, 10), (-10, 10)).count(), 0);
    }
}
