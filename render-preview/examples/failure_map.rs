//! The failure-region table and chart of BENCHMARKS.md (see `render_preview::failure_map`):
//!
//! `cargo run --release -p render-preview --example failure_map -- OUT_PREFIX [SIZE]`
//!
//! Writes OUT_PREFIX.md (the table), OUT_PREFIX.json (every measured point), OUT_PREFIX.png
//! and OUT_PREFIX.svg (the chart); SIZE is the image side in pixels (default 200).

use render_preview::failure_map::{self, Mode};
use render_preview::{failure_chart, Method};

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let prefix = a.first().ok_or_else(|| anyhow::anyhow!("usage: failure_map OUT_PREFIX [SIZE]"))?;
    let size: u32 = a.get(1).map_or(Ok(200), |s| s.parse())?;
    let dir = tempfile::tempdir()?;
    let sweeps = failure_map::run(&Mode::ALL, &Method::ALL, None, size, dir.path())?;
    let md = failure_map::markdown(&sweeps);
    print!("{md}");
    std::fs::write(format!("{prefix}.md"), &md)?;
    std::fs::write(format!("{prefix}.json"), serde_json::to_string_pretty(&sweeps)?)?;
    failure_chart::write(&sweeps, format!("{prefix}.png").as_ref(), format!("{prefix}.svg").as_ref())?;
    Ok(())
}
