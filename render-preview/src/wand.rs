//! `wand`: the randomized z-buffer of Wand et al. (TR WSI-2000-20): every frame draws fresh
//! random surface points with probability proportional to their projected area, enough of
//! them that every pixel receives one with high probability, each written as a `d × d`
//! square through a depth buffer. The randomness *is* the level of detail: nothing coarser
//! than a leaf is ever drawn.
//!
//! A tour of one frame:
//!
//! 1. **Box selection** (§6.2.1) walks the scene graph (groups, instances, tints and inlines,
//!    as the other methods do; an instance's tree is walked under its camera-space placement,
//!    which is the paper's camera transformed into the instance, §7.2) and, in each tree,
//!    stops at nodes whose depth range satisfies `z_max / z_min ≤ √ε`: within such a box the
//!    distance factor `1/z²` of the projection varies by at most ε. Nodes outside the frustum
//!    or facing away (normal cone) are dropped.
//! 2. **Counts** (§4, §5.1.1, §5.2): a box's projected area is bounded by
//!    `A · f² · cos β_max / (cos α_max · z_min²)` (its surface area, the focal length in
//!    pixels, the best orientation its normal cone allows, the image-border term, its nearest
//!    depth); it receives `m = a / d² · ln(v / d²)` samples for `v` image pixels — the
//!    occupancy rule that fills every `d × d` cell with probability near 1 — rounded at random
//!    so the expectation is exact.
//! 3. **Descent** (§6.3, the dynamic variant): each sample walks from its box to a leaf,
//!    taking a child with probability `area_child / area_node`. The `m` samples of a box go
//!    down together as sorted uniforms split at each node (the inverse-CDF form of the same
//!    choice), so a node is read once per box however many samples pass it.
//! 4. **Points**: a sample lands uniformly in the leaf's tangent disc of its area
//!    (`√(a/π)`), is back-face tested with the leaf's normal (§5.1.2: the test that stops
//!    dark backsides leaking through thin objects), shaded, projected, and written as the
//!    `d × d` pixel square around it with a depth test per pixel.
//! 5. **Large leaves** (§7.1): a leaf whose projected area exceeds `d / ln v` px² (the
//!    paper's measured optimum, §8.3, scaled by [`WandOptions::large`]) would receive about a
//!    sample or more; it is drawn once as the `zbuffer` method's splat instead, into the same
//!    depth buffer. A subtree whose every leaf is that large goes to the splat path whole.
//!
//! Randomness is counter-based ([`SplitMix64`] keyed by seed, box and sample rank), so a frame
//! depends on the seed only, never on the number of threads. Isolated unsampled pixels are
//! closed by [`raster::fill_holes`] as for `zbuffer`.
//!
//! Measured (bunny res2 as 717 k leaves of r/200, front view, against its mesh; 2 shared
//! cores): at 1280 × 720 every leaf projects above the threshold, so the default frame is the
//! leaves as splats, 32.46 dB / IoU 0.9976 in 0.28–0.45 s (`zbuffer` 32.42 / 0.9976,
//! 0.25–0.28 s); sampling every leaf (`--wand-large inf`) gives d = 1 28.69 dB / 0.9939,
//! 6.7 M samples, 1.2–1.3 s; d = 2 25.73 / 0.9886, 1.5 M samples, 0.44–0.55 s; d = 4
//! 22.49 / 0.9781, 0.34 M, 0.28–0.40 s, all from 2,502 boxes. At 384² (`zbuffer` 30.13 /
//! 0.9966): default 31.01 / 0.9969; sampled d = 1 25.45 / 0.9878 (1.25 M samples), d = 2
//! 22.27 / 0.9771 (275 k). The sampled frames lose mostly at outlines (`tests/wand_failures.rs`).
//! A 10 × 10 grid of the same bunny (iso view, 1280 × 720) is sampled by default: 2.2 M
//! samples, 12.9 per covered pixel, 3.0 s against `zbuffer`'s 0.3 s — the descents read
//! 13 M nodes, memory-bound, as the paper's dynamic variant is the slow one (§6.3).
//!
//! What it does not do: occlusion culling (the cost is linear in projected area, hidden area
//! included, §2), the filtered high-quality mode (§5.3), orientation classes (the normal cone
//! bounds `cos β` per box instead) and sampling through instances below a box (group trees
//! are refined at box selection with the LOD test; a whole child scene smaller than
//! `--pixel-error` is drawn as one splat, as `zbuffer` does).

use std::time::Instant;

