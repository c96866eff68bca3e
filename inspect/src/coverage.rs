//! `--against MESH`: how much of a source mesh's surface the decoded leaf spheres cover.
//!
//! Area-uniform random points on the mesh (every mesh instance applied, fixed seed) are
//! tested against the leaves of every geometry tree reached from the graph root, in world
//! space (instances and inlines through [`sct_format::traverse`]). A point is covered when it
//! lies inside some leaf sphere; for the uncovered ones the distance to the nearest leaf
//! sphere's surface is measured, absolute and in that leaf's radii.
//!
//! Instancing is not expanded: each distinct tree is decoded once into a [`SphereTree`] in its
//! own frame, and each use of it is a transformed reference in a second [`SphereTree`] over
//! the uses' world bounds. A query maps the point into the frames of the uses that can
//! matter, so memory follows the stored leaves, not the instanced ones.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::Serialize;

use sct_format::traverse::{ReachedKind, Traversal, TraverseOptions};
use sct_format::{Limits, Node, SctReader, Similarity, Transform};

use crate::InspectError;

/// Relative slack on leaf radii: centres and radii are stored as f32 (same slack as the
/// voxelizer's own coverage check).
const RADIUS_SLACK: f64 = 1e-6;
/// Items per k-d tree bucket.
const BUCKET: usize = 8;

/// Options of a coverage check.
#[derive(Clone, Debug)]
pub struct AgainstOptions {
    /// Surface points to test.
    pub points: usize,
    /// Seed of the point generator (same seed, same points).
    pub seed: u64,
    /// Coverage fraction below which the check fails.
    pub min_coverage: f64,
    /// Limits for every SCT file opened.
    pub limits: Limits,
    /// Most graph nodes the traversal may reach, a shared node counted once per path to it
    /// (each reached tree is one use). Default [`MAX_USES`].
    pub max_uses: u64,
    /// Follow inlines whose target lies outside the scene file's directory.
    pub allow_outside_inlines: bool,
    /// Draw the test points only where the voxelizer keeps samples: surfaces it drops by
    /// alpha (glTF MASK below the cutoff, fully transparent BLEND, textures' alpha) are
    /// left out, so alpha-masked assets can be held to full coverage.
    pub exclude_alpha_dropped: bool,
    /// Most leaf-tree queries over all points (a point queries each use whose bound may hold
    /// a nearer leaf). Default [`MAX_USE_QUERIES`].
    pub max_use_queries: u64,
}

/// Default [`AgainstOptions::max_use_queries`]: 4 × 10^6, 40 per default point, a few
/// seconds. A point of a real scene queries one to a few uses; uses stacked at one place
/// (65,536 inlines of one file, differing by a hair so they are not one use) would have
/// every point query every use: hours, for a 164 KB file.
pub const MAX_USE_QUERIES: u64 = 4_000_000;

/// What the query limit names in its error.
pub const USE_QUERIES: &str = "leaf-tree queries of the coverage check (--max-use-queries)";

/// Default [`AgainstOptions::max_uses`]. Uses are not deduplicated (each is a placement), so
/// a DAG of shared groups or instances `d` deep reaches `2^d` of them: a file of a few
/// hundred bytes would otherwise hang or exhaust memory. At the limit an 870-byte file of 40
/// nested shared groups stops after 10.6 s at 356 MB peak (half the nodes reached are uses,
/// ~72 bytes each); real scenes' instance counts are far below it.
pub const MAX_USES: u64 = 10_000_000;

/// Default number of surface points.
pub const DEFAULT_POINTS: usize = 100_000;
/// Default seed.
pub const DEFAULT_SEED: u64 = 0x5C7_C0FE;
/// Default threshold: a tree built from the mesh covers it completely, so anything short of
/// 99.9 % (at 10^5 points: more than 100 misses) means missing or misplaced geometry.
pub const DEFAULT_MIN_COVERAGE: f64 = 0.999;

