//! Any bytes: open, verify and decode every tree; errors are fine, panics are not.
#![no_main]
use libfuzzer_sys::fuzz_target;
use sct_format::{Limits, SctReader};

fuzz_target!(|data: &[u8]| {
    let limits = Limits { max_decompressed_bytes: 1 << 24, max_tree_nodes: 1 << 20, ..Limits::default() };
    if let Ok(r) = SctReader::from_bytes(data.to_vec(), &limits) {
        let _ = r.verify_checksums();
        for t in 0..r.trees().len() {
            let _ = r.read_tree(t);
        }
    }
});
