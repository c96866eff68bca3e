//! `parilov`: multi-view visibility orderings (Parilov & Stuerzlinger; preview-methods.md D).
//!
//! Point samples on one side of a plane Π, drawn in order of non-increasing distance from Π,
//! occlude each other correctly for every eye on the other side; so a frame needs no depth
//! buffer, only orders. The scene is drawn in **cells**, visited back to front: a cell is a
//! tree node whose samples — its descendants [`CELL_LEVELS`] levels down, each standing for
//! about 2^-8 of its area — are at most `--pixel-error` pixels wide. Each cell's samples are
//! streamed in a stored order, one pixel each, painter style. A cell is drawn from the
//! fewest levels down at which its samples are that narrow (the paper's "node has sufficient
//! LOD"): [`CELL_LEVELS`] or a level less for a cell reached by refining, fewer for a tree
//! already that small at its root, down to the root alone (see "Far instances" below). A cell keeps its order from
//! frame to frame (in a [`SceneFiles`] reused across frames) while the view vector to it
//! stays within `--parilov-threshold` of the order's axis (45° guarantees no artifact, 70° is
//! the paper's practical setting); else its samples are re-sorted along the tree axis most
//! parallel to the view vector. Re-sorted cells per frame are counted (the paper's Table 4:
//! 2.5–6.5 % on a 2° fly-around; here 3.2 % at 70°, 8.0 % at 45° on the bunny).
//!
//! Choices, where SCT differs from the paper's octree:
//! - **Split planes are recomputed, not stored.** Our trees split a node's sample centres
//!   by an axis-aligned plane of its tree frame, but SCT does not record it. Two siblings are
//!   ordered by the plane through the midpoint of their centres, normal to the tree axis
//!   along which the centres lie farthest apart (the split axis). It matches the real split
//!   except when the eye lies between the two planes, i.e. very close to a split.
//! - **Cells are subtrees** with a fixed depth of samples below them (the paper's octree
//!   nodes hold a fixed 16³ sample grid), so a cell's samples do not change with the view
//!   and its order is a permutation kept with its axis.
//! - **Sorting** is linear, as the paper's: a counting sort of the samples' coordinates along
//!   the axis, quantized to 16 bits over the cell (the paper's 4-bit grid coordinate is a
//!   property of its sample grid, which SCT cells do not have).
//! - **Close-ups:** a sample wider than the footprint is replaced by "virtual children", one
//!   per pixel its splat covers, at its depth (the paper replicates samples into temporary
//!   octree children). Such cells are sorted again every frame along their kept axis
//!   (`cells_recut`). Wide samples reach across their cell's split plane, which breaks the
//!   order between cells: the paper's own "non-infinitesimal primitives" failure (tested).
//! - **Affine instances** (SCT 1.3): a cell's samples are sized by the most the matrix
//!   stretches them, not by their mapped area, and wide samples are drawn as the matrix's
//!   image of their disc (see `lod::Placement::patch_stretch`); sized by area, cells of
//!   stretched boxes held samples wider than the footprint whose virtual children spilled
//!   over every edge (SimpleInstancing −2.4 dB against baked copies; now −0.1 dB).
//! - **Far instances.** The paper's octree nodes hold samples at their own resolution, so a
//!   node whose samples are below a pixel is drawn from its own (coarse) grid, not from its
//!   descendants'. Our cells hold no samples of their own size but their descendants are the
//!   tree's coarser samples, so a cell is drawn from the fewest levels down whose samples
//!   (each 2^-L of its area) fit the footprint. Drawn always [`CELL_LEVELS`] down, every
//!   instance of the 600 × 600 grid, a cell from its root, streamed its 2^8-level cut of far
//!   sub-pixel samples (81.6 M samples for 381 k covered pixels, overdraw 214, 23–32 s, over
//!   the default `--max-nodes`); drawn from the fitting level it streams 1.24 M (3.4 a covered
//!   pixel) in less time than `zbuffer`, at the same error against `zbuffer`'s frame. Such a
//!   level's nodes are loose spheres, so many are wider than the footprint and are drawn as
//!   the pixels of their splat, like the other methods' one splat for a far instance. Cells
//!   reached by refining are unchanged (their samples are at most 8 levels down anyway).
//! - Cracks between single-pixel samples are closed by the same hole filling as the other
//!   methods. A frame is drawn on one thread (no tiles) and is the same on any thread count.

