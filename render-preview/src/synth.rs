//! Test and benchmark scenes: a small stand-in for the voxelizer and tree builder, so the
//! renderer can be exercised on real models without the other tools. Every triangle is
//! split into a regular grid of sub-triangles no longer than `spacing`; each becomes a
//! leaf whose sphere covers it (centroid, farthest corner), so the leaf discs cover the
//! whole surface. Leaves are organised by median splits on the largest extent (separate
//! objects in separate subtrees) and merged bottom up with `sct_format::geometry::parent_of`.

use std::path::Path;

use sct_format::graph::{Generator, GraphNode, InstanceAttrs, Propagation, SceneGraph, Similarity};
use sct_format::write::{write_scene_file, Scene, WriteOptions};
use sct_format::{Node, SceneTree};

use crate::error::{Error, Result};
use crate::reference::WorldMesh;
use crate::shade::linear_to_srgb8;

/// Leaves sampled from a mesh: one per sub-triangle of side at most `spacing`.
pub fn sample_mesh(mesh: &WorldMesh, spacing: f32) -> Vec<Node> {
    let mut out = Vec::new();
    let spacing = spacing.max(1e-12);
    for t in &mesh.tris {
        let d = |a: [f32; 3], b: [f32; 3]| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
        let longest = d(t.p[0], t.p[1]).max(d(t.p[1], t.p[2])).max(d(t.p[2], t.p[0]));
        let n = ((longest / spacing).ceil() as usize).clamp(1, 4096);
        let inv = 1.0 / n as f32;
        let pos = |b: [f32; 3]| -> [f32; 3] { std::array::from_fn(|k| b[0] * t.p[0][k] + b[1] * t.p[1][k] + b[2] * t.p[2][k]) };
        let full_area = {
            let e1: [f32; 3] = std::array::from_fn(|k| t.p[1][k] - t.p[0][k]);
            let e2: [f32; 3] = std::array::from_fn(|k| t.p[2][k] - t.p[0][k]);
            let c = [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]];
            0.5 * (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt()
        };
        let sub_area = full_area * inv * inv;
        let mut emit = |corners: [[f32; 3]; 3]| {
            let bc: [f32; 3] = std::array::from_fn(|k| (corners[0][k] + corners[1][k] + corners[2][k]) / 3.0);
            let c = mesh.color_at(t, bc);
            if c[3] <= 0.0 {
                return;
            }
            let center = pos(bc);
            let radius = corners.iter().map(|&b| d(pos(b), center)).fold(0.0f32, f32::max).max(1e-9);
            out.push(Node {
                center,
                radius,
                normal: WorldMesh::normal_at(t, bc),
                cone: 0.0,
                area: sub_area,
                color: [linear_to_srgb8(c[0]), linear_to_srgb8(c[1]), linear_to_srgb8(c[2]), (c[3] * 255.0 + 0.5).clamp(1.0, 255.0) as u8],
            });
        };
        for i in 0..n {
            for j in 0..n - i {
                let b = |i: usize, j: usize| [1.0 - (i + j) as f32 * inv, i as f32 * inv, j as f32 * inv];
                emit([b(i, j), b(i + 1, j), b(i, j + 1)]);
                if i + j + 2 <= n {
                    emit([b(i + 1, j), b(i + 1, j + 1), b(i, j + 1)]);
                }
            }
        }
    }
    out
}

/// Builds a full binary scene tree over `leaves` (median splits on the largest extent),
/// stored breadth first.
pub fn build_tree(leaves: Vec<Node>) -> Result<SceneTree> {
    build_tree_of_objects(vec![leaves])
}

