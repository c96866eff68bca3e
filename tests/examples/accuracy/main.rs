//! The accuracy table of BENCHMARKS.md: every mesh and point cloud of the shared library
//! (not `nasty/`) converted at default settings, previewed at the default and the iso view
//! against its own mesh, and measured the way a user would measure it.
//!
//! ```sh
//! scripts/accuracy.sh                   # builds the binaries, then runs this
//! cargo run --release -p sct-integration-tests --example accuracy -- --out out/accuracy
//! ```
//!
//! One row per model: triangles, samples, leaf samples per pixel the model covers in the
//! default view, SCT bytes, convert and render seconds, foreground PSNR and SSIM, silhouette
//! IoU, missing and extra pixel fractions (worse of the two views), coverage of the mesh's
//! visible surface by the leaf spheres (`sct-inspect --against --exclude-alpha-dropped`),
//! and the max and mean distance from a leaf centre to the surface in voxel units. Prints Markdown on stdout; files go to `--out`.

mod surface;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use serde_json::Value;

struct Args {
    out: PathBuf,
    models: PathBuf,
}

fn args() -> Args {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).parent().map(Path::to_path_buf).unwrap_or_default();
    let mut a = Args { out: repo.join("out/accuracy"), models: repo.join("../shared/models") };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let v = it.next().unwrap_or_else(|| fail(&format!("{flag} needs a value")));
        match flag.as_str() {
            "--out" => a.out = PathBuf::from(v),
            "--models" => a.models = PathBuf::from(v),
            _ => fail(&format!("unknown flag {flag} (flags: --out DIR, --models DIR)")),
        }
    }
    a
}

fn fail(msg: &str) -> ! {
    eprintln!("accuracy: {msg}");
    std::process::exit(2)
}

/// The release binaries beside this example (target/release/examples/accuracy).
fn bin(name: &str) -> PathBuf {
    let exe = std::env::current_exe().unwrap_or_else(|e| fail(&e.to_string()));
    let dir = exe.parent().and_then(Path::parent).unwrap_or_else(|| fail("no target dir"));
    let p = dir.join(name);
    if !p.is_file() {
        fail(&format!("{} missing: run `cargo build --release --workspace` first (scripts/accuracy.sh does)", p.display()));
    }
    p
}

/// Runs a tool once: (wall seconds, JSON on stdout, exit status, stderr).
fn run(tool: &str, args: &[&str]) -> (f64, Value, i32, String) {
    let t = Instant::now();
    let out = Command::new(bin(tool)).args(args).output().unwrap_or_else(|e| fail(&format!("{tool}: {e}")));
    let secs = t.elapsed().as_secs_f64();
    let json = serde_json::from_slice(&out.stdout).unwrap_or(Value::Null);
    (secs, json, out.status.code().unwrap_or(-1), String::from_utf8_lossy(&out.stderr).trim().to_string())
}

/// The mesh and point-cloud files of the library: every `.obj .gltf .glb .ply` outside
/// `nasty/`, one glTF variant per model (the binary one when both are there).
fn models(root: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        let Ok(rd) = std::fs::read_dir(&dir) else { continue };
        for e in rd.flatten() {
            let p = e.path();
            if p.is_dir() {
                if p.file_name().is_some_and(|n| n != "nasty") {
                    stack.push(p);
                }
                continue;
            }
            let ext = p.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
            if matches!(ext.as_deref(), Some("obj" | "gltf" | "glb" | "ply")) {
                found.push(p);
            }
        }
    }
    // A model folder with glTF-Binary keeps only that variant.
    let has_binary = |p: &Path| p.parent().and_then(Path::parent).is_some_and(|m| m.join("glTF-Binary").is_dir());
    found.retain(|p| !(p.extension().is_some_and(|e| e == "gltf") && has_binary(p)));
    found.sort();
    found
}

fn n(v: &Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

fn fmt_int(x: f64) -> String {
    if !x.is_finite() {
        return "–".into();
    }
    let s = format!("{x:.0}");
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i) % 3 == 0 {
            out.push(',');
        }
        out.push(c);
    }
    out
}

fn fmt(x: f64, digits: usize) -> String {
    if x.is_finite() {
        format!("{x:.digits$}")
    } else {
        "–".into()
    }
}

