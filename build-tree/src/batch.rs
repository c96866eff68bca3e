//! Batch conversion of an asset library: every mesh under a directory becomes an SCT file
//! under an output directory with the same folder structure.
//!
//! - **Parallel**: `jobs` files at a time, each conversion itself parallel (rayon).
//! - **Incremental**: an output is up to date when its own provenance (`GENR`) records this
//!   tool version, the same job key (a hash of every sampling and build parameter), sources
//!   whose current BLAKE3 hashes still match and referenced files that were missing and
//!   still are (a texture added later makes the output stale); such files are skipped and
//!   report the warnings of the conversion that made them.
//! - **Per asset**: `NAME.EXT.options.json` beside an asset sets its own options
//!   ([`crate::sidecar`]); `--texture` for the whole library is refused.
//! - **Robust**: a failing input is reported and the batch goes on; outputs are written
//!   atomically, so an interrupted run leaves only whole files and simply resumes. Temporary
//!   files of interrupted runs are removed: at once when their process (on this host) is
//!   gone, else after [`STALE_TEMP_AGE`].
//! - **Shardable**: `shard` picks a deterministic subset by a hash of each relative path, so
//!   N machines each run `--shard k/N` with no coordination (see the README).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use sct_format::{Limits, Profile, SctReader};
use voxelize::args::SamplingArgs;

use crate::convert::{convert_meshes_checked, is_mesh_path, BatchTag, ConvertError};
use crate::error::BuildError;
use crate::pipeline::{Config, Refinement};
use crate::progress::{BatchProgress, Tracker};
use crate::tree::{BuildOptions, Weld};

/// Version of the `--json` batch report layout.
pub const REPORT_SCHEMA: &str = "sct-build-tree-batch/1";

/// Bump when the sampler, tree builder or encoders change their output for the same
/// inputs and flags without a crate version change, so batch runs redo old outputs.
pub const ENCODER_REVISION: u32 = 8;

/// Temporary files of other processes younger than this are left alone: they may belong
/// to a run still in progress (a retried shard, another host on shared storage).
pub const STALE_TEMP_AGE: std::time::Duration = std::time::Duration::from_secs(3600);

/// One shard of a batch: this run converts the inputs whose path hash is `index` mod `count`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Shard {
    /// This shard, `0 ≤ index < count`.
    pub index: u32,
    /// Number of shards.
    pub count: u32,
}

impl std::str::FromStr for Shard {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (k, n) = s.split_once('/').ok_or_else(|| format!("expected K/N (e.g. 0/8), got {s:?}"))?;
        let index: u32 = k.trim().parse().map_err(|_| format!("bad shard index {k:?}"))?;
        let count: u32 = n.trim().parse().map_err(|_| format!("bad shard count {n:?}"))?;
        if count == 0 {
            return Err(format!("the shard count N must be at least 1 (K/N with 0 <= K < N, e.g. 0/8), got {s:?}"));
        }
        if index >= count {
            return Err(format!("the shard index K counts from 0 and must be below N = {count} (K/N with 0 <= K < N), got {s:?}"));
        }
        Ok(Shard { index, count })
    }
}

impl Shard {
    /// Whether the input at `rel` (relative path, `/`-separated) belongs to this shard. The
    /// hash of the path, not its position in a listing, so adding files elsewhere in the
    /// library does not move existing files between shards.
    pub fn contains(&self, rel: &str) -> bool {
        let h = blake3::hash(rel.as_bytes());
        let mut b = [0u8; 8];
        b.copy_from_slice(&h.as_bytes()[..8]);
        u64::from_le_bytes(b) % u64::from(self.count) == u64::from(self.index)
    }
}

/// Samples per asset in batch mode unless `--sample-budget` says otherwise, whatever the
/// density rule: the default density's budget ([`voxelize::args::DEFAULT_SAMPLE_BUDGET`]).
pub const DEFAULT_SAMPLE_BUDGET: u64 = voxelize::args::DEFAULT_SAMPLE_BUDGET;

