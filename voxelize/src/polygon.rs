//! Polygon triangulation: project onto the best-fit plane (Newell normal) and run a
//! constrained Delaunay triangulation (spade), keeping the faces inside the polygon.
//! A fan is wrong for concave polygons (it covers area outside them and covers some inside
//! twice); this keeps the exact polygon area.

use spade::{ConstrainedDelaunayTriangulation, Point2, Triangulation};

/// Triangulates a simple (possibly concave) polygon given by its corner positions; returns
/// triangles as indices into `corners`, oriented like the polygon. Falls back to a fan when
/// the polygon is degenerate (no plane) or the CDT cannot be built (non-finite input).
pub fn triangulate(corners: &[[f32; 3]]) -> Vec<[u32; 3]> {
    let n = corners.len();
    if n < 3 {
        return Vec::new();
    }
    if n == 3 {
        return vec![[0, 1, 2]];
    }
    cdt(corners).unwrap_or_else(|| fan(n))
}

/// Fan triangulation (correct for convex polygons only).
pub fn fan(n: usize) -> Vec<[u32; 3]> {
    (1..n.saturating_sub(1)).map(|i| [0, i as u32, i as u32 + 1]).collect()
}

/// Area of a planar polygon in 3D (half the length of its Newell vector).
pub fn polygon_area(corners: &[[f32; 3]]) -> f64 {
    let n = newell(corners);
    0.5 * (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt()
}

fn newell(c: &[[f32; 3]]) -> [f64; 3] {
    let mut n = [0.0f64; 3];
    for i in 0..c.len() {
        let a = c[i].map(f64::from);
        let b = c[(i + 1) % c.len()].map(f64::from);
        n[0] += (a[1] - b[1]) * (a[2] + b[2]);
        n[1] += (a[2] - b[2]) * (a[0] + b[0]);
        n[2] += (a[0] - b[0]) * (a[1] + b[1]);
    }
    n
}

fn cdt(corners: &[[f32; 3]]) -> Option<Vec<[u32; 3]>> {
    let nrm = newell(corners);
    let len = (nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]).sqrt();
    if !(len > 0.0) || !len.is_finite() {
        return None;
    }
    let nz = nrm.map(|v| v / len);
    // Orthonormal basis (u, v) of the plane with u × v = n, so the projected polygon keeps
    // the polygon's orientation (counter-clockwise about n).
    let helper = if nz[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let u = normalize(cross(helper, nz));
    let v = cross(nz, u);
    let centroid = {
        let mut c = [0.0; 3];
        for p in corners {
            for k in 0..3 {
                c[k] += f64::from(p[k]);
            }
        }
        c.map(|x| x / corners.len() as f64)
    };
    let mut pts: Vec<[f64; 2]> = corners
        .iter()
        .map(|p| {
            let d = [f64::from(p[0]) - centroid[0], f64::from(p[1]) - centroid[1], f64::from(p[2]) - centroid[2]];
            [dot(d, u), dot(d, v)]
        })
        .collect();
    // Scale to unit size: spade rejects very large coordinates and snaps tiny ones.
    let scale = pts.iter().flat_map(|p| p.iter()).fold(0.0f64, |m, x| m.max(x.abs()));
    if !(scale > 0.0) {
        return None;
    }
    for p in &mut pts {
        *p = [p[0] / scale, p[1] / scale];
    }
    let mut t: ConstrainedDelaunayTriangulation<Point2<f64>> = ConstrainedDelaunayTriangulation::new();
    // Vertex handle index -> first corner at that position (duplicates, e.g. keyhole
    // bridges, map to one handle).
    let mut corner_of: Vec<u32> = Vec::new();
    let mut handles = Vec::with_capacity(pts.len());
    for (i, p) in pts.iter().enumerate() {
        let h = t.insert(Point2::new(p[0], p[1])).ok()?;
        if h.index() >= corner_of.len() {
            corner_of.resize(h.index() + 1, u32::MAX);
        }
        if corner_of[h.index()] == u32::MAX {
            corner_of[h.index()] = i as u32;
        }
        handles.push(h);
    }
    for i in 0..handles.len() {
        let (a, b) = (handles[i], handles[(i + 1) % handles.len()]);
        if a != b {
            // Conflicting (self-intersecting) constraints are skipped, not split: the
            // inside test below still follows the original outline.
            let _ = t.try_add_constraint(a, b);
        }
    }
    let mut out = Vec::new();
    for f in t.inner_faces() {
        let vs = f.vertices();
        let p = vs.map(|h| h.position());
        let c = [(p[0].x + p[1].x + p[2].x) / 3.0, (p[0].y + p[1].y + p[2].y) / 3.0];
        if !inside(&pts, c) {
            continue;
        }
        let idx = vs.map(|h| corner_of.get(h.fix().index()).copied().unwrap_or(u32::MAX));
        if idx.contains(&u32::MAX) {
            continue;
        }
        // spade faces are counter-clockwise in the (u, v) plane, i.e. about n.
        out.push(idx);
    }
    if out.is_empty() {
        return None;
    }
    Some(out)
}

/// Even-odd point-in-polygon test.
fn inside(poly: &[[f64; 2]], p: [f64; 2]) -> bool {
    let mut c = false;
    let n = poly.len();
    let mut j = n - 1;
    for i in 0..n {
        let (a, b) = (poly[i], poly[j]);
        if (a[1] > p[1]) != (b[1] > p[1]) {
            let x = (b[0] - a[0]) * (p[1] - a[1]) / (b[1] - a[1]) + a[0];
            if p[0] < x {
                c = !c;
            }
        }
        j = i;
    }
    c
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn normalize(a: [f64; 3]) -> [f64; 3] {
    let l = dot(a, a).sqrt();
    a.map(|x| x / l)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri_area(c: &[[f32; 3]], t: &[[u32; 3]]) -> f64 {
        t.iter().map(|t| polygon_area(&[c[t[0] as usize], c[t[1] as usize], c[t[2] as usize]])).sum()
    }

    #[test]
    fn concave_l_shape_keeps_area() {
        // An L: area 3; a fan from corner 0 would cover the notch.
        let c = [[0., 0., 0.], [2., 0., 0.], [2., 1., 0.], [1., 1., 0.], [1., 2., 0.], [0., 2., 0.]];
        let t = triangulate(&c);
        assert_eq!(t.len(), 4);
        assert!((tri_area(&c, &t) - 3.0).abs() < 1e-9);
    }

    #[test]
    fn star_vs_fan() {
        // A concave star polygon, fan from a reflex vertex is wrong, CDT is exact.
        let mut c = Vec::new();
        for i in 0..10 {
            let r = if i % 2 == 0 { 1.0 } else { 0.4 };
            let a = (i as f32 + 0.5) * std::f32::consts::TAU / 10.0;
            c.push([r * a.cos(), 0.3, r * a.sin()]);
        }
        let exact = polygon_area(&c);
        let t = triangulate(&c);
        assert!((tri_area(&c, &t) - exact).abs() < 1e-6 * exact);
        // Orientation follows the polygon.
        let n = newell(&c);
        for tr in &t {
            let tn = newell(&[c[tr[0] as usize], c[tr[1] as usize], c[tr[2] as usize]]);
            assert!(dot(n, tn) > 0.0);
        }
    }
}
