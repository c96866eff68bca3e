//! Checks of one block: decoding it, each node alone, and each sibling pair against its
//! parent (containment, cone, area, colour).

use super::*;

/// Issues found in a block, by node index within its level.
pub(super) struct BlockOut {
    pub(super) internal_nodes: Vec<Node>,
    pub(super) flags: Vec<bool>,
    pub(super) issues: Vec<(u64, CheckId, String)>,
}

/// Decodes a block with the reader's decoder, naming the failed check.
pub(super) fn decode_block(src: &Source<'_>, idx: &TreeIndex, b: usize, parents: &[Node], limits: &Limits) -> Result<(Vec<Node>, Vec<bool>), Problem> {
    crate::read::decode_block_in(src, idx, b, parents, limits)
        .map(|d| (d.nodes, d.internal))
        .map_err(|er| (classify(&er, CheckId::BlockDecode), er.to_string()))
}

pub(super) fn non_finite_what(n: &Node) -> String {
    let mut bad = Vec::new();
    if !n.center.iter().all(|v| v.is_finite()) {
        bad.push(format!("centre {:?}", n.center));
    }
    if !(n.radius.is_finite() && n.radius >= 0.0) {
        bad.push(format!("radius {}", n.radius));
    }
    if !n.normal.iter().all(|v| v.is_finite()) {
        bad.push(format!("normal {:?}", n.normal));
    }
    if !(n.cone.is_finite() && (0.0..=std::f32::consts::PI).contains(&n.cone)) {
        bad.push(format!("cone {}", n.cone));
    }
    if !(n.area.is_finite() && n.area >= 0.0) {
        bad.push(format!("area {}", n.area));
    }
    bad.join(", ")
}

pub(super) fn normal_ok(n: &Node) -> bool {
    if n.cone >= std::f32::consts::PI - 1e-6 {
        return true;
    }
    let l = n.normal.iter().map(|&v| v as f64 * v as f64).sum::<f64>().sqrt();
    (l - 1.0).abs() <= NORMAL_TOL
}

/// Checks a node on its own (finite, unit axis).
pub(super) fn check_node(n: &Node, at: u64, out: &mut Vec<(u64, CheckId, String)>) -> bool {
    if !n.is_finite() {
        out.push((at, CheckId::NonFinite, non_finite_what(n)));
        return false;
    }
    if !normal_ok(n) {
        out.push((at, CheckId::Normal, format!("cone axis {:?} is not unit length", n.normal)));
    }
    true
}

/// Checks `child` against `parent` (containment and cone).
pub(super) fn check_contained(p: &Node, c: &Node, slack: f32, cone_tol: f32, at: u64, out: &mut Vec<(u64, CheckId, String)>) {
    if !sphere_contains(p, c, slack) {
        let d = dist(p.center, c.center);
        out.push((
            at,
            CheckId::ChildOutsideParent,
            format!(
                "child sphere (centre {:?}, radius {}) reaches {:.6} from the parent centre, parent radius {} (slack {slack} → {:.6})",
                c.center,
                c.radius,
                d + c.radius as f64,
                p.radius,
                p.radius as f64 * (1.0 + slack as f64)
            ),
        ));
    }
    if !cone_contains(p.normal, p.cone, c.normal, c.cone, cone_tol) {
        out.push((
            at,
            CheckId::ConeContainment,
            format!("parent cone (axis {:?}, {:.6} rad) does not contain child cone (axis {:?}, {:.6} rad)", p.normal, p.cone, c.normal, c.cone),
        ));
    }
}

pub(super) fn area_ok(parent: f32, sum: f64) -> bool {
    area_ok_within(parent, sum, 0.0)
}

/// [`area_ok`] with `slack` more absolute difference allowed.
pub(super) fn area_ok_within(parent: f32, sum: f64, slack: f64) -> bool {
    let p = parent as f64;
    (p - sum).abs() <= AREA_REL_TOL * p.abs().max(sum.abs()) + slack + 1e-30
}

pub(super) fn color_ok(a: [u8; 4], b: [u8; 4], tol: [u8; 4]) -> bool {
    (0..4).all(|i| a[i].abs_diff(b[i]) <= tol[i])
}

pub(super) fn dist(a: [f32; 3], b: [f32; 3]) -> f64 {
    (0..3).map(|i| (a[i] as f64 - b[i] as f64).powi(2)).sum::<f64>().sqrt()
}

/// Checks a pair of decoded children against their decoded parent.
pub(super) fn check_pair(p: &Node, a: &Node, b: &Node, first: u64, profile: Profile, out: &mut Vec<(u64, CheckId, String)>) {
    let slack = profile.containment_slack();
    let (cone_tol, col_tol) = (cone_tolerance(profile), color_tolerance(profile));
    let ok_a = check_node(a, first, out);
    let ok_b = check_node(b, first + 1, out);
    if !p.is_finite() {
        return; // reported at the parent's own level
    }
    if ok_a {
        check_contained(p, a, slack, cone_tol, first, out);
    }
    if ok_b {
        check_contained(p, b, slack, cone_tol, first + 1, out);
    }
    if ok_a && ok_b {
        let sum = a.area as f64 + b.area as f64;
        // The parent is the failing node; it is reported at its first child's index with a
        // marker so the path resolver names the parent.
        if !area_ok(p.area, sum) {
            out.push((first | PARENT_BIT, CheckId::AreaSum, format!("parent {:.6}, children {:.6} ({} + {})", p.area, sum, a.area, b.area)));
        }
        let mean = merge_color(a.color, a.area, b.color, b.area);
        if !color_ok(p.color, mean, col_tol) {
            out.push((
                first | PARENT_BIT,
                CheckId::ColorMean,
                format!("parent {:?}, area-weighted mean of children {mean:?} (tolerance {col_tol:?})", p.color),
            ));
        }
    }
}

/// Marks an issue index as "the parent of child `index`".
pub(super) const PARENT_BIT: u64 = 1 << 63;

pub(super) fn check_block(src: &Source<'_>, idx: &TreeIndex, b: usize, parents: &[Node], limits: &Limits) -> Result<BlockOut, Problem> {
    let (nodes, flags) = decode_block(src, idx, b, parents, limits)?;
    let first = idx.blocks[b].first_node;
    let mut issues = Vec::new();
    for (k, p) in parents.iter().enumerate() {
        check_pair(p, &nodes[2 * k], &nodes[2 * k + 1], first + 2 * k as u64, idx.profile, &mut issues);
    }
    let internal_nodes = nodes.iter().zip(&flags).filter(|(_, &f)| f).map(|(n, _)| *n).collect();
    Ok(BlockOut { internal_nodes, flags, issues })
}