use rayon::prelude::*;
use sct_format::rng::SplitMix64;
use sct_format::{Node, SctReader};

use crate::camera::View;
use crate::error::{Error, Result};
use crate::lod::{self, Cursor, Decision, LodParams, LodStats, NodeAt, Placement, TreeCache, TreeOut};
use crate::raster::{self, Frame, Splat, BAND};
use crate::scene::{Item, SceneFiles};
use crate::shade::{self, Shading};

/// The `wand` method's settings.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct WandOptions {
    /// Side of the square each sample writes, pixels (the paper's `d`; 1 is per-pixel
    /// reconstruction, 2 saves ≈ 75 % of the samples, §5.2). The method's quality knob.
    pub d: u32,
    /// Box selection's depth accuracy ε: a box's `z_max / z_min` is at most `√ε` (§6.2.1).
    pub eps: f32,
    /// Seed of the frame's random numbers.
    pub seed: u64,
    /// Multiple of the paper's large-leaf threshold `d / ln v` px² above which a leaf is
    /// drawn as a splat instead of sampled (`f32::INFINITY`: sample everything).
    pub large: f32,
    /// Multiple of the `ln(v/d²)` samples per `d × d` cell.
    pub oversample: f32,
}

impl Default for WandOptions {
    /// `d = 2` (the paper's compromise, "nearly indistinguishable" from the z-buffer on the
    /// Buddha); ε = 1.1, smaller than the paper's advice ("a relatively large value", its box
    /// selection being costly): here selection is a few thousand nodes, and smaller boxes
    /// have narrower normal cones, so the `cos β` bound tightens too. Bunny at 1280 × 720,
    /// every leaf sampled: ε = 4 / 2 / 1.2 / 1.1 / 1.05 draw 6.8 / 4.6 / 2.1 / 1.5 / 1.2 M
    /// samples from 16 / 69 / 837 / 2,502 / 8,322 boxes. The paper's large-leaf threshold
    /// and sample count.
    fn default() -> Self {
        WandOptions { d: 2, eps: 1.1, seed: 0, large: 1.0, oversample: 1.0 }
    }
}

impl WandOptions {
    /// Why the settings cannot be used, if they cannot.
    pub fn check(&self) -> std::result::Result<(), String> {
        if !(1..=MAX_D).contains(&self.d) {
            return Err(format!("wand d {} must be a square side of 1 to {MAX_D} pixels", self.d));
        }
        if !(self.eps.is_finite() && self.eps > 1.0) {
            return Err(format!("wand ε {} must be a finite number above 1 (the depth ratio of a box is at most √ε)", self.eps));
        }
        if self.large.is_nan() || self.large < 0.0 {
            return Err(format!("wand large-leaf factor {} must be ≥ 0 (inf: sample every leaf)", self.large));
        }
        if !(self.oversample.is_finite() && self.oversample > 0.0) {
            return Err(format!("wand oversampling factor {} must be a positive number", self.oversample));
        }
        Ok(())
    }
}

/// Largest square side: the paper's experiments stop at 10; squares larger than a band of
/// the rasterizer would only be slower.
pub const MAX_D: u32 = 32;

/// Counters of a `wand` frame (`wand.stats` in the JSON).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct WandStats {
    /// Nodes selected as sampling boxes (single leaves included).
    pub boxes: u64,
    /// Of those, single leaves too small for the splat path.
    pub leaf_boxes: u64,
    /// Σ of the boxes' sample counts before random rounding.
    pub expected_samples: f64,
    /// Samples drawn (each descended to a leaf).
    pub samples: u64,
    /// Samples discarded by the back-face test.
    pub backfacing: u64,
    /// Samples behind the near plane or whose square misses the image.
    pub outside: u64,
    /// `d × d` squares written (samples less the two above).
    pub squares: u64,
    /// Leaves drawn by the splat path (projected area over the threshold).
    pub leaf_splats: u64,
    /// Group leaves, group nodes and inlines drawn whole as one splat.
    pub other_splats: u64,
    /// Nodes examined by box selection (splat path included).
    pub select_nodes: u64,
    /// Node reads of the descents (once per box and node, however many samples pass).
    pub descent_nodes: u64,
    /// Samples per `d × d` cell of projected area: `ln(v/d²)` × the oversampling factor.
    pub per_cell: f64,
    /// The large-leaf threshold used, px² of projected area.
    pub large_leaf_px2: f64,
    /// Samples drawn per covered pixel.
    pub samples_per_covered_pixel: f64,
    /// Seconds: box selection (and the splat path's refinement), sampling, drawing.
    pub select_seconds: f64,
    /// Seconds drawing samples (descent, jitter, shading, projection).
    pub sample_seconds: f64,
    /// Seconds in the depth buffer (splats, squares, hole filling).
    pub draw_seconds: f64,
}

