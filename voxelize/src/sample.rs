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

mod scanline;

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

impl Method {
    /// The name used on the command line and in JSON.
    pub fn name(self) -> &'static str {
        match self {
            Method::Voxel => "voxel",
            Method::Scanline => "scanline",
            Method::Vertex => "vertex",
        }
    }
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
    /// Coarsen the voxel, when the density rule would make more, to about this many samples
    /// (estimated before merging).
    pub budget: Option<u64>,
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
            budget: None,
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

/// One mesh of [`sample_scene_into`]: a [`SampledMesh`] whose samples went to the sink.
#[derive(Clone, Debug)]
pub struct StreamedMesh {
    /// Name.
    pub name: String,
    /// Samples handed to the sink for this mesh.
    pub count: u64,
    /// Similarity placements (identity for meshes baked into world space).
    pub instances: Vec<sct_format::Similarity>,
    /// Affine placements, row-major 3 × 4.
    pub affine: Vec<[[f64; 4]; 3]>,
}

/// Result of [`sample_scene_into`]: everything but the samples.
#[derive(Clone, Debug)]
pub struct Streamed {
    /// Sampled meshes, in the order their samples reached the sink.
    pub meshes: Vec<StreamedMesh>,
    /// The voxel size.
    pub voxel: VoxelChoice,
    /// Counters.
    pub stats: SampleStats,
}

/// Why [`sample_scene_into`] stopped.
#[derive(Debug)]
pub enum StreamError<E> {
    /// Sampling is impossible (bad density, too many samples, grid too large).
    Sampling(String),
    /// The sink failed; sampling stopped there.
    Sink(E),
}

/// A sink that never fails (collecting in memory, counting).
pub type Never = std::convert::Infallible;

/// Where samples go as they are made, in runs, in their final order. `Send`: a sink works
/// while the threads make the next batch.
pub type Sink<'a, E> = dyn FnMut(&[Node]) -> Result<(), E> + Send + 'a;

/// A [`Sink`] told which mesh (index into [`Streamed::meshes`]) each run belongs to.
pub type MeshSink<'a, E> = dyn FnMut(usize, &[Node]) -> Result<(), E> + Send + 'a;

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
    tex: Option<Tex<'a>>,
    alpha_tex: Option<Tex<'a>>,
    alpha: AlphaMode,
}

/// A texture as a material binds it: the image, its UV set, transform and wrap modes.
#[derive(Clone, Copy)]
struct Tex<'a> {
    img: TexImage<'a>,
    tr: &'a TextureRef,
    /// The UV transform is the identity: lookups skip it.
    plain: bool,
    /// The image's texel grid for [`Tex::interior`].
    grid: TexelGrid,
}

/// Width and height of a decoded image as the interior lookup uses them.
#[derive(Clone, Copy)]
struct TexelGrid {
    w: f64,
    h: f64,
    /// `w − 1`, `h − 1`: the texel coordinates whose 2×2 block needs no wrapping lie below.
    x_end: f64,
    y_end: f64,
    /// Texels per row (`w`).
    stride: usize,
}

impl<'a> Tex<'a> {
    fn new(img: TexImage<'a>, tr: &'a TextureRef) -> Self {
        let (w, h) = (f64::from(img.img.width), f64::from(img.img.height));
        Tex { img, tr, plain: tr.transform == [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], grid: TexelGrid { w, h, x_end: w - 1.0, y_end: h - 1.0, stride: img.img.width as usize } }
    }

    /// Linear RGBA at texture coordinates `uv` (before the transform), bit for bit
    /// [`Image::sample`] of the transformed coordinates with the binding's wrap modes.
    #[inline(always)]
    fn sample(&self, uv: [f32; 2]) -> [f32; 4] {
        // The identity transform changes finite coordinates at most in the sign of a zero,
        // which the lookup ignores; the interior lookup takes finite coordinates only.
        let st = if self.plain { uv } else { self.tr.transform_uv(uv) };
        if let Some(s) = self.interior(st) {
            return s;
        }
        // The general lookup gets the transformed coordinates exactly (for the identity too:
        // it maps non-finite ones to NaN); a non-identity transform is not applied twice.
        let st = if self.plain { self.tr.transform_uv(uv) } else { st };
        self.img.sample(st, self.tr.wrap_s, self.tr.wrap_t)
    }

    /// [`bilinear`]'s lookup in the pre-decoded texels where its 2×2 texel block needs no
    /// wrapping (texel coordinates in [0, width − 1) × [0, height − 1): nearly every lookup
    /// of a texture that is not tiled), with the same arithmetic; `None` elsewhere (edge
    /// texels, wrapping, non-finite coordinates, no decoded table), left to [`TexImage::sample`].
    #[inline(always)]
    fn interior(&self, uv: [f32; 2]) -> Option<[f32; 4]> {
        self.interior_in(self.img.linear?, uv)
    }

    /// [`Tex::interior`] with the decoded texels `lin` (this binding's) at hand.
    #[inline(always)]
    fn interior_in(&self, lin: &[[f32; 4]], uv: [f32; 2]) -> Option<[f32; 4]> {
        let g = &self.grid;
        // `bilinear` computes these from i64 sizes: the same f64 values.
        let x = f64::from(uv[0]) * g.w - 0.5;
        let y = f64::from(uv[1]) * g.h - 0.5;
        // NaN fails too.
        if !(x >= 0.0 && y >= 0.0 && x < g.x_end && y < g.y_end) {
            return None;
        }
        // Truncation is the floor of these non-negative values below 2^32 (u32: the
        // saturating conversion is a float clamp, cheaper than i64's fix-ups).
        let (xi, yi) = (x as u32, y as u32);
        let (fx, fy) = ((x - f64::from(xi)) as f32, (y - f64::from(yi)) as f32);
        // `0 ≤ xi < w − 1` and `0 ≤ yi < h − 1`: the block lies in the table.
        let w = g.stride;
        let i = yi as usize * w + xi as usize;
        let block = lin.get(i..i + w + 2)?;
        let (&[a, b], &[c, d]) = (block.first_chunk::<2>()?, block.last_chunk::<2>()?);
        let mut out = [0.0; 4];
        for k in 0..4 {
            let top = a[k] + (b[k] - a[k]) * fx;
            let bot = c[k] + (d[k] - c[k]) * fx;
            out[k] = top + (bot - top) * fy;
        }
        Some(out)
    }
}

/// A texture image for the samplers, with its texels decoded to linear RGBA once when that
/// table is affordable ([`decode_textures`]).
#[derive(Clone, Copy)]
struct TexImage<'a> {
    img: &'a Image,
    /// `width × height` linear texels (the values [`Image::sample`] decodes per lookup).
    linear: Option<&'a [[f32; 4]]>,
}

impl TexImage<'_> {
    /// [`Image::sample`], bit for bit; reads pre-decoded texels when there are some. Out of
    /// line: per sample it is the rare path after [`Tex::interior`].
    #[inline(never)]
    fn sample(&self, uv: [f32; 2], wrap_s: Wrap, wrap_t: Wrap) -> [f32; 4] {
        let Some(lin) = self.linear else {
            return self.img.sample(uv, wrap_s, wrap_t);
        };
        // `decode_textures` made `lin` only for images with 0 < width × height = lin.len().
        let (w, h) = (i64::from(self.img.width), i64::from(self.img.height));
        bilinear(w, h, uv, wrap_s, wrap_t, |i| lin.get(i).copied().unwrap_or([1.0; 4]))
    }
}

/// Linear RGBA tables of the scene's textured images (index = image index), for images of at
/// most 2^24 texels while the tables stay under 1 GiB in all; `None` = decode per lookup.
fn decode_textures(scene: &LoadedScene) -> Vec<Option<Vec<[f32; 4]>>> {
    let mut used = vec![false; scene.images.len()];
    for m in &scene.materials {
        for t in [&m.texture, &m.alpha_texture].into_iter().flatten() {
            if let Some(u) = used.get_mut(t.image) {
                *u = true;
            }
        }
    }
    let lut = srgb_lut();
    let mut budget: u64 = 1 << 26; // texels (16 B each)
    scene
        .images
        .iter()
        .zip(used)
        .map(|(img, used)| {
            let n = u64::from(img.width) * u64::from(img.height);
            if !used || n == 0 || n > 1 << 24 || n > budget || img.rgba.len() as u64 != n {
                return None;
            }
            budget -= n;
            Some(img.rgba.par_iter().map(|t| [lut[t[0] as usize], lut[t[1] as usize], lut[t[2] as usize], t[3] as f32 / 255.0]).collect())
        })
        .collect()
}

/// One sample before merging: a packed voxel key ([`KeyPack`]) and attributes.
#[derive(Clone, Copy)]
struct Rec {
    key: u64,
    area: f32,
    normal: [f32; 3],
    color: [f32; 4],
}

/// Packs voxel coordinates of one unit into a `u64` (x major, then y, then z — the
/// lexicographic order of the coordinates), so merging sorts plain integers.
#[derive(Clone, Copy, Debug)]
struct KeyPack {
    lo: [i64; 3],
    hi: [i64; 3],
    bits: [u32; 3],
    /// `bits[1] + bits[2]`.
    shift_x: u32,
}

impl KeyPack {
    /// Covers the grid cells of `lo..=hi` (grid units) with one cell of margin.
    fn new(lo: [f64; 3], hi: [f64; 3]) -> Result<KeyPack, String> {
        // Saturating: coordinates far beyond the grid must give an error, not an overflow.
        let l = lo.map(|v| floor_i64(v).saturating_sub(1));
        let h = hi.map(|v| floor_i64(v).saturating_add(1));
        let bits: [u32; 3] = std::array::from_fn(|k| 64 - (h[k].saturating_sub(l[k]).max(1) as u64).leading_zeros());
        if bits.iter().sum::<u32>() > 64 {
            return Err(format!(
                "the voxel grid ({} × {} × {} voxels) is too large to index with 64-bit voxel keys; use a larger voxel size",
                h[0].saturating_sub(l[0]),
                h[1].saturating_sub(l[1]),
                h[2].saturating_sub(l[2])
            ));
        }
        Ok(KeyPack { lo: l, hi: h, bits, shift_x: bits[1] + bits[2] })
    }
    #[inline]
    fn pack(&self, k: [i64; 3]) -> u64 {
        // Clamped so a rounding stray can never spill into a neighbouring field (max then min:
        // `clamp` would also check lo ≤ hi, which `new` guarantees, on every sample).
        let v: [u64; 3] = std::array::from_fn(|i| (k[i].max(self.lo[i]).min(self.hi[i]) - self.lo[i]) as u64);
        (v[0] << self.shift_x) | (v[1] << self.bits[2]) | v[2]
    }
    /// Where axis `k`'s field starts in a key.
    #[inline]
    fn shift(&self, k: usize) -> u32 {
        match k {
            0 => self.shift_x,
            1 => self.bits[2],
            _ => 0,
        }
    }
    #[inline]
    fn unpack(&self, key: u64) -> [i64; 3] {
        let mask = |b: u32| if b == 0 { 0 } else { u64::MAX >> (64 - b) };
        let z = key & mask(self.bits[2]);
        let y = (key >> self.bits[2]) & mask(self.bits[1]);
        let x = key.checked_shr(self.bits[1] + self.bits[2]).unwrap_or(0) & mask(self.bits[0]);
        [x as i64 + self.lo[0], y as i64 + self.lo[1], z as i64 + self.lo[2]]
    }
}

const MAXV: usize = 10;

/// Every voxel x index (no slab restriction).
const ALL_X: (i64, i64) = (i64::MIN, i64::MAX);

/// A convex polygon in the projection plane (coordinates along axes a, b).
#[derive(Clone, Copy)]
struct Poly2 {
    v: [[f64; 2]; MAXV],
    n: usize,
}

