//! `canopy`'s occlusion culling against no culling, interleaved (BENCHMARKS.md, "`canopy`:
//! the Table 14 analogue and the dense block"):
//!
//! `cargo run --release -p render-preview --example canopy_cull -- FILE.sct VIEW W H T1 T2 T3 CLIP RUNS CULL...`
//!
//! VIEW is a preset (`front`, `iso`, …); T1–T3 are the thresholds in pixels; CULL is a
//! t_OccCull value, `off`, or `plain`: no image graph at all, the thesis's §6.8 baseline ("a
//! simpler depth first refinement that replaces stages one to three": t1 = t2 = f32::MAX, so the
//! mask holds the roots and stage 3 refines them to T3, drawing the same discs through a
//! depth buffer, as the thesis's baseline did). Each run renders every CULL once, in the
//! order given, so load changes fall on all of them alike. Prints per CULL the median frame
//! time, the median seconds per stage, the counters of the last run and the share of pixels
//! that differ from the unculled frame (a warm-up render before the runs) by more than 24
//! levels in some channel. First it prints the ceiling: the unculled mask nodes
//! that show no pixel when their discs are drawn through a depth buffer, and their share of
//! the discs (what a perfect culling at the mask's level of detail would remove).

use std::path::PathBuf;

use render_preview::{render, CanopyOptions, Frame, Method, RenderOptions, SceneFiles, ViewPreset};

fn differing(a: &Frame, b: &Frame) -> f64 {
    let n = a.color.iter().zip(&b.color).filter(|(x, y)| (0..3).any(|k| x[k].abs_diff(y[k]) > 24)).count();
    n as f64 / a.color.len().max(1) as f64
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    if a.len() < 10 {
        anyhow::bail!("usage: canopy_cull FILE.sct VIEW W H T1 T2 T3 CLIP RUNS CULL...");
    }
    let path = PathBuf::from(&a[0]);
    let view: ViewPreset = a[1].parse().map_err(|e| anyhow::anyhow!("view {}: {e}", a[1]))?;
    let (w, h): (u32, u32) = (a[2].parse()?, a[3].parse()?);
    let (t1, t2, t3, clip): (f32, f32, f32, f32) = (a[4].parse()?, a[5].parse()?, a[6].parse()?, a[7].parse()?);
    let runs: usize = a[8].parse()?;
    // NaN stands for `plain`.
    let culls: Vec<f32> = a[9..].iter().map(|s| match s.as_str() { "off" => Ok(f32::INFINITY), "plain" => Ok(f32::NAN), _ => s.parse::<f32>() }).collect::<Result<_, _>>()?;
    let opts = |cull: f32| RenderOptions {
        method: Method::Canopy,
        canopy: if cull.is_nan() {
            CanopyOptions { t1: f32::MAX, t2: f32::MAX, t3, occ_cull: f32::INFINITY, occ_clip: clip, zbuffer: true }
        } else {
            CanopyOptions { t1, t2, t3, occ_cull: cull, occ_clip: clip, zbuffer: false }
        },
        width: w,
        height: h,
        view,
        // Dense blocks at the thesis's t3 examine more than the default 10^7 nodes.
        max_nodes: 60_000_000,
        ..Default::default()
    };
    let mut files = SceneFiles::open(&path, &Default::default())?;
    // A warm-up frame (tables, page cache) that is also the unculled reference.
    let reference = render(&mut files, &opts(f32::INFINITY))?.frame;
    // The ceiling: the unculled discs through a depth buffer, counting the mask nodes that
    // show no pixel.
    let mut zb = opts(f32::INFINITY);
    zb.canopy.zbuffer = true;
    let z = render(&mut files, &zb)?.stats.canopy.ok_or_else(|| anyhow::anyhow!("no canopy counters"))?;
    let mut totals = vec![Vec::new(); culls.len()];
    let mut stages = vec![vec![Vec::new(); 4]; culls.len()];
    let mut last = vec![None; culls.len()];
    for _ in 0..runs {
        for (k, &c) in culls.iter().enumerate() {
            let out = render(&mut files, &opts(c))?;
            totals[k].push(out.stats.seconds.total);
            let s = out.stats.canopy.ok_or_else(|| anyhow::anyhow!("no canopy counters"))?;
            for (i, t) in s.stage_seconds.iter().enumerate() {
                stages[k][i].push(*t);
            }
            last[k] = Some((s, differing(&out.frame, &reference)));
        }
    }
    println!("{} {w}x{h} {view:?}, t1/t2/t3 {t1}/{t2}/{t3} px, t_OccClip {clip}, {runs} runs", path.display());
    println!(
        "unculled: {} of {} mask nodes ({:.1} %) show no pixel through a depth buffer; they hold {} of {} discs ({:.1} %)",
        z.hidden_mask_nodes,
        z.nodes_stage2,
        100.0 * z.hidden_mask_nodes as f64 / z.nodes_stage2.max(1) as f64,
        z.hidden_rasterized,
        z.nodes_rasterized,
        100.0 * z.hidden_rasterized as f64 / z.nodes_rasterized.max(1) as f64
    );
    println!("| t_OccCull | frame (median) | stage 1 / 2 / 3 / 4, s | nodes after S1 / S2 / rasterized | relations sep / int / cont | occluded | cycles broken | differing from unculled |");
    println!("|---|---|---|---|---|---|---|---|");
    for (k, &c) in culls.iter().enumerate() {
        let Some((s, diff)) = last[k] else { continue };
        let st: Vec<f64> = stages[k].iter_mut().map(|v| median(v)).collect();
        let name = if c.is_nan() { "plain".to_string() } else if c.is_finite() { format!("{c}") } else { "off".to_string() };
        println!(
            "| {name} | {:.3} s | {:.3} / {:.3} / {:.3} / {:.3} | {} / {} / {} | {} / {} / {} | {} | {} | {:.3} % |",
            median(&mut totals[k]),
            st[0],
            st[1],
            st[2],
            st[3],
            s.nodes_stage1,
            s.nodes_stage2,
            s.nodes_rasterized,
            s.relations.separate,
            s.relations.intersecting,
            s.relations.contained,
            s.occluded,
            s.cycles_broken,
            diff * 100.0
        );
    }
    Ok(())
}
