//! End-to-end tests: files built with the synthetic builder are rendered and compared with
//! the mesh reference, with golden images, and through the CLI.

mod common;
use common::{reference_for};

use std::path::{Path, PathBuf};

use render_preview::reference::{render_reference, WorldMesh};
use render_preview::{metrics, render_file, synth, Error, Frame, RenderOptions, UpAxis, View, ViewPreset};
use voxelize::mesh::{Instance, LoadedScene, Material, Mesh, PointCloud, Primitive, IDENTITY};
use sct_format::graph::{Generator, GraphNode, InstanceAttrs, Propagation, SceneGraph, Similarity};
use sct_format::traverse::TraverseErrorKind;
use sct_format::write::{write_scene_file, Scene, WriteOptions};
use sct_format::Node;

fn small(w: u32, h: u32) -> RenderOptions {
    RenderOptions { width: w, height: h, ..RenderOptions::default() }
}

fn sphere_file(dir: &Path) -> (PathBuf, WorldMesh) {
    let mesh = synth::uv_sphere([0.0, 0.0, 0.0], 1.0, 24, [0.8, 0.3, 0.2, 1.0]);
    let path = dir.join("sphere.sct");
    synth::write_mesh_sct(&mesh, 0.02, &path, &WriteOptions::default()).unwrap();
    (path, mesh)
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
    assert!(m.fg_psnr_db.unwrap() >= FG_PSNR_BAR, "{m:?}");
    assert!(m.silhouette_iou >= 0.97, "{m:?}");
    // Holes as `hole_fraction` counts them (three of four neighbours covered) include the
    // notches of the outline, which `raster::fill_holes` leaves open since it stopped
    // growing outlines: 0.25 % of this 160 × 120 sphere's pixels, against 0.02 % when it
    // filled them (and 0.1-0.6 dB more foreground PSNR on most shared models at 1280 × 720).
    assert!(m.hole_fraction < 0.004, "{m:?}");
}

/// Foreground PSNR the synthetic sphere and the bunny must reach at the default threshold
/// (the bunny scored 29.7 dB front and 28.6 dB iso when it was set). Over the foreground
/// only, the outline's pixels weigh far more than in the old whole-frame PSNR (whose bar
/// was 30 dB), so the bar is lower for the same images.
const FG_PSNR_BAR: f64 = 27.0;

/// A shared Stanford scan at 512² from the front and iso views: foreground PSNR ≥
/// `FG_PSNR_BAR` and silhouette IoU ≥ 0.97 at the default --pixel-error (skipped when the shared models are
/// not present). Leaves are sampled at 1/150 of the bounding radius.
fn scan_matches_its_mesh(rel: &str, min_fg_psnr: f64) {
    let ply = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/models/scans").join(rel);
    if !ply.exists() {
        eprintln!("skipping: {} not found", ply.display());
        return;
    }
    let mesh = WorldMesh::load(&ply).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("scan.sct");
    let (_, r) = mesh.bound().unwrap();
    synth::write_mesh_sct(&mesh, (r / 150.0) as f32, &path, &WriteOptions::default()).unwrap();
    // The outline is where splats and triangles differ most, so the image must be large
    // enough for it to stay a small part of the object.
    for view in [ViewPreset::Front, ViewPreset::Iso] {
        let opts = RenderOptions { view, ..small(512, 512) };
        let out = render_file(&path, &opts).unwrap();
        let m = metrics::compare(&out.frame, &reference_for(&mesh, &out, &opts));
        assert!(m.fg_psnr_db.unwrap() >= min_fg_psnr, "{rel} {view:?} {m:?}");
        assert!(m.silhouette_iou >= 0.97, "{rel} {view:?} {m:?}");
        assert!(m.hole_fraction < 0.001, "{rel} {view:?} {m:?}");
    }
}

#[test]
fn bunny_matches_its_mesh_at_default_threshold() {
    scan_matches_its_mesh("stanford-bunny-original-ply/bun_zipper_res2.ply", FG_PSNR_BAR);
}

