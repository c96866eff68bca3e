//! The voxel method's triangle rasterizer: exact triangle ∩ voxel pieces, swept strip by
//! strip and column by column in the projection plane.

use crate::mesh::*;

use super::clip::{ping, Poly2, MAXV};
use super::keys::{offset_reach, KeyPack, Rec};
use super::shade::{face_axes, has_plane, Mat, Planes, Tri};
use super::AreaMode;

/// Every voxel x index (no slab restriction).
pub(super) const ALL_X: (i64, i64) = (i64::MIN, i64::MAX);

/// Emits the samples of one triangle of [`voxel_triangle_axis`] (depth axis `D`): a struct
/// rather than a closure so that its always-inlined call sites need no argument passing.
pub(super) struct Emitter<'p, 'm, const D: usize> {
    planes: &'p Planes<'m>,
    kp: &'p KeyPack,
    keep: (i64, i64),
    ascale: f64,
    dropped: u64,
    skipped: u64,
    /// The triangle's depth plane `[d0, ga, gb]`: depth = d0 + ga·a + gb·b.
    depth: [f64; 3],
    /// Pieces whose colour varies are sampled at half the voxel ([`Emitter::quarters`]).
    fine: bool,
}

impl<const D: usize> Emitter<'_, '_, D> {
    /// The piece of projected area `area2` and centroid `cen` (at depth `dc`: the centroid of
    /// the piece itself lies above the centroid of its projection) in voxel (ia, ib, k) along
    /// axes (D + 1, D + 2, D), lying within `reach` of its centroid.
    ///
    /// A piece whose colour varies by more than [`FINE_SPREAD`] (a texture or vertex colours
    /// with detail at the voxel's scale: lines, text) is emitted as its four quarters (the
    /// piece cut by the voxel's mid-planes across the projection plane), each a record of
    /// its own at its own centroid with its own colour, marked to be merged only with fine
    /// records of the same octant: the surface there is sampled at half the voxel.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn emit(&mut self, out: &mut Vec<Rec>, ia: i64, ib: i64, k: i64, area2: f64, cen: [f64; 2], dc: f64, reach: f64, piece: Piece) {
        let mut key = [0i64; 3];
        key[(D + 1) % 3] = ia;
        key[(D + 2) % 3] = ib;
        key[D] = k;
        if self.keep != ALL_X && !(self.keep.0..=self.keep.1).contains(&key[0].clamp(self.kp.lo[0], self.kp.hi[0])) {
            self.skipped += 1;
            return;
        }
        match self.planes.shade(cen) {
            (Some(color), normal) => {
                // The key range holds every piece with a voxel to spare, so the clamp leaves
                // the voxel as it is; the offset is taken from the voxel of the key all the same.
                let v = self.kp.clamp(key);
                let color = if self.planes.flat_c.is_some() {
                    color
                } else {
                    let (mean, spread) = piece_color(self.planes, cen, color, piece);
                    if spread > FINE_SPREAD && self.fine && self.quarters(out, v, ia, ib, piece) {
                        return;
                    }
                    mean
                };
                self.push(out, v, area2, cen, dc, reach, normal, color, false);
            }
            // The centroid is dropped by alpha, but the edge of an alpha-textured decal may
            // cross the piece: its kept part is sampled by quarters.
            (None, _) => {
                if !(self.fine && self.planes.flat_c.is_none() && any_kept(self.planes, cen, piece) && self.quarters(out, self.kp.clamp(key), ia, ib, piece)) {
                    self.dropped += 1;
                }
            }
        }
    }

    /// A record of voxel `v` (in the key range) for the piece of projected area `area2` and
    /// centroid `cen` at depth `dc` lying within `reach` of it; `fine` marks a quarter.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn push(&self, out: &mut Vec<Rec>, v: [i64; 3], area2: f64, cen: [f64; 2], dc: f64, reach: f64, normal: [f32; 3], color: [f32; 4], fine: bool) {
        let mut p = [0.0; 3];
        (p[(D + 1) % 3], p[(D + 2) % 3], p[D]) = (cen[0], cen[1], dc);
        let (off, r) = offset_reach(p, v, reach);
        let area = (area2 * self.ascale) as f32;
        out.push(Rec { key: self.kp.pack_in_range(v), area: if fine { -area } else { area }, normal, color, off, r });
    }

    /// Emits the quarters of a piece of voxel `v` (column `ia`, `ib`) whose colour varies:
    /// the piece cut at the column's mid-lines, each part with area a record at its own
    /// centroid, reaching its own vertices, coloured as [`piece_color`] colours it (the
    /// centroid's alpha deciding, as for any piece). False (nothing emitted) when the piece
    /// has too many vertices to cut without overflowing a polygon.
    #[inline(never)]
    fn quarters(&mut self, out: &mut Vec<Rec>, v: [i64; 3], ia: i64, ib: i64, piece: Piece) -> bool {
        let mut poly = Poly2::empty();
        match piece {
            Piece::Square => poly.set_square(ia as f64, ib as f64),
            Piece::Poly(p) => poly = *p,
        }
        if poly.n + 2 > MAXV {
            return false;
        }
        let (mut lo, mut hi, mut q) = (Poly2::empty(), Poly2::empty(), [Poly2::empty(), Poly2::empty(), Poly2::empty(), Poly2::empty()]);
        poly.split_axis_into::<0>(ia as f64 + 0.5, &mut lo, &mut hi);
        let [q0, q1, q2, q3] = &mut q;
        lo.split_axis_into::<1>(ib as f64 + 0.5, q0, q1);
        hi.split_axis_into::<1>(ib as f64 + 0.5, q2, q3);
        let [d0, ga, gb] = self.depth;
        let depth = |p: &[f64; 2]| d0 + ga * p[0] + gb * p[1];
        for part in &q {
            if part.n < 3 {
                continue;
            }
            let (ar, c) = part.area_centroid();
            if !(ar > 0.0) {
                continue;
            }
            match self.planes.shade(c) {
                (Some(at_c), normal) => {
                    let dc = depth(&c);
                    let color = piece_color(self.planes, c, at_c, Piece::Poly(part)).0;
                    self.push(out, v, ar, c, dc, reach(part, c, dc, |_, p| depth(p)), normal, color, true);
                }
                (None, _) => self.dropped += 1,
            }
        }
        true
    }
}