/// Builds one tree over several objects' leaves: each object gets a subtree of its own
/// (median splits on the largest extent), and only the top levels join the objects' roots
/// (median splits of the objects by their roots' centres). Median splits over all leaves
/// at once would cut through objects of unequal leaf counts and leave nodes holding pieces
/// of two distant objects down to two-leaf nodes: loose spheres, and leaves that decode
/// wide, since the codec quantizes a child relative to its decoded parent. Empty objects
/// are skipped. Stored breadth first.
pub fn build_tree_of_objects(objects: Vec<Vec<Node>>) -> Result<SceneTree> {
    let mut objects: Vec<Vec<Node>> = objects.into_iter().filter(|o| !o.is_empty()).collect();
    if objects.is_empty() {
        return SceneTree::from_bfs(Vec::new(), Vec::new()).map_err(|e| Error::Invalid(e.to_string()));
    }
    // Arena: (node, children).
    let mut arena: Vec<(Node, Option<[u32; 2]>)> = Vec::with_capacity(2 * objects.iter().map(Vec::len).sum::<usize>());
    let mut roots: Vec<u32> = objects.iter_mut().map(|o| median_split(o, &mut arena)).collect();
    let root = join_roots(&mut roots, &mut arena);
    let mut nodes = Vec::with_capacity(arena.len());
    let mut internal = Vec::with_capacity(arena.len());
    let mut level = vec![root];
    while !level.is_empty() {
        let mut next = Vec::new();
        for &i in &level {
            let (n, ch) = arena[i as usize];
            nodes.push(n);
            internal.push(ch.is_some());
            if let Some([a, b]) = ch {
                next.push(a);
                next.push(b);
            }
        }
        level = next;
    }
    SceneTree::from_bfs(nodes, internal).map_err(|e| Error::Invalid(e.to_string()))
}

/// The axis of largest extent of some centres.
fn widest_axis<'a>(centres: impl Iterator<Item = &'a [f32; 3]>) -> usize {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for c in centres {
        for k in 0..3 {
            lo[k] = lo[k].min(c[k]);
            hi[k] = hi[k].max(c[k]);
        }
    }
    (0..3).max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b]))).unwrap_or(0)
}

/// The subtree of one object's leaves (non-empty) in `arena`; returns its root.
fn median_split(leaves: &mut [Node], arena: &mut Vec<(Node, Option<[u32; 2]>)>) -> u32 {
    if leaves.len() == 1 {
        arena.push((leaves[0], None));
        return (arena.len() - 1) as u32;
    }
    let axis = widest_axis(leaves.iter().map(|l| &l.center));
    let mid = leaves.len() / 2;
    leaves.select_nth_unstable_by(mid, |a, b| a.center[axis].total_cmp(&b.center[axis]));
    let (l, r) = leaves.split_at_mut(mid);
    let a = median_split(l, arena);
    let b = median_split(r, arena);
    let node = sct_format::geometry::parent_of(&arena[a as usize].0, &arena[b as usize].0);
    arena.push((node, Some([a, b])));
    (arena.len() - 1) as u32
}

/// Joins subtree roots of `arena` (non-empty) by median splits of their centres; returns
/// the root over them all.
fn join_roots(roots: &mut [u32], arena: &mut Vec<(Node, Option<[u32; 2]>)>) -> u32 {
    if roots.len() == 1 {
        return roots[0];
    }
    let axis = widest_axis(roots.iter().map(|&r| &arena[r as usize].0.center));
    let mid = roots.len() / 2;
    roots.select_nth_unstable_by(mid, |&a, &b| arena[a as usize].0.center[axis].total_cmp(&arena[b as usize].0.center[axis]).then(a.cmp(&b)));
    let (l, r) = roots.split_at_mut(mid);
    let a = join_roots(l, arena);
    let b = join_roots(r, arena);
    let node = sct_format::geometry::parent_of(&arena[a as usize].0, &arena[b as usize].0);
    arena.push((node, Some([a, b])));
    (arena.len() - 1) as u32
}

fn generator(what: &str) -> Generator {
    Generator {
        tool: "render-preview-synth".into(),
        version: env!("CARGO_PKG_VERSION").into(),
        parameters: serde_json::json!({ "scene": what }),
        sources: Vec::new(),
    }
}

