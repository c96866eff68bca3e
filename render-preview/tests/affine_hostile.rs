//! Hostile affine instances (SCT 1.3) through every method: matrices the reader accepts one
//! by one but whose world maps reach the edges of f32 and f64 (entries near f32::MAX, deep
//! chains that compose past f64, mirrors, near-singular products) must render or fail with an
//! error, within the render limits and in bounded time, never panic; a matrix or reference the
//! reader refuses fails the render with the reader's error.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use render_preview::{render_file, Method, RenderOptions};
use sct_format::graph::InstanceAttrs;
use sct_format::container::{write_container, SectionOut};
use sct_format::raw::SCT_MAGIC;
use sct_format::write::{write_scene_file, Scene, WriteOptions};
use sct_format::{Affine, Generator, GraphNode, Profile, SceneGraph, SceneTree};

const METHODS: [Method; 6] = [Method::Zbuffer, Method::Gauss, Method::Canopy, Method::Parilov, Method::Wald, Method::Wand];

fn diag(x: f64, y: f64, z: f64) -> Affine {
    Affine { matrix: [[x, 0.0, 0.0, 0.0], [0.0, y, 0.0, 0.0], [0.0, 0.0, z, 0.0]] }
}

fn sphere_tree() -> SceneTree {
    let mesh = render_preview::synth::uv_sphere([0.5, 0.25, 0.0], 1.0, 12, [0.8, 0.5, 0.3, 1.0]);
    render_preview::synth::build_tree(render_preview::synth::sample_mesh(&mesh, 0.15)).expect("tree")
}

/// A scene of the sphere's tree under a chain of affine instances, `chain[0]` innermost.
fn write_chain(path: &Path, chain: &[Affine]) -> PathBuf {
    let mut nodes = vec![GraphNode::Tree { tree: 0 }];
    for (k, a) in chain.iter().enumerate() {
        nodes.push(GraphNode::Affine { child: k as u32, transform: *a, attrs: InstanceAttrs::default() });
    }
    let root = chain.len() as u32;
    let scene = Scene { generator: Generator { tool: "test".into(), ..Default::default() }, graph: SceneGraph { nodes, root }, trees: vec![sphere_tree()] };
    write_scene_file(path, &scene, &WriteOptions { profile: Profile::Raw, ..Default::default() }).expect("every matrix is valid on its own");
    path.to_path_buf()
}

/// Small renders with tight node and pixel limits: a framed view, and a fixed camera near
/// the origin (the framed one may refuse a scene whose bound is not finite).
fn renders(p: &Path) {
    for method in METHODS {
        let base = RenderOptions { method, width: 48, height: 36, max_nodes: 50_000, max_splat_pixels: 4_000_000, ..RenderOptions::default() };
        let fixed = RenderOptions { eye: Some([0.0, 0.0, 6.0]), target: Some([0.0; 3]), ..base.clone() };
        for opts in [base, fixed] {
            let t = Instant::now();
            let r = render_file(p, &opts);
            assert!(t.elapsed() < Duration::from_secs(20), "{}: {method:?} took {:?}", p.display(), t.elapsed());
            if let Ok(r) = r {
                assert_eq!(r.frame.width * r.frame.height, 48 * 36, "{method:?}");
            }
        }
    }
}

