//! Comparison scenes built from mesh files: an SCT file (sampled with [`crate::synth`]) and
//! the matching world-space mesh that serves as the accuracy reference.
//!
//! | spec | scene | view |
//! |---|---|---|
//! | `one:MESH` | the model alone (depth complexity 1) | front |
//! | `pair:FRONT,BACK` | FRONT in front of BACK, scaled to the same size, BACK 2.5 radii behind and 0.6 radii aside (the thesis's Table 14 set-up, Bunny in front of Venus, with models we have) | front |
//! | `grid:MESH:N` | an N × N jittered grid of instances (spacing 1.5 model diameters ÷ 2, jitter ±⅓ spacing; thesis §6.6) | iso |
//! | `block:MESH:N[:S]` | a dense N × N × N block of instances, S model radii apart (default 2: bounding spheres touching), staggered by half a spacing on odd layers (thesis §6.8) | iso |
//!
//! Instances share one tree; the reference repeats the mesh's triangles. Leaves are sampled
//! at 1/`density` of the model's bounding radius (default 200).

use std::path::{Path, PathBuf};

use sct_format::graph::{GraphNode, InstanceAttrs, Propagation, SceneGraph, Similarity};
use sct_format::write::{write_scene_file, Scene, WriteOptions};

use crate::camera::ViewPreset;
use crate::error::{Error, Result};
use crate::reference::WorldMesh;
use crate::synth;

/// What a scene spec asks for.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum SceneSpec {
    /// One model.
    One {
        /// Mesh file.
        mesh: PathBuf,
    },
    /// A model in front of another.
    Pair {
        /// The nearer model.
        front: PathBuf,
        /// The farther model.
        back: PathBuf,
    },
    /// A jittered N × N grid of instances.
    Grid {
        /// Mesh file.
        mesh: PathBuf,
        /// Instances per side.
        n: usize,
    },
    /// A dense N × N × N block of instances.
    Block {
        /// Mesh file.
        mesh: PathBuf,
        /// Instances per side.
        n: usize,
        /// Distance between neighbours, in model radii.
        spacing: f64,
    },
}

impl std::str::FromStr for SceneSpec {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let (kind, rest) = s.split_once(':').ok_or_else(|| format!("expected KIND:ARGS (one:MESH, pair:FRONT,BACK, grid:MESH:N, block:MESH:N), got {s:?}"))?;
        let sized = |rest: &str| -> std::result::Result<(PathBuf, usize), String> {
            let (m, n) = rest.rsplit_once(':').ok_or_else(|| format!("expected {kind}:MESH:N, got {s:?}"))?;
            let n: usize = n.parse().map_err(|e| format!("{kind} size {n:?}: {e}"))?;
            if n == 0 || n > 1000 {
                return Err(format!("{kind} size {n} must be 1..=1000"));
            }
            Ok((PathBuf::from(m), n))
        };
        match kind {
            "one" => Ok(SceneSpec::One { mesh: rest.into() }),
            "pair" => {
                let (a, b) = rest.split_once(',').ok_or_else(|| format!("expected pair:FRONT,BACK, got {s:?}"))?;
                Ok(SceneSpec::Pair { front: a.into(), back: b.into() })
            }
            "grid" => sized(rest).map(|(mesh, n)| SceneSpec::Grid { mesh, n }),
            "block" => {
                // block:MESH:N:S when the last two fields are numbers (a path may hold ':').
                let spaced = rest.rsplit_once(':').and_then(|(head, s)| {
                    let (_, n) = head.rsplit_once(':')?;
                    n.parse::<usize>().ok()?;
                    Some((head, s))
                });
                match spaced {
                    Some((head, sp)) => {
                        let spacing: f64 = sp.parse().map_err(|e| format!("block spacing {sp:?}: {e}"))?;
                        if !(spacing.is_finite() && spacing > 0.0) {
                            return Err(format!("block spacing {spacing} must be a positive number of model radii"));
                        }
                        sized(head).map(|(mesh, n)| SceneSpec::Block { mesh, n, spacing })
                    }
                    None => sized(rest).map(|(mesh, n)| SceneSpec::Block { mesh, n, spacing: 2.0 }),
                }
            }
            _ => Err(format!("unknown scene kind {kind:?} (one, pair, grid, block)")),
        }
    }
}

