//! Which meshes are seen from both sides (spec §6.2, two-sided trees).
//!
//! A renderer may cull a surface seen from its back only when the source promises that the
//! back is never seen. glTF says so per material (`doubleSided`); OBJ and PLY say nothing,
//! so their meshes are judged by their topology: a closed mesh whose faces are consistently
//! oriented hides its back faces behind its front ones, so it keeps back-face culling and its
//! speed; an open mesh (a leaf card, a bunny with holes in its base) or one whose faces
//! disagree about "outside" (a beetle exported with flipped parts) shows back faces, so it is
//! two-sided.

use rayon::prelude::*;

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
///
/// Sorts and counts rather than hashes: a dense scan has tens of millions of edges, and hash
/// maps of them cost seconds and hundreds of bytes per triangle (4.4 M triangles: 30 s, the
/// larger part of sampling); a parallel sort of the vertices and a counting layout of the
/// edges cost a fraction of a second and 4 bytes an edge.
pub fn closed_and_oriented(mesh: &Mesh) -> bool {
    // Vertices are numbered over the primitives in order; ids hold 31 bits (below), so
    // larger meshes are judged open (two-sided: never wrong, only slower to draw).
    let mut first = Vec::with_capacity(mesh.primitives.len());
    let mut total = 0usize;
    for p in &mesh.primitives {
        first.push(total);
        total += p.positions.len();
    }
    if total >= 1 << 31 {
        return false;
    }
    // An index out of range (the loaders refuse them) makes the mesh open; checked once, in
    // parallel, so the passes below index freely.
    let out_of_range = |p: &crate::mesh::Primitive| p.triangles.par_iter().any(|t| t.iter().any(|&v| v as usize >= p.positions.len()));
    if mesh.primitives.iter().any(out_of_range) {
        return false;
    }
    // Most meshes that are not closed show it in one parallel pass, without the weld and
    // edge lists below.
    if edge_balance(mesh) != 0 {
        return false;
    }
    // Weld: every vertex, ordered by position (±0 alike) then number, gets the id of its
    // position class: the smallest number in it. Ids then follow the file's vertex order,
    // which the triangles' order mostly follows, so the passes below read and write memory
    // nearly in order (ids in position order scattered them over the whole array).
    let mut verts: Vec<([u32; 3], u32)> = Vec::with_capacity(total);
    for (p, &f) in mesh.primitives.iter().zip(&first) {
        verts.par_extend(p.positions.par_iter().enumerate().map(|(i, &q)| (position_key(q), (f + i) as u32)));
    }
    verts.par_sort_unstable();
    let mut id = vec![0u32; total];
    let mut class = 0u32;
    for (k, v) in verts.iter().enumerate() {
        if k == 0 || verts[k - 1].0 != v.0 {
            class = v.1;
        }
        id[v.1 as usize] = class;
    }
    drop(verts);
    // Each edge filed under its lower id as (higher id, direction): a closed, oriented mesh
    // has every undirected edge exactly twice, once in each direction, so the list of each
    // id holds each of its higher neighbours twice, once per direction. The lists are laid
    // out by counting (two passes over the triangles, 4 bytes an edge, `end` of 4 bytes an
    // id: counts below 2^32, larger meshes are judged open) and checked in parallel, each
    // sorted on its own in cache: cheaper than sorting every edge as one 8-byte key.
    let tris: usize = mesh.primitives.iter().map(|p| p.triangles.len()).sum();
    if tris.checked_mul(3).is_none_or(|e| e > u32::MAX as usize) {
        return false;
    }
    let ids = total;
    let mut end = vec![0u32; ids];
    for_each_edge(mesh, &first, &id, |lo, _| end[lo as usize] += 1);
    // Running sums: `end[v]` is where v's list starts, then (after filling) where it ends.
    let mut sum = 0u32;
    for e in &mut end {
        (*e, sum) = (sum, sum + *e);
    }
    if sum == 0 {
        return false;
    }
    let mut entries = vec![0u32; sum as usize];
    for_each_edge(mesh, &first, &id, |lo, entry| {
        let at = &mut end[lo as usize];
        entries[*at as usize] = entry;
        *at += 1;
    });
    (0..ids).into_par_iter().with_min_len(1 << 12).map_init(Vec::new, |list: &mut Vec<u32>, v| {
        let begin = if v == 0 { 0 } else { end[v - 1] as usize };
        list.clear();
        list.extend_from_slice(&entries[begin..end[v] as usize]);
        list.sort_unstable();
        list.len() % 2 == 0 && list.chunks_exact(2).all(|e| e[0] >> 1 == e[1] >> 1 && e[0] & 1 == 0 && e[1] & 1 == 1)
    })
    .all(|ok| ok)
}

/// The position key of the weld below: the coordinates' bits, ±0 alike.
fn position_key(q: [f32; 3]) -> [u32; 3] {
    q.map(|c| if c == 0.0 { 0 } else { c.to_bits() })
}

/// A 64-bit hash of `z`: one step of the workspace's SplitMix64.
fn mix(z: u64) -> u64 {
    sct_format::rng::SplitMix64(z).next_u64()
}

