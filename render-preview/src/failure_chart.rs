//! The failure-region chart: one panel per failure scene, each method's measure against the
//! scene's parameter (one line per method, the colours of the comparison chart), the bound
//! as a dashed line and the points that break it ringed.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::compare_chart::{color, FONT};
use crate::error::{Error, Result};
use crate::failure_map::{Mode, Sweep};
use crate::Method;

const PANEL_W: u32 = 380;
const PANEL_H: u32 = 300;
const LEGEND_H: u32 = 44;

/// Writes the chart of `sweeps` as PNG and SVG.
pub fn write(sweeps: &[Sweep], png: &Path, svg: &Path) -> Result<()> {
    let modes = modes(sweeps);
    let cols = modes.len().max(2) as u32;
    let (w, h) = (PANEL_W * cols, PANEL_H + LEGEND_H);
    let mut s = String::new();
    draw(sweeps, SVGBackend::with_string(&mut s, (w, h)).into_drawing_area()).map_err(|m| Error::Output { path: svg.to_path_buf(), message: m })?;
    sct_format::atomic::write_atomic(svg, |f| {
        use std::io::Write;
        f.write_all(s.as_bytes()).map_err(sct_format::Error::from)
    })
    .map_err(|e| Error::Output { path: svg.to_path_buf(), message: e.to_string() })?;
    let mut rgb = vec![0u8; (w * h * 3) as usize];
    draw(sweeps, BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area()).map_err(|m| Error::Output { path: png.to_path_buf(), message: m })?;
    let img = image::RgbImage::from_raw(w, h, rgb).ok_or_else(|| Error::Output { path: png.to_path_buf(), message: "buffer size".into() })?;
    crate::write_rgb_png(png, &img)
}

fn modes(sweeps: &[Sweep]) -> Vec<Mode> {
    let mut m: Vec<Mode> = Vec::new();
    for s in sweeps {
        if !m.contains(&s.mode) {
            m.push(s.mode);
        }
    }
    m
}

/// The colour of `m`: its place in [`Method::ALL`], as in the comparison chart.
fn method_color(m: Method) -> RGBColor {
    color(Method::ALL.iter().position(|&x| x == m).unwrap_or(0))
}

fn draw<DB: DrawingBackend>(sweeps: &[Sweep], root: DrawingArea<DB, Shift>) -> std::result::Result<(), String> {
    plotters::style::register_font("sans-serif", FontStyle::Normal, FONT).map_err(|_| "invalid chart font".to_string())?;
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    root.fill(&WHITE).map_err(e)?;
    let (legend, body) = root.split_vertically(LEGEND_H);
    let mut methods: Vec<Method> = Vec::new();
    for s in sweeps {
        if !methods.contains(&s.method) {
            methods.push(s.method);
        }
    }
    let (mut x, y) = (12, LEGEND_H as i32 / 2);
    let font = ("sans-serif", 15).into_font();
    for &m in &methods {
        let c = method_color(m);
        legend.draw(&PathElement::new(vec![(x, y), (x + 26, y)], c.stroke_width(3))).map_err(e)?;
        legend.draw(&Circle::new((x + 13, y), 4, c.filled())).map_err(e)?;
        legend.draw(&Text::new(m.name().to_string(), (x + 32, y - 8), font.clone())).map_err(e)?;
        x += 40 + 9 * m.name().len() as i32 + 24;
    }
    legend.draw(&Circle::new((x + 8, y), 8, BLACK.stroke_width(2))).map_err(e)?;
    legend.draw(&Text::new("breaks the bound (dashed)", (x + 22, y - 8), font)).map_err(e)?;
    let modes = modes(sweeps);
    let panels = body.split_evenly((1, modes.len().max(1)));
    for (area, &mode) in panels.iter().zip(&modes) {
        let mine: Vec<&Sweep> = sweeps.iter().filter(|s| s.mode == mode).collect();
        panel(area, mode, &mine).map_err(e)?;
    }
    root.present().map_err(e)?;
    Ok(())
}

fn panel<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, mode: Mode, sweeps: &[&Sweep]) -> std::result::Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    // The parameter values are spaced evenly (they are chosen, not continuous), labelled by value.
    let params: Vec<f64> = sweeps.first().map(|s| s.samples.iter().map(|p| p.param).collect()).unwrap_or_default();
    let (bound, _) = mode.bound();
    let (mut v0, mut v1) = (bound, bound);
    for s in sweeps {
        for p in &s.samples {
            if p.value.is_finite() {
                (v0, v1) = (v0.min(p.value), v1.max(p.value));
            }
        }
    }
    let pad = ((v1 - v0) * 0.08).max(0.01);
    let n = params.len().max(1) as f64;
    let mut c = ChartBuilder::on(area)
        .caption(mode.title(), ("sans-serif", 14))
        .margin(8)
        .x_label_area_size(34)
        .y_label_area_size(52)
        .build_cartesian_2d(-0.4..(n - 0.6), (v0 - pad)..(v1 + pad))?;
    let label = |v: &f64| {
        let i = v.round();
        if (v - i).abs() < 1e-6 && i >= 0.0 && (i as usize) < params.len() {
            format!("{}", params[i as usize])
        } else {
            String::new()
        }
    };
    c.configure_mesh().x_desc(mode.parameter()).y_desc(mode.measure()).label_style(("sans-serif", 12)).x_labels(params.len() + 1).x_label_formatter(&label).y_labels(6).light_line_style(WHITE).draw()?;
    c.draw_series(DashedLineSeries::new(vec![(-0.4, bound), (n - 0.6, bound)], 6, 4, BLACK.mix(0.7).stroke_width(1)))?;
    for s in sweeps {
        let col = method_color(s.method);
        let pts: Vec<(f64, f64, bool)> = s.samples.iter().enumerate().map(|(i, p)| (i as f64, p.value, p.holds)).collect();
        c.draw_series(LineSeries::new(pts.iter().map(|&(x, y, _)| (x, y)), col.stroke_width(2)))?;
        c.draw_series(pts.iter().map(|&(x, y, _)| Circle::new((x, y), 4, col.filled())))?;
        c.draw_series(pts.iter().filter(|p| !p.2).map(|&(x, y, _)| Circle::new((x, y), 8, BLACK.stroke_width(1))))?;
    }
    Ok(())
}
