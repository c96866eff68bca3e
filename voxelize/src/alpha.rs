//! Which points of a surface the voxelizer keeps by alpha: glTF `MASK` below the cutoff and
//! fully transparent `BLEND` (OBJ `d`, `map_d`) make no samples. [`visible_surface_points`]
//! draws test points from the rest only, so a coverage check (`sct-inspect --against …
//! --exclude-alpha-dropped`) can gate alpha-masked assets too.

use crate::mesh::{cross, norm, sub, transform_point, AlphaMode, LoadedScene, Material, Primitive};

/// Alpha at a point of triangle `tri` of `p` with barycentric weights `w`, as the samplers
/// compute it: base colour × vertex colour × texture alpha × the alpha texture's luminance.
fn alpha_at(m: &Material, scene: &LoadedScene, p: &Primitive, tri: [u32; 3], w: [f64; 3]) -> f32 {
    let wf = w.map(|x| x as f32);
    let mix4 = |c: &[[f32; 4]]| -> [f32; 4] {
        std::array::from_fn(|k| (0..3).map(|i| c.get(tri[i] as usize).map_or(1.0, |v| v[k]) * wf[i]).sum())
    };
    let uv = |set: u32| -> [f32; 2] {
        let Some(uvs) = p.uvs.get(set as usize) else { return [0.0; 2] };
        std::array::from_fn(|k| (0..3).map(|i| uvs.get(tri[i] as usize).map_or(0.0, |v| v[k]) * wf[i]).sum())
    };
    let mut a = m.base_color[3];
    if let Some(c) = &p.colors {
        a *= mix4(c)[3];
    }
    if let Some(t) = &m.texture {
        if let Some(img) = scene.images.get(t.image) {
            a *= img.sample(t.transform_uv(uv(t.tex_coord)), t.wrap_s, t.wrap_t)[3];
        }
    }
    if let Some(t) = &m.alpha_texture {
        if let Some(img) = scene.images.get(t.image) {
            let s = img.sample(t.transform_uv(uv(t.tex_coord)), t.wrap_s, t.wrap_t);
            a *= 0.2126 * s[0] + 0.7152 * s[1] + 0.0722 * s[2];
        }
    }
    a
}

/// Whether the voxelizer keeps a sample at this point (the alpha rule of its shading).
pub fn kept_by_alpha(scene: &LoadedScene, p: &Primitive, tri: [u32; 3], w: [f64; 3]) -> bool {
    let m = scene.material(p);
    match m.alpha_mode {
        AlphaMode::Opaque => true,
        AlphaMode::Mask(cut) => alpha_at(&m, scene, p, tri, w) >= cut,
        AlphaMode::Blend => alpha_at(&m, scene, p, tri, w) >= 0.5 / 255.0,
    }
}

/// `n` points drawn uniformly by area over the placed triangles, like
/// [`crate::mesh::surface_points`], but only where [`kept_by_alpha`] holds; and the number
/// of draws left out. Fewer than `n` points when almost all of the surface is dropped (at
/// most `64 n` draws are made). Load the scene with textures for texture alpha to count.
pub fn visible_surface_points(scene: &LoadedScene, n: usize, seed: u64) -> (Vec<[f64; 3]>, u64) {
    struct Tri<'a> {
        p: &'a Primitive,
        t: [u32; 3],
        w: [[f64; 3]; 3],
    }
    let mut tris: Vec<Tri<'_>> = Vec::new();
    let mut cdf: Vec<f64> = Vec::new();
    let mut total = 0.0;
    for inst in &scene.instances {
        let Some(mesh) = scene.meshes.get(inst.mesh) else { continue };
        for p in &mesh.primitives {
            for &t in &p.triangles {
                let w = t.map(|i| transform_point(&inst.transform, p.positions[i as usize]));
                let a = 0.5 * norm(cross(sub(w[1], w[0]), sub(w[2], w[0])));
                if a > 0.0 {
                    total += a;
                    tris.push(Tri { p, t, w });
                    cdf.push(total);
                }
            }
        }
    }
    let mut out = Vec::with_capacity(n);
    let mut dropped = 0u64;
    if tris.is_empty() {
        return (out, 0);
    }
    let mut rng = sct_format::rng::SplitMix64(seed);
    let max_draws = (n as u64).saturating_mul(64);
    let mut draws = 0u64;
    while out.len() < n && draws < max_draws {
        draws += 1;
        let x = rng.next_f64() * total;
        let i = cdf.partition_point(|&c| c < x).min(tris.len() - 1);
        let tri = &tris[i];
        let (mut u, mut v) = (rng.next_f64(), rng.next_f64());
        if u + v > 1.0 {
            u = 1.0 - u;
            v = 1.0 - v;
        }
        if !kept_by_alpha(scene, tri.p, tri.t, [1.0 - u - v, u, v]) {
            dropped += 1;
            continue;
        }
        let [a, b, c] = tri.w;
        out.push(std::array::from_fn(|k| a[k] + u * (b[k] - a[k]) + v * (c[k] - a[k])));
    }
    (out, dropped)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{Instance, Mesh, IDENTITY};

    /// Two quads side by side, the right one transparent (BLEND, alpha 0): every point kept
    /// lies on the left one, and about half the draws are left out.
    #[test]
    fn transparent_surfaces_are_left_out() {
        let quad = |x0: f32, material: usize| Primitive {
            positions: vec![[x0, 0.0, 0.0], [x0 + 1.0, 0.0, 0.0], [x0 + 1.0, 1.0, 0.0], [x0, 1.0, 0.0]],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            material: Some(material),
            ..Default::default()
        };
        let scene = LoadedScene {
            meshes: vec![Mesh { name: "m".into(), primitives: vec![quad(0.0, 0), quad(1.0, 1)] }],
            instances: vec![Instance { mesh: 0, transform: IDENTITY }],
            materials: vec![
                Material::default(),
                Material { base_color: [1.0, 1.0, 1.0, 0.0], alpha_mode: AlphaMode::Blend, ..Default::default() },
            ],
            ..Default::default()
        };
        let (pts, dropped) = visible_surface_points(&scene, 1000, 7);
        assert_eq!(pts.len(), 1000);
        assert!(pts.iter().all(|p| p[0] <= 1.0), "only the opaque quad");
        assert!((700..1400).contains(&dropped), "{dropped}");
        let all = crate::mesh::surface_points(&scene, 1000, 7);
        assert!(all.iter().any(|p| p[0] > 1.0));
    }
}
