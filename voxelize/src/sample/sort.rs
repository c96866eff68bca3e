//! Stable sorting of a slab part's records by voxel key: an LSD radix sort of packed
//! (key, index) items.

use super::keys::Rec;

/// Sorts `recs` by key, stably: fills `items` with their indices in key order, each in the
/// low bits of an item under the returned mask. Normally an item is the key (relative to
/// the smallest) above the index, so one radix sort of plain `u64`s by their key bits
/// orders them; when the two do not fit in 64 bits, items are bare indices (comparison sort).
/// `range` = (lo, bits) when every key is known to lie in `lo .. lo + 2^bits` (a middle part
/// of [`SlabParts`]), which saves a scan for the smallest and largest keys.
pub(super) fn sort_order(recs: &[Rec], range: Option<(u64, u32)>, items: &mut Vec<u64>, tmp: &mut Vec<u64>) -> u64 {
    items.clear();
    let (lo, key_bits) = range.unwrap_or_else(|| {
        let (lo, hi) = recs.iter().fold((u64::MAX, 0), |(l, h), r| (l.min(r.key), h.max(r.key)));
        (lo, 64 - hi.saturating_sub(lo).leading_zeros())
    });
    let n = recs.len();
    let idx_bits = 64 - (n as u64).leading_zeros();
    if key_bits + idx_bits > 64 {
        items.extend(0..n as u64);
        items.sort_by_key(|&i| recs[i as usize].key);
        return u64::MAX;
    }
    let item = |i: usize, r: &Rec| ((r.key - lo) << idx_bits) | i as u64;
    let (passes, d) = radix_digits(n, key_bits);
    if passes != 2 || !radix_worth(n, key_bits) {
        items.extend(recs.iter().enumerate().map(|(i, r)| item(i, r)));
        radix_sort_bits(items, tmp, idx_bits, key_bits);
        return (1u64 << idx_bits) - 1;
    }
    // The usual case (a part of a slab: two digits): both digits counted in one read.
    items.extend(recs.iter().enumerate().map(|(i, r)| item(i, r)));
    let mut counts = vec![0u32; 2 << d];
    let (c0, c1) = counts.split_at_mut(1 << d);
    // Masks from the counters' lengths: the counting goes unchecked.
    let (Some(m0), Some(m1)) = (c0.len().checked_sub(1), c1.len().checked_sub(1)) else {
        return u64::MAX; // unreachable: both halves hold 2^d counters
    };
    for &x in items.iter() {
        let v = (x >> idx_bits) as usize;
        c0[v & m0] += 1;
        c1[(v >> d) & m1] += 1;
    }
    radix_passes(items, tmp, idx_bits, d, &mut counts);
    (1u64 << idx_bits) - 1
}

/// Widest radix digit: slab keys of up to 28 bits (a slab's x cells above a unit's y and z
/// fields: the dense runs' keys) sort in two passes; 2^14 counters still sit in L2.
pub(super) const RADIX_DIGIT_BITS: u32 = 14;

/// Whether a radix sort beats a comparison sort for `n` items with `bits` key bits.
pub(super) fn radix_worth(n: usize, bits: u32) -> bool {
    n > 64 && n <= u32::MAX as usize && bits > 0
}

/// (passes, digit bits) of a radix sort of `n` items by `bits` key bits: digits of at most
/// [`RADIX_DIGIT_BITS`], and at most about n/2 counters (for short inputs, time would go to
/// the counters), so a slab part's 8–16k items with 23–24 key bits take two passes.
pub(super) fn radix_digits(n: usize, bits: u32) -> (u32, u32) {
    let widest = (usize::BITS - n.leading_zeros()).saturating_sub(1).clamp(8, RADIX_DIGIT_BITS);
    let passes = bits.min(64).div_ceil(widest);
    (passes, bits.div_ceil(passes.max(1)))
}

