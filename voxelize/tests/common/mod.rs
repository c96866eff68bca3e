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


/// The scene's world triangles (every instance applied).
pub fn world_triangles(scene: &LoadedScene) -> Vec<[[f64; 3]; 3]> {
    let mut out = Vec::new();
    for inst in &scene.instances {
        for p in &scene.meshes[inst.mesh].primitives {
            for t in &p.triangles {
                out.push(t.map(|i| voxelize::mesh::transform_point(&inst.transform, p.positions[i as usize])));
            }
        }
    }
    out
}

/// Distance from each of `points` to the nearest of `tris`: triangles bucketed in a grid of
/// `cell`, searched ring by ring until no unvisited cell can hold a nearer one.
pub fn surface_distances(tris: &[[[f64; 3]; 3]], points: &[[f64; 3]], cell: f64) -> Vec<f64> {
    use rayon::prelude::*;
    use std::collections::HashMap;
    let key = |p: [f64; 3]| p.map(|x| (x / cell).floor() as i64);
    let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
    for (i, t) in tris.iter().enumerate() {
        let lo = key(std::array::from_fn(|k| t.iter().map(|v| v[k]).fold(f64::INFINITY, f64::min)));
        let hi = key(std::array::from_fn(|k| t.iter().map(|v| v[k]).fold(f64::NEG_INFINITY, f64::max)));
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    grid.entry([x, y, z]).or_default().push(i as u32);
                }
            }
        }
    }
    points
        .par_iter()
        .map(|&p| {
            let c = key(p);
            let mut best = f64::INFINITY;
            for ring in 0i64..=64 {
                for dx in -ring..=ring {
                    for dy in -ring..=ring {
                        for dz in -ring..=ring {
                            if dx.abs().max(dy.abs()).max(dz.abs()) != ring {
                                continue;
                            }
                            for &i in grid.get(&[c[0] + dx, c[1] + dy, c[2] + dz]).map_or(&[][..], |v| &v[..]) {
                                let q = voxelize::mesh::closest_on_triangle(p, &tris[i as usize]);
                                best = best.min(((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2)).sqrt());
                            }
                        }
                    }
                }
                if best <= ring as f64 * cell {
                    return best;
                }
            }
            // Far from everything: every triangle.
            tris.iter().map(|t| {
                let q = voxelize::mesh::closest_on_triangle(p, t);
                ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2)).sqrt()
            }).fold(best, f64::min)
        })
        .collect()
}

/// A one-triangle glTF whose buffer (and optionally an image) has the given URI.
pub fn gltf_with(buffer_uri: &str, image_uri: Option<&str>) -> String {
    let images = image_uri.map_or(String::new(), |u| format!(r#","images":[{{"uri":{u:?}}}]"#));
    format!(
        r#"{{"asset":{{"version":"2.0"}},"buffers":[{{"uri":{buffer_uri:?},"byteLength":36}}],
"bufferViews":[{{"buffer":0,"byteLength":36}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],"nodes":[{{"mesh":0}}],"scenes":[{{"nodes":[0]}}],"scene":0{images}}}"#
    )
}

/// The unit triangle's three positions (f32, little-endian): the buffer of [`gltf_with`].
pub fn triangle_bin() -> Vec<u8> {
    [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0].iter().flat_map(|v| v.to_le_bytes()).collect()
}
