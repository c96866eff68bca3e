//! Distance from every leaf centre of an SCT file to the surface of its source mesh, in
//! voxel units: the "samples on the surface" figure of the accuracy table
//! (`scripts/accuracy.sh`). Used as a module by the `accuracy` example.
//!
//! Triangles are binned in a hash grid of cells two voxels wide (large triangles split until
//! each piece spans at most a cell per axis, so a cell lists only triangles that come near
//! it); a leaf looks at the cells its own sphere overlaps, because a leaf sphere contains
//! surface points, so its nearest surface point lies within its radius.

use std::collections::HashMap;
use std::path::Path;

use sct_format::traverse::{ReachedKind, Traversal, TraverseOptions};
use voxelize::mesh::closest_on_triangle;

type V3 = [f64; 3];

fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}


/// Triangles of a mesh in a hash grid.
pub struct SurfaceGrid {
    tris: Vec<[V3; 3]>,
    cell: f64,
    cells: HashMap<[i64; 3], Vec<u32>>,
}

impl SurfaceGrid {
    /// Bins `tris` in cells of edge `cell`.
    pub fn new(tris: Vec<[V3; 3]>, cell: f64) -> SurfaceGrid {
        let mut g = SurfaceGrid { tris, cell, cells: HashMap::new() };
        for i in 0..g.tris.len() {
            let t = g.tris[i];
            g.bin(i as u32, t, 0);
        }
        g
    }

    fn key(&self, p: V3) -> [i64; 3] {
        p.map(|v| (v / self.cell).floor() as i64)
    }

    fn bin(&mut self, i: u32, t: [V3; 3], depth: u32) {
        let lo = self.key([0, 1, 2].map(|k| t[0][k].min(t[1][k]).min(t[2][k])));
        let hi = self.key([0, 1, 2].map(|k| t[0][k].max(t[1][k]).max(t[2][k])));
        let span = (0..3).map(|k| hi[k] - lo[k]).max().unwrap_or(0);
        if span > 1 && depth < 24 {
            // Four pieces at the edge midpoints: each about half as wide.
            let m = |a: V3, b: V3| [0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]), 0.5 * (a[2] + b[2])];
            let (ab, bc, ca) = (m(t[0], t[1]), m(t[1], t[2]), m(t[2], t[0]));
            for piece in [[t[0], ab, ca], [ab, t[1], bc], [ca, bc, t[2]], [ab, bc, ca]] {
                self.bin(i, piece, depth + 1);
            }
            return;
        }
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    let v = self.cells.entry([x, y, z]).or_default();
                    if v.last() != Some(&i) {
                        v.push(i);
                    }
                }
            }
        }
    }

    /// Distance from `p` to the nearest triangle within `r` of it (searching the cells the
    /// ball overlaps), or `None` when none is that close.
    pub fn distance_within(&self, p: V3, r: f64) -> Option<f64> {
        let lo = self.key(p.map(|v| v - r));
        let hi = self.key(p.map(|v| v + r));
        let mut best = f64::INFINITY;
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    for &i in self.cells.get(&[x, y, z]).map_or(&[][..], Vec::as_slice) {
                        let q = closest_on_triangle(p, &self.tris[i as usize]);
                        best = best.min(dot(sub(p, q), sub(p, q)).sqrt());
                    }
                }
            }
        }
        (best <= r * (1.0 + 1e-6) + 1e-12).then_some(best)
    }
}

/// World triangles of a mesh file (every instance), or `None` for a point cloud.
pub fn mesh_triangles(path: &Path) -> Result<Option<Vec<[V3; 3]>>, String> {
    let scene = voxelize::load(path, &voxelize::LoadOptions::default()).map_err(|e| e.to_string())?;
    let mut tris = Vec::new();
    for inst in &scene.instances {
        let Some(mesh) = scene.meshes.get(inst.mesh) else { continue };
        for p in &mesh.primitives {
            for t in &p.triangles {
                tris.push(t.map(|i| voxelize::mesh::transform_point(&inst.transform, p.positions[i as usize])));
            }
        }
    }
    Ok((!tris.is_empty()).then_some(tris))
}

/// Leaf centres and radii of an SCT file in world space (through instances and groups).
pub fn leaves(path: &Path) -> Result<Vec<(V3, f64)>, String> {
    let mut out = Vec::new();
    for r in Traversal::open(path, TraverseOptions::default()).map_err(|e| e.to_string())? {
        let r = r.map_err(|e| e.to_string())?;
        if !matches!(r.kind, ReachedKind::Tree) {
            continue;
        }
        let tree = r.file.read_tree(r.tree).map_err(|e| e.to_string())?;
        for i in tree.leaves() {
            let n = r.state.apply(&tree.nodes()[i]);
            out.push((n.center.map(f64::from), f64::from(n.radius)));
        }
    }
    Ok(out)
}

/// Sample centres and radii of a samples file in world space (every placement).
pub fn samples(path: &Path) -> Result<Vec<(V3, f64)>, String> {
    let f = sct_format::samples::SamplesFile::read_file(path, &sct_format::Limits::default()).map_err(|e| e.to_string())?;
    let mut out = Vec::new();
    for inst in &f.instances {
        for n in f.mesh_samples(inst.mesh as usize) {
            let n = inst.transform.apply_node(n);
            out.push((n.center.map(f64::from), f64::from(n.radius)));
        }
    }
    for a in &f.affine_instances {
        let stretch = a.max_stretch();
        for n in f.mesh_samples(a.mesh as usize) {
            let n = a.transform_node(n, stretch);
            out.push((n.center.map(f64::from), f64::from(n.radius)));
        }
    }
    Ok(out)
}

/// (max, mean) distance of the leaf centres to the surface divided by `voxel`, and the
/// number of leaves whose sphere reaches no triangle (each one a containment failure).
pub fn centre_distances(leaves: &[(V3, f64)], grid: &SurfaceGrid, voxel: f64) -> (f64, f64, usize) {
    let (mut max, mut sum, mut far) = (0.0f64, 0.0f64, 0usize);
    for &(c, r) in leaves {
        match grid.distance_within(c, r.max(1e-9 * voxel)) {
            Some(d) => {
                max = max.max(d);
                sum += d;
            }
            None => far += 1,
        }
    }
    let n = (leaves.len() - far).max(1) as f64;
    (max / voxel, sum / n / voxel, far)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closest_points_on_a_triangle() {
        let near = |a: V3, b: V3| (0..3).all(|k| (a[k] - b[k]).abs() < 1e-12);
        let t = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        assert!(near(closest_on_triangle([0.2, 0.2, 5.0], &t), [0.2, 0.2, 0.0]));
        assert!(near(closest_on_triangle([-1.0, -1.0, 0.0], &t), [0.0, 0.0, 0.0]));
        assert!(near(closest_on_triangle([1.0, 1.0, 0.0], &t), [0.5, 0.5, 0.0]));
        let g = SurfaceGrid::new(vec![[[0.0, 0.0, 0.0], [100.0, 0.0, 0.0], [0.0, 100.0, 0.0]]], 0.5);
        assert!(g.distance_within([10.0, 10.0, 0.3], 0.5).is_some_and(|d| (d - 0.3).abs() < 1e-12));
        assert_eq!(g.distance_within([10.0, 10.0, 0.7], 0.5), None);
    }
}
