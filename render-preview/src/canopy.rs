//! `canopy`: the thesis's own renderer (§3.3, §3.7, §5.4–5.8): an image graph of scene nodes
//! refined in three stages, front-to-back order from dependency counters, occlusion culling
//! by summed occluder strength × overlap, and rasterization without a depth buffer.
//!
//! 1. **Stage 1** refines from the scene's roots, depth first, until a node's view cone is at
//!    most `t1` (thresholds are the projected radius `f·tan α` in pixels of the view-cone
//!    semi-angle α = asin(r/d), EQ 20), with view-frustum and normal-cone culling.
//! 2. **Relations** join the nodes whose view cones overlap in 2D (σ < αA + αB, EQ 24). The 3D
//!    class picks the dominant node (§3.3.5): separate spheres → the smaller `d − r`, except
//!    that the farther node dominates when its tangent distance `√(d² − r²)` is smaller;
//!    contained → the container; intersecting → the nearer centre, ties by the lower index
//!    (§3.3.6); a node containing the eye dominates everything it overlaps (Null_2D).
//! 3. **Stage 2**: each node counts its dominant partners not yet in the occlusion mask M; a
//!    node whose count is 0 is taken (last in, first out). If its occlusion estimate exceeds
//!    `t_OccCull` it is culled; else if its cone is at most `t2` (or it is a leaf) it is
//!    committed to M; else it is replaced by its children, whose relations are rebuilt
//!    against the parent's partners. Committing adds `OccStrength(n) · OccRatio(p, n)` to each
//!    occludee `p` over a separate relation (EQ 28–30, 41; intersecting relations add nothing,
//!    containment occludes outright); occluders weaker than `t_OccClip` add nothing (§5.7.1).
//! 4. **Stage 3** refines each node of M depth first to `t3` with the LOD test on its sphere;
//!    **stage 4** draws the sets in reverse M order, back to front, as the conservative EQ 46
//!    discs, later discs overwriting earlier ones (no depth buffer); `zbuffer` draws the same
//!    discs through the depth buffer instead, for comparison. Inside each set the order is the
//!    tree's level order, the same every frame.
//!
//! Closed forms and tables: `OccRatio` is the closed-form area of the lens where two circles of
//! radii αA, αB at distance σ overlap, divided by π αA² (exact for small cones, where the
//! thesis's stochastic table approximates the same quantity); `PVA(i, ω)` — the mean of
//! max(0, V̂·l) over normals l uniform on the cone of half-angle i at angle ω from V̂ (EQ 31–39)
//! — is a 64 × 64 table over [0, π]² filled once per process with 1,024 stratified samples per
//! entry and interpolated bilinearly. Plane-bit inheritance (EQ 27) and the front-facing
//! shortcut are optimisations left out: every node is tested against all planes.

use std::sync::OnceLock;
use std::time::Instant;

use crate::camera::View;
use crate::error::Result;
use crate::lod::{LodParams, LodStats};
use crate::raster::{self, Frame, Splat};
use crate::scene::{Item, SceneFiles};
use crate::LodSize;

/// The `canopy` method's settings (thresholds in pixels of projected view-cone radius).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct CanopyOptions {
    /// Stage 1 threshold (no occlusion culling above it).
    pub t1: f32,
    /// Stage 2 threshold: the occlusion mask's level of detail.
    pub t2: f32,
    /// Stage 3 threshold: the drawn discs' level of detail (the method's quality knob).
    pub t3: f32,
    /// Occlusion estimate above which a node is culled (`f32::INFINITY`: no culling).
    pub occ_cull: f32,
    /// Occluders weaker than this add nothing.
    pub occ_clip: f32,
    /// Draw the stage-3 discs through a depth buffer instead of in reverse mask order.
    pub zbuffer: bool,
}

/// Focal length of the default camera (720 px high, 40° vertical field of view).
const DEFAULT_FOCAL: f64 = 360.0 / 0.363_970_234_266_202_4;

/// Thesis chapter-6 angle `deg` as a projected radius for the default camera.
fn px(deg: f64) -> f32 {
    (DEFAULT_FOCAL * deg.to_radians().tan()) as f32
}

