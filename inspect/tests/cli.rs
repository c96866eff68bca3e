//! The binary end to end: golden reports for a file built from the Stanford bunny, exit
//! statuses, dumps, help. Regenerate the golden files with `UPDATE_GOLDEN=1 cargo test -p inspect --test cli`.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::*;
use sct_format::{GraphNode, InstanceAttrs, Profile, Propagation, SceneGraph, SceneTree, Similarity};

fn run(args: &[&str]) -> Output {
    Command::new(bin()).args(args).output().unwrap()
}

fn stdout(o: &Output) -> String {
    String::from_utf8(o.stdout.clone()).unwrap()
}

/// The bunny (8171 vertices, one leaf each) as a group of the plain tree and a tinted,
/// scaled instance of it, raw profile (its bytes do not depend on lossy codec tuning).
fn bunny_scene(path: &Path) {
    let t = bunny_tree();
    let tr = Similarity { translation: [0.3, 0.0, 0.0], rotation: [0.0, 0.0, 0.38268343236508984, 0.9238795325112867], scale: 0.5 };
    let attrs = InstanceAttrs { size: Propagation::PullUp, color: Propagation::PushDown, tint: Some([255, 128, 128, 255]) };
    let a = t.nodes()[0];
    let b = sct_format::traverse::TraversalState::IDENTITY.push_instance(&tr, &attrs).apply(&a);
    let gt = SceneTree::from_bfs(vec![sct_format::geometry::parent_of(&a, &b), a, b], vec![true, false, false]).unwrap();
    let nodes = vec![GraphNode::Tree { tree: 0 }, GraphNode::Instance { child: 0, transform: tr, attrs }, GraphNode::Group { children: vec![0, 1], tree: 1 }];
    write(path, SceneGraph { nodes, root: 2 }, vec![t, gt], Profile::Raw);
}

fn golden(name: &str, actual: &str) {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/golden").join(name);
    if std::env::var_os("UPDATE_GOLDEN").is_some_and(|v| v == "1") {
        std::fs::write(&p, actual).unwrap();
        return;
    }
    let want = std::fs::read_to_string(&p).unwrap_or_else(|_| panic!("{} missing: run with UPDATE_GOLDEN=1", p.display()));
    assert_eq!(actual, want, "golden {name} differs (UPDATE_GOLDEN=1 regenerates it)");
}

