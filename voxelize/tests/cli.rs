//! The binary: exit statuses, JSON summary, atomic output.

use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_sct-voxelize"))
}

fn model(rel: &str) -> Option<std::path::PathBuf> {
    let p = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/models").join(rel);
    p.exists().then_some(p)
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
