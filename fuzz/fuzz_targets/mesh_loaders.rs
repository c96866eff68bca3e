//! Any bytes as a mesh file: the first byte picks the format (OBJ with an MTL beside it, PLY,
//! glTF or GLB), the rest is the file, up to a `0xFF 0xFE` marker after which the bytes are the
//! companion file (the OBJ's `m.mtl`, the glTF's `b.bin`). The file is loaded, and a scene
//! that loads is sampled at a small budget. Errors are fine; findings are panics, hangs
//! (-timeout) and memory past -rss_limit_mb.
#![no_main]
use libfuzzer_sys::fuzz_target;

use std::path::PathBuf;
use std::sync::OnceLock;

use voxelize::{LoadOptions, Options, SampleOptions};

/// One directory per fuzzing process (files are rewritten each run).
fn dir() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("sct-fuzz-mesh-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("temp dir");
        d
    })
}

fuzz_target!(|data: &[u8]| {
    let Some((&kind, rest)) = data.split_first() else { return };
    let (main, companion) = match rest.windows(2).position(|w| w == [0xFF, 0xFE]) {
        Some(i) => (&rest[..i], &rest[i + 2..]),
        None => (rest, &[][..]),
    };
    let (name, other) = match kind % 4 {
        0 => ("m.obj", "m.mtl"),
        1 => ("m.ply", "m.png"),
        2 => ("m.gltf", "b.bin"),
        _ => ("m.glb", "b.bin"),
    };
    let d = dir();
    let path = d.join(name);
    std::fs::write(&path, main).expect("write input");
    std::fs::write(d.join(other), companion).expect("write companion");
    let load = LoadOptions { max_file_bytes: 1 << 20, max_face_corners: 1 << 12, ..LoadOptions::default() };
    if voxelize::load(&path, &load).is_err() || kind & 4 == 0 {
        return;
    }
    let opts = Options {
        inputs: vec![path],
        output: None,
        load,
        sample: SampleOptions { max_samples: 1 << 16, budget: Some(1 << 10), ..SampleOptions::default() },
    };
    let _ = voxelize::sample_in_memory(&opts, &|_, _| {});
});
