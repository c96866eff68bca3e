//! Scene composition (thesis §5.10, §5.11): one tree per mesh, instances, groups (each with
//! its own tree over its children's transformed bounds, §5.10.5), inlines and the
//! `scene.json` description (schema in `spec/scene-json.md`).

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use serde::Deserialize;
use sct_format::graph::{GraphNode, InstanceAttrs, Propagation, SceneGraph, Similarity};
use sct_format::read::SctReader;
use sct_format::samples::SamplesFile;
use sct_format::traverse::{graph_bound, TraversalState};
use sct_format::{Affine, Limits, Node, SceneTree};

use crate::error::BuildError;
use crate::tree::{build_tree_owned, build_tree_with_map_owned, BuildOptions, BuildStats, Weld};

/// A `scene.json` file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// Named nodes that `{"ref": name}` uses; every use shares one graph node.
    #[serde(default)]
    pub defs: BTreeMap<String, SceneNode>,
    /// The scene's root.
    pub root: SceneNode,
}

/// One node of a `scene.json` description.
#[derive(Clone, Debug, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum SceneNode {
    /// The samples file's own composition: every instance it lists (glTF node placements).
    Source,
    /// A mesh of the samples file, by index or name; its tree is built once and shared.
    Mesh(MeshRef),
    /// A group over its children.
    Group(Vec<SceneNode>),
    /// A transformed, optionally tinted use of a node.
    Instance(Box<InstanceSpec>),
    /// Another SCT file, by a path relative to the output file (not copied).
    Inline(String),
    /// A node of `defs`.
    Ref(String),
    /// A jittered grid of instances of one node (the §6.7 test scene).
    Grid(Box<GridSpec>),
}

/// A mesh by index or name.
#[derive(Clone, Debug, Deserialize)]
#[serde(untagged)]
pub enum MeshRef {
    /// Index into the samples file's mesh table.
    Index(u32),
    /// Mesh name.
    Name(String),
}

/// Attribute handling of an instance, as written in JSON.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum PropagationSpec {
    /// Take the attribute from the child.
    PullUp,
    /// Impose the attribute on the child.
    PushDown,
}

impl From<PropagationSpec> for Propagation {
    fn from(p: PropagationSpec) -> Self {
        match p {
            PropagationSpec::PullUp => Propagation::PullUp,
            PropagationSpec::PushDown => Propagation::PushDown,
        }
    }
}

/// A bounding sphere to fit an instance's child into (push-down size).
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitSpec {
    /// Target centre.
    pub center: [f64; 3],
    /// Target radius (> 0).
    pub radius: f64,
}

/// An instance.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InstanceSpec {
    /// The instanced node.
    pub child: SceneNode,
    /// Translation (not with `fit`).
    pub translation: Option<[f64; 3]>,
    /// Unit quaternion `[x, y, z, w]`.
    pub rotation: Option<[f64; 4]>,
    /// Uniform scale (not with `fit`).
    pub scale: Option<f64>,
    /// Push-down size: scale and translate so the child's bound becomes this sphere.
    pub fit: Option<FitSpec>,
    /// RGBA tint multiplied into every colour below (push-down colour).
    pub tint: Option<[u8; 4]>,
    /// Colour handling; defaults to push-down when a tint is given, else pull-up.
    pub color: Option<PropagationSpec>,
}

/// A jittered `nx × nz` grid on the x–z plane, every cell an instance of `child` fitted
/// into a sphere of `radius`, optionally randomly tinted (push-down).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridSpec {
    /// The instanced node.
    pub child: SceneNode,
    /// Cells along x.
    pub nx: u32,
    /// Cells along z.
    pub nz: u32,
    /// Cell spacing.
    #[serde(default = "one")]
    pub spacing: f64,
    /// Uniform random offset in `[-jitter, jitter]` on x and z.
    #[serde(default)]
    pub jitter: f64,
    /// Radius every instance is fitted to.
    #[serde(default = "half")]
    pub radius: f64,
    /// Random push-down tint per instance.
    #[serde(default)]
    pub random_tint: bool,
    /// Random rotation about y per instance.
    #[serde(default)]
    pub random_rotation: bool,
    /// Seed of the deterministic generator.
    #[serde(default)]
    pub seed: u64,
}

fn one() -> f64 {
    1.0
}
fn half() -> f64 {
    0.5
}

