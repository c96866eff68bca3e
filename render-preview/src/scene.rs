//! Opening SCT files and walking their scene graphs (groups, instances with transform and
//! tint, inlines), refining every tree reached with [`crate::lod`].
//!
//! The graph walk is the renderer's own rather than [`sct_format::traverse::Traversal`]:
//! that iterator reads every group tree whole and names every group leaf by its path, while
//! the renderer refines group trees lazily with the same LOD test as geometry, so a group
//! leaf drawn as a splat never expands its child. Everything else follows the traversal's
//! rules: instance state is [`TraversalState`] (same transform and tint composition), and
//! inlines get the same checks in the same order (target present, no cycle on the branch,
//! depth limit, BLAKE3 hash) with the same [`TraverseErrorKind`] errors.
//!
//! # Affine instances (SCT 1.3)
//!
//! Below an affine instance the world transform is a general affine map, and a leaf splat
//! (centre, normal, radius) would map to an ellipse. Every method takes the same simple,
//! conservative route through its [`Placement`]: the centre is mapped exactly, the normal by
//! the inverse transpose and renormalised, the radius scaled by σ_max (a disc slightly fat
//! along the squashed directions), cones widened by the condition number (so normal-cone
//! back-face culling stays safe) and areas scaled by Nanson's factor of the node's axis. Per
//! method: `zbuffer` and `gauss` decide the LOD cut from those mapped attributes; `gauss`
//! draws its Gaussian kernels from them (the equal-area shrink uses the mapped area over the
//! mapped radius), `zbuffer` draws a flat patch as the matrix's image of its disc (an
//! ellipse: discs of the mapped area stuck out over the edges of stretched boxes);
//! `canopy` builds its image graph from the mapped spheres and its
//! occlusion strength from the mapped area and widened cone; `parilov` sorts a cell's samples
//! along the mapped normal of a tree axis (planes of constant tree coordinate stay planes),
//! sizes cells by the widest stretch of the matrix in a patch's plane and draws the matrix's
//! image of each disc; `wald` collects mapped surfels (support capped by the
//! mapped patch radius); `wand` places its random points on each leaf's disc in the tree's
//! frame and maps them exactly (the disc becomes the true ellipse), drawing them with
//! probability ∝ mapped area.

pub(crate) mod items;

pub(crate) use items::Item;

use std::collections::{HashMap, VecDeque};
use std::path::{Path, PathBuf};
use std::rc::Rc;

use sct_format::traverse::{hex, resolve_inline, scene_root, TraversalState, TraverseErrorKind, VisitBudget};
use sct_format::{AffineMap, GraphNode, Limits, Node, SctReader, Transform};

use crate::camera::View;
use crate::error::{Error, Result};
use crate::lod::{self, Decision, LodParams, LodStats, Placement, TreeCache, TreeOut};
use crate::raster::Splat;

/// One open file with its block caches.
pub(crate) struct OpenFile {
    pub path: PathBuf,
    pub reader: SctReader,
    trees: Vec<TreeCache>,
    /// BLAKE3 of the file, computed the first time an inline needs it.
    hash: Option<[u8; 32]>,
}

/// Every file a render touched (the main file first, then inlines as they are reached).
pub struct SceneFiles {
    files: Vec<OpenFile>,
    /// Canonical path → index in `files`.
    by_path: HashMap<PathBuf, usize>,
    limits: Limits,
    /// Check inline targets' BLAKE3 hashes (on by default).
    verify_inline_hashes: bool,
    /// The directory inline targets must stay in, unless `allow_outside_inlines`.
    root: PathBuf,
    allow_outside_inlines: bool,
    /// The `parilov` method's kept cell orders, reused by the next frame rendered from these
    /// files.
    pub(crate) parilov_orders: crate::parilov::Orders,
}

impl std::fmt::Debug for SceneFiles {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SceneFiles").field("files", &self.files.iter().map(|f| &f.path).collect::<Vec<_>>()).finish()
    }
}

/// The files inlined on the way to a graph node (a persistent stack shared by siblings),
/// for cycle detection.
struct Chain {
    file: usize,
    parent: Option<Rc<Chain>>,
    depth: u32,
}