/// One node to be sampled.
struct SampleBox {
    file: usize,
    tree: usize,
    d: usize,
    i: u64,
    pl: Placement,
    /// Sample back faces too (two-sided tree or back-face culling off).
    both_sides: bool,
    count: u64,
}

/// One drawn sample: the top-left pixel of its square, its depth and colour.
#[derive(Clone, Copy, Debug)]
struct Sample {
    x0: i32,
    y0: i32,
    z: f32,
    color: [u8; 4],
}

/// Per-frame constants of box selection.
struct Ctx<'a> {
    view: &'a View,
    p: &'a LodParams,
    o: &'a WandOptions,
    /// `f² / cos α_max`: pixels² per unit area facing the eye at unit depth, at the image
    /// corner where the border term is largest (conservative everywhere).
    k_area: f32,
    /// `f²`: pixels² per unit area facing the eye at unit depth on the axis (the paper's
    /// large-triangle classes go by area and distance only).
    focal2: f32,
    /// Leaves projecting larger than this (px²) are splatted.
    large_px2: f32,
    /// Samples per px² of projected area.
    per_px2: f64,
    sqrt_eps: f32,
}

#[inline]
fn mul(m: &[[f32; 3]; 3], v: [f32; 3]) -> [f32; 3] {
    [
        m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2],
        m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
        m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2],
    ]
}

#[inline]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Upper bound of `cos β` (normal against the direction to the eye) over a node: the normal
/// cone's axis at angle γ from the eye direction of the centre, widened by the cone and by
/// the sphere's view-cone angle; with `both_sides` the normal's sign does not matter.
fn cos_beta_max(c: [f32; 3], r: f32, n: [f32; 3], cone: f32, both_sides: bool) -> f32 {
    let d = dot(c, c).sqrt();
    if d <= r || d == 0.0 {
        return 1.0;
    }
    let mut g = (-dot(n, c) / d).clamp(-1.0, 1.0).acos();
    if both_sides {
        g = g.min(std::f32::consts::PI - g);
    }
    let a = (r / d).min(1.0).asin();
    let b = (g - cone - a).max(0.0);
    if b >= std::f32::consts::FRAC_PI_2 {
        0.0
    } else {
        b.cos()
    }
}

/// A counter-based stream: the same (seed, box, rank) always gives the same numbers.
fn stream(seed: u64, bx: u64, rank: u64) -> SplitMix64 {
    let k = SplitMix64(seed ^ bx.wrapping_mul(0xD1B5_4A32_D192_ED03)).next_u64();
    SplitMix64(k ^ rank.wrapping_mul(0xA24B_AED4_963E_E407))
}

