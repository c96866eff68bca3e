//! Structure, attribute and determinism tests of `build_tree`.

use build_tree::{build_tree, build_tree_owned, build_tree_with_map, BuildOptions, Weld};
use sct_format::geometry::{cone_contains, sphere_contains};
use sct_format::{Node, SceneTree};

/// Deterministic pseudo-random numbers (no external RNG needed).
struct Lcg(u64);
impl Lcg {
    fn f(&mut self) -> f32 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((self.0 >> 40) as f32) / (1u64 << 24) as f32
    }
}

/// Samples on a unit sphere (normals outward), with a few exact and near duplicates.
fn sphere_samples(n: usize, seed: u64) -> Vec<Node> {
    let mut r = Lcg(seed);
    let mut v = Vec::with_capacity(n);
    while v.len() < n {
        let (x, y, z) = (r.f() * 2.0 - 1.0, r.f() * 2.0 - 1.0, r.f() * 2.0 - 1.0);
        let l = (x * x + y * y + z * z).sqrt();
        if !(0.1..=1.0).contains(&l) {
            continue;
        }
        let nrm = [x / l, y / l, z / l];
        let s = Node {
            center: nrm,
            radius: 0.01 + 0.01 * r.f(),
            normal: nrm,
            cone: 0.0,
            area: 0.5 + r.f(),
            color: [(r.f() * 255.0) as u8, (r.f() * 255.0) as u8, (r.f() * 255.0) as u8, 255],
        };
        v.push(s);
        if v.len() % 97 == 0 && v.len() < n {
            v.push(s); // exact duplicate
        }
    }
    v
}

fn check_tree(t: &SceneTree) {
    let nodes = t.nodes();
    // Full binary tree: 2L - 1 nodes.
    assert_eq!(t.len(), 2 * t.leaf_count() - 1);
    for i in 0..t.len() {
        if let Some([a, b]) = t.children(i) {
            for c in [a, b] {
                assert!(sphere_contains(&nodes[i], &nodes[c], 0.0), "child {c} outside parent {i}");
                assert!(cone_contains(nodes[i].normal, nodes[i].cone, nodes[c].normal, nodes[c].cone, 0.0));
            }
            let area = nodes[a].area as f64 + nodes[b].area as f64;
            assert!((nodes[i].area as f64 - area).abs() <= 1e-6 * area.max(1e-30));
        }
    }
    // Every leaf normal inside every ancestor cone.
    let parents = t.parents();
    for leaf in t.leaves() {
        let mut p = parents[leaf];
        while p != sct_format::tree::NO_CHILD {
            let pn = &nodes[p as usize];
            assert!(cone_contains(pn.normal, pn.cone, nodes[leaf].normal, nodes[leaf].cone, 0.0));
            p = parents[p as usize];
        }
    }
}

#[test]
fn structure_and_attributes() {
    let s = sphere_samples(20_000, 1);
    let opts = BuildOptions { weld: Weld::Absolute(0.0), ..Default::default() };
    let (t, st, map) = build_tree_with_map(&s, &opts).unwrap();
    check_tree(&t);
    // Duplicates (every 97th) welded, nothing else.
    let mut keys: Vec<[u32; 3]> = s.iter().map(|x| x.center.map(f32::to_bits)).collect();
    keys.sort_unstable();
    keys.dedup();
    assert_eq!(st.leaves as usize, keys.len());
    assert_eq!(st.leaves as usize + st.welded as usize, s.len());
    assert_eq!(st.nodes, 2 * st.leaves - 1);
    // Every sample in exactly one leaf, and inside it.
    let mut per_leaf = vec![0usize; t.len()];
    for (i, &leaf) in map.iter().enumerate() {
        assert!(!t.is_internal(leaf as usize));
        assert!(sphere_contains(&t.nodes()[leaf as usize], &s[i], 0.0));
        per_leaf[leaf as usize] += 1;
    }
    assert_eq!(per_leaf.iter().filter(|&&c| c > 0).count() as u64, st.leaves);
    // Depth bound.
    let bound = (st.leaves as f64).log2().ceil() as u32 + opts.depth_slack;
    assert!(st.depth <= bound, "depth {} > {bound}", st.depth);
    assert_eq!(t.level_count() as u32, st.depth + 1);
    // Total area preserved; root colour = area-weighted mean within rounding per level.
    let total: f64 = s.iter().map(|x| x.area as f64).sum();
    let root = t.nodes()[0];
    assert!((root.area as f64 - total).abs() <= 1e-4 * total);
    for ch in 0..3 {
        let mean: f64 = s.iter().map(|x| x.area as f64 * x.color[ch] as f64).sum::<f64>() / total;
        // Each level rounds to the nearest integer: error ≤ 0.5 per level in the worst case,
        // far less on average.
        assert!((root.color[ch] as f64 - mean).abs() <= 2.0, "channel {ch}: {} vs {mean}", root.color[ch]);
    }
}