use std::collections::HashMap;

use crate::camera::View;
use crate::error::Result;
use crate::lod::{self, Decision, LodParams, LodStats, Placement};
use crate::raster::{self, alpha_passes, Frame, Splat};
use crate::scene::items::Item;
use crate::scene::SceneFiles;

/// Settings of the `parilov` method.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ParilovOptions {
    /// Largest angle (degrees) between the view vector to a cell and its order's axis before
    /// the cell is re-sorted (45: no artifacts, the paper's guarantee; 70: its practice).
    pub threshold_deg: f32,
}

impl Default for ParilovOptions {
    fn default() -> Self {
        ParilovOptions { threshold_deg: 70.0 }
    }
}

/// Levels between a cell and its samples: a cell holds up to 2^8 = 256 samples, its
/// descendants this many levels down (or leaves above them), whatever the view, so that an
/// order stays valid while the view turns (the paper's cells are octree nodes holding a fixed
/// 16³ sample grid).
pub const CELL_LEVELS: u32 = 8;

/// Work of one `parilov` frame (`parilov` in the JSON).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct ParilovStats {
    /// Cells drawn.
    pub cells: u64,
    /// Cells whose samples were sorted this frame (no kept order, the view turned past the
    /// threshold, or the cut changed).
    pub cells_resorted: u64,
    /// `cells_resorted / cells`.
    pub resort_fraction: f64,
    /// Cells whose kept axis was still valid but whose samples changed (close-ups replicate
    /// samples per view; a cell's fitting level changes with its distance), sorted again
    /// along that axis.
    pub cells_recut: u64,
    /// Samples streamed (one pixel each), virtual ones included.
    pub samples: u64,
    /// Samples wider than the footprint, each replaced by one virtual sample per pixel it
    /// covers (close-ups).
    pub virtual_samples: u64,
    /// Background pixels between samples filled from their neighbours.
    pub holes_filled: u64,
    /// Samples streamed per second of the frame's drawing (traversal, sorting, pixels).
    pub samples_per_second: f64,
}

/// The kept orders of the cells, by cell (file, tree, level, node, instance state).
#[derive(Default)]
pub(crate) struct Orders {
    map: HashMap<[u64; 5], Order>,
}

struct Order {
    /// Tree axis (0–2) and direction (+1 / −1) the samples are sorted along.
    axis: usize,
    sign: f32,
    /// Sample indices of the cut, farthest first.
    perm: Vec<u32>,
}

