//! `--against MESH`: the embedded fuze model voxelized and built through the libraries, then
//! checked against its own mesh, a scaled copy, and through an instance transform and an
//! inline.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::*;
use sct_format::{GraphNode, InstanceAttrs, Limits, Profile, SceneGraph, SctReader, Similarity};

fn fuze_obj() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/fuze/fuze.obj")
}

/// Voxelizes the fuze and builds it with `profile` into `dir/fuze-<profile>.sct`.
fn build_fuze(dir: &Path, profile: Profile) -> PathBuf {
    build_mesh(dir, &fuze_obj(), "fuze", profile)
}

/// Voxelizes `mesh` and builds it with `profile` into `dir/<name>-<profile>.sct`.
fn build_mesh(dir: &Path, mesh: &Path, name: &str, profile: Profile) -> PathBuf {
    let samples = dir.join(format!("{name}.samples"));
    if !samples.exists() {
        let opts =
            voxelize::Options { inputs: vec![mesh.to_path_buf()], output: Some(samples.clone()), load: Default::default(), sample: Default::default() };
        voxelize::run(&opts, &|_, _| {}).expect("voxelize");
    }
    let out = dir.join(format!("{name}-{}.sct", profile.name()));
    let cfg = build_tree::pipeline::Config {
        samples,
        output: out.clone(),
        scene: None,
        profile,
        compression_level: None,
        centre_offsets: true,
        leaf_refinement: Default::default(),
        build: Default::default(),
    };
    build_tree::pipeline::run(&cfg, &mut |_| {}).expect("build");
    out
}

/// Writes the fuze OBJ with every vertex mapped by `f` (faces, UVs and the rest unchanged).
fn write_mapped_obj(path: &Path, f: impl Fn([f64; 3]) -> [f64; 3]) {
    let text = std::fs::read_to_string(fuze_obj()).unwrap();
    let mut out = String::new();
    for l in text.lines() {
        match l.strip_prefix("v ") {
            Some(rest) => {
                let v: Vec<f64> = rest.split_whitespace().map(|x| x.parse().unwrap()).collect();
                let p = f([v[0], v[1], v[2]]);
                out.push_str(&format!("v {} {} {}\n", p[0], p[1], p[2]));
            }
            None => {
                out.push_str(l);
                out.push('\n');
            }
        }
    }
    std::fs::write(path, out).unwrap();
}

fn against(sct: &Path, mesh: &Path, extra: &[&str]) -> (Output, serde_json::Value) {
    let o = Command::new(bin()).arg(sct).arg("--against").arg(mesh).arg("--json").args(extra).output().unwrap();
    let v = serde_json::from_slice(&o.stdout).unwrap_or(serde_json::Value::Null);
    (o, v)
}

#[test]
fn own_mesh_is_fully_covered_and_scaled_mesh_is_not() {
    let d = tmp();
    for profile in [Profile::Default, Profile::Canopy] {
        let sct = build_fuze(d.path(), profile);
        let (o, v) = against(&sct, &fuze_obj(), &[]);
        assert_eq!(o.status.code(), Some(0), "{profile:?}: {}", String::from_utf8_lossy(&o.stderr));
        let c = &v["coverage"];
        assert_eq!(c["points"], 100_000);
        assert_eq!(c["covered"], 100_000, "{profile:?}: {c}");
        assert_eq!(c["fraction"], 1.0);
        assert_eq!(c["passed"], true);
        assert!(c["worst_uncovered"].is_null());
        assert_eq!(c["tree_uses"], 1);
    }
    // The same tree against the mesh grown by 10 %: the shell moves off the leaves.
    let sct = d.path().join("fuze-default.sct");
    let big = d.path().join("fuze-big.obj");
    write_mapped_obj(&big, |p| p.map(|x| x * 1.1));
    let (o, v) = against(&sct, &big, &["--points", "20000"]);
    assert_eq!(o.status.code(), Some(1), "{}", String::from_utf8_lossy(&o.stderr));
    let c = &v["coverage"];
    let frac = c["fraction"].as_f64().unwrap();
    assert!(frac < 0.9, "{c}");
    assert_eq!(c["passed"], false);
    let w = &c["worst_uncovered"];
    // The fuze is ~0.33 units tall: 10 % moves its far end by ~0.02, many leaf radii.
    let (dist, radii) = (w["distance"].as_f64().unwrap(), w["leaf_radii"].as_f64().unwrap());
    assert!(dist > 0.005 && dist < 0.05, "{w}");
    assert!(radii > 3.0, "{w}");
    // The threshold flag decides the exit status; the figures do not change.
    let (o, v2) = against(&sct, &big, &["--points", "20000", "--min-coverage", "0"]);
    assert_eq!(o.status.code(), Some(0));
    assert_eq!(v2["coverage"]["fraction"], c["fraction"]);
    // Text output names the figures.
    let o = Command::new(bin()).arg(&sct).args(["--against"]).arg(&big).args(["--points", "20000"]).output().unwrap();
    let s = String::from_utf8_lossy(&o.stdout);
    assert!(s.contains("coverage of") && s.contains("FAIL") && s.contains("leaf radii"), "{s}");
}

