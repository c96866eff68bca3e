//! Sample centres stand on the surface they sample, and the sample spheres still cover it:
//! planar faces at voxel sizes from a fraction of the model to larger than it (clamped),
//! every sampler and area mode; a real scan's centres lie close to its surface.

mod common;

use common::*;
use voxelize::mesh::{Instance, LoadedScene, Material, Mesh, Primitive, IDENTITY};
use voxelize::sample::{coverage, sample_scene, world_spheres, AreaMode, Density, Method, SampleOptions, Sampled};
use voxelize::{load, LoadOptions};

fn scene_of(name: &str, positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>) -> LoadedScene {
    LoadedScene {
        meshes: vec![Mesh { name: name.into(), primitives: vec![Primitive { positions, triangles, ..Default::default() }] }],
        instances: vec![Instance { mesh: 0, transform: IDENTITY }],
        materials: vec![Material::default()],
        ..Default::default()
    }
}

/// A 2 × 2 square at y = 0 (a voxel face of every grid), x and z in [−1, 1].
fn quad() -> LoadedScene {
    scene_of("quad", vec![[-1.0, 0.0, -1.0], [1.0, 0.0, -1.0], [1.0, 0.0, 1.0], [-1.0, 0.0, 1.0]], vec![[0, 2, 1], [0, 3, 2]])
}

