//! The accuracy reference: the source mesh rendered with a plain triangle rasterizer under
//! the same camera, headlight shading, textures and alpha handling as the splat renderer
//! (perspective-correct attributes, near-plane clipping, depth test on view-axis depth,
//! back faces culled unless the material is double sided, screen-door alpha).

use std::path::Path;

use voxelize::mesh::{AlphaMode, LoadedScene, Material, TextureRef};

use crate::camera::View;
use crate::error::Result;
use crate::raster::{alpha_passes, Frame};
use crate::shade::{self, Shading};

/// Crease angle for meshes without normals, as the voxelizer uses (thesis §5.2.2).
pub const CREASE_DEG: f32 = 60.0;

/// One world-space triangle with everything shading needs.
#[derive(Clone, Debug)]
pub struct Tri {
    /// Corners, world space.
    pub p: [[f32; 3]; 3],
    /// Unit corner normals, world space.
    pub n: [[f32; 3]; 3],
    /// Linear RGBA corner colours (material factor × vertex colour).
    pub c: [[f32; 4]; 3],
    /// Corner UVs of the base-colour texture's set.
    pub uv: [[f32; 2]; 3],
    /// Corner UVs of the alpha texture's set.
    pub uv_alpha: [[f32; 2]; 3],
    /// Material index into [`WorldMesh::materials`].
    pub material: u32,
}

/// A loaded mesh flattened to world-space triangles.
#[derive(Debug)]
pub struct WorldMesh {
    /// Triangles of every instance.
    pub tris: Vec<Tri>,
    /// Materials (index 0 is the default material).
    pub materials: Vec<Material>,
    /// The scene (for its images).
    pub scene: LoadedScene,
}

fn normalize(v: [f64; 3]) -> [f32; 3] {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if l > 0.0 && l.is_finite() {
        [(v[0] / l) as f32, (v[1] / l) as f32, (v[2] / l) as f32]
    } else {
        [0.0, 0.0, 1.0]
    }
}

impl WorldMesh {
    /// Loads a mesh file with the voxelizer's loader.
    pub fn load(path: &Path) -> Result<WorldMesh> {
        let scene = voxelize::load(path, &voxelize::LoadOptions::default())?;
        Ok(WorldMesh::from_scene(scene))
    }

    /// Flattens a loaded scene.
    pub fn from_scene(scene: LoadedScene) -> WorldMesh {
        let mut materials = vec![Material::default()];
        materials.extend(scene.materials.iter().cloned());
        let mut tris = Vec::new();
        for inst in &scene.instances {
            let Some(mesh) = scene.meshes.get(inst.mesh) else { continue };
            let m = &inst.transform;
            for prim in &mesh.primitives {
                let mat_idx = prim.material.filter(|&i| i < scene.materials.len()).map_or(0, |i| i + 1);
                let mat = &materials[mat_idx];
                let computed =
                    if prim.normals.is_none() { Some(voxelize::mesh::corner_normals(prim, CREASE_DEG)) } else { None };
                let uv_set = |t: &Option<TextureRef>| t.as_ref().and_then(|t| prim.uvs.get(t.tex_coord as usize));
                let (uvs, uvs_a) = (uv_set(&mat.texture), uv_set(&mat.alpha_texture));
                for (ti, t) in prim.triangles.iter().enumerate() {
                    let idx = t.map(|i| i as usize);
                    let p = idx.map(|i| {
                        let w = voxelize::mesh::transform_point(m, prim.positions[i]);
                        [w[0] as f32, w[1] as f32, w[2] as f32]
                    });
                    let n: [[f32; 3]; 3] = std::array::from_fn(|k| {
                        let local = match (&prim.normals, &computed) {
                            (Some(ns), _) => ns.get(idx[k]).copied().unwrap_or([0.0, 0.0, 1.0]),
                            (None, Some(cn)) => cn[ti][k],
                            _ => [0.0, 0.0, 1.0],
                        };
                        normalize(voxelize::mesh::transform_normal(m, local))
                    });
                    let c: [[f32; 4]; 3] = std::array::from_fn(|k| {
                        let vc = prim.colors.as_ref().and_then(|cs| cs.get(idx[k]).copied()).unwrap_or([1.0; 4]);
                        std::array::from_fn(|j| vc[j] * mat.base_color[j])
                    });
                    let get_uv = |set: Option<&Vec<[f32; 2]>>| -> [[f32; 2]; 3] {
                        std::array::from_fn(|k| set.and_then(|s| s.get(idx[k]).copied()).unwrap_or([0.0; 2]))
                    };
                    tris.push(Tri { p, n, c, uv: get_uv(uvs), uv_alpha: get_uv(uvs_a), material: mat_idx as u32 });
                }
            }
        }
        WorldMesh { tris, materials, scene }
    }

