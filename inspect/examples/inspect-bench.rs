//! Benchmark of quick and deep validation on a synthetic N-node file (issue 5 §6).
//!
//! `cargo run --release -p inspect --example inspect-bench -- [NODES] [raw|canopy|default] [DIR]`

use std::path::PathBuf;
use std::time::Instant;

use sct_format::geometry::parent_of;
use sct_format::validate::{validate_file, ValidateOptions};
use sct_format::{Generator, Node, Profile, Scene, SceneTree, WriteOptions};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let nodes: usize = args.get(1).map(|s| s.parse()).transpose()?.unwrap_or(10_000_000);
    let profile: Profile = args.get(2).map(|s| s.parse()).transpose().map_err(anyhow::Error::msg)?.unwrap_or(Profile::Raw);
    let dir = args.get(3).map(PathBuf::from).unwrap_or_else(std::env::temp_dir);
    let leaves = nodes.div_ceil(2);
    let path = dir.join(format!("inspect-bench-{nodes}-{}.sct", profile.name()));
    if !path.exists() {
        let t = Instant::now();
        let tree = build(leaves);
        let scene = Scene::single_tree(Generator { tool: "inspect-bench".into(), ..Default::default() }, tree);
        sct_format::write_scene_file(&path, &scene, &WriteOptions { profile, ..Default::default() })?;
        eprintln!("built {} in {:.2?}", path.display(), t.elapsed());
    }
    let bytes = std::fs::metadata(&path)?.len();
    for deep in [false, true] {
        let mut best = f64::MAX;
        let mut report = None;
        for _ in 0..3 {
            let t = Instant::now();
            let r = validate_file(&path, &ValidateOptions { deep, ..Default::default() })?;
            best = best.min(t.elapsed().as_secs_f64());
            report = Some(r);
        }
        let r = report.unwrap_or_default();
        println!(
            "{} validation: {:.3} s (best of 3), {} nodes, {} blocks, {} issues, file {} bytes, profile {}",
            if deep { "deep" } else { "quick" },
            best,
            r.nodes,
            r.blocks,
            r.issues.len(),
            bytes,
            profile.name()
        );
    }
    Ok(())
}

/// A consistent balanced tree over `n` leaves on a helix: topology from splitting leaf ranges
/// breadth first, attributes filled bottom-up (children follow their parent in BFS order).
fn build(n: usize) -> SceneTree {
    let leaf = |i: usize| {
        let a = i as f32 * 0.001;
        Node {
            center: [a.cos(), a.sin(), a * 0.01],
            radius: 0.0005,
            normal: [a.cos(), a.sin(), 0.0],
            cone: 0.0,
            area: 1e-6,
            color: [(i % 256) as u8, 128, 64, 255],
        }
    };
    let mut ranges: Vec<(usize, usize)> = Vec::with_capacity(2 * n);
    ranges.push((0, n));
    let mut k = 0;
    while k < ranges.len() {
        let (a, b) = ranges[k];
        if b - a > 1 {
            let m = a + (b - a) / 2;
            ranges.push((a, m));
            ranges.push((m, b));
        }
        k += 1;
    }
    let flags: Vec<bool> = ranges.iter().map(|&(a, b)| b - a > 1).collect();
    let nodes: Vec<Node> = ranges.iter().map(|&(a, b)| if b - a == 1 { leaf(a) } else { Node::default() }).collect();
    drop(ranges);
    let mut tree = SceneTree::from_bfs(nodes, flags).expect("consistent construction");
    for i in (0..tree.len()).rev() {
        if let Some([a, b]) = tree.children(i) {
            let p = parent_of(&tree.nodes()[a], &tree.nodes()[b]);
            tree.nodes_mut()[i] = p;
        }
    }
    tree
}