/// Draws a `wand` frame of `files` into `frame` (background, infinite depth). Returns the
/// counters, the refinement counters (box selection and splat path), the fragments written
/// and the primitives drawn (squares and splats).
pub(crate) fn render(files: &mut SceneFiles, view: &View, p: &LodParams, o: &WandOptions, frame: &mut Frame) -> Result<(WandStats, LodStats, u64, u64)> {
    o.check().map_err(Error::Invalid)?;
    let t0 = Instant::now();
    let v = (frame.width as f64 * frame.height as f64).max(1.0);
    let d2 = f64::from(o.d * o.d);
    // The occupancy rule for d × d cells: ln(cells) samples per cell, at least one.
    let per_cell = (v / d2).ln().max(1.0) * f64::from(o.oversample);
    let f = view.focal;
    let (tx, ty) = (view.width as f32 / (2.0 * f), view.height as f32 / (2.0 * f));
    let ctx = Ctx {
        view,
        p,
        o,
        k_area: f * f * (1.0 + tx * tx + ty * ty).sqrt(),
        focal2: f * f,
        large_px2: (o.large as f64 * f64::from(o.d) / v.ln().max(1.0)) as f32,
        per_px2: per_cell / d2,
        sqrt_eps: o.eps.sqrt(),
    };
    let mut st = WandStats { per_cell, large_leaf_px2: f64::from(ctx.large_px2), ..WandStats::default() };
    let mut lod = LodStats::default();
    let mut splats = Vec::new();
    let boxes = select(files, &ctx, &mut splats, &mut lod, &mut st)?;
    st.select_nodes = lod.nodes_visited;
    // Each sample costs the depth buffer d² pixels and each splat its box: bounded, as
    // the other methods bound their splats, before anything is drawn.
    let samples: u64 = boxes.iter().map(|b| b.count).sum();
    let (w, h) = (frame.width as i64, frame.height as i64);
    let splat_px = splats.iter().fold(0u64, |sum, s| {
        let [x0, x1, y0, y1] = s.bounds.map(i64::from);
        let cols = (x1.min(w - 1) - x0.max(0) + 1).max(0);
        let rows = (y1.min(h - 1) - y0.max(0) + 1).max(0);
        sum.saturating_add(cols.saturating_mul(rows) as u64)
    });
    let pixels = samples.saturating_mul(d2 as u64).saturating_add(splat_px);
    if pixels > p.max_splat_pixels {
        let e = sct_format::Error::LimitExceeded { what: lod::PIXELS_COVERED, value: pixels, limit: p.max_splat_pixels };
        return Err(Error::sct(std::path::Path::new("wand samples"), e));
    }
    let t1 = Instant::now();
    let drawn = draw_samples(files, &ctx, &boxes, &mut st)?;
    let t2 = Instant::now();
    raster::rasterize(frame, &splats);
    let square_fragments = draw_squares(frame, &drawn, o.d as i32);
    raster::fill_holes(frame);
    let t3 = Instant::now();
    let covered = frame.covered() as u64;
    st.samples_per_covered_pixel = if covered == 0 { 0.0 } else { st.samples as f64 / covered as f64 };
    st.select_seconds = (t1 - t0).as_secs_f64();
    st.sample_seconds = (t2 - t1).as_secs_f64();
    st.draw_seconds = (t3 - t2).as_secs_f64();
    let fragments = square_fragments + crate::method::count_fragments(&splats, frame.width, frame.height);
    lod.nodes_visited += st.descent_nodes;
    Ok((st, lod, fragments, st.squares + splats.len() as u64))
}

/// Box selection over the scene graph: sampling boxes in a fixed order, and the splats of
/// large leaves and of whole child scenes.
fn select(files: &mut SceneFiles, ctx: &Ctx<'_>, splats: &mut Vec<Splat>, lod: &mut LodStats, st: &mut WandStats) -> Result<Vec<SampleBox>> {
    let mut boxes = Vec::new();
    let mut stack: Vec<Item> = files.root_items()?;
    stack.reverse();
    let mut rounding = stream(ctx.o.seed, u64::MAX, 0);
    while let Some(it) = stack.pop() {
        let pl = files.item_placement(ctx.view, &it);
        let spot = files.item_spot(&it);
        if let Some(s) = spot.filter(|s| !s.group) {
            let (reader, cache) = files.tree(s.file, s.tree).ok_or_else(|| Error::Invalid(format!("graph refers to missing tree {}", s.tree)))?;
            let both_sides = cache.two_sided(reader) || !ctx.p.backface;
            let found = select_tree(reader, cache, (s.d, s.i), &pl, both_sides, ctx, splats, lod, st)?;
            for (d, i, m) in found {
                // Random rounding keeps the expected count exact for boxes of a fraction of
                // a sample (single leaves far away).
                let count = m.floor() as u64 + u64::from(rounding.next_f64() < m.fract());
                st.expected_samples += m;
                boxes.push(SampleBox { file: s.file, tree: s.tree, d, i, pl, both_sides, count });
            }
            continue;
        }
        // A group-tree node or an inline: the LOD test of the other methods (a child scene
        // below the pixel error is one splat), with the cone test only where it is valid.
        lod.nodes_visited += 1;
        check_nodes(lod, ctx.p)?;
        let n = files.item_node(&it)?;
        let leaf = match spot {
            Some(s) => {
                let (reader, cache) = files.tree(s.file, s.tree).ok_or_else(|| Error::Invalid(format!("graph refers to missing tree {}", s.tree)))?;
                !cache.node_at(reader, s.d, s.i)?.internal
            }
            None => true,
        };
        let gp = LodParams { backface: ctx.p.backface && !n.two_sided, kernel: None, ..*ctx.p };
        let mut one = LodStats::default();
        match lod::decide(&n.node, leaf, true, &pl, ctx.view, &gp, &mut one) {
            // `Leaf` only with `LodParams::leaves` (the wald method), never set here.
            Decision::Cull | Decision::Leaf(_) => {}
            Decision::Draw(s) => {
                splats.push(s);
                st.other_splats += 1;
            }
            Decision::Refine | Decision::Descend => {
                let mut kids = files.item_children(&it)?;
                kids.reverse();
                stack.extend(kids);
            }
        }
        one.nodes_visited = 0;
        lod.add(&one);
    }
    st.boxes = boxes.len() as u64;
    Ok(boxes)
}

