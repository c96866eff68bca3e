//! 16-bit octahedral normals and 8-bit round-up cone angles (thesis §5.9.1.2).
//!
//! We use the octahedral map (Meyer et al. 2010; Cigolle et al. 2014) with 8 bits per
//! coordinate and "precise" encoding (of the four surrounding codes, the one decoding
//! closest to the input) instead of the thesis's sign-bits + 7/6-bit (x, y) table. Both use
//! 16 bits; the thesis scheme quantizes x and y to 1/127 and recovers z = √(1-x²-y²), whose
//! error explodes near the equator (≈5° at z ≈ 0, the banding the thesis mentions), while
//! the octahedral code's worst case is [`MAX_NORMAL_ERROR_DEG`] everywhere: equal or better.
//!
//! Code layout: `u16 = u | v << 8`, `x = u/255·2-1`, `y = v/255·2-1`, `z = 1-|x|-|y|`; when
//! `z < 0`, `(x, y) ← ((1-|y|)·sgn x, (1-|x|)·sgn y)` (sgn 0 = +1); then normalise (f32).

use std::f64::consts::PI;

/// Worst-case angle between a unit normal and its decoded octahedral code, in degrees
/// (measured over 2M random and adversarial directions in the unit test, rounded up).
pub const MAX_NORMAL_ERROR_DEG: f64 = 0.64;

/// Cone quantization step: 256 codes over [0, π], code 255 = π ("any direction").
pub const CONE_STEP: f64 = PI / 255.0;

fn sgn(v: f32) -> f32 {
    if v < 0.0 {
        -1.0
    } else {
        1.0
    }
}

/// Decodes an octahedral code to a unit vector (f32, deterministic IEEE operations only).
#[inline]
pub fn oct_decode(code: u16) -> [f32; 3] {
    normalized(oct_unnormalized(code))
}

/// A surface point scaled to unit length, as [`oct_decode`] does it.
#[inline]
fn normalized([x, y, z]: [f32; 3]) -> [f32; 3] {
    let l = (x * x + y * y + z * z).sqrt();
    // l ≥ 1/√3 on the octahedron surface: never zero.
    [x / l, y / l, z / l]
}

/// `c / 255 · 2 − 1` (f32) for every code byte `c`: a code's octahedral coordinate. Built at
/// compile time (IEEE arithmetic, the same values as at run time; checked in a test), so that
/// decoding a code costs a lookup instead of a division.
static OCT_COORD: [f32; 256] = {
    let mut t = [0f32; 256];
    let mut i = 0;
    while i < 256 {
        t[i] = i as f32 / 255.0 * 2.0 - 1.0;
        i += 1;
    }
    t
};

/// The octahedral coordinate of code byte `c` (see [`OCT_COORD`]).
#[inline]
fn coord(c: u8) -> f32 {
    OCT_COORD[c as usize]
}

/// The octahedron-surface point of `code`, before [`oct_decode`] normalises it.
#[inline]
fn oct_unnormalized(code: u16) -> [f32; 3] {
    let mut x = coord(code as u8);
    let mut y = coord((code >> 8) as u8);
    let z = 1.0 - x.abs() - y.abs();
    if z < 0.0 {
        let (ox, oy) = (x, y);
        x = (1.0 - oy.abs()) * sgn(ox);
        y = (1.0 - ox.abs()) * sgn(oy);
    }
    [x, y, z]
}

/// Octahedral projection to [0, 255]² (continuous), f32.
fn oct_project(n: [f32; 3]) -> [f32; 2] {
    let s = n[0].abs() + n[1].abs() + n[2].abs();
    let (mut x, mut y) = (n[0] / s, n[1] / s);
    if n[2] < 0.0 {
        let (ox, oy) = (x, y);
        x = (1.0 - oy.abs()) * sgn(ox);
        y = (1.0 - ox.abs()) * sgn(oy);
    }
    [(x * 0.5 + 0.5) * 255.0, (y * 0.5 + 0.5) * 255.0]
}

/// Nearest-in-code-space octahedral code (used for predictions, where only determinism
/// matters). `n` must be non-zero and finite.
#[inline]
pub fn oct_encode_fast(n: [f32; 3]) -> u16 {
    let p = oct_project(n);
    round_projected(p[0]) | round_projected(p[1]) << 8
}

/// `round_byte_f32(v)` for what [`oct_project`] returns for any input: a value in [0, 255]
/// (`|n₀| / (|n₀| + |n₁| + |n₂|) ≤ 1`, also after the fold) or NaN (non-finite components).
/// There no range test is needed: the truncation is exact and NaN truncates to 0.
#[inline]
fn round_projected(v: f32) -> u16 {
    let t = v as i32;
    (t + (v - t as f32 >= 0.5) as i32) as u16
}

