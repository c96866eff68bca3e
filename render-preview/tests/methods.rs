//! The preview methods behind `--method`: `gauss` against the mesh reference on real models
//! (with floors measured when they were set), through groups, instances, tints and inlines,
//! its determinism, its documented failure mode (background leaking through blended
//! kernels), and the work counters in `--json`.

mod common;
use common::{shared, reference_for, synth_shared};

use std::path::{Path, PathBuf};

use render_preview::reference::WorldMesh;
use render_preview::{metrics, render_file, synth, Method, RenderOptions, Shading, View, ViewPreset, Weighting};
use sct_format::graph::GraphNode;
use sct_format::write::{write_scene_file, Scene, WriteOptions};

fn small(w: u32, h: u32) -> RenderOptions {
    RenderOptions { width: w, height: h, ..RenderOptions::default() }
}

fn gauss(o: RenderOptions) -> RenderOptions {
    RenderOptions { method: Method::Gauss, ..o }
}

/// Floors for `gauss` against the mesh at 384², front and iso, default settings; leaves at
/// 1/200 of the bounding radius. Measured when set (front / iso), `zbuffer` in brackets:
/// - fuze: PSNR 32.61 / 30.10 dB (34.31 / 29.63), SSIM 0.940 / 0.926 (0.944 / 0.921),
///   IoU 0.982 / 0.976 (0.986 / 0.978)
/// - Duck: PSNR 31.29 / 30.25 dB (30.56 / 30.17), SSIM 0.910 / 0.927 (0.952 / 0.955),
///   IoU 0.995 / 0.997 (0.995 / 0.997)
/// - bunny (res2): PSNR 28.24 / 27.82 dB (28.29 / 27.33), SSIM 0.893 / 0.873 (0.934 / 0.909),
///   IoU 0.995 / 0.994 (0.996 / 0.994)
///
/// Each floor is the lower view's figure less 1 dB, 0.01 SSIM and 0.005 IoU.
const MODELS: [(&str, f64, f64, f64); 3] = [
    ("textured-obj/fuze/fuze.obj", 29.1, 0.916, 0.971),
    ("gltf/Duck/glTF-Binary/Duck.glb", 29.2, 0.90, 0.99),
    ("scans/stanford-bunny-original-ply/bun_zipper_res2.ply", 26.8, 0.863, 0.989),
];

#[test]
fn gauss_matches_the_mesh_on_real_models() {
    let mut failed = Vec::new();
    for (rel, min_psnr, min_ssim, min_iou) in MODELS {
        let Some(path) = shared(rel) else { continue };
        let mesh = WorldMesh::load(&path).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let sct = dir.path().join("m.sct");
        let (_, r) = mesh.bound().unwrap();
        synth::write_mesh_sct(&mesh, (r / 200.0) as f32, &sct, &WriteOptions::default()).unwrap();
        for view in [ViewPreset::Front, ViewPreset::Iso] {
            let base = RenderOptions { view, ..small(384, 384) };
            let z = render_file(&sct, &base).unwrap();
            let refr = reference_for(&mesh, &z, &base);
            let mz = metrics::compare(&z.frame, &refr);
            let g = render_file(&sct, &gauss(base.clone())).unwrap();
            let mg = metrics::compare(&g.frame, &refr);
            eprintln!(
                "{rel} {view:?}: gauss {:.2} dB SSIM {:.4} IoU {:.4} | zbuffer {:.2} dB SSIM {:.4} IoU {:.4}",
                mg.fg_psnr_db.unwrap(),
                mg.fg_ssim.unwrap(),
                mg.silhouette_iou,
                mz.fg_psnr_db.unwrap(),
                mz.fg_ssim.unwrap(),
                mz.silhouette_iou
            );
            if mg.fg_psnr_db.unwrap() < min_psnr || mg.fg_ssim.unwrap() < min_ssim || mg.silhouette_iou < min_iou {
                failed.push(format!("{rel} {view:?} {mg:?}"));
            }
            // Same cut, same counters up to the compositing.
            assert_eq!(g.stats.splats, z.stats.splats);
            assert_eq!(g.stats.work.nodes_visited, z.stats.work.nodes_visited);
            assert!(g.stats.work.fragments >= g.stats.work.covered_pixels, "{:?}", g.stats.work);
        }
    }
    assert!(failed.is_empty(), "below the floors:\n{}", failed.join("\n"));
}

