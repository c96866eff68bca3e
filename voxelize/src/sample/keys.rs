//! Sample records before merging and their packed voxel keys, and where emitters put them.

use crate::mesh::floor_i64;

/// One sample before merging: a packed voxel key ([`KeyPack`]), attributes, and the point
/// of the surface it stands for with the radius that reaches all of its piece of surface.
#[derive(Clone, Copy, Debug)]
pub(super) struct Rec {
    pub(super) key: u64,
    /// The piece's area; its sign marks a quarter of a piece sampled at half the voxel
    /// (negative, merged only with quarters in the same octant of the voxel).
    pub(super) area: f32,
    pub(super) normal: [f32; 3],
    pub(super) color: [f32; 4],
    /// The sample's point (the centroid of its piece of surface) relative to the centre of
    /// its voxel, in voxel units: voxel-local so that f32 keeps it to 2^-25 of a voxel
    /// wherever the voxel lies.
    pub(super) off: [f32; 3],
    /// Radius (voxel units) of the ball around `off` that holds the sample's whole piece of
    /// surface, rounded up.
    pub(super) r: f32,
}

/// `x ≥ 0` as an f32 no smaller than `x` (for radii: containment must survive the rounding).
#[inline(always)]
pub(super) fn up_f32(x: f64) -> f32 {
    let y = x as f32;
    // For a non-negative finite `y`, the next larger f32 is one bit pattern up (`next_up`
    // without its checks for negative, infinite and NaN values). Without a branch: whether
    // rounding went down is a coin toss, which a branch would mispredict half the time.
    f32::from_bits(y.to_bits() + u32::from(f64::from(y) < x))
}

/// A record's offset ([`Rec::off`]) for the point `p` (grid units) sampling voxel `v`, and
/// its radius for a piece that lies within `r` of `p`: `r` grown by how far rounding to f32
/// moved the point (the L1 length of the move, at least its length: no square root), so the
/// ball around the stored point still holds the piece.
#[inline(always)]
pub(super) fn offset_reach(p: [f64; 3], v: [i64; 3], r: f64) -> ([f32; 3], f32) {
    let o: [f64; 3] = std::array::from_fn(|k| p[k] - v[k] as f64 - 0.5);
    let off = o.map(|x| x as f32);
    let moved = (f64::from(off[0]) - o[0]).abs() + (f64::from(off[1]) - o[1]).abs() + (f64::from(off[2]) - o[2]).abs();
    (off, up_f32(r + moved))
}

/// Packs voxel coordinates of one unit into a `u64` (x major, then y, then z — the
/// lexicographic order of the coordinates), so merging sorts plain integers.
#[derive(Clone, Copy, Debug)]
pub(super) struct KeyPack {
    pub(super) lo: [i64; 3],
    pub(super) hi: [i64; 3],
    pub(super) bits: [u32; 3],
    /// `bits[1] + bits[2]`.
    pub(super) shift_x: u32,
}