/// The unit cube [0, 1]³, twelve outward-facing triangles.
fn unit_box() -> LoadedScene {
    let positions: Vec<[f32; 3]> = (0..8).map(|i| [(i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32]).collect();
    let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
    let triangles = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
    scene_of("box", positions, triangles)
}

/// The samplers and modes every planar test runs: (method, merge, area).
const MODES: [(Method, bool, AreaMode); 6] = [
    (Method::Voxel, true, AreaMode::Exact),
    (Method::Voxel, false, AreaMode::Exact),
    (Method::Voxel, true, AreaMode::Eq17),
    (Method::Scanline, true, AreaMode::Eq17),
    (Method::Scanline, false, AreaMode::Eq17),
    (Method::Vertex, true, AreaMode::Exact),
];

fn run(scene: &LoadedScene, h: f64, (method, merge, area): (Method, bool, AreaMode)) -> Sampled {
    let opts = SampleOptions { method, merge, area, density: Density::VoxelSize(h), ..Default::default() };
    sample_scene(scene, &opts, &|_, _| {}).expect("samples")
}

fn centres(s: &Sampled) -> Vec<[f64; 3]> {
    world_spheres(&s.meshes).into_iter().map(|s| s.0).collect()
}

/// Distance from `p` to the surface of the box `[0, 1]³`.
fn box_distance(p: [f64; 3]) -> f64 {
    let inside = p.iter().all(|&x| (0.0..=1.0).contains(&x));
    if inside {
        p.iter().map(|&x| x.min(1.0 - x)).fold(f64::INFINITY, f64::min)
    } else {
        p.iter().map(|&x| (-x).max(x - 1.0).max(0.0).powi(2)).sum::<f64>().sqrt()
    }
}

/// On a plane at y = 0 every centre lies on the plane (to f32 rounding) and on the square,
/// at every voxel size (the plane lies on voxel faces), for every sampler and mode, merged
/// or not; voxels wider than the square are clamped to it.
#[test]
fn planar_quad_centres_lie_on_the_plane() {
    let scene = quad();
    for h in [0.55, 0.3, 0.07, 0.013, 1.7, 5.0] {
        for mode in MODES {
            let s = run(&scene, h, mode);
            let c = centres(&s);
            assert!(!c.is_empty());
            for p in &c {
                assert!(p[1].abs() <= 1e-5 * 2.0, "{mode:?} voxel {h}: centre {p:?} off the plane");
                assert!(p[0].abs() <= 1.0 + 1e-5 && p[2].abs() <= 1.0 + 1e-5, "{mode:?} voxel {h}: centre {p:?} off the square");
            }
            // The vertex sampler has no voxels to clamp.
            let want = if mode.0 == Method::Vertex { h } else { h.min(2.0) };
            assert_eq!(s.voxel.size, want, "{mode:?}");
        }
    }
}

/// The unit box: unmerged centres lie on its faces; merged ones too where their pieces come
/// from one face (their normal is that face's), else inside the box (the mean of points on
/// two or three faces); every centre lies in the box, at every voxel size.
#[test]
fn box_centres_lie_on_its_faces() {
    let scene = unit_box();
    for h in [0.55, 0.3, 0.13, 0.031, 2.0] {
        for mode in MODES {
            let s = run(&scene, h, mode);
            for m in &s.meshes {
                for n in &m.samples {
                    let p = n.center.map(f64::from);
                    assert!(p.iter().all(|&x| (-1e-6..=1.0 + 1e-6).contains(&x)), "{mode:?} voxel {h}: centre {p:?} outside the box");
                    // Merging keeps the faces of an edge or corner voxel apart: every centre
                    // lies on a face, with that face's normal.
                    assert!(box_distance(p) <= 1e-5, "{mode:?} voxel {h}: centre {p:?} is {} off the box", box_distance(p));
                    if mode.0 != Method::Vertex {
                        let axis_normal = n.normal.iter().filter(|&&x| x.abs() > 1.0 - 1e-6).count() == 1;
                        assert!(axis_normal, "{mode:?} voxel {h}: normal {:?} at {p:?} is no face's", n.normal);
                    }
                }
            }
        }
    }
}

/// A closed box whose file normals all point inward: every sample's normal still points
/// out, to the side the winding calls the front (renderers cull one-sided trees by the
/// normals, mesh renderers by the winding; they must agree).
#[test]
fn inward_file_normals_face_the_winding_front() {
    let mut scene = unit_box();
    let prim = &mut scene.meshes[0].primitives[0];
    prim.normals = Some(prim.positions.iter().map(|p| p.map(|x| 0.5 - x)).collect());
    for mode in MODES {
        let s = run(&scene, 0.13, mode);
        for n in s.meshes.iter().flat_map(|m| &m.samples) {
            let out: f32 = (0..3).map(|k| n.normal[k] * (n.center[k] - 0.5)).sum();
            assert!(out > 0.0, "{mode:?}: normal {:?} at {:?} points into the box", n.normal, n.center);
        }
    }
}

/// Dense random points of the faces each lie in some sample sphere (the voxel method covers
/// by construction, merged or not, with exact or EQ 17 areas); the scan-line method covers
/// the columns whose centres its triangles hold, so everything a voxel inside the edges.
#[test]
fn spheres_cover_planar_faces_at_any_voxel_size() {
    for (name, scene) in [("quad", quad()), ("box", unit_box())] {
        let pts = voxelize::mesh::surface_points(&scene, 20_000, 3);
        for h in [0.55, 0.3, 0.07, 1.7, 5.0] {
            for mode in MODES {
                let s = run(&scene, h, mode);
                let h = s.voxel.size;
                let inner: Vec<[f64; 3]> = match (name, mode.0) {
                    (_, Method::Voxel | Method::Vertex) => pts.clone(),
                    // Points at least a voxel from every edge of the quad.
                    ("quad", Method::Scanline) => pts.iter().filter(|p| p[0].abs() <= 1.0 - h && p[2].abs() <= 1.0 - h).copied().collect(),
                    _ => continue,
                };
                let (frac, missed) = coverage(&world_spheres(&s.meshes), &inner);
                assert!(missed.is_empty(), "{name} {mode:?} voxel {h}: coverage {frac}, e.g. {:?} uncovered", missed.first().map(|&i| inner[i]));
            }
        }
    }
}

/// The vertex sampler's centres are the mesh's vertices.
#[test]
fn vertex_samples_sit_on_vertices() {
    let scene = unit_box();
    let s = run(&scene, 0.3, (Method::Vertex, true, AreaMode::Exact));
    let verts = &scene.meshes[0].primitives[0].positions;
    assert_eq!(s.meshes[0].samples.len(), verts.len());
    for n in &s.meshes[0].samples {
        assert!(verts.iter().any(|v| (0..3).all(|k| (v[k] - n.center[k]).abs() <= 1e-6)), "{:?} is no vertex", n.center);
    }
}

/// A voxel far wider than the model (the Duck at 1000 units) is clamped to the model's
/// largest extent with a warning; every centre lies in the model's world bounding box and
/// the spheres still cover the surface.
#[test]
fn a_voxel_wider_than_the_model_is_clamped() {
    let Some(path) = model("gltf/Duck/glTF-Binary/Duck.glb") else { return };
    let scene = load(&path, &LoadOptions::default()).expect("duck");
    let (lo, hi) = scene.world_bounds().expect("bounds");
    let extent = (0..3).map(|k| hi[k] - lo[k]).fold(0.0, f64::max);
    for mode in [(Method::Voxel, true, AreaMode::Exact), (Method::Voxel, false, AreaMode::Eq17), (Method::Scanline, true, AreaMode::Eq17)] {
        let s = run(&scene, 1000.0, mode);
        assert_eq!(s.voxel.size, extent, "{mode:?}");
        assert!(s.voxel.reason.contains("clamped"), "{}", s.voxel.reason);
        assert!(s.stats.warnings.iter().any(|w| w.contains("larger than the model")), "{:?}", s.stats.warnings);
        let slack = 1e-6 * extent;
        for p in centres(&s) {
            assert!((0..3).all(|k| p[k] >= lo[k] - slack && p[k] <= hi[k] + slack), "{mode:?}: centre {p:?} outside {lo:?}..{hi:?}");
        }
        if mode.0 == Method::Voxel {
            let pts = voxelize::mesh::surface_points(&scene, 20_000, 5);
            let (frac, missed) = coverage(&world_spheres(&s.meshes), &pts);
            assert!(missed.is_empty(), "{mode:?}: coverage {frac}");
        }
    }
    // A voxel that fits is left alone.
    let s = run(&scene, extent / 3.0, MODES[0]);
    assert_eq!(s.voxel.size, extent / 3.0);
    assert!(s.stats.warnings.is_empty());
}

/// A scan's centres lie on or near its surface: unmerged ones on their triangles (to
/// rounding), merged ones within a small fraction of a voxel (the mean of pieces of a
/// curved surface lies under it).
#[test]
fn scan_centres_lie_near_the_surface() {
    let Some(path) = model("scans/stanford-bunny-original-ply/bun_zipper_res2.ply") else { return };
    let scene = load(&path, &LoadOptions::default()).expect("bunny");
    let tris = world_triangles(&scene);
    let h = coarse(&scene, 150.0);
    for (mode, max_voxels, mean_voxels) in [((Method::Voxel, false, AreaMode::Exact), 1e-5, 1e-6), ((Method::Voxel, true, AreaMode::Exact), 0.2, 0.01), ((Method::Scanline, false, AreaMode::Eq17), 1e-5, 1e-6)] {
        let s = run(&scene, h, mode);
        let d = surface_distances(&tris, &centres(&s), 2.0 * h);
        let max = d.iter().fold(0.0f64, |m, &x| m.max(x)) / h;
        let mean = d.iter().sum::<f64>() / d.len() as f64 / h;
        assert!(max <= max_voxels && mean <= mean_voxels, "{mode:?}: centres up to {max} voxels ({mean} on average) off the surface");
    }
}

/// A piece cut by a depth face whose upper part is a sliver (no polygon of its own, only the
/// rounding of the lower part's area) stands at a point of the piece, not at a centroid by
/// difference: that division by almost nothing put a sample of spot's control mesh 4 voxels
/// off its surface, with a 4-voxel radius to reach its piece (at the default view's voxel).
#[test]
fn sliver_parts_at_depth_faces_stay_on_the_surface() {
    let Some(path) = model("textured-obj/spot/spot_control_mesh.obj") else { return };
    let scene = load(&path, &LoadOptions::default()).expect("spot control mesh");
    let tris = world_triangles(&scene);
    let h = 0.005_380_232_215_109_83;
    for merge in [false, true] {
        let s = run(&scene, h, (Method::Voxel, merge, AreaMode::Exact));
        let sph = spheres(&s);
        let d = surface_distances(&tris, &centres(&s), 2.0 * h);
        let max = d.iter().fold(0.0f64, |m, &x| m.max(x)) / h;
        // A piece lies in its voxel and its centroid in the piece: within √3 voxels.
        let widest = sph.iter().fold(0.0f64, |m, s| m.max(s.1)) / h;
        assert!(max <= if merge { 0.5 } else { 1e-4 } && widest <= 3f64.sqrt(), "merge {merge}: centres up to {max} voxels off the surface, radii up to {widest} voxels");
    }
}

/// Figures for a report, not a check: the distance from a samples file's centres to the
/// surface of a model, in voxel units. `SCT_SAMPLES=… SCT_MODEL=… SCT_VOXEL=… cargo test
/// --release -p voxelize --test surface -- --ignored --nocapture measure`.
#[test]
#[ignore]
fn measure_centre_to_surface_distance() {
    let (Ok(samples), Ok(mesh), Ok(h)) = (std::env::var("SCT_SAMPLES"), std::env::var("SCT_MODEL"), std::env::var("SCT_VOXEL")) else {
        return eprintln!("set SCT_SAMPLES, SCT_MODEL and SCT_VOXEL");
    };
    let h: f64 = h.parse().expect("SCT_VOXEL is a number");
    let file = sct_format::samples::SamplesFile::read_file(std::path::Path::new(&samples), &sct_format::Limits::default()).expect("samples file");
    let scene = load(std::path::Path::new(&mesh), &LoadOptions::default()).expect("model");
    let tris = world_triangles(&scene);
    let mut points = Vec::new();
    for inst in &file.instances {
        let m = &file.meshes[inst.mesh as usize];
        for n in &file.samples[m.first as usize..(m.first + m.count) as usize] {
            points.push(inst.transform.apply_point(n.center.map(f64::from)));
        }
    }
    let d = surface_distances(&tris, &points, 2.0 * h);
    let mut sorted = d.clone();
    sorted.sort_by(f64::total_cmp);
    let pct = |q: f64| sorted[((sorted.len() - 1) as f64 * q) as usize] / h;
    let radii: Vec<f64> = file.samples.iter().map(|n| f64::from(n.radius) / h).collect();
    println!(
        "{} samples: centre to surface (voxels) max {:.3e} mean {:.3e} median {:.3e} p99 {:.3e}; radius (voxels) min {:.4} mean {:.4} max {:.4}",
        d.len(),
        pct(1.0),
        d.iter().sum::<f64>() / d.len() as f64 / h,
        pct(0.5),
        pct(0.99),
        radii.iter().fold(f64::INFINITY, |m, &x| m.min(x)),
        radii.iter().sum::<f64>() / radii.len() as f64,
        radii.iter().fold(0.0f64, |m, &x| m.max(x)),
    );
}
