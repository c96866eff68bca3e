//! Speed–accuracy sweep: each model rendered over a series of `--pixel-error` values,
//! timed (open + refine + rasterize, best of N) and compared with its mesh reference;
//! charted with plotters as time against foreground PSNR, one line per model (PNG and SVG).

use std::path::{Path, PathBuf};

use plotters::prelude::*;

use crate::error::{Error, Result};
use crate::metrics::{self, Metrics};
use crate::reference::{render_reference_bounded, WorldMesh};
use crate::{render_file, RenderOptions, View};

/// The chart font (DejaVu Sans Mono, Bitstream Vera licence: see assets/).
static FONT: &[u8] = include_bytes!("../assets/DejaVuSansMono.ttf");

/// One rendered threshold.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SweepPoint {
    /// Threshold.
    pub pixel_error: f32,
    /// Best wall time over the repetitions, seconds (open + refine + raster).
    pub seconds: f64,
    /// Splats drawn.
    pub splats: u64,
    /// Bytes read.
    pub bytes_read: u64,
    /// Accuracy against the mesh.
    pub metrics: Metrics,
}

/// One model's curve.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SweepModel {
    /// SCT file.
    pub model: PathBuf,
    /// Reference mesh.
    pub mesh: PathBuf,
    /// File size.
    pub file_size: u64,
    /// Points in threshold order.
    pub points: Vec<SweepPoint>,
}

/// Runs the sweep.
pub fn run(models: &[(PathBuf, PathBuf)], pixel_errors: &[f32], repeat: u32, base: &RenderOptions) -> Result<Vec<SweepModel>> {
    let mut out = Vec::new();
    for (model, mesh_path) in models {
        let mut mesh = None::<WorldMesh>;
        let mut reference = None;
        let mut points = Vec::new();
        let mut file_size = 0;
        for &pe in pixel_errors {
            let opts = RenderOptions { pixel_error: pe, ..base.clone() };
            let mut best = None::<crate::Rendered>;
            for _ in 0..repeat.max(1) {
                let r = render_file(model, &opts)?;
                if best.as_ref().is_none_or(|b| r.stats.seconds.total < b.stats.seconds.total) {
                    best = Some(r);
                }
            }
            let Some(r) = best else { continue };
            file_size = r.stats.file_size;
            let refr = match &reference {
                Some(f) => f,
                None => {
                    // Loaded after the first render, whose file's provenance says how the
                    // textures were bound when it was sampled.
                    let m = match &mesh {
                        Some(m) => m,
                        None => mesh.insert(crate::reference::load_for(model, mesh_path, &r.provenance, None)?.0),
                    };
                    let view = View::new(&r.camera, r.near)?;
                    reference.insert(render_reference_bounded(m, &view, opts.shading, opts.background, opts.max_splat_pixels / crate::reference::REFERENCE_PIXEL_COST)?)
                }
            };
            points.push(SweepPoint {
                pixel_error: pe,
                seconds: r.stats.seconds.total,
                splats: r.stats.splats,
                bytes_read: r.stats.bytes_read,
                metrics: metrics::compare(&r.frame, refr),
            });
        }
        out.push(SweepModel { model: model.clone(), mesh: mesh_path.clone(), file_size, points });
    }
    Ok(out)
}

/// Writes `base.png`, `base.svg` and `base.json`.
pub fn write_outputs(result: &[SweepModel], base: &Path) -> Result<()> {
    let with = |ext: &str| {
        let mut p = base.as_os_str().to_owned();
        p.push(format!(".{ext}"));
        PathBuf::from(p)
    };
    let json = serde_json::to_vec_pretty(result).map_err(|e| Error::Invalid(e.to_string()))?;
    let jp = with("json");
    sct_format::atomic::write_atomic(&jp, |w| {
        use std::io::Write;
        w.write_all(&json).map_err(sct_format::Error::from)
    })
    .map_err(|e| Error::Output { path: jp.clone(), message: e.to_string() })?;
    let png = with("png");
    let svg_path = with("svg");
    let mut svg = String::new();
    chart(result, SVGBackend::with_string(&mut svg, (900, 600))).map_err(|m| Error::Output { path: svg_path.clone(), message: m })?;
    sct_format::atomic::write_atomic(&svg_path, |w| {
        use std::io::Write;
        w.write_all(svg.as_bytes()).map_err(sct_format::Error::from)
    })
    .map_err(|e| Error::Output { path: svg_path.clone(), message: e.to_string() })?;
    let mut rgb = vec![0u8; 900 * 600 * 3];
    chart(result, BitMapBackend::with_buffer(&mut rgb, (900, 600))).map_err(|m| Error::Output { path: png.clone(), message: m })?;
    let img = image::RgbImage::from_raw(900, 600, rgb).ok_or_else(|| Error::Output { path: png.clone(), message: "buffer size".into() })?;
    crate::write_rgb_png(&png, &img)
}

fn chart<DB: DrawingBackend>(result: &[SweepModel], backend: DB) -> std::result::Result<(), String> {
    // Registering twice is harmless (the map entry is replaced).
    plotters::style::register_font("sans-serif", FontStyle::Normal, FONT).map_err(|_| "invalid chart font".to_string())?;
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    let root = backend.into_drawing_area();
    root.fill(&WHITE).map_err(e)?;
    let pts = result.iter().flat_map(|m| m.points.iter());
    let (mut t0, mut t1, mut p0, mut p1) = (f64::INFINITY, 0f64, f64::INFINITY, f64::NEG_INFINITY);
    for p in pts {
        t0 = t0.min(p.seconds * 1e3);
        t1 = t1.max(p.seconds * 1e3);
        // Unscored points (an empty image) are left off the chart.
        if let Some(db) = p.metrics.fg_psnr_db {
            p0 = p0.min(db);
            p1 = p1.max(db);
        }
    }
    if !t0.is_finite() || !p0.is_finite() {
        (t0, t1, p0, p1) = (1.0, 10.0, 0.0, 40.0);
    }
    let (t0, t1) = ((t0 * 0.8).max(1e-3), (t1 * 1.25).max(t0 * 2.0));
    let (p0, p1) = ((p0 - 2.0).floor(), (p1 + 2.0).ceil());
    let mut c = ChartBuilder::on(&root)
        .caption("render-preview: speed vs accuracy (labels: --pixel-error)", ("sans-serif", 20))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d((t0..t1).log_scale(), p0..p1)
        .map_err(e)?;
    c.configure_mesh()
        .x_desc("wall time per frame, ms (open + refine + raster, log scale)")
        .y_desc("foreground PSNR vs mesh reference, dB")
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(e)?;
    for (i, m) in result.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        let name = m.model.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let scored: Vec<&SweepPoint> = m.points.iter().filter(|p| p.metrics.fg_psnr_db.is_some()).collect();
        let line: Vec<(f64, f64)> = scored.iter().map(|p| (p.seconds * 1e3, p.metrics.fg_psnr_db.unwrap_or(0.0))).collect();
        c.draw_series(LineSeries::new(line.clone(), color.stroke_width(2)))
            .map_err(e)?
            .label(name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2)));
        c.draw_series(line.iter().zip(&scored).map(|(&(x, y), p)| {
            EmptyElement::at((x, y))
                + Circle::new((0, 0), 4, color.filled())
                + Text::new(format!("{}", p.pixel_error), (6, -14), ("sans-serif", 12))
        }))
        .map_err(e)?;
    }
    c.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).label_font(("sans-serif", 14)).draw().map_err(e)?;
    root.present().map_err(e)?;
    Ok(())
}