/// Angle in radians between two non-zero vectors (f64, atan2 form: accurate near 0 and π).
pub fn angle(a: [f32; 3], b: [f32; 3]) -> f64 {
    let a = [a[0] as f64, a[1] as f64, a[2] as f64];
    let b = [b[0] as f64, b[1] as f64, b[2] as f64];
    let c = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    let cn = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
    cn.atan2(a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
}

/// True when `n` is finite and not (numerically) zero.
#[inline]
pub fn usable(n: [f32; 3]) -> bool {
    usable_len2(len2_f64(n))
}

/// `|n|²` in f64 (the squares of f32 values are exact).
#[inline]
fn len2_f64(n: [f32; 3]) -> f64 {
    let m = [n[0] as f64, n[1] as f64, n[2] as f64];
    m[0] * m[0] + m[1] * m[1] + m[2] * m[2]
}

/// [`usable`] from the `l2` of [`len2_f64`], one range test for both conditions: finite
/// components give a finite sum (each square < 1.2e77), a non-finite one an infinite or NaN sum.
#[inline]
fn usable_len2(l2: f64) -> bool {
    l2 > 1e-30 && l2 < f64::INFINITY
}

/// [`usable`] as first written (finiteness per component, then the sum), kept for an identity test.
#[cfg(test)]
fn usable_reference(n: [f32; 3]) -> bool {
    n.iter().all(|v| v.is_finite()) && n.iter().map(|v| (*v as f64).powi(2)).sum::<f64>() > 1e-30
}

/// Precise octahedral code of `n` (finite, non-zero): of the four codes around the projection,
/// the one whose decoded vector is closest in angle.
pub fn oct_encode(n: [f32; 3]) -> u16 {
    oct_encode_decoded(n).0
}

/// [`oct_encode`] and the code's decoded vector (`oct_decode` of it, computed anyway).
///
/// Candidates are ranked by their cosine with the input rather than the atan2 angle, at a
/// fraction of the cost (this runs once per encoded node). Nothing is normalised: for the
/// input `n` and each candidate's unnormalised surface point `w`, cos² ∝ (n·w)² / |w|² is
/// compared cross-multiplied in f64 (no square root or division), which orders like the
/// cosine while every n·w > 0; otherwise n·w / |w| is compared. The order matches the
/// angle's except between candidates within rounding (~1e-16 relative) of each other.
pub fn oct_encode_decoded(n: [f32; 3]) -> (u16, [f32; 3]) {
    let p = oct_project(n);
    let (fu, fv) = (super::rounding::floor_f32(p[0]), super::rounding::floor_f32(p[1]));
    let m = [n[0] as f64, n[1] as f64, n[2] as f64];
    let mut cand = [(0u16, 0f64, 0f64); 4];
    for (k, c) in cand.iter_mut().enumerate() {
        let u = (fu + (k >> 1) as f32).clamp(0.0, 255.0) as u16;
        let v = (fv + (k & 1) as f32).clamp(0.0, 255.0) as u16;
        let code = u | v << 8;
        let (d, l2) = dot_len2(m, oct_unnormalized(code));
        *c = (code, d, l2);
    }
    let code = cand[pick_precise(&cand)].0;
    (code, oct_decode(code))
}

/// `m·w` and `|w|²` in f64 (`w` an unnormalised surface point).
#[inline]
fn dot_len2(m: [f64; 3], w: [f32; 3]) -> (f64, f64) {
    let d = m[0] * w[0] as f64 + m[1] * w[1] as f64 + m[2] * w[2] as f64;
    let l2 = (w[0] as f64).powi(2) + (w[1] as f64).powi(2) + (w[2] as f64).powi(2);
    (d, l2)
}

/// Of four candidates `(code, m·w, |w|²)`, the index of the one closest in angle to `m`.
///
/// Rank by cos² = (m·w)² / |w|² (the |m|² factor is common), cross-multiplied: no square root
/// or division per candidate. Valid while every m·w > 0, which holds for these neighbouring
/// codes; otherwise fall back to cosines. The first wins a tie.
#[inline]
fn pick_precise(cand: &[(u16, f64, f64); 4]) -> usize {
    let all_positive = cand.iter().all(|c| c.1 > 0.0);
    let mut best = 0;
    for k in 1..4 {
        let (b, c) = (cand[best], cand[k]);
        let better = if all_positive { c.1 * c.1 * b.2 > b.1 * b.1 * c.2 } else { c.1 / c.2.sqrt() > b.1 / b.2.sqrt() };
        if better {
            best = k;
        }
    }
    best
}

/// Decoded cone semi-angle of `code`.
#[inline]
pub fn cone_decode(code: u8) -> f32 {
    CONE_TABLE[code as usize]
}

/// Decoded cone angles, built at compile time (IEEE arithmetic, the same values as at run time;
/// checked in a test): no lazy-initialisation check on each of the encoder's two lookups a node.
static CONE_TABLE: [f32; 256] = {
    let mut t = [0f32; 256];
    let mut i = 0;
    while i < 256 {
        t[i] = (i as f64 * CONE_STEP) as f32;
        i += 1;
    }
    // f32 π lies above the true π, so code 255 covers the whole sphere.
    t[255] = std::f32::consts::PI;
    t
};

/// Smallest cone code whose decoded angle is at least `need` radians (code 255 = π covers
/// any need, including ≥ π).
pub fn cone_encode_up(need: f64) -> u8 {
    let t = &CONE_TABLE;
    // Also catches NaN.
    if need.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return 0;
    }
    // Start at ⌊need / step⌋ (a multiplication and a truncating cast): the code below it
    // decodes a whole step (far more than the rounding of `t` or of the product) under
    // `need`, so the walk up still stops at the smallest covering code.
    let mut c = ((need * (255.0 / PI)) as usize).min(255);
    while c < 255 && (t[c] as f64) < need {
        c += 1;
    }
    c as u8
}

