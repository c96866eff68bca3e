//! Turning sorted records into samples: one per surface of a voxel when merging, else one
//! per record. A voxel's records belong to one surface when their normals lie within 60° of
//! the surface's first record's normal; a box's edge, a crease or the two sides of a thin
//! part give one sample per side, each on its own side. (Averaging them would put the sample
//! between the surfaces, on neither, with a normal that shades neither.) A merged sample
//! stands at the area-weighted centroid of its records' points (the centroid of the union of
//! their pieces), with a radius that reaches every piece; areas add, normal and colour are
//! area-weighted means.

use sct_format::Node;

use crate::mesh::norm;

use super::keys::{KeyPack, Rec};
use super::shade::srgb8;

/// Appends to `out` the nodes of records in the order of `items` (record index = item &
/// `idx_mask`, in key order), merging records of one voxel when `merge`.
pub(super) fn merge_sorted(items: &[u64], idx_mask: u64, recs: &[Rec], shape: &NodeShape, merge: bool, out: &mut Vec<Node>) {
    // One copy of the loop per case: the flags do not take registers in it. Items carry
    // their keys above the index unless they are bare indices (idx_mask all ones).
    match (merge, idx_mask != u64::MAX) {
        (true, true) => merge_loop::<true, true>(items, idx_mask, recs, shape, out),
        (true, false) => merge_loop::<true, false>(items, idx_mask, recs, shape, out),
        (false, _) => merge_loop::<false, false>(items, idx_mask, recs, shape, out),
    }
}

/// What turns a voxel key and records into a node's centre, radius and area.
pub(super) struct NodeShape<'k> {
    kp: &'k KeyPack,
    h: f64,
    h2: f64,
    /// Whether every record's piece lies in its voxel (the voxel method; a scan-line sample
    /// stands for its column's piece of plane, which can leave the voxel): a merged sample's
    /// radius then need not exceed the distance to the voxel's farthest corner.
    in_voxel: bool,
    /// Added to every radius (world units): pieces are computed in grid coordinates of
    /// magnitude up to M, each vertex and centroid to within a few ulps of M, and 64 ulps of
    /// M bound how far a computed piece, centroid or centre lies from the exact one; then
    /// rounding a centre to f32 moves it by at most half an ulp of the largest coordinate
    /// per axis (a bound for the unit rather than each centre's move: a few bits of the
    /// radius, no work per sample).
    slack: f64,
}

impl<'k> NodeShape<'k> {
    /// The shape of the nodes of key range `kp` at voxel size `h`; `in_voxel` as the field.
    pub(super) fn new(kp: &'k KeyPack, h: f64, in_voxel: bool) -> Self {
        // Centres lie within a voxel of the key range (the range has a voxel to spare).
        let m: [f64; 3] = std::array::from_fn(|k| (kp.lo[k] as f64).abs().max((kp.hi[k] as f64).abs()) + 2.0);
        let pieces = m.iter().fold(0.0f64, |a, &b| a.max(b)) * (1.0 / (1u64 << 46) as f64) * h;
        // Rounding to f32 moves a value below 2^e by at most half an ulp of [2^(e−1), 2^e),
        // 2^(e−25); 2^(e−24) also covers a `log2` that rounds across a power of two.
        let moved = |x: f64| (x * h).max(f64::MIN_POSITIVE).log2().ceil().exp2() * (1.0 / (1u64 << 24) as f64);
        let centre = m.iter().map(|&x| moved(x)).sum::<f64>();
        NodeShape { kp, h, h2: h * h, in_voxel, slack: pieces + centre }
    }
}

