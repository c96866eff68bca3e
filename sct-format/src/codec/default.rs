//! The default profile: canopy's quantizers, reorganised into byte-aligned attribute streams
//! predicted from the decoded parent (and, for the second child, from the first), with the
//! area stored as a fraction of the parent's. The container zstd-compresses the payload.
//!
//! Position/radius, normal, cone and colour use exactly canopy's quantizers, so containment,
//! the stick-out slack, the 0.64° normal bound, the round-up cone and the ≤ 4/2/4/8 colour
//! steps hold unchanged; predictions change the bytes, never the values. The encoder uses its
//! freedom where it costs no bound (spec/SCT-profiles.md §1.1, §1.2, §3): of equally tight
//! position/radius states it stores the one whose bytes are most frequent in the block (the
//! centre error may then exceed canopy's 0.144 parent radii, the radius does not change); of
//! the normal codes within 0.64° the one closest to the prediction; area codes on a coarser
//! grid for balanced pairs. The area is lossy (bound below).
//!
//! # Block payload (n parents, m = 2n children, child `2k` = A, `2k+1` = B of parent `k`)
//!
//! Streams follow each other without padding or headers; each holds one byte per child
//! (per pair for the area), in child order:
//!
//! | stream | bytes | content |
//! |---|---|---|
//! | 1 | m | state low byte |
//! | 2 | m | state high byte (state < 6821, as canopy) |
//! | 3 | m | `zz(u - û)`: octahedral `u` residual |
//! | 4 | m | `zz(v - v̂)`: octahedral `v` residual |
//! | 5 | m | cone code (canopy's) |
//! | 6 | m | `zz5(r - r̂)` 5-bit red code residual |
//! | 7 | m | `zz6(g - ĝ)` 6-bit green code residual |
//! | 8 | m | `zz5(b - b̂)` 5-bit blue code residual |
//! | 9 (alpha only) | m | `zz4(a - â)` 4-bit alpha code residual |
//! | 10 | n | area code low byte |
//! | 11 | n | area code high byte (code ≤ 4096) |
//!
//! | 12 (centre offsets only) | m | `zz8(s)`: the child's centre moved by `s · r_P / 128` along its decoded normal |
//! | 13, 14, 15 (leaf refinement only) | m each | `zz8(dx)`, `zz8(dy)`, `zz8(dz)`: the child's centre moved by `(dx, dy, dz) · r_C / 128` |
//! | 16 (leaf refinement only) | m | `k`: the child's radius scaled by `(256 − k) / 256` |
//!
//! Total `8m + 2n` bytes (`9m + 2n` with alpha), i.e. 9 (10) bytes per child before zstd,
//! `m` more with centre offsets (1.2, tree flag bit 2) and `4m` more with leaf refinement
//! (1.4, tree flag bit 3).
//!
//! # Centre offsets (1.2)
//!
//! The position/radius state puts a child's centre on a grid of `r_P / 6` steps, so a leaf's
//! centre may lie up to about a fifth of its parent's radius off the surface it stands for; a
//! renderer draws it there (outlines grow, planes get relief). With tree flag bit 2 every child
//! also carries a signed byte `s`: its centre moves by `s · r_P / 128` along its decoded
//! normal, which brings a leaf back onto its surface to within `r_P / 256` (plus the tangential
//! error times the normal's error). The encoder picks the `s` that best cancels the centre error
//! along the normal, and only values that keep the original child contained and the decoded
//! child inside the stick-out slack of its parent, so every bound below is unchanged. It refines
//! leaves only and stores 0 for nodes with children ([`encode_with_leaves`]); a decoder
//! applies whatever is stored. When a leaf's moved centre still lies more than `r/128` (its
//! own radius) off its tangent plane, the encoder tries the same radius code at the
//! neighbouring grid points, whose offsets end at other fractions of a step
//! ([`pick_state_near_plane`]): voxelized planes then hold their leaves within 1 % of the
//! voxel.
//!
//! # Leaf refinement (1.4)
//!
//! The state's grid and its radius steps are relative to the parent, so a leaf is stored up
//! to a fifth of its parent's radius off its true place and with a radius that grows to
//! contain it anyway: on the voxelized bunny the decoded leaf radius is 1.23× the sample's
//! (median; 1.5× at the 90th percentile). Where each leaf carries its own colour (point
//! clouds: every point is a measurement) that misplaces and widens every splat. With tree flag
//! bit 3 every child also carries three signed bytes `(dx, dy, dz)` and a byte `k`: after the
//! state (and the centre offset, if any) is decoded with radius `r_C`, its centre moves by
//! `(dx, dy, dz) · r_C / 128` and its radius becomes `r_C · (256 − k) / 256`. The unit is the
//! child's own decoded radius, so any centre error a state allows (less than `r_C`) can be
//! cancelled to within `r_C / 256` per axis, however small the leaf is against its parent.
//! The encoder refines leaves only (0 elsewhere), picks the step nearest to the centre error
//! on each axis and the smallest radius that still contains the original child, and, like
//! centre offsets, keeps the child inside the stick-out slack of its parent and encodable
//! under it; so every bound below holds as written.
//!
//! # Leaf refinement where it is needed (1.2 and 1.4 together)
//!
//! Refining every leaf of a mesh costs 1.36–1.75× the file, and most leaves gain little: a
//! centre moved along its own flat piece of surface still lies on the surface. What hurts is
//! a centre moved past the piece's edge, e.g. past a face's convex edge, where it reads as
//! distance from the mesh. A tree with both flags stores centre offsets for every leaf and
//! a nonzero refinement only for the leaves whose centre lies off their piece
//! ([`refine::tangential_error`]) and whose parent does not show a smoothly curved surface, where
//! the neighbouring pieces continue the surface ([`refine::lands_on_its_neighbours`]); those are
//! moved just back onto their piece ([`refine::pick_nudge`]). The others store zeros, which zstd
//! packs to almost nothing. A decoder needs no rule for this: it applies the offset, then
//! the refinement, as stored.
//!
//! `zzb(d)`: the difference taken modulo `2^b`, read as a signed value in `[-2^(b-1),
//! 2^(b-1))`, zigzag-mapped (`0,-1,1,-2,… → 0,1,2,3,…`). A byte ≥ `2^b` is malformed.
//!
//! Predictions (all f32/f64 IEEE arithmetic, deterministic):
//! - Areas first: `a_A = A_P · (code / 4096)` (f32), `a_B = A_P − a_A` (f32), so siblings
//!   sum to the parent's decoded area.
//! - Normal of A: `oct_fast(n_P)`; of B: `oct_fast(2(n_P·n_A)n_P − n_A)` (the reflection of
//!   A's decoded axis about the parent's, exact when the parent axis bisects the children's
//!   as EQ 11–12 does for equal cones), falling back to `n_P` when that is zero. `oct_fast`
//!   rounds the octahedral projection to the nearest code; an unusable parent axis predicts +z.
//! - Colour of A: the parent's colour quantized; of B: `(A_P·c_P − a_A·c_A) / a_B` (EQ 14
//!   solved for B with decoded values, f64, rounded, clamped to [0, 255]) quantized, or the
//!   parent's colour when `a_B ≤ 0`.
//!
//! # Area bound
//!
//! The stored fraction is `4096·a/(a+b)` rounded to a step of 1 to 8 codes ([`area_code`]), so
//! each level moves a child's fraction by at most `4/4096` and by at most 1/32 of the smaller
//! child's fraction; decoded siblings sum exactly (up to one f32 rounding) to their decoded
//! parent. Errors accumulate with depth (measured in `examples/rate_distortion.rs`).