/// What to convert and how.
#[derive(Clone, Debug)]
pub struct BatchOptions {
    /// Library root; every `.obj`, `.gltf`, `.glb` and `.ply` below it is an input.
    pub input_dir: PathBuf,
    /// Output root (created if missing); mirrors the input folders.
    pub output_dir: PathBuf,
    /// Sampling flags (as `sct-voxelize`).
    pub sampling: SamplingArgs,
    /// Node profile.
    pub profile: Profile,
    /// zstd level override.
    pub compression_level: Option<i32>,
    /// Default profile: store centre offsets (spec 1.2).
    pub centre_offsets: bool,
    /// Default profile: which trees store leaf refinement (spec 1.4).
    pub leaf_refinement: Refinement,
    /// Tree options.
    pub build: BuildOptions,
    /// Convert even when the output is up to date.
    pub force: bool,
    /// Only this shard's inputs.
    pub shard: Option<Shard>,
    /// Files converted at the same time (each conversion is itself parallel).
    pub jobs: usize,
    /// A conversion that warns fails (`--strict`), and so does an up-to-date output whose
    /// conversion warned.
    pub deny_warnings: bool,
}

/// Outcome of one input.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum JobStatus {
    /// Converted now.
    Converted,
    /// Skipped: the output's provenance matches the source and parameters.
    UpToDate,
    /// Failed; the batch went on.
    Failed,
}

/// One input's line in the report.
#[derive(Clone, Debug, serde::Serialize)]
pub struct JobResult {
    /// Input path relative to the library root (`/`-separated).
    pub input: String,
    /// Output path relative to the output root.
    pub output: String,
    /// What happened.
    pub status: JobStatus,
    /// The error, for failed inputs.
    pub error: Option<String>,
    /// Exit code the single-file command would have given (0, 1 or 2).
    pub exit_code: i32,
    /// Samples made (converted inputs).
    pub samples: u64,
    /// Leaves in the output (converted inputs).
    pub leaves: u64,
    /// Output size in bytes (converted and up-to-date inputs).
    pub bytes: u64,
    /// Seconds spent on this input.
    pub seconds: f64,
    /// Non-fatal problems of the conversion (missing texture, a mesh left out, ...).
    pub warnings: Vec<String>,
}

