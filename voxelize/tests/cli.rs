//! The binary: exit statuses, JSON summary, atomic output.

mod common;

use std::process::Command;

use common::model;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_sct-voxelize"))
}

#[test]
fn exit_codes_and_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("box.samples");
    // Usage error: no input.
    assert_eq!(bin().status().unwrap().code(), Some(2));
    // I/O error: missing input.
    let st = bin().args(["/nonexistent.obj", "-o"]).arg(&out).output().unwrap();
    assert_eq!(st.status.code(), Some(2));
    assert!(!out.exists());
    let Some(bx) = model("gltf/Box/glTF-Binary/Box.glb") else { return };
    let st = bin().arg(&bx).arg("-o").arg(&out).args(["--voxel-size", "0.05", "--json"]).output().unwrap();
    assert_eq!(st.status.code(), Some(0), "{}", String::from_utf8_lossy(&st.stderr));
    let v: serde_json::Value = serde_json::from_slice(&st.stdout).unwrap();
    assert!(v["samples"].as_u64().unwrap() > 100);
    assert_eq!(v["voxel_size"].as_f64(), Some(0.05));
    let f = sct_format::samples::SamplesFile::read_file(&out, &sct_format::Limits::default()).unwrap();
    assert_eq!(f.samples.len() as u64, v["samples"].as_u64().unwrap());
    assert_eq!(f.generator.tool, "sct-voxelize");
    assert!(!f.generator.sources.is_empty());
    // Bad input: Draco → 1, and the earlier output is left untouched.
    let before = std::fs::read(&out).unwrap();
    if let Some(draco) = model("nasty/gltf-draco-duck/glTF-Draco/Duck.gltf") {
        let st = bin().arg(&draco).arg("-o").arg(&out).output().unwrap();
        assert_eq!(st.status.code(), Some(1));
        let err = String::from_utf8_lossy(&st.stderr);
        assert!(err.contains("KHR_draco_mesh_compression"), "{err}");
        assert_eq!(err.matches("error").count(), 1, "printed once: {err}");
    }
    assert_eq!(std::fs::read(&out).unwrap(), before);
    // Bad flag value → 2.
    let st = bin().arg(&bx).arg("-o").arg(&out).args(["--voxel-size", "-1"]).output().unwrap();
    assert_eq!(st.status.code(), Some(2));
}

/// `--sample-budget` coarsens the voxel to about N samples (after merging), says so in the
/// voxel reason, leaves a coarser density alone, and refuses a budget that cannot be met.
#[test]
fn sample_budget_caps_the_density() {
    let Some(bunny) = model("scans/stanford-bunny-original-ply/bun_zipper.ply") else { return };
    let run = |args: &[&str]| {
        let st = bin().arg(&bunny).args(["-o", "unused.samples", "--dry-run", "--json"]).args(args).output().unwrap();
        (st.status.code(), serde_json::from_slice::<serde_json::Value>(&st.stdout).ok(), String::from_utf8_lossy(&st.stderr).into_owned())
    };
    let (code, v, err) = run(&["--sample-budget", "50000"]);
    assert_eq!(code, Some(0), "{err}");
    let v = v.unwrap();
    let n = v["samples"].as_u64().unwrap();
    assert!((45_000..=51_000).contains(&n), "{n} samples for a budget of 50000");
    assert!(v["voxel_size_reason"].as_str().unwrap().contains("coarsened"), "{v}");
    assert!(!v["warnings"].to_string().contains("quarters"), "an untextured scan keeps to its budget: {v}");
    // Already coarser than the budget needs: unchanged.
    let (_, plain, _) = run(&["--voxel-size", "0.004"]);
    let (_, capped, _) = run(&["--voxel-size", "0.004", "--sample-budget", "50000000"]);
    assert_eq!(plain.unwrap()["samples"], capped.unwrap()["samples"]);
    // Without merging every triangle keeps a sample: a budget below the triangle count fails.
    let (code, _, err) = run(&["--sample-budget", "1000", "--no-merge"]);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("--sample-budget 1000 cannot be met"), "{err}");
}