fn check_nodes(lod: &LodStats, p: &LodParams) -> Result<()> {
    if lod.nodes_visited > p.max_nodes {
        let e = sct_format::Error::LimitExceeded { what: lod::NODES_EXAMINED, value: lod.nodes_visited, limit: p.max_nodes };
        return Err(Error::sct(std::path::Path::new("wand box selection"), e));
    }
    Ok(())
}

/// Box selection in one tree from node `start`: returns `(level, index, samples)` of each
/// box, depth first (left child first), and appends the splat path's splats.
#[allow(clippy::too_many_arguments)]
fn select_tree(
    reader: &SctReader,
    cache: &TreeCache,
    start: (usize, u64),
    pl: &Placement,
    both_sides: bool,
    ctx: &Ctx<'_>,
    splats: &mut Vec<Splat>,
    lod: &mut LodStats,
    st: &mut WandStats,
) -> Result<Vec<(usize, u64, f64)>> {
    let mut out = Vec::new();
    let Some(root) = cache.root() else { return Ok(out) };
    let view = ctx.view;
    let s2 = pl.s * pl.s;
    // Our leaves are nearly uniform in area (one voxel's piece of surface), so the mean
    // leaf says whether a node's leaves are large on screen without reading them.
    let leaves = cache.leaf_count(reader).max(1);
    let mean_leaf = root.area / leaves as f32 * if pl.affine { pl.area_factor(root.normal) } else { s2 };
    // The splat path draws leaves only: every internal node refines.
    let leaf_params = LodParams { pixel_error: f32::MIN_POSITIVE, kernel: None, backface: ctx.p.backface && !both_sides, ..*ctx.p };
    let mut stack = vec![start];
    while let Some((d, i)) = stack.pop() {
        lod.nodes_visited += 1;
        check_nodes(lod, ctx.p)?;
        let at = cache.node_at(reader, d, i)?;
        let n = at.node;
        let c = mul(&pl.m, n.center);
        let c = [c[0] + pl.t[0], c[1] + pl.t[1], c[2] + pl.t[2]];
        let r = n.radius * pl.s;
        if view.outside(c, r) {
            lod.frustum_culled += 1;
            continue;
        }
        let nrm = pl.normal(n.normal);
        let cone = pl.cone(n.cone);
        let s2 = if pl.affine { pl.area_factor(n.normal) } else { s2 };
        if !both_sides && view.backfacing(c, r, nrm, cone) {
            lod.backface_culled += 1;
            continue;
        }
        let z_min = (c[2] - r).max(view.near);
        let z_max = c[2] + r;
        let large = |area: f32, z: f32| area * ctx.focal2 / (z * z) > ctx.large_px2;
        let samples = |n: &Node| -> f64 {
            let a = n.area * s2 * ctx.k_area * cos_beta_max(c, r, nrm, cone, both_sides) / (z_min * z_min);
            f64::from(a) * ctx.per_px2
        };
        if !at.internal {
            if large(n.area * s2, z_min) {
                let mut one = LodStats::default();
                if let Decision::Draw(s) = lod::decide(&n, true, false, pl, view, &leaf_params, &mut one) {
                    splats.push(s);
                    st.leaf_splats += 1;
                }
                one.nodes_visited = 0;
                lod.add(&one);
            } else {
                st.leaf_boxes += 1;
                out.push((d, i, samples(&n)));
            }
            continue;
        }
        if large(mean_leaf, z_max) {
            // Even at the far side of the sphere a leaf gets a sample or more: the whole
            // subtree goes to the splat path, refined level by level in parallel.
            let mut t = TreeOut::default();
            lod::traverse_from(reader, cache, pl, view, &leaf_params, false, (d, i), lod.nodes_visited, &mut t)?;
            st.leaf_splats += t.stats.leaf_splats;
            splats.append(&mut t.splats);
            lod.add(&t.stats);
            // The subtree's root was counted above.
            lod.nodes_visited -= 1;
            continue;
        }
        if z_max <= ctx.sqrt_eps * z_min && !large(mean_leaf, z_min) {
            out.push((d, i, samples(&n)));
            continue;
        }
        stack.push((d + 1, at.first_child + 1));
        stack.push((d + 1, at.first_child));
    }
    Ok(out)
}

/// Per-thread counters of the sampling pass.
#[derive(Default)]
struct Tally {
    samples: u64,
    backfacing: u64,
    outside: u64,
    nodes: u64,
}