/// The dragon's thin claws and horns make its outline long for its area: it failed the bar
/// (28.9 dB whole-frame, IoU 0.959) while splats thickened silhouettes; over its foreground
/// it scored 22.8 dB front (23.0 iso) with leaves drawn as their covering spheres, and
/// 23.26 dB front with leaves at their patch's size: the bar fails the former.
#[test]
fn dragon_matches_its_mesh_at_default_threshold() {
    scan_matches_its_mesh("stanford-dragon-100k/dragon.ply", 23.2);
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

fn blake3_of(p: &Path) -> [u8; 32] {
    *blake3::hash(&std::fs::read(p).unwrap()).as_bytes()
}

fn write_graph(path: &Path, nodes: Vec<GraphNode>, root: u32, trees: Vec<sct_format::SceneTree>) {
    let scene = Scene { generator: Generator::default(), graph: SceneGraph { nodes, root }, trees };
    write_scene_file(path, &scene, &WriteOptions::default()).unwrap();
}

/// The root sphere of the one-tree file at `path`.
fn root_of(path: &Path) -> Node {
    let r = sct_format::SctReader::open(path, &sct_format::Limits::default()).unwrap();
    r.trees()[0].header.root
}

/// `outer.sct` inlining `sphere.sct` three times under a group: as is, through a red
/// push-down instance moved right, and through a half-size green instance turned 90° about
/// +Y and moved left (whose tint covers a pull-up instance with a tint that must not apply).
fn composed_scene(dir: &Path) -> PathBuf {
    let (inner, _) = sphere_file(dir);
    let bound = root_of(&inner);
    let push = |t: [u8; 4]| InstanceAttrs { tint: Some(t), color: Propagation::PushDown, ..Default::default() };
    let right = Similarity { translation: [2.5, 0.0, 0.0], ..Similarity::IDENTITY };
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let left = Similarity { translation: [-2.0, 0.0, 0.0], rotation: [0.0, h, 0.0, h], scale: 0.5 };
    let ignored = InstanceAttrs { tint: Some([0, 0, 0, 255]), color: Propagation::PullUp, ..Default::default() };
    let nodes = vec![
        GraphNode::Inline { path: "sphere.sct".into(), hash: blake3_of(&inner), bound },
        GraphNode::Instance { child: 0, transform: right, attrs: push([255, 60, 60, 255]) },
        GraphNode::Instance { child: 0, transform: Similarity::IDENTITY, attrs: ignored },
        GraphNode::Instance { child: 2, transform: left, attrs: push([60, 255, 60, 255]) },
    ];
    let bounds = [bound, right.apply_node(&bound), left.apply_node(&bound)];
    let (gtree, order) = synth::build_indexed_group(&bounds).unwrap();
    let children = order.iter().map(|&k| [0u32, 1, 3][k]).collect();
    let mut nodes = nodes;
    nodes.push(GraphNode::Group { children, tree: 0 });
    let outer = dir.join("outer.sct");
    write_graph(&outer, nodes, 4, vec![gtree]);
    outer
}

#[test]
fn inline_renders_like_its_target() {
    let dir = tempfile::tempdir().unwrap();
    let (inner, _) = sphere_file(dir.path());
    let outer = dir.path().join("outer.sct");
    let nodes = vec![GraphNode::Inline { path: "sphere.sct".into(), hash: blake3_of(&inner), bound: root_of(&inner) }];
    write_graph(&outer, nodes, 0, vec![]);
    let opts = RenderOptions { eye: Some([1.0, 2.0, 3.0]), target: Some([0.0; 3]), ..small(80, 60) };
    let a = render_file(&inner, &opts).unwrap();
    let b = render_file(&outer, &opts).unwrap();
    assert_eq!(b.stats.files, 2);
    assert!(a.frame.covered() > 1000);
    assert_eq!(a.frame, b.frame, "an inline must draw exactly what its target draws");
}

#[test]
fn composed_scene_shows_inlines_instances_and_tints() {
    let dir = tempfile::tempdir().unwrap();
    let outer = composed_scene(dir.path());
    let opts = RenderOptions { view: ViewPreset::Front, shading: render_preview::Shading::Flat, ..small(240, 120) };
    let out = render_file(&outer, &opts).unwrap();
    assert_eq!(out.stats.files, 2, "the inline target is opened once");
    let f = &out.frame;
    let view = View::new(&out.camera, out.near).unwrap();
    let at = |p: [f64; 3]| {
        let q = view.project(view.to_camera(p));
        f.color[q[1] as usize * f.width + q[0] as usize]
    };
    // Front surfaces (z = radius · scale) of the three uses; the sphere is sRGB [231, 149, 124].
    let (mid, right, left) = (at([0.0, 0.0, 1.0]), at([2.5, 0.0, 1.0]), at([-2.0, 0.0, 0.5]));
    assert!(mid[0] > 200 && mid[1] > 120 && mid[2] > 100, "plain inline keeps its colour: {mid:?}");
    assert!(right[0] > 200 && right[1] < 60 && right[2] < 60, "red tint multiplies: {right:?}");
    assert!(left[1] > 120 && left[0] < 80 && left[2] < 60, "green tint (pull-up tint ignored): {left:?}");
    // The half-size instance is half as tall on screen.
    let rows = |x: f64| {
        (0..f.height).filter(|&y| f.depth[y * f.width + view.project(view.to_camera([x, 0.0, 0.0]))[0] as usize].is_finite()).count()
    };
    let (full, half) = (rows(0.0), rows(-2.0));
    assert!((full as f64 / half as f64 - 2.0).abs() < 0.25, "{full} vs {half}");
    golden("composed_iso", &render_file(&outer, &RenderOptions { view: ViewPreset::Iso, ..small(96, 72) }).unwrap().frame);
}

#[test]
fn bad_inlines_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let (inner, _) = sphere_file(dir.path());
    let bound = root_of(&inner);
    let exe = env!("CARGO_BIN_EXE_sct-render-preview");
    let png = dir.path().join("out.png");
    let cases: [(&str, &str, [u8; 32], &str); 3] = [
        ("badhash.sct", "sphere.sct", [7; 32], "BLAKE3"),
        ("missing.sct", "nope.sct", blake3_of(&inner), "cannot be opened"),
        ("cycle.sct", "cycle.sct", [0; 32], "cycle"),
    ];
    for (name, target, hash, msg) in cases {
        let p = dir.path().join(name);
        write_graph(&p, vec![GraphNode::Inline { path: target.into(), hash, bound }], 0, vec![]);
        let e = render_file(&p, &small(64, 48)).unwrap_err();
        let ok = match (&e, msg) {
            (Error::Inline { kind, .. }, "BLAKE3") => {
                matches!(**kind, TraverseErrorKind::InlineHash { .. })
            }
            (Error::Inline { kind, .. }, "cannot be opened") => {
                matches!(**kind, TraverseErrorKind::InlineMissing { .. })
            }
            (Error::Inline { kind, .. }, _) => {
                matches!(**kind, TraverseErrorKind::InlineCycle { .. })
            }
            _ => false,
        };
        assert!(ok, "{name}: {e:?}");
        let o = std::process::Command::new(exe).args([p.to_str().unwrap(), "-o", png.to_str().unwrap()]).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{name}: {err}");
        assert!(err.contains(msg) && err.contains(name) && err.lines().count() == 1, "{name}: {err}");
    }
    // Depth limit: one inline is one too many with max_inline_depth 0.
    let p = dir.path().join("deep.sct");
    write_graph(&p, vec![GraphNode::Inline { path: "sphere.sct".into(), hash: blake3_of(&inner), bound }], 0, vec![]);
    let mut opts = small(64, 48);
    opts.limits.max_inline_depth = 0;
    let e = render_file(&p, &opts).unwrap_err();
    assert!(matches!(&e, Error::Inline { kind, .. } if matches!(**kind, TraverseErrorKind::InlineDepth { limit: 0 })), "{e:?}");
    assert!(render_file(&p, &small(64, 48)).is_ok());
}