    /// Linear RGBA of triangle `t` at barycentric `b`, after the material's alpha mode
    /// (alpha 0 means "no surface here").
    pub fn color_at(&self, t: &Tri, b: [f32; 3]) -> [f32; 4] {
        let mat = &self.materials[t.material as usize];
        let mut c: [f32; 4] = std::array::from_fn(|j| b[0] * t.c[0][j] + b[1] * t.c[1][j] + b[2] * t.c[2][j]);
        let lerp_uv = |uv: &[[f32; 2]; 3]| [b[0] * uv[0][0] + b[1] * uv[1][0] + b[2] * uv[2][0], b[0] * uv[0][1] + b[1] * uv[1][1] + b[2] * uv[2][1]];
        if let Some(tex) = &mat.texture {
            if let Some(img) = self.scene.images.get(tex.image) {
                let s = img.sample(tex.transform_uv(lerp_uv(&t.uv)), tex.wrap_s, tex.wrap_t);
                for j in 0..4 {
                    c[j] *= s[j];
                }
            }
        }
        if let Some(tex) = &mat.alpha_texture {
            if let Some(img) = self.scene.images.get(tex.image) {
                let s = img.sample(tex.transform_uv(lerp_uv(&t.uv_alpha)), tex.wrap_s, tex.wrap_t);
                c[3] *= 0.2126 * s[0] + 0.7152 * s[1] + 0.0722 * s[2];
            }
        }
        c[3] = match mat.alpha_mode {
            AlphaMode::Opaque => 1.0,
            AlphaMode::Mask(cut) => {
                if c[3] < cut {
                    0.0
                } else {
                    1.0
                }
            }
            AlphaMode::Blend => c[3].clamp(0.0, 1.0),
        };
        c
    }

    /// Unit normal of triangle `t` at barycentric `b`.
    pub fn normal_at(t: &Tri, b: [f32; 3]) -> [f32; 3] {
        let v: [f64; 3] = std::array::from_fn(|j| (b[0] * t.n[0][j] + b[1] * t.n[1][j] + b[2] * t.n[2][j]) as f64);
        normalize(v)
    }

    /// World bounding sphere (centre of the box, half diagonal).
    pub fn bound(&self) -> Option<([f64; 3], f64)> {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for t in &self.tris {
            for p in &t.p {
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k] as f64);
                    hi[k] = hi[k].max(p[k] as f64);
                }
            }
        }
        if self.tris.is_empty() {
            return None;
        }
        let c = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0, (lo[2] + hi[2]) / 2.0];
        let r = ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2)).sqrt() / 2.0;
        Some((c, r))
    }
}

/// A camera-space vertex during clipping: position and barycentric weights in the
/// original triangle.
#[derive(Clone, Copy)]
struct CV {
    p: [f32; 3],
    b: [f32; 3],
}

fn lerp(a: CV, b: CV, t: f32) -> CV {
    CV { p: std::array::from_fn(|k| a.p[k] + (b.p[k] - a.p[k]) * t), b: std::array::from_fn(|k| a.b[k] + (b.b[k] - a.b[k]) * t) }
}

/// Renders `mesh` into a new frame.
pub fn render_reference(mesh: &WorldMesh, view: &View, shading: Shading, background: [u8; 3]) -> Frame {
    let (w, h) = (view.width as usize, view.height as usize);
    let [r, g, b] = background;
    let mut frame = Frame::new(w, h, [r, g, b, 255]);
    let eye = view.eye;
    for t in &mesh.tris {
        let mat = &mesh.materials[t.material as usize];
        // Back faces (by winding) are culled like back-facing normal cones.
        if !mat.double_sided {
            let e1: [f64; 3] = std::array::from_fn(|k| (t.p[1][k] - t.p[0][k]) as f64);
            let e2: [f64; 3] = std::array::from_fn(|k| (t.p[2][k] - t.p[0][k]) as f64);
            let nf = [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]];
            let to_eye: [f64; 3] = std::array::from_fn(|k| eye[k] - t.p[0][k] as f64);
            if nf[0] * to_eye[0] + nf[1] * to_eye[1] + nf[2] * to_eye[2] < 0.0 {
                continue;
            }
        }
        let cv: [CV; 3] = std::array::from_fn(|k| {
            let mut bb = [0.0; 3];
            bb[k] = 1.0;
            CV { p: view.to_camera(t.p[k].map(f64::from)), b: bb }
        });
        // Clip against the near plane (Sutherland–Hodgman, one plane).
        let near = view.near;
        let mut poly: Vec<CV> = Vec::with_capacity(4);
        for k in 0..3 {
            let (a, bv) = (cv[k], cv[(k + 1) % 3]);
            let (ina, inb) = (a.p[2] >= near, bv.p[2] >= near);
            if ina {
                poly.push(a);
            }
            if ina != inb {
                poly.push(lerp(a, bv, (near - a.p[2]) / (bv.p[2] - a.p[2])));
            }
        }
        for k in 1..poly.len().saturating_sub(1) {
            raster_tri(mesh, t, [poly[0], poly[k], poly[k + 1]], view, shading, &mut frame);
        }
    }
    frame
}

