//! `wald`: one ray per pixel through the implicit surface of hat-weighted splats (Wald &
//! Seidel, "Interactive Ray Tracing of Point-based Models", 2005; Adamson & Alexa's surface).
//!
//! A short tour:
//!
//! 1. **Leaves.** The scene graph is walked with the other methods' refinement
//!    ([`SceneFiles::collect_surfels`](crate::SceneFiles)): every leaf whose support may be
//!    seen (frustum and normal-cone culling of the scaled spheres) becomes a camera-space
//!    [`Surfel`] `(p, n, r, colour)` with its instance's transform and tint applied; groups,
//!    instances and inlines are followed as for any method, and `--max-nodes` bounds the
//!    work (32 bytes a splat). A leaf's support is bounded by
//!    [`MAX_SUPPORT_PATCH_RATIO`] × its patch's equal-area radius: the decoded sphere of a
//!    leaf under a parent that spans a gap is far wider than the leaf. The paper uses every point; here an internal node whose
//!    sphere projects to at most [`LOD_FRACTION`] × `--pixel-error` stands for its leaves,
//!    so that far instances cost about a splat per pixel: `compare`'s 20 × 20 bunny grid
//!    (275 M leaves) at 512² traces 576k splats in 1.2 s and scores 16.8 dB / IoU 0.963
//!    against the mesh (zbuffer 12.9 dB / 0.894). A single model at preview sizes is all
//!    leaves.
//! 2. **Structure.** A bounding-volume hierarchy of the surfels' supports (spheres of radius
//!    leaf radius × `--wald-radius-scale`), split at the median of the longest axis down to
//!    [`LEAF_SIZE`] surfels. The scene's own sphere tree is not traced directly: instances
//!    and inlines would need the ray transformed into each use, group leaves expanded per
//!    ray and blocks decoded from many threads; one flat hierarchy in camera space serves
//!    every scene alike. On the bunny (310k splats, 384²) it builds in 0.05–0.1 s, holds
//!    17 MB and costs 21 node visits per ray (the paper's k-d tree: 41–55 traversal steps).
//!    Tracing the scene's sphere tree per ray was not measured against it. Wald's SAH k-d
//!    tree with leaf shrinking is not built (see "intervals" below for what stands in for
//!    its tight cells).
//! 3. **Surface.** Each splat weighs a point `x` with the hat `w_i = 1 − |x − p_i| / r_i`
//!    inside its sphere (paper §3.1); with `W = Σ w_i` the surface is the zero set of
//!    `F(x) = (W·x − Σ w_i p_i) · Σ w_i n_i` (EQ 1–2: `W²` times the distance to the
//!    weighted plane, the same roots and signs without a division).
//! 4. **Rays.** Pixel centres, eye at the origin, direction `(x, y, 1)` so that the ray
//!    parameter is the depth written to the frame. The hierarchy is walked front to back
//!    from a heap of node entry distances; the spheres the ray crosses give intervals
//!    `[t_in, t_out]`. Overlapping intervals form a *cluster*, complete once no unvisited
//!    node starts before its end; outside clusters `W = 0` and there is no surface.
//! 5. **Intervals.** A cluster is cut at every sphere boundary into intervals over which the
//!    same splats overlap the ray (the 1-D counterpart of a k-d cell, as tight as the
//!    supports allow). `F` is sampled at `k` evenly spaced points of each interval
//!    (`--wald-k`, ends shared), using only the cluster's splats; the first sign change is
//!    interpolated linearly (the paper's INTERSECT, §3.2.1). Wide supports make long runs
//!    whose boundaries are thinned to [`MAX_INTERVALS`], so that a ray costs samples ×
//!    splats, not splats²: radius scale 4 on the bunny at 384² traces in 5 s (20 s
//!    without), scale 1 is unchanged (33.1 dB).
//! 6. **Shading.** At the hit, the normal is `Σ w_i n_i` normalized, the colour the
//!    `w`-weighted mean of the splat colours in linear light, lit by the same Lambert
//!    headlight as every method ([`crate::shade`]). A blended alpha below 255 takes the
//!    screen door of the rasterizers and lets the ray go on behind.
//!
//! Rows are traced in parallel (rayon); every pixel depends on its ray alone, so the image
//! is the same on any number of threads. [`WaldStats`] reports the paper's per-ray counters.