/// Covered-pixel bounding box (width, height) of a frame.
fn extent(f: &Frame) -> (usize, usize) {
    let (mut x0, mut x1, mut y0, mut y1) = (usize::MAX, 0, usize::MAX, 0);
    for y in 0..f.height {
        for x in 0..f.width {
            if f.depth[y * f.width + x].is_finite() {
                (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
            }
        }
    }
    (x1.saturating_sub(x0) + 1, y1.saturating_sub(y0) + 1)
}

/// Regression: `--up auto` guessed Z up for anything 1.5× taller along Z than wide, which
/// stood Y-up props on end. The default is now +Y unless the file's provenance records the
/// source's up axis; `--up` overrides both.
#[test]
fn up_axis_is_y_unless_recorded_or_given() {
    let dir = tempfile::tempdir().unwrap();
    // A sphere stretched 3× along Z: a tall object if Z is up, a circle seen along Z.
    let mut mesh = synth::uv_sphere([0.0, 0.0, 0.0], 1.0, 16, [0.8, 0.8, 0.8, 1.0]);
    for t in &mut mesh.tris {
        for p in &mut t.p {
            p[2] *= 3.0;
        }
    }
    let write = |name: &str, parameters: serde_json::Value| {
        let tree = synth::build_tree(synth::sample_mesh(&mesh, 0.1)).unwrap();
        let path = dir.path().join(name);
        let scene = Scene::single_tree(Generator { parameters, ..Generator::default() }, tree);
        write_scene_file(&path, &scene, &WriteOptions::default()).unwrap();
        path
    };
    let opts = small(120, 120);
    let plain = write("plain.sct", serde_json::Value::Null);
    let (w, h) = extent(&render_file(&plain, &opts).unwrap().frame);
    assert!(w.abs_diff(h) <= 2, "default Y up: seen along Z, a circle: {w}x{h}");
    let out = render_file(&plain, &RenderOptions { up_axis: Some(UpAxis::Z), ..opts.clone() }).unwrap();
    let (w, h) = extent(&out.frame);
    assert!(h > 2 * w, "--up z: upright, seen from the front (-Y): {w}x{h}");
    assert!(out.camera.eye[1] < 0.0 && out.camera.up == [0.0, 0.0, 1.0], "{:?}", out.camera);
    // Recorded by the sampling step of a one- or two-step build.
    let recorded = write("recorded.sct", serde_json::json!({ "sampling": { "parameters": { "up": "z" } } }));
    let out = render_file(&recorded, &opts).unwrap();
    let (w, h) = extent(&out.frame);
    assert!(h > 2 * w, "provenance up z: upright: {w}x{h}");
    assert_eq!(out.up_axis, UpAxis::Z);
    // The option wins over the record.
    let (w, h) = extent(&render_file(&recorded, &RenderOptions { up_axis: Some(UpAxis::Y), ..opts.clone() }).unwrap().frame);
    assert!(w.abs_diff(h) <= 2, "--up y over the record: {w}x{h}");
}

/// Regression: the default camera framed the root bounding sphere, so a model filled a
/// small part of the frame (a truck 15 % of the width). Its projected extent now fills
/// about 90 % of the tighter dimension, for a model off the origin and in composed scenes.
#[test]
fn default_view_fills_ninety_percent_of_the_frame() {
    let dir = tempfile::tempdir().unwrap();
    // A wide, flat ellipsoid away from the origin (normals by the inverse transpose).
    let mut mesh = synth::uv_sphere([0.0, 0.0, 0.0], 1.0, 24, [0.8, 0.8, 0.8, 1.0]);
    for t in &mut mesh.tris {
        for p in &mut t.p {
            *p = [p[0] * 4.0 + 10.0, p[1] + 5.0, p[2] * 0.5 - 3.0];
        }
        for n in &mut t.n {
            let m = [n[0] / 4.0, n[1], n[2] / 0.5];
            let l = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
            *n = m.map(|v| v / l);
        }
    }
    let path = dir.path().join("wide.sct");
    synth::write_mesh_sct(&mesh, 0.03, &path, &WriteOptions::default()).unwrap();
    let grid = instance_scene(dir.path());
    for (file, view) in [(&path, ViewPreset::Front), (&path, ViewPreset::Iso), (&grid, ViewPreset::Front), (&grid, ViewPreset::Top)] {
        for (w, h) in [(320, 180), (180, 320)] {
            let out = render_file(file, &RenderOptions { view, ..small(w, h) }).unwrap();
            let (ew, eh) = extent(&out.frame);
            let fill = (ew as f64 / w as f64).max(eh as f64 / h as f64);
            assert!((0.82..=0.92).contains(&fill), "{} {view:?} {w}x{h}: fills {ew}x{eh} = {fill:.3}", file.display());
            // Centred.
            let [x0, y0, x1, y1] = out.frame.covered_box().unwrap();
            assert!(((x0 + x1) as f64 / 2.0 - w as f64 / 2.0).abs() < 0.05 * w as f64, "{x0}..{x1} of {w}");
            assert!(((y0 + y1) as f64 / 2.0 - h as f64 / 2.0).abs() < 0.05 * h as f64, "{y0}..{y1} of {h}");
        }
    }
}

#[test]
fn cli_empty_images_are_errors_unless_allowed() {
    let exe = env!("CARGO_BIN_EXE_sct-render-preview");
    let dir = tempfile::tempdir().unwrap();
    let (path, _) = sphere_file(dir.path());
    let png = dir.path().join("out.png");
    let run = |args: &[&str]| std::process::Command::new(exe).args(args).output().unwrap();
    let base = [path.to_str().unwrap(), "-o", png.to_str().unwrap(), "--width", "64", "--height", "48"];
    // Looking away from the model: every node is outside the frustum.
    let away = [&base[..], &["--eye", "0,0,5", "--target", "0,0,10"]].concat();
    let o = run(&away);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("nothing was drawn") && err.contains("frustum") && err.lines().count() == 1, "{err}");
    assert!(png.exists(), "the image is still written");
    let o = run(&[&away[..], &["--allow-empty", "--json"]].concat());
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["empty"].as_str().unwrap().contains("frustum"));
    // Inside the closed sphere: back-face culling removes everything.
    let o = run(&[&base[..], &["--eye", "0,0,0.2", "--target", "0,0,-1"]].concat());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("back-face culling"), "{err}");
    // A file without geometry.
    let empty = dir.path().join("empty.sct");
    let scene = Scene::single_tree(Default::default(), sct_format::SceneTree::from_bfs(Vec::new(), Vec::new()).unwrap());
    write_scene_file(&empty, &scene, &WriteOptions::default()).unwrap();
    let o = run(&[empty.to_str().unwrap(), "-o", png.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("no geometry"), "{err}");
}

