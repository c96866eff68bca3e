//! Point clouds: one sample per point, sized by its nearest neighbours.

use rayon::prelude::*;
use sct_format::Node;

use crate::mesh::*;

use super::coverage::Grid;
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
    let grid = Grid::build(&pts, cell);
    let dist: Vec<f64> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut best = [f64::INFINITY; 4];
            let mut ring = 1i64;
            loop {
                grid.for_each_near(pts[i], ring, |j| {
                    if j != i {
                        let d = norm(sub(pts[i], pts[j]));
                        if d < best[3] {
                            best[3] = d;
                            best.sort_by(|a, b| a.total_cmp(b));
                        }
                    }
                });
                if best[3].is_finite() && best[3] <= ring as f64 * cell || ring >= 8 {
                    break;
                }
                ring *= 2;
            }
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
}
