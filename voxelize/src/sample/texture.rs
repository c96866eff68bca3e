//! Texture lookups of the samplers: a material's texture binding, with the image's texels
//! decoded to linear RGBA once ([`decode_textures`]) and a fast bilinear lookup where no
//! wrapping is needed, equal bit for bit to [`Image::sample`].

use rayon::prelude::*;

use crate::mesh::*;

/// A texture as a material binds it: the image, its UV set, transform and wrap modes.
#[derive(Clone, Copy)]
pub(super) struct Tex<'a> {
    pub(super) img: TexImage<'a>,
    pub(super) tr: &'a TextureRef,
    /// The UV transform is the identity: lookups skip it.
    pub(super) plain: bool,
    /// The image's texel grid for [`Tex::interior`].
    pub(super) grid: TexelGrid,
}

/// Width and height of a decoded image as the interior lookup uses them.
#[derive(Clone, Copy)]
pub(super) struct TexelGrid {
    w: f64,
    h: f64,
    /// `w − 1`, `h − 1`: the texel coordinates whose 2×2 block needs no wrapping lie below.
    x_end: f64,
    y_end: f64,
    /// Texels per row (`w`).
    stride: usize,
}

impl<'a> Tex<'a> {
    pub(super) fn new(img: TexImage<'a>, tr: &'a TextureRef) -> Self {
        let (w, h) = (f64::from(img.img.width), f64::from(img.img.height));
        Tex { img, tr, plain: tr.transform == [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], grid: TexelGrid { w, h, x_end: w - 1.0, y_end: h - 1.0, stride: img.img.width as usize } }
    }

    /// Linear RGBA at texture coordinates `uv` (before the transform), bit for bit
    /// [`Image::sample`] of the transformed coordinates with the binding's wrap modes.
    #[inline(always)]
    pub(super) fn sample(&self, uv: [f32; 2]) -> [f32; 4] {
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
    pub(super) fn interior(&self, uv: [f32; 2]) -> Option<[f32; 4]> {
        self.interior_in(self.img.linear?, uv)
    }

    /// [`Tex::interior`] with the decoded texels `lin` (this binding's) at hand.
    #[inline(always)]
    pub(super) fn interior_in(&self, lin: &[[f32; 4]], uv: [f32; 2]) -> Option<[f32; 4]> {
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
pub(super) struct TexImage<'a> {
    pub(super) img: &'a Image,
    /// `width × height` linear texels (the values [`Image::sample`] decodes per lookup).
    pub(super) linear: Option<&'a [[f32; 4]]>,
}

impl TexImage<'_> {
    /// [`Image::sample`], bit for bit; reads pre-decoded texels when there are some. Out of
    /// line: per sample it is the rare path after [`Tex::interior`].
    #[inline(never)]
    pub(super) fn sample(&self, uv: [f32; 2], wrap_s: Wrap, wrap_t: Wrap) -> [f32; 4] {
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
pub(super) fn decode_textures(scene: &LoadedScene) -> Vec<Option<Vec<[f32; 4]>>> {
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
