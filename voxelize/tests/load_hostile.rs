//! Hostile inputs for the loaders, every one generated here: files that are not regular
//! files, URIs leading out of the model's directory or into devices, faces of very many
//! corners, coordinates that overflow areas. Each must be refused (or warned about) with a
//! clear error, never block, read without end or run for minutes.
#![cfg(unix)]

mod common;

use std::path::{Path, PathBuf};

use common::{gltf_with, triangle_bin};
use voxelize::{load, LoadError, LoadOptions};

fn mkfifo(p: &Path) {
    let ok = std::process::Command::new("mkfifo").arg(p).status().expect("run mkfifo").success();
    assert!(ok, "mkfifo {}", p.display());
}

const TRIANGLE_OBJ: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n";

/// Item 5: a FIFO as the input, as an MTL, as the texture override or as a PLY
/// `TextureFile` is never opened for reading (opening it would block forever): the input and
/// the override are refused naming the file, the MTL and the PLY texture become warnings.
#[test]
fn fifos_are_refused_not_opened() {
    let dir = tempfile::tempdir().expect("tempdir");
    let fifo = dir.path().join("pipe.obj");
    mkfifo(&fifo);
    let e = load(&fifo, &LoadOptions::default()).expect_err("a FIFO input is refused");
    assert!(matches!(e, LoadError::NotRegularFile { kind: "a FIFO", .. }), "{e}");
    assert!(e.to_string().contains("pipe.obj"), "{e}");
    assert_eq!(voxelize::Error::from(e).exit_code(), 2);

    // An OBJ whose MTL is a FIFO: loads with the default colour and a warning.
    mkfifo(&dir.path().join("pipe.mtl"));
    let obj = dir.path().join("m.obj");
    std::fs::write(&obj, format!("mtllib pipe.mtl\nusemtl x\n{TRIANGLE_OBJ}")).expect("write");
    let s = load(&obj, &LoadOptions::default()).expect("loads without its MTL");
    assert!(s.warnings.iter().any(|w| w.contains("pipe.mtl")), "{:?}", s.warnings);

    // The texture override names a FIFO: refused, named.
    let tex = dir.path().join("pipe.png");
    mkfifo(&tex);
    let plain = dir.path().join("plain.obj");
    std::fs::write(&plain, TRIANGLE_OBJ).expect("write");
    let e = load(&plain, &LoadOptions { texture_override: Some(tex), ..Default::default() }).expect_err("refused");
    assert!(matches!(&e, LoadError::NotRegularFile { path, .. } if path.ends_with("pipe.png")), "{e}");

    // A PLY whose TextureFile is a FIFO: loads with vertex colours and a warning.
    let ply = dir.path().join("t.ply");
    std::fs::write(
        &ply,
        "ply\nformat ascii 1.0\ncomment TextureFile pipe.png\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
         property float u\nproperty float v\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\
         0 0 0 0 0\n1 0 0 1 0\n0 1 0 0 1\n3 0 1 2\n",
    )
    .expect("write");
    let s = load(&ply, &LoadOptions::default()).expect("loads without its texture");
    assert!(s.warnings.iter().any(|w| w.contains("pipe.png")), "{:?}", s.warnings);
}