impl Tally {
    fn add(&mut self, o: &Tally) {
        self.samples += o.samples;
        self.backfacing += o.backfacing;
        self.outside += o.outside;
        self.nodes += o.nodes;
    }
}

/// Descends every box's samples to leaves and turns them into squares, boxes in parallel;
/// the output order is box order, then sample rank.
fn draw_samples(files: &SceneFiles, ctx: &Ctx<'_>, boxes: &[SampleBox], st: &mut WandStats) -> Result<Vec<Sample>> {
    let parts: Vec<Result<(Vec<Sample>, Tally)>> = boxes
        .par_iter()
        .enumerate()
        .map(|(bi, b)| {
            let (reader, cache) = files.tree(b.file, b.tree).ok_or_else(|| Error::Invalid(format!("graph refers to missing tree {}", b.tree)))?;
            let job = Job { reader, cache, ctx, b, bx: bi as u64 };
            let us = sorted_uniforms(ctx.o.seed, bi as u64, b.count as usize);
            let mut cur = Cursor::default();
            let at = cur.node_at(cache, reader, b.d, b.i)?;
            let mut out = Vec::with_capacity(us.len());
            let mut t = Tally::default();
            job.descend(&mut cur, b.d, at, &us, 0.0, 1.0, 0, &mut out, &mut t)?;
            Ok((out, t))
        })
        .collect();
    let mut all = Vec::new();
    let mut t = Tally::default();
    for part in parts {
        let (s, pt) = part?;
        all.extend_from_slice(&s);
        t.add(&pt);
    }
    st.samples = t.samples;
    st.backfacing = t.backfacing;
    st.outside = t.outside;
    st.descent_nodes = t.nodes;
    st.squares = all.len() as u64;
    Ok(all)
}

/// The sampling of one box.
struct Job<'a> {
    reader: &'a SctReader,
    cache: &'a TreeCache,
    ctx: &'a Ctx<'a>,
    b: &'a SampleBox,
    bx: u64,
}

/// `m` sorted uniforms on [0, 1) in O(m) from the stream of box `bx`: partial sums of
/// exponential spacings, normalized (the order statistics of uniforms), so no sort is needed.
fn sorted_uniforms(seed: u64, bx: u64, m: usize) -> Vec<f64> {
    let mut rng = stream(seed, bx, u64::MAX);
    let mut us = Vec::with_capacity(m);
    let mut sum = 0.0;
    for _ in 0..m {
        sum += -(1.0 - rng.next_f64()).ln();
        us.push(sum);
    }
    let total = sum - (1.0 - rng.next_f64()).ln();
    for u in &mut us {
        *u /= total;
    }
    us
}

/// Boxes with more samples than this split their descent over two threads.
const PARALLEL_SAMPLES: usize = 1 << 15;