/// [`cone_encode_up`] as first written (division and `ceil`), kept for an identity test.
#[cfg(test)]
fn cone_encode_up_reference(need: f64) -> u8 {
    let t = &CONE_TABLE;
    if need.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return 0;
    }
    let mut c = (super::rounding::ceil_f64(need / CONE_STEP).clamp(0.0, 255.0) as usize).saturating_sub(1);
    while c < 255 && (t[c] as f64) < need {
        c += 1;
    }
    c as u8
}

/// Encodes a normal cone `(axis, semi-angle)`: returns the octahedral code, its decoded axis
/// and the cone code such that the decoded cone contains the original one (`angle(axis,
/// decoded axis) + cone ≤ decoded cone`, in f64). A zero or non-finite axis is stored as +z
/// with cone π.
pub fn encode_cone_decoded(axis: [f32; 3], cone: f32) -> (u16, [f32; 3], u8) {
    if !usable(axis) {
        let code = oct_encode([0.0, 0.0, 1.0]);
        return (code, oct_decode(code), 255);
    }
    let (code, dec) = oct_encode_decoded(axis);
    (code, dec, cone_code_over(axis, dec, cone))
}

/// `cone_encode_up(cone + angle(axis, dec))` (cone clamped at 0), with the `atan2` of
/// [`angle`] worked out only when needed: from the same f64 cross and dot products,
/// `x = |a×b| / a·b` brackets the angle, `atan x ∈ [x − x³/3, x]` for `x ≥ 0`; when both ends
/// (widened by 1e-12, far more than the rounding of `x` and of `atan2`) round up to the same
/// code, that is the code (`cone_encode_up` is monotone). The codes are identical to the
/// direct evaluation; the bracket decides almost always (normal errors are < 0.64°).
fn cone_code_over(axis: [f32; 3], dec: [f32; 3], cone: f32) -> u8 {
    let base = cone.max(0.0) as f64;
    let a = [axis[0] as f64, axis[1] as f64, axis[2] as f64];
    let b = [dec[0] as f64, dec[1] as f64, dec[2] as f64];
    let c = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    let cn = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
    let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    if dot > 0.0 {
        let x = cn / dot;
        if x < 0.1 {
            let lo = (x - x * x * x / 3.0 - 1e-12).max(0.0);
            let code = cone_encode_up(base + lo);
            // Same code for the upper end iff it covers that too (the smallest code covering
            // `lo` is then the smallest covering anything in between); 255 covers all.
            if code == 255 || CONE_TABLE[code as usize] as f64 >= base + x + 1e-12 {
                return code;
            }
        }
    }
    cone_encode_up(base + angle(axis, dec))
}

/// [`cone_code_over`] for a decoded axis `dec = normalized(w)` whose surface point `w` passed
/// the search's bound test (`m·w > 0`, `(m·w)² ≥ COS2_MAX_ERROR·|m|²·|w|²`, so within 0.64°
/// of `axis`), with a fast path for a cone of 0 (every leaf): the angle is then below the
/// first cone step, since the f32 normalisation moves `w` by < 1e-6 rad and 0.64° + 1e-6 rad
/// < π/255 = 0.706°, so the code is 1, or 0 when the angle is exactly 0. That is when the f64
/// cross product is exactly zero: its products of f32 values are exact, so each difference is
/// zero only for equal products, and a non-zero one cannot vanish when squared (it is far
/// above 1e-150). Checked against [`cone_code_over`] in `cone_toward_matches_reference`.
#[inline]
fn cone_code_within_bound(axis: [f32; 3], dec: [f32; 3], cone: f32) -> u8 {
    // `cone_code_over` uses `cone.max(0.0)`: 0 for a negative or NaN cone too.
    if cone.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        let a = [axis[0] as f64, axis[1] as f64, axis[2] as f64];
        let b = [dec[0] as f64, dec[1] as f64, dec[2] as f64];
        let parallel = a[1] * b[2] == a[2] * b[1] && a[2] * b[0] == a[0] * b[2] && a[0] * b[1] == a[1] * b[0];
        return (!parallel) as u8;
    }
    cone_code_small_angle(axis, dec, cone)
}

/// Largest angle (rad) for which [`cone_code_small_angle`] certifies the next code up: above
/// 0.64° + 1e-6 rad (the search's bound with the f32 rounding), below one cone step minus the
/// f32 rounding of the table (0.0123), and small enough that `atan x ≥ x·(1 − x²/3)` loses less
/// than 1e-4 of `x²`.
const SMALL_ANGLE: f64 = 0.0115;