impl Default for AgainstOptions {
    fn default() -> Self {
        AgainstOptions {
            points: DEFAULT_POINTS,
            seed: DEFAULT_SEED,
            min_coverage: DEFAULT_MIN_COVERAGE,
            limits: Limits::default(),
            max_uses: MAX_USES,
            allow_outside_inlines: false,
            max_use_queries: MAX_USE_QUERIES,
            exclude_alpha_dropped: false,
        }
    }
}

/// The uncovered point farthest from every leaf sphere.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Uncovered {
    /// The point (world space).
    pub point: [f64; 3],
    /// Distance from the point to the nearest leaf sphere's surface (world units).
    pub distance: f64,
    /// World radius of that leaf.
    pub leaf_radius: f64,
    /// `distance / leaf_radius`.
    pub leaf_radii: f64,
}

/// The result of a coverage check (the `coverage` member of the JSON report).
#[derive(Clone, Debug, Serialize)]
pub struct CoverageReport {
    /// The mesh as given.
    pub mesh: String,
    /// Points tested.
    pub points: u64,
    /// Seed of the points.
    pub seed: u64,
    /// Points inside some leaf sphere.
    pub covered: u64,
    /// `covered / points` (there is always at least one point).
    pub fraction: f64,
    /// The threshold.
    pub min_coverage: f64,
    /// `fraction >= min_coverage`.
    pub passed: bool,
    /// Distinct geometry trees decoded.
    pub trees: u64,
    /// Leaves stored in those trees.
    pub leaves: u64,
    /// Uses of those trees reached from the root (instances and inlines counted).
    pub tree_uses: u64,
    /// Leaves reached counting every use (saturating).
    pub leaves_expanded: u64,
    /// The worst uncovered point, null when every point is covered.
    pub worst_uncovered: Option<Uncovered>,
    /// Branches the traversal could not follow (missing inline, unreadable tree); their
    /// leaves are not counted.
    pub errors: Vec<String>,
    /// Phase timings; not serialized, so the report's bytes do not depend on the machine.
    #[serde(skip)]
    pub seconds: Seconds,
}

/// Phase timings (not part of the deterministic content; benchmarks read them).
#[derive(Clone, Debug, Default, Serialize)]
pub struct Seconds {
    /// Mesh load and point generation.
    pub mesh: f64,
    /// Traversal, leaf decoding and index building.
    pub index: f64,
    /// Point queries.
    pub query: f64,
}

/// A k-d tree over spheres; each node keeps the bounding box of its items' centres and their
/// largest radius, which gives a lower bound of the signed distance to any item below it.
#[derive(Debug, Default)]
pub struct SphereTree {
    /// Items `[x, y, z, r]` with their original index, reordered so every node's items are
    /// contiguous. f32 like the file's leaves: 20 bytes per leaf.
    items: Vec<([f32; 4], u32)>,
    nodes: Vec<KdNode>,
}

#[derive(Clone, Copy, Debug)]
struct KdNode {
    lo: [f64; 3],
    hi: [f64; 3],
    rmax: f64,
    start: u32,
    end: u32,
    /// Index of the first child (the second follows it); 0 for a bucket.
    left: u32,
}

/// Orders `items` so that each half (first `len / 2`, rest) is split again recursively
/// along the longest extent of its centres: the implicit layout [`SphereTree::build`] indexes.
/// The halves are disjoint, so large ones are ordered in parallel; ties break on the
/// original index, so the order does not depend on the thread count.
fn partition(items: &mut [([f32; 4], u32)]) {
    if items.len() <= BUCKET {
        return;
    }
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for (it, _) in items.iter() {
        for k in 0..3 {
            lo[k] = lo[k].min(it[k]);
            hi[k] = hi[k].max(it[k]);
        }
    }
    let ext = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
    let ax = if ext[0] >= ext[1] && ext[0] >= ext[2] {
        0
    } else if ext[1] >= ext[2] {
        1
    } else {
        2
    };
    let m = items.len() / 2;
    items.select_nth_unstable_by(m, |a, b| a.0[ax].total_cmp(&b.0[ax]).then(a.1.cmp(&b.1)));
    let (a, b) = items.split_at_mut(m);
    if a.len() > 16_384 {
        rayon::join(|| partition(a), || partition(b));
    } else {
        partition(a);
        partition(b);
    }
}

