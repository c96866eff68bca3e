//! Per-asset options in batch mode: `NAME.EXT.options.json` beside an asset, e.g.
//! `spot.obj.options.json` holding `{"texture": "spot_texture.png"}` (paths relative to the
//! asset's folder). Batch mode refuses `--texture`, which would re-texture every asset; an
//! options file sets it for one. The file is part of the job's identity: a changed, added
//! or removed options file makes the output stale.

use std::path::{Path, PathBuf};

use voxelize::args::SamplingArgs;

/// Suffix appended to an asset's file name to name its options file.
pub const SIDECAR_SUFFIX: &str = ".options.json";

/// Largest options file read, in bytes.
const MAX_SIDECAR_BYTES: u64 = 64 << 10;

/// The options an asset's options file may set.
#[derive(Clone, Debug, Default, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
#[non_exhaustive]
pub struct AssetOptions {
    /// Base-colour texture for the asset's primitives that have UVs but no texture of their
    /// own (as `--texture` in single-file mode), relative to the asset's folder.
    pub texture: Option<PathBuf>,
}

/// The options file of the asset at `input`.
pub fn sidecar_path(input: &Path) -> PathBuf {
    let mut name = input.file_name().unwrap_or_default().to_os_string();
    name.push(SIDECAR_SUFFIX);
    input.with_file_name(name)
}

/// Reads the options file of `input`, if there is one. Err: why it cannot be used (not
/// readable, not JSON, an unknown key): a bad input, the asset is not converted.
pub fn read_asset_options(input: &Path) -> Result<Option<AssetOptions>, String> {
    let path = sidecar_path(input);
    if !path.exists() {
        return Ok(None);
    }
    let bytes = sct_format::fsio::read_regular(&path, MAX_SIDECAR_BYTES).map_err(|e| format!("{}: {e}", path.display()))?;
    serde_json::from_slice::<AssetOptions>(&bytes).map(Some).map_err(|e| format!("{}: {e} (expected e.g. {{\"texture\": \"albedo.png\"}})", path.display()))
}

impl AssetOptions {
    /// `base` with these options applied for the asset at `input`.
    pub fn apply(&self, base: &SamplingArgs, input: &Path) -> SamplingArgs {
        let mut s = base.clone();
        if let Some(t) = &self.texture {
            s.texture = Some(input.parent().unwrap_or(Path::new("")).join(t));
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn options_files_are_read_and_checked() {
        let d = tempfile::tempdir().expect("tempdir");
        let asset = d.path().join("spot.obj");
        assert_eq!(sidecar_path(&asset), d.path().join("spot.obj.options.json"));
        assert_eq!(read_asset_options(&asset), Ok(None));
        std::fs::write(sidecar_path(&asset), br#"{"texture": "tex/spot.png"}"#).expect("write");
        let o = read_asset_options(&asset).expect("read").expect("some");
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            s: SamplingArgs,
        }
        let base = <Cli as clap::Parser>::parse_from(["x"]).s;
        let s = o.apply(&base, &asset);
        assert_eq!(s.texture, Some(d.path().join("tex/spot.png")));
        std::fs::write(sidecar_path(&asset), br#"{"textur": "x.png"}"#).expect("write");
        let e = read_asset_options(&asset).unwrap_err();
        assert!(e.contains("unknown field") && e.contains("spot.obj.options.json"), "{e}");
    }
}