mod refine;

use refine::{pick_nudge, pick_refinement, put_refinement};

use super::canopy::{check_child, check_parent, color_codes, sphere_ties, Codes};
use super::{color, normal, posrad, CodecParams};
use crate::error::{Error, Result};
use crate::node::Node;

/// Same bound as canopy: the same position/radius states are used.
pub const CONTAINMENT_SLACK: f32 = super::canopy::CONTAINMENT_SLACK;

/// Area fraction denominator.
const AREA_ONE: u16 = 4096;

/// Most a level moves a child's area fraction (of its decoded parent's area) in this
/// encoder: half the coarsest step of [`area_code`], 8 codes of 4096 (see "Area bound").
pub const AREA_FRACTION_ERROR: f64 = 4.0 / 4096.0;

/// Zigzag of a `bits`-bit wrapped difference (`bits` in 1..=8), without branches: the
/// difference is sign-extended from `bits` bits by shifts, then `2s` or `-2s-1` is `(s << 1)
/// ^ (s >> 31)`. The encoder takes 13 a child.
#[inline]
fn zz(code: u8, pred: u8, bits: u32) -> u8 {
    let d = (code as u32).wrapping_sub(pred as u32);
    let s = ((d << (32 - bits)) as i32) >> (32 - bits);
    ((s << 1) ^ (s >> 31)) as u8
}

/// [`zz`] as first written, kept for an identity test.
#[cfg(test)]
fn zz_reference(code: u8, pred: u8, bits: u32) -> u8 {
    let m = (1u32 << bits) - 1;
    let d = (code as u32).wrapping_sub(pred as u32) & m;
    let half = 1u32 << (bits - 1);
    let s = if d >= half { d as i32 - (1 << bits) } else { d as i32 };
    (if s >= 0 { 2 * s } else { -2 * s - 1 }) as u8
}

/// Inverse of [`zz`]; `None` when the byte is out of range.
fn unzz(z: u8, pred: u8, bits: u32) -> Option<u8> {
    if (z as u32) >> bits != 0 {
        return None;
    }
    let s = if z & 1 == 0 { (z >> 1) as i32 } else { -((z >> 1) as i32) - 1 };
    Some(((pred as i32 + s) & ((1 << bits) - 1)) as u8)
}

/// The parent's share of both normal predictions, worked out once per pair: whether its
/// axis is usable, and A's prediction (also B's fallback).
#[derive(Clone, Copy)]
struct ParentAxis {
    usable: bool,
    pred_a: u16,
}

fn parent_axis(p: &Node) -> ParentAxis {
    let usable = normal::usable(p.normal);
    let pred_a = if usable { normal::oct_encode_fast(p.normal) } else { normal::oct_encode_fast([0.0, 0.0, 1.0]) };
    ParentAxis { usable, pred_a }
}

/// B's prediction from the parent `p` (with `pa = parent_axis(p)`) and A's decoded axis `a`.
fn pred_normal_b(p: &Node, pa: ParentAxis, a: [f32; 3]) -> u16 {
    let n = p.normal;
    if !pa.usable {
        return pa.pred_a;
    }
    let l2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2];
    let d = 2.0 * (n[0] * a[0] + n[1] * a[1] + n[2] * a[2]) / l2;
    let r = [d * n[0] - a[0], d * n[1] - a[1], d * n[2] - a[2]];
    if normal::usable(r) {
        normal::oct_encode_fast(r)
    } else {
        pa.pred_a
    }
}

/// The predictions as first written (each re-checking the parent), kept for an identity test.
#[cfg(test)]
fn pred_normal_a_reference(p: &Node) -> u16 {
    if normal::usable(p.normal) {
        normal::oct_encode_fast(p.normal)
    } else {
        normal::oct_encode_fast([0.0, 0.0, 1.0])
    }
}

/// See [`pred_normal_a_reference`].
#[cfg(test)]
fn pred_normal_b_reference(p: &Node, a: [f32; 3]) -> u16 {
    let n = p.normal;
    if !normal::usable(n) {
        return pred_normal_a_reference(p);
    }
    let l2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2];
    let d = 2.0 * (n[0] * a[0] + n[1] * a[1] + n[2] * a[2]) / l2;
    let r = [d * n[0] - a[0], d * n[1] - a[1], d * n[2] - a[2]];
    if normal::usable(r) {
        normal::oct_encode_fast(r)
    } else {
        pred_normal_a_reference(p)
    }
}

/// Only the first `ch` channels are predicted (the others are not stored). `(area_a, area_b)`
/// must be `areas(p, code)`.
///
/// A channel of A equal to the parent's predicts the parent's value without the division: with
/// `area_b > 0` the parent's area is finite and positive and `area_a` lies in `[0, A_P]`, so
/// `(A_P·c − a_A·c) / a_B` is `c·(A_P − a_A) / a_B` up to one f64 rounding of exact products,
/// and `a_B` is the f32 rounding of `A_P − a_A`: the quotient is within `c·2⁻²³ < 1/2` of `c`.
fn pred_color_b(p: &Node, area_a: f32, area_b: f32, ca: [u8; 4], ch: usize) -> [u8; 4] {
    // Also catches NaN.
    if area_b.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return p.color;
    }
    let (ap, aa, ab) = (p.area as f64, area_a as f64, area_b as f64);
    let mut out = [0u8; 4];
    for i in 0..ch {
        out[i] = if ca[i] == p.color[i] {
            p.color[i]
        } else {
            // NaN (hostile parent area) clamps to 0 via `as`; no panic.
            super::rounding::round_byte_f64((ap * p.color[i] as f64 - aa * ca[i] as f64) / ab)
        };
    }
    out
}