impl Default for CanopyOptions {
    /// Chapter 6: t1 = 2.5°, t2 = 1.0°, t3 = 0.1° (43.2, 17.3 and 1.73 px at the default
    /// camera), t_OccCull = 1.9, t_OccClip = 0.
    fn default() -> Self {
        CanopyOptions { t1: px(2.5), t2: px(1.0), t3: px(0.1), occ_cull: 1.9, occ_clip: 0.0, zbuffer: false }
    }
}

/// Relations formed, by 3D class.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Relations {
    /// separate_3d.
    pub separate: u64,
    /// intersecting_3d (and the viewpoint-containing Null_2D ones).
    pub intersecting: u64,
    /// contained_3d.
    pub contained: u64,
}

/// The thesis's Table 14 columns for one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct CanopyStats {
    /// Seconds per stage (stage 2 includes relation building for stage 1's nodes).
    pub stage_seconds: [f64; 4],
    /// Image nodes after stage 1.
    pub nodes_stage1: u64,
    /// Image nodes in the occlusion mask after stage 2.
    pub nodes_stage2: u64,
    /// Discs rasterized.
    pub nodes_rasterized: u64,
    /// Relations formed.
    pub relations: Relations,
    /// Nodes culled as occluded.
    pub occluded: u64,
    /// Image nodes culled by the view frustum (stages 1–2).
    pub frustum_culled: u64,
    /// Image nodes culled as back-facing (stages 1–2).
    pub backface_culled: u64,
    /// Times stage 2 found every waiting node waiting on another (a dependency cycle) and
    /// took the one with the fewest unfinished dominators, nearest first.
    pub cycles_broken: u64,
    /// With the discs drawn through a depth buffer (`zbuffer`): mask nodes none of whose
    /// discs is in front at any pixel, and their discs. What a perfect occlusion culling at
    /// the mask's level of detail could remove (0 in the painter's order, which cannot tell).
    pub hidden_mask_nodes: u64,
    /// Discs of [`CanopyStats::hidden_mask_nodes`].
    pub hidden_rasterized: u64,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum St {
    Pending,
    InM,
    Culled,
    Refined,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Class {
    Sep,
    Inter,
    Cont,
}

struct INode {
    item: Item,
    r: f32,
    /// Unit direction from the eye to the centre, and the distance.
    v: [f32; 3],
    d: f32,
    alpha: f32,
    size: f32,
    inside: bool,
    refinable: bool,
    /// Area over π r², times the PVA at this view: the occluder strength (EQ 40).
    strength: f32,
    st: St,
    counter: u32,
    occ: f32,
    /// (partner, class, this node dominates).
    rel: Vec<(u32, Class, bool)>,
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `PVA(i, ω)` by table (see the module documentation).
fn pva(i: f32, w: f32) -> f32 {
    const N: usize = 64;
    static T: OnceLock<Vec<f32>> = OnceLock::new();
    let t = T.get_or_init(|| {
        let pi = std::f64::consts::PI;
        let mut t = vec![0f32; N * N];
        let s = 32usize; // 32 × 32 stratified samples per entry
        let cos_phi: Vec<f64> = (0..s).map(|q| (2.0 * pi * (q as f64 + 0.5) / s as f64).cos()).collect();
        for a in 0..N {
            let cone = pi * a as f64 / (N - 1) as f64;
            for b in 0..N {
                let om = pi * b as f64 / (N - 1) as f64;
                let v = [om.sin(), 0.0, om.cos()];
                let mut sum = 0.0;
                for p in 0..s {
                    // cos θ uniform on [cos cone, 1] (uniform on the cap, EQ 38), φ uniform.
                    let ct = 1.0 - (1.0 - cone.cos()) * (p as f64 + 0.5) / s as f64;
                    let st = (1.0 - ct * ct).max(0.0).sqrt();
                    for cp in &cos_phi {
                        sum += (v[0] * st * cp + v[2] * ct).max(0.0);
                    }
                }
                t[a * N + b] = (sum / (s * s) as f64) as f32;
            }
        }
        t
    });
    let f = |x: f32| (x.clamp(0.0, std::f32::consts::PI) / std::f32::consts::PI * (N - 1) as f32).min((N - 1) as f32 - 1e-4);
    let (x, y) = (f(i), f(w));
    let (xi, yi) = (x as usize, y as usize);
    let (fx, fy) = (x - xi as f32, y - yi as f32);
    let g = |a: usize, b: usize| t[a * N + b];
    let top = g(xi, yi) * (1.0 - fy) + g(xi, yi + 1) * fy;
    let bot = g(xi + 1, yi) * (1.0 - fy) + g(xi + 1, yi + 1) * fy;
    top * (1.0 - fx) + bot * fx
}

/// The fraction of a circle of radius `a` covered by one of radius `b` at distance `s`.
pub fn occ_ratio(a: f32, b: f32, s: f32) -> f32 {
    if a <= 0.0 {
        return 0.0;
    }
    if s >= a + b {
        return 0.0;
    }
    if s <= (a - b).abs() {
        return (b.min(a) / a).powi(2);
    }
    let (a2, b2, s2) = (a * a, b * b, s * s);
    let ca = ((s2 + a2 - b2) / (2.0 * s * a)).clamp(-1.0, 1.0).acos();
    let cb = ((s2 + b2 - a2) / (2.0 * s * b)).clamp(-1.0, 1.0).acos();
    let k = ((-s + a + b) * (s + a - b) * (s - a + b) * (s + a + b)).max(0.0).sqrt();
    ((a2 * ca + b2 * cb - 0.5 * k) / (std::f32::consts::PI * a2)).clamp(0.0, 1.0)
}

struct Graph<'a> {
    files: &'a mut SceneFiles,
    view: &'a View,
    backface: bool,
    nodes: Vec<INode>,
    stats: CanopyStats,
    /// Relations linked so far (checked against [`MAX_RELATIONS`]).
    links: u64,
}

impl Graph<'_> {
    /// The image node of `it`, or `None` when it is culled by the frustum or its cone.
    fn image(&mut self, it: Item) -> Result<Option<INode>> {
        let n = self.files.item_node(&it)?;
        let pl = self.files.item_placement(self.view, &it);
        let m = |v: [f32; 3], r: &[[f32; 3]; 3]| [dot(r[0], v), dot(r[1], v), dot(r[2], v)];
        let c = m(n.node.center, &pl.m);
        let c = [c[0] + pl.t[0], c[1] + pl.t[1], c[2] + pl.t[2]];
        let r = n.node.radius * pl.s;
        if self.view.outside(c, r) {
            self.stats.frustum_culled += 1;
            return Ok(None);
        }
        let nrm = pl.normal(n.node.normal);
        let cone = pl.cone(n.node.cone);
        if self.backface && !n.two_sided && self.view.backfacing(c, r, nrm, cone) {
            self.stats.backface_culled += 1;
            return Ok(None);
        }
        let d = dot(c, c).sqrt().max(1e-30);
        let inside = d <= r;
        let alpha = if inside { std::f32::consts::FRAC_PI_2 } else { (r / d).asin() };
        let size = if inside || c[2] <= self.view.near { f32::INFINITY } else { self.view.focal * alpha.tan() };
        let v = c.map(|x| x / d);
        // ω: angle between the normal-cone axis and the direction to the eye (−v).
        let mut cw = -dot(nrm, v);
        if n.two_sided {
            cw = cw.abs();
        }
        let area = n.node.area * pl.area_factor(n.node.normal);
        let strength = if r > 0.0 && area.is_finite() { (area * pva(cone, cw.clamp(-1.0, 1.0).acos()) / (std::f32::consts::PI * r * r)).min(1.0) } else { 0.0 };
        Ok(Some(INode { item: it, r, v, d, alpha, size, inside, refinable: n.refinable, strength, st: St::Pending, counter: 0, occ: 0.0, rel: Vec::new() }))
    }

    /// The relation of nodes `a` and `b` if their view cones overlap: class and whether `a`
    /// dominates.
    fn relate(&self, a: u32, b: u32) -> Option<(Class, bool)> {
        let (x, y) = (&self.nodes[a as usize], &self.nodes[b as usize]);
        if x.inside || y.inside {
            let a_dom = if x.inside && y.inside { (x.d, a) < (y.d, b) } else { x.inside };
            return Some((Class::Inter, a_dom));
        }
        let sigma = dot(x.v, y.v).clamp(-1.0, 1.0).acos();
        if sigma >= x.alpha + y.alpha {
            return None;
        }
        let cx = x.v.map(|t| t * x.d);
        let cy = y.v.map(|t| t * y.d);
        let dd = (0..3).map(|k| (cx[k] - cy[k]).powi(2)).sum::<f32>();
        if dd > (x.r + y.r).powi(2) {
            // The smaller d − r, unless the farther node's tangent distance is smaller.
            let (kx, ky) = (x.d - x.r, y.d - y.r);
            let (tx, ty) = ((x.d * x.d - x.r * x.r).max(0.0).sqrt(), (y.d * y.d - y.r * y.r).max(0.0).sqrt());
            let a_near = (kx, a) < (ky, b);
            let a_dom = if a_near { tx <= ty } else { tx < ty };
            Some((Class::Sep, a_dom))
        } else if dd < (x.r - y.r).powi(2) {
            Some((Class::Cont, x.r > y.r || (x.r == y.r && a < b)))
        } else {
            Some((Class::Inter, (x.d, a) < (y.d, b)))
        }
    }

    fn link(&mut self, a: u32, b: u32, class: Class, a_dom: bool) {
        match class {
            Class::Sep => self.stats.relations.separate += 1,
            Class::Inter => self.stats.relations.intersecting += 1,
            Class::Cont => self.stats.relations.contained += 1,
        }
        self.links += 1;
        self.nodes[a as usize].rel.push((b, class, a_dom));
        self.nodes[b as usize].rel.push((a, class, !a_dom));
    }

    /// Occlusion that committed occluder `o` adds to occludee `p`.
    fn contribution(&self, p: u32, o: u32, class: Class, clip: f32) -> f32 {
        let (x, y) = (&self.nodes[p as usize], &self.nodes[o as usize]);
        match class {
            Class::Cont => f32::INFINITY,
            Class::Inter => 0.0,
            Class::Sep if y.strength < clip => 0.0,
            Class::Sep => y.strength * occ_ratio(x.alpha, y.alpha, dot(x.v, y.v).clamp(-1.0, 1.0).acos()),
        }
    }
}

