//! One-step mesh conversion and batch conversion of a small library of real models
//! (copied from ../shared/models, nasty files included), through the `sct-build-tree` binary.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use sct_format::validate::{validate_file, ValidateOptions};
use sct_format::{Limits, SctReader};

fn models() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/models")
}

fn bin(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sct-build-tree")).args(args).output().expect("run sct-build-tree")
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for e in std::fs::read_dir(from).expect("read_dir") {
        let e = e.expect("entry");
        let target = to.join(e.file_name());
        if e.file_type().expect("type").is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), &target).expect("copy");
        }
    }
}

/// A library with folders: two good OBJ models (one with MTL + texture), a glTF with
/// external buffers, a file that must fail (truncated PLY) and one that is refused (Draco).
fn library(root: &Path) {
    let m = models();
    copy_dir(&m.join("nasty/obj-negative-indices-cube"), &root.join("props/cube"));
    copy_dir(&m.join("nasty/obj-concave-ngons-wallhole"), &root.join("props/wall"));
    copy_dir(&m.join("gltf/Box"), &root.join("gltf/box"));
    copy_dir(&m.join("nasty/ply-truncated-ant-half"), &root.join("broken"));
    copy_dir(&m.join("nasty/gltf-draco-duck"), &root.join("broken/draco"));
}

fn json(out: &Output) -> serde_json::Value {
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&out.stdout)))
}

fn jobs_by_status(rep: &serde_json::Value, status: &str) -> Vec<String> {
    rep["jobs"]
        .as_array()
        .expect("jobs")
        .iter()
        .filter(|j| j["status"] == status)
        .map(|j| j["input"].as_str().expect("input").to_string())
        .collect()
}

#[test]
fn batch_converts_mirrors_skips_up_to_date_and_reports_failures() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (lib, out) = (dir.path().join("lib"), dir.path().join("out"));
    library(&lib);

    let first = bin(&[lib.as_os_str(), "-o".as_ref(), out.as_os_str(), "--json".as_ref()]);
    assert_eq!(first.status.code(), Some(1), "a failed input makes the batch exit 1");
    let rep = json(&first);
    assert_eq!(rep["schema"], "sct-build-tree-batch/1");
    let failed = jobs_by_status(&rep, "failed");
    assert!(failed.iter().any(|p| p.ends_with(".ply")), "{failed:?}");
    assert!(failed.iter().any(|p| p.contains("draco")), "{failed:?}");
    let converted = jobs_by_status(&rep, "converted");
    assert!(converted.len() >= 3, "{converted:?}");
    // Every converted output mirrors its input's folder and validates deeply.
    for job in rep["jobs"].as_array().expect("jobs").iter().filter(|j| j["status"] == "converted") {
        let input = job["input"].as_str().expect("input");
        let output = job["output"].as_str().expect("output");
        assert_eq!(Path::new(output).parent(), Path::new(input).parent(), "{input} -> {output}");
        let r = validate_file(&out.join(output), &ValidateOptions { deep: true, ..Default::default() }).expect("validate");
        assert!(r.issues.is_empty(), "{output}: {:?}", r.issues);
    }
    // The failed input's error names the file.
    let ply_err = rep["jobs"].as_array().expect("jobs").iter().find(|j| j["input"].as_str().is_some_and(|p| p.ends_with(".ply"))).expect("ply job");
    assert!(ply_err["error"].as_str().is_some_and(|e| e.contains("ant-half.ply")), "{ply_err}");

    // Second run: nothing to do, outputs untouched.
    let before: Vec<Vec<u8>> = converted.iter().map(|c| std::fs::read(out.join(Path::new(c).with_extension("sct"))).expect("read")).collect();
    let rep2 = json(&bin(&[lib.as_os_str(), "-o".as_ref(), out.as_os_str(), "--json".as_ref()]));
    assert_eq!(jobs_by_status(&rep2, "up-to-date").len(), converted.len());
    assert!(jobs_by_status(&rep2, "converted").is_empty());
    let after: Vec<Vec<u8>> = converted.iter().map(|c| std::fs::read(out.join(Path::new(c).with_extension("sct"))).expect("read")).collect();
    assert!(before == after);

    // A changed source (or a changed resource of it) is converted again; only it.
    let cube = lib.join("props/cube/negative_indices.obj");
    let mut text = std::fs::read_to_string(&cube).expect("read obj");
    text.push_str("\n# edited\n");
    std::fs::write(&cube, text).expect("write obj");
    // An interrupted run: a stale temporary file and a truncated output.
    let wall_out = out.join("props/wall/wallhole.sct");
    let wall = std::fs::read(&wall_out).expect("read");
    std::fs::write(&wall_out, &wall[..wall.len() / 2]).expect("truncate");
    // (an hour old: younger temp files may belong to a run still in progress)
    let stale = std::fs::File::create(out.join("props/wall/.wallhole.sct.999999.tmp")).expect("stale");
    stale.set_modified(std::time::SystemTime::now() - std::time::Duration::from_secs(7200)).expect("mtime");
    let rep3 = json(&bin(&[lib.as_os_str(), "-o".as_ref(), out.as_os_str(), "--json".as_ref()]));
    let mut again = jobs_by_status(&rep3, "converted");
    again.sort();
    assert_eq!(again, ["props/cube/negative_indices.obj", "props/wall/wallhole.obj"]);
    assert_eq!(rep3["stale_temp_files_removed"], 1);
    assert!(!out.join("props/wall/.wallhole.sct.999999.tmp").exists());
    assert_eq!(std::fs::read(&wall_out).expect("read"), wall, "reconversion is deterministic");

    // Other parameters make every output stale.
    let rep4 = json(&bin(&[lib.as_os_str(), "-o".as_ref(), out.as_os_str(), "--json".as_ref(), "--k".as_ref(), "2".as_ref()]));
    assert_eq!(jobs_by_status(&rep4, "converted").len(), converted.len());
}

