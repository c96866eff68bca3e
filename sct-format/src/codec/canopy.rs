//! The canopy profile: the thesis's 86-bit node (§5.9.1), padded to whole bytes.
//!
//! Each child is stored on its own, relative to its decoded parent, in a fixed-size record
//! (no padding between records; all multi-byte fields little-endian):
//!
//! | bytes | field |
//! |---|---|
//! | 0–1 | `u16`: bits 0–13 position/radius state (< [`posrad::STATE_COUNT`]), bits 14–15 zero |
//! | 2–3 | `u16`: octahedral normal code (`u` low byte, `v` high byte), see [`normal`] |
//! | 4 | `u8`: cone code, semi-angle `code·π/255` (255 → f32 π) |
//! | 5–6 | `u16`: RGB565, `r << 11 | g << 5 | b` |
//! | 7 (RGBA only) | `u8`: alpha code in bits 0–3, bits 4–7 zero |
//! | 7–10 / 8–11 | `f32` area |
//!
//! so 11 bytes a node (86 bits used, 2 padding bits) without alpha and 12 bytes (90 used)
//! with alpha. We pad rather than bit-pack: 2.3 % larger, but every record is byte-aligned
//! and randomly addressable. A decoder rejects non-zero padding bits, states ≥ the state
//! count, and negative or non-finite areas. Without alpha, alpha decodes as 255.
//!
//! # Worst-case errors (documented bounds)
//!
//! - **Containment**: the decoded child sphere contains the original child sphere, checked
//!   as `|c_dec - c| + r ≤ r_dec` in f64 on the f32 values (no further tolerance).
//! - **Position**: the decoded centre is the grid point chosen; for a child inside its
//!   decoded parent whose nearest grid point is legal the error is ≤ √3/12 ≈ 0.144 parent
//!   radii (the thesis's bound). The encoder may pick a farther point when that gives a
//!   smaller decoded radius (near the boundary); the error is then still ≤ the decoded radius
//!   minus the child's radius, i.e. the decoded sphere contains the child.
//! - **Radius**: `r_dec - r < e + 1/13` parent radii (`e` the position error).
//! - **Stick-out** ([`CONTAINMENT_SLACK`]): a decoded child lies inside its decoded parent
//!   grown by `√3/6 + 1/13 ≈ 0.3656` parent radii, for *every* legal state (the legality rule).
//! - **Normal**: ≤ [`normal::MAX_NORMAL_ERROR_DEG`] (0.64°) between axis and decoded axis.
//! - **Cone**: the decoded cone contains the original cone; it is wider by less than the
//!   normal error plus one step π/255 (0.706°).
//! - **Colour**: ≤ 4 steps (R, B), ≤ 2 steps (G), ≤ 8 steps (alpha), 8-bit steps.
//! - **Area**: exact (f32).

use super::{color, normal, posrad, CodecParams};
use crate::error::{Error, Result};
use crate::node::Node;

/// A decoded child lies inside its decoded parent grown by `√3/6 + 1/13 ≈ 0.36560` parent
/// radii: every legal position/radius state satisfies `|g|/6 + q/13 ≤ 1 + √3/6 + 1/13`. The
/// constant adds 1e-4 for the f32 evaluation of centre and radius.
pub const CONTAINMENT_SLACK: f32 = 0.3657;

/// Number of legal position/radius states (see the state rule in `spec/SCT-profiles.md`).
pub const STATE_COUNT: usize = posrad::STATE_COUNT;

/// Worst-case angle between a normal and its decoded axis, degrees.
pub const MAX_NORMAL_ERROR_DEG: f64 = normal::MAX_NORMAL_ERROR_DEG;

/// Worst-case colour error per channel (R, G, B, A) in 8-bit steps.
pub const MAX_COLOR_ERROR: [u8; 4] = [color::MAX_ERR_5, color::MAX_ERR_6, color::MAX_ERR_5, color::MAX_ERR_4];

/// Bytes per node record.
pub fn node_bytes(params: CodecParams) -> usize {
    if params.alpha {
        12
    } else {
        11
    }
}

/// Checks a decoded parent can anchor children.
pub(super) fn check_parent(p: &Node, k: usize) -> Result<()> {
    if !(p.center.iter().all(|v| v.is_finite()) && p.radius.is_finite() && p.radius > 0.0) {
        return Err(Error::Misuse(format!(
            "parent {k} has a non-finite centre or a radius that is not positive (centre ({}, {}, {}), radius {})",
            p.center[0], p.center[1], p.center[2], p.radius
        )));
    }
    Ok(())
}

