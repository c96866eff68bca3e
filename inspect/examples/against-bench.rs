//! Benchmark of `--against`: phase timings (mesh load + points, leaf decoding + index,
//! queries) over several runs, medians printed.
//!
//! `cargo run --release -p inspect --example against-bench -- FILE.sct MESH [POINTS] [RUNS]`

use std::path::PathBuf;

use inspect::{coverage_against, AgainstOptions};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let (Some(file), Some(mesh)) = (args.get(1).map(PathBuf::from), args.get(2).map(PathBuf::from)) else {
        anyhow::bail!("usage: against-bench FILE.sct MESH [POINTS] [RUNS]");
    };
    let points: usize = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(100_000);
    let runs: usize = args.get(4).map(|s| s.parse()).transpose()?.unwrap_or(5).max(1);
    let opts = AgainstOptions { points, ..Default::default() };
    let (mut mesh_s, mut index_s, mut query_s, mut total_s) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut last = None;
    for _ in 0..runs {
        let t = std::time::Instant::now();
        let r = coverage_against(&file, &mesh, &opts)?;
        total_s.push(t.elapsed().as_secs_f64());
        mesh_s.push(r.seconds.mesh);
        index_s.push(r.seconds.index);
        query_s.push(r.seconds.query);
        last = Some(r);
    }
    let Some(r) = last else { anyhow::bail!("no run") };
    println!(
        "{} points vs {} leaves ({} trees, {} uses): coverage {:.4}%; median of {runs}: total {:.3} s = mesh+points {:.3} s, decode+index {:.3} s, queries {:.3} s ({:.2} µs/point); threads {}",
        r.points,
        r.leaves,
        r.trees,
        r.tree_uses,
        r.fraction * 100.0,
        median(total_s),
        median(mesh_s),
        median(index_s),
        median(query_s.clone()),
        median(query_s) * 1e6 / r.points.max(1) as f64,
        rayon::current_num_threads()
    );
    Ok(())
}