/// A composed scene, ready for [`sct_format::write::write_scene_file`].
#[derive(Debug, Default)]
pub struct Composed {
    /// Graph.
    pub graph: SceneGraph,
    /// Trees referenced by the graph.
    pub trees: Vec<SceneTree>,
    /// Build figures of every mesh tree built (in tree order) and of every group tree.
    pub mesh_stats: Vec<BuildStats>,
    /// Group trees built.
    pub groups: u64,
    /// Instance nodes (similarity and affine).
    pub instances: u64,
    /// Affine instance nodes among them (spec §7).
    pub affine_instances: u64,
    /// Inlined files (path as resolved, BLAKE3 hex).
    pub inlines: Vec<(String, String)>,
    /// Trees built from a point cloud's samples ([`sct_format::samples::MeshEntry::is_point_cloud`]), ascending.
    pub point_cloud_trees: Vec<u32>,
}

/// Builds graph nodes bottom-up, sharing mesh trees and `defs`.
pub struct Composer<'a> {
    /// Mutable so a single-mesh file's samples can be handed to the builder (see `mesh`).
    samples: &'a mut SamplesFile,
    opts: BuildOptions,
    out_dir: PathBuf,
    limits: Limits,
    defs: &'a BTreeMap<String, SceneNode>,
    nodes: Vec<GraphNode>,
    /// Bound of every graph node in its own frame (what a parent group's leaf must be).
    bounds: Vec<Node>,
    /// Whether a graph node holds two-sided surfaces (spec §6.2): a group tree over such a
    /// child is two-sided too, so no group node above it is culled by its cone.
    two_sided: Vec<bool>,

    trees: Vec<SceneTree>,
    mesh_node: HashMap<u32, u32>,
    def_node: HashMap<String, Option<u32>>,
    out: Composed,
    /// Cells of the grids made so far (see [`MAX_GRID_CELLS`]).
    grid_cells: u64,
}

/// Default of [`BuildOptions::max_grid_cells`]: most grid cells (instances) over all grids
/// of one scene, 2^21, about 0.6 GB and a few seconds of composition (the §6.7 scene has
/// 360,000).
pub const MAX_GRID_CELLS: u64 = 1 << 21;

static NO_DEFS: BTreeMap<String, SceneNode> = BTreeMap::new();

impl<'a> Composer<'a> {
    /// A composer over `samples`; inlines are resolved relative to `out_dir`. When the file
    /// has a single mesh spanning all its samples, building that mesh's tree moves the
    /// samples out of `samples` (its `samples` vector is left empty) to save their memory.
    pub fn new(samples: &'a mut SamplesFile, opts: BuildOptions, out_dir: &Path, limits: Limits) -> Self {
        Composer {
            samples,
            opts,
            out_dir: out_dir.to_path_buf(),
            limits,
            defs: &NO_DEFS,
            nodes: Vec::new(),
            bounds: Vec::new(),
            two_sided: Vec::new(),
            trees: Vec::new(),
            mesh_node: HashMap::new(),
            def_node: HashMap::new(),
            out: Composed::default(),
            grid_cells: 0,
        }
    }

    /// Composes the samples file's own instances (no `scene.json`): a single identity
    /// instance gives a one-tree file; otherwise a group over one instance per placement.
    pub fn compose_source(self) -> Result<Composed, BuildError> {
        self.compose(&SceneNode::Source, &NO_DEFS)
    }

    /// Composes a `scene.json` description.
    pub fn compose_file(self, scene: &'a SceneFile) -> Result<Composed, BuildError> {
        self.compose(&scene.root, &scene.defs)
    }

    fn compose(mut self, root: &SceneNode, defs: &'a BTreeMap<String, SceneNode>) -> Result<Composed, BuildError> {
        self.defs = defs;
        let r = self.node(root)?;
        self.out.graph = SceneGraph { nodes: self.nodes, root: r };
        self.out.trees = self.trees;
        Ok(self.out)
    }

    fn push(&mut self, n: GraphNode, bound: Node) -> u32 {
        let two_sided = match &n {
            GraphNode::Tree { tree } | GraphNode::Group { tree, .. } => self.trees.get(*tree as usize).is_some_and(SceneTree::is_two_sided),
            GraphNode::Instance { child, .. } | GraphNode::Affine { child, .. } => self.two_sided.get(*child as usize).copied().unwrap_or(false),
            // Set by `inline`, which has the file open.
            GraphNode::Inline { .. } => false,
        };
        self.two_sided.push(two_sided);
        self.nodes.push(n);
        self.bounds.push(bound);
        (self.nodes.len() - 1) as u32
    }

