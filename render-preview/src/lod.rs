//! Lazy block cache and level-by-level LOD refinement of one scene tree.
//!
//! A tree is stored breadth first in blocks per level; a block can only be decoded with
//! its decoded parents, so the cache decodes on demand, recursively fetching the parent
//! blocks it needs. Refinement walks the tree one level at a time: the frontier of each
//! level is sorted, so finding its blocks is a merge walk, and the children of the
//! `k`-th internal node of a level are nodes `2k`, `2k+1` of the next.

use std::sync::{Arc, OnceLock};

use rayon::prelude::*;
use sct_format::{Node, SctReader};

use crate::camera::View;
use crate::error::{Error, Result};
use crate::raster::Splat;
use crate::shade::{self, Shading};
use crate::LodSize;

/// One decoded block plus what refinement needs to find children.
#[derive(Debug)]
pub(crate) struct Block {
    nodes: Vec<Node>,
    internal: Vec<bool>,
    /// Internal nodes before position `i` within the block.
    rank_before: Vec<u32>,
    /// Positions of the internal nodes within the block.
    internal_pos: Vec<u32>,
    first_node: u64,
    internal_before: u64,
}

impl Block {
    fn new(nodes: Vec<Node>, internal: Vec<bool>, first_node: u64, internal_before: u64) -> Block {
        let mut rank_before = Vec::with_capacity(nodes.len());
        let mut internal_pos = Vec::new();
        for (i, &f) in internal.iter().enumerate() {
            rank_before.push(internal_pos.len() as u32);
            if f {
                internal_pos.push(i as u32);
            }
        }
        Block { nodes, internal, rank_before, internal_pos, first_node, internal_before }
    }
    fn end(&self) -> u64 {
        self.first_node + self.nodes.len() as u64
    }
}

/// Decoded blocks of one tree, filled on demand; shared by every instance of the tree.
#[derive(Debug)]
pub(crate) struct TreeCache {
    tree: usize,
    /// `levels[d][k]`: local block `k` of level `d` (level 0 holds the root only).
    levels: Vec<Vec<OnceLock<Arc<Block>>>>,
    first_block: Vec<usize>,
    /// Leaves in the levels above level `d` (to number a group tree's leaves).
    leaves_before: Vec<u64>,
}

impl TreeCache {
    pub(crate) fn new(reader: &SctReader, tree: usize) -> TreeCache {
        let t = &reader.trees()[tree];
        let mut levels = Vec::with_capacity(t.levels.len());
        let mut first_block = Vec::with_capacity(t.levels.len());
        let mut leaves_before = Vec::with_capacity(t.levels.len());
        let mut leaves = 0u64;
        for (d, l) in t.levels.iter().enumerate() {
            first_block.push(l.first_block as usize);
            leaves_before.push(leaves);
            let internal = t.levels.get(d + 1).map_or(0, |n| n.node_count / 2);
            leaves += l.node_count.saturating_sub(internal);
            let n = if d == 0 { 1 } else { l.block_count as usize };
            levels.push((0..n).map(|_| OnceLock::new()).collect::<Vec<_>>());
        }
        if let Some(root) = levels.first().and_then(|l| l.first()) {
            let _ = root.set(Arc::new(Block::new(vec![t.header.root], vec![t.header.root_internal == 1], 0, 0)));
        }
        TreeCache { tree, levels, first_block, leaves_before }
    }

    /// Root node, if the tree has one.
    pub(crate) fn root(&self) -> Option<Node> {
        self.levels.first()?.first()?.get().map(|b| b.nodes[0])
    }

    fn malformed(&self, reader: &SctReader, what: String) -> Error {
        let at = reader.trees()[self.tree].section.offset;
        Error::sct(reader.path().unwrap_or(std::path::Path::new("<memory>")), sct_format::Error::malformed(at, what))
    }

    /// Local block of level `d` holding node `i`.
    fn block_of(&self, reader: &SctReader, d: usize, i: u64) -> Result<usize> {
        if d == 0 {
            return Ok(0);
        }
        let g = reader.trees()[self.tree].block_of(d, i).ok_or_else(|| self.malformed(reader, format!("level {d} has no node {i}")))?;
        Ok(g - self.first_block[d])
    }

    fn cached(&self, d: usize, k: usize) -> Option<Arc<Block>> {
        self.levels.get(d)?.get(k)?.get().cloned()
    }

    /// The decoded parents of block `k` of level `d` (internal nodes of level `d − 1`).
    fn parents_of(&self, reader: &SctReader, d: usize, k: usize) -> Result<Vec<Node>> {
        let e = &reader.trees()[self.tree].blocks[self.first_block[d] + k];
        let lo = e.first_node / 2;
        let hi = lo + e.node_count as u64 / 2;
        let mut out = Vec::with_capacity((hi - lo) as usize);
        let mut pk = if d == 1 {
            0
        } else {
            reader.trees()[self.tree]
                .block_of_internal(d - 1, lo)
                .ok_or_else(|| self.malformed(reader, format!("no parent block for level {d}")))?
                - self.first_block[d - 1]
        };
        while (out.len() as u64) < hi - lo {
            if pk >= self.levels[d - 1].len() {
                return Err(self.malformed(reader, format!("level {d} block {k} has parents past the end of level {}", d - 1)));
            }
            let pb = self.get(reader, d - 1, pk)?;
            let ib = pb.internal_before;
            let from = lo.max(ib) - ib;
            let to = (hi.min(ib + pb.internal_pos.len() as u64)).saturating_sub(ib);
            for r in from..to {
                out.push(pb.nodes[pb.internal_pos[r as usize] as usize]);
            }
            pk += 1;
        }
        Ok(out)
    }

