//! Hierarchical node attributes (thesis §5.1, EQ 9–14): the parent of two children, and the
//! containment predicates a validator checks them with.
//!
//! Everything is computed in f64. When a result is stored in f32 the radius and the cone
//! angle are *recomputed against the rounded f32 centre / axis* and then rounded up, so a
//! parent contains its children exactly as stored, not just in exact arithmetic. Inputs are
//! assumed finite (see [`Node::is_finite`]); non-finite input gives unspecified (but
//! non-panicking) output.

use std::f64::consts::PI;

use crate::node::Node;

mod bounds;
use bounds::Interval;

/// Relative safety margin applied before rounding up to f32: covers the few-ulp error of
/// the f64 distance/angle evaluation so that an f64 re-check of containment never fails.
const F64_MARGIN: f64 = 8.0 * f64::EPSILON;

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

fn to64(v: [f32; 3]) -> [f64; 3] {
    [v[0] as f64, v[1] as f64, v[2] as f64]
}

fn to32(v: [f64; 3]) -> [f32; 3] {
    [v[0] as f32, v[1] as f32, v[2] as f32]
}

/// Unit vector along `v`, or `None` for a (near) zero vector.
fn normalize(v: [f64; 3]) -> Option<[f64; 3]> {
    let l = norm(v);
    if l > 1e-300 && l.is_finite() {
        Some([v[0] / l, v[1] / l, v[2] / l])
    } else {
        None
    }
}

/// Angle between two unit vectors; atan2 is accurate near 0 and π where acos is not.
fn angle_between(a: [f64; 3], b: [f64; 3]) -> f64 {
    norm(cross(a, b)).atan2(dot(a, b))
}

/// Smallest f32 that is `>= v` (for non-negative finite `v`).
fn f32_up(v: f64) -> f32 {
    let f = v as f32;
    if (f as f64) < v {
        f.next_up()
    } else {
        f
    }
}

/// Minimal sphere enclosing spheres `(ca, ra)` and `(cb, rb)` (EQ 9–10), in f64.
///
/// When one sphere contains the other the result is the bigger one (the thesis's special
/// case; equal spheres return `a`).
pub fn enclosing_sphere(ca: [f64; 3], ra: f64, cb: [f64; 3], rb: f64) -> ([f64; 3], f64) {
    let v = sub(cb, ca);
    let l = norm(v);
    if l + rb <= ra {
        return (ca, ra);
    }
    if l + ra <= rb {
        return (cb, rb);
    }
    // Here l > |ra - rb| >= 0, so dividing by l is safe.
    let rc = 0.5 * (l + ra + rb);
    let t = (rc - ra) / l;
    ([ca[0] + v[0] * t, ca[1] + v[1] * t, ca[2] + v[2] * t], rc)
}

/// Smallest normal cone containing cones `(na, ta)` and `(nb, tb)` (EQ 11–12), in f64.
///
/// Axes need not be unit; a zero axis is treated as the whole sphere (cone π). Angles are
/// clamped to [0, π]. Returns a unit axis and a semi-angle in [0, π]; a result of π means
/// "any direction" (obtuse cones up to the whole sphere are allowed).
pub fn merge_cones(na: [f64; 3], ta: f64, nb: [f64; 3], tb: f64) -> ([f64; 3], f64) {
    let (n, t, _) = merge_unit_cones(normalize(na), ta, normalize(nb), tb);
    (n, t)
}

/// [`merge_cones`] on already normalised axes (`None`: zero axis). Also returns the angle
/// between the two axes when both exist, so [`parent_of`] need not evaluate it again
/// (`angle_between` is symmetric bit for bit: the cross product only changes sign).
fn merge_unit_cones(a: Option<[f64; 3]>, ta: f64, b: Option<[f64; 3]>, tb: f64) -> ([f64; 3], f64, Option<f64>) {
    let ta = ta.clamp(0.0, PI);
    let tb = tb.clamp(0.0, PI);
    let (a, b) = match (a, b) {
        (Some(a), Some(b)) => (a, b),
        (Some(a), None) => return (a, PI, None),
        (None, Some(b)) => return (b, PI, None),
        (None, None) => return ([0.0, 0.0, 1.0], PI, None),
    };
    let ab = dot(a, b);
    let d = norm(cross(a, b)).atan2(ab);
    if d + tb <= ta {
        return (a, ta, Some(d));
    }
    if d + ta <= tb {
        return (b, tb, Some(d));
    }
    let tc = 0.5 * (d + ta + tb);
    if tc >= PI {
        return (a, PI, Some(d));
    }
    // Rotate A's axis towards B's by (tc - ta) within the plane spanned by the two axes.
    let u = normalize(sub(b, [a[0] * ab, a[1] * ab, a[2] * ab]))
        // Antiparallel (or parallel, which the containment cases already caught): every
        // plane through A works, so pick a deterministic perpendicular.
        .unwrap_or_else(|| any_perpendicular(a));
    let phi = tc - ta;
    let (s, c) = phi.sin_cos();
    ([a[0] * c + u[0] * s, a[1] * c + u[1] * s, a[2] * c + u[2] * s], tc, Some(d))
}