/// Checks a child's attributes are representable.
#[inline]
pub(super) fn check_child(c: &Node, i: usize, params: CodecParams) -> Result<()> {
    // Inlined test; the error is built out of line (it kept this function from inlining).
    if attributes_usable(c) && (params.alpha || c.color[3] == 255) {
        return Ok(());
    }
    child_error(c, i, params)
}

/// Finite attributes, radius and area not negative.
#[inline]
fn attributes_usable(c: &Node) -> bool {
    // The same test, cheaper: a sum of the nine values is finite only if each is (an infinite
    // or NaN term makes it infinite or NaN); an overflowing sum takes the full test.
    let sum = c.center[0] + c.center[1] + c.center[2] + c.normal[0] + c.normal[1] + c.normal[2] + c.radius + c.area + c.cone;
    let finite = sum.is_finite()
        || (c.center.iter().all(|v| v.is_finite())
            && c.radius.is_finite()
            && c.area.is_finite()
            && c.cone.is_finite()
            && c.normal.iter().all(|v| v.is_finite()));
    finite && c.radius >= 0.0 && c.area >= 0.0
}

/// Why [`check_child`] refuses `c`.
#[cold]
#[inline(never)]
fn child_error(c: &Node, i: usize, params: CodecParams) -> Result<()> {
    if !attributes_usable(c) {
        let mut bad = Vec::new();
        if !c.center.iter().all(|v| v.is_finite()) {
            bad.push(format!("centre ({}, {}, {})", c.center[0], c.center[1], c.center[2]));
        }
        if !(c.radius.is_finite() && c.radius >= 0.0) {
            bad.push(format!("radius {}", c.radius));
        }
        if !(c.area.is_finite() && c.area >= 0.0) {
            bad.push(format!("area {}", c.area));
        }
        if !c.normal.iter().all(|v| v.is_finite()) || !c.cone.is_finite() {
            bad.push(format!("normal cone ({}, {}, {}; {} rad)", c.normal[0], c.normal[1], c.normal[2], c.cone));
        }
        return Err(Error::Misuse(format!(
            "child node {i} at ({}, {}, {}) has {}: coordinates this large overflow single precision; scale the model down",
            c.center[0],
            c.center[1],
            c.center[2],
            if bad.is_empty() { "an unusable attribute".to_string() } else { bad.join(", ") }
        )));
    }
    if !params.alpha && c.color[3] != 255 {
        return Err(Error::Misuse(format!(
            "child {i} has alpha {} but the tree's codec parameters say it is opaque",
            c.color[3]
        )));
    }
    Ok(())
}

/// Encodes one child's sphere or explains why it cannot.
pub(super) fn sphere_state(p: &Node, c: &Node, i: usize) -> Result<u16> {
    posrad::encode_sphere(p.center, p.radius, c.center, c.radius).ok_or_else(|| too_far(p, c, i))
}

/// [`sphere_state`] and the other equally tight states (see [`posrad::encode_sphere_ties`]).
pub(super) fn sphere_ties(p: &Node, c: &Node, i: usize) -> Result<posrad::Ties> {
    posrad::encode_sphere_ties(p.center, p.radius, c.center, c.radius).ok_or_else(|| too_far(p, c, i))
}

fn too_far(p: &Node, c: &Node, i: usize) -> Error {
    Error::Misuse(format!(
        "child {i} (centre ({}, {}, {}), radius {}) lies too far outside its decoded parent (centre ({}, {}, {}), radius {}) \
         for any position/radius state to contain it",
        c.center[0], c.center[1], c.center[2], c.radius, p.center[0], p.center[1], p.center[2], p.radius
    ))
}

/// Packs RGB(A) into the 565 word and the 4-bit alpha code.
#[inline]
pub(super) fn color_codes(c: [u8; 4]) -> [u8; 4] {
    // Written out: `[0, 1, 2, 3].map(..)` compiled to an out-of-line `try_map` call (~80
    // instructions a node, twice per node in the default encoder).
    let q = |i: usize| color::quant(c[i], color::BITS[i]);
    [q(0), q(1), q(2), q(3)]
}

/// Encodes sibling pairs relative to their decoded parents; returns them as decoded.
/// On error `out` is left as it was.
pub fn encode(params: CodecParams, parents: &[Node], children: &[Node], out: &mut Vec<u8>) -> Result<Vec<Node>> {
    if children.len() != 2 * parents.len() {
        return Err(Error::Misuse(format!("{} children for {} parents", children.len(), parents.len())));
    }
    let start = out.len();
    let mut dec = Vec::with_capacity(children.len());
    if let Err(e) = encode_into(params, parents, children, out, &mut dec) {
        out.truncate(start);
        return Err(e);
    }
    Ok(dec)
}

