//! Any bytes: open, verify and decode every tree, bound every graph node (affine instance
//! chains included) and validate; errors are fine, panics are not.
#![no_main]
use libfuzzer_sys::fuzz_target;
use sct_format::validate::{validate_bytes, ValidateOptions};
use sct_format::{Limits, SctReader};

fuzz_target!(|data: &[u8]| {
    let limits = Limits { max_decompressed_bytes: 1 << 24, max_tree_nodes: 1 << 20, max_graph_nodes: 1 << 16, ..Limits::default() };
    if let Ok(r) = SctReader::from_bytes(data.to_vec(), &limits) {
        let _ = r.verify_checksums();
        for t in 0..r.trees().len() {
            let _ = r.read_tree(t);
        }
        for i in 0..r.graph().nodes.len().min(256) {
            let _ = sct_format::traverse::graph_bound(&r, i as u32);
        }
    }
    let _ = validate_bytes(data, &ValidateOptions { limits, ..Default::default() });
});