use std::time::Instant;

use rayon::prelude::*;

use crate::camera::View;
use crate::raster::{alpha_passes, Frame};
use crate::shade::{self, linear_to_srgb8, srgb_to_linear_lut, Shading};

/// Internal nodes whose sphere projects to at most this fraction of `--pixel-error` (px)
/// become splats instead of their leaves: at the default 1 px, half a pixel, so what the
/// coarser splat loses is below the pixel.
pub const LOD_FRACTION: f32 = 0.5;

/// A leaf's support radius (before `--wald-radius-scale`) is at most this multiple of its
/// patch's equal-area radius `√(area / π)`. Sub-triangles of ordinary meshes have covering
/// spheres of 1.5–2 equal-area radii (2–4 once quantized) and keep them; a leaf whose sphere
/// was inflated on decoding by a parent spanning a gap does not (the `compare` pair scene,
/// bunny before the dragon: a leaf of radius 0.19 around a patch of 0.0007 drew a 30 px
/// disc; 18.97 → 35.95 dB). Measured at 384² against no bound: 8 changes neither the fuze
/// nor the CesiumMilkTruck (long sliver triangles) and gains 0.1–0.5 dB on the bunny,
/// dragon and duck; 4 costs the truck 2.2 dB (holes between slivers), 2 costs it 7 dB (the
/// earlier bound at the splat methods' 1.3 opened holes everywhere).
pub const MAX_SUPPORT_PATCH_RATIO: f32 = 8.0;

/// Surfels per leaf of the hierarchy.
pub const LEAF_SIZE: usize = 4;

/// The paper's samples per cell (§3.2.1: "a constant number of k = 4 samples").
pub const DEFAULT_K: u32 = 4;

/// Largest radius scale: each doubling quadruples the splats a ray meets, and beyond a few
/// leaf radii the surface is only a blur of the model.
pub const MAX_RADIUS_SCALE: f32 = 8.0;

/// Most intervals one cluster is cut into (see `Tracer::sample_cluster`): at the default
/// radii a cluster holds about ten splats (twenty boundaries), so only wide supports reach it.
pub const MAX_INTERVALS: usize = 32;

/// Most samples per interval (`--wald-k`): more only costs time.
pub const MAX_K: u32 = 1024;

/// The `wald` method's settings.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct WaldOptions {
    /// Support radius of a splat as a multiple of its leaf's radius (the paper uses the
    /// radii it is given, Wu & Kobbelt's hole-free optimized ones: 1).
    pub radius_scale: f32,
    /// Samples of `F` per interval, its two ends included (the paper's `k`, 4).
    pub k: u32,
}

impl Default for WaldOptions {
    fn default() -> Self {
        WaldOptions { radius_scale: 1.0, k: DEFAULT_K }
    }
}

impl WaldOptions {
    /// Checks the settings (a usage error otherwise).
    pub fn validate(&self) -> std::result::Result<(), String> {
        if !(self.radius_scale.is_finite() && self.radius_scale > 0.0 && self.radius_scale <= MAX_RADIUS_SCALE) {
            return Err(format!("wald radius scale {} must lie in (0, {MAX_RADIUS_SCALE}]", self.radius_scale));
        }
        if !(2..=MAX_K).contains(&self.k) {
            return Err(format!("wald k {} must lie in 2..={MAX_K} (samples per interval, both ends included)", self.k));
        }
        Ok(())
    }
}

/// One splat in camera space: the support sphere `(c, r)` (leaf radius × scale), the unit
/// normal and the tinted sRGB colour.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Surfel {
    /// Centre, camera space.
    pub c: [f32; 3],
    /// Unit normal, camera space.
    pub n: [f32; 3],
    /// Support radius.
    pub r: f32,
    /// sRGB colour, straight alpha (tint applied).
    pub color: [u8; 4],
}

