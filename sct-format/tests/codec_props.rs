//! Property tests of the lossy node codecs (canopy and default).
//!
//! Tolerances: sphere containment is checked with none (f64 arithmetic on the stored f32
//! values, exactly the encoder's criterion); cone containment with 1e-9 rad for the f64
//! atan2 angle; stick-out with 1e-6 of the parent radius for the f64 distance of f32 values.

use proptest::prelude::*;
use sct_format::codec::{canopy, decode_children, encode_children, CodecParams, Profile};
use sct_format::{Error, Node};

fn d64(a: [f32; 3], b: [f32; 3]) -> f64 {
    let d = |i: usize| a[i] as f64 - b[i] as f64;
    (d(0) * d(0) + d(1) * d(1) + d(2) * d(2)).sqrt()
}

fn angle(a: [f32; 3], b: [f32; 3]) -> f64 {
    let a = a.map(|v| v as f64);
    let b = b.map(|v| v as f64);
    let c = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt().atan2(a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
}

fn unit(v: [f32; 3]) -> [f32; 3] {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if l < 1e-3 {
        [0.0, 0.0, 1.0]
    } else {
        v.map(|x| x / l)
    }
}

fn vec3(r: f32) -> impl Strategy<Value = [f32; 3]> {
    [-r..r, -r..r, -r..r]
}

prop_compose! {
    fn parent()(c in vec3(100.0), r in 1e-3f32..100.0, n in vec3(1.0), cone in 0f32..std::f32::consts::PI,
                area in 1e-3f32..1e3, col in any::<[u8; 4]>()) -> Node {
        Node { center: c, radius: r, normal: unit(n), cone, area, color: [col[0], col[1], col[2], 255] }
    }
}

prop_compose! {
    /// A child at fraction `t` of the free space inside `p` (t ≤ 1: contained; up to 1.15:
    /// slightly outside, as f32 rounding or a loose builder can produce).
    fn child(p: Node, alpha: bool)(dir in vec3(1.0), k in 0f32..1.0, t in 0f32..1.15, n in vec3(1.0),
                  cone in 0f32..3.2, area in 0f32..1e3, col in any::<[u8; 4]>()) -> (Node, bool) {
        let r = p.radius * k;
        let u = unit(dir);
        let dist = (p.radius - r) * t;
        let center = [0, 1, 2].map(|i| p.center[i] + u[i] * dist);
        let cone = cone.min(std::f32::consts::PI);
        let n = Node { center, radius: r, normal: unit(n), cone, area,
                       color: [col[0], col[1], col[2], if alpha { col[3] } else { 255 }] };
        let inside = d64(center, p.center) + r as f64 <= p.radius as f64;
        (n, inside)
    }
}

fn pairs(alpha: bool) -> impl Strategy<Value = (Vec<Node>, Vec<(Node, bool)>)> {
    prop::collection::vec(parent(), 1..8).prop_flat_map(move |ps| {
        let kids: Vec<_> = ps.iter().flat_map(|p| [child(*p, alpha), child(*p, alpha)]).collect();
        (Just(ps), kids)
    })
}

fn check(profile: Profile, alpha: bool, ps: &[Node], kids: &[(Node, bool)]) -> Result<(), TestCaseError> {
    check_with(profile, CodecParams { alpha, ..Default::default() }, ps, kids)
}

fn check_with(profile: Profile, params: CodecParams, ps: &[Node], kids: &[(Node, bool)]) -> Result<(), TestCaseError> {
    let children: Vec<Node> = kids.iter().map(|k| k.0).collect();
    let mut out = vec![0xAB]; // encoders append
    let res = encode_children(profile, params, ps, &children, &mut out);
    let dec = match res {
        Ok(d) => d,
        Err(Error::Misuse(_)) => {
            // Only a child outside its parent may be refused.
            prop_assert!(kids.iter().any(|k| !k.1), "a contained child was refused");
            prop_assert_eq!(out.len(), 1);
            return Ok(());
        }
        Err(e) => return Err(TestCaseError::fail(format!("unexpected error {e}"))),
    };
    prop_assert_eq!(out[0], 0xAB);
    let mut again = Vec::new();
    decode_children(profile, params, ps, &out[1..], 0, &mut again).map_err(|e| TestCaseError::fail(e.to_string()))?;
    prop_assert_eq!(&again, &dec, "decode(encode) differs from the returned nodes");
    let slack = profile.containment_slack() as f64;
    let cmax = canopy::MAX_COLOR_ERROR;
    for (i, (c, d)) in children.iter().zip(&dec).enumerate() {
        let p = &ps[i / 2];
        prop_assert!(d.is_finite());
        prop_assert!(d64(d.center, c.center) + c.radius as f64 <= d.radius as f64, "child {i} not contained: {c:?} -> {d:?}");
        prop_assert!(
            d64(d.center, p.center) + d.radius as f64 <= p.radius as f64 * (1.0 + slack + 1e-6),
            "child {i} sticks out of its parent by more than the slack"
        );
        let e = angle(c.normal, d.normal);
        prop_assert!(e.to_degrees() <= canopy::MAX_NORMAL_ERROR_DEG, "normal error {}", e.to_degrees());
        prop_assert!(e + c.cone as f64 <= d.cone as f64 + 1e-9 || d.cone == std::f32::consts::PI, "cone not contained");
        for (j, (&a, &b)) in c.color.iter().zip(&d.color).enumerate() {
            prop_assert!((a as i32 - b as i32).unsigned_abs() <= cmax[j] as u32, "colour {j}");
        }
        if profile == Profile::Canopy {
            prop_assert_eq!(c.area, d.area);
        }
    }
    if profile == Profile::Default {
        for (k, p) in ps.iter().enumerate() {
            let s = dec[2 * k].area as f64 + dec[2 * k + 1].area as f64;
            prop_assert!((s - p.area as f64).abs() <= p.area as f64 * 1e-6, "areas do not sum to the parent's");
            let (a, b) = (children[2 * k].area as f64, children[2 * k + 1].area as f64);
            if a + b > 0.0 {
                let f = dec[2 * k].area as f64 / p.area as f64;
                // Half a code step: 1/8192 for slivers, at most 1/32 of the smaller side's
                // fraction, at most 4/4096 (the encoder's coarsest step is 8 codes).
                let x = a / (a + b);
                let half_step = (x.min(1.0 - x) / 32.0).clamp(0.5 / 4096.0, 4.0 / 4096.0);
                prop_assert!((f - x).abs() <= half_step + 1e-6, "area fraction error {} > {half_step}", (f - x).abs());
            }
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn canopy_props((ps, kids) in pairs(false)) { check(Profile::Canopy, false, &ps, &kids)?; }

    #[test]
    fn canopy_alpha_props((ps, kids) in pairs(true)) { check(Profile::Canopy, true, &ps, &kids)?; }

    #[test]
    fn default_props((ps, kids) in pairs(false)) { check(Profile::Default, false, &ps, &kids)?; }

    #[test]
    fn default_alpha_props((ps, kids) in pairs(true)) { check(Profile::Default, true, &ps, &kids)?; }

    /// Centre offsets (1.2) keep every bound, and never move a centre away from the original
    /// along the decoded normal.
    #[test]
    fn default_centre_offset_props((ps, kids) in pairs(false), alpha in any::<bool>()) {
        let with = CodecParams { alpha, centre_offsets: true, ..Default::default() };
        check_with(Profile::Default, with, &ps, &kids)?;
        let children: Vec<Node> = kids.iter().map(|k| k.0).collect();
        let (mut a, mut b) = (Vec::new(), Vec::new());
        if let (Ok(plain), Ok(moved)) = (
            encode_children(Profile::Default, CodecParams { alpha, ..Default::default() }, &ps, &children, &mut a),
            encode_children(Profile::Default, with, &ps, &children, &mut b),
        ) {
            for (i, ((c, d0), d1)) in children.iter().zip(&plain).zip(&moved).enumerate() {
                let along = |d: &Node| (0..3).map(|k| (c.center[k] as f64 - d.center[k] as f64) * d0.normal[k] as f64).sum::<f64>().abs();
                // Plus the f32 rounding of a centre far from the origin against a small parent.
                let ulps = 4.0 * f32::EPSILON as f64 * c.center.iter().fold(0f32, |m, v| m.max(v.abs())) as f64;
                prop_assert!(along(d1) <= along(d0) + ps[i / 2].radius as f64 * 1e-6 + ulps, "child {i}: offset moved the centre away along the normal");
            }
        }
    }

    /// Leaf refinement (1.4) keeps every bound and puts a refined child within 1/256 of its
    /// decoded radius of the original's centre on every axis and within 2 % (plus that step)
    /// of its radius, unless the child had to stay as decoded; a refined sphere never grows.
    #[test]
    fn default_leaf_refinement_props((ps, kids) in pairs(false), alpha in any::<bool>()) {
        let with = CodecParams { alpha, centre_offsets: false, leaf_refinement: true };
        check_with(Profile::Default, with, &ps, &kids)?;
        let children: Vec<Node> = kids.iter().map(|k| k.0).collect();
        let (mut a, mut b) = (Vec::new(), Vec::new());
        if let (Ok(plain), Ok(refined)) = (
            encode_children(Profile::Default, CodecParams { alpha, ..Default::default() }, &ps, &children, &mut a),
            encode_children(Profile::Default, with, &ps, &children, &mut b),
        ) {
            // (That the encoder moves anything at all is checked on a fixed tree by the
            // round-trip test `leaf_refinement_puts_leaves_at_their_place_and_size…`: a
            // handful of random pairs can all have to stay as decoded.)
            for (i, ((c, d0), d1)) in children.iter().zip(&plain).zip(&refined).enumerate() {
                prop_assert!(d1.radius <= d0.radius, "child {i}: refinement grew the radius");
                if d1 != d0 {
                    let step = d0.radius as f64 / 256.0 * 1.0001;
                    for k in 0..3 {
                        // Half a step, plus the f32 rounding of a centre far from the origin.
                        let ulps = 4.0 * f32::EPSILON as f64 * (c.center[k] as f64).abs();
                        prop_assert!((d1.center[k] as f64 - c.center[k] as f64).abs() <= step + ulps || d1.center == d0.center, "child {i}: axis {k} off by more than a step");
                    }
                    if d1.center != d0.center {
                        prop_assert!(d1.radius as f64 <= c.radius as f64 * 1.02 + 3.0 * step + 1e-6, "child {i}: radius {} for {}", d1.radius, c.radius);
                    }
                }
            }
        }
    }

    /// Leaf refinement with centre offsets (refinement where it is needed) keeps every bound,
    /// leaves a child untouched when the offset left it within its allowance (area / 6 radius,
    /// plus radius / 128) of its original centre along the original's tangent plane, and
    /// otherwise moves it back within that allowance or, failing that, refines it fully (every
    /// axis within a step); a sphere never grows.
    #[test]
    fn default_refinement_where_needed_props((ps, kids) in pairs(false), alpha in any::<bool>()) {
        let with = CodecParams { alpha, centre_offsets: true, leaf_refinement: true };
        check_with(Profile::Default, with, &ps, &kids)?;
        let children: Vec<Node> = kids.iter().map(|k| k.0).collect();
        let (mut a, mut b) = (Vec::new(), Vec::new());
        if let (Ok(plain), Ok(refined)) = (
            encode_children(Profile::Default, CodecParams { alpha, centre_offsets: true, ..Default::default() }, &ps, &children, &mut a),
            encode_children(Profile::Default, with, &ps, &children, &mut b),
        ) {
            for (i, ((c, d0), d1)) in children.iter().zip(&plain).zip(&refined).enumerate() {
                prop_assert!(d1.radius <= d0.radius, "child {i}: refinement grew the radius");
                let n = c.normal.map(f64::from);
                let nn: f64 = n.iter().map(|v| v * v).sum();
                let tangential = |d: &Node| {
                    let v: [f64; 3] = std::array::from_fn(|k| d.center[k] as f64 - c.center[k] as f64);
                    let along = if nn > 1e-30 { (0..3).map(|k| v[k] * n[k]).sum::<f64>().powi(2) / nn } else { 0.0 };
                    (v.iter().map(|x| x * x).sum::<f64>() - along).max(0.0).sqrt()
                };
                let ulps = 8.0 * f32::EPSILON as f64 * c.center.iter().chain(&d0.center).fold(0f32, |m, v| m.max(v.abs())) as f64;
                let allowed = c.area as f64 / (6.0 * c.radius as f64) + c.radius as f64 / 128.0;
                if tangential(d0) + ulps < allowed {
                    prop_assert_eq!(d1, d0, "child {}: moved though within its allowance", i);
                } else if d1 != d0 {
                    let step = d0.radius as f64 / 256.0 * 1.0001;
                    let full = (0..3).all(|k| (d1.center[k] as f64 - c.center[k] as f64).abs() <= step + ulps);
                    prop_assert!(tangential(d1) <= allowed + ulps || full || d1.center == d0.center, "child {i}: left {} off its piece (allowed {allowed})", tangential(d1));
                }
            }
        }
    }

    /// Arbitrary bytes, of arbitrary and of exactly the expected length, never panic.
    #[test]
    fn arbitrary_bytes_never_panic(ps in prop::collection::vec(parent(), 0..6), junk in prop::collection::vec(any::<u8>(), 0..300), alpha in any::<bool>()) {
        let params = CodecParams { alpha, ..Default::default() };
        for profile in [Profile::Canopy, Profile::Default] {
            let mut out = Vec::new();
            let _ = decode_children(profile, params, &ps, &junk, 5, &mut out);
            // Exact length, so the per-field checks run too.
            let need = match profile {
                Profile::Canopy => ps.len() * 2 * canopy::node_bytes(params),
                _ => ps.len() * (2 * if alpha { 9 } else { 8 } + 2),
            };
            let bytes: Vec<u8> = junk.iter().copied().cycle().take(need).collect();
            if bytes.len() == need {
                let mut out = Vec::new();
                if decode_children(profile, params, &ps, &bytes, 5, &mut out).is_ok() {
                    prop_assert_eq!(out.len(), 2 * ps.len());
                }
            }
        }
    }
}

/// Wrong lengths are `Malformed` at the block's offset.
#[test]
fn wrong_length_is_malformed_with_offset() {
    let p = Node { radius: 1.0, normal: [0.0, 0.0, 1.0], color: [0, 0, 0, 255], ..Node::default() };
    for profile in [Profile::Canopy, Profile::Default] {
        let mut out = Vec::new();
        let e = decode_children(profile, CodecParams::default(), &[p], &[0u8; 3], 1234, &mut out);
        assert!(matches!(e, Err(Error::Malformed { offset: 1234, .. })), "{profile:?}: {e:?}");
    }
}

/// Measures the worst stick-out over many contained children (deterministic LCG), reports
/// it, and checks it against the documented slack.
#[test]
fn measured_stick_out_within_slack() {
    let mut s = 0x1234_5678_9abc_def0u64;
    let mut rnd = move || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((s >> 11) as f64 / (1u64 << 53) as f64) as f32
    };
    let p = Node { center: [0.3, -0.2, 0.1], radius: 1.0, normal: [0.0, 0.0, 1.0], cone: 0.0, area: 1.0, color: [0, 0, 0, 255] };
    let mut worst = 0f64;
    let mut worst_pos = 0f64;
    for _ in 0..20_000 {
        let mut kids = Vec::new();
        for _ in 0..2 {
            let k = rnd();
            let u = unit([rnd() * 2.0 - 1.0, rnd() * 2.0 - 1.0, rnd() * 2.0 - 1.0]);
            let dist = (1.0 - k) * rnd().sqrt();
            kids.push(Node { center: [0, 1, 2].map(|i| p.center[i] + u[i] * dist), radius: k, ..p });
        }
        let mut out = Vec::new();
        let dec = encode_children(Profile::Canopy, CodecParams::default(), &[p], &kids, &mut out).expect("contained");
        for (c, d) in kids.iter().zip(&dec) {
            worst = worst.max(d64(d.center, p.center) + d.radius as f64 - 1.0);
            worst_pos = worst_pos.max(d64(d.center, c.center));
        }
    }
    eprintln!("worst stick-out {worst:.4} parent radii, worst centre error {worst_pos:.4}");
    assert!(worst <= canopy::CONTAINMENT_SLACK as f64);
}