/// [`cone_code_over`] for `cone > 0` without a square root or division when the angle is
/// small. `c1 = cone_encode_up(cone)` is the smallest code the answer can be; with `room =
/// T[c1] − cone` the answer is `c1` when `x = |a×b| / a·b ≤ room − 1e-12` (`atan x ≤ x`), and
/// `c1 + 1` when `x ≤ SMALL_ANGLE` and `x·(1 − x²/3) > room + 1e-12` (then the angle is above
/// `room` but more than one step below `T[c1 + 1]`). Both are tested squared, `cn²` against
/// `room²·dot²`: the cross product's components and the dot product carry one or two
/// roundings of exact products (relative 1e-16, far inside the 1e-12 margins that
/// [`cone_code_over`]'s bracket also uses for `atan2` and the sum `cone + angle`). Anything
/// else goes to [`cone_code_over`].
#[inline]
fn cone_code_small_angle(axis: [f32; 3], dec: [f32; 3], cone: f32) -> u8 {
    let base = cone as f64;
    let c1 = cone_encode_up(base);
    if c1 == 255 {
        return 255;
    }
    let a = [axis[0] as f64, axis[1] as f64, axis[2] as f64];
    let b = [dec[0] as f64, dec[1] as f64, dec[2] as f64];
    let c = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    let cn2 = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
    let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    if dot > 0.0 {
        let dot2 = dot * dot;
        let room = CONE_TABLE[c1 as usize] as f64 - base;
        let below = room - 1e-12;
        if below > 0.0 && cn2 <= below * below * dot2 {
            return c1;
        }
        let above = room + 1e-12;
        if cn2 <= SMALL_ANGLE * SMALL_ANGLE * dot2 && cn2 > above * above * (1.0 + 1e-4) * dot2 {
            return c1 + 1;
        }
    }
    cone_code_over(axis, dec, cone)
}

/// `cos²` of 0.63999°, written out so that no libm call decides a code: 10⁻⁵° inside
/// [`MAX_NORMAL_ERROR_DEG`], because a code is accepted on its unrounded axis and the f32
/// rounding of the decoded axis moves it by up to 3·10⁻⁶° (at exactly 0.64° a random test
/// found 0.6400000064°).
const COS2_MAX_ERROR: f64 = 0.9998752377928093;