/// Counters of a `wald` render (`wald.stats` in the JSON).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct WaldStats {
    /// Splats in the hierarchy (leaves of the scene in the view).
    pub splats: u64,
    /// Nodes of the hierarchy.
    pub bvh_nodes: u64,
    /// Bytes of the surfels and the hierarchy.
    pub memory_bytes: u64,
    /// Rays cast (one per pixel).
    pub rays: u64,
    /// Rays that found the surface.
    pub hits: u64,
    /// Hierarchy nodes popped, per ray (the paper's "traversals").
    pub nodes_per_ray: f64,
    /// Clusters of overlapping supports sampled, per ray (the paper's "intersections").
    pub clusters_per_ray: f64,
    /// Splats of the sampled clusters, per ray (the paper's "splats": 4.4–6.9 at 1 M
    /// points with its k-d tree, 5–16 without its optimizations).
    pub splats_per_ray: f64,
    /// Evaluations of `F`, per ray.
    pub samples_per_ray: f64,
    /// Splat weights computed (samples × splats overlapping the sample's interval), per ray.
    pub weights_per_ray: f64,
    /// Rays per second of the tracing phase (all threads).
    pub rays_per_second: f64,
    /// Seconds to collect the leaves (graph walk, decoding).
    pub collect_seconds: f64,
    /// Seconds to build the hierarchy.
    pub build_seconds: f64,
    /// Seconds to trace the rays.
    pub trace_seconds: f64,
}

/// A node of the hierarchy: an internal node's children are `a` and `a + 1`; a leaf
/// (`n > 0`) holds surfels `a .. a + n`.
#[derive(Clone, Copy, Debug)]
struct BNode {
    lo: [f32; 3],
    hi: [f32; 3],
    a: u32,
    n: u32,
}

/// The surfels, reordered so that each hierarchy leaf holds a contiguous run.
pub struct Bvh {
    surfels: Vec<Surfel>,
    nodes: Vec<BNode>,
}

