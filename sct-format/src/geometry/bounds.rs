//! Certified enclosures of libm's f64 `atan2`, `sin` and `cos`, a few times cheaper than the
//! calls, so that [`super::parent_of`] can skip the exact calls whenever an enclosure already
//! decides its f32 result.
//!
//! Each estimate is a truncated alternating Taylor series (for |x| ≤ 1 its terms shrink, so
//! the truncation error is at most the first omitted term), evaluated in f64 (a few ulp),
//! compared with a libm that is within 1 ulp (glibc, musl, the BSDs and the CRT libms are on
//! these functions). The error bound of each is written next to its margin; every margin
//! exceeds that sum more than tenfold.

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

/// An interval `[lo, hi]` known to hold a libm result.
#[derive(Clone, Copy, Debug)]
pub(super) struct Interval {
    pub lo: f64,
    pub hi: f64,
}

impl Interval {
    pub fn exact(v: f64) -> Self {
        Interval { lo: v, hi: v }
    }

    /// The image under a nondecreasing `f`. Every sequence of f64 operations on one variable
    /// with `+`, `-` of a constant and `×` by a non-negative constant is nondecreasing,
    /// because IEEE rounding is.
    pub fn map(self, f: impl Fn(f64) -> f64) -> Self {
        Interval { lo: f(self.lo), hi: f(self.hi) }
    }

    /// Whether every value of the interval is `<= b`, when all or none are (`None` when the
    /// interval straddles `b`, or for a NaN). The usual answer, none, costs one comparison.
    pub fn le(self, b: f64) -> Option<bool> {
        if self.lo > b {
            Some(false)
        } else if self.hi <= b {
            Some(true)
        } else {
            None
        }
    }

    /// Whether every value of the interval is `>= b`, when all or none are (`None` when the
    /// interval straddles `b`, or for a NaN). The usual answer, none, costs one comparison.
    pub fn ge(self, b: f64) -> Option<bool> {
        if self.hi < b {
            Some(false)
        } else if self.lo >= b {
            Some(true)
        } else {
            None
        }
    }

    /// Whether every value of the interval equals `v` (equality is not monotone, so it
    /// is decided only for a point interval or a `v` outside).
    pub fn equals(self, v: f64) -> Option<bool> {
        if self.lo == self.hi {
            Some(self.lo == v)
        } else if v < self.lo || v > self.hi {
            Some(false)
        } else {
            None
        }
    }
}

/// `c[0] + c[1] z + … + c[n-1] z^(n-1)` by Horner's rule (unrolled: `n` is a constant).
/// It starts from `c[n-1]`, not from `0 z + c[n-1]`: the same value for finite `z`, two
/// instructions fewer (the compiler may not drop `0 z`, which is NaN for an infinite `z`).
#[inline(always)]
fn horner(c: &[f64], z: f64) -> f64 {
    c.iter().rev().copied().reduce(|p, ck| p * z + ck).unwrap_or(0.0)
}

/// atan(x) = x (1 − x²/3 + x⁴/5 − …), 16 terms.
const ATAN: [f64; 16] = {
    let mut c = [0.0; 16];
    let mut k = 0;
    while k < 16 {
        c[k] = (if k % 2 == 0 { 1.0 } else { -1.0 }) / (2 * k + 1) as f64;
        k += 1;
    }
    c
};

/// Below it [`atan_unit`] sums the series directly, above it after the reduction.
const TAN_PI_8: f64 = 0.414_213_562_373_095;

/// Largest |x| handed to [`atan_series`]: tan(π/8) plus rounding, on both sides of the
/// reduction ((q−1)/(q+1) at q = tan(π/8) is −tan(π/8)).
#[cfg(test)]
const ATAN_X_MAX: f64 = 0.41422;

/// Below it (angles under 3.6°, the usual case) 6 terms of the series suffice.
const ATAN_SHORT: f64 = 1.0 / 16.0;

