//! `--export-ply`: samples files and SCT level cuts to PLY point clouds (the layout and the
//! level-cut rule are in [`sct_format::export`]).

use std::io::Read;
use std::path::Path;

use sct_format::export::{samples_to_ply, scene_to_ply, ExportSummary};
use sct_format::samples::SamplesFile;
use sct_format::traverse::TraverseOptions;
use sct_format::Limits;

use crate::InspectError;

/// Default cap on exported points (32 bytes each in the PLY: 3.2 GB).
pub const DEFAULT_MAX_POINTS: u64 = 100_000_000;

/// Exports `file` — a samples file (all samples, every placement) or an SCT file (the cut at
/// `level`, or the leaves) — to the PLY file `out`, in world space.
pub fn export_ply(file: &Path, out: &Path, level: Option<usize>, max_points: u64, limits: &Limits) -> Result<ExportSummary, InspectError> {
    let mut magic = [0u8; 8];
    let n = std::fs::File::open(file)
        .and_then(|mut f| f.read(&mut magic))
        .map_err(|e| sct_format::Error::io(file, e))?;
    if magic[..n] == sct_format::raw::SAMPLES_MAGIC[..] {
        if level.is_some() {
            return Err(InspectError::Usage("--export-level applies to SCT files; a samples file has no levels".into()));
        }
        let samples = SamplesFile::read_file(file, limits)?;
        return Ok(samples_to_ply(&samples, out, max_points)?);
    }
    let opts = TraverseOptions { limits: limits.clone(), ..Default::default() };
    Ok(scene_to_ply(file, level, out, opts, max_points)?)
}