/// A built scene.
#[derive(Debug)]
pub struct BuiltScene {
    /// Short name (file stems and the kind).
    pub name: String,
    /// The SCT file.
    pub sct: PathBuf,
    /// The reference mesh, world space.
    pub mesh: WorldMesh,
    /// The view preset the scene is seen from.
    pub view: ViewPreset,
    /// Leaves in the tree.
    pub leaves: usize,
    /// Instances of the tree.
    pub instances: usize,
}

fn stem(p: &Path) -> String {
    p.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "model".into())
}

fn load(p: &Path) -> Result<(WorldMesh, [f64; 3], f64)> {
    let m = WorldMesh::load(p)?;
    let (c, r) = m.bound().ok_or_else(|| Error::Invalid(format!("{}: the mesh has no triangles", p.display())))?;
    Ok((m, c, r))
}

/// Moves and scales every triangle: `p' = (p − c)·s + t`.
fn place(m: &mut WorldMesh, c: [f64; 3], s: f64, t: [f64; 3]) {
    for tri in &mut m.tris {
        for p in &mut tri.p {
            *p = std::array::from_fn(|k| ((p[k] as f64 - c[k]) * s + t[k]) as f32);
        }
    }
    for p in &mut m.points {
        p.p = std::array::from_fn(|k| ((p.p[k] as f64 - c[k]) * s + t[k]) as f32);
        p.radius *= s as f32;
    }
}