    fn node(&mut self, n: &SceneNode) -> Result<u32, BuildError> {
        match n {
            SceneNode::Source => self.source(),
            SceneNode::Mesh(m) => {
                let idx = self.mesh_index(m)?;
                self.mesh(idx)
            }
            SceneNode::Group(children) => {
                let mut ids = Vec::with_capacity(children.len());
                for c in children {
                    ids.push(self.node(c)?);
                }
                self.group(ids)
            }
            SceneNode::Instance(spec) => {
                let child = self.node(&spec.child)?;
                let transform = self.instance_transform(spec, child)?;
                let color = spec.color.map(Propagation::from).unwrap_or(if spec.tint.is_some() {
                    Propagation::PushDown
                } else {
                    Propagation::PullUp
                });
                let size = if spec.fit.is_some() { Propagation::PushDown } else { Propagation::PullUp };
                self.instance(child, transform, InstanceAttrs { size, color, tint: spec.tint })
            }
            SceneNode::Inline(path) => self.inline(path),
            SceneNode::Ref(name) => match self.def_node.get(name) {
                Some(Some(id)) => Ok(*id),
                Some(None) => Err(BuildError::Input(format!("scene: \"{name}\" refers to itself"))),
                None => {
                    let def = self
                        .defs
                        .get(name)
                        .ok_or_else(|| BuildError::Input(format!("scene: no def named \"{name}\"")))?;
                    self.def_node.insert(name.clone(), None);
                    let id = self.node(def)?;
                    self.def_node.insert(name.clone(), Some(id));
                    Ok(id)
                }
            },
            SceneNode::Grid(g) => self.grid(g),
        }
    }

    fn source(&mut self) -> Result<u32, BuildError> {
        let insts = &self.samples.instances;
        if insts.is_empty() && self.samples.affine_instances.is_empty() {
            return Err(BuildError::Input("the samples file lists no instances".into()));
        }
        let mut ids = Vec::with_capacity(insts.len());
        for inst in insts.clone() {
            let tree = self.mesh(inst.mesh)?;
            ids.push(if inst.transform == Similarity::IDENTITY {
                tree
            } else {
                self.instance(tree, inst.transform, InstanceAttrs::default())?
            });
        }
        // Non-similarity placements (non-uniform scale, shear, mirror) left unbaked
        // (`bake_affine_instances`): affine instances of the mesh's one tree.
        for a in self.samples.affine_instances.clone() {
            let tree = self.mesh(a.mesh)?;
            ids.push(self.affine(tree, a.affine(), InstanceAttrs::default())?);
        }
        if ids.len() == 1 {
            return Ok(ids[0]);
        }
        self.group(ids)
    }

    fn mesh_index(&self, m: &MeshRef) -> Result<u32, BuildError> {
        let meshes = &self.samples.meshes;
        match m {
            MeshRef::Index(i) if (*i as usize) < meshes.len() => Ok(*i),
            MeshRef::Index(i) => Err(BuildError::Input(format!("scene: mesh {i} out of range ({} meshes)", meshes.len()))),
            MeshRef::Name(name) => meshes
                .iter()
                .position(|e| &e.name == name)
                .map(|i| i as u32)
                .ok_or_else(|| BuildError::Input(format!("scene: no mesh named \"{name}\""))),
        }
    }

    /// The graph node of mesh `m`'s tree, building the tree on first use.
    fn mesh(&mut self, m: u32) -> Result<u32, BuildError> {
        if let Some(&id) = self.mesh_node.get(&m) {
            return Ok(id);
        }
        if m as usize >= self.samples.meshes.len() {
            return Err(BuildError::Input(format!("instance refers to mesh {m}, the file has {}", self.samples.meshes.len())));
        }
        let two_sided = self.samples.meshes[m as usize].two_sided;
        if self.samples.meshes[m as usize].is_point_cloud() {
            self.out.point_cloud_trees.push(self.trees.len() as u32);
        }
        let (mut tree, stats) = build_tree_owned(self.take_mesh_samples(m as usize), &self.opts)
            .map_err(|e| prefix(e, &format!("mesh {m} ({:?})", self.samples.meshes[m as usize].name)))?;
        tree.set_two_sided(two_sided);
        let root = tree.nodes()[0];
        self.trees.push(tree);
        self.out.mesh_stats.push(stats);
        let id = self.push(GraphNode::Tree { tree: (self.trees.len() - 1) as u32 }, root);
        self.mesh_node.insert(m, id);
        Ok(id)
    }

    /// Mesh `m`'s samples for the builder to consume. The file's only mesh (the common
    /// case, and the memory peak of a build) takes the file's vector itself, so the samples
    /// are not held twice while its tree is built; other meshes copy their range, since the
    /// file's vector still serves the rest. Each mesh is built once (`mesh_node`).
    fn take_mesh_samples(&mut self, m: usize) -> Vec<Node> {
        let f = &mut *self.samples;
        let whole = f.meshes.len() == 1 && f.meshes[0].first == 0 && f.meshes[0].count == f.samples.len() as u64;
        if whole {
            std::mem::take(&mut f.samples)
        } else {
            f.mesh_samples(m).to_vec()
        }
    }

