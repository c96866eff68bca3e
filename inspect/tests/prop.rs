//! Property: validating any file the writer produced from a consistent tree reports no
//! issue, in quick and deep mode, for every profile, whether the tree comes from the test
//! helper's median splits or from `build-tree` itself (welding, centre splits, depth limit).

mod common;

use common::*;
use proptest::prelude::*;
use sct_format::validate::{validate_file, ValidateOptions};
use sct_format::{Node, Profile};

fn arb_leaf() -> impl Strategy<Value = Node> {
    (
        prop::array::uniform3(-100.0f32..100.0),
        prop::sample::select(vec![1e-3f32, 1.0, 50.0]),
        0.0f32..1.0,
        prop::array::uniform3(-1.0f32..1.0).prop_filter("nonzero", |n| n.iter().map(|v| v * v).sum::<f32>() > 1e-2),
        prop_oneof![Just(0.0f32), 0.0f32..3.0],
        0.0f32..10.0,
        prop::array::uniform4(any::<u8>()),
    )
        .prop_map(|(c, s, r, n, cone, area, color)| {
            let l = n.iter().map(|v| v * v).sum::<f32>().sqrt();
            Node { center: [c[0] * s, c[1] * s, c[2] * s], radius: r * s, normal: [n[0] / l, n[1] / l, n[2] / l], cone, area, color }
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    #[test]
    fn written_consistent_trees_validate(
        leaves in prop::collection::vec(arb_leaf(), 1..300),
        profile in prop::sample::select(vec![Profile::Raw, Profile::Canopy, Profile::Default]),
    ) {
        let d = tmp();
        let f = path_in(&d, "p.sct");
        write_single(&f, kd_tree(leaves), profile);
        for deep in [false, true] {
            let r = validate_file(&f, &ValidateOptions { deep, ..Default::default() }).unwrap();
            prop_assert!(r.is_valid(), "{profile:?} deep {deep}: {:#?}", r.issues);
        }
    }

    #[test]
    fn build_tree_output_validates(
        samples in prop::collection::vec(arb_leaf(), 1..400),
        duplicates in 0usize..40,
        profile in prop::sample::select(vec![Profile::Raw, Profile::Canopy, Profile::Default]),
    ) {
        // Exact duplicates exercise welding; a leaf repeated many times, degenerate splits.
        let mut samples = samples;
        for k in 0..duplicates {
            samples.push(samples[k % samples.len()]);
        }
        let (tree, stats) = build_tree::build_tree(&samples, &build_tree::BuildOptions::default()).unwrap();
        prop_assert_eq!(stats.nodes as usize, tree.len());
        let d = tmp();
        let f = path_in(&d, "b.sct");
        write_single(&f, tree, profile);
        for deep in [false, true] {
            let r = validate_file(&f, &ValidateOptions { deep, ..Default::default() }).unwrap();
            prop_assert!(r.is_valid(), "{profile:?} deep {deep}: {:#?}", r.issues);
        }
    }
}