/// The normalised weighting (EQ 2) against blending (EQ 1) on the bunny, front, 384²: 28.05
/// vs 28.24 dB, SSIM 0.951 vs 0.893 when measured (no leak: much higher SSIM).
#[test]
fn normalized_weighting_removes_the_leak_at_equal_psnr() {
    let dir = tempfile::tempdir().unwrap();
    let Some((mesh, sct)) = synth_shared("scans/stanford-bunny-original-ply/bun_zipper_res2.ply", dir.path()) else { return };
    let base = gauss(small(384, 384));
    let blend = render_file(&sct, &base).unwrap();
    let refr = reference_for(&mesh, &blend, &base);
    let norm_opts = RenderOptions { gauss: render_preview::GaussOptions { weighting: Weighting::Normalized, ..base.gauss }, ..base.clone() };
    let norm = render_file(&sct, &norm_opts).unwrap();
    let (mb, mn) = (metrics::compare(&blend.frame, &refr), metrics::compare(&norm.frame, &refr));
    eprintln!("blend {mb:?}\nnormalized {mn:?}");
    assert!(mn.fg_psnr_db.unwrap() >= mb.fg_psnr_db.unwrap() - 0.5, "{mn:?} vs {mb:?}");
    assert!(mn.fg_ssim.unwrap() >= mb.fg_ssim.unwrap() + 0.03, "{mn:?} vs {mb:?}");
    assert!(mn.silhouette_iou >= 0.99, "{mn:?}");
}

fn sphere_file(dir: &Path) -> PathBuf {
    let mesh = synth::uv_sphere([0.0, 0.0, 0.0], 1.0, 24, [0.8, 0.3, 0.2, 1.0]);
    let path = dir.join("sphere.sct");
    synth::write_mesh_sct(&mesh, 0.02, &path, &WriteOptions::default()).unwrap();
    path
}

#[test]
fn gauss_draws_groups_instances_tints_and_inlines() {
    let dir = tempfile::tempdir().unwrap();
    // A 3×3 grid of tinted instances under a group tree, seen from the top.
    let mesh = synth::uv_sphere([0.0, 0.0, 0.0], 1.0, 12, [0.9, 0.9, 0.9, 1.0]);
    let tree = synth::build_tree(synth::sample_mesh(&mesh, 0.08)).unwrap();
    let tints = [[255, 40, 40, 255], [40, 255, 40, 255], [40, 40, 255, 255]];
    let scene = synth::instance_grid(tree, 3, 3, 2.5, |i| Some(tints[i % 3])).unwrap();
    let grid = dir.path().join("grid.sct");
    write_scene_file(&grid, &scene, &WriteOptions::default()).unwrap();
    let opts = gauss(RenderOptions { view: ViewPreset::Top, shading: Shading::Flat, ..small(120, 120) });
    let out = render_file(&grid, &opts).unwrap();
    let f = &out.frame;
    let view = View::new(&out.camera, out.near).unwrap();
    let at = |x: f64| {
        let p = view.project(view.to_camera([x, 1.0, 0.0]));
        f.color[p[1] as usize * 120 + p[0] as usize]
    };
    let (l, m, r) = (at(-2.5), at(0.0), at(2.5));
    assert!(l[0] > 150 && l[1] < 100, "left instance red: {l:?}");
    assert!(m[1] > 150 && m[0] < 100, "middle instance green: {m:?}");
    assert!(r[2] > 150 && r[0] < 100, "right instance blue: {r:?}");
    // The same cut through the depth buffer covers the same pixels, nearly.
    let z = render_file(&grid, &RenderOptions { method: Method::Zbuffer, ..opts.clone() }).unwrap();
    let m = metrics::compare(&out.frame, &z.frame);
    assert!(m.silhouette_iou > 0.97, "{m:?}");
    // An inline draws exactly what its target draws.
    let inner = sphere_file(dir.path());
    let r = sct_format::SctReader::open(&inner, &sct_format::Limits::default()).unwrap();
    let bound = r.trees()[0].header.root;
    let hash = *blake3::hash(&std::fs::read(&inner).unwrap()).as_bytes();
    let outer = dir.path().join("outer.sct");
    let scene = Scene {
        generator: Default::default(),
        graph: sct_format::graph::SceneGraph { nodes: vec![GraphNode::Inline { path: "sphere.sct".into(), hash, bound }], root: 0 },
        trees: vec![],
    };
    write_scene_file(&outer, &scene, &WriteOptions::default()).unwrap();
    let o = gauss(RenderOptions { eye: Some([1.0, 2.0, 3.0]), target: Some([0.0; 3]), ..small(80, 60) });
    let (a, b) = (render_file(&inner, &o).unwrap(), render_file(&outer, &o).unwrap());
    assert!(a.frame.covered() > 1000);
    assert_eq!(a.frame, b.frame);
}