/// Like [`encode_cone_decoded`], but among the codes near the projection (a 4×4 block) whose
/// decoded axis lies within [`MAX_NORMAL_ERROR_DEG`] of `axis`, picks the one of smallest
/// cost `zz(u, û) + zz(v, v̂)` (the residual against the prediction `pred = û | v̂ << 8`), then
/// the closest; the precise code of [`oct_encode`] is the starting point, so it is kept unless
/// another is strictly better. The cone code still rounds up over the actual axis error, so the
/// decoded cone contains the original cone.
///
/// The prediction itself costs 0, so when it lies in the block and within the bound nothing can
/// beat it: that is checked first, before the block is set up (about a third of the bunny's
/// children stop there).
///
/// The inner 2×2 of the block (the precise code's candidates) share their rows' and columns'
/// coordinates (the same f32 operations as [`oct_unnormalized`], so the same values); on the
/// upper hemisphere (`z ≥ 0`, no fold) also the f64 terms `m₀x`, `x²` of a column and `m₁y`,
/// `y²` of a row: `m·w = (m₀x + m₁y) + m₂z` and `|w|² = (x² + y²) + z²` are then the same
/// operations in the same order as [`dot_len2`], so the same values. The outer ring is
/// evaluated directly, and only for candidates that cost no more than the best so far (a
/// candidate costing more is skipped before any floating point).
pub fn encode_cone_toward(axis: [f32; 3], cone: f32, pred: u16, zz: impl Fn(u8, u8) -> u32) -> (u16, [f32; 3], u8) {
    let m = [axis[0] as f64, axis[1] as f64, axis[2] as f64];
    let n2 = m[0] * m[0] + m[1] * m[1] + m[2] * m[2];
    if !usable_len2(n2) {
        return encode_cone_decoded(axis, cone);
    }
    let p = oct_project(axis);
    // A usable axis projects into [0, 255]² (|x|, |y| ≤ 1 after the division by the L1 norm):
    // truncation is the floor there.
    let (iu, iv) = (p[0] as i32, p[1] as i32);
    let bound = COS2_MAX_ERROR * n2;
    // The block's codes are u ∈ [iu − 1, iu + 2] ∩ [0, 255], likewise v.
    let in_block = |c: u16, i: i32| (c as i32 - (i - 1)) as u32 <= 3;
    if in_block(pred & 0xff, iu) && in_block(pred >> 8, iv) {
        let w = oct_unnormalized(pred);
        let (d, l2) = dot_len2(m, w);
        // The search's bound test, negated.
        if !(d <= 0.0 || d * d < bound * l2) {
            let dec = normalized(w);
            return (pred, dec, cone_code_within_bound(axis, dec, cone));
        }
    }
    // iu, iv lie in [0, 255], so clamping in integers gives the float clamp's codes.
    let block = |c: i32| [(c - 1).max(0), c, (c + 1).min(255), (c + 2).min(255)].map(|c| c as u16);
    let (us, vs) = (block(iu), block(iv));
    let cu = us.map(|u| zz(u as u8, pred as u8));
    let cv = vs.map(|v| zz(v as u8, (pred >> 8) as u8));
    // The inner 2×2 (block rows and columns 1 and 2), index 0 or 1 here: 1 - |x|, m₀x, x²
    // (f64) per column, and the same for y per row.
    let xs = [coord(us[1] as u8), coord(us[2] as u8)];
    let ys = [coord(vs[1] as u8), coord(vs[2] as u8)];
    let omx = xs.map(|x| 1.0 - x.abs());
    let mx = xs.map(|x| m[0] * x as f64);
    let my = ys.map(|y| m[1] * y as f64);
    let x2 = xs.map(|x| (x as f64) * (x as f64));
    let y2 = ys.map(|y| (y as f64) * (y as f64));
    // oct_unnormalized of inner code us[1 + i] | vs[1 + j] << 8.
    let surface = |i: usize, j: usize| {
        let (mut x, mut y) = (xs[i], ys[j]);
        let z = omx[i] - y.abs();
        if z < 0.0 {
            let (ox, oy) = (x, y);
            x = (1.0 - oy.abs()) * sgn(ox);
            y = omx[i] * sgn(oy);
        }
        [x, y, z]
    };
    // dot_len2(m, surface(i, j)).
    let dl = |i: usize, j: usize| {
        let z = omx[i] - ys[j].abs();
        if z < 0.0 {
            return dot_len2(m, surface(i, j));
        }
        let z = z as f64;
        (mx[i] + my[j] + m[2] * z, x2[i] + y2[j] + z * z)
    };
    // The precise code: oct_encode_decoded's four candidates are the inner 2×2 of the block.
    let mut cand = [(0u16, 0f64, 0f64); 4];
    for (k, c) in cand.iter_mut().enumerate() {
        let (i, j) = (k >> 1, k & 1);
        let (d, l2) = dl(i, j);
        *c = (us[1 + i] | vs[1 + j] << 8, d, l2);
    }
    let k0 = pick_precise(&cand);
    let (c0, d0, l0) = cand[k0];
    let k0c = cu[1 + (k0 >> 1)] + cv[1 + (k0 & 1)];
    let mut best = (k0c, c0);
    let mut best_ij = (1 + (k0 >> 1), 1 + (k0 & 1));
    // A cost of 0 is the prediction itself: nothing can beat it.
    if k0c > 0 {
        // The best's cosine, needed only against a candidate of equal cost: the precise
        // code's is worked out when first needed.
        let mut best_cos: Option<f64> = None;
        for i in 0..4 {
            // Costs are sums of non-negative row and column terms: a whole row can cost too much.
            if cu[i] > best.0 {
                continue;
            }
            for j in 0..4 {
                let k = cu[i] + cv[j];
                let code = us[i] | vs[j] << 8;
                if k > best.0 || code == best.1 {
                    continue;
                }
                // The inner 2×2 were worked out for the precise code already.
                let (d, l2) = if (1..=2).contains(&i) && (1..=2).contains(&j) {
                    let c = cand[((i - 1) << 1) | (j - 1)];
                    (c.1, c.2)
                } else {
                    dot_len2(m, oct_unnormalized(code))
                };
                if d <= 0.0 || d * d < bound * l2 {
                    continue;
                }
                let c = d / (n2 * l2).sqrt();
                if k < best.0 || c > *best_cos.get_or_insert_with(|| d0 / (n2 * l0).sqrt()) {
                    best = (k, code);
                    best_ij = (i, j);
                    best_cos = Some(c);
                }
            }
        }
    }
    // oct_decode(best.1): the same surface point.
    let (bi, bj) = best_ij;
    let w = if (1..=2).contains(&bi) && (1..=2).contains(&bj) { surface(bi - 1, bj - 1) } else { oct_unnormalized(best.1) };
    let dec = normalized(w);
    // A code other than the precise one passed the bound test to be chosen.
    let within_bound = best.1 != c0 || !(d0 <= 0.0 || d0 * d0 < bound * l0);
    let cone_code = if within_bound { cone_code_within_bound(axis, dec, cone) } else { cone_code_over(axis, dec, cone) };
    (best.1, dec, cone_code)
}

