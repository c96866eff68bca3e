//! Validation of many files in one run (`sct-inspect a.sct b.sct DIR/ --validate`): one
//! result per file, a summary, and one exit status for CI. The JSON layout is
//! `spec/inspect-json.md`, schema [`MANY_SCHEMA`].

use std::io::Write;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::Serialize;

use crate::{validate_file, ValidateOptions, Validation};

/// Version tag of the many-file JSON report.
pub const MANY_SCHEMA: &str = "sct-inspect-validate/1";

/// What became of one file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Verdict {
    /// No issue found.
    Valid,
    /// Issues found (listed in the result's validation).
    Invalid,
    /// The file could not be read at all (missing, unreadable, not a regular file).
    Error,
}

/// One file's result.
#[derive(Clone, Debug, Serialize)]
pub struct FileResult {
    /// The path as given or found below a given directory.
    pub file: String,
    /// The verdict.
    pub verdict: Verdict,
    /// Exit status the file alone would give: 0 valid, 1 invalid, 2 unreadable.
    pub exit_code: i32,
    /// Why the file could not be read ([`Verdict::Error`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// The validation report (absent for [`Verdict::Error`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub validation: Option<Validation>,
}

/// Counts over all files.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ManySummary {
    /// Files validated.
    pub files: u64,
    /// Valid files.
    pub valid: u64,
    /// Invalid files.
    pub invalid: u64,
    /// Files that could not be read.
    pub errors: u64,
}

/// The whole run (`--json`).
#[derive(Clone, Debug, Serialize)]
pub struct ManyReport {
    /// [`MANY_SCHEMA`].
    pub schema: &'static str,
    /// Whether the deep checks ran.
    pub deep: bool,
    /// Per file, in the order given (a directory's files sorted by path).
    pub results: Vec<FileResult>,
    /// Counts.
    pub summary: ManySummary,
}

impl ManyReport {
    /// Exit status of the run: 2 when a file could not be read, else 1 when one is invalid,
    /// else 0.
    pub fn exit_code(&self) -> i32 {
        self.results.iter().map(|r| r.exit_code).max().unwrap_or(0)
    }
}

/// The files to validate: each path given, and for a directory every `*.sct` file below it
/// (hidden entries skipped, directory symlinks not followed), sorted. A directory that
/// cannot be listed becomes an [`Verdict::Error`] entry of its own (the `String`).
pub fn expand_inputs(paths: &[PathBuf]) -> Vec<(PathBuf, Option<String>)> {
    let mut out = Vec::new();
    for p in paths {
        if !p.is_dir() {
            out.push((p.clone(), None));
            continue;
        }
        let mut found = Vec::new();
        let mut stack = vec![p.clone()];
        while let Some(dir) = stack.pop() {
            let entries = match std::fs::read_dir(&dir) {
                Ok(e) => e,
                Err(e) => {
                    found.push((dir.clone(), Some(format!("cannot list the directory: {e}"))));
                    continue;
                }
            };
            for entry in entries.flatten() {
                let name = entry.file_name();
                if name.to_string_lossy().starts_with('.') {
                    continue;
                }
                let child = entry.path();
                match entry.file_type() {
                    Ok(t) if t.is_dir() => stack.push(child),
                    Ok(_) if is_sct_name(&child) => found.push((child, None)),
                    _ => {}
                }
            }
        }
        found.sort();
        if found.is_empty() {
            // A CI step pointed at the wrong folder must not pass on nothing.
            found.push((p.clone(), Some("no .sct file below this directory".into())));
        }
        out.extend(found);
    }
    out
}

fn is_sct_name(p: &Path) -> bool {
    p.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("sct"))
}

/// Validates every file of [`expand_inputs`]`(paths)`, several at a time.
pub fn validate_many(paths: &[PathBuf], opts: &ValidateOptions) -> ManyReport {
    let inputs = expand_inputs(paths);
    let results: Vec<FileResult> = inputs
        .par_iter()
        .map(|(path, listing_error)| {
            let file = path.display().to_string();
            if let Some(e) = listing_error {
                return FileResult { file, verdict: Verdict::Error, exit_code: 2, error: Some(e.clone()), validation: None };
            }
            match validate_file(path, opts) {
                Ok(v) if v.is_valid() => FileResult { file, verdict: Verdict::Valid, exit_code: 0, error: None, validation: Some(v) },
                Ok(v) => FileResult { file, verdict: Verdict::Invalid, exit_code: 1, error: None, validation: Some(v) },
                Err(e) => FileResult { file, verdict: Verdict::Error, exit_code: 2, error: Some(e.to_string()), validation: None },
            }
        })
        .collect();
    let count = |v: Verdict| results.iter().filter(|r| r.verdict == v).count() as u64;
    let summary = ManySummary { files: results.len() as u64, valid: count(Verdict::Valid), invalid: count(Verdict::Invalid), errors: count(Verdict::Error) };
    ManyReport { schema: MANY_SCHEMA, deep: opts.deep, results, summary }
}

/// Writes the human report: a verdict line per file (`--quiet`: only the files that are
/// not valid), each issue indented below its file, and a summary line.
pub fn write_many_text(r: &ManyReport, quiet: bool, w: &mut dyn Write) -> std::io::Result<()> {
    for f in &r.results {
        match f.verdict {
            Verdict::Valid if quiet => {}
            Verdict::Valid => writeln!(w, "valid    {}", f.file)?,
            Verdict::Invalid => {
                let v = f.validation.as_ref();
                let n = v.map_or(0, |v| v.issues.len() as u64 + v.issues_omitted);
                writeln!(w, "INVALID  {}: {n} issue(s)", f.file)?;
                for i in v.map_or(&[][..], |v| &v.issues[..]) {
                    writeln!(w, "    {}", one_line(&i.to_string()))?;
                }
                if let Some(v) = v.filter(|v| v.issues_omitted > 0) {
                    writeln!(w, "    … and {} more issue(s) not listed", v.issues_omitted)?;
                }
            }
            Verdict::Error => writeln!(w, "ERROR    {}: {}", f.file, one_line(f.error.as_deref().unwrap_or("")))?,
        }
    }
    let s = &r.summary;
    let verdict = if s.invalid + s.errors == 0 { "all valid" } else { "FAILED" };
    writeln!(
        w,
        "{} file(s) validated ({}): {} valid, {} invalid, {} unreadable: {verdict}",
        s.files,
        if r.deep { "deep" } else { "quick" },
        s.valid,
        s.invalid,
        s.errors
    )
}

fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn directories_expand_to_their_sct_files_sorted() {
        let d = tempfile::tempdir().expect("tempdir");
        std::fs::create_dir_all(d.path().join("sub/.hidden")).expect("mkdir");
        for n in ["b.sct", "a.SCT", "sub/c.sct", "sub/.hidden/x.sct", "sub/readme.txt", ".d.sct"] {
            std::fs::write(d.path().join(n), b"x").expect("write");
        }
        let got: Vec<String> = expand_inputs(&[d.path().to_path_buf()])
            .into_iter()
            .map(|(p, _)| p.strip_prefix(d.path()).expect("below").display().to_string())
            .collect();
        assert_eq!(got, ["a.SCT", "b.sct", "sub/c.sct"]);
    }
}
