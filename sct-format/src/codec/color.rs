//! 5:6:5(:4) colour quantization (thesis §5.9.1.3).
//!
//! A `b`-bit code `c` decodes by bit replication (`c << (8-b) | c >> (2b-8)`, and `c·17` for
//! 4 bits), which maps 0 → 0 and the top code → 255 exactly. The encoder picks the code
//! whose decoded value is nearest (ties to the lower code). Worst-case errors in 8-bit steps
//! (unit test): 5 bits → [`MAX_ERR_5`], 6 bits → [`MAX_ERR_6`], 4 bits → [`MAX_ERR_4`].

/// Worst error of a 5-bit channel (8-bit steps).
pub const MAX_ERR_5: u8 = 4;
/// Worst error of a 6-bit channel (8-bit steps).
pub const MAX_ERR_6: u8 = 2;
/// Worst error of a 4-bit channel (8-bit steps).
pub const MAX_ERR_4: u8 = 8;

/// Decodes a `bits`-bit code (bits ∈ {4, 5, 6}).
#[inline]
pub const fn dequant(code: u8, bits: u32) -> u8 {
    let c = code as u32 & ((1 << bits) - 1);
    let v = match bits {
        4 => c * 17,
        _ => (c << (8 - bits)) | (c >> (2 * bits - 8)),
    };
    v as u8
}

/// Nearest `bits`-bit code of an 8-bit value (the definition; [`quant`] looks it up).
const fn quant_exact(v: u8, bits: u32) -> u8 {
    let top = (1u32 << bits) - 1;
    let lo = {
        let e = (v as u32 * top) / 255;
        if e < top {
            e
        } else {
            top
        }
    };
    let mut best = lo;
    let mut err = (dequant(lo as u8, bits) as i32 - v as i32).abs();
    // The nearest code is within one of the linear estimate.
    let cands = [lo.saturating_sub(1), if lo + 1 < top { lo + 1 } else { top }];
    let mut i = 0;
    while i < 2 {
        let c = cands[i];
        let e = (dequant(c as u8, bits) as i32 - v as i32).abs();
        if e < err || (e == err && c < best) {
            best = c;
            err = e;
        }
        i += 1;
    }
    best as u8
}

const fn quant_table(bits: u32) -> [u8; 256] {
    let mut t = [0u8; 256];
    let mut v = 0;
    while v < 256 {
        t[v] = quant_exact(v as u8, bits);
        v += 1;
    }
    t
}

/// Quantization tables for 4, 5 and 6 bits (every node's colour goes through one per channel).
static QUANT: [[u8; 256]; 3] = [quant_table(4), quant_table(5), quant_table(6)];

/// Nearest `bits`-bit code of an 8-bit value (bits ∈ {4, 5, 6}).
#[inline]
pub fn quant(v: u8, bits: u32) -> u8 {
    match bits {
        4..=6 => QUANT[bits as usize - 4][v as usize],
        _ => quant_exact(v, bits),
    }
}

/// Bits per channel: RGB 5:6:5, alpha 4.
pub const BITS: [u32; 4] = [5, 6, 5, 4];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_bounds() {
        for (bits, bound) in [(5, MAX_ERR_5), (6, MAX_ERR_6), (4, MAX_ERR_4)] {
            let mut worst = 0;
            for v in 0..=255u8 {
                let c = quant(v, bits);
                let d = dequant(c, bits);
                let e = (d as i32 - v as i32).unsigned_abs() as u8;
                worst = worst.max(e);
                // Nearest: no other code is strictly closer.
                for o in 0..(1u8 << bits) {
                    assert!((dequant(o, bits) as i32 - v as i32).abs() >= e as i32);
                }
            }
            assert_eq!(worst, bound, "{bits} bits");
            for c in 0..(1u8 << bits) {
                assert_eq!(quant(dequant(c, bits), bits), c, "codes are fixed points");
            }
            assert_eq!(dequant((1 << bits) - 1, bits), 255);
        }
    }
}