impl Chain {
    fn contains(&self, file: usize) -> bool {
        let mut c = Some(self);
        while let Some(x) = c {
            if x.file == file {
                return true;
            }
            c = x.parent.as_deref();
        }
        false
    }
}

struct Visit {
    chain: Rc<Chain>,
    node: u32,
    state: TraversalState,
}

impl SceneFiles {
    /// Opens `path` (parsing only its index).
    pub fn open(path: &Path, limits: &Limits) -> Result<SceneFiles> {
        let canon = std::fs::canonicalize(path).map_err(|e| Error::sct(path, sct_format::Error::io(path, e)))?;
        let root = scene_root(&canon);
        let mut s = SceneFiles { files: Vec::new(), by_path: HashMap::new(), limits: limits.clone(), verify_inline_hashes: true, root, allow_outside_inlines: false, parilov_orders: Default::default() };
        let reader = SctReader::open(&canon, limits).map_err(|e| Error::sct(path, e))?;
        s.add_file(canon, reader);
        Ok(s)
    }

    /// The path of the main file (as opened).
    pub(crate) fn main_path(&self) -> PathBuf {
        self.files.first().map(|f| f.path.clone()).unwrap_or_default()
    }

    /// Turns the BLAKE3 check of inline targets off (it reads each target file whole once).
    pub fn set_verify_inline_hashes(&mut self, on: bool) {
        self.verify_inline_hashes = on;
    }

    /// Follows inlines whose target lies outside the scene file's directory (off by default).
    pub fn set_allow_outside_inlines(&mut self, on: bool) {
        self.allow_outside_inlines = on;
    }

    fn add_file(&mut self, canon: PathBuf, reader: SctReader) -> usize {
        let trees = (0..reader.trees().len()).map(|t| TreeCache::new(&reader, t)).collect();
        self.files.push(OpenFile { path: canon.clone(), reader, trees, hash: None });
        self.by_path.insert(canon, self.files.len() - 1);
        self.files.len() - 1
    }

    /// Resolves inline `rel` (with recorded `hash`) of the file at the head of `chain`, with
    /// the checks of `sct_format::traverse` in the same order: target present, not already
    /// on the branch, depth limit, hash.
    fn follow_inline(&mut self, chain: &Chain, rel: &str, hash: &[u8; 32]) -> std::result::Result<usize, TraverseErrorKind> {
        let root = (!self.allow_outside_inlines).then_some(self.root.as_path());
        let canon = resolve_inline(&self.files[chain.file].path, rel, root)?;
        let known = self.by_path.get(&canon).copied();
        if known.is_some_and(|k| chain.contains(k)) {
            let mut files = Vec::new();
            let mut c = Some(chain);
            while let Some(x) = c {
                files.push(self.files[x.file].path.clone());
                c = x.parent.as_deref();
            }
            files.reverse();
            files.push(canon);
            return Err(TraverseErrorKind::InlineCycle { chain: files });
        }
        if chain.depth + 1 > self.limits.max_inline_depth {
            return Err(TraverseErrorKind::InlineDepth { limit: self.limits.max_inline_depth });
        }
        let k = match known {
            Some(k) => k,
            None => {
                let reader = SctReader::open(&canon, &self.limits).map_err(|e| match e {
                    sct_format::Error::Io { source, .. } => TraverseErrorKind::InlineMissing { target: canon.clone(), source },
                    e => TraverseErrorKind::Read(e),
                })?;
                self.add_file(canon.clone(), reader)
            }
        };
        if self.verify_inline_hashes {
            let f = &mut self.files[k];
            let found = match f.hash {
                Some(h) => h,
                None => *f.hash.insert(f.reader.content_hash().map_err(TraverseErrorKind::Read)?),
            };
            if &found != hash {
                return Err(TraverseErrorKind::InlineHash { target: canon, expected: hex(hash), found: hex(&found) });
            }
        }
        Ok(k)
    }

    /// Bytes read so far over all files.
    pub fn bytes_read(&self) -> u64 {
        self.files.iter().map(|f| f.reader.bytes_read()).sum()
    }