/// Camera-space direction along which tree coordinate `k` grows under `pl` (column `k` of
/// the normal matrix: under an affine placement, the normal of the mapped planes
/// `x_k = const`, renormalised).
fn axis(pl: &Placement, k: usize) -> [f32; 3] {
    let mut e = [0.0; 3];
    e[k] = 1.0;
    pl.normal(e)
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Camera-space centre and radius of a node under `pl`.
fn camera_sphere(pl: &Placement, c: [f32; 3], r: f32) -> ([f32; 3], f32) {
    let m = &pl.m;
    let x = [0, 1, 2].map(|i| m[i][0] * c[0] + m[i][1] * c[1] + m[i][2] * c[2] + pl.t[i]);
    (x, r * pl.s)
}


/// A sample of a cell: its order key (coordinate along the order's axis, larger is
/// farther), pixel, depth and shaded colour.
#[derive(Clone, Copy)]
struct Sample {
    x: f32,
    y: f32,
    z: f32,
    color: [u8; 4],
    /// The splat of a sample wider than the footprint, drawn as its virtual children.
    wide: Option<Splat>,
}

/// Draws a frame: cells back to front, each cell's samples in its (kept or new) order.
pub(crate) fn render(files: &mut SceneFiles, view: &View, p: &LodParams, o: &ParilovOptions, frame: &mut Frame) -> Result<(ParilovStats, LodStats)> {
    let t0 = std::time::Instant::now();
    let cos_threshold = o.threshold_deg.to_radians().cos();
    let footprint = 0.5 * p.pixel_error;
    let mut stats = ParilovStats::default();
    let mut lod = LodStats::default();
    let mut orders = std::mem::take(&mut files.parilov_orders);
    // Samples are always drawn (their size is the cell's business); back faces still culled.
    let draw_all = LodParams { pixel_error: f32::INFINITY, outline_refine: 1.0, kernel: None, ..*p };
    // Depth-first, back to front: a stack whose top is the farthest item not yet drawn.
    let mut stack: Vec<Item> = files.root_items()?;
    sort_far_first(files, view, &mut stack);
    stack.reverse();
    let mut content: Vec<sct_format::Node> = Vec::new();
    let mut samples: Vec<Sample> = Vec::new();
    let mut keys: Vec<f32> = Vec::new();
    // The same bounds as the other methods: nodes examined, and pixels under wide samples.
    // Those pixels are painted one by one on one thread (the splat rasterizer works in
    // parallel tiles), so a quarter of the pixel cap keeps the worst case as short: 2^31
    // took 9.6 s on a 999 KB file.
    let mut wide_pixels = 0u64;
    let wide_cap = p.max_splat_pixels / 4;
    while let Some(it) = stack.pop() {
        if lod.nodes_visited > p.max_nodes {
            return Err(limit(files, lod::NODES_EXAMINED, lod.nodes_visited, p.max_nodes));
        }
        let n = files.item_node(&it)?;
        let pl = files.item_placement(view, &it);
        let (c, r) = camera_sphere(&pl, n.node.center, n.node.radius);
        lod.nodes_visited += 1;
        if view.outside(c, r) {
            lod.frustum_culled += 1;
            continue;
        }
        if !n.two_sided && p.backface && view.backfacing(c, r, axis_rotate(&pl, n.node.normal), pl.cone(n.node.cone)) {
            lod.backface_culled += 1;
            continue;
        }
        // A plain tree's node becomes a cell once its samples (CELL_LEVELS down, each about
        // 2^-CELL_LEVELS of its area) are at most the footprint wide: their equal-area
        // radius in the tree frame times the most the placement stretches the patch (under
        // an affine instance a stretched patch is wider than its equal-area disc); group
        // trees and inlines refine until they reach plain trees.
        let depth = c[2].max(view.near);
        let sample_radius = view.focal * pl.patch_stretch(n.node.normal, n.node.cone) * (n.node.area / std::f32::consts::PI / (1u64 << CELL_LEVELS) as f32).sqrt() / depth;
        if n.refinable && !(it.is_plain_tree() && sample_radius <= footprint && c[2] > r) {
            let mut kids = files.item_children(&it)?;
            order_children(files, view, &mut kids);
            // Farthest on top of the stack.
            stack.extend(kids.into_iter().rev());
            continue;
        }
        // A cell: its samples, the fewest levels down (at most CELL_LEVELS) at which they are
        // at most the footprint wide — the paper's "node has sufficient LOD". A cell reached
        // by refining is drawn CELL_LEVELS down (or a level or so less); a tree that is a cell
        // from its root (a far instance) is drawn from a coarser level, down to its root
        // alone, as the other methods draw it as one splat.
        content.clear();
        if n.refinable {
            files.descendants(&it, sample_levels(sample_radius, footprint), &mut content)?;
        } else {
            content.push(n.node);
        }
        samples.clear();
        let mut wide = false;
        // A two-sided tree's samples face both ways (spec §6.2): none is culled.
        let sample_params = if n.two_sided { LodParams { backface: false, ..draw_all } } else { draw_all };
        for q in &content {
            if let Decision::Draw(s) = lod::decide(q, true, false, &pl, view, &sample_params, &mut lod) {
                let is_wide = 1.0 / s.inv_b2.sqrt() > footprint * 1.01;
                if is_wide {
                    // Close-up: a sample wider than the footprint stands for virtual
                    // children, one per pixel its splat covers, at its depth.
                    let [x0, x1, y0, y1] = s.bounds.map(i64::from);
                    let (w, h) = (frame.width as i64, frame.height as i64);
                    wide_pixels = wide_pixels.saturating_add(((x1.min(w - 1) - x0.max(0) + 1).max(0) * (y1.min(h - 1) - y0.max(0) + 1).max(0)) as u64);
                    if wide_pixels > wide_cap {
                        return Err(limit(files, lod::PIXELS_COVERED, wide_pixels, wide_cap));
                    }
                    wide = true;
                    stats.virtual_samples += 1;
                }
                samples.push(Sample { x: s.x, y: s.y, z: s.z, color: s.color, wide: is_wide.then_some(s) });
            }
        }
        if samples.is_empty() {
            continue;
        }
        stats.cells += 1;
        let key = it.key();
        let len = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt().max(1e-30);
        let v = c.map(|x| x / len);
        let point = |q: &Sample| [(q.x - view.cx) * q.z / view.focal, -(q.y - view.cy) * q.z / view.focal, q.z];
        // The kept axis while the view vector stays within the threshold of it.
        let kept_axis = orders.map.get(&key).filter(|ord| ord.sign * dot(v, axis(&pl, ord.axis)) >= cos_threshold).map(|ord| (ord.axis, ord.sign));
        let (k, sgn) = match kept_axis {
            Some(ks) => ks,
            None => {
                stats.cells_resorted += 1;
                // The tree axis most parallel to the view vector, pointing away from the eye.
                (0..3).map(|k| (k, dot(v, axis(&pl, k)))).max_by(|a, b| a.1.abs().total_cmp(&b.1.abs())).map(|(k, d)| (k, if d < 0.0 { -1.0 } else { 1.0 })).unwrap_or((2, 1.0))
            }
        };
        let a = axis(&pl, k);
        keys.clear();
        keys.extend(samples.iter().map(|q| sgn * dot(a, point(q))));
        // A kept order is reused when the cell's samples are the same ones (no close-up
        // replication): its permutation is still sorted along the kept axis.
        let reuse = kept_axis.is_some()
            && !wide
            && orders.map.get(&key).is_some_and(|ord| ord.perm.len() == samples.len() && ord.perm.windows(2).all(|w| keys[w[0] as usize] >= keys[w[1] as usize] - 1e-5 * len));
        if !reuse {
            if kept_axis.is_some() {
                stats.cells_recut += 1;
            }
            orders.map.insert(key, Order { axis: k, sign: sgn, perm: counting_sort_far_first(&keys) });
        }
        for &i in &orders.map[&key].perm {
            stats.samples += draw(frame, &samples[i as usize]);
        }
    }
    let before = frame.covered();
    raster::fill_holes(frame);
    stats.holes_filled = (frame.covered() - before) as u64;
    files.parilov_orders = orders;
    stats.resort_fraction = if stats.cells > 0 { stats.cells_resorted as f64 / stats.cells as f64 } else { 0.0 };
    let secs = t0.elapsed().as_secs_f64();
    stats.samples_per_second = if secs > 0.0 { stats.samples as f64 / secs } else { 0.0 };
    Ok((stats, lod))
}

/// Levels below a cell at which its samples are at most `footprint` wide, given their width
/// `radius_at_cell_levels` [`CELL_LEVELS`] down: each level up doubles a sample's area, so
/// `k` levels up widens it √2^k; the fewest levels, in `0..=CELL_LEVELS`.
fn sample_levels(radius_at_cell_levels: f32, footprint: f32) -> u32 {
    if !(radius_at_cell_levels > 0.0 && footprint > 0.0) {
        return CELL_LEVELS;
    }
    // Area ratio between the footprint's disc and a sample's CELL_LEVELS down: that many
    // levels up still fit.
    let up = (2.0 * (footprint / radius_at_cell_levels).log2()).floor();
    if up.is_nan() {
        return CELL_LEVELS;
    }
    CELL_LEVELS - up.clamp(0.0, CELL_LEVELS as f32) as u32
}

/// Sample indices ordered by `keys`, largest (farthest) first, by a linear sort: the keys
/// quantized to 16 bits over their range and sorted by two stable counting passes of 8 bits
/// (the paper's counting sort on its 4-bit grid coordinate, with finer buckets). Samples in
/// one bucket (within 1/65,536 of the cell's depth range) keep their index order, so a frame
/// repeats exactly.
fn counting_sort_far_first(keys: &[f32]) -> Vec<u32> {
    let (lo, hi) = keys.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), &k| (l.min(k), h.max(k)));
    let scale = if hi > lo { 65535.0 / (hi - lo) } else { 0.0 };
    // Descending key = ascending (65535 − quantized key).
    let q: Vec<u16> = keys.iter().map(|&k| 65535 - (((k - lo) * scale).clamp(0.0, 65535.0) as u16)).collect();
    let mut a: Vec<u32> = (0..keys.len() as u32).collect();
    let mut b = vec![0u32; keys.len()];
    for shift in [0u32, 8] {
        let mut count = [0usize; 257];
        for &i in &a {
            count[((q[i as usize] >> shift) & 0xff) as usize + 1] += 1;
        }
        for d in 0..256 {
            count[d + 1] += count[d];
        }
        for &i in &a {
            let d = ((q[i as usize] >> shift) & 0xff) as usize;
            b[count[d]] = i;
            count[d] += 1;
        }
        std::mem::swap(&mut a, &mut b);
    }
    a
}