/// A textured model's pieces whose colour varies are sampled by quarters, which the
/// budget's estimate (made before sampling) does not count: when they take the count more
/// than 10 % past the budget, a warning says by how much and why.
#[test]
fn sample_budget_overshoot_from_colour_quarters_warns() {
    let Some(helmet) = model("gltf/DamagedHelmet/glTF-Binary/DamagedHelmet.glb") else { return };
    let st = bin().arg(&helmet).args(["-o", "unused.samples", "--dry-run", "--json", "--sample-budget", "100000"]).output().unwrap();
    assert_eq!(st.status.code(), Some(0), "{}", String::from_utf8_lossy(&st.stderr));
    let v: serde_json::Value = serde_json::from_slice(&st.stdout).unwrap();
    let n = v["samples"].as_u64().unwrap();
    assert!(n > 110_000, "{n} samples: the overshoot this test is about is gone; drop the warning if the estimate now counts quarters");
    let warnings = v["warnings"].to_string();
    assert!(warnings.contains("the sample budget of 100000") && warnings.contains("sampled by quarters"), "{v}");
    assert!(String::from_utf8_lossy(&st.stderr).contains("sampled by quarters"));
}

/// A voxel wider than the model is clamped to the model's largest extent, and the JSON
/// summary carries the warning (also printed to stderr).
#[test]
fn oversized_voxel_is_clamped_with_a_warning() {
    let Some(duck) = model("gltf/Duck/glTF-Binary/Duck.glb") else { return };
    let st = bin().arg(&duck).args(["--dry-run", "--json", "--voxel-size", "1000"]).output().unwrap();
    assert_eq!(st.status.code(), Some(0), "{}", String::from_utf8_lossy(&st.stderr));
    let v: serde_json::Value = serde_json::from_slice(&st.stdout).unwrap();
    assert!(v["voxel_size"].as_f64().unwrap() < 1000.0, "{v}");
    let warnings = v["warnings"].as_array().unwrap();
    assert!(warnings.iter().any(|w| w.as_str().unwrap().contains("larger than the model")), "{v}");
    assert!(String::from_utf8_lossy(&st.stderr).contains("larger than the model"));
}

/// A few KB of stacked quads ask the default density for tens of millions of samples (each
/// layer fills the intended view): the default budget coarsens the voxel, with a warning,
/// so a small file cannot take a conversion's time and memory. An explicit voxel size is
/// bounded by --max-samples instead.
#[test]
fn stacked_surfaces_meet_the_default_budget() {
    let dir = tempfile::tempdir().unwrap();
    let obj = dir.path().join("stack.obj");
    let mut text = String::new();
    for k in 0..200 {
        let z = k as f64 * 0.001;
        text += &format!("v 0 0 {z}\nv 1 0 {z}\nv 1 1 {z}\nv 0 1 {z}\n");
        let b = 4 * k + 1;
        text += &format!("f {} {} {}\nf {} {} {}\n", b, b + 1, b + 2, b, b + 2, b + 3);
    }
    std::fs::write(&obj, text).unwrap();
    assert!(std::fs::metadata(&obj).unwrap().len() < 20_000);
    let st = bin().arg(&obj).args(["--dry-run", "--json"]).output().unwrap();
    assert_eq!(st.status.code(), Some(0), "{}", String::from_utf8_lossy(&st.stderr));
    let v: serde_json::Value = serde_json::from_slice(&st.stdout).unwrap();
    let samples = v["samples"].as_u64().unwrap();
    assert!(samples <= 4_400_000, "{samples} samples");
    let warned = v["warnings"].as_array().unwrap().iter().any(|w| w.as_str().is_some_and(|w| w.contains("sample budget of 4000000")));
    assert!(warned, "{:?}", v["warnings"]);
    let st = bin().arg(&obj).args(["--dry-run", "--json", "--voxel-size", "1e-5"]).output().unwrap();
    assert_eq!(st.status.code(), Some(1), "refused by --max-samples: {}", String::from_utf8_lossy(&st.stderr));
}

