//! The loaded scene: what every loader produces and what the samplers, the preview
//! renderer's reference rasterizer and `inspect --against` consume.
//!
//! Conventions:
//! - colours are **linear** RGBA in [0, 1] (8-bit sRGB inputs are decoded on load; textures
//!   keep their 8-bit sRGB texels and are decoded per lookup), output colours are re-encoded
//!   to sRGB by the sampler;
//! - a [`Mesh`] lives in its own local frame; an [`Instance`] places it in the world by a
//!   general affine matrix (column-major, glTF convention);
//! - triangles are counter-clockwise seen from the front; zero-area triangles have already
//!   been removed and counted in [`LoadStats::degenerate_triangles`].

use std::path::PathBuf;

mod normals;

pub use normals::corner_normals;

/// Column-major 4×4 affine matrix (`m[col][row]`), as glTF stores it.
pub type Mat4 = [[f64; 4]; 4];

/// The identity matrix.
pub const IDENTITY: Mat4 =
    [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];

/// How a sampler treats texture coordinates outside [0, 1] (glTF sampler wrap modes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Wrap {
    /// Tile.
    #[default]
    Repeat,
    /// Tile, every other copy mirrored.
    MirroredRepeat,
    /// Clamp to the edge texel.
    ClampToEdge,
}

/// A decoded texture image: 8-bit sRGB RGBA, rows top to bottom (v = 0 is the top row, the
/// glTF convention; OBJ's v is flipped by the OBJ loader).
#[derive(Clone, Debug)]
pub struct Image {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// `width * height` RGBA texels.
    pub rgba: Vec<[u8; 4]>,
    /// Where it came from (file path or "embedded image N").
    pub source: String,
}

/// A texture binding of a material.
#[derive(Clone, Debug)]
pub struct TextureRef {
    /// Index into [`LoadedScene::images`].
    pub image: usize,
    /// Which UV set ([`Primitive::uvs`] index) it reads.
    pub tex_coord: u32,
    /// Affine UV transform applied before lookup (KHR_texture_transform): `uv' = M · (u, v, 1)`,
    /// rows of a 2×3 matrix.
    pub transform: [[f32; 3]; 2],
    /// Wrap mode along u.
    pub wrap_s: Wrap,
    /// Wrap mode along v.
    pub wrap_t: Wrap,
}

/// Identity UV transform.
pub const UV_IDENTITY: [[f32; 3]; 2] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

/// glTF alpha mode; OBJ and PLY map `d`/alpha to `Blend` when below 1.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum AlphaMode {
    /// Alpha ignored (forced to 1).
    #[default]
    Opaque,
    /// Alpha below the cutoff drops the sample, otherwise alpha is 1.
    Mask(f32),
    /// Alpha kept; alpha 0 drops the sample.
    Blend,
}

/// A material: base colour factor × texture × vertex colour.
#[derive(Clone, Debug)]
pub struct Material {
    /// Name as in the file.
    pub name: String,
    /// Linear RGBA factor.
    pub base_color: [f32; 4],
    /// Base-colour texture.
    pub texture: Option<TextureRef>,
    /// Separate alpha (opacity) texture, luminance used (OBJ `map_d`).
    pub alpha_texture: Option<TextureRef>,
    /// Alpha handling.
    pub alpha_mode: AlphaMode,
    /// Rendered from both sides.
    pub double_sided: bool,
}

impl Default for Material {
    fn default() -> Self {
        Material {
            name: String::from("default"),
            base_color: [0.8, 0.8, 0.8, 1.0],
            texture: None,
            alpha_texture: None,
            alpha_mode: AlphaMode::Opaque,
            double_sided: false,
        }
    }
}

/// Triangles sharing one material and one vertex layout.
#[derive(Clone, Debug, Default)]
pub struct Primitive {
    /// Vertex positions (local frame).
    pub positions: Vec<[f32; 3]>,
    /// Per-vertex normals, if the file has them (not necessarily unit length).
    pub normals: Option<Vec<[f32; 3]>>,
    /// Per-vertex linear RGBA colours.
    pub colors: Option<Vec<[f32; 4]>>,
    /// UV sets (glTF TEXCOORD_n is `uvs[n]`).
    pub uvs: Vec<Vec<[f32; 2]>>,
    /// Triangles (indices into the vertex arrays, all in range).
    pub triangles: Vec<[u32; 3]>,
    /// Index into [`LoadedScene::materials`]; `None` = default material.
    pub material: Option<usize>,
}

