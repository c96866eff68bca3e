//! What a pipeline relies on (issue "fit for pipelines"): inputs named by their content,
//! output paths that say what is wrong with them, `--strict`, and batch runs that are
//! never stale, keep their warnings, take per-asset options and leave no temporary files.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn models() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/models")
}

fn bin<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sct-build-tree")).args(args).output().expect("run sct-build-tree")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn json(o: &Output) -> serde_json::Value {
    serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&o.stdout)))
}

fn job<'a>(rep: &'a serde_json::Value, input_end: &str) -> &'a serde_json::Value {
    rep["jobs"].as_array().expect("jobs").iter().find(|j| j["input"].as_str().is_some_and(|i| i.ends_with(input_end))).expect("job")
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for e in std::fs::read_dir(from).expect("read_dir").flatten() {
        if e.file_type().expect("type").is_dir() {
            copy_dir(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).expect("copy");
        }
    }
}

const QUICK: [&str; 2] = ["--screen-error", "4"];

#[test]
fn inputs_are_named_by_content_and_outputs_by_what_is_wrong() {
    let d = tempfile::tempdir().expect("tempdir");
    let p = |n: &str| d.path().join(n);
    std::fs::write(p("tri.stl"), "solid t\n facet normal 0 0 1\n outer loop\n vertex 0 0 0\n vertex 1 0 0\n vertex 0 1 0\n endloop\n endfacet\nendsolid t\n").expect("write");
    let o = bin(&[p("tri.stl").as_os_str(), "-o".as_ref(), p("t.sct").as_os_str()]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("STL is not supported") && !stderr(&o).contains("magic"), "{}", stderr(&o));

    // An extension-less GLB converts; its output given back as "samples" is named for what it is.
    let glb = models().join("gltf/Box/glTF-Binary/Box.glb");
    std::fs::copy(&glb, p("box")).expect("copy");
    let o = bin(&[p("box").as_os_str(), "-o".as_ref(), p("box.sct").as_os_str(), QUICK[0].as_ref(), QUICK[1].as_ref()]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let o = bin(&[p("box.sct").as_os_str(), "-o".as_ref(), p("again.sct").as_os_str()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("this is an SCT scene file, not a samples file"), "{}", stderr(&o));

    // -o DIR/ and -o missing/dir/x.sct: usage and I/O errors (2) that name the output.
    let o = bin(&[p("box").as_os_str(), "-o".as_ref(), format!("{}/", p("outdir").display()).as_ref()]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("names a directory") && !stderr(&o).contains("Not a directory"), "{}", stderr(&o));
    let o = bin(&[p("box").as_os_str(), "-o".as_ref(), p("missing/dir/x.sct").as_os_str()]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("does not exist") && !stderr(&o).contains(".x.sct."), "{}", stderr(&o));

    // Batch: -o an existing file, --shard 0/0, --texture.
    let lib = p("lib");
    copy_dir(&models().join("gltf/Box"), &lib);
    std::fs::write(p("afile"), b"x").expect("write");
    let o = bin(&[lib.as_os_str(), "-o".as_ref(), p("afile").as_os_str()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("is not a directory") && !stderr(&o).contains("File exists"), "{}", stderr(&o));
    let o = bin(&[lib.as_os_str(), "-o".as_ref(), p("out").as_os_str(), "--shard".as_ref(), "0/0".as_ref()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("at least 1") && !stderr(&o).contains("0..0"), "{}", stderr(&o));
    let o = bin(&[lib.as_os_str(), "-o".as_ref(), p("out").as_os_str(), "--texture".as_ref(), p("t.png").as_os_str()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("options.json"), "{}", stderr(&o));
}

/// The spider's MTL names textures that are not there: a warning, and with `--strict` a
/// failure that writes nothing.
#[test]
fn strict_fails_a_conversion_that_warns() {
    let d = tempfile::tempdir().expect("tempdir");
    let obj = models().join("textured-obj/spider/spider.obj");
    let out = d.path().join("spider.sct");
    let o = bin(&[obj.as_os_str(), "-o".as_ref(), out.as_os_str(), QUICK[0].as_ref(), QUICK[1].as_ref()]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(stderr(&o).contains("wal67ar_small.jpg"), "{}", stderr(&o));
    std::fs::remove_file(&out).expect("rm");
    for flag in ["--strict", "--deny-warnings"] {
        let o = bin(&[obj.as_os_str(), "-o".as_ref(), out.as_os_str(), QUICK[0].as_ref(), QUICK[1].as_ref(), flag.as_ref()]);
        assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
        assert!(stderr(&o).contains("--strict") && stderr(&o).contains("wal67ar_small.jpg"), "{}", stderr(&o));
        assert!(!out.exists(), "nothing written with {flag}");
    }
}

/// A texture the source names but that is missing is part of the job: when it appears,
/// the output is converted again. Up-to-date outputs report the warnings of the
/// conversion that made them, and `--strict` fails on them too.
#[test]
fn batch_outputs_are_never_stale_and_keep_their_warnings() {
    let d = tempfile::tempdir().expect("tempdir");
    let (lib, out) = (d.path().join("lib"), d.path().join("out"));
    copy_dir(&models().join("textured-obj/spider"), &lib.join("spider"));
    let run = |extra: &[&str]| {
        let mut args: Vec<&std::ffi::OsStr> = vec![lib.as_os_str(), "-o".as_ref(), out.as_os_str(), "--json".as_ref(), QUICK[0].as_ref(), QUICK[1].as_ref()];
        args.extend(extra.iter().map(|s| std::ffi::OsStr::new(*s)));
        bin(&args)
    };
    let first = run(&[]);
    assert_eq!(first.status.code(), Some(0), "{}", stderr(&first));
    let rep = json(&first);
    assert_eq!(job(&rep, "spider.obj")["status"], "converted");
    let warnings = job(&rep, "spider.obj")["warnings"].clone();
    assert!(warnings.to_string().contains("wal67ar_small.jpg"), "{warnings}");

    let second = run(&[]);
    let rep = json(&second);
    assert_eq!(job(&rep, "spider.obj")["status"], "up-to-date");
    assert_eq!(job(&rep, "spider.obj")["warnings"], warnings, "an up-to-date output keeps its warnings");
    let table = bin(&[lib.as_os_str(), "-o".as_ref(), out.as_os_str(), QUICK[0].as_ref(), QUICK[1].as_ref()]);
    assert!(String::from_utf8_lossy(&table.stdout).contains("wal67ar_small.jpg"), "the human table lists them too");
    let strict = run(&["--strict"]);
    assert_eq!(strict.status.code(), Some(1), "{}", stderr(&strict));
    assert_eq!(job(&json(&strict), "spider.obj")["status"], "failed");

    // The missing texture appears: the output is stale.
    std::fs::copy(lib.join("spider/SpiderTex.jpg"), lib.join("spider/wal67ar_small.jpg")).expect("copy");
    let third = run(&[]);
    let rep = json(&third);
    assert_eq!(job(&rep, "spider.obj")["status"], "converted", "{rep}");
    assert!(!job(&rep, "spider.obj")["warnings"].to_string().contains("wal67ar_small.jpg"));

    // An options file appearing beside the asset makes it stale as well, and is applied.
    assert_eq!(job(&json(&run(&[])), "spider.obj")["status"], "up-to-date");
    std::fs::write(lib.join("spider/spider.obj.options.json"), br#"{"texture": "SpiderTex.jpg"}"#).expect("write");
    let rep = json(&run(&[]));
    assert_eq!(job(&rep, "spider.obj")["status"], "converted", "{rep}");
    assert_eq!(job(&json(&run(&[])), "spider.obj")["status"], "up-to-date");
    std::fs::write(lib.join("spider/spider.obj.options.json"), br#"{"texture": "nope.jpg", "extra": 1}"#).expect("write");
    let rep = json(&run(&[]));
    assert_eq!(job(&rep, "spider.obj")["status"], "failed");
    assert!(job(&rep, "spider.obj")["error"].as_str().unwrap_or("").contains("unknown field"), "{rep}");
}

/// `--texture` in single-file mode textures only what has no texture of its own: the
/// Duck keeps its own (the same colours as without the flag).
#[test]
fn texture_applies_only_to_untextured_meshes() {
    let d = tempfile::tempdir().expect("tempdir");
    let duck = models().join("gltf/Duck/glTF-Binary/Duck.glb");
    let spots = models().join("textured-obj/spider/SpiderTex.jpg");
    let (a, b) = (d.path().join("a.sct"), d.path().join("b.sct"));
    let o = bin(&[duck.as_os_str(), "-o".as_ref(), a.as_os_str(), QUICK[0].as_ref(), QUICK[1].as_ref(), "--json".as_ref()]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let o = bin(&[duck.as_os_str(), "-o".as_ref(), b.as_os_str(), QUICK[0].as_ref(), QUICK[1].as_ref(), "--texture".as_ref(), spots.as_os_str(), "--json".as_ref()]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(stderr(&o).contains("--texture") && stderr(&o).contains("was not used"), "{}", stderr(&o));
    let leaves = |p: &Path| {
        let r = sct_format::SctReader::open(p, &sct_format::Limits::default()).expect("open");
        let t = r.read_tree(0).expect("tree");
        t.nodes().iter().map(|n| n.color).collect::<Vec<_>>()
    };
    assert_eq!(leaves(&a), leaves(&b), "the Duck's own texture is kept");
}

/// A temporary file that a run on this host left behind is removed by the next batch as
/// soon as its process is gone, however young it is.
#[cfg(target_os = "linux")]
#[test]
fn batch_removes_temp_files_of_dead_processes_at_once() {
    let d = tempfile::tempdir().expect("tempdir");
    let (lib, out) = (d.path().join("lib"), d.path().join("out"));
    copy_dir(&models().join("gltf/Box"), &lib);
    let first = bin(&[lib.as_os_str(), "-o".as_ref(), out.as_os_str(), QUICK[0].as_ref(), QUICK[1].as_ref()]);
    assert_eq!(first.status.code(), Some(0), "{}", stderr(&first));
    let sct = std::fs::read_dir(out.join("glTF-Binary")).expect("dir").flatten().find(|e| e.file_name().to_string_lossy().ends_with(".sct")).expect("an output");
    // A PID that has exited: a short child, waited for.
    let mut child = Command::new("true").spawn().expect("spawn");
    let dead = child.id();
    child.wait().expect("wait");
    let tag = sct_format::atomic::host_tag();
    let leftover = sct.path().with_file_name(format!(".{}.{dead}.{tag}0badf00d.tmp", sct.file_name().to_string_lossy()));
    let other_host = sct.path().with_file_name(format!(".{}.{dead}.ffffffff0badf00d.tmp", sct.file_name().to_string_lossy()));
    std::fs::write(&leftover, b"partial").expect("write");
    if tag != "ffffffff" {
        std::fs::write(&other_host, b"partial").expect("write");
    }
    let second = bin(&[lib.as_os_str(), "-o".as_ref(), out.as_os_str(), QUICK[0].as_ref(), QUICK[1].as_ref(), "--json".as_ref()]);
    assert_eq!(second.status.code(), Some(0), "{}", stderr(&second));
    assert!(!leftover.exists(), "a dead process's temporary file is removed");
    assert!(json(&second)["stale_temp_files_removed"].as_u64() >= Some(1));
    if tag != "ffffffff" {
        assert!(other_host.exists(), "another host's young temporary file is left alone");
    }
}