/// A deterministic value in [−1, 1] from an index.
fn jitter(i: u64) -> f64 {
    let mut h = i.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xD1B5_4A32_D192_ED03;
    h ^= h >> 31;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 29;
    (h >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
}

/// Builds `spec` into `dir` with leaves at 1/`density` of the model's radius.
pub fn build(spec: &SceneSpec, dir: &Path, density: f64) -> Result<BuiltScene> {
    let opts = WriteOptions::default();
    let density = density.max(1.0);
    match spec {
        SceneSpec::One { mesh } => {
            let (m, _, r) = load(mesh)?;
            let name = format!("one-{}", stem(mesh));
            let sct = dir.join(format!("{name}.sct"));
            let leaves = synth::write_mesh_sct(&m, (r / density) as f32, &sct, &opts)?;
            Ok(BuiltScene { name, sct, mesh: m, view: ViewPreset::Front, leaves, instances: 1 })
        }
        SceneSpec::Pair { front, back } => {
            let (mut a, ca, ra) = load(front)?;
            let (mut b, cb, rb) = load(back)?;
            // Both at unit radius: the front one at the origin, the back one behind it.
            place(&mut a, ca, 1.0 / ra, [0.0; 3]);
            place(&mut b, cb, 1.0 / rb, [0.6, 0.0, -2.5]);
            let (la, lb) = (synth::sample_mesh(&a, (1.0 / density) as f32), synth::sample_mesh(&b, (1.0 / density) as f32));
            let leaves = la.len() + lb.len();
            let name = format!("pair-{}-{}", stem(front), stem(back));
            let sct = dir.join(format!("{name}.sct"));
            // Each model in a subtree of its own, joined at the root.
            let tree = synth::build_tree_of_objects(vec![la, lb])?;
            write_scene_file(&sct, &Scene::single_tree(Default::default(), tree), &opts).map_err(|e| Error::sct(&sct, e))?;
            // One mesh: b's triangles keep their own materials after a's.
            let off = a.materials.len() as u32;
            let mut mesh = a;
            mesh.materials.extend(b.materials.iter().cloned());
            mesh.tris.extend(b.tris.into_iter().map(|mut t| {
                t.material += off;
                t
            }));
            if b.materials.iter().any(|m| m.texture.is_some()) {
                return Err(Error::Invalid(format!("{}: a textured back model is not supported in a pair scene", back.display())));
            }
            Ok(BuiltScene { name, sct, mesh, view: ViewPreset::Front, leaves, instances: 1 })
        }
        SceneSpec::Grid { mesh, n } => {
            let (m, c, r) = load(mesh)?;
            let step = 1.5 * r;
            let mut offsets = Vec::with_capacity(n * n);
            for i in 0..*n {
                for j in 0..*n {
                    let k = (i * n + j) as u64;
                    let half = (*n as f64 - 1.0) / 2.0;
                    offsets.push([(j as f64 - half) * step + jitter(2 * k) * step / 3.0, 0.0, (i as f64 - half) * step + jitter(2 * k + 1) * step / 3.0]);
                }
            }
            instanced(&format!("grid{n}-{}", stem(mesh)), m, c, r, density, &offsets, dir, ViewPreset::Iso)
        }
        SceneSpec::Block { mesh, n, spacing } => {
            let (m, c, r) = load(mesh)?;
            let step = spacing * r;
            let half = (*n as f64 - 1.0) / 2.0;
            let mut offsets = Vec::with_capacity(n * n * n);
            for y in 0..*n {
                let stagger = if y % 2 == 1 { step / 2.0 } else { 0.0 };
                for z in 0..*n {
                    for x in 0..*n {
                        offsets.push([(x as f64 - half) * step + stagger, (y as f64 - half) * step, (z as f64 - half) * step + stagger]);
                    }
                }
            }
            // The default spacing keeps the name the benchmarks use.
            let name = if *spacing == 2.0 { format!("block{n}-{}", stem(mesh)) } else { format!("block{n}s{spacing}-{}", stem(mesh)) };
            instanced(&name, m, c, r, density, &offsets, dir, ViewPreset::Iso)
        }
    }
}

/// One tree (the mesh centred at the origin) placed at `offsets`, under a group tree.
#[allow(clippy::too_many_arguments)]
fn instanced(name: &str, mut m: WorldMesh, c: [f64; 3], r: f64, density: f64, offsets: &[[f64; 3]], dir: &Path, view: ViewPreset) -> Result<BuiltScene> {
    place(&mut m, c, 1.0, [0.0; 3]);
    let leaves = synth::sample_mesh(&m, (r / density) as f32);
    let count = leaves.len();
    let tree = synth::build_tree(leaves)?;
    let root = *tree.nodes().first().ok_or_else(|| Error::Invalid(format!("{name}: the mesh has no leaves")))?;
    let mut nodes = vec![GraphNode::Tree { tree: 0 }];
    let mut bounds = Vec::with_capacity(offsets.len());
    for t in offsets {
        let transform = Similarity { translation: *t, ..Similarity::IDENTITY };
        bounds.push(transform.apply_node(&root));
        nodes.push(GraphNode::Instance { child: 0, transform, attrs: InstanceAttrs { color: Propagation::PullUp, ..Default::default() } });
    }
    let (gtree, order) = synth::build_indexed_group(&bounds)?;
    nodes.push(GraphNode::Group { children: order.iter().map(|&k| k as u32 + 1).collect(), tree: 1 });
    let root_idx = (nodes.len() - 1) as u32;
    let scene = Scene { generator: Default::default(), graph: SceneGraph { nodes, root: root_idx }, trees: vec![tree, gtree] };
    let sct = dir.join(format!("{name}.sct"));
    write_scene_file(&sct, &scene, &WriteOptions::default()).map_err(|e| Error::sct(&sct, e))?;
    // The reference repeats the triangles.
    let base = std::mem::take(&mut m.tris);
    m.tris.reserve(base.len() * offsets.len());
    for t in offsets {
        m.tris.extend(base.iter().map(|tri| {
            let mut tri = tri.clone();
            for p in &mut tri.p {
                *p = std::array::from_fn(|k| (p[k] as f64 + t[k]) as f32);
            }
            tri
        }));
    }
    Ok(BuiltScene { name: name.to_string(), sct, mesh: m, view, leaves: count, instances: offsets.len() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_parse() {
        assert_eq!("one:a.obj".parse::<SceneSpec>().unwrap(), SceneSpec::One { mesh: "a.obj".into() });
        assert_eq!("pair:a.ply,b.ply".parse::<SceneSpec>().unwrap(), SceneSpec::Pair { front: "a.ply".into(), back: "b.ply".into() });
        assert_eq!("grid:c:/x.obj:30".parse::<SceneSpec>().unwrap(), SceneSpec::Grid { mesh: "c:/x.obj".into(), n: 30 });
        assert_eq!("block:x.obj:8".parse::<SceneSpec>().unwrap(), SceneSpec::Block { mesh: "x.obj".into(), n: 8, spacing: 2.0 });
        assert_eq!("block:c:/x.obj:8".parse::<SceneSpec>().unwrap(), SceneSpec::Block { mesh: "c:/x.obj".into(), n: 8, spacing: 2.0 });
        assert_eq!("block:c:/x.obj:8:1.25".parse::<SceneSpec>().unwrap(), SceneSpec::Block { mesh: "c:/x.obj".into(), n: 8, spacing: 1.25 });
        for bad in ["x.obj", "grid:x.obj", "grid:x.obj:0", "cube:x.obj", "pair:a.obj", "block:x.obj:8:0", "block:x.obj:8:-1"] {
            assert!(bad.parse::<SceneSpec>().is_err(), "{bad}");
        }
    }

    /// A UV sphere of radius 1 with `seg` segments as OBJ text.
    fn sphere_obj(path: &Path, seg: usize) {
        let mut s = String::new();
        for i in 0..=seg {
            let th = std::f64::consts::PI * i as f64 / seg as f64;
            for j in 0..2 * seg {
                let ph = std::f64::consts::PI * j as f64 / seg as f64;
                s.push_str(&format!("v {} {} {}\n", th.sin() * ph.cos(), th.cos(), -th.sin() * ph.sin()));
            }
        }
        let row = 2 * seg;
        for i in 0..seg {
            for j in 0..row {
                let a = i * row + j + 1;
                let b = i * row + (j + 1) % row + 1;
                let (c, d) = (a + row, b + row);
                if i != 0 {
                    s.push_str(&format!("f {a} {c} {b}\n"));
                }
                if i != seg - 1 {
                    s.push_str(&format!("f {b} {c} {d}\n"));
                }
            }
        }
        std::fs::write(path, s).unwrap();
    }

    /// Internal nodes whose subtree holds leaves of both objects (`second` tells them apart).
    fn mixed_nodes(tree: &sct_format::SceneTree, second: impl Fn(&sct_format::Node) -> bool) -> usize {
        let nodes = tree.nodes();
        let mut mask = vec![0u8; nodes.len()];
        // Breadth first: children come after their parent.
        for i in (0..nodes.len()).rev() {
            mask[i] = match tree.children(i) {
                Some([a, b]) => mask[a] | mask[b],
                None => 1 << u8::from(second(&nodes[i])),
            };
        }
        (0..nodes.len()).filter(|&i| tree.is_internal(i) && mask[i] == 3).count()
    }

    #[test]
    fn pair_keeps_each_model_in_its_own_subtree() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.obj"), dir.path().join("b.obj"));
        // Unequal leaf counts: median splits of the union cut through the larger model.
        sphere_obj(&a, 6);
        sphere_obj(&b, 14);
        let density = 12.0;
        let s = build(&SceneSpec::Pair { front: a.clone(), back: b.clone() }, dir.path(), density).unwrap();
        let tree = sct_format::SctReader::open(&s.sct, &sct_format::Limits::default()).unwrap().read_tree(0).unwrap();
        // Unit radii, the back model 2.5 behind the front one: it lies beyond z = −1.25.
        let back = |n: &sct_format::Node| n.center[2] < -1.25;
        assert_eq!(tree.leaf_count(), s.leaves);
        assert_eq!(mixed_nodes(&tree, back), 1, "only the root holds both models");
        // The same leaves under one median-split tree mix the models below the root.
        let (mut ma, ca, ra) = load(&a).unwrap();
        let (mut mb, cb, rb) = load(&b).unwrap();
        place(&mut ma, ca, 1.0 / ra, [0.0; 3]);
        place(&mut mb, cb, 1.0 / rb, [0.6, 0.0, -2.5]);
        let mut all = synth::sample_mesh(&ma, (1.0 / density) as f32);
        all.extend(synth::sample_mesh(&mb, (1.0 / density) as f32));
        assert_eq!(all.len(), s.leaves);
        let union = synth::build_tree(all).unwrap();
        assert!(mixed_nodes(&union, back) > 1, "the test scene does not mix under plain median splits");
    }

    #[test]
    fn jitter_is_in_range_and_repeatable() {
        for i in 0..1000 {
            let j = jitter(i);
            assert!((-1.0..=1.0).contains(&j));
            assert_eq!(j, jitter(i));
        }
    }
}