/// A named mesh: one or more primitives in one local frame.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// Name (file name, object name or glTF mesh name).
    pub name: String,
    /// Primitives.
    pub primitives: Vec<Primitive>,
}

impl Mesh {
    /// Number of triangles over all primitives.
    pub fn triangle_count(&self) -> usize {
        self.primitives.iter().map(|p| p.triangles.len()).sum()
    }
}

/// A placement of a mesh in the world.
#[derive(Clone, Copy, Debug)]
pub struct Instance {
    /// Index into [`LoadedScene::meshes`].
    pub mesh: usize,
    /// Local-to-world matrix (column-major).
    pub transform: Mat4,
}

/// A point sample set (a PLY without faces).
#[derive(Clone, Debug, Default)]
pub struct PointCloud {
    /// Positions (world frame).
    pub positions: Vec<[f32; 3]>,
    /// Normals, if present.
    pub normals: Option<Vec<[f32; 3]>>,
    /// Linear RGBA colours, if present.
    pub colors: Option<Vec<[f32; 4]>>,
}

/// Counts reported by the loaders.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct LoadStats {
    /// Triangles read (after polygon triangulation, before dropping degenerate ones), counted
    /// once per mesh, not per instance.
    pub triangles_read: u64,
    /// Zero-area triangles dropped.
    pub degenerate_triangles: u64,
    /// Polygons with more than three corners triangulated (CDT).
    pub polygons_triangulated: u64,
    /// Point or line primitives skipped.
    pub skipped_primitives: u64,
}

/// Everything a mesh file describes, resolved and validated.
#[derive(Clone, Debug, Default)]
pub struct LoadedScene {
    /// Meshes in local frames.
    pub meshes: Vec<Mesh>,
    /// Placements; a mesh appears in the scene once per instance.
    pub instances: Vec<Instance>,
    /// Materials.
    pub materials: Vec<Material>,
    /// Decoded images.
    pub images: Vec<Image>,
    /// A point cloud, when the file has vertices but no faces.
    pub points: Option<PointCloud>,
    /// Non-fatal problems (missing MTL, missing texture, skipped primitives …).
    pub warnings: Vec<String>,
    /// Counts.
    pub stats: LoadStats,
    /// Files read (the input and every resource it referenced that was found).
    pub files: Vec<PathBuf>,
    /// Files a source references that were not found (an MTL, a texture): each one's
    /// appearance would change the result, so batch mode records them and converts again
    /// when one appears.
    pub missing: Vec<PathBuf>,
    /// The format says per material which surfaces are seen from both sides (glTF
    /// `doubleSided`); otherwise sidedness comes from topology (see [`crate::sides`]).
    pub declares_sides: bool,
}

impl LoadedScene {
    /// The material of a primitive (the default one when it has none).
    pub fn material(&self, p: &Primitive) -> Material {
        p.material.and_then(|m| self.materials.get(m)).cloned().unwrap_or_default()
    }

    /// Total triangle count over all instances (what a renderer draws).
    pub fn instanced_triangle_count(&self) -> u64 {
        self.instances
            .iter()
            .map(|i| self.meshes.get(i.mesh).map_or(0, |m| m.triangle_count() as u64))
            .sum()
    }

    /// Total world-space surface area over all instances (added triangle by triangle in
    /// order, computed in parallel: the same bits on any number of threads).
    pub fn world_area(&self) -> f64 {
        let mut total = 0.0;
        for inst in &self.instances {
            let Some(mesh) = self.meshes.get(inst.mesh) else { continue };
            // The identity (a PLY's or OBJ's one instance) moves a finite coordinate only
            // from -0 to +0, which changes no area's bits (they come from squares): its
            // triangles skip the transform (3 % of the instructions of the one-step conversion
            // of a 4.4 M-triangle PLY).
            let identity = inst.transform == IDENTITY;
            for p in &mesh.primitives {
                [total] = crate::par::ordered_sum(p.triangles.len(), [total], |ti| {
                    let [a, b, c] = if identity {
                        p.triangles[ti].map(|i| p.positions[i as usize].map(f64::from))
                    } else {
                        p.triangles[ti].map(|i| transform_point(&inst.transform, p.positions[i as usize]))
                    };
                    [0.5 * norm(cross(sub(b, a), sub(c, a)))]
                });
            }
        }
        total
    }

