//! Scene composition through the whole pipeline, read back with the traversal; CLI exit codes.

use std::path::Path;
use std::process::Command;

use build_tree::pipeline::{run, Config};
use build_tree::BuildOptions;
use sct_format::geometry::{cone_contains, sphere_contains};
use sct_format::graph::{Generator, Similarity};
use sct_format::read::SctReader;
use sct_format::samples::{MeshEntry, SampleInstance, SamplesFile};
use sct_format::traverse::{ReachedKind, Traversal, TraverseOptions};
use sct_format::{GraphNode, Limits, Node, Profile};

/// A small ball of samples around `c` (radius 1), coloured `col`.
fn ball(c: [f32; 3], col: [u8; 4], n: usize) -> Vec<Node> {
    (0..n)
        .map(|i| {
            let t = i as f32 * 2.399_963; // golden angle spiral
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let r = (1.0 - z * z).sqrt();
            let d = [r * t.cos(), r * t.sin(), z];
            Node { center: [c[0] + d[0], c[1] + d[1], c[2] + d[2]], radius: 0.1, normal: d, cone: 0.0, area: 0.05, color: col }
        })
        .collect()
}

fn samples_file(dir: &Path) -> std::path::PathBuf {
    let mut samples = ball([0.0; 3], [255, 0, 0, 255], 500);
    samples.extend(ball([5.0, 0.0, 0.0], [0, 255, 0, 255], 300));
    samples.extend(ball([0.0, 5.0, 0.0], [0, 0, 255, 255], 200));
    let meshes = vec![
        MeshEntry { name: "red".into(), first: 0, count: 500, two_sided: false },
        MeshEntry { name: "green".into(), first: 500, count: 300, two_sided: false },
        MeshEntry { name: "blue".into(), first: 800, count: 200, two_sided: false },
    ];
    let t = Similarity { translation: [10.0, 0.0, 0.0], rotation: [0.0, 0.0, std::f64::consts::FRAC_1_SQRT_2, std::f64::consts::FRAC_1_SQRT_2], scale: 2.0 };
    let instances = vec![
        SampleInstance { mesh: 0, transform: Similarity::IDENTITY },
        SampleInstance { mesh: 1, transform: Similarity::IDENTITY },
        SampleInstance { mesh: 2, transform: t },
        SampleInstance { mesh: 0, transform: t },
    ];
    let f = SamplesFile { generator: Generator::default(), meshes, instances, affine_instances: Vec::new(), samples };
    let p = dir.join("three.samples");
    f.write_file(&p).unwrap();
    p
}

fn cfg(samples: &Path, out: &Path, scene: Option<&Path>) -> Config {
    Config {
        samples: samples.into(),
        output: out.into(),
        scene: scene.map(Into::into),
        profile: Profile::Raw,
        compression_level: None,
        centre_offsets: true,
        leaf_refinement: Default::default(),
        build: BuildOptions::default(),
    }
}

/// Walks the file; checks every group leaf equals its child's world bound and that every
/// geometry tree's world root lies inside every enclosing group leaf. Returns
/// (geometry trees reached, world roots).
fn walk(path: &Path) -> Vec<Node> {
    let mut roots = Vec::new();
    for r in Traversal::open(path, TraverseOptions::default()).unwrap() {
        let r = r.unwrap();
        let tree = r.file.read_tree(r.tree).unwrap();
        match &r.kind {
            ReachedKind::Group { children } => {
                let leaves: Vec<usize> = tree.leaves().collect();
                assert_eq!(leaves.len(), children.len());
                for (j, &c) in children.iter().enumerate() {
                    let leaf = r.state.apply(&tree.nodes()[leaves[j]]);
                    let bound = sct_format::traverse::graph_bound(&r.file, c).map(|b| r.state.apply(&b)).unwrap();
                    assert!(sphere_contains(&leaf, &bound, 1e-5), "group leaf {j} does not bound child {c}");
                    assert!(cone_contains(leaf.normal, leaf.cone, bound.normal, bound.cone, 1e-4));
                }
            }
            ReachedKind::Tree => roots.push(r.world_root().unwrap()),
        }
    }
    roots
}