/// The quantized codes of one child (what the streams or records hold, predictions undone).
#[derive(Clone, Copy)]
pub(super) struct Codes {
    /// Position/radius state.
    pub state: u16,
    /// Cone code.
    pub cone: u8,
    /// Colour codes (5/6/5/4 bits).
    pub color: [u8; 4],
}

/// The decoded node of one record's codes (`axis` = `oct_decode(c.normal)`, which the encoder
/// has at hand): shared by encoder and decoder, so the encoder returns exactly what a reader
/// gets without decoding its output again.
#[inline]
fn record_node(t: &posrad::Tables, p: &Node, c: Codes, axis: [f32; 3], alpha: bool, area: f32) -> Option<Node> {
    let Codes { state: s, cone, color: q } = c;
    let (center, radius) = posrad::decode_state(t, s as usize, p.center, p.radius)?;
    let color = [
        color::dequant(q[0], 5),
        color::dequant(q[1], 6),
        color::dequant(q[2], 5),
        if alpha { color::dequant(q[3], 4) } else { 255 },
    ];
    Some(Node { center, radius, normal: axis, cone: normal::cone_decode(cone), area, color })
}

fn encode_into(params: CodecParams, parents: &[Node], children: &[Node], out: &mut Vec<u8>, dec: &mut Vec<Node>) -> Result<()> {
    out.reserve(children.len() * node_bytes(params));
    let t = posrad::tables();
    for (k, pair) in children.chunks_exact(2).enumerate() {
        let p = &parents[k];
        check_parent(p, k)?;
        for (h, c) in pair.iter().enumerate() {
            let i = 2 * k + h;
            check_child(c, i, params)?;
            let s = sphere_state(p, c, i)?;
            let (n, axis, cone) = normal::encode_cone_decoded(c.normal, c.cone);
            let q = color_codes(c.color);
            out.extend_from_slice(&s.to_le_bytes());
            out.extend_from_slice(&n.to_le_bytes());
            out.push(cone);
            let rgb = (q[0] as u16) << 11 | (q[1] as u16) << 5 | q[2] as u16;
            out.extend_from_slice(&rgb.to_le_bytes());
            if params.alpha {
                out.push(q[3]);
            }
            out.extend_from_slice(&c.area.to_le_bytes());
            dec.push(
                record_node(t, p, Codes { state: s, cone, color: q }, axis, params.alpha, c.area)
                    .ok_or_else(|| Error::Misuse(format!("canopy encoder: state {s} of child {i} is not decodable (bug)")))?,
            );
        }
    }
    Ok(())
}