/// Items 5 and 14: glTF buffer URIs naming devices (`/dev/zero`, `file:///dev/zero`,
/// `../…/dev/zero`, a symlink to it), a FIFO, or a regular file outside the model's
/// directory. Outside the directory is refused unless allowed; a device or FIFO is refused
/// even when allowed (it is never read: a device reports length 0 and never ends).
#[test]
fn gltf_uris_stay_inside_and_read_only_regular_files() {
    let root = tempfile::tempdir().expect("tempdir");
    let dir = root.path().join("model");
    std::fs::create_dir(&dir).expect("mkdir");
    std::fs::write(dir.join("tri.bin"), triangle_bin()).expect("write");
    std::fs::write(root.path().join("outside.bin"), triangle_bin()).expect("write");
    std::os::unix::fs::symlink("/dev/zero", dir.join("zero.bin")).expect("symlink");
    std::os::unix::fs::symlink(root.path().join("outside.bin"), dir.join("out-link.bin")).expect("symlink");
    mkfifo(&dir.join("pipe.bin"));
    let write = |name: &str, uri: &str| -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, gltf_with(uri, None)).expect("write");
        p
    };
    let deny = LoadOptions::default();
    let allow = LoadOptions { allow_outside_uris: true, ..Default::default() };

    let ok = write("ok.gltf", "tri.bin");
    assert_eq!(load(&ok, &deny).expect("inside loads").stats.triangles_read, 1);
    let spaced = write("spaced.gltf", "sub%20dir/tri.bin");
    std::fs::create_dir(dir.join("sub dir")).expect("mkdir");
    std::fs::write(dir.join("sub dir/tri.bin"), triangle_bin()).expect("write");
    assert_eq!(load(&spaced, &deny).expect("percent-decoded URI loads").stats.triangles_read, 1);

    let outside = write("outside.gltf", "../outside.bin");
    let e = load(&outside, &deny).expect_err("outside refused");
    assert!(matches!(e, LoadError::UriOutsideDirectory { .. }), "{e}");
    assert!(e.to_string().contains("--allow-outside-uris"), "{e}");
    assert_eq!(load(&outside, &allow).expect("allowed").stats.triangles_read, 1);
    let linked_out = write("linked.gltf", "out-link.bin");
    assert!(matches!(load(&linked_out, &deny), Err(LoadError::UriOutsideDirectory { .. })));

    for uri in ["/dev/zero", "file:///dev/zero", "../../../../../../../../../../dev/zero", "zero.bin"] {
        let g = write("dev.gltf", uri);
        let e = load(&g, &deny).expect_err(uri);
        assert!(matches!(e, LoadError::UriOutsideDirectory { .. }), "{uri}: {e}");
        let e = load(&g, &allow).expect_err(uri);
        assert!(matches!(e, LoadError::NotRegularFile { kind: "a character device", .. }), "{uri}: {e}");
    }
    let g = write("fifo.gltf", "pipe.bin");
    assert!(matches!(load(&g, &deny), Err(LoadError::NotRegularFile { kind: "a FIFO", .. })));

    // An image URI into a device or a FIFO: a warning, the geometry still loads.
    for uri in ["/dev/zero", "pipe.bin"] {
        let p = dir.join("img.gltf");
        std::fs::write(&p, gltf_with("tri.bin", Some(uri))).expect("write");
        for opts in [&deny, &allow] {
            let s = load(&p, opts).expect("loads without the image");
            assert!(s.images.is_empty() && s.warnings.iter().any(|w| w.contains("image")), "{uri}: {:?}", s.warnings);
        }
    }
}

/// A star polygon of `n` corners (every other one reflex) as one OBJ face.
fn star_obj(n: usize) -> String {
    let mut s = String::with_capacity(n * 40);
    for i in 0..n {
        let r = if i % 2 == 0 { 1.0 } else { 0.4 };
        let a = (i as f64 + 0.5) * std::f64::consts::TAU / n as f64;
        s.push_str(&format!("v {} {} 0\n", r * a.cos(), r * a.sin()));
    }
    s.push('f');
    for i in 1..=n {
        s.push_str(&format!(" {i}"));
    }
    s.push('\n');
    s
}

/// Item 8: a face with more corners than the limit is refused with a clear error before it
/// is triangulated; a large concave face under the limit triangulates exactly (n − 2
/// triangles).
#[test]
fn face_corner_limit() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("star.obj");
    std::fs::write(&p, star_obj(1000)).expect("write");
    let e = load(&p, &LoadOptions { max_face_corners: 999, ..Default::default() }).expect_err("over the limit");
    assert!(matches!(&e, LoadError::Limit { what, .. } if what.contains("1000 corners") && what.contains("999")), "{e}");
    let s = load(&p, &LoadOptions::default()).expect("under the default limit");
    assert_eq!(s.stats.triangles_read, 998);

    let ply = dir.path().join("star.ply");
    let mut text = String::from("ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n");
    text.push_str("0 0 0\n1 0 0\n1 1 0\n0.5 0.5 0\n0 1 0\n5 0 1 2 3 4\n");
    std::fs::write(&ply, text).expect("write");
    let e = load(&ply, &LoadOptions { max_face_corners: 4, ..Default::default() }).expect_err("over the limit");
    assert!(matches!(&e, LoadError::Limit { what, .. } if what.contains("5 corners")), "{e}");
}