/// [`pred_color_b`] as first written (a division per channel), kept for an identity test.
#[cfg(test)]
fn pred_color_b_reference(p: &Node, area_a: f32, area_b: f32, ca: [u8; 4], ch: usize) -> [u8; 4] {
    if area_b.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return p.color;
    }
    let (ap, aa, ab) = (p.area as f64, area_a as f64, area_b as f64);
    let mut out = [0u8; 4];
    for i in 0..ch {
        let v = (ap * p.color[i] as f64 - aa * ca[i] as f64) / ab;
        out[i] = super::rounding::round_byte_f64(v);
    }
    out
}

fn quant4(c: [u8; 4]) -> [u8; 4] {
    color_codes(c)
}

fn areas(p: &Node, code: u16) -> (f32, f32) {
    let a = p.area * (code as f32 / AREA_ONE as f32);
    (a, (p.area - a).max(0.0))
}

/// The stored area code of a pair with areas `a`, `b` (informative: any code ≤ 4096 decodes).
///
/// The fraction `x = 4096·a/(a+b)` is rounded to the nearest multiple of a step that depends
/// on the smaller side `s = min(x, 4096 − x)`: [`AREA_STEP`] (8) when `s ≥ 128`, else the
/// largest power of two ≤ `s/16` (at least 1). Balanced pairs thus use one code in 8 (3 bits
/// less to store; the fraction is off by ≤ 4/4096) while a step never exceeds 1/16 of the
/// smaller side, so a level adds at most 1/32 relative error to the smaller child (and slivers
/// below 16/4096 keep the full resolution).
fn area_code(a: f32, b: f32) -> u16 {
    let sum = a as f64 + b as f64;
    // Also catches NaN.
    if sum.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return AREA_ONE / 2;
    }
    let x = (a as f64 / sum * AREA_ONE as f64).clamp(0.0, AREA_ONE as f64);
    let side = x.min(AREA_ONE as f64 - x);
    // floor(log2(side)) - 4, from the integer part (no libm call); side < 16 → step 1.
    let whole = side as u32;
    let shift = if whole >= 16 { (whole.ilog2() - 4).min(AREA_STEP.ilog2()) } else { 0 };
    let step = (1u32 << shift) as f64;
    (super::rounding::round_f64(x / step) * step).clamp(0.0, AREA_ONE as f64) as u16
}

/// Coarsest area code step (see [`area_code`]).
const AREA_STEP: u32 = 8;

/// Counts of the state's low and high bytes over a block's reference choices.
struct StateHistogram {
    low: [u32; 256],
    high: [u32; 256],
}

impl Default for StateHistogram {
    fn default() -> Self {
        StateHistogram { low: [0; 256], high: [0; 256] }
    }
}

impl StateHistogram {
    fn add(&mut self, s: u16) {
        self.low[(s & 0xff) as usize] += 1;
        self.high[(s >> 8) as usize] += 1;
    }

    /// Proportional to the probability of `s` when the two byte streams are coded on their
    /// own (order 0): a larger weight costs fewer bits. Exact integers, so the choice does not
    /// depend on floating point.
    fn weight(&self, s: u16) -> u64 {
        (self.low[(s & 0xff) as usize] as u64 + 1) * (self.high[(s >> 8) as usize] as u64 + 1)
    }
}

/// Of equally tight states, the one whose bytes are most frequent in the block (the first on
/// a tie, i.e. the reference choice).
fn pick_state(t: &super::posrad::Ties, hist: &StateHistogram) -> u16 {
    let mut best = (hist.weight(t.states[0]), t.states[0]);
    for &s in &t.as_slice()[1..] {
        let w = hist.weight(s);
        if w > best.0 {
            best = (w, s);
        }
    }
    best.1
}

fn channels(params: CodecParams) -> usize {
    if params.alpha {
        4
    } else {
        3
    }
}

/// Payload size for `n` parents.
pub(crate) fn payload_len(params: CodecParams, n: usize) -> Option<usize> {
    let m = n.checked_mul(2)?;
    let per_child = 5 + channels(params) + params.centre_offsets as usize + 4 * params.leaf_refinement as usize;
    m.checked_mul(per_child)?.checked_add(n.checked_mul(2)?)
}

/// Denominator of a leaf refinement's centre step: one step is `r_C / 128`.
const REFINE_STEPS: f32 = 128.0;

/// Moves `node`'s centre by `d · r_C / 128` and scales its radius by `(256 − k) / 256`, in
/// f32 in the order written (spec/SCT-profiles.md §3): the one definition the encoder and
/// decoder share.
#[inline]
fn apply_refinement(node: &mut Node, d: [i8; 3], k: u8) {
    let unit = node.radius / REFINE_STEPS;
    for (c, &s) in node.center.iter_mut().zip(&d) {
        if s != 0 {
            *c += s as f32 * unit;
        }
    }
    if k != 0 {
        node.radius = node.radius * (256 - k as u32) as f32 / 256.0;
    }
}

/// Whether `moved` may replace the decoded child of `p` for original `orig`: it contains
/// the original, is finite, lies within the stick-out bound of `p` and is itself encodable
/// under `p` (a decoded tree written again must encode). `near` is the state `moved` was
/// moved from (where its encodability is tried first).
fn acceptable(p: &Node, orig: &Node, moved: &Node, near: u16) -> bool {
    let bound = posrad::stick_out_bound() as f32;
    moved.center.iter().all(|c| c.is_finite())
        && moved.radius.is_finite()
        && crate::geometry::sphere_contains(moved, orig, 0.0)
        && crate::geometry::sphere_contains(p, moved, bound)
        && posrad::encodable_near(near, p.center, p.radius, moved.center, moved.radius)
}

/// Denominator of a centre offset: one step is `r_P / 128`.
const OFFSET_STEPS: f32 = 128.0;

/// Moves `node`'s centre by `s · r_P / 128` along its (decoded, unit) normal, in f32 in the
/// order written (spec/SCT-profiles.md §3): the one definition the encoder and decoder share.
#[inline]
fn apply_offset(node: &mut Node, s: i8, parent_radius: f32) {
    if s == 0 {
        return;
    }
    let t = s as f32 * parent_radius / OFFSET_STEPS;
    for (c, n) in node.center.iter_mut().zip(node.normal) {
        *c += t * n;
    }
}

