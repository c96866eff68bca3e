#![allow(dead_code)]
use std::path::PathBuf;

use voxelize::mesh::LoadedScene;
use voxelize::sample::{sample_scene, Density, Sampled, SampleOptions};

/// The shared models folder (`../shared/models` from the workspace root), if present.
pub fn models() -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/models");
    p.is_dir().then_some(p)
}

pub fn model(rel: &str) -> Option<PathBuf> {
    let p = models()?.join(rel);
    p.exists().then_some(p)
}

/// A voxel size giving roughly `per_diag` voxels across the scene's diagonal.
pub fn coarse(scene: &LoadedScene, per_diag: f64) -> f64 {
    let (lo, hi) = scene.world_bounds().expect("non-empty scene");
    let d: f64 = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    d / per_diag
}

pub fn sample(scene: &LoadedScene, h: f64, merge: bool) -> Sampled {
    let opts = SampleOptions { density: Density::VoxelSize(h), merge, ..Default::default() };
    sample_scene(scene, &opts, &|_, _| {}).expect("sampling succeeds")
}

pub fn spheres(s: &Sampled) -> Vec<([f64; 3], f64)> {
    voxelize::sample::world_spheres(&s.meshes)
}

/// Closest point of triangle `t` to `p` (Ericson, Real-Time Collision Detection §5.1.5).
pub fn closest_on_triangle(p: [f64; 3], t: &[[f64; 3]; 3]) -> [f64; 3] {
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let along = |a: [f64; 3], d: [f64; 3], s: f64| [a[0] + s * d[0], a[1] + s * d[1], a[2] + s * d[2]];
    let [a, b, c] = *t;
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = sub(p, b);
    let (d3, d4) = (dot(ab, bp), dot(ac, bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return along(a, ab, d1 / (d1 - d3));
    }
    let cp = sub(p, c);
    let (d5, d6) = (dot(ab, cp), dot(ac, cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return along(a, ac, d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return along(b, sub(c, b), (d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    [a[0] + ab[0] * v + ac[0] * w, a[1] + ab[1] * v + ac[1] * w, a[2] + ab[2] * v + ac[2] * w]
}

/// The scene's world triangles (every instance applied).
pub fn world_triangles(scene: &LoadedScene) -> Vec<[[f64; 3]; 3]> {
    let mut out = Vec::new();
    for inst in &scene.instances {
        for p in &scene.meshes[inst.mesh].primitives {
            for t in &p.triangles {
                out.push(t.map(|i| voxelize::mesh::transform_point(&inst.transform, p.positions[i as usize])));
            }
        }
    }
    out
}

/// Distance from each of `points` to the nearest of `tris`: triangles bucketed in a grid of
/// `cell`, searched ring by ring until no unvisited cell can hold a nearer one.
pub fn surface_distances(tris: &[[[f64; 3]; 3]], points: &[[f64; 3]], cell: f64) -> Vec<f64> {
    use rayon::prelude::*;
    use std::collections::HashMap;
    let key = |p: [f64; 3]| p.map(|x| (x / cell).floor() as i64);
    let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
    for (i, t) in tris.iter().enumerate() {
        let lo = key(std::array::from_fn(|k| t.iter().map(|v| v[k]).fold(f64::INFINITY, f64::min)));
        let hi = key(std::array::from_fn(|k| t.iter().map(|v| v[k]).fold(f64::NEG_INFINITY, f64::max)));
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    grid.entry([x, y, z]).or_default().push(i as u32);
                }
            }
        }
    }
    points
        .par_iter()
        .map(|&p| {
            let c = key(p);
            let mut best = f64::INFINITY;
            for ring in 0i64..=64 {
                for dx in -ring..=ring {
                    for dy in -ring..=ring {
                        for dz in -ring..=ring {
                            if dx.abs().max(dy.abs()).max(dz.abs()) != ring {
                                continue;
                            }
                            for &i in grid.get(&[c[0] + dx, c[1] + dy, c[2] + dz]).map_or(&[][..], |v| &v[..]) {
                                let q = closest_on_triangle(p, &tris[i as usize]);
                                best = best.min(((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2)).sqrt());
                            }
                        }
                    }
                }
                if best <= ring as f64 * cell {
                    return best;
                }
            }
            // Far from everything: every triangle.
            tris.iter().map(|t| {
                let q = closest_on_triangle(p, t);
                ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2)).sqrt()
            }).fold(best, f64::min)
        })
        .collect()
}