    fn instance(&mut self, child: u32, transform: Similarity, attrs: InstanceAttrs) -> Result<u32, BuildError> {
        if !transform.is_valid(1e-6) {
            return Err(BuildError::Input(format!("instance transform is not a similarity: {transform:?}")));
        }
        // Exactly what a traversal computes, so the group leaf above equals the child's bound.
        let bound = TraversalState::IDENTITY.push_instance(&transform, &attrs).apply(&self.bounds[child as usize]);
        if !bound.is_finite() {
            return Err(BuildError::Input(format!("instance transform makes the bound non-finite: {transform:?}")));
        }
        self.out.instances += 1;
        Ok(self.push(GraphNode::Instance { child, transform, attrs }, bound))
    }

    /// An affine instance of `child` (spec §7); its bound is what a traversal computes.
    fn affine(&mut self, child: u32, transform: Affine, attrs: InstanceAttrs) -> Result<u32, BuildError> {
        if let Some(why) = transform.problem() {
            return Err(BuildError::Input(why));
        }
        let bound = TraversalState::IDENTITY.push(&transform.into(), &attrs).apply(&self.bounds[child as usize]);
        if !bound.is_finite() {
            return Err(BuildError::Input(format!("affine instance makes the bound non-finite: {transform}")));
        }
        self.out.instances += 1;
        self.out.affine_instances += 1;
        Ok(self.push(GraphNode::Affine { child, transform, attrs }, bound))
    }

    fn instance_transform(&self, spec: &InstanceSpec, child: u32) -> Result<Similarity, BuildError> {
        let rotation = match spec.rotation {
            Some(q) => normalize_quat(q)?,
            None => [0.0, 0.0, 0.0, 1.0],
        };
        match spec.fit {
            Some(fit) => {
                if spec.translation.is_some() || spec.scale.is_some() {
                    return Err(BuildError::Input("scene: an instance takes either `fit` or `translation`/`scale`".into()));
                }
                fit_transform(&self.bounds[child as usize], rotation, fit.center, fit.radius)
            }
            None => Ok(Similarity {
                translation: spec.translation.unwrap_or([0.0; 3]),
                rotation,
                scale: spec.scale.unwrap_or(1.0),
            }),
        }
    }

    /// A group: its tree is built over the children's bounds, and the children are stored
    /// in the tree's breadth-first leaf order, so leaf `j` bounds `children[j]` (§5.10.5).
    fn group(&mut self, children: Vec<u32>) -> Result<u32, BuildError> {
        if children.is_empty() {
            return Err(BuildError::Input("scene: a group needs at least one child".into()));
        }
        let bounds: Vec<Node> = children.iter().map(|&c| self.bounds[c as usize]).collect();
        // Never weld: every child must keep its own leaf.
        let opts = BuildOptions { weld: Weld::Off, ..self.opts };
        let (mut tree, stats, map) = build_tree_with_map_owned(bounds, &opts)?;
        tree.set_two_sided(children.iter().any(|&c| self.two_sided.get(c as usize).copied().unwrap_or(false)));
        let mut order: Vec<(u32, u32)> = map.iter().zip(&children).map(|(&leaf, &c)| (leaf, c)).collect();
        order.sort_unstable();
        let children: Vec<u32> = order.into_iter().map(|(_, c)| c).collect();
        let root = tree.nodes()[0];
        self.trees.push(tree);
        self.out.mesh_stats.push(stats);
        self.out.groups += 1;
        Ok(self.push(GraphNode::Group { children, tree: (self.trees.len() - 1) as u32 }, root))
    }

    fn inline(&mut self, path: &str) -> Result<u32, BuildError> {
        if path.contains('\\') || Path::new(path).is_absolute() {
            return Err(BuildError::Input(format!("scene: inline path {path:?} must be relative with '/' separators")));
        }
        let full = self.out_dir.join(path);
        let reader = SctReader::open(&full, &self.limits).map_err(|e| prefix(e.into(), &format!("inline {path:?}")))?;
        let bound = graph_bound(&reader, reader.graph().root)
            .ok_or_else(|| BuildError::Input(format!("inline {path:?}: the file's scene has no bound")))?;
        let hash = reader.content_hash().map_err(|e| prefix(e.into(), &format!("inline {path:?}")))?;
        self.out.inlines.push((full.display().to_string(), sct_format::traverse::hex(&hash)));
        let id = self.push(GraphNode::Inline { path: path.to_string(), hash, bound }, bound);
        // Conservative: any two-sided tree in the file makes the inline two-sided.
        self.two_sided[id as usize] = reader.trees().iter().any(|t| t.two_sided());
        Ok(id)
    }

