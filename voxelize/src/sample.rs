//! Samplers (thesis §5.2): the scan-line voxelization in one uniform grid and the QSplat
//! vertex-patch sampler, plus the density choice (EQ 15–17) and coverage helpers.
//!
//! ## Voxel method (default)
//! Every triangle is rasterized in its canonical orientation: the axis closest to its normal
//! is the depth axis, the other two index grid *columns*. For each column the triangle
//! overlaps, the triangle is clipped to the column and the depth range of the clipped polygon
//! gives the voxels it crosses — one voxel for most columns (the dominant axis keeps depth
//! slopes ≤ 1), up to three where the plane is steep (45°). Each crossed voxel becomes a sample
//! at the voxel centre with radius = half the voxel diagonal (EQ 15), so the union of the
//! sample spheres contains every voxel the surface passes through, and hence the surface:
//! coverage is guaranteed by construction, not just for points near column centres.
//! The sample's area is the exact area of triangle ∩ voxel (the §5.2.3 "better measurement";
//! the sum equals the mesh area to rounding), or EQ 17 (triangle area / sample count) with
//! [`AreaMode::Eq17`]. Attributes are interpolated at the centroid of triangle ∩ voxel.
//!
//! ## Scanline method (the thesis as written)
//! One sample per column whose centre falls inside the projected triangle, in the voxel that
//! holds the plane point above that centre; EQ 17 areas. A triangle that covers no column
//! centre gets one sample at its centroid's voxel (the thesis would drop it). Coverage is
//! *not* guaranteed near triangle edges; it is here to compare with the thesis' counts.
//!
//! ## Merging
//! Samples of the same mesh that fall in the same voxel (from neighbouring triangles) are
//! merged here (thesis Table 2, "after merging"): the voxel key exists only here, so
//! build-tree would need a spatial search to find duplicates. Areas add; colour and normal
//! are area-weighted means. `merge = false` keeps one sample per triangle per voxel.

use rayon::prelude::*;
use sct_format::Node;

use crate::mesh::*;

/// Which sampler.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Conservative scan-line voxelization (exact triangle ∩ voxel).
    Voxel,
    /// The thesis' scan-line: one sample per covered column centre.
    Scanline,
    /// QSplat vertex patches (§5.2.1): one sample per vertex, radius = longest incident edge.
    Vertex,
}

/// How voxel samples get their area.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AreaMode {
    /// Area of triangle ∩ voxel.
    Exact,
    /// EQ 17: triangle area / number of samples of the triangle.
    Eq17,
}

/// How the voxel size is chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Density {
    /// Explicit voxel edge length (world units).
    VoxelSize(f64),
    /// EQ 16: base length l = max(μ − kσ, β) of the edge lengths, γ samples per l.
    Auto {
        /// Standard deviations below the mean.
        k: f64,
        /// Samples per base length.
        gamma: f64,
        /// Minimum base length β; `None` = a quarter of the mean edge length (for long-tailed
        /// edge distributions μ − kσ is tiny or negative).
        min_base: Option<f64>,
    },
    /// Viewing needs: a sample's projected diameter is at most `pixels` pixels when seen from
    /// `distance` with a `fov_deg` field of view over `resolution` pixels.
    Screen {
        /// Allowed projected sample diameter in pixels.
        pixels: f64,
        /// Image width in pixels.
        resolution: f64,
        /// Nearest viewing distance (world units).
        distance: f64,
        /// Horizontal field of view in degrees.
        fov_deg: f64,
    },
}

/// Sampler options.
#[derive(Clone, Debug)]
pub struct SampleOptions {
    /// Sampler.
    pub method: Method,
    /// Density.
    pub density: Density,
    /// Area mode (voxel method).
    pub area: AreaMode,
    /// Merge samples of one mesh that share a voxel.
    pub merge: bool,
    /// Crease angle for computed normals, degrees.
    pub crease_deg: f32,
    /// Refuse to make more samples than this (estimated before sampling).
    pub max_samples: u64,
}

impl Default for SampleOptions {
    fn default() -> Self {
        SampleOptions {
            method: Method::Voxel,
            density: Density::Auto { k: 3.0, gamma: 2.0, min_base: None },
            area: AreaMode::Exact,
            merge: true,
            crease_deg: 60.0,
            max_samples: 400_000_000,
        }
    }
}

/// The chosen voxel size and why.
#[derive(Clone, Debug, PartialEq)]
pub struct VoxelChoice {
    /// Voxel edge length in world units.
    pub size: f64,
    /// Human-readable derivation.
    pub reason: String,
}

/// One sampled mesh: its samples (in its frame) and where it is placed.
#[derive(Clone, Debug)]
pub struct SampledMesh {
    /// Name.
    pub name: String,
    /// Samples in the mesh's frame.
    pub samples: Vec<Node>,
    /// Similarity placements (identity for meshes baked into world space).
    pub instances: Vec<sct_format::Similarity>,
    /// Affine placements (non-uniform scale, shear, mirror) as row-major 3 × 4 matrices;
    /// written to the samples file's `AFFI` section (spec §8).
    pub affine: Vec<[[f64; 4]; 3]>,
}

/// Counters of a sampling run.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SampleStats {
    /// Samples before merging.
    pub samples_before_merge: u64,
    /// Samples after merging (= written), over meshes (not instances).
    pub samples: u64,
    /// Samples dropped by alpha (MASK cutoff or alpha 0).
    pub dropped_alpha: u64,
    /// Triangles sampled (once per sampled mesh, not per instance).
    pub triangles: u64,
    /// Meshes instanced (sampled once, placed several times).
    pub instanced_meshes: u64,
    /// Placements baked into world space because they were neither a similarity nor an
    /// invertible affine map (projective or singular matrices).
    pub baked_non_similar: u64,
    /// Affine (non-similarity) placements kept as instances.
    pub affine_instances: u64,
    /// Sum of sample areas over the scene (instances included, scaled).
    pub sample_area: f64,
    /// Mesh area over the scene (instances included).
    pub mesh_area: f64,
}