#[test]
fn near_duplicates_weld_within_tolerance() {
    let mut s = sphere_samples(1000, 2);
    let extra: Vec<Node> = s.iter().take(50).map(|x| Node { center: [x.center[0] + 1e-4, x.center[1], x.center[2]], ..*x }).collect();
    s.extend(extra);
    let (t, st) = build_tree(&s, &BuildOptions { weld: Weld::Absolute(1e-3), ..Default::default() }).unwrap();
    check_tree(&t);
    assert!(st.welded >= 50, "welded {}", st.welded);
    let (_, st0) = build_tree(&s, &BuildOptions { weld: Weld::Off, ..Default::default() }).unwrap();
    assert_eq!(st0.welded, 0);
    assert_eq!(st0.leaves as usize, s.len());
}

#[test]
fn degenerate_inputs() {
    let one = sphere_samples(1, 3);
    let (t, st) = build_tree(&one, &BuildOptions::default()).unwrap();
    assert_eq!((t.len(), st.depth), (1, 0));
    // All coincident: welded to one leaf, or a balanced tree when welding is off.
    let same = vec![one[0]; 1000];
    let (t, _) = build_tree(&same, &BuildOptions::default()).unwrap();
    assert_eq!(t.len(), 1);
    assert!((t.nodes()[0].area - 1000.0 * one[0].area).abs() < 1e-2 * t.nodes()[0].area);
    let (t, st) = build_tree(&same, &BuildOptions { weld: Weld::Off, depth_slack: 0, ..Default::default() }).unwrap();
    assert_eq!(t.len(), 1999);
    assert_eq!(st.depth, 10);
    // Points on a line with exponentially growing gaps: the centre split degenerates into a
    // chain; the depth budget must keep it logarithmic.
    let chain: Vec<Node> = (0..2000).map(|i| Node { center: [1.01f32.powi(i), 0.0, 0.0], radius: 0.001, normal: [0.0, 0.0, 1.0], area: 1.0, ..Default::default() }).collect();
    let (t, st) = build_tree(&chain, &BuildOptions { weld: Weld::Off, depth_slack: 2, ..Default::default() }).unwrap();
    check_tree(&t);
    assert!(st.depth <= 11 + 2, "depth {}", st.depth);
    assert!(st.forced_splits > 0);
    assert!(build_tree(&[], &BuildOptions::default()).is_err());
    let bad = vec![Node { radius: f32::NAN, ..one[0] }];
    assert!(build_tree(&bad, &BuildOptions::default()).is_err());
    // Among many good samples (the check runs in parallel chunks), the error names the
    // first bad one.
    let mut many: Vec<Node> = (0..6).flat_map(|k| chain.iter().map(move |n| Node { center: [n.center[0], k as f32, 0.0], ..*n })).collect();
    many[4321].cone = 4.0;
    many[9000].normal[1] = f32::INFINITY;
    match build_tree(&many, &BuildOptions::default()) {
        Err(e) => assert!(e.to_string().contains("sample 4321 "), "{e}"),
        Ok(_) => panic!("a cone above π was accepted"),
    }
}

