//! The accuracy reference: the source mesh rendered with a plain triangle rasterizer under
//! the same camera, headlight shading, textures and alpha handling as the splat renderer
//! (perspective-correct attributes, near-plane clipping, depth test on view-axis depth,
//! back faces culled only on one-sided meshes, screen-door alpha). Point clouds are drawn
//! as discs turned to their normals, as the splat renderer draws leaves.
//!
//! Which faces are culled is decided per triangle by [`culled`] from the mesh's `two_sided`
//! flag, by the voxelizer's own rule ([`LoadedScene::mesh_two_sided`]: glTF `doubleSided`
//! materials; OBJ and PLY meshes that are open or inconsistently oriented), so the
//! reference culls exactly what the SCT file's two-sided trees leave uncut.

use std::collections::HashMap;
use std::path::Path;

use voxelize::mesh::{AlphaMode, LoadedScene, Material, TextureRef};

use crate::camera::View;
use crate::error::{Error, Result};
use crate::provenance::Provenance;
use crate::raster::{alpha_passes, Frame};
use crate::shade::{self, Shading};
use crate::zbuffer::{resolve, zbuffer_frame};

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
    /// Drawn from both sides (see [`culled`]).
    pub two_sided: bool,
}

/// A point of a point cloud, drawn as a disc turned to its normal.
#[derive(Clone, Copy, Debug)]
pub struct Point {
    /// Centre, world space.
    pub p: [f32; 3],
    /// Disc radius, world units.
    pub radius: f32,
    /// Unit normal (for shading).
    pub n: [f32; 3],
    /// sRGB colour.
    pub color: [u8; 4],
}

/// A loaded mesh flattened to world-space triangles.
#[derive(Debug)]
pub struct WorldMesh {
    /// Triangles of every instance.
    pub tris: Vec<Tri>,
    /// Materials (index 0 is the default material).
    pub materials: Vec<Material>,
    /// Points of a point cloud (a file without faces).
    pub points: Vec<Point>,
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
    /// Loads a mesh file with the voxelizer's loader and default options.
    pub fn load(path: &Path) -> Result<WorldMesh> {
        WorldMesh::load_with(path, &voxelize::LoadOptions::default())
    }

    /// Loads a mesh file with the voxelizer's loader (texture binding as `opts`).
    pub fn load_with(path: &Path, opts: &voxelize::LoadOptions) -> Result<WorldMesh> {
        let scene = voxelize::load(path, opts)?;
        Ok(WorldMesh::from_scene(scene))
    }

    /// Whether nothing can be drawn: no triangles and no points.
    pub fn is_empty(&self) -> bool {
        self.tris.is_empty() && self.points.is_empty()
    }

    /// Flattens a loaded scene.
    pub fn from_scene(scene: LoadedScene) -> WorldMesh {
        let mut materials = vec![Material::default()];
        materials.extend(scene.materials.iter().cloned());
        let mut tris = Vec::new();
        // Per mesh, computed on first use (a topology check for OBJ and PLY meshes).
        let mut two_sided_mesh: HashMap<usize, bool> = HashMap::new();
        for inst in &scene.instances {
            let Some(mesh) = scene.meshes.get(inst.mesh) else { continue };
            let m = &inst.transform;
            // A mirroring transform turns counter-clockwise triangles clockwise: swapping two
            // corners keeps the winding's front where the surface's front is.
            let mirrored = det3(m) < 0.0;
            for prim in &mesh.primitives {
                let mat_idx = prim.material.filter(|&i| i < scene.materials.len()).map_or(0, |i| i + 1);
                let mat = &materials[mat_idx];
                let two_sided = *two_sided_mesh.entry(inst.mesh).or_insert_with(|| scene.mesh_two_sided(inst.mesh));
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
                    let mut tri = Tri { p, n, c, uv: get_uv(uvs), uv_alpha: get_uv(uvs_a), material: mat_idx as u32, two_sided };
                    if mirrored {
                        tri.p.swap(1, 2);
                        tri.n.swap(1, 2);
                        tri.c.swap(1, 2);
                        tri.uv.swap(1, 2);
                        tri.uv_alpha.swap(1, 2);
                    }
                    tris.push(tri);
                }
            }
        }
        let points = scene.points.as_ref().map_or_else(Vec::new, |pc| {
            voxelize::sample::sample_points(pc)
                .into_iter()
                .map(|n| Point { p: n.center, radius: point_radius(&n), n: n.normal, color: n.color })
                .collect()
        });
        WorldMesh { tris, materials, points, scene }
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

