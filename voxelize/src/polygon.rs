//! Polygon triangulation: project onto the best-fit plane (Newell normal) and run a
//! constrained Delaunay triangulation (spade), keeping the faces inside the polygon.
//! A fan is wrong for concave polygons (it covers area outside them and covers some inside
//! twice); this keeps the exact polygon area.
//!
//! Cost: the CDT is O(n log n) for n corners. Which of its faces lie inside is decided by
//! an even-odd test against the outline for small polygons (O(n) per face, O(n²) in all) and,
//! above [`EVEN_ODD_MAX_CORNERS`], by a walk over the faces that flips inside/outside when
//! it crosses an outline edge (O(n)): the same faces for a simple polygon, linear time for a
//! hostile one of 10⁶ corners. The loaders also cap the corners of one face
//! ([`crate::LoadOptions::max_face_corners`]).

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

/// Polygons with at most this many corners decide which CDT faces are inside by the
/// even-odd test of each face's centroid against the outline (quadratic, so kept small);
/// larger ones by the linear walk ([`inside_by_walk`]).
pub const EVEN_ODD_MAX_CORNERS: usize = 64;

fn cdt(corners: &[[f32; 3]]) -> Option<Vec<[u32; 3]>> {
    cdt_with(corners, corners.len() <= EVEN_ODD_MAX_CORNERS)
}

fn cdt_with(corners: &[[f32; 3]], even_odd: bool) -> Option<Vec<[u32; 3]>> {
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
    // How many outline edges cover each CDT edge (by undirected edge index): crossing an
    // edge covered an odd number of times switches between inside and outside (a keyhole
    // bridge, walked there and back, is covered twice and switches nothing).
    let mut cover: Vec<u8> = Vec::new();
    for i in 0..handles.len() {
        let (a, b) = (handles[i], handles[(i + 1) % handles.len()]);
        if a != b {
            // Conflicting (self-intersecting) constraints are skipped, not split: the
            // inside tests below still follow the original outline (the even-odd test
            // exactly, the walk approximately).
            for e in t.try_add_constraint(a, b) {
                let k = e.as_undirected().index();
                if k >= cover.len() {
                    cover.resize(k + 1, 0);
                }
                cover[k] ^= 1;
            }
        }
    }
    let walked = if even_odd { None } else { Some(inside_by_walk(&t, &cover)) };
    let mut out = Vec::new();
    for f in t.inner_faces() {
        let vs = f.vertices();
        let is_inside = match &walked {
            Some(w) => w.get(f.fix().index()).copied().unwrap_or(false),
            None => {
                let p = vs.map(|h| h.position());
                let c = [(p[0].x + p[1].x + p[2].x) / 3.0, (p[0].y + p[1].y + p[2].y) / 3.0];
                inside(&pts, c)
            }
        };
        if !is_inside {
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

/// Inside flags of the CDT's faces (by face index): a breadth-first walk from the outer face
/// (outside), switching sides across every edge that `cover` marks as covered an odd number
/// of times by the outline. Linear in the number of faces.
fn inside_by_walk(t: &ConstrainedDelaunayTriangulation<Point2<f64>>, cover: &[u8]) -> Vec<bool> {
    let odd = |e: spade::handles::FixedUndirectedEdgeHandle| cover.get(e.index()).copied().unwrap_or(0) == 1;
    let mut state: Vec<Option<bool>> = vec![None; t.num_all_faces()];
    let mut queue = std::collections::VecDeque::new();
    // Seeds: the faces on the convex hull, reached from the outer face (outside).
    for e in t.convex_hull() {
        for d in [e, e.rev()] {
            if let Some(f) = d.face().as_inner() {
                let slot = &mut state[f.fix().index()];
                if slot.is_none() {
                    *slot = Some(odd(d.as_undirected().fix()));
                    queue.push_back(f.fix());
                }
            }
        }
    }
    while let Some(f) = queue.pop_front() {
        let here = state[f.index()].unwrap_or(false);
        for e in t.face(f).adjacent_edges() {
            if let Some(n) = e.rev().face().as_inner() {
                let slot = &mut state[n.fix().index()];
                if slot.is_none() {
                    *slot = Some(here ^ odd(e.as_undirected().fix()));
                    queue.push_back(n.fix());
                }
            }
        }
    }
    state.into_iter().map(|s| s.unwrap_or(false)).collect()
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

    /// A star of `n` corners alternating between radius 1 and 0.4 (every other corner
    /// reflex), in the plane y = 0.3.
    fn star(n: usize) -> Vec<[f32; 3]> {
        (0..n)
            .map(|i| {
                let r = if i % 2 == 0 { 1.0 } else { 0.4 };
                let a = (i as f64 + 0.5) * std::f64::consts::TAU / n as f64;
                [(r * a.cos()) as f32, 0.3, (r * a.sin()) as f32]
            })
            .collect()
    }

    /// The linear walk keeps exactly the faces the even-odd test keeps, on concave stars, a
    /// comb, and a square with a square hole joined by a keyhole bridge (duplicate corners,
    /// a bridge edge walked twice).
    #[test]
    fn walk_equals_even_odd() {
        let mut comb: Vec<[f32; 3]> = Vec::new();
        for k in 0..40 {
            let x = k as f32;
            comb.extend([[x, 0.0, 0.0], [x, 0.0, 5.0], [x + 0.5, 0.0, 5.0], [x + 0.5, 0.0, 0.2]]);
        }
        comb.extend([[40.0, 0.0, 0.0], [40.0, 0.0, -1.0], [0.0, 0.0, -1.0]]);
        let keyhole: Vec<[f32; 3]> = [
            [0., 0.], [4., 0.], [4., 4.], [0., 4.], [0., 2.], [1., 2.], [1., 3.], [3., 3.], [3., 1.], [1., 1.], [1., 2.], [0., 2.],
        ]
        .iter()
        .map(|p| [p[0], p[1], 0.0])
        .collect();
        for c in [star(10), star(66), star(1000), comb, keyhole] {
            let (a, b) = (cdt_with(&c, true).expect("cdt"), cdt_with(&c, false).expect("cdt"));
            assert_eq!(a, b, "{} corners", c.len());
            assert!((tri_area(&c, &b) - polygon_area(&c)).abs() < 1e-6 * polygon_area(&c));
        }
    }

    /// A face of 200,000 corners, half of them reflex, triangulates into n − 2 triangles of
    /// the polygon's exact area. The even-odd test alone made this quadratic (4·10¹⁰ steps).
    #[test]
    fn huge_concave_polygon_is_exact() {
        let c = star(200_000);
        let t = triangulate(&c);
        assert_eq!(t.len(), c.len() - 2);
        let exact = polygon_area(&c);
        assert!((tri_area(&c, &t) - exact).abs() < 1e-6 * exact);
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