/// Result of [`sample_scene`].
#[derive(Clone, Debug)]
pub struct Sampled {
    /// Sampled meshes.
    pub meshes: Vec<SampledMesh>,
    /// The voxel size.
    pub voxel: VoxelChoice,
    /// Counters.
    pub stats: SampleStats,
}

/// Chooses the voxel size (EQ 16, explicit, or viewing needs).
pub fn choose_voxel_size(scene: &LoadedScene, d: &Density) -> Result<VoxelChoice, String> {
    let c = match *d {
        Density::VoxelSize(h) => VoxelChoice { size: h, reason: format!("explicit --voxel-size {h}") },
        Density::Screen { pixels, resolution, distance, fov_deg } => {
            let pix = 2.0 * distance * (fov_deg.to_radians() / 2.0).tan() / resolution;
            // Sample diameter 2r = √3 h (EQ 15) must project to ≤ `pixels` pixels.
            let h = pixels * pix / 3f64.sqrt();
            VoxelChoice {
                size: h,
                reason: format!(
                    "viewing target: {pixels} px at {resolution} px across a {fov_deg}° view from distance {distance}: pixel footprint {pix:.6}, sample diameter √3·h ≤ {:.6}",
                    pixels * pix
                ),
            }
        }
        Density::Auto { k, gamma, min_base } => {
            // Edge lengths over all instances (a mesh placed n times counts n times, scaled
            // by the instance's linear scale factor).
            let mut count = 0.0f64;
            let mut sum = 0.0f64;
            let mut sum2 = 0.0f64;
            let mut inst_count = vec![Vec::<f64>::new(); scene.meshes.len()];
            for inst in &scene.instances {
                if let Some(v) = inst_count.get_mut(inst.mesh) {
                    v.push(determinant(&inst.transform).abs().cbrt());
                }
            }
            for (mi, mesh) in scene.meshes.iter().enumerate() {
                let scales = &inst_count[mi];
                if scales.is_empty() {
                    continue;
                }
                let (n_inst, s1, s2) = (scales.len() as f64, scales.iter().sum::<f64>(), scales.iter().map(|s| s * s).sum::<f64>());
                for p in &mesh.primitives {
                    for t in &p.triangles {
                        for e in 0..3 {
                            let a = p.positions[t[e] as usize].map(f64::from);
                            let b = p.positions[t[(e + 1) % 3] as usize].map(f64::from);
                            let l = norm(sub(a, b));
                            count += n_inst;
                            sum += l * s1;
                            sum2 += l * l * s2;
                        }
                    }
                }
            }
            if count == 0.0 {
                return Err("no triangle edges to derive a voxel size from (EQ 16); give --voxel-size".into());
            }
            let mu = sum / count;
            let sigma = (sum2 / count - mu * mu).max(0.0).sqrt();
            let beta = min_base.unwrap_or(0.25 * mu);
            let raw = mu - k * sigma;
            let base = raw.max(beta);
            let h = base / gamma;
            VoxelChoice {
                size: h,
                reason: format!(
                    "automatic (EQ 16): edge length mean μ = {mu:.6}, σ = {sigma:.6}, k = {k}: μ − kσ = {raw:.6}{}; γ = {gamma} samples per base length → voxel {h:.6}",
                    if raw < beta { format!(" clipped to β = {beta:.6}") } else { String::new() }
                ),
            }
        }
    };
    if !(c.size.is_finite() && c.size > 0.0) {
        return Err(format!("voxel size {} is not a positive finite number ({})", c.size, c.reason));
    }
    Ok(c)
}

/// A unit of sampling: one mesh in one frame.
struct Unit {
    mesh: usize,
    /// Frame transform applied to the mesh's vertices before sampling (baked world) or
    /// `None` (sampled in its local frame; instances carry the placement).
    bake: Option<Mat4>,
    /// Voxel size in the unit's frame.
    h: f64,
    name: String,
    instances: Vec<sct_format::Similarity>,
    affine: Vec<[[f64; 4]; 3]>,
}

/// The samples-file form (row-major 3 × 4) of an affine `Mat4` (column-major), when it is
/// affine (last row 0 0 0 1) and invertible.
fn to_affine(m: &Mat4) -> Option<sct_format::samples::AffineInstance> {
    if m[0][3] != 0.0 || m[1][3] != 0.0 || m[2][3] != 0.0 || m[3][3] != 1.0 {
        return None;
    }
    let a = sct_format::samples::AffineInstance { mesh: 0, matrix: std::array::from_fn(|r| std::array::from_fn(|c| m[c][r])) };
    a.is_valid().then_some(a)
}