/// The straightforward form of [`encode_cone_toward`] (before its per-row precomputation),
/// kept to check that the fast form picks identical codes.
#[cfg(test)]
fn encode_cone_toward_reference(axis: [f32; 3], cone: f32, pred: u16, zz: impl Fn(u8, u8) -> u32) -> (u16, [f32; 3], u8) {
    if !usable(axis) {
        return encode_cone_decoded(axis, cone);
    }
    let p = oct_project(axis);
    let (fu, fv) = (super::rounding::floor_f32(p[0]), super::rounding::floor_f32(p[1]));
    const D: [f32; 4] = [-1.0, 0.0, 1.0, 2.0];
    let us = D.map(|d| (fu + d).clamp(0.0, 255.0) as u16);
    let vs = D.map(|d| (fv + d).clamp(0.0, 255.0) as u16);
    let xs = us.map(|u| u as f32 / 255.0 * 2.0 - 1.0);
    let ys = vs.map(|v| v as f32 / 255.0 * 2.0 - 1.0);
    let cu = us.map(|u| zz(u as u8, pred as u8));
    let cv = vs.map(|v| zz(v as u8, (pred >> 8) as u8));
    // oct_unnormalized of code us[i] | vs[j] << 8.
    let surface = |i: usize, j: usize| {
        let (mut x, mut y) = (xs[i], ys[j]);
        let z = 1.0 - x.abs() - y.abs();
        if z < 0.0 {
            let (ox, oy) = (x, y);
            x = (1.0 - oy.abs()) * sgn(ox);
            y = (1.0 - ox.abs()) * sgn(oy);
        }
        [x, y, z]
    };
    let m = [axis[0] as f64, axis[1] as f64, axis[2] as f64];
    // The precise code: oct_encode_decoded's four candidates are the inner 2×2 of the block.
    let mut cand = [(0u16, 0f64, 0f64); 4];
    for (k, c) in cand.iter_mut().enumerate() {
        let (i, j) = (1 + (k >> 1), 1 + (k & 1));
        let (d, l2) = dot_len2(m, surface(i, j));
        *c = (us[i] | vs[j] << 8, d, l2);
    }
    let k0 = pick_precise(&cand);
    let (c0, d0, l0) = cand[k0];
    let k0c = cu[1 + (k0 >> 1)] + cv[1 + (k0 & 1)];
    let mut best = (k0c, c0);
    // A cost of 0 is the prediction itself: nothing can beat it.
    if k0c > 0 {
        let n2 = m[0] * m[0] + m[1] * m[1] + m[2] * m[2];
        let mut best_cos = d0 / (n2 * l0).sqrt();
        for i in 0..4 {
            for j in 0..4 {
                let k = cu[i] + cv[j];
                let code = us[i] | vs[j] << 8;
                if k > best.0 || code == best.1 {
                    continue;
                }
                let (d, l2) = dot_len2(m, surface(i, j));
                if d <= 0.0 || d * d < COS2_MAX_ERROR * n2 * l2 {
                    continue;
                }
                let c = d / (n2 * l2).sqrt();
                if k < best.0 || c > best_cos {
                    best = (k, code);
                    best_cos = c;
                }
            }
        }
    }
    let dec = oct_decode(best.1);
    (best.1, dec, cone_code_over(axis, dec, cone))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(i: u64) -> [f32; 3] {
        // Deterministic quasi-random directions (golden-ratio spiral) plus jitter.
        let n = 2_000_000u64;
        let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
        let r = (1.0 - z * z).sqrt();
        let phi = i as f64 * 2.399963229728653;
        [(r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32]
    }

    #[test]
    fn normal_error_bound() {
        let mut worst = 0f64;
        let mut sum = 0f64;
        let n = 2_000_000u64;
        for i in 0..n {
            let v = unit(i);
            let a = angle(v, oct_decode(oct_encode(v)));
            worst = worst.max(a);
            sum += a;
        }
        for v in [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 1.0, -1e-7], [-0.577, 0.577, 0.577]] {
            worst = worst.max(angle(v, oct_decode(oct_encode(v))));
        }
        let worst_deg = worst.to_degrees();
        eprintln!("oct16 worst {worst_deg:.4} deg, mean {:.4} deg", (sum / n as f64).to_degrees());
        assert!(worst_deg <= MAX_NORMAL_ERROR_DEG, "{worst_deg}");
    }

    #[test]
    fn every_code_decodes_to_unit() {
        for c in 0..=u16::MAX {
            let v = oct_decode(c);
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            assert!((l - 1.0).abs() < 1e-6, "{c}");
            // Codes on the grid map back to themselves or an equivalent (seam) code.
            assert!(angle(v, oct_decode(oct_encode(v))) < 1e-6);
        }
    }

    /// The bracketed cone code equals the direct `atan2` evaluation.
    #[test]
    fn cone_code_over_matches_atan2() {
        let mut differ = 0;
        for i in 0..400_000u64 {
            let v = unit(i * 5);
            let cone = [0.0f32, 1e-3, 0.3, (i % 255) as f32 * (CONE_STEP as f32), 3.0][(i % 5) as usize];
            for dec in [oct_decode(oct_encode(v)), oct_decode(oct_encode(v) ^ 0x0101), oct_decode(oct_encode(v).wrapping_add(3)), v] {
                let want = cone_encode_up(cone.max(0.0) as f64 + angle(v, dec));
                assert_eq!(cone_code_over(v, dec, cone), want, "{v:?} {dec:?} {cone}");
                differ += (cone_encode_up(cone as f64) != want) as u32;
            }
        }
        assert!(differ > 1000);
    }

    /// The compile-time coordinate table holds what run-time arithmetic gives.
    #[test]
    fn oct_coord_table_matches_run_time() {
        let k = std::hint::black_box(255.0f32);
        for c in 0..=255u8 {
            assert_eq!(coord(c).to_bits(), (c as f32 / k * 2.0 - 1.0).to_bits(), "{c}");
        }
    }

    /// The small-angle cone code equals the `atan2` evaluation for decoded axes within the
    /// search's bound, for random cones and for cones placed so that cone + angle lands within
    /// ±1e-9 of a table value (both certificates and the fallback are taken).
    #[test]
    fn cone_code_small_angle_matches_atan2() {
        let mut rng = crate::rng::SplitMix64(0x0C0E_5A11_A6E1_0001);
        let (mut low, mut high) = (0u32, 0u32);
        for i in 0..300_000u64 {
            let v = unit(i * 6);
            let code = oct_encode(v);
            let r = rng.next_u64();
            // The precise code and neighbours that stay within the bound.
            let cands = [code, code.wrapping_add(1), code.wrapping_sub(1), code.wrapping_add(256), code.wrapping_sub(256)];
            let dec = oct_decode(cands[(r % 5) as usize]);
            let theta = angle(v, dec);
            if theta.is_nan() || theta > 0.0112 {
                continue;
            }
            let cone = match (r >> 8) % 4 {
                0 => (rng.next_f64() * 3.2) as f32,
                1 => (r >> 16) as u8 as f32 * CONE_STEP as f32,
                _ => {
                    // cone + theta near the table value of a random code.
                    let k = 1 + ((r >> 16) % 250) as usize;
                    let off = (rng.next_f64() - 0.5) * 2e-9;
                    (CONE_TABLE[k] as f64 - theta + off) as f32
                }
            };
            if cone.is_nan() || cone <= 0.0 {
                continue;
            }
            let want = cone_encode_up(cone as f64 + theta);
            let got = cone_code_small_angle(v, dec, cone);
            assert_eq!(got, want, "{v:?} {dec:?} {cone}");
            assert_eq!(got, cone_code_over(v, dec, cone));
            let c1 = cone_encode_up(cone as f64);
            low += (got == c1) as u32;
            high += (got == c1 + 1) as u32;
        }
        assert!(low > 10_000 && high > 10_000, "{low} {high}");
    }

    /// `round_projected` equals `round_byte_f32` on [0, 255] (every 97th float, and ±8 ulps
    /// around every half-integer) and NaN, and `oct_project` stays in that set for special and
    /// random bit-pattern inputs.
    #[test]
    fn round_projected_matches_round_byte() {
        let check = |v: f32| assert_eq!(round_projected(v), crate::codec::rounding::round_byte_f32(v) as u16, "{v}");
        let mut b = 0u32;
        while b <= 255f32.to_bits() {
            check(f32::from_bits(b));
            b += 97;
        }
        for h in 0..=510 {
            let x = h as f32 * 0.5;
            let (mut up, mut down) = (x, x);
            for _ in 0..8 {
                check(up);
                check(down);
                up = up.next_up();
                down = down.next_down().max(0.0);
            }
        }
        check(f32::NAN);
        let in_range = |v: f32| v.is_nan() || (0.0..=255.0).contains(&v);
        let special = [0.0f32, -0.0, 1e-45, -1.0, 1.0, 3e38, -3.4e38, f32::INFINITY, f32::NEG_INFINITY, f32::NAN];
        for &a in &special {
            for &b in &special {
                for &c in &special {
                    let p = oct_project([a, b, c]);
                    assert!(in_range(p[0]) && in_range(p[1]), "{a} {b} {c}: {p:?}");
                }
            }
        }
        let mut rng = crate::rng::SplitMix64(0x0C7A_11ED_0000_0003);
        for _ in 0..1_000_000 {
            let r = rng.next_u64();
            let n = [f32::from_bits(r as u32), f32::from_bits((r >> 32) as u32), f32::from_bits((r >> 16) as u32)];
            let p = oct_project(n);
            assert!(in_range(p[0]) && in_range(p[1]), "{n:?}: {p:?}");
        }
    }

    /// The compile-time table holds what run-time arithmetic gives.
    #[test]
    fn cone_table_matches_run_time() {
        let step = std::hint::black_box(PI) / 255.0;
        for (i, &v) in CONE_TABLE.iter().enumerate().take(255) {
            assert_eq!(v.to_bits(), ((i as f64 * step) as f32).to_bits(), "{i}");
        }
        assert_eq!(CONE_TABLE[255], std::f32::consts::PI);
    }

    /// The multiply-and-walk cone code equals the division-and-ceil one, around every code
    /// boundary and at random.
    #[test]
    fn cone_encode_up_matches_reference() {
        let mut needs = vec![f64::NAN, -1.0, 0.0, -0.0, 1e-300, 3.2, 4.0, 1e300, f64::INFINITY, PI, std::f32::consts::PI as f64];
        for &b in CONE_TABLE.iter() {
            let b = b as f64;
            let (mut up, mut down) = (b, b);
            for _ in 0..4 {
                needs.extend([up, down]);
                up = up.next_up();
                down = down.next_down();
            }
        }
        let mut rng = crate::rng::SplitMix64(0x1234_5678_9ABC_DEF1);
        needs.extend((0..1_000_000).map(|_| rng.next_f64() * 3.3));
        for need in needs {
            assert_eq!(cone_encode_up(need), cone_encode_up_reference(need), "{need}");
        }
    }

    #[test]
    fn cone_rounds_up() {
        for i in 0..10_000 {
            let need = i as f64 / 10_000.0 * 3.2;
            let c = cone_encode_up(need);
            assert!(cone_decode(c) as f64 >= need || c == 255);
            if c > 0 && c < 255 {
                assert!((cone_decode(c - 1) as f64) < need);
            }
        }
        assert_eq!(cone_encode_up(0.0), 0);
        assert_eq!(cone_encode_up(10.0), 255);
        assert_eq!(cone_decode(255), std::f32::consts::PI);
    }

    /// The one-sum `usable` equals the per-component form on special, tiny, huge and random
    /// components.
    #[test]
    fn usable_matches_reference() {
        let special = [0.0f32, -0.0, 1.0, -1.0, 1e-15, 1e-16, -7e-16, 1e-20, 1e-45, 3e38, -3.4e38, f32::MAX, f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
        for &a in &special {
            for &b in &special {
                for &c in &special {
                    assert_eq!(usable([a, b, c]), usable_reference([a, b, c]), "{a} {b} {c}");
                }
            }
        }
        let mut rng = crate::rng::SplitMix64(0x1357_9BDF_2468_ACE0);
        for _ in 0..1_000_000 {
            let r = rng.next_u64();
            // Random bit patterns: every exponent, NaNs and infinities included.
            let v = [f32::from_bits(r as u32), f32::from_bits((r >> 32) as u32), f32::from_bits((r >> 16) as u32 ^ 0x3000_0000)];
            assert_eq!(usable(v), usable_reference(v), "{v:?}");
            // Lengths around the 1e-15 threshold.
            let w = v.map(|x| if x.is_finite() { x.abs().min(1.0) * 1e-15 } else { x });
            assert_eq!(usable(w), usable_reference(w), "{w:?}");
        }
    }

    /// The fast 4×4 search picks the same code, decoded axis and cone code as the
    /// straightforward one, for random, axis-aligned and equator directions and predictions.
    #[test]
    fn cone_toward_matches_reference() {
        let mut rng = crate::rng::SplitMix64(0x2545_F491_4F6C_DD1D);
        let mut rnd = || rng.next_u64();
        let zz = |a: u8, b: u8| {
            let d = a.wrapping_sub(b) as i8 as i32;
            (if d >= 0 { 2 * d } else { -2 * d - 1 }) as u32
        };
        let mut axes: Vec<[f32; 3]> = (0..400_000).map(|i| unit(i * 5)).collect();
        for _ in 0..200_000 {
            let r = rnd();
            let f = |s: u32| ((r >> s) as u16 as f32 / 65535.0 * 2.0 - 1.0) * if (r >> (s + 16)) & 3 == 0 { 1e-3 } else { 1.0 };
            axes.push([f(0), f(16), f(32)]);
        }
        axes.extend([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 1.0, -1e-7], [-0.577, 0.577, 0.577], [0.0; 3]]);
        // Axes exactly on a decoded code (angle 0: cone code 0 for a zero cone), and multiples.
        for _ in 0..100_000 {
            let d = oct_decode(rnd() as u16);
            axes.extend([d, d.map(|v| v * 2.0), d.map(|v| v * 0.375)]);
        }
        let mut exact_zero = 0;
        for a in axes {
            let r = rnd();
            let near = oct_encode(if usable(a) { a } else { [0.0, 0.0, 1.0] });
            let pred = match r & 3 {
                0 => r as u16,
                1 => near,
                _ => {
                    let du = ((r >> 8) % 9) as u8;
                    let dv = ((r >> 16) % 9) as u8;
                    ((near as u8).wrapping_add(du).wrapping_sub(4)) as u16 | (((near >> 8) as u8).wrapping_add(dv).wrapping_sub(4) as u16) << 8
                }
            };
            // Leaves have cone 0: half the cases (also -0.0 and a negative cone).
            let cone = match (r >> 32) & 7 {
                0..=2 => 0.0,
                3 => [-0.0, -0.25][((r >> 36) & 1) as usize],
                _ => ((r >> 24) as u8) as f32 / 255.0,
            };
            let got = encode_cone_toward(a, cone, pred, zz);
            let want = encode_cone_toward_reference(a, cone, pred, zz);
            assert_eq!(got.0, want.0, "{a:?} {pred}");
            assert_eq!(got.1.map(f32::to_bits), want.1.map(f32::to_bits), "{a:?} {pred}");
            assert_eq!(got.2, want.2, "{a:?} {pred}");
            exact_zero += (want.2 == 0) as u32;
            assert_eq!(want.1.map(f32::to_bits), oct_decode(want.0).map(f32::to_bits));
        }
        // Zero cones on exactly decodable axes: the angle-0 case of the zero-cone fast path.
        assert!(exact_zero > 10_000, "{exact_zero}");
    }
}