impl Bvh {
    /// Builds the hierarchy (median splits on the longest axis of the centres' box).
    pub fn build(mut surfels: Vec<Surfel>) -> Bvh {
        let mut nodes = Vec::with_capacity(2 * surfels.len() / LEAF_SIZE + 1);
        if !surfels.is_empty() {
            nodes.push(BNode { lo: [0.0; 3], hi: [0.0; 3], a: 0, n: 0 });
            let len = surfels.len();
            build_node(&mut surfels, 0, len, 0, &mut nodes);
        }
        Bvh { surfels, nodes }
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Bytes held.
    pub fn memory_bytes(&self) -> u64 {
        (self.surfels.len() * std::mem::size_of::<Surfel>() + self.nodes.len() * std::mem::size_of::<BNode>()) as u64
    }
}

/// Fills node `at` for surfels `lo..hi` (reordering them) and its subtree.
fn build_node(s: &mut [Surfel], lo: usize, hi: usize, at: usize, nodes: &mut Vec<BNode>) {
    let mut bl = [f32::INFINITY; 3];
    let mut bh = [f32::NEG_INFINITY; 3];
    let mut cl = [f32::INFINITY; 3];
    let mut ch = [f32::NEG_INFINITY; 3];
    for x in &s[lo..hi] {
        for k in 0..3 {
            bl[k] = bl[k].min(x.c[k] - x.r);
            bh[k] = bh[k].max(x.c[k] + x.r);
            cl[k] = cl[k].min(x.c[k]);
            ch[k] = ch[k].max(x.c[k]);
        }
    }
    if hi - lo <= LEAF_SIZE {
        nodes[at] = BNode { lo: bl, hi: bh, a: lo as u32, n: (hi - lo) as u32 };
        return;
    }
    let axis = (0..3).fold(0, |b, k| if ch[k] - cl[k] > ch[b] - cl[b] { k } else { b });
    let mid = lo + (hi - lo) / 2;
    // Ties are broken by the whole centre so that the order is a function of the set.
    s[lo..hi].select_nth_unstable_by(mid - lo, |a, b| a.c[axis].total_cmp(&b.c[axis]).then_with(|| a.c.map(f32::to_bits).cmp(&b.c.map(f32::to_bits))));
    let child = nodes.len();
    nodes.push(BNode { lo: [0.0; 3], hi: [0.0; 3], a: 0, n: 0 });
    nodes.push(BNode { lo: [0.0; 3], hi: [0.0; 3], a: 0, n: 0 });
    nodes[at] = BNode { lo: bl, hi: bh, a: child as u32, n: 0 };
    build_node(s, lo, mid, child, nodes);
    build_node(s, mid, hi, child + 1, nodes);
}

/// Per-ray counters, summed over rows.
#[derive(Clone, Copy, Default)]
struct Counts {
    rays: u64,
    hits: u64,
    nodes: u64,
    clusters: u64,
    splats: u64,
    samples: u64,
    weights: u64,
}

impl Counts {
    fn add(mut self, o: Counts) -> Counts {
        self.rays += o.rays;
        self.hits += o.hits;
        self.nodes += o.nodes;
        self.clusters += o.clusters;
        self.splats += o.splats;
        self.samples += o.samples;
        self.weights += o.weights;
        self
    }
}

/// An interval of the ray inside one splat's support.
#[derive(Clone, Copy)]
struct Span {
    t0: f32,
    t1: f32,
    i: u32,
}

/// Buffers one worker reuses from ray to ray.
#[derive(Default)]
struct Scratch {
    /// Min-heap of (entry distance, node).
    heap: Vec<(f32, u32)>,
    /// Spans found and not yet sampled, sorted by `t0`.
    pending: Vec<Span>,
    /// Interval ends of the cluster being sampled.
    ends: Vec<f32>,
}

fn heap_push(h: &mut Vec<(f32, u32)>, v: (f32, u32)) {
    h.push(v);
    let mut i = h.len() - 1;
    while i > 0 {
        let p = (i - 1) / 2;
        if h[p].0 <= h[i].0 {
            break;
        }
        h.swap(p, i);
        i = p;
    }
}

fn heap_pop(h: &mut Vec<(f32, u32)>) -> Option<(f32, u32)> {
    let last = h.pop()?;
    if h.is_empty() {
        return Some(last);
    }
    let top = std::mem::replace(&mut h[0], last);
    let mut i = 0;
    loop {
        let (l, r) = (2 * i + 1, 2 * i + 2);
        let mut m = i;
        if l < h.len() && h[l].0 < h[m].0 {
            m = l;
        }
        if r < h.len() && h[r].0 < h[m].0 {
            m = r;
        }
        if m == i {
            break;
        }
        h.swap(i, m);
        i = m;
    }
    Some(top)
}

/// What a ray found.
struct Hit {
    t: f32,
    n: [f32; 3],
    /// Linear RGB and alpha (0–1).
    color: [f32; 4],
}

/// Entry and exit distances of the ray `t·d` (inverse direction `inv`) through a box.
#[inline]
fn slab(lo: &[f32; 3], hi: &[f32; 3], inv: &[f32; 3]) -> (f32, f32) {
    let mut t0 = f32::NEG_INFINITY;
    let mut t1 = f32::INFINITY;
    for k in 0..3 {
        let a = lo[k] * inv[k];
        let b = hi[k] * inv[k];
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    (t0, t1)
}

/// The sphere's interval along `t·d` (`dd = d·d`), if the ray meets it.
#[inline]
fn sphere_span(s: &Surfel, d: &[f32; 3], dd: f32) -> Option<(f32, f32)> {
    let b = d[0] * s.c[0] + d[1] * s.c[1] + d[2] * s.c[2];
    let cc = s.c[0] * s.c[0] + s.c[1] * s.c[1] + s.c[2] * s.c[2];
    // Distance² from the centre to the ray's line, computed as |c|² − (d·c)²/|d|²; the
    // half chord follows from it.
    let q = cc - b * b / dd;
    let h2 = s.r * s.r - q;
    if h2 <= 0.0 {
        return None;
    }
    let tm = b / dd;
    let h = (h2 / dd).sqrt();
    Some((tm - h, tm + h))
}

/// Settings of one frame's tracing.
struct Tracer<'a> {
    bvh: &'a Bvh,
    k: u32,
    near: f32,
    lut: &'a [f32; 256],
}

impl Tracer<'_> {
    /// Traces the ray `t·d` (`t` = depth) and returns the first surface found whose alpha
    /// passes the screen door at pixel `(x, y)`.
    fn trace(&self, d: [f32; 3], px: (usize, usize), sc: &mut Scratch, cn: &mut Counts) -> Option<Hit> {
        cn.rays += 1;
        let nodes = &self.bvh.nodes;
        if nodes.is_empty() {
            return None;
        }
        // Zero components give infinite inverses; a tiny one keeps the slab products finite.
        let inv = d.map(|v| 1.0 / if v.abs() < 1e-20 { 1e-20 } else { v });
        let dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        sc.heap.clear();
        sc.pending.clear();
        let (t0, t1) = slab(&nodes[0].lo, &nodes[0].hi, &inv);
        if t1 >= t0.max(self.near) {
            heap_push(&mut sc.heap, (t0.max(self.near), 0));
        }
        loop {
            let next = sc.heap.first().map_or(f32::INFINITY, |h| h.0);
            // The first cluster of pending spans is complete when no unvisited node starts
            // before its end: every support that overlaps it has been found.
            if let Some(first) = sc.pending.first() {
                let mut end = first.t1;
                let mut m = 1;
                while m < sc.pending.len() && sc.pending[m].t0 <= end {
                    end = end.max(sc.pending[m].t1);
                    m += 1;
                }
                if end < next {
                    if let Some(h) = self.sample_cluster(m, d, sc, cn) {
                        if alpha_passes(linear_alpha_to_u8(h.color[3]), px.0, px.1) {
                            cn.hits += 1;
                            return Some(h);
                        }
                    }
                    sc.pending.drain(..m);
                    continue;
                }
            }
            let Some((_, ni)) = heap_pop(&mut sc.heap) else { break };
            cn.nodes += 1;
            let nd = nodes[ni as usize];
            if nd.n == 0 {
                for c in [nd.a, nd.a + 1] {
                    let b = &nodes[c as usize];
                    let (t0, t1) = slab(&b.lo, &b.hi, &inv);
                    let t0 = t0.max(self.near);
                    if t1 >= t0 {
                        heap_push(&mut sc.heap, (t0, c));
                    }
                }
                continue;
            }
            for i in nd.a..nd.a + nd.n {
                let Some((t0, t1)) = sphere_span(&self.bvh.surfels[i as usize], &d, dd) else { continue };
                let t0 = t0.max(self.near);
                if t1 > t0 {
                    // Sorted insert (by t0, then index, so the order is the same on any thread).
                    let at = sc.pending.partition_point(|s| (s.t0, s.i) < (t0, i));
                    sc.pending.insert(at, Span { t0, t1, i });
                }
            }
        }
        None
    }