    fn decode_with(&self, reader: &SctReader, d: usize, k: usize, parents: &[Node]) -> Result<Arc<Block>> {
        let path = reader.path().unwrap_or(std::path::Path::new("<memory>"));
        let g = self.first_block[d] + k;
        let blk = reader.decode_block(self.tree, g, parents).map_err(|e| Error::sct(path, e))?;
        let e = &reader.trees()[self.tree].blocks[g];
        let b = Arc::new(Block::new(blk.nodes, blk.internal, e.first_node, e.internal_before));
        // Another thread may have won the race; either copy is identical.
        let _ = self.levels[d][k].set(b.clone());
        Ok(self.cached(d, k).unwrap_or(b))
    }

    /// Block `k` of level `d`, decoding it (and the parent blocks it needs) if necessary.
    fn get(&self, reader: &SctReader, d: usize, k: usize) -> Result<Arc<Block>> {
        if let Some(b) = self.cached(d, k) {
            return Ok(b);
        }
        if d >= self.levels.len() || k >= self.levels[d].len() {
            return Err(self.malformed(reader, format!("block {k} of level {d} does not exist")));
        }
        let parents = self.parents_of(reader, d, k)?;
        self.decode_with(reader, d, k, &parents)
    }

    /// Node `i` of level `d`: the node, whether it is internal, the index of its first child
    /// in level `d + 1` (internal nodes) and its leaf number (leaves; breadth-first order,
    /// which names a group leaf's child).
    pub(crate) fn node_at(&self, reader: &SctReader, d: usize, i: u64) -> Result<NodeAt> {
        let k = self.block_of(reader, d, i)?;
        let b = self.get(reader, d, k)?;
        self.at_in(reader, &b, d, i)
    }

    /// Node `i` of level `d`, found in its decoded block `b`.
    fn at_in(&self, reader: &SctReader, b: &Block, d: usize, i: u64) -> Result<NodeAt> {
        let local = i.checked_sub(b.first_node).filter(|&l| l < b.nodes.len() as u64).ok_or_else(|| self.malformed(reader, format!("level {d} has no node {i}")))? as usize;
        let rank = b.internal_before + b.rank_before[local] as u64;
        let leaves_before = self.leaves_before.get(d).copied().unwrap_or(0);
        Ok(NodeAt { node: b.nodes[local], internal: b.internal[local], first_child: 2 * rank, leaf_no: leaves_before + i - rank })
    }

    /// Leaves of the whole tree, from the index's level counts (nothing decoded).
    pub(crate) fn leaf_count(&self, reader: &SctReader) -> u64 {
        let Some(t) = reader.trees().get(self.tree) else { return 0 };
        let last = t.levels.len().saturating_sub(1);
        self.leaves_before.get(last).copied().unwrap_or(0) + t.levels.get(last).map_or(0, |l| l.node_count)
    }

    /// Two-sided trees are never culled as back-facing (spec §6.2).
    pub(crate) fn two_sided(&self, reader: &SctReader) -> bool {
        reader.trees().get(self.tree).is_some_and(|t| t.two_sided())
    }

    /// Decodes the blocks `ks` of level `d`, in parallel when several are missing.
    fn ensure(&self, reader: &SctReader, d: usize, ks: &[usize]) -> Result<()> {
        let missing: Vec<usize> = ks.iter().copied().filter(|&k| self.cached(d, k).is_none()).collect();
        if missing.len() <= 1 {
            return missing.iter().try_for_each(|&k| self.get(reader, d, k).map(|_| ()));
        }
        // Parents first, sequentially, so that no parent block is decoded twice.
        let jobs: Vec<(usize, Vec<Node>)> = missing.iter().map(|&k| Ok((k, self.parents_of(reader, d, k)?))).collect::<Result<_>>()?;
        jobs.par_iter().try_for_each(|(k, p)| self.decode_with(reader, d, *k, p).map(|_| ()))
    }
}

/// [`TreeCache::node_at`] for walks down one tree that read many nodes of the same few
/// blocks (the `wand` descents): the last block of each level is kept, so a node in it costs
/// a range check instead of a block search and a shared reference count update. One per
/// thread; cloning shares the blocks.
#[derive(Clone, Default)]
pub(crate) struct Cursor {
    blocks: Vec<Option<Arc<Block>>>,
}

impl Cursor {
    pub(crate) fn node_at(&mut self, cache: &TreeCache, reader: &SctReader, d: usize, i: u64) -> Result<NodeAt> {
        if let Some(Some(b)) = self.blocks.get(d) {
            if i >= b.first_node && i < b.end() {
                return cache.at_in(reader, b, d, i);
            }
        }
        let k = cache.block_of(reader, d, i)?;
        let b = cache.get(reader, d, k)?;
        let at = cache.at_in(reader, &b, d, i)?;
        if self.blocks.len() <= d {
            self.blocks.resize(d + 1, None);
        }
        self.blocks[d] = Some(b);
        Ok(at)
    }
}