impl SphereTree {
    /// Builds the tree over spheres `[x, y, z, r]`, each with the id searches report
    /// (taken as they come, so the caller's vector is not copied).
    pub fn build(mut items: Vec<([f32; 4], u32)>) -> SphereTree {
        partition(&mut items);
        let mut nodes = Vec::new();
        if !items.is_empty() {
            let empty = KdNode { lo: [0.0; 3], hi: [0.0; 3], rmax: 0.0, start: 0, end: items.len() as u32, left: 0 };
            nodes.push(empty);
            // Ranges breadth first (the split rule of `partition`), so children follow parents.
            let mut k = 0;
            while k < nodes.len() {
                let (s, e) = (nodes[k].start, nodes[k].end);
                if (e - s) as usize > BUCKET {
                    let m = s + (e - s) / 2;
                    nodes[k].left = nodes.len() as u32;
                    nodes.push(KdNode { start: s, end: m, ..empty });
                    nodes.push(KdNode { start: m, end: e, ..empty });
                }
                k += 1;
            }
            // Boxes bottom-up: buckets from their items, inner nodes from their children.
            for k in (0..nodes.len()).rev() {
                let n = nodes[k];
                let (mut lo, mut hi, mut rmax) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3], 0.0f64);
                let mut add = |l: [f64; 3], h: [f64; 3], r: f64| {
                    for j in 0..3 {
                        lo[j] = lo[j].min(l[j]);
                        hi[j] = hi[j].max(h[j]);
                    }
                    rmax = rmax.max(r);
                };
                if n.left == 0 {
                    for (it, _) in &items[n.start as usize..n.end as usize] {
                        let c = [it[0] as f64, it[1] as f64, it[2] as f64];
                        add(c, c, it[3] as f64);
                    }
                } else {
                    for c in [nodes[n.left as usize], nodes[n.left as usize + 1]] {
                        add(c.lo, c.hi, c.rmax);
                    }
                }
                nodes[k].lo = lo;
                nodes[k].hi = hi;
                nodes[k].rmax = rmax;
            }
        }
        SphereTree { items, nodes }
    }

    /// Number of items.
    pub fn len(&self) -> usize {
        self.items.len()
    }

    /// True when the tree holds no item.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// A sphere bounding every item sphere, `None` when empty.
    pub fn bound(&self) -> Option<[f64; 4]> {
        let n = self.nodes.first()?;
        let c = [0.5 * (n.lo[0] + n.hi[0]), 0.5 * (n.lo[1] + n.hi[1]), 0.5 * (n.lo[2] + n.hi[2])];
        let half = dist(n.lo, c);
        Some([c[0], c[1], c[2], half + n.rmax])
    }

    /// Smallest `eval(id, item, best)` over items, searched nearest-box first and pruned by
    /// the lower bound `|p - box| - rmax`, which `eval` must respect (a true signed distance
    /// to something inside the item's sphere). Stops as soon as the best is `<= stop`.
    /// Returns the best and the (reordered) index of its item, `None` when nothing beat
    /// `best_in`.
    fn search(&self, p: [f64; 3], best_in: f64, stop: f64, mut eval: impl FnMut(u32, &[f32; 4], f64) -> f64) -> (f64, Option<usize>) {
        let mut best = best_in;
        let mut arg = None;
        if self.nodes.is_empty() {
            return (best, arg);
        }
        let mut stack: Vec<(f64, u32)> = Vec::with_capacity(64);
        stack.push((lower_bound(&self.nodes[0], p), 0));
        while let Some((lb, k)) = stack.pop() {
            if lb >= best {
                continue;
            }
            let n = &self.nodes[k as usize];
            if n.left == 0 {
                for i in n.start as usize..n.end as usize {
                    let (it, id) = &self.items[i];
                    let d = eval(*id, it, best);
                    if d < best {
                        best = d;
                        arg = Some(i);
                        if best <= stop {
                            return (best, arg);
                        }
                    }
                }
            } else {
                let (a, b) = (n.left, n.left + 1);
                let (la, lb2) = (lower_bound(&self.nodes[a as usize], p), lower_bound(&self.nodes[b as usize], p));
                // Push the farther first so the nearer is explored first.
                if la <= lb2 {
                    stack.push((lb2, b));
                    stack.push((la, a));
                } else {
                    stack.push((la, a));
                    stack.push((lb2, b));
                }
            }
        }
        (best, arg)
    }

    /// Signed distance from `p` to the nearest item sphere (negative inside) and that
    /// item's radius, stopping at the first sphere containing `p`; `None` when no item is
    /// nearer than `best_in`.
    pub fn nearest(&self, p: [f64; 3], best_in: f64) -> Option<(f64, f64)> {
        let (d, i) = self.search(p, best_in, 0.0, |_, it, _| sphere_distance(p, it));
        i.map(|i| (d, self.items[i].0[3] as f64))
    }
}