/// [`merge_sorted`]'s loop; `KEYED`: runs of one voxel are found from the items' key bits,
/// without reading the records.
pub(super) fn merge_loop<const MERGE: bool, const KEYED: bool>(items: &[u64], idx_mask: u64, recs: &[Rec], shape: &NodeShape, out: &mut Vec<Node>) {
    let &NodeShape { kp, h, h2, in_voxel, slack } = shape;
    // Keys ascend, so neighbours mostly share x and y (the bits above z): their voxel
    // centres are taken once per (x, y) column, only z per key. (Each key field has at least
    // 1 bit and they sum to at most 64, so z's are fewer than 64: the shift is exact.)
    let z_bits = kp.bits[2] & 63;
    let z_mask = (1u64 << z_bits) - 1;
    let z_lo = kp.lo[2];
    let mut column = (u64::MAX, [0.0f64; 2]);
    // Neighbouring voxels mostly carry the same colour (always for untextured meshes without
    // vertex colours): encode a colour once for a run of equal ones (equal bits: one integer
    // compare; a colour equal as floats but not in bits, ±0, only encodes again).
    let bits = |c: [f32; 4]| c.map(f32::to_bits);
    let mut memo = (bits([f32::NAN; 4]), srgb8([f32::NAN; 4]));
    // A local vector: its length and pointer stay in registers across the loop.
    let mut nodes = std::mem::take(out);
    let mut surfaces = Surfaces::default();
    let mut fine: Vec<u64> = Vec::new();
    nodes.reserve(items.len());
    let n = items.len();
    let mut i = 0;
    while i < n {
        let it = items[i];
        let first = &recs[(it & idx_mask) as usize];
        let key = first.key;
        let mut j = i + 1;
        if MERGE {
            if KEYED {
                while j < n && (items[j] ^ it) & !idx_mask == 0 {
                    j += 1;
                }
            } else {
                while j < n && recs[items[j] as usize].key == key {
                    j += 1;
                }
            }
        }
        let hi = key >> z_bits;
        if hi != column.0 {
            let v = kp.unpack(key);
            column = (hi, [v[0] as f64 + 0.5, v[1] as f64 + 0.5]);
        }
        let voxel_centre = [column.1[0], column.1[1], ((key & z_mask) as i64 + z_lo) as f64 + 0.5];
        let mut push = |(normal, area, color, off, reach): Merged| {
            if bits(color) != memo.0 {
                memo = (bits(color), srgb8(color));
            }
            let center: [f32; 3] = std::array::from_fn(|k| ((voxel_centre[k] + off[k]) * h) as f32);
            // Rounded up: grown by 2^-22 before rounding to nearest, which takes off at most 2^-24.
            let radius = ((reach * h + slack) * (1.0 + 1.0 / (1u64 << 22) as f64)) as f32;
            nodes.push(Node { center, radius, normal, cone: 0.0, area, color: memo.1 });
        };
        if j == i + 1 {
            // The common case: nothing to merge.
            push((first.normal, (f64::from(first.area.abs()) * h2) as f32, first.color, first.off.map(f64::from), f64::from(first.r)));
        } else {
            let run = &items[i..j];
            let rec = |it: u64| &recs[(it & idx_mask) as usize];
            let mut merge_surfaces = |run: &[u64], push: &mut dyn FnMut(Merged)| {
                if run[1..].iter().all(|&it| same_surface(rec(run[0]).normal, rec(it).normal)) {
                    push(merge_run(run, idx_mask, recs, h2, in_voxel));
                } else {
                    surfaces.split(run, |it| rec(it));
                    for s in 0..surfaces.count() {
                        push(merge_run(surfaces.items(s), idx_mask, recs, h2, in_voxel));
                    }
                }
            };
            if !run.iter().any(|&it| rec(it).area.is_sign_negative()) {
                merge_surfaces(run, &mut push);
            } else {
                // Quarters of pieces whose colour varies (the voxel sampled at half its size):
                // the whole pieces merge as ever, the quarters by the octant of the voxel that
                // holds their point, in octant order.
                let octant = |r: &Rec| if r.area.is_sign_negative() { 1 + r.off.iter().enumerate().fold(0, |o, (k, &x)| o | (usize::from(x >= 0.0) << k)) } else { 0 };
                for g in 0..9 {
                    fine.clear();
                    fine.extend(run.iter().copied().filter(|&it| octant(rec(it)) == g));
                    if !fine.is_empty() {
                        merge_surfaces(&fine, &mut push);
                    }
                }
            }
        }
        i = j;
    }
    *out = nodes;
}

/// (normal, area, colour, offset, reach) of a merged sample; see [`merge_run`].
type Merged = ([f32; 3], f32, [f32; 4], [f64; 3], f64);

/// Cosine of the largest angle between the normals of two pieces of one surface.
const SAME_SURFACE_COS: f32 = 0.5;

#[inline(always)]
fn same_surface(a: [f32; 3], b: [f32; 3]) -> bool {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2] >= SAME_SURFACE_COS
}