    /// World-space axis-aligned bounds (min, max) over instances and points; `None` if empty.
    /// The vertices are taken on every thread, with the bits of the serial loop (see
    /// [`crate::par::bounds`]).
    pub fn world_bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        let mut b = crate::par::NO_BOUNDS;
        let mut any = false;
        for inst in &self.instances {
            let Some(mesh) = self.meshes.get(inst.mesh) else { continue };
            // The identity gives a finite coordinate back but for -0, which it makes +0, as
            // adding +0 does (see `world_area`).
            let identity = inst.transform == IDENTITY;
            for p in &mesh.primitives {
                any |= !p.positions.is_empty();
                b = crate::par::bounds(p.positions.len(), b, |i| {
                    let v = p.positions[i];
                    if identity { v.map(|c| f64::from(c) + 0.0) } else { transform_point(&inst.transform, v) }
                });
            }
        }
        if let Some(pc) = &self.points {
            any |= !pc.positions.is_empty();
            b = crate::par::bounds(pc.positions.len(), b, |i| pc.positions[i].map(f64::from));
        }
        any.then_some(b)
    }
}

/// Largest magnitude a world-space coordinate may reach (after instancing), checked at load.
/// Beyond it, products of edge lengths (areas, cross products) and sums of areas overflow the
/// f32 of a sample: a triangle spanning ±3·10³⁸ has an infinite area. 10¹⁵ keeps any area
/// (< 2·10³⁰) far inside f32 and is far beyond real scenes (the solar system is 10¹³ m).
pub const MAX_WORLD_COORDINATE: f64 = 1e15;

/// The largest world-space coordinate magnitude of the scene and the mesh that reaches it
/// (`"points"` for a point cloud); `None` for an empty scene. Each mesh's local bounding box
/// is mapped by each instance (the images of a box's corners bound the image of the box), so
/// this costs one pass over the vertices plus 8 points per instance. NaN (from a matrix
/// that overflows) counts as infinite.
pub fn max_world_coordinate(scene: &LoadedScene) -> Option<(f64, String)> {
    let boxes: Vec<Option<([f32; 3], [f32; 3])>> = scene
        .meshes
        .iter()
        .map(|m| {
            let mut it = m.primitives.iter().flat_map(|p| p.positions.iter());
            let first = *it.next()?;
            Some(it.fold((first, first), |(lo, hi), p| (std::array::from_fn(|k| lo[k].min(p[k])), std::array::from_fn(|k| hi[k].max(p[k])))))
        })
        .collect();
    let mut worst: Option<(f64, String)> = None;
    let mut note = |v: f64, name: &str| {
        if worst.as_ref().is_none_or(|(w, _)| v > *w) {
            worst = Some((v, name.to_string()));
        }
    };
    // NaN (a matrix that overflows) counts as infinitely far.
    let magnitude = |p: [f64; 3]| p.iter().fold(0.0f64, |m, v| if v.is_nan() { f64::INFINITY } else { m.max(v.abs()) });
    for inst in &scene.instances {
        let (Some(mesh), Some(Some((lo, hi)))) = (scene.meshes.get(inst.mesh), boxes.get(inst.mesh)) else { continue };
        for c in 0..8 {
            let corner = std::array::from_fn(|k| if c >> k & 1 == 0 { lo[k] } else { hi[k] });
            let w = transform_point(&inst.transform, corner);
            note(magnitude(w), &mesh.name);
        }
    }
    if let Some(pc) = &scene.points {
        for p in &pc.positions {
            note(magnitude(p.map(f64::from)), "points");
        }
    }
    worst
}