    /// Total size of the files opened.
    pub fn file_len(&self) -> u64 {
        self.files.iter().map(|f| f.reader.file_len()).sum()
    }

    /// Number of files opened.
    pub fn file_count(&self) -> usize {
        self.files.len()
    }

    /// World-space bounding sphere of the main file's root graph node (`None` for an empty
    /// scene).
    pub fn root_bound(&self) -> Option<Node> {
        let f = self.files.first()?;
        self.bound(0, f.reader.graph().root, 0)
    }

    /// The main file's provenance (GENR parameters) as far as previews use it.
    pub fn provenance(&self) -> crate::provenance::Provenance {
        self.files.first().map(|f| crate::provenance::Provenance::from_generator(f.reader.generator())).unwrap_or_default()
    }

    /// World-space spheres (centre, radius) whose extent is the scene's, for framing the
    /// default camera: every tree the main file's graph reaches (through instances and
    /// groups) contributes the nodes of a shallow level cut, placed by its instances'
    /// transforms; an inline contributes its stored bound (it is not opened). The cut is
    /// the first level with at least [`FRAMING_CUT_NODES`] nodes (the leaves above it
    /// included), made coarser when many instances share the budget, so that the spheres
    /// hug the surface to within a few percent of the model's size.
    pub fn framing_spheres(&self) -> Vec<([f64; 3], f64)> {
        let Some(f) = self.files.first() else {
            return Vec::new();
        };
        let mut uses = Vec::new();
        let mut visits = 0usize;
        collect_uses(&f.reader, f.reader.graph().root, TraversalState::IDENTITY, 0, &mut visits, &mut uses);
        let trees = uses.iter().filter(|u| matches!(u.what, Use::Tree(_))).count().max(1);
        let per_tree = (FRAMING_BUDGET / trees).clamp(8, FRAMING_CUT_NODES);
        let mut cuts: HashMap<usize, Vec<Node>> = HashMap::new();
        let mut out = Vec::new();
        for u in &uses {
            let nodes: &[Node] = match &u.what {
                Use::Tree(t) => cuts.entry(*t).or_insert_with(|| shallow_cut(&f.reader, *t, per_tree).unwrap_or_default()),
                Use::Bound(n) => std::slice::from_ref(n),
            };
            for n in nodes {
                let w = u.state.apply(n);
                out.push((w.center.map(f64::from), w.radius as f64));
            }
        }
        out
    }

    fn bound(&self, file: usize, node: u32, depth: u32) -> Option<Node> {
        let f = &self.files[file];
        match f.reader.graph().nodes.get(node as usize)? {
            GraphNode::Tree { tree } | GraphNode::Group { tree, .. } => {
                let root = f.trees.get(*tree as usize)?.root()?;
                // Merged spheres grow level by level, so the root sphere is loose (often
                // 2-3× the object): bound the spheres a few levels down instead, which
                // costs only the first few (small) blocks.
                Some(tighter_bound(&f.reader, *tree as usize).filter(|t| t.radius < root.radius).map_or(root, |t| Node {
                    center: t.center,
                    radius: t.radius,
                    ..root
                }))
            }
            n @ (GraphNode::Instance { .. } | GraphNode::Affine { .. }) => {
                let (child, transform, _) = n.instance()?;
                (depth < 1024).then(|| self.bound(file, child, depth + 1))?.map(|n| transform.apply_node(&n))
            }
            GraphNode::Inline { bound, .. } => Some(*bound),
        }
    }

    /// Refines the whole scene for `view`, returning splats in a deterministic order.
    pub(crate) fn collect(&mut self, view: &View, p: &LodParams) -> Result<(Vec<Splat>, LodStats)> {
        let (splats, _, stats) = self.walk(view, p)?;
        Ok((splats, stats))
    }

    /// Every leaf of the scene in the view, as camera-space surfels with their instance's
    /// placement and tint applied, in a deterministic order (`p.leaves` must be set: the
    /// `wald` method). Bounded by `p.max_nodes` like any refinement.
    pub(crate) fn collect_surfels(&mut self, view: &View, p: &LodParams) -> Result<(Vec<crate::wald::Surfel>, LodStats)> {
        debug_assert!(p.leaves.is_some());
        let (_, surfels, stats) = self.walk(view, p)?;
        Ok((surfels, stats))
    }