/// The voxel size recorded in a file's provenance (the sampling step's `voxel_size`,
/// wherever the generator nests it).
fn voxel_size(v: &Value) -> Option<f64> {
    match v {
        Value::Object(m) => m.get("voxel_size").and_then(Value::as_f64).or_else(|| m.values().find_map(voxel_size)),
        Value::Array(a) => a.iter().find_map(voxel_size),
        _ => None,
    }
}

/// Per view metrics of one preview against the mesh.
#[derive(Default, Clone, Copy)]
struct View {
    psnr: f64,
    ssim: f64,
    iou: f64,
    missing: f64,
    extra: f64,
    secs: f64,
    covered_px: f64,
}

fn preview(sct: &str, mesh: &str, png: &str, view: &str) -> Result<View, String> {
    let (secs, j, code, err) = run("sct-render-preview", &[sct, "-o", png, "--reference", mesh, "--view", view, "--json"]);
    if code != 0 {
        return Err(format!("render-preview exit {code}: {err}"));
    }
    let m = &j["metrics"];
    Ok(View {
        psnr: n(&m["fg_psnr_db"]),
        ssim: n(&m["fg_ssim"]),
        iou: n(&m["silhouette_iou"]),
        missing: n(&m["missing_fraction"]),
        extra: n(&m["extra_fraction"]),
        secs,
        covered_px: n(&m["reference_pixels"]),
    })
}

struct Row {
    name: String,
    triangles: f64,
    samples: f64,
    per_px: f64,
    bytes: f64,
    convert_s: f64,
    views: [View; 2],
    coverage: f64,
    sample_dist: Option<(f64, f64, usize)>,
    dist: Option<(f64, f64, usize)>,
    note: String,
}

fn measure(model: &Path, root: &Path, out: &Path) -> Row {
    let rel = model.strip_prefix(root).unwrap_or(model).display().to_string();
    let stem = rel.replace(['/', ' '], "_");
    let mut row = Row {
        name: rel,
        triangles: f64::NAN,
        samples: f64::NAN,
        per_px: f64::NAN,
        bytes: f64::NAN,
        convert_s: f64::NAN,
        views: [View::default(); 2],
        coverage: f64::NAN,
        sample_dist: None,
        dist: None,
        note: String::new(),
    };
    let sct = out.join(format!("{stem}.sct")).display().to_string();
    let mesh = model.display().to_string();
    let (secs, rep, code, err) = run("sct-build-tree", &[&mesh, "-o", &sct, "--json"]);
    row.convert_s = secs;
    if code != 0 {
        row.note = format!("conversion refused (exit {code}): {}", err.lines().last().unwrap_or(""));
        return row;
    }
    // A mesh input reports its sampling and its build; a point cloud the same.
    row.samples = n(&rep["build"]["leaves"]);
    row.bytes = n(&rep["build"]["bytes"]);
    row.triangles = n(&rep["sampling"]["triangles_instanced"]);
    for (k, view) in ["front", "iso"].into_iter().enumerate() {
        let png = out.join(format!("{stem}.{view}.png")).display().to_string();
        match preview(&sct, &mesh, &png, view) {
            Ok(v) => row.views[k] = v,
            Err(e) => row.note = e,
        }
    }
    row.per_px = row.samples / row.views[0].covered_px;
    // The surface the alpha mode keeps: a fully transparent panel is no surface to cover.
    let (_, cov, _, _) = run("sct-inspect", &[&sct, "--against", &mesh, "--exclude-alpha-dropped", "--json", "--min-coverage", "0"]);
    row.coverage = n(&cov["coverage"]["fraction"]);
    let voxel = std::fs::read(&sct)
        .ok()
        .and_then(|b| sct_format::read::SctReader::from_bytes(b, &sct_format::Limits::default()).ok())
        .and_then(|r| voxel_size(&serde_json::to_value(r.generator()).unwrap_or(Value::Null)));
    // The samples as the voxelizer makes them (the same default settings), before the
    // tree's codec quantizes their positions.
    let smp = out.join(format!("{stem}.samples")).display().to_string();
    let (_, _, code, err) = run("sct-voxelize", &[&mesh, "-o", &smp, "--json"]);
    let samples = if code == 0 { surface::samples(Path::new(&smp)) } else { Err(format!("sct-voxelize exit {code}: {err}")) };
    let _ = std::fs::remove_file(&smp);
    match (surface::mesh_triangles(model), surface::leaves(Path::new(&sct)), samples, voxel) {
        (Ok(Some(tris)), Ok(leaves), Ok(samples), Some(h)) => {
            if !row.triangles.is_finite() {
                row.triangles = tris.len() as f64;
            }
            let grid = surface::SurfaceGrid::new(tris, 2.0 * h);
            row.sample_dist = Some(surface::centre_distances(&samples, &grid, h));
            row.dist = Some(surface::centre_distances(&leaves, &grid, h));
        }
        (Ok(None), _, _, _) => {
            row.triangles = 0.0;
            row.note = "point cloud: no surface to measure distances to".into();
        }
        (Err(e), _, _, _) | (_, Err(e), _, _) | (_, _, Err(e), _) => row.note = e,
        (_, _, _, None) => row.note = "no voxel size in the provenance".into(),
    }
    row
}

