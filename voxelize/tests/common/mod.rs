#![allow(dead_code)]
use std::path::PathBuf;

use voxelize::mesh::LoadedScene;
use voxelize::sample::{sample_scene, Density, Sampled, SampleOptions};

/// The shared models folder (`../shared/models` from the workspace root), if present.
pub fn models() -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/models");
    p.is_dir().then_some(p)
}

pub fn model(rel: &str) -> Option<PathBuf> {
    let p = models()?.join(rel);
    p.exists().then_some(p)
}

/// A voxel size giving roughly `per_diag` voxels across the scene's diagonal.
pub fn coarse(scene: &LoadedScene, per_diag: f64) -> f64 {
    let (lo, hi) = scene.world_bounds().expect("non-empty scene");
    let d: f64 = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    d / per_diag
}

pub fn sample(scene: &LoadedScene, h: f64, merge: bool) -> Sampled {
    let opts = SampleOptions { density: Density::VoxelSize(h), merge, ..Default::default() };
    sample_scene(scene, &opts, &|_, _| {}).expect("sampling succeeds")
}

pub fn spheres(s: &Sampled) -> Vec<([f64; 3], f64)> {
    voxelize::sample::world_spheres(&s.meshes)
}
