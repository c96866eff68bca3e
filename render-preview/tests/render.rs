//! End-to-end tests: files built with the synthetic builder are rendered and compared with
//! the mesh reference, with golden images, and through the CLI.

use std::path::{Path, PathBuf};

use render_preview::reference::{render_reference, WorldMesh};
use render_preview::{metrics, render_file, synth, Error, Frame, RenderOptions, View, ViewPreset};
use sct_format::write::{write_scene_file, Scene, WriteOptions};

fn small(w: u32, h: u32) -> RenderOptions {
    RenderOptions { width: w, height: h, ..RenderOptions::default() }
}

fn sphere_file(dir: &Path) -> (PathBuf, WorldMesh) {
    let mesh = synth::uv_sphere([0.0, 0.0, 0.0], 1.0, 24, [0.8, 0.3, 0.2, 1.0]);
    let path = dir.join("sphere.sct");
    synth::write_mesh_sct(&mesh, 0.02, &path, &WriteOptions::default()).unwrap();
    (path, mesh)
}

fn reference_for(mesh: &WorldMesh, out: &render_preview::Rendered, opts: &RenderOptions) -> Frame {
    let view = View::new(&out.camera, out.near).unwrap();
    render_reference(mesh, &view, opts.shading, opts.background)
}

#[test]
fn sphere_matches_its_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let (path, mesh) = sphere_file(dir.path());
    let opts = small(160, 120);
    let out = render_file(&path, &opts).unwrap();
    assert!(out.stats.splats > 100);
    assert!(out.frame.covered() > 3000, "blank image? {}", out.frame.covered());
    let m = metrics::compare(&out.frame, &reference_for(&mesh, &out, &opts));
    assert!(m.psnr_db >= 30.0, "{m:?}");
    assert!(m.silhouette_iou >= 0.97, "{m:?}");
    assert!(m.hole_fraction < 0.001, "{m:?}");
}

/// A shared Stanford scan (skipped when the shared models are not present).
#[test]
fn bunny_matches_its_mesh_at_default_threshold() {
    let ply = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/models/scans/stanford-bunny-original-ply/bun_zipper_res2.ply");
    if !ply.exists() {
        eprintln!("skipping: {} not found", ply.display());
        return;
    }
    let mesh = WorldMesh::load(&ply).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bunny.sct");
    let (_, r) = mesh.bound().unwrap();
    synth::write_mesh_sct(&mesh, (r / 150.0) as f32, &path, &WriteOptions::default()).unwrap();
    // Splats thicken silhouettes by about half a pixel, so the image must be large enough
    // for the outline to stay a small part of the object (at 256² PSNR is about 28.5 dB).
    for view in [ViewPreset::Front, ViewPreset::Iso] {
        let opts = RenderOptions { view, ..small(512, 512) };
        let out = render_file(&path, &opts).unwrap();
        let m = metrics::compare(&out.frame, &reference_for(&mesh, &out, &opts));
        assert!(m.psnr_db >= 30.0, "{view:?} {m:?}");
        assert!(m.silhouette_iou >= 0.97, "{view:?} {m:?}");
    }
}

#[test]
fn close_up_beyond_leaf_resolution_has_no_holes() {
    let dir = tempfile::tempdir().unwrap();
    let (path, _) = sphere_file(dir.path());
    // Eye just outside the surface with a narrow field of view: leaves span many pixels.
    let opts = RenderOptions { eye: Some([0.0, 0.0, 1.05]), target: Some([0.0; 3]), fov_y_deg: 10.0, ..small(80, 60) };
    let out = render_file(&path, &opts).unwrap();
    assert_eq!(out.frame.covered(), 80 * 60, "holes in a close-up");
    assert!(out.stats.lod.leaf_splats > 0);
    // Only the blocks near the view were needed.
    assert!(out.stats.bytes_read < out.stats.file_size, "{} of {}", out.stats.bytes_read, out.stats.file_size);
}