/// Regression: the up-to-date check used to resolve the recorded source paths from the
/// current directory, so a batch run from another directory converted everything again.
#[test]
fn up_to_date_check_does_not_depend_on_the_working_directory() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (lib, out) = (dir.path().join("lib"), dir.path().join("out"));
    copy_dir(&models().join("nasty/obj-concave-ngons-wallhole"), &lib.join("wall"));
    // First run from the temp dir with relative paths, second from elsewhere with absolute ones.
    let first = Command::new(env!("CARGO_BIN_EXE_sct-build-tree"))
        .current_dir(dir.path())
        .args(["lib", "-o", "out", "--json"])
        .output()
        .expect("run");
    assert!(first.status.success(), "{}", String::from_utf8_lossy(&first.stderr));
    assert_eq!(jobs_by_status(&json(&first), "converted").len(), 1);
    // Provenance names the sources relative to the library root (portable, not cwd-bound).
    let sct = out.join("wall").read_dir().expect("out").map(|e| e.expect("entry").path()).find(|p| p.extension().is_some_and(|e| e == "sct")).expect("output");
    let g = SctReader::open(&sct, &Limits::default()).expect("open").generator().clone();
    assert!(g.sources.iter().any(|s| s.path.starts_with("wall/") && s.path.ends_with(".obj")), "{:?}", g.sources);
    assert!(g.sources.iter().all(|s| !s.path.starts_with("lib")), "{:?}", g.sources);
    let second = Command::new(env!("CARGO_BIN_EXE_sct-build-tree"))
        .current_dir(lib.join("wall"))
        .args([lib.as_os_str(), "-o".as_ref(), out.as_os_str(), "--json".as_ref()])
        .output()
        .expect("run");
    assert!(second.status.success(), "{}", String::from_utf8_lossy(&second.stderr));
    assert_eq!(jobs_by_status(&json(&second), "up-to-date").len(), 1, "{}", String::from_utf8_lossy(&second.stdout));
}

#[test]
fn shards_partition_the_library() {
    let dir = tempfile::tempdir().expect("tempdir");
    let lib = dir.path().join("lib");
    library(&lib);
    let mut all = Vec::new();
    for k in 0..3 {
        let out = dir.path().join(format!("out{k}"));
        let shard = format!("{k}/3");
        let rep = json(&bin(&[lib.as_os_str(), "-o".as_ref(), out.as_os_str(), "--json".as_ref(), "--shard".as_ref(), shard.as_ref()]));
        assert_eq!(rep["shard"]["index"], k);
        all.extend(rep["jobs"].as_array().expect("jobs").iter().map(|j| j["input"].as_str().expect("input").to_string()));
    }
    let n = all.len();
    all.sort();
    all.dedup();
    assert_eq!(all.len(), n, "an input in two shards");
    let whole = json(&bin(&[lib.as_os_str(), "-o".as_ref(), dir.path().join("whole").as_os_str(), "--json".as_ref()]));
    assert_eq!(whole["jobs"].as_array().expect("jobs").len(), n, "shards miss an input");
    let bad = bin(&[lib.as_os_str(), "-o".as_ref(), dir.path().join("x").as_os_str(), "--shard".as_ref(), "3/3".as_ref()]);
    assert_eq!(bad.status.code(), Some(2));
    // Batch flags outside batch mode, and an output root equal to the library: usage errors.
    let mesh = lib.join("props/cube/negative_indices.obj");
    let one = bin(&[mesh.as_os_str(), "-o".as_ref(), dir.path().join("c.sct").as_os_str(), "--shard".as_ref(), "0/2".as_ref()]);
    assert_eq!(one.status.code(), Some(2));
    let same = bin(&[lib.as_os_str(), "-o".as_ref(), lib.as_os_str()]);
    assert_eq!(same.status.code(), Some(2), "{}", String::from_utf8_lossy(&same.stderr));
}