fn plan_units(scene: &LoadedScene, h: f64, stats: &mut SampleStats) -> Vec<Unit> {
    let mut units = Vec::new();
    for (mi, mesh) in scene.meshes.iter().enumerate() {
        let insts: Vec<&Instance> = scene.instances.iter().filter(|i| i.mesh == mi).collect();
        if insts.is_empty() {
            continue;
        }
        // A reused mesh is sampled once in its own frame and placed by similarity or affine
        // instances; a single placement, or a projective/singular one, is baked into world
        // space (exact world grid).
        let mut sims = Vec::new();
        let mut affs = Vec::new();
        let mut baked = Vec::new();
        for inst in &insts {
            if let Some(s) = to_similarity(&inst.transform) {
                sims.push(s);
            } else if let Some(a) = to_affine(&inst.transform) {
                affs.push(a);
            } else {
                baked.push(inst.transform);
            }
        }
        if sims.len() + affs.len() >= 2 {
            // The largest stretch of any placement decides the local voxel, so no placement
            // is sampled coarser than the world voxel.
            let stretch = sims.iter().map(|s| s.scale).chain(affs.iter().map(|a| a.max_stretch())).fold(0.0f64, f64::max);
            stats.instanced_meshes += 1;
            stats.affine_instances += affs.len() as u64;
            units.push(Unit {
                mesh: mi,
                bake: None,
                h: h / stretch,
                name: mesh.name.clone(),
                instances: sims,
                affine: affs.iter().map(|a| a.matrix).collect(),
            });
        } else {
            // At most one usable placement: bake it (its original matrix).
            baked.extend(
                insts.iter().filter(|i| to_similarity(&i.transform).is_some() || to_affine(&i.transform).is_some()).map(|i| i.transform),
            );
        }
        if !baked.is_empty() && insts.len() > 1 {
            stats.baked_non_similar += baked.len() as u64;
        }
        let many = baked.len() > 1;
        for (k, m) in baked.into_iter().enumerate() {
            let name = if many { format!("{}#{k}", mesh.name) } else { mesh.name.clone() };
            units.push(Unit { mesh: mi, bake: Some(m), h, name, instances: vec![sct_format::Similarity::IDENTITY], affine: Vec::new() });
        }
    }
    units
}

/// Per-triangle input in grid units.
struct Tri {
    p: [[f64; 3]; 3],
    n: [[f32; 3]; 3],
    c: [[f32; 4]; 3],
    uv: [[f32; 2]; 3],
    uv2: [[f32; 2]; 3],
}

/// Material view used in the hot loop.
struct Mat<'a> {
    base: [f32; 4],
    tex: Option<(&'a Image, &'a TextureRef)>,
    alpha_tex: Option<(&'a Image, &'a TextureRef)>,
    alpha: AlphaMode,
}

#[derive(Clone, Copy)]
struct Rec {
    key: [i32; 3],
    area: f32,
    normal: [f32; 3],
    color: [f32; 4],
}

const MAXV: usize = 12;
#[derive(Clone, Copy)]
struct Poly {
    v: [[f64; 3]; MAXV],
    n: usize,
}

impl Poly {
    fn clip(&self, axis: usize, lo: f64, hi: f64) -> Poly {
        let a = self.clip_half(axis, lo, true);
        a.clip_half(axis, hi, false)
    }
    /// Keeps the side `x[axis] >= c` (keep_above) or `<= c`.
    fn clip_half(&self, axis: usize, c: f64, keep_above: bool) -> Poly {
        let mut out = Poly { v: [[0.0; 3]; MAXV], n: 0 };
        if self.n == 0 {
            return out;
        }
        let inside = |p: &[f64; 3]| if keep_above { p[axis] >= c } else { p[axis] <= c };
        for i in 0..self.n {
            let cur = self.v[i];
            let prev = self.v[(i + self.n - 1) % self.n];
            let (ci, pi) = (inside(&cur), inside(&prev));
            if ci != pi {
                let t = (c - prev[axis]) / (cur[axis] - prev[axis]);
                let mut x = [prev[0] + t * (cur[0] - prev[0]), prev[1] + t * (cur[1] - prev[1]), prev[2] + t * (cur[2] - prev[2])];
                x[axis] = c; // exact on the plane, so neighbouring clips agree
                if out.n < MAXV {
                    out.v[out.n] = x;
                    out.n += 1;
                }
            }
            if ci && out.n < MAXV {
                out.v[out.n] = cur;
                out.n += 1;
            }
        }
        out
    }
    /// (area, centroid) of the planar polygon.
    fn area_centroid(&self) -> (f64, [f64; 3]) {
        if self.n < 3 {
            return (0.0, self.v[0]);
        }
        let o = self.v[0];
        let mut total = [0.0; 3];
        let mut w = 0.0;
        let mut c = [0.0; 3];
        for i in 1..self.n - 1 {
            let cr = cross(sub(self.v[i], o), sub(self.v[i + 1], o));
            total = [total[0] + cr[0], total[1] + cr[1], total[2] + cr[2]];
            let a = norm(cr);
            w += a;
            for k in 0..3 {
                c[k] += a * (o[k] + self.v[i][k] + self.v[i + 1][k]) / 3.0;
            }
        }
        let area = 0.5 * norm(total);
        if w > 0.0 {
            (area, c.map(|x| x / w))
        } else {
            let mut m = [0.0; 3];
            for p in &self.v[..self.n] {
                for k in 0..3 {
                    m[k] += p[k] / self.n as f64;
                }
            }
            (0.0, m)
        }
    }
}

