//! `sct-inspect` on hostile files: empty trees reached from the graph, DAGs of shared groups,
//! inlines outside the scene directory, samples exports over the point limit, FIFOs. No
//! input may panic (exit 101), hang or allocate without bound.

mod common;

#[path = "../../sct-format/tests/common/craft.rs"]
mod craft;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use common::*;
use craft::Sec;
use inspect::export::export_ply;
use inspect::{dump, InspectError};
use sct_format::geometry::parent_of;
use sct_format::raw::{tags, SAMPLES_MAGIC};
use sct_format::{GraphNode, InstanceAttrs, Limits, Node, Profile, SceneGraph, SceneTree, Similarity};

/// Runs the binary, failing the test (not hanging it) if it does not finish in two minutes.
fn run(args: &[&std::ffi::OsStr]) -> Output {
    let mut child = Command::new(bin()).args(args).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("spawn");
    let t0 = Instant::now();
    while child.try_wait().expect("wait").is_none() {
        if t0.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            panic!("sct-inspect {args:?} did not finish");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().expect("output")
}

fn args<'a>(v: &'a [&'a dyn AsRef<std::ffi::OsStr>]) -> Vec<&'a std::ffi::OsStr> {
    v.iter().map(|a| a.as_ref()).collect()
}

fn leaf(x: f32) -> Node {
    Node { center: [x, 0.0, 0.0], radius: 0.5, normal: [0.0, 0.0, 1.0], cone: 0.0, area: 1.0, color: [90, 90, 90, 255] }
}

fn pair(a: Node, b: Node) -> SceneTree {
    SceneTree::from_bfs(vec![parent_of(&a, &b), a, b], vec![true, false, false]).expect("tree")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// Item 1: an empty tree as the root, as an instance and beside a tree in a group: validation,
/// dumps and exports work (the dump and the export used to panic).
#[test]
fn empty_trees_dump_and_export() {
    let d = tmp();
    let t = pair(leaf(0.0), leaf(1.0));
    let b = t.nodes()[0];
    type Case = (&'static str, Vec<GraphNode>, u32, Vec<SceneTree>, &'static str);
    let cases: [Case; 3] = [
        ("root", vec![GraphNode::Tree { tree: 0 }], 0, vec![SceneTree::default()], "root"),
        (
            "instance",
            vec![GraphNode::Tree { tree: 0 }, GraphNode::Instance { child: 0, transform: Similarity::IDENTITY, attrs: InstanceAttrs::default() }],
            1,
            vec![SceneTree::default()],
            "root",
        ),
        (
            "group",
            vec![GraphNode::Tree { tree: 0 }, GraphNode::Tree { tree: 1 }, GraphNode::Group { children: vec![0, 1], tree: 2 }],
            2,
            vec![SceneTree::default(), t.clone(), pair(b, b)],
            "root/0",
        ),
    ];
    for (name, nodes, root, trees, empty_at) in cases {
        let f = path_in(&d, &format!("{name}.sct"));
        write(&f, SceneGraph { nodes, root }, trees, Profile::Raw);
        for flag in ["--validate", "--deep"] {
            let o = run(&args(&[&f, &flag]));
            assert_eq!(o.status.code(), Some(0), "{name} {flag}: {}{}", text(&o.stdout), text(&o.stderr));
        }
        let o = run(&args(&[&f, &"--dump", &empty_at]));
        assert_eq!(o.status.code(), Some(0), "{name}: {}", text(&o.stderr));
        assert!(text(&o.stdout).contains("is empty tree"), "{}", text(&o.stdout));
        let below = format!("{empty_at}/0");
        let o = run(&args(&[&f, &"--dump", &below]));
        assert_eq!(o.status.code(), Some(2), "{name}: a path below an empty tree is a usage error: {}", text(&o.stderr));
        let ply = path_in(&d, &format!("{name}.ply"));
        for level in [None, Some("0"), Some("3")] {
            let mut a: Vec<&std::ffi::OsStr> = vec![f.as_os_str(), "--export-ply".as_ref(), ply.as_os_str()];
            if let Some(l) = level {
                a.push("--export-level".as_ref());
                a.push(l.as_ref());
            }
            let o = run(&a);
            assert_eq!(o.status.code(), Some(0), "{name} {level:?}: {}", text(&o.stderr));
        }
    }
}

/// Item 4: a DAG of shared groups stops the export at the traversal's visit limit; the dump
/// walks only the branch to the requested path, so it answers at once.
#[test]
fn shared_groups_are_bounded() {
    let d = tmp();
    let t = pair(leaf(0.0), leaf(1.0));
    let b = t.nodes()[0];
    let mut nodes = vec![GraphNode::Tree { tree: 0 }];
    for k in 1..=40u32 {
        nodes.push(GraphNode::Group { children: vec![k - 1, k - 1], tree: 1 });
    }
    let f = path_in(&d, "dag.sct");
    write(&f, SceneGraph { nodes, root: 40 }, vec![t, pair(b, b)], Profile::Raw);
    let limits = Limits { max_traversal_visits: 5_000, ..Limits::default() };
    match export_ply(&f, &path_in(&d, "dag.ply"), None, u64::MAX, &limits, false) {
        Err(e @ InspectError::Sct(sct_format::Error::LimitExceeded { .. })) => assert_eq!(e.exit_code(), 1),
        other => panic!("{other:?}"),
    }
    let deep_path = format!("root{}", "/1".repeat(40));
    let mut out = Vec::new();
    dump(&f, &deep_path, 1, &limits, false, &mut out).expect("dump");
    assert!(text(&out).contains("is node 0 of tree 0"), "{}", text(&out));
    // The binary's --max-visits sets the same cap: low, the export stops at once naming it;
    // high enough for a 10-level DAG (2^11 visits), it exports.
    let ply = path_in(&d, "cli.ply");
    let o = run(&args(&[&f, &"--export-ply", &ply, &"--max-visits", &"5000"]));
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("limit exceeded"), "{}", text(&o.stderr));
    let t = pair(leaf(0.0), leaf(1.0));
    let mut nodes = vec![GraphNode::Tree { tree: 0 }];
    for k in 1..=10u32 {
        nodes.push(GraphNode::Group { children: vec![k - 1, k - 1], tree: 1 });
    }
    let small = path_in(&d, "dag10.sct");
    write(&small, SceneGraph { nodes, root: 10 }, vec![t, pair(b, b)], Profile::Raw);
    assert_eq!(run(&args(&[&small, &"--export-ply", &ply, &"--max-visits", &"1000"])).status.code(), Some(1));
    let o = run(&args(&[&small, &"--export-ply", &ply, &"--max-visits", &"5000"]));
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stderr));
}

