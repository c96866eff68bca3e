use super::*;
use crate::rng::SplitMix64;

fn stretched() -> Affine {
    // Scale (3, 0.5, 2), a shear and a rotation about z, then a translation.
    Affine { matrix: [[2.6, -0.25, 0.4, 1.0], [1.5, 0.43, 0.0, -2.0], [0.0, 0.3, 2.0, 0.5]] }
}

fn mirrored() -> Affine {
    Affine { matrix: [[-1.0, 0.0, 0.0, 0.0], [0.0, 2.0, 0.0, 3.0], [0.0, 0.0, 0.5, 0.0]] }
}

fn random_affine(r: &mut SplitMix64) -> Affine {
    loop {
        let a = Affine { matrix: std::array::from_fn(|_| std::array::from_fn(|_| r.next_f64() * 4.0 - 2.0)) };
        if a.condition() < 50.0 {
            return a;
        }
    }
}

fn unit(r: &mut SplitMix64) -> [f64; 3] {
    loop {
        let v: [f64; 3] = std::array::from_fn(|_| r.next_f64() * 2.0 - 1.0);
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if l > 0.1 && l <= 1.0 {
            return v.map(|x| x / l);
        }
    }
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn len(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

/// σ_max never undershoots the largest stretch of a unit vector and is close to it.
#[test]
fn max_stretch_bounds_every_direction() {
    let mut r = SplitMix64(3);
    for _ in 0..50 {
        let a = random_affine(&mut r);
        let s = a.max_stretch();
        let best = (0..4000).map(|_| len(a.apply_vector(unit(&mut r)))).fold(0.0, f64::max);
        assert!(s >= best && s < best * 1.02, "stretch {s}, sampled {best}");
    }
    assert!((Affine { matrix: [[3.0, 0.0, 0.0, 1.0], [0.0, -0.5, 0.0, 0.0], [0.0, 0.0, 2.0, 0.0]] }.condition() - 6.0).abs() < 1e-9);
}

/// The inverse undoes the map; composition applies the inner map first.
#[test]
fn inverse_and_compose() {
    let a = stretched();
    let inv = a.inverse().expect("invertible");
    let p = [0.3, -1.2, 4.0];
    let back = inv.apply_point(a.apply_point(p));
    assert!(len([back[0] - p[0], back[1] - p[1], back[2] - p[2]]) < 1e-12);
    let b = mirrored();
    let ab = a.compose(&b).apply_point(p);
    let want = a.apply_point(b.apply_point(p));
    assert!(len([ab[0] - want[0], ab[1] - want[1], ab[2] - want[2]]) < 1e-12);
    assert!(Affine { matrix: [[1.0, 2.0, 3.0, 0.0], [2.0, 4.0, 6.0, 0.0], [0.0, 0.0, 1.0, 0.0]] }.inverse().is_none());
}

/// A similarity's matrix composes like the similarity; two similarities stay one.
#[test]
fn transforms_compose_like_their_matrices() {
    let s = Similarity { translation: [1.0, 2.0, 3.0], rotation: [0.0, 0.382_683_432_365_089_8, 0.0, 0.923_879_532_511_286_7], scale: 2.0 };
    let t = Transform::Similarity(s).compose(&Transform::Similarity(s));
    assert!(t.as_similarity().is_some());
    let a = Transform::from(stretched());
    let sa = Transform::Similarity(s).compose(&a);
    assert!(sa.as_similarity().is_none());
    let p = [0.5, -0.25, 2.0];
    let got = sa.apply_point(p);
    let want = s.apply_point(stretched().apply_point(p));
    assert!(len([got[0] - want[0], got[1] - want[1], got[2] - want[2]]) < 1e-12);
    let back = Affine::from_similarity(&s).similarity(1e-9).expect("a similarity");
    assert!((back.scale - 2.0).abs() < 1e-12 && back.rotation.iter().zip(s.rotation).all(|(a, b)| (a - b).abs() < 1e-12));
    assert!(stretched().similarity(1e-6).is_none());
    assert!(mirrored().similarity(1e-6).is_none(), "a mirror is no similarity instance");
}

/// Hostile matrices are refused: NaN, infinite, singular, an entry beyond f32, a condition
/// number above the limit.
#[test]
fn invalid_matrices_are_named() {
    let mut nan = stretched();
    nan.matrix[1][2] = f64::NAN;
    assert!(nan.problem().is_some_and(|m| m.contains("non-finite")));
    let mut inf = stretched();
    inf.matrix[0][3] = f64::INFINITY;
    assert!(!inf.is_valid());
    let singular = Affine { matrix: [[1.0, 2.0, 3.0, 0.0], [2.0, 4.0, 6.0, 0.0], [0.0, 0.0, 1.0, 0.0]] };
    assert!(singular.problem().is_some_and(|m| m.contains("singular")));
    let tiny = Affine { matrix: [[1e-120, 0.0, 0.0, 0.0], [0.0, 1e-120, 0.0, 0.0], [0.0, 0.0, 1e-120, 0.0]] };
    assert!(tiny.problem().is_some_and(|m| m.contains("singular")), "a subnormal determinant");
    let huge = Affine { matrix: [[1e39, 0.0, 0.0, 0.0], [0.0, 1e39, 0.0, 0.0], [0.0, 0.0, 1e39, 0.0]] };
    assert!(huge.problem().is_some_and(|m| m.contains("f32 range")));
    let flat = Affine { matrix: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1e-7, 0.0]] };
    assert!(flat.problem().is_some_and(|m| m.contains("condition number")));
    let fine = Affine { matrix: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1e-5, 0.0]] };
    assert!(fine.is_valid() && stretched().is_valid() && mirrored().is_valid());
}

