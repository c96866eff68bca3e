//! The sampling flags as a reusable clap argument group: `sct-voxelize` and the one-step
//! mesh conversion of `sct-build-tree` flatten the same struct, so every voxelize option
//! is available in both with the same names, defaults and help.

use std::path::PathBuf;

use clap::{Args, ValueEnum};

use crate::load::LoadOptions;
use crate::sample::{AreaMode, Density, Method, SampleOptions};

/// The sample budget of the default density and of batch conversion: about four leaves per
/// pixel of a full 1280 × 720 view, so an ordinary model at the default density (2–3 leaves
/// per pixel it covers) never meets it, while a file of stacked surfaces, or EQ 16 on a
/// finely tessellated asset in a library, cannot take the memory of a conversion (about
/// 125 B per sample at its peak: 500 MB).
pub const DEFAULT_SAMPLE_BUDGET: u64 = 4_000_000;

/// Sampler choice on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MethodArg {
    /// Conservative scan-line voxelization: every voxel a triangle crosses (coverage guaranteed).
    Voxel,
    /// The thesis' scan-line: one sample per covered grid-column centre (≈ 40 % fewer samples than voxel at one voxel size, each ≈ 1.6× cheaper; no coverage guarantee near triangle edges).
    Scanline,
    /// QSplat vertex patches: one sample per vertex, radius = longest incident edge.
    Vertex,
}

/// Density rule on the command line (when no --voxel-size or --distance is given).
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DensityArg {
    /// The intended view: the model framed as sct-render-preview frames it by default (90 % of 1280 × 720, 40°), voxels --screen-error pixels wide there (default 1.5: its default --pixel-error 0.75 draws splats up to 1.5 px across).
    View,
    /// The thesis's EQ 16 from the mesh's edge lengths (--k, --gamma, --min-base): follows the triangles, not any view.
    Eq16,
}

/// Area mode on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum AreaArg {
    /// Exact area of triangle ∩ voxel.
    Exact,
    /// Thesis EQ 17: triangle area / samples of the triangle.
    Eq17,
}

/// How meshes are sampled (thesis §5.2). The voxel size comes from --voxel-size, else from
/// a viewing target (--screen-error with --distance), else from the --density rule: the
/// intended view (default) or EQ 16.
#[derive(Args, Clone, Debug, serde::Serialize)]
#[command(next_help_heading = "Sampling (mesh inputs)")]
pub struct SamplingArgs {
    /// Sampler.
    #[arg(long, value_enum, default_value = "voxel")]
    pub method: MethodArg,
    /// Voxel edge length in world units (overrides everything else).
    #[arg(long, value_name = "LEN")]
    pub voxel_size: Option<f64>,
    /// Density rule: the intended view (default preview framing, voxels 1.5 px wide) or the thesis's EQ 16.
    #[arg(long, value_enum, default_value = "view")]
    pub density: DensityArg,
    /// EQ 16: standard deviations below the mean edge length [default: 3]; implies --density eq16.
    #[arg(long)]
    pub k: Option<f64>,
    /// EQ 16: samples per base length [default: 2]; implies --density eq16.
    #[arg(long)]
    pub gamma: Option<f64>,
    /// EQ 16: minimum base length β (default a quarter of the mean edge length); implies --density eq16.
    #[arg(long, value_name = "LEN")]
    pub min_base: Option<f64>,
    /// Leaf size in pixels: of the intended view (--density view), or, with --distance, the largest projected sample diameter of that viewing target.
    #[arg(long, value_name = "PX")]
    pub screen_error: Option<f64>,
    /// Viewing target: image width in pixels.
    #[arg(long, value_name = "PX", default_value_t = 1920.0)]
    pub resolution: f64,
    /// Viewing target: nearest viewing distance in world units.
    #[arg(long, value_name = "LEN")]
    pub distance: Option<f64>,
    /// Viewing target: horizontal field of view in degrees.
    #[arg(long, value_name = "DEG", default_value_t = 60.0)]
    pub fov: f64,
    /// How samples get their area.
    #[arg(long, value_enum, default_value = "exact")]
    pub area: AreaArg,
    /// Keep one sample per triangle per voxel (no merging of samples sharing a voxel).
    #[arg(long)]
    pub no_merge: bool,
    /// Crease angle (degrees) for normals computed when a mesh has none.
    #[arg(long, value_name = "DEG", default_value_t = 60.0)]
    pub crease: f32,
    /// Bind this image as the base-colour texture of the primitives that have texture
    /// coordinates but no texture of their own (an OBJ without MTL, e.g. spot); textures
    /// the model brings are kept. Not in batch mode (see NAME.EXT.options.json there).
    #[arg(long, value_name = "IMAGE")]
    pub texture: Option<PathBuf>,
    /// Ignore textures (colours from factors and vertex colours).
    #[arg(long)]
    pub no_textures: bool,
    /// Let glTF buffer and image URIs name files outside the model's directory (absolute
    /// paths, file: URIs, `..`, symlinks leading out); refused by default.
    #[arg(long)]
    pub allow_outside_uris: bool,
    /// Refuse runs estimated to make more samples than this.
    #[arg(long, value_name = "N", default_value_t = 400_000_000)]
    pub max_samples: u64,
    /// Coarsen the voxel, when the density rule above would make more, to about N samples,
    /// with a warning [default: 4000000 with the default density and in batch mode; none
    /// when --voxel-size, --distance or EQ 16 ask for a density].
    #[arg(long, value_name = "N")]
    pub sample_budget: Option<u64>,
}