impl Job<'_> {
    /// Takes the samples `us` (sorted, inside `[lo, hi)`, the node's share of its box's
    /// area) from node `at` of level `d` down to leaves: a child's share is proportional to
    /// its area (§6.3). `rank` is the first sample's rank in the box, its random key.
    #[allow(clippy::too_many_arguments)]
    fn descend(&self, cur: &mut Cursor, d: usize, at: NodeAt, us: &[f64], lo: f64, hi: f64, rank: u64, out: &mut Vec<Sample>, t: &mut Tally) -> Result<()> {
        if us.is_empty() {
            return Ok(());
        }
        t.nodes += 1;
        if !at.internal {
            for k in 0..us.len() {
                self.point(&at.node, rank + k as u64, out, t);
            }
            return Ok(());
        }
        let a = cur.node_at(self.cache, self.reader, d + 1, at.first_child)?;
        let b = cur.node_at(self.cache, self.reader, d + 1, at.first_child + 1)?;
        let (aa, ab) = (f64::from(a.node.area.max(0.0)), f64::from(b.node.area.max(0.0)));
        let share = if aa + ab > 0.0 && (aa + ab).is_finite() { aa / (aa + ab) } else { 0.5 };
        let mid = lo + share * (hi - lo);
        let split = us.partition_point(|&u| u < mid);
        let (left, right) = us.split_at(split);
        if us.len() > PARALLEL_SAMPLES {
            let (lo_part, hi_part) = rayon::join(
                || {
                    let (mut o, mut t, mut c) = (Vec::with_capacity(left.len()), Tally::default(), cur.clone());
                    self.descend(&mut c, d + 1, a, left, lo, mid, rank, &mut o, &mut t).map(|_| (o, t))
                },
                || {
                    let (mut o, mut t, mut c) = (Vec::with_capacity(right.len()), Tally::default(), cur.clone());
                    self.descend(&mut c, d + 1, b, right, mid, hi, rank + split as u64, &mut o, &mut t).map(|_| (o, t))
                },
            );
            let ((lo_out, lo_t), (hi_out, hi_t)) = (lo_part?, hi_part?);
            out.extend_from_slice(&lo_out);
            out.extend_from_slice(&hi_out);
            t.add(&lo_t);
            t.add(&hi_t);
            return Ok(());
        }
        self.descend(cur, d + 1, a, left, lo, mid, rank, out, t)?;
        self.descend(cur, d + 1, b, right, mid, hi, rank + split as u64, out, t)
    }

    /// One sample in `leaf`: a uniform point of its tangent disc, back-face tested, shaded
    /// and projected to the top-left pixel of its square.
    fn point(&self, leaf: &Node, rank: u64, out: &mut Vec<Sample>, t: &mut Tally) {
        t.samples += 1;
        let (ctx, pl) = (self.ctx, &self.b.pl);
        let mut rng = stream(ctx.o.seed, self.bx, rank);
        let n = leaf.normal;
        // An orthonormal tangent basis (any one: the disc is round).
        let e = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
        let t1 = [n[1] * e[2] - n[2] * e[1], n[2] * e[0] - n[0] * e[2], n[0] * e[1] - n[1] * e[0]];
        let l1 = dot(t1, t1).sqrt();
        let rho = (leaf.area.max(0.0) / std::f32::consts::PI).sqrt() * rng.next_f32().sqrt();
        let theta = std::f32::consts::TAU * rng.next_f32();
        let mut x = leaf.center;
        if l1 > 1e-12 && rho > 0.0 {
            let t1 = t1.map(|v| v / l1);
            let t2 = [n[1] * t1[2] - n[2] * t1[1], n[2] * t1[0] - n[0] * t1[2], n[0] * t1[1] - n[1] * t1[0]];
            let (s, c) = theta.sin_cos();
            for k in 0..3 {
                x[k] += rho * (c * t1[k] + s * t2[k]);
            }
        }
        let p = mul(&pl.m, x);
        let p = [p[0] + pl.t[0], p[1] + pl.t[1], p[2] + pl.t[2]];
        let nrm = mul(&pl.rot, n);
        // In camera space the eye is the origin: n · (eye − p) ≤ 0 faces away (§5.1.2).
        if !self.b.both_sides && dot(nrm, p) >= 0.0 {
            t.backfacing += 1;
            return;
        }
        if p[2] <= ctx.view.near {
            t.outside += 1;
            return;
        }
        let [sx, sy] = ctx.view.project(p);
        let half = ctx.o.d as f32 / 2.0;
        // The d × d pixels whose centres are nearest the point (its own pixel for d = 1).
        let (x0, y0) = ((sx - half + 0.5).floor(), (sy - half + 0.5).floor());
        let dd = ctx.o.d as f32;
        if !(x0 + dd > 0.0 && y0 + dd > 0.0 && x0 < ctx.view.width as f32 && y0 < ctx.view.height as f32) {
            t.outside += 1;
            return;
        }
        let mut color = leaf.color;
        if let Some(tint) = pl.tint {
            color = sct_format::traverse::tint_color(color, tint);
        }
        if ctx.p.shading == Shading::Lambert {
            let len = dot(p, p).sqrt().max(1e-30);
            color = shade::apply(color, shade::lambert(nrm, p.map(|v| -v / len)));
        }
        out.push(Sample { x0: x0 as i32, y0: y0 as i32, z: p[2], color });
    }
}