/// Item 19: finite vertices near ±3·10³⁸ (each one a valid f32) make infinite areas; the
/// load refuses them naming the mesh, in every format and through an instance's scale.
#[test]
fn coordinates_that_overflow_areas_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let obj = dir.path().join("huge.obj");
    std::fs::write(&obj, "o giant\nv -3e38 -3e38 0\nv 3e38 -3e38 0\nv 0 3e38 0\nf 1 2 3\n").expect("write");
    let e = load(&obj, &LoadOptions::default()).expect_err("refused");
    assert!(matches!(&e, LoadError::Limit { what, .. } if what.contains("giant")), "{e}");

    let ply = dir.path().join("huge.ply");
    std::fs::write(
        &ply,
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\n\
         property list uchar int vertex_indices\nend_header\n-3e38 0 0\n3e38 0 0\n0 3e38 0\n3 0 1 2\n",
    )
    .expect("write");
    assert!(matches!(load(&ply, &LoadOptions::default()), Err(LoadError::Limit { .. })));

    // A unit triangle under a node scale of 1e30: huge only in world space.
    let bin = dir.path().join("tri.bin");
    std::fs::write(&bin, triangle_bin()).expect("write");
    let g = dir.path().join("scaled.gltf");
    let text = gltf_with("tri.bin", None).replace(r#""nodes":[{"mesh":0}]"#, r#""nodes":[{"mesh":0,"scale":[1e30,1e30,1e30]}]"#);
    std::fs::write(&g, text).expect("write");
    assert!(matches!(load(&g, &LoadOptions::default()), Err(LoadError::Limit { .. })));
    // Large but sane coordinates still load.
    std::fs::write(&obj, "v -1e12 -1e12 0\nv 1e12 -1e12 0\nv 0 1e12 0\nf 1 2 3\n").expect("write");
    assert!(load(&obj, &LoadOptions::default()).is_ok());
}

/// Item 16: `-o /dev/null` writes through the device (it stays a character device, as
/// root too, where a rename over it used to succeed); `-o /dev/full` fails with the OS's
/// error and `/dev/full` stays a device; an output symlink to a regular file survives.
#[test]
fn device_and_symlink_outputs_are_not_replaced() {
    use std::os::unix::fs::FileTypeExt;
    let dir = tempfile::tempdir().expect("tempdir");
    let obj = dir.path().join("t.obj");
    std::fs::write(&obj, TRIANGLE_OBJ).expect("write");
    let opts = |out: &Path| voxelize::Options {
        inputs: vec![obj.clone()],
        output: Some(out.to_path_buf()),
        load: LoadOptions::default(),
        sample: voxelize::SampleOptions { density: voxelize::Density::VoxelSize(0.1), ..Default::default() },
    };
    let is_dev = |p: &str| std::fs::symlink_metadata(p).expect("lstat").file_type().is_char_device();
    voxelize::run(&opts(Path::new("/dev/null")), &|_, _| {}).expect("written to /dev/null");
    assert!(is_dev("/dev/null"));
    let e = voxelize::run(&opts(Path::new("/dev/full")), &|_, _| {}).expect_err("no space on /dev/full");
    assert_eq!(e.exit_code(), 2, "{e}");
    assert!(is_dev("/dev/full"));

    let real = dir.path().join("real.samples");
    std::fs::write(&real, b"old").expect("write");
    let link = dir.path().join("link.samples");
    std::os::unix::fs::symlink(&real, &link).expect("symlink");
    voxelize::run(&opts(&link), &|_, _| {}).expect("written through the link");
    assert!(std::fs::symlink_metadata(&link).expect("lstat").file_type().is_symlink());
    assert!(std::fs::metadata(&real).expect("stat").len() > 3, "the link's target holds the samples");
}

