//! A block payload of any bytes through every profile's child decoder, below a few parents
//! of varied size. The reader reaches this code only after a block's CRC matched, so
//! mutating whole files rarely gets here; this target starts here. Errors are fine; panics,
//! non-finite attributes from finite parents (quantized profiles), and a wrong child
//! count are not.
#![no_main]
use libfuzzer_sys::fuzz_target;
use sct_format::codec::{decode_children, CodecParams};
use sct_format::{Node, Profile};

fuzz_target!(|data: &[u8]| {
    let Some((&head, rest)) = data.split_first() else { return };
    let Some(profile) = Profile::from_id(head & 0x3) else { return };
    let default = profile == Profile::Default;
    let params = CodecParams { alpha: head & 0x4 != 0, centre_offsets: head & 0x8 != 0 && default, leaf_refinement: head & 0x10 != 0 && default };
    let n_parents = 1 + (head >> 5) as usize; // 1..=8
    let parents: Vec<Node> = (0..n_parents)
        .map(|i| {
            let s = 10f32.powi(i as i32 % 7 - 3);
            Node {
                center: [i as f32 * s, -s, 0.5 * s],
                radius: s,
                normal: [0.0, 0.6, 0.8],
                cone: (i % 4) as f32 * 0.8,
                area: s * s,
                color: [i as u8, 128, 255 - i as u8, 255],
            }
        })
        .collect();
    let mut out = Vec::new();
    if decode_children(profile, params, &parents, rest, 0, &mut out).is_ok() {
        assert_eq!(out.len(), 2 * n_parents);
        // Raw stores f32 verbatim (NaN included: the validator's job); the quantized
        // profiles decode relative to finite parents and must stay finite.
        for n in out.iter().filter(|_| profile != Profile::Raw) {
            assert!(n.center.iter().chain(&n.normal).all(|v| v.is_finite()) && n.radius.is_finite() && n.area.is_finite(), "{n:?}");
        }
    }
});