/// Closest point of triangle `t` to `p` (Ericson, Real-Time Collision Detection §5.1.5).
pub fn closest_on_triangle(p: [f64; 3], t: &[[f64; 3]; 3]) -> [f64; 3] {
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let along = |a: [f64; 3], d: [f64; 3], s: f64| [a[0] + s * d[0], a[1] + s * d[1], a[2] + s * d[2]];
    let [a, b, c] = *t;
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = sub(p, b);
    let (d3, d4) = (dot(ab, bp), dot(ac, bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return along(a, ab, d1 / (d1 - d3));
    }
    let cp = sub(p, c);
    let (d5, d6) = (dot(ab, cp), dot(ac, cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return along(a, ac, d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return along(b, sub(c, b), (d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    [a[0] + ab[0] * v + ac[0] * w, a[1] + ab[1] * v + ac[1] * w, a[2] + ab[2] * v + ac[2] * w]
}

/// Applies an affine matrix to a point.
pub fn transform_point(m: &Mat4, p: [f32; 3]) -> [f64; 3] {
    let [x, y, z] = p.map(f64::from);
    [
        m[0][0] * x + m[1][0] * y + m[2][0] * z + m[3][0],
        m[0][1] * x + m[1][1] * y + m[2][1] * z + m[3][1],
        m[0][2] * x + m[1][2] * y + m[2][2] * z + m[3][2],
    ]
}

/// Applies the inverse-transpose (cofactor matrix; scale is irrelevant since normals are
/// renormalised) of the upper 3×3 of `m` to a normal.
pub fn transform_normal(m: &Mat4, n: [f32; 3]) -> [f64; 3] {
    let c0 = [m[0][0], m[0][1], m[0][2]];
    let c1 = [m[1][0], m[1][1], m[1][2]];
    let c2 = [m[2][0], m[2][1], m[2][2]];
    // Cofactor matrix columns: (c1×c2, c2×c0, c0×c1) are the rows of det·M⁻¹, so
    // M⁻ᵀ n ∝ n.x (c1×c2) + n.y (c2×c0) + n.z (c0×c1), times sign(det) to keep orientation.
    let [x, y, z] = n.map(f64::from);
    let a = cross(c1, c2);
    let b = cross(c2, c0);
    let c = cross(c0, c1);
    let s = if determinant(m) < 0.0 { -1.0 } else { 1.0 };
    [
        s * (x * a[0] + y * b[0] + z * c[0]),
        s * (x * a[1] + y * b[1] + z * c[1]),
        s * (x * a[2] + y * b[2] + z * c[2]),
    ]
}

/// Determinant of the upper 3×3.
pub fn determinant(m: &Mat4) -> f64 {
    let c0 = [m[0][0], m[0][1], m[0][2]];
    let c1 = [m[1][0], m[1][1], m[1][2]];
    let c2 = [m[2][0], m[2][1], m[2][2]];
    dot(c0, cross(c1, c2))
}

/// Matrix product `a · b`.
pub fn mat_mul(a: &Mat4, b: &Mat4) -> Mat4 {
    let mut r = [[0.0; 4]; 4];
    for (c, col) in r.iter_mut().enumerate() {
        for (row, v) in col.iter_mut().enumerate() {
            *v = (0..4).map(|k| a[k][row] * b[c][k]).sum();
        }
    }
    r
}

/// Decomposes `m` into a similarity (translation, unit quaternion, uniform scale > 0) when it
/// is one within a relative tolerance of 1e-6; `None` for non-uniform scale, shear,
/// reflection or projective matrices (those are baked into world space instead).
pub fn to_similarity(m: &Mat4) -> Option<sct_format::Similarity> {
    if m[0][3].abs() > 1e-12 || m[1][3].abs() > 1e-12 || m[2][3].abs() > 1e-12 || (m[3][3] - 1.0).abs() > 1e-12 {
        return None;
    }
    let det = determinant(m);
    if !(det > 0.0) || !det.is_finite() {
        return None;
    }
    let s = det.cbrt();
    let cols = [0, 1, 2].map(|c| [m[c][0] / s, m[c][1] / s, m[c][2] / s]);
    for i in 0..3 {
        for j in 0..3 {
            let d = dot(cols[i], cols[j]) - if i == j { 1.0 } else { 0.0 };
            if d.abs() > 1e-6 {
                return None;
            }
        }
    }
    // Rotation matrix r[row][col] from the columns; standard robust quaternion extraction.
    let r = |row: usize, col: usize| cols[col][row];
    let tr = r(0, 0) + r(1, 1) + r(2, 2);
    let q = if tr > 0.0 {
        let w4 = 2.0 * (1.0 + tr).sqrt();
        [(r(2, 1) - r(1, 2)) / w4, (r(0, 2) - r(2, 0)) / w4, (r(1, 0) - r(0, 1)) / w4, w4 / 4.0]
    } else if r(0, 0) > r(1, 1) && r(0, 0) > r(2, 2) {
        let x4 = 2.0 * (1.0 + r(0, 0) - r(1, 1) - r(2, 2)).sqrt();
        [x4 / 4.0, (r(0, 1) + r(1, 0)) / x4, (r(0, 2) + r(2, 0)) / x4, (r(2, 1) - r(1, 2)) / x4]
    } else if r(1, 1) > r(2, 2) {
        let y4 = 2.0 * (1.0 + r(1, 1) - r(0, 0) - r(2, 2)).sqrt();
        [(r(0, 1) + r(1, 0)) / y4, y4 / 4.0, (r(1, 2) + r(2, 1)) / y4, (r(0, 2) - r(2, 0)) / y4]
    } else {
        let z4 = 2.0 * (1.0 + r(2, 2) - r(0, 0) - r(1, 1)).sqrt();
        [(r(0, 2) + r(2, 0)) / z4, (r(1, 2) + r(2, 1)) / z4, z4 / 4.0, (r(1, 0) - r(0, 1)) / z4]
    };
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    Some(sct_format::Similarity {
        translation: [m[3][0], m[3][1], m[3][2]],
        rotation: q.map(|v| v / n),
        scale: s,
    })
}

/// Matrix of a glTF TRS.
pub fn trs_matrix(t: [f64; 3], q: [f64; 4], s: [f64; 3]) -> Mat4 {
    let [x, y, z, w] = q;
    let r = [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + z * w), 2.0 * (x * z - y * w)],
        [2.0 * (x * y - z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + x * w)],
        [2.0 * (x * z + y * w), 2.0 * (y * z - x * w), 1.0 - 2.0 * (x * x + y * y)],
    ];
    [
        [r[0][0] * s[0], r[0][1] * s[0], r[0][2] * s[0], 0.0],
        [r[1][0] * s[1], r[1][1] * s[1], r[1][2] * s[1], 0.0],
        [r[2][0] * s[2], r[2][1] * s[2], r[2][2] * s[2], 0.0],
        [t[0], t[1], t[2], 1.0],
    ]
}

/// `x.floor() as i64` without a libm call (`floor` is not inlined on the baseline x86-64
/// target, and the samplers call it per voxel): truncate, then step down for negative
/// fractions. Saturates like `as` for huge values; NaN gives 0.
#[inline]
pub fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x {
        t.saturating_sub(1) // saturated at i64::MIN for huge negative x
    } else {
        t
    }
}

/// Decodes one 8-bit sRGB channel to linear.
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Encodes a linear channel in [0, 1] as 8-bit sRGB.
pub fn linear_to_srgb8(c: f32) -> u8 {
    Srgb8::get().encode(c)
}

/// Tables of the exact linear → 8-bit sRGB encoder ([`linear_to_srgb8`]); hold on to
/// [`Srgb8::get`] to encode many values without re-checking the lazy initialisation.
pub struct Srgb8 {
    /// The 255 midpoints between 8-bit codes, in linear, then +∞ (so code 255 compares false).
    mid: [f32; 256],
    /// The code at the start of each cell of 2^16 floats below 1.0 (by bit pattern).
    start: [u8; SRGB8_CELLS],
}

/// Bits of a float's pattern below its encoder cell's index: a cell spans 1/128 of its value
/// (7 mantissa bits), at most 0.88 of an 8-bit step, so it holds at most one midpoint.
const SRGB8_CELL_SHIFT: u32 = 16;
/// Cells of the floats in [0, 1) (1.0 is 0x3F80_0000).
const SRGB8_CELLS: usize = 0x3F80_0000 >> SRGB8_CELL_SHIFT;

impl Srgb8 {
    /// The shared tables.
    pub fn get() -> &'static Srgb8 {
        static T: std::sync::OnceLock<Srgb8> = std::sync::OnceLock::new();
        T.get_or_init(|| {
            let mid: [f32; 256] = std::array::from_fn(|i| if i < 255 { srgb_to_linear((i as f32 + 0.5) / 255.0) } else { f32::INFINITY });
            let start = std::array::from_fn(|j| mid.partition_point(|&m| m < f32::from_bits((j as u32) << SRGB8_CELL_SHIFT)) as u8);
            Srgb8 { mid, start }
        })
    }

    /// The code is the number of midpoints between 8-bit codes (in linear) below `c`: the
    /// same rounding as encoding with powf. The table gives that count at the start of c's
    /// cell (positive floats order like their bits), and one comparison with the next
    /// midpoint finishes it exactly (a cell holds at most one; tested for every float).
    #[inline]
    pub fn encode(&self, c: f32) -> u8 {
        // One integer test for the common case 0 < c < 1 (0x3F80_0000 is 1.0).
        let b = c.to_bits();
        if b.wrapping_sub(1) >= 0x3F80_0000 - 1 {
            // c ≤ 0 (or −0), c ≥ 1, NaN or an infinity: NaN and infinities give 0, as the
            // exact encoder did.
            return if c >= 1.0 && c != f32::INFINITY { 255 } else { 0 };
        }
        let code = self.start.get((b >> SRGB8_CELL_SHIFT) as usize).copied().unwrap_or(255);
        code + u8::from(self.mid[code as usize] < c)
    }
}

/// Lookup table: 8-bit sRGB → linear.
pub fn srgb_lut() -> &'static [f32; 256] {
    static LUT: std::sync::OnceLock<[f32; 256]> = std::sync::OnceLock::new();
    LUT.get_or_init(|| std::array::from_fn(|i| srgb_to_linear(i as f32 / 255.0)))
}

impl Image {
    /// Bilinear lookup honouring wrap modes; returns linear RGBA (texel centres at half
    /// integers, the GL convention).
    pub fn sample(&self, uv: [f32; 2], wrap_s: Wrap, wrap_t: Wrap) -> [f32; 4] {
        let (w, h) = (self.width as i64, self.height as i64);
        if w == 0 || h == 0 || self.rgba.len() < (w * h) as usize {
            return [1.0; 4];
        }
        let lut = srgb_lut();
        bilinear(w, h, uv, wrap_s, wrap_t, |i| {
            let t = self.rgba[i];
            [lut[t[0] as usize], lut[t[1] as usize], lut[t[2] as usize], t[3] as f32 / 255.0]
        })
    }
}

/// Bilinear lookup in a `w` × `h` texture (texel centres at half-integers, the GL convention)
/// with the wrap modes; `texel(row-major index)` gives one linear RGBA texel. Shared by
/// [`Image::sample`] and the sampler's pre-decoded tables, so both stay bit-identical.
#[inline]
pub(crate) fn bilinear(w: i64, h: i64, uv: [f32; 2], wrap_s: Wrap, wrap_t: Wrap, texel: impl Fn(usize) -> [f32; 4]) -> [f32; 4] {
    let u = if uv[0].is_finite() { uv[0] } else { 0.0 };
    let v = if uv[1].is_finite() { uv[1] } else { 0.0 };
    let x = u as f64 * w as f64 - 0.5;
    let y = v as f64 * h as f64 - 0.5;
    // Clamp before conversion so huge UVs cannot overflow.
    let (xi, yi) = (floor_i64(x.clamp(-1e15, 1e15)), floor_i64(y.clamp(-1e15, 1e15)));
    let fx = (x - xi as f64) as f32;
    let fy = (y - yi as f64) as f32;
    // Wrap the two columns and rows once (4 wraps, not 8); a hot path (once per sample).
    let (x0, x1) = (wrap_index(xi, w, wrap_s), wrap_index(xi + 1, w, wrap_s));
    let (r0, r1) = (wrap_index(yi, h, wrap_t) * w, wrap_index(yi + 1, h, wrap_t) * w);
    let at = |i: i64| texel(i as usize);
    let (a, b, c, d) = (at(r0 + x0), at(r0 + x1), at(r1 + x0), at(r1 + x1));
    std::array::from_fn(|k| {
        let top = a[k] + (b[k] - a[k]) * fx;
        let bot = c[k] + (d[k] - c[k]) * fx;
        top + (bot - top) * fy
    })
}

#[inline]
pub(crate) fn wrap_index(i: i64, n: i64, wrap: Wrap) -> i64 {
    if (0..n).contains(&i) {
        return i; // the common case, without a division
    }
    match wrap {
        Wrap::ClampToEdge => i.clamp(0, n - 1),
        Wrap::Repeat => i.rem_euclid(n),
        Wrap::MirroredRepeat => {
            let p = i.rem_euclid(2 * n);
            if p < n {
                p
            } else {
                2 * n - 1 - p
            }
        }
    }
}

impl TextureRef {
    /// Applies the UV transform.
    pub fn transform_uv(&self, uv: [f32; 2]) -> [f32; 2] {
        let m = &self.transform;
        [m[0][0] * uv[0] + m[0][1] * uv[1] + m[0][2], m[1][0] * uv[0] + m[1][1] * uv[1] + m[1][2]]
    }
}

pub(crate) fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
pub(crate) fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
pub(crate) fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

/// Whether a triangle has (numerically) zero area: its doubled area is below 1e-12 of its
/// longest squared edge, so slivers a float cannot orient are dropped, real thin ones kept.
pub fn is_degenerate(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> bool {
    let (a, b, c) = (a.map(f64::from), b.map(f64::from), c.map(f64::from));
    let e = [sub(b, a), sub(c, b), sub(a, c)];
    let longest = e.iter().map(|v| dot(*v, *v)).fold(0.0, f64::max);
    let cr = norm(cross(e[0], sub(c, a)));
    !(cr > 1e-12 * longest) || longest == 0.0
}

/// Area-uniform random points on the scene's surface in world space (every instance
/// counted), from a seeded generator: the same seed gives the same points. Used by coverage
/// checks (`inspect --against`, tests).
pub fn surface_points(scene: &LoadedScene, n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut tris: Vec<[[f64; 3]; 3]> = Vec::new();
    let mut cdf: Vec<f64> = Vec::new();
    let mut total = 0.0;
    for inst in &scene.instances {
        let Some(mesh) = scene.meshes.get(inst.mesh) else { continue };
        for p in &mesh.primitives {
            for t in &p.triangles {
                let w = t.map(|i| transform_point(&inst.transform, p.positions[i as usize]));
                let a = 0.5 * norm(cross(sub(w[1], w[0]), sub(w[2], w[0])));
                if a > 0.0 {
                    total += a;
                    tris.push(w);
                    cdf.push(total);
                }
            }
        }
    }
    if tris.is_empty() {
        return Vec::new();
    }
    let mut rng = sct_format::rng::SplitMix64(seed);
    (0..n)
        .map(|_| {
            let x = rng.next_f64() * total;
            let i = cdf.partition_point(|&c| c < x).min(tris.len() - 1);
            let [a, b, c] = tris[i];
            let (mut u, mut v) = (rng.next_f64(), rng.next_f64());
            if u + v > 1.0 {
                u = 1.0 - u;
                v = 1.0 - v;
            }
            std::array::from_fn(|k| a[k] + u * (b[k] - a[k]) + v * (c[k] - a[k]))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The identity instance's area and bounds, taken without the transform, have the bits of
    /// those through the transform: on triangles with signed zeros (the only coordinates the
    /// identity changes, -0 to +0), zero-length edges and magnitudes far apart. The sum over
    /// a non-identity instance still goes through its transform.
    #[test]
    fn identity_area_skips_the_transform_with_the_same_bits() {
        let mut rng = sct_format::rng::SplitMix64(7);
        let coord = |rng: &mut sct_format::rng::SplitMix64| -> f32 {
            match rng.next_u64() % 6 {
                0 => 0.0,
                1 => -0.0,
                2 => (rng.next_f64() as f32 - 0.5) * 1e-6,
                _ => (rng.next_f64() as f32 - 0.5) * 10f32.powi((rng.next_u64() % 7) as i32 - 3),
            }
        };
        let positions: Vec<[f32; 3]> = (0..600).map(|_| [coord(&mut rng), coord(&mut rng), coord(&mut rng)]).collect();
        let triangles: Vec<[u32; 3]> = (0..2000).map(|_| std::array::from_fn(|_| (rng.next_u64() % 600) as u32)).collect();
        let mesh = Mesh { name: "m".into(), primitives: vec![Primitive { positions, triangles, ..Default::default() }] };
        let through = |m: &Mat4| {
            let p = &mesh.primitives[0];
            p.triangles.iter().fold(0.0f64, |s, t| {
                let [a, b, c] = t.map(|i| transform_point(m, p.positions[i as usize]));
                s + 0.5 * norm(cross(sub(b, a), sub(c, a)))
            })
        };
        let shift: Mat4 = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.25, 1.0]];
        for m in [IDENTITY, shift] {
            let scene = LoadedScene { meshes: vec![mesh.clone()], instances: vec![Instance { mesh: 0, transform: m }], ..Default::default() };
            assert_eq!(scene.world_area().to_bits(), through(&m).to_bits());
            // The bounds too, vertex by vertex: the transform of each, and of a signed zero.
            for v in &mesh.primitives[0].positions {
                let one = Mesh { name: "v".into(), primitives: vec![Primitive { positions: vec![*v], ..Default::default() }] };
                let scene = LoadedScene { meshes: vec![one], instances: vec![Instance { mesh: 0, transform: m }], ..Default::default() };
                let p = transform_point(&m, *v).map(f64::to_bits);
                assert_eq!(scene.world_bounds().map(|(lo, hi)| (lo.map(f64::to_bits), hi.map(f64::to_bits))), Some((p, p)), "{v:?}");
            }
        }
    }

    #[test]
    fn floor_i64_is_floor_and_saturates() {
        for x in [-1.5, -1.0, -0.25, 0.0, 0.75, 2.0, 2.7, -3e9, 7.5e12] {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
        }
        assert_eq!((floor_i64(-1e300), floor_i64(1e300), floor_i64(f64::NAN)), (i64::MIN, i64::MAX, 0));
    }

    /// The encoder before the cell table (a 4096-entry start table and a walk along the
    /// midpoints), kept as the reference of the exhaustive test below.
    fn encode_before_cells(c: f32) -> u8 {
        static T: std::sync::OnceLock<([f32; 255], [u8; 4097])> = std::sync::OnceLock::new();
        let (mid, start) = T.get_or_init(|| {
            let mid: [f32; 255] = std::array::from_fn(|i| srgb_to_linear((i as f32 + 0.5) / 255.0));
            (mid, std::array::from_fn(|j| mid.partition_point(|&m| m < j as f32 / 4096.0) as u8))
        });
        if c.to_bits().wrapping_sub(1) >= 0x3F80_0000 - 1 {
            return if c >= 1.0 && c != f32::INFINITY { 255 } else { 0 };
        }
        let mut code = start[((c * 4096.0) as u32 as usize).min(4096)] as usize;
        while code < 255 && mid[code] < c {
            code += 1;
        }
        code as u8
    }

    /// The cell-table encoder gives the bytes of the one before it for every float in
    /// [0, 1] (the values its table covers; all others take the same early branch in both),
    /// and for every 4099th bit pattern elsewhere.
    #[test]
    fn srgb_cell_encoder_equals_the_previous_encoder_for_every_float() {
        use rayon::prelude::*;
        let t = Srgb8::get();
        let bad = (0..=0x3F80_0000u32 >> 16).into_par_iter().find_map_any(|hi| {
            (hi << 16..=(hi << 16 | 0xFFFF).min(0x3F80_0000)).map(f32::from_bits).find(|&c| t.encode(c) != encode_before_cells(c))
        });
        assert_eq!(bad, None);
        let bad = (0x3F80_0000u64..=u32::MAX as u64 + 0x3F80_0000).step_by(4099).map(|b| f32::from_bits(b as u32)).find(|&c| t.encode(c) != encode_before_cells(c));
        assert_eq!(bad, None);
    }

    /// The table-driven encoder equals a binary search over the midpoints everywhere.
    #[test]
    fn srgb_encode_matches_binary_search() {
        let mid: [f32; 255] = std::array::from_fn(|i| srgb_to_linear((i as f32 + 0.5) / 255.0));
        let mut x = 0.0f32;
        let mut checked = 0;
        while x <= 1.01 {
            assert_eq!(linear_to_srgb8(x), mid.partition_point(|&t| t < x) as u8, "at {x}");
            x = if x < 1e-4 { x + 1e-9 } else { x + 1.3e-7 };
            checked += 1;
        }
        // Every midpoint and its neighbours (the rounding boundaries).
        for &m in &mid {
            for v in [m.next_down(), m, m.next_up()] {
                assert_eq!(linear_to_srgb8(v), mid.partition_point(|&t| t < v) as u8, "at {v}");
            }
        }
        assert!(checked > 1_000_000);
        assert_eq!((linear_to_srgb8(f32::NAN), linear_to_srgb8(-1.0), linear_to_srgb8(2.0)), (0, 0, 255));
        // The edges of the integer range test of the fast path.
        for v in [-0.0, f32::from_bits(1), f32::MIN_POSITIVE, 1.0f32.next_down(), 1.0, f32::MAX, f32::INFINITY, f32::NEG_INFINITY, -f32::NAN] {
            let want = if v.is_finite() { mid.partition_point(|&t| t < v) as u8 } else { 0 };
            assert_eq!(linear_to_srgb8(v), want, "at {v:e}");
        }
    }
}