    /// Samples `F` over the cluster of the first `m` pending spans and returns the first
    /// root (paper §3.2.1, with the cluster cut into intervals at every span end).
    fn sample_cluster(&self, m: usize, d: [f32; 3], sc: &mut Scratch, cn: &mut Counts) -> Option<Hit> {
        let spans = &sc.pending[..m];
        cn.clusters += 1;
        cn.splats += m as u64;
        sc.ends.clear();
        for s in spans {
            sc.ends.push(s.t0);
            sc.ends.push(s.t1);
        }
        sc.ends.sort_unstable_by(f32::total_cmp);
        sc.ends.dedup();
        // Wide supports (a large radius scale) make runs of hundreds of splats, and samples
        // at every boundary would cost samples × splats ∝ m²: past MAX_INTERVALS the
        // boundaries are thinned evenly, the cluster's two ends kept.
        if sc.ends.len() > MAX_INTERVALS + 1 {
            let n = sc.ends.len() - 1;
            let mut j = 0;
            sc.ends.retain(|_| {
                let keep = j * MAX_INTERVALS % n < MAX_INTERVALS || j == n;
                j += 1;
                keep
            });
        }
        let steps = self.k - 1;
        let mut old: Option<(f32, f32)> = None; // (t, F) of the last sample with W > 0
        for w in sc.ends.windows(2) {
            let (a, b) = (w[0], w[1]);
            // The interval's first end is the previous one's last sample (or the cluster's
            // start, where W = 0).
            let first = if old.is_none() { 0 } else { 1 };
            for j in first..=steps {
                let t = if j == steps { b } else { a + (b - a) * (j as f32 / steps as f32) };
                cn.samples += 1;
                let Some(f) = self.field(spans, d, t, cn) else { continue };
                if f == 0.0 {
                    return self.hit_at(spans, d, t);
                }
                if let Some((ot, of)) = old {
                    if (of < 0.0) != (f < 0.0) {
                        let th = ot + (t - ot) * (of / (of - f));
                        return self.hit_at(spans, d, th).or_else(|| self.hit_at(spans, d, t));
                    }
                }
                old = Some((t, f));
            }
        }
        None
    }