/// A unit vector perpendicular to unit `a`.
fn any_perpendicular(a: [f64; 3]) -> [f64; 3] {
    // Cross with the coordinate axis least aligned with `a` is never degenerate.
    let ax = [a[0].abs(), a[1].abs(), a[2].abs()];
    let e = if ax[0] <= ax[1] && ax[0] <= ax[2] {
        [1.0, 0.0, 0.0]
    } else if ax[1] <= ax[2] {
        [0.0, 1.0, 0.0]
    } else {
        [0.0, 0.0, 1.0]
    };
    normalize(cross(a, e)).unwrap_or([1.0, 0.0, 0.0])
}

/// Parent area (EQ 13).
pub fn merge_area(wa: f32, wb: f32) -> f32 {
    (wa as f64 + wb as f64) as f32
}

/// Area-weighted RGBA colour (EQ 14), rounded to nearest. With zero (or negative) total
/// area both children weigh equally, so a zero-area subtree still gets a sensible colour.
pub fn merge_color(ca: [u8; 4], wa: f32, cb: [u8; 4], wb: f32) -> [u8; 4] {
    // Equal colours (untextured surfaces, flat materials) blend to themselves: with the
    // weights below finite and non-negative, a channel `c` gives `c` times a product of
    // roundings within 6 ulp of 1, under 1e-13 away from `c` (exactly 0 for 0), which the
    // rounding to u8 takes back to `c`.
    if ca == cb {
        return ca;
    }
    blend_colors(ca, wa, cb, wb)
}

/// [`merge_color`] of two different colours. Out of line so that the usual equal colours
/// return as they are (inlined, the channels were split and packed again on that path too).
#[inline(never)]
fn blend_colors(ca: [u8; 4], wa: f32, cb: [u8; 4], wb: f32) -> [u8; 4] {
    let (wa, wb) = (wa.max(0.0) as f64, wb.max(0.0) as f64);
    let (wa, wb) = if wa + wb > 0.0 && (wa + wb).is_finite() { (wa, wb) } else { (1.0, 1.0) };
    let inv = 1.0 / (wa + wb);
    let mut out = [0u8; 4];
    for i in 0..4 {
        let v = (ca[i] as f64 * wa + cb[i] as f64 * wb) * inv;
        out[i] = round_to_u8(v);
    }
    out
}

/// `v.round().clamp(0.0, 255.0) as u8` (half away from zero), without the `round` call
/// that a baseline x86-64 build makes: truncate, then add one when the exact fraction
/// `v - trunc(v)` (exact for 0 ≤ v < 255) is at least one half. NaN gives 0 like the cast.
#[inline]
fn round_to_u8(v: f64) -> u8 {
    if v >= 255.0 {
        255
    } else if v >= 0.0 {
        let i = v as u8;
        i + u8::from(v - i as f64 >= 0.5)
    } else {
        0
    }
}

/// Smallest f32 radius such that the sphere at f32 centre `c` contains both spheres.
fn covering_radius(c: [f32; 3], a: &Node, b: &Node) -> f32 {
    let c = to64(c);
    let ra = norm(sub(to64(a.center), c)) + a.radius as f64;
    let rb = norm(sub(to64(b.center), c)) + b.radius as f64;
    f32_up(ra.max(rb) * (1.0 + F64_MARGIN))
}

/// Smallest f32 cone angle at f32 axis `n` containing the cones `(ua, ta)` and `(ub, tb)`
/// (normalised axes, `None` for a zero axis; π at most).
fn covering_cone(n: [f32; 3], ua: Option<[f64; 3]>, ta: f32, ub: Option<[f64; 3]>, tb: f32) -> f32 {
    let Some(n) = normalize(to64(n)) else { return std::f32::consts::PI };
    let need = |axis: Option<[f64; 3]>, cone: f32| match axis {
        Some(m_axis) => angle_between(n, m_axis) + cone as f64,
        None => PI,
    };
    cone_from_need(need(ua, ta).max(need(ub, tb)))
}

/// [`covering_cone`] for two axes, from enclosures of the two angles: `None` unless both
/// ends give the same f32. Sound because [`cone_from_need`] of the max of `angle + cone`
/// is nondecreasing in each f64 angle (every step rounds monotonically). The cones are not
/// NaN (a NaN cone leaves [`parent_cone_bounded`] undecided before it gets here), so a plain
/// comparison picks what `f64::max` would, without its NaN handling.
fn covering_cone_bounded(n: [f32; 3], ua: [f64; 3], ta: f32, ub: [f64; 3], tb: f32) -> Option<f32> {
    let n = normalize(to64(n))?;
    let (ia, ib) = (angle_bounds(n, ua)?, angle_bounds(n, ub)?);
    let at = |xa: f64, xb: f64| {
        let (need_a, need_b) = (xa + ta as f64, xb + tb as f64);
        cone_from_need(if need_a >= need_b { need_a } else { need_b })
    };
    let (lo, hi) = (at(ia.lo, ib.lo), at(ia.hi, ib.hi));
    (lo.to_bits() == hi.to_bits()).then_some(lo)
}

/// An enclosure of [`angle_between`] of unit `n` and `m` (inlined: it was an out-of-line
/// closure called twice per parent).
#[inline(always)]
fn angle_bounds(n: [f64; 3], m: [f64; 3]) -> Option<Interval> {
    bounds::atan2(norm(cross(n, m)), dot(n, m))
}