/// Decodes the children of `parents` (`2 · parents.len()` records).
pub fn decode(params: CodecParams, parents: &[Node], bytes: &[u8], offset: u64, out: &mut Vec<Node>) -> Result<()> {
    let nb = node_bytes(params);
    let count = parents.len().checked_mul(2).ok_or_else(|| Error::malformed(offset, "parent count overflows"))?;
    let need = count.checked_mul(nb).ok_or_else(|| Error::malformed(offset, "node count overflows"))?;
    if bytes.len() != need {
        return Err(Error::malformed(
            offset,
            format!("canopy block holds {} bytes, {count} nodes of {nb} bytes need {need}", bytes.len()),
        ));
    }
    let t = posrad::tables();
    out.reserve(count);
    for (i, rec) in bytes.chunks_exact(nb).enumerate() {
        let at = offset + (i * nb) as u64;
        let p = &parents[i / 2];
        let u16_at = |o: usize| u16::from_le_bytes([rec[o], rec[o + 1]]);
        let s = u16_at(0);
        if s >> 14 != 0 {
            return Err(Error::malformed(at, "canopy node: padding bits 14-15 of the state word are set"));
        }
        let rgb = u16_at(5);
        if params.alpha && rec[7] >> 4 != 0 {
            return Err(Error::malformed(at + 7, "canopy node: padding bits 4-7 of the alpha byte are set"));
        }
        let a = nb - 4;
        let area = f32::from_le_bytes([rec[a], rec[a + 1], rec[a + 2], rec[a + 3]]);
        if !(area.is_finite() && area >= 0.0) {
            return Err(Error::malformed(at + a as u64, format!("canopy node: area {area} is not a finite non-negative number")));
        }
        let q = [(rgb >> 11) as u8, (rgb >> 5 & 0x3f) as u8, (rgb & 0x1f) as u8, if params.alpha { rec[7] } else { 0 }];
        let node = record_node(t, p, Codes { state: s, cone: rec[4], color: q }, normal::oct_decode(u16_at(2)), params.alpha, area).ok_or_else(|| {
            Error::malformed(at, format!("canopy node: position/radius state {s} ≥ {}", posrad::STATE_COUNT))
        })?;
        out.push(node);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(c: [f32; 3], r: f32) -> Node {
        Node { center: c, radius: r, normal: [0.0, 0.6, 0.8], cone: 0.1, area: 2.5, color: [200, 100, 50, 255] }
    }

    /// Coordinates of 1e30 (areas overflow to infinity): the refusal names the attribute and
    /// the cause in words, not a Rust `Node { … }` structure.
    #[test]
    fn unusable_children_are_described_in_words() {
        let mut c = node([1e30, 0.0, 0.0], 1e30);
        c.area = f32::INFINITY;
        let e = check_child(&c, 3, CodecParams { alpha: false, ..Default::default() }).unwrap_err().to_string();
        assert!(e.contains("area inf") && e.contains("child node 3") && e.contains("scale the model down"), "{e}");
        assert!(!e.contains("Node {") && !e.contains("center:"), "{e}");
    }

    #[test]
    fn round_trip_pair() {
        let p = node([0.0; 3], 1.0);
        let kids = [node([0.5, 0.0, 0.0], 0.5), node([-0.5, 0.0, 0.0], 0.5)];
        let mut out = Vec::new();
        let dec = encode(CodecParams::default(), &[p], &kids, &mut out).unwrap();
        assert_eq!(out.len(), 22);
        for (d, c) in dec.iter().zip(&kids) {
            assert!(posrad::contains(d.center, d.radius, c.center, c.radius));
            assert_eq!(d.area, c.area);
            assert!(normal::angle(d.normal, c.normal) + c.cone as f64 <= d.cone as f64);
        }
        let mut again = Vec::new();
        decode(CodecParams::default(), &[p], &out, 0, &mut again).unwrap();
        assert_eq!(again, dec);
    }

    #[test]
    fn alpha_layout_and_misuse() {
        let p = node([0.0; 3], 1.0);
        let mut kids = [node([0.5, 0.0, 0.0], 0.5), node([-0.5, 0.0, 0.0], 0.5)];
        kids[1].color[3] = 100;
        let mut out = Vec::new();
        assert!(matches!(encode(CodecParams::default(), &[p], &kids, &mut out), Err(Error::Misuse(_))));
        assert!(out.is_empty());
        let dec = encode(CodecParams { alpha: true, ..Default::default() }, &[p], &kids, &mut out).unwrap();
        assert_eq!(out.len(), 24);
        assert_eq!(dec[1].color[3], 102);
    }

    /// The summed finiteness test agrees with checking each value, also when the sum overflows.
    #[test]
    fn check_child_matches_per_value_test() {
        let base = node([1.0, 2.0, 3.0], 0.5);
        let mut cases = vec![base];
        for f in 0..9 {
            for v in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, f32::MAX, -f32::MAX, -1.0, 0.0] {
                let mut c = base;
                let slot = match f {
                    0..=2 => &mut c.center[f],
                    3..=5 => &mut c.normal[f - 3],
                    6 => &mut c.radius,
                    7 => &mut c.area,
                    _ => &mut c.cone,
                };
                *slot = v;
                cases.push(c);
                let mut d = c;
                d.center[1] = f32::MAX;
                cases.push(d);
            }
        }
        for c in cases {
            let all = [c.center[0], c.center[1], c.center[2], c.normal[0], c.normal[1], c.normal[2], c.radius, c.area, c.cone];
            let want = all.iter().all(|v| v.is_finite()) && c.radius >= 0.0 && c.area >= 0.0;
            assert_eq!(check_child(&c, 0, CodecParams::default()).is_ok(), want, "{c:?}");
        }
    }

    #[test]
    fn bad_bytes_are_malformed() {
        let p = node([0.0; 3], 1.0);
        let mut v = Vec::new();
        assert!(decode(CodecParams::default(), &[p], &[0; 21], 7, &mut v).is_err());
        let mut b = [0u8; 22];
        b[0] = 0xff;
        b[1] = 0xff;
        assert!(matches!(decode(CodecParams::default(), &[p], &b, 7, &mut v), Err(Error::Malformed { offset: 7, .. })));
    }
}
