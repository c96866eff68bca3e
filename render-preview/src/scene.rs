//! Opening SCT files and walking their scene graphs (groups, instances with transform and
//! tint, inlines), refining every tree reached with [`crate::lod`].

use std::collections::{HashMap, VecDeque};
use std::path::{Path, PathBuf};

use sct_format::{GraphNode, Limits, Node, Propagation, SctReader, Similarity};

use crate::camera::View;
use crate::error::{Error, Result};
use crate::lod::{self, Decision, LodParams, LodStats, Placement, TreeCache, TreeOut};
use crate::raster::Splat;

/// One open file with its block caches.
pub(crate) struct OpenFile {
    pub path: PathBuf,
    pub reader: SctReader,
    trees: Vec<TreeCache>,
}

/// Every file a render touched (the main file first, then inlines as they are reached).
pub struct SceneFiles {
    files: Vec<OpenFile>,
    by_path: HashMap<PathBuf, usize>,
    limits: Limits,
}

impl std::fmt::Debug for SceneFiles {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SceneFiles").field("files", &self.files.iter().map(|f| &f.path).collect::<Vec<_>>()).finish()
    }
}

/// A world-space transform plus the tint accumulated from instances above.
#[derive(Clone, Copy, Debug)]
struct Ctx {
    sim: Similarity,
    tint: Option<[u8; 4]>,
}

struct Visit {
    file: usize,
    node: u32,
    ctx: Ctx,
    depth: u32,
}

fn compose_tint(a: Option<[u8; 4]>, b: Option<[u8; 4]>) -> Option<[u8; 4]> {
    match (a, b) {
        (Some(a), Some(b)) => Some(crate::shade::tint(a, b)),
        (x, None) | (None, x) => x,
    }
}

impl SceneFiles {
    /// Opens `path` (parsing only its index).
    pub fn open(path: &Path, limits: &Limits) -> Result<SceneFiles> {
        let mut s = SceneFiles { files: Vec::new(), by_path: HashMap::new(), limits: limits.clone() };
        s.open_file(path)?;
        Ok(s)
    }

    fn open_file(&mut self, path: &Path) -> Result<usize> {
        let key = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf());
        if let Some(&i) = self.by_path.get(&key) {
            return Ok(i);
        }
        let reader = SctReader::open(path, &self.limits).map_err(|e| Error::sct(path, e))?;
        let trees = (0..reader.trees().len()).map(|t| TreeCache::new(&reader, t)).collect();
        self.files.push(OpenFile { path: path.to_path_buf(), reader, trees });
        self.by_path.insert(key, self.files.len() - 1);
        Ok(self.files.len() - 1)
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

    fn bound(&self, file: usize, node: u32, depth: u32) -> Option<Node> {
        let f = &self.files[file];
        match f.reader.graph().nodes.get(node as usize)? {
            GraphNode::Tree { tree } | GraphNode::Group { tree, .. } => {
                let root = f.trees.get(*tree as usize)?.root()?;
                // Merged spheres grow level by level, so the root sphere is loose (often
                // 2-3× the object): bound the spheres a few levels down instead, which
                // costs only the first few (small) blocks.
                Some(tighter_bound(&f.reader, *tree as usize).filter(|t| t.radius < root.radius).map_or(root, |t| Node { center: t.center, radius: t.radius, ..root }))
            }
            GraphNode::Instance { child, transform, .. } => {
                (depth < 1024).then(|| self.bound(file, *child, depth + 1))?.map(|n| transform.apply_node(&n))
            }
            GraphNode::Inline { bound, .. } => Some(*bound),
        }
    }