/// Most image nodes in stages 1–2 (the thesis's frames hold a few thousand; Table 14).
pub const MAX_IMAGE_NODES: usize = 1 << 18;

/// Most relations the image graph may hold (each costs two 8-byte entries), and most
/// candidate pairs tested for them (8 bytes each): about 0.5 GB at most together. Real
/// scenes at the default thresholds form 0.5–1.7 M relations; a file of identical nodes
/// relates every pair (the candidates of 2^21 nodes in one place are 2^41).
pub const MAX_RELATIONS: u64 = 1 << 24;

fn too_big(o: &CanopyOptions) -> crate::Error {
    crate::Error::Invalid(format!(
        "canopy's image graph exceeds {MAX_IMAGE_NODES} nodes or {MAX_RELATIONS} relations (or as many candidate pairs) at t1 {} px, t2 {} px: raise --canopy-t1 / --canopy-t2",
        o.t1,
        o.t2
    ))
}

/// Stage 1 to 4 for one frame: draws into `frame` and returns the counters.
/// What stage 4 draws the mask's sets with.
pub(crate) enum Draw<'a> {
    /// EQ 46 discs cut at `t3` (the `canopy` method).
    Discs,
    /// `gauss` kernels of the LOD cut of `p` (the `gauss` method in mask order), composited
    /// in reverse mask order.
    Gauss(&'a crate::gauss::GaussOptions),
}