/// A file that is not a mesh is named by what it is (STL, FBX, an SCT file), not by its
/// magic bytes; a GLB without its extension still loads.
#[test]
fn inputs_are_named_by_their_content() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.samples");
    let stl = dir.path().join("tri.stl");
    std::fs::write(&stl, "solid t\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   vertex 1 0 0\n   vertex 0 1 0\n  endloop\n endfacet\nendsolid t\n").unwrap();
    let fbx = dir.path().join("x.fbx");
    std::fs::write(&fbx, b"Kaydara FBX Binary  \x00\x1a\x00").unwrap();
    let sct = dir.path().join("scene.sct");
    std::fs::write(&sct, sct_format::raw::SCT_MAGIC).unwrap();
    for (input, want) in [(&stl, "STL is not supported"), (&fbx, "FBX is not supported"), (&sct, "this is an SCT scene file")] {
        let st = bin().arg(input).arg("-o").arg(&out).output().unwrap();
        let err = String::from_utf8_lossy(&st.stderr);
        assert_eq!(st.status.code(), Some(1), "{err}");
        assert!(err.contains(want) && !err.contains("magic"), "{err}");
        assert_eq!(err.lines().count(), 1, "said once: {err}");
    }
    let Some(glb) = model("gltf/Box/glTF-Binary/Box.glb") else { return };
    let bare = dir.path().join("box");
    std::fs::copy(glb, &bare).unwrap();
    let st = bin().arg(&bare).arg("-o").arg(&out).args(["--voxel-size", "0.1"]).output().unwrap();
    assert_eq!(st.status.code(), Some(0), "{}", String::from_utf8_lossy(&st.stderr));
}

/// A sample count over --max-samples with an explicit --voxel-size suggests what applies to
/// it (a larger voxel size), not the other density rules' knobs.
#[test]
fn a_rejected_voxel_size_suggests_a_larger_one() {
    let Some(bx) = model("gltf/Box/glTF-Binary/Box.glb") else { return };
    let st = bin().arg(&bx).args(["--dry-run", "--voxel-size", "0.0005", "--max-samples", "1000"]).output().unwrap();
    let err = String::from_utf8_lossy(&st.stderr);
    assert_ne!(st.status.code(), Some(0), "{err}");
    assert!(err.contains("larger --voxel-size"), "{err}");
    assert!(!err.contains("screen-error") && !err.contains('γ') && !err.contains("gamma"), "{err}");
}

/// Ctrl-C (SIGINT) or SIGTERM while a samples file is written: the hidden temporary file
/// is removed, the exit status is 128 + signal, and no output appears.
#[cfg(unix)]
#[test]
fn an_interrupted_run_leaves_no_temporary_file() {
    let Some(dragon) = model("scans/stanford-dragon-100k/dragon.ply") else { return };
    for (signal, code) in [("-INT", 130), ("-TERM", 143)] {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("dragon.samples");
        let mut child = bin().arg(&dragon).arg("-o").arg(&out).args(["--voxel-size", "0.05", "--threads", "1"]).stderr(std::process::Stdio::piped()).spawn().unwrap();
        let tmp_exists = || std::fs::read_dir(dir.path()).unwrap().flatten().any(|e| e.file_name().to_string_lossy().ends_with(".tmp"));
        let t0 = std::time::Instant::now();
        while !tmp_exists() && t0.elapsed().as_secs() < 60 && child.try_wait().unwrap().is_none() {
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        assert!(tmp_exists(), "the run finished before it could be interrupted; make it longer");
        let k = Command::new("kill").arg(signal).arg(child.id().to_string()).status().unwrap();
        assert!(k.success());
        let o = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(code), "{err}");
        assert!(err.contains("temporary file(s) removed"), "{err}");
        let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().flatten().map(|e| e.file_name()).collect();
        assert!(left.is_empty(), "left behind: {left:?}");
    }
}

/// `-o DIR/` and `-o missing/x.samples`: usage/I/O errors (2) that say what is wrong with
/// the output path, naming it once and never the hidden temporary file.
#[test]
fn output_path_errors_say_what_is_wrong_once() {
    let Some(bx) = model("gltf/Box/glTF-Binary/Box.glb") else { return };
    let dir = tempfile::tempdir().unwrap();
    let slash = format!("{}/", dir.path().join("od").display());
    let missing = dir.path().join("missing/x.samples");
    for (out, want) in [(slash.clone(), "names a directory"), (missing.display().to_string(), "does not exist")] {
        let st = bin().arg(&bx).args(["-o", &out, "--voxel-size", "0.1"]).output().unwrap();
        let err = String::from_utf8_lossy(&st.stderr);
        assert_eq!(st.status.code(), Some(2), "{err}");
        assert!(err.contains(want) && !err.contains(".x.samples.") && !err.contains("Not a directory"), "{err}");
        assert_eq!(err.matches(out.trim_end_matches('/')).count(), 1 + usize::from(out.ends_with('/')), "{err}");
    }
}