/// The whole batch (`--json` output, schema [`REPORT_SCHEMA`]).
#[derive(Clone, Debug, serde::Serialize)]
pub struct BatchReport {
    /// Report layout version.
    pub schema: &'static str,
    /// Library root.
    pub input_dir: String,
    /// Output root.
    pub output_dir: String,
    /// The shard this run converted, if any.
    pub shard: Option<Shard>,
    /// Hash of every sampling and build parameter (recorded in each output's provenance).
    pub job_key: String,
    /// Mesh files found in the library (all shards).
    pub found: u64,
    /// Per input of this shard, sorted by path.
    pub jobs: Vec<JobResult>,
    /// Inputs converted now.
    pub converted: u64,
    /// Inputs skipped as up to date.
    pub up_to_date: u64,
    /// Inputs that failed.
    pub failed: u64,
    /// Stale temporary files of interrupted runs removed.
    pub stale_temp_files_removed: u64,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// Hash of everything that determines an output besides its sources: tool version,
/// sampling flags and build parameters.
pub fn job_key(opts: &BatchOptions) -> String {
    let weld = match opts.build.weld {
        Weld::Off => serde_json::json!("off"),
        Weld::Absolute(t) => serde_json::json!({ "absolute": t }),
        Weld::RelativeToMeanRadius(f) => serde_json::json!({ "relative_to_mean_radius": f }),
    };
    let v = serde_json::json!({
        "tool": "sct-build-tree",
        "version": env!("CARGO_PKG_VERSION"),
        // Encoder changes that keep the crate version still change the output bytes.
        "encoder_revision": ENCODER_REVISION,
        "sampling": serde_json::to_value(&opts.sampling).unwrap_or(serde_json::Value::Null),
        "profile": opts.profile.name(),
        // The effective level, so a changed default invalidates old outputs.
        "compression_level": opts.compression_level.unwrap_or(sct_format::write::DEFAULT_ZSTD_LEVEL),
        "centre_offsets": opts.centre_offsets,
        "leaf_refinement": opts.leaf_refinement,
        "weld": weld,
        "depth_slack": opts.build.depth_slack,
    });
    blake3::hash(v.to_string().as_bytes()).to_hex().to_string()
}

/// Mesh files found (relative paths) and unreadable entries (relative path, error).
pub type Discovered = (Vec<PathBuf>, Vec<(PathBuf, String)>);

/// Every mesh file below `root`, as sorted relative paths. Hidden entries (names starting
/// with `.`) and `skip` (the output root, when it lies inside the library) are left out;
/// directory symlinks are not followed (no cycles). Unreadable directories are returned in
/// the second list.
pub fn discover(root: &Path, skip: Option<&Path>) -> Result<Discovered, BuildError> {
    let meta = std::fs::metadata(root).map_err(|e| BuildError::Io(format!("{}: {e}", root.display())))?;
    if !meta.is_dir() {
        return Err(BuildError::Io(format!("{}: not a directory", root.display())));
    }
    let skip = skip.and_then(|s| s.canonicalize().ok());
    let mut found = Vec::new();
    let mut unreadable = Vec::new();
    let mut stack = vec![PathBuf::new()];
    while let Some(rel) = stack.pop() {
        let dir = root.join(&rel);
        if skip.as_deref().is_some_and(|s| dir.canonicalize().ok().as_deref() == Some(s)) {
            continue;
        }
        let entries = match std::fs::read_dir(&dir) {
            Ok(e) => e,
            Err(e) => {
                unreadable.push((rel, e.to_string()));
                continue;
            }
        };
        for entry in entries {
            let entry = match entry {
                Ok(e) => e,
                Err(e) => {
                    unreadable.push((rel.clone(), e.to_string()));
                    continue;
                }
            };
            let name = entry.file_name();
            if name.to_string_lossy().starts_with('.') {
                continue;
            }
            let child = rel.join(&name);
            match entry.file_type() {
                Ok(t) if t.is_dir() => stack.push(child),
                Ok(t) if (t.is_file() || t.is_symlink()) && is_mesh_path(&child) => found.push(child),
                Ok(_) => {}
                Err(e) => unreadable.push((child, e.to_string())),
            }
        }
    }
    found.sort();
    unreadable.sort();
    Ok((found, unreadable))
}

/// Output paths (relative) for the inputs: `name.ext` → `name.sct`, except that inputs
/// whose outputs would collide (`chair.obj` and `chair.ply` in one folder) keep their
/// extension: `chair.obj.sct`, `chair.ply.sct`; names that still collide also get a hash
/// of their input path (`chair.obj.1a2b3c4d.sct`). Collisions are judged case-insensitively,
/// so the outputs stay distinct on case-insensitive file systems too.
pub fn output_paths(inputs: &[PathBuf]) -> Vec<PathBuf> {
    let fold = |p: &Path| slash(p).to_lowercase();
    let counts = |v: &[PathBuf]| {
        let mut count: BTreeMap<String, usize> = BTreeMap::new();
        for p in v {
            *count.entry(fold(p)).or_default() += 1;
        }
        count
    };
    let with_ext = |input: &PathBuf, extra: &str| {
        let mut name = input.file_name().unwrap_or_default().to_os_string();
        name.push(extra);
        name.push(".sct");
        input.with_file_name(name)
    };
    let plain: Vec<PathBuf> = inputs.iter().map(|p| p.with_extension("sct")).collect();
    let c = counts(&plain);
    let second: Vec<PathBuf> = inputs
        .iter()
        .zip(&plain)
        .map(|(input, out)| if c.get(&fold(out)).copied().unwrap_or(0) > 1 { with_ext(input, "") } else { out.clone() })
        .collect();
    let c = counts(&second);
    inputs
        .iter()
        .zip(second)
        .map(|(input, out)| {
            if c.get(&fold(&out)).copied().unwrap_or(0) > 1 {
                let h = blake3::hash(slash(input).as_bytes()).to_hex();
                with_ext(input, &format!(".{}", &h[..8]))
            } else {
                out
            }
        })
        .collect()
}

fn slash(p: &Path) -> String {
    p.components().map(|c| c.as_os_str().to_string_lossy()).collect::<Vec<_>>().join("/")
}

/// Whether `output` was made by this tool version with `key` from sources that are
/// unchanged; relative source paths are relative to the library `root` (as
/// [`crate::convert::convert_meshes`] records them in batch mode). Any doubt (unreadable, invalid, other
/// parameters, a source gone or changed) means "convert again".
pub fn is_up_to_date(output: &Path, key: &str, root: &Path) -> bool {
    up_to_date_warnings(output, key, root).is_some()
}

/// [`is_up_to_date`], returning the warnings its conversion recorded when it is: an
/// up-to-date output reports them again, as its first conversion did. Stale as well: a
/// file the sources referenced that was missing then and exists now (a texture added
/// since, an options file created).
pub fn up_to_date_warnings(output: &Path, key: &str, root: &Path) -> Option<Vec<String>> {
    let reader = SctReader::open(output, &Limits::default()).ok()?;
    let g = reader.generator();
    let params = g.parameters.get("sampling").and_then(|s| s.get("parameters"))?;
    let recorded = params.get("job_key").and_then(|v| v.as_str());
    if g.tool != "sct-build-tree" || g.version != env!("CARGO_PKG_VERSION") || recorded != Some(key) {
        return None;
    }
    // Outputs of older runs lack the list: they cannot tell, so they are converted again.
    let missing = params.get("missing_sources")?.as_array()?;
    if missing.iter().any(|m| m.as_str().is_none_or(|p| root.join(p).exists())) {
        return None;
    }
    let fresh = !g.sources.is_empty()
        && g.sources.iter().all(|s| sct_format::atomic::hash_file(&root.join(&s.path)).is_ok_and(|h| h == s.blake3));
    let warnings = params.get("warnings").and_then(|w| w.as_array()).map_or_else(Vec::new, |w| {
        w.iter().filter_map(|s| s.as_str().map(str::to_string)).collect()
    });
    fresh.then_some(warnings)
}

/// Removes temporary files (`.NAME.PID.RANDOM.tmp`, see `sct_format::atomic`, and the older
/// `.NAME.PID.tmp`) that an interrupted run left beside `output`: at once when the name says
/// it was written on this host by a process that is gone
/// ([`sct_format::atomic::process_is_gone`]), else once at least [`STALE_TEMP_AGE`] old.
/// Returns how many were removed.
fn remove_stale_temp_files(output: &Path) -> u64 {
    let (Some(dir), Some(name)) = (output.parent(), output.file_name()) else {
        return 0;
    };
    let prefix = format!(".{}.", name.to_string_lossy());
    let own_pid = std::process::id().to_string();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    let mut removed = 0;
    for e in entries.flatten() {
        let n = e.file_name().to_string_lossy().into_owned();
        let Some(middle) = n.strip_prefix(&prefix).and_then(|r| r.strip_suffix(".tmp")) else {
            continue;
        };
        // Only `.NAME.<digits>.tmp` or `.NAME.<digits>.<16 hex digits>.tmp`, never one of
        // this process's (its own files in flight), and only when old enough that no live
        // run can still be writing it (a writer of another container may share our PID).
        let (pid, random) = middle.split_once('.').unwrap_or((middle, ""));
        let pid_ok = !pid.is_empty() && pid.bytes().all(|b| b.is_ascii_digit());
        let random_ok = random.is_empty() || (random.len() == 16 && random.bytes().all(|b| b.is_ascii_hexdigit()));
        let old = e.metadata().and_then(|m| m.modified()).ok().and_then(|t| t.elapsed().ok()).is_some_and(|age| age >= STALE_TEMP_AGE);
        let gone = pid.parse::<u32>().is_ok_and(|p| sct_format::atomic::process_is_gone(p, random));
        if pid_ok && random_ok && pid != own_pid && (old || gone) && std::fs::remove_file(e.path()).is_ok() {
            removed += 1;
        }
    }
    removed
}

/// Converts the library. Per-input failures are in the report (the batch goes on); only a
/// failure of the batch itself (an unreadable library root, an output root that cannot be
/// created) is an error. `progress` is called when an input starts and when it finishes
/// (for a progress display), from worker threads.
pub fn run_batch(opts: &BatchOptions, progress: &(dyn Fn(&BatchProgress<'_>) + Sync)) -> Result<BatchReport, BuildError> {
    let t0 = Instant::now();
    if opts.output_dir.exists() && !opts.output_dir.is_dir() {
        return Err(BuildError::Io(format!(
            "{}: exists and is not a directory; with a directory as input (batch mode), -o names the output directory",
            opts.output_dir.display()
        )));
    }
    std::fs::create_dir_all(&opts.output_dir).map_err(|e| BuildError::Io(format!("{}: {e}", opts.output_dir.display())))?;
    if opts.output_dir.canonicalize().ok().is_some_and(|o| opts.input_dir.canonicalize().ok() == Some(o)) {
        return Err(BuildError::Io(format!(
            "{}: the output directory must differ from the library root (outputs would mix with the inputs)",
            opts.output_dir.display()
        )));
    }
    let (all, unreadable) = discover(&opts.input_dir, Some(&opts.output_dir))?;
    let outputs = output_paths(&all);
    let key = job_key(opts);
    let mine: Vec<(PathBuf, PathBuf)> = all
        .iter()
        .zip(outputs)
        .filter(|(rel, _)| opts.shard.is_none_or(|s| s.contains(&slash(rel))))
        .map(|(a, b)| (a.clone(), b))
        .collect();
    let total = mine.len();
    let results: Vec<Mutex<Option<(JobResult, u64)>>> = (0..total).map(|_| Mutex::new(None)).collect();
    let next = AtomicUsize::new(0);
    let sizes: Vec<u64> = mine.iter().map(|(rel, _)| std::fs::metadata(opts.input_dir.join(rel)).map_or(0, |m| m.len())).collect();
    let tracker = Tracker::new(total, sizes.iter().sum());
    let workers = opts.jobs.clamp(1, total.max(1));
    std::thread::scope(|scope| {
        for _ in 0..workers {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some((rel, out_rel)) = mine.get(i) else { break };
                tracker.started(i, slash(rel), progress);
                // A bug that panics on one input must not take the rest of the batch down.
                let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| run_one(opts, &key, rel, out_rel)))
                    .unwrap_or_else(|_| (failed(rel, out_rel, "internal error: the conversion panicked (a bug; please report it)".into(), 2, 0.0), 0));
                tracker.finished(i, sizes[i], &r.0, progress);
                if let Ok(mut slot) = results[i].lock() {
                    *slot = Some(r);
                }
            });
        }
    });
    let mut jobs = Vec::with_capacity(total + unreadable.len());
    let mut stale = 0;
    for (i, slot) in results.into_iter().enumerate() {
        let r = slot.into_inner().ok().flatten();
        match r {
            Some((job, removed)) => {
                stale += removed;
                jobs.push(job);
            }
            // Unreachable unless a slot's lock was poisoned; still reported, never lost.
            None => jobs.push(failed(&mine[i].0, &mine[i].1, "internal error: no result recorded".into(), 2, 0.0)),
        }
    }
    for (dir, e) in unreadable {
        if opts.shard.is_none_or(|s| s.contains(&slash(&dir))) {
            jobs.push(failed(&dir, Path::new(""), format!("cannot read: {e}"), 2, 0.0));
        }
    }
    jobs.sort_by(|a, b| a.input.cmp(&b.input));
    let count = |s: JobStatus| jobs.iter().filter(|j| j.status == s).count() as u64;
    Ok(BatchReport {
        schema: REPORT_SCHEMA,
        input_dir: opts.input_dir.display().to_string(),
        output_dir: opts.output_dir.display().to_string(),
        shard: opts.shard,
        job_key: key,
        found: all.len() as u64,
        converted: count(JobStatus::Converted),
        up_to_date: count(JobStatus::UpToDate),
        failed: count(JobStatus::Failed),
        jobs,
        stale_temp_files_removed: stale,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

fn failed(rel: &Path, out_rel: &Path, error: String, exit_code: i32, seconds: f64) -> JobResult {
    JobResult {
        input: slash(rel),
        output: slash(out_rel),
        status: JobStatus::Failed,
        error: Some(error),
        exit_code,
        samples: 0,
        leaves: 0,
        bytes: 0,
        seconds,
        warnings: Vec::new(),
    }
}

/// Converts one input; returns its result and the number of stale temp files removed.
fn run_one(opts: &BatchOptions, key: &str, rel: &Path, out_rel: &Path) -> (JobResult, u64) {
    let t = Instant::now();
    let input = opts.input_dir.join(rel);
    let output = opts.output_dir.join(out_rel);
    let removed = remove_stale_temp_files(&output);
    let up_to_date = if opts.force { None } else { up_to_date_warnings(&output, key, &opts.input_dir) };
    if let Some(warnings) = up_to_date {
        if opts.deny_warnings && !warnings.is_empty() {
            let e = format!("{} warning(s) with --strict (recorded when the output was made; fix them or use --force): {}", warnings.len(), warnings.join("; "));
            let mut job = failed(rel, out_rel, e, 1, t.elapsed().as_secs_f64());
            job.warnings = warnings;
            return (job, removed);
        }
        let bytes = std::fs::metadata(&output).map(|m| m.len()).unwrap_or(0);
        let job = JobResult {
            input: slash(rel),
            output: slash(out_rel),
            status: JobStatus::UpToDate,
            error: None,
            exit_code: 0,
            samples: 0,
            leaves: 0,
            bytes,
            seconds: t.elapsed().as_secs_f64(),
            warnings,
        };
        return (job, removed);
    }
    let sampling = match crate::sidecar::read_asset_options(&input) {
        Ok(Some(o)) => o.apply(&opts.sampling, &input),
        Ok(None) => opts.sampling.clone(),
        Err(e) => return (failed(rel, out_rel, e, 1, t.elapsed().as_secs_f64()), removed),
    };
    let sidecar = crate::sidecar::sidecar_path(&input);
    if let Some(parent) = output.parent() {
        if let Err(e) = std::fs::create_dir_all(parent) {
            return (failed(rel, out_rel, format!("{}: {e}", parent.display()), 2, t.elapsed().as_secs_f64()), removed);
        }
    }
    let cfg = Config {
        samples: PathBuf::new(),
        output,
        scene: None,
        profile: opts.profile,
        compression_level: opts.compression_level,
        centre_offsets: opts.centre_offsets,
        leaf_refinement: opts.leaf_refinement,
        build: opts.build,
    };
    let tag = BatchTag { key, root: &opts.input_dir, sidecar: &sidecar };
    let job = match convert_meshes_checked(std::slice::from_ref(&input), &sampling, &cfg, Some(tag), opts.deny_warnings, &mut |_| {}) {
        Ok(rep) => JobResult {
            input: slash(rel),
            output: slash(out_rel),
            status: JobStatus::Converted,
            error: None,
            exit_code: 0,
            samples: rep.build.samples,
            leaves: rep.build.leaves,
            bytes: rep.build.bytes,
            seconds: t.elapsed().as_secs_f64(),
            warnings: rep.sampling.warnings,
        },
        Err(e) => {
            let mut job = failed(rel, out_rel, e.to_string(), e.exit_code(), t.elapsed().as_secs_f64());
            if let ConvertError::Warnings(w) = e {
                job.warnings = w;
            }
            job
        }
    };
    (job, removed)
}

/// The summary table printed on stdout (one line per input, then totals).
pub fn format_table(rep: &BatchReport) -> String {
    use std::fmt::Write;
    let w = rep.jobs.iter().map(|j| j.input.len()).max().unwrap_or(5).max(5);
    let mut s = String::new();
    let _ = writeln!(s, "{:<10} {:<w$} {:>11} {:>11} {:>10} {:>8} {:>8}  error", "status", "input", "samples", "leaves", "bytes", "seconds", "warnings");
    for j in &rep.jobs {
        let status = match j.status {
            JobStatus::Converted => "converted",
            JobStatus::UpToDate => "up-to-date",
            JobStatus::Failed => "FAILED",
        };
        let _ = writeln!(
            s,
            "{:<10} {:<w$} {:>11} {:>11} {:>10} {:>8.2} {:>8}  {}",
            status,
            j.input,
            j.samples,
            j.leaves,
            j.bytes,
            j.seconds,
            j.warnings.len(),
            // One line per input, whatever the error text holds (parsers quote whole lines).
            j.error.as_deref().unwrap_or("").split_whitespace().collect::<Vec<_>>().join(" ")
        );
    }
    // Warnings after the table, named by input (a missing texture, a mesh left out, an
    // asset the sample budget coarsened): what a person reading the log must not miss.
    let warned: Vec<&JobResult> = rep.jobs.iter().filter(|j| !j.warnings.is_empty()).collect();
    if !warned.is_empty() {
        let count: usize = warned.iter().map(|j| j.warnings.len()).sum();
        let _ = writeln!(s, "{count} warning(s) in {} input(s):", warned.len());
        for j in warned {
            for warning in &j.warnings {
                let _ = writeln!(s, "  {}: {}", j.input, warning.split_whitespace().collect::<Vec<_>>().join(" "));
            }
        }
    }
    let shard = rep.shard.map(|s| format!(" (shard {}/{})", s.index, s.count)).unwrap_or_default();
    let _ = writeln!(
        s,
        "{} inputs{shard}: {} converted, {} up to date, {} failed in {:.2} s",
        rep.jobs.len(),
        rep.converted,
        rep.up_to_date,
        rep.failed,
        rep.seconds
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shard_parsing_and_partition() {
        assert_eq!("1/4".parse::<Shard>(), Ok(Shard { index: 1, count: 4 }));
        assert!("4/4".parse::<Shard>().is_err());
        let e = "0/0".parse::<Shard>().unwrap_err();
        assert!(e.contains("at least 1") && !e.contains("0..0"), "{e}");
        let e = "4/4".parse::<Shard>().unwrap_err();
        assert!(e.contains("below N = 4"), "{e}");
        assert!("x".parse::<Shard>().is_err());
        // Every path lands in exactly one shard.
        let shards: Vec<Shard> = (0..3).map(|index| Shard { index, count: 3 }).collect();
        for i in 0..200 {
            let p = format!("dir{}/model{i}.obj", i % 7);
            assert_eq!(shards.iter().filter(|s| s.contains(&p)).count(), 1, "{p}");
        }
        // And the split is not degenerate.
        let in0 = (0..200).filter(|i| shards[0].contains(&format!("m{i}.obj"))).count();
        assert!((30..=110).contains(&in0), "{in0}");
    }

    #[test]
    fn colliding_outputs_keep_their_extension() {
        let inputs: Vec<PathBuf> = ["a/chair.obj", "a/chair.ply", "a/table.glb", "b/chair.obj"].iter().map(PathBuf::from).collect();
        let out: Vec<String> = output_paths(&inputs).iter().map(|p| slash(p)).collect();
        assert_eq!(out, ["a/chair.obj.sct", "a/chair.ply.sct", "a/table.sct", "b/chair.sct"]);
        // Second-order and case-only collisions: every output distinct, case-folded.
        let inputs: Vec<PathBuf> = ["chair.obj", "chair.ply", "chair.obj.ply", "Lamp.OBJ", "lamp.ply"].iter().map(PathBuf::from).collect();
        let out: Vec<String> = output_paths(&inputs).iter().map(|p| slash(p).to_lowercase()).collect();
        let mut uniq = out.clone();
        uniq.sort();
        uniq.dedup();
        assert_eq!(uniq.len(), out.len(), "{out:?}");
        assert!(out.iter().all(|o| o.ends_with(".sct")), "{out:?}");
    }

    #[test]
    fn stale_temp_files_are_removed_but_not_others() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("m.sct");
        let old = std::time::SystemTime::now() - 2 * STALE_TEMP_AGE;
        let own = format!(".m.sct.{}.00000000deadbeef.tmp", std::process::id());
        let names = [
            ".m.sct.123.tmp",
            ".m.sct.124.0123456789abcdef.tmp",
            ".m.sct.x1.tmp",
            ".m.sct.125.xyz.tmp",
            ".n.sct.5.tmp",
            "m.sct",
            ".m.sct.77.tmp",
            own.as_str(),
        ];
        for n in names {
            let f = std::fs::File::create(dir.path().join(n)).expect("create");
            // All old but `.m.sct.77.tmp`: a run that may still be writing it.
            if n != ".m.sct.77.tmp" {
                f.set_modified(old).expect("mtime");
            }
        }
        assert_eq!(remove_stale_temp_files(&out), 2);
        assert!(!dir.path().join(".m.sct.123.tmp").exists());
        assert!(!dir.path().join(".m.sct.124.0123456789abcdef.tmp").exists(), "the random-suffixed pattern is cleaned too");
        assert!(dir.path().join(".m.sct.77.tmp").exists(), "a fresh temp file is left alone");
        assert!(dir.path().join(".m.sct.x1.tmp").exists() && dir.path().join(".n.sct.5.tmp").exists());
        assert!(dir.path().join(".m.sct.125.xyz.tmp").exists());
        assert!(dir.path().join(&own).exists(), "this process's own temp files are left alone");
        assert!(out.exists());
    }

    /// A temporary file named by `sct_format::atomic` today matches the cleanup's pattern.
    #[test]
    fn atomic_temp_names_are_recognised_as_stale() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("m.sct");
        let seen = std::cell::Cell::new(None);
        let r: sct_format::Result<()> = sct_format::atomic::write_atomic(&out, |_| {
            let tmp = std::fs::read_dir(dir.path()).expect("dir").flatten().map(|e| e.file_name()).next();
            seen.set(tmp);
            Err(sct_format::Error::Misuse("stop before publishing".into()))
        });
        assert!(r.is_err());
        let name = seen.take().expect("a temporary file existed while writing");
        // Recreate it as another process's leftover (a different PID) and age it.
        let name = name.to_string_lossy().replace(&format!(".{}.", std::process::id()), ".1.");
        let f = std::fs::File::create(dir.path().join(&name)).expect("create");
        f.set_modified(std::time::SystemTime::now() - 2 * STALE_TEMP_AGE).expect("mtime");
        assert_eq!(remove_stale_temp_files(&out), 1, "{name}");
    }
}
