//! The CLI's output image and usage errors: `-o x.jpg` writes JPEG (the extension names the
//! format, or the name is refused before rendering), and out-of-range settings are usage
//! errors (exit 2) named by clap, not rendering failures (exit 1).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use render_preview::synth;
use sct_format::write::WriteOptions;

fn sphere(dir: &Path) -> PathBuf {
    let mesh = synth::uv_sphere([0.0, 0.0, 0.0], 1.0, 16, [0.8, 0.3, 0.2, 1.0]);
    let path = dir.join("sphere.sct");
    synth::write_mesh_sct(&mesh, 0.05, &path, &WriteOptions::default()).unwrap();
    path
}

fn run(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sct-render-preview")).args(args).output().unwrap()
}

#[test]
fn the_output_extension_names_the_image_format() {
    let d = tempfile::tempdir().unwrap();
    let file = sphere(d.path());
    for (name, magic) in [("p.jpg", &b"\xff\xd8\xff"[..]), ("p.JPEG", &b"\xff\xd8\xff"[..]), ("p.png", &b"\x89PNG"[..])] {
        let out = d.path().join(name);
        let o = run(&[file.as_os_str(), "-o".as_ref(), out.as_os_str(), "--width".as_ref(), "64".as_ref(), "--height".as_ref(), "48".as_ref()]);
        assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
        assert!(std::fs::read(&out).unwrap().starts_with(magic), "{name}");
    }
    let gif = d.path().join("p.gif");
    let o = run(&[file.as_os_str(), "-o".as_ref(), gif.as_os_str()]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains(".jpg"), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!gif.exists());
}

#[test]
fn out_of_range_settings_are_usage_errors() {
    let d = tempfile::tempdir().unwrap();
    let file = sphere(d.path());
    let out = d.path().join("p.png");
    for args in [["--width", "0"], ["--height", "0"], ["--pixel-error", "0"], ["--pixel-error", "-1"], ["--fov", "0"], ["--fill", "0"]] {
        let arg = format!("{}={}", args[0], args[1]);
        let o = run(&[file.as_os_str(), "-o".as_ref(), out.as_os_str(), arg.as_ref()]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert_eq!(err.matches(args[0]).count(), 1, "named once: {err}");
    }
    assert!(!out.exists());
}