/// The stored cone angle for a needed f64 angle: grown by the margin, rounded up.
fn cone_from_need(need: f64) -> f32 {
    let t = need * (1.0 + F64_MARGIN) + F64_MARGIN;
    // f32 π rounds above the true π, so it always covers the whole sphere.
    if t >= PI {
        std::f32::consts::PI
    } else {
        f32_up(t).min(std::f32::consts::PI)
    }
}

/// The parent of two children (EQ 9–14): minimal enclosing sphere, merged normal cone,
/// summed area and area-weighted colour. The result contains both children exactly in its
/// stored f32 form (see [`sphere_contains`] and [`cone_contains`] with zero tolerance).
pub fn parent_of(a: &Node, b: &Node) -> Node {
    let (c, r) = enclosing_sphere(to64(a.center), a.radius as f64, to64(b.center), b.radius as f64);
    let center = to32(c);
    // Containment cases return a child unchanged: keep its exact radius.
    let radius = if center == a.center && r == a.radius as f64 && covers(a, b) {
        a.radius
    } else if center == b.center && r == b.radius as f64 && covers(b, a) {
        b.radius
    } else {
        covering_radius(center, a, b)
    };

    // Each child's axis is normalised once per path and shared by the merge, the containment
    // checks and the covering angle (the same f64 operations as evaluating them separately).
    let bounded = match (normalize(to64(a.normal)), normalize(to64(b.normal))) {
        (Some(va), Some(vb)) => parent_cone_bounded(a, va, b, vb),
        _ => None,
    };
    let (normal, cone) = bounded.unwrap_or_else(|| exact_parent_cone(a, b));
    Node {
        center,
        radius,
        normal,
        cone,
        area: merge_area(a.area, b.area),
        color: merge_color(a.color, a.area, b.color, b.area),
    }
}

/// [`parent_cone`] of the nodes: the rare fallback of [`parent_cone_bounded`], out of line
/// and normalising the axes again rather than have them kept across the fast path.
#[cold]
#[inline(never)]
fn exact_parent_cone(a: &Node, b: &Node) -> ([f32; 3], f32) {
    parent_cone(a, normalize(to64(a.normal)), b, normalize(to64(b.normal)))
}

/// The parent's stored axis and cone angle, with libm's exact `atan2`, `sin` and `cos`.
fn parent_cone(a: &Node, ua: Option<[f64; 3]>, b: &Node, ub: Option<[f64; 3]>) -> ([f32; 3], f32) {
    let (n, t, d) = merge_unit_cones(ua, a.cone as f64, ub, b.cone as f64);
    let normal = to32(n);
    // `cone_contains(outer, inner, 0)` with the axes' angle `d` already known.
    let contains = |outer: f32, inner: f32| {
        let (outer, inner) = (outer as f64, inner as f64);
        outer >= PI || d.is_some_and(|d| d + inner <= outer)
    };
    let cone = if normal == a.normal && t == a.cone as f64 && contains(a.cone, b.cone) {
        a.cone
    } else if normal == b.normal && t == b.cone as f64 && contains(b.cone, a.cone) {
        b.cone
    } else {
        covering_cone(normal, ua, a.cone, ub, b.cone)
    };
    (normal, cone)
}

/// [`parent_cone`] for two non-zero axes, with every libm result replaced by an enclosure
/// ([`bounds`]): each step of [`merge_unit_cones`] and of the choice above runs on both ends
/// of the enclosure, and the result is returned only when every decision and every rounding
/// to f32 comes out the same at both ends; `None` (rare: near ties, rounding boundaries,
/// wide angles) leaves the exact path to decide. The steps are monotone in the enclosed
/// value, so agreement at the ends means agreement for the exact libm value between them.
fn parent_cone_bounded(a: &Node, va: [f64; 3], b: &Node, vb: [f64; 3]) -> Option<([f32; 3], f32)> {
    // `clamp(0, π)` for cones that are not negative or NaN (real ones never are; the others
    // are left to the exact path): f32 π lies above f64 π, so whole-sphere cones still clamp.
    let (ta, tb) = (a.cone as f64, b.cone as f64);
    if !(ta >= 0.0 && tb >= 0.0) {
        return None;
    }
    let (ta, tb) = (if ta < PI { ta } else { PI }, if tb < PI { tb } else { PI });
    let ab = dot(va, vb);
    let d = bounds::atan2(norm(cross(va, vb)), ab)?;
    // merge_unit_cones: containment, whole sphere, else rotate A's axis towards B's.
    // `d + x <= y` and `tc >= π` are monotone in `d` (IEEE rounding is); a NaN cone is undecided.
    let (normal, t) = if d.map(|d| d + tb).le(ta)? {
        (to32(va), Interval::exact(ta))
    } else if d.map(|d| d + ta).le(tb)? {
        (to32(vb), Interval::exact(tb))
    } else {
        let tc = d.map(|d| 0.5 * (d + ta + tb));
        if tc.ge(PI)? {
            (to32(va), Interval::exact(PI))
        } else {
            let u = normalize(sub(vb, [va[0] * ab, va[1] * ab, va[2] * ab])).unwrap_or_else(|| any_perpendicular(va));
            let (s, c) = bounds::sin_cos(tc.map(|tc| tc - ta))?;
            (rotated_axis_f32(va, u, s, c)?, tc)
        }
    };
    let contains = |outer: f32, inner: f32| {
        let (outer, inner) = (outer as f64, inner as f64);
        if outer >= PI {
            Some(true)
        } else {
            d.map(|d| d + inner).le(outer)
        }
    };
    // `normal == x.normal && t == x.cone && contains(..)`, short-circuiting like the exact path.
    let keeps = |x: &Node, y: &Node| -> Option<bool> {
        if normal != x.normal || !t.equals(x.cone as f64)? {
            return Some(false);
        }
        contains(x.cone, y.cone)
    };
    let cone = if keeps(a, b)? {
        a.cone
    } else if keeps(b, a)? {
        b.cone
    } else {
        covering_cone_bounded(normal, va, a.cone, vb, b.cone)?
    };
    Some((normal, cone))
}