    /// World bounding sphere (centre of the box, half diagonal) of the triangles and points.
    pub fn bound(&self) -> Option<([f64; 3], f64)> {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in self.tris.iter().flat_map(|t| &t.p).chain(self.points.iter().map(|p| &p.p)) {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k] as f64);
                hi[k] = hi[k].max(p[k] as f64);
            }
        }
        if self.is_empty() {
            return None;
        }
        let c = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0, (lo[2] + hi[2]) / 2.0];
        let r = ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2)).sqrt() / 2.0;
        Some((c, r))
    }
}

/// How the reference mesh was loaded (reported beside the metrics).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct ReferenceLoad {
    /// The image bound as every material's base-colour texture, if any.
    pub texture: Option<std::path::PathBuf>,
    /// Where `texture` came from: `"option"` (`--reference-texture`), `"provenance"` (the
    /// SCT file's sampling record) or null.
    pub texture_from: Option<&'static str>,
    /// Whether textures were decoded.
    pub textures: bool,
}

/// Loads the reference mesh of the SCT file `sct` with the texture binding it was sampled
/// with (its provenance), or `texture` when given. A texture the provenance names but that
/// cannot be found is an error rather than a silently untextured reference.
pub fn load_for(sct: &Path, mesh: &Path, provenance: &Provenance, texture: Option<&Path>) -> Result<(WorldMesh, ReferenceLoad)> {
    let (texture, texture_from) = match (texture, provenance.locate_texture(mesh, sct)) {
        (Some(t), _) => (Some(t.to_path_buf()), Some("option")),
        (None, Some(Ok(t))) => (Some(t), Some("provenance")),
        (None, Some(Err(tried))) => {
            return Err(Error::ReferenceTexture { recorded: provenance.texture.clone().unwrap_or_default(), tried });
        }
        (None, None) => (None, None),
    };
    let textures = provenance.textures.unwrap_or(true);
    let opts = voxelize::LoadOptions { texture_override: texture.clone(), load_textures: textures, ..Default::default() };
    Ok((WorldMesh::load_with(mesh, &opts)?, ReferenceLoad { texture, texture_from, textures }))
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

/// Renders `mesh` into a new frame, however long that takes (see
/// [`render_reference_bounded`] for untrusted meshes).
pub fn render_reference(mesh: &WorldMesh, view: &View, shading: Shading, background: [u8; 3]) -> Frame {
    match draw(mesh, view, shading, background, u64::MAX) {
        Ok(f) | Err((f, _)) => f,
    }
}

/// What a reference pixel test costs in splat pixel tests: the reference rasterizer draws
/// one triangle at a time on one thread, the splat raster in parallel tiles. Callers bound a
/// reference by [`crate::RenderOptions::max_splat_pixels`] divided by this (2^28 pixels,
/// about 2 s, by default; real meshes test a few million).
pub const REFERENCE_PIXEL_COST: u64 = 8;

/// [`render_reference`] that tests at most `max_pixels` pixels (each triangle and point
/// counted by its bounding box clipped to the image, in output pixels; a triangle's pixel
/// is [`SUPERSAMPLE`]² subpixel tests) and fails with a limit error naming
/// [`crate::PIXELS_COVERED`] past it: 76,000 stacked triangles filling the view (a 1 MB
/// PLY) rasterized for more than a minute.
pub fn render_reference_bounded(mesh: &WorldMesh, view: &View, shading: Shading, background: [u8; 3], max_pixels: u64) -> Result<Frame> {
    draw(mesh, view, shading, background, max_pixels).map_err(|(_, pixels)| {
        let e = sct_format::Error::LimitExceeded { what: crate::PIXELS_COVERED, value: pixels, limit: max_pixels };
        crate::Error::Invalid(format!("reference render: {e}"))
    })
}

/// The reference frame, or the partial frame and the pixels asked for once they pass
/// `max_pixels` (nothing more is drawn then).
fn draw(mesh: &WorldMesh, view: &View, shading: Shading, background: [u8; 3], max_pixels: u64) -> std::result::Result<Frame, (Frame, u64)> {
    let [r, g, b] = background;
    let bg = [r, g, b, 255];
    // Triangles and points are drawn into `SUPERSAMPLE²` subpixels a pixel, as the default
    // `zbuffer` preview draws its splats, and resolved alike.
    let fine = view.supersampled(SUPERSAMPLE);
    let mut sub = Frame::new(fine.width as usize, fine.height as usize, bg);
    // Counted in output pixels, as the limit is: a pixel is `SUPERSAMPLE²` subpixel tests.
    let per_pixel = u64::from(SUPERSAMPLE * SUPERSAMPLE);
    let mut subpixels = 0u64;
    let drawn = draw_triangles(mesh, &fine, shading, &mut sub, &mut subpixels, max_pixels.saturating_mul(per_pixel));
    let mut splats = Vec::new();
    if drawn.is_ok() && !mesh.points.is_empty() {
        splats = point_splats(&mesh.points, &fine, shading);
        let (iw, ih) = (i64::from(fine.width), i64::from(fine.height));
        subpixels = splats.iter().fold(subpixels, |sum, s| {
            let [x0, x1, y0, y1] = s.bounds.map(i64::from);
            let n = (x1.min(iw - 1) - x0.max(0) + 1).max(0) * (y1.min(ih - 1) - y0.max(0) + 1).max(0);
            sum.saturating_add(n as u64)
        });
    }
    let pixels = subpixels / per_pixel;
    if drawn.is_err() || pixels > max_pixels {
        return Err((resolve(&sub, SUPERSAMPLE as usize, bg), pixels));
    }
    // Points are drawn as the default (`zbuffer`) splat renderer draws its leaves, cracks and
    // depth pits closed alike: a lossless tree of the pond scan scored 34.3 dB against a
    // reference without the pit fill and 30.0 dB once the renderer filled its pits (single
    // far points seen between near ones).
    let frame = if mesh.points.is_empty() { resolve(&sub, SUPERSAMPLE as usize, bg) } else { zbuffer_frame(sub, &splats, SUPERSAMPLE as usize, bg) };
    Ok(frame)
}

/// Subpixels per pixel side of a mesh reference. A pixel of the reference has the mean
/// colour (in linear light) of its covered `3 × 3` subpixels, as an antialiased renderer
/// would show the mesh: one sample per pixel looks a texture up once per pixel and
/// aliases, and a preview (whose leaves carry colours averaged over their surface) was
/// scored against that aliasing. Measured against a 4 × 4 supersampled image, the previews
/// of DamagedHelmet (2048² textures) score 1.5–2.1 dB more, SimpleInstancing (thin box
/// edges) 1.2 dB more. Odd, so that the middle subpixel is the pixel's centre.
pub const SUPERSAMPLE: u32 = 3;

/// Draws the mesh's triangles into `frame` (of `view`'s size), counting the pixels each
/// triangle's clipped bounding box tests into `pixels`; stops once they pass `max_pixels`.
fn draw_triangles(mesh: &WorldMesh, view: &View, shading: Shading, frame: &mut Frame, pixels: &mut u64, max_pixels: u64) -> std::result::Result<(), ()> {
    let eye = view.eye;
    for t in &mesh.tris {
        if culled(t.two_sided, &t.p, eye) {
            continue;
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
            raster_tri(mesh, t, [poly[0], poly[k], poly[k + 1]], view, shading, frame, pixels);
            if *pixels > max_pixels {
                return Err(());
            }
        }
    }
    Ok(())
}

/// Whether a triangle (world-space corners, counter-clockwise from its front) is culled
/// when seen from `eye`: only one-sided triangles whose front faces away are.
pub fn culled(two_sided: bool, p: &[[f32; 3]; 3], eye: [f64; 3]) -> bool {
    if two_sided {
        return false;
    }
    let e1: [f64; 3] = std::array::from_fn(|k| (p[1][k] - p[0][k]) as f64);
    let e2: [f64; 3] = std::array::from_fn(|k| (p[2][k] - p[0][k]) as f64);
    let nf = [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]];
    let to_eye: [f64; 3] = std::array::from_fn(|k| eye[k] - p[0][k] as f64);
    nf[0] * to_eye[0] + nf[1] * to_eye[1] + nf[2] * to_eye[2] < 0.0
}

