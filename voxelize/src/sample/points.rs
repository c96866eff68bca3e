//! Point clouds: one sample per point, sized by its nearest neighbours.

use rayon::prelude::*;
use sct_format::Node;

use crate::mesh::*;

use super::shade::srgb8;
use super::{Never, Sink};

/// Samples a point cloud: one sample per point, radius = mean distance to its 4 nearest
/// neighbours (so neighbouring spheres overlap), area = that distance squared (the area of
/// a point's cell in a regular sampling of that spacing).
pub fn sample_points(pc: &PointCloud) -> Vec<Node> {
    let mut out = Vec::with_capacity(pc.positions.len());
    let Ok(()) = sample_points_into(pc, &mut |nodes| {
        out.extend_from_slice(nodes);
        Ok::<(), Never>(())
    });
    out
}

/// Samples handed to a sink at a time by [`sample_points_into`].
pub(super) const POINT_RUN: usize = 1 << 16;

/// [`sample_points`] handing the samples to `sink` in runs, in point order; a sink error
/// stops it and is returned.
pub fn sample_points_into<E>(pc: &PointCloud, sink: &mut Sink<'_, E>) -> Result<(), E> {
    let n = pc.positions.len();
    if n == 0 {
        return Ok(());
    }
    let pts: Vec<[f64; 3]> = pc.positions.iter().map(|p| p.map(f64::from)).collect();
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in &pts {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let ext = sub(hi, lo);
    // Cell size from the bounding box's surface-like measure: about 2 points per cell.
    let area_est = (ext[0] * ext[1] + ext[1] * ext[2] + ext[0] * ext[2]).max(1e-300);
    let mut cell = (2.0 * area_est / n as f64).sqrt().max(norm(ext) * 1e-6).max(1e-30);
    if !cell.is_finite() {
        cell = 1.0;
    }
    let tree = KdTree::build(&pts);
    let dist: Vec<f64> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut best = [f64::INFINITY; 4];
            tree.nearest(i, 0, &mut best);
            let f: Vec<f64> = best.iter().copied().filter(|d| d.is_finite()).collect();
            if f.is_empty() {
                cell
            } else {
                f.iter().sum::<f64>() / f.len() as f64
            }
        })
        .collect();
    let node = |i: usize| {
        let d = dist[i];
        let normal = pc.normals.as_ref().map_or([0.0, 0.0, 1.0], |ns| {
            let v = ns[i].map(f64::from);
            let l = norm(v);
            if l > 0.0 && l.is_finite() { v.map(|x| (x / l) as f32) } else { [0.0, 0.0, 1.0] }
        });
        let c = pc.colors.as_ref().map_or([0.8, 0.8, 0.8, 1.0], |c| c[i]);
        Node { center: pc.positions[i], radius: d as f32, normal, cone: 0.0, area: (d * d) as f32, color: srgb8(c) }
    };
    let mut run = Vec::with_capacity(n.min(POINT_RUN));
    for start in (0..n).step_by(POINT_RUN) {
        run.clear();
        run.extend((start..n.min(start + POINT_RUN)).map(node));
        sink(&run)?;
    }
    Ok(())
}

/// Points per k-d tree leaf.
const KD_LEAF: usize = 8;

/// A k-d tree over points, for their exact nearest neighbours. A uniform grid (what this
/// replaced) scans whole cells, so points crowded into one cell cost their count squared:
/// 83,000 points at one position took 41 s, 10 M on 1,000 positions more than 6 minutes.
/// Median splits keep the tree balanced whatever the points (coincident ones are split by
/// their order), and a query visits the far side of a split only when it may hold a point
/// strictly nearer than the 4th nearest so far: among coincident points that is never once
/// 4 are found.
struct KdTree<'a> {
    pts: &'a [[f64; 3]],
    /// Point indices, permuted so that every node's points are a contiguous range.
    idx: Vec<u32>,
    nodes: Vec<Kd>,
}

enum Kd {
    /// Points `idx[start..end]`.
    Leaf { start: usize, end: usize },
    /// Points with coordinate `axis` at most `at` go left, at least `at` right.
    Split { axis: usize, at: f64, left: usize, right: usize },
}

impl<'a> KdTree<'a> {
    fn build(pts: &'a [[f64; 3]]) -> Self {
        // Point counts fit in u32: a point cloud is bounded by the loader's file-size cap.
        let mut idx: Vec<u32> = (0..pts.len() as u32).collect();
        let mut nodes = Vec::new();
        Self::split(pts, &mut idx, 0, &mut nodes);
        KdTree { pts, idx, nodes }
    }