/// Writes each sample's `d × d` square through the depth buffer, bands of rows in
/// parallel; a pixel keeps the nearest sample, the earliest of equals, so the image does
/// not depend on the thread count. Returns the pixels tested.
fn draw_squares(frame: &mut Frame, samples: &[Sample], d: i32) -> u64 {
    let (w, h) = (frame.width, frame.height);
    if w == 0 || h == 0 || samples.is_empty() {
        return 0;
    }
    let nb = h.div_ceil(BAND);
    let bands = |s: &Sample| {
        let a = s.y0.max(0) as usize / BAND;
        let b = ((s.y0 + d - 1).min(h as i32 - 1)).max(0) as usize / BAND;
        a..=b
    };
    // Counting sort of sample indices by band, keeping sample order within a band.
    let mut start = vec![0usize; nb + 1];
    for s in samples {
        for b in bands(s) {
            start[b + 1] += 1;
        }
    }
    for b in 0..nb {
        start[b + 1] += start[b];
    }
    let mut fill = start.clone();
    let mut order = vec![0u32; start[nb]];
    let mut order_hi = Vec::new();
    let wide = samples.len() > u32::MAX as usize;
    if wide {
        order_hi = vec![0usize; start[nb]];
    }
    for (k, s) in samples.iter().enumerate() {
        for b in bands(s) {
            if wide {
                order_hi[fill[b]] = k;
            } else {
                order[fill[b]] = k as u32;
            }
            fill[b] += 1;
        }
    }
    let index = |j: usize| if wide { order_hi[j] } else { order[j] as usize };
    frame
        .color
        .par_chunks_mut(BAND * w)
        .zip(frame.depth.par_chunks_mut(BAND * w))
        .enumerate()
        .map(|(b, (color, depth))| {
            let rows = color.len() / w;
            let top = (b * BAND) as i32;
            let mut frags = 0u64;
            for j in start[b]..start[b + 1] {
                let s = &samples[index(j)];
                let (ya, yb) = ((s.y0 - top).max(0), (s.y0 + d - top).min(rows as i32));
                let (xa, xb) = (s.x0.max(0), (s.x0 + d).min(w as i32));
                for y in ya..yb {
                    let row = y as usize * w;
                    for x in xa..xb {
                        let i = row + x as usize;
                        frags += 1;
                        if s.z < depth[i] {
                            depth[i] = s.z;
                            color[i] = s.color;
                        }
                    }
                }
            }
            frags
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orientation_bound() {
        let c = [0.0, 0.0, 10.0];
        // Facing the eye: 1; edge on: 0 (a point sphere, a flat cone).
        assert!((cos_beta_max(c, 0.0, [0.0, 0.0, -1.0], 0.0, false) - 1.0).abs() < 1e-6);
        assert!(cos_beta_max(c, 0.0, [1.0, 0.0, 0.0], 0.0, false).abs() < 1e-6);
        // Facing away counts only two-sided.
        assert_eq!(cos_beta_max(c, 0.0, [0.0, 0.0, 1.0], 0.0, false), 0.0);
        assert!((cos_beta_max(c, 0.0, [0.0, 0.0, 1.0], 0.0, true) - 1.0).abs() < 1e-6);
        // A cone or a view cone that reaches the eye direction: 1.
        let g = 0.5f32;
        assert!((cos_beta_max(c, 0.0, [g.sin(), 0.0, -g.cos()], 0.6, false) - 1.0).abs() < 1e-6);
        assert!((cos_beta_max(c, 0.0, [g.sin(), 0.0, -g.cos()], 0.3, false) - 0.2f32.cos()).abs() < 1e-4);
    }

    #[test]
    fn sorted_uniforms_are_uniform_and_sorted() {
        let us = sorted_uniforms(7, 3, 20000);
        assert!(us.windows(2).all(|w| w[0] <= w[1]) && us[0] >= 0.0 && us[us.len() - 1] < 1.0);
        let below_quarter = us.partition_point(|&u| u < 0.25) as f64 / us.len() as f64;
        assert!((below_quarter - 0.25).abs() < 0.01, "{below_quarter}");
        assert_eq!(us, sorted_uniforms(7, 3, 20000));
        assert_ne!(us, sorted_uniforms(8, 3, 20000));
    }

    #[test]
    fn squares_keep_the_nearest_and_are_thread_independent() {
        let mut f = Frame::new(40, 40, [0; 4]);
        let s = [
            Sample { x0: 3, y0: 14, z: 2.0, color: [1, 0, 0, 255] },
            Sample { x0: 4, y0: 15, z: 1.0, color: [2, 0, 0, 255] },
            Sample { x0: 4, y0: 15, z: 1.0, color: [3, 0, 0, 255] },
            Sample { x0: -1, y0: 38, z: 1.0, color: [4, 0, 0, 255] },
        ];
        let frags = draw_squares(&mut f, &s, 2);
        assert_eq!(frags, 4 + 4 + 4 + 2);
        assert_eq!(f.color[14 * 40 + 3][0], 1);
        assert_eq!(f.color[15 * 40 + 4][0], 2, "the nearer square wins; of equals the first");
        assert_eq!(f.color[16 * 40 + 5][0], 2);
        assert_eq!(f.color[39 * 40][0], 4);
        assert_eq!(f.covered(), 4 + 3 + 2);
    }
}
