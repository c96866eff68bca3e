//! Turning sorted records into samples: one per voxel when merging (areas add, normal and
//! colour are area-weighted means), else one per record.

use sct_format::Node;

use crate::mesh::norm;

use super::keys::{KeyPack, Rec};
use super::shade::srgb8;

/// Appends to `out` the nodes of records in the order of `items` (record index = item &
/// `idx_mask`, in key order), merging records of one voxel when `merge` (areas add;
/// normal and colour are area-weighted means).
#[allow(clippy::too_many_arguments)]
pub(super) fn merge_sorted(items: &[u64], idx_mask: u64, recs: &[Rec], kp: &KeyPack, r: f32, h: f64, h2: f64, merge: bool, out: &mut Vec<Node>) {
    // One copy of the loop per case: the flags do not take registers in it. Items carry
    // their keys above the index unless they are bare indices (idx_mask all ones).
    let shape = NodeShape { kp, r, h, h2 };
    match (merge, idx_mask != u64::MAX) {
        (true, true) => merge_loop::<true, true>(items, idx_mask, recs, &shape, out),
        (true, false) => merge_loop::<true, false>(items, idx_mask, recs, &shape, out),
        (false, _) => merge_loop::<false, false>(items, idx_mask, recs, &shape, out),
    }
}

/// What turns a voxel key and a record's area into a node's centre, radius and area.
pub(super) struct NodeShape<'k> {
    kp: &'k KeyPack,
    r: f32,
    h: f64,
    h2: f64,
}

/// [`merge_sorted`]'s loop; `KEYED`: runs of one voxel are found from the items' key bits,
/// without reading the records.
pub(super) fn merge_loop<const MERGE: bool, const KEYED: bool>(items: &[u64], idx_mask: u64, recs: &[Rec], shape: &NodeShape, out: &mut Vec<Node>) {
    let &NodeShape { kp, r, h, h2 } = shape;
    // Keys ascend, so neighbours mostly share x and y (the bits above z): their centre
    // coordinates are taken once per (x, y) column, only z per key. (Each key field has at
    // least 1 bit and they sum to at most 64, so z's are fewer than 64: the shift is exact.)
    let z_bits = kp.bits[2] & 63;
    let z_mask = (1u64 << z_bits) - 1;
    let z_lo = kp.lo[2];
    let c = |v: i64| ((v as f64 + 0.5) * h) as f32;
    let mut column = (u64::MAX, [0.0f32; 2]);
    // Neighbouring voxels mostly carry the same colour (always for untextured meshes without
    // vertex colours): encode a colour once for a run of equal ones (equal bits: one integer
    // compare; a colour equal as floats but not in bits, ±0, only encodes again).
    let bits = |c: [f32; 4]| c.map(f32::to_bits);
    let mut memo = (bits([f32::NAN; 4]), srgb8([f32::NAN; 4]));
    // A local vector: its length and pointer stay in registers across the loop.
    let mut nodes = std::mem::take(out);
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
            column = (hi, [c(v[0]), c(v[1])]);
        }
        let center = [column.1[0], column.1[1], c((key & z_mask) as i64 + z_lo)];
        if j == i + 1 {
            // The common case: nothing to merge.
            if bits(first.color) != memo.0 {
                memo = (bits(first.color), srgb8(first.color));
            }
            nodes.push(Node { center, radius: r, normal: first.normal, cone: 0.0, area: (f64::from(first.area) * h2) as f32, color: memo.1 });
        } else {
            let (normal, area, color) = merge_run(&items[i..j], idx_mask, recs, h2);
            if bits(color) != memo.0 {
                memo = (bits(color), srgb8(color));
            }
            nodes.push(Node { center, radius: r, normal, cone: 0.0, area, color: memo.1 });
        }
        i = j;
    }
    *out = nodes;
}

/// (normal, area, colour) of a run of records of one voxel (its own function with its own
/// locals; inlined: a call per run measured +4 % instructions in the voxel method's merge).
#[inline(always)]
pub(super) fn merge_run(run: &[u64], idx_mask: u64, recs: &[Rec], h2: f64) -> ([f32; 3], f32, [f32; 4]) {
    let (mut a, mut wsum, mut nn, mut c) = (0.0f64, 0.0f64, [0.0f64; 3], [0.0f64; 4]);
    for &it in run {
        let x = &recs[(it & idx_mask) as usize];
        // Zero-area pieces (edge slivers) still count a little so colour is defined.
        let w = f64::from(x.area).max(1e-12);
        a += f64::from(x.area);
        wsum += w;
        for (s, v) in nn.iter_mut().zip(x.normal) {
            *s += w * f64::from(v);
        }
        for (s, v) in c.iter_mut().zip(x.color) {
            *s += w * f64::from(v);
        }
    }
    let l = norm(nn);
    let first = run.first().map_or([0.0; 3], |&it| recs[(it & idx_mask) as usize].normal);
    let normal = if l > 1e-9 * wsum { nn.map(|x| (x / l) as f32) } else { first };
    (normal, (a * h2) as f32, c.map(|x| (x / wsum) as f32))
}

#[cfg(test)]
mod tests {
    use super::*;
    use super::super::sort::sort_order;

    /// Merging from keyed items (runs found from the items) and from bare indices (runs found
    /// from the records' keys) gives the same nodes; equal voxels merge, others pass through.
    #[test]
    fn merge_sorted_finds_runs_from_items_or_records() {
        let kp = KeyPack::new([0.0; 3], [20.0; 3]).expect("keys");
        let mut rng = sct_format::rng::SplitMix64(9);
        let recs: Vec<Rec> = (0..3000)
            .map(|i| {
                let v = |r: &mut sct_format::rng::SplitMix64| (r.next_u64() % 1000) as f32 / 1000.0;
                let key = kp.pack([(rng.next_u64() % 4) as i64, (rng.next_u64() % 5) as i64, (rng.next_u64() % 30) as i64]);
                Rec { key, area: if i % 7 == 0 { 0.0 } else { v(&mut rng) }, normal: [v(&mut rng), 0.5, -0.25], color: [v(&mut rng), 0.25, 0.5, 1.0] }
            })
            .collect();
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
        for merge in [true, false] {
            let (mut a, mut b) = (Vec::new(), Vec::new());
            merge_sorted(&items, mask, &recs, &kp, 0.5, 0.1, 0.01, merge, &mut a);
            merge_sorted(&bare, u64::MAX, &recs, &kp, 0.5, 0.1, 0.01, merge, &mut b);
            assert_eq!(a.len(), if merge { voxels } else { recs.len() });
            // Centres (x and y taken once per column) are those of the unpacked keys.
            let want: Vec<u64> = if merge { keys.clone() } else { items.iter().map(|&it| recs[(it & mask) as usize].key).collect() };
            let centre = |k: u64| kp.unpack(k).map(|v| ((v as f64 + 0.5) * 0.1) as f32);
            assert!(a.iter().zip(&want).all(|(n, &k)| n.center == centre(k)));
            let bits = |n: &Node| (n.center, n.normal.map(f32::to_bits), n.area.to_bits(), n.color);
            assert_eq!(a.iter().map(bits).collect::<Vec<_>>(), b.iter().map(bits).collect::<Vec<_>>());
        }
    }
}