#[test]
fn hostile_affine_chains_render_or_fail_in_every_method() {
    let dir = tempfile::tempdir().expect("tempdir");
    let big = f32::MAX as f64;
    // Each matrix passes the reader's checks: entries ≤ f32::MAX, a normal determinant,
    // condition ≤ 10⁶.
    let shear = Affine { matrix: [[1.0, 900.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]] };
    let cases: Vec<(&str, Vec<Affine>)> = vec![
        // One map to the edge of f32: world centres and radii overflow f32.
        ("f32max", vec![diag(big, big, big)]),
        ("f32max-mirror", vec![diag(-big, big, big)]),
        ("1e38-translate", vec![Affine { matrix: [[1e3, 0.0, 0.0, 3e38], [0.0, 1.0, 0.0, -3e38], [0.0, 0.0, 1e-2, 3e38]] }]),
        // Chains that compose past f64: entries, determinant and condition all overflow.
        ("chain-up", vec![diag(big, big, big); 12]),
        ("chain-aniso", vec![diag(1e3, 1.0, 1e-2); 200]),
        ("chain-down", vec![diag(1e-30, 1e-30, 1e-30); 20]),
        // Shears whose product is nearly singular in f64 (the condition grows ×10⁶ a step).
        ("chain-shear", vec![shear; 60]),
        ("chain-mirror", (0..64).map(|k| if k % 2 == 0 { diag(-2.0, 0.5, 1.0) } else { diag(1.0, -3.0, 0.25) }).collect()),
    ];
    for (name, chain) in cases {
        let p = write_chain(&dir.path().join(format!("{name}.sct")), &chain);
        let opts = sct_format::validate::ValidateOptions { deep: true, ..Default::default() };
        let report = sct_format::validate::validate_file(&p, &opts).expect("validates");
        assert!(report.is_valid(), "{name}: every record is valid: {:?}", report.issues);
        renders(&p);
    }
}


/// The file's section `tag`, stored bytes and flags as the writer made them.
fn section(b: &[u8], tag: [u8; 4]) -> SectionOut {
    let r = sct_format::SctReader::from_bytes(b.to_vec(), &sct_format::Limits::default()).expect("valid");
    let e = r.sections().iter().find(|e| e.tag == tag).expect("section").clone();
    SectionOut { tag, required: e.required(), stored: b[e.offset as usize..(e.offset + e.stored_len) as usize].to_vec(), raw_len: e.raw_len, compressed: e.compressed() }
}

/// A graph of the tree and one affine instance of `child` with `matrix` (spec §7 records).
fn graph(child: u32, matrix: [[f64; 4]; 3]) -> Vec<u8> {
    let mut g = 2u64.to_le_bytes().to_vec();
    g.extend_from_slice(&1u32.to_le_bytes());
    g.push(0);
    g.extend_from_slice(&0u32.to_le_bytes());
    g.push(4);
    g.extend_from_slice(&child.to_le_bytes());
    matrix.iter().flatten().for_each(|v| g.extend_from_slice(&v.to_le_bytes()));
    g.push(0);
    g.extend_from_slice(&[255; 4]);
    g
}

/// Matrices and references the reader refuses (NaN, infinite, singular, past f32, an
/// instance of itself) fail every method's render with the reader's malformed-file error,
/// at the record's offset.
#[test]
fn refused_affine_records_fail_every_method_with_the_readers_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let valid = std::fs::read(write_chain(&dir.path().join("valid.sct"), &[diag(2.0, 1.0, 0.5)])).expect("read");
    let id = diag(1.0, 1.0, 1.0).matrix;
    let mut nan = id;
    nan[1][1] = f64::NAN;
    let mut inf = id;
    inf[2][3] = f64::INFINITY;
    for (name, g) in [
        ("nan", graph(0, nan)),
        ("inf", graph(0, inf)),
        ("singular", graph(0, diag(1.0, 0.0, 1.0).matrix)),
        ("huge", graph(0, diag(1e39, 1e39, 1e39).matrix)),
        ("self", graph(1, id)),
    ] {
        let mut b = Vec::new();
        let (_, at) = write_container(SCT_MAGIC, &[section(&valid, *b"GENR"), SectionOut::plain(*b"GRPH", g), section(&valid, *b"TREE")], &mut b).expect("container");
        // Node 1 follows the 12-byte graph head and node 0's 5 bytes.
        let record = at[1] + 12 + 5;
        let p = dir.path().join(format!("{name}.sct"));
        std::fs::write(&p, &b).expect("write");
        for method in METHODS {
            let opts = RenderOptions { method, width: 48, height: 36, ..RenderOptions::default() };
            match render_file(&p, &opts) {
                Err(render_preview::Error::Sct { source: sct_format::Error::Malformed { offset, what }, .. }) => {
                    assert!(what.contains("affine instance") || what.contains("earlier node"), "{name}: {what}");
                    assert_eq!(offset, record, "{name}: {what}");
                }
                other => panic!("{name} {method:?}: {:?}", other.map(|r| r.stats.splats)),
            }
        }
    }
}