fn main() {
    let a = args();
    std::fs::create_dir_all(&a.out).unwrap_or_else(|e| fail(&format!("{}: {e}", a.out.display())));
    let models = models(&a.models);
    if models.is_empty() {
        fail(&format!("no models under {}", a.models.display()));
    }
    let mut rows = Vec::new();
    for m in &models {
        eprintln!("accuracy: {}", m.display());
        rows.push(measure(m, &a.models, &a.out));
    }
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let load = std::fs::read_to_string("/proc/loadavg").ok().and_then(|l| l.split_whitespace().next().map(str::to_string)).unwrap_or_else(|| "?".into());
    println!("Regenerated by `scripts/accuracy.sh` ({cores} cores, load average {load} when it finished). Default settings throughout; PSNR, SSIM, IoU, missing and extra are the worse of the front and iso views (1280 × 720); \"per px\" is leaf samples per pixel the mesh covers in the front view; distances are from centres to the mesh surface in voxels, of the samples (\"sample\", as the voxelizer makes them) and of the SCT file's leaves (\"leaf\", after the codec quantizes positions); \"far\" counts leaves whose sphere reaches no triangle; coverage is of the surface the alpha mode keeps (`sct-inspect --against --exclude-alpha-dropped`).\n");
    println!("| model | triangles | samples | per px | SCT bytes | convert s | render s | fg PSNR dB | fg SSIM | IoU | missing | extra | coverage | sample max | sample mean | leaf max | leaf mean | far | note |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|");
    let worst = |f: fn(&View) -> f64, lower_is_worse: bool, r: &Row| {
        let (a, b) = (f(&r.views[0]), f(&r.views[1]));
        if lower_is_worse {
            a.min(b)
        } else {
            a.max(b)
        }
    };
    for r in &rows {
        let (dmax, dmean, far) = r.dist.map_or(("–".into(), "–".into(), "–".into()), |(x, m, f)| (fmt(x, 4), fmt(m, 4), f.to_string()));
        let (smax, smean) = r.sample_dist.map_or(("–".into(), "–".into()), |(x, m, f)| (fmt(x, 4), format!("{}{}", fmt(m, 4), if f > 0 { format!(" ({f} far)") } else { String::new() })));
        println!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            r.name,
            fmt_int(r.triangles),
            fmt_int(r.samples),
            fmt(r.per_px, 2),
            fmt_int(r.bytes),
            fmt(r.convert_s, 2),
            fmt(r.views[0].secs.max(r.views[1].secs), 2),
            fmt(worst(|v| v.psnr, true, r), 1),
            fmt(worst(|v| v.ssim, true, r), 3),
            fmt(worst(|v| v.iou, true, r), 3),
            fmt(worst(|v| v.missing, false, r), 3),
            fmt(worst(|v| v.extra, false, r), 3),
            fmt(r.coverage, 4),
            smax,
            smean,
            dmax,
            dmean,
            far,
            r.note
        );
    }
    let pass = |r: &Row| worst(|v| v.iou, true, r) >= 0.97 && worst(|v| v.psnr, true, r) >= 25.0;
    let ok = rows.iter().filter(|r| pass(r)).count();
    println!("\n{ok} of {} models reach IoU ≥ 0.97 and foreground PSNR ≥ 25 dB at both views.", rows.len());
}
