//! Which meshes are seen from both sides (spec §6.2, two-sided trees).
//!
//! A renderer may cull a surface seen from its back only when the source promises that the
//! back is never seen. glTF says so per material (`doubleSided`); OBJ and PLY say nothing,
//! so their meshes are judged by their topology: a closed mesh whose faces are consistently
//! oriented hides its back faces behind its front ones, so it keeps back-face culling and its
//! speed; an open mesh (a leaf card, a bunny with holes in its base) or one whose faces
//! disagree about "outside" (a beetle exported with flipped parts) shows back faces, so it is
//! two-sided.

use std::collections::HashMap;

use crate::mesh::{LoadedScene, Mesh};

impl LoadedScene {
    /// Whether mesh `i` is seen from both sides: when any primitive's material is
    /// double-sided (glTF `doubleSided`), or, in a format that does not declare sidedness
    /// (OBJ, PLY), when the mesh is not [`closed_and_oriented`].
    pub fn mesh_two_sided(&self, i: usize) -> bool {
        let Some(mesh) = self.meshes.get(i) else { return false };
        mesh.primitives.iter().any(|p| self.material(p).double_sided) || (!self.declares_sides && !closed_and_oriented(mesh))
    }

    /// A point cloud is two-sided: without normals nothing says which way its surface
    /// faces, and a scan's normals, when present, are often estimated without a consistent
    /// orientation (the pond scan's point half away from the viewer: culled, 80 % of its
    /// pixels went missing).
    pub fn points_two_sided(&self) -> bool {
        self.points.is_some()
    }
}

/// Whether every edge of the mesh (vertices welded by exact position, over all primitives)
/// is shared by exactly two triangles that run it in opposite directions: a closed,
/// consistently oriented surface. Degenerate triangles (two equal corners) are ignored.
pub fn closed_and_oriented(mesh: &Mesh) -> bool {
    let mut ids: HashMap<[u32; 3], u32> = HashMap::new();
    // Directed edge (a, b) → +1 for each a→b, and the undirected edge's use count.
    let mut directed: HashMap<(u32, u32), i32> = HashMap::new();
    let mut any = false;
    for p in &mesh.primitives {
        let mut id = |v: u32| -> Option<u32> {
            let pos = p.positions.get(v as usize)?;
            let key = pos.map(|c| if c == 0.0 { 0 } else { c.to_bits() });
            let next = ids.len() as u32;
            Some(*ids.entry(key).or_insert(next))
        };
        for t in &p.triangles {
            let (Some(a), Some(b), Some(c)) = (id(t[0]), id(t[1]), id(t[2])) else { return false };
            if a == b || b == c || a == c {
                continue;
            }
            any = true;
            for (u, v) in [(a, b), (b, c), (c, a)] {
                *directed.entry((u, v)).or_insert(0) += 1;
            }
        }
    }
    // Closed and oriented: each directed edge once, and its reverse once.
    any && directed.iter().all(|(&(u, v), &n)| n == 1 && directed.get(&(v, u)) == Some(&1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{Material, Primitive};

    fn mesh(positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>) -> Mesh {
        Mesh { name: "m".into(), primitives: vec![Primitive { positions, triangles, ..Default::default() }] }
    }

    fn tetra(flip_one: bool) -> Mesh {
        let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let mut t = vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]];
        if flip_one {
            t[2] = [1, 3, 2];
        }
        mesh(p, t)
    }

    #[test]
    fn closed_oriented_tetrahedron_is_one_sided() {
        assert!(closed_and_oriented(&tetra(false)));
    }

    #[test]
    fn flipped_face_or_hole_makes_two_sided() {
        assert!(!closed_and_oriented(&tetra(true)));
        let mut open = tetra(false);
        open.primitives[0].triangles.pop();
        assert!(!closed_and_oriented(&open));
        // An edge shared by three triangles (a fin on the tetrahedron).
        let mut fin = tetra(false);
        fin.primitives[0].positions.push([1.0, 1.0, 1.0]);
        fin.primitives[0].triangles.push([0, 1, 4]);
        assert!(!closed_and_oriented(&fin));
        assert!(!closed_and_oriented(&mesh(vec![], vec![])));
        // A single quad (a leaf card) is open.
        let quad = mesh(vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]], vec![[0, 1, 2], [0, 2, 3]]);
        assert!(!closed_and_oriented(&quad));
    }

    #[test]
    fn seams_weld_by_position() {
        // The tetrahedron with every triangle's corners duplicated (as at UV seams).
        let t = tetra(false);
        let p = &t.primitives[0];
        let mut positions = Vec::new();
        let mut triangles = Vec::new();
        for tri in &p.triangles {
            let base = positions.len() as u32;
            positions.extend(tri.map(|i| p.positions[i as usize]));
            triangles.push([base, base + 1, base + 2]);
        }
        assert!(closed_and_oriented(&mesh(positions, triangles)));
    }

    #[test]
    fn gltf_sidedness_comes_from_materials() {
        let mut scene = LoadedScene { meshes: vec![tetra(false)], declares_sides: true, ..Default::default() };
        assert!(!scene.mesh_two_sided(0));
        scene.materials.push(Material { double_sided: true, ..Default::default() });
        scene.meshes[0].primitives[0].material = Some(0);
        assert!(scene.mesh_two_sided(0));
        // Without declared sidedness a double-sided material still counts; without it the
        // closed tetrahedron stays one-sided, and an open glTF mesh too.
        scene.declares_sides = false;
        assert!(scene.mesh_two_sided(0));
        scene.meshes[0].primitives[0].material = None;
        assert!(!scene.mesh_two_sided(0));
        scene.meshes[0].primitives[0].triangles.pop();
        assert!(scene.mesh_two_sided(0));
        scene.declares_sides = true;
        assert!(!scene.mesh_two_sided(0), "glTF: an open mesh with one-sided materials is culled as its format says");
    }
}