#[test]
fn camera_inside_and_degenerate_cameras() {
    let dir = tempfile::tempdir().unwrap();
    let (path, _) = sphere_file(dir.path());
    let inside = RenderOptions { eye: Some([0.0, 0.0, 0.2]), target: Some([0.0, 0.0, -1.0]), ..small(64, 48) };
    let out = render_file(&path, &inside).unwrap();
    // Inside a closed sphere every surface faces away: back-face culling leaves the background.
    assert_eq!(out.frame.covered(), 0);
    let out = render_file(&path, &RenderOptions { backface_culling: false, ..inside.clone() }).unwrap();
    assert!(out.frame.covered() > 64 * 48 / 2, "the inside wall should show: {}", out.frame.covered());
    for bad in [
        RenderOptions { eye: Some([0.0; 3]), target: Some([0.0; 3]), ..small(64, 48) },
        RenderOptions { up: Some([0.0, 0.0, 1.0]), ..small(64, 48) },
        RenderOptions { fov_y_deg: 0.0, ..small(64, 48) },
        RenderOptions { width: 0, ..small(64, 48) },
    ] {
        assert!(matches!(render_file(&path, &bad), Err(Error::Camera(_))));
    }
}

#[test]
fn empty_tree_renders_background() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("empty.sct");
    // SceneTree::default() panics in level_count() (empty level_starts), so build it properly.
    let scene = Scene::single_tree(Default::default(), sct_format::SceneTree::from_bfs(Vec::new(), Vec::new()).unwrap());
    write_scene_file(&path, &scene, &WriteOptions::default()).unwrap();
    let out = render_file(&path, &small(32, 24)).unwrap();
    assert_eq!(out.stats.splats, 0);
    assert_eq!(out.frame.covered(), 0);
}

fn instance_scene(dir: &Path) -> PathBuf {
    let mesh = synth::uv_sphere([0.0, 0.0, 0.0], 1.0, 12, [0.9, 0.9, 0.9, 1.0]);
    let tree = synth::build_tree(synth::sample_mesh(&mesh, 0.08)).unwrap();
    let tints = [[255, 40, 40, 255], [40, 255, 40, 255], [40, 40, 255, 255]];
    let scene = synth::instance_grid(tree, 3, 3, 2.5, |i| Some(tints[i % 3])).unwrap();
    let path = dir.join("grid.sct");
    write_scene_file(&path, &scene, &WriteOptions::default()).unwrap();
    path
}

#[test]
fn instancing_and_tint_show_in_a_composed_scene() {
    let dir = tempfile::tempdir().unwrap();
    let path = instance_scene(dir.path());
    let opts = RenderOptions { view: ViewPreset::Top, shading: render_preview::Shading::Flat, ..small(120, 120) };
    let out = render_file(&path, &opts).unwrap();
    // From the top, the 3×3 grid shows instance i at column i % 3: red, green, blue.
    let f = &out.frame;
    let mut dominant = [0usize; 3];
    for c in f.color.iter().zip(&f.depth).filter(|(_, d)| d.is_finite()).map(|(c, _)| c) {
        let k = (0..3).max_by_key(|&k| c[k]).unwrap();
        dominant[k] += 1;
    }
    assert!(dominant.iter().all(|&n| n > 300), "each tint should cover many pixels: {dominant:?}");
    // Sample the top of each sphere of the middle row (z = 0) where it projects.
    let view = View::new(&out.camera, out.near).unwrap();
    let at = |x: f64| {
        let p = view.project(view.to_camera([x, 1.0, 0.0]));
        f.color[p[1] as usize * 120 + p[0] as usize]
    };
    let (l, m, r) = (at(-2.5), at(0.0), at(2.5));
    assert!(l[0] > 150 && l[1] < 100, "left instance red: {l:?}");
    assert!(m[1] > 150 && m[0] < 100, "middle instance green: {m:?}");
    assert!(r[2] > 150 && r[0] < 100, "right instance blue: {r:?}");
}