/// The colour spread of a piece ([`piece_color`]) above which it is sampled at half the
/// voxel: the largest difference, over the red, green and blue channels, between two of
/// its five colour points, on a square-root scale of linear intensity (close to the sRGB
/// scale the preview shows: 0.15 is about 40 of 255 levels at mid grey). A texture whose
/// detail is finer than the voxel (lines, text) varies by more inside a piece; smooth
/// textures, gradients and noise of a few levels do not. Measured on the shared models
/// (foreground PSNR, worse view; samples per covered pixel): capsule 21.5 → 25.3 dB at
/// 2.9 per px (0.1: 25.7 dB, 3.1; 0.25: 23.9 dB, 2.6), DamagedHelmet 23.6 → 23.9 dB at
/// 3.7 per px (0.1: 4.1 per px), BoxTextured 25.9 → 26.3 dB.
pub(super) const FINE_SPREAD: f32 = 0.15;

/// Where a piece lies, for [`piece_color`]: the unit square of an interior column (its
/// centre is the centroid), or a polygon.
#[derive(Clone, Copy)]
pub(super) enum Piece<'a> {
    Square,
    Poly(&'a Poly2),
}

/// The mean colour of a piece whose colour varies (a texture, vertex colours): the
/// centroid's colour `at_cen` with four more points of the piece (halfway from the centroid
/// to the square's corners, or to the polygon's vertices — inside the piece, so inside the
/// triangle and its texture chart). One lookup at the centroid point-samples a texture at
/// the voxel's spacing and aliases its fine detail (thin lines break up, small text
/// scrambles); the mean over the piece is what the piece shows from afar. Points that the
/// alpha mode drops count as nothing; whether the sample is dropped stays the centroid's
/// decision. Also returns the spread of the points' colours ([`FINE_SPREAD`]).
#[inline(always)]
fn piece_color(planes: &Planes, cen: [f64; 2], at_cen: [f32; 4], piece: Piece) -> ([f32; 4], f32) {
    let mut sum = at_cen;
    let mut n = 1.0f32;
    // Square roots of the smallest and largest red, green and blue (for the spread), and the
    // smallest and largest alpha, a point the alpha mode drops counting as alpha 0: the edge
    // of a decal is detail too.
    let mut lo = [at_cen[0], at_cen[1], at_cen[2], at_cen[3]];
    let mut hi = lo;
    piece_points(cen, piece, |p| match planes.shade(p) {
        (Some(c), _) => {
            for k in 0..4 {
                sum[k] += c[k];
                lo[k] = lo[k].min(c[k]);
                hi[k] = hi[k].max(c[k]);
            }
            n += 1.0;
        }
        (None, _) => lo[3] = 0.0,
    });
    let spread = (0..3).fold(hi[3] - lo[3], |s, k| s.max(hi[k].max(0.0).sqrt() - lo[k].max(0.0).sqrt()));
    (sum.map(|x| x / n), spread)
}