fn sphere_distance(p: [f64; 3], it: &[f32; 4]) -> f64 {
    dist(p, [it[0] as f64, it[1] as f64, it[2] as f64]) - it[3] as f64 * (1.0 + RADIUS_SLACK)
}

fn lower_bound(n: &KdNode, p: [f64; 3]) -> f64 {
    let s: f64 = (0..3).map(|k| (n.lo[k] - p[k]).max(p[k] - n.hi[k]).max(0.0).powi(2)).sum();
    s.sqrt() - n.rmax * (1.0 + RADIUS_SLACK)
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// One use of a decoded tree: world = `transform(local)`.
struct Use {
    tree: usize,
    transform: Similarity,
}

/// The inverse of a similarity applied to a point: `rotate⁻¹(p - t) / s`.
fn to_local(t: &Similarity, p: [f64; 3]) -> [f64; 3] {
    let d = [p[0] - t.translation[0], p[1] - t.translation[1], p[2] - t.translation[2]];
    let [x, y, z, w] = t.rotation;
    let inv = Similarity { translation: [0.0; 3], rotation: [-x, -y, -z, w], scale: 1.0 };
    let r = inv.rotate(d);
    [r[0] / t.scale, r[1] / t.scale, r[2] / t.scale]
}

/// Decodes the leaves of tree `t` of `file` level by level, keeping only leaves and the
/// previous level's internal nodes.
fn decode_leaves(file: &SctReader, t: usize) -> Result<Vec<([f32; 4], u32)>, sct_format::Error> {
    let Some(idx) = file.trees().get(t) else { return Ok(Vec::new()) };
    let sphere = |n: &Node, id: usize| ([n.center[0], n.center[1], n.center[2], n.radius], id as u32);
    if idx.header.node_count == 0 {
        return Ok(Vec::new());
    }
    let mut leaves = Vec::with_capacity(idx.header.leaf_count.min(1 << 28) as usize);
    if idx.header.root_internal == 0 {
        leaves.push(sphere(&idx.header.root, 0));
        return Ok(leaves);
    }
    file.walk_tree(t, |_, blk| {
        for (n, &f) in blk.nodes.iter().zip(&blk.internal) {
            if !f {
                leaves.push(sphere(n, leaves.len()));
            }
        }
        Ok(())
    })?;
    Ok(leaves)
}

/// Errors listed in a [`CoverageReport`]; later ones are only counted.
pub const MAX_ERRORS: usize = 1000;

/// The report's errors: the first [`MAX_ERRORS`] in traversal order, then one line counting
/// the rest. A broken inline shared along many paths yields one error per path; listing them
/// all would cost memory in proportion to the (bounded, but large) number of paths.
#[derive(Default)]
struct Errors {
    list: Vec<String>,
    omitted: u64,
}

impl Errors {
    fn push(&mut self, e: String) {
        if self.list.len() < MAX_ERRORS {
            self.list.push(e);
        } else {
            self.omitted = self.omitted.saturating_add(1);
        }
    }

    fn finish(mut self) -> Vec<String> {
        if self.omitted > 0 {
            self.list.push(format!("... and {} more errors, not listed", self.omitted));
        }
        self.list
    }
}

/// Loads `mesh` and draws the test points.
fn mesh_points(mesh: &Path, opts: &AgainstOptions) -> Result<Vec<[f64; 3]>, InspectError> {
    // Texture alpha matters only when alpha-dropped surfaces are left out.
    let load = voxelize::LoadOptions { load_textures: opts.exclude_alpha_dropped, ..Default::default() };
    let scene = voxelize::load(mesh, &load)?;
    let mut pts = if opts.exclude_alpha_dropped {
        voxelize::alpha::visible_surface_points(&scene, opts.points, opts.seed).0
    } else {
        voxelize::mesh::surface_points(&scene, opts.points, opts.seed)
    };
    if pts.is_empty() {
        // A point cloud (PLY without faces): its points are the surface.
        if let Some(pc) = scene.points.as_ref().filter(|pc| !pc.positions.is_empty()) {
            let mut rng = sct_format::rng::SplitMix64(opts.seed);
            pts = (0..opts.points).map(|_| pc.positions[(rng.next_u64() % pc.positions.len() as u64) as usize].map(f64::from)).collect();
        }
    }
    if pts.is_empty() && opts.points > 0 {
        return Err(InspectError::BadMesh(format!("{}: no triangle with positive area and no points", mesh.display())));
    }
    Ok(pts)
}

/// Checks how much of `mesh`'s surface the leaves of the SCT file at `file` cover.
pub fn coverage_against(file: &Path, mesh: &Path, opts: &AgainstOptions) -> Result<CoverageReport, InspectError> {
    if opts.points == 0 {
        // No point is trivially covered: the check would pass whatever the file holds.
        return Err(InspectError::Usage("--points must be at least 1".into()));
    }
    let t0 = std::time::Instant::now();
    let points = mesh_points(mesh, opts)?;
    let t1 = std::time::Instant::now();

    let topts = TraverseOptions { limits: opts.limits.clone(), verify_inline_hashes: false, allow_outside_inlines: opts.allow_outside_inlines };
    let mut trees: Vec<SphereTree> = Vec::new();
    // `None`: the tree failed to decode; it is reported once, not decoded again per use.
    let mut by_key: HashMap<(PathBuf, usize), Option<usize>> = HashMap::new();
    let mut uses: Vec<Use> = Vec::new();
    let mut affine_trees: HashMap<(PathBuf, usize, [[u64; 4]; 3]), usize> = HashMap::new();
    // Uses of one tree under one transform (bit for bit) place the same leaves: queried once.
    let mut distinct: std::collections::HashSet<(usize, [u64; 8])> = std::collections::HashSet::new();
    let (mut use_count, mut leaves_expanded) = (0u64, 0u64);
    let mut errors = Errors::default();
    let mut reached_count = 0u64;
    for item in Traversal::open(file, topts)? {
        // Every item counts (also errors and group nodes), so a DAG whose leaves are broken
        // or empty is bounded too, not only one that yields uses.
        reached_count = reached_count.saturating_add(1);
        sct_format::Limits::check("graph nodes reached by the coverage traversal (shared nodes once per path)", reached_count, opts.max_uses)?;
        let reached = match item {
            Ok(r) => r,
            // The traversal's own visit limit ends it: a partial coverage is no answer.
            Err(e) if e.is_visit_limit() => return Err(crate::traverse_fatal(e)),
            Err(e) => {
                errors.push(e.to_string());
                continue;
            }
        };
        if reached.kind != ReachedKind::Tree {
            continue; // group trees bound other nodes; their leaves are not samples
        }
        let key = (reached.file_path.clone(), reached.tree);
        let ti = match by_key.get(&key) {
            Some(&Some(i)) => i,
            Some(None) => continue,
            None => match decode_leaves(&reached.file, reached.tree) {
                Ok(leaves) => {
                    trees.push(SphereTree::build(leaves));
                    by_key.insert(key, Some(trees.len() - 1));
                    trees.len() - 1
                }
                Err(e) => {
                    errors.push(format!("{}: tree {} of {}: {e}", reached.path, reached.tree, reached.file_path.display()));
                    by_key.insert(key, None);
                    continue;
                }
            },
        };
        // An affine map (format 1.3) does not preserve distances: the leaves of such a use
        // are mapped into the world (centre M·c, radius r·σ_max, spec §7) and queried there,
        // once per tree and matrix.
        let (ti, t) = match reached.state.transform {
            Transform::Similarity(t) => (ti, t),
            Transform::Affine(a) => {
                let key = (reached.file_path.clone(), reached.tree, a.affine.matrix.map(|r| r.map(f64::to_bits)));
                let wi = match affine_trees.get(&key) {
                    Some(&i) => i,
                    None => {
                        let Ok(leaves) = decode_leaves(&reached.file, reached.tree) else { continue };
                        let mapped = leaves
                            .into_iter()
                            .map(|(b, id)| {
                                let n = a.apply_node(&Node { center: [b[0], b[1], b[2]], radius: b[3], ..Node::default() });
                                ([n.center[0], n.center[1], n.center[2], n.radius], id)
                            })
                            .collect();
                        trees.push(SphereTree::build(mapped));
                        affine_trees.insert(key, trees.len() - 1);
                        trees.len() - 1
                    }
                };
                (wi, Similarity::IDENTITY)
            }
        };
        if !trees[ti].is_empty() {
            use_count += 1;
            leaves_expanded = leaves_expanded.saturating_add(trees[ti].len() as u64);
            let [a, b, c] = t.translation;
            let [x, y, z, w] = t.rotation;
            if distinct.insert((ti, [a, b, c, x, y, z, w, t.scale].map(f64::to_bits))) {
                uses.push(Use { tree: ti, transform: t });
            }
        }
    }
    // Top level: each use's world bound.
    let bounds: Vec<([f32; 4], u32)> = uses
        .iter()
        .map(|u| {
            let b = trees[u.tree].bound().unwrap_or_default();
            let c = u.transform.apply_point([b[0], b[1], b[2]]);
            let c32 = c.map(|x| x as f32);
            // Rounding the centre to f32 moves it: grow the radius by that and round up.
            let moved = dist(c, c32.map(f64::from));
            let r = ((b[3] * u.transform.scale + moved) as f32).next_up();
            [c32[0], c32[1], c32[2], r]
        })
        .zip(0u32..)
        .collect();
    let top = SphereTree::build(bounds);
    let t2 = std::time::Instant::now();

    // (signed distance, nearest leaf radius) per point, world units. Queries are counted
    // over all points; past the limit every remaining one is skipped and the check fails.
    let queries = std::sync::atomic::AtomicU64::new(0);
    let results: Vec<(f64, f64)> = points
        .par_iter()
        .map(|&p| {
            let mut radius = 0.0;
            let (d, _) = top.search(p, f64::INFINITY, 0.0, |id, bound, best| {
                if sphere_distance(p, bound) >= best {
                    return f64::INFINITY; // nothing in this use can be nearer
                }
                if queries.fetch_add(1, std::sync::atomic::Ordering::Relaxed) >= opts.max_use_queries {
                    return f64::INFINITY;
                }
                let u = &uses[id as usize];
                let s = u.transform.scale;
                match trees[u.tree].nearest(to_local(&u.transform, p), best / s) {
                    Some((dl, rl)) if dl * s < best => {
                        radius = rl * s;
                        dl * s
                    }
                    _ => f64::INFINITY,
                }
            });
            (d, radius)
        })
        .collect();
    let t3 = std::time::Instant::now();
    let asked = queries.into_inner();
    sct_format::Limits::check(USE_QUERIES, asked, opts.max_use_queries)?;

    let covered = results.iter().filter(|r| r.0 <= 0.0).count() as u64;
    // The first point (lowest index) among the farthest: deterministic for any thread count.
    let worst = results.iter().enumerate().filter(|(_, r)| r.0 > 0.0).fold(None::<(usize, f64, f64)>, |w, (i, r)| match w {
        Some((_, d, _)) if d >= r.0 => w,
        _ => Some((i, r.0, r.1)),
    });
    let n = points.len() as u64;
    let fraction = if n == 0 { 1.0 } else { covered as f64 / n as f64 };
    Ok(CoverageReport {
        mesh: mesh.display().to_string(),
        points: n,
        seed: opts.seed,
        covered,
        fraction,
        min_coverage: opts.min_coverage,
        passed: fraction >= opts.min_coverage,
        // Stored trees only: the world copies of affine uses are not in the file.
        trees: (trees.len() - affine_trees.len()) as u64,
        leaves: {
            let copies: std::collections::HashSet<usize> = affine_trees.values().copied().collect();
            trees.iter().enumerate().filter(|(i, _)| !copies.contains(i)).map(|(_, t)| t.len() as u64).sum()
        },
        tree_uses: use_count,
        leaves_expanded,
        worst_uncovered: worst.map(|(i, d, r)| Uncovered {
            point: points[i],
            distance: d,
            leaf_radius: r,
            leaf_radii: if r > 0.0 { d / r } else { f64::INFINITY },
        }),
        errors: errors.finish(),
        seconds: Seconds { mesh: (t1 - t0).as_secs_f64(), index: (t2 - t1).as_secs_f64(), query: (t3 - t2).as_secs_f64() },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute force against the k-d tree on a grid of spheres of varied radii.
    #[test]
    fn nearest_matches_brute_force() {
        let mut rng = sct_format::rng::SplitMix64(7);
        let spheres: Vec<[f32; 4]> =
            (0..2000).map(|_| [rng.next_f64() * 10.0, rng.next_f64() * 10.0, rng.next_f64(), 0.01 + rng.next_f64() * 0.2].map(|x| x as f32)).collect();
        let t = SphereTree::build(spheres.iter().copied().zip(0u32..).collect());
        for _ in 0..500 {
            let p = [rng.next_f64() * 12.0 - 1.0, rng.next_f64() * 12.0 - 1.0, rng.next_f64() * 3.0 - 1.0];
            let (want, wr) = spheres.iter().map(|s| (sphere_distance(p, s), s[3] as f64)).fold((f64::INFINITY, 0.0), |a, b| if b.0 < a.0 { b } else { a });
            let (got, gr) = t.nearest(p, f64::INFINITY).unwrap();
            if want <= 0.0 {
                assert!(got <= 0.0, "{p:?}: inside per brute force, k-d says {got}");
            } else {
                assert_eq!(got, want, "{p:?}");
                assert_eq!(gr, wr, "{p:?}");
            }
        }
    }

    #[test]
    fn to_local_inverts_apply_point() {
        let t = Similarity { translation: [1.0, -2.0, 0.5], rotation: [0.0, 0.38268343236508984, 0.0, 0.9238795325112867], scale: 2.5 };
        let p = [0.3, 0.7, -1.1];
        let q = to_local(&t, t.apply_point(p));
        for k in 0..3 {
            assert!((q[k] - p[k]).abs() < 1e-12, "{q:?} vs {p:?}");
        }
    }
}