/// A glTF placing one mesh by 3,000 affine (non-uniformly scaled) nodes: every placement is
/// a copy of the mesh's samples downstream (build-tree bakes them), and the area tally
/// transforms each sample once per placement. The default budget counts the copies, so the
/// run stays small (the mesh sampled at the density of 14,500 placements took 6 s to tally,
/// and its samples times placements could reach billions).
#[test]
fn affine_copies_count_against_the_budget() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("tri.bin"), common::triangle_bin()).unwrap();
    let nodes: Vec<String> = (0..3000).map(|i| format!(r#"{{"mesh":0,"scale":[{},1,2],"translation":[{},0,0]}}"#, 1.0 + i as f64 * 1e-3, i as f64 * 0.01)).collect();
    let roots: Vec<String> = (0..3000).map(|i| i.to_string()).collect();
    let gltf = format!(
        r#"{{"asset":{{"version":"2.0"}},"buffers":[{{"uri":"tri.bin","byteLength":36}}],"bufferViews":[{{"buffer":0,"byteLength":36}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],"nodes":[{}],"scenes":[{{"nodes":[{}]}}],"scene":0}}"#,
        nodes.join(","),
        roots.join(",")
    );
    let p = dir.path().join("nodes.gltf");
    std::fs::write(&p, gltf).unwrap();
    let st = bin().arg(&p).args(["--dry-run", "--json", "--sample-budget", "300000"]).output().unwrap();
    assert_eq!(st.status.code(), Some(0), "{}", String::from_utf8_lossy(&st.stderr));
    let v: serde_json::Value = serde_json::from_slice(&st.stdout).unwrap();
    let samples = v["samples"].as_u64().unwrap();
    assert!(samples * 3001 <= 600_000, "{samples} samples, each copied 3,000 times");
}

/// Regression: `sct-voxelize … --json | head -c 100` panicked ("failed printing to stdout")
/// when the reader closed the pipe. A closed pipe ends the output quietly.
#[test]
fn a_closed_stdout_pipe_is_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let obj = dir.path().join("quad.obj");
    std::fs::write(&obj, "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n").unwrap();
    let out = dir.path().join("quad.samples");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_sct-voxelize"))
        .args([obj.to_str().unwrap(), "-o", out.to_str().unwrap(), "--json"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(o.status.code(), Some(0), "{err}");
}

/// A model named by its bare file name, run from its own directory, finds the files beside
/// it: a glTF's external buffer (its directory used to be the empty path, which does not
/// canonicalize, so the buffer was refused as outside it) and an OBJ's MTL.
#[test]
fn a_bare_file_name_finds_the_files_beside_it() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("tri.bin"), common::triangle_bin()).unwrap();
    std::fs::write(dir.path().join("tri.gltf"), common::gltf_with("tri.bin", None)).unwrap();
    std::fs::write(dir.path().join("m.mtl"), "newmtl red\nKd 1 0 0\n").unwrap();
    std::fs::write(dir.path().join("tri.obj"), "mtllib m.mtl\nusemtl red\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    for name in ["tri.gltf", "tri.obj"] {
        let st = bin().current_dir(dir.path()).args([name, "-o", "out.samples", "--voxel-size", "0.1", "--json"]).output().unwrap();
        assert_eq!(st.status.code(), Some(0), "{name}: {}", String::from_utf8_lossy(&st.stderr));
        let v: serde_json::Value = serde_json::from_slice(&st.stdout).unwrap();
        assert_eq!(v["warnings"].as_array().map(Vec::len), Some(0), "{name}: {}", v["warnings"]);
        let f = sct_format::samples::SamplesFile::read_file(&dir.path().join("out.samples"), &sct_format::Limits::default()).unwrap();
        assert!(!f.samples.is_empty(), "{name}");
        if name == "tri.obj" {
            assert!(f.samples.iter().all(|s| s.color[..3] == [255, 0, 0]), "{name}: the MTL's colour");
        }
    }
}