/// Writes a glTF-free OBJ sphere (counter-clockwise outside) and its SCT with `parameters`
/// as provenance; returns (obj, sct).
fn obj_and_sct(dir: &Path, parameters: serde_json::Value) -> (PathBuf, PathBuf) {
    let mesh = synth::uv_sphere([0.0, 0.0, 0.0], 1.0, 16, [0.8, 0.8, 0.8, 1.0]);
    let obj = dir.join("ball.obj");
    let mut text = String::new();
    for t in &mesh.tris {
        for p in &t.p {
            text.push_str(&format!("v {} {} {}\n", p[0], p[1], p[2]));
        }
    }
    for i in 0..mesh.tris.len() {
        text.push_str(&format!("f {} {} {}\n", 3 * i + 1, 3 * i + 2, 3 * i + 3));
    }
    std::fs::write(&obj, text).unwrap();
    let tree = synth::build_tree(synth::sample_mesh(&mesh, 0.02)).unwrap();
    let sct = dir.join("ball.sct");
    write_scene_file(&sct, &Scene::single_tree(Generator { parameters, ..Generator::default() }, tree), &WriteOptions::default()).unwrap();
    (obj, sct)
}

#[test]
fn cli_min_psnr_and_min_iou_gate_the_reference() {
    let exe = env!("CARGO_BIN_EXE_sct-render-preview");
    let dir = tempfile::tempdir().unwrap();
    let (obj, sct) = obj_and_sct(dir.path(), serde_json::Value::Null);
    let png = dir.path().join("out.png");
    let run = |extra: &[&str]| {
        let args = [&[sct.to_str().unwrap(), "-o", png.to_str().unwrap(), "--width", "160", "--height", "120", "--reference", obj.to_str().unwrap(), "--json"][..], extra].concat();
        std::process::Command::new(exe).args(args).output().unwrap()
    };
    let o = run(&[]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["schema"], "sct-render-preview/2");
    let (db, iou) = (v["metrics"]["fg_psnr_db"].as_f64().unwrap(), v["metrics"]["silhouette_iou"].as_f64().unwrap());
    assert!(db > 20.0 && iou > 0.9, "{v}");
    assert!(v["metrics"].get("psnr_db").is_none(), "the whole-frame PSNR is gone: {v}");
    let file: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.path().join("out.metrics.json")).unwrap()).unwrap();
    assert_eq!(file["metrics"], v["metrics"]);
    for (flags, ok, msg) in [
        (vec!["--min-psnr", "15", "--min-iou", "0.5"], true, ""),
        (vec!["--min-psnr", "90"], false, "below --min-psnr 90"),
        (vec!["--min-iou", "0.9999"], false, "below --min-iou 0.9999"),
    ] {
        let o = run(&flags);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(if ok { 0 } else { 1 }), "{flags:?}: {err}");
        assert!(ok || (err.contains(msg) && err.lines().count() == 1), "{flags:?}: {err}");
        // The outputs are written either way.
        assert!(serde_json::from_slice::<serde_json::Value>(&o.stdout).is_ok());
    }
    // The gates need a reference.
    let o = std::process::Command::new(exe).args([sct.to_str().unwrap(), "-o", png.to_str().unwrap(), "--min-psnr", "20"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
}

/// Regression: the reference ignored the texture the SCT was sampled with (`--texture`),
/// so a correctly textured spot scored 22 dB over the whole frame (11.5 dB over its
/// pixels) against an untextured cow.
#[test]
fn reference_binds_the_texture_recorded_in_the_provenance() {
    let spot = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/models/textured-obj/spot");
    let (obj, tex) = (spot.join("spot_triangulated.obj"), spot.join("spot_texture.png"));
    if !obj.exists() || !tex.exists() {
        eprintln!("skipping: {} not found", obj.display());
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let load = voxelize::LoadOptions { texture_override: Some(tex.clone()), ..Default::default() };
    let mesh = WorldMesh::load_with(&obj, &load).unwrap();
    let (_, r) = mesh.bound().unwrap();
    let tree = synth::build_tree(synth::sample_mesh(&mesh, (r / 200.0) as f32)).unwrap();
    // As sct-build-tree records a one-step build with --texture, run in the model's folder.
    let parameters = serde_json::json!({ "sampling": { "tool": "sct-voxelize", "parameters": { "texture_override": "spot_texture.png" } } });
    let sct = dir.path().join("spot.sct");
    write_scene_file(&sct, &Scene::single_tree(Generator { parameters, ..Generator::default() }, tree), &WriteOptions::default()).unwrap();
    let exe = env!("CARGO_BIN_EXE_sct-render-preview");
    let png = dir.path().join("spot.png");
    let run = |extra: &[&str]| {
        let args = [&[sct.to_str().unwrap(), "-o", png.to_str().unwrap(), "--width", "320", "--height", "320", "--reference", obj.to_str().unwrap(), "--json"][..], extra].concat();
        let o = std::process::Command::new(exe).args(args).output().unwrap();
        assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice::<serde_json::Value>(&o.stdout).unwrap()
    };
    let v = run(&[]);
    assert_eq!(v["reference_load"]["texture_from"], "provenance", "{v}");
    let textured = v["metrics"]["fg_psnr_db"].as_f64().unwrap();
    assert!(textured >= 20.0, "{v}");
    // An explicit texture overrides the record: a wrong one scores far lower.
    let wrong = dir.path().join("grey.png");
    image::RgbImage::from_pixel(4, 4, image::Rgb([90, 90, 90])).save(&wrong).unwrap();
    let v = run(&["--reference-texture", wrong.to_str().unwrap()]);
    assert_eq!(v["reference_load"]["texture_from"], "option");
    assert!(v["metrics"]["fg_psnr_db"].as_f64().unwrap() < textured - 5.0, "{v}");
}

#[test]
fn a_recorded_texture_that_cannot_be_found_is_an_error() {
    let exe = env!("CARGO_BIN_EXE_sct-render-preview");
    let dir = tempfile::tempdir().unwrap();
    let (obj, sct) = obj_and_sct(dir.path(), serde_json::json!({ "sampling": { "parameters": { "texture_override": "gone/tex.png" } } }));
    let png = dir.path().join("out.png");
    let o = std::process::Command::new(exe)
        .args([sct.to_str().unwrap(), "-o", png.to_str().unwrap(), "--width", "64", "--height", "48", "--reference", obj.to_str().unwrap()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("gone/tex.png") && err.contains("--reference-texture") && err.lines().count() == 1, "{err}");
}

/// A one-mesh scene of `prim` placed by `transform`, with `material`.
fn scene_of(prim: Primitive, material: Material, transform: voxelize::mesh::Mat4) -> LoadedScene {
    LoadedScene {
        meshes: vec![Mesh { name: "m".into(), primitives: vec![Primitive { material: Some(0), ..prim }] }],
        instances: vec![Instance { mesh: 0, transform }],
        materials: vec![material],
        ..Default::default()
    }
}

fn sphere_prim() -> Primitive {
    let m = synth::uv_sphere([0.0, 0.0, 0.0], 1.0, 16, [1.0; 4]);
    m.scene.meshes[0].primitives[0].clone()
}

fn front_camera(w: u32, h: u32) -> View {
    let cam = render_preview::Camera { eye: [0.0, 0.0, 5.0], target: [0.0; 3], up: [0.0, 1.0, 0.0], fov_y_deg: 40.0, width: w, height: h };
    View::new(&cam, 1e-3).unwrap()
}

/// Regression: a mirroring instance transform (negative determinant) turned the winding
/// around and the reference culled the faces towards the eye, showing the far half.
#[test]
fn reference_keeps_the_front_of_mirrored_instances() {
    let view = front_camera(64, 64);
    let mirror = [[-1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];
    let plain = WorldMesh::from_scene(scene_of(sphere_prim(), Material::default(), IDENTITY));
    let mirrored = WorldMesh::from_scene(scene_of(sphere_prim(), Material::default(), mirror));
    assert!(plain.tris.iter().all(|t| !t.two_sided), "a closed sphere is one-sided");
    let (a, b) = (render_reference(&plain, &view, render_preview::Shading::Flat, [0; 3]), render_reference(&mirrored, &view, render_preview::Shading::Flat, [0; 3]));
    let centre = 32 * 64 + 32;
    // The near surface is 4 units from the eye, the far one 6.
    assert!((a.depth[centre] - 4.0).abs() < 0.05, "{}", a.depth[centre]);
    assert!((b.depth[centre] - 4.0).abs() < 0.05, "mirrored instance shows its far side: {}", b.depth[centre]);
}

/// Open surfaces and double-sided materials are drawn from both sides; only closed,
/// consistently oriented meshes with one-sided materials are culled.
#[test]
fn reference_draws_two_sided_surfaces_from_behind() {
    let view = front_camera(32, 32);
    // A square facing -Z (away from the eye): open, so two-sided.
    let quad = Primitive {
        positions: vec![[-1.0, -1.0, 0.0], [-1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.0, -1.0, 0.0]],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        ..Default::default()
    };
    let open = WorldMesh::from_scene(scene_of(quad.clone(), Material::default(), IDENTITY));
    assert!(render_reference(&open, &view, render_preview::Shading::Flat, [0; 3]).covered() > 100);
    // Inside a closed sphere the surface faces away and is culled, unless double-sided.
    let inside = render_preview::Camera { eye: [0.0, 0.0, 0.5], target: [0.0, 0.0, -1.0], up: [0.0, 1.0, 0.0], fov_y_deg: 40.0, width: 32, height: 32 };
    let inside = View::new(&inside, 1e-3).unwrap();
    let closed = WorldMesh::from_scene(scene_of(sphere_prim(), Material::default(), IDENTITY));
    assert_eq!(render_reference(&closed, &inside, render_preview::Shading::Flat, [0; 3]).covered(), 0);
    let double = WorldMesh::from_scene(scene_of(sphere_prim(), Material { double_sided: true, ..Material::default() }, IDENTITY));
    assert_eq!(render_reference(&double, &inside, render_preview::Shading::Flat, [0; 3]).covered(), 32 * 32);
}

/// Stacked triangles filling the view (76,000 in a 1 MB PLY rasterized for over a minute):
/// the bounded reference stops at its pixel limit; within it, it draws as the plain one.
#[test]
fn reference_render_stops_at_its_pixel_limit() {
    let view = front_camera(32, 32);
    let quad = Primitive {
        positions: vec![[-1.0, -1.0, 0.0], [-1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.0, -1.0, 0.0]],
        triangles: [[0, 1, 2], [0, 2, 3]].repeat(500),
        ..Default::default()
    };
    let mesh = WorldMesh::from_scene(scene_of(quad, Material::default(), IDENTITY));
    let bounded = |max| render_preview::reference::render_reference_bounded(&mesh, &view, render_preview::Shading::Flat, [0; 3], max);
    match bounded(10_000) {
        Err(e) => assert!(e.to_string().contains(render_preview::PIXELS_COVERED), "{e}"),
        Ok(f) => panic!("drew {} pixels", f.covered()),
    }
    let plain = render_reference(&mesh, &view, render_preview::Shading::Flat, [0; 3]);
    let within = bounded(u64::MAX).expect("within the limit");
    assert!(plain.covered() > 100 && within.color == plain.color);
}

/// Regression: a point cloud's reference was empty (it has no triangles) and still scored.
#[test]
fn reference_draws_point_clouds() {
    let positions: Vec<[f32; 3]> = (0..40).flat_map(|i| (0..40).map(move |j| [i as f32 / 20.0 - 1.0, j as f32 / 20.0 - 1.0, 0.0])).collect();
    let scene = LoadedScene { points: Some(PointCloud { positions, normals: None, colors: None }), ..Default::default() };
    let mesh = WorldMesh::from_scene(scene);
    assert!(!mesh.is_empty() && mesh.tris.is_empty());
    let f = render_reference(&mesh, &front_camera(64, 64), render_preview::Shading::Lambert, [0; 3]);
    // The 2×2 square at distance 5 spans about 2 / (2·5·tan 20°) = 55 % of the frame.
    let n = f.covered();
    assert!(n > 800 && n < 1600 && f.depth[32 * 64 + 32].is_finite(), "{n}");
    let pond = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/models/ply/pond-pointcloud-colours/pond.0.ply");
    if pond.exists() {
        let mesh = WorldMesh::load(&pond).unwrap();
        assert!(mesh.points.len() > 1000 && mesh.bound().is_some());
    }
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
    // Printed once: the cause used to be repeated after the message that already held it.
    let msg = String::from_utf8_lossy(&g.stderr);
    assert_eq!(msg.matches("not an SCT").count(), 1, "{msg}");
    let msg = String::from_utf8_lossy(&run(&[missing.to_str().unwrap(), "-o", png.to_str().unwrap()]).stderr).into_owned();
    assert_eq!(msg.matches("No such file").count(), 1, "{msg}");
    assert_eq!(run(&[path.to_str().unwrap(), "-o", png.to_str().unwrap(), "--view", "sideways"]).status.code(), Some(2));
    // Degenerate camera: invalid input, one clear message.
    let d = run(&[path.to_str().unwrap(), "-o", png.to_str().unwrap(), "--eye", "0,0,0", "--target", "0,0,0"]);
    assert_eq!(d.status.code(), Some(1));
    let msg = String::from_utf8_lossy(&d.stderr);
    assert!(msg.contains("camera") && msg.lines().count() == 1, "{msg}");
}

#[test]
fn same_bytes_on_1_and_4_threads() {
    let dir = tempfile::tempdir().unwrap();
    let (sphere, _) = sphere_file(dir.path());
    let outer = composed_scene(dir.path());
    // Large enough that refinement splits its frontier across threads (≥ 8192 nodes).
    for (path, opts) in [(&sphere, RenderOptions { pixel_error: 0.5, ..small(640, 480) }), (&outer, small(320, 240))] {
        let run = |n: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
            pool.install(|| render_file(path, &opts).unwrap())
        };
        let (a, b) = (run(1), run(4));
        assert!(a.stats.lod.nodes_visited > 8192 || path == &outer);
        assert_eq!(a.frame, b.frame, "{}", path.display());
    }
}
