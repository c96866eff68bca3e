//! Attributes of a point of a triangle: colour (material, vertex colours, textures, alpha)
//! and normal, per sample or from per-triangle planes over the projection plane.

use crate::mesh::*;

use super::texture::Tex;

/// Per-triangle input in grid units.
pub(super) struct Tri {
    pub(super) p: [[f64; 3]; 3],
    pub(super) n: [[f32; 3]; 3],
    pub(super) c: [[f32; 4]; 3],
    pub(super) uv: [[f32; 2]; 3],
    pub(super) uv2: [[f32; 2]; 3],
}

/// Material view used in the hot loop.
pub(super) struct Mat<'a> {
    pub(super) base: [f32; 4],
    pub(super) tex: Option<Tex<'a>>,
    pub(super) alpha_tex: Option<Tex<'a>>,
    pub(super) alpha: AlphaMode,
}

/// Shades a point of a triangle given barycentric weights; `None` = dropped by alpha.
pub(super) fn shade(t: &Tri, w: [f64; 3], mat: &Mat) -> (Option<[f32; 4]>, [f32; 3]) {
    let wf = w.map(|x| x as f32);
    let mix4 = |a: &[[f32; 4]; 3]| -> [f32; 4] { std::array::from_fn(|k| a[0][k] * wf[0] + a[1][k] * wf[1] + a[2][k] * wf[2]) };
    let mix2 = |a: &[[f32; 2]; 3]| -> [f32; 2] { std::array::from_fn(|k| a[0][k] * wf[0] + a[1][k] * wf[1] + a[2][k] * wf[2]) };
    let n = std::array::from_fn(|k| t.n[0][k] * wf[0] + t.n[1][k] * wf[1] + t.n[2][k] * wf[2]);
    (shade_color(mix4(&t.c), mix2(&t.uv), mix2(&t.uv2), mat), n)
}

/// The material colour for vertex colour `vc` and texture coordinates `uv` (colour texture),
/// `uv2` (alpha texture); `None` = dropped by alpha.
#[inline(always)]
pub(super) fn shade_color(vc: [f32; 4], uv: [f32; 2], uv2: [f32; 2], mat: &Mat) -> Option<[f32; 4]> {
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
pub(super) struct Planes<'m> {
    pub(super) o: [f64; 2],
    pub(super) n: [[f32; 3]; 3],
    pub(super) c: [[f32; 3]; 4],
    pub(super) uv: [[f32; 3]; 2],
    pub(super) uv2: [[f32; 3]; 2],
    /// The colour when it is the same everywhere (no texture, equal vertex colours).
    pub(super) flat_c: Option<Option<[f32; 4]>>,
    /// The unit normal when the corner normals are equal (and not zero).
    pub(super) flat_n: Option<[f32; 3]>,
    /// Unit face normal, for interpolated normals of (near) zero length.
    pub(super) face_n: [f32; 3],
    /// The vertex colour when the corners share it (a textured triangle's colour varies
    /// while this does not): used as it is, its planes being flat.
    pub(super) vc: Option<[f32; 4]>,
    pub(super) mat: &'m Mat<'m>,
}

impl<'m> Planes<'m> {
    pub(super) fn new(t: &Tri, q: &[[f64; 2]; 3], fnrm: [f64; 3], mat: &'m Mat<'m>) -> Self {
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
        let flat_n = (t.n[0] == t.n[1] && t.n[0] == t.n[2]).then(|| near_face(unit_or(t.n[0], face_n), face_n));
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
    pub(super) fn shade(&self, p: [f64; 2]) -> (Option<[f32; 4]>, [f32; 3]) {
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
            None => near_face(unit_or(self.n.each_ref().map(at), self.face_n), self.face_n),
        };
        (c, n)
    }
}