/// Item 20: inlines leave the scene directory only with --allow-outside-inlines.
#[test]
fn outside_inlines_need_the_flag() {
    let d = tmp();
    let scene = d.path().join("scene");
    std::fs::create_dir_all(&scene).expect("dir");
    let t = pair(leaf(0.0), leaf(1.0));
    let b = t.nodes()[0];
    let outside = path_in(&d, "outside.sct");
    write(&outside, SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }], root: 0 }, vec![t], Profile::Raw);
    let hash = *blake3_of(&outside);
    let top = scene.join("top.sct");
    write(&top, SceneGraph { nodes: vec![GraphNode::Inline { path: "../outside.sct".into(), hash, bound: b }], root: 0 }, vec![], Profile::Raw);
    let o = run(&args(&[&top, &"--validate"]));
    assert_eq!(o.status.code(), Some(1));
    assert!(text(&o.stdout).contains("inline-outside"), "{}", text(&o.stdout));
    assert!(!text(&o.stdout).contains(&sct_format::traverse::hex(&hash)), "the target's hash is not computed, let alone printed");
    let o = run(&args(&[&top, &"--validate", &"--allow-outside-inlines"]));
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stdout));
    let ply = path_in(&d, "x.ply");
    assert_eq!(run(&args(&[&top, &"--export-ply", &ply])).status.code(), Some(1));
    assert_eq!(run(&args(&[&top, &"--export-ply", &ply, &"--allow-outside-inlines"])).status.code(), Some(0));
}