/// Samples `mesh` at `spacing` and writes a one-tree SCT file; returns the leaf count.
pub fn write_mesh_sct(mesh: &WorldMesh, spacing: f32, path: &Path, opts: &WriteOptions) -> Result<usize> {
    let leaves = sample_mesh(mesh, spacing);
    let n = leaves.len();
    let tree = build_tree(leaves)?;
    let scene = Scene::single_tree(generator("mesh"), tree);
    write_scene_file(path, &scene, opts).map_err(|e| Error::sct(path, e))?;
    Ok(n)
}

/// A scene of `nx × nz` instances of `tree` on a grid with spacing `step` (in the XZ
/// plane), bounded by a group tree; instance `i` gets `tints(i)` as push-down tint.
pub fn instance_grid(tree: SceneTree, nx: usize, nz: usize, step: f64, tints: impl Fn(usize) -> Option<[u8; 4]>) -> Result<Scene> {
    let root = *tree.nodes().first().ok_or_else(|| Error::Invalid("empty tree".into()))?;
    let mut nodes = vec![GraphNode::Tree { tree: 0 }];
    let mut bounds = Vec::with_capacity(nx * nz);
    for iz in 0..nz {
        for ix in 0..nx {
            let i = iz * nx + ix;
            let transform = Similarity {
                translation: [(ix as f64 - (nx as f64 - 1.0) / 2.0) * step, 0.0, (iz as f64 - (nz as f64 - 1.0) / 2.0) * step],
                ..Similarity::IDENTITY
            };
            let tint = tints(i);
            let color = if tint.is_some() { Propagation::PushDown } else { Propagation::PullUp };
            let attrs = InstanceAttrs { tint, color, ..Default::default() };
            bounds.push(transform.apply_node(&root));
            nodes.push(GraphNode::Instance { child: 0, transform, attrs });
        }
    }
    // Group tree over the instance bounds: its leaf j must bound child j, so build it
    // with the leaves in instance order by tagging each with its index.
    let group = build_indexed_group(&bounds)?;
    let (gtree, order) = group;
    let children = order.iter().map(|&k| k as u32 + 1).collect();
    nodes.push(GraphNode::Group { children, tree: 1 });
    let root_idx = (nodes.len() - 1) as u32;
    Ok(Scene { generator: generator("instance grid"), graph: SceneGraph { nodes, root: root_idx }, trees: vec![tree, gtree] })
}

/// A group tree over `bounds` (the world bounds of a group's children) and, for each of
/// its leaves in breadth-first order, the index of the bound it holds: leaf `j` bounds
/// child `order[j]`.
pub fn build_indexed_group(bounds: &[Node]) -> Result<(SceneTree, Vec<usize>)> {
    // Encode the index in a side table keyed by position in the arena: build with the same
    // median-split scheme, tracking indices alongside.
    let mut items: Vec<(Node, usize)> = bounds.iter().copied().zip(0..).collect();
    let mut arena: Vec<(Node, Option<[u32; 2]>, usize)> = Vec::with_capacity(2 * items.len());
    fn rec(items: &mut [(Node, usize)], arena: &mut Vec<(Node, Option<[u32; 2]>, usize)>) -> u32 {
        if items.len() == 1 {
            arena.push((items[0].0, None, items[0].1));
            return (arena.len() - 1) as u32;
        }
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for l in items.iter() {
            for k in 0..3 {
                lo[k] = lo[k].min(l.0.center[k]);
                hi[k] = hi[k].max(l.0.center[k]);
            }
        }
        let axis = (0..3).max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b]))).unwrap_or(0);
        let mid = items.len() / 2;
        items.select_nth_unstable_by(mid, |a, b| a.0.center[axis].total_cmp(&b.0.center[axis]).then(a.1.cmp(&b.1)));
        let (l, r) = items.split_at_mut(mid);
        let a = rec(l, arena);
        let b = rec(r, arena);
        let node = sct_format::geometry::parent_of(&arena[a as usize].0, &arena[b as usize].0);
        arena.push((node, Some([a, b]), usize::MAX));
        (arena.len() - 1) as u32
    }
    if items.is_empty() {
        return Err(Error::Invalid("no instances".into()));
    }
    let root = rec(&mut items, &mut arena);
    let (mut nodes, mut internal, mut order) = (Vec::new(), Vec::new(), Vec::new());
    let mut level = vec![root];
    while !level.is_empty() {
        let mut next = Vec::new();
        for &i in &level {
            let (n, ch, idx) = arena[i as usize];
            nodes.push(n);
            internal.push(ch.is_some());
            match ch {
                Some([a, b]) => {
                    next.push(a);
                    next.push(b);
                }
                None => order.push(idx),
            }
        }
        level = next;
    }
    Ok((SceneTree::from_bfs(nodes, internal).map_err(|e| Error::Invalid(e.to_string()))?, order))
}

