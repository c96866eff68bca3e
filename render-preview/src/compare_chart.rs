//! The comparison chart: one column per scene, foreground PSNR (top) and SSIM (bottom)
//! against time per frame (log scale, decade ticks), one line per method with its knob
//! values as point labels (a label that would overlap another or a point is left out; the
//! JSON has them all), each panel's Pareto front (time against that panel's metric) ringed
//! and joined by a dashed line, `wand`'s spread over seeds as a bar from the least to the
//! greatest score at each of its points, and the legend in a strip above the panels.

use std::path::Path;

use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::compare::{CompareResult, Point, SceneResult};
use crate::error::{Error, Result};

/// The chart font (DejaVu Sans Mono, Bitstream Vera licence: see assets/).
pub(crate) static FONT: &[u8] = include_bytes!("../assets/DejaVuSansMono.ttf");

const PANEL_W: u32 = 440;
const PANEL_H: u32 = 330;
const LEGEND_H: u32 = 44;

/// Method colours, in method order.
pub(crate) fn color(i: usize) -> RGBColor {
    const C: [RGBColor; 6] = [RGBColor(31, 119, 180), RGBColor(214, 39, 40), RGBColor(44, 160, 44), RGBColor(148, 103, 189), RGBColor(255, 127, 14), RGBColor(23, 190, 207)];
    C[i % C.len()]
}

/// Writes the chart as PNG and SVG.
pub fn write(r: &CompareResult, png: &Path, svg: &Path) -> Result<()> {
    // At least two panels wide, so that the legend fits.
    let cols = r.scenes.len().max(2) as u32;
    let (w, h) = (PANEL_W * cols, PANEL_H * 2 + LEGEND_H);
    let mut s = String::new();
    draw(r, SVGBackend::with_string(&mut s, (w, h)).into_drawing_area()).map_err(|m| Error::Output { path: svg.to_path_buf(), message: m })?;
    sct_format::atomic::write_atomic(svg, |f| {
        use std::io::Write;
        f.write_all(s.as_bytes()).map_err(sct_format::Error::from)
    })
    .map_err(|e| Error::Output { path: svg.to_path_buf(), message: e.to_string() })?;
    let mut rgb = vec![0u8; (w * h * 3) as usize];
    draw(r, BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area()).map_err(|m| Error::Output { path: png.to_path_buf(), message: m })?;
    let img = image::RgbImage::from_raw(w, h, rgb).ok_or_else(|| Error::Output { path: png.to_path_buf(), message: "buffer size".into() })?;
    crate::write_rgb_png(png, &img)
}

fn draw<DB: DrawingBackend>(r: &CompareResult, root: DrawingArea<DB, Shift>) -> std::result::Result<(), String> {
    plotters::style::register_font("sans-serif", FontStyle::Normal, FONT).map_err(|_| "invalid chart font".to_string())?;
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    root.fill(&WHITE).map_err(e)?;
    let (legend, body) = root.split_vertically(LEGEND_H);
    // Legend: one entry per method, then the Pareto marker.
    let methods: Vec<&str> = r.scenes.first().map(|s| s.methods.iter().map(|m| m.method.name()).collect()).unwrap_or_default();
    let mut x = 12;
    let y = LEGEND_H as i32 / 2;
    let font = ("sans-serif", 15).into_font();
    for (i, name) in methods.iter().enumerate() {
        let c = color(i);
        legend.draw(&PathElement::new(vec![(x, y), (x + 26, y)], c.stroke_width(3))).map_err(e)?;
        legend.draw(&Circle::new((x + 13, y), 4, c.filled())).map_err(e)?;
        legend.draw(&Text::new(name.to_string(), (x + 32, y - 8), font.clone())).map_err(e)?;
        x += 40 + 9 * name.len() as i32 + 24;
    }
    legend.draw(&Circle::new((x + 8, y), 8, BLACK.stroke_width(2))).map_err(e)?;
    legend.draw(&Text::new(legend_note(r), (x + 22, y - 8), font.clone())).map_err(e)?;
    let cols = r.scenes.len().max(1);
    let panels = body.split_evenly((2, cols));
    for (si, sc) in r.scenes.iter().enumerate() {
        for (row, metric) in ["fg PSNR, dB", "fg SSIM"].iter().enumerate() {
            let area = &panels[row * cols + si];
            let value = |p: &Point| if row == 0 { p.metrics.fg_psnr_db } else { p.metrics.fg_ssim };
            let spread = |p: &Point| p.seeds.as_ref().and_then(|s| if row == 0 { s.fg_psnr_db } else { s.fg_ssim }).map(|s| (s.min, s.max));
            panel(area, sc, metric, &value, &spread).map_err(e)?;
        }
    }
    root.present().map_err(e)?;
    Ok(())
}