/// glTF nodes shared between parents: 2 × 40 nodes, each level's two both children of both
/// nodes above, 2^40 paths to the mesh from a 2 KB file (at 60 levels the loader took 7 s
/// and 0.7 GB before its visit cap). glTF node hierarchies are strict trees: a node reached
/// twice is refused at once. A node that is a root and a child, or a cycle, likewise.
#[test]
fn gltf_nodes_reached_twice_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(dir.path().join("tri.bin"), triangle_bin()).expect("write");
    let mut nodes = vec![r#"{"mesh":0}"#.to_string(), r#"{"mesh":0}"#.to_string()];
    for k in 1..40 {
        let c = format!(r#"{{"children":[{},{}]}}"#, 2 * (k - 1), 2 * (k - 1) + 1);
        nodes.push(c.clone());
        nodes.push(c);
    }
    let top = nodes.len();
    let base = gltf_with("tri.bin", None);
    for (name, nodes, roots) in [
        ("dag.gltf", nodes.join(","), format!("{},{}", top - 2, top - 1)),
        ("twice.gltf", r#"{"children":[1]},{"mesh":0}"#.to_string(), "0,1".to_string()),
        ("cycle.gltf", r#"{"children":[1]},{"children":[0],"mesh":0}"#.to_string(), "0".to_string()),
    ] {
        let text = base.replace(r#""nodes":[{"mesh":0}],"scenes":[{"nodes":[0]}]"#, &format!(r#""nodes":[{nodes}],"scenes":[{{"nodes":[{roots}]}}]"#));
        assert_ne!(text, base);
        let p = dir.path().join(name);
        std::fs::write(&p, text).expect("write");
        let t = std::time::Instant::now();
        match load(&p, &LoadOptions::default()) {
            Err(e) => assert!(e.to_string().contains("reached twice"), "{name}: {e}"),
            Ok(s) => panic!("{name}: {} instances", s.instances.len()),
        }
        assert!(t.elapsed().as_secs() < 2, "{name}: {:?}", t.elapsed());
    }
}

/// A POSITION attribute naming an accessor the file does not have (found by the
/// `mesh_loaders` fuzz target): the gltf crate's validator looked it up unchecked and
/// panicked. Refused with the mesh, the primitive and the index, also when the file has no
/// accessors at all.
#[test]
fn gltf_position_naming_a_missing_accessor_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(dir.path().join("tri.bin"), triangle_bin()).expect("write");
    let base = gltf_with("tri.bin", None);
    for (name, from, to, want) in [
        ("index.gltf", r#""POSITION":0"#, r#""POSITION":2"#, "accessor 2, but the file has 1 accessors"),
        ("none.gltf", r#""accessors":["#, r#""accessoms":["#, "accessor 0, but the file has 0 accessors"),
    ] {
        let text = base.replace(from, to);
        assert_ne!(text, base);
        let p = dir.path().join(name);
        std::fs::write(&p, text).expect("write");
        let e = load(&p, &LoadOptions::default()).expect_err(name);
        let msg = e.to_string();
        assert!(msg.contains("mesh 0 primitive 0") && msg.contains(want) && msg.contains(name), "{name}: {msg}");
        assert_eq!(voxelize::Error::from(e).exit_code(), 1, "{name}");
    }
}

/// A GLB whose header declares fewer bytes than the header itself (found by the
/// `mesh_loaders` fuzz target; the gltf crate's subtraction overflowed): refused, named.
#[test]
fn glb_declaring_less_than_its_header_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    for declared in [0u32, 11] {
        let mut glb = b"glTF".to_vec();
        glb.extend(2u32.to_le_bytes());
        glb.extend(declared.to_le_bytes());
        glb.extend([0u8; 20]);
        let p = dir.path().join(format!("short{declared}.glb"));
        std::fs::write(&p, glb).expect("write");
        let e = load(&p, &LoadOptions::default()).expect_err("refused");
        assert!(e.to_string().contains(&format!("declares {declared} bytes")), "{e}");
        assert_eq!(voxelize::Error::from(e).exit_code(), 1);
    }
}

/// A placement with a zero scale (found by the `mesh_loaders` fuzz target): baked into world
/// space it flattens its copy of the mesh, whose triangles then have no plane (their depth
/// plane divided by zero: an overflow in debug builds, a stray zero-area sample from the
/// scan-line sampler). The flattened copy samples nothing; the other copy samples as alone,
/// and only the singular placement is counted as such.
#[test]
fn a_flattening_placement_samples_nothing() {
    use voxelize::sample::{sample_scene, Density, Method, SampleOptions};
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(dir.path().join("tri.bin"), triangle_bin()).expect("write");
    let base = gltf_with("tri.bin", None);
    let two = r#""nodes":[{"mesh":0},{"mesh":0,"scale":[1,0,1],"translation":[0,0,1]}],"scenes":[{"nodes":[0,1]}]"#;
    let text = base.replace(r#""nodes":[{"mesh":0}],"scenes":[{"nodes":[0]}]"#, two);
    assert_ne!(text, base);
    let p = dir.path().join("flat.gltf");
    std::fs::write(&p, text).expect("write");
    let scene = load(&p, &LoadOptions::default()).expect("loads");
    for method in [Method::Voxel, Method::Scanline] {
        let opts = SampleOptions { method, density: Density::VoxelSize(0.1), ..Default::default() };
        let s = sample_scene(&scene, &opts, &|_, _| {}).expect("samples");
        let sets: Vec<_> = s.meshes.iter().filter(|m| !m.samples.is_empty()).collect();
        assert_eq!((s.meshes.len(), sets.len()), (2, 1), "{method:?}: the flattened copy samples nothing");
        assert_eq!(s.stats.baked_non_similar, 1, "{method:?}");
        let samples = &sets[0].samples;
        assert!(samples.iter().all(|n| n.center.iter().chain(&n.normal).all(|c| c.is_finite()) && n.area > 0.0), "{method:?}");
        let area: f64 = samples.iter().map(|n| n.area as f64).sum();
        assert!((area - 0.5).abs() < 1e-6, "{method:?}: sample area {area}");
    }
}

/// An MTL colour statement with fewer than three numbers (found by the `mesh_loaders` fuzz
/// target; tobj unwrapped them and panicked, so the whole OBJ failed): the model loads with
/// the default colour and a warning naming the library, the line and the keyword, like any
/// other unreadable material library.
#[test]
fn an_mtl_colour_short_of_numbers_is_a_warning() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (k, line) in ["Kd 1 0", "Ks", "Ka 0.5"].iter().enumerate() {
        std::fs::write(dir.path().join("m.mtl"), format!("newmtl x\nNs 10\n{line}\n")).expect("write");
        let obj = dir.path().join(format!("m{k}.obj"));
        std::fs::write(&obj, format!("mtllib m.mtl\nusemtl x\n{TRIANGLE_OBJ}")).expect("write");
        let s = load(&obj, &LoadOptions::default()).expect("loads without its materials");
        let key = line.split(' ').next().expect("a keyword");
        assert!(s.warnings.iter().any(|w| w.contains("m.mtl") && w.contains(&format!("line 3: {key} needs three numbers"))), "{line}: {:?}", s.warnings);
        assert_eq!(s.meshes.iter().map(|m| m.primitives.len()).sum::<usize>(), 1, "{line}");
    }
}

/// A buffer view whose byteStride is less than its accessor's element (found by the
/// `mesh_loaders` fuzz target: gltf's iterator asserts against it in debug builds and reads
/// overlapping elements in release ones): refused, naming the accessor and the stride.
#[test]
fn gltf_stride_below_the_element_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(dir.path().join("tri.bin"), triangle_bin()).expect("write");
    let base = gltf_with("tri.bin", None);
    let text = base.replace(r#""bufferViews":[{"buffer":0,"byteLength":36}]"#, r#""bufferViews":[{"buffer":0,"byteLength":36,"byteStride":8}]"#);
    assert_ne!(text, base);
    let p = dir.path().join("stride.gltf");
    std::fs::write(&p, text).expect("write");
    let e = load(&p, &LoadOptions::default()).expect_err("refused");
    let msg = e.to_string();
    assert!(msg.contains("accessor 0 (POSITION)") && msg.contains("byteStride 8, less than the 12-byte element"), "{msg}");
    assert_eq!(voxelize::Error::from(e).exit_code(), 1);
}

/// A PLY header number past 64 bits, in the format version or an element count (found by
/// the `mesh_loaders` fuzz target: the header grammar unwrapped its parse and panicked, so a
/// panic message and backtrace reached the terminal before the error): refused with its
/// line, no panic.
#[test]
fn ply_header_numbers_past_64_bits_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let huge = "18446744073709551616"; // u64::MAX + 1
    for (name, header, line) in [
        ("version.ply", format!("ply\nformat ascii 1.{huge}\nelement vertex 3\n"), 2),
        ("count.ply", format!("ply\nformat ascii 1.0\nelement vertex {huge}\n"), 3),
    ] {
        let p = dir.path().join(name);
        std::fs::write(&p, format!("{header}property float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n")).expect("write");
        let e = load(&p, &LoadOptions::default()).expect_err(name);
        assert!(!matches!(e, LoadError::ParserPanic { .. }), "{name}: {e}");
        assert!(e.to_string().contains(&format!("header line {line}: a number too large for 64 bits")), "{name}: {e}");
    }
    // u64::MAX itself parses (and the count is then refused as more than the file holds).
    let p = dir.path().join("max.ply");
    std::fs::write(&p, "ply\nformat ascii 1.0\nelement vertex 18446744073709551615\nproperty float x\nend_header\n0\n").expect("write");
    let e = load(&p, &LoadOptions::default()).expect_err("refused");
    assert!(!e.to_string().contains("too large for 64 bits") && !matches!(e, LoadError::ParserPanic { .. }), "{e}");
}
