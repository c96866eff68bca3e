//! The `parilov` method (multi-view visibility orderings): accuracy against the mesh and
//! against the same cut through a depth buffer, kept orders along an orbit (the paper's
//! Table 4 measure), the paper's worst case (a solid sample cube seen towards its corner)
//! at both thresholds, instances, and an empty tree. Measurements print with `--nocapture`.

mod common;
use common::{shared, synth_shared};

use std::path::{Path, PathBuf};

use render_preview::reference::{render_reference, WorldMesh};
use render_preview::{metrics, render, render_file, synth, Method, ParilovOptions, RenderOptions, SceneFiles, View};
use sct_format::write::{write_scene_file, Scene, WriteOptions};
use sct_format::{Limits, Node};

fn parilov(o: RenderOptions) -> RenderOptions {
    RenderOptions { method: Method::Parilov, ..o }
}

/// Bunny (res2) at 1/200 of its radius, 384², front, default knobs. Measured when set:
/// parilov 26.6 dB, SSIM 0.933, IoU 0.991 against the mesh (zbuffer 30.1 dB, 0.947, 0.997:
/// one pixel per sample grows the outline by the pixels that hold a sample's centre, extra
/// 0.9 %); 27.0 dB against zbuffer's frame of the same knob; every cell sorted once (a first
/// frame). Bars: the measured values less 1 dB / 0.01.
#[test]
fn parilov_matches_the_mesh_and_the_depth_buffered_cut() {
    let dir = tempfile::tempdir().unwrap();
    let Some((mesh, sct)) = synth_shared("scans/stanford-bunny-original-ply/bun_zipper_res2.ply", dir.path()) else { return };
    let o = parilov(RenderOptions { width: 384, height: 384, ..RenderOptions::default() });
    let out = render_file(&sct, &o).unwrap();
    let refr = render_reference(&mesh, &View::new(&out.camera, out.near).unwrap(), o.shading, o.background);
    let m = metrics::compare(&out.frame, &refr);
    let z = render_file(&sct, &RenderOptions { method: Method::Zbuffer, ..o.clone() }).unwrap();
    let zm = metrics::compare(&z.frame, &refr);
    let vs = metrics::compare(&out.frame, &z.frame);
    let ps = out.stats.parilov.unwrap();
    eprintln!("parilov {m:?}\nzbuffer {zm:?}\nparilov vs zbuffer {:?} dB\n{ps:?}", vs.fg_psnr_db);
    assert!(m.fg_psnr_db.unwrap() >= 25.6 && m.fg_ssim.unwrap() >= 0.923 && m.silhouette_iou >= 0.981, "{m:?}");
    assert!(vs.fg_psnr_db.unwrap() >= 26.0, "{vs:?}");
    assert_eq!(ps.cells_resorted, ps.cells, "a first frame sorts every cell");
    assert!(ps.samples > 10_000 && out.stats.work.primitives == ps.samples);
    // One thread or many: the same frame.
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    assert_eq!(pool.install(|| render_file(&sct, &o)).unwrap().frame, out.frame);
}

/// Kept orders along an orbit: the same files rendered 36 times, the eye turning 2° a frame
/// about the bunny (the paper's fly-around: 2.5–6.5 % of the cells re-sorted per frame at
/// 70°). Measured when set: after the first frame, 70° re-sorts 3.2 % of the cells per frame
/// on average and 45° 8.0 %; a kept order's frame within 0.03 dB of a fresh render's.
/// Bounds: at most 5 % (70°) and 12 % (45°) per frame, 45° re-sorting more, and a kept
/// order costing at most 1 dB against a fresh sort.
#[test]
fn kept_orders_are_reused_along_an_orbit() {
    let Some(path) = shared("scans/stanford-bunny-original-ply/bun_zipper_res2.ply") else { return };
    let mesh = WorldMesh::load(&path).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let sct = dir.path().join("b.sct");
    let (c, r) = mesh.bound().unwrap();
    synth::write_mesh_sct(&mesh, (r / 200.0) as f32, &sct, &WriteOptions::default()).unwrap();
    let mut fractions = Vec::new();
    for threshold in [70.0f32, 45.0] {
        let mut files = SceneFiles::open(&sct, &Limits::default()).unwrap();
        let (mut sum, mut worst_loss) = (0.0, 0.0f64);
        for f in 0..36 {
            let a = (f as f64 * 2.0).to_radians();
            let eye = [c[0] + 3.0 * r * a.sin(), c[1] + 0.5 * r, c[2] + 3.0 * r * a.cos()];
            let o = parilov(RenderOptions { width: 256, height: 256, eye: Some(eye), target: Some(c), parilov: ParilovOptions { threshold_deg: threshold }, ..RenderOptions::default() });
            let out = render(&mut files, &o).unwrap();
            let ps = out.stats.parilov.unwrap();
            if f == 0 {
                assert_eq!(ps.cells_resorted, ps.cells);
                continue;
            }
            sum += ps.resort_fraction;
            if f % 7 == 0 {
                let refr = render_reference(&mesh, &View::new(&out.camera, out.near).unwrap(), o.shading, o.background);
                let kept = metrics::compare(&out.frame, &refr).fg_psnr_db.unwrap();
                let fresh = metrics::compare(&render_file(&sct, &o).unwrap().frame, &refr).fg_psnr_db.unwrap();
                worst_loss = worst_loss.max(fresh - kept);
            }
        }
        let mean = sum / 35.0;
        eprintln!("threshold {threshold}°: {:.2} % of cells re-sorted per frame, worst loss of a kept order {worst_loss:.2} dB", mean * 100.0);
        assert!(worst_loss <= 1.0, "{threshold}°: {worst_loss}");
        fractions.push(mean);
    }
    assert!(fractions[0] <= 0.05 && fractions[1] <= 0.12 && fractions[1] > fractions[0], "{fractions:?}");
}