#[test]
fn golden_reports() {
    let d = tmp();
    let f = path_in(&d, "bunny.sct");
    bunny_scene(&f);
    let fs = f.to_str().unwrap();
    let norm = |s: String| s.replace(fs, "<FILE>").replace(&d.path().display().to_string(), "<DIR>");
    let o = run(&[fs, "--deep"]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    golden("bunny_report.txt", &norm(stdout(&o)));
    let o = run(&[fs, "--json", "--deep"]);
    assert_eq!(o.status.code(), Some(0));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["schema"], "sct-inspect/1");
    assert_eq!(v["totals"]["leaves_expanded"], 2 * 8171);
    assert_eq!(v["validation"]["issues"].as_array().unwrap().len(), 0);
    golden("bunny_report.json", &norm(stdout(&o)));
    let o = run(&[fs, "--dump", "root/1", "--levels", "3"]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    golden("bunny_dump_root_1.txt", &norm(stdout(&o)));
}

#[test]
fn exit_codes_and_streams() {
    let d = tmp();
    // I/O error: 2, message on stderr only.
    let o = run(&[d.path().join("none.sct").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(o.stdout.is_empty());
    assert!(String::from_utf8_lossy(&o.stderr).contains("sct-inspect:"));
    // Usage error: 2.
    assert_eq!(run(&["--bogus"]).status.code(), Some(2));
    // Not an SCT file: 1 (the content is at fault).
    let f = path_in(&d, "junk.sct");
    std::fs::write(&f, b"hello").unwrap();
    assert_eq!(run(&[f.to_str().unwrap()]).status.code(), Some(1));
    let o = run(&[f.to_str().unwrap(), "--validate"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stdout(&o).contains("file magic:"), "{}", stdout(&o));
    // Bad dump path: 2.
    let g = path_in(&d, "ok.sct");
    write_single(&g, kd_tree(mesh_leaves(&load_ascii_ply(Path::new(BUNNY)).0[..8], &[])), Profile::Raw);
    assert_eq!(run(&[g.to_str().unwrap(), "--dump", "root/2"]).status.code(), Some(2));
    assert_eq!(run(&[g.to_str().unwrap(), "--dump", "root/0/0/0/0/0/0"]).status.code(), Some(2));
    let o = run(&[g.to_str().unwrap(), "--dump"]);
    assert_eq!(o.status.code(), Some(0));
    assert!(stdout(&o).contains("root/0/1"), "{}", stdout(&o));
}

#[test]
fn help_has_examples() {
    let o = run(&["--help"]);
    assert_eq!(o.status.code(), Some(0));
    let s = stdout(&o);
    assert!(s.contains("Examples:") && s.contains("--deep") && s.contains("--dump"));
}

/// `cargo install` ships every `[[bin]]`: the benchmarks are examples, so sct-inspect is the
/// only binary.
#[test]
fn only_sct_inspect_is_a_binary() {
    let toml = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("Cargo.toml")).unwrap();
    assert_eq!(toml.matches("[[bin]]").count(), 1, "{toml}");
    assert!(!Path::new(env!("CARGO_MANIFEST_DIR")).join("src/bin").exists());
}

/// `--against` does not apply the voxelizer's alpha rule: `--help` says so.
#[test]
fn help_states_the_alpha_limitation_of_against() {
    let o = run(&["--help"]);
    let s = stdout(&o);
    assert!(s.contains("drops by alpha") && s.contains("less than 100 %"), "{s}");
}

/// CI: many files and directories in one run, one result per file and a summary; exit 1
/// when one is invalid, 2 when one cannot be read; `--quiet` lists only failures; `--json`
/// is one document, errors included.
#[test]
fn validates_many_files_and_directories() {
    let d = tmp();
    let dir = d.path().join("lib");
    std::fs::create_dir_all(dir.join("sub")).unwrap();
    let good = dir.join("good.sct");
    write_single(&good, bunny_tree(), Profile::Raw);
    let mut bytes = std::fs::read(&good).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x55;
    std::fs::write(dir.join("sub/bad.sct"), &bytes).unwrap();
    std::fs::write(dir.join("notes.txt"), b"not an SCT file, not looked at").unwrap();
    let extra = d.path().join("extra.sct");
    std::fs::copy(&good, &extra).unwrap();
    let (g, e, l) = (good.to_str().unwrap(), extra.to_str().unwrap(), dir.to_str().unwrap());

    let o = run(&[e, l, "--validate"]);
    assert_eq!(o.status.code(), Some(1), "{}", String::from_utf8_lossy(&o.stderr));
    let text = stdout(&o);
    assert_eq!(text.lines().filter(|l| l.starts_with("valid ")).count(), 2, "{text}");
    assert!(text.lines().any(|l| l.starts_with("INVALID") && l.contains("bad.sct")), "{text}");
    assert!(text.trim_end().ends_with("3 file(s) validated (quick): 2 valid, 1 invalid, 0 unreadable: FAILED"), "{text}");

    let o = run(&[l, "--deep", "--quiet"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(!stdout(&o).contains("valid    "), "--quiet lists only failures: {}", stdout(&o));

    let o = run(&[g, e, "--validate", "--json"]);
    assert_eq!(o.status.code(), Some(0));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["schema"], "sct-inspect-validate/1");
    assert_eq!(v["summary"]["valid"], 2);
    assert_eq!(v["results"][0]["verdict"], "valid");

    let missing = d.path().join("missing.sct");
    let o = run(&[g, missing.to_str().unwrap(), "--validate", "--json"]);
    assert_eq!(o.status.code(), Some(2));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["results"][1]["verdict"], "error");
    let empty = d.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    assert_eq!(run(&[empty.to_str().unwrap(), "--validate"]).status.code(), Some(2), "an empty folder is not a pass");

    // A directory without --validate: a usage error that says what to do, not "No such device".
    let o = run(&[l]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("is a directory") && err.contains("--validate"), "{err}");

    // --json also for errors: a single file that cannot be read.
    let o = run(&[missing.to_str().unwrap(), "--json"]);
    assert_eq!(o.status.code(), Some(2));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["error"].as_str().unwrap().contains("missing.sct"), "{v}");
    assert_eq!(v["exit_code"], 2);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.matches("No such file").count(), 1, "the cause once: {err}");

    // --quiet on one file: the verdict only, no statistics.
    let o = run(&[g, "--validate", "--quiet"]);
    assert_eq!(o.status.code(), Some(0));
    assert_eq!(stdout(&o).lines().count(), 1, "{}", stdout(&o));
    assert!(stdout(&o).contains("valid"));
}

/// Regression: `sct-inspect FILE --dump … | head -1` printed "writing output: Broken pipe"
/// and failed. A reader that closes the pipe has what it wanted: exit 0, nothing said.
#[test]
fn a_closed_stdout_pipe_ends_quietly() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bunny.sct");
    bunny_scene(&path);
    for args in [&["--dump", "root", "--levels", "12"][..], &["--json"][..]] {
        let mut child = Command::new(bin())
            .arg(&path)
            .args(args)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        drop(child.stdout.take());
        let o = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.is_empty(), "{args:?}: {err}");
        assert_eq!(o.status.code(), Some(0), "{args:?}");
    }
}
