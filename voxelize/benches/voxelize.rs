//! `cargo bench -p voxelize`: the bunny at thesis Table 8 (k = 3, γ = 2), a dense bunny run
//! and a dense textured run (spot, ≥ 20 M samples). Prints figures for BENCHMARKS.md; not a
//! timed test.

use std::time::Instant;

use voxelize::sample::{sample_scene, Density, SampleOptions};
use voxelize::{load, LoadOptions};

fn main() {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/models");
    let bunny = root.join("scans/stanford-bunny/stanford-bunny.obj");
    let spot = root.join("textured-obj/spot/spot_triangulated.obj");
    let spot_opts = LoadOptions { texture_override: Some(root.join("textured-obj/spot/spot_texture.png")), ..Default::default() };
    let runs = [
        ("bunny Table 8 (k=3, γ=2)", &bunny, LoadOptions::default(), Density::Auto { k: 3.0, gamma: 2.0, min_base: None }),
        ("bunny dense (voxel 6e-5)", &bunny, LoadOptions::default(), Density::VoxelSize(6e-5)),
        ("spot textured dense (voxel 6e-4)", &spot, spot_opts, Density::VoxelSize(6e-4)),
    ];
    for (label, path, lopts, density) in runs {
        let scene = match load(path, &lopts) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("{label}: skipped ({e})");
                continue;
            }
        };
        let opts = SampleOptions { density, ..Default::default() };
        let t = Instant::now();
        let s = match sample_scene(&scene, &opts, &|_, _| {}) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("{label}: {e}");
                continue;
            }
        };
        let secs = t.elapsed().as_secs_f64();
        println!(
            "{label}: voxel {:.3e}, {} samples before merging, {} after, {:.2} s, {:.2} M samples/s, area error {:.2e}",
            s.voxel.size,
            s.stats.samples_before_merge,
            s.stats.samples,
            secs,
            s.stats.samples as f64 / secs / 1e6,
            (s.stats.sample_area - s.stats.mesh_area) / s.stats.mesh_area
        );
    }
}