    fn grid(&mut self, g: &GridSpec) -> Result<u32, BuildError> {
        let count = g.nx as u64 * g.nz as u64;
        // Each cell costs about 280 bytes while composing (an instance node, its group-tree
        // leaf and parent, the build's working copies) and 0.2 µs..2 µs: a 70-byte scene of
        // 2^28 cells took 14 GB before it was stopped. Cells over all grids of the scene
        // are bounded, before any is made.
        let total = self.grid_cells.saturating_add(count);
        let max = self.opts.max_grid_cells;
        if count == 0 || total > max {
            return Err(BuildError::Input(format!(
                "scene: grid of {} × {} instances: grids may hold 1 to {max} cells in all ({} before this one; --max-grid-cells)",
                g.nx, g.nz, self.grid_cells
            )));
        }
        self.grid_cells = total;
        if !(g.radius > 0.0 && g.spacing.is_finite() && g.jitter.is_finite()) {
            return Err(BuildError::Input("scene: grid needs radius > 0 and finite spacing and jitter".into()));
        }
        let child = self.node(&g.child)?;
        let mut rng = sct_format::rng::SplitMix64(g.seed);
        let mut ids = Vec::with_capacity(count as usize);
        for i in 0..g.nx {
            for k in 0..g.nz {
                let x = i as f64 * g.spacing + g.jitter * (2.0 * rng.next_f64() - 1.0);
                let z = k as f64 * g.spacing + g.jitter * (2.0 * rng.next_f64() - 1.0);
                let rotation = if g.random_rotation {
                    let half = std::f64::consts::PI * rng.next_f64();
                    [0.0, half.sin(), 0.0, half.cos()]
                } else {
                    [0.0, 0.0, 0.0, 1.0]
                };
                let transform = fit_transform(&self.bounds[child as usize], rotation, [x, 0.0, z], g.radius)?;
                let (tint, color) = if g.random_tint {
                    let v = rng.next_u64();
                    (Some([v as u8, (v >> 8) as u8, (v >> 16) as u8, 255]), Propagation::PushDown)
                } else {
                    (None, Propagation::PullUp)
                };
                ids.push(self.instance(child, transform, InstanceAttrs { size: Propagation::PushDown, color, tint })?);
            }
        }
        self.group(ids)
    }
}

fn prefix(e: BuildError, what: &str) -> BuildError {
    match e {
        BuildError::Input(m) => BuildError::Input(format!("{what}: {m}")),
        BuildError::Format(f) => match f {
            sct_format::Error::Io { .. } => BuildError::Io(format!("{what}: {f}")),
            other => BuildError::Input(format!("{what}: {other}")),
        },
        other => other,
    }
}

fn normalize_quat(q: [f64; 4]) -> Result<[f64; 4], BuildError> {
    let l = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !(l.is_finite() && l > 1e-12) {
        return Err(BuildError::Input(format!("scene: rotation {q:?} is not a quaternion")));
    }
    Ok(q.map(|v| v / l))
}

/// The similarity that maps `bound` onto the sphere (`center`, `radius`) after `rotation`.
fn fit_transform(bound: &Node, rotation: [f64; 4], center: [f64; 3], radius: f64) -> Result<Similarity, BuildError> {
    // `!(x > 0.0)` and not `x <= 0.0`: a NaN radius must be refused too.
    if !(bound.radius > 0.0 && radius > 0.0 && radius.is_finite()) {
        return Err(BuildError::Input(format!("scene: cannot fit a bound of radius {} into radius {radius}", bound.radius)));
    }
    let scale = radius / bound.radius as f64;
    let mut t = Similarity { translation: [0.0; 3], rotation, scale };
    let c = t.apply_point([bound.center[0] as f64, bound.center[1] as f64, bound.center[2] as f64]);
    t.translation = [center[0] - c[0], center[1] - c[1], center[2] - c[2]];
    Ok(t)
}

/// Reads and parses a `scene.json` file.
pub fn read_scene_file(path: &Path) -> Result<SceneFile, BuildError> {
    let text = std::fs::read_to_string(path).map_err(|e| BuildError::Io(format!("reading {}: {e}", path.display())))?;
    serde_json::from_str(&text).map_err(|e| BuildError::Input(format!("{}: {e}", path.display())))
}