/// One node found by [`TreeCache::node_at`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct NodeAt {
    pub node: Node,
    pub internal: bool,
    pub first_child: u64,
    pub leaf_no: u64,
}

/// Placement of a tree in camera space: `c_cam = m·c + t`, `n_cam = rot·n`, `r' = s·r`.
///
/// Under an affine instance (spec §7) `m` is the camera rotation times the linear part A,
/// `rot` the camera rotation times det(A)·A⁻ᵀ with the sign of det(A) (the normal matrix
/// scaled by |det A|: `|rot·n|` is Nanson's area factor of a patch with unit normal n), `s`
/// = σ_max(A) (a sphere's image lies in the sphere of radius `s·r`: conservative, slightly
/// fat for a stretched sphere, which is an ellipsoid) and cones widen by the condition
/// number `kappa`. Use [`Placement::normal`], [`Placement::cone`] and
/// [`Placement::area_factor`]: they reduce to `rot·n`, the cone and `s²` for a similarity.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Placement {
    pub m: [[f32; 3]; 3],
    pub rot: [[f32; 3]; 3],
    pub t: [f32; 3],
    pub s: f32,
    /// Push-down tint multipliers (as `sct_format::traverse::TraversalState`).
    pub tint: Option<[f32; 4]>,
    /// An affine (non-similarity) placement: normals need renormalising.
    pub affine: bool,
    /// Condition number of the linear part (1 for a similarity).
    pub kappa: f32,
}

impl Placement {
    /// Camera-space unit normal of a tree-frame unit normal (the inverse transpose,
    /// renormalised, under an affine placement).
    #[inline]
    pub(crate) fn normal(&self, n: [f32; 3]) -> [f32; 3] {
        let v = mul(&self.rot, n);
        if !self.affine {
            return v;
        }
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if l > 0.0 && l.is_finite() {
            v.map(|x| x / l)
        } else {
            v
        }
    }

    /// The camera-space cone semi-angle: κ·cone, at most π (spec §7; unchanged under a
    /// similarity).
    #[inline]
    pub(crate) fn cone(&self, cone: f32) -> f32 {
        if self.affine && cone > 0.0 {
            (cone * self.kappa).min(std::f32::consts::PI)
        } else {
            cone
        }
    }

    /// What the placement multiplies the area of a patch with unit normal `n` by: `s²`, or
    /// Nanson's |det A|·|A⁻ᵀ n| under an affine placement.
    #[inline]
    pub(crate) fn area_factor(&self, n: [f32; 3]) -> f32 {
        if self.affine {
            let v = mul(&self.rot, n);
            (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
        } else {
            self.s * self.s
        }
    }

    /// The most the placement stretches a patch with unit normal `n` whose normals spread
    /// within `cone` (its samples' width over their tree-frame width): the scale of a
    /// similarity; under an affine placement the largest stretch within the tangent plane
    /// of `n` (exact for a flat patch), moving to σ_max as the cone opens (sin(cone), all of
    /// it from 90°: a folded patch, a box's edge or corner, has faces in every plane).
    /// The equal-area radius of the mapped patch (Nanson's factor of the axis) is no bound
    /// on a stretched patch's width: `parilov` cells sized by it held samples wider than
    /// the footprint, drawn as virtual children across edges (SimpleInstancing −2.4 dB).
    #[inline]
    pub(crate) fn patch_stretch(&self, n: [f32; 3], cone: f32) -> f32 {
        if !self.affine {
            return self.s;
        }
        let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        if l.is_nan() || l <= 0.0 || cone >= std::f32::consts::FRAC_PI_2 {
            return self.s;
        }
        let (t1, t2) = tangents(n.map(|v| v / l));
        // Largest singular value of A on the plane: the top eigenvalue of the 2 × 2 Gram
        // matrix of the mapped tangents (the camera rotation keeps lengths).
        let (a, b) = (mul(&self.m, t1), mul(&self.m, t2));
        let (aa, ab, bb) = (dot3(a, a), dot3(a, b), dot3(b, b));
        let top = 0.5 * (aa + bb) + (0.25 * (aa - bb) * (aa - bb) + ab * ab).sqrt();
        let flat = top.sqrt().min(self.s);
        if !flat.is_finite() {
            return self.s;
        }
        flat + (self.s - flat) * cone.max(0.0).sin()
    }
}

#[inline]
fn mul(m: &[[f32; 3]; 3], v: [f32; 3]) -> [f32; 3] {
    [
        m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
        m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
        m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
    ]
}

/// What the node limit names in its error.
pub const NODES_EXAMINED: &str = "tree nodes examined by one render (--max-nodes)";
/// What the pixel limit names in its error.
pub const PIXELS_COVERED: &str = "pixels under the splats of one render, by bounding box (--max-splat-pixels)";

/// Render settings the per-node decision needs.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LodParams {
    /// Most tree nodes examined over the whole render ([`crate::RenderOptions::max_nodes`]).
    pub max_nodes: u64,
    /// Most pixels under all splats ([`crate::RenderOptions::max_splat_pixels`]).
    pub max_splat_pixels: u64,
    pub pixel_error: f32,
    pub shading: Shading,
    pub ellipses: bool,
    pub backface: bool,
    /// Cap on a leaf splat's radius (pixels) when it nearly reaches the eye.
    pub max_radius: f32,
    /// Internal splats are drawn with at most this multiple of their equal-area radius.
    pub area_cover: f32,
    /// What the threshold is compared with.
    pub lod_size: LodSize,
    /// Internal nodes that may hold part of an outline refine until their splat is at most
    /// this fraction of `pixel_error` (1: no different from the others).
    pub outline_refine: f32,
    /// Draw each node as this Gaussian kernel's support ellipse (the `gauss` method)
    /// instead of the opaque splat.
    pub kernel: Option<crate::gauss::Kernel>,
    /// Collect every leaf in the view as a camera-space surfel whose support is its sphere
    /// scaled by this factor (the `wald` method) instead of choosing a cut: internal nodes
    /// always refine, leaves become [`Decision::Leaf`], group leaves descend.
    pub leaves: Option<f32>,
    /// Under an affine placement, draw a flat patch as the matrix's image of its disc
    /// ([`affine_splat`]) instead of the disc of its mapped area (`parilov`, whose wide
    /// samples have no depth test to trim what sticks out over an edge, and `zbuffer`: on
    /// SimpleInstancing's 120 stretched boxes 25.0 → 25.4 dB front, 25.7 → 27.0 iso).
    pub matrix_splats: bool,
    /// Push splats' rims back ([`RIM_DEPTH`]): for `zbuffer`, whose depth test then splits
    /// the overlap of a surface's splats by nearer centre. The other methods keep flat
    /// discs (their papers' splats, and the depths they compare).
    pub rims: bool,
}