pub(crate) fn render(files: &mut SceneFiles, view: &View, p: &LodParams, o: &CanopyOptions, draw: Draw<'_>, frame: &mut Frame) -> Result<(CanopyStats, LodStats, u64)> {
    let t0 = Instant::now();
    let mut g = Graph { files, view, backface: p.backface, nodes: Vec::new(), stats: CanopyStats::default(), links: 0 };
    // Stage 1.
    let mut stack: Vec<Item> = g.files.root_items()?;
    stack.reverse();
    while let Some(it) = stack.pop() {
        if g.nodes.len() + stack.len() > MAX_IMAGE_NODES {
            return Err(too_big(o));
        }
        let Some(n) = g.image(it)? else { continue };
        if n.refinable && n.size > o.t1 {
            let mut ch = g.files.item_children(&n.item)?;
            ch.reverse();
            stack.extend(ch);
        } else {
            g.nodes.push(n);
        }
    }
    g.stats.nodes_stage1 = g.nodes.len() as u64;
    let t1 = Instant::now();
    // Relations among stage 1's nodes: candidates from a screen grid of their EQ 46 discs.
    let cell = 64.0f32;
    let (gw, gh) = ((view.width as f32 / cell).ceil() as usize + 1, (view.height as f32 / cell).ceil() as usize + 1);
    let mut grid: Vec<Vec<u32>> = vec![Vec::new(); gw * gh];
    let mut everywhere = Vec::new();
    for (i, n) in g.nodes.iter().enumerate() {
        let c = n.v.map(|t| t * n.d);
        let rad = view.projected_radius(c, n.r);
        if !rad.is_finite() || n.inside || c[2] <= view.near {
            everywhere.push(i as u32);
            continue;
        }
        let [x, y] = view.project(c);
        let cl = |v: f32, hi: usize| ((v / cell).floor().max(0.0) as usize).min(hi - 1);
        for gy in cl(y - rad, gh)..=cl(y + rad, gh) {
            for gx in cl(x - rad, gw)..=cl(x + rad, gw) {
                grid[gy * gw + gx].push(i as u32);
            }
        }
    }
    // Counted before they are listed: nodes piled in one place make every pair a candidate.
    let n1 = g.nodes.len() as u32;
    let candidates = grid.iter().map(|c| (c.len() as u64) * (c.len() as u64).saturating_sub(1) / 2).sum::<u64>() + everywhere.len() as u64 * u64::from(n1);
    if candidates > MAX_RELATIONS {
        return Err(too_big(o));
    }
    let mut pairs: Vec<(u32, u32)> = Vec::with_capacity(candidates as usize);
    for c in &grid {
        for (k, &a) in c.iter().enumerate() {
            for &b in &c[k + 1..] {
                pairs.push((a.min(b), a.max(b)));
            }
        }
    }
    for &e in &everywhere {
        for b in 0..n1 {
            if b != e {
                pairs.push((e.min(b), e.max(b)));
            }
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    for (a, b) in pairs {
        if let Some((class, a_dom)) = g.relate(a, b) {
            g.link(a, b, class, a_dom);
            let occludee = if a_dom { b } else { a };
            g.nodes[occludee as usize].counter += 1;
        }
    }
    // Stage 2.
    let mut u: Vec<u32> = (0..n1).rev().filter(|&i| g.nodes[i as usize].counter == 0).collect();
    let mut mask: Vec<u32> = Vec::new();
    loop {
        let cycles_before = g.stats.cycles_broken;
        let n = match u.pop() {
            Some(n) => n,
            None => {
                // Every waiting node waits on another: the classes' dominance rules formed a
                // cycle. Break it at the waiting node with the fewest dominators, nearest first.
                let next = (0..g.nodes.len() as u32)
                    .filter(|&i| g.nodes[i as usize].st == St::Pending)
                    .min_by(|&a, &b| {
                        let (x, y) = (&g.nodes[a as usize], &g.nodes[b as usize]);
                        (x.counter, x.d - x.r, a).partial_cmp(&(y.counter, y.d - y.r, b)).unwrap_or(std::cmp::Ordering::Equal)
                    });
                match next {
                    Some(n) => {
                        g.stats.cycles_broken += 1;
                        n
                    }
                    None => break,
                }
            }
        };
        // A node pushed when its count was 0 may have gained a dominator since (a partner's
        // child); it is pushed again when that one is done.
        if g.nodes[n as usize].st != St::Pending || (g.nodes[n as usize].counter != 0 && g.stats.cycles_broken == cycles_before) {
            continue;
        }
        let node = &g.nodes[n as usize];
        let rel = node.rel.clone();
        if node.occ > o.occ_cull {
            g.nodes[n as usize].st = St::Culled;
            g.stats.occluded += 1;
            release(&mut g, &rel, &mut u, None, o);
        } else if !node.refinable || node.size <= o.t2 {
            g.nodes[n as usize].st = St::InM;
            mask.push(n);
            release(&mut g, &rel, &mut u, Some(n), o);
        } else {
            g.nodes[n as usize].st = St::Refined;
            if g.nodes.len() > MAX_IMAGE_NODES {
                return Err(too_big(o));
            }
            let item = g.nodes[n as usize].item.clone();
            let mut kids = Vec::new();
            for it in g.files.item_children(&item)? {
                if let Some(c) = g.image(it)? {
                    g.nodes.push(c);
                    kids.push((g.nodes.len() - 1) as u32);
                }
            }
            let live: Vec<(u32, Class, bool)> = rel.iter().copied().filter(|&(q, _, _)| matches!(g.nodes[q as usize].st, St::Pending | St::InM)).collect();
            for (k, &c) in kids.iter().enumerate() {
                let partners = live.iter().map(|&(q, _, _)| q).chain(kids[..k].iter().copied());
                for q in partners.collect::<Vec<_>>() {
                    let Some((class, c_dom)) = g.relate(c, q) else { continue };
                    if g.links >= MAX_RELATIONS {
                        return Err(too_big(o));
                    }
                    g.link(c, q, class, c_dom);
                    match (c_dom, g.nodes[q as usize].st) {
                        (false, St::InM) => {
                            let add = g.contribution(c, q, class, o.occ_clip);
                            g.nodes[c as usize].occ += add;
                        }
                        (false, _) => g.nodes[c as usize].counter += 1,
                        (true, St::Pending) => g.nodes[q as usize].counter += 1,
                        (true, _) => {}
                    }
                }
            }
            // The parent no longer holds back its occludees.
            for &(q, _, dom) in &live {
                if dom && g.nodes[q as usize].st == St::Pending {
                    let c = &mut g.nodes[q as usize].counter;
                    *c = c.saturating_sub(1);
                    if *c == 0 {
                        u.push(q);
                    }
                }
            }
            for &c in kids.iter().rev() {
                if g.nodes[c as usize].counter == 0 {
                    u.push(c);
                }
            }
        }
    }
    g.stats.nodes_stage2 = mask.len() as u64;
    let t2 = Instant::now();
    // Stage 3: each mask node refined to t3 with EQ 46 discs of its nodes' spheres (or to the
    // kernels' LOD cut).
    let p3 = match draw {
        Draw::Discs => LodParams { pixel_error: o.t3, lod_size: LodSize::Sphere, ellipses: false, area_cover: f32::INFINITY, outline_refine: 1.0, kernel: None, ..*p },
        Draw::Gauss(_) => *p,
    };
    let mut lod = LodStats::default();
    let mut sets: Vec<Vec<Splat>> = Vec::with_capacity(mask.len());
    for &m in &mask {
        let mut s = Vec::new();
        let item = g.nodes[m as usize].item.clone();
        g.files.refine_item(&item, view, &p3, &mut s, &mut lod)?;
        sets.push(s);
    }
    let sizes: Vec<usize> = sets.iter().rev().map(Vec::len).collect();
    let splats: Vec<Splat> = sets.into_iter().rev().flatten().collect();
    g.stats.nodes_rasterized = splats.len() as u64;
    let t3 = Instant::now();
    // Stage 4.
    let fragments = match draw {
        Draw::Gauss(go) => {
            let order: Vec<u32> = (0..splats.len() as u32).collect();
            crate::gauss::composite(frame, &splats, &order, go, view.focal).fragments
        }
        Draw::Discs => {
            if o.zbuffer {
                raster::rasterize(frame, &splats);
                let (n, d) = hidden_sets(frame, &splats, &sizes);
                g.stats.hidden_mask_nodes = n;
                g.stats.hidden_rasterized = d;
            } else {
                paint(frame, &splats);
            }
            raster::fill_holes(frame);
            crate::method::count_fragments(&splats, frame.width, frame.height)
        }
    };
    let t4 = Instant::now();
    g.stats.stage_seconds = [(t1 - t0).as_secs_f64(), (t2 - t1).as_secs_f64(), (t3 - t2).as_secs_f64(), (t4 - t3).as_secs_f64()];
    lod.nodes_visited += g.nodes.len() as u64;
    Ok((g.stats, lod, fragments))
}

/// Takes a culled or committed node out of its occludees' counts; a committed one
/// (`occluder`) adds its occlusion to them.
fn release(g: &mut Graph<'_>, rel: &[(u32, Class, bool)], u: &mut Vec<u32>, occluder: Option<u32>, o: &CanopyOptions) {
    for &(q, class, dom) in rel {
        if !dom || g.nodes[q as usize].st != St::Pending {
            continue;
        }
        if let Some(m) = occluder {
            let add = g.contribution(q, m, class, o.occ_clip);
            g.nodes[q as usize].occ += add;
        }
        let c = &mut g.nodes[q as usize].counter;
        *c = c.saturating_sub(1);
        if *c == 0 {
            u.push(q);
        }
    }
}

/// Of `splats` cut into consecutive sets of `sizes`, after a depth-buffered draw into
/// `frame`: the sets none of whose splats holds the depth at any pixel, and their splats.
fn hidden_sets(frame: &Frame, splats: &[Splat], sizes: &[usize]) -> (u64, u64) {
    let (w, h) = (frame.width, frame.height);
    let (mut sets, mut discs, mut at) = (0u64, 0u64, 0usize);
    for &n in sizes {
        let set = &splats[at..at + n];
        at += n;
        let mut seen = false;
        for s in set {
            s.for_each_pixel(w, h, |i| seen |= frame.depth[i] == s.z);
            if seen {
                break;
            }
        }
        if !seen {
            sets += 1;
            discs += n as u64;
        }
    }
    (sets, discs)
}

/// Opaque splats in the given order, each overwriting what is under it (no depth test).
fn paint(frame: &mut Frame, splats: &[Splat]) {
    let (w, h) = (frame.width, frame.height);
    for s in splats {
        s.for_each_pixel(w, h, |i| {
            frame.color[i] = s.color;
            frame.depth[i] = s.z;
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lens_ratio_limits() {
        assert_eq!(occ_ratio(1.0, 1.0, 2.5), 0.0);
        assert!((occ_ratio(1.0, 3.0, 0.5) - 1.0).abs() < 1e-6);
        assert!((occ_ratio(2.0, 1.0, 0.2) - 0.25).abs() < 1e-6);
        // Two unit circles one radius apart: lens area 2π/3 − √3/2 over π.
        let want = (2.0 * std::f32::consts::PI / 3.0 - 3f32.sqrt() / 2.0) / std::f32::consts::PI;
        assert!((occ_ratio(1.0, 1.0, 1.0) - want).abs() < 1e-4);
    }

    #[test]
    fn pva_matches_the_disc_and_sphere_cases() {
        // A flat disc facing the eye: cos 0 = 1; edge on: 0; a full sphere of normals: ¼.
        assert!((pva(0.0, 0.0) - 1.0).abs() < 1e-3);
        assert!(pva(0.0, std::f32::consts::FRAC_PI_2).abs() < 2e-2);
        assert!((pva(std::f32::consts::PI, 1.0) - 0.25).abs() < 1e-2);
    }

    #[test]
    fn defaults_are_chapter_six_in_pixels() {
        let o = CanopyOptions::default();
        assert!((o.t1 - 43.2).abs() < 0.1 && (o.t2 - 17.3).abs() < 0.1 && (o.t3 - 1.73).abs() < 0.01, "{o:?}");
    }
}