/// The sum, wrapping, over every edge of every non-degenerate triangle of a hash of its two
/// positions (welded as below), added when the triangle runs the edge from the lower key to
/// the higher and subtracted otherwise. In a closed, oriented mesh every edge is run once
/// each way, so the sum is exactly 0: a sum other than 0 proves the mesh is not one (a sum of
/// 0 proves nothing, and the exact test decides). A wrapping sum is the same whatever the
/// order of its terms, so it is the same on any thread count.
fn edge_balance(mesh: &Mesh) -> u64 {
    mesh.primitives
        .iter()
        .map(|p| {
            p.triangles
                .par_iter()
                .map(|t| {
                    let [a, b, c] = t.map(|v| position_key(p.positions[v as usize]));
                    if a == b || b == c || a == c {
                        return 0;
                    }
                    [(a, b), (b, c), (c, a)].iter().fold(0u64, |s, &(u, v)| {
                        let (lo, hi, plus) = if u < v { (u, v, true) } else { (v, u, false) };
                        let h = mix(mix(mix(lo[0] as u64 | (lo[1] as u64) << 32) ^ (lo[2] as u64 | (hi[0] as u64) << 32)) ^ (hi[1] as u64 | (hi[2] as u64) << 32));
                        if plus { s.wrapping_add(h) } else { s.wrapping_sub(h) }
                    })
                })
                .reduce(|| 0, u64::wrapping_add)
        })
        .fold(0, u64::wrapping_add)
}

/// Calls `f(lower id, higher id << 1 | direction)` for each edge of each non-degenerate
/// triangle (ids welded by position: `id[first[primitive] + vertex]`), direction 0 when the
/// triangle runs the edge from the lower id to the higher. Every index must be in range.
fn for_each_edge(mesh: &Mesh, first: &[usize], id: &[u32], mut f: impl FnMut(u32, u32)) {
    for (pi, p) in mesh.primitives.iter().enumerate() {
        for t in &p.triangles {
            let [a, b, c] = t.map(|v| id[first[pi] + v as usize]);
            if a == b || b == c || a == c {
                continue;
            }
            for (u, v) in [(a, b), (b, c), (c, a)] {
                let (lo, hi, dir) = if u < v { (u, v, 0) } else { (v, u, 1) };
                f(lo, hi << 1 | dir);
            }
        }
    }
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

    /// The rule as a map of directed edges (the definition, slowly).
    fn by_map(m: &Mesh) -> bool {
        let mut ids = std::collections::BTreeMap::new();
        let mut directed = std::collections::BTreeMap::new();
        for p in &m.primitives {
            for t in &p.triangles {
                let mut id = |v: u32| {
                    let key = p.positions[v as usize].map(|c| if c == 0.0 { 0 } else { c.to_bits() });
                    let next = ids.len();
                    *ids.entry(key).or_insert(next)
                };
                let (a, b, c) = (id(t[0]), id(t[1]), id(t[2]));
                if a == b || b == c || a == c {
                    continue;
                }
                for e in [(a, b), (b, c), (c, a)] {
                    *directed.entry(e).or_insert(0) += 1;
                }
            }
        }
        !directed.is_empty() && directed.iter().all(|(&(u, v), &n)| n == 1 && directed.get(&(v, u)) == Some(&1))
    }

    /// An octahedron split over primitives, with random faces flipped, dropped, doubled or
    /// made degenerate, and vertices duplicated (welded by position) or signed zeros: the
    /// sorting check agrees with the definition.
    #[test]
    fn sorted_check_agrees_with_the_definition() {
        let mut rng = sct_format::rng::SplitMix64(5);
        let pos = [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]];
        let faces = [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]];
        let (mut closed, mut open) = (0, 0);
        for _ in 0..2000 {
            let mut prims: Vec<Primitive> = (0..1 + rng.next_u64() % 3).map(|_| Primitive::default()).collect();
            for f in faces {
                let mut f: [u32; 3] = f;
                match rng.next_u64() % 24 {
                    0 => continue,
                    1 => f.swap(1, 2),
                    2 => f[1] = f[0],
                    _ => {}
                }
                let copies = if rng.next_u64() % 24 == 0 { 2 } else { 1 };
                let k = (rng.next_u64() % prims.len() as u64) as usize;
                for _ in 0..copies {
                    let p = &mut prims[k];
                    let t = f.map(|v| {
                        let mut q: [f32; 3] = pos[v as usize];
                        if rng.next_u64() % 2 == 0 {
                            q = q.map(|c| if c == 0.0 { -0.0 } else { c });
                        }
                        p.positions.push(q);
                        (p.positions.len() - 1) as u32
                    });
                    p.triangles.push(t);
                }
            }
            let m = Mesh { name: "o".into(), primitives: prims };
            let want = by_map(&m);
            assert_eq!(closed_and_oriented(&m), want);
            if want {
                closed += 1;
            } else {
                open += 1;
            }
        }
        assert!(closed > 100 && open > 100, "{closed} closed, {open} open");
    }

    /// The edge balance is 0 for closed, oriented meshes (welded seams and signed zeros
    /// included) and, in practice, not 0 for open ones: a hole, a flipped face, a fin.
    #[test]
    fn edge_balance_is_zero_exactly_when_every_edge_runs_both_ways() {
        assert_eq!(edge_balance(&tetra(false)), 0);
        // The tetrahedron with every vertex duplicated per face, and signed zeros.
        let t = tetra(false);
        let p = &t.primitives[0];
        let mut positions = Vec::new();
        let triangles = p.triangles.iter().map(|tri| tri.map(|v| {
            positions.push(p.positions[v as usize].map(|c| if c == 0.0 && positions.len() % 2 == 0 { -0.0 } else { c }));
            (positions.len() - 1) as u32
        })).collect();
        assert_eq!(edge_balance(&mesh(positions, triangles)), 0);
        assert_ne!(edge_balance(&tetra(true)), 0);
        let mut open = tetra(false);
        open.primitives[0].triangles.pop();
        assert_ne!(edge_balance(&open), 0);
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
        // An index past the vertices (which no loader lets through) is open, not a panic.
        let mut bad = tetra(false);
        bad.primitives[0].triangles[1][2] = 4;
        assert!(!closed_and_oriented(&bad));
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