/// The centre offset for decoded child `dec` (of state `state`) of original `orig` under
/// parent `p`, with the child it decodes to: the step
/// count nearest to the centre error along the decoded normal, walked back toward 0 until the
/// moved child still contains the original, stays within the stick-out bound of `p` and is
/// itself encodable under `p` (0 always qualifies: it is the child as decoded without
/// offsets).
fn pick_offset(p: &Node, orig: &Node, dec: &Node, state: u16) -> (i8, Node) {
    let step = p.radius as f64 / OFFSET_STEPS as f64;
    if step.is_nan() || step <= 0.0 || !step.is_finite() {
        return (0, *dec);
    }
    let along: f64 = (0..3).map(|a| (orig.center[a] as f64 - dec.center[a] as f64) * dec.normal[a] as f64).sum();
    let want = (along / step).round();
    if !want.is_finite() {
        return (0, *dec);
    }
    let mut s = want.clamp(i8::MIN as f64, i8::MAX as f64) as i8;
    while s != 0 {
        let mut moved = *dec;
        apply_offset(&mut moved, s, p.radius);
        // Within the stick-out bound, and encodable itself: a decoded tree written again
        // must encode, and a child off the state grid that sticks out of its parent may fit
        // no state.
        if acceptable(p, orig, &moved, state) {
            return (s, moved);
        }
        s -= s.signum();
    }
    (0, *dec)
}

/// Unit vector of `n` in f64, or `None` when it has no usable direction.
fn unit64(n: [f32; 3]) -> Option<[f64; 3]> {
    if !normal::usable(n) {
        return None;
    }
    let l = (0..3).map(|a| n[a] as f64 * n[a] as f64).sum::<f64>().sqrt();
    Some([n[0] as f64 / l, n[1] as f64 / l, n[2] as f64 / l])
}

/// `(c - orig.center) · n` in f64: the signed distance of `c` from the plane through the
/// original centre normal to unit `n`.
fn plane_error(orig: &Node, n: [f64; 3], c: [f32; 3]) -> f64 {
    (0..3).map(|a| (c[a] as f64 - orig.center[a] as f64) * n[a]).sum()
}

/// How far from its tangent plane the encoder leaves a leaf before it looks at other states:
/// `r / 128` of the original leaf's radius `r` (a voxel sample's radius is 0.7–1 voxel, so
/// under 1 % of the voxel).
const PLANE_STEPS: f64 = 128.0;

/// The state and centre offset of leaf `orig` under parent `p`, given the first choice
/// `s0` (decoding to `plain` without and to `first` with its offset): when `first`'s centre
/// lies farther than `tol` from the plane through the original centre normal to the
/// original normal (the surface itself, on a planar piece), the state of the same radius
/// code at a neighbouring grid point whose nearest offset lands within `tol` of that plane
/// (preferring one that leaves the error along the plane as `first` left it, then the one
/// with the most frequent state bytes, `weight`), else the one that lands nearest, if nearer
/// than `first`.
///
/// The offset's step is `r_P / 128`, so the first choice may leave up to `r_P / 256` along
/// the normal. A neighbour's grid point lies `r_P / 6` (21⅓ steps) away along each axis, so
/// its offset ends at another fraction of a step: for an axis-aligned plane the three grid
/// points along the normal leave at most `r_P / 768`. Each candidate keeps the documented
/// rule for its offset (the step nearest along its decoded normal, which never ends farther
/// along that normal than `plain`) and every bound ([`acceptable`]); its radius is `plain`'s.
#[allow(clippy::too_many_arguments)]
fn pick_state_near_plane(
    t: &posrad::Tables,
    p: &Node,
    orig: &Node,
    s0: u16,
    plain: &Node,
    first: (i8, Node),
    tol: f64,
    weight: impl Fn(u16) -> u64,
) -> (u16, i8, Node) {
    let keep = (s0, first.0, first.1);
    let Some(n) = unit64(orig.normal) else { return keep };
    let step = p.radius as f64 / OFFSET_STEPS as f64;
    let e_first = plane_error(orig, n, first.1.center);
    let e0 = e_first.abs();
    if e0.is_nan() || e0 <= tol || step.is_nan() || step <= 0.0 || !step.is_finite() {
        return keep;
    }
    let along = |d: &Node| (0..3).map(|a| (orig.center[a] as f64 - d.center[a] as f64) * d.normal[a] as f64).sum::<f64>();
    let limit = along(plain).abs();
    let dist2 = |d: &Node| (0..3).map(|a| (orig.center[a] as f64 - d.center[a] as f64).powi(2)).sum::<f64>();
    // Tangential error: what the offset cannot correct.
    let tangential = |d: &Node, e: f64| (dist2(d) - e * e).max(0.0).sqrt();
    let t_first = tangential(&first.1, e0);
    let t0 = t_first + step / 2.0;
    // A neighbour moves the centre along the plane by `(δ - (δ·n)n) · r_P/6` from where
    // `first` left it (its offset moves it along a normal within 0.64° of `n`: at most
    // 0.01 r_P sideways); where that lies beyond the radius's room for error it cannot
    // contain the child. Skipping those early keeps the search cheap (on an axis-aligned face
    // only the two along the normal remain).
    let side0: [f64; 3] = [0, 1, 2].map(|a| first.1.center[a] as f64 - orig.center[a] as f64 - e_first * n[a]);
    let room = plain.radius as f64 - orig.radius as f64 + 0.01 * p.radius as f64;
    let grid = p.radius as f64 / posrad::QP as f64;
    let Some(&(g0, q0)) = t.state.get(s0 as usize) else { return keep };
    // On the stack: this runs for a good share of all leaves.
    let mut cands = [(0f64, 0u16, 0i8, *plain); 26];
    let mut k = 0;
    for d in NEIGHBOURS {
        let dn = d[0] as f64 * n[0] + d[1] as f64 * n[1] + d[2] as f64 * n[2];
        let side: f64 = (0..3).map(|a| (side0[a] + grid * (d[a] as f64 - dn * n[a])).powi(2)).sum();
        if side > room * room {
            continue;
        }
        let g = [0, 1, 2].map(|a| g0[a] as i32 + d[a]);
        let Some(s) = t.index(g, q0 as i32) else { continue };
        // The state decides only the centre and radius (`child_node`); the rest is `plain`'s.
        let Some((center, radius)) = posrad::decode_state(t, s as usize, p.center, p.radius) else { continue };
        let dec = Node { center, radius, ..*plain };
        let want = (along(&dec) / step).round();
        if want.is_nan() || want.abs() > i8::MAX as f64 {
            continue;
        }
        let o = want as i8;
        let mut moved = dec;
        apply_offset(&mut moved, o, p.radius);
        let e = plane_error(orig, n, moved.center).abs();
        // Containment first (as `acceptable` tests it): a neighbour off the plane's normal
        // moves the centre along the plane by up to a grid step, which most radii refuse.
        if e < e0 && dist2(&moved).sqrt() + orig.radius as f64 <= moved.radius as f64 && along(&moved).abs() <= limit {
            cands[k] = (e, s, o, moved);
            k += 1;
        }
    }
    let cands = &cands[..k];
    // Those within `tol` first: of them, those that keep the tangential error (to half a
    // step: a longer move along a tilted decoded normal shifts the centre a little), which
    // decides whether a leaf at the edge of a face lies past it, then the cheapest (most
    // frequent state bytes). Then the others, nearest the plane first. Equals keep their
    // order. Keys are worked out once each (the tangential error takes a square root).
    let key = |c: &(f64, u16, i8, Node)| if c.0 <= tol { (false, tangential(&c.3, c.0) > t0, u64::MAX - weight(c.1)) } else { (true, false, 0) };
    let mut keys = [(false, false, 0u64); 26];
    for (kc, c) in keys.iter_mut().zip(cands) {
        *kc = key(c);
    }
    let order = |i: usize, j: usize| keys[i].cmp(&keys[j]).then(cands[i].0.total_cmp(&cands[j].0));
    first_accepted(k, order, |i| acceptable(p, orig, &cands[i].3, cands[i].1)).map_or(keep, |i| (cands[i].1, cands[i].2, cands[i].3))
}