/// A solid cube of `n³` samples, coloured faces over a magenta inside, as a two-sided tree.
fn sample_cube(n: usize, dir: &Path) -> PathBuf {
    let h = 1.0 / n as f32;
    let mut leaves = Vec::new();
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                let p = [i, j, k].map(|v| (v as f32 + 0.5) * h - 0.5);
                let face = [i, j, k].iter().any(|&v| v == 0 || v == n - 1);
                let color = if face { [60, 160, 60, 255] } else { [255, 0, 255, 255] };
                leaves.push(Node { center: p, radius: 0.87 * h, normal: [0.0, 0.0, 1.0], cone: std::f32::consts::PI, area: h * h, color });
            }
        }
    }
    let mut tree = synth::build_tree(leaves).unwrap();
    tree.set_two_sided(true);
    let sct = dir.join(format!("cube{n}.sct"));
    write_scene_file(&sct, &Scene::single_tree(Default::default(), tree), &WriteOptions::default()).unwrap();
    sct
}

/// Fraction of the covered pixels that show the cube's magenta inside.
fn magenta(f: &render_preview::Frame) -> f64 {
    let covered = f.depth.iter().filter(|d| d.is_finite()).count().max(1);
    f.color.iter().filter(|c| c[0] > 200 && c[1] < 80 && c[2] > 200).count() as f64 / covered as f64
}

/// The paper's worst case (§2.3, preview-methods.md D4): a solid 64³ cube of samples (about
/// a pixel apart at 80²), coloured faces over a magenta inside, sorted face-on, then seen 30°
/// and 45° off that face and towards its corner (54.7°) with the orders kept. Magenta pixels
/// are the visibility artifact. Measured when set: 0.03–0.28 % of the cube's pixels at 45°
/// (which re-sorts 14–86 % of the cells on the way) and 0.03–0.18 % at 70° (7–13 %): the
/// kept orders hold to the corner; what shows comes from samples wider than the footprint
/// (their virtual children cross split planes). Bounds: ≤ 0.5 % at 45°, ≤ 3 % at 70°.
#[test]
fn sample_cube_shows_its_inside_only_past_the_threshold() {
    let dir = tempfile::tempdir().unwrap();
    let sct = sample_cube(64, dir.path());
    for threshold in [45.0f32, 70.0] {
        let mut files = SceneFiles::open(&sct, &Limits::default()).unwrap();
        for (deg, toward_corner) in [(0.0f64, false), (30.0, false), (45.0, false), (54.7356, true)] {
            // Face-on looks along −z; the others turn about y (and, for the corner, x too).
            let a = deg.to_radians();
            let eye = if toward_corner { [1.443, 1.443, 1.443] } else { [2.5 * a.sin(), 0.0, 2.5 * a.cos()] };
            // Pixel error 1, as measured.
            let o = parilov(RenderOptions { width: 80, height: 80, eye: Some(eye), target: Some([0.0; 3]), parilov: ParilovOptions { threshold_deg: threshold }, pixel_error: 1.0, ..RenderOptions::default() });
            let out = render(&mut files, &o).unwrap();
            let m = magenta(&out.frame);
            let ps = out.stats.parilov.unwrap();
            eprintln!("threshold {threshold}°, view {deg}°: magenta {m:.4} of covered, re-sorted {:.2}, {} samples ({} virtual)", ps.resort_fraction, ps.samples, ps.virtual_samples);
            assert!(m <= if threshold == 45.0 { 0.005 } else { 0.03 }, "{threshold}°, view {deg}°: {m}");
        }
    }
}

