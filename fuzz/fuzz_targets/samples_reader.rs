//! Any bytes through the samples reader; errors are fine, panics are not.
#![no_main]
use libfuzzer_sys::fuzz_target;
use sct_format::samples::SamplesFile;
use sct_format::Limits;

fuzz_target!(|data: &[u8]| {
    let limits = Limits { max_decompressed_bytes: 1 << 24, max_samples: 1 << 20, ..Limits::default() };
    let _ = SamplesFile::read(data, &limits);
});