#[test]
fn gauss_is_deterministic_across_runs_and_threads() {
    let dir = tempfile::tempdir().unwrap();
    let path = sphere_file(dir.path());
    let opts = gauss(RenderOptions { view: ViewPreset::Iso, ..small(200, 150) });
    let a = render_file(&path, &opts).unwrap();
    let b = render_file(&path, &opts).unwrap();
    assert_eq!(a.frame, b.frame);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let c = pool.install(|| render_file(&path, &opts)).unwrap();
    assert_eq!(a.frame, c.frame);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(4).build().unwrap();
    let d = pool.install(|| render_file(&path, &opts)).unwrap();
    assert_eq!(a.frame, d.frame);
}

/// Coconu & Hege §5.4: "alpha-blending does not guarantee perfect opacity: a small amount of
/// background color also contributes". A white plate 0.3 in front of a black one, both
/// facing the eye, flat shading, leaves of 0.4 px; inside the white plate (3 px from its
/// outline) the luma drop (8-bit) is measured per `--pixel-error` 0.5, 1, 2, 4. When set:
/// - blending: a mean drop of 4.7–4.8 everywhere (the black behind shows by about 2 %), at
///   most 105 at one pixel, and 0.00–0.07 % of pixels darker by more than 64;
/// - normalised weighting: mean 0.02–0.30, 0.00–0.04 % darker by more than 64;
/// - the depth buffer: 0.07 / 0.5 / 1.8 / 2.7 % of pixels at pixel error 0.5 / 1 / 2 / 4 show
///   the black plate outright (cracks between internal splats drawn at `AREA_COVER ×` their
///   equal-area radius, which `raster::fill_holes` does not close because the plate behind
///   covers them; 4.6–5.3 % before `raster::fill_depth_pits` closed the one-pixel pits, and
///   1.5 / 1.4 / 3.1 / 3.9 % with one sample a pixel and flat discs).
///
/// The bounds are those figures with a margin.
const LEAK_PIXEL_ERRORS: [f32; 4] = [0.5, 1.0, 2.0, 4.0];

/// See [`gauss_leaks_the_layer_behind_within_a_bound`]: the depth buffer's share of front
/// plate pixels showing the black plate, after `raster::fill_depth_pits`, at pixel error ≤ 1
/// and above (measured 0.5 % and 2.7 % at most; 4.6–5.3 % without it).
const ZBUFFER_CRACKS: [f64; 2] = [0.01, 0.035];