/// A UV sphere mesh (for tests that need no model file).
pub fn uv_sphere(center: [f32; 3], radius: f32, seg: usize, color: [f32; 4]) -> WorldMesh {
    use voxelize::mesh::{Instance, LoadedScene, Material, Mesh, Primitive, IDENTITY};
    let seg = seg.max(3);
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    // Poles and the seam use exact values so that coincident vertices are bit-identical
    // and the mesh is a closed surface (see `voxelize::sides::closed_and_oriented`).
    for i in 0..=seg {
        let th = std::f32::consts::PI * i as f32 / seg as f32;
        let (st, ct) = if i == 0 { (0.0, 1.0) } else if i == seg { (0.0, -1.0) } else { th.sin_cos() };
        for j in 0..=2 * seg {
            let ph = std::f32::consts::PI * j as f32 / seg as f32;
            let (sp, cp) = if j == 0 || j == 2 * seg { (0.0, 1.0) } else { ph.sin_cos() };
            let n = [st * cp, ct, -st * sp];
            normals.push(n);
            positions.push([center[0] + radius * n[0], center[1] + radius * n[1], center[2] + radius * n[2]]);
        }
    }
    let row = 2 * seg + 1;
    let mut triangles = Vec::new();
    for i in 0..seg {
        for j in 0..2 * seg {
            let a = (i * row + j) as u32;
            let b = a + 1;
            let c = a + row as u32;
            let d = c + 1;
            // Counter-clockwise seen from outside; skip the degenerate pole triangles.
            if i != 0 {
                triangles.push([a, c, b]);
            }
            if i != seg - 1 {
                triangles.push([b, c, d]);
            }
        }
    }
    let prim = Primitive { positions, normals: Some(normals), triangles, material: Some(0), ..Default::default() };
    let material = Material { base_color: color, ..Default::default() };
    let scene = LoadedScene {
        meshes: vec![Mesh { name: "sphere".into(), primitives: vec![prim] }],
        instances: vec![Instance { mesh: 0, transform: IDENTITY }],
        materials: vec![material],
        ..Default::default()
    };
    WorldMesh::from_scene(scene)
}

/// A mesh of flat quads, each given by four corners counter-clockwise seen from its front
/// and a linear RGBA colour (for failure-mode scenes: plates, layers, leaves).
pub fn quads(quads: &[([[f32; 3]; 4], [f32; 4])]) -> WorldMesh {
    use voxelize::mesh::{Instance, LoadedScene, Material, Mesh, Primitive, IDENTITY};
    let mut meshes = Vec::new();
    let mut materials = Vec::new();
    let mut instances = Vec::new();
    for (i, (p, color)) in quads.iter().enumerate() {
        let prim = Primitive { positions: p.to_vec(), triangles: vec![[0, 1, 2], [0, 2, 3]], material: Some(i), ..Default::default() };
        meshes.push(Mesh { name: format!("quad{i}"), primitives: vec![prim] });
        materials.push(Material { base_color: *color, ..Default::default() });
        instances.push(Instance { mesh: i, transform: IDENTITY });
    }
    WorldMesh::from_scene(LoadedScene { meshes, instances, materials, ..Default::default() })
}
