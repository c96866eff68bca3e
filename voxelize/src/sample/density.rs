//! The voxel size: the density rules (EQ 16, an explicit size, viewing needs) and the
//! estimate of the samples a voxel size makes, which a sample budget inverts.

use crate::mesh::*;

use super::plan::Unit;
use super::Method;

/// How the voxel size is chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Density {
    /// The intended view (the default): the view `sct-render-preview` shows by default —
    /// the model's bounding box framed at 90 % of a 1280 × 720, 40° frame from the front and
    /// from the iso direction, +Y up ([`sct_format::view::default_pixel_size`]) — with
    /// voxels `pixels` pixels wide there ([`Density::VIEW_PIXELS`] by default): the density
    /// follows what that view can show, not the triangle count.
    View {
        /// Voxel edge in pixels of the intended view.
        pixels: f64,
    },
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

impl Density {
    /// Voxel edge, in pixels of the intended view, of the default density. The preview's
    /// default LOD (`--pixel-error 0.75`: splats of at most 0.75 px radius, 1.5 px across)
    /// draws the leaves themselves, and the half-voxel quarters where colour varies, and
    /// nothing finer is made than it draws (a 1-px voxel made 2.2× the samples for the same
    /// image).
    pub const VIEW_PIXELS: f64 = 1.5;
}

/// The chosen voxel size and why.
#[derive(Clone, Debug, PartialEq)]
pub struct VoxelChoice {
    /// Voxel edge length in world units.
    pub size: f64,
    /// Human-readable derivation.
    pub reason: String,
}

/// Chooses the voxel size (the intended view, EQ 16, explicit, or a viewing target).
pub fn choose_voxel_size(scene: &LoadedScene, d: &Density) -> Result<VoxelChoice, String> {
    let c = match *d {
        Density::VoxelSize(h) => VoxelChoice { size: h, reason: format!("explicit --voxel-size {h}") },
        Density::View { pixels } => {
            let (lo, hi) = scene.world_bounds().ok_or("the scene has no geometry to size a voxel from; give --voxel-size")?;
            let pix = sct_format::view::default_pixel_size(lo, hi, sct_format::view::UpAxis::Y);
            let h = pixels * pix;
            VoxelChoice {
                size: h,
                reason: format!(
                    "intended view: the model framed at {:.0} % of {} × {} px ({}° vertical field of view, front and iso, +Y up): pixel {pix:.6}, voxel {pixels} px = {h:.6}",
                    100.0 * sct_format::view::DEFAULT_FILL,
                    sct_format::view::DEFAULT_WIDTH,
                    sct_format::view::DEFAULT_HEIGHT,
                    sct_format::view::DEFAULT_FOV_Y_DEG
                ),
            }
        }
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

/// Samples made at voxel size `h`, estimated before allocating. Before merging, a triangle
/// crosses about `area/h² + perimeter/(2h) + 1` voxels, so the count is
/// `area/h² + perimeter/h + per_triangle` summed over all units (each unit's voxel is a fixed
/// multiple of `h`). After merging, a surface leaves about one sample per voxel it crosses:
/// `Σ area·|n|₁/h²` for the voxel sampler (a plane crosses `|n|₁/h²` cubes per unit area),
/// `Σ area·|n|∞/h²` for the scan-line sampler (one sample per column). Both can be solved for
/// the `h` of a sample budget.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct SampleEstimate {
    /// Σ triangle area / (unit voxel / h)², world units².
    pub(super) area: f64,
    /// Σ half perimeter / (unit voxel / h), world units.
    pub(super) perimeter: f64,
    /// Samples that do not shrink with a coarser voxel (one per triangle; all of them for the
    /// vertex sampler).
    pub(super) per_triangle: f64,
    /// Σ triangle area × (voxels crossed per unit area × h²) / (unit voxel / h)².
    pub(super) merged_area: f64,
}

impl SampleEstimate {
    pub(super) fn of(scene: &LoadedScene, units: &[Unit], h: f64, method: Method) -> Self {
        let mut e = SampleEstimate::default();
        for u in units {
            let mesh = &scene.meshes[u.mesh];
            let m = u.bake.unwrap_or([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]);
            let k = u.h / h;
            // Each affine placement stands for a copy of the unit's samples: consumers bake
            // one per placement (spec §8), and the area tally transforms every sample once per
            // placement. Counted as copies, so the budget and --max-samples bound them: 14,500
            // affine nodes of one mesh in a 1 MB glTF took 6 s of tallying for 5,151 samples
            // (and could ask for billions of baked samples).
            let w = 1.0 + u.affine.len() as f64;
            for p in &mesh.primitives {
                // Added in triangle order (the terms computed in parallel): the same bits on
                // any number of threads. A term left out adds +0.0, which changes no sum of
                // non-negative terms.
                let acc = [e.per_triangle, e.area, e.perimeter, e.merged_area];
                [e.per_triangle, e.area, e.perimeter, e.merged_area] = crate::par::ordered_sum(p.triangles.len(), acc, |ti| {
                    if method == Method::Vertex {
                        return [w, 0.0, 0.0, 0.0];
                    }
                    let [a, b, c] = p.triangles[ti].map(|i| transform_point(&m, p.positions[i as usize]));
                    let n = cross(sub(b, a), sub(c, a));
                    let area = w * 0.5 * norm(n) / (k * k);
                    // Columns are sampled at their centres (no edge term); a conservative
                    // voxelization also takes the voxels along the edges.
                    let perimeter = if method == Method::Voxel { w * (norm(sub(b, a)) + norm(sub(c, b)) + norm(sub(a, c))) / k } else { 0.0 };
                    let len = norm(n);
                    let merged = if len > 0.0 {
                        let [x, y, z] = n.map(|v| v.abs() / len);
                        area * if method == Method::Scanline { x.max(y).max(z) } else { x + y + z }
                    } else {
                        0.0
                    };
                    [w, area, perimeter, merged]
                });
            }
        }
        e
    }

    /// Samples before merging.
    pub(super) fn at(&self, h: f64) -> f64 {
        self.merged_area / (h * h) + self.perimeter / h + self.per_triangle
    }

    /// The voxel size expected to give `budget` samples (after merging when `merge`), if a
    /// finite one exists.
    pub(super) fn voxel_for(&self, budget: f64, merge: bool) -> Option<f64> {
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
}