/// Stable LSD radix sort of `items` by their bits `shift .. shift + bits` (the bits above are
/// zero), in the passes of [`radix_digits`]; passes where every item has the same digit are
/// skipped.
pub(super) fn radix_sort_bits(items: &mut [u64], tmp: &mut Vec<u64>, shift: u32, bits: u32) {
    let n = items.len();
    if !radix_worth(n, bits) {
        items.sort_by_key(|&x| x >> shift.min(63)); // stable
        return;
    }
    let (passes, d) = radix_digits(n, bits);
    // Every pass's counters filled in one read of the items.
    let mut counts = vec![0u32; (passes as usize) << d];
    let m = (1u64 << d) - 1;
    for &x in items.iter() {
        let mut v = x >> shift;
        for c in counts.chunks_exact_mut(1 << d) {
            if let Some(c) = c.get_mut((v & m) as usize) {
                *c += 1;
            }
            v >>= d;
        }
    }
    radix_passes(items, tmp, shift, d, &mut counts);
}

/// The passes of an LSD radix sort whose digit counts (pass p's `2^d` counters at
/// `p·2^d`, one pass per block) are in `counts`: digit p is bits `shift + p·d ..` of an item.
pub(super) fn radix_passes(items: &mut [u64], tmp: &mut Vec<u64>, shift: u32, d: u32, counts: &mut [u32]) {
    let n = items.len();
    // The scratch buffer is reused across calls: grown (zeroed) only when too short.
    if tmp.len() < n {
        tmp.resize(n, 0);
    }
    let tmp = &mut tmp[..n];
    let mut in_items = true; // where the current data lives
    for (p, count) in counts.chunks_exact_mut(1 << d).enumerate() {
        let (src, dst): (&[u64], &mut [u64]) = if in_items { (items, &mut *tmp) } else { (&*tmp, items) };
        if scatter_by_digit(src, dst, shift + p as u32 * d, count) {
            in_items = !in_items;
        }
    }
    if !in_items {
        items.copy_from_slice(tmp);
    }
}

/// One counting-sort pass of [`radix_passes`]: moves `src` into `dst` stably ordered by the
/// digit `(x >> sh) & (count.len() − 1)`, where `count` holds each digit's count
/// (`count.len()` a power of two; masking by it lets the counter indexing go unchecked).
/// Returns false, moving nothing, when all digits are equal.
pub(super) fn scatter_by_digit(src: &[u64], dst: &mut [u64], sh: u32, count: &mut [u32]) -> bool {
    let (Some(m), Some(&first)) = (count.len().checked_sub(1), src.first()) else {
        return false;
    };
    // All digits are equal when the first item's digit counts them all.
    if count[(first >> sh) as usize & m] as usize == src.len() {
        return false;
    }
    let mut pos = 0;
    for c in count.iter_mut() {
        (*c, pos) = (pos, pos + *c);
    }
    for &x in src {
        let c = &mut count[(x >> sh) as usize & m];
        dst[*c as usize] = x;
        *c += 1;
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Slab parts (4k–16k items, 23–24 key bits) sort in two passes.
    #[test]
    fn slab_parts_take_two_radix_passes() {
        for n in [4096, 5000, 8192, 16_383] {
            for bits in [23, 24] {
                assert_eq!(radix_digits(n, bits), (2, 12), "n {n}, bits {bits}");
            }
        }
        assert_eq!(radix_digits(16_384, 28), (2, 14));
    }

    #[test]
    fn radix_sort_is_a_stable_sort() {
        let mut rng = sct_format::rng::SplitMix64(3);
        let mut tmp = Vec::new();
        for (n, shift, bits) in [(10, 4, 5), (1000, 10, 3), (5000, 0, 40), (70_000, 17, 23), (3000, 0, 64), (4000, 30, 33), (4000, 12, 22), (300, 5, 0), (20_000, 15, 27), (20_000, 15, 28), (2000, 20, 26), (70_000, 17, 28)] {
            // The low `shift` bits are payload (not sorted on: stability shows).
            let mut v: Vec<u64> = (0..n as u64)
                .map(|_| {
                    let mut key = if bits == 0 { 0 } else { rng.next_u64() >> (64 - bits) };
                    if n == 70_000 && bits == 28 {
                        key &= !0x3FFF; // the low digit is the same everywhere: its pass is skipped
                    }
                    key.checked_shl(shift).unwrap_or(0) | (rng.next_u64() & ((1u64 << shift) - 1))
                })
                .collect();
            let mut want = v.clone();
            want.sort_by_key(|&x| x.checked_shr(shift).unwrap_or(0));
            radix_sort_bits(&mut v, &mut tmp, shift, bits);
            assert_eq!(v, want, "n {n}, shift {shift}, bits {bits}");
        }
    }
}