impl SamplingArgs {
    /// The density rule these flags select.
    pub fn density(&self) -> Density {
        if let Some(h) = self.voxel_size {
            Density::VoxelSize(h)
        } else if let Some(d) = self.distance {
            Density::Screen { pixels: self.screen_error.unwrap_or(1.0), resolution: self.resolution, distance: d, fov_deg: self.fov }
        } else {
            // A flag of EQ 16 asks for EQ 16: it would otherwise be silently ignored.
            let eq16 = self.density == DensityArg::Eq16 || self.k.is_some() || self.gamma.is_some() || self.min_base.is_some();
            if eq16 {
                Density::Auto { k: self.k.unwrap_or(3.0), gamma: self.gamma.unwrap_or(2.0), min_base: self.min_base }
            } else {
                Density::View { pixels: self.screen_error.unwrap_or(Density::VIEW_PIXELS) }
            }
        }
    }

    /// Loader options.
    pub fn load_options(&self) -> LoadOptions {
        LoadOptions {
            texture_override: self.texture.clone(),
            load_textures: !self.no_textures,
            allow_outside_uris: self.allow_outside_uris,
            ..Default::default()
        }
    }

    /// Sampler options.
    pub fn sample_options(&self) -> SampleOptions {
        SampleOptions {
            method: match self.method {
                MethodArg::Voxel => Method::Voxel,
                MethodArg::Scanline => Method::Scanline,
                MethodArg::Vertex => Method::Vertex,
            },
            density: self.density(),
            area: match self.area {
                AreaArg::Exact => AreaMode::Exact,
                AreaArg::Eq17 => AreaMode::Eq17,
            },
            merge: !self.no_merge,
            crease_deg: self.crease,
            max_samples: self.max_samples,
            // The intended view needs no more than a few samples per pixel; more means many
            // surfaces stacked behind each other (a hostile file of a few KB can ask for
            // billions), so the default density gets a default budget. Explicit densities
            // are bounded by --max-samples.
            budget: self.sample_budget.or(matches!(self.density(), Density::View { .. }).then_some(DEFAULT_SAMPLE_BUDGET)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        s: SamplingArgs,
    }

    #[test]
    fn density_precedence_voxel_size_then_screen_then_rule() {
        let p = |a: &[&str]| Cli::try_parse_from(std::iter::once("x").chain(a.iter().copied())).map(|c| c.s.density());
        assert!(matches!(p(&["--voxel-size", "0.5", "--screen-error", "1", "--distance", "3"]), Ok(Density::VoxelSize(h)) if h == 0.5));
        assert!(matches!(p(&["--screen-error", "1", "--distance", "3"]), Ok(Density::Screen { distance, .. }) if distance == 3.0));
        // The default is the intended view; --screen-error alone sets its leaf width.
        assert!(matches!(p(&[]), Ok(Density::View { pixels }) if pixels == Density::VIEW_PIXELS));
        assert!(matches!(p(&["--screen-error", "2"]), Ok(Density::View { pixels }) if pixels == 2.0));
        // EQ 16 only when asked for.
        assert!(matches!(p(&["--density", "eq16", "--k", "2"]), Ok(Density::Auto { k, gamma, .. }) if k == 2.0 && gamma == 2.0));
        assert!(matches!(p(&["--density", "eq16"]), Ok(Density::Auto { k, gamma, .. }) if k == 3.0 && gamma == 2.0));
        // Its own flags imply it rather than being ignored.
        assert!(matches!(p(&["--gamma", "4"]), Ok(Density::Auto { k, gamma, .. }) if k == 3.0 && gamma == 4.0));
    }
}
