//! Benchmarks: `cargo run --release -p render-preview --example bench -- FILE.sct [WIDTH HEIGHT]`.
//! Prints full-decode time, end-to-end preview time (open + refine + raster, best of 5)
//! and rasterizer throughput (splats/s) on the splats of that view, replicated.

use std::path::PathBuf;
use std::time::Instant;

use render_preview::{raster, render_file, Frame, RenderOptions};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let path = PathBuf::from(args.get(1).ok_or_else(|| anyhow::anyhow!("usage: bench FILE.sct [W H]"))?);
    let w: u32 = args.get(2).map_or(Ok(1280), |s| s.parse())?;
    let h: u32 = args.get(3).map_or(Ok(720), |s| s.parse())?;
    let threads = rayon::current_num_threads();
    let r = sct_format::SctReader::open(&path, &sct_format::Limits::default())?;
    let t = Instant::now();
    let tree = r.read_tree(0)?;
    println!("full decode: {} nodes ({} leaves) in {:.3} s", tree.len(), tree.leaf_count(), t.elapsed().as_secs_f64());
    let opts = RenderOptions { width: w, height: h, ..Default::default() };
    let mut best = f64::INFINITY;
    let mut last = None;
    for _ in 0..5 {
        let out = render_file(&path, &opts)?;
        best = best.min(out.stats.seconds.total);
        last = Some(out);
    }
    let out = last.ok_or_else(|| anyhow::anyhow!("no render"))?;
    println!(
        "preview {w}x{h}: best {:.3} s (open {:.4}, traverse {:.3}, raster {:.4}); {} splats, {} nodes visited, {} / {} bytes read, threads {threads}",
        best,
        out.stats.seconds.open,
        out.stats.seconds.traverse,
        out.stats.seconds.raster,
        out.stats.splats,
        out.stats.lod.nodes_visited,
        out.stats.bytes_read,
        out.stats.file_size
    );
    // Rasterizer throughput on this view's splats (collected again through the library).
    let mut files = render_preview::SceneFiles::open(&path, &opts.limits)?;
    let splats = render_preview::collect_splats(&mut files, &opts)?;
    bbox_stats(&splats);
    let mut all = Vec::with_capacity(splats.len() * 8);
    while all.len() < 4_000_000 && !splats.is_empty() {
        all.extend_from_slice(&splats);
    }
    let mut best = f64::INFINITY;
    let reps: usize = std::env::var("RP_REPS").ok().and_then(|v| v.parse().ok()).unwrap_or(5);
    let cpu0 = cpu_seconds();
    let mut total = 0.0;
    for _ in 0..reps {
        let mut f = Frame::new(w as usize, h as usize, [0, 0, 0, 255]);
        let t = Instant::now();
        raster::rasterize(&mut f, &all);
        best = best.min(t.elapsed().as_secs_f64());
        total += t.elapsed().as_secs_f64();
    }
    println!("raster cpu/wall ratio {:.2}", (cpu_seconds() - cpu0) / total);
    println!("raster: {} splats in {:.4} s = {:.1} M splats/s", all.len(), best, all.len() as f64 / best / 1e6);
    Ok(())
}

#[allow(dead_code)]
fn bbox_stats(s: &[render_preview::Splat]) {
    let n = s.len() as f64;
    let area: f64 = s.iter().map(|s| ((2.0 * s.ex + 1.0) * (2.0 * s.ey + 1.0)) as f64).sum();
    println!("mean bbox area {:.2} px", area / n);
}

/// User + system CPU seconds of this process (Linux), to see how much of the machine we got.
fn cpu_seconds() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let f: Vec<&str> = s.rsplit(')').next().unwrap_or("").split_whitespace().collect();
    let t = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (t(11) + t(12)) / 100.0
}