/// The limit error of the other methods, naming the main file.
fn limit(files: &SceneFiles, what: &'static str, value: u64, limit: u64) -> crate::Error {
    crate::Error::sct(&files.main_path(), sct_format::Error::LimitExceeded { what, value, limit })
}

/// Camera-space direction of a tree-frame normal under `pl`.
fn axis_rotate(pl: &Placement, n: [f32; 3]) -> [f32; 3] {
    pl.normal(n)
}

/// Draws sample `q` over what is there (no depth test): the pixel holding it, or each pixel
/// of a wide sample's splat (its virtual children). Returns the pixel samples drawn.
fn draw(frame: &mut Frame, q: &Sample) -> u64 {
    let (w, h) = (frame.width, frame.height);
    if let Some(s) = &q.wide {
        let mut n = 0;
        s.for_each_pixel(w, h, |i| {
            n += 1;
            if alpha_passes(s.color[3], i % w, i / w) {
                frame.color[i] = s.color;
                frame.depth[i] = s.z;
            }
        });
        return n;
    }
    let (x, y) = (q.x.floor(), q.y.floor());
    if x >= 0.0 && y >= 0.0 && (x as usize) < w && (y as usize) < h && q.z.is_finite() {
        let (x, y) = (x as usize, y as usize);
        if alpha_passes(q.color[3], x, y) {
            let i = y * w + x;
            frame.color[i] = q.color;
            frame.depth[i] = q.z;
        }
    }
    1
}