#[test]
fn deterministic_across_thread_counts() {
    let s = sphere_samples(200_000, 4);
    let run = |threads| {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| build_tree(&s, &BuildOptions::default()).unwrap().0)
    };
    let a = run(1);
    let b = run(2);
    let c = run(3);
    assert!(a == b && b == c);
}

/// The consuming builder (which reorders, welds and grows the samples' own vector) gives the
/// same tree as the borrowing one and the mapping one, with many multi-sample welds (whose
/// result depends on member order) and without welding.
#[test]
fn owned_borrowed_and_mapped_builds_agree() {
    let mut s = sphere_samples(30_000, 7);
    let near: Vec<Node> = s.iter().step_by(3).map(|x| Node { center: [x.center[0] + 2e-4, x.center[1], x.center[2]], ..*x }).collect();
    s.extend(near);
    for weld in [Weld::Absolute(5e-3), Weld::RelativeToMeanRadius(0.5), Weld::Off] {
        let opts = BuildOptions { weld, ..Default::default() };
        let (a, sa) = build_tree(&s, &opts).unwrap();
        let (b, sb) = build_tree_owned(s.clone(), &opts).unwrap();
        let (c, sc, map) = build_tree_with_map(&s, &opts).unwrap();
        assert_eq!(a.nodes(), b.nodes());
        assert_eq!(a.internal_flags(), b.internal_flags());
        assert_eq!(a.nodes(), c.nodes());
        assert_eq!((sa.leaves, sa.depth, sa.welded), (sb.leaves, sb.depth, sb.welded));
        assert_eq!((sa.leaves, sa.depth, sa.welded), (sc.leaves, sc.depth, sc.welded));
        if weld != Weld::Off {
            assert!(sa.welded > 1000, "{weld:?} welded only {}", sa.welded);
        }
        check_tree(&a);
        // Every sample maps to a leaf that contains it, and every leaf is used.
        let mut used = vec![false; a.len()];
        for (x, &leaf) in s.iter().zip(&map) {
            assert!(!a.is_internal(leaf as usize));
            assert!(sphere_contains(&a.nodes()[leaf as usize], x, 0.0));
            used[leaf as usize] = true;
        }
        assert_eq!(used.iter().filter(|&&u| u).count() as u64, sa.leaves);
    }
}

/// Welded groups of every size from 1 to 150 (ranges that start and end on either side of
/// 64-item words): each leaf is the weld of exactly its group (area sums to the group's),
/// and the map sends every sample to its group's leaf. Guards the layout's range ends.
#[test]
fn welded_groups_across_word_boundaries() {
    let mut s = Vec::new();
    for g in 1..=150usize {
        let c = [g as f32, (g * g % 7) as f32, 0.5];
        s.extend((0..g).map(|k| Node { center: c, radius: 0.1, normal: [0.0, 0.0, 1.0], area: 1.0 + k as f32, ..Default::default() }));
    }
    let (t, st, map) = build_tree_with_map(&s, &BuildOptions { weld: Weld::Absolute(0.0), ..Default::default() }).unwrap();
    check_tree(&t);
    assert_eq!(st.leaves, 150);
    let mut at = 0;
    for g in 1..=150usize {
        let leaf = map[at] as usize;
        assert!(map[at..at + g].iter().all(|&m| m as usize == leaf), "group {g}");
        assert!(t.children(leaf).is_none());
        let area: f32 = (0..g).map(|k| 1.0 + k as f32).sum();
        assert_eq!(t.nodes()[leaf].area, area, "group {g}");
        assert_eq!(t.nodes()[leaf].center, s[at].center);
        at += g;
    }
}