fn blake3_of(p: &Path) -> Box<[u8; 32]> {
    let r = sct_format::SctReader::open(p, &Limits::default()).expect("open");
    Box::new(r.content_hash().expect("hash"))
}

/// Item 12: --max-points is checked on the samples file's tables before any sample is decoded
/// (these chunks are garbage inside: decoding first reported them instead).
#[test]
fn samples_export_checks_max_points_first() {
    let d = tmp();
    let n = 65_536u32;
    let mut smps = Vec::new();
    for _ in 0..2 {
        let f = craft::corrupt_frame(36 * n as u64);
        smps.extend_from_slice(&n.to_le_bytes());
        smps.extend_from_slice(&(f.len() as u32).to_le_bytes());
        smps.extend_from_slice(&f);
    }
    let mut mesh = 1u64.to_le_bytes().to_vec();
    mesh.extend_from_slice(&0u64.to_le_bytes());
    mesh.extend_from_slice(&(2 * n as u64).to_le_bytes());
    mesh.extend_from_slice(&0u32.to_le_bytes());
    let mut inst = 1u64.to_le_bytes().to_vec();
    inst.extend_from_slice(&0u32.to_le_bytes());
    for v in [0.0f64, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0] {
        inst.extend_from_slice(&v.to_le_bytes());
    }
    let file = craft::container(
        SAMPLES_MAGIC,
        &[Sec::plain(tags::GENR, craft::genr()), Sec::plain(tags::MESH, mesh), Sec::zstd(tags::INST, &inst), Sec::plain(*b"SMPS", smps)],
    );
    let f = path_in(&d, "s.samples");
    std::fs::write(&f, file).expect("write");
    let ply = path_in(&d, "s.ply");
    let o = run(&args(&[&f, &"--export-ply", &ply, &"--max-points", &"1000"]));
    assert_eq!(o.status.code(), Some(1));
    assert!(text(&o.stderr).contains("PLY export points is 131072, limit is 1000"), "{}", text(&o.stderr));
    assert!(!ply.exists());
}

/// Item 5: a FIFO given as the file is refused at once (exit 2, an I/O error) for every mode.
#[cfg(unix)]
#[test]
fn fifo_input_is_refused() {
    let d = tmp();
    let fifo: PathBuf = path_in(&d, "pipe.sct");
    assert!(Command::new("mkfifo").arg(&fifo).status().expect("mkfifo").success());
    let ply = path_in(&d, "x.ply");
    for extra in [vec![], vec!["--validate"], vec!["--dump"], vec!["--export-ply", ply.to_str().expect("utf8")]] {
        let mut a: Vec<&std::ffi::OsStr> = vec![fifo.as_os_str()];
        a.extend(extra.iter().map(|s| std::ffi::OsStr::new(*s)));
        let o = run(&a);
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {}", text(&o.stderr));
        assert!(text(&o.stderr).contains("FIFO"), "{}", text(&o.stderr));
    }
}

/// Item 4: `--against` stops with the traversal's visit limit (a partial coverage of a DAG's
/// first paths would be no answer).
#[test]
fn coverage_stops_at_the_visit_limit() {
    let d = tmp();
    let t = pair(leaf(0.0), leaf(1.0));
    let b = t.nodes()[0];
    let mut nodes = vec![GraphNode::Tree { tree: 0 }];
    for k in 1..=40u32 {
        nodes.push(GraphNode::Group { children: vec![k - 1, k - 1], tree: 1 });
    }
    let f = path_in(&d, "dag.sct");
    write(&f, SceneGraph { nodes, root: 40 }, vec![t, pair(b, b)], Profile::Raw);
    let mesh = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/fuze/fuze.obj");
    let opts = inspect::AgainstOptions { points: 10, limits: Limits { max_traversal_visits: 5_000, ..Limits::default() }, ..Default::default() };
    match inspect::coverage_against(&f, &mesh, &opts) {
        Err(InspectError::Sct(sct_format::Error::LimitExceeded { what, .. })) => assert_eq!(what, sct_format::traverse::VISITS),
        other => panic!("{:?}", other.map(|c| c.fraction)),
    }
}
