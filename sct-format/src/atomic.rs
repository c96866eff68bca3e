//! Atomic output: write to a temporary file beside the target, then rename, so a reader
//! (or a crash) never sees a partial file.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// Calls `fill` with a buffered writer on a temporary file next to `path`, then renames it
/// over `path`. On any error the temporary file is removed and `path` is untouched.
pub fn write_atomic<T>(path: &Path, fill: impl FnOnce(&mut BufWriter<File>) -> Result<T>) -> Result<T> {
    write_atomic_with(path, fill)
}

/// [`write_atomic`] for a `fill` that fails with its caller's error type (a writer fed by a
/// sampler fails with the sampler's errors too), into which this function's own I/O errors
/// convert.
pub fn write_atomic_with<T, E: From<Error>>(path: &Path, fill: impl FnOnce(&mut BufWriter<File>) -> std::result::Result<T, E>) -> std::result::Result<T, E> {
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().ok_or_else(|| Error::Misuse(format!("{} is not a file path", path.display())))?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(".{}.tmp", std::process::id()));
    let tmp: PathBuf = dir.join(tmp_name);
    let result = (|| -> std::result::Result<T, E> {
        let file = File::create(&tmp).map_err(|e| Error::io(&tmp, e))?;
        let mut w = BufWriter::with_capacity(1 << 20, file);
        let value = fill(&mut w)?;
        w.flush().map_err(|e| Error::io(&tmp, e))?;
        let file = w.into_inner().map_err(|e| Error::io(&tmp, e.into_error()))?;
        file.sync_all().map_err(|e| Error::io(&tmp, e))?;
        std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))?;
        Ok(value)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// BLAKE3 hash of a file's bytes, lowercase hex (streams; memory stays small).
pub fn hash_file(path: &Path) -> Result<String> {
    let mut h = blake3::Hasher::new();
    h.update_reader(File::open(path).map_err(|e| Error::io(path, e))?).map_err(|e| Error::io(path, e))?;
    Ok(h.finalize().to_hex().to_string())
}

/// BLAKE3 hash of `data`, lowercase hex: the same value as `blake3::hash`, with the subtrees of
/// a large input hashed in parallel (a serial hash would be the read's longest step once the
/// samples decode in parallel).
pub fn hash_bytes(data: &[u8]) -> String {
    use blake3::hazmat::{left_subtree_len, merge_subtrees_root, Mode};
    if data.len() <= PARALLEL_HASH_MIN {
        return blake3::hash(data).to_hex().to_string();
    }
    // The root splits where BLAKE3's tree does (left_subtree_len), as must every subtree.
    let left = left_subtree_len(data.len() as u64) as usize;
    let (l, r) = data.split_at(left);
    let (lcv, rcv) = rayon::join(|| subtree_cv(l, 0), || subtree_cv(r, left as u64));
    merge_subtrees_root(&lcv, &rcv, Mode::Hash).to_hex().to_string()
}

/// Below this, one thread hashes the whole input (about a millisecond).
const PARALLEL_HASH_MIN: usize = 1 << 20;

/// Chaining value of the subtree over `data`, which starts at byte `offset` of the input.
fn subtree_cv(data: &[u8], offset: u64) -> blake3::hazmat::ChainingValue {
    use blake3::hazmat::{left_subtree_len, merge_subtrees_non_root, HasherExt, Mode};
    if data.len() <= PARALLEL_HASH_MIN {
        return blake3::Hasher::new().set_input_offset(offset).update(data).finalize_non_root();
    }
    let left = left_subtree_len(data.len() as u64) as usize;
    let (l, r) = data.split_at(left);
    let (lcv, rcv) = rayon::join(|| subtree_cv(l, offset), || subtree_cv(r, offset + left as u64));
    merge_subtrees_non_root(&lcv, &rcv, Mode::Hash)
}

#[cfg(test)]
mod tests {
    /// The parallel hash is BLAKE3's, around every split size.
    #[test]
    fn hash_bytes_is_blake3() {
        let data: Vec<u8> = (0..5_300_000u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect();
        for len in [0, 1, 1024, 1025, 1 << 20, (1 << 20) + 1, (2 << 20) + 1024, (3 << 20) + 7, 4 << 20, data.len()] {
            assert_eq!(super::hash_bytes(&data[..len]), blake3::hash(&data[..len]).to_hex().to_string(), "{len}");
        }
    }
}