/// Counters of one render.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct LodStats {
    /// Nodes examined.
    pub nodes_visited: u64,
    /// Nodes culled by the view frustum.
    pub frustum_culled: u64,
    /// Nodes culled as back-facing (normal cone).
    pub backface_culled: u64,
    /// Internal nodes drawn because they were small enough.
    pub internal_splats: u64,
    /// Leaves drawn.
    pub leaf_splats: u64,
}

impl LodStats {
    pub(crate) fn add(&mut self, o: &LodStats) {
        self.nodes_visited += o.nodes_visited;
        self.frustum_culled += o.frustum_culled;
        self.backface_culled += o.backface_culled;
        self.internal_splats += o.internal_splats;
        self.leaf_splats += o.leaf_splats;
    }
}

/// What to do with one node.
pub(crate) enum Decision {
    Cull,
    Draw(Splat),
    Refine,
    /// A group-tree leaf too large to draw: draw its child graph node instead.
    Descend,
    /// A leaf collected for ray tracing ([`LodParams::leaves`]).
    Leaf(crate::wald::Surfel),
}

/// The per-node decision: cull, draw (projected size under the threshold, or a leaf) or
/// refine. `leaf` says the node has no children.
#[inline]
pub(crate) fn decide(n: &Node, leaf: bool, group: bool, pl: &Placement, view: &View, p: &LodParams, st: &mut LodStats) -> Decision {
    st.nodes_visited += 1;
    let c = mul(&pl.m, n.center);
    let c = [c[0] + pl.t[0], c[1] + pl.t[1], c[2] + pl.t[2]];
    let r = n.radius * pl.s;
    if let Some(scale) = p.leaves {
        return decide_leaf(n, leaf, group, c, r, scale, pl, view, p, st);
    }
    if view.outside(c, r) {
        st.frustum_culled += 1;
        return Decision::Cull;
    }
    let nrm = pl.normal(n.normal);
    let cone = pl.cone(n.cone);
    if p.backface && view.backfacing(c, r, nrm, cone) {
        st.backface_culled += 1;
        return Decision::Cull;
    }
    let mut s = view.projected_radius(c, r);
    // Spheres are loose: an internal node's surface patch is usually much smaller than its
    // sphere, and a leaf's piece of a voxel (cut by an edge, a silhouette or the surface's
    // own slope) is smaller than the ball around it. Drawing the whole conservative circle
    // thickens silhouettes by up to a pixel (fandisk, dragon, box: 3-4 dB of foreground
    // PSNR, all of it outline). The splat shrinks towards the disc of equal area, kept large
    // enough (×AREA_COVER) that neighbouring discs still overlap: a whole voxel's square
    // keeps its covering circle (√(1/π)·1.3 > √½).
    // (In the world's frame under an affine placement: area and radius scale differently.)
    let area = if pl.affine { n.area * pl.area_factor(n.normal) / (pl.s * pl.s) } else { n.area };
    let shrink = if n.radius > 0.0 {
        ((area / std::f32::consts::PI).sqrt() * p.area_cover / n.radius).min(1.0)
    } else {
        1.0
    };
    // With `LodSize::Patch` the threshold applies to that drawn splat rather than to the
    // sphere (EQ 46): the cut stops a level or two higher, where the sphere is 2-4x the
    // patch, for about a quarter of the nodes and blocks. Group leaves keep the sphere test:
    // their "patch" is a whole child scene.
    let size = if p.lod_size == LodSize::Patch && !group { s * shrink } else { s };
    // An outline is where a drawn internal node errs most: its disc (of the whole patch's
    // area, front and back) reaches past the outline into the background, a full-contrast
    // error for each pixel. Nodes that may hold part of one refine to half the threshold:
    // +1.5 dB on SimpleInstancing's many small boxes, for 1 % more splats
    // ([`crate::OUTLINE_REFINE`]).
    if size > p.pixel_error || (!leaf && !group && size > p.pixel_error * p.outline_refine && on_silhouette(c, r, nrm, cone)) {
        if !leaf {
            return Decision::Refine;
        }
        if group {
            return Decision::Descend;
        }
    }
    if c[2] <= view.near {
        // A leaf whose centre is behind the near plane cannot be projected.
        st.frustum_culled += 1;
        return Decision::Cull;
    }
    if leaf {
        st.leaf_splats += 1;
    } else {
        st.internal_splats += 1;
    }
    s = s.min(p.max_radius) * shrink;
    let mut color = n.color;
    if let Some(t) = pl.tint {
        color = sct_format::traverse::tint_color(color, t);
    }
    let d = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt().max(1e-30);
    let l = [-c[0] / d, -c[1] / d, -c[2] / d];
    if p.shading == Shading::Lambert {
        color = shade::apply(color, shade::lambert(nrm, l));
    }
    let [x, y] = view.project(c);
    if let Some(k) = &p.kernel {
        // The opaque splat's disc (the leaf's covering radius, an internal node's
        // AREA_COVER × equal-area radius) is the kernel's half-opacity contour.
        return Decision::Draw(k.splat(c, nrm, r * shrink, cone, view.focal, x, y, color));
    }
    let affine = || (p.matrix_splats && pl.affine && n.cone < std::f32::consts::FRAC_PI_2).then(|| affine_splat(n, pl, view, c, p.max_radius, p.area_cover, [x, y], color)).flatten();
    let sp = if p.ellipses { affine().unwrap_or_else(|| surface_splat(c, nrm, cone, s, [x, y], color)) } else { Splat::disc(x, y, c[2], s, color) };
    Decision::Draw(if p.rims { with_rim(sp, view.focal) } else { sp })
}

