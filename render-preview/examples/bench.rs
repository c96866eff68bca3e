//! Benchmarks: `cargo run --release -p render-preview --example bench -- FILE.sct [WIDTH HEIGHT]`
//! (`RP_ZBUFFER=1`: only the default method's 3 × 3 frame, tiled against whole-frame).
//! Prints full-decode time, end-to-end preview time (open + refine + raster, best of 5)
//! and rasterizer throughput (splats/s) on the splats of that view, replicated.

use std::path::PathBuf;
use std::time::Instant;

use render_preview::{raster, render_file, zbuffer, Frame, RenderOptions};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let path = PathBuf::from(args.get(1).ok_or_else(|| anyhow::anyhow!("usage: bench FILE.sct [W H]"))?);
    let w: u32 = args.get(2).map_or(Ok(1280), |s| s.parse())?;
    let h: u32 = args.get(3).map_or(Ok(720), |s| s.parse())?;
    let threads = rayon::current_num_threads();
    let opts = RenderOptions { width: w, height: h, ..Default::default() };
    // RP_ZBUFFER=1: only the default method's supersampled frame, tiled against whole-frame.
    if std::env::var_os("RP_ZBUFFER").is_some() {
        return zbuffer_frames(&path, &opts);
    }
    // RP_RASTER_ONLY=1: only the rasterizer figure (for profiling).
    if std::env::var_os("RP_RASTER_ONLY").is_none() {
        previews(&path, &opts, threads)?;
    }
    raster_throughput(&path, &opts)
}

