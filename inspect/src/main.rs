//! `sct-inspect`: statistics, dumps and validation of SCT files.
//!
//! Exit status: 0 valid, 1 invalid (issues found or the file cannot be parsed), 2 usage or
//! I/O error. Results go to stdout, diagnostics to stderr.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use inspect::{dump, summarize, validate_file, write_json, write_text, write_validation, InspectError, ValidateOptions};
use sct_format::Limits;

const EXAMPLES: &str = "\
Examples:
  sct-inspect bunny.sct                  report counts, sizes and the root node
  sct-inspect bunny.sct --json           the same as JSON (schema sct-inspect/1, spec/inspect-json.md)
  sct-inspect bunny.sct --validate       quick structural validation (exit 1 when invalid)
  sct-inspect bunny.sct --deep --json    decode every block and check hierarchical consistency
  sct-inspect bunny.sct --dump root/0/1 --levels 2
                                         print the graph and two levels below node root/0/1";

/// Statistics, dumps and validation of SCT scene-tree files.
#[derive(Parser, Debug)]
#[command(name = "sct-inspect", version, after_help = EXAMPLES)]
struct Cli {
    /// The SCT file.
    file: PathBuf,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
    /// Quick validation: structure, checksums, graph, transforms, inline targets.
    #[arg(long)]
    validate: bool,
    /// Deep validation: also decode every block and check hierarchical consistency (implies --validate).
    #[arg(long)]
    deep: bool,
    /// Print the scene graph and the scene tree below PATH (abstract path, default root).
    #[arg(long, value_name = "PATH", num_args = 0..=1, default_missing_value = "root")]
    dump: Option<String>,
    /// Levels printed by --dump.
    #[arg(long, value_name = "N", default_value_t = 3, requires = "dump")]
    levels: usize,
}

fn run(cli: &Cli) -> Result<i32, InspectError> {
    let limits = Limits::default();
    let mut out = std::io::stdout().lock();
    if let Some(p) = &cli.dump {
        dump(&cli.file, p, cli.levels, &limits, &mut out)?;
        return Ok(0);
    }
    let validation = if cli.validate || cli.deep {
        Some(validate_file(&cli.file, &ValidateOptions { deep: cli.deep, limits: limits.clone() })?)
    } else {
        None
    };
    let invalid = validation.as_ref().is_some_and(|v| !v.is_valid());
    match summarize(&cli.file, &limits) {
        Ok(mut s) => {
            s.validation = validation;
            if cli.json {
                write_json(&s, &mut out)?;
            } else {
                write_text(&s, &mut out)?;
                if let Some(v) = &s.validation {
                    write_validation(v, &mut out)?;
                }
            }
        }
        // An unparsable file still gets its issues printed when validating.
        Err(e) if e.exit_code() == 1 && validation.is_some() => {
            let v = validation.clone().unwrap_or_default();
            if cli.json {
                serde_json::to_writer_pretty(&mut out, &serde_json::json!({"schema": inspect::SCHEMA, "file": cli.file, "error": e.to_string(), "validation": v})).map_err(std::io::Error::from)?;
                writeln!(out)?;
            } else {
                write_validation(&v, &mut out)?;
            }
            return Ok(1);
        }
        Err(e) => return Err(e),
    }
    out.flush()?;
    Ok(if invalid { 1 } else { 0 })
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(&cli) {
        Ok(code) => ExitCode::from(code as u8),
        Err(e) => {
            let code = e.exit_code();
            eprintln!("sct-inspect: {:#}", anyhow::Error::new(e));
            ExitCode::from(code as u8)
        }
    }
}