/// The first of `0..n` (at most 32) in `order` (equals in index order, as a stable sort
/// leaves them) that `accept` takes: the least not yet tried, in turn. Usually the first is
/// taken, so this costs a scan where sorting would cost a sort.
fn first_accepted(n: usize, order: impl Fn(usize, usize) -> std::cmp::Ordering, mut accept: impl FnMut(usize) -> bool) -> Option<usize> {
    debug_assert!(n <= 32);
    let mut untried = if n >= 32 { u32::MAX } else { (1u32 << n) - 1 };
    while untried != 0 {
        let mut least = untried.trailing_zeros() as usize;
        let mut rest = untried & (untried - 1);
        while rest != 0 {
            let i = rest.trailing_zeros() as usize;
            if order(i, least) == std::cmp::Ordering::Less {
                least = i;
            }
            rest &= rest - 1;
        }
        if accept(least) {
            return Some(least);
        }
        untried &= !(1 << least);
    }
    None
}

/// The 26 grid offsets around a grid point, x-major (the order decides among equal
/// candidates of [`pick_state_near_plane`]). A table: working them out of a counter took a
/// sixth of that search's instructions.
const NEIGHBOURS: [[i32; 3]; 26] = {
    let mut t = [[0; 3]; 26];
    let (mut b, mut k) = (0, 0);
    while b < 27 {
        if b != 13 {
            t[k] = [b / 9 - 1, b / 3 % 3 - 1, b % 3 - 1];
            k += 1;
        }
        b += 1;
    }
    t
};

/// The decoded child with codes `c` (`ch` colour channels), `axis = oct_decode(c.normal)` and
/// decoded area `area`: the one definition the
/// encoder (to return what a reader gets) and the decoder share, so they agree bit for bit.
#[inline]
fn child_node(t: &posrad::Tables, p: &Node, c: Codes, axis: [f32; 3], ch: usize, area: f32) -> Option<Node> {
    let Codes { state: s, cone, color: q } = c;
    let (center, radius) = posrad::decode_state(t, s as usize, p.center, p.radius)?;
    let mut color = [255u8; 4];
    for j in 0..ch {
        color[j] = color::dequant(q[j], color::BITS[j]);
    }
    Some(Node { center, radius, normal: axis, cone: normal::cone_decode(cone), area, color })
}

/// The payload's streams for `m` children, in order (see the table above).
pub fn streams(params: CodecParams, m: usize) -> Vec<super::Stream> {
    use super::Stream;
    let mut v = vec![Stream::of(0, m), Stream::of(0, m), Stream::of(1, m), Stream::of(1, m), Stream::of(2, m)];
    v.extend((0..channels(params)).map(|_| Stream::of(3, m)));
    v.extend([Stream::of(4, m / 2), Stream::of(4, m / 2)]);
    if params.centre_offsets {
        v.push(Stream::of(0, m));
    }
    if params.leaf_refinement {
        v.extend((0..4).map(|_| Stream::of(0, m)));
    }
    v
}

/// Encodes sibling pairs relative to their decoded parents; returns them as decoded. With
/// centre offsets every child is refined (see [`encode_with_leaves`]).
/// On error `out` is left as it was.
pub fn encode(params: CodecParams, parents: &[Node], children: &[Node], out: &mut Vec<u8>) -> Result<Vec<Node>> {
    encode_with_leaves(params, parents, children, None, out)
}