    /// `F` at `t·d`, or `None` where no support reaches (W = 0).
    #[inline]
    fn field(&self, spans: &[Span], d: [f32; 3], t: f32, cn: &mut Counts) -> Option<f32> {
        let x = [d[0] * t, d[1] * t, d[2] * t];
        let mut wsum = 0.0f32;
        let mut dp = [0.0f32; 3]; // Σ w (x − p), i.e. W·x − Σ w p
        let mut nn = [0.0f32; 3]; // Σ w n
        for s in spans {
            // Spans are sorted by entry: none after this one reaches back to `t`.
            if s.t0 > t {
                break;
            }
            if t > s.t1 {
                continue;
            }
            cn.weights += 1;
            let sf = &self.bvh.surfels[s.i as usize];
            let v = [x[0] - sf.c[0], x[1] - sf.c[1], x[2] - sf.c[2]];
            let dist = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            let w = 1.0 - dist / sf.r;
            if w <= 0.0 {
                continue;
            }
            wsum += w;
            for k in 0..3 {
                dp[k] += w * v[k];
                nn[k] += w * sf.n[k];
            }
        }
        (wsum > 0.0).then(|| dp[0] * nn[0] + dp[1] * nn[1] + dp[2] * nn[2])
    }

    /// Normal and colour of the surface at `t·d`: the weighted means of the splats'.
    fn hit_at(&self, spans: &[Span], d: [f32; 3], t: f32) -> Option<Hit> {
        let x = [d[0] * t, d[1] * t, d[2] * t];
        let mut wsum = 0.0f32;
        let mut nn = [0.0f32; 3];
        let mut col = [0.0f32; 4];
        for s in spans {
            if s.t0 > t {
                break;
            }
            let sf = &self.bvh.surfels[s.i as usize];
            let v = [x[0] - sf.c[0], x[1] - sf.c[1], x[2] - sf.c[2]];
            let w = 1.0 - (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() / sf.r;
            if w <= 0.0 {
                continue;
            }
            wsum += w;
            for k in 0..3 {
                nn[k] += w * sf.n[k];
                col[k] += w * self.lut[sf.color[k] as usize];
            }
            col[3] += w * sf.color[3] as f32 / 255.0;
        }
        if wsum <= 0.0 {
            return None;
        }
        let l = (nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2]).sqrt();
        // Opposite normals may cancel (a thin two-sided sheet): face the eye then.
        let n = if l > 1e-12 { nn.map(|v| v / l) } else { [0.0, 0.0, -1.0] };
        Some(Hit { t, n, color: col.map(|c| c / wsum) })
    }
}

fn linear_alpha_to_u8(a: f32) -> u8 {
    (a * 255.0 + 0.5).clamp(0.0, 255.0) as u8
}

