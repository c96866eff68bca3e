//! One-step conversion: meshes → SCT in one process, running the voxelizer in memory (no
//! samples file on disk). Used by `sct-build-tree model.glb -o model.sct` and by
//! [`crate::batch`].

use std::path::{Path, PathBuf};
use std::time::Instant;

use voxelize::args::SamplingArgs;

use crate::error::BuildError;
use crate::pipeline::{run_samples, Config, Report, Upstream};

/// File extensions (lowercase) that are converted as meshes.
pub const MESH_EXTENSIONS: [&str; 4] = ["obj", "gltf", "glb", "ply"];

/// Whether `path` names a mesh the voxelizer reads (by extension, case-insensitive).
pub fn is_mesh_path(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| MESH_EXTENSIONS.iter().any(|m| m.eq_ignore_ascii_case(e)))
}

/// A failed conversion: the sampling step or the build step.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConvertError {
    /// Loading or sampling the meshes failed.
    #[error("sampling: {0}")]
    Sample(#[from] voxelize::Error),
    /// Building or writing the SCT file failed.
    #[error(transparent)]
    Build(#[from] BuildError),
    /// The sampling step warned and warnings were to fail the conversion (`--strict`);
    /// nothing was written.
    #[error("{} warning(s) with --strict, nothing written: {}", .0.len(), .0.join("; "))]
    Warnings(Vec<String>),
}

impl ConvertError {
    /// Process exit code: 1 for bad input, 2 for usage and I/O errors.
    pub fn exit_code(&self) -> i32 {
        match self {
            ConvertError::Sample(e) => e.exit_code(),
            ConvertError::Build(e) => e.exit_code(),
            ConvertError::Warnings(_) => 1,
        }
    }
}

/// What a one-step conversion did: the voxelizer's summary and the build report.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ConvertReport {
    /// The sampling step (as `sct-voxelize --json` prints it; nothing written).
    pub sampling: voxelize::Summary,
    /// The build step (as `sct-build-tree --json` prints it).
    pub build: Report,
}

/// Batch bookkeeping recorded in a conversion's provenance.
#[derive(Clone, Copy, Debug)]
pub struct BatchTag<'a> {
    /// Hash of everything besides the sources that determines the output
    /// ([`crate::batch::job_key`]).
    pub key: &'a str,
    /// The library root: sources below it are recorded relative to it, so the up-to-date
    /// check does not depend on the directory the batch is run from.
    pub root: &'a Path,
    /// The asset's options file ([`crate::sidecar`]): a source when it exists, else a
    /// missing file whose appearance makes the output stale.
    pub sidecar: &'a Path,
}

/// Samples `inputs` in one grid with `sampling`'s options and builds `cfg.output` from the
/// samples in memory (`cfg.samples` is ignored). `batch`, when given, records the job key in
/// the provenance and the sources relative to the library root (batch mode uses both to
/// recognise up-to-date outputs).
pub fn convert_meshes(
    inputs: &[PathBuf],
    sampling: &SamplingArgs,
    cfg: &Config,
    batch: Option<BatchTag<'_>>,
    phase: &mut dyn FnMut(&str),
) -> Result<ConvertReport, ConvertError> {
    convert_meshes_checked(inputs, sampling, cfg, batch, false, phase)
}

/// [`convert_meshes`], failing with [`ConvertError::Warnings`] before anything is written
/// when `deny_warnings` is set and the sampling step warned (`--strict`).
///
/// In batch mode the provenance also records, under the sampling step's parameters, the
/// conversion's `warnings` (so an up-to-date output reports them again) and the
/// `missing_sources`: files the asset references that were not found, and its absent
/// options file (so that one appearing makes the output stale).
pub fn convert_meshes_checked(
    inputs: &[PathBuf],
    sampling: &SamplingArgs,
    cfg: &Config,
    batch: Option<BatchTag<'_>>,
    deny_warnings: bool,
    phase: &mut dyn FnMut(&str),
) -> Result<ConvertReport, ConvertError> {
    let t0 = Instant::now();
    phase("sampling meshes");
    let opts = voxelize::Options {
        inputs: inputs.to_vec(),
        output: None,
        load: sampling.load_options(),
        sample: sampling.sample_options(),
    };
    let (samples, summary) = voxelize::sample_in_memory(&opts, &|_, _| {})?;
    if deny_warnings && !summary.warnings.is_empty() {
        return Err(ConvertError::Warnings(summary.warnings));
    }
    let mut generator = samples.generator.clone();
    if let Some(tag) = batch {
        let relative = |p: &str| match Path::new(p).strip_prefix(tag.root) {
            Ok(rel) => rel.components().map(|c| c.as_os_str().to_string_lossy()).collect::<Vec<_>>().join("/"),
            Err(_) => p.to_string(),
        };
        let mut missing: Vec<String> = summary.missing_inputs.iter().map(|p| relative(p)).collect();
        match sct_format::atomic::hash_file(tag.sidecar) {
            Ok(blake3) => generator.sources.push(sct_format::SourceRef { path: tag.sidecar.display().to_string(), blake3 }),
            Err(_) => missing.push(relative(&tag.sidecar.display().to_string())),
        }
        if let Some(map) = generator.parameters.as_object_mut() {
            map.insert("job_key".into(), serde_json::Value::String(tag.key.to_string()));
            map.insert("missing_sources".into(), serde_json::json!(missing));
            map.insert("warnings".into(), serde_json::json!(summary.warnings));
        }
        for s in &mut generator.sources {
            s.path = relative(&s.path);
        }
    }
    let build = run_samples(cfg, samples, Upstream::Sampled(generator), t0, phase)?;
    Ok(ConvertReport { sampling: summary, build })
}
