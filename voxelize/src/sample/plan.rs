//! What to sample: the units (one mesh in one frame: baked into world space or sampled once
//! and placed by instances), the voxel size after budget and limits, and each unit's key range.

use crate::mesh::*;

use super::density::{choose_voxel_size, SampleEstimate, VoxelChoice};
use super::keys::KeyPack;
use super::{Method, SampleOptions, SampleStats};

/// A unit of sampling: one mesh in one frame.
pub(super) struct Unit {
    pub(super) mesh: usize,
    /// Frame transform applied to the mesh's vertices before sampling (baked world) or
    /// `None` (sampled in its local frame; instances carry the placement).
    pub(super) bake: Option<Mat4>,
    /// Voxel size in the unit's frame.
    pub(super) h: f64,
    pub(super) name: String,
    pub(super) instances: Vec<sct_format::Similarity>,
    pub(super) affine: Vec<[[f64; 4]; 3]>,
}

/// The samples-file form (row-major 3 × 4) of an affine `Mat4` (column-major), when it is
/// affine (last row 0 0 0 1) and invertible.
pub(super) fn to_affine(m: &Mat4) -> Option<sct_format::samples::AffineInstance> {
    if m[0][3] != 0.0 || m[1][3] != 0.0 || m[2][3] != 0.0 || m[3][3] != 1.0 {
        return None;
    }
    let a = sct_format::samples::AffineInstance { mesh: 0, matrix: std::array::from_fn(|r| std::array::from_fn(|c| m[c][r])) };
    a.is_valid().then_some(a)
}

pub(super) fn plan_units(scene: &LoadedScene, h: f64, stats: &mut SampleStats) -> Vec<Unit> {
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

/// The voxel size, the units to sample and their counters so far: the density rule, the
/// sample budget and the limits, checked before any sampling.
pub(super) fn plan_sampling(scene: &LoadedScene, opts: &SampleOptions) -> Result<(VoxelChoice, SampleStats, Vec<Unit>), String> {
    let mut voxel = choose_voxel_size(scene, &opts.density)?;
    let mut stats = SampleStats::default();
    let mut units = plan_units(scene, voxel.size, &mut stats);
    let mut est = SampleEstimate::of(scene, &units, voxel.size, opts.method);
    // The vertex sampler makes one sample per triangle at any voxel size: no budget applies.
    if let (Some(budget), false) = (opts.budget, opts.method == Method::Vertex) {
        if let Some(coarser) = est.voxel_for(budget as f64, opts.merge).filter(|&c| c > voxel.size) {
            voxel.reason = format!("{}; coarsened to {coarser:.6} to stay within --sample-budget {budget}", voxel.reason);
            stats = SampleStats::default();
            stats.warnings.push(format!(
                "the sample budget of {budget} coarsened the voxel from {:.6} (what the density rule asks) to {coarser:.6} ({:.1}× coarser)",
                voxel.size,
                coarser / voxel.size
            ));
            voxel.size = coarser;
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
    // A voxel wider than the model says nothing more than one that just spans it; the
    // vertex sampler has no voxels.
    // Bounds once (a pass over every vertex).
    let bounds = scene.world_bounds();
    let extent = bounds.map_or(0.0, |(lo, hi)| (0..3).fold(0.0f64, |m, k| m.max(hi[k] - lo[k])));
    if opts.method != Method::Vertex && extent > 0.0 && extent < voxel.size {
        let asked = voxel.size;
        voxel.reason = format!("{}; clamped to the model's largest extent {extent:.6}", voxel.reason);
        voxel.size = extent;
        stats = SampleStats { warnings: std::mem::take(&mut stats.warnings), ..Default::default() };
        units = plan_units(scene, extent, &mut stats);
        est = SampleEstimate::of(scene, &units, extent, opts.method);
        stats.warnings.push(format!(
            "voxel size {asked} is larger than the model (largest bounding-box extent {extent}); clamped to {extent}"
        ));
    }
    let h = voxel.size;
    if let Some(b) = bounds {
        let ext = b.0.iter().chain(b.1.iter()).fold(0.0f64, |m, v| m.max(v.abs()));
        if units.iter().any(|u| u.bake.is_some() && ext / u.h > (1u64 << 30) as f64) {
            return Err(format!("voxel size {h} is too small for coordinates up to {ext} (more than 2^30 voxels along an axis)"));
        }
    }
    let estimate = est.at(h);
    if estimate > opts.max_samples as f64 {
        // Suggest what applies to the density rule in use.
        let fix = match opts.density {
            crate::Density::VoxelSize(_) => "give a larger --voxel-size, or raise --max-samples",
            crate::Density::Auto { .. } => "use a smaller --gamma or a larger --k, set --sample-budget, or raise --max-samples",
            _ => "use a larger --screen-error, set --sample-budget, or raise --max-samples",
        };
        return Err(format!("voxel size {h} would make about {estimate:.0} samples, more than --max-samples {}; {fix}", opts.max_samples));
    }
    Ok((voxel, stats, units))
}

/// The voxel-key packing of a unit: its vertices' bounds in grid units.
pub(super) fn unit_keys(mesh: &Mesh, u: &Unit) -> Result<KeyPack, String> {
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