/// Determinant of the linear part of a column-major affine matrix.
fn det3(m: &voxelize::mesh::Mat4) -> f64 {
    m[0][0] * (m[1][1] * m[2][2] - m[2][1] * m[1][2]) - m[1][0] * (m[0][1] * m[2][2] - m[2][1] * m[0][2])
        + m[2][0] * (m[0][1] * m[1][2] - m[1][1] * m[0][2])
}

/// A point's disc radius: the one the splat renderer draws the point's leaf with (its
/// sample's equal-area disc × [`crate::AREA_COVER`], at most its sphere), so the reference
/// is the cloud at full resolution and the metrics measure what the tree and its codec
/// changed. The sample's area is the square of the mean distance to its nearest
/// neighbours, so neighbouring discs overlap.
fn point_radius(n: &sct_format::Node) -> f32 {
    (crate::AREA_COVER * (n.area / std::f32::consts::PI).sqrt()).min(n.radius)
}

/// The points' discs, turned to their normals (no back-face culling: a point has no back).
fn point_splats(points: &[Point], view: &View, shading: Shading) -> Vec<crate::raster::Splat> {
    points
        .iter()
        .filter_map(|pt| {
            let c = view.to_camera(pt.p.map(f64::from));
            if view.outside(c, pt.radius) || c[2] <= view.near {
                return None;
            }
            let s = view.projected_radius(c, pt.radius);
            let color = if shading == Shading::Lambert {
                let n = view.dir_to_camera(pt.n.map(f64::from)).map(|v| v as f32);
                let d = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt().max(1e-30);
                shade::apply(pt.color, shade::lambert(n, [-c[0] / d, -c[1] / d, -c[2] / d]))
            } else {
                pt.color
            };
            let [x, y] = view.project(c);
            let s = s.min(2.0 * view.width.max(view.height) as f32);
            // Oriented like the splat renderer's leaves, so that the reference shows the
            // cloud at full resolution rather than another convention: screen-facing discs
            // covered 9 % more of a pond scan seen at a low angle than its own leaves did.
            let n = view.dir_to_camera(pt.n.map(f64::from)).map(|v| v as f32);
            let unit = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2] - 1.0).abs() < 1e-3;
            let sp = if unit { crate::lod::surface_splat(c, n, 0.0, s, [x, y], color) } else { crate::raster::Splat::disc(x, y, c[2], s, color) };
            Some(crate::lod::with_rim(sp, view.focal))
        })
        .collect()
}