/// Relative margin of [`atan2`]: truncation ≤ |x|³³/33 / |atan x| ≤ 0.17158¹⁶/33/0.94
/// = 1.8e-14 relative (16 terms, |x| ≤ tan(π/8)) or ≤ 16⁻¹²/13/0.998 = 2.8e-16 (6 terms,
/// |x| ≤ 1/16), plus ≤ 1e-15 for the f64 evaluation and the argument reduction and 2.2e-16
/// for libm, against 2⁻⁴² = 2.3e-13.
const ATAN_REL: f64 = 1.0 / (1u64 << 42) as f64;

/// atan(x) for |x| ≤ tan(π/8) (plus rounding).
#[inline(always)]
fn atan_series(x: f64) -> f64 {
    x * horner(&ATAN, x * x)
}

/// atan(q) for 0 ≤ q ≤ 1, reduced to |x| ≤ tan(π/8) by atan(q) = π/4 + atan((q−1)/(q+1)).
#[inline(always)]
fn atan_unit(q: f64) -> f64 {
    if q <= ATAN_SHORT {
        q * horner(&ATAN[..6], q * q)
    } else if q <= TAN_PI_8 {
        atan_series(q)
    } else {
        FRAC_PI_4 + atan_series((q - 1.0) / (q + 1.0))
    }
}

/// An interval holding `y.atan2(x)` for `y ≥ 0` (a vector norm), or `None` outside the
/// cases handled here (zero, huge or tiny arguments, NaN): the caller then calls libm.
#[inline(always)]
pub(super) fn atan2(y: f64, x: f64) -> Option<Interval> {
    let ax = x.abs();
    // With y > 1e-150 and |x| < 1e150 the ratio below is a normal number (or an ignorable
    // tiny one next to π/2); x = ±0 and y = ∞ give π/2 like libm. NaN fails both tests.
    if !(y > 1e-150 && ax < 1e150) {
        // atan2(±0, x > 0) = ±0 exactly (C99 F.9.1.4).
        return (y == 0.0 && x > 0.0).then_some(Interval::exact(y));
    }
    let v = if y <= ax {
        // Result in [0, π/4] or [3π/4, π]; q ≥ 1e-300 keeps full relative precision.
        let q = y / ax;
        let a = atan_unit(q);
        if x > 0.0 {
            a
        } else {
            PI - a
        }
    } else {
        // Result in (π/4, 3π/4): absolute error of atan(q) ≤ 1e-14, relative to ≥ π/4.
        let a = atan_unit(ax / y);
        if x > 0.0 {
            FRAC_PI_2 - a
        } else {
            FRAC_PI_2 + a
        }
    };
    let m = v * ATAN_REL;
    Some(Interval { lo: v - m, hi: v + m })
}

/// sin(x) = x (1 − x²/3! + x⁴/5! − …), 9 terms.
const SIN: [f64; 9] = {
    let mut c = [0.0; 9];
    let mut k = 0;
    let mut f = 1.0; // (2k+1)!
    while k < 9 {
        c[k] = (if k % 2 == 0 { 1.0 } else { -1.0 }) / f;
        f *= ((2 * k + 2) * (2 * k + 3)) as f64;
        k += 1;
    }
    c
};

/// cos(x) = 1 − x²/2! + x⁴/4! − …, 9 terms.
const COS: [f64; 9] = {
    let mut c = [0.0; 9];
    let mut k = 0;
    let mut f = 1.0; // (2k)!
    while k < 9 {
        c[k] = (if k % 2 == 0 { 1.0 } else { -1.0 }) / f;
        f *= ((2 * k + 1) * (2 * k + 2)) as f64;
        k += 1;
    }
    c
};

/// Below it 4 terms of sin and 5 of cos suffice.
const SIN_COS_SHORT: f64 = 1.0 / 16.0;

/// Relative margin of [`sin_cos`] on (0, 1]: truncation ≤ 1/19! / (sin x / x ≥ 0.84) = 1e-17
/// for sin and ≤ 1/18! / (cos 1 = 0.54) = 2.9e-16 for cos (9 terms), or ≤ 16⁻⁸/9! = 6.4e-16
/// and ≤ 16⁻¹⁰/10! = 2.5e-19 below [`SIN_COS_SHORT`] (4 and 5 terms), plus ≤ 1.5e-15 of f64
/// evaluation and 2.2e-16 for libm, against 2⁻⁴⁶ = 1.4e-14.
const SIN_COS_REL: f64 = 1.0 / (1u64 << 46) as f64;