/// Samples a loaded scene.
pub fn sample_scene(scene: &LoadedScene, opts: &SampleOptions, progress: &(dyn Fn(u64, u64) + Sync)) -> Result<Sampled, String> {
    let voxel = choose_voxel_size(scene, &opts.density)?;
    let h = voxel.size;
    let mut stats = SampleStats::default();
    let units = plan_units(scene, h, &mut stats);
    // Estimate before allocating: a triangle crosses about (area/h² + perimeter/h + 1) voxels
    // times up to ~1.7 for steep planes.
    let mut estimate = 0.0f64;
    for u in &units {
        let mesh = &scene.meshes[u.mesh];
        let s = u.bake.map_or(1.0, |m| determinant(&m).abs().cbrt());
        for p in &mesh.primitives {
            for t in &p.triangles {
                let [a, b, c] = t.map(|i| p.positions[i as usize].map(f64::from));
                let area = 0.5 * norm(cross(sub(b, a), sub(c, a))) * s * s;
                let per = (norm(sub(b, a)) + norm(sub(c, b)) + norm(sub(a, c))) * s;
                estimate += match opts.method {
                    Method::Vertex => 1.0,
                    _ => area / (u.h * u.h) + 0.5 * per / u.h + 1.0,
                };
            }
        }
        if let Some(b) = scene.world_bounds() {
            let ext = b.0.iter().chain(b.1.iter()).fold(0.0f64, |m, v| m.max(v.abs()));
            if u.bake.is_some() && ext / u.h > (1u64 << 30) as f64 {
                return Err(format!("voxel size {h} is too small for coordinates up to {ext} (more than 2^30 voxels along an axis)"));
            }
        }
    }
    if estimate > opts.max_samples as f64 {
        return Err(format!(
            "voxel size {h} would make about {estimate:.0} samples, more than --max-samples {}; use a larger --voxel-size or a smaller γ",
            opts.max_samples
        ));
    }
    let total_tris: u64 = units.iter().map(|u| scene.meshes[u.mesh].triangle_count() as u64).sum();
    let done = std::sync::atomic::AtomicU64::new(0);
    let mut out = Vec::new();
    for u in &units {
        let mesh = &scene.meshes[u.mesh];
        let mut recs: Vec<Rec> = Vec::new();
        let mut vnodes: Vec<Node> = Vec::new();
        let mut dropped = 0u64;
        for prim in &mesh.primitives {
            let material = scene.material(prim);
            fn tex_of<'a>(images: &'a [Image], t: &'a Option<TextureRef>) -> Option<(&'a Image, &'a TextureRef)> {
                t.as_ref().and_then(|t| images.get(t.image).map(|i| (i, t)))
            }
            let mat = Mat {
                base: material.base_color,
                tex: tex_of(&scene.images, &material.texture),
                alpha_tex: tex_of(&scene.images, &material.alpha_texture),
                alpha: material.alpha_mode,
            };
            let (r, v, d) = sample_primitive(prim, u, &mat, opts, &done, total_tris, progress);
            recs.extend(r);
            vnodes.extend(v);
            dropped += d;
        }
        stats.triangles += mesh.triangle_count() as u64;
        stats.dropped_alpha += dropped;
        stats.samples_before_merge += (recs.len() + vnodes.len()) as u64;
        let nodes = if opts.method == Method::Vertex {
            vnodes
        } else {
            // Sort (voxel key, record index) pairs: unique keys make the unstable parallel
            // sort deterministic, and equal voxels keep triangle order, so merging does not
            // depend on the thread count. Cheaper than moving 44-byte records around.
            let mut order: Vec<u128> = recs
                .par_iter()
                .enumerate()
                .map(|(i, r)| {
                    let k = r.key.map(|v| u128::from((v as i64 + (1i64 << 31)) as u32));
                    (k[0] << 96) | (k[1] << 64) | (k[2] << 32) | i as u128
                })
                .collect();
            order.par_sort_unstable();
            let sorted: Vec<Rec> = order.par_iter().map(|&o| recs[(o & 0xFFFF_FFFF) as usize]).collect();
            drop(order);
            to_nodes(&sorted, u.h, opts.merge)
        };
        stats.samples += nodes.len() as u64;
        let area: f64 = nodes.iter().map(|n| f64::from(n.area)).sum();
        stats.sample_area += u.instances.iter().map(|s| area * s.scale * s.scale).sum::<f64>();
        for m in &u.affine {
            let a = sct_format::samples::AffineInstance { mesh: 0, matrix: *m };
            let st = a.max_stretch();
            stats.sample_area += nodes.iter().map(|n| f64::from(a.transform_node(n, st).area)).sum::<f64>();
        }
        out.push(SampledMesh { name: u.name.clone(), samples: nodes, instances: u.instances.clone(), affine: u.affine.clone() });
    }
    stats.mesh_area = scene.world_area();
    Ok(Sampled { meshes: out, voxel, stats })
}