#[test]
fn one_step_conversion_equals_voxelize_then_build() {
    let dir = tempfile::tempdir().expect("tempdir");
    let model = models().join("nasty/obj-concave-ngons-wallhole/wallhole.obj");
    let one = dir.path().join("one.sct");
    let out = bin(&[model.as_os_str(), "-o".as_ref(), one.as_os_str(), "--k".as_ref(), "2".as_ref(), "--json".as_ref()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let rep = json(&out);
    assert!(rep["sampling"]["samples"].as_u64().is_some_and(|n| n > 100), "{rep}");
    assert_eq!(rep["sampling"]["samples"], rep["build"]["samples"]);

    // The same through a samples file on disk.
    let samples = dir.path().join("two.samples");
    let opts = voxelize::Options {
        inputs: vec![model.clone()],
        output: Some(samples.clone()),
        load: Default::default(),
        sample: voxelize::SampleOptions {
            density: voxelize::Density::Auto { k: 2.0, gamma: 2.0, min_base: None },
            ..Default::default()
        },
    };
    voxelize::run(&opts, &|_, _| {}).expect("voxelize");
    let two = dir.path().join("two.sct");
    let out2 = bin(&[samples.as_os_str(), "-o".as_ref(), two.as_os_str()]);
    assert!(out2.status.success(), "{}", String::from_utf8_lossy(&out2.stderr));

    let (a, b) = (SctReader::open(&one, &Limits::default()).expect("one"), SctReader::open(&two, &Limits::default()).expect("two"));
    assert_eq!(a.trees().len(), b.trees().len());
    for t in 0..a.trees().len() {
        assert_eq!(a.read_tree(t).expect("tree").nodes(), b.read_tree(t).expect("tree").nodes());
    }
    // Provenance: the one-step file names the mesh as its source and records the sampling.
    let g = a.generator();
    assert!(g.sources.iter().any(|s| s.path.ends_with("wallhole.obj")), "{:?}", g.sources);
    assert_eq!(g.parameters["sampling"]["tool"], "sct-voxelize");
    // The two-step file names the samples file and keeps the voxelizer's record, meshes included.
    let g2 = b.generator();
    assert!(g2.sources.iter().any(|s| s.path.ends_with("two.samples")), "{:?}", g2.sources);
    assert_eq!(g2.parameters["sampling"]["tool"], "sct-voxelize");
    let upstream = g2.parameters["sampling"]["sources"].as_array().expect("sampling sources");
    assert!(upstream.iter().any(|s| s["path"].as_str().is_some_and(|p| p.ends_with("wallhole.obj"))), "{upstream:?}");
}

#[test]
fn inputs_are_checked() {
    let dir = tempfile::tempdir().expect("tempdir");
    let o = dir.path().join("x.sct");
    let m = models().join("nasty/obj-negative-indices-cube/negative_indices.obj");
    // Mixing a mesh and a non-mesh is a usage error.
    let out = bin(&[m.as_os_str(), Path::new("x.samples").as_os_str(), "-o".as_ref(), o.as_os_str()]);
    assert_eq!(out.status.code(), Some(2));
    // Sampling flags on a samples-file input would be ignored: refused instead.
    let samples = dir.path().join("cube.samples");
    let opts = voxelize::Options { inputs: vec![m.clone()], output: Some(samples.clone()), load: Default::default(), sample: Default::default() };
    voxelize::run(&opts, &|_, _| {}).expect("voxelize");
    let out = bin(&[samples.as_os_str(), "-o".as_ref(), o.as_os_str(), "--voxel-size".as_ref(), "0.1".as_ref()]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--voxel-size applies to mesh inputs"), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(bin(&[samples.as_os_str(), "-o".as_ref(), o.as_os_str()]).status.success());
    std::fs::remove_file(&o).expect("rm");
    // A mesh that fails to load is bad input, named in the message.
    let bad = models().join("nasty/ply-truncated-ant-half/ant-half.ply");
    let out = bin(&[bad.as_os_str(), "-o".as_ref(), o.as_os_str()]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("ant-half.ply"));
    assert!(!o.exists(), "no output for a failed conversion");
}

/// Regression: a glTF mesh with no triangles (POINTS/LINES only) or whose samples are all
/// transparent used to abort the whole conversion ("no samples to build a tree from").
#[test]
fn meshes_without_samples_are_left_out_with_a_warning() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (i, model) in ["nasty/gltf-primitive-modes/glTF/MeshPrimitiveModes.gltf", "gltf/AlphaBlendModeTest/glTF-Binary/AlphaBlendModeTest.glb"]
        .iter()
        .enumerate()
    {
        let out = dir.path().join(format!("{i}.sct"));
        let run = bin(&[models().join(model).as_os_str(), "-o".as_ref(), out.as_os_str(), "--json".as_ref()]);
        assert!(run.status.success(), "{model}: {}", String::from_utf8_lossy(&run.stderr));
        let rep = json(&run);
        let warnings = rep["sampling"]["warnings"].as_array().expect("warnings");
        assert!(warnings.iter().any(|w| w.as_str().is_some_and(|w| w.contains("produced no samples"))), "{model}: {warnings:?}");
        let v = validate_file(&out, &ValidateOptions::default()).expect("validate");
        assert!(v.issues.is_empty(), "{model}: {:?}", v.issues);
    }
}

/// A batch whose sample budget coarsens one asset names that asset in a warning, in the
/// JSON report and in the human table; the asset within budget gets none.
#[test]
fn budget_that_coarsens_an_asset_warns_by_name() {
    let dir = tempfile::tempdir().expect("tempdir");
    let lib = dir.path().join("lib");
    let m = models();
    copy_dir(&m.join("gltf/Box/glTF-Binary"), &lib.join("box"));
    copy_dir(&m.join("nasty/gltf-no-indices/glTF"), &lib.join("triangle"));
    let out = dir.path().join("out");
    let args = |json: bool| {
        let mut a: Vec<&std::ffi::OsStr> = vec![lib.as_os_str(), "-o".as_ref(), out.as_os_str(), "--sample-budget".as_ref(), "150000".as_ref(), "--force".as_ref()];
        if json {
            a.push("--json".as_ref());
        }
        bin(&a)
    };
    let rep = json(&args(true));
    let warned: Vec<(String, Vec<String>)> = rep["jobs"]
        .as_array()
        .expect("jobs")
        .iter()
        .map(|j| {
            let w = j["warnings"].as_array().expect("warnings").iter().filter_map(|w| w.as_str()).filter(|w| w.contains("sample budget")).map(String::from).collect();
            (j["input"].as_str().unwrap_or("").to_string(), w)
        })
        .collect();
    let coarsened: Vec<&str> = warned.iter().filter(|(_, w)| !w.is_empty()).map(|(i, _)| i.as_str()).collect();
    assert_eq!(coarsened, ["box/Box.glb"], "{warned:?}");
    let human = args(false);
    let table = String::from_utf8_lossy(&human.stdout);
    assert!(table.lines().any(|l| l.starts_with("  box/Box.glb: the sample budget of 150000 coarsened")), "{table}");
    assert!(!table.contains("triangle/TriangleWithoutIndices.gltf: the sample budget"), "{table}");
}

/// The terminal progress bar, forced on a piped stderr with `--progress always`: the batch
/// draws its bar (count, bar, time left, inputs running) and clears it at the end; by
/// default a piped stderr gets no bar at all.
#[test]
fn forced_terminal_progress_draws_the_bar() {
    let dir = tempfile::tempdir().expect("tempdir");
    let lib = dir.path().join("lib");
    copy_dir(&models().join("nasty/obj-negative-indices-cube"), &lib.join("cube"));
    copy_dir(&models().join("gltf/Box"), &lib.join("box"));
    let out = dir.path().join("out");
    let forced = bin(&[lib.as_os_str(), "-o".as_ref(), out.as_os_str(), "--progress".as_ref(), "always".as_ref(), "--jobs".as_ref(), "1".as_ref()]);
    assert!(forced.status.success(), "{}", String::from_utf8_lossy(&forced.stderr));
    let err = String::from_utf8_lossy(&forced.stderr);
    // Three inputs (Box comes as .gltf and .glb), counted up to the last.
    assert!(err.contains("0/3 files [") && err.contains("3/3 files ["), "no bar drawn: {err:?}");
    assert!(err.contains("ETA … · converting ") && err.contains("converting cube/negative_indices.obj"), "no time left or running inputs: {err:?}");
    assert!(err.ends_with("\r\x1b[2K"), "the bar is not cleared at the end: {err:?}");
    let plain = bin(&[lib.as_os_str(), "-o".as_ref(), dir.path().join("out2").as_os_str(), "--jobs".as_ref(), "1".as_ref()]);
    assert!(plain.status.success());
    assert!(!String::from_utf8_lossy(&plain.stderr).contains("files ["), "a bar in a pipe");
}