/// Intervals holding `p.sin()` and `p.cos()` for every `p` in `phi`, or `None` unless
/// `phi` lies in (0, 1], where sin rises, cos falls and both are 1-Lipschitz.
#[inline(always)]
pub(super) fn sin_cos(phi: Interval) -> Option<(Interval, Interval)> {
    if !(phi.lo > 0.0 && phi.hi <= 1.0) {
        return None;
    }
    let (x, z) = (phi.lo, phi.lo * phi.lo);
    let (s, c) = if x <= SIN_COS_SHORT {
        (x * horner(&SIN[..4], z), horner(&COS[..5], z))
    } else {
        (x * horner(&SIN, z), horner(&COS, z))
    };
    // The width, rounded up: the moves of sin and cos across the interval.
    let w = (phi.hi - phi.lo) * (1.0 + 1.0 / (1u64 << 50) as f64);
    let (ms, mc) = (s * SIN_COS_REL, c * SIN_COS_REL);
    Some((Interval { lo: s - ms, hi: s + ms + w }, Interval { lo: c - mc - w, hi: c + mc }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    fn unit(rng: &mut SplitMix64) -> [f64; 3] {
        loop {
            let v = [0, 1, 2].map(|_| rng.next_f32() as f64 * 2.0 - 1.0);
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if l > 1e-3 {
                return v.map(|x| x / l);
            }
        }
    }

    fn holds(i: Interval, v: f64) -> bool {
        i.lo <= v && v <= i.hi
    }

    #[test]
    fn atan2_interval_holds_libm() {
        let mut rng = SplitMix64(3);
        let mut checked = 0;
        let mut check = |y: f64, x: f64| {
            if let Some(i) = atan2(y, x) {
                assert!(holds(i, y.atan2(x)), "atan2({y:e}, {x:e}) = {:e} outside {i:?}", y.atan2(x));
                // The interval is narrow (what makes it useful).
                assert!(i.hi - i.lo <= 1e-12 * y.atan2(x).abs(), "{i:?}");
                checked += 1;
            }
        };
        // The arguments parent_of meets: |a × b| and a · b of unit vectors, near and far.
        for _ in 0..300_000 {
            let a = unit(&mut rng);
            let mut b = unit(&mut rng);
            let t = [1e-9, 1e-5, 1e-2, 1.0][(rng.next_u64() % 4) as usize];
            if rng.next_u64() % 2 == 0 {
                b = [0, 1, 2].map(|k| a[k] + b[k] * t);
            }
            if rng.next_u64() % 4 == 0 {
                b = b.map(|x| -x);
            }
            let c = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
            check((c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt(), a[0] * b[0] + a[1] * b[1] + a[2] * b[2]);
        }
        // Every octant boundary and the reduction threshold, with neighbours.
        for (y, x) in [(1.0, 1.0), (0.414, 1.0), (0.4142135623730951, 1.0), (1.0, 0.414), (1.0, -1.0), (1e-17, 1.0), (1e-17, -1.0), (ATAN_SHORT, 1.0), (1.0, ATAN_SHORT)] {
            let (mut y, mut x): (f64, f64) = (y, x);
            for _ in 0..64 {
                check(y, x);
                check(x.abs(), -y);
                y = y.next_up();
                x = x.next_down();
            }
        }
        for _ in 0..300_000 {
            check(f64::from_bits(rng.next_u64()).abs(), f64::from_bits(rng.next_u64()));
            check(rng.next_f32() as f64 * 10.0, (rng.next_f32() as f64 - 0.5) * 10.0);
        }
        assert!(checked > 500_000, "{checked}");
        assert_eq!(atan2(0.0, 1.0).map(|i| i.lo.to_bits()), Some(0));
        assert!(atan2(0.0, -1.0).is_none() && atan2(f64::NAN, 1.0).is_none() && atan2(1.0, f64::NAN).is_none());
        for (y, x) in [(1.0, 0.0), (1.0, -0.0), (f64::INFINITY, 1.0), (f64::INFINITY, -1.0), (1e-150f64.next_up(), 1e150f64.next_down())] {
            let i = atan2(y, x).expect("handled");
            assert!(holds(i, y.atan2(x)), "atan2({y:e}, {x:e}): {i:?}");
        }
    }

    #[test]
    fn sin_cos_intervals_hold_libm() {
        let mut rng = SplitMix64(5);
        for k in 0..1_000_000u32 {
            let scale = [1e-12, 1e-6, 1e-3, 0.1, 1.0][k as usize % 5];
            let lo = (rng.next_f32() as f64 * scale).max(f64::MIN_POSITIVE);
            let hi = if k % 3 == 0 { lo } else { (lo + lo * 1e-12 * rng.next_f32() as f64).min(1.0) };
            let (Some((s, c)), true) = (sin_cos(Interval { lo, hi }), lo <= 1.0) else { panic!("{lo:e}") };
            for p in [lo, hi, 0.5 * (lo + hi)] {
                assert!(holds(s, p.sin()) && holds(c, p.cos()), "{p:e}: {s:?} {c:?}");
            }
            assert!(s.hi - s.lo <= 1e-13 * s.hi + 2.0 * (hi - lo) && c.hi - c.lo <= 1e-13 + 2.0 * (hi - lo));
        }
        let mut p = SIN_COS_SHORT;
        for _ in 0..64 {
            p = p.next_down();
        }
        for _ in 0..128 {
            let (s, c) = sin_cos(Interval::exact(p)).expect("in range");
            assert!(holds(s, p.sin()) && holds(c, p.cos()), "{p:e}");
            p = p.next_up();
        }
        assert!(sin_cos(Interval::exact(1.0)).is_some());
        for bad in [0.0, -1e-3, 1.0000000000000002, f64::NAN] {
            assert!(sin_cos(Interval::exact(bad)).is_none(), "{bad}");
        }
    }

    #[test]
    fn le_and_ge_decide_only_whole_intervals() {
        let i = Interval { lo: 1.0, hi: 2.0 };
        assert_eq!([0.5, 1.0, 1.5, 2.0, 3.0].map(|b| i.le(b)), [Some(false), None, None, Some(true), Some(true)]);
        assert_eq!([0.5, 1.0, 1.5, 2.0, 3.0].map(|b| i.ge(b)), [Some(true), Some(true), None, None, Some(false)]);
        // A NaN bound or end is left undecided (the exact path then runs).
        assert_eq!((i.le(f64::NAN), i.ge(f64::NAN)), (None, None));
        assert_eq!(Interval::exact(f64::NAN).le(1.0), None);
        assert_eq!((Interval::exact(1.0).le(1.0), Interval::exact(1.0).ge(1.0)), (Some(true), Some(true)));
    }

    #[test]
    fn series_coefficients() {
        assert_eq!((ATAN[0], ATAN[1], ATAN[15]), (1.0, -1.0 / 3.0, -1.0 / 31.0));
        assert_eq!((SIN[0], SIN[1], SIN[2]), (1.0, -1.0 / 6.0, 1.0 / 120.0));
        assert_eq!((COS[0], COS[1], COS[2]), (1.0, -0.5, 1.0 / 24.0));
        assert!((SIN[8] - 1.0 / 355687428096000.0).abs() < 1e-28 && (COS[8] - 1.0 / 20922789888000.0).abs() < 1e-28);
        for q in [TAN_PI_8, TAN_PI_8.next_up(), 1.0] {
            assert!(q.abs() <= ATAN_X_MAX || ((q - 1.0) / (q + 1.0)).abs() <= ATAN_X_MAX);
        }
        const { assert!(ATAN_X_MAX * ATAN_X_MAX < 0.17158 + 1e-5) };
    }
}