impl Poly2 {
    /// Makes this the unit square at (x, y), in place (vertices past `n` are never read).
    fn set_square(&mut self, x: f64, y: f64) {
        self.v[..4].copy_from_slice(&[[x, y], [x + 1.0, y], [x + 1.0, y + 1.0], [x, y + 1.0]]);
        self.n = 4;
    }
    /// An empty polygon (a buffer for the `_into` clips).
    fn empty() -> Poly2 {
        Poly2 { v: [[0.0; 2]; MAXV], n: 0 }
    }
    /// Keeps `x[axis] ∈ [lo, hi]`.
    fn clip_axis(&self, axis: usize, lo: f64, hi: f64) -> Poly2 {
        let (mut tmp, mut out) = (Poly2::empty(), Poly2::empty());
        self.clip_axis_into(axis, lo, hi, &mut tmp, &mut out);
        out
    }
    /// [`Poly2::clip_axis`] into `out` (`tmp` holds the half-way polygon): the hot loops
    /// reuse two buffers instead of zeroing and copying fresh polygons.
    #[inline]
    fn clip_axis_into(&self, axis: usize, lo: f64, hi: f64, tmp: &mut Poly2, out: &mut Poly2) {
        self.clip_half_into(|p| p[axis] - lo, Some((axis, lo)), tmp);
        tmp.clip_half_into(|p| hi - p[axis], Some((axis, hi)), out);
    }
    /// Splits at `x[AXIS] = c` into the parts `x[AXIS] ≤ c` (`below`) and `≥ c` (`above`) in
    /// one pass: the polygons of the two clips, with each cut point computed once and shared,
    /// so the parts meet exactly. `AXIS` is a constant so that the coordinate reads and the
    /// exact cut coordinate need no runtime index.
    #[inline]
    fn split_axis_into<const AXIS: usize>(&self, c: f64, below: &mut Poly2, above: &mut Poly2) {
        let axis = AXIS;
        below.n = 0;
        above.n = 0;
        if self.n == 0 {
            return;
        }
        let mut prev = self.v[self.n - 1];
        let mut fp = prev[axis] - c;
        // The previous vertex's sides, carried so each vertex is compared once.
        let (mut prev_above, mut prev_below) = (fp >= 0.0, fp <= 0.0);
        for i in 0..self.n {
            let cur = self.v[i];
            let fc = cur[axis] - c;
            let (cur_above, cur_below) = (fc >= 0.0, fc <= 0.0);
            let (cross_above, cross_below) = (cur_above != prev_above, cur_below != prev_below);
            if cross_above || cross_below {
                let t = fp / (fp - fc);
                let mut x = [prev[0] + t * (cur[0] - prev[0]), prev[1] + t * (cur[1] - prev[1])];
                x[axis] = c;
                if cross_above && above.n < MAXV {
                    above.v[above.n] = x;
                    above.n += 1;
                }
                if cross_below && below.n < MAXV {
                    below.v[below.n] = x;
                    below.n += 1;
                }
            }
            if cur_above && above.n < MAXV {
                above.v[above.n] = cur;
                above.n += 1;
            }
            if cur_below && below.n < MAXV {
                below.v[below.n] = cur;
                below.n += 1;
            }
            prev = cur;
            fp = fc;
            (prev_above, prev_below) = (cur_above, cur_below);
        }
    }
    /// Keeps the side `f(p) >= 0` of a line (`f` affine). `exact` = (axis, value) for
    /// axis-aligned lines: intersections get that coordinate exactly, so neighbouring clips
    /// agree bit for bit.
    #[inline]
    fn clip_half(&self, f: impl Fn(&[f64; 2]) -> f64, exact: Option<(usize, f64)>) -> Poly2 {
        let mut out = Poly2::empty();
        self.clip_half_into(f, exact, &mut out);
        out
    }
    /// [`Poly2::clip_half`] into `out` (its old vertices are overwritten).
    #[inline]
    fn clip_half_into(&self, f: impl Fn(&[f64; 2]) -> f64, exact: Option<(usize, f64)>, out: &mut Poly2) {
        self.clip_half_by_index_into(|_, p| f(p), exact, out);
    }
    /// [`Poly2::clip_half_into`] with `f` also given the vertex's index, so it can read values
    /// already computed per vertex.
    #[inline]
    fn clip_half_by_index_into(&self, f: impl Fn(usize, &[f64; 2]) -> f64, exact: Option<(usize, f64)>, out: &mut Poly2) {
        out.n = 0;
        if self.n == 0 {
            return;
        }
        let mut prev = self.v[self.n - 1];
        let mut fp = f(self.n - 1, &prev);
        let mut prev_in = fp >= 0.0; // carried: each vertex is compared once
        for i in 0..self.n {
            let cur = self.v[i];
            let fc = f(i, &cur);
            let cur_in = fc >= 0.0;
            if cur_in != prev_in && out.n < MAXV {
                let t = fp / (fp - fc);
                let mut x = [prev[0] + t * (cur[0] - prev[0]), prev[1] + t * (cur[1] - prev[1])];
                if let Some((axis, c)) = exact {
                    x[axis] = c;
                }
                out.v[out.n] = x;
                out.n += 1;
            }
            if cur_in && out.n < MAXV {
                out.v[out.n] = cur;
                out.n += 1;
            }
            prev = cur;
            fp = fc;
            prev_in = cur_in;
        }
    }
    /// (area, centroid) of the polygon (shoelace, relative to the first vertex for precision).
    /// Inlined: it runs once or twice per boundary or depth-crossing column.
    #[inline(always)]
    fn area_centroid(&self) -> (f64, [f64; 2]) {
        let o = self.v[0];
        let (mut a2, mut cx, mut cy) = (0.0, 0.0, 0.0);
        for i in 1..self.n.saturating_sub(1) {
            let (p, q) = ([self.v[i][0] - o[0], self.v[i][1] - o[1]], [self.v[i + 1][0] - o[0], self.v[i + 1][1] - o[1]]);
            let cr = p[0] * q[1] - q[0] * p[1];
            a2 += cr;
            cx += cr * (p[0] + q[0]);
            cy += cr * (p[1] + q[1]);
        }
        if a2 != 0.0 {
            (0.5 * a2.abs(), [o[0] + cx / (3.0 * a2), o[1] + cy / (3.0 * a2)])
        } else {
            let n = self.n.max(1) as f64;
            let m = self.v[..self.n].iter().fold([0.0; 2], |m, p| [m[0] + p[0] / n, m[1] + p[1] / n]);
            (0.0, m)
        }
    }
    /// (min, max) of `f` over the vertices; NaN values are ignored. Plain comparisons: one
    /// instruction each where `f64::min`/`max` add NaN handling (they may differ only in the
    /// sign of a zero, which compares and floors alike).
    fn range(&self, f: impl Fn(&[f64; 2]) -> f64) -> (f64, f64) {
        self.range_keeping(f, &mut [0.0; MAXV])
    }
    /// [`Poly2::range`] that also stores each vertex's value in `vals`.
    #[inline]
    fn range_keeping(&self, f: impl Fn(&[f64; 2]) -> f64, vals: &mut [f64; MAXV]) -> (f64, f64) {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for (p, v) in self.v[..self.n].iter().zip(vals.iter_mut()) {
            let x = f(p);
            *v = x;
            (lo, hi) = (if x < lo { x } else { lo }, if x > hi { x } else { hi });
        }
        (lo, hi)
    }
}

/// The polygon at `r` of a ping-pong pair (to read) and the other one (to write).
fn ping(pair: &mut [Poly2; 2], r: usize) -> (&Poly2, &mut Poly2) {
    let (a, b) = pair.split_at_mut(1);
    if r == 0 { (&a[0], &mut b[0]) } else { (&b[0], &mut a[0]) }
}

/// Samples made at voxel size `h`, estimated before allocating. Before merging, a triangle
/// crosses about `area/h² + perimeter/(2h) + 1` voxels, so the count is
/// `area/h² + perimeter/h + per_triangle` summed over all units (each unit's voxel is a fixed
/// multiple of `h`). After merging, a surface leaves about one sample per voxel it crosses:
/// `Σ area·|n|₁/h²` for the voxel sampler (a plane crosses `|n|₁/h²` cubes per unit area),
/// `Σ area·|n|∞/h²` for the scan-line sampler (one sample per column). Both can be solved for
/// the `h` of a sample budget.
#[derive(Clone, Copy, Debug, Default)]
struct SampleEstimate {
    /// Σ triangle area / (unit voxel / h)², world units².
    area: f64,
    /// Σ half perimeter / (unit voxel / h), world units.
    perimeter: f64,
    /// Samples that do not shrink with a coarser voxel (one per triangle; all of them for the
    /// vertex sampler).
    per_triangle: f64,
    /// Σ triangle area × (voxels crossed per unit area × h²) / (unit voxel / h)².
    merged_area: f64,
}

impl SampleEstimate {
    fn of(scene: &LoadedScene, units: &[Unit], h: f64, method: Method) -> Self {
        let mut e = SampleEstimate::default();
        for u in units {
            let mesh = &scene.meshes[u.mesh];
            let m = u.bake.unwrap_or([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]);
            let k = u.h / h;
            for p in &mesh.primitives {
                for t in &p.triangles {
                    e.per_triangle += 1.0;
                    if method == Method::Vertex {
                        continue;
                    }
                    let [a, b, c] = t.map(|i| transform_point(&m, p.positions[i as usize]));
                    let n = cross(sub(b, a), sub(c, a));
                    let area = 0.5 * norm(n) / (k * k);
                    e.area += area;
                    // Columns are sampled at their centres (no edge term); a conservative
                    // voxelization also takes the voxels along the edges.
                    if method == Method::Voxel {
                        e.perimeter += (norm(sub(b, a)) + norm(sub(c, b)) + norm(sub(a, c))) / k;
                    }
                    let len = norm(n);
                    if len > 0.0 {
                        let [x, y, z] = n.map(|v| v.abs() / len);
                        e.merged_area += area * if method == Method::Scanline { x.max(y).max(z) } else { x + y + z };
                    }
                }
            }
        }
        e
    }

    /// Samples before merging.
    fn at(&self, h: f64) -> f64 {
        self.merged_area / (h * h) + self.perimeter / h + self.per_triangle
    }

    /// The voxel size expected to give `budget` samples (after merging when `merge`), if a
    /// finite one exists.
    fn voxel_for(&self, budget: f64, merge: bool) -> Option<f64> {
        let h = if merge {
            (self.merged_area / budget).sqrt()
        } else {
            // area·x² + perimeter·x − room = 0 with x = 1/h.
            let (a, p) = (self.merged_area, self.perimeter);
            let room = budget - self.per_triangle;
            if room <= 0.0 || a <= 0.0 {
                return None;
            }
            let x = (-p + (p * p + 4.0 * a * room).sqrt()) / (2.0 * a);
            1.0 / x
        };
        (h.is_finite() && h > 0.0).then_some(h)
    }
}

/// Samples a loaded scene into memory: [`sample_scene_into`] collecting each mesh's samples.
pub fn sample_scene(scene: &LoadedScene, opts: &SampleOptions, progress: &(dyn Fn(u64, u64) + Sync)) -> Result<Sampled, String> {
    let mut samples: Vec<Vec<Node>> = Vec::new();
    let streamed = sample_scene_into(scene, opts, progress, &mut |mesh, nodes| {
        if samples.len() <= mesh {
            samples.resize_with(mesh + 1, Vec::new);
        }
        samples[mesh].extend_from_slice(nodes);
        Ok::<(), Never>(())
    })
    .map_err(|e| match e {
        StreamError::Sampling(msg) => msg,
        StreamError::Sink(never) => match never {},
    })?;
    samples.resize_with(streamed.meshes.len(), Vec::new);
    let meshes = streamed
        .meshes
        .into_iter()
        .zip(samples)
        .map(|(m, samples)| SampledMesh { name: m.name, samples, instances: m.instances, affine: m.affine })
        .collect();
    Ok(Sampled { meshes, voxel: streamed.voxel, stats: streamed.stats })
}

/// Samples a loaded scene, handing the samples to `sink(mesh, samples)` in runs, mesh after
/// mesh (`mesh` indexes the result's meshes) and in each mesh's final (voxel) order, as they
/// are made: no result is held, only two batches of slabs (the sink works on one while the
/// threads make the next). A sink error stops sampling and is returned.
pub fn sample_scene_into<E: Send>(
    scene: &LoadedScene,
    opts: &SampleOptions,
    progress: &(dyn Fn(u64, u64) + Sync),
    sink: &mut MeshSink<'_, E>,
) -> Result<Streamed, StreamError<E>> {
    let (voxel, mut stats, units) = plan_sampling(scene, opts).map_err(StreamError::Sampling)?;
    let total_tris: u64 = units.iter().map(|u| scene.meshes[u.mesh].triangle_count() as u64).sum();
    let done = std::sync::atomic::AtomicU64::new(0);
    let linear = decode_textures(scene);
    let mut out = Vec::new();
    for (ui, u) in units.iter().enumerate() {
        let mesh = &scene.meshes[u.mesh];
        let kp = unit_keys(mesh, u).map_err(StreamError::Sampling)?;
        let prepared: Vec<Prepared> = mesh
            .primitives
            .iter()
            .map(|prim| {
                let material = scene.material(prim);
                let tex_of = |t: &Option<TextureRef>| -> Option<(TexImage, TextureRef)> {
                    t.as_ref().and_then(|t| {
                        let linear = linear.get(t.image).and_then(|l| l.as_deref());
                        scene.images.get(t.image).map(|img| (TexImage { img, linear }, t.clone()))
                    })
                };
                let mat = MatOwned {
                    base: material.base_color,
                    tex: tex_of(&material.texture),
                    alpha_tex: tex_of(&material.alpha_texture),
                    alpha: material.alpha_mode,
                };
                Prepared::new(prim, u, mat, opts.crease_deg)
            })
            .collect();
        let mut tally = AreaTally::new(&u.affine);
        let mut emit = |nodes: &[Node]| {
            tally.add(nodes);
            sink(ui, nodes)
        };
        let (before, dropped) = if opts.method == Method::Vertex {
            let mut dropped = 0;
            for pp in &prepared {
                let (v, d) = vertex_patches(pp.prim, &pp.pos, &pp.nrm, pp.computed.as_deref(), &pp.mat.view(), u.h);
                emit(&v).map_err(StreamError::Sink)?;
                dropped += d;
            }
            let n = mesh.triangle_count() as u64;
            progress(done.fetch_add(n, std::sync::atomic::Ordering::Relaxed) + n, total_tris);
            (tally.count, dropped)
        } else {
            let progress = |n| progress((done.fetch_add(n, std::sync::atomic::Ordering::Relaxed) + n).min(total_tris), total_tris);
            sample_slabs(&prepared, &kp, u.h, opts, &progress, &mut emit).map_err(StreamError::Sink)?
        };
        stats.triangles += mesh.triangle_count() as u64;
        stats.dropped_alpha += dropped;
        stats.samples_before_merge += before;
        stats.samples += tally.count;
        stats.sample_area = tally.add_placed_area(stats.sample_area, &u.instances);
        out.push(StreamedMesh { name: u.name.clone(), count: tally.count, instances: u.instances.clone(), affine: u.affine.clone() });
    }
    stats.mesh_area = scene.world_area();
    Ok(Streamed { meshes: out, voxel, stats })
}

/// The voxel size, the units to sample and their counters so far: the density rule, the
/// sample budget and the limits, checked before any sampling.
fn plan_sampling(scene: &LoadedScene, opts: &SampleOptions) -> Result<(VoxelChoice, SampleStats, Vec<Unit>), String> {
    let mut voxel = choose_voxel_size(scene, &opts.density)?;
    let mut stats = SampleStats::default();
    let mut units = plan_units(scene, voxel.size, &mut stats);
    let mut est = SampleEstimate::of(scene, &units, voxel.size, opts.method);
    // The vertex sampler makes one sample per triangle at any voxel size: no budget applies.
    if let (Some(budget), false) = (opts.budget, opts.method == Method::Vertex) {
        if let Some(coarser) = est.voxel_for(budget as f64, opts.merge).filter(|&c| c > voxel.size) {
            voxel.reason = format!("{}; coarsened to {coarser:.6} to stay within --sample-budget {budget}", voxel.reason);
            voxel.size = coarser;
            stats = SampleStats::default();
            units = plan_units(scene, coarser, &mut stats);
            est = SampleEstimate::of(scene, &units, coarser, opts.method);
        } else if !opts.merge && est.at(voxel.size) > budget as f64 {
            return Err(format!(
                "--sample-budget {budget} cannot be met without merging: the {} sampler makes at least one sample per triangle ({:.0})",
                opts.method.name(),
                est.per_triangle
            ));
        }
    }
    let h = voxel.size;
    if let Some(b) = scene.world_bounds() {
        let ext = b.0.iter().chain(b.1.iter()).fold(0.0f64, |m, v| m.max(v.abs()));
        if units.iter().any(|u| u.bake.is_some() && ext / u.h > (1u64 << 30) as f64) {
            return Err(format!("voxel size {h} is too small for coordinates up to {ext} (more than 2^30 voxels along an axis)"));
        }
    }
    let estimate = est.at(h);
    if estimate > opts.max_samples as f64 {
        return Err(format!(
            "voxel size {h} would make about {estimate:.0} samples, more than --max-samples {}; use a larger --voxel-size, a smaller γ or --sample-budget",
            opts.max_samples
        ));
    }
    Ok((voxel, stats, units))
}