    /// The graph walk behind [`Self::collect`] and [`Self::collect_surfels`].
    fn walk(&mut self, view: &View, p: &LodParams) -> Result<(Vec<Splat>, Vec<crate::wald::Surfel>, LodStats)> {
        let mut splats = Vec::new();
        let mut surfels = Vec::new();
        let mut stats = LodStats::default();
        let mut queue = VecDeque::new();
        if self.files.is_empty() {
            return Ok((splats, surfels, stats));
        }
        let root = self.files[0].reader.graph().root;
        let chain = Rc::new(Chain { file: 0, parent: None, depth: 0 });
        queue.push_back(Visit { chain, node: root, state: TraversalState::IDENTITY });
        // Shared groups make the paths through a small graph exponential in number: every
        // visit counts against the limit sct_format's traversal enforces.
        let mut budget = VisitBudget::new(&self.limits);
        while let Some(v) = queue.pop_front() {
            let fi = v.chain.file;
            budget.charge(1).map_err(|e| Error::sct(&self.files[fi].path, e))?;
            let f = &self.files[fi];
            let gnode = f
                .reader
                .graph()
                .nodes
                .get(v.node as usize)
                .cloned()
                .ok_or_else(|| Error::Invalid(format!("{}: graph node {} does not exist", f.path.display(), v.node)))?;
            match gnode {
                GraphNode::Tree { tree } | GraphNode::Group { tree, .. } => {
                    let group = matches!(gnode, GraphNode::Group { .. });
                    let cache = f
                        .trees
                        .get(tree as usize)
                        .ok_or_else(|| Error::Invalid(format!("{}: graph refers to missing tree {tree}", f.path.display())))?;
                    let pl = placement(view, &v.state);
                    let mut out = TreeOut::default();
                    lod::traverse(&f.reader, cache, &pl, view, p, group, stats.nodes_visited, &mut out)?;
                    splats.append(&mut out.splats);
                    surfels.append(&mut out.surfels);
                    stats.add(&out.stats);
                    if let GraphNode::Group { children, .. } = &gnode {
                        for j in out.group_leaves {
                            let child = children
                                .get(j as usize)
                                .copied()
                                .ok_or_else(|| Error::Invalid(format!("{}: group leaf {j} has no child", f.path.display())))?;
                            queue.push_back(Visit { chain: v.chain.clone(), node: child, state: v.state });
                        }
                    }
                }
                GraphNode::Instance { .. } | GraphNode::Affine { .. } => {
                    let Some((child, transform, attrs)) = gnode.instance() else { continue };
                    let state = v.state.push(&transform, &attrs);
                    queue.push_back(Visit { chain: v.chain, node: child, state });
                }
                GraphNode::Inline { path, bound, hash } => {
                    // The stored bound lets us cull or draw the inline without opening it, but
                    // not by its cone: the inlined file may hold two-sided surfaces, whose
                    // cones bound their normals only up to sign (spec §6.2).
                    let pl = placement(view, &v.state);
                    let mut st = LodStats::default();
                    let by_bound = lod::LodParams { backface: false, ..*p };
                    match lod::decide(&bound, true, true, &pl, view, &by_bound, &mut st) {
                        // Inline bounds are decided as group leaves: never a `Leaf`.
                        Decision::Cull | Decision::Refine | Decision::Leaf(_) => {}
                        Decision::Draw(s) => splats.push(s),
                        Decision::Descend => {
                            let k = self.follow_inline(&v.chain, &path, &hash).map_err(|kind| Error::Inline {
                                file: self.files[fi].path.clone(),
                                graph_node: v.node,
                                kind: Box::new(kind),
                            })?;
                            let root = self.files[k].reader.graph().root;
                            let chain = Rc::new(Chain { file: k, depth: v.chain.depth + 1, parent: Some(v.chain) });
                            queue.push_back(Visit { chain, node: root, state: v.state });
                            continue;
                        }
                    }
                    stats.add(&st);
                }
            }
        }
        // Each splat costs the raster its pixels: a few million splats of a few pixels is a
        // render, as many covering the whole frame would take hours. Counted by bounding
        // box, clipped to the image, before anything is drawn.
        let (w, h) = (i64::from(view.width), i64::from(view.height));
        let pixels = splats.iter().fold(0u64, |sum, s| {
            let [x0, x1, y0, y1] = s.bounds.map(i64::from);
            let cols = (x1.min(w - 1) - x0.max(0) + 1).max(0);
            let rows = (y1.min(h - 1) - y0.max(0) + 1).max(0);
            sum.saturating_add(cols.saturating_mul(rows) as u64)
        });
        // A ray-traced splat costs a ray per pixel its support's projection covers (the
        // `wald` method): the same bound, so that a large radius scale or a close-up fails
        // fast instead of tracing for hours.
        let pixels = surfels.iter().fold(pixels, |sum, sf| sum.saturating_add(crate::wald::support_pixels(sf, view)));
        // The limit is in output pixels; a supersampled view counted subpixels.
        let pixels = pixels / u64::from(view.subpixels).pow(2).max(1);
        if pixels > p.max_splat_pixels {
            let e = sct_format::Error::LimitExceeded { what: lod::PIXELS_COVERED, value: pixels, limit: p.max_splat_pixels };
            return Err(Error::sct(&self.files[0].path, e));
        }
        Ok((splats, surfels, stats))
    }
}