fn previews(path: &std::path::Path, opts: &RenderOptions, threads: usize) -> anyhow::Result<()> {
    let (w, h) = (opts.width, opts.height);
    let r = sct_format::SctReader::open(path, &sct_format::Limits::default())?;
    let t = Instant::now();
    let tree = r.read_tree(0)?;
    println!("full decode: {} nodes ({} leaves) in {:.3} s", tree.len(), tree.leaf_count(), t.elapsed().as_secs_f64());
    let mut best = f64::INFINITY;
    let mut last = None;
    let mut all = Vec::new();
    for _ in 0..5 {
        let out = render_file(path, opts)?;
        all.push(out.stats.seconds.total);
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
    all.sort_by(f64::total_cmp);
    println!("preview totals (s): {all:.3?}, median {:.3}", all[all.len() / 2]);
    Ok(())
}

fn raster_throughput(path: &std::path::Path, opts: &RenderOptions) -> anyhow::Result<()> {
    let (w, h) = (opts.width, opts.height);
    // Rasterizer throughput on this view's splats (collected again through the library).
    let mut files = render_preview::SceneFiles::open(path, &opts.limits)?;
    let splats = render_preview::collect_splats(&mut files, opts)?;
    bbox_stats(&splats);
    // The view's own splats once, as a preview draws them (per-frame overheads show here).
    let mut once = Vec::with_capacity(21);
    for _ in 0..21 {
        let mut f = Frame::new(w as usize, h as usize, [0, 0, 0, 255]);
        let t = Instant::now();
        raster::rasterize(&mut f, &splats);
        once.push(t.elapsed().as_secs_f64());
    }
    once.sort_by(f64::total_cmp);
    println!("raster once: {} splats, median {:.2} ms (best {:.2} ms)", splats.len(), once[10] * 1e3, once[0] * 1e3);
    let mut all = Vec::with_capacity(splats.len() * 8);
    while all.len() < 4_000_000 && !splats.is_empty() {
        all.extend_from_slice(&splats);
    }
    let reps: usize = std::env::var("RP_REPS").ok().and_then(|v| v.parse().ok()).unwrap_or(7).max(1);
    let cpu0 = cpu_seconds();
    let mut times = Vec::with_capacity(reps);
    for _ in 0..reps {
        let mut f = Frame::new(w as usize, h as usize, [0, 0, 0, 255]);
        let t = Instant::now();
        raster::rasterize(&mut f, &all);
        times.push(t.elapsed().as_secs_f64());
    }
    let total: f64 = times.iter().sum();
    times.sort_by(f64::total_cmp);
    let (best, median) = (times[0], times[reps / 2]);
    println!("raster cpu/wall ratio {:.2}, threads {}", (cpu_seconds() - cpu0) / total, rayon::current_num_threads());
    let n = all.len() as f64;
    println!("raster: {} splats, median {median:.4} s = {:.1} M splats/s (best {best:.4} s = {:.1} M/s)", all.len(), n / median / 1e6, n / best / 1e6);
    Ok(())
}

/// The `zbuffer` frame of the view's splats (drawn, blended, hole-filled, resolved) by the
/// tiled path and by the whole-frame steps, alternately (`RP_REPS` each, default 7;
/// `RP_TILED_ONLY=1` skips the whole-frame one, for profiling).
fn zbuffer_frames(path: &std::path::Path, opts: &RenderOptions) -> anyhow::Result<()> {
    let mut files = render_preview::SceneFiles::open(path, &opts.limits)?;
    let (splats, [sw, sh], s) = render_preview::collect_zbuffer_splats(&mut files, opts)?;
    let s = s as usize;
    let reps: usize = std::env::var("RP_REPS").ok().and_then(|v| v.parse().ok()).unwrap_or(7).max(1);
    let tiled_only = std::env::var_os("RP_TILED_ONLY").is_some();
    let bg = [0, 0, 0, 255];
    let (mut tiled, mut whole) = (Vec::new(), Vec::new());
    let mut tiled_cpu = 0.0;
    for _ in 0..reps {
        let (t, c) = (Instant::now(), cpu_seconds());
        let a = zbuffer::zbuffer_tiled(sw, sh, &splats, s, bg);
        tiled.push(t.elapsed().as_secs_f64());
        tiled_cpu += cpu_seconds() - c;
        if !tiled_only {
            let t = Instant::now();
            let b = zbuffer::zbuffer_frame(Frame::new(sw, sh, bg), &splats, s, bg);
            whole.push(t.elapsed().as_secs_f64());
            anyhow::ensure!(a == b, "the tiled frame differs from the whole-frame one");
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN) * 1e3
    };
    println!(
        "zbuffer frame {sw}x{sh} ({s}x{s} a pixel), {} splats: tiled median {:.1} ms (CPU {:.1} ms a frame), whole-frame median {:.1} ms, threads {}",
        splats.len(),
        median(&mut tiled),
        tiled_cpu / reps as f64 * 1e3,
        median(&mut whole),
        rayon::current_num_threads()
    );
    Ok(())
}

fn bbox_stats(s: &[render_preview::Splat]) {
    let n = s.len() as f64;
    let dims = |s: &render_preview::Splat| {
        let [x0, x1, y0, y1] = s.bounds.map(i32::from);
        ((x1 - x0 + 1).max(0), (y1 - y0 + 1).max(0))
    };
    let area: f64 = s.iter().map(dims).map(|(w, h)| (w * h) as f64).sum();
    // Shares by bounding box: no pixel centre, 1x1, within 2x2, larger.
    let mut hist = [0usize; 4];
    for (w, h) in s.iter().map(dims) {
        hist[if w * h == 0 { 0 } else if w * h == 1 { 1 } else if w <= 2 && h <= 2 { 2 } else { 3 }] += 1;
    }
    let p = hist.map(|k| 100.0 * k as f64 / n.max(1.0));
    println!(
        "mean pixel bounding box {:.2} px (pixel centres); boxes: empty {:.1} %, 1x1 {:.1} %, within 2x2 {:.1} %, larger {:.1} %",
        area / n,
        p[0],
        p[1],
        p[2],
        p[3]
    );
}

/// User + system CPU seconds of this process (Linux), to see how much of the machine we got.
fn cpu_seconds() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let f: Vec<&str> = s.rsplit(')').next().unwrap_or("").split_whitespace().collect();
    let t = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (t(11) + t(12)) / 100.0
}