    /// Builds the subtree over `idx` (starting at `start` of the whole permutation); returns
    /// its node.
    fn split(pts: &[[f64; 3]], idx: &mut [u32], start: usize, nodes: &mut Vec<Kd>) -> usize {
        let me = nodes.len();
        if idx.len() <= KD_LEAF {
            nodes.push(Kd::Leaf { start, end: start + idx.len() });
            return me;
        }
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for &i in idx.iter() {
            let p = pts[i as usize];
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        let axis = (0..3).max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b]))).unwrap_or(0);
        let mid = idx.len() / 2;
        idx.select_nth_unstable_by(mid, |&a, &b| pts[a as usize][axis].total_cmp(&pts[b as usize][axis]));
        let at = pts[idx[mid] as usize][axis];
        nodes.push(Kd::Leaf { start, end: start }); // replaced below, once the children exist
        let (l, r) = idx.split_at_mut(mid);
        let left = Self::split(pts, l, start, nodes);
        let right = Self::split(pts, r, start + mid, nodes);
        nodes[me] = Kd::Split { axis, at, left, right };
        me
    }

    /// Merges into `best` (sorted distances) the points of subtree `node` nearer than its
    /// last entry, other than point `i` itself.
    fn nearest(&self, i: usize, node: usize, best: &mut [f64; 4]) {
        let q = self.pts[i];
        match self.nodes[node] {
            Kd::Leaf { start, end } => {
                for &j in &self.idx[start..end] {
                    if j as usize != i {
                        let d = norm(sub(q, self.pts[j as usize]));
                        if d < best[3] {
                            best[3] = d;
                            best.sort_by(|a, b| a.total_cmp(b));
                        }
                    }
                }
            }
            Kd::Split { axis, at, left, right } => {
                let off = q[axis] - at;
                let (near, far) = if off < 0.0 { (left, right) } else { (right, left) };
                self.nearest(i, near, best);
                if off.abs() < best[3] {
                    self.nearest(i, far, best);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Point samples reach the sink in runs of [`POINT_RUN`], in point order; a sink error
    /// stops them.
    #[test]
    fn point_runs_equal_the_collected_samples() {
        let mut rng = sct_format::rng::SplitMix64(21);
        let n = POINT_RUN + 1000;
        let positions: Vec<[f32; 3]> = (0..n).map(|_| [rng.next_f64() as f32, rng.next_f64() as f32, 0.0]).collect();
        let pc = PointCloud { positions, normals: None, colors: None };
        let all = sample_points(&pc);
        let mut runs = Vec::new();
        sample_points_into(&pc, &mut |nodes| {
            runs.push(nodes.to_vec());
            Ok::<(), Never>(())
        })
        .expect("infallible");
        assert_eq!(runs.iter().map(Vec::len).collect::<Vec<_>>(), [POINT_RUN, 1000]);
        let bits = |n: &Node| (n.center.map(f32::to_bits), n.radius.to_bits(), n.area.to_bits(), n.color);
        assert!(runs.concat().iter().map(bits).eq(all.iter().map(bits)));
        let mut calls = 0;
        assert_eq!(
            sample_points_into(&pc, &mut |_| {
                calls += 1;
                Err(7)
            }),
            Err(7)
        );
        assert_eq!(calls, 1);
    }

    /// The k-d tree finds exactly the 4 nearest other points (distances as a brute-force
    /// scan finds them), with duplicates, clusters and points on split planes.
    #[test]
    fn nearest_four_are_exact() {
        let mut rng = sct_format::rng::SplitMix64(24);
        let mut pts: Vec<[f64; 3]> = (0..3000).map(|_| [rng.next_f64(), rng.next_f64(), (rng.next_f64() * 4.0).floor()]).collect();
        pts.extend(std::iter::repeat_n([0.5, 0.5, 0.5], 20));
        pts.extend((0..50).map(|k| [2.0 + k as f64 * 1e-12, 2.0, 2.0]));
        let tree = KdTree::build(&pts);
        for i in (0..pts.len()).step_by(7) {
            let mut best = [f64::INFINITY; 4];
            tree.nearest(i, 0, &mut best);
            let mut all: Vec<f64> = (0..pts.len()).filter(|&j| j != i).map(|j| norm(sub(pts[i], pts[j]))).collect();
            all.sort_by(|a, b| a.total_cmp(b));
            assert_eq!(best[..], all[..4], "point {i}");
        }
    }

    /// Points crowded at one position, or a few, cost no more than spread ones (83,000 at
    /// one position took 41 s with the grid this replaced).
    #[test]
    fn coincident_points_are_fast() {
        let n = 200_000;
        let t = std::time::Instant::now();
        for positions in [vec![[0.5f32; 3]; n], (0..n).map(|i| [(i % 1000) as f32, 0.0, 0.0]).collect()] {
            let pc = PointCloud { positions, normals: None, colors: None };
            assert_eq!(sample_points(&pc).len(), n);
        }
        assert!(t.elapsed().as_secs() < 20, "{:?}", t.elapsed());
    }
}