/// Traces one ray per pixel centre of `frame` through `bvh` (built in `view`'s camera
/// space), writing colour and depth; returns the per-ray counters (the timing fields and
/// the structure's are left for the caller).
pub fn trace(frame: &mut Frame, bvh: &Bvh, view: &View, opts: &WaldOptions, shading: Shading) -> WaldStats {
    let t0 = Instant::now();
    let w = frame.width;
    let tracer = Tracer { bvh, k: opts.k.clamp(2, MAX_K), near: view.near, lut: srgb_to_linear_lut() };
    let mask = reach_mask(bvh, view);
    let counts = frame
        .color
        .par_chunks_mut(w.max(1))
        .zip(frame.depth.par_chunks_mut(w.max(1)))
        .enumerate()
        .map_init(Scratch::default, |sc, (y, (crow, drow))| {
            let mut cn = Counts::default();
            let dy = -((y as f32 + 0.5) - view.cy) / view.focal;
            for (x, (c, z)) in crow.iter_mut().zip(drow.iter_mut()).enumerate() {
                if !mask[y * w + x] {
                    // No support projects onto this pixel: the ray meets nothing.
                    cn.rays += 1;
                    continue;
                }
                let d = [((x as f32 + 0.5) - view.cx) / view.focal, dy, 1.0];
                let Some(h) = tracer.trace(d, (x, y), sc, &mut cn) else { continue };
                let k = if shading == Shading::Lambert {
                    let dl = (d[0] * d[0] + d[1] * d[1] + 1.0).sqrt();
                    shade::lambert(h.n, [-d[0] / dl, -d[1] / dl, -1.0 / dl])
                } else {
                    1.0
                };
                *c = [linear_to_srgb8(h.color[0] * k), linear_to_srgb8(h.color[1] * k), linear_to_srgb8(h.color[2] * k), 255];
                *z = h.t;
            }
            cn
        })
        .reduce(Counts::default, Counts::add);
    let secs = t0.elapsed().as_secs_f64();
    let per = |v: u64| if counts.rays == 0 { 0.0 } else { v as f64 / counts.rays as f64 };
    WaldStats {
        splats: bvh.surfels.len() as u64,
        bvh_nodes: bvh.nodes.len() as u64,
        memory_bytes: bvh.memory_bytes(),
        rays: counts.rays,
        hits: counts.hits,
        nodes_per_ray: per(counts.nodes),
        clusters_per_ray: per(counts.clusters),
        splats_per_ray: per(counts.splats),
        samples_per_ray: per(counts.samples),
        weights_per_ray: per(counts.weights),
        rays_per_second: if secs > 0.0 { counts.rays as f64 / secs } else { 0.0 },
        collect_seconds: 0.0,
        build_seconds: 0.0,
        trace_seconds: secs,
    }
}

/// Pixels whose centre may see `s`'s support: its projected bounding box clipped to the
/// image, the whole image when the support reaches the eye plane.
pub(crate) fn support_pixels(s: &Surfel, view: &View) -> u64 {
    let (w, h) = (f64::from(view.width), f64::from(view.height));
    let r = view.projected_radius(s.c, s.r);
    if !r.is_finite() {
        return (w * h) as u64;
    }
    let [x, y] = view.project(s.c);
    let (r, x, y) = (f64::from(r), f64::from(x), f64::from(y));
    let cols = ((x + r).min(w) - (x - r).max(0.0)).max(0.0) + 1.0;
    let rows = ((y + r).min(h) - (y - r).max(0.0)).max(0.0) + 1.0;
    (cols.min(w) * rows.min(h)) as u64
}

/// Pixels whose ray may meet a support: the union of the supports' projected bounding
/// boxes (widened by a pixel against rounding). Most pixels of a preview are background,
/// and their rays would otherwise walk the hierarchy down to the supports they pass by.
fn reach_mask(bvh: &Bvh, view: &View) -> Vec<bool> {
    let (w, h) = (view.width as usize, view.height as usize);
    let mut mask = vec![false; w * h];
    for s in &bvh.surfels {
        let r = view.projected_radius(s.c, s.r);
        if !r.is_finite() {
            // The support reaches the eye plane: it may be met anywhere.
            mask.fill(true);
            return mask;
        }
        let [x, y] = view.project(s.c);
        let span = |c: f32, n: usize| {
            let lo = (c - r - 1.0).floor().max(0.0);
            let hi = (c + r + 1.0).ceil().min(n as f32 - 1.0);
            (lo as usize, hi as usize, hi >= lo)
        };
        let ((x0, x1, okx), (y0, y1, oky)) = (span(x, w), span(y, h));
        if okx && oky {
            for row in mask[y0 * w..=y1 * w + x1].chunks_mut(w) {
                let end = x1.min(row.len() - 1);
                if x0 <= end {
                    row[x0..=end].fill(true);
                }
            }
        }
    }
    mask
}