/// Orders sibling items back to front. Two children of a tree node are ordered by the plane
/// through the midpoint of their centres, normal to the tree axis along which the centres
/// differ most (the build's split axis); anything else, farthest centre first.
fn order_children(files: &SceneFiles, view: &View, kids: &mut [Item]) {
    if let [a, b] = kids {
        if let (Ok(na), Ok(nb)) = (files.item_node(a), files.item_node(b)) {
            if a.same_tree(b) {
                let pl = files.item_placement(view, a);
                let d = [0, 1, 2].map(|k| nb.node.center[k] - na.node.center[k]);
                let k = (0..3).max_by(|&x, &y| d[x].abs().total_cmp(&d[y].abs())).unwrap_or(0);
                let (ca, _) = camera_sphere(&pl, na.node.center, 0.0);
                let (cb, _) = camera_sphere(&pl, nb.node.center, 0.0);
                let n = axis(&pl, k);
                let m = [0, 1, 2].map(|i| 0.5 * (ca[i] + cb[i]));
                // Side of the plane: the eye is the camera-space origin.
                let eye_side = -dot(n, m);
                let a_side = dot(n, ca) - dot(n, m);
                if (eye_side >= 0.0) == (a_side >= 0.0) {
                    kids.swap(0, 1);
                }
                return;
            }
        }
    }
    sort_far_first(files, view, kids);
}

