//! The `--json` report's container/stream figures, written bytes identical for 1 and 2
//! threads, and decoded children inside decoded parents, in every profile.

use build_tree::pipeline::{run, Config};
use build_tree::{build_tree, BuildOptions};
use sct_format::geometry::sphere_contains;
use sct_format::graph::Generator;
use sct_format::samples::SamplesFile;
use sct_format::write::{write_scene, Scene, WriteOptions};
use sct_format::{Limits, Node, Profile, SctReader};

/// `n` samples on a wavy, coloured torus (deterministic), varied areas.
fn torus(n: usize) -> Vec<Node> {
    (0..n)
        .map(|i| {
            let u = i as f32 * 2.399_963;
            let v = i as f32 * 0.618_034 * std::f32::consts::TAU;
            let (r0, r1) = (1.0 + 0.05 * (5.0 * u).sin(), 0.3);
            let c = [(r0 + r1 * v.cos()) * u.cos(), (r0 + r1 * v.cos()) * u.sin(), r1 * v.sin()];
            let nrm = [v.cos() * u.cos(), v.cos() * u.sin(), v.sin()];
            let col = [(128.0 + 120.0 * u.sin()) as u8, (128.0 + 120.0 * v.cos()) as u8, (i % 251) as u8, 255];
            Node { center: c, radius: 0.004, normal: nrm, cone: 0.0, area: 1e-5 * (1.0 + (i % 5) as f32), color: col }
        })
        .collect()
}

#[test]
fn report_figures_are_consistent() {
    let dir = tempfile::tempdir().unwrap();
    let samples = dir.path().join("t.samples");
    SamplesFile::single_mesh(Generator::default(), "torus", torus(60_000)).write_file(&samples).unwrap();
    for profile in [Profile::Raw, Profile::Canopy, Profile::Default] {
        let out = dir.path().join(format!("t-{}.sct", profile.name()));
        let cfg = Config {
            samples: samples.clone(),
            output: out.clone(),
            scene: None,
            profile,
            compression_level: None,
            centre_offsets: true,
            leaf_refinement: Default::default(),
            build: BuildOptions::default(),
        };
        let rep = run(&cfg, &mut |_| {}).unwrap();
        assert_eq!(rep.containers, rep.containers_by_level.iter().sum::<u64>(), "{profile:?}");
        assert_eq!(rep.containers_by_level.len() as u32, rep.depth + 1);
        assert_eq!(rep.containers_by_level[0], 0, "the root is in the tree header");
        assert_eq!(rep.containers_by_height.get(&1), Some(&rep.containers));
        assert_eq!(rep.links_per_leaf, 0.0);
        // One mask bit per node, 2L - 1 nodes minus the root: about 2 bits per leaf raw.
        if profile != Profile::Default {
            assert!((rep.topology_bits_per_leaf - 2.0).abs() < 0.01, "{}", rep.topology_bits_per_leaf);
        }
        let sum: f64 = rep.bytes_per_leaf_by_stream.values().sum();
        assert!((sum - rep.bytes_per_leaf).abs() <= 1e-9 * rep.bytes_per_leaf, "{sum} vs {}", rep.bytes_per_leaf);
        for k in ["topology", "position_radius", "normal", "cone", "color", "area", "index", "file"] {
            assert!(rep.bytes_per_leaf_by_stream.get(k).is_some_and(|&v| v > 0.0), "{profile:?}: stream {k} missing or empty");
        }
        if profile == Profile::Raw {
            // Raw records: 16 + 12 + 4 + 4 + 4 bytes per node, two nodes per leaf (less the root).
            let pr = rep.bytes_per_leaf_by_stream["position_radius"];
            assert!((pr - 32.0).abs() < 0.01, "{pr}");
        }
        assert_eq!(std::fs::metadata(&out).unwrap().len(), rep.bytes);
    }
}

#[test]
fn written_bytes_identical_for_one_and_two_threads_and_decoded_children_inside_parents() {
    let s = torus(40_000);
    let (tree, _) = build_tree(&s, &BuildOptions::default()).unwrap();
    let scene = Scene::single_tree(Generator::default(), tree);
    for profile in [Profile::Raw, Profile::Canopy, Profile::Default] {
        // Small blocks so that levels have many blocks to spread over threads.
        let opts = WriteOptions { profile, block_nodes: 1024, ..Default::default() };
        let write = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let mut buf = Vec::new();
            pool.install(|| write_scene(&scene, &opts, &mut buf)).unwrap();
            buf
        };
        let one = write(1);
        assert!(one == write(2), "{profile:?}: bytes differ between 1 and 2 threads");
        let back = SctReader::from_bytes(one, &Limits::default()).unwrap().read_tree(0).unwrap();
        let nodes = back.nodes();
        let slack = profile.containment_slack();
        for i in 0..back.len() {
            if let Some([a, b]) = back.children(i) {
                for c in [a, b] {
                    assert!(sphere_contains(&nodes[i], &nodes[c], slack), "{profile:?}: decoded child {c} outside decoded parent {i}");
                }
            }
        }
    }
}