/// Ray–splat pairs of a traced frame (the `fragments` of [`crate::Work`]).
pub(crate) fn fragments(s: &WaldStats) -> u64 {
    (s.splats_per_ray * s.rays as f64).round() as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(n: usize, spacing: f32, z: f32) -> Vec<Surfel> {
        let mut v = Vec::new();
        for i in 0..n {
            for j in 0..n {
                let c = [(i as f32 - n as f32 / 2.0) * spacing, (j as f32 - n as f32 / 2.0) * spacing, z];
                v.push(Surfel { c, n: [0.0, 0.0, -1.0], r: spacing, color: [200, 100, 50, 255] });
            }
        }
        v
    }

    #[test]
    fn a_plane_facing_the_eye_is_hit_at_its_depth() {
        let bvh = Bvh::build(plane(20, 0.1, 5.0));
        let tr = Tracer { bvh: &bvh, k: 4, near: 1e-3, lut: srgb_to_linear_lut() };
        let mut sc = Scratch::default();
        let mut cn = Counts::default();
        let h = tr.trace([0.013, -0.021, 1.0], (0, 0), &mut sc, &mut cn).unwrap();
        assert!((h.t - 5.0).abs() < 1e-3, "{}", h.t);
        assert!((h.n[2] + 1.0).abs() < 1e-4);
        assert!((linear_to_srgb8(h.color[0]) as i32 - 200).abs() <= 1);
        // Off the plane: nothing.
        assert!(tr.trace([1.0, 0.0, 1.0], (0, 0), &mut sc, &mut cn).is_none());
        assert_eq!(cn.rays, 2);
        assert_eq!(cn.hits, 1);
    }

    #[test]
    fn the_nearer_of_two_planes_is_found() {
        let mut s = plane(10, 0.1, 3.0);
        s.extend(plane(10, 0.1, 2.0).into_iter().map(|p| Surfel { color: [10, 10, 10, 255], ..p }));
        let bvh = Bvh::build(s);
        let tr = Tracer { bvh: &bvh, k: 4, near: 1e-3, lut: srgb_to_linear_lut() };
        let h = tr.trace([0.0, 0.0, 1.0], (0, 0), &mut Scratch::default(), &mut Counts::default()).unwrap();
        assert!((h.t - 2.0).abs() < 1e-3, "{}", h.t);
    }

    #[test]
    fn wide_supports_are_sampled_within_the_interval_cap() {
        // Supports of five spacings: a ray meets about 80 of them, 160 boundaries, thinned
        // to MAX_INTERVALS; the plane is still found, at its depth.
        let bvh = Bvh::build(plane(40, 0.1, 5.0).into_iter().map(|s| Surfel { r: 0.5, ..s }).collect());
        let tr = Tracer { bvh: &bvh, k: 4, near: 1e-3, lut: srgb_to_linear_lut() };
        let mut cn = Counts::default();
        let h = tr.trace([0.013, -0.021, 1.0], (0, 0), &mut Scratch::default(), &mut cn).unwrap();
        assert!((h.t - 5.0).abs() < 1e-3, "{}", h.t);
        assert!(cn.splats > 40 && cn.samples <= (MAX_INTERVALS as u64 + 2) * 3 + 1, "{} splats, {} samples", cn.splats, cn.samples);
    }

    #[test]
    fn heap_pops_in_order() {
        let mut h = Vec::new();
        for (i, v) in [5.0, 1.0, 3.0, 2.0, 4.0, 0.5].into_iter().enumerate() {
            heap_push(&mut h, (v, i as u32));
        }
        let mut out = Vec::new();
        while let Some((v, _)) = heap_pop(&mut h) {
            out.push(v);
        }
        assert_eq!(out, vec![0.5, 1.0, 2.0, 3.0, 4.0, 5.0]);
    }

    #[test]
    fn options_are_checked() {
        assert!(WaldOptions::default().validate().is_ok());
        assert!(WaldOptions { k: 1, ..Default::default() }.validate().is_err());
        assert!(WaldOptions { radius_scale: 0.0, ..Default::default() }.validate().is_err());
        assert!(WaldOptions { radius_scale: f32::NAN, ..Default::default() }.validate().is_err());
    }
}