#[test]
fn samples_instances_become_trees_and_instances() {
    let dir = tempfile::tempdir().unwrap();
    let s = samples_file(dir.path());
    let out = dir.path().join("auto.sct");
    let rep = run(&cfg(&s, &out, None), &mut |_| {}).unwrap();
    assert_eq!(rep.trees, 4, "three meshes + one group");
    assert_eq!(rep.instances, 2);
    let f = SctReader::open(&out, &Limits::default()).unwrap();
    let g = f.graph();
    assert!(matches!(g.nodes[g.root as usize], GraphNode::Group { .. }));
    let roots = walk(&out);
    assert_eq!(roots.len(), 4);
    // The instanced blue ball: scale 2, rotated 90° about z, moved by +10 x: centre (5, 0, 0)
    // rotated -> (0, 5, 0) ... blue is at (0, 5) -> rotated to (-5, 0) ×2 -> (-10, 0) + 10.
    let blue = roots.iter().find(|n| n.color[2] > 200).unwrap();
    assert!((blue.center[0] - 0.0).abs() < 0.05 && blue.center[1].abs() < 0.05, "{:?}", blue.center);
    // Radius × s: the red mesh appears at scale 1 and 2.
    let mut red: Vec<&Node> = roots.iter().filter(|n| n.color[0] > 200).collect();
    red.sort_by(|a, b| a.radius.total_cmp(&b.radius));
    assert!((red[1].radius / red[0].radius - 2.0).abs() < 1e-5, "radius × s");
    assert!((red[1].area / red[0].area - 4.0).abs() < 1e-5, "area × s²");
    assert!((blue.area - 4.0 * 200.0 * 0.05).abs() < 1e-2, "area × s²: {}", blue.area);
}

#[test]
fn scene_json_group_of_tinted_instances_grid_and_inline() {
    let dir = tempfile::tempdir().unwrap();
    let s = samples_file(dir.path());
    // A first file to inline.
    let first = dir.path().join("red.sct");
    std::fs::write(dir.path().join("red.json"), r#"{"root": {"mesh": "red"}}"#).unwrap();
    run(&cfg(&s, &first, Some(&dir.path().join("red.json"))), &mut |_| {}).unwrap();

    let scene = r#"{
      "defs": { "g": { "mesh": 1 } },
      "root": { "group": [
        { "instance": { "child": { "mesh": "red" }, "translation": [0, 0, 10], "tint": [128, 255, 255, 255] } },
        { "instance": { "child": { "ref": "g" }, "scale": 3, "rotation": [0, 1, 0, 0] } },
        { "instance": { "child": { "ref": "g" }, "fit": { "center": [20, 0, 0], "radius": 0.5 } } },
        { "grid": { "child": { "mesh": "blue" }, "nx": 4, "nz": 3, "spacing": 1.2, "jitter": 0.5, "radius": 0.5, "random_tint": true, "seed": 7 } },
        { "inline": "red.sct" }
      ] }
    }"#;
    let sp = dir.path().join("scene.json");
    std::fs::write(&sp, scene).unwrap();
    let out = dir.path().join("scene.sct");
    let rep = run(&cfg(&s, &out, Some(&sp)), &mut |_| {}).unwrap();
    assert_eq!(rep.groups, 2, "root group + grid group");
    assert_eq!(rep.instances, 3 + 12);
    // Mesh trees are shared: red, green, blue built once each.
    assert_eq!(rep.trees, 3 + 2);
    let roots = walk(&out);
    // red (tinted), green ×2, blue ×12, inlined red.
    assert_eq!(roots.len(), 1 + 2 + 12 + 1);
    let tinted = roots.iter().filter(|n| n.color[1] == 0 && n.color[2] == 0 && n.color[0] > 0 && n.color[0] < 200).count();
    assert_eq!(tinted, 1, "one half-red tinted instance");
    let fitted = roots.iter().find(|n| (n.center[0] - 20.0).abs() < 1e-3).unwrap();
    assert!((fitted.radius - 0.5).abs() < 1e-3);
    // Deterministic across runs (identical bytes).
    let again = dir.path().join("again.sct");
    run(&cfg(&s, &again, Some(&sp)), &mut |_| {}).unwrap();
    assert_eq!(std::fs::read(&out).unwrap(), std::fs::read(&again).unwrap());
}