fn sample_primitive(
    prim: &Primitive,
    u: &Unit,
    mat: &Mat,
    opts: &SampleOptions,
    done: &std::sync::atomic::AtomicU64,
    total: u64,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> (Vec<Rec>, Vec<Node>, u64) {
    let inv_h = 1.0 / u.h;
    // Vertex positions and normals in the unit's frame, positions in grid units.
    let pos: Vec<[f64; 3]> = prim
        .positions
        .iter()
        .map(|&p| {
            let w = match &u.bake {
                Some(m) => transform_point(m, p),
                None => p.map(f64::from),
            };
            w.map(|x| x * inv_h)
        })
        .collect();
    let flip = u.bake.as_ref().is_some_and(|m| determinant(m) < 0.0);
    let nrm: Option<Vec<[f32; 3]>> = prim.normals.as_ref().map(|ns| {
        ns.iter()
            .map(|&n| {
                let w = match &u.bake {
                    Some(m) => transform_normal(m, n),
                    None => n.map(f64::from),
                };
                let l = norm(w);
                if l > 0.0 && l.is_finite() {
                    w.map(|x| (x / l) as f32)
                } else {
                    [0.0; 3]
                }
            })
            .collect()
    });
    let computed = if nrm.is_none() { Some(corner_normals(prim, opts.crease_deg)) } else { None };
    let tc = mat.tex.map_or(0, |t| t.1.tex_coord as usize);
    let tc2 = mat.alpha_tex.map_or(0, |t| t.1.tex_coord as usize);
    let uvset = prim.uvs.get(tc);
    let uvset2 = prim.uvs.get(tc2);
    if opts.method == Method::Vertex {
        let (nodes, d) = vertex_patches(prim, &pos, &nrm, computed.as_deref(), mat, u.h);
        let n = prim.triangles.len() as u64;
        progress(done.fetch_add(n, std::sync::atomic::Ordering::Relaxed) + n, total);
        return (Vec::new(), nodes, d);
    }
    let chunk = 4096;
    let parts: Vec<(Vec<Rec>, u64)> = prim
        .triangles
        .par_chunks(chunk)
        .enumerate()
        .map(|(ci, tris)| {
            let mut out = Vec::new();
            let mut dropped = 0u64;
            for (k, t) in tris.iter().enumerate() {
                let ti = ci * chunk + k;
                // A mirroring bake flips the winding; swap to keep the front side.
                let idx = if flip { [t[0], t[2], t[1]] } else { *t };
                let vi = idx.map(|i| i as usize);
                let n = match (&nrm, &computed) {
                    (Some(n), _) => vi.map(|i| n[i]),
                    (None, Some(c)) => {
                        let c = c[ti];
                        let cn = if flip { [c[0], c[2], c[1]] } else { c };
                        match &u.bake {
                            Some(m) => cn.map(|n| {
                                let w = transform_normal(m, n);
                                let l = norm(w);
                                if l > 0.0 { w.map(|x| (x / l) as f32) } else { [0.0; 3] }
                            }),
                            None => cn,
                        }
                    }
                    _ => [[0.0; 3]; 3],
                };
                let tri = Tri {
                    p: vi.map(|i| pos[i]),
                    n,
                    c: vi.map(|i| prim.colors.as_ref().map_or([1.0; 4], |c| c[i])),
                    uv: vi.map(|i| uvset.map_or([0.0; 2], |s| s[i])),
                    uv2: vi.map(|i| uvset2.map_or([0.0; 2], |s| s[i])),
                };
                dropped += match opts.method {
                    Method::Voxel => voxel_triangle(&tri, mat, opts.area, &mut out),
                    Method::Scanline => scanline_triangle(&tri, mat, &mut out),
                    Method::Vertex => 0,
                };
            }
            let d = done.fetch_add(tris.len() as u64, std::sync::atomic::Ordering::Relaxed) + tris.len() as u64;
            progress(d, total);
            (out, dropped)
        })
        .collect();
    let dropped: u64 = parts.iter().map(|p| p.1).sum();
    let mut recs = Vec::with_capacity(parts.iter().map(|p| p.0.len()).sum());
    for (p, _) in parts {
        recs.extend(p);
    }
    (recs, Vec::new(), dropped)
}

/// Shades a point of a triangle given barycentric weights; `None` = dropped by alpha.
fn shade(t: &Tri, w: [f64; 3], mat: &Mat) -> (Option<[f32; 4]>, [f32; 3]) {
    let wf = w.map(|x| x as f32);
    let mix4 = |a: &[[f32; 4]; 3]| -> [f32; 4] { std::array::from_fn(|k| a[0][k] * wf[0] + a[1][k] * wf[1] + a[2][k] * wf[2]) };
    let mix2 = |a: &[[f32; 2]; 3]| -> [f32; 2] { std::array::from_fn(|k| a[0][k] * wf[0] + a[1][k] * wf[1] + a[2][k] * wf[2]) };
    let vc = mix4(&t.c);
    let mut c: [f32; 4] = std::array::from_fn(|k| mat.base[k] * vc[k]);
    if let Some((img, tr)) = mat.tex {
        let s = img.sample(tr.transform_uv(mix2(&t.uv)), tr.wrap_s, tr.wrap_t);
        for k in 0..4 {
            c[k] *= s[k];
        }
    }
    if let Some((img, tr)) = mat.alpha_tex {
        let s = img.sample(tr.transform_uv(mix2(&t.uv2)), tr.wrap_s, tr.wrap_t);
        c[3] *= 0.2126 * s[0] + 0.7152 * s[1] + 0.0722 * s[2];
    }
    let keep = match mat.alpha {
        AlphaMode::Opaque => {
            c[3] = 1.0;
            true
        }
        AlphaMode::Mask(cut) => {
            let k = c[3] >= cut;
            c[3] = 1.0;
            k
        }
        // An alpha that rounds to 0 in 8 bits is fully transparent (thesis: removed).
        AlphaMode::Blend => c[3] >= 0.5 / 255.0,
    };
    let n = std::array::from_fn(|k| t.n[0][k] * wf[0] + t.n[1][k] * wf[1] + t.n[2][k] * wf[2]);
    (keep.then_some(c), n)
}

/// Barycentric coordinates of `p` (projected on axes a, b).
fn bary(t: &Tri, a: usize, b: usize, p: [f64; 3]) -> [f64; 3] {
    let [p0, p1, p2] = t.p;
    let d = (p1[a] - p0[a]) * (p2[b] - p0[b]) - (p2[a] - p0[a]) * (p1[b] - p0[b]);
    if d == 0.0 {
        return [1.0 / 3.0; 3];
    }
    let w1 = ((p[a] - p0[a]) * (p2[b] - p0[b]) - (p2[a] - p0[a]) * (p[b] - p0[b])) / d;
    let w2 = ((p1[a] - p0[a]) * (p[b] - p0[b]) - (p[a] - p0[a]) * (p1[b] - p0[b])) / d;
    // Clamp: centroids lie inside, rounding may put them a hair outside.
    let w = [(1.0 - w1 - w2).clamp(0.0, 1.0), w1.clamp(0.0, 1.0), w2.clamp(0.0, 1.0)];
    let s = w[0] + w[1] + w[2];
    w.map(|x| x / s)
}

fn face_axes(t: &Tri) -> ([f64; 3], usize, usize, usize) {
    let fnrm = cross(sub(t.p[1], t.p[0]), sub(t.p[2], t.p[0]));
    let ax = fnrm.map(f64::abs);
    let d = if ax[0] >= ax[1] && ax[0] >= ax[2] { 0 } else if ax[1] >= ax[2] { 1 } else { 2 };
    (fnrm, d, (d + 1) % 3, (d + 2) % 3)
}

fn push_rec(out: &mut Vec<Rec>, key: [i64; 3], area: f64, col: [f32; 4], n: [f32; 3], fnrm: [f64; 3]) {
    let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    let normal = if l > 1e-12 {
        n.map(|x| x / l)
    } else {
        let fl = norm(fnrm);
        fnrm.map(|x| (x / fl) as f32)
    };
    out.push(Rec { key: key.map(|k| k.clamp(i32::MIN as i64, i32::MAX as i64) as i32), area: area as f32, normal, color: col });
}

/// Conservative voxelization of one triangle; returns the number of alpha-dropped samples.
fn voxel_triangle(t: &Tri, mat: &Mat, area_mode: AreaMode, out: &mut Vec<Rec>) -> u64 {
    let (fnrm, d, a, b) = face_axes(t);
    let tri_area_grid = 0.5 * norm(fnrm);
    let start = out.len();
    let mut dropped = 0;
    let tri = Poly { v: { let mut v = [[0.0; 3]; MAXV]; v[..3].copy_from_slice(&t.p); v }, n: 3 };
    let lo = |ax: usize| t.p.iter().map(|p| p[ax]).fold(f64::INFINITY, f64::min).floor() as i64;
    let hi = |ax: usize| t.p.iter().map(|p| p[ax]).fold(f64::NEG_INFINITY, f64::max).floor() as i64;
    for ia in lo(a)..=hi(a) {
        let strip = tri.clip(a, ia as f64, ia as f64 + 1.0);
        if strip.n < 3 {
            continue;
        }
        let blo = strip.v[..strip.n].iter().map(|p| p[b]).fold(f64::INFINITY, f64::min).floor() as i64;
        let bhi = strip.v[..strip.n].iter().map(|p| p[b]).fold(f64::NEG_INFINITY, f64::max).floor() as i64;
        for ib in blo..=bhi {
            let col = strip.clip(b, ib as f64, ib as f64 + 1.0);
            if col.n < 3 {
                continue;
            }
            let dmin = col.v[..col.n].iter().map(|p| p[d]).fold(f64::INFINITY, f64::min);
            let dmax = col.v[..col.n].iter().map(|p| p[d]).fold(f64::NEG_INFINITY, f64::max);
            let kmin = dmin.floor() as i64;
            let mut kmax = dmax.floor() as i64;
            if kmax > kmin && dmax == kmax as f64 {
                kmax -= 1; // touches the next voxel's face only
            }
            for k in kmin..=kmax {
                let piece = if kmin == kmax { col } else { col.clip(d, k as f64, k as f64 + 1.0) };
                if piece.n < 3 {
                    continue;
                }
                let (area, cen) = piece.area_centroid();
                if area <= 0.0 && kmin != kmax {
                    continue;
                }
                let w = bary(t, a, b, cen);
                let (c, n) = shade(t, w, mat);
                let mut key = [0i64; 3];
                key[a] = ia;
                key[b] = ib;
                key[d] = k;
                match c {
                    Some(c) => push_rec(out, key, area, c, n, fnrm),
                    None => dropped += 1,
                }
            }
        }
    }
    let made = out.len() - start;
    if area_mode == AreaMode::Eq17 && made > 0 {
        let each = (tri_area_grid / (made as u64 + dropped) as f64) as f32;
        for r in &mut out[start..] {
            r.area = each;
        }
    }
    dropped
}

/// The thesis' scan-line: one sample per column centre inside the projected triangle.
fn scanline_triangle(t: &Tri, mat: &Mat, out: &mut Vec<Rec>) -> u64 {
    let (fnrm, d, a, b) = face_axes(t);
    let start = out.len();
    let mut dropped = 0;
    let (pa, pb) = (t.p.map(|p| p[a]), t.p.map(|p| p[b]));
    let lo_a = pa.iter().fold(f64::INFINITY, |m, &v| m.min(v));
    let hi_a = pa.iter().fold(f64::NEG_INFINITY, |m, &v| m.max(v));
    let lo_b = pb.iter().fold(f64::INFINITY, |m, &v| m.min(v));
    let hi_b = pb.iter().fold(f64::NEG_INFINITY, |m, &v| m.max(v));
    let depth = |w: [f64; 3]| w[0] * t.p[0][d] + w[1] * t.p[1][d] + w[2] * t.p[2][d];
    let emit = |out: &mut Vec<Rec>, dropped: &mut u64, ia: i64, ib: i64, w: [f64; 3]| {
        let (c, n) = shade(t, w, mat);
        let mut key = [0i64; 3];
        key[a] = ia;
        key[b] = ib;
        key[d] = depth(w).floor() as i64;
        match c {
            Some(c) => push_rec(out, key, 0.0, c, n, fnrm),
            None => *dropped += 1,
        }
    };
    let det = (pa[1] - pa[0]) * (pb[2] - pb[0]) - (pa[2] - pa[0]) * (pb[1] - pb[0]);
    for ia in ((lo_a - 0.5).ceil() as i64)..=((hi_a - 0.5).floor() as i64) {
        for ib in ((lo_b - 0.5).ceil() as i64)..=((hi_b - 0.5).floor() as i64) {
            let (ca, cb) = (ia as f64 + 0.5, ib as f64 + 0.5);
            let w1 = ((ca - pa[0]) * (pb[2] - pb[0]) - (pa[2] - pa[0]) * (cb - pb[0])) / det;
            let w2 = ((pa[1] - pa[0]) * (cb - pb[0]) - (ca - pa[0]) * (pb[1] - pb[0])) / det;
            let w0 = 1.0 - w1 - w2;
            if w0 >= 0.0 && w1 >= 0.0 && w2 >= 0.0 {
                emit(out, &mut dropped, ia, ib, [w0, w1, w2]);
            }
        }
    }
    if out.len() == start && dropped == 0 {
        let w = [1.0 / 3.0; 3];
        let cen: [f64; 3] = std::array::from_fn(|k| (t.p[0][k] + t.p[1][k] + t.p[2][k]) / 3.0);
        emit(out, &mut dropped, cen[a].floor() as i64, cen[b].floor() as i64, w);
    }
    let made = out.len() - start;
    if made > 0 {
        let each = (0.5 * norm(fnrm) / (made as u64 + dropped) as f64) as f32;
        for r in &mut out[start..] {
            r.area = each;
        }
    }
    dropped
}

/// QSplat vertex patches (§5.2.1): a sphere at every used vertex, radius = the longest
/// incident edge (so the spheres of a triangle's corners contain it), area = a third of the
/// incident triangles' areas.
fn vertex_patches(
    prim: &Primitive,
    pos: &[[f64; 3]],
    nrm: &Option<Vec<[f32; 3]>>,
    computed: Option<&[[[f32; 3]; 3]]>,
    mat: &Mat,
    h: f64,
) -> (Vec<Node>, u64) {
    let nv = pos.len();
    let mut radius = vec![0.0f64; nv];
    let mut area = vec![0.0f64; nv];
    let mut nacc = vec![[0.0f64; 3]; nv];
    let mut used = vec![false; nv];
    for (ti, t) in prim.triangles.iter().enumerate() {
        let v = t.map(|i| i as usize);
        let fa = 0.5 * norm(cross(sub(pos[v[1]], pos[v[0]]), sub(pos[v[2]], pos[v[0]])));
        for e in 0..3 {
            let (i, j) = (v[e], v[(e + 1) % 3]);
            let l = norm(sub(pos[i], pos[j]));
            radius[i] = radius[i].max(l);
            radius[j] = radius[j].max(l);
            area[v[e]] += fa / 3.0;
            used[v[e]] = true;
            if let Some(c) = computed {
                for k in 0..3 {
                    nacc[v[e]][k] += fa * f64::from(c[ti][e][k]);
                }
            }
        }
    }
    let uvset = mat.tex.and_then(|t| prim.uvs.get(t.1.tex_coord as usize));
    let uvset2 = mat.alpha_tex.and_then(|t| prim.uvs.get(t.1.tex_coord as usize));
    let mut out = Vec::new();
    let mut dropped = 0;
    for i in 0..nv {
        if !used[i] {
            continue;
        }
        let n = match nrm {
            Some(n) => n[i],
            None => nacc[i].map(|x| x as f32),
        };
        let t = Tri {
            p: [pos[i]; 3],
            n: [n; 3],
            c: [prim.colors.as_ref().map_or([1.0; 4], |c| c[i]); 3],
            uv: [uvset.map_or([0.0; 2], |s| s[i]); 3],
            uv2: [uvset2.map_or([0.0; 2], |s| s[i]); 3],
        };
        let (c, n) = shade(&t, [1.0, 0.0, 0.0], mat);
        let Some(c) = c else {
            dropped += 1;
            continue;
        };
        let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        let n = if l > 0.0 { n.map(|x| x / l) } else { [0.0, 0.0, 1.0] };
        out.push(Node {
            center: pos[i].map(|x| (x * h) as f32),
            radius: (radius[i] * h) as f32,
            normal: n,
            cone: 0.0,
            area: (area[i] * h * h) as f32,
            color: srgb8(c),
        });
    }
    (out, dropped)
}

fn to_nodes(recs: &[Rec], h: f64, merge: bool) -> Vec<Node> {
    let r = (0.5 * 3f64.sqrt() * h) as f32;
    let center = |k: [i32; 3]| k.map(|v| ((f64::from(v) + 0.5) * h) as f32);
    let h2 = (h * h) as f32;
    if !merge {
        return recs
            .iter()
            .map(|x| Node { center: center(x.key), radius: r, normal: x.normal, cone: 0.0, area: x.area * h2, color: srgb8(x.color) })
            .collect();
    }
    let mut out = Vec::new();
    let mut i = 0;
    while i < recs.len() {
        let key = recs[i].key;
        let mut j = i;
        let (mut a, mut n, mut c) = (0.0f64, [0.0f64; 3], [0.0f64; 4]);
        while j < recs.len() && recs[j].key == key {
            let x = &recs[j];
            // Zero-area pieces (edge slivers) still count a little so colour is defined.
            let w = f64::from(x.area).max(1e-12);
            a += f64::from(x.area);
            for k in 0..3 {
                n[k] += w * f64::from(x.normal[k]);
            }
            for k in 0..4 {
                c[k] += w * f64::from(x.color[k]);
            }
            j += 1;
        }
        let wsum: f64 = recs[i..j].iter().map(|x| f64::from(x.area).max(1e-12)).sum();
        let l = norm(n);
        let normal = if l > 1e-9 * wsum { n.map(|x| (x / l) as f32) } else { recs[i].normal };
        out.push(Node {
            center: center(key),
            radius: r,
            normal,
            cone: 0.0,
            area: (a * h * h) as f32,
            color: srgb8(c.map(|x| (x / wsum) as f32)),
        });
        i = j;
    }
    out
}

fn srgb8(c: [f32; 4]) -> [u8; 4] {
    let a = (c[3].clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
    [linear_to_srgb8(c[0]), linear_to_srgb8(c[1]), linear_to_srgb8(c[2]), a]
}

/// Samples a point cloud: one sample per point, radius = mean distance to its 4 nearest
/// neighbours (so neighbouring spheres overlap), area = that distance squared (the area of
/// a point's cell in a regular sampling of that spacing).
pub fn sample_points(pc: &PointCloud) -> Vec<Node> {
    let n = pc.positions.len();
    if n == 0 {
        return Vec::new();
    }
    let pts: Vec<[f64; 3]> = pc.positions.iter().map(|p| p.map(f64::from)).collect();
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in &pts {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let ext = sub(hi, lo);
    // Cell size from the bounding box's surface-like measure: about 2 points per cell.
    let area_est = (ext[0] * ext[1] + ext[1] * ext[2] + ext[0] * ext[2]).max(1e-300);
    let mut cell = (2.0 * area_est / n as f64).sqrt().max(norm(ext) * 1e-6).max(1e-30);
    if !cell.is_finite() {
        cell = 1.0;
    }
    let grid = Grid::build(&pts, cell);
    let dist: Vec<f64> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut best = [f64::INFINITY; 4];
            let mut ring = 1i64;
            loop {
                grid.for_each_near(pts[i], ring, |j| {
                    if j != i {
                        let d = norm(sub(pts[i], pts[j]));
                        if d < best[3] {
                            best[3] = d;
                            best.sort_by(|a, b| a.total_cmp(b));
                        }
                    }
                });
                if best[3].is_finite() && best[3] <= ring as f64 * cell || ring >= 8 {
                    break;
                }
                ring *= 2;
            }
            let f: Vec<f64> = best.iter().copied().filter(|d| d.is_finite()).collect();
            if f.is_empty() {
                cell
            } else {
                f.iter().sum::<f64>() / f.len() as f64
            }
        })
        .collect();
    (0..n)
        .map(|i| {
            let d = dist[i];
            let normal = pc.normals.as_ref().map_or([0.0, 0.0, 1.0], |ns| {
                let v = ns[i].map(f64::from);
                let l = norm(v);
                if l > 0.0 && l.is_finite() { v.map(|x| (x / l) as f32) } else { [0.0, 0.0, 1.0] }
            });
            let c = pc.colors.as_ref().map_or([0.8, 0.8, 0.8, 1.0], |c| c[i]);
            Node { center: pc.positions[i], radius: d as f32, normal, cone: 0.0, area: (d * d) as f32, color: srgb8(c) }
        })
        .collect()
}

/// A uniform grid hash over points (used for neighbour search and coverage checks).
pub struct Grid {
    cell: f64,
    map: std::collections::HashMap<[i64; 3], Vec<u32>>,
}

impl Grid {
    /// Buckets points into cells of edge `cell`.
    pub fn build(pts: &[[f64; 3]], cell: f64) -> Grid {
        let mut map: std::collections::HashMap<[i64; 3], Vec<u32>> = std::collections::HashMap::new();
        for (i, p) in pts.iter().enumerate() {
            map.entry(p.map(|x| (x / cell).floor() as i64)).or_default().push(i as u32);
        }
        Grid { cell, map }
    }
    /// Calls `f` for every point in cells within `ring` cells of `p`'s cell.
    pub fn for_each_near(&self, p: [f64; 3], ring: i64, mut f: impl FnMut(usize)) {
        let c = p.map(|x| (x / self.cell).floor() as i64);
        for dx in -ring..=ring {
            for dy in -ring..=ring {
                for dz in -ring..=ring {
                    if let Some(v) = self.map.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) {
                        for &j in v {
                            f(j as usize);
                        }
                    }
                }
            }
        }
    }
}

