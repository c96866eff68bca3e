//! PLY export read back by an independent PLY parser (the voxelizer's ply-rs-bw loader):
//! samples files and SCT level cuts.

use std::path::{Path, PathBuf};

use sct_format::export::{level_cut, samples_to_ply, scene_to_ply};
use sct_format::samples::SamplesFile;
use sct_format::traverse::TraverseOptions;
use sct_format::{Limits, Profile, SctReader};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("workspace root").to_path_buf()
}

fn read_ply_points(path: &Path) -> voxelize::mesh::PointCloud {
    let scene = voxelize::load(path, &voxelize::LoadOptions::default()).expect("ply-rs-bw reads the export");
    assert_eq!(scene.meshes.iter().map(|m| m.triangle_count()).sum::<usize>(), 0, "a point cloud, no faces");
    scene.points.expect("a point cloud")
}

#[test]
fn samples_and_level_cuts_round_trip_through_a_ply_parser() {
    let dir = tempfile::tempdir().expect("tempdir");
    let samples_path = dir.path().join("fuze.samples");
    let opts = voxelize::Options {
        inputs: vec![repo().join("assets/fuze/fuze.obj")],
        output: Some(samples_path.clone()),
        load: Default::default(),
        sample: Default::default(),
    };
    voxelize::run(&opts, &|_, _| {}).expect("voxelize");
    let samples = SamplesFile::read_file(&samples_path, &Limits::default()).expect("samples");

    // Samples: every sample once (one identity placement), positions, normals and radii
    // exact, colours as stored.
    let ply = dir.path().join("samples.ply");
    let s = samples_to_ply(&samples, &ply, u64::MAX).expect("export");
    assert_eq!(s.points as usize, samples.samples.len());
    let pc = read_ply_points(&ply);
    assert_eq!(pc.positions.len(), samples.samples.len());
    for (p, n) in pc.positions.iter().zip(&samples.samples) {
        assert_eq!(*p, n.center);
    }
    let normals = pc.normals.expect("normals");
    assert!(normals.iter().zip(&samples.samples).all(|(a, n)| *a == n.normal));
    // The loader linearises sRGB bytes; re-encoding must give the stored bytes back.
    let colors = pc.colors.expect("colours exported");
    let srgb = |l: f32| {
        let v = if l <= 0.003_130_8 { 12.92 * l } else { 1.055 * l.powf(1.0 / 2.4) - 0.055 };
        (v * 255.0).round() as i32
    };
    for (c, n) in colors.iter().zip(&samples.samples) {
        for k in 0..3 {
            assert!((srgb(c[k]) - i32::from(n.color[k])).abs() <= 1, "{c:?} vs {:?}", n.color);
        }
    }
    // Radius is not read by the mesh loader: check it from the raw records.
    let data = std::fs::read(&ply).expect("read");
    let body = data.windows(11).position(|w| w == b"end_header\n").expect("header") + 11;
    for (rec, n) in data[body..].chunks_exact(32).zip(&samples.samples) {
        assert_eq!(f32::from_le_bytes([rec[28], rec[29], rec[30], rec[31]]), n.radius);
    }

    // SCT level cut: as many points as the cut of the tree read to that level.
    let sct = dir.path().join("fuze.sct");
    let cfg = build_tree::pipeline::Config {
        samples: samples_path,
        output: sct.clone(),
        scene: None,
        profile: Profile::Default,
        compression_level: None,
        centre_offsets: true,
        leaf_refinement: Default::default(),
        build: Default::default(),
    };
    build_tree::pipeline::run(&cfg, &mut |_| {}).expect("build");
    let reader = SctReader::open(&sct, &Limits::default()).expect("open");
    for level in [0usize, 6, 12] {
        let cut = level_cut(&reader.read_tree_levels(0, level + 1).expect("levels"), level);
        let out = dir.path().join(format!("l{level}.ply"));
        let e = scene_to_ply(&sct, Some(level), &out, TraverseOptions::default(), u64::MAX).expect("export");
        assert_eq!(e.points as usize, cut.len());
        let pc = read_ply_points(&out);
        assert_eq!(pc.positions.len(), cut.len());
        assert!(pc.positions.iter().zip(&cut).all(|(p, n)| *p == n.center));
    }
    // The leaves: one point per leaf.
    let out = dir.path().join("leaves.ply");
    let e = scene_to_ply(&sct, None, &out, TraverseOptions::default(), u64::MAX).expect("export");
    assert_eq!(e.points, reader.read_tree(0).expect("tree").leaf_count() as u64);
}