/// `to32(a cos φ + u sin φ)` (`a`, `u` unit) from enclosures of sin φ and cos φ, when every
/// component rounds to the same non-zero f32 over the whole range (a zero could differ in sign).
///
/// Evaluated at the enclosures' low ends, the f64 component differs from the exact path's by
/// at most `|a_k|·width(cos) + |u_k|·width(sin)` plus the two evaluations' rounding (three
/// roundings each of terms ≤ 2 in size: ≤ 2⁻⁵⁰ in all); the slack 2⁻⁴⁸ also covers
/// `|a_k|, |u_k| ≤ 1 + 2⁻⁵²` and the rounding of the bounds themselves. Rounding to f32 is
/// monotone, so agreement at both bounds decides the exact component.
#[inline(always)]
fn rotated_axis_f32(a: [f64; 3], u: [f64; 3], s: Interval, c: Interval) -> Option<[f32; 3]> {
    const SLACK: f64 = 1.0 / (1u64 << 48) as f64;
    let e = (c.hi - c.lo) + (s.hi - s.lo) + SLACK;
    let mut out = [0f32; 3];
    for k in 0..3 {
        let mid = a[k] * c.lo + u[k] * s.lo;
        let (lo, hi) = ((mid - e) as f32, (mid + e) as f32);
        if lo.to_bits() != hi.to_bits() || lo == 0.0 {
            return None;
        }
        out[k] = lo;
    }
    Some(out)
}

fn covers(outer: &Node, inner: &Node) -> bool {
    sphere_contains(outer, inner, 0.0)
}

/// True when `inner`'s sphere lies inside `outer`'s sphere grown by `slack × outer.radius`
/// (the codecs' documented containment tolerance), evaluated in f64.
pub fn sphere_contains(outer: &Node, inner: &Node, slack: f32) -> bool {
    let d = norm(sub(to64(inner.center), to64(outer.center)));
    d + inner.radius as f64 <= outer.radius as f64 * (1.0 + slack as f64)
}

/// True when the cone `(inner_axis, inner_angle)` lies inside `(outer_axis, outer_angle)`
/// with `tol` radians of tolerance. Axes need not be unit; an outer cone of (about) π
/// contains everything; a zero axis counts as the whole sphere.
pub fn cone_contains(outer_axis: [f32; 3], outer_angle: f32, inner_axis: [f32; 3], inner_angle: f32, tol: f32) -> bool {
    let (outer, inner, tol) = (outer_angle as f64, inner_angle as f64, tol as f64);
    if outer + tol >= PI {
        return true;
    }
    match (normalize(to64(outer_axis)), normalize(to64(inner_axis))) {
        (Some(o), Some(i)) => angle_between(o, i) + inner <= outer + tol,
        _ => false,
    }
}