/// A mesh's sample count and area sums, added run by run as its samples stream past, each
/// sum in sample order (the order, hence the bits, of summing the whole mesh at once).
struct AreaTally {
    count: u64,
    /// Σ area in the mesh's frame.
    area: f64,
    /// Per affine placement: the map, its stretch and Σ placed area.
    affine: Vec<(sct_format::samples::AffineInstance, f64, f64)>,
}

impl AreaTally {
    fn new(affine: &[[[f64; 4]; 3]]) -> Self {
        let affine = affine
            .iter()
            .map(|m| {
                let a = sct_format::samples::AffineInstance { mesh: 0, matrix: *m };
                (a, a.max_stretch(), 0.0)
            })
            .collect();
        AreaTally { count: 0, area: 0.0, affine }
    }

    fn add(&mut self, nodes: &[Node]) {
        self.count += nodes.len() as u64;
        self.area = nodes.iter().fold(self.area, |s, n| s + f64::from(n.area));
        for (a, stretch, sum) in &mut self.affine {
            *sum = nodes.iter().fold(*sum, |s, n| s + f64::from(a.transform_node(n, *stretch).area));
        }
    }

    /// `scene_area` plus the area over every placement (similarities scale areas by s²,
    /// affine maps per sample), added in the order the whole-mesh sums were.
    fn add_placed_area(&self, mut scene_area: f64, instances: &[sct_format::Similarity]) -> f64 {
        scene_area += instances.iter().map(|s| self.area * s.scale * s.scale).sum::<f64>();
        for (_, _, sum) in &self.affine {
            scene_area += sum;
        }
        scene_area
    }
}

/// The voxel-key packing of a unit: its vertices' bounds in grid units.
fn unit_keys(mesh: &Mesh, u: &Unit) -> Result<KeyPack, String> {
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for p in &mesh.primitives {
        for &v in &p.positions {
            let w = match &u.bake {
                Some(m) => transform_point(m, v),
                None => v.map(f64::from),
            };
            for k in 0..3 {
                lo[k] = lo[k].min(w[k] / u.h);
                hi[k] = hi[k].max(w[k] / u.h);
            }
        }
    }
    if lo.iter().chain(hi.iter()).any(|v| !v.is_finite()) {
        (lo, hi) = ([0.0; 3], [0.0; 3]);
    }
    KeyPack::new(lo, hi)
}

/// Samples a unit's triangles slab by slab and merges same-voxel samples.
///
/// The grid is cut into slabs along x holding about equal numbers of expected samples;
/// each slab voxelizes the triangles overlapping it, keeping only its own voxels, then
/// radix-sorts and merges them in buffers reused by its thread. Voxel keys are x-major, so
/// concatenating slabs in order gives the globally sorted result, and equal voxels (always in
/// one slab) merge in triangle order whatever the thread count: deterministic output, no
/// global sort, and memory per batch of slabs rather than per scene: each batch's slab
/// outputs go to `emit` in slab order, then their buffers serve a later batch. Returns
/// (samples before merging, alpha-dropped samples), or the first error of `emit`.
fn sample_slabs<E: Send>(
    pp: &[Prepared],
    kp: &KeyPack,
    h: f64,
    opts: &SampleOptions,
    progress: &(dyn Fn(u64) + Sync),
    emit: &mut Sink<'_, E>,
) -> Result<(u64, u64), E> {
    // Every triangle: (primitive, index), x-cell range, expected samples.
    let mut tris: Vec<(u32, u32)> = Vec::new();
    let mut xr: Vec<(i64, i64)> = Vec::new();
    let mut est: Vec<f64> = Vec::new();
    for (pi, p) in pp.iter().enumerate() {
        for (ti, t) in p.prim.triangles.iter().enumerate() {
            let [a, b, c] = t.map(|v| p.pos[v as usize]);
            let lo = a[0].min(b[0]).min(c[0]).floor() as i64;
            let hi = a[0].max(b[0]).max(c[0]).floor() as i64;
            tris.push((pi as u32, ti as u32));
            xr.push((lo.clamp(kp.lo[0], kp.hi[0]), hi.clamp(kp.lo[0], kp.hi[0])));
            est.push(0.5 * norm(cross(sub(b, a), sub(c, a))) + 0.5 * (norm(sub(b, a)) + norm(sub(c, b)) + norm(sub(a, c))) + 1.0);
        }
    }
    if tris.is_empty() {
        return Ok((0, 0));
    }
    // Expected samples per x cell (difference array), cells of `cell` voxels (coarser only
    // for enormous grids), then slab boundaries at equal quantiles.
    let width = (kp.hi[0] - kp.lo[0] + 1) as u64;
    let cell = width.div_ceil(1 << 20).max(1) as i64;
    let ncells = ((kp.hi[0] - kp.lo[0]) / cell + 1) as usize;
    let cell_of = |x: i64| ((x - kp.lo[0]) / cell) as usize;
    let mut diff = vec![0.0f64; ncells + 1];
    for (r, e) in xr.iter().zip(&est) {
        let (c0, c1) = (cell_of(r.0), cell_of(r.1));
        let per = e / (c1 - c0 + 1) as f64;
        diff[c0] += per;
        diff[c1 + 1] -= per;
    }
    let total: f64 = est.iter().sum();
    let slabs = ((total / slab_target()).ceil() as usize).clamp(8, 16_384).min(ncells);
    let mut slab_of_cell = vec![0u32; ncells];
    let mut slab_x: Vec<(i64, i64)> = Vec::with_capacity(slabs);
    let (mut acc, mut run, mut start) = (0.0, 0.0, 0usize);
    for c in 0..ncells {
        run += diff[c];
        acc += run;
        slab_of_cell[c] = slab_x.len() as u32;
        let last = c + 1 == ncells;
        if last || acc >= (slab_x.len() + 1) as f64 * total / slabs as f64 {
            let x0 = kp.lo[0] + start as i64 * cell;
            let x1 = if last { kp.hi[0] } else { kp.lo[0] + (c as i64 + 1) * cell - 1 };
            slab_x.push((x0, x1));
            start = c + 1;
        }
    }
    let mut lists: Vec<Vec<u32>> = vec![Vec::new(); slab_x.len()];
    for (gi, r) in xr.iter().enumerate() {
        for l in &mut lists[slab_of_cell[cell_of(r.0)] as usize..=slab_of_cell[cell_of(r.1)] as usize] {
            l.push(gi as u32);
        }
    }
    let per_slab = total / slab_x.len() as f64;
    let radius = (0.5 * 3f64.sqrt() * h) as f32;
    let h2 = h * h;
    #[derive(Default)]
    struct Bufs {
        recs: Vec<Rec>,
        parts: SlabParts,
        items: Vec<u64>,
        tmp: Vec<u64>,
    }
    // Slab buffers outlive rayon's jobs in a pool, so batches reuse them.
    let pool: std::sync::Mutex<Vec<Bufs>> = std::sync::Mutex::new(Vec::new());
    struct Pooled<'p> {
        bufs: Bufs,
        pool: &'p std::sync::Mutex<Vec<Bufs>>,
    }
    impl Drop for Pooled<'_> {
        fn drop(&mut self) {
            let b = std::mem::take(&mut self.bufs);
            if let Ok(mut p) = self.pool.lock() {
                p.push(b);
            }
        }
    }
    // Slabs run in batches of 4 per thread (enough to balance the threads). A batch's
    // outputs are emitted in slab order while the threads make the next batch (the sink's
    // work, a file write, overlaps sampling), then their buffers serve a later batch: the
    // outputs of two batches exist at a time, whatever the scene's size, and no fresh pages
    // are faulted in and zeroed after the first two.
    let outs: std::sync::Mutex<Vec<Vec<Node>>> = std::sync::Mutex::new(Vec::new());
    let batch = 4 * rayon::current_num_threads();
    let make_batch = |lists: &[Vec<u32>], slab_x: &[(i64, i64)]| -> Vec<(Vec<Node>, u64, u64)> {
        lists
            .par_iter()
            .zip(slab_x.par_iter())
            .map_init(
                || Pooled {
                    bufs: pool.lock().ok().and_then(|mut p| p.pop()).unwrap_or_default(),
                    pool: &pool,
                },
                |pooled, (list, &(x0, x1))| {
                    let bufs = &mut pooled.bufs;
                    bufs.parts.reset(kp, (x0, x1), per_slab);
                    let mut dropped = 0u64;
                    for &gi in list {
                        let (pi, ti) = tris[gi as usize];
                        let p = &pp[pi as usize];
                        let t = p.tri(ti as usize);
                        let mat = p.mat.view();
                        if opts.method == Method::Scanline {
                            // Per-triangle areas (EQ 17) need the whole triangle's sample count:
                            // counted row by row, while only this slab's voxels are shaded and
                            // kept (each voxel, hence each alpha drop, belongs to one slab).
                            // Straight into the parts: nothing rescales its records afterwards.
                            dropped += scanline::scanline_triangle(&t, &mat, kp, (x0, x1), &mut bufs.parts);
                            continue;
                        }
                        // The voxel method rescales a triangle's EQ 17 areas once it has them
                        // all, so its records (few, in L1) pass through `recs` to the parts.
                        bufs.recs.clear();
                        dropped += if (opts.method, opts.area) == (Method::Voxel, AreaMode::Exact) {
                            voxel_triangle(&t, &mat, AreaMode::Exact, kp, (x0, x1), ALL_X, &mut bufs.recs)
                        } else {
                            voxel_triangle(&t, &mat, opts.area, kp, ALL_X, (x0, x1), &mut bufs.recs)
                        };
                        bufs.parts.extend(&bufs.recs);
                    }
                    // Progress counts a triangle once, in its first slab.
                    progress(list.iter().filter(|&&gi| xr[gi as usize].0 >= x0).count() as u64);
                    let before = bufs.parts.len();
                    let mut out = outs.lock().ok().and_then(|mut o| o.pop()).unwrap_or_default();
                    out.clear();
                    out.reserve(if opts.merge { before * 4 / 5 } else { before });
                    for (i, part) in bufs.parts.parts.iter().enumerate() {
                        let idx_mask = sort_order(part, bufs.parts.key_range(i), &mut bufs.items, &mut bufs.tmp);
                        merge_sorted(&bufs.items, idx_mask, part, kp, radius, h, h2, opts.merge, &mut out);
                    }
                    let before = before as u64;
                    (out, before, dropped)
                },
            )
            .collect()
    };
    let mut emit_batch = |parts: Vec<(Vec<Node>, u64, u64)>| -> Result<(u64, u64), E> {
        let (mut before, mut dropped) = (0u64, 0u64);
        for (mut p, b, d) in parts {
            emit(&p)?;
            before += b;
            dropped += d;
            p.clear();
            if let Ok(mut o) = outs.lock() {
                o.push(p);
            }
        }
        Ok((before, dropped))
    };
    let (mut before, mut dropped) = (0u64, 0u64);
    let mut made = Vec::new();
    for (lists, slab_x) in lists.chunks(batch).zip(slab_x.chunks(batch)) {
        let last = std::mem::take(&mut made);
        let (emitted, next) = rayon::join(|| emit_batch(last), || make_batch(lists, slab_x));
        let (b, d) = emitted?;
        (before, dropped, made) = (before + b, dropped + d, next);
    }
    let (b, d) = emit_batch(made)?;
    Ok((before + b, dropped + d))
}

/// Expected samples per slab (unit tests lower it to get many slabs and batches from small
/// meshes).
#[cfg(not(test))]
fn slab_target() -> f64 {
    131_072.0
}
#[cfg(test)]
static SLAB_TARGET: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(131_072);
#[cfg(test)]
fn slab_target() -> f64 {
    SLAB_TARGET.load(std::sync::atomic::Ordering::Relaxed) as f64
}

/// Records per part of a slab (about): a part's records (40 B each) and sort items stay in
/// a core's L2 (512 KiB) while they are sorted and merged, so the merge's gathers in key
/// order hit L2 rather than L3, where a whole slab's records (about 5 MB) would lie.
/// (2k and 4k records per part, or 8-bit radix digits, measured slower; 16k the same.)
const PART_RECS: f64 = 8192.0;

/// Where an emitter puts its records.
trait RecSink {
    fn push(&mut self, r: Rec);
    /// The buffer where every key of `lo..=hi` goes, when there is one: a run of records
    /// is then pushed there without finding each one's place.
    fn run(&mut self, lo: u64, hi: u64) -> Option<&mut Vec<Rec>>;
}

impl RecSink for Vec<Rec> {
    #[inline]
    fn push(&mut self, r: Rec) {
        Vec::push(self, r);
    }
    #[inline]
    fn run(&mut self, _lo: u64, _hi: u64) -> Option<&mut Vec<Rec>> {
        Some(self)
    }
}

impl RecSink for SlabParts {
    /// Appends a record to the part of its key.
    #[inline]
    fn push(&mut self, r: Rec) {
        let i = self.part_of(r.key);
        if let Some(p) = self.parts.get_mut(i) {
            p.push(r);
        }
    }
    /// The part of `lo..=hi` when both ends (and so every key between, parts being key
    /// ranges in order) fall in it.
    #[inline]
    fn run(&mut self, lo: u64, hi: u64) -> Option<&mut Vec<Rec>> {
        let i = self.part_of(lo);
        if i == self.part_of(hi) { self.parts.get_mut(i) } else { None }
    }
}

/// A slab's records in parts by key: part `i` holds the keys `base + i·2^shift ..` (clamped
/// to the first and last part), where `base` is the key of the slab's first x with the
/// lowest y and z. The parts are in key order and each key lies in one part, in the order
/// its records came: sorting and merging the parts one by one equals doing it for the whole
/// slab.
#[derive(Default)]
struct SlabParts {
    parts: Vec<Vec<Rec>>,
    base: u64,
    shift: u32,
    last: u64,
}