/// A voxel's records split by surface (reused across voxels: no allocation per voxel).
#[derive(Default)]
struct Surfaces {
    /// Each surface's first normal.
    normals: Vec<[f32; 3]>,
    /// Each record's surface, in run order.
    label: Vec<u32>,
    /// The items grouped by surface, surfaces in order of first appearance.
    grouped: Vec<u64>,
    /// Where each surface's items start in `grouped` (one more entry than surfaces).
    starts: Vec<usize>,
}

impl Surfaces {
    /// Splits `run` into surfaces: a record with area joins the first surface whose first
    /// normal lies within 60° of its own, or starts one; a record without area (a piece
    /// that only touches the voxel, an edge or a corner) joins the surface nearest its
    /// normal and starts none, so slivers add no samples (unless the voxel holds nothing
    /// else). The order of `run` decides, so the split is as deterministic as the sort.
    fn split<'r>(&mut self, run: &[u64], rec: impl Fn(u64) -> &'r Rec) {
        self.normals.clear();
        self.label.clear();
        // A voxel of slivers only (a face lying on the voxel's boundary) splits them alike.
        let any_area = run.iter().any(|&it| rec(it).area.abs() > 0.0);
        for &it in run {
            let r = rec(it);
            let l = if r.area.abs() > 0.0 || !any_area {
                match self.normals.iter().position(|&n| same_surface(n, r.normal)) {
                    Some(s) => s,
                    None => {
                        self.normals.push(r.normal);
                        self.normals.len() - 1
                    }
                }
            } else {
                u32::MAX as usize
            };
            self.label.push(l as u32);
        }
        for (l, &it) in self.label.iter_mut().zip(run) {
            if *l == u32::MAX {
                let n = rec(it).normal;
                let dot = |s: &[f32; 3]| s[0] * n[0] + s[1] * n[1] + s[2] * n[2];
                let best = (0..self.normals.len()).fold(0, |b, s| if dot(&self.normals[s]) > dot(&self.normals[b]) { s } else { b });
                *l = best as u32;
            }
        }
        self.grouped.clear();
        self.starts.clear();
        for s in 0..self.normals.len() as u32 {
            self.starts.push(self.grouped.len());
            self.grouped.extend(run.iter().zip(&self.label).filter(|&(_, &l)| l == s).map(|(&it, _)| it));
        }
        self.starts.push(self.grouped.len());
    }
    fn count(&self) -> usize {
        self.normals.len()
    }
    fn items(&self, s: usize) -> &[u64] {
        &self.grouped[self.starts[s]..self.starts[s + 1]]
    }
}