#[test]
fn gauss_leaks_the_layer_behind_within_a_bound() {
    let dir = tempfile::tempdir().unwrap();
    let q = |z: f32, h: f32| [[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]];
    let mesh = synth::quads(&[(q(0.0, 1.0), [1.0, 1.0, 1.0, 1.0]), (q(-0.3, 2.0), [0.0, 0.0, 0.0, 1.0])]);
    let sct = dir.path().join("plates.sct");
    synth::write_mesh_sct(&mesh, 0.01, &sct, &WriteOptions::default()).unwrap();
    let base = RenderOptions { shading: Shading::Flat, eye: Some([0.0, 0.0, 4.0]), target: Some([0.0; 3]), background: [0, 0, 0], ..small(160, 160) };
    let leak = |opts: &RenderOptions| {
        let out = render_file(&sct, opts).unwrap();
        let view = View::new(&out.camera, out.near).unwrap();
        let [x0, y0] = view.project(view.to_camera([-1.0, 1.0, 0.0]));
        let [x1, y1] = view.project(view.to_camera([1.0, -1.0, 0.0]));
        let f = &out.frame;
        if let Some(d) = std::env::var_os("DUMP") {
            render_preview::write_png(&Path::new(&d).join(format!("leak-{:?}-{:?}-{}.png", opts.method, opts.gauss.weighting, opts.pixel_error)), f).unwrap();
        }
        let (mut sum, mut max, mut dark, mut n) = (0.0f64, 0.0f64, 0usize, 0usize);
        for y in (y0 as usize + 3)..(y1 as usize - 3) {
            for x in (x0 as usize + 3)..(x1 as usize - 3) {
                let c = f.color[y * f.width + x];
                let drop = 255.0 - (0.299 * c[0] as f64 + 0.587 * c[1] as f64 + 0.114 * c[2] as f64);
                sum += drop;
                max = max.max(drop);
                dark += (drop > 64.0) as usize;
                n += 1;
            }
        }
        Leak { mean: sum / n as f64, max, dark: dark as f64 / n as f64 }
    };
    let normalized = render_preview::GaussOptions { weighting: Weighting::Normalized, ..Default::default() };
    for pe in LEAK_PIXEL_ERRORS {
        let o = RenderOptions { pixel_error: pe, ..base.clone() };
        let (b, n, z) = (leak(&gauss(o.clone())), leak(&RenderOptions { gauss: normalized, ..gauss(o.clone()) }), leak(&o));
        eprintln!("pixel_error {pe}: luma drop (mean, max, fraction > 64) blend {b:?}, normalized {n:?}, zbuffer {z:?}");
        assert!(b.mean <= 6.0 && b.dark <= 0.002, "pixel_error {pe}: blending {b:?}");
        assert!(n.mean <= 0.6 && n.dark <= 0.001, "pixel_error {pe}: normalized {n:?}");
        assert!(z.dark <= ZBUFFER_CRACKS[(pe > 1.0) as usize] && b.dark <= z.dark, "pixel_error {pe}: blending {b:?} vs zbuffer {z:?}");
    }
}

/// Luma drop inside the front plate: mean, largest, and the fraction of pixels darker by
/// more than 64.
#[derive(Debug)]
struct Leak {
    mean: f64,
    #[allow(dead_code)] // printed
    max: f64,
    dark: f64,
}

#[test]
fn cli_method_flag_and_work_counters() {
    let dir = tempfile::tempdir().unwrap();
    let path = sphere_file(dir.path());
    let exe = env!("CARGO_BIN_EXE_sct-render-preview");
    let png = dir.path().join("s.png");
    let run = |extra: &[&str]| {
        let args = [&[path.to_str().unwrap(), "-o", png.to_str().unwrap(), "--width", "96", "--height", "72", "--json"][..], extra].concat();
        std::process::Command::new(exe).args(args).output().unwrap()
    };
    for (m, extra) in [("zbuffer", &[][..]), ("gauss", &["--method", "gauss"][..]), ("gauss", &["--method", "gauss", "--gauss-weighting", "normalized"][..])] {
        let o = run(extra);
        assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(v["schema"], "sct-render-preview/2");
        assert_eq!(v["method"], m);
        let w = &v["work"];
        assert!(w["nodes_visited"].as_u64().unwrap() > 0 && w["primitives"].as_u64() == v["splats"].as_u64(), "{v}");
        assert!(w["fragments"].as_u64().unwrap() >= w["covered_pixels"].as_u64().unwrap(), "{v}");
        assert!(w["overdraw"].as_f64().unwrap() >= 1.0 && w["bytes_read"].as_u64().unwrap() > 0, "{v}");
        assert_eq!(v["gauss"].is_null(), m == "zbuffer", "{v}");
    }
    let o = run(&["--method", "phong"]);
    assert_eq!(o.status.code(), Some(2));
    let o = run(&["--method", "gauss", "--gauss-alpha-min", "0.9"]);
    assert_eq!(o.status.code(), Some(1), "{}", String::from_utf8_lossy(&o.stderr));
}