#[test]
fn bad_scenes_are_input_errors() {
    let dir = tempfile::tempdir().unwrap();
    let s = samples_file(dir.path());
    let out = dir.path().join("x.sct");
    for bad in [
        r#"{"root": {"mesh": 9}}"#,
        r#"{"root": {"mesh": "nope"}}"#,
        r#"{"root": {"ref": "a"}, "defs": {"a": {"group": [{"ref": "a"}]}}}"#,
        r#"{"root": {"group": []}}"#,
        r#"{"root": {"wat": 1}}"#,
        r#"{"root": {"instance": {"child": {"mesh": 0}, "scale": -1}}}"#,
        // A 70-byte scene of 2^28 cells took 14 GB; cells over all grids are bounded by
        // MAX_GRID_CELLS (2^21), checked before any cell is made.
        r#"{"root": {"grid": {"child": {"mesh": 0}, "nx": 16384, "nz": 16384}}}"#,
        r#"{"root": {"group": [{"grid": {"child": {"mesh": 0}, "nx": 1024, "nz": 1024}}, {"grid": {"child": {"mesh": 0}, "nx": 1024, "nz": 1025}}]}}"#,
    ] {
        let sp = dir.path().join("bad.json");
        std::fs::write(&sp, bad).unwrap();
        let t = std::time::Instant::now();
        let e = run(&cfg(&s, &out, Some(&sp)), &mut |_| {}).unwrap_err();
        assert_eq!(e.exit_code(), 1, "{bad}: {e}");
        assert!(t.elapsed().as_secs() < 5, "{bad}: {:?}", t.elapsed());
    }
    assert!(!out.exists(), "no output on failure");
}

#[test]
fn cli_exit_codes_and_json() {
    let dir = tempfile::tempdir().unwrap();
    let s = samples_file(dir.path());
    let out = dir.path().join("cli.sct");
    let exe = env!("CARGO_BIN_EXE_sct-build-tree");
    let o = Command::new(exe).arg(&s).arg("-o").arg(&out).args(["--json", "--profile", "canopy"]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["leaves"], 1000);
    assert!(v["bytes"].as_u64().unwrap() > 0);
    // Bad input (not a samples file) -> 1; missing file -> 2; bad flag -> 2.
    let junk = dir.path().join("junk.samples");
    std::fs::write(&junk, b"not samples").unwrap();
    assert_eq!(Command::new(exe).arg(&junk).arg("-o").arg(&out).status().unwrap().code(), Some(1));
    assert_eq!(Command::new(exe).arg(dir.path().join("missing")).arg("-o").arg(&out).status().unwrap().code(), Some(2));
    assert_eq!(Command::new(exe).arg(&s).arg("--bogus").status().unwrap().code(), Some(2));
    // --max-grid-cells sets the grid cap: a 4 × 4 grid needs 16.
    let sp = dir.path().join("grid.json");
    std::fs::write(&sp, r#"{"root": {"grid": {"child": {"mesh": 0}, "nx": 4, "nz": 4}}}"#).unwrap();
    let grid = |cap: &str| Command::new(exe).arg(&s).arg("-o").arg(&out).arg("--scene").arg(&sp).args(["--max-grid-cells", cap]).output().unwrap();
    let o = grid("15");
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--max-grid-cells"), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(grid("16").status.code(), Some(0));
}

/// A two-sided mesh gives a two-sided tree (its leaves keep their cones: they bound the
/// normals up to sign); the one-sided meshes stay one-sided and the group over both is
/// two-sided. The file passes deep validation and is labelled 1.1.
#[test]
fn two_sided_meshes_build_two_sided_trees() {
    let dir = tempfile::tempdir().unwrap();
    let s = samples_file(dir.path());
    let mut f = SamplesFile::read_file(&s, &Limits::default()).unwrap();
    f.meshes[1].two_sided = true;
    f.write_file(&s).unwrap();
    let out = dir.path().join("two.sct");
    run(&cfg(&s, &out, None), &mut |_| {}).unwrap();
    let r = SctReader::open(&out, &Limits::default()).unwrap();
    assert_eq!(r.header().minor, 1);
    let g = r.graph();
    let mut seen = 0;
    for n in &g.nodes {
        if let GraphNode::Tree { tree } = n {
            let t = r.read_tree(*tree as usize).unwrap();
            let green = t.nodes()[0].color[1] > 200;
            assert_eq!(t.is_two_sided(), green, "tree {tree}");
            let max_cone = t.leaves().map(|i| t.nodes()[i].cone).fold(0.0, f32::max);
            assert!(max_cone < 0.1, "leaves keep their normals' cones ({max_cone})");
            seen += usize::from(green);
        }
    }
    assert_eq!(seen, 1);
    let GraphNode::Group { tree, .. } = g.nodes[g.root as usize] else { panic!("root is a group") };
    assert!(r.read_tree(tree as usize).unwrap().is_two_sided(), "a group over a two-sided child is two-sided");
    let rep = sct_format::validate::validate_file(&out, &sct_format::validate::ValidateOptions { deep: true, ..Default::default() }).unwrap();
    assert!(rep.is_valid(), "{:?}", rep.issues);
}