fn fmt_ms(v: f64) -> String {
    if v >= 1.0 {
        format!("{v:.0}")
    } else {
        format!("{v}")
    }
}

#[allow(clippy::type_complexity)]
fn panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    sc: &crate::compare::SceneResult,
    metric: &str,
    value: &dyn Fn(&Point) -> Option<f64>,
    spread: &dyn Fn(&Point) -> Option<(f64, f64)>,
) -> std::result::Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let pts: Vec<(f64, f64)> = sc.methods.iter().flat_map(|m| m.points.iter().filter_map(|p| value(p).map(|v| (p.seconds * 1e3, v)))).collect();
    let (mut t0, mut t1, mut v0, mut v1) = (f64::INFINITY, 0f64, f64::INFINITY, f64::NEG_INFINITY);
    for &(t, v) in &pts {
        (t0, t1, v0, v1) = (t0.min(t), t1.max(t), v0.min(v), v1.max(v));
    }
    for (lo, hi) in sc.methods.iter().flat_map(|m| m.points.iter().filter_map(spread)) {
        (v0, v1) = (v0.min(lo), v1.max(hi));
    }
    if !t0.is_finite() || !v0.is_finite() {
        (t0, t1, v0, v1) = (1.0, 10.0, 0.0, 1.0);
    }
    let (t0, t1) = ((t0 * 0.7).max(1e-3), (t1 * 1.4).max(t0 * 2.0));
    let pad = ((v1 - v0) * 0.12).max(if metric.contains("SSIM") { 0.005 } else { 0.5 });
    let (v0, v1) = (v0 - pad, v1 + pad);
    let decades = (t1.log10().floor() - t0.log10().ceil()) as i32 + 1;
    let mut c = ChartBuilder::on(area)
        .caption(format!("{} — {metric}", sc.name), ("sans-serif", 14))
        .margin(8)
        .x_label_area_size(34)
        .y_label_area_size(52)
        .build_cartesian_2d((t0..t1).log_scale(), v0..v1)?;
    // Decades only; with two decades or fewer in view, 2× and 5× as well (at least 40 px
    // apart on a 440 px panel).
    let few = decades <= 2;
    let is_tick = |v: &f64| {
        let l = v.log10();
        let m = v / 10f64.powf(l.floor());
        (l - l.round()).abs() < 1e-6 || (few && ((m - 2.0).abs() < 1e-6 || (m - 5.0).abs() < 1e-6))
    };
    let decade_fmt = |v: &f64| if is_tick(v) { fmt_ms(*v) } else { String::new() };
    let plain_fmt = |v: &f64| format!("{:.3}", v).trim_end_matches('0').trim_end_matches('.').to_string();
    let mut mesh = c.configure_mesh();
    mesh.x_desc("time per frame, ms (log)").y_desc(metric).label_style(("sans-serif", 12)).y_labels(6);
    if decades >= 1 {
        mesh.x_label_formatter(&decade_fmt).x_labels(40);
    } else {
        mesh.x_label_formatter(&plain_fmt).x_labels(3);
    }
    mesh.draw()?;
    // This panel's Pareto front (time against its own metric) joined in time order, drawn
    // first so the method lines sit on top.
    let on_front = |t: f64, v: f64| !pts.iter().any(|&(t2, v2)| t2 <= t && v2 >= v && (t2 < t || v2 > v));
    let mut front: Vec<(f64, f64)> = pts.iter().copied().filter(|&(t, v)| on_front(t, v)).collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0));
    c.draw_series(DashedLineSeries::new(front.clone(), 6, 4, BLACK.mix(0.6).stroke_width(1)))?;
    let mut placed: Vec<[i32; 4]> = Vec::new();
    for (mi, m) in sc.methods.iter().enumerate() {
        let col = color(mi);
        let line: Vec<(f64, f64, &Point)> = m.points.iter().filter_map(|p| value(p).map(|v| (p.seconds * 1e3, v, p))).collect();
        c.draw_series(LineSeries::new(line.iter().map(|&(x, y, _)| (x, y)), col.stroke_width(2)))?;
        c.draw_series(line.iter().map(|&(x, y, _)| Circle::new((x, y), 4, col.filled())))?;
        c.draw_series(line.iter().filter(|l| on_front(l.0, l.1)).map(|&(x, y, _)| Circle::new((x, y), 8, BLACK.stroke_width(2))))?;
        for &(x, y, _) in &line {
            let (px, py) = c.backend_coord(&(x, y));
            placed.push([px - 5, py - 5, px + 5, py + 5]);
        }
    }
    seed_bars(&mut c, sc, spread)?;
    // Knob labels: the first free spot of four around each point, or none.
    for (mi, m) in sc.methods.iter().enumerate() {
        let col = color(mi);
        for p in &m.points {
            let Some(v) = value(p) else { continue };
            let (px, py) = c.backend_coord(&(p.seconds * 1e3, v));
            let text = format!("{}", p.knob);
            let (tw, th) = (7 * text.len() as i32 + 2, 13);
            for (dx, dy) in [(7, -16), (7, 4), (-7 - tw, -16), (-7 - tw, 4)] {
                let r = [px + dx, py + dy, px + dx + tw, py + dy + th];
                let inside = |q: &[i32; 4]| r[0] < q[2] && q[0] < r[2] && r[1] < q[3] && q[1] < r[3];
                if placed.iter().any(inside) {
                    continue;
                }
                placed.push(r);
                let style = ("sans-serif", 12).into_font().color(&col);
                c.draw_series(std::iter::once(EmptyElement::at((p.seconds * 1e3, v)) + Text::new(text.clone(), (dx, dy), style)))?;
                break;
            }
        }
    }
    Ok(())
}