/// The cut at level 9 of a tree (the leaves above it included): its nodes, for bounds
/// that are much tighter than the root sphere.
fn cut_nodes(reader: &SctReader, tree: usize) -> Option<Vec<Node>> {
    cut_at(reader, tree, 9)
}

/// The nodes of level `level` (or the last level) of a tree plus the leaves above it.
fn cut_at(reader: &SctReader, tree: usize, level: usize) -> Option<Vec<Node>> {
    let t = reader.read_tree_levels(tree, level.saturating_add(1)).ok()?;
    let last = t.level_count().checked_sub(1)?;
    let start = t.level(last).start;
    Some(t.nodes().iter().enumerate().filter(|&(i, _)| !(t.is_internal(i) && i < start)).map(|(_, n)| *n).collect())
}

/// Nodes per tree of the framing cut (see [`SceneFiles::framing_spheres`]).
pub const FRAMING_CUT_NODES: usize = 16384;
/// Most framing spheres over all tree uses: instances of many trees get coarser cuts.
const FRAMING_BUDGET: usize = 1 << 16;
/// Most graph nodes visited while collecting framing spheres; a group whose children would
/// exceed it contributes its own tree's cut instead. With `FRAMING_BUDGET` it keeps the
/// spheres to about 2^17 however many instances a scene has.
const FRAMING_VISITS: usize = 1 << 12;

/// The first-level cut of a tree with at least `min_nodes` nodes (the whole tree when it
/// has fewer), read from the index's level counts so only the levels above are decoded.
fn shallow_cut(reader: &SctReader, tree: usize, min_nodes: usize) -> Option<Vec<Node>> {
    let levels = &reader.trees().get(tree)?.levels;
    let level = levels.iter().position(|l| l.node_count as usize >= min_nodes).unwrap_or(levels.len().saturating_sub(1));
    cut_at(reader, tree, level)
}

/// What one use of a graph node contributes to the framing spheres.
enum Use {
    /// A tree's shallow cut.
    Tree(usize),
    /// One sphere (an inline's stored bound).
    Bound(Node),
}

struct FramingUse {
    what: Use,
    state: TraversalState,
}