/// Whether the alpha mode keeps any of the four points [`piece_color`] adds to a piece's
/// centroid.
#[inline(never)]
fn any_kept(planes: &Planes, cen: [f64; 2], piece: Piece) -> bool {
    let mut any = false;
    piece_points(cen, piece, |p| any |= planes.shade(p).0.is_some());
    any
}

/// Calls `f` with the four points of a piece that [`piece_color`] adds to its centroid
/// `cen`: halfway from the centroid to the unit square's corners, or to (at most four of)
/// the polygon's vertices.
#[inline(always)]
fn piece_points(cen: [f64; 2], piece: Piece, mut f: impl FnMut([f64; 2])) {
    match piece {
        Piece::Square => {
            for (da, db) in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)] {
                f([cen[0] + da, cen[1] + db]);
            }
        }
        Piece::Poly(poly) => {
            // At most four of the vertices, spread around the polygon.
            let m = poly.n.min(MAXV);
            let step = m.div_ceil(4).max(1);
            for v in poly.v[..m].iter().step_by(step) {
                f([0.5 * (cen[0] + v[0]), 0.5 * (cen[1] + v[1])]);
            }
        }
    }
}

/// The mean of the vertices of `poly` whose depth (`dv`, per vertex) is at least `kf`: a
/// point of the piece at or past that depth face (the piece is convex), or `None`.
#[inline]
fn upper_vertices_mean(poly: &Poly2, dv: &[f64], kf: f64) -> Option<[f64; 2]> {
    let (mut m, mut n) = ([0.0f64; 2], 0usize);
    for (p, &d) in poly.v[..poly.n].iter().zip(dv) {
        if d >= kf {
            m = [m[0] + p[0], m[1] + p[1]];
            n += 1;
        }
    }
    (n > 0).then(|| [m[0] / n as f64, m[1] / n as f64])
}

/// Largest distance from the point (`c`, depth `dc`) to the vertices of `poly` lifted onto
/// the triangle's plane (vertex `i` at depth `depth_at(i, vertex)`): a piece is convex, so
/// the ball of this radius around the point holds it.
#[inline(always)]
fn reach(poly: &Poly2, c: [f64; 2], dc: f64, depth_at: impl Fn(usize, &[f64; 2]) -> f64) -> f64 {
    let mut m = 0.0f64;
    for (i, p) in poly.v[..poly.n].iter().enumerate() {
        let (x, y, z) = (p[0] - c[0], p[1] - c[1], depth_at(i, p) - dc);
        let s = x * x + y * y + z * z;
        m = if s > m { s } else { m };
    }
    m.sqrt()
}

/// The depths of a piece's vertices (into `dv`) with their range, as
/// [`Poly2::range_keeping`], and the largest squared distance from the point (`c`, depth
/// `dc`) to the vertices lifted onto the plane, in one pass.
#[inline(always)]
fn depths_and_reach2(poly: &Poly2, depth: impl Fn(&[f64; 2]) -> f64, c: [f64; 2], dc: f64, dv: &mut [f64; MAXV]) -> (f64, f64, f64) {
    let (mut lo, mut hi, mut m) = (f64::INFINITY, f64::NEG_INFINITY, 0.0f64);
    for (p, v) in poly.v[..poly.n].iter().zip(dv.iter_mut()) {
        let d = depth(p);
        *v = d;
        (lo, hi) = (if d < lo { d } else { lo }, if d > hi { d } else { hi });
        let (x, y, z) = (p[0] - c[0], p[1] - c[1], d - dc);
        let s = x * x + y * y + z * z;
        m = if s > m { s } else { m };
    }
    (lo, hi, m)
}