/// The legend's note on the markers: the bars only when some point has a seed spread.
fn legend_note(r: &CompareResult) -> &'static str {
    let bars = r.scenes.iter().flat_map(|s| &s.methods).flat_map(|m| &m.points).any(|p| p.seeds.is_some());
    if bars {
        "Pareto front; labels: knob value; bars: min–max over seeds"
    } else {
        "Pareto front; labels: knob value"
    }
}

/// A vertical bar with end caps from the least to the greatest score over seeds at each
/// point that has a spread, in its method's colour.
fn seed_bars<DB: DrawingBackend>(
    c: &mut ChartContext<'_, DB, Cartesian2d<LogCoord<f64>, RangedCoordf64>>,
    sc: &SceneResult,
    spread: &dyn Fn(&Point) -> Option<(f64, f64)>,
) -> std::result::Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    for (mi, m) in sc.methods.iter().enumerate() {
        let col = color(mi);
        for p in &m.points {
            let Some((lo, hi)) = spread(p) else { continue };
            let x = p.seconds * 1e3;
            c.draw_series(std::iter::once(PathElement::new(vec![(x, lo), (x, hi)], col.stroke_width(2))))?;
            for v in [lo, hi] {
                c.draw_series(std::iter::once(EmptyElement::at((x, v)) + PathElement::new(vec![(-5, 0), (5, 0)], col.stroke_width(2))))?;
            }
        }
    }
    Ok(())
}