/// Large footprints (D4: "the above idea does not apply for non-infinitesimal primitives"):
/// the same cube at 24³ samples seen face-on at 256², samples about 6 px apart. Replicated
/// into one virtual sample per pixel at their own depth, a sample's pixels reach across its
/// cell's split plane, so the inside shows through where a nearer cell was drawn before a
/// farther one's wide samples. Measured when set: 15.4 % of the pixels magenta (zbuffer
/// 0.07 %, cracks between its splats). Bound: parilov shows more than 10× zbuffer's and
/// below 25 %.
#[test]
fn large_footprints_break_the_ordering() {
    let dir = tempfile::tempdir().unwrap();
    let sct = sample_cube(24, dir.path());
    let o = parilov(RenderOptions { width: 256, height: 256, eye: Some([0.0, 0.0, 2.5]), target: Some([0.0; 3]), ..RenderOptions::default() });
    let m = magenta(&render_file(&sct, &o).unwrap().frame);
    let z = magenta(&render_file(&sct, &RenderOptions { method: Method::Zbuffer, ..o.clone() }).unwrap().frame);
    eprintln!("large footprints: parilov magenta {m:.4}, zbuffer {z:.4}");
    assert!(m > 10.0 * z && m < 0.25, "{m} {z}");
}

/// Instances and tints render (a 3 × 3 grid of tinted bunnies), and an empty tree gives the
/// background.
#[test]
fn instances_and_empty_trees() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = synth::uv_sphere([0.0; 3], 1.0, 16, [0.8, 0.8, 0.8, 1.0]);
    let tree = synth::build_tree(synth::sample_mesh(&mesh, 0.05)).unwrap();
    let scene = synth::instance_grid(tree, 3, 3, 2.5, |i| Some([255, (i * 25) as u8, 0, 255])).unwrap();
    let sct = dir.path().join("grid.sct");
    write_scene_file(&sct, &scene, &WriteOptions::default()).unwrap();
    let o = parilov(RenderOptions { width: 200, height: 150, ..RenderOptions::default() });
    let out = render_file(&sct, &o).unwrap();
    let z = render_file(&sct, &RenderOptions { method: Method::Zbuffer, ..o.clone() }).unwrap();
    let vs = metrics::compare(&out.frame, &z.frame);
    eprintln!("grid: {:?} vs zbuffer {vs:?}", out.stats.parilov);
    assert!(vs.silhouette_iou > 0.95 && vs.fg_psnr_db.unwrap() > 25.0, "{vs:?}");
    let empty = dir.path().join("empty.sct");
    write_scene_file(&empty, &Scene::single_tree(Default::default(), sct_format::SceneTree::default()), &WriteOptions::default()).unwrap();
    let e = render_file(&empty, &o).unwrap();
    assert_eq!(e.frame.covered(), 0);
}


/// A far instance is drawn from its tree's coarse levels: a 60 × 60 grid of tinted spheres
/// (leaves 1/40 of the radius apart) seen iso at 320 × 240, each instance about 7 covered pixels. Each
/// instance is a cell from its root; its samples are taken the fewest levels down at which
/// they are at most the footprint wide (not a fixed 8 levels, 2^8 samples of a small
/// fraction of a pixel each). Measured when set: 5.1 samples streamed per covered pixel
/// (fixed 8 levels: 23.0), 20.2 dB / IoU 0.990 against zbuffer's one-sample frame (fixed 8
/// levels: 17.9 dB / 0.981; the tiny instances alias in both); every cell sorted on this
/// first frame (before instance keys were fully mixed, the instances at (x, z) and
/// (−x, −z) shared one kept order: 1,709 cells found another instance's). Bounds: at most
/// 10 samples per covered pixel, 19 dB and IoU 0.98 against the depth buffer, every cell
/// sorted.
#[test]
fn far_instances_stream_few_samples() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = synth::uv_sphere([0.0; 3], 1.0, 24, [0.8, 0.8, 0.8, 1.0]);
    let tree = synth::build_tree(synth::sample_mesh(&mesh, 0.05)).unwrap();
    let scene = synth::instance_grid(tree, 60, 60, 2.5, |i| Some([255, 200 + (i * 7 % 56) as u8, 150 + (i * 13 % 60) as u8, 255])).unwrap();
    let sct = dir.path().join("grid60.sct");
    write_scene_file(&sct, &scene, &WriteOptions::default()).unwrap();
    let o = parilov(RenderOptions { width: 320, height: 240, view: render_preview::ViewPreset::Iso, ..RenderOptions::default() });
    let out = render_file(&sct, &o).unwrap();
    let z = render_file(&sct, &RenderOptions { method: Method::Zbuffer, supersample: 1, ..o.clone() }).unwrap();
    let vs = metrics::compare(&out.frame, &z.frame);
    let ps = out.stats.parilov.unwrap();
    let per_pixel = ps.samples as f64 / out.stats.work.covered_pixels.max(1) as f64;
    eprintln!("grid 60: {per_pixel:.2} samples per covered pixel, {ps:?}\nvs zbuffer {vs:?}");
    assert!(ps.cells >= 3000, "{ps:?}");
    assert!(per_pixel <= 10.0, "{per_pixel} samples per covered pixel");
    assert!(vs.silhouette_iou >= 0.98 && vs.fg_psnr_db.unwrap() >= 19.0, "{vs:?}");
    assert_eq!(ps.cells_resorted, ps.cells, "a first frame sorts every cell");
}