/// Conservative voxelization of one triangle; returns the number of alpha-dropped samples.
///
/// Works in the projection plane (axes a, b; depth d is a linear function of them): the
/// triangle is clipped to each grid strip, then to each column of the strip, and the depth
/// range of the piece gives the voxels it crosses. Columns entirely inside the triangle —
/// most of them for triangles larger than a voxel — skip clipping: their piece is the unit
/// square. Only pieces crossing a depth boundary are split by depth lines.
///
/// Only voxels whose x index lies in `xr` (inclusive) are emitted (the caller's slab), and
/// the triangle is cut to that band first. `keep` restricts output the same way without the
/// cut: voxels outside it (x index clamped to the key range) are counted, not shaded or
/// emitted, so EQ 17 areas still divide by the whole triangle's count.
#[allow(clippy::too_many_arguments)]
pub(super) fn voxel_triangle(t: &Tri, mat: &Mat, area_mode: AreaMode, kp: &KeyPack, xr: (i64, i64), keep: (i64, i64), out: &mut Vec<Rec>) -> u64 {
    let (fnrm, d, _, _) = face_axes(t);
    if !has_plane(fnrm, d) {
        return 0;
    }
    // One copy per depth axis: the axis indices become constants (key assembly, the slab
    // tests), the arithmetic is the same.
    match d {
        0 => voxel_triangle_axis::<0>(t, fnrm, mat, area_mode, kp, xr, keep, out),
        1 => voxel_triangle_axis::<1>(t, fnrm, mat, area_mode, kp, xr, keep, out),
        _ => voxel_triangle_axis::<2>(t, fnrm, mat, area_mode, kp, xr, keep, out),
    }
}

