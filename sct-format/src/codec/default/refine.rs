//! The encoder's choice of leaf refinement (1.4): for every leaf of a tree refined whole
//! ([`pick_refinement`]), or, with centre offsets, only where a leaf lies off its piece of
//! surface and that may leave the surface ([`pick_nudge`]; the parent module's "Leaf
//! refinement where it is needed"). Decoding needs none of this: [`super::apply_refinement`]
//! is the one definition both sides share.

use super::{acceptable, apply_refinement, plane_error, unit64, zz, PLANE_STEPS, REFINE_STEPS};
use crate::node::Node;

/// The leaf refinement of decoded child `dec` of original `orig` under parent `p`, with the
/// child it decodes to: on each axis the step nearest to the centre error, then the largest
/// radius cut `k` whose sphere still passes [`acceptable`]; when no cut does, the centre
/// steps are dropped and only the radius is cut; `([0; 3], 0)` (the child as decoded) always
/// qualifies. `state` is `dec`'s position/radius state.
pub(super) fn pick_refinement(p: &Node, orig: &Node, dec: &Node, state: u16) -> ([i8; 3], u8, Node) {
    let unit = dec.radius as f64 / REFINE_STEPS as f64;
    if unit.is_nan() || unit <= 0.0 || !unit.is_finite() {
        return ([0; 3], 0, *dec);
    }
    let d = [0, 1, 2].map(|a| {
        let want = ((orig.center[a] as f64 - dec.center[a] as f64) / unit).round();
        if want.is_finite() {
            want.clamp(-127.0, 127.0) as i8
        } else {
            0
        }
    });
    for steps in [d, [0; 3]] {
        let mut moved = *dec;
        apply_refinement(&mut moved, steps, 0);
        // The radius needed around the moved centre; start at the cut it allows and back off
        // while f32 rounding (or a bound) refuses it.
        let off: f64 = (0..3).map(|a| (moved.center[a] as f64 - orig.center[a] as f64).powi(2)).sum::<f64>().sqrt();
        let need = off + orig.radius as f64;
        let mut k = (256.0 * (1.0 - need / dec.radius as f64)).floor().clamp(0.0, 255.0) as u8;
        loop {
            let mut r = *dec;
            apply_refinement(&mut r, steps, k);
            if acceptable(p, orig, &r, state) {
                return (steps, k, r);
            }
            if k == 0 {
                break;
            }
            k -= 1;
        }
    }
    ([0; 3], 0, *dec)
}

/// How far `dec`, the decoded leaf, lies from `orig`'s centre along `orig`'s tangent plane,
/// as the vector from the original centre, with how far it may lie while surely staying on
/// the piece of surface `orig` stands for: `a / (6r)` (`a` and `r` the original's area and
/// radius). Why that is safe for a flat convex piece with its centroid at the original
/// centre: the piece lies inside the sphere, so in any direction it is at most `2r` long and,
/// holding area `a`, at least `a / 2r` wide across it; the centroid lies at least a third of
/// the width from either supporting line, so the disc of radius `a / 6r` about it lies on the
/// piece. A piece cut by a face's edge is narrow and allows little; a whole voxel's square of
/// surface allows 0.24 voxel. `None` when either length is not finite.
pub(super) fn tangential_error(orig: &Node, dec: &Node) -> Option<([f64; 3], f64)> {
    let n = orig.normal.map(f64::from);
    let nn = n.iter().map(|v| v * v).sum::<f64>();
    let d: [f64; 3] = std::array::from_fn(|a| dec.center[a] as f64 - orig.center[a] as f64);
    let along = if nn > 1e-30 { (0..3).map(|a| d[a] * n[a]).sum::<f64>() / nn } else { 0.0 };
    let t: [f64; 3] = std::array::from_fn(|a| d[a] - along * n[a]);
    let allowed = orig.area as f64 / (6.0 * orig.radius as f64);
    (t.iter().all(|v| v.is_finite()) && allowed.is_finite()).then_some((t, allowed.max(0.0)))
}

/// A nudge's steps are multiples of this many `r_C / 128` units where that suffices: fewer
/// distinct values pack into fewer bits.
const NUDGE_GRAIN: f64 = 8.0;

/// Writes child `i`'s refinement `(d, k)` into the four refinement streams of `m` children.
pub(super) fn put_refinement(refine: &mut [u8], m: usize, i: usize, d: [i8; 3], k: u8) {
    for a in 0..3 {
        refine[a * m + i] = zz(d[a] as u8, 0, 8);
    }
    refine[3 * m + i] = k;
}

