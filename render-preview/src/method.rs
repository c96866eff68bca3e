//! The preview methods behind `--method`, and the work counters every method reports.
//!
//! | method | what it draws | order | quality knob |
//! |---|---|---|---|
//! | `zbuffer` (default) | opaque elliptical splats of the LOD cut | depth buffer | `--pixel-error` |
//! | `gauss` | elliptical Gaussian kernels of the same cut (Coconu & Hege) | per-frame depth sort, back to front, no depth buffer | `--pixel-error` (the sample spacing `d_t` on screen) |
//! | `canopy` | EQ 46 discs of the nodes' spheres, cut at `t3`, after image-graph occlusion culling (thesis) | reverse occlusion-mask order, no depth buffer | `--canopy-t3` (px) |
//! | `parilov` | one pixel per node of the cut (nodes at most `--pixel-error` px wide), in cells | cells back to front by split planes, each cell's kept sample order (Parilov & Stuerzlinger), no depth buffer | `--pixel-error` (px wide); `--parilov-threshold` (°) |
//! | `wald` | the implicit surface of hat-weighted splats of every leaf in view (Wald & Seidel; far internal nodes below half of `--pixel-error` stand for their leaves), one ray per pixel | first sign change along each ray | `--wald-radius-scale` (and `--wald-k`) |
//! | `wand` | fresh random leaf points each frame, ∝ projected area, `ln v` per pixel, as `d × d` squares; leaves larger than `d / ln v` px² as `zbuffer` splats (Wand et al.) | depth buffer | `--wand-d` (px) |
//!
//! Every method walks the same scene graph (groups, instances, tints, inlines). `zbuffer` and
//! `gauss` refine it with the same LOD test, so at equal `--pixel-error` they draw the same cut
//! and differ only in how they composite it; `canopy` has its own three-stage refinement;
//! `wald` takes every leaf in view (but for subtrees below half a pixel) and ray-traces them.
//! `wand` draws no level of detail at all (its randomness is the LOD) and refines group trees
//! and inlines only, with the same test.

use rayon::prelude::*;

use crate::raster::Splat;

/// A preview method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Opaque elliptical splats resolved by a depth buffer (thesis §5.8 discs, LOD cut).
    #[default]
    Zbuffer,
    /// Elliptical Gaussian splats alpha-blended back to front, no depth buffer (Coconu & Hege).
    Gauss,
    /// The thesis's image-graph occlusion culling and reverse-mask-order discs, no depth
    /// buffer (§3.3, §5.4–5.8).
    Canopy,
    /// Multi-view visibility orderings: one pixel per sample in kept per-cell orders, cells
    /// back to front, no depth buffer (Parilov & Stuerzlinger).
    Parilov,
    /// One ray per pixel through the implicit surface of hat-weighted splats of every leaf
    /// (Wald & Seidel 2005).
    Wald,
    /// The randomized z-buffer: random surface points drawn with probability proportional
    /// to projected area, as `d × d` squares through a depth buffer (Wand et al.).
    Wand,
}

impl Method {
    /// Every method, in the order charts list them.
    pub const ALL: [Method; 6] = [Method::Zbuffer, Method::Gauss, Method::Canopy, Method::Parilov, Method::Wald, Method::Wand];

    /// The name used on the command line and in JSON.
    pub fn name(self) -> &'static str {
        match self {
            Method::Zbuffer => "zbuffer",
            Method::Gauss => "gauss",
            Method::Canopy => "canopy",
            Method::Parilov => "parilov",
            Method::Wald => "wald",
            Method::Wand => "wand",
        }
    }

    /// The name of the method's quality knob.
    pub fn knob(self) -> &'static str {
        match self {
            Method::Zbuffer | Method::Gauss | Method::Parilov => "pixel_error",
            Method::Canopy => "t3",
            Method::Wald => "radius_scale",
            Method::Wand => "d",
        }
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Method::ALL.into_iter().find(|m| m.name() == s).ok_or_else(|| format!("unknown method {s:?} (zbuffer, gauss, canopy, parilov, wald, wand)"))
    }
}

/// Work a render did, comparable across methods (`work` in the JSON).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Work {
    /// Scene-tree nodes examined by the refinement.
    pub nodes_visited: u64,
    /// Primitives drawn (splats or kernels).
    pub primitives: u64,
    /// Pixel writes: pixel centres inside a primitive (depth-tested or blended).
    pub fragments: u64,
    /// Pixels covered in the image.
    pub covered_pixels: u64,
    /// `fragments / covered_pixels` (0 when nothing is covered).
    pub overdraw: f64,
    /// SCT bytes read (index and decoded blocks).
    pub bytes_read: u64,
}

impl Work {
    pub(crate) fn new(nodes_visited: u64, primitives: u64, fragments: u64, covered_pixels: u64, bytes_read: u64) -> Work {
        let overdraw = if covered_pixels == 0 { 0.0 } else { fragments as f64 / covered_pixels as f64 };
        Work { nodes_visited, primitives, fragments, covered_pixels, overdraw, bytes_read }
    }
}

/// Pixel centres inside the splats (clipped to a `w × h` frame): the fragments a depth
/// buffer tests. Counted apart from the timed rasterization, by row spans
/// ([`Splat::pixels_covered`]).
pub fn count_fragments(splats: &[Splat], w: usize, h: usize) -> u64 {
    splats
        .par_chunks(4096)
        .map(|chunk| {
            let mut n = 0u64;
            for s in chunk {
                n += s.pixels_covered(w, h);
            }
            n
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for m in Method::ALL {
            assert_eq!(m.name().parse::<Method>().unwrap(), m);
        }
        assert!("canopy2".parse::<Method>().is_err());
    }

    #[test]
    fn fragments_of_a_disc() {
        // Pixel centres within 3 px of (8, 8), as the rasterizer's own test counts them.
        let mut f = crate::Frame::new(16, 16, [0; 4]);
        let s = [Splat::disc(8.0, 8.0, 1.0, 3.0, [1, 1, 1, 255])];
        crate::raster::rasterize(&mut f, &s);
        assert_eq!(count_fragments(&s, 16, 16), f.covered() as u64);
        assert_eq!(count_fragments(&[s[0], s[0]], 16, 16), 2 * f.covered() as u64);
    }
}