/// True when unit-ish `normal` lies inside the cone `(axis, angle)` within `tol` radians.
pub fn normal_in_cone(axis: [f32; 3], angle: f32, normal: [f32; 3], tol: f32) -> bool {
    cone_contains(axis, angle, normal, 0.0, tol)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn node(c: [f32; 3], r: f32, n: [f32; 3], cone: f32, area: f32, color: [u8; 4]) -> Node {
        Node { center: c, radius: r, normal: n, cone, area, color }
    }

    #[test]
    fn separate_spheres_give_minimal_parent() {
        let a = node([0.0, 0.0, 0.0], 1.0, [0.0, 0.0, 1.0], 0.0, 1.0, [0; 4]);
        let b = node([4.0, 0.0, 0.0], 1.0, [0.0, 0.0, 1.0], 0.0, 1.0, [0; 4]);
        let p = parent_of(&a, &b);
        assert!((p.center[0] - 2.0).abs() < 1e-6 && p.center[1] == 0.0);
        assert!(p.radius >= 3.0 && p.radius < 3.0 + 1e-5);
        assert!(sphere_contains(&p, &a, 0.0) && sphere_contains(&p, &b, 0.0));
    }

    #[test]
    fn contained_sphere_gives_the_bigger() {
        let a = node([0.1, 0.2, 0.3], 5.0, [0.0, 0.0, 1.0], 0.1, 1.0, [0; 4]);
        let b = node([1.0, 0.0, 0.0], 0.5, [0.0, 0.0, 1.0], 0.0, 1.0, [0; 4]);
        for p in [parent_of(&a, &b), parent_of(&b, &a)] {
            assert_eq!(p.center, a.center);
            assert_eq!(p.radius, a.radius);
            assert_eq!(p.normal, a.normal);
            assert_eq!(p.cone, a.cone);
        }
    }

    #[test]
    fn identical_spheres_and_zero_radius() {
        let a = node([1.0, 2.0, 3.0], 0.0, [1.0, 0.0, 0.0], 0.0, 0.0, [10, 20, 30, 255]);
        let p = parent_of(&a, &a);
        assert_eq!(p.center, a.center);
        assert_eq!(p.radius, 0.0);
        assert_eq!(p.cone, 0.0);
        assert_eq!(p.color, a.color);
    }

    #[test]
    fn antiparallel_normals_give_right_angle_cone() {
        let a = node([0.0; 3], 1.0, [0.0, 0.0, 1.0], 0.0, 1.0, [0; 4]);
        let b = node([0.0; 3], 1.0, [0.0, 0.0, -1.0], 0.0, 1.0, [0; 4]);
        let p = parent_of(&a, &b);
        assert!((p.cone as f64 - PI / 2.0).abs() < 1e-6, "cone {}", p.cone);
        assert!(p.normal[2].abs() < 1e-6, "axis must be perpendicular: {:?}", p.normal);
        assert!(cone_contains(p.normal, p.cone, a.normal, 0.0, 0.0));
        assert!(cone_contains(p.normal, p.cone, b.normal, 0.0, 0.0));
    }

    #[test]
    fn obtuse_cones_grow_to_whole_sphere() {
        let a = node([0.0; 3], 1.0, [0.0, 0.0, 1.0], 2.0, 1.0, [0; 4]);
        let b = node([0.0; 3], 1.0, [0.0, 0.0, -1.0], 2.0, 1.0, [0; 4]);
        let p = parent_of(&a, &b);
        assert_eq!(p.cone, std::f32::consts::PI);
        // Obtuse but not whole: (π/2 + 2.0 + 0) / 2 < π.
        let c = node([0.0; 3], 1.0, [1.0, 0.0, 0.0], 0.0, 1.0, [0; 4]);
        let q = parent_of(&a, &c);
        assert!(q.cone > 1.5 && q.cone < std::f32::consts::PI);
        assert!(cone_contains(q.normal, q.cone, a.normal, a.cone, 0.0));
        assert!(cone_contains(q.normal, q.cone, c.normal, c.cone, 0.0));
    }

    #[test]
    fn zero_cones_same_normal() {
        let a = node([0.0; 3], 1.0, [0.0, 1.0, 0.0], 0.0, 1.0, [0; 4]);
        let p = parent_of(&a, &a);
        assert_eq!(p.normal, a.normal);
        assert_eq!(p.cone, 0.0);
    }

    #[test]
    fn zero_axis_is_whole_sphere() {
        let a = node([0.0; 3], 1.0, [0.0, 0.0, 0.0], 0.0, 1.0, [0; 4]);
        let b = node([0.0; 3], 1.0, [0.0, 1.0, 0.0], 0.0, 1.0, [0; 4]);
        assert_eq!(parent_of(&a, &b).cone, std::f32::consts::PI);
    }

    #[test]
    fn area_and_colour() {
        let a = node([0.0; 3], 1.0, [0.0, 0.0, 1.0], 0.0, 3.0, [255, 0, 0, 255]);
        let b = node([1.0, 0.0, 0.0], 1.0, [0.0, 0.0, 1.0], 0.0, 1.0, [0, 0, 255, 255]);
        let p = parent_of(&a, &b);
        assert_eq!(p.area, 4.0);
        assert_eq!(p.color, [191, 0, 64, 255]);
        // Zero total area: plain mean.
        assert_eq!(merge_color([0, 0, 0, 0], 0.0, [255, 255, 255, 255], 0.0), [128, 128, 128, 128]);
        // One zero-area child has no influence.
        assert_eq!(merge_color([0, 0, 0, 0], 0.0, [200, 100, 50, 255], 2.0), [200, 100, 50, 255]);
    }

    /// The pre-sharing implementation of [`parent_of`] (each step normalising its own axes,
    /// `f64::round` for the colour),
    /// kept verbatim as the bit-exact reference for the optimised one.
    mod reference {
        use super::super::*;

        pub fn merge_cones(na: [f64; 3], ta: f64, nb: [f64; 3], tb: f64) -> ([f64; 3], f64) {
            let ta = ta.clamp(0.0, PI);
            let tb = tb.clamp(0.0, PI);
            let (a, b) = match (normalize(na), normalize(nb)) {
                (Some(a), Some(b)) => (a, b),
                (Some(a), None) => return (a, PI),
                (None, Some(b)) => return (b, PI),
                (None, None) => return ([0.0, 0.0, 1.0], PI),
            };
            let d = angle_between(a, b);
            if d + tb <= ta {
                return (a, ta);
            }
            if d + ta <= tb {
                return (b, tb);
            }
            let tc = 0.5 * (d + ta + tb);
            if tc >= PI {
                return (a, PI);
            }
            let u = normalize(sub(b, [a[0] * dot(a, b), a[1] * dot(a, b), a[2] * dot(a, b)]))
                .unwrap_or_else(|| any_perpendicular(a));
            let phi = tc - ta;
            let (s, c) = phi.sin_cos();
            ([a[0] * c + u[0] * s, a[1] * c + u[1] * s, a[2] * c + u[2] * s], tc)
        }

        fn covering_cone(n: [f32; 3], a: &Node, b: &Node) -> f32 {
            let Some(n) = normalize(to64(n)) else { return std::f32::consts::PI };
            let need = |m: &Node| match normalize(to64(m.normal)) {
                Some(m_axis) => angle_between(n, m_axis) + m.cone as f64,
                None => PI,
            };
            let t = need(a).max(need(b)) * (1.0 + F64_MARGIN) + F64_MARGIN;
            if t >= PI {
                std::f32::consts::PI
            } else {
                f32_up(t).min(std::f32::consts::PI)
            }
        }

        pub fn merge_color(ca: [u8; 4], wa: f32, cb: [u8; 4], wb: f32) -> [u8; 4] {
            let (wa, wb) = (wa.max(0.0) as f64, wb.max(0.0) as f64);
            let (wa, wb) = if wa + wb > 0.0 && (wa + wb).is_finite() { (wa, wb) } else { (1.0, 1.0) };
            let inv = 1.0 / (wa + wb);
            let mut out = [0u8; 4];
            for i in 0..4 {
                let v = (ca[i] as f64 * wa + cb[i] as f64 * wb) * inv;
                out[i] = v.round().clamp(0.0, 255.0) as u8;
            }
            out
        }

        pub fn parent_of(a: &Node, b: &Node) -> Node {
            let (c, r) = enclosing_sphere(to64(a.center), a.radius as f64, to64(b.center), b.radius as f64);
            let center = to32(c);
            let radius = if center == a.center && r == a.radius as f64 && covers(a, b) {
                a.radius
            } else if center == b.center && r == b.radius as f64 && covers(b, a) {
                b.radius
            } else {
                covering_radius(center, a, b)
            };
            let (n, t) = merge_cones(to64(a.normal), a.cone as f64, to64(b.normal), b.cone as f64);
            let normal = to32(n);
            let cone = if normal == a.normal && t == a.cone as f64 && cone_contains(a.normal, a.cone, b.normal, b.cone, 0.0) {
                a.cone
            } else if normal == b.normal && t == b.cone as f64 && cone_contains(b.normal, b.cone, a.normal, a.cone, 0.0) {
                b.cone
            } else {
                covering_cone(normal, a, b)
            };
            Node {
                center,
                radius,
                normal,
                cone,
                area: merge_area(a.area, b.area),
                color: merge_color(a.color, a.area, b.color, b.area),
            }
        }
    }

    fn node_bits(n: &Node) -> ([u32; 3], u32, [u32; 3], u32, u32, [u8; 4]) {
        (
            n.center.map(f32::to_bits),
            n.radius.to_bits(),
            n.normal.map(f32::to_bits),
            n.cone.to_bits(),
            n.area.to_bits(),
            n.color,
        )
    }

    /// Test inputs from the workspace's generator, plus special values.
    struct Rng(crate::rng::SplitMix64);
    impl Rng {
        fn new(seed: u64) -> Self {
            Rng(crate::rng::SplitMix64(seed))
        }
        fn next(&mut self) -> u64 {
            self.0.next_u64()
        }
        fn unit(&mut self) -> f32 {
            self.0.next_f32()
        }
        fn pick<T: Copy>(&mut self, v: &[T]) -> T {
            v[(self.next() % v.len() as u64) as usize]
        }
        /// A float from a mix of ordinary, special and raw-bit values.
        fn float(&mut self, scale: f32) -> f32 {
            const SPECIAL: [f32; 12] = [
                0.0, -0.0, 1.0, -1.0, f32::MIN_POSITIVE, 1e-30, 1e30, f32::INFINITY, f32::NEG_INFINITY,
                f32::NAN, std::f32::consts::PI, std::f32::consts::FRAC_PI_2,
            ];
            match self.next() % 16 {
                0 => self.pick(&SPECIAL),
                1 => f32::from_bits(self.next() as u32),
                _ => (self.unit() * 2.0 - 1.0) * scale,
            }
        }
        fn axis(&mut self) -> [f32; 3] {
            match self.next() % 8 {
                0 => [self.float(1.0), self.float(1.0), self.float(1.0)],
                1 => [0.0, 0.0, 0.0],
                2 => self.pick(&[[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]),
                _ => {
                    let v = [self.unit() * 2.0 - 1.0, self.unit() * 2.0 - 1.0, self.unit() * 2.0 - 1.0];
                    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                    if l > 0.0 { v.map(|x| x / l) } else { [0.0, 0.0, 1.0] }
                }
            }
        }
        fn node(&mut self) -> Node {
            let scale = self.pick(&[1e-4f32, 1e-2, 1.0, 100.0, 1e6]);
            let cone = match self.next() % 6 {
                0 => 0.0,
                1 => std::f32::consts::PI,
                2 => self.float(4.0),
                _ => self.unit() * std::f32::consts::PI,
            };
            Node {
                center: [self.float(scale), self.float(scale), self.float(scale)],
                radius: match self.next() % 4 {
                    0 => 0.0,
                    1 => self.float(scale),
                    _ => self.unit() * scale,
                },
                normal: self.axis(),
                cone,
                area: if self.next() % 4 == 0 { self.float(10.0) } else { self.unit() * 10.0 },
                color: (self.next() as u32).to_le_bytes(),
            }
        }
        /// A node related to `a`: a copy, a shifted copy, one nested inside, or a copy with
        /// a nearby, equal or opposite axis (the containment and antiparallel branches).
        fn related(&mut self, a: &Node) -> Node {
            let mut b = self.node();
            match self.next() % 6 {
                0 => b = *a,
                1 => {
                    b.center = a.center;
                    b.radius = a.radius * self.unit();
                }
                2 => b.normal = a.normal,
                3 => b.normal = a.normal.map(|x| -x),
                4 => {
                    b.normal = a.normal.map(|x| x + (self.unit() - 0.5) * 1e-3);
                    b.cone = a.cone;
                }
                _ => {
                    b.normal = a.normal;
                    b.cone = a.cone * self.unit();
                    b.center = a.center;
                }
            }
            b
        }
    }

    #[test]
    fn round_to_u8_matches_round_clamp_cast() {
        let reference = |v: f64| v.round().clamp(0.0, 255.0) as u8;
        let mut vs = vec![f64::NAN, f64::INFINITY, f64::NEG_INFINITY, f64::MAX, f64::MIN, -0.0, 0.0, 1e-300, -1e-300];
        for k in -4..=1024 {
            let h = k as f64 * 0.5;
            let (mut lo, mut hi) = (h, h);
            for _ in 0..4 {
                lo = lo.next_down();
                hi = hi.next_up();
                vs.extend([lo, hi]);
            }
            vs.push(h);
        }
        let mut rng = Rng::new(7);
        for _ in 0..200_000 {
            vs.push((rng.unit() as f64 * 2.0 - 0.5) * 300.0);
            vs.push(f64::from_bits(rng.next()));
        }
        for v in vs {
            assert_eq!(round_to_u8(v), reference(v), "v = {v:e} ({:#x})", v.to_bits());
        }
    }

    #[test]
    fn merge_color_matches_reference() {
        let mut rng = Rng::new(11);
        for _ in 0..400_000 {
            let (ca, cb) = ((rng.next() as u32).to_le_bytes(), (rng.next() as u32).to_le_bytes());
            let (wa, wb) = (rng.float(10.0), if rng.next() % 4 == 0 { rng.float(1e-3) } else { rng.unit() * 10.0 });
            assert_eq!(merge_color(ca, wa, cb, wb), reference::merge_color(ca, wa, cb, wb), "{ca:?} {wa:e} {cb:?} {wb:e}");
        }
        // Equal colours (the shortcut): every channel value, weights of every scale,
        // zero, negative, infinite and NaN.
        let special = [0.0, -0.0, -1.0, f32::MIN_POSITIVE, 1e-45, f32::MAX, f32::INFINITY, f32::NEG_INFINITY, f32::NAN, 1.0, 3.0];
        for k in 0..200_000u32 {
            let c = (rng.next() as u32).to_le_bytes().map(|v| if k % 3 == 0 { [0, 1, 127, 128, 254, 255][v as usize % 6] } else { v });
            let w = |rng: &mut Rng| match rng.next() % 3 {
                0 => special[(rng.next() % special.len() as u64) as usize],
                1 => f32::from_bits(rng.next() as u32),
                _ => rng.unit() * 10.0,
            };
            let (wa, wb) = (w(&mut rng), w(&mut rng));
            assert_eq!(merge_color(c, wa, c, wb), reference::merge_color(c, wa, c, wb), "{c:?} {wa:e} {wb:e}");
        }
    }

    #[test]
    fn parent_of_matches_reference_bit_for_bit() {
        let mut rng = Rng::new(0x0005_C70F_9A2E);
        for i in 0..400_000 {
            let a = rng.node();
            let b = if i % 2 == 0 { rng.node() } else { rng.related(&a) };
            for (x, y) in [(&a, &b), (&b, &a)] {
                let got = node_bits(&parent_of(x, y));
                let want = node_bits(&reference::parent_of(x, y));
                assert_eq!(got, want, "case {i}: parent_of({x:?}, {y:?})");
            }
            let (n1, t1) = merge_cones(to64(a.normal), a.cone as f64, to64(b.normal), b.cone as f64);
            let (n2, t2) = reference::merge_cones(to64(a.normal), a.cone as f64, to64(b.normal), b.cone as f64);
            assert_eq!((n1.map(f64::to_bits), t1.to_bits()), (n2.map(f64::to_bits), t2.to_bits()), "case {i}");
        }
        // Deep folds: parents of parents (the builder's real inputs).
        let mut rng = Rng::new(42);
        for _ in 0..2_000 {
            let mut acc_new = rng.node();
            let mut acc_old = acc_new;
            for _ in 0..16 {
                let s = if rng.next() % 3 == 0 { rng.related(&acc_new) } else { rng.node() };
                acc_new = parent_of(&acc_new, &s);
                acc_old = reference::parent_of(&acc_old, &s);
                assert_eq!(node_bits(&acc_new), node_bits(&acc_old));
            }
        }
    }

    /// Leaf-like siblings: unit f32 normals a small angle apart (or equal), small cones.
    fn realistic_pair(rng: &mut Rng) -> (Node, Node) {
        let mut a = rng.node();
        let mut b = rng.node();
        let n = loop {
            let n = rng.axis();
            if normalize(to64(n)).is_some() && n.iter().all(|x| x.is_finite()) {
                break n;
            }
        };
        let spread = rng.pick(&[0.0f32, 1e-6, 1e-3, 0.05, 0.3, 1.0]);
        let tilt = |rng: &mut Rng| n.map(|x| x + (rng.unit() - 0.5) * spread);
        let unit = |v: [f32; 3]| {
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            v.map(|x| x / l)
        };
        a.normal = unit(tilt(rng));
        b.normal = unit(tilt(rng));
        a.cone = rng.pick(&[0.0, 0.0, 1e-3, 0.1, 0.5]) * rng.unit();
        b.cone = rng.pick(&[0.0, 0.0, 1e-3, 0.1, 0.5]) * rng.unit();
        (a, b)
    }

    #[test]
    fn bounded_cone_matches_exact_and_decides_realistic_pairs() {
        let mut rng = Rng::new(0xC0DE);
        let (mut tried, mut decided) = (0u32, 0u32);
        for i in 0..400_000 {
            let (a, b) = match i % 3 {
                0 => realistic_pair(&mut rng),
                1 => (rng.node(), rng.node()),
                _ => {
                    let a = rng.node();
                    (a, rng.related(&a))
                }
            };
            let (ua, ub) = (normalize(to64(a.normal)), normalize(to64(b.normal)));
            let (Some(va), Some(vb)) = (ua, ub) else { continue };
            let exact = parent_cone(&a, ua, &b, ub);
            let got = parent_cone_bounded(&a, va, &b, vb);
            if let Some(got) = got {
                assert_eq!(
                    (got.0.map(f32::to_bits), got.1.to_bits()),
                    (exact.0.map(f32::to_bits), exact.1.to_bits()),
                    "case {i}: {a:?} {b:?}"
                );
            }
            if i % 3 == 0 && a.normal != b.normal {
                tried += 1;
                decided += u32::from(got.is_some());
            }
        }
        // The fast path is the point: it must decide nearly every leaf-like pair.
        assert!(decided as f64 >= 0.97 * tried as f64, "{decided} of {tried}");
    }

    #[test]
    fn bottom_up_merges_of_leaf_like_nodes_match_reference() {
        let mut rng = Rng::new(99);
        for _ in 0..200 {
            let (base, _) = realistic_pair(&mut rng);
            let mut level: Vec<Node> = (0..256)
                .map(|_| {
                    let (mut x, _) = realistic_pair(&mut rng);
                    x.normal = base.normal.map(|v| v + (rng.unit() - 0.5) * 0.2);
                    x.cone = 0.0;
                    x
                })
                .collect();
            while level.len() > 1 {
                level = level
                    .chunks(2)
                    .map(|p| {
                        let (got, want) = (parent_of(&p[0], &p[1]), reference::parent_of(&p[0], &p[1]));
                        assert_eq!(node_bits(&got), node_bits(&want), "{:?}", p);
                        got
                    })
                    .collect();
            }
        }
    }

    fn arb_unit() -> impl Strategy<Value = [f32; 3]> {
        (-1.0f32..1.0, -1.0f32..1.0, -1.0f32..1.0)
            .prop_filter("nonzero", |(x, y, z)| x * x + y * y + z * z > 1e-3)
            .prop_map(|(x, y, z)| {
                let l = (x * x + y * y + z * z).sqrt();
                [x / l, y / l, z / l]
            })
    }

    prop_compose! {
        fn arb_node()(
            c in prop::array::uniform3(-1000.0f32..1000.0),
            scale in prop::sample::select(vec![1e-4f32, 1e-2, 1.0, 100.0]),
            r in 0.0f32..10.0,
            n in arb_unit(),
            cone in prop_oneof![Just(0.0f32), 0.0f32..std::f32::consts::PI, Just(std::f32::consts::PI)],
            area in 0.0f32..10.0,
            color in prop::array::uniform4(any::<u8>()),
        ) -> Node {
            node([c[0] * scale, c[1] * scale, c[2] * scale], r * scale, n, cone, area, color)
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        #[test]
        fn parent_contains_children(a in arb_node(), b in arb_node()) {
            let p = parent_of(&a, &b);
            prop_assert!(p.is_finite());
            prop_assert!(sphere_contains(&p, &a, 0.0), "{p:?} !⊇ {a:?}");
            prop_assert!(sphere_contains(&p, &b, 0.0), "{p:?} !⊇ {b:?}");
            prop_assert!(cone_contains(p.normal, p.cone, a.normal, a.cone, 0.0));
            prop_assert!(cone_contains(p.normal, p.cone, b.normal, b.cone, 0.0));
            // Tightness: never larger than the sum-based bound by more than rounding.
            let d = norm(sub(to64(a.center), to64(b.center)));
            let bound = (0.5 * (d + a.radius as f64 + b.radius as f64)).max(a.radius as f64).max(b.radius as f64);
            prop_assert!((p.radius as f64) <= bound * (1.0 + 1e-6) + 1e-6 * bound.max(1e-30) + 1e-30);
            prop_assert!(p.area >= a.area.max(b.area));
        }

        #[test]
        fn nested_merges_keep_containment(nodes in prop::collection::vec(arb_node(), 2..16)) {
            // Fold left: every original node must stay inside the final parent (transitivity
            // through rounded f32 parents).
            let mut acc = nodes[0];
            for n in &nodes[1..] {
                acc = parent_of(&acc, n);
            }
            for n in &nodes {
                prop_assert!(sphere_contains(&acc, n, 0.0));
                prop_assert!(cone_contains(acc.normal, acc.cone, n.normal, n.cone, 0.0));
            }
        }

        #[test]
        fn merge_is_symmetric_in_size(a in arb_node(), b in arb_node()) {
            let p = parent_of(&a, &b);
            let q = parent_of(&b, &a);
            prop_assert!((p.radius - q.radius).abs() <= 1e-5 * p.radius.max(1e-20));
            prop_assert_eq!(p.area, q.area);
        }
    }
}