/// The mapped node bounds what the map does to the node: every point of its sphere lands in
/// the mapped sphere, every normal within its cone lands within the mapped cone, and a
/// flat patch's area scales exactly (Nanson).
#[test]
fn mapped_nodes_bound_mapped_points_and_normals() {
    let mut r = SplitMix64(11);
    for k in 0..40 {
        let a = if k == 0 { mirrored() } else { random_affine(&mut r) };
        let map = AffineMap::new(a);
        let axis = unit(&mut r);
        let cone = (r.next_f64() * 0.6) as f32;
        let n = Node { center: [0.5, -1.0, 2.0], radius: 0.75, normal: axis.map(|v| v as f32), cone, area: 2.0, color: [9, 8, 7, 255] };
        let m = map.apply_node(&n);
        assert!(m.is_finite(), "{m}");
        assert_eq!(m.color, n.color);
        let mc = m.center.map(f64::from);
        for _ in 0..500 {
            let d = unit(&mut r);
            let t = r.next_f64().cbrt() * f64::from(n.radius);
            let p: [f64; 3] = std::array::from_fn(|i| f64::from(n.center[i]) + d[i] * t);
            let q = a.apply_point(p);
            assert!(len([q[0] - mc[0], q[1] - mc[1], q[2] - mc[2]]) <= f64::from(m.radius), "point outside the mapped sphere");
            // A normal within the cone: the axis tilted by at most `cone`.
            let tilt = f64::from(cone) * r.next_f64();
            let side = unit(&mut r);
            let perp = {
                let d = dot(side, axis);
                let v = [side[0] - d * axis[0], side[1] - d * axis[1], side[2] - d * axis[2]];
                let l = len(v).max(1e-12);
                v.map(|x| x / l)
            };
            let nn: [f64; 3] = std::array::from_fn(|i| axis[i] * tilt.cos() + perp[i] * tilt.sin());
            let (mn, _) = map.map_normal(nn).expect("normal");
            let angle = dot(mn, m.normal.map(f64::from)).clamp(-1.0, 1.0).acos();
            assert!(angle <= f64::from(m.cone) + 1e-5, "normal at {angle} outside the mapped cone {}", m.cone);
        }
        // Nanson: a small flat square with normal `axis` maps to a parallelogram of area
        // |Au × Av|.
        let u = {
            let s = if axis[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
            let c = cross(axis, s);
            c.map(|x| x / len(c))
        };
        let v = cross(axis, u);
        let mapped = len(cross(a.apply_vector(u), a.apply_vector(v)));
        let leaf = Node { cone: 0.0, area: 1.0, ..n };
        let ml = map.apply_node(&leaf);
        assert!((f64::from(ml.area) - mapped).abs() <= 1e-5 * mapped, "area {} vs {mapped}", ml.area);
        assert_eq!(ml.cone, 0.0, "a leaf's normal maps exactly");
    }
}

/// A mirror keeps outward normals outward: on a sphere around the origin, the mapped normal
/// of a point points away from the mapped centre's side it came from.
#[test]
fn mirrors_keep_normals_outward() {
    let a = mirrored();
    let map = AffineMap::new(a);
    assert!(a.determinant() < 0.0);
    let mut r = SplitMix64(5);
    for _ in 0..200 {
        let p = unit(&mut r);
        let (n, _) = map.map_normal(p).expect("normal");
        let q = a.apply_point(p);
        let o = a.apply_point([0.0; 3]);
        assert!(dot(n, [q[0] - o[0], q[1] - o[1], q[2] - o[2]]) > 0.0);
    }
}

/// A cone grows by the condition number and stops at π; an ill-conditioned map makes a
/// wide cone "any direction".
#[test]
fn cones_grow_by_the_condition_number() {
    let map = AffineMap::new(Affine { matrix: [[4.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]] });
    assert!((map.map_cone(0.1) - 0.4).abs() < 1e-6);
    assert!(map.map_cone(0.1) >= 0.4);
    assert_eq!(map.map_cone(1.0), std::f32::consts::PI);
    assert_eq!(map.map_cone(0.0), 0.0);
}