impl SlabParts {
    /// Empties the parts and sizes them for a slab of x range `xs` expecting `expected` records
    /// (at most 2^8 parts: their write streams stay in L1).
    fn reset(&mut self, kp: &KeyPack, xs: (i64, i64), expected: f64) {
        let base = kp.pack([xs.0, kp.lo[1], kp.lo[2]]);
        let span = kp.pack([xs.1, kp.hi[1], kp.hi[2]]).saturating_sub(base);
        let want = (expected / PART_RECS).clamp(1.0, 256.0) as u64;
        let mut shift = 0;
        while span.checked_shr(shift).unwrap_or(0) >= want {
            shift += 1;
        }
        let count = span.checked_shr(shift).unwrap_or(0) as usize + 1;
        self.parts.truncate(count);
        self.parts.iter_mut().for_each(Vec::clear);
        self.parts.resize_with(count, Vec::new);
        // A shift of 64 (one part) becomes 63: `part_of`'s `min` still gives part 0, and
        // the shift needs no check there.
        (self.base, self.shift, self.last) = (base, shift.min(63), count as u64 - 1);
    }

    /// The part of a voxel key.
    #[inline]
    fn part_of(&self, key: u64) -> usize {
        // `shift ≤ 63` (see `reset`).
        (key.saturating_sub(self.base) >> self.shift).min(self.last) as usize
    }

    /// Appends records, each to the part of its key (record by record: copying runs of one
    /// part at once measured slower, most runs being short).
    fn extend(&mut self, recs: &[Rec]) {
        for r in recs {
            self.push(*r);
        }
    }

    fn len(&self) -> usize {
        self.parts.iter().map(Vec::len).sum()
    }

    /// (lowest key, key bits) of part `i`'s keys when known from its place: the first and
    /// last parts also hold clamped strays, so only the parts between them.
    fn key_range(&self, i: usize) -> Option<(u64, u32)> {
        let i = i as u64;
        if i == 0 || i >= self.last {
            return None;
        }
        let lo = (i << self.shift).checked_add(self.base)?;
        Some((lo, self.shift))
    }
}

/// Sorts `recs` by key, stably: fills `items` with their indices in key order, each in the
/// low bits of an item under the returned mask. Normally an item is the key (relative to
/// the smallest) above the index, so one radix sort of plain `u64`s by their key bits
/// orders them; when the two do not fit in 64 bits, items are bare indices (comparison sort).
/// `range` = (lo, bits) when every key is known to lie in `lo .. lo + 2^bits` (a middle part
/// of [`SlabParts`]), which saves a scan for the smallest and largest keys.
fn sort_order(recs: &[Rec], range: Option<(u64, u32)>, items: &mut Vec<u64>, tmp: &mut Vec<u64>) -> u64 {
    items.clear();
    let (lo, key_bits) = range.unwrap_or_else(|| {
        let (lo, hi) = recs.iter().fold((u64::MAX, 0), |(l, h), r| (l.min(r.key), h.max(r.key)));
        (lo, 64 - hi.saturating_sub(lo).leading_zeros())
    });
    let n = recs.len();
    let idx_bits = 64 - (n as u64).leading_zeros();
    if key_bits + idx_bits > 64 {
        items.extend(0..n as u64);
        items.sort_by_key(|&i| recs[i as usize].key);
        return u64::MAX;
    }
    let item = |i: usize, r: &Rec| ((r.key - lo) << idx_bits) | i as u64;
    let (passes, d) = radix_digits(n, key_bits);
    if passes != 2 || !radix_worth(n, key_bits) {
        items.extend(recs.iter().enumerate().map(|(i, r)| item(i, r)));
        radix_sort_bits(items, tmp, idx_bits, key_bits);
        return (1u64 << idx_bits) - 1;
    }
    // The usual case (a part of a slab: two digits): both digits counted in one read.
    items.extend(recs.iter().enumerate().map(|(i, r)| item(i, r)));
    let mut counts = vec![0u32; 2 << d];
    let (c0, c1) = counts.split_at_mut(1 << d);
    // Masks from the counters' lengths: the counting goes unchecked.
    let (Some(m0), Some(m1)) = (c0.len().checked_sub(1), c1.len().checked_sub(1)) else {
        return u64::MAX; // unreachable: both halves hold 2^d counters
    };
    for &x in items.iter() {
        let v = (x >> idx_bits) as usize;
        c0[v & m0] += 1;
        c1[(v >> d) & m1] += 1;
    }
    radix_passes(items, tmp, idx_bits, d, &mut counts);
    (1u64 << idx_bits) - 1
}

/// Appends to `out` the nodes of records in the order of `items` (record index = item &
/// `idx_mask`, in key order), merging records of one voxel when `merge` (areas add;
/// normal and colour are area-weighted means).
#[allow(clippy::too_many_arguments)]
fn merge_sorted(items: &[u64], idx_mask: u64, recs: &[Rec], kp: &KeyPack, r: f32, h: f64, h2: f64, merge: bool, out: &mut Vec<Node>) {
    // One copy of the loop per case: the flags do not take registers in it. Items carry
    // their keys above the index unless they are bare indices (idx_mask all ones).
    let shape = NodeShape { kp, r, h, h2 };
    match (merge, idx_mask != u64::MAX) {
        (true, true) => merge_loop::<true, true>(items, idx_mask, recs, &shape, out),
        (true, false) => merge_loop::<true, false>(items, idx_mask, recs, &shape, out),
        (false, _) => merge_loop::<false, false>(items, idx_mask, recs, &shape, out),
    }
}

/// What turns a voxel key and a record's area into a node's centre, radius and area.
struct NodeShape<'k> {
    kp: &'k KeyPack,
    r: f32,
    h: f64,
    h2: f64,
}

/// [`merge_sorted`]'s loop; `KEYED`: runs of one voxel are found from the items' key bits,
/// without reading the records.
fn merge_loop<const MERGE: bool, const KEYED: bool>(items: &[u64], idx_mask: u64, recs: &[Rec], shape: &NodeShape, out: &mut Vec<Node>) {
    let &NodeShape { kp, r, h, h2 } = shape;
    // Keys ascend, so neighbours mostly share x and y (the bits above z): their centre
    // coordinates are taken once per (x, y) column, only z per key. (Each key field has at
    // least 1 bit and they sum to at most 64, so z's are fewer than 64: the shift is exact.)
    let z_bits = kp.bits[2] & 63;
    let z_mask = (1u64 << z_bits) - 1;
    let z_lo = kp.lo[2];
    let c = |v: i64| ((v as f64 + 0.5) * h) as f32;
    let mut column = (u64::MAX, [0.0f32; 2]);
    // Neighbouring voxels mostly carry the same colour (always for untextured meshes without
    // vertex colours): encode a colour once for a run of equal ones (equal bits: one integer
    // compare; a colour equal as floats but not in bits, ±0, only encodes again).
    let bits = |c: [f32; 4]| c.map(f32::to_bits);
    let mut memo = (bits([f32::NAN; 4]), srgb8([f32::NAN; 4]));
    // A local vector: its length and pointer stay in registers across the loop.
    let mut nodes = std::mem::take(out);
    nodes.reserve(items.len());
    let n = items.len();
    let mut i = 0;
    while i < n {
        let it = items[i];
        let first = &recs[(it & idx_mask) as usize];
        let key = first.key;
        let mut j = i + 1;
        if MERGE {
            if KEYED {
                while j < n && (items[j] ^ it) & !idx_mask == 0 {
                    j += 1;
                }
            } else {
                while j < n && recs[items[j] as usize].key == key {
                    j += 1;
                }
            }
        }
        let hi = key >> z_bits;
        if hi != column.0 {
            let v = kp.unpack(key);
            column = (hi, [c(v[0]), c(v[1])]);
        }
        let center = [column.1[0], column.1[1], c((key & z_mask) as i64 + z_lo)];
        if j == i + 1 {
            // The common case: nothing to merge.
            if bits(first.color) != memo.0 {
                memo = (bits(first.color), srgb8(first.color));
            }
            nodes.push(Node { center, radius: r, normal: first.normal, cone: 0.0, area: (f64::from(first.area) * h2) as f32, color: memo.1 });
        } else {
            let (normal, area, color) = merge_run(&items[i..j], idx_mask, recs, h2);
            if bits(color) != memo.0 {
                memo = (bits(color), srgb8(color));
            }
            nodes.push(Node { center, radius: r, normal, cone: 0.0, area, color: memo.1 });
        }
        i = j;
    }
    *out = nodes;
}

/// (normal, area, colour) of a run of records of one voxel (its own function with its own
/// locals; inlined: a call per run measured +4 % instructions in the voxel method's merge).
#[inline(always)]
fn merge_run(run: &[u64], idx_mask: u64, recs: &[Rec], h2: f64) -> ([f32; 3], f32, [f32; 4]) {
    let (mut a, mut wsum, mut nn, mut c) = (0.0f64, 0.0f64, [0.0f64; 3], [0.0f64; 4]);
    for &it in run {
        let x = &recs[(it & idx_mask) as usize];
        // Zero-area pieces (edge slivers) still count a little so colour is defined.
        let w = f64::from(x.area).max(1e-12);
        a += f64::from(x.area);
        wsum += w;
        for (s, v) in nn.iter_mut().zip(x.normal) {
            *s += w * f64::from(v);
        }
        for (s, v) in c.iter_mut().zip(x.color) {
            *s += w * f64::from(v);
        }
    }
    let l = norm(nn);
    let first = run.first().map_or([0.0; 3], |&it| recs[(it & idx_mask) as usize].normal);
    let normal = if l > 1e-9 * wsum { nn.map(|x| (x / l) as f32) } else { first };
    (normal, (a * h2) as f32, c.map(|x| (x / wsum) as f32))
}

/// Widest radix digit: slab keys of up to 28 bits (a slab's x cells above a unit's y and z
/// fields: the dense runs' keys) sort in two passes; 2^14 counters still sit in L2.
const RADIX_DIGIT_BITS: u32 = 14;

/// Whether a radix sort beats a comparison sort for `n` items with `bits` key bits.
fn radix_worth(n: usize, bits: u32) -> bool {
    n > 64 && n <= u32::MAX as usize && bits > 0
}

/// (passes, digit bits) of a radix sort of `n` items by `bits` key bits: digits of at most
/// [`RADIX_DIGIT_BITS`], and at most about n/2 counters (for short inputs, time would go to
/// the counters), so a slab part's 8–16k items with 23–24 key bits take two passes.
fn radix_digits(n: usize, bits: u32) -> (u32, u32) {
    let widest = (usize::BITS - n.leading_zeros()).saturating_sub(1).clamp(8, RADIX_DIGIT_BITS);
    let passes = bits.min(64).div_ceil(widest);
    (passes, bits.div_ceil(passes.max(1)))
}

/// Stable LSD radix sort of `items` by their bits `shift .. shift + bits` (the bits above are
/// zero), in the passes of [`radix_digits`]; passes where every item has the same digit are
/// skipped.
fn radix_sort_bits(items: &mut [u64], tmp: &mut Vec<u64>, shift: u32, bits: u32) {
    let n = items.len();
    if !radix_worth(n, bits) {
        items.sort_by_key(|&x| x >> shift.min(63)); // stable
        return;
    }
    let (passes, d) = radix_digits(n, bits);
    // Every pass's counters filled in one read of the items.
    let mut counts = vec![0u32; (passes as usize) << d];
    let m = (1u64 << d) - 1;
    for &x in items.iter() {
        let mut v = x >> shift;
        for c in counts.chunks_exact_mut(1 << d) {
            if let Some(c) = c.get_mut((v & m) as usize) {
                *c += 1;
            }
            v >>= d;
        }
    }
    radix_passes(items, tmp, shift, d, &mut counts);
}

/// The passes of an LSD radix sort whose digit counts (pass p's `2^d` counters at
/// `p·2^d`, one pass per block) are in `counts`: digit p is bits `shift + p·d ..` of an item.
fn radix_passes(items: &mut [u64], tmp: &mut Vec<u64>, shift: u32, d: u32, counts: &mut [u32]) {
    let n = items.len();
    // The scratch buffer is reused across calls: grown (zeroed) only when too short.
    if tmp.len() < n {
        tmp.resize(n, 0);
    }
    let tmp = &mut tmp[..n];
    let mut in_items = true; // where the current data lives
    for (p, count) in counts.chunks_exact_mut(1 << d).enumerate() {
        let (src, dst): (&[u64], &mut [u64]) = if in_items { (items, &mut *tmp) } else { (&*tmp, items) };
        if scatter_by_digit(src, dst, shift + p as u32 * d, count) {
            in_items = !in_items;
        }
    }
    if !in_items {
        items.copy_from_slice(tmp);
    }
}

/// One counting-sort pass of [`radix_passes`]: moves `src` into `dst` stably ordered by the
/// digit `(x >> sh) & (count.len() − 1)`, where `count` holds each digit's count
/// (`count.len()` a power of two; masking by it lets the counter indexing go unchecked).
/// Returns false, moving nothing, when all digits are equal.
fn scatter_by_digit(src: &[u64], dst: &mut [u64], sh: u32, count: &mut [u32]) -> bool {
    let (Some(m), Some(&first)) = (count.len().checked_sub(1), src.first()) else {
        return false;
    };
    // All digits are equal when the first item's digit counts them all.
    if count[(first >> sh) as usize & m] as usize == src.len() {
        return false;
    }
    let mut pos = 0;
    for c in count.iter_mut() {
        (*c, pos) = (pos, pos + *c);
    }
    for &x in src {
        let c = &mut count[(x >> sh) as usize & m];
        dst[*c as usize] = x;
        *c += 1;
    }
    true
}

/// A material with owned texture references (a `Prepared` outlives the scene borrow only
/// through the images).
struct MatOwned<'a> {
    base: [f32; 4],
    tex: Option<(TexImage<'a>, TextureRef)>,
    alpha_tex: Option<(TexImage<'a>, TextureRef)>,
    alpha: AlphaMode,
}

impl MatOwned<'_> {
    fn view(&self) -> Mat<'_> {
        Mat {
            base: self.base,
            tex: self.tex.as_ref().map(|(i, t)| Tex::new(*i, t)),
            alpha_tex: self.alpha_tex.as_ref().map(|(i, t)| Tex::new(*i, t)),
            alpha: self.alpha,
        }
    }
}