/// Sorts items by the distance of their centres from the eye, farthest first.
fn sort_far_first(files: &SceneFiles, view: &View, items: &mut [Item]) {
    let mut d: Vec<(f32, usize)> = items
        .iter()
        .enumerate()
        .map(|(i, it)| {
            let c = files.item_node(it).map(|n| camera_sphere(&files.item_placement(view, it), n.node.center, 0.0).0).unwrap_or([0.0; 3]);
            (-(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]), i)
        })
        .collect();
    d.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
    let sorted: Vec<Item> = d.iter().map(|&(_, i)| items[i].clone()).collect();
    items.clone_from_slice(&sorted);
}

#[cfg(test)]
mod tests {
    use super::{counting_sort_far_first, sample_levels, CELL_LEVELS};

    #[test]
    fn sample_levels_go_up_while_samples_fit_the_footprint() {
        // Samples CELL_LEVELS down at the footprint or wider: all the levels.
        assert_eq!(sample_levels(0.5, 0.5), CELL_LEVELS);
        assert_eq!(sample_levels(2.0, 0.5), CELL_LEVELS);
        // Half the footprint: a quarter of its area, two levels up still fit; just over
        // half: one.
        assert_eq!(sample_levels(0.25, 0.5), CELL_LEVELS - 2);
        assert_eq!(sample_levels(0.26, 0.5), CELL_LEVELS - 1);
        // A far subtree: its root alone.
        assert_eq!(sample_levels(1e-4, 0.5), 0);
        // No area or no footprint: the fixed depth.
        assert_eq!(sample_levels(0.0, 0.5), CELL_LEVELS);
        assert_eq!(sample_levels(f32::NAN, 0.5), CELL_LEVELS);
        assert_eq!(sample_levels(0.1, f32::INFINITY), 0);
    }

    #[test]
    fn counting_sort_orders_far_first_and_keeps_ties_in_index_order() {
        let keys = [0.5f32, 2.0, -1.0, 2.0, 0.0, 1.0e-9, 0.5];
        let perm = counting_sort_far_first(&keys);
        assert_eq!(perm, [1, 3, 0, 6, 4, 5, 2]);
        assert_eq!(counting_sort_far_first(&[]), Vec::<u32>::new());
        assert_eq!(counting_sort_far_first(&[3.0, 3.0]), [0, 1]);
        // Against a comparison sort on random keys (ties broken by index).
        let mut rng = sct_format::rng::SplitMix64(7);
        let keys: Vec<f32> = (0..1000).map(|_| (rng.next_u64() % 5000) as f32 * 0.25).collect();
        let mut want: Vec<u32> = (0..1000).collect();
        want.sort_by(|&x, &y| keys[y as usize].total_cmp(&keys[x as usize]).then(x.cmp(&y)));
        assert_eq!(counting_sort_far_first(&keys), want);
    }
}