/// Walks the graph from `node`, recording the trees and bounds it reaches with their
/// instance state. Groups descend into their children while the visit budget allows.
fn collect_uses(reader: &SctReader, node: u32, state: TraversalState, depth: u32, visits: &mut usize, out: &mut Vec<FramingUse>) {
    *visits += 1;
    if depth > 1024 {
        return;
    }
    match reader.graph().nodes.get(node as usize) {
        Some(GraphNode::Tree { tree }) => out.push(FramingUse { what: Use::Tree(*tree as usize), state }),
        Some(GraphNode::Group { tree, children }) => {
            if *visits + children.len() > FRAMING_VISITS {
                out.push(FramingUse { what: Use::Tree(*tree as usize), state });
            } else {
                for &c in children {
                    collect_uses(reader, c, state, depth + 1, visits, out);
                }
            }
        }
        Some(n @ (GraphNode::Instance { .. } | GraphNode::Affine { .. })) => {
            // Instances do not multiply the walk (groups do, and stop at the budget).
            if let Some((child, transform, attrs)) = n.instance() {
                collect_uses(reader, child, state.push(&transform, &attrs), depth + 1, visits, out);
            }
        }
        Some(GraphNode::Inline { bound, .. }) => out.push(FramingUse { what: Use::Bound(*bound), state }),
        None => {}
    }
}

/// Axis-aligned box around spheres.
fn sphere_box(nodes: &[Node]) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for n in nodes {
        for k in 0..3 {
            lo[k] = lo[k].min(n.center[k] - n.radius);
            hi[k] = hi[k].max(n.center[k] + n.radius);
        }
    }
    (lo, hi)
}

/// A sphere around the cut at level 9 (and the leaves above it), centred on the cut's
/// bounding box, or `None` when that cannot be read.
fn tighter_bound(reader: &SctReader, tree: usize) -> Option<Node> {
    let cut = cut_nodes(reader, tree)?;
    let (lo, hi) = sphere_box(&cut);
    let center: [f32; 3] = std::array::from_fn(|k| (lo[k] + hi[k]) / 2.0);
    let mut radius = 0f32;
    for n in &cut {
        let d = (0..3).map(|k| (n.center[k] - center[k]).powi(2)).sum::<f32>().sqrt();
        radius = radius.max(d + n.radius);
    }
    (radius.is_finite() && radius > 0.0).then_some(Node { center, radius, ..Node::default() })
}

/// Camera-space placement of a world-space transform and tint.
fn placement(view: &View, state: &TraversalState) -> Placement {
    let tint = state.is_tinted().then_some(state.tint);
    let sim = match &state.transform {
        Transform::Similarity(sim) => sim,
        Transform::Affine(a) => return affine_placement(view, a, tint),
    };
    let cols = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]].map(|e| view.dir_to_camera(sim.rotate(e)));
    let mut rot = [[0f32; 3]; 3];
    let mut m = [[0f32; 3]; 3];
    for (j, col) in cols.iter().enumerate() {
        for i in 0..3 {
            rot[i][j] = col[i] as f32;
            m[i][j] = (col[i] * sim.scale) as f32;
        }
    }
    Placement { m, rot, t: view.to_camera(sim.translation), s: sim.scale as f32, tint, affine: false, kappa: 1.0 }
}

/// Camera-space placement of an affine world transform (see [`Placement`]): the linear
/// part and the signed cofactor matrix (normals) in camera axes, σ_max rounded up and the
/// condition number.
fn affine_placement(view: &View, a: &AffineMap, tint: Option<[f32; 4]>) -> Placement {
    let lin = a.affine.linear();
    let sign = a.affine.determinant().signum();
    let mut m = [[0f32; 3]; 3];
    let mut rot = [[0f32; 3]; 3];
    for j in 0..3 {
        let col = view.dir_to_camera([lin[0][j], lin[1][j], lin[2][j]]);
        let ncol = view.dir_to_camera([sign * a.cofactor[0][j], sign * a.cofactor[1][j], sign * a.cofactor[2][j]]);
        for i in 0..3 {
            m[i][j] = col[i] as f32;
            rot[i][j] = ncol[i] as f32;
        }
    }
    let t = view.to_camera([a.affine.matrix[0][3], a.affine.matrix[1][3], a.affine.matrix[2][3]]);
    let s = a.stretch as f32;
    let s = if f64::from(s) < a.stretch { s.next_up() } else { s };
    Placement { m, rot, t, s, tint, affine: true, kappa: a.condition as f32 }
}
