//! Opening and reading the files a loader is pointed at — the input, and every resource it
//! names (MTL, texture, glTF buffer or image, PLY `TextureFile`) — as regular files only,
//! with reads bounded by the bytes actually read.
//!
//! Why: a FIFO blocks `open` forever (no writer ever comes), and a device such as
//! `/dev/zero` reports a length of 0 while reading it never ends, so neither a `metadata`
//! check nor the declared length can bound a read. The type is checked after following
//! symlinks, before opening; the open itself is non-blocking (a FIFO swapped in after the
//! check cannot block it) and the type is checked again on the open handle.

use std::fs::{File, Metadata};
use std::io::Read;
use std::path::Path;

use crate::error::LoadError;

/// What kind of non-regular file `meta` describes, for messages ("a FIFO", …).
pub fn kind_name(meta: &Metadata) -> &'static str {
    let t = meta.file_type();
    if t.is_dir() {
        return "a directory";
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO";
        }
        if t.is_char_device() {
            return "a character device";
        }
        if t.is_block_device() {
            return "a block device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    "not a regular file"
}

/// Opens `path` for reading if it is a regular file (after following symlinks); anything
/// else is [`LoadError::NotRegularFile`] without blocking. Returns the file and its
/// metadata (from the open handle).
pub fn open_regular(path: &Path) -> Result<(File, Metadata), LoadError> {
    let io = |source| LoadError::Io { path: path.to_path_buf(), source };
    let not_regular = |meta: &Metadata| LoadError::NotRegularFile { path: path.to_path_buf(), kind: kind_name(meta) };
    let meta = std::fs::metadata(path).map_err(io)?;
    if !meta.is_file() {
        return Err(not_regular(&meta));
    }
    let mut oo = std::fs::OpenOptions::new();
    oo.read(true);
    #[cfg(unix)]
    {
        // Non-blocking open: if the path became a FIFO since the check above, `open`
        // returns at once instead of waiting for a writer (the fstat below refuses it).
        // On a regular file the flag has no effect on reads.
        use std::os::unix::fs::OpenOptionsExt;
        oo.custom_flags(libc::O_NONBLOCK);
    }
    let file = oo.open(path).map_err(io)?;
    let meta = file.metadata().map_err(io)?;
    if !meta.is_file() {
        return Err(not_regular(&meta));
    }
    Ok((file, meta))
}

/// Reads the whole of regular file `path`, refusing it once more than `max` bytes have been
/// read ([`LoadError::Limit`]): the bound holds whatever the file's metadata claims.
pub fn read_regular(path: &Path, max: u64) -> Result<Vec<u8>, LoadError> {
    let (file, meta) = open_regular(path)?;
    let too_big = |what: String| LoadError::Limit { path: path.to_path_buf(), what };
    if meta.len() > max {
        return Err(too_big(format!("file is {} bytes, more than the limit of {max}", meta.len())));
    }
    // The length is only a capacity hint (it was checked against `max`); the read itself is
    // bounded by `take`, one byte past the limit so a file that grew can be told apart.
    let mut buf = Vec::with_capacity(usize::try_from(meta.len()).unwrap_or(0));
    file.take(max.saturating_add(1))
        .read_to_end(&mut buf)
        .map_err(|source| LoadError::Io { path: path.to_path_buf(), source })?;
    if buf.len() as u64 > max {
        return Err(too_big(format!("file holds more than the limit of {max} bytes")));
    }
    Ok(buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A regular file reads; a FIFO is refused at once (not blocked on), named in the error;
    /// a directory is refused; a read stops at the limit.
    #[cfg(unix)]
    #[test]
    fn only_regular_files_are_read_and_reads_are_bounded() {
        let dir = tempfile::tempdir().expect("tempdir");
        let f = dir.path().join("a.bin");
        std::fs::write(&f, b"0123456789").expect("write");
        assert_eq!(read_regular(&f, 10).expect("read"), b"0123456789");
        assert!(matches!(read_regular(&f, 9), Err(LoadError::Limit { .. })));

        let fifo = dir.path().join("pipe.obj");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo");
        assert!(made.success());
        let e = read_regular(&fifo, 1 << 20).expect_err("a FIFO is refused");
        assert!(matches!(e, LoadError::NotRegularFile { kind: "a FIFO", .. }), "{e}");
        assert!(e.to_string().contains("pipe.obj"), "{e}");

        // Through a symlink: the type is that of the target.
        let link = dir.path().join("link.obj");
        std::os::unix::fs::symlink(&fifo, &link).expect("symlink");
        assert!(matches!(read_regular(&link, 1 << 20), Err(LoadError::NotRegularFile { .. })));
        assert!(matches!(read_regular(dir.path(), 1 << 20), Err(LoadError::NotRegularFile { kind: "a directory", .. })));
        // A device reports length 0 and never ends: refused by type, not read.
        assert!(matches!(read_regular(Path::new("/dev/zero"), 1 << 20), Err(LoadError::NotRegularFile { kind: "a character device", .. })));
    }
}