/// Draws one triangle, adding the pixels of its clipped bounding box to `pixels` (before
/// drawing, so a caller can stop at a budget).
fn raster_tri(mesh: &WorldMesh, t: &Tri, v: [CV; 3], view: &View, shading: Shading, frame: &mut Frame, pixels: &mut u64) {
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
    *pixels = pixels.saturating_add((x1 + 1).saturating_sub(x0) as u64 * (y1 + 1).saturating_sub(y0) as u64);
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn culling_follows_the_winding_unless_two_sided() {
        let p = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]; // front faces +Z
        assert!(!culled(false, &p, [0.0, 0.0, 5.0]));
        assert!(culled(false, &p, [0.0, 0.0, -5.0]));
        assert!(!culled(true, &p, [0.0, 0.0, -5.0]));
    }

    /// Stripes a third of a pixel wide, red and blue, average to their mix in linear light
    /// (one sample per pixel showed whichever stripe held the pixel's centre); a pixel whose
    /// centre the mesh misses stays background, so coverage is as with one sample.
    #[test]
    fn sub_pixel_stripes_average_and_coverage_stays_centre_sampled() {
        let cam = crate::camera::Camera { eye: [0.0, 0.0, 10.0], target: [0.0; 3], up: [0.0, 1.0, 0.0], fov_y_deg: 30.0, width: 64, height: 64 };
        let view = View::new(&cam, 0.1).expect("view");
        // One pixel is this wide at the target plane.
        let px = 2.0 * 10.0 * (15f32.to_radians()).tan() / 64.0;
        let stripe = px / 3.0;
        let mut quads = Vec::new();
        for i in 0..60 {
            let x0 = -10.0 * stripe + i as f32 * stripe;
            let color = if i % 2 == 0 { [1.0, 0.0, 0.0, 1.0] } else { [0.0, 0.0, 1.0, 1.0] };
            quads.push(([[x0, -5.0 * px, 0.0], [x0 + stripe, -5.0 * px, 0.0], [x0 + stripe, 5.0 * px, 0.0], [x0, 5.0 * px, 0.0]], color));
        }
        let mesh = crate::synth::quads(&quads);
        let f = render_reference(&mesh, &view, Shading::Flat, [0, 0, 0]);
        let covered: Vec<usize> = (0..f.depth.len()).filter(|&i| f.depth[i].is_finite()).collect();
        assert!(covered.len() > 100, "{} pixels covered", covered.len());
        let inner: Vec<usize> = covered.iter().copied().filter(|&i| i % 64 > 24 && i % 64 < 40).collect();
        for &i in &inner {
            let [r, _, b, _] = f.color[i];
            assert!(r > 120 && b > 120, "pixel {i} shows a single stripe: {:?}", f.color[i]);
        }
        // The mesh's rows: exactly the pixels whose centre lies within ±5 px of the axis.
        let rows: std::collections::BTreeSet<usize> = covered.iter().map(|i| i / 64).collect();
        assert_eq!(rows.len(), 10, "rows {rows:?}");
    }

    /// The budget is in output pixels: a quad whose two triangles' boxes cover about 2 × 400
    /// pixels (7,200 subpixel tests) fits in 1,000 and not in 500.
    #[test]
    fn the_pixel_budget_counts_output_pixels() {
        let cam = crate::camera::Camera { eye: [0.0, 0.0, 10.0], target: [0.0; 3], up: [0.0, 1.0, 0.0], fov_y_deg: 30.0, width: 64, height: 64 };
        let view = View::new(&cam, 0.1).expect("view");
        let px = 2.0 * 10.0 * (15f32.to_radians()).tan() / 64.0;
        let h = 10.0 * px;
        let mesh = crate::synth::quads(&[([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]], [1.0, 1.0, 1.0, 1.0])]);
        assert!(render_reference_bounded(&mesh, &view, Shading::Flat, [0, 0, 0], 1_000).is_ok());
        assert!(render_reference_bounded(&mesh, &view, Shading::Flat, [0, 0, 0], 500).is_err());
    }

    #[test]
    fn mirrored_determinant() {
        let mut m = voxelize::mesh::IDENTITY;
        assert!(det3(&m) > 0.0);
        m[1][1] = -2.0;
        assert!(det3(&m) < 0.0);
    }
}