/// [`voxel_triangle`] with depth axis `D` (`fnrm` = the face normal of [`face_axes`]).
#[allow(clippy::too_many_arguments)]
pub(super) fn voxel_triangle_axis<const D: usize>(
    t: &Tri,
    fnrm: [f64; 3],
    mat: &Mat,
    area_mode: AreaMode,
    kp: &KeyPack,
    xr: (i64, i64),
    keep: (i64, i64),
    out: &mut Vec<Rec>,
) -> u64 {
    let (d, a, b) = (D, (D + 1) % 3, (D + 2) % 3);
    let tri_area_grid = 0.5 * norm(fnrm);
    // Projected area → surface area; depth = d0 + ga·x + gb·y.
    let ascale = norm(fnrm) / fnrm[d].abs();
    let (ga, gb) = (-fnrm[a] / fnrm[d], -fnrm[b] / fnrm[d]);
    let d0 = t.p[0][d] - ga * t.p[0][a] - gb * t.p[0][b];
    let depth = |p: &[f64; 2]| d0 + ga * p[0] + gb * p[1];
    let q = t.p.map(|p| [p[a], p[b]]);
    // Edge functions e(x, y) = A x + B y + C ≥ 0 inside (orientation fixed by the sign).
    let orient = if (q[1][0] - q[0][0]) * (q[2][1] - q[0][1]) - (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]) >= 0.0 { 1.0 } else { -1.0 };
    let edges: [[f64; 3]; 3] = std::array::from_fn(|i| {
        let (p0, p1) = (q[i], q[(i + 1) % 3]);
        let (ea, eb) = (-(p1[1] - p0[1]) * orient, (p1[0] - p0[0]) * orient);
        [ea, eb, -(ea * p0[0] + eb * p0[1])]
    });
    // Attributes at a piece's centroid (inside the triangle up to rounding, so the planes
    // need no clamping).
    let planes = Planes::new(t, &q, fnrm, mat);
    let start = out.len();
    let mut em = Emitter::<D> { planes: &planes, kp, keep, ascale, dropped: 0, skipped: 0, depth: [d0, ga, gb], fine: area_mode == AreaMode::Exact };
    let mut tri = Poly2 { v: [[0.0; 2]; MAXV], n: 3 };
    tri.v[..3].copy_from_slice(&q);
    let (txlo, txhi) = t.p.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), p| (l.min(p[0]), h.max(p[0])));
    if floor_i64(txlo) < xr.0 || floor_i64(txhi) > xr.1 {
        // Only part of the triangle lies in the caller's slab: cut it to the slab's x band
        // first, so strips and columns outside it cost nothing. The band's faces are voxel
        // faces, so pieces and areas are unchanged.
        let (x0, x1) = (xr.0 as f64, xr.1 as f64 + 1.0);
        tri = match (a, b) {
            (0, _) => tri.clip_axis(0, x0, x1),
            (_, 0) => tri.clip_axis(1, x0, x1),
            _ => tri.clip_half(|p| depth(p) - x0, None).clip_half(|p| x1 - depth(p), None),
        };
        // A triangle that only touches the band (its corner or edge on the band's face) leaves
        // a polygon without area, whose pieces would be samples of area 0 in the voxels past
        // that face.
        if tri.n < 3 || !(tri.area_centroid().0 > 0.0) {
            return 0;
        }
    }
    let (alo, ahi) = tri.range(|p| p[0]);
    let mut lo_a = floor_i64(alo);
    let mut hi_a = floor_i64(ahi);
    if a == 0 {
        (lo_a, hi_a) = (lo_a.max(xr.0), hi_a.min(xr.1));
    }
    let half = 0.5 * (ga.abs() + gb.abs());
    // An interior column's piece is the unit square lifted onto the plane: its corners lie
    // √(½ + (depth change to a corner)²) from its centre, the largest change being `half`.
    let reach_interior = (0.5 + half * half).sqrt();
    const EPS: f64 = 1e-9;
    // The triangle is swept: each strip is split off the rest of the triangle (one pass, the
    // cut shared by both sides), each boundary column off the rest of its strip. Reused
    // buffers: the rest of the triangle and of the strip (ping-pong pairs), the strip, the
    // column piece, the lower depth part and a clip temporary.
    let mut rest = [tri, Poly2::empty()];
    let mut r = 0;
    let (mut col, mut lower, mut upper, mut tmp) = (Poly2::empty(), Poly2::empty(), Poly2::empty(), Poly2::empty());
    // Depths of the parts' vertices.
    let (mut dl, mut du) = ([0.0; MAXV], [0.0; MAXV]);
    // The strip is split off into `srest[0]`, where the rest of the strip starts.
    let mut srest = [Poly2::empty(), Poly2::empty()];
    for ia in lo_a..=hi_a {
        let (x0, x1) = (ia as f64, ia as f64 + 1.0);
        if x1 >= ahi {
            // The rest lies below x1: it is the strip (the split would copy it).
            srest[0] = rest[r]; // a copy: a third of a swap's moves
            rest[r].n = 0;
        } else {
            let (src, dst) = ping(&mut rest, r);
            src.split_axis_into::<0>(x1, &mut srest[0], dst);
            r ^= 1;
        }
        let strip = &srest[0];
        if strip.n < 3 {
            continue;
        }
        let (bmin, bmax) = strip.range(|p| p[1]);
        // Columns [ib, ib+1] of this strip lying inside every edge's half-plane.
        let (mut in_lo, mut in_hi) = (f64::NEG_INFINITY, f64::INFINITY);
        for e in &edges {
            let amin = (e[0] * x0).min(e[0] * x1) + e[2];
            if e[1] > 0.0 {
                in_lo = in_lo.max(-amin / e[1]);
            } else if e[1] < 0.0 {
                in_hi = in_hi.min(-amin / e[1]);
            } else if amin < 0.0 {
                in_hi = f64::NEG_INFINITY;
            }
        }
        let first_in = (in_lo + EPS).ceil();
        let last_in = (in_hi - EPS).floor() - 1.0; // last ib with ib + 1 ≤ in_hi
        let (mut blo, mut bhi) = (floor_i64(bmin), floor_i64(bmax));
        if b == 0 {
            (blo, bhi) = (blo.max(xr.0), bhi.min(xr.1));
        }
        // The rest of the strip lies above `cut` (interior columns are skipped, not split off).
        let (mut sr, mut cut) = (0, blo as f64);
        // Depths of the current piece's vertices.
        let mut dv = [0.0; MAXV];
        for ib in blo..=bhi {
            let y = ib as f64;
            let interior = y >= first_in && y <= last_in;
            let (area2, cen, dc, dmin, dmax, reach2) = if interior {
                let cen = [x0 + 0.5, y + 0.5];
                let dc = depth(&cen);
                (1.0, cen, dc, dc - half, dc + half, reach_interior * reach_interior)
            } else {
                if y > cut {
                    let (src, dst) = ping(&mut srest, sr);
                    src.clip_half_into(|p| p[1] - y, Some((1, y)), dst);
                    sr ^= 1;
                }
                if y + 1.0 >= bmax {
                    col = srest[sr];
                    srest[sr].n = 0;
                } else {
                    let (src, dst) = ping(&mut srest, sr);
                    src.split_axis_into::<1>(y + 1.0, &mut col, dst);
                    sr ^= 1;
                }
                cut = y + 1.0;
                if col.n < 3 {
                    continue;
                }
                let (ar, cen) = col.area_centroid();
                let dc = depth(&cen);
                let (dmin, dmax, reach2) = depths_and_reach2(&col, depth, cen, dc, &mut dv);
                (ar, cen, dc, dmin, dmax, reach2)
            };
            let kmin = floor_i64(dmin);
            let mut kmax = floor_i64(dmax);
            if kmax > kmin && dmax == kmax as f64 {
                kmax -= 1; // touches the next voxel's face only
            }
            if kmin == kmax {
                if d != 0 || (xr.0..=xr.1).contains(&kmin) {
                    let reach = if interior { reach_interior } else { reach2.sqrt() };
                    em.emit(out, ia, ib, kmin, area2, cen, dc, reach, if interior { Piece::Square } else { Piece::Poly(&col) });
                }
                continue;
            }
            if interior {
                col.set_square(x0, y);
            }
            let poly = &col;
            if kmax == kmin + 1 {
                // One depth face crosses the piece (the common steep case): one split gives
                // both parts. The upper part's area is the remainder, so the two areas still
                // add up to the piece's exactly; its centroid is its own (a centroid by
                // difference loses digits when the part is a sliver).
                let kf = kmax as f64;
                if interior {
                    for (v, p) in dv.iter_mut().zip(&poly.v[..poly.n]) {
                        *v = depth(p);
                    }
                }
                // The piece's vertex depths were computed once (above, or with their range).
                poly.split_values_into(&dv, kf, (&mut lower, &mut dl), (&mut upper, &mut du));
                let (al, cl) = if lower.n >= 3 { lower.area_centroid() } else { (0.0, cen) };
                let au = area2 - al;
                let keep = |k: i64| d != 0 || (xr.0..=xr.1).contains(&k);
                if al > 0.0 && keep(kmin) {
                    let dc = depth(&cl);
                    em.emit(out, ia, ib, kmin, al, cl, dc, reach(&lower, cl, dc, |i, _| dl[i]), Piece::Poly(&lower));
                }
                if au > 0.0 && keep(kmax) {
                    let (ad, cd) = if upper.n >= 3 { upper.area_centroid() } else { (0.0, cen) };
                    // An upper part without area of its own is a sliver at the depth face:
                    // `au` is then rounding left over from the lower part's area, and a
                    // centroid by difference divides by it (it put a sample of the spot's
                    // control mesh 4 voxels off its surface, with a radius of 4 voxels to
                    // reach its piece). The piece's vertices past the face stand for it.
                    let cu = if ad > 0.0 { cd } else { upper_vertices_mean(poly, &dv, kf).unwrap_or(cen) };
                    let dc = depth(&cu);
                    // A part too thin for its own polygon lies in the piece.
                    let reach = if upper.n >= 3 { reach(&upper, cu, dc, |i, _| du[i]) } else { reach(poly, cu, dc, |i, _| dv[i]) };
                    em.emit(out, ia, ib, kmax, au, cu, dc, reach, Piece::Poly(if upper.n >= 3 { &upper } else { poly }));
                }
                continue;
            }
            let (kmin, kmax) = if d == 0 { (kmin.max(xr.0), kmax.min(xr.1)) } else { (kmin, kmax) };
            for k in kmin..=kmax {
                let kf = k as f64;
                poly.clip_half_into(|p| depth(p) - kf, None, &mut tmp);
                tmp.clip_half_into(|p| kf + 1.0 - depth(p), None, &mut lower);
                let sub = &lower;
                if sub.n < 3 {
                    continue;
                }
                let (ar, cen) = sub.area_centroid();
                if ar > 0.0 {
                    let dc = depth(&cen);
                    em.emit(out, ia, ib, k, ar, cen, dc, reach(sub, cen, dc, |_, p| depth(p)), Piece::Poly(sub));
                }
            }
        }
    }
    let (dropped, skipped) = (em.dropped, em.skipped);
    let made = out.len() - start;
    if area_mode == AreaMode::Eq17 && made > 0 {
        let each = (tri_area_grid / (made as u64 + dropped + skipped) as f64) as f32;
        for r in &mut out[start..] {
            r.area = each;
        }
    }
    dropped
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::AlphaMode;

    /// Random triangles in every orientation and size (slivers, steep and flat ones, ones
    /// smaller than a voxel and ones spanning dozens, flat ones on a voxel face): every
    /// record's point lies on its triangle's plane and in its voxel, and random points of the triangle each lie in the ball of
    /// a record of their voxel (the pieces of a voxel are the triangle ∩ voxel); exact and
    /// EQ 17 areas place records alike.
    #[test]
    fn records_stand_on_their_pieces_and_reach_them() {
        let mut rng = sct_format::rng::SplitMix64(43);
        let mat = Mat { base: [0.5, 0.6, 0.7, 1.0], tex: None, alpha_tex: None, alpha: AlphaMode::Opaque };
        let kp = KeyPack::new([-70.0; 3], [70.0; 3]).expect("keys");
        let (mut checked, mut multi) = (0u64, 0u64);
        for i in 0..3000 {
            let scale = [0.3, 2.0, 9.0, 40.0][i % 4];
            let o: [f64; 3] = std::array::from_fn(|_| rng.next_f64() * 40.0 - 20.0);
            let mut p: [[f64; 3]; 3] = std::array::from_fn(|_| std::array::from_fn(|k| o[k] + rng.next_f64() * scale));
            if i % 5 == 0 {
                p[2] = std::array::from_fn(|k| p[0][k] + 1e-3 * (p[1][k] - p[0][k]) + 1e-4 * rng.next_f64()); // sliver
            }
            if i % 7 == 0 {
                let z = p[0][2].floor(); // on a voxel face
                p.iter_mut().for_each(|v| v[2] = z);
            }
            let t = Tri { p, n: [[0.0, 0.0, 1.0]; 3], c: [[1.0; 4]; 3], uv: [[0.0; 2]; 3], uv2: [[0.0; 2]; 3] };
            let fnrm = cross(sub(p[1], p[0]), sub(p[2], p[0]));
            let len = norm(fnrm);
            if !(len > 1e-9) {
                continue;
            }
            let unit = fnrm.map(|x| x / len);
            let mut exact = Vec::new();
            voxel_triangle(&t, &mat, AreaMode::Exact, &kp, ALL_X, ALL_X, &mut exact);
            let mut eq17 = Vec::new();
            voxel_triangle(&t, &mat, AreaMode::Eq17, &kp, ALL_X, ALL_X, &mut eq17);
            let place = |r: &Rec| (r.key, r.off.map(f32::to_bits), r.r.to_bits());
            assert!(exact.iter().map(place).eq(eq17.iter().map(place)));
            let point = |r: &Rec| {
                let v = kp.unpack(r.key);
                std::array::from_fn::<f64, 3, _>(|k| v[k] as f64 + 0.5 + f64::from(r.off[k]))
            };
            for r in &exact {
                let c = point(r);
                let off_plane = dot(sub(c, p[0]), unit).abs();
                // The offsets are f32: within √3·2^-25 voxel of the centroid.
                assert!(off_plane <= 6e-8, "{p:?}: record point {c:?} {off_plane:e} off the plane");
                assert!(r.off.iter().all(|&x| x.abs() <= 0.5 + 1e-6), "{p:?}: record point {c:?} outside its voxel");
            }
            multi += u64::from(exact.len() > 1);
            // Random points of the triangle.
            for _ in 0..200 {
                let (mut u, mut v) = (rng.next_f64(), rng.next_f64());
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                let q: [f64; 3] = std::array::from_fn(|k| p[0][k] + u * (p[1][k] - p[0][k]) + v * (p[2][k] - p[0][k]));
                let key = kp.pack(q.map(|x| x.floor() as i64));
                let held = exact.iter().filter(|r| r.key == key).any(|r| {
                    let c = point(r);
                    norm(sub(q, c)) <= f64::from(r.r) + 1e-9
                });
                // A point on a voxel face (to rounding) may belong to the neighbour's piece,
                // unless the whole triangle lies in that face.
                let on_face = (0..3).any(|k| (q[k] - q[k].round()).abs() < 1e-9 && !(p[0][k] == p[1][k] && p[0][k] == p[2][k]));
                assert!(held || on_face, "{p:?}: point {q:?} in no record's ball");
                checked += 1;
            }
        }
        assert!(checked > 400_000 && multi > 1500, "{checked} {multi}");
    }
}
