//! Random but self-consistent scene trees for round-trip and hostile-input tests.
#![allow(dead_code)]

use sct_format::{Node, SceneTree};

/// The workspace's deterministic generator with the helpers these tests need.
pub struct Rng(pub sct_format::rng::SplitMix64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(sct_format::rng::SplitMix64(seed))
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }
    pub fn f32(&mut self) -> f32 {
        self.0.next_f32()
    }
    pub fn unit(&mut self) -> [f32; 3] {
        loop {
            let v = [self.f32() * 2.0 - 1.0, self.f32() * 2.0 - 1.0, self.f32() * 2.0 - 1.0];
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if l > 0.1 && l <= 1.0 {
                return [v[0] / l, v[1] / l, v[2] / l];
            }
        }
    }
}

/// A random full binary tree of about `target_nodes` nodes, generated top-down so that every
/// child lies inside its parent, areas split exactly, and cones contain the children's
/// normals (internal cones are whole-sphere; leaves have cone 0).
pub fn random_tree(seed: u64, target_nodes: usize, alpha: bool) -> SceneTree {
    generated_tree(seed, target_nodes, alpha, false)
}

/// Normal of [`planar_tree`]'s plane: tilted, so that the position code's grid cannot
/// follow it.
pub const PLANE_NORMAL: [f32; 3] = [0.48, 0.6, 0.64];

/// [`random_tree`] of a plane: every centre lies on the plane through `(1, -2, 3)` with
/// normal [`PLANE_NORMAL`], and every normal is that normal.
pub fn planar_tree(seed: u64, target_nodes: usize) -> SceneTree {
    generated_tree(seed, target_nodes, false, true)
}

fn generated_tree(seed: u64, target_nodes: usize, alpha: bool, planar: bool) -> SceneTree {
    let mut rng = Rng::new(seed);
    let root = Node { center: [1.0, -2.0, 3.0], radius: 1000.0, normal: [0.0, 0.0, 1.0], cone: std::f32::consts::PI, area: 100.0, color: [128, 64, 32, 255] };
    let mut nodes = vec![root];
    let mut internal = Vec::new();
    let mut level = vec![root];
    let mut total = 1usize;
    while !level.is_empty() {
        let mut next = Vec::new();
        for p in &level {
            let split = total + 2 <= target_nodes && (next.len() < 4 || rng.f32() < 0.9) && p.radius > 1e-2;
            internal.push(split);
            if !split {
                continue;
            }
            total += 2;
            let f = 0.2 + 0.6 * rng.f32();
            for area in [p.area * f, p.area * (1.0 - f)] {
                let r = p.radius * (0.5 + 0.3 * rng.f32());
                let mut d = rng.unit();
                if planar {
                    let n = PLANE_NORMAL;
                    let t = d[0] * n[0] + d[1] * n[1] + d[2] * n[2];
                    let v = [d[0] - t * n[0], d[1] - t * n[1], d[2] - t * n[2]];
                    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-6);
                    d = [v[0] / l, v[1] / l, v[2] / l];
                }
                let off = (p.radius - r) * rng.f32();
                let leafish = rng.f32() < 0.3;
                let c = Node {
                    center: [p.center[0] + d[0] * off, p.center[1] + d[1] * off, p.center[2] + d[2] * off],
                    radius: r,
                    normal: if planar { PLANE_NORMAL } else { rng.unit() },
                    cone: if leafish { 0.0 } else { std::f32::consts::PI },
                    area,
                    color: [rng.next_u64() as u8, rng.next_u64() as u8, rng.next_u64() as u8, if alpha { rng.next_u64() as u8 } else { 255 }],
                };
                next.push(c);
            }
        }
        nodes.extend_from_slice(&next);
        level = next;
    }
    // Leaves carry cone 0.
    for (n, &i) in nodes.iter_mut().zip(&internal) {
        if !i {
            n.cone = 0.0;
        }
    }
    SceneTree::from_bfs(nodes, internal).expect("generator builds a valid tree")
}
pub mod craft;