fn raster_tri(mesh: &WorldMesh, t: &Tri, v: [CV; 3], view: &View, shading: Shading, frame: &mut Frame) {
    let (w, h) = (frame.width, frame.height);
    let s: [[f32; 2]; 3] = v.map(|c| view.project(c.p));
    let area = (s[1][0] - s[0][0]) * (s[2][1] - s[0][1]) - (s[2][0] - s[0][0]) * (s[1][1] - s[0][1]);
    if area.abs() < 1e-12 || !area.is_finite() {
        return;
    }
    let minx = s.iter().map(|p| p[0]).fold(f32::INFINITY, f32::min);
    let maxx = s.iter().map(|p| p[0]).fold(f32::NEG_INFINITY, f32::max);
    let miny = s.iter().map(|p| p[1]).fold(f32::INFINITY, f32::min);
    let maxy = s.iter().map(|p| p[1]).fold(f32::NEG_INFINITY, f32::max);
    let x0 = ((minx - 0.5).ceil().max(0.0)) as usize;
    let y0 = ((miny - 0.5).ceil().max(0.0)) as usize;
    let x1 = (maxx - 0.5).floor().min(w as f32 - 1.0);
    let y1 = (maxy - 0.5).floor().min(h as f32 - 1.0);
    if x1 < 0.0 || y1 < 0.0 {
        return;
    }
    let (x1, y1) = (x1 as usize, y1 as usize);
    let inv_z = v.map(|c| 1.0 / c.p[2]);
    for py in y0..=y1 {
        let fy = py as f32 + 0.5;
        for px in x0..=x1 {
            let fx = px as f32 + 0.5;
            let edge = |a: [f32; 2], b: [f32; 2]| (b[0] - a[0]) * (fy - a[1]) - (fx - a[0]) * (b[1] - a[1]);
            let w0 = edge(s[1], s[2]) / area;
            let w1 = edge(s[2], s[0]) / area;
            let w2 = 1.0 - w0 - w1;
            if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                continue;
            }
            // Perspective-correct weights.
            let q = [w0 * inv_z[0], w1 * inv_z[1], w2 * inv_z[2]];
            let qs = q[0] + q[1] + q[2];
            let z = 1.0 / qs;
            let i = py * w + px;
            if z >= frame.depth[i] {
                continue;
            }
            let pw = [q[0] / qs, q[1] / qs, q[2] / qs];
            let b: [f32; 3] = std::array::from_fn(|k| pw[0] * v[0].b[k] + pw[1] * v[1].b[k] + pw[2] * v[2].b[k]);
            let c = mesh.color_at(t, b);
            let a8 = (c[3] * 255.0 + 0.5) as u8;
            if a8 == 0 || !alpha_passes(a8, px, py) {
                continue;
            }
            let k = if shading == Shading::Lambert {
                let n = view.dir_to_camera(WorldMesh::normal_at(t, b).map(f64::from));
                let p: [f32; 3] = std::array::from_fn(|k| pw[0] * v[0].p[k] + pw[1] * v[1].p[k] + pw[2] * v[2].p[k]);
                let d = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt().max(1e-30);
                shade::lambert([n[0] as f32, n[1] as f32, n[2] as f32], [-p[0] / d, -p[1] / d, -p[2] / d])
            } else {
                1.0
            };
            frame.depth[i] = z;
            frame.color[i] = [
                shade::linear_to_srgb8(c[0] * k),
                shade::linear_to_srgb8(c[1] * k),
                shade::linear_to_srgb8(c[2] * k),
                255,
            ];
        }
    }
}