/// World-space spheres (centre, radius) of sampled meshes, every instance applied (affine
/// ones baked as a samples-file consumer does, spec §8).
pub fn world_spheres(meshes: &[SampledMesh]) -> Vec<([f64; 3], f64)> {
    let mut out = Vec::new();
    for m in meshes {
        for s in &m.instances {
            for n in &m.samples {
                out.push((s.apply_point(n.center.map(f64::from)), f64::from(n.radius) * s.scale));
            }
        }
        for mat in &m.affine {
            let a = sct_format::samples::AffineInstance { mesh: 0, matrix: *mat };
            let st = a.max_stretch();
            for n in &m.samples {
                let b = a.transform_node(n, st);
                out.push((b.center.map(f64::from), f64::from(b.radius)));
            }
        }
    }
    out
}

/// Fraction of `points` inside at least one sphere, and the indices of uncovered points.
/// Spheres are bucketed in a grid of the largest radius, so each lookup visits 27 cells.
pub fn coverage(spheres: &[([f64; 3], f64)], points: &[[f64; 3]]) -> (f64, Vec<usize>) {
    if points.is_empty() {
        return (1.0, Vec::new());
    }
    let rmax = spheres.iter().map(|s| s.1).fold(0.0f64, f64::max);
    if !(rmax > 0.0) {
        return (0.0, (0..points.len()).collect());
    }
    let centers: Vec<[f64; 3]> = spheres.iter().map(|s| s.0).collect();
    let grid = Grid::build(&centers, rmax);
    let missed: Vec<usize> = points
        .par_iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let mut hit = false;
            grid.for_each_near(*p, 1, |j| {
                if !hit {
                    let (c, r) = spheres[j];
                    // A relative slack of 1e-6 absorbs f32 storage of centres and radii.
                    let d2 = dot(sub(*p, c), sub(*p, c));
                    hit = d2 <= (r * (1.0 + 1e-6)) * (r * (1.0 + 1e-6));
                }
            });
            (!hit).then_some(i)
        })
        .collect();
    (1.0 - missed.len() as f64 / points.len() as f64, missed)
}