/// (normal, area, colour, offset, reach) of a run of records of one voxel: the offset is
/// the area-weighted mean of the records' offsets (the centroid of their pieces), the reach
/// (voxel units) the farthest any piece lies from it, bounded by the voxel's farthest
/// corner when `in_voxel`. Its own function with its own locals; inlined: a call per run
/// measured +4 % instructions in the voxel method's merge.
#[inline(always)]
pub(super) fn merge_run(run: &[u64], idx_mask: u64, recs: &[Rec], h2: f64, in_voxel: bool) -> Merged {
    let (mut a, mut wsum, mut nn, mut c, mut o) = (0.0f64, 0.0f64, [0.0f64; 3], [0.0f64; 4], [0.0f64; 3]);
    for &it in run {
        let x = &recs[(it & idx_mask) as usize];
        // Zero-area pieces (edge slivers) still count a little so colour is defined.
        // A quarter's area carries its mark in the sign.
        let w = f64::from(x.area.abs()).max(1e-12);
        a += f64::from(x.area.abs());
        wsum += w;
        for (s, v) in nn.iter_mut().zip(x.normal) {
            *s += w * f64::from(v);
        }
        for (s, v) in c.iter_mut().zip(x.color) {
            *s += w * f64::from(v);
        }
        for (s, v) in o.iter_mut().zip(x.off) {
            *s += w * f64::from(v);
        }
    }
    let o = o.map(|x| x / wsum);
    // Each piece lies within its record's radius of the record's point.
    let mut reach = 0.0f64;
    for &it in run {
        let x = &recs[(it & idx_mask) as usize];
        let d = [0, 1, 2].map(|k| o[k] - f64::from(x.off[k]));
        reach = reach.max((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() + f64::from(x.r));
    }
    if in_voxel {
        let corner = [0, 1, 2].map(|k| 0.5 + o[k].abs());
        reach = reach.min((corner[0] * corner[0] + corner[1] * corner[1] + corner[2] * corner[2]).sqrt());
    }
    let l = norm(nn);
    let first = run.first().map_or([0.0; 3], |&it| recs[(it & idx_mask) as usize].normal);
    let normal = if l > 1e-9 * wsum { nn.map(|x| (x / l) as f32) } else { first };
    (normal, (a * h2) as f32, c.map(|x| (x / wsum) as f32), o, reach)
}

#[cfg(test)]
mod tests {
    use super::super::keys::offset_reach;
    use super::super::sort::sort_order;
    use super::*;

    /// Random records of pieces in voxels: each piece is a few points of its voxel, its record
    /// their mean with the radius reaching them all. Returns the records and their pieces
    /// (grid units).
    fn pieces(kp: &KeyPack, n: usize, seed: u64) -> (Vec<Rec>, Vec<Vec<[f64; 3]>>) {
        let mut rng = sct_format::rng::SplitMix64(seed);
        let (mut recs, mut pts) = (Vec::new(), Vec::new());
        for i in 0..n {
            let v = [(rng.next_u64() % 4) as i64, (rng.next_u64() % 5) as i64, (rng.next_u64() % 30) as i64];
            let piece: Vec<[f64; 3]> = (0..1 + i % 4).map(|_| std::array::from_fn(|k| v[k] as f64 + rng.next_f64())).collect();
            let mean: [f64; 3] = std::array::from_fn(|k| piece.iter().map(|p| p[k]).sum::<f64>() / piece.len() as f64);
            let reach = piece.iter().map(|p| (0..3).map(|k| (p[k] - mean[k]).powi(2)).sum::<f64>().sqrt()).fold(0.0, f64::max);
            let (off, r) = offset_reach(mean, v, reach);
            let c = |r: &mut sct_format::rng::SplitMix64| (r.next_u64() % 1000) as f32 / 1000.0;
            let area = if i % 7 == 0 { 0.0 } else { c(&mut rng) };
            // One surface per voxel here (normals within 60°); `surfaces_split_a_voxel` tests the split.
            recs.push(Rec { key: kp.pack(v), area, normal: [c(&mut rng) * 0.5, 0.5, 0.75], color: [c(&mut rng), 0.25, 0.5, 1.0], off, r });
            pts.push(piece);
        }
        (recs, pts)
    }

    /// Merging from keyed items (runs found from the items) and from bare indices (runs found
    /// from the records' keys) gives the same nodes; equal voxels merge, others pass through.
    /// Every node's ball holds the pieces of its records, and its centre is their records'
    /// area-weighted mean point (each record's own point when unmerged).
    #[test]
    fn merge_sorted_finds_runs_from_items_or_records() {
        let kp = KeyPack::new([0.0; 3], [4.0, 5.0, 30.0]).expect("keys");
        let (recs, pts) = pieces(&kp, 3000, 9);
        let (mut items, mut tmp) = (Vec::new(), Vec::new());
        let mask = sort_order(&recs, None, &mut items, &mut tmp);
        assert_ne!(mask, u64::MAX);
        let mut bare: Vec<u64> = (0..recs.len() as u64).collect();
        bare.sort_by_key(|&i| recs[i as usize].key);
        assert_eq!(items.iter().map(|&x| x & mask).collect::<Vec<_>>(), bare);
        let mut keys: Vec<u64> = recs.iter().map(|r| r.key).collect();
        keys.sort_unstable();
        keys.dedup();
        let voxels = keys.len();
        assert!(voxels < recs.len() / 4);
        let h = 0.1;
        for (merge, in_voxel) in [(true, true), (true, false), (false, true)] {
            let shape = NodeShape::new(&kp, h, in_voxel);
            let (mut a, mut b) = (Vec::new(), Vec::new());
            merge_sorted(&items, mask, &recs, &shape, merge, &mut a);
            merge_sorted(&bare, u64::MAX, &recs, &shape, merge, &mut b);
            assert_eq!(a.len(), if merge { voxels } else { recs.len() });
            let bits = |n: &Node| (n.center.map(f32::to_bits), n.radius.to_bits(), n.normal.map(f32::to_bits), n.area.to_bits(), n.color);
            assert_eq!(a.iter().map(bits).collect::<Vec<_>>(), b.iter().map(bits).collect::<Vec<_>>());
            // The records of each node, in item order.
            let mut groups: Vec<Vec<usize>> = Vec::new();
            for &it in &items {
                let r = (it & mask) as usize;
                match groups.last_mut() {
                    Some(g) if merge && recs[g[0]].key == recs[r].key => g.push(r),
                    _ => groups.push(vec![r]),
                }
            }
            assert_eq!(groups.len(), a.len());
            let mut corner_bound = 0;
            for (node, g) in a.iter().zip(&groups) {
                let c = node.center.map(f64::from);
                let mut far = 0.0f64;
                for p in g.iter().flat_map(|&r| &pts[r]) {
                    let d = (0..3).map(|k| (p[k] * h - c[k]).powi(2)).sum::<f64>().sqrt();
                    assert!(d <= f64::from(node.radius), "{d} > {}", node.radius);
                    far = far.max(d);
                }
                let w = |r: usize| f64::from(recs[r].area).max(1e-12);
                let v = kp.unpack(recs[g[0]].key);
                for k in 0..3 {
                    let mean = g.iter().map(|&r| w(r) * (v[k] as f64 + 0.5 + f64::from(recs[r].off[k]))).sum::<f64>() / g.iter().map(|&r| w(r)).sum::<f64>();
                    assert!((mean * h - c[k]).abs() <= 3e-7, "{mean} {c:?}");
                }
                // Tight: no larger than the records' own balls allow.
                let balls = g.iter().map(|&r| {
                    let o = (0..3).map(|k| ((v[k] as f64 + 0.5 + f64::from(recs[r].off[k])) * h - c[k]).powi(2)).sum::<f64>().sqrt();
                    o + f64::from(recs[r].r) * h
                });
                let bound = balls.fold(0.0, f64::max);
                // Up to the f32 rounding of the centre (coordinates below 3: 2^-22 each).
                assert!(f64::from(node.radius) <= bound + 1e-6, "{} > {bound}", node.radius);
                corner_bound += usize::from(f64::from(node.radius) < bound * 0.999);
            }
            assert_eq!(corner_bound > 0, merge && in_voxel, "{corner_bound} radii bounded by the voxel's corners");
        }
    }

    /// A voxel holding pieces of two perpendicular faces (a box's edge) gives one sample per
    /// face, each at its own pieces' centroid with its own normal; a zero-area sliver joins
    /// the face nearest its normal and adds no sample.
    #[test]
    fn surfaces_split_a_voxel() {
        let kp = KeyPack::new([0.0; 3], [4.0; 3]).expect("keys");
        let v = [1, 1, 1];
        let rec = |p: [f64; 3], normal: [f32; 3], area: f32| {
            let (off, r) = offset_reach(p, v, 0.1);
            Rec { key: kp.pack(v), area, normal, color: [0.5, 0.5, 0.5, 1.0], off, r }
        };
        let top = [0.0, 0.0, 1.0];
        let side = [1.0, 0.0, 0.0];
        let recs = vec![
            rec([1.5, 1.2, 2.0], top, 0.2),
            rec([2.0, 1.5, 1.5], side, 0.3),
            rec([1.5, 1.8, 2.0], top, 0.2),
            rec([2.0, 1.5, 1.9], [0.9, 0.0, 0.436], 0.0), // a sliver, nearest the side
            rec([1.7, 1.5, 2.0], [0.2, 0.0, 0.98], 0.4), // within 60° of the top
        ];
        let items: Vec<u64> = (0..recs.len() as u64).collect();
        let h = 1.0;
        let shape = NodeShape::new(&kp, h, true);
        let mut out = Vec::new();
        merge_sorted(&items, u64::MAX, &recs, &shape, true, &mut out);
        assert_eq!(out.len(), 2, "{out:?}");
        let (t, s) = (&out[0], &out[1]);
        // The top's centre is on the plane z = 2, the side's on x = 2.
        assert!((t.center[2] - 2.0).abs() < 1e-6, "{t:?}");
        assert!((s.center[0] - 2.0).abs() < 1e-6, "{s:?}");
        assert!(t.normal[2] > 0.9 && s.normal[0] > 0.9);
        assert!((t.area - 0.8).abs() < 1e-6 && (s.area - 0.3).abs() < 1e-6);
        // The sliver's point lies in the side's ball.
        let d = ((s.center[0] - 2.0).powi(2) + (s.center[1] - 1.5).powi(2) + (s.center[2] - 1.9).powi(2)).sqrt();
        assert!(d <= s.radius);
        // Without merging every record is a sample.
        merge_sorted(&items, u64::MAX, &recs, &shape, false, &mut out);
        assert_eq!(out.len(), 2 + recs.len());
    }
}