/// A primitive ready for sampling: vertex positions in grid units of the unit's frame,
/// normals transformed and normalised (or computed per corner).
struct Prepared<'a> {
    prim: &'a Primitive,
    mat: MatOwned<'a>,
    pos: Vec<[f64; 3]>,
    nrm: Option<Vec<[f32; 3]>>,
    computed: Option<Vec<[[f32; 3]; 3]>>,
    /// `computed` through the bake, in the flipped winding when it mirrors: what [`Self::tri`]
    /// reads, done once rather than per (triangle, slab).
    baked: Option<Vec<[[f32; 3]; 3]>>,
    flip: bool,
}

impl<'a> Prepared<'a> {
    fn new(prim: &'a Primitive, u: &Unit, mat: MatOwned<'a>, crease_deg: f32) -> Self {
        let inv_h = 1.0 / u.h;
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
        let computed = if nrm.is_none() { Some(corner_normals(prim, crease_deg)) } else { None };
        let baked = computed.as_ref().map(|c| c.iter().map(|&c| bake_corner_normals(c, u.bake.as_ref(), flip)).collect());
        Prepared { prim, mat, pos, nrm, computed, baked, flip }
    }

    /// Triangle `ti` with its attributes.
    fn tri(&self, ti: usize) -> Tri {
        let prim = self.prim;
        let t = prim.triangles[ti];
        // A mirroring bake flips the winding; swap to keep the front side.
        let idx = if self.flip { [t[0], t[2], t[1]] } else { t };
        let vi = idx.map(|i| i as usize);
        let n = match (&self.nrm, &self.baked) {
            (Some(n), _) => vi.map(|i| n[i]),
            (None, Some(c)) => c.get(ti).copied().unwrap_or_default(),
            _ => [[0.0; 3]; 3],
        };
        let uvset = self.mat.tex.as_ref().and_then(|t| prim.uvs.get(t.1.tex_coord as usize));
        let uvset2 = self.mat.alpha_tex.as_ref().and_then(|t| prim.uvs.get(t.1.tex_coord as usize));
        Tri {
            p: vi.map(|i| self.pos[i]),
            n,
            c: vi.map(|i| prim.colors.as_ref().map_or([1.0; 4], |c| c[i])),
            uv: vi.map(|i| uvset.map_or([0.0; 2], |s| s[i])),
            uv2: vi.map(|i| uvset2.map_or([0.0; 2], |s| s[i])),
        }
    }
}

/// A triangle's computed corner normals as [`Prepared::tri`] gives them: in the winding of
/// `flip`, through `bake` and normalised.
fn bake_corner_normals(c: [[f32; 3]; 3], bake: Option<&Mat4>, flip: bool) -> [[f32; 3]; 3] {
    let cn = if flip { [c[0], c[2], c[1]] } else { c };
    match bake {
        Some(m) => cn.map(|n| {
            let w = transform_normal(m, n);
            let l = norm(w);
            if l > 0.0 { w.map(|x| (x / l) as f32) } else { [0.0; 3] }
        }),
        None => cn,
    }
}

/// Shades a point of a triangle given barycentric weights; `None` = dropped by alpha.
fn shade(t: &Tri, w: [f64; 3], mat: &Mat) -> (Option<[f32; 4]>, [f32; 3]) {
    let wf = w.map(|x| x as f32);
    let mix4 = |a: &[[f32; 4]; 3]| -> [f32; 4] { std::array::from_fn(|k| a[0][k] * wf[0] + a[1][k] * wf[1] + a[2][k] * wf[2]) };
    let mix2 = |a: &[[f32; 2]; 3]| -> [f32; 2] { std::array::from_fn(|k| a[0][k] * wf[0] + a[1][k] * wf[1] + a[2][k] * wf[2]) };
    let n = std::array::from_fn(|k| t.n[0][k] * wf[0] + t.n[1][k] * wf[1] + t.n[2][k] * wf[2]);
    (shade_color(mix4(&t.c), mix2(&t.uv), mix2(&t.uv2), mat), n)
}

/// The material colour for vertex colour `vc` and texture coordinates `uv` (colour texture),
/// `uv2` (alpha texture); `None` = dropped by alpha.
#[inline(always)]
fn shade_color(vc: [f32; 4], uv: [f32; 2], uv2: [f32; 2], mat: &Mat) -> Option<[f32; 4]> {
    let mut c: [f32; 4] = std::array::from_fn(|k| mat.base[k] * vc[k]);
    if let Some(t) = &mat.tex {
        let s = t.sample(uv);
        for k in 0..4 {
            c[k] *= s[k];
        }
    }
    if let Some(t) = &mat.alpha_tex {
        let s = t.sample(uv2);
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
    keep.then_some(c)
}

/// A triangle's attributes as affine functions of the projection-plane point (a, b): set up
/// once per triangle, so a sample costs a few multiply-adds instead of barycentric weights
/// (three divisions) and mixing. Channel planes are `[value at o, d/da, d/db]`. Colour and
/// normal that do not vary over the triangle are shaded once.
struct Planes<'m> {
    o: [f64; 2],
    n: [[f32; 3]; 3],
    c: [[f32; 3]; 4],
    uv: [[f32; 3]; 2],
    uv2: [[f32; 3]; 2],
    /// The colour when it is the same everywhere (no texture, equal vertex colours).
    flat_c: Option<Option<[f32; 4]>>,
    /// The unit normal when the corner normals are equal (and not zero).
    flat_n: Option<[f32; 3]>,
    /// Unit face normal, for interpolated normals of (near) zero length.
    face_n: [f32; 3],
    /// The vertex colour when the corners share it (a textured triangle's colour varies
    /// while this does not): used as it is, its planes being flat.
    vc: Option<[f32; 4]>,
    mat: &'m Mat<'m>,
}

impl<'m> Planes<'m> {
    fn new(t: &Tri, q: &[[f64; 2]; 3], fnrm: [f64; 3], mat: &'m Mat<'m>) -> Self {
        let det = (q[1][0] - q[0][0]) * (q[2][1] - q[0][1]) - (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]);
        // Gradients of the barycentric weights w1, w2 (w0 = 1 − w1 − w2); a triangle that
        // projects to a line gets the mean of its corners everywhere.
        let (w1, w2) = if det != 0.0 {
            let inv = 1.0 / det;
            ([(q[2][1] - q[0][1]) * inv, -(q[2][0] - q[0][0]) * inv], [-(q[1][1] - q[0][1]) * inv, (q[1][0] - q[0][0]) * inv])
        } else {
            ([0.0; 2], [0.0; 2])
        };
        let plane = |v: [f32; 3]| -> [f32; 3] {
            let v = v.map(f64::from);
            if det == 0.0 {
                return [((v[0] + v[1] + v[2]) / 3.0) as f32, 0.0, 0.0];
            }
            let (d1, d2) = (v[1] - v[0], v[2] - v[0]);
            [v[0] as f32, (d1 * w1[0] + d2 * w2[0]) as f32, (d1 * w1[1] + d2 * w2[1]) as f32]
        };
        let fl = norm(fnrm);
        let face_n = fnrm.map(|x| (x / fl) as f32);
        let flat_n = (t.n[0] == t.n[1] && t.n[0] == t.n[2]).then(|| unit_or(t.n[0], face_n));
        let flat_c = (mat.tex.is_none() && mat.alpha_tex.is_none() && t.c[0] == t.c[1] && t.c[0] == t.c[2])
            .then(|| shade_color(t.c[0], [0.0; 2], [0.0; 2], mat));
        // Only the varying attributes need planes.
        let varies = flat_c.is_none();
        Planes {
            o: q[0],
            n: if flat_n.is_none() { std::array::from_fn(|k| plane(t.n.map(|n| n[k]))) } else { [[0.0; 3]; 3] },
            c: if varies { std::array::from_fn(|k| plane(t.c.map(|c| c[k]))) } else { [[0.0; 3]; 4] },
            uv: if varies && mat.tex.is_some() { std::array::from_fn(|k| plane(t.uv.map(|c| c[k]))) } else { [[0.0; 3]; 2] },
            uv2: if varies && mat.alpha_tex.is_some() { std::array::from_fn(|k| plane(t.uv2.map(|c| c[k]))) } else { [[0.0; 3]; 2] },
            flat_c,
            flat_n,
            face_n,
            vc: (t.c[0] == t.c[1] && t.c[0] == t.c[2]).then_some(t.c[0]),
            mat,
        }
    }

    /// (colour or `None` = dropped by alpha, unit normal) at projection-plane point `p`.
    #[inline(always)]
    fn shade(&self, p: [f64; 2]) -> (Option<[f32; 4]>, [f32; 3]) {
        let (da, db) = ((p[0] - self.o[0]) as f32, (p[1] - self.o[1]) as f32);
        let at = |pl: &[f32; 3]| pl[0] + pl[1] * da + pl[2] * db;
        let c = match self.flat_c {
            Some(c) => c,
            None => {
                // Only the channels the material reads; the values are the same.
                let vc = self.vc.unwrap_or_else(|| self.c.each_ref().map(at));
                let uv = if self.mat.tex.is_some() { self.uv.each_ref().map(at) } else { [0.0; 2] };
                let uv2 = if self.mat.alpha_tex.is_some() { self.uv2.each_ref().map(at) } else { [0.0; 2] };
                shade_color(vc, uv, uv2, self.mat)
            }
        };
        let n = match self.flat_n {
            Some(n) => n,
            None => unit_or(self.n.each_ref().map(at), self.face_n),
        };
        (c, n)
    }
}

/// `n` scaled to unit length, or `fallback` when it is (nearly) zero.
#[inline]
fn unit_or(n: [f32; 3], fallback: [f32; 3]) -> [f32; 3] {
    let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if l > 1e-12 {
        let inv = 1.0 / l;
        n.map(|x| x * inv)
    } else {
        fallback
    }
}

fn face_axes(t: &Tri) -> ([f64; 3], usize, usize, usize) {
    let fnrm = cross(sub(t.p[1], t.p[0]), sub(t.p[2], t.p[0]));
    let ax = fnrm.map(f64::abs);
    let d = if ax[0] >= ax[1] && ax[0] >= ax[2] { 0 } else if ax[1] >= ax[2] { 1 } else { 2 };
    (fnrm, d, (d + 1) % 3, (d + 2) % 3)
}


/// Emits the samples of one triangle of [`voxel_triangle_axis`] (depth axis `D`): a struct
/// rather than a closure so that its always-inlined call sites need no argument passing.
struct Emitter<'p, 'm, const D: usize> {
    planes: &'p Planes<'m>,
    kp: &'p KeyPack,
    keep: (i64, i64),
    ascale: f64,
    dropped: u64,
    skipped: u64,
}

impl<const D: usize> Emitter<'_, '_, D> {
    /// The piece of projected area `area2` and centroid `cen` in voxel (ia, ib, k) along axes
    /// (D + 1, D + 2, D).
    #[inline(always)]
    fn emit(&mut self, out: &mut Vec<Rec>, ia: i64, ib: i64, k: i64, area2: f64, cen: [f64; 2]) {
        let mut key = [0i64; 3];
        key[(D + 1) % 3] = ia;
        key[(D + 2) % 3] = ib;
        key[D] = k;
        if self.keep != ALL_X && !(self.keep.0..=self.keep.1).contains(&key[0].clamp(self.kp.lo[0], self.kp.hi[0])) {
            self.skipped += 1;
            return;
        }
        match self.planes.shade(cen) {
            (Some(color), normal) => out.push(Rec { key: self.kp.pack(key), area: (area2 * self.ascale) as f32, normal, color }),
            (None, _) => self.dropped += 1,
        }
    }
}

/// Conservative voxelization of one triangle; returns the number of alpha-dropped samples.
///
/// Works in the projection plane (axes a, b; depth d is a linear function of them): the
/// triangle is clipped to each grid strip, then to each column of the strip, and the depth
/// range of the piece gives the voxels it crosses. Columns entirely inside the triangle —
/// most of them for triangles larger than a voxel — skip clipping: their piece is the unit
/// square. Only pieces crossing a depth boundary are split by depth lines.
///
/// Only voxels whose x index lies in `xr` (inclusive) are emitted (the caller's slab), and
/// the triangle is cut to that band first. `keep` restricts output the same way without the
/// cut: voxels outside it (x index clamped to the key range) are counted, not shaded or
/// emitted, so EQ 17 areas still divide by the whole triangle's count.
#[allow(clippy::too_many_arguments)]
fn voxel_triangle(t: &Tri, mat: &Mat, area_mode: AreaMode, kp: &KeyPack, xr: (i64, i64), keep: (i64, i64), out: &mut Vec<Rec>) -> u64 {
    let (fnrm, d, _, _) = face_axes(t);
    // One copy per depth axis: the axis indices become constants (key assembly, the slab
    // tests), the arithmetic is the same.
    match d {
        0 => voxel_triangle_axis::<0>(t, fnrm, mat, area_mode, kp, xr, keep, out),
        1 => voxel_triangle_axis::<1>(t, fnrm, mat, area_mode, kp, xr, keep, out),
        _ => voxel_triangle_axis::<2>(t, fnrm, mat, area_mode, kp, xr, keep, out),
    }
}