impl KeyPack {
    /// Covers the grid cells of `lo..=hi` (grid units) with one cell of margin.
    pub(super) fn new(lo: [f64; 3], hi: [f64; 3]) -> Result<KeyPack, String> {
        // Saturating: coordinates far beyond the grid must give an error, not an overflow.
        let l = lo.map(|v| floor_i64(v).saturating_sub(1));
        let h = hi.map(|v| floor_i64(v).saturating_add(1));
        let bits: [u32; 3] = std::array::from_fn(|k| 64 - (h[k].saturating_sub(l[k]).max(1) as u64).leading_zeros());
        if bits.iter().sum::<u32>() > 64 {
            return Err(format!(
                "the voxel grid ({} × {} × {} voxels) is too large to index with 64-bit voxel keys; use a larger voxel size",
                h[0].saturating_sub(l[0]),
                h[1].saturating_sub(l[1]),
                h[2].saturating_sub(l[2])
            ));
        }
        Ok(KeyPack { lo: l, hi: h, bits, shift_x: bits[1] + bits[2] })
    }
    #[inline]
    pub(super) fn pack(&self, k: [i64; 3]) -> u64 {
        self.pack_in_range(self.clamp(k))
    }
    /// The voxel of the key range nearest to `k`: the voxel whose key [`KeyPack::pack`] gives
    /// `k`. Clamped so a rounding stray can never spill into a neighbouring field (max then
    /// min: `clamp` would also check lo ≤ hi, which `new` guarantees, on every sample).
    #[inline]
    pub(super) fn clamp(&self, k: [i64; 3]) -> [i64; 3] {
        std::array::from_fn(|i| k[i].max(self.lo[i]).min(self.hi[i]))
    }
    /// [`KeyPack::pack`] of a voxel already in the key range.
    #[inline]
    pub(super) fn pack_in_range(&self, k: [i64; 3]) -> u64 {
        let v: [u64; 3] = std::array::from_fn(|i| (k[i] - self.lo[i]) as u64);
        (v[0] << self.shift_x) | (v[1] << self.bits[2]) | v[2]
    }
    /// Where axis `k`'s field starts in a key.
    #[inline]
    pub(super) fn shift(&self, k: usize) -> u32 {
        match k {
            0 => self.shift_x,
            1 => self.bits[2],
            _ => 0,
        }
    }
    #[inline]
    pub(super) fn unpack(&self, key: u64) -> [i64; 3] {
        let mask = |b: u32| if b == 0 { 0 } else { u64::MAX >> (64 - b) };
        let z = key & mask(self.bits[2]);
        let y = (key >> self.bits[2]) & mask(self.bits[1]);
        let x = key.checked_shr(self.bits[1] + self.bits[2]).unwrap_or(0) & mask(self.bits[0]);
        [x as i64 + self.lo[0], y as i64 + self.lo[1], z as i64 + self.lo[2]]
    }
}

/// Where an emitter puts its records.
pub(super) trait RecSink {
    fn push(&mut self, r: Rec);
    /// The buffer where every key of `lo..=hi` goes, when there is one: a run of records
    /// is then pushed there without finding each one's place.
    fn run(&mut self, lo: u64, hi: u64) -> Option<&mut Vec<Rec>>;
}

impl RecSink for Vec<Rec> {
    #[inline]
    fn push(&mut self, r: Rec) {
        Vec::push(self, r);
    }
    #[inline]
    fn run(&mut self, _lo: u64, _hi: u64) -> Option<&mut Vec<Rec>> {
        Some(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `up_f32` is the smallest f32 no smaller than its argument: exact values, values
    /// between two f32s, zero, subnormals and values beyond the largest f32.
    #[test]
    fn up_f32_rounds_up_to_the_next_f32() {
        let mut rng = sct_format::rng::SplitMix64(19);
        let mut xs = vec![0.0, 1.0, f64::from(f32::MAX), f64::from(f32::MAX) * 1.5, 1e-45, f64::from(f32::from_bits(1)), 0.1];
        for _ in 0..100_000 {
            xs.push(rng.next_f64() * 2f64.powi((rng.next_u64() % 60) as i32 - 30));
        }
        for x in xs {
            let y = up_f32(x);
            assert!(f64::from(y) >= x, "{x:e} → {y:e}");
            assert!(y == 0.0 || f64::from(y.next_down()) < x, "{x:e} → {y:e} is not the smallest");
        }
    }

    #[test]
    fn key_pack_round_trips_and_orders_x_major() {
        let kp = KeyPack::new([-5.5, 0.0, 1000.2], [300.0, 2.0, 1001.0]).unwrap();
        let pts = [[-6, 0, 999], [-6, 3, 1002], [0, 1, 1000], [301, -1, 1002], [17, 2, 1001]];
        for p in pts {
            assert_eq!(kp.unpack(kp.pack(p)), p);
        }
        let mut by_key = pts.to_vec();
        by_key.sort_by_key(|p| kp.pack(*p));
        let mut lex = pts.to_vec();
        lex.sort();
        assert_eq!(by_key, lex);
        // Out-of-range coordinates clamp instead of spilling into another field.
        assert_eq!(kp.unpack(kp.pack([i64::MAX, 0, 1000])), [301, 0, 1000]);
        assert_eq!(kp.unpack(kp.pack([i64::MIN, 9, i64::MIN])), [-7, 3, 999]);
        assert!(KeyPack::new([0.0; 3], [3e6; 3]).is_err(), "3 × 22 bits do not fit");
        assert!(KeyPack::new([-1e300; 3], [1e300; 3]).is_err(), "saturates, then refuses");
    }
}