    /// Refines the whole scene for `view`, returning splats in a deterministic order.
    pub(crate) fn collect(&mut self, view: &View, p: &LodParams) -> Result<(Vec<Splat>, LodStats)> {
        let mut splats = Vec::new();
        let mut stats = LodStats::default();
        let mut queue = VecDeque::new();
        if self.files.is_empty() {
            return Ok((splats, stats));
        }
        let root = self.files[0].reader.graph().root;
        queue.push_back(Visit { file: 0, node: root, ctx: Ctx { sim: Similarity::IDENTITY, tint: None }, depth: 0 });
        while let Some(v) = queue.pop_front() {
            let f = &self.files[v.file];
            let gnode = f.reader.graph().nodes.get(v.node as usize).cloned().ok_or_else(|| {
                Error::Invalid(format!("{}: graph node {} does not exist", f.path.display(), v.node))
            })?;
            match gnode {
                GraphNode::Tree { tree } | GraphNode::Group { tree, .. } => {
                    let group = matches!(gnode, GraphNode::Group { .. });
                    let cache = f.trees.get(tree as usize).ok_or_else(|| {
                        Error::Invalid(format!("{}: graph refers to missing tree {tree}", f.path.display()))
                    })?;
                    let pl = placement(view, &v.ctx);
                    let mut out = TreeOut::default();
                    lod::traverse(&f.reader, cache, &pl, view, p, group, &mut out)?;
                    splats.append(&mut out.splats);
                    stats.add(&out.stats);
                    if let GraphNode::Group { children, .. } = &gnode {
                        for j in out.group_leaves {
                            let child = children.get(j as usize).copied().ok_or_else(|| {
                                Error::Invalid(format!("{}: group leaf {j} has no child", f.path.display()))
                            })?;
                            queue.push_back(Visit { file: v.file, node: child, ctx: v.ctx, depth: v.depth });
                        }
                    }
                }
                GraphNode::Instance { child, transform, attrs } => {
                    // As in sct_format::traverse (§5.11.2): a tint only applies to a
                    // push-down-colour instance; a pull-up instance keeps child colours.
                    let tint = if attrs.color == Propagation::PushDown { attrs.tint } else { None };
                    let ctx = Ctx { sim: v.ctx.sim.compose(&transform), tint: compose_tint(v.ctx.tint, tint) };
                    queue.push_back(Visit { file: v.file, node: child, ctx, depth: v.depth });
                }
                GraphNode::Inline { path, bound, .. } => {
                    // The stored bound lets us cull or draw the inline without opening it.
                    let pl = placement(view, &v.ctx);
                    let mut st = LodStats::default();
                    match lod::decide(&bound, true, true, &pl, view, p, &mut st) {
                        Decision::Cull | Decision::Refine => {}
                        Decision::Draw(s) => splats.push(s),
                        Decision::Descend => {
                            if v.depth >= self.limits.max_inline_depth {
                                return Err(Error::Invalid(format!(
                                    "{}: inlines nested deeper than {} (a cycle?)",
                                    f.path.display(),
                                    self.limits.max_inline_depth
                                )));
                            }
                            let target = f.path.parent().unwrap_or(Path::new(".")).join(&path);
                            let k = self.open_file(&target)?;
                            let root = self.files[k].reader.graph().root;
                            queue.push_back(Visit { file: k, node: root, ctx: v.ctx, depth: v.depth + 1 });
                            continue;
                        }
                    }
                    stats.add(&st);
                }
            }
        }
        Ok((splats, stats))
    }
}

/// A sphere around the cut at level 9 (and the leaves above it), centred on the cut's
/// bounding box, or `None` when that cannot be read.
fn tighter_bound(reader: &SctReader, tree: usize) -> Option<Node> {
    const LEVELS: usize = 10;
    let t = reader.read_tree_levels(tree, LEVELS).ok()?;
    let last = t.level_count().checked_sub(1)?;
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for (i, n) in t.nodes().iter().enumerate() {
        if t.is_internal(i) && i < t.level(last).start {
            continue;
        }
        for k in 0..3 {
            lo[k] = lo[k].min(n.center[k] - n.radius);
            hi[k] = hi[k].max(n.center[k] + n.radius);
        }
    }
    let center: [f32; 3] = std::array::from_fn(|k| (lo[k] + hi[k]) / 2.0);
    let mut radius = 0f32;
    for (i, n) in t.nodes().iter().enumerate() {
        if t.is_internal(i) && i < t.level(last).start {
            continue;
        }
        let d = (0..3).map(|k| (n.center[k] - center[k]).powi(2)).sum::<f32>().sqrt();
        radius = radius.max(d + n.radius);
    }
    (radius.is_finite() && radius > 0.0).then_some(Node { center, radius, ..Node::default() })
}

/// Camera-space placement of a world-space similarity.
fn placement(view: &View, ctx: &Ctx) -> Placement {
    let sim = &ctx.sim;
    let cols = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]].map(|e| view.dir_to_camera(sim.rotate(e)));
    let mut rot = [[0f32; 3]; 3];
    let mut m = [[0f32; 3]; 3];
    for (j, col) in cols.iter().enumerate() {
        for i in 0..3 {
            rot[i][j] = col[i] as f32;
            m[i][j] = (col[i] * sim.scale) as f32;
        }
    }
    Placement { m, rot, t: view.to_camera(sim.translation), s: sim.scale as f32, tint: ctx.tint }
}