/// How far behind its centre a drawn splat's rim lies, in units of its radius in the world
/// ([`Splat::rim`]). Flat discs of one surface tie in depth wherever they overlap and the
/// first drawn takes the whole overlap, which moves texture edges by up to a splat's
/// radius; with the rim pushed back, each pixel of the overlap goes to the splat whose
/// centre is nearer (in its ellipse's metric), as a sphere's front would. Pushed back by
/// one radius, a surface at most that far behind can show through the rim: leaves are
/// about a pixel, so such surfaces are within a pixel of each other.
pub(crate) const RIM_DEPTH: f32 = 1.0;

/// `sp` with its rim ([`RIM_DEPTH`] × its major radius, taken from pixels at its depth to
/// the world by `focal`, pixels per unit at distance 1).
pub(crate) fn with_rim(mut sp: Splat, focal: f32) -> Splat {
    let major = 1.0 / sp.inv_b2.max(1e-30).sqrt();
    sp.rim = RIM_DEPTH * major * sp.z / focal;
    sp
}

/// The splat of a flat patch under an affine placement: the patch's disc in the tree frame
/// (the equal-area radius × `area_cover`, at most the node's radius, as [`decide`] shrinks
/// splats) maps to an ellipse of the tangent plane (axes from the matrix, not a disc of the
/// same area), projected through the perspective's Jacobian at `c`. A disc of the mapped
/// area sticks out across the short axis of a stretched patch: over an edge, onto the next
/// face. `None` when the projection degenerates (the caller draws the disc splat).
#[allow(clippy::too_many_arguments)]
fn affine_splat(n: &Node, pl: &Placement, view: &View, c: [f32; 3], cap: f32, area_cover: f32, [x, y]: [f32; 2], color: [u8; 4]) -> Option<Splat> {
    let nt = n.normal;
    let len = dot3(nt, nt).sqrt();
    if len.is_nan() || len <= 0.0 || c[2] <= 0.0 {
        return None;
    }
    let nt = nt.map(|v| v / len);
    let (t1, t2) = tangents(nt);
    let rho = if n.radius > 0.0 { ((n.area / std::f32::consts::PI).sqrt() * area_cover).min(n.radius) } else { 0.0 };
    // Screen-space images of the two tangent radii: x = cx + f·X/Z, y = cy − f·Y/Z.
    let k = view.focal / c[2];
    let screen = |t: [f32; 3]| {
        let u = mul(&pl.m, t).map(|v| v * rho);
        [k * (u[0] - c[0] / c[2] * u[2]), -k * (u[1] - c[1] / c[2] * u[2])]
    };
    // Normals within the cone tilt the patch out of its plane by up to sin(cone) of its
    // radius: a flat ellipsoid in the tree frame, mapped whole (the cone itself is not
    // widened by the condition number here; that bound is for culling).
    let (a, b, e) = (screen(t1), screen(t2), screen(nt.map(|v| v * n.cone.sin())));
    // Semi-axes of the projected ellipsoid: eigenvalues of M·Mᵀ with M = [a b e].
    let (sxx, sxy, syy) = (a[0] * a[0] + b[0] * b[0] + e[0] * e[0], a[0] * a[1] + b[0] * b[1] + e[0] * e[1], a[1] * a[1] + b[1] * b[1] + e[1] * e[1]);
    let mean = 0.5 * (sxx + syy);
    let d = (0.25 * (sxx - syy) * (sxx - syy) + sxy * sxy).sqrt();
    let (major, minor) = ((mean + d).sqrt(), (mean - d).max(0.0).sqrt());
    if !(major.is_finite() && major > 0.0) {
        return None;
    }
    // Minor-axis direction: the eigenvector of the smaller eigenvalue.
    let (ux, uy) = if d > 1e-12 * mean { (sxy, mean - d - sxx) } else { (1.0, 0.0) };
    let ul = (ux * ux + uy * uy).sqrt();
    let (ux, uy) = if ul > 0.0 && ul.is_finite() { (ux / ul, uy / ul) } else { (1.0, 0.0) };
    let scale = if major > cap { cap / major } else { 1.0 };
    Some(Splat::ellipse(x, y, c[2], major * scale, minor * scale, ux, uy, color))
}