/// Compares with tests/golden/NAME.png; `UPDATE_GOLDEN=1` rewrites the golden file.
fn golden(name: &str, frame: &Frame) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden").join(format!("{name}.png"));
    if std::env::var_os("UPDATE_GOLDEN").is_some() {
        render_preview::write_png(&path, frame).unwrap();
        return;
    }
    let g = image::open(&path).unwrap_or_else(|e| panic!("{}: {e} (run with UPDATE_GOLDEN=1 to create)", path.display())).to_rgb8();
    assert_eq!((g.width() as usize, g.height() as usize), (frame.width, frame.height));
    let img = frame.to_rgb_image();
    let mut bad = 0usize;
    let mut sum = 0u64;
    for (a, b) in img.pixels().zip(g.pixels()) {
        let d = (0..3).map(|k| (a[k] as i32 - b[k] as i32).unsigned_abs()).max().unwrap_or(0);
        sum += d as u64;
        if d > 24 {
            bad += 1;
        }
    }
    let n = frame.width * frame.height;
    assert!(bad * 100 <= n, "{name}: {bad} of {n} pixels differ from the golden image");
    assert!((sum as f64 / n as f64) < 2.0, "{name}: mean difference {}", sum as f64 / n as f64);
}

#[test]
fn golden_images() {
    let dir = tempfile::tempdir().unwrap();
    let (path, _) = sphere_file(dir.path());
    golden("sphere_iso", &render_file(&path, &RenderOptions { view: ViewPreset::Iso, ..small(96, 72) }).unwrap().frame);
    let grid = instance_scene(dir.path());
    golden("grid_iso", &render_file(&grid, &RenderOptions { view: ViewPreset::Iso, ..small(96, 72) }).unwrap().frame);
}

#[test]
fn cli_exit_codes_and_json() {
    let exe = env!("CARGO_BIN_EXE_sct-render-preview");
    let dir = tempfile::tempdir().unwrap();
    let (path, _) = sphere_file(dir.path());
    let png = dir.path().join("out.png");
    let run = |args: &[&str]| std::process::Command::new(exe).args(args).output().unwrap();
    let ok = run(&[path.to_str().unwrap(), "-o", png.to_str().unwrap(), "--width", "64", "--height", "48", "--json"]);
    assert_eq!(ok.status.code(), Some(0), "{}", String::from_utf8_lossy(&ok.stderr));
    let v: serde_json::Value = serde_json::from_slice(&ok.stdout).unwrap();
    assert!(v["splats"].as_u64().unwrap() > 0 && v["bytes_read"].as_u64().unwrap() <= v["file_size"].as_u64().unwrap());
    assert!(v["seconds"]["total"].as_f64().is_some());
    assert_eq!(image::open(&png).unwrap().width(), 64);
    // Missing file: I/O (2). Garbage file: invalid input (1). Bad flag: usage (2).
    let missing = dir.path().join("nope.sct");
    assert_eq!(run(&[missing.to_str().unwrap(), "-o", png.to_str().unwrap()]).status.code(), Some(2));
    let garbage = dir.path().join("garbage.sct");
    std::fs::write(&garbage, b"this is not an SCT file at all, not even close........").unwrap();
    let g = run(&[garbage.to_str().unwrap(), "-o", png.to_str().unwrap()]);
    assert_eq!(g.status.code(), Some(1), "{}", String::from_utf8_lossy(&g.stderr));
    assert_eq!(run(&[path.to_str().unwrap(), "-o", png.to_str().unwrap(), "--view", "sideways"]).status.code(), Some(2));
    // Degenerate camera: invalid input, one clear message.
    let d = run(&[path.to_str().unwrap(), "-o", png.to_str().unwrap(), "--eye", "0,0,0", "--target", "0,0,0"]);
    assert_eq!(d.status.code(), Some(1));
    let msg = String::from_utf8_lossy(&d.stderr);
    assert!(msg.contains("camera") && msg.lines().count() == 1, "{msg}");
}