/// [`voxel_triangle`] with depth axis `D` (`fnrm` = the face normal of [`face_axes`]).
#[allow(clippy::too_many_arguments)]
fn voxel_triangle_axis<const D: usize>(
    t: &Tri,
    fnrm: [f64; 3],
    mat: &Mat,
    area_mode: AreaMode,
    kp: &KeyPack,
    xr: (i64, i64),
    keep: (i64, i64),
    out: &mut Vec<Rec>,
) -> u64 {
    let (d, a, b) = (D, (D + 1) % 3, (D + 2) % 3);
    let tri_area_grid = 0.5 * norm(fnrm);
    // Projected area → surface area; depth = d0 + ga·x + gb·y.
    let ascale = norm(fnrm) / fnrm[d].abs();
    let (ga, gb) = (-fnrm[a] / fnrm[d], -fnrm[b] / fnrm[d]);
    let d0 = t.p[0][d] - ga * t.p[0][a] - gb * t.p[0][b];
    let depth = |p: &[f64; 2]| d0 + ga * p[0] + gb * p[1];
    let q = t.p.map(|p| [p[a], p[b]]);
    // Edge functions e(x, y) = A x + B y + C ≥ 0 inside (orientation fixed by the sign).
    let orient = if (q[1][0] - q[0][0]) * (q[2][1] - q[0][1]) - (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]) >= 0.0 { 1.0 } else { -1.0 };
    let edges: [[f64; 3]; 3] = std::array::from_fn(|i| {
        let (p0, p1) = (q[i], q[(i + 1) % 3]);
        let (ea, eb) = (-(p1[1] - p0[1]) * orient, (p1[0] - p0[0]) * orient);
        [ea, eb, -(ea * p0[0] + eb * p0[1])]
    });
    // Attributes at a piece's centroid (inside the triangle up to rounding, so the planes
    // need no clamping).
    let planes = Planes::new(t, &q, fnrm, mat);
    let start = out.len();
    let mut em = Emitter::<D> { planes: &planes, kp, keep, ascale, dropped: 0, skipped: 0 };
    let mut tri = Poly2 { v: [[0.0; 2]; MAXV], n: 3 };
    tri.v[..3].copy_from_slice(&q);
    let (txlo, txhi) = t.p.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), p| (l.min(p[0]), h.max(p[0])));
    if floor_i64(txlo) < xr.0 || floor_i64(txhi) > xr.1 {
        // Only part of the triangle lies in the caller's slab: cut it to the slab's x band
        // first, so strips and columns outside it cost nothing. The band's faces are voxel
        // faces, so pieces and areas are unchanged.
        let (x0, x1) = (xr.0 as f64, xr.1 as f64 + 1.0);
        tri = match (a, b) {
            (0, _) => tri.clip_axis(0, x0, x1),
            (_, 0) => tri.clip_axis(1, x0, x1),
            _ => tri.clip_half(|p| depth(p) - x0, None).clip_half(|p| x1 - depth(p), None),
        };
        if tri.n < 3 {
            return 0;
        }
    }
    let (alo, ahi) = tri.range(|p| p[0]);
    let mut lo_a = floor_i64(alo);
    let mut hi_a = floor_i64(ahi);
    if a == 0 {
        (lo_a, hi_a) = (lo_a.max(xr.0), hi_a.min(xr.1));
    }
    let half = 0.5 * (ga.abs() + gb.abs());
    const EPS: f64 = 1e-9;
    // The triangle is swept: each strip is split off the rest of the triangle (one pass, the
    // cut shared by both sides), each boundary column off the rest of its strip. Reused
    // buffers: the rest of the triangle and of the strip (ping-pong pairs), the strip, the
    // column piece, the lower depth part and a clip temporary.
    let mut rest = [tri, Poly2::empty()];
    let mut r = 0;
    let (mut col, mut lower, mut tmp) = (Poly2::empty(), Poly2::empty(), Poly2::empty());
    // The strip is split off into `srest[0]`, where the rest of the strip starts.
    let mut srest = [Poly2::empty(), Poly2::empty()];
    for ia in lo_a..=hi_a {
        let (x0, x1) = (ia as f64, ia as f64 + 1.0);
        if x1 >= ahi {
            // The rest lies below x1: it is the strip (the split would copy it).
            srest[0] = rest[r]; // a copy: a third of a swap's moves
            rest[r].n = 0;
        } else {
            let (src, dst) = ping(&mut rest, r);
            src.split_axis_into::<0>(x1, &mut srest[0], dst);
            r ^= 1;
        }
        let strip = &srest[0];
        if strip.n < 3 {
            continue;
        }
        let (bmin, bmax) = strip.range(|p| p[1]);
        // Columns [ib, ib+1] of this strip lying inside every edge's half-plane.
        let (mut in_lo, mut in_hi) = (f64::NEG_INFINITY, f64::INFINITY);
        for e in &edges {
            let amin = (e[0] * x0).min(e[0] * x1) + e[2];
            if e[1] > 0.0 {
                in_lo = in_lo.max(-amin / e[1]);
            } else if e[1] < 0.0 {
                in_hi = in_hi.min(-amin / e[1]);
            } else if amin < 0.0 {
                in_hi = f64::NEG_INFINITY;
            }
        }
        let first_in = (in_lo + EPS).ceil();
        let last_in = (in_hi - EPS).floor() - 1.0; // last ib with ib + 1 ≤ in_hi
        let (mut blo, mut bhi) = (floor_i64(bmin), floor_i64(bmax));
        if b == 0 {
            (blo, bhi) = (blo.max(xr.0), bhi.min(xr.1));
        }
        // The rest of the strip lies above `cut` (interior columns are skipped, not split off).
        let (mut sr, mut cut) = (0, blo as f64);
        // Depths of the current piece's vertices.
        let mut dv = [0.0; MAXV];
        for ib in blo..=bhi {
            let y = ib as f64;
            let interior = y >= first_in && y <= last_in;
            let (area2, cen, dmin, dmax) = if interior {
                let cen = [x0 + 0.5, y + 0.5];
                let dc = depth(&cen);
                (1.0, cen, dc - half, dc + half)
            } else {
                if y > cut {
                    let (src, dst) = ping(&mut srest, sr);
                    src.clip_half_into(|p| p[1] - y, Some((1, y)), dst);
                    sr ^= 1;
                }
                if y + 1.0 >= bmax {
                    col = srest[sr];
                    srest[sr].n = 0;
                } else {
                    let (src, dst) = ping(&mut srest, sr);
                    src.split_axis_into::<1>(y + 1.0, &mut col, dst);
                    sr ^= 1;
                }
                cut = y + 1.0;
                if col.n < 3 {
                    continue;
                }
                let (ar, cen) = col.area_centroid();
                let (dmin, dmax) = col.range_keeping(depth, &mut dv);
                (ar, cen, dmin, dmax)
            };
            let kmin = floor_i64(dmin);
            let mut kmax = floor_i64(dmax);
            if kmax > kmin && dmax == kmax as f64 {
                kmax -= 1; // touches the next voxel's face only
            }
            if kmin == kmax {
                if d != 0 || (xr.0..=xr.1).contains(&kmin) {
                    em.emit(out, ia, ib, kmin, area2, cen);
                }
                continue;
            }
            if interior {
                col.set_square(x0, y);
            }
            let poly = &col;
            if kmax == kmin + 1 {
                // One depth face crosses the piece (the common steep case): one clip gives the
                // lower part; the upper part is the remainder (area and centroid by
                // difference), so the two areas still add up to the piece's exactly.
                let kf = kmax as f64;
                if interior {
                    for (v, p) in dv.iter_mut().zip(&poly.v[..poly.n]) {
                        *v = depth(p);
                    }
                }
                // The piece's vertex depths were computed once (by range_keeping or above).
                poly.clip_half_by_index_into(|i, _| kf - dv[i], None, &mut lower);
                let (al, cl) = if lower.n >= 3 { lower.area_centroid() } else { (0.0, cen) };
                let au = area2 - al;
                let cu = if au > 0.0 { [(area2 * cen[0] - al * cl[0]) / au, (area2 * cen[1] - al * cl[1]) / au] } else { cen };
                let keep = |k: i64| d != 0 || (xr.0..=xr.1).contains(&k);
                if al > 0.0 && keep(kmin) {
                    em.emit(out, ia, ib, kmin, al, cl);
                }
                if au > 0.0 && keep(kmax) {
                    em.emit(out, ia, ib, kmax, au, cu);
                }
                continue;
            }
            let (kmin, kmax) = if d == 0 { (kmin.max(xr.0), kmax.min(xr.1)) } else { (kmin, kmax) };
            for k in kmin..=kmax {
                let kf = k as f64;
                poly.clip_half_into(|p| depth(p) - kf, None, &mut tmp);
                tmp.clip_half_into(|p| kf + 1.0 - depth(p), None, &mut lower);
                let sub = &lower;
                if sub.n < 3 {
                    continue;
                }
                let (ar, cen) = sub.area_centroid();
                if ar > 0.0 {
                    em.emit(out, ia, ib, k, ar, cen);
                }
            }
        }
    }
    let (dropped, skipped) = (em.dropped, em.skipped);
    let made = out.len() - start;
    if area_mode == AreaMode::Eq17 && made > 0 {
        let each = (tri_area_grid / (made as u64 + dropped + skipped) as f64) as f32;
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
    let uvset = mat.tex.and_then(|t| prim.uvs.get(t.tr.tex_coord as usize));
    let uvset2 = mat.alpha_tex.and_then(|t| prim.uvs.get(t.tr.tex_coord as usize));
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

fn srgb8(c: [f32; 4]) -> [u8; 4] {
    let a = (c[3].clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
    let t = Srgb8::get();
    [t.encode(c[0]), t.encode(c[1]), t.encode(c[2]), a]
}

/// Samples a point cloud: one sample per point, radius = mean distance to its 4 nearest
/// neighbours (so neighbouring spheres overlap), area = that distance squared (the area of
/// a point's cell in a regular sampling of that spacing).
pub fn sample_points(pc: &PointCloud) -> Vec<Node> {
    let mut out = Vec::with_capacity(pc.positions.len());
    let Ok(()) = sample_points_into(pc, &mut |nodes| {
        out.extend_from_slice(nodes);
        Ok::<(), Never>(())
    });
    out
}

/// Samples handed to a sink at a time by [`sample_points_into`].
const POINT_RUN: usize = 1 << 16;

/// [`sample_points`] handing the samples to `sink` in runs, in point order; a sink error
/// stops it and is returned.
pub fn sample_points_into<E>(pc: &PointCloud, sink: &mut Sink<'_, E>) -> Result<(), E> {
    let n = pc.positions.len();
    if n == 0 {
        return Ok(());
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
    let node = |i: usize| {
        let d = dist[i];
        let normal = pc.normals.as_ref().map_or([0.0, 0.0, 1.0], |ns| {
            let v = ns[i].map(f64::from);
            let l = norm(v);
            if l > 0.0 && l.is_finite() { v.map(|x| (x / l) as f32) } else { [0.0, 0.0, 1.0] }
        });
        let c = pc.colors.as_ref().map_or([0.8, 0.8, 0.8, 1.0], |c| c[i]);
        Node { center: pc.positions[i], radius: d as f32, normal, cone: 0.0, area: (d * d) as f32, color: srgb8(c) }
    };
    let mut run = Vec::with_capacity(n.min(POINT_RUN));
    for start in (0..n).step_by(POINT_RUN) {
        run.clear();
        run.extend((start..n.min(start + POINT_RUN)).map(node));
        sink(&run)?;
    }
    Ok(())
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_budget_voxel_inverts_the_estimate() {
        let e = SampleEstimate { area: 2.0, perimeter: 30.0, per_triangle: 1000.0, merged_area: 3.0 };
        for budget in [2e3, 1e5, 3.7e7] {
            let h = e.voxel_for(budget, false).unwrap();
            assert!((e.at(h) - budget).abs() <= 1e-9 * budget, "{budget}: {}", e.at(h));
            let h = e.voxel_for(budget, true).unwrap();
            assert!((e.merged_area / (h * h) - budget).abs() <= 1e-9 * budget);
        }
        // Unmerged, every triangle keeps a sample: no voxel size gets below that.
        assert_eq!(e.voxel_for(1000.0, false), None);
        assert_eq!(SampleEstimate::default().voxel_for(10.0, true), None);
    }

    #[test]
    fn key_pack_round_trips_and_orders_x_major() {
        let kp = KeyPack::new([-5.5, 0.0, 1000.2], [300.0, 2.0, 1001.0]).unwrap();
        let pts = [[-6, 0, 999], [-6, 3, 1002], [0, 1, 1000], [301, -1, 1002], [17, 2, 1001]];
        for p in pts {
            assert_eq!(kp.unpack(kp.pack(p)), p);
        }
        let mut by_key = pts.to_vec();
        by_key.sort_by_key(|p| kp.pack(*p));
        let mut lex = pts.to_vec();
        lex.sort();
        assert_eq!(by_key, lex);
        // Out-of-range coordinates clamp instead of spilling into another field.
        assert_eq!(kp.unpack(kp.pack([i64::MAX, 0, 1000])), [301, 0, 1000]);
        assert_eq!(kp.unpack(kp.pack([i64::MIN, 9, i64::MIN])), [-7, 3, 999]);
        assert!(KeyPack::new([0.0; 3], [3e6; 3]).is_err(), "3 × 22 bits do not fit");
        assert!(KeyPack::new([-1e300; 3], [1e300; 3]).is_err(), "saturates, then refuses");
    }

    /// Lookups in the pre-decoded linear table equal `Image::sample` bit for bit, inside,
    /// outside (every wrap mode), at texel centres and edges, and for non-finite UVs.
    #[test]
    fn decoded_texture_lookup_matches_image_sample() {
        let mut rng = sct_format::rng::SplitMix64(11);
        let (w, h) = (7u32, 5u32);
        let rgba: Vec<[u8; 4]> = (0..w * h).map(|_| std::array::from_fn(|_| (rng.next_u64() >> 56) as u8)).collect();
        let img = Image { width: w, height: h, rgba, source: "test".into() };
        let scene = LoadedScene {
            images: vec![img],
            materials: vec![Material { texture: Some(TextureRef { image: 0, tex_coord: 0, transform: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], wrap_s: Wrap::Repeat, wrap_t: Wrap::Repeat }), ..Default::default() }],
            ..Default::default()
        };
        let linear = decode_textures(&scene);
        let img = &scene.images[0];
        let tex = TexImage { img, linear: linear[0].as_deref() };
        assert!(tex.linear.is_some());
        let mut uvs: Vec<[f32; 2]> = (0..20_000).map(|_| [(rng.next_f64() * 6.0 - 3.0) as f32, (rng.next_f64() * 6.0 - 3.0) as f32]).collect();
        for i in -8..=16 {
            let (cx, cy) = ((i as f32 + 0.5) / w as f32, i as f32 / h as f32);
            uvs.extend([[cx, cy], [cy, cx], [cx.next_up(), cy.next_down()]]);
        }
        uvs.extend([[f32::NAN, 0.3], [0.2, f32::INFINITY], [1e30, -1e30], [-0.0, 1.0]]);
        for ws in [Wrap::Repeat, Wrap::MirroredRepeat, Wrap::ClampToEdge] {
            for wt in [Wrap::Repeat, Wrap::MirroredRepeat, Wrap::ClampToEdge] {
                for &uv in &uvs {
                    let (got, want) = (tex.sample(uv, ws, wt), img.sample(uv, ws, wt));
                    assert_eq!(got.map(f32::to_bits), want.map(f32::to_bits), "uv {uv:?} {ws:?} {wt:?}");
                }
            }
        }
    }

    /// The material lookups (fast interior path, then the general one) equal `Image::sample`
    /// of the transformed coordinates bit for bit: random coordinates inside and outside
    /// [0, 1], near 0 and 1, at texel centres and block edges, ±0 and non-finite ones, every
    /// wrap mode, with the identity and other transforms; most inside lookups take the fast
    /// path.
    #[test]
    fn material_texture_lookup_matches_image_sample() {
        let mut rng = sct_format::rng::SplitMix64(29);
        let (w, h) = (9u32, 6u32);
        let rgba: Vec<[u8; 4]> = (0..w * h).map(|_| std::array::from_fn(|_| (rng.next_u64() >> 56) as u8)).collect();
        let img = Image { width: w, height: h, rgba, source: "test".into() };
        let plain = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let scene = LoadedScene {
            images: vec![img],
            materials: vec![Material { texture: Some(TextureRef { image: 0, tex_coord: 0, transform: plain, wrap_s: Wrap::Repeat, wrap_t: Wrap::Repeat }), ..Default::default() }],
            ..Default::default()
        };
        let linear = decode_textures(&scene);
        let img = &scene.images[0];
        let tex_img = TexImage { img, linear: linear[0].as_deref() };
        let mut uvs: Vec<[f32; 2]> = (0..4000).map(|_| [(rng.next_f64() * 3.0 - 1.0) as f32, (rng.next_f64() * 3.0 - 1.0) as f32]).collect();
        uvs.extend((0..4000).map(|_| [rng.next_f64() as f32, rng.next_f64() as f32]));
        for i in -2..=20 {
            // Texel centres, block edges (half-integer texel coordinates) and their neighbours.
            for f in [i as f32 / 2.0 / w as f32, (i as f32 + 0.5) / w as f32] {
                let g = f * w as f32 / h as f32;
                uvs.extend([[f, g], [g, f], [f.next_up(), g.next_down()], [f.next_down(), g.next_up()]]);
            }
        }
        for e in [0.0f32, 1.0] {
            uvs.extend([[e, 0.5], [0.5, e], [e.next_up(), e.next_down()], [e.next_down(), 0.3], [0.7, e.next_up()]]);
        }
        uvs.extend([[-0.0, 0.5], [0.5, -0.0], [f32::NAN, 0.3], [0.2, f32::INFINITY], [f32::NEG_INFINITY, 0.5], [1e30, -1e30]]);
        let transforms = [plain, [[0.5, 0.0, 0.25], [0.0, 0.5, 0.25]], [[0.0, 1.0, 0.0], [-1.0, 0.0, 1.0]], [[2.0, 0.3, -0.5], [0.1, 1.5, 0.2]]];
        let mut fast = 0;
        for transform in transforms {
            for wrap_s in [Wrap::Repeat, Wrap::MirroredRepeat, Wrap::ClampToEdge] {
                for wrap_t in [Wrap::Repeat, Wrap::MirroredRepeat, Wrap::ClampToEdge] {
                    let tr = TextureRef { image: 0, tex_coord: 0, transform, wrap_s, wrap_t };
                    let tex = Tex::new(tex_img, &tr);
                    assert_eq!(tex.plain, transform == plain);
                    for &uv in &uvs {
                        let want = img.sample(tr.transform_uv(uv), wrap_s, wrap_t);
                        assert_eq!(tex.sample(uv).map(f32::to_bits), want.map(f32::to_bits), "uv {uv:?} {transform:?} {wrap_s:?} {wrap_t:?}");
                        fast += usize::from(tex.interior(tr.transform_uv(uv)).is_some());
                    }
                }
            }
        }
        assert!(fast * 4 > uvs.len() * 9 * transforms.len(), "{fast} fast lookups");
    }

    /// [`Planes::shade`]'s shortcuts (a vertex colour shared by the corners used as it is,
    /// unread texture coordinates skipped) give the colours of evaluating every plane, for
    /// textured (identity and other transforms, alpha textures) and untextured materials,
    /// every alpha mode, shared and varying vertex colours.
    #[test]
    fn planes_shortcuts_match_full_evaluation() {
        let mut rng = sct_format::rng::SplitMix64(31);
        let (w, h) = (5u32, 4u32);
        let rgba: Vec<[u8; 4]> = (0..w * h).map(|_| std::array::from_fn(|_| (rng.next_u64() >> 56) as u8)).collect();
        let tr = |transform| TextureRef { image: 0, tex_coord: 0, transform, wrap_s: Wrap::Repeat, wrap_t: Wrap::MirroredRepeat };
        let trs = [tr([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), tr([[0.7, 0.2, 0.1], [-0.3, 1.1, 0.05]])];
        let scene = LoadedScene {
            images: vec![Image { width: w, height: h, rgba, source: "test".into() }],
            materials: vec![Material { texture: Some(trs[0].clone()), ..Default::default() }],
            ..Default::default()
        };
        let linear = decode_textures(&scene);
        let tex_img = TexImage { img: &scene.images[0], linear: linear[0].as_deref() };
        let mut shared_vc = 0;
        for i in 0..3000 {
            let mat = Mat {
                base: [0.9, 0.8, 0.7, 0.6],
                tex: (i % 3 != 0).then(|| Tex::new(tex_img, &trs[i % 2])),
                alpha_tex: (i % 4 == 1).then(|| Tex::new(tex_img, &trs[1])),
                alpha: [AlphaMode::Opaque, AlphaMode::Mask(0.4), AlphaMode::Blend][i % 3],
            };
            let mut f = || rng.next_f64() as f32;
            let c0 = [f(), f(), f(), f()];
            let c = if i % 2 == 0 { [c0; 3] } else { [c0, [f(), f(), f(), f()], [f(), f(), f(), f()]] };
            let uv: [[f32; 2]; 3] = std::array::from_fn(|_| [f() * 2.0 - 0.5, f() * 2.0 - 0.5]);
            let uv2: [[f32; 2]; 3] = std::array::from_fn(|_| [f(), f()]);
            let n: [[f32; 3]; 3] = std::array::from_fn(|_| [f() - 0.5, f() - 0.5, f() - 0.5]);
            let p: [[f64; 3]; 3] = std::array::from_fn(|_| std::array::from_fn(|_| rng.next_f64() * 20.0));
            let t = Tri { p, n, c, uv, uv2 };
            let (fnrm, _, a, b) = face_axes(&t);
            let q = t.p.map(|p| [p[a], p[b]]);
            let planes = Planes::new(&t, &q, fnrm, &mat);
            shared_vc += usize::from(planes.flat_c.is_none() && planes.vc.is_some());
            for _ in 0..10 {
                let pt = [q[0][0] + (rng.next_f64() - 0.3) * 8.0, q[0][1] + (rng.next_f64() - 0.3) * 8.0];
                let (da, db) = ((pt[0] - planes.o[0]) as f32, (pt[1] - planes.o[1]) as f32);
                let at = |pl: &[f32; 3]| pl[0] + pl[1] * da + pl[2] * db;
                let want = planes.flat_c.unwrap_or_else(|| shade_color(planes.c.each_ref().map(at), planes.uv.each_ref().map(at), planes.uv2.each_ref().map(at), &mat));
                let got = planes.shade(pt).0;
                assert_eq!(got.map(|c| c.map(f32::to_bits)), want.map(|c| c.map(f32::to_bits)), "{t:?}", t = (i, pt));
            }
        }
        assert!(shared_vc > 500, "{shared_vc}");
    }

    /// An n × n grid of unit size, bumped in z (2 n² triangles).
    fn bumpy_sheet(n: u32) -> Primitive {
        let mut positions = Vec::new();
        for y in 0..=n {
            for x in 0..=n {
                let (fx, fy) = (x as f32 / n as f32, y as f32 / n as f32);
                positions.push([fx, fy, 0.15 * (7.0 * fx).sin() * (5.0 * fy).cos()]);
            }
        }
        let mut triangles = Vec::new();
        for y in 0..n {
            for x in 0..n {
                let i = y * (n + 1) + x;
                triangles.push([i, i + 1, i + n + 2]);
                triangles.push([i, i + n + 2, i + n + 1]);
            }
        }
        Primitive { positions, triangles, ..Default::default() }
    }

    /// Two meshes: a sheet placed by a similarity and two affine maps (sampled once in its
    /// frame), and a smaller sheet baked into world space.
    fn instanced_scene() -> LoadedScene {
        let scale = |s: [f64; 3], t: [f64; 3]| -> Mat4 { [[s[0], 0.0, 0.0, 0.0], [0.0, s[1], 0.0, 0.0], [0.0, 0.0, s[2], 0.0], [t[0], t[1], t[2], 1.0]] };
        LoadedScene {
            meshes: vec![
                Mesh { name: "sheet".into(), primitives: vec![bumpy_sheet(40)] },
                Mesh { name: "small".into(), primitives: vec![bumpy_sheet(8), bumpy_sheet(5)] },
            ],
            instances: vec![
                Instance { mesh: 0, transform: scale([1.5; 3], [0.0; 3]) },
                Instance { mesh: 0, transform: scale([1.0, 2.0, 0.5], [3.0, 0.0, 0.0]) },
                Instance { mesh: 0, transform: scale([0.7, 1.0, 1.3], [0.0, 3.0, 0.0]) },
                Instance { mesh: 1, transform: scale([0.5; 3], [-1.0, 0.0, 0.0]) },
            ],
            materials: vec![Material { base_color: [0.8, 0.5, 0.2, 1.0], ..Default::default() }],
            ..Default::default()
        }
    }

    /// The sink gets each mesh's samples in runs (many slabs, several batches), mesh after
    /// mesh, in the order and with the counters of the collected result, and the areas summed
    /// run by run equal, bit for bit, the sums over whole meshes (instances applied).
    #[test]
    fn sink_runs_equal_the_collected_result() {
        SLAB_TARGET.store(300, std::sync::atomic::Ordering::Relaxed);
        let scene = instanced_scene();
        for method in [Method::Voxel, Method::Scanline, Method::Vertex] {
            let opts = SampleOptions { method, density: Density::VoxelSize(0.004), ..Default::default() };
            let collected = sample_scene(&scene, &opts, &|_, _| {}).expect("samples");
            let mut runs: Vec<(usize, Vec<Node>)> = Vec::new();
            let streamed = sample_scene_into(&scene, &opts, &|_, _| {}, &mut |mesh, nodes| {
                runs.push((mesh, nodes.to_vec()));
                Ok::<(), Never>(())
            })
            .expect("samples");
            assert!(runs.windows(2).all(|w| w[0].0 <= w[1].0), "{method:?}: meshes interleaved");
            assert_eq!(streamed.meshes.len(), 2);
            assert_eq!(streamed.stats, collected.stats, "{method:?}");
            if method != Method::Vertex {
                assert!(runs.len() > 8 * rayon::current_num_threads(), "{method:?}: {} runs, not several batches", runs.len());
            }
            for (mi, (m, c)) in streamed.meshes.iter().zip(&collected.meshes).enumerate() {
                let got: Vec<Node> = runs.iter().filter(|r| r.0 == mi).flat_map(|r| r.1.iter().copied()).collect();
                assert_eq!((m.count, &m.name, &m.instances, &m.affine), (c.samples.len() as u64, &c.name, &c.instances, &c.affine));
                let bits = |n: &Node| (n.center.map(f32::to_bits), n.radius.to_bits(), n.normal.map(f32::to_bits), n.area.to_bits(), n.color);
                assert!(got.iter().map(bits).eq(c.samples.iter().map(bits)), "{method:?}: mesh {mi} differs");
            }
            assert_eq!(collected.meshes[0].affine.len(), 2);
            // The whole-mesh sums the tally replaces (same order of additions).
            let mut want = 0.0f64;
            for m in &collected.meshes {
                let area: f64 = m.samples.iter().map(|n| f64::from(n.area)).sum();
                want += m.instances.iter().map(|s| area * s.scale * s.scale).sum::<f64>();
                for mat in &m.affine {
                    let a = sct_format::samples::AffineInstance { mesh: 0, matrix: *mat };
                    let st = a.max_stretch();
                    want += m.samples.iter().map(|n| f64::from(a.transform_node(n, st).area)).sum::<f64>();
                }
            }
            assert_eq!(streamed.stats.sample_area.to_bits(), want.to_bits(), "{method:?}");
            let rel = (want - scene.world_area()) / scene.world_area();
            assert!(rel.abs() < 0.02, "{method:?}: area error {rel:e}");
        }
    }

    /// A sink error stops sampling at once (no further runs) and comes back as the error.
    #[test]
    fn sink_error_stops_sampling() {
        SLAB_TARGET.store(300, std::sync::atomic::Ordering::Relaxed);
        let scene = instanced_scene();
        for method in [Method::Voxel, Method::Vertex] {
            let opts = SampleOptions { method, density: Density::VoxelSize(0.004), ..Default::default() };
            let mut calls = 0;
            let r = sample_scene_into(&scene, &opts, &|_, _| {}, &mut |_, _| {
                calls += 1;
                if calls == 2 { Err("disk full") } else { Ok(()) }
            });
            assert!(matches!(r, Err(StreamError::Sink("disk full"))), "{method:?}: {r:?}");
            assert_eq!(calls, 2, "{method:?}");
        }
        // A sampling error is told apart from a sink error.
        let opts = SampleOptions { density: Density::VoxelSize(1e-9), ..Default::default() };
        let r = sample_scene_into(&scene, &opts, &|_, _| {}, &mut |_, _| Ok::<(), Never>(()));
        assert!(matches!(r, Err(StreamError::Sampling(_))));
    }

    /// Point samples reach the sink in runs of [`POINT_RUN`], in point order; a sink error
    /// stops them.
    #[test]
    fn point_runs_equal_the_collected_samples() {
        let mut rng = sct_format::rng::SplitMix64(21);
        let n = POINT_RUN + 1000;
        let positions: Vec<[f32; 3]> = (0..n).map(|_| [rng.next_f64() as f32, rng.next_f64() as f32, 0.0]).collect();
        let pc = PointCloud { positions, normals: None, colors: None };
        let all = sample_points(&pc);
        let mut runs = Vec::new();
        sample_points_into(&pc, &mut |nodes| {
            runs.push(nodes.to_vec());
            Ok::<(), Never>(())
        })
        .expect("infallible");
        assert_eq!(runs.iter().map(Vec::len).collect::<Vec<_>>(), [POINT_RUN, 1000]);
        let bits = |n: &Node| (n.center.map(f32::to_bits), n.radius.to_bits(), n.area.to_bits(), n.color);
        assert!(runs.concat().iter().map(bits).eq(all.iter().map(bits)));
        let mut calls = 0;
        assert_eq!(
            sample_points_into(&pc, &mut |_| {
                calls += 1;
                Err(7)
            }),
            Err(7)
        );
        assert_eq!(calls, 1);
    }

    /// A bumpy sheet over many slabs (small slab target: dozens of slabs, several batches):
    /// 1 and 2 threads give the same samples for every method; progress counts each triangle
    /// once; EQ 17 and scan-line areas still divide each triangle's area by its whole sample
    /// count (they sum to the mesh area) although multi-slab triangles are shaded per slab.
    #[test]
    fn slabs_batches_progress_and_per_triangle_areas() {
        SLAB_TARGET.store(300, std::sync::atomic::Ordering::Relaxed);
        let prim = bumpy_sheet(40);
        let ntris = prim.triangles.len() as u64;
        let scene = LoadedScene {
            meshes: vec![Mesh { name: "sheet".into(), primitives: vec![prim] }],
            instances: vec![Instance { mesh: 0, transform: IDENTITY }],
            materials: vec![Material { base_color: [0.8, 0.5, 0.2, 1.0], ..Default::default() }],
            ..Default::default()
        };
        let area = scene.world_area();
        for (method, area_mode) in [(Method::Voxel, AreaMode::Exact), (Method::Voxel, AreaMode::Eq17), (Method::Scanline, AreaMode::Eq17)] {
            let opts = SampleOptions { method, area: area_mode, density: Density::VoxelSize(0.004), merge: false, ..Default::default() };
            let run = |threads: usize| {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
                let calls = std::sync::Mutex::new(Vec::new());
                let s = pool.install(|| {
                    sample_scene(&scene, &opts, &|done, total| {
                        assert_eq!(total, ntris);
                        calls.lock().expect("lock").push(done);
                    })
                });
                (s.expect("samples"), calls.into_inner().expect("lock"))
            };
            let (a, pa) = run(1);
            let (b, pb) = run(2);
            for p in [pa, pb] {
                // Reaches the total, and only at the end (the slabs after the last one where
                // a triangle starts add nothing); counting a triangle in every slab it spans
                // would saturate after a fraction of the slabs.
                assert_eq!(p.iter().max(), Some(&ntris), "{method:?}");
                let at_total = p.iter().filter(|&&d| d == ntris).count();
                assert!(p.len() > 100 && at_total * 10 < p.len(), "{method:?}: {at_total} of {} calls at the total", p.len());
            }
            assert!(a.stats.samples > 40_000, "{method:?}: {} samples", a.stats.samples);
            let (na, nb) = (&a.meshes[0].samples, &b.meshes[0].samples);
            // Slab outputs are placed in slab order across batches: voxels x-major throughout.
            assert!(na.windows(2).all(|w| w[0].center <= w[1].center), "{method:?}: nodes out of voxel order");
            assert_eq!(na.len(), nb.len());
            for (x, y) in na.iter().zip(nb) {
                assert_eq!((x.center, x.area.to_bits(), x.normal, x.color), (y.center, y.area.to_bits(), y.normal, y.color), "{method:?}");
            }
            let rel = (a.stats.sample_area - area) / area;
            assert!(rel.abs() < 1e-5, "{method:?}: area error {rel:e}");
        }
    }

    /// One-pass splitting gives the polygons of the two clips bit for bit (vertices on the cut
    /// line included), so swept strips and columns meet exactly.
    #[test]
    fn split_equals_two_clips() {
        let mut rng = sct_format::rng::SplitMix64(5);
        for i in 0..20_000 {
            // Random triangles, some with vertices on the cut line.
            let mut p = Poly2::empty();
            p.n = 3;
            for v in &mut p.v[..3] {
                *v = [(rng.next_f64() * 8.0).floor() / 2.0, rng.next_f64() * 4.0];
            }
            let (axis, c) = (i % 2, if i % 3 == 0 { 2.0 } else { rng.next_f64() * 4.0 });
            let (mut below, mut above) = (Poly2::empty(), Poly2::empty());
            if axis == 0 {
                p.split_axis_into::<0>(c, &mut below, &mut above);
            } else {
                p.split_axis_into::<1>(c, &mut below, &mut above);
            }
            let want_below = p.clip_half(|q| c - q[axis], Some((axis, c)));
            let want_above = p.clip_half(|q| q[axis] - c, Some((axis, c)));
            for (got, want) in [(below, want_below), (above, want_above)] {
                assert_eq!(got.n, want.n);
                assert_eq!(got.v[..got.n], want.v[..want.n]);
            }
        }
    }

    /// Merging from keyed items (runs found from the items) and from bare indices (runs found
    /// from the records' keys) gives the same nodes; equal voxels merge, others pass through.
    #[test]
    fn merge_sorted_finds_runs_from_items_or_records() {
        let kp = KeyPack::new([0.0; 3], [20.0; 3]).expect("keys");
        let mut rng = sct_format::rng::SplitMix64(9);
        let recs: Vec<Rec> = (0..3000)
            .map(|i| {
                let v = |r: &mut sct_format::rng::SplitMix64| (r.next_u64() % 1000) as f32 / 1000.0;
                let key = kp.pack([(rng.next_u64() % 4) as i64, (rng.next_u64() % 5) as i64, (rng.next_u64() % 30) as i64]);
                Rec { key, area: if i % 7 == 0 { 0.0 } else { v(&mut rng) }, normal: [v(&mut rng), 0.5, -0.25], color: [v(&mut rng), 0.25, 0.5, 1.0] }
            })
            .collect();
        let (mut items, mut tmp) = (Vec::new(), Vec::new());
        let mask = sort_order(&recs, None, &mut items, &mut tmp);
        assert_ne!(mask, u64::MAX);
        let mut bare: Vec<u64> = (0..recs.len() as u64).collect();
        bare.sort_by_key(|&i| recs[i as usize].key);
        assert_eq!(items.iter().map(|&x| x & mask).collect::<Vec<_>>(), bare);
        let mut keys: Vec<u64> = recs.iter().map(|r| r.key).collect();
        keys.sort_unstable();
        keys.dedup();
        let voxels = keys.len();
        assert!(voxels < recs.len() / 4);
        for merge in [true, false] {
            let (mut a, mut b) = (Vec::new(), Vec::new());
            merge_sorted(&items, mask, &recs, &kp, 0.5, 0.1, 0.01, merge, &mut a);
            merge_sorted(&bare, u64::MAX, &recs, &kp, 0.5, 0.1, 0.01, merge, &mut b);
            assert_eq!(a.len(), if merge { voxels } else { recs.len() });
            // Centres (x and y taken once per column) are those of the unpacked keys.
            let want: Vec<u64> = if merge { keys.clone() } else { items.iter().map(|&it| recs[(it & mask) as usize].key).collect() };
            let centre = |k: u64| kp.unpack(k).map(|v| ((v as f64 + 0.5) * 0.1) as f32);
            assert!(a.iter().zip(&want).all(|(n, &k)| n.center == centre(k)));
            let bits = |n: &Node| (n.center, n.normal.map(f32::to_bits), n.area.to_bits(), n.color);
            assert_eq!(a.iter().map(bits).collect::<Vec<_>>(), b.iter().map(bits).collect::<Vec<_>>());
        }
    }

    /// Records dealt to a slab's parts (x inside the slab, and strays beyond it on both sides)
    /// and then sorted part by part come out in the order of one stable sort of them all by
    /// key; there are several parts, and their keys ascend from part to part.
    #[test]
    fn slab_parts_sorted_one_by_one_equal_one_stable_sort() {
        let kp = KeyPack::new([0.0; 3], [300.0, 40.0, 40.0]).expect("keys");
        let mut rng = sct_format::rng::SplitMix64(5);
        let mut parts = SlabParts::default();
        for (xs, expected) in [((100, 163), 60_000.0), ((0, 0), 30_000.0), ((5, 300), 1.0e7), ((10, 20), 100.0)] {
            parts.reset(&kp, xs, expected);
            let mut all = Vec::new();
            for _ in 0..50 {
                let tri: Vec<Rec> = (0..rng.next_u64() % 200)
                    .map(|i| {
                        let x = xs.0 - 3 + (rng.next_u64() % (xs.1 - xs.0 + 7) as u64) as i64;
                        let key = kp.pack([x, (rng.next_u64() % 40) as i64, (rng.next_u64() % 40) as i64]);
                        Rec { key, area: 0.5, normal: [(all.len() + i as usize) as f32; 3], color: [0.0; 4] }
                    })
                    .collect();
                all.extend_from_slice(&tri);
                parts.extend(&tri);
            }
            assert_eq!(parts.len(), all.len());
            if expected > 50_000.0 {
                assert!(parts.parts.iter().filter(|p| !p.is_empty()).count() > 2, "{xs:?}");
            }
            let mut by_parts = Vec::new();
            let mut last_key = 0;
            for (pi, p) in parts.parts.iter().enumerate() {
                let (mut items, mut tmp) = (Vec::new(), Vec::new());
                // A middle part's place bounds its keys: its sort skips the scan for them.
                if let Some((lo, bits)) = parts.key_range(pi) {
                    assert!(p.iter().all(|r| (r.key - lo) >> bits == 0), "{xs:?}: part {pi}");
                }
                let mask = sort_order(p, parts.key_range(pi), &mut items, &mut tmp);
                assert!(p.iter().all(|r| r.key >= last_key));
                last_key = p.iter().map(|r| r.key).max().unwrap_or(last_key);
                by_parts.extend(items.iter().map(|&it| p[(it & mask) as usize].normal[0]));
            }
            all.sort_by_key(|r| r.key);
            assert_eq!(by_parts, all.iter().map(|r| r.normal[0]).collect::<Vec<_>>(), "{xs:?}");
        }
    }

    #[test]
    fn clip_by_kept_depths_equals_clip_by_depth() {
        // The voxel method clips a piece with depths kept by range_keeping: same polygons.
        let mut rng = sct_format::rng::SplitMix64(11);
        for _ in 0..5_000 {
            let mut p = Poly2::empty();
            p.n = 3 + (rng.next_f64() * 3.0) as usize;
            for v in &mut p.v[..p.n] {
                *v = [rng.next_f64() * 3.0, rng.next_f64() * 3.0];
            }
            let (ga, gb, kf) = (rng.next_f64() * 2.0 - 1.0, rng.next_f64() * 2.0 - 1.0, rng.next_f64() * 2.0);
            let depth = |q: &[f64; 2]| 0.25 + ga * q[0] + gb * q[1];
            let mut dv = [0.0; MAXV];
            let kept = p.range_keeping(depth, &mut dv);
            let want = p.range(depth);
            assert_eq!((kept.0.to_bits(), kept.1.to_bits()), (want.0.to_bits(), want.1.to_bits()));
            let (mut got, mut want) = (Poly2::empty(), Poly2::empty());
            p.clip_half_by_index_into(|i, _| kf - dv[i], None, &mut got);
            p.clip_half_into(|q| kf - depth(q), None, &mut want);
            assert_eq!(got.n, want.n);
            for (a, b) in got.v[..got.n].iter().zip(&want.v[..want.n]) {
                assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits));
            }
        }
    }

    #[test]
    fn polygon_range_is_min_and_max_ignoring_nan() {
        let mut p = Poly2::empty();
        p.set_square(2.0, -3.0);
        assert_eq!(p.range(|v| v[0]), (2.0, 3.0));
        assert_eq!(p.range(|v| v[1] * 2.0), (-6.0, -4.0));
        assert_eq!(p.range(|v| if v[0] == 3.0 { f64::NAN } else { v[1] }), (-3.0, -2.0));
        p.n = 0;
        assert_eq!(p.range(|v| v[0]), (f64::INFINITY, f64::NEG_INFINITY));
    }

    /// Slab parts (4k–16k items, 23–24 key bits) sort in two passes.
    #[test]
    fn slab_parts_take_two_radix_passes() {
        for n in [4096, 5000, 8192, 16_383] {
            for bits in [23, 24] {
                assert_eq!(radix_digits(n, bits), (2, 12), "n {n}, bits {bits}");
            }
        }
        assert_eq!(radix_digits(16_384, 28), (2, 14));
    }

    #[test]
    fn radix_sort_is_a_stable_sort() {
        let mut rng = sct_format::rng::SplitMix64(3);
        let mut tmp = Vec::new();
        for (n, shift, bits) in [(10, 4, 5), (1000, 10, 3), (5000, 0, 40), (70_000, 17, 23), (3000, 0, 64), (4000, 30, 33), (4000, 12, 22), (300, 5, 0), (20_000, 15, 27), (20_000, 15, 28), (2000, 20, 26), (70_000, 17, 28)] {
            // The low `shift` bits are payload (not sorted on: stability shows).
            let mut v: Vec<u64> = (0..n as u64)
                .map(|_| {
                    let mut key = if bits == 0 { 0 } else { rng.next_u64() >> (64 - bits) };
                    if n == 70_000 && bits == 28 {
                        key &= !0x3FFF; // the low digit is the same everywhere: its pass is skipped
                    }
                    key.checked_shl(shift).unwrap_or(0) | (rng.next_u64() & ((1u64 << shift) - 1))
                })
                .collect();
            let mut want = v.clone();
            want.sort_by_key(|&x| x.checked_shr(shift).unwrap_or(0));
            radix_sort_bits(&mut v, &mut tmp, shift, bits);
            assert_eq!(v, want, "n {n}, shift {shift}, bits {bits}");
        }
    }
}