#[inline]
fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

#[inline]
fn dot3(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// An orthonormal basis of the plane normal to unit `n`.
#[inline]
fn tangents(n: [f32; 3]) -> ([f32; 3], [f32; 3]) {
    let h = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let t1 = cross(n, h);
    let l1 = dot3(t1, t1).sqrt();
    let t1 = t1.map(|v| v / l1);
    (t1, cross(n, t1))
}

/// [`decide`] when collecting leaves for ray tracing: a node is culled when the scaled
/// supports of all its leaves lie outside the view frustum, or all face away from the eye;
/// otherwise internal nodes refine (unless below the pixel footprint) and leaves become
/// surfels.
#[allow(clippy::too_many_arguments)]
#[inline]
fn decide_leaf(n: &Node, leaf: bool, group: bool, c: [f32; 3], r: f32, scale: f32, pl: &Placement, view: &View, p: &LodParams, st: &mut LodStats) -> Decision {
    // A child sphere lies inside its parent (|c_i − c| + r_i ≤ r), so its support scaled by
    // s ≥ 1 lies inside the parent's scaled by s: the same cull is conservative at every
    // level. Scales below 1 shrink the supports and keep the unscaled sphere as the bound.
    let reach = r * scale.max(1.0);
    if view.outside(c, reach) {
        st.frustum_culled += 1;
        return Decision::Cull;
    }
    let nrm = pl.normal(n.normal);
    // Back-facing supports add nothing a ray can reach before the front surface: the
    // normal-cone test holds for every point of the (scaled) sphere.
    if p.backface && view.backfacing(c, reach, nrm, pl.cone(n.cone)) {
        st.backface_culled += 1;
        return Decision::Cull;
    }
    // Far away, whole subtrees shrink below a pixel: an internal node whose sphere projects
    // to at most `LOD_FRACTION × pixel_error` stands for its leaves (Wald & Seidel use every
    // point; this is the level-of-detail extension the write-up suggests). It keeps the
    // splats of a scene of many instances near one per pixel and layer instead of one per
    // leaf, within `--max-nodes`. Group leaves keep descending: their subtree is a scene.
    let small = !leaf && !group && view.projected_radius(c, r) <= p.pixel_error * crate::wald::LOD_FRACTION;
    if !leaf && !small {
        return Decision::Refine;
    }
    if group {
        return Decision::Descend;
    }
    if small {
        st.internal_splats += 1;
    } else {
        st.leaf_splats += 1;
    }
    let mut color = n.color;
    if let Some(t) = pl.tint {
        color = sct_format::traverse::tint_color(color, t);
    }
    // A leaf's decoded sphere may be far wider than its patch: positions and radii are
    // quantized relative to the decoded parent, so a leaf whose parent spans a gap (a
    // subtree holding parts of two objects) decodes to at least a thirteenth of the parent's
    // radius plus the grid error (`sct_format::codec::posrad`). Its hat would spread the
    // surface over that whole sphere; the support is kept within a few patch radii instead.
    let patch = if pl.affine { (n.area * pl.area_factor(n.normal) / std::f32::consts::PI).sqrt() } else { (n.area / std::f32::consts::PI).sqrt() * pl.s };
    let r = if leaf && n.area > 0.0 { r.min(crate::wald::MAX_SUPPORT_PATCH_RATIO * patch) } else { r };
    Decision::Leaf(crate::wald::Surfel { c, n: nrm, r: r * scale, color })
}

/// The splat of a surface patch at camera-space `c` with unit normal `nrm` (normals within
/// `cone` of it), radius `s` pixels, projected to `xy`: seen at angle γ the patch projects
/// to an ellipse whose minor axis shrinks by |cos γ| (widened by the cone); a disc when it
/// faces the eye or its cone is obtuse.
pub(crate) fn surface_splat(c: [f32; 3], nrm: [f32; 3], cone: f32, s: f32, [x, y]: [f32; 2], color: [u8; 4]) -> Splat {
    if cone < std::f32::consts::FRAC_PI_2 {
        let d = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt().max(1e-30);
        let cg = ((nrm[0] * c[0] + nrm[1] * c[1] + nrm[2] * c[2]) / d).abs();
        let k = (cg + cone.sin()).min(1.0);
        if k < 0.999 {
            // Screen direction of the normal at the centre (derivative of the projection).
            let ux = nrm[0] * c[2] - c[0] * nrm[2];
            let uy = -(nrm[1] * c[2] - c[1] * nrm[2]);
            let len = (ux * ux + uy * uy).sqrt();
            if len > 1e-12 {
                // No lower bound on the minor axis: at a silhouette the surface is seen
                // edge on and any width is growth beyond the outline (a 0.6 px floor cost
                // the dragon 2 dB); the few cracks thin splats leave on grazing surfaces
                // are closed by `raster::fill_holes`.
                let minor = (s * k).min(s);
                return Splat::ellipse(x, y, c[2], s, minor, ux / len, uy / len, color);
            }
        }
    }
    Splat::disc(x, y, c[2], s, color)
}

/// True when a node's patch may hold part of an outline: not every normal of its cone faces
/// the eye from every point of its sphere (the front-facing counterpart of
/// [`View::backfacing`]).
#[inline]
fn on_silhouette(c: [f32; 3], r: f32, n: [f32; 3], cone: f32) -> bool {
    let d2 = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
    if d2 <= r * r || cone >= std::f32::consts::FRAC_PI_2 {
        return true;
    }
    let d = d2.sqrt();
    let cg = -(n[0] * c[0] + n[1] * c[1] + n[2] * c[2]) / d;
    // Every normal faces the eye when γ + cone + α < 90°, i.e. cos γ > sin(cone + α).
    let sa = (r / d).min(1.0);
    let ca = (1.0 - sa * sa).max(0.0).sqrt();
    let (sc, cc) = cone.sin_cos();
    let st = sc * ca + cc * sa;
    cg.abs() <= st || cc * ca - sc * sa <= 0.0
}

/// Output of one tree traversal.
#[derive(Default)]
pub(crate) struct TreeOut {
    pub splats: Vec<Splat>,
    /// Leaves collected for ray tracing ([`LodParams::leaves`]).
    pub surfels: Vec<crate::wald::Surfel>,
    /// Leaf numbers (breadth-first leaf order) of group-tree leaves that need their
    /// child graph node drawn.
    pub group_leaves: Vec<u64>,
    pub stats: LodStats,
}

/// Refines one tree under `pl`; `before` nodes were examined earlier in the render, and past
/// [`LodParams::max_nodes`] in all the render fails with a limit error naming
/// [`NODES_EXAMINED`], before the level that would pass it is decoded. With `group` set,
/// leaves that still need refinement are reported in `group_leaves` instead of being drawn.
#[allow(clippy::too_many_arguments)]
pub(crate) fn traverse(
    reader: &SctReader,
    cache: &TreeCache,
    pl: &Placement,
    view: &View,
    p: &LodParams,
    group: bool,
    before: u64,
    out: &mut TreeOut,
) -> Result<()> {
    traverse_from(reader, cache, pl, view, p, group, (0, 0), before, out)
}

/// [`traverse`] from node `start.1` of level `start.0` instead of the root.
#[allow(clippy::too_many_arguments)]
pub(crate) fn traverse_from(
    reader: &SctReader,
    cache: &TreeCache,
    pl: &Placement,
    view: &View,
    p: &LodParams,
    group: bool,
    start: (usize, u64),
    before: u64,
    out: &mut TreeOut,
) -> Result<()> {
    if cache.root().is_none() {
        return Ok(());
    }
    // A two-sided tree's surfaces are seen from both sides (spec §6.2): its cones bound the
    // normals up to sign, so none of its nodes is culled as back-facing.
    let two_sided = reader.trees().get(cache.tree).is_some_and(|t| t.two_sided());
    let one_sided;
    let p = if two_sided && p.backface {
        one_sided = LodParams { backface: false, ..*p };
        &one_sided
    } else {
        p
    };
    let mut frontier: Vec<u64> = vec![start.1];
    let mut d = start.0;
    while !frontier.is_empty() {
        if d >= cache.levels.len() {
            return Err(cache.malformed(reader, format!("children expected below the last level {}", d - 1)));
        }
        // Nodes that never shrink below the pixel error (identical children, or a tree used
        // thousands of times close up) would have the render examine, and keep a splat of,
        // every node: bounded here, a level at a time.
        let examined = before.saturating_add(out.stats.nodes_visited).saturating_add(frontier.len() as u64);
        if examined > p.max_nodes {
            let e = sct_format::Error::LimitExceeded { what: NODES_EXAMINED, value: examined, limit: p.max_nodes };
            return Err(Error::sct(reader.path().unwrap_or(std::path::Path::new("")), e));
        }
        // Group the sorted frontier by block.
        let mut groups: Vec<(usize, usize, usize)> = Vec::new(); // (block, start, end) in frontier
        let mut i = 0;
        while i < frontier.len() {
            let k = cache.block_of(reader, d, frontier[i])?;
            let end_node = if d == 0 {
                1
            } else {
                let e = &reader.trees()[cache.tree].blocks[cache.first_block[d] + k];
                e.first_node + e.node_count as u64
            };
            let j = i + frontier[i..].partition_point(|&n| n < end_node);
            groups.push((k, i, j));
            i = j;
        }
        let ks: Vec<usize> = groups.iter().map(|g| g.0).collect();
        cache.ensure(reader, d, &ks)?;
        let blocks: Vec<Arc<Block>> = ks.iter().map(|&k| cache.get(reader, d, k)).collect::<Result<_>>()?;
        let leaves_before = cache.leaves_before[d];
        let work = |gi: usize| -> (TreeOut, Vec<u64>) {
            let (_, a, b) = groups[gi];
            let blk = &blocks[gi];
            let mut o = TreeOut::default();
            let mut next = Vec::new();
            for &node in &frontier[a..b] {
                let local = (node - blk.first_node) as usize;
                debug_assert!(node < blk.end());
                let internal = blk.internal[local];
                match decide(&blk.nodes[local], !internal, group, pl, view, p, &mut o.stats) {
                    Decision::Cull => {}
                    Decision::Draw(s) => o.splats.push(s),
                    Decision::Leaf(s) => o.surfels.push(s),
                    Decision::Descend => {
                        let rank = blk.internal_before + blk.rank_before[local] as u64;
                        o.group_leaves.push(leaves_before + node - rank);
                    }
                    Decision::Refine => {
                        let rank = blk.internal_before + blk.rank_before[local] as u64;
                        next.push(2 * rank);
                        next.push(2 * rank + 1);
                    }
                }
            }
            (o, next)
        };
        let results: Vec<(TreeOut, Vec<u64>)> = if frontier.len() >= 8192 {
            (0..groups.len()).into_par_iter().map(work).collect()
        } else {
            (0..groups.len()).map(work).collect()
        };
        let mut next = Vec::new();
        for (o, n) in results {
            out.splats.extend_from_slice(&o.splats);
            out.surfels.extend_from_slice(&o.surfels);
            out.group_leaves.extend_from_slice(&o.group_leaves);
            out.stats.add(&o.stats);
            next.extend_from_slice(&n);
        }
        frontier = next;
        d += 1;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{on_silhouette, Placement};

    #[test]
    fn outline_nodes_are_those_whose_cone_may_turn_edge_on() {
        let c = [0.0, 0.0, 10.0];
        // Facing the eye (or, two-sided, away from it) squarely: no outline.
        assert!(!on_silhouette(c, 0.1, [0.0, 0.0, -1.0], 0.0));
        assert!(!on_silhouette(c, 0.1, [0.0, 0.0, 1.0], 0.0));
        assert!(!on_silhouette(c, 0.1, [0.0, 0.0, -1.0], 1.0));
        // Edge on, or a cone or a view cone that reaches edge on.
        assert!(on_silhouette(c, 0.1, [1.0, 0.0, 0.0], 0.0));
        let t = 1.2f32;
        assert!(on_silhouette(c, 0.1, [t.sin(), 0.0, -t.cos()], 0.4));
        assert!(!on_silhouette(c, 0.1, [t.sin(), 0.0, -t.cos()], 0.3));
        assert!(on_silhouette(c, 5.0, [t.sin(), 0.0, -t.cos()], 0.0));
        // Obtuse cones and an eye inside the sphere.
        assert!(on_silhouette(c, 0.1, [0.0, 0.0, -1.0], 1.6));
        assert!(on_silhouette(c, 11.0, [0.0, 0.0, -1.0], 0.0));
    }

    /// Under diag(4, 1, 0.25) a flat patch facing z is stretched 4× along x (its mapped area
    /// only 4×: an equal-area radius of 2×); one facing x at most 1×; a folded patch (cone
    /// ≥ 90°) σ_max = 4×. A similarity's stretch is its scale.
    #[test]
    fn patch_stretch_is_the_widest_stretch_in_the_patch_plane() {
        let affine = Placement { m: [[4.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.25]], rot: [[0.25, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 4.0]], t: [0.0; 3], s: 4.0, tint: None, affine: true, kappa: 16.0 };
        let z = [0.0, 0.0, 1.0];
        assert!((affine.patch_stretch(z, 0.0) - 4.0).abs() < 1e-5);
        assert!((affine.area_factor(z).sqrt() - 2.0).abs() < 1e-5);
        assert!((affine.patch_stretch([1.0, 0.0, 0.0], 0.0) - 1.0).abs() < 1e-5);
        assert!((affine.patch_stretch([1.0, 0.0, 0.0], 0.5) - (1.0 + 3.0 * 0.5f32.sin())).abs() < 1e-5);
        assert_eq!(affine.patch_stretch([1.0, 0.0, 0.0], 1.6), 4.0);
        let sim = Placement { affine: false, s: 2.5, kappa: 1.0, ..affine };
        assert_eq!(sim.patch_stretch(z, 0.3), 2.5);
    }
}
