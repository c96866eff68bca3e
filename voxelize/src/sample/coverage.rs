//! Coverage checks: world-space sample spheres and the fraction of points they contain.

use rayon::prelude::*;

use crate::mesh::*;

use super::SampledMesh;

/// A uniform grid hash over points (used for neighbour search and coverage checks).
pub struct Grid {
    cell: f64,
    map: std::collections::HashMap<[i64; 3], Vec<u32>>,
}

impl Grid {
    /// Buckets points into cells of edge `cell`.
    pub fn build(pts: &[[f64; 3]], cell: f64) -> Grid {
        let mut map: std::collections::HashMap<[i64; 3], Vec<u32>> = std::collections::HashMap::new();
        for (i, p) in pts.iter().enumerate() {
            map.entry(p.map(|x| (x / cell).floor() as i64)).or_default().push(i as u32);
        }
        Grid { cell, map }
    }
    /// Calls `f` for every point in cells within `ring` cells of `p`'s cell.
    pub fn for_each_near(&self, p: [f64; 3], ring: i64, mut f: impl FnMut(usize)) {
        let c = p.map(|x| (x / self.cell).floor() as i64);
        for dx in -ring..=ring {
            for dy in -ring..=ring {
                for dz in -ring..=ring {
                    if let Some(v) = self.map.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) {
                        for &j in v {
                            f(j as usize);
                        }
                    }
                }
            }
        }
    }
}

/// World-space spheres (centre, radius) of sampled meshes, every instance applied (affine
/// ones baked as a samples-file consumer does, spec §8).
pub fn world_spheres(meshes: &[SampledMesh]) -> Vec<([f64; 3], f64)> {
    let mut out = Vec::new();
    for m in meshes {
        for s in &m.instances {
            for n in &m.samples {
                out.push((s.apply_point(n.center.map(f64::from)), f64::from(n.radius) * s.scale));
            }
        }
        for mat in &m.affine {
            let a = sct_format::samples::AffineInstance { mesh: 0, matrix: *mat };
            let st = a.max_stretch();
            for n in &m.samples {
                let b = a.transform_node(n, st);
                out.push((b.center.map(f64::from), f64::from(b.radius)));
            }
        }
    }
    out
}

/// Fraction of `points` inside at least one sphere, and the indices of uncovered points.
/// Spheres are bucketed in a grid of the largest radius, so each lookup visits 27 cells.
pub fn coverage(spheres: &[([f64; 3], f64)], points: &[[f64; 3]]) -> (f64, Vec<usize>) {
    if points.is_empty() {
        return (1.0, Vec::new());
    }
    let rmax = spheres.iter().map(|s| s.1).fold(0.0f64, f64::max);
    if !(rmax > 0.0) {
        return (0.0, (0..points.len()).collect());
    }
    let centers: Vec<[f64; 3]> = spheres.iter().map(|s| s.0).collect();
    let grid = Grid::build(&centers, rmax);
    let missed: Vec<usize> = points
        .par_iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let mut hit = false;
            grid.for_each_near(*p, 1, |j| {
                if !hit {
                    let (c, r) = spheres[j];
                    // A relative slack of 1e-6 absorbs f32 storage of centres and radii.
                    let d2 = dot(sub(*p, c), sub(*p, c));
                    hit = d2 <= (r * (1.0 + 1e-6)) * (r * (1.0 + 1e-6));
                }
            });
            (!hit).then_some(i)
        })
        .collect();
    (1.0 - missed.len() as f64 / points.len() as f64, missed)
}