/// A sample's normal leans at most 5° from its triangle's own normal. A file's
/// shading normals (or smoothed corner normals) can lean far from the geometry: a capsule made
/// by stretching a sphere keeps the sphere's normals, 15° off on average and 28° at most. A
/// renderer culls a one-sided tree by the samples' normals, so with such normals it hides
/// surface that faces the eye near the silhouette and shows surface that faces away (the
/// capsule lost 7 % of its outline and showed its far wall, mirrored, through the holes).
/// Leaning at most 5° keeps culling wrong only on surface seen within 5° of edge-on, and
/// keeps most of the smooth look: measured on the shared models, 0° (face normals) cost a
/// coarse bunny 2.6 dB of its shading and 10° left the spider's thin legs culled. This is
/// the bound's cosine; [`LEAN_SIN`] its sine.
const LEAN_COS: f32 = 0.996_194_7;
const LEAN_SIN: f32 = 0.087_155_74;

/// Unit `n` turned towards the unit face normal `f` until it leans at most 5° from it
/// ([`LEAN_COS`]).
#[inline(always)]
pub(super) fn near_face(n: [f32; 3], f: [f32; 3]) -> [f32; 3] {
    let d = n[0] * f[0] + n[1] * f[1] + n[2] * f[2];
    if d >= LEAN_COS {
        return n;
    }
    let t = [n[0] - d * f[0], n[1] - d * f[1], n[2] - d * f[2]];
    let l = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
    if l < 1e-12 {
        return f;
    }
    std::array::from_fn(|k| f[k] * LEAN_COS + t[k] / l * LEAN_SIN)
}

/// `n` scaled to unit length, or `fallback` when it is (nearly) zero.
#[inline]
pub(super) fn unit_or(n: [f32; 3], fallback: [f32; 3]) -> [f32; 3] {
    let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if l > 1e-12 {
        let inv = 1.0 / l;
        n.map(|x| x * inv)
    } else {
        fallback
    }
}

pub(super) fn face_axes(t: &Tri) -> ([f64; 3], usize, usize, usize) {
    let fnrm = cross(sub(t.p[1], t.p[0]), sub(t.p[2], t.p[0]));
    let ax = fnrm.map(f64::abs);
    let d = if ax[0] >= ax[1] && ax[0] >= ax[2] { 0 } else if ax[1] >= ax[2] { 1 } else { 2 };
    (fnrm, d, (d + 1) % 3, (d + 2) % 3)
}

/// Whether face normal `fnrm` (largest component on axis `d`, [`face_axes`]) gives the
/// triangle a plane in the sampling frame. The loader drops triangles without area, but a
/// singular placement baked into world space (a zero scale) flattens the others too: such a
/// triangle has no area to sample, and its depth plane would divide by zero.
pub(super) fn has_plane(fnrm: [f64; 3], d: usize) -> bool {
    let m = fnrm[d].abs();
    m > 0.0 && m.is_finite()
}

pub(super) fn srgb8(c: [f32; 4]) -> [u8; 4] {
    let a = (c[3].clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
    let t = Srgb8::get();
    [t.encode(c[0]), t.encode(c[1]), t.encode(c[2]), a]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Normals leaning more than 5° from the face (even pointing behind it)
    /// are turned to lean exactly that much, towards their own side; closer ones are kept.
    #[test]
    fn normals_lean_at_most_the_bound_from_the_face() {
        let lean = 5f32.to_radians();
        assert!((LEAN_COS - lean.cos()).abs() < 1e-7 && (LEAN_SIN - lean.sin()).abs() < 1e-7);
        let f = [0.0f32, 0.0, 1.0];
        for deg in [0.0f32, 2.0, 4.9, 5.1, 15.0, 28.0, 89.0, 135.0, 180.0] {
            let a = deg.to_radians();
            let n = [a.sin(), 0.0, a.cos()];
            let m = near_face(n, f);
            let len = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
            assert!((len - 1.0).abs() < 1e-5, "{deg}°: length {len}");
            let got = m[2].clamp(-1.0, 1.0).acos();
            let want = a.min(lean);
            assert!((got - want).abs() < 1e-4, "{deg}°: leans {} want {}", got.to_degrees(), want.to_degrees());
            if deg > 0.0 && deg < 180.0 {
                assert!(m[0] > 0.0, "{deg}°: turned to the other side");
            }
        }
    }
    use super::super::texture::{decode_textures, TexImage};

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
}