/// Whether a leaf moved off its piece lands on its neighbours' surface, judged by its
/// decoded parent `p`: under a smoothly curved parent (normal cone wider than a flat face's,
/// whose decoded cone holds the normal code's 0.64°, and narrower than [`CREASE_CONE`]) the
/// surface next to the piece continues it, leaning by at most twice the cone; a centre moved
/// off the piece lies on or near it. Under a flat parent the piece's edge may be a face's
/// edge with the next face beyond the parent, and a wide cone holds a crease: no such claim.
pub(super) fn lands_on_its_neighbours(p: &Node) -> bool {
    let theta = p.cone as f64;
    theta > FLAT_CONE && theta < CREASE_CONE
}

/// Normal-cone semi-angle (radians) up to which a decoded parent counts as flat: a flat
/// face's normal decoded and its cone widened to hold it (0.64°), with a margin.
const FLAT_CONE: f64 = 0.02;

/// Normal-cone semi-angle (radians, 10°) from which a decoded parent counts as holding a
/// crease.
const CREASE_CONE: f64 = 0.1745;

/// The refinement of a leaf that the position code left off its piece of surface
/// ([`tangential_error`] past its allowance plus `r / 128`), with the child it decodes to:
/// `None` when it lies on its piece, or lands on its neighbours' ([`lands_on_its_neighbours`]). The centre
/// moves back along the tangent plane just far enough to lie within 0.75 of the allowance,
/// the radius kept: steps that are multiples of [`NUDGE_GRAIN`], else of 1 (small, few distinct values, which zstd packs in few bits),
/// each axis rounded down or up so that the centre lands on the piece and no farther from
/// the plane than before (or `r / 128`); when no such nudge is [`acceptable`], the leaf is
/// refined as [`pick_refinement`] refines it. `state` is `dec`'s position/radius state.
pub(super) fn pick_nudge(p: &Node, orig: &Node, dec: &Node, state: u16) -> Option<([i8; 3], u8, Node)> {
    if lands_on_its_neighbours(p) {
        return None;
    }
    // Lengths that are not finite count as off the piece.
    let Some((t, allowed)) = tangential_error(orig, dec) else {
        return Some(pick_refinement(p, orig, dec, state));
    };
    let len = t.iter().map(|v| v * v).sum::<f64>().sqrt();
    // Past a crease or an open edge, a centre at most `r / 128` past its allowance lies at
    // most that far from the surface: the tolerance the plane is held to.
    if len <= allowed + orig.radius as f64 / PLANE_STEPS {
        return None;
    }
    let unit = dec.radius as f64 / REFINE_STEPS as f64;
    let back = 1.0 - 0.75 * allowed / len;
    // Without a usable normal no nudge is judged: refined whole.
    let Some(n) = unit64(orig.normal) else { return Some(pick_refinement(p, orig, dec, state)) };
    let before = plane_error(orig, n, dec.center).abs().max(orig.radius as f64 / PLANE_STEPS);
    let on_piece = |moved: &Node| tangential_error(orig, moved).is_some_and(|(t2, _)| t2.iter().map(|v| v * v).sum::<f64>().sqrt() <= allowed);
    for grain in [NUDGE_GRAIN, 1.0] {
        let want = t.map(|v| -v * back / unit / grain);
        if !(unit > 0.0 && want.iter().all(|v| v.is_finite() && v.abs() * grain <= 126.0)) {
            break;
        }
        // Each axis rounded down or up: of the moves that land on the piece, the one nearest
        // the plane (rounding per axis moves the centre along the normal too). The plane
        // test, a dot product, goes first: the piece test (a division and a square root)
        // and `acceptable` are needed only for corners that pass it.
        let mut best: Option<(f64, [i8; 3], Node)> = None;
        for corner in 0..8 {
            let steps: [i8; 3] = std::array::from_fn(|a| {
                let v = if corner >> a & 1 == 0 { want[a].floor() } else { want[a].ceil() };
                (v * grain) as i8
            });
            let mut moved = *dec;
            apply_refinement(&mut moved, steps, 0);
            let e = plane_error(orig, n, moved.center).abs();
            if e <= before && best.as_ref().is_none_or(|b| e < b.0) && on_piece(&moved) && acceptable(p, orig, &moved, state) {
                best = Some((e, steps, moved));
            }
        }
        if let Some((_, steps, moved)) = best {
            return Some((steps, 0, moved));
        }
    }
    Some(pick_refinement(p, orig, dec, state))
}
