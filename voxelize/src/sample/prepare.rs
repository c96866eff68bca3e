//! Primitives ready for sampling: positions in grid units of their unit's frame, normals
//! transformed or computed, materials bound to decoded textures.

use crate::mesh::*;

use super::plan::Unit;
use super::shade::{Mat, Tri};
use super::texture::{Tex, TexImage};

/// A material with owned texture references (a `Prepared` outlives the scene borrow only
/// through the images).
pub(super) struct MatOwned<'a> {
    pub(super) base: [f32; 4],
    pub(super) tex: Option<(TexImage<'a>, TextureRef)>,
    pub(super) alpha_tex: Option<(TexImage<'a>, TextureRef)>,
    pub(super) alpha: AlphaMode,
}

impl MatOwned<'_> {
    pub(super) fn view(&self) -> Mat<'_> {
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
pub(super) struct Prepared<'a> {
    pub(super) prim: &'a Primitive,
    pub(super) mat: MatOwned<'a>,
    pub(super) pos: Vec<[f64; 3]>,
    pub(super) nrm: Option<Vec<[f32; 3]>>,
    pub(super) computed: Option<Vec<[[f32; 3]; 3]>>,
    /// `computed` through the bake, in the flipped winding when it mirrors: what [`Self::tri`]
    /// reads, done once rather than per (triangle, slab).
    pub(super) baked: Option<Vec<[[f32; 3]; 3]>>,
    pub(super) flip: bool,
}

impl<'a> Prepared<'a> {
    pub(super) fn new(prim: &'a Primitive, u: &Unit, mat: MatOwned<'a>, crease_deg: f32) -> Self {
        use rayon::prelude::*;
        let inv_h = 1.0 / u.h;
        let pos: Vec<[f64; 3]> = prim
            .positions
            .par_iter()
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
            ns.par_iter()
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
        let computed = if nrm.is_none() && !finer_than_voxels(prim, &pos) { Some(corner_normals(prim, crease_deg)) } else { None };
        let baked = computed.as_ref().map(|c| c.iter().map(|&c| bake_corner_normals(c, u.bake.as_ref(), flip)).collect());
        Prepared { prim, mat, pos, nrm, computed, baked, flip }
    }

    /// Triangle `ti` with its attributes.
    pub(super) fn tri(&self, ti: usize) -> Tri {
        let prim = self.prim;
        let t = prim.triangles[ti];
        // A mirroring bake flips the winding; swap to keep the front side.
        let idx = if self.flip { [t[0], t[2], t[1]] } else { t };
        let vi = idx.map(|i| i as usize);
        let p = vi.map(|i| self.pos[i]);
        let n = match (&self.nrm, &self.baked) {
            (Some(n), _) => front_facing(vi.map(|i| n[i]), &p),
            (None, Some(c)) => c.get(ti).copied().unwrap_or_default(),
            _ => [[0.0; 3]; 3],
        };
        let uvset = self.mat.tex.as_ref().and_then(|t| prim.uvs.get(t.1.tex_coord as usize));
        let uvset2 = self.mat.alpha_tex.as_ref().and_then(|t| prim.uvs.get(t.1.tex_coord as usize));
        Tri {
            p,
            n,
            c: vi.map(|i| prim.colors.as_ref().map_or([1.0; 4], |c| c[i])),
            uv: vi.map(|i| uvset.map_or([0.0; 2], |s| s[i])),
            uv2: vi.map(|i| uvset2.map_or([0.0; 2], |s| s[i])),
        }
    }
}

/// Whether a primitive's triangles are on average smaller than half a voxel's face (`pos` in
/// grid units): each sample then merges several triangles' pieces, whose face normals average
/// to the smooth normal there, and a sample's normal may lean only 5° from its pieces' faces
/// anyway ([`super::shade::near_face`]). Smoothed corner normals would change almost nothing
/// and cost a third of a dense mesh's conversion (a random walk over each vertex's faces):
/// such primitives take their face normals. Coarser ones keep them for a smooth look.
fn finer_than_voxels(prim: &Primitive, pos: &[[f64; 3]]) -> bool {
    use rayon::prelude::*;
    let n = prim.triangles.len();
    if n == 0 {
        return false;
    }
    let area2: f64 = prim
        .triangles
        .par_iter()
        .map(|t| match t.map(|i| pos.get(i as usize)) {
            [Some(a), Some(b), Some(c)] => norm(cross(sub(*b, *a), sub(*c, *a))),
            _ => 0.0,
        })
        .sum();
    // Mean area below 1/2 voxel², i.e. its double below 1.
    area2 < n as f64
}

/// The file's corner normals `n` of the triangle `p`, each turned to the side its winding
/// calls the front. Renderers cull one-sided trees by the samples' normals while the mesh
/// reference (and every mesh renderer) culls by winding: a file whose normals point inward
/// would otherwise show a closed model's inside (the far wall, mirrored) where its front
/// should be. Two-sided trees light by |n·l|, so the sign changes nothing there.
fn front_facing(mut n: [[f32; 3]; 3], p: &[[f64; 3]; 3]) -> [[f32; 3]; 3] {
    let f = cross(sub(p[1], p[0]), sub(p[2], p[0]));
    for c in &mut n {
        if f64::from(c[0]) * f[0] + f64::from(c[1]) * f[1] + f64::from(c[2]) * f[2] < 0.0 {
            *c = c.map(|x| -x);
        }
    }
    n
}

/// A triangle's computed corner normals as [`Prepared::tri`] gives them: in the winding of
/// `flip`, through `bake` and normalised.
pub(super) fn bake_corner_normals(c: [[f32; 3]; 3], bake: Option<&Mat4>, flip: bool) -> [[f32; 3]; 3] {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A grid of `k × k` squares (two triangles each) over `side` grid units.
    fn grid(k: u32, side: f64) -> (Primitive, Vec<[f64; 3]>) {
        let mut positions = Vec::new();
        for j in 0..=k {
            for i in 0..=k {
                positions.push([i as f32, j as f32, 0.0]);
            }
        }
        let at = |i: u32, j: u32| j * (k + 1) + i;
        let triangles = (0..k).flat_map(|j| (0..k).flat_map(move |i| [[at(i, j), at(i + 1, j), at(i + 1, j + 1)], [at(i, j), at(i + 1, j + 1), at(i, j + 1)]])).collect();
        let pos = positions.iter().map(|p: &[f32; 3]| p.map(|x| f64::from(x) * side / k as f64)).collect();
        (Primitive { positions, triangles, ..Default::default() }, pos)
    }

    /// Corner normals are skipped only where triangles are finer than the voxels.
    #[test]
    fn fine_primitives_take_face_normals() {
        let (p, pos) = grid(40, 10.0); // triangles of 0.03 voxel²
        assert!(finer_than_voxels(&p, &pos));
        let (p, pos) = grid(4, 10.0); // 3.1 voxel²
        assert!(!finer_than_voxels(&p, &pos));
        assert!(!finer_than_voxels(&Primitive::default(), &[]));
    }
}
