//! `--export-ply`: samples files and SCT level cuts to PLY point clouds (the layout and the
//! level-cut rule are in [`sct_format::export`]).

use std::io::Read;
use std::path::Path;

use sct_format::export::{samples_file_to_ply, scene_to_ply, ExportSummary};
use sct_format::traverse::TraverseOptions;
use sct_format::Limits;

use crate::InspectError;

/// Default cap on exported points (32 bytes each in the PLY: 3.2 GB).
pub const DEFAULT_MAX_POINTS: u64 = 100_000_000;

/// Exports `file` — a samples file (all samples, every placement) or an SCT file (the cut at
/// `level`, or the leaves) — to the PLY file `out`, in world space. `max_points` is checked
/// before anything is decoded (samples) or written (scenes). Inlines leave the scene's
/// directory only with `allow_outside_inlines`.
pub fn export_ply(file: &Path, out: &Path, level: Option<usize>, max_points: u64, limits: &Limits, allow_outside_inlines: bool) -> Result<ExportSummary, InspectError> {
    let mut magic = [0u8; 8];
    // A regular file only: a FIFO would block the open.
    let n = sct_format::fsio::open_regular(file)?
        .read(&mut magic)
        .map_err(|e| sct_format::Error::io(file, e))?;
    if magic[..n] == sct_format::raw::SAMPLES_MAGIC[..] {
        if level.is_some() {
            return Err(InspectError::Usage("--export-level applies to SCT files; a samples file has no levels".into()));
        }
        return Ok(samples_file_to_ply(file, out, max_points, limits)?);
    }
    let opts = TraverseOptions { limits: limits.clone(), allow_outside_inlines, ..Default::default() };
    Ok(scene_to_ply(file, level, out, opts, max_points)?)
}