#[test]
fn leaves_are_placed_through_instances_and_inlines() {
    let d = tmp();
    let plain = build_fuze(d.path(), Profile::Default);
    let tree = SctReader::open(&plain, &Limits::default()).unwrap().read_tree(0).unwrap();
    let t = Similarity { translation: [1.0, -2.0, 0.5], rotation: [0.0, 0.0, std::f64::consts::FRAC_1_SQRT_2, std::f64::consts::FRAC_1_SQRT_2], scale: 2.0 };
    let inst = d.path().join("inst.sct");
    let nodes = vec![GraphNode::Tree { tree: 0 }, GraphNode::Instance { child: 0, transform: t, attrs: InstanceAttrs::default() }];
    write(&inst, SceneGraph { nodes, root: 1 }, vec![tree], Profile::Default);
    let moved = d.path().join("fuze-moved.obj");
    write_mapped_obj(&moved, |p| t.apply_point(p));
    let (o, v) = against(&inst, &moved, &[]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(v["coverage"]["fraction"], 1.0, "{}", v["coverage"]);
    // The untransformed mesh is nowhere near the placed leaves.
    let (o, v) = against(&inst, &fuze_obj(), &["--points", "2000"]);
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(v["coverage"]["covered"], 0, "{}", v["coverage"]);

    // An outer file inlining the instance file: same world placement, one more file.
    let outer = d.path().join("outer.sct");
    let bound = sct_format::traverse::graph_bound(&SctReader::open(&inst, &Limits::default()).unwrap(), 1).unwrap();
    let nodes = vec![GraphNode::Inline { path: "inst.sct".into(), hash: [0; 32], bound }];
    write(&outer, SceneGraph { nodes, root: 0 }, vec![], Profile::Raw);
    let (o, v) = against(&outer, &moved, &["--points", "5000"]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(v["coverage"]["fraction"], 1.0);
    assert_eq!(v["coverage"]["tree_uses"], 1);
}

#[test]
fn instanced_gltf_through_build_tree_is_fully_covered() {
    // Khronos SimpleInstancing: build-tree turns the glTF's placements into instances.
    let mesh = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/models/gltf/SimpleInstancing/glTF/SimpleInstancing.gltf");
    let mesh = mesh.as_path();
    let d = tmp();
    let sct = build_mesh(d.path(), mesh, "si", Profile::Default);
    let (o, v) = against(&sct, mesh, &["--points", "20000"]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    let c = &v["coverage"];
    assert_eq!(c["fraction"], 1.0, "{c}");
    assert!(v["graph"]["instances"].as_u64().unwrap() > 0, "{}", v["graph"]);
    assert!(c["tree_uses"].as_u64().unwrap() > c["trees"].as_u64().unwrap(), "{c}");
}

#[test]
fn point_cloud_mesh_uses_its_points() {
    // A PLY without faces: the fuze's vertices lie on its surface, so all are covered.
    let d = tmp();
    let sct = build_fuze(d.path(), Profile::Raw);
    let text = std::fs::read_to_string(fuze_obj()).unwrap();
    let verts: Vec<&str> = text.lines().filter_map(|l| l.strip_prefix("v ")).collect();
    let mut ply = format!("ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nend_header\n", verts.len());
    for v in &verts {
        ply.push_str(v.trim());
        ply.push('\n');
    }
    let cloud = d.path().join("cloud.ply");
    std::fs::write(&cloud, ply).unwrap();
    let (o, v) = against(&sct, &cloud, &["--points", "3000"]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(v["coverage"]["points"], 3000);
    assert_eq!(v["coverage"]["fraction"], 1.0, "{}", v["coverage"]);
}

#[test]
fn output_is_deterministic_across_thread_counts() {
    let d = tmp();
    let sct = build_fuze(d.path(), Profile::Default);
    let big = d.path().join("fuze-big.obj");
    write_mapped_obj(&big, |p| [p[0] * 1.05, p[1], p[2] * 1.05]);
    let run = |threads: &str| {
        let o = Command::new(bin()).env("RAYON_NUM_THREADS", threads).arg(&sct).arg("--against").arg(&big).args(["--json", "--points", "30000"]).output().unwrap();
        o.stdout
    };
    let one = run("1");
    assert!(!one.is_empty());
    assert_eq!(one, run("3"));
}

#[test]
fn mesh_errors_have_their_exit_status() {
    let d = tmp();
    let sct = build_fuze(d.path(), Profile::Raw);
    // Missing mesh: I/O, 2.
    let (o, _) = against(&sct, &d.path().join("none.obj"), &[]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("none.obj"));
    // Unparsable PLY and unknown format: bad input, 1.
    let bad = d.path().join("bad.ply");
    std::fs::write(&bad, b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n").unwrap();
    let (o, _) = against(&sct, &bad, &[]);
    assert_eq!(o.status.code(), Some(1), "{}", String::from_utf8_lossy(&o.stderr));
    let unknown = d.path().join("mesh.xyz");
    std::fs::write(&unknown, b"1 2 3\n").unwrap();
    assert_eq!(against(&sct, &unknown, &[]).0.status.code(), Some(1));
    // Threshold outside [0, 1], no points, or --against with --dump: usage, 2.
    assert_eq!(against(&sct, &fuze_obj(), &["--min-coverage", "99"]).0.status.code(), Some(2));
    let (o, _) = against(&sct, &fuze_obj(), &["--points", "0"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--points"), "{}", String::from_utf8_lossy(&o.stderr));
    // A valid --dump value, so only the conflicts_with rule can refuse it.
    let (o, _) = against(&sct, &fuze_obj(), &["--dump", "root"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("cannot be used with"), "{}", String::from_utf8_lossy(&o.stderr));
}

/// The library refuses 0 points too (it would report fraction 1 of nothing).
#[test]
fn zero_points_is_a_usage_error() {
    let d = tmp();
    let sct = build_fuze(d.path(), Profile::Raw);
    let opts = inspect::AgainstOptions { points: 0, ..Default::default() };
    let Err(e) = inspect::coverage_against(&sct, &fuze_obj(), &opts) else { panic!("0 points accepted") };
    assert_eq!(e.exit_code(), 2, "{e}");
}

/// A DAG of shared groups reaches 2^depth tree uses from a file of a few hundred bytes: the
/// check must stop at its limit with an input error (exit 1), not hang or run out of memory.
#[test]
fn shared_group_dag_stops_at_the_use_limit() {
    use sct_format::{geometry::parent_of, Node, SceneTree};
    let d = tmp();
    let leaf = Node { center: [0.0; 3], radius: 1.0, normal: [0.0, 0.0, 1.0], cone: 0.0, area: 1.0, color: [9, 9, 9, 255] };
    let geo = SceneTree::from_bfs(vec![leaf], vec![false]).unwrap();
    let pair = SceneTree::from_bfs(vec![parent_of(&leaf, &leaf), leaf, leaf], vec![true, false, false]).unwrap();
    let depth = 40u32;
    let mut nodes = vec![GraphNode::Tree { tree: 0 }];
    nodes.extend((0..depth).map(|i| GraphNode::Group { children: vec![i, i], tree: 1 }));
    let sct = d.path().join("dag.sct");
    write(&sct, SceneGraph { nodes, root: depth }, vec![geo, pair], Profile::Raw);
    assert!(std::fs::metadata(&sct).unwrap().len() < 4096);
    let opts = inspect::AgainstOptions { points: 10, max_uses: 1000, ..Default::default() };
    let Err(e) = inspect::coverage_against(&sct, &fuze_obj(), &opts) else { panic!("no limit") };
    assert_eq!(e.exit_code(), 1, "{e}");
    assert!(e.to_string().contains("coverage traversal"), "{e}");
}

/// A missing inline shared along 2^12 paths: one error per path, but only the first
/// `MAX_ERRORS` are listed, then a count of the rest.
#[test]
fn errors_of_a_shared_missing_inline_are_capped() {
    use sct_format::{geometry::parent_of, Node, SceneTree};
    let d = tmp();
    let leaf = Node { center: [0.0; 3], radius: 1.0, normal: [0.0, 0.0, 1.0], cone: 0.0, area: 1.0, color: [9, 9, 9, 255] };
    let pair = SceneTree::from_bfs(vec![parent_of(&leaf, &leaf), leaf, leaf], vec![true, false, false]).unwrap();
    let depth = 12u32;
    let mut nodes = vec![GraphNode::Inline { path: "missing.sct".into(), hash: [0; 32], bound: leaf }];
    nodes.extend((0..depth).map(|i| GraphNode::Group { children: vec![i, i], tree: 0 }));
    let sct = d.path().join("dag.sct");
    write(&sct, SceneGraph { nodes, root: depth }, vec![pair], Profile::Raw);
    let opts = inspect::AgainstOptions { points: 10, ..Default::default() };
    let r = inspect::coverage_against(&sct, &fuze_obj(), &opts).unwrap();
    let max = inspect::coverage::MAX_ERRORS;
    assert_eq!(r.errors.len(), max + 1);
    assert_eq!(r.errors[max], format!("... and {} more errors, not listed", (1 << depth) - max));
}

/// An alpha-masked asset (glTF AlphaBlendModeTest: MASK and fully transparent BLEND
/// surfaces) covers less than its whole mesh; leaving out what the voxelizer drops by alpha
/// lets it be gated like any other asset.
#[test]
fn alpha_dropped_surfaces_can_be_left_out() {
    let mesh = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/models/gltf/AlphaBlendModeTest/glTF-Binary/AlphaBlendModeTest.glb");
    if !mesh.exists() {
        return;
    }
    let d = tmp();
    let sct = build_mesh(d.path(), &mesh, "alpha", Profile::Default);
    let all = inspect::coverage_against(&sct, &mesh, &inspect::AgainstOptions { points: 20_000, ..Default::default() }).expect("coverage");
    let kept = inspect::coverage_against(&sct, &mesh, &inspect::AgainstOptions { points: 20_000, exclude_alpha_dropped: true, ..Default::default() })
        .expect("coverage");
    assert!(!all.passed, "every triangle: {}", all.fraction);
    assert!(kept.fraction > all.fraction && kept.fraction >= 0.99, "kept {} vs all {}", kept.fraction, all.fraction);
    assert_eq!(kept.points, 20_000);
}

/// Uses stacked at one place: 2,000 instances of one leaf, at translations differing by a
/// hair (distinct uses) or all equal (one use, queried once). A point far from them queries
/// every distinct use whose bound may hold a nearer leaf; the check stops at its query limit
/// instead of taking hours (65,536 such inlines of a 4 M-leaf tree ran past a minute).
#[test]
fn stacked_uses_are_bounded_by_the_query_limit() {
    use sct_format::{geometry::parent_of, Node, SceneTree};
    let d = tmp();
    let leaf = Node { center: [100.0, 0.0, 0.0], radius: 1.0, normal: [0.0, 0.0, 1.0], cone: 0.0, area: 1.0, color: [9, 9, 9, 255] };
    let k = 2000u32;
    // A balanced group tree of k leaves, breadth first.
    let group_tree = || {
        let mut q = std::collections::VecDeque::from([k as usize]);
        let (mut nodes, mut flags) = (Vec::new(), Vec::new());
        while let Some(n) = q.pop_front() {
            nodes.push(if n > 1 { parent_of(&leaf, &leaf) } else { leaf });
            flags.push(n > 1);
            if n > 1 {
                q.push_back(n / 2);
                q.push_back(n - n / 2);
            }
        }
        SceneTree::from_bfs(nodes, flags).unwrap()
    };
    let geo = SceneTree::from_bfs(vec![leaf], vec![false]).unwrap();
    for (name, step, stops) in [("hair.sct", 1e-9, true), ("same.sct", 0.0, false)] {
        let mut nodes = vec![GraphNode::Tree { tree: 0 }];
        for i in 0..k {
            let t = Similarity { translation: [i as f64 * step, 0.0, 0.0], ..Similarity::IDENTITY };
            nodes.push(GraphNode::Instance { child: 0, transform: t, attrs: InstanceAttrs::default() });
        }
        nodes.push(GraphNode::Group { children: (1..=k).collect(), tree: 1 });
        let sct = d.path().join(name);
        write(&sct, SceneGraph { nodes, root: k + 1 }, vec![geo.clone(), group_tree()], Profile::Raw);
        let opts = inspect::AgainstOptions { points: 100, max_use_queries: 50_000, ..Default::default() };
        match inspect::coverage_against(&sct, &fuze_obj(), &opts) {
            Err(e) if stops => assert!(e.to_string().contains(inspect::coverage::USE_QUERIES), "{e}"),
            Ok(r) if !stops => assert_eq!((r.tree_uses, r.leaves_expanded, r.covered), (k as u64, k as u64, 0)),
            other => panic!("{name}: {:?}", other.map(|r| r.tree_uses)),
        }
    }
}