/// `--gauss-order mask`: the kernels of each `canopy` mask node in reverse mask order instead
/// of a per-frame depth sort. Bunny (res2), 384², front: measured with outline refinement
/// (`OUTLINE_REFINE`), depth order 30.31 dB; mask order without culling 30.22 dB, with
/// t_OccCull 1.9 29.19 dB (67 nodes occluded; before outline refinement 28.24, 28.35 and
/// 27.78). Bounds: the unculled mask order within 0.5 dB of the depth order, culling costing
/// at most 1.2 dB, and the same image on one thread.
#[test]
fn gauss_in_mask_order() {
    let dir = tempfile::tempdir().unwrap();
    let Some((mesh, sct)) = synth_shared("scans/stanford-bunny-original-ply/bun_zipper_res2.ply", dir.path()) else { return };
    // At pixel error 1, where the figures above were measured.
    let depth = gauss(RenderOptions { pixel_error: 1.0, ..small(384, 384) });
    let d = render_file(&sct, &depth).unwrap();
    let refr = reference_for(&mesh, &d, &depth);
    let mask = RenderOptions { gauss: render_preview::GaussOptions { order: render_preview::Order::Mask, ..depth.gauss }, ..depth.clone() };
    let off = RenderOptions { canopy: render_preview::CanopyOptions { occ_cull: f32::INFINITY, ..mask.canopy }, ..mask.clone() };
    let (m_on, m_off) = (render_file(&sct, &mask).unwrap(), render_file(&sct, &off).unwrap());
    let (sd, son, soff) = (metrics::compare(&d.frame, &refr), metrics::compare(&m_on.frame, &refr), metrics::compare(&m_off.frame, &refr));
    eprintln!("depth {:?} | mask {:?} (occluded {}) | mask, no culling {:?}", sd.fg_psnr_db, son.fg_psnr_db, m_on.stats.canopy.unwrap().occluded, soff.fg_psnr_db);
    assert!(m_on.stats.canopy.is_some() && m_off.stats.canopy.unwrap().occluded == 0);
    assert!(soff.fg_psnr_db.unwrap() >= sd.fg_psnr_db.unwrap() - 0.5, "{soff:?} vs {sd:?}");
    assert!(son.fg_psnr_db.unwrap() >= soff.fg_psnr_db.unwrap() - 1.2 && son.silhouette_iou >= 0.99, "{son:?}");
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    assert_eq!(pool.install(|| render_file(&sct, &mask)).unwrap().frame, m_on.frame);
}

/// Every method on an empty tree (background, no error), from inside a closed sphere (back
/// faces culled: nothing drawn) and with a degenerate camera (an error).
#[test]
fn every_method_handles_empty_and_degenerate_views() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("empty.sct");
    let scene = Scene::single_tree(Default::default(), sct_format::SceneTree::from_bfs(Vec::new(), Vec::new()).unwrap());
    write_scene_file(&empty, &scene, &WriteOptions::default()).unwrap();
    let sphere = sphere_file(dir.path());
    for method in Method::ALL {
        let o = RenderOptions { method, ..small(48, 32) };
        let out = render_file(&empty, &o).unwrap();
        assert_eq!((out.frame.covered(), out.stats.splats), (0, 0), "{method}");
        let inside = RenderOptions { eye: Some([0.0, 0.0, 0.2]), target: Some([0.0, 0.0, -1.0]), ..o.clone() };
        assert_eq!(render_file(&sphere, &inside).unwrap().frame.covered(), 0, "{method}");
        let bad = RenderOptions { eye: Some([0.0; 3]), target: Some([0.0; 3]), ..o.clone() };
        assert!(matches!(render_file(&sphere, &bad), Err(render_preview::Error::Camera(_))), "{method}");
    }
}
