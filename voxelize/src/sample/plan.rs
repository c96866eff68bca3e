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
        let singular = baked.len();
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
        if singular > 0 && insts.len() > 1 {
            stats.baked_non_similar += singular as u64;
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
    // The bounds of the vertices divided by `h`, taken on every thread. Dividing by a
    // positive finite `h` is monotone (correctly rounded) and makes NaN of NaN only, so the
    // least and greatest quotients are the quotients of the least and greatest coordinates:
    // three divisions per bound rather than per vertex. The quotients' values are those of the
    // loop over the vertices; only the sign of a zero bound may differ, which no key sees
    // (`KeyPack::new` floors). Any other `h` divides vertex by vertex, as that loop did.
    let once = u.h.is_finite() && u.h > 0.0;
    let mut b = crate::par::NO_BOUNDS;
    for p in &mesh.primitives {
        b = crate::par::bounds(p.positions.len(), b, |i| {
            let v = p.positions[i];
            let w = match &u.bake {
                Some(m) => transform_point(m, v),
                None => v.map(f64::from),
            };
            if once { w } else { w.map(|c| c / u.h) }
        });
    }
    let (mut lo, mut hi) = if once { (b.0.map(|c| c / u.h), b.1.map(|c| c / u.h)) } else { b };
    if lo.iter().chain(hi.iter()).any(|v| !v.is_finite()) {
        (lo, hi) = ([0.0; 3], [0.0; 3]);
    }
    KeyPack::new(lo, hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The loop over the vertices that `unit_keys` replaces: one quotient per coordinate.
    fn unit_keys_per_vertex(mesh: &Mesh, u: &Unit) -> Result<KeyPack, String> {
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

    fn same(a: &Result<KeyPack, String>, b: &Result<KeyPack, String>) -> bool {
        match (a, b) {
            (Ok(a), Ok(b)) => (a.lo, a.hi, a.bits, a.shift_x) == (b.lo, b.hi, b.bits, b.shift_x),
            (Err(a), Err(b)) => a == b,
            _ => false,
        }
    }

    /// The keys of the bounds divided once equal those of the quotients vertex by vertex, on
    /// 1 and several threads: for vertices with signed zeros, NaN, infinities, subnormals and
    /// magnitudes that overflow when divided, for baked and local units, and voxel sizes that
    /// are tiny, huge, zero, negative, infinite or NaN (divided vertex by vertex).
    #[test]
    fn unit_keys_equal_the_per_vertex_loop() {
        let mut rng = sct_format::rng::SplitMix64(3);
        let specials = [0.0f32, -0.0, f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 1e-40, -1e-40, f32::MAX, -f32::MAX];
        let mut coord = |special_every: u64| -> f32 {
            if rng.next_u64() % special_every == 0 {
                specials[(rng.next_u64() % specials.len() as u64) as usize]
            } else {
                ((rng.next_f64() - 0.5) * 200.0) as f32
            }
        };
        let mut meshes = Vec::new();
        for (n, every) in [(0usize, 1u64), (1, 1), (5, 2), (40_000, 5_000), (40_000, 1 << 40), (20_000, 3)] {
            let prims = (0..3).map(|_| Primitive { positions: (0..n).map(|_| [coord(every), coord(every), coord(every)]).collect(), ..Default::default() }).collect();
            meshes.push(Mesh { name: "m".into(), primitives: prims });
        }
        // Every coordinate the same zero but one of the other sign.
        for z in [0.0f32, -0.0] {
            let mut positions = vec![[z; 3]; 30_000];
            positions[17_000] = [-z; 3];
            meshes.push(Mesh { name: "z".into(), primitives: vec![Primitive { positions, ..Default::default() }] });
        }
        let shift: Mat4 = [[2.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.5, 0.0, 3.0, 0.0], [-7.0, 0.25, 1e3, 1.0]];
        let tiny = f64::from_bits(1);
        for mesh in &meshes {
            for bake in [None, Some(IDENTITY), Some(shift)] {
                for h in [0.37, 1e-300, tiny, 1e300, 0.0, -0.0, -2.0, f64::INFINITY, f64::NEG_INFINITY, f64::NAN] {
                    let u = Unit { mesh: 0, bake, h, name: String::new(), instances: Vec::new(), affine: Vec::new() };
                    let want = unit_keys_per_vertex(mesh, &u);
                    for threads in [1, 2, 3] {
                        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
                        let got = pool.install(|| unit_keys(mesh, &u));
                        assert!(same(&got, &want), "h {h:e}, bake {bake:?}, {threads} threads: {got:?} vs {want:?}");
                    }
                }
            }
        }
    }
}