/// [`encode`], refining with centre offsets and leaf refinement only the children that
/// `has_children` marks `false` (all children when it is `None`). Nodes with children gain
/// little from either (they are drawn only where they are smaller than the pixel error) and
/// would cost bytes of entropy each; a stored 0 costs almost nothing.
pub fn encode_with_leaves(params: CodecParams, parents: &[Node], children: &[Node], has_children: Option<&[bool]>, out: &mut Vec<u8>) -> Result<Vec<Node>> {
    if children.len() != 2 * parents.len() || has_children.is_some_and(|f| f.len() != children.len()) {
        return Err(Error::Misuse(format!("{} children for {} parents", children.len(), parents.len())));
    }
    let n = parents.len();
    let m = 2 * n;
    let ch = channels(params);
    let len = payload_len(params, n).ok_or_else(|| Error::Misuse("block too large".into()))?;
    let t = posrad::tables();
    let start = out.len();
    out.resize(start + len, 0);
    let buf = &mut out[start..];
    let (states, rest) = buf.split_at_mut(2 * m);
    let (norms, rest) = rest.split_at_mut(2 * m);
    let (cones, rest) = rest.split_at_mut(m);
    let (cols, rest) = rest.split_at_mut(ch * m);
    let (area_bytes, rest) = rest.split_at_mut(2 * n);
    let (offsets, refine) = rest.split_at_mut(if params.centre_offsets { m } else { 0 });
    let mut dec = Vec::with_capacity(m);
    let r = (|| -> Result<()> {
        // Pass 1: the equally tight position/radius states of every child, and how often the
        // reference choice (the first) uses each state byte in this block.
        let mut ties = Vec::with_capacity(m);
        let mut hist = StateHistogram::default();
        for (k, pair) in children.chunks_exact(2).enumerate() {
            let p = &parents[k];
            check_parent(p, k)?;
            let (a, b) = (&pair[0], &pair[1]);
            check_child(a, 2 * k, params)?;
            check_child(b, 2 * k + 1, params)?;
            for (h, c) in pair.iter().enumerate() {
                let t = sphere_ties(p, c, 2 * k + h)?;
                hist.add(t.states[0]);
                ties.push(t);
            }
        }
        for (k, pair) in children.chunks_exact(2).enumerate() {
            let p = &parents[k];
            let (a, b) = (&pair[0], &pair[1]);
            let code = area_code(a.area, b.area);
            area_bytes[k] = code as u8;
            area_bytes[n + k] = (code >> 8) as u8;
            let (area_a, area_b) = areas(p, code);
            let pa = parent_axis(p);
            let mut dec_a: Option<Node> = None;
            for (h, c) in pair.iter().enumerate() {
                let i = 2 * k + h;
                let s = pick_state(&ties[i], &hist);
                states[i] = s as u8;
                states[m + i] = (s >> 8) as u8;
                let (pred, pc) = match &dec_a {
                    None => (pa.pred_a, quant4(p.color)),
                    Some(da) => (pred_normal_b(p, pa, da.normal), quant4(pred_color_b(p, area_a, area_b, da.color, ch))),
                };
                let (nc, axis, cone) = normal::encode_cone_toward(c.normal, c.cone, pred, |a, b| zz(a, b, 8) as u32);
                norms[i] = zz(nc as u8, pred as u8, 8);
                norms[m + i] = zz((nc >> 8) as u8, (pred >> 8) as u8, 8);
                cones[i] = cone;
                let q = quant4(c.color);
                for j in 0..ch {
                    cols[j * m + i] = zz(q[j], pc[j], color::BITS[j]);
                }
                // The state the decoded child stands on (the near-plane choice may change it).
                let mut state = s;
                let mut node = child_node(t, p, Codes { state: s, cone, color: q }, axis, ch, if h == 0 { area_a } else { area_b })
                    .ok_or_else(|| Error::Misuse(format!("default encoder: state {s} of child {i} is not decodable (bug)")))?;
                let leaf = !has_children.is_some_and(|f| f[i]);
                if params.centre_offsets && leaf {
                    let first = pick_offset(p, c, &node, s);
                    let tol = c.radius as f64 / PLANE_STEPS;
                    let (s2, o, moved) = pick_state_near_plane(t, p, c, s, &node, first, tol, |s2| hist.weight(s2));
                    if s2 != s {
                        states[i] = s2 as u8;
                        states[m + i] = (s2 >> 8) as u8;
                        state = s2;
                    }
                    node = moved;
                    offsets[i] = zz(o as u8, 0, 8);
                }
                if params.leaf_refinement && leaf {
                    if !params.centre_offsets {
                        let (d, k, refined) = pick_refinement(p, c, &node, state);
                        node = refined;
                        put_refinement(refine, m, i, d, k);
                    } else if let Some((d, k, refined)) = pick_nudge(p, c, &node, state) {
                        // Refinement where it is needed: only leaves off their piece.
                        node = refined;
                        put_refinement(refine, m, i, d, k);
                    }
                }
                dec.push(node);
                dec_a = Some(node);
            }
        }
        Ok(())
    })();
    if let Err(e) = r {
        out.truncate(start);
        return Err(e);
    }
    Ok(dec)
}

/// Decodes the children of `parents` from a default-profile payload.
pub fn decode(params: CodecParams, parents: &[Node], bytes: &[u8], offset: u64, out: &mut Vec<Node>) -> Result<()> {
    let n = parents.len();
    let need = payload_len(params, n).ok_or_else(|| Error::malformed(offset, "parent count overflows"))?;
    if bytes.len() != need {
        return Err(Error::malformed(
            offset,
            format!("default block holds {} bytes, {n} sibling pairs need {need}", bytes.len()),
        ));
    }
    let m = 2 * n;
    let ch = channels(params);
    let (states, rest) = bytes.split_at(2 * m);
    let (norms, rest) = rest.split_at(2 * m);
    let (cones, rest) = rest.split_at(m);
    let (cols, rest) = rest.split_at(ch * m);
    let (area_bytes, rest) = rest.split_at(2 * n);
    let (offsets, refine) = rest.split_at(if params.centre_offsets { m } else { 0 });
    // Stream start offsets, for error positions.
    let col_off = offset + 5 * m as u64;
    let area_off = col_off + (ch * m) as u64;
    let t = posrad::tables();
    out.reserve(m);
    for (k, p) in parents.iter().enumerate() {
        let code = area_bytes[k] as u16 | (area_bytes[n + k] as u16) << 8;
        if code > AREA_ONE {
            return Err(Error::malformed(area_off + k as u64, format!("default block: area code {code} > {AREA_ONE}")));
        }
        let (area_a, area_b) = areas(p, code);
        let pa = parent_axis(p);
        let mut dec_a: Option<Node> = None;
        for h in 0..2 {
            let i = 2 * k + h;
            let s = states[i] as u16 | (states[m + i] as u16) << 8;
            let (pred, pc) = match &dec_a {
                None => (pa.pred_a, quant4(p.color)),
                Some(a) => (pred_normal_b(p, pa, a.normal), quant4(pred_color_b(p, area_a, area_b, a.color, ch))),
            };
            let u = unzz(norms[i], pred as u8, 8).unwrap_or(0);
            let v = unzz(norms[m + i], (pred >> 8) as u8, 8).unwrap_or(0);
            let mut q = [0u8; 4];
            for j in 0..ch {
                q[j] = unzz(cols[j * m + i], pc[j], color::BITS[j]).ok_or_else(|| {
                    Error::malformed(col_off + (j * m + i) as u64, format!("default block: colour residual {} out of range", cols[j * m + i]))
                })?;
            }
            let nc = u as u16 | (v as u16) << 8;
            let mut node = child_node(t, p, Codes { state: s, cone: cones[i], color: q }, normal::oct_decode(nc), ch, if h == 0 { area_a } else { area_b })
                .ok_or_else(|| {
                    Error::malformed(offset + i as u64, format!("default block: position/radius state {s} ≥ {}", posrad::STATE_COUNT))
                })?;
            if let Some(&z) = offsets.get(i) {
                // Every byte is a valid 8-bit zigzag code.
                apply_offset(&mut node, unzz(z, 0, 8).unwrap_or(0) as i8, p.radius);
            }
            if params.leaf_refinement {
                // Every byte is a valid 8-bit zigzag code and every k a valid cut.
                let d = [0, 1, 2].map(|a| refine.get(a * m + i).map_or(0, |&z| unzz(z, 0, 8).unwrap_or(0) as i8));
                apply_refinement(&mut node, d, refine.get(3 * m + i).copied().unwrap_or(0));
            }
            out.push(node);
            dec_a = Some(node);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The branch-free zigzag equals the first form for every code, prediction and width
    /// used (also predictions and codes wider than `bits`, as the encoder never passes them).
    #[test]
    fn zigzag_matches_reference() {
        for bits in [4u32, 5, 6, 8] {
            for code in 0..=255u8 {
                for pred in 0..=255u8 {
                    assert_eq!(zz(code, pred, bits), zz_reference(code, pred, bits), "{code} {pred} {bits}");
                }
            }
        }
    }

    /// Predictions from `parent_axis` equal the first form, which re-checked the parent, for
    /// random, special (zero, NaN, ±inf, subnormal, huge) and mixed parent and A axes.
    #[test]
    fn normal_predictions_match_reference() {
        let special = [0.0f32, -0.0, 1.0, -1.0, 1e-20, -1e-30, 1e-45, 3e38, -3e38, f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let value = |r: u64| {
            if r % 5 == 0 {
                special[(r >> 8) as usize % special.len()]
            } else {
                ((r >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) as f32
            }
        };
        for _ in 0..400_000 {
            let mut v = [0f32; 6];
            for e in &mut v {
                let r = next();
                *e = value(r);
            }
            let p = Node { center: [0.0; 3], radius: 1.0, normal: [v[0], v[1], v[2]], cone: 0.0, area: 1.0, color: [0; 4] };
            let a = [v[3], v[4], v[5]];
            let pa = parent_axis(&p);
            assert_eq!(pa.pred_a, pred_normal_a_reference(&p), "{v:?}");
            assert_eq!(pred_normal_b(&p, pa, a), pred_normal_b_reference(&p, a), "{v:?}");
        }
    }

    /// The equal-channel shortcut of `pred_color_b` gives the divided form's bytes for every
    /// area code, over special (zero, subnormal, huge, infinite, NaN, negative) and random
    /// parent areas and colours, A's channels equal to the parent's or not.
    #[test]
    fn color_prediction_matches_reference() {
        let special = [0.0f32, -0.0, 1e-45, 1e-40, 1.1754944e-38, 1e-20, 1.0, 3.0, 1e20, 3e38, f32::MAX, f32::INFINITY, f32::NAN, -1.0, -3e38];
        let mut rng = crate::rng::SplitMix64(0xC010_0B1D_5EED_0001);
        let mut checked = 0u64;
        for round in 0..40 {
            let area = if round < special.len() { special[round] } else { f32::from_bits(rng.next_u64() as u32 & 0x7fff_ffff) };
            for code in 0..=AREA_ONE {
                let r = rng.next_u64();
                let pc = [r as u8, (r >> 8) as u8, (r >> 16) as u8, (r >> 24) as u8];
                let mut ca = [(r >> 32) as u8, (r >> 40) as u8, (r >> 48) as u8, (r >> 56) as u8];
                // Mostly A's channels equal to the parent's (the shortcut), extremes included.
                for (j, c) in ca.iter_mut().enumerate() {
                    if (r >> (60 - j)) & 1 == 0 {
                        *c = pc[j];
                    }
                }
                let p = Node { center: [0.0; 3], radius: 1.0, normal: [0.0, 0.0, 1.0], cone: 0.0, area, color: pc };
                let (aa, ab) = areas(&p, code);
                for ch in [3, 4] {
                    assert_eq!(pred_color_b(&p, aa, ab, ca, ch), pred_color_b_reference(&p, aa, ab, ca, ch), "{area} {code} {pc:?} {ca:?}");
                    let flat = [0u8, 255, 1, 254][(r as usize >> 20) % 4];
                    let p = Node { color: [flat; 4], ..p };
                    assert_eq!(pred_color_b(&p, aa, ab, [flat; 4], ch), pred_color_b_reference(&p, aa, ab, [flat; 4], ch), "{area} {code} {flat}");
                    checked += 1;
                }
            }
        }
        assert!(checked > 300_000);
    }

    #[test]
    fn neighbours_are_the_grid_offsets_x_major() {
        let want: Vec<[i32; 3]> = (0..27).map(|b| [b / 9 - 1, b / 3 % 3 - 1, b % 3 - 1]).filter(|d| *d != [0, 0, 0]).collect();
        assert_eq!(NEIGHBOURS.to_vec(), want);
    }

    #[test]
    fn first_accepted_matches_a_stable_sort() {
        let mut rng = crate::rng::SplitMix64(7);
        for _ in 0..20_000 {
            let n = (rng.next_u64() % 27) as usize;
            // Few distinct keys: many ties, which must keep their order.
            let keys: Vec<u64> = (0..n).map(|_| rng.next_u64() % 4).collect();
            let taken: Vec<bool> = (0..n).map(|_| rng.next_u64() % 3 == 0).collect();
            let mut sorted: Vec<usize> = (0..n).collect();
            sorted.sort_by(|&a, &b| keys[a].cmp(&keys[b]));
            let want = sorted.into_iter().find(|&i| taken[i]);
            let mut tried = Vec::new();
            let got = first_accepted(n, |a, b| keys[a].cmp(&keys[b]), |i| {
                tried.push(i);
                taken[i]
            });
            assert_eq!(got, want, "keys {keys:?} taken {taken:?}");
            // Each candidate is tried at most once.
            let mut once = tried.clone();
            once.sort_unstable();
            once.dedup();
            assert_eq!(once.len(), tried.len());
        }
    }

    #[test]
    fn zigzag_round_trip() {
        for bits in [4u32, 5, 6, 8] {
            for code in 0..(1u32 << bits) {
                for pred in 0..(1u32 << bits) {
                    let z = zz(code as u8, pred as u8, bits);
                    assert!((z as u32) < (1 << bits));
                    assert_eq!(unzz(z, pred as u8, bits), Some(code as u8));
                }
            }
        }
        assert_eq!(zz(3, 3, 5), 0);
        assert_eq!(zz(2, 3, 5), 1);
        assert_eq!(zz(4, 3, 5), 2);
        assert_eq!(unzz(32, 0, 5), None);
    }

    #[test]
    fn area_codes_coarse_for_balanced_pairs_fine_for_slivers() {
        for i in 0..=20_000u32 {
            let a = i as f32 / 20_000.0;
            let b = 1.0 - a;
            let c = area_code(a, b);
            let x = a as f64 / (a as f64 + b as f64) * 4096.0;
            let s = x.min(4096.0 - x);
            let err = (c as f64 - x).abs();
            assert!(err <= 4.0 + 1e-9, "{a}: code {c} for {x}");
            assert!(err <= (s / 32.0).max(0.5) + 1e-9, "{a}: code {c} for {x}");
            if s >= 128.0 {
                assert_eq!(c % 8, 0, "{a}: balanced pair must use the 8-code grid");
            }
            if s < 16.0 {
                assert!(err <= 0.5 + 1e-9, "{a}: sliver keeps full resolution");
            }
        }
        assert_eq!(area_code(0.0, 0.0), AREA_ONE / 2);
        assert_eq!(area_code(1.0, 0.0), AREA_ONE);
        assert_eq!(area_code(0.0, 1.0), 0);
    }

    #[test]
    fn tie_choice_follows_the_block_histogram() {
        let mut h = StateHistogram::default();
        for _ in 0..10 {
            h.add(0x0102);
        }
        h.add(0x0304);
        let t = super::posrad::Ties { len: 3, states: [0x0304, 0x0505, 0x0102, 0, 0, 0, 0, 0] };
        assert_eq!(pick_state(&t, &h), 0x0102);
        // Equal weights keep the reference choice.
        let t = super::posrad::Ties { len: 2, states: [0x0606, 0x0707, 0, 0, 0, 0, 0, 0] };
        assert_eq!(pick_state(&t, &h), 0x0606);
    }

    /// Many similar pairs: the encoder's freedoms must leave mostly zero normal residuals and
    /// 8-code area steps (a regression guard for the size of the default profile).
    #[test]
    fn encoder_choices_shrink_the_streams() {
        let mut parents = Vec::new();
        let mut kids = Vec::new();
        for i in 0..2000 {
            let t = i as f32 * 0.37;
            let p = Node { center: [t, 0.0, 0.0], radius: 1.0, normal: [0.0, 0.0, 1.0], cone: 0.3, area: 2.0, color: [100; 4] };
            let (s, c) = (0.1 * (t * 1.3).sin(), 0.1 * (t * 0.7).cos());
            let n = [s, c, 1.0];
            let off = 0.4 + 0.05 * (t * 2.1).sin();
            let a = Node { center: [t + off, 0.0, 0.0], radius: 0.58, normal: n, cone: 0.0, area: 1.0 + 0.1 * s, color: [100; 4] };
            // Nearly the mirror of A's normal (0.2° off): the prediction is within reach.
            let b = Node { center: [t - off, 0.0, 0.0], radius: 0.58, normal: [-s + 0.0035, -c, 1.0], cone: 0.0, area: 1.0 - 0.1 * s, color: [100; 4] };
            parents.push(Node { color: [100, 100, 100, 255], ..p });
            kids.extend([Node { color: [100, 100, 100, 255], ..a }, Node { color: [100, 100, 100, 255], ..b }]);
        }
        let mut out = Vec::new();
        let dec = encode(CodecParams::default(), &parents, &kids, &mut out).unwrap();
        let m = kids.len();
        let n = parents.len();
        // B's normal is the reflection of A's: a code within 0.64° equal to the prediction
        // exists for most, and must be taken.
        let zero_b = (0..n).filter(|k| out[2 * m + 2 * k + 1] == 0 && out[3 * m + 2 * k + 1] == 0).count();
        assert!(zero_b * 10 >= n * 7, "{zero_b} of {n} B normals predicted exactly");
        // The precise (closest) codes would match the prediction far less often.
        let precise = (0..n).filter(|&k| normal::oct_encode(kids[2 * k + 1].normal) == pred_normal_b(&parents[k], parent_axis(&parents[k]), dec[2 * k].normal)).count();
        assert!(precise * 10 < zero_b * 7, "precise codes match {precise} times, chosen {zero_b}");
        // Balanced pairs: area codes on the 8-code grid.
        assert!(out[8 * m..8 * m + n].iter().all(|&c| c % 8 == 0));
        for (c, d) in kids.iter().zip(&dec) {
            let e = normal::angle(c.normal, d.normal).to_degrees();
            assert!(e <= normal::MAX_NORMAL_ERROR_DEG, "{e}");
        }
        let mut again = Vec::new();
        decode(CodecParams::default(), &parents, &out, 0, &mut again).unwrap();
        assert_eq!(again, dec);
    }

    #[test]
    fn mirrored_pair_predicts_exactly() {
        let na = [0.6f32, 0.0, 0.8];
        let nb = [-0.6f32, 0.0, 0.8];
        let p = Node { center: [0.0; 3], radius: 1.0, normal: [0.0, 0.0, 1.0], cone: 0.7, area: 2.0, color: [100, 100, 100, 255] };
        let a = Node { center: [0.5, 0.0, 0.0], radius: 0.5, normal: na, cone: 0.0, area: 1.0, color: [80, 60, 40, 255] };
        let b = Node { center: [-0.5, 0.0, 0.0], radius: 0.5, normal: nb, cone: 0.0, area: 1.0, color: [120, 140, 160, 255] };
        let mut out = Vec::new();
        let dec = encode(CodecParams::default(), &[p], &[a, b], &mut out).unwrap();
        assert_eq!(out.len(), 2 * 8 + 2);
        assert_eq!(dec[0].area + dec[1].area, 2.0);
        // B's normal residual is tiny (reflection predictor).
        assert!(out[4 + 1] <= 2 && out[6 + 1] <= 2, "{:?}", out);
        let mut again = Vec::new();
        decode(CodecParams::default(), &[p], &out, 0, &mut again).unwrap();
        assert_eq!(again, dec);
    }
}
