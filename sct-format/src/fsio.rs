//! Opening input files so that no file system object can hang or crash a reader.
//!
//! A path may name a FIFO (opening it blocks until a writer appears, reading it may never
//! end), a device (`/dev/zero` never ends), a socket or a directory. [`open_regular`] opens
//! only regular files (after following symlinks), without ever blocking in `open`, and
//! [`read_regular`] reads one with a bound. Every SCT input this crate opens goes through
//! them, and so does every file the mesh loaders read (the input, MTL, textures, glTF
//! buffers and images, PLY `TextureFile`: `voxelize::load`) and `sct-build-tree` opens: one
//! implementation, one behaviour. [`not_regular_kind`] tells a refusal by type apart.
//!
//! [`Source`] holds the bytes of an SCT file: in memory, or a regular file read on demand
//! with positioned reads. Reading instead of memory-mapping matters for robustness: when
//! another process truncates a mapped file, touching the lost pages raises SIGBUS and kills
//! the process, while a read past the new end is an ordinary I/O error.
//!
//! A reader does not hold its file open for its whole life: a scene that inlines thousands of
//! files would run out of file descriptors (1,024 by default on many systems; a map held
//! none). At most [`OPEN_FILES`] sources keep their file open at a time; one whose file was
//! closed reopens it by path on its next read and checks it is still the same file (device,
//! inode, length, modification time), else the read is an I/O error.

use std::borrow::Cow;
use std::fs::File;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// Why a path was refused: it exists but is not a regular file. It is the source of the
/// [`Error::Io`] the functions here return (kind `InvalidInput`), so callers with their own
/// error types can tell it apart ([`not_regular_kind`]) without parsing messages.
#[derive(Debug, thiserror::Error)]
#[error("not a regular file ({kind})")]
#[non_exhaustive]
pub struct NotRegular {
    /// What it is instead: "a FIFO", "a character device", "a directory", …
    pub kind: &'static str,
}

/// The error for a path that exists but is not a regular file.
fn not_regular(path: &Path, meta: &std::fs::Metadata) -> Error {
    Error::io(path, std::io::Error::new(std::io::ErrorKind::InvalidInput, NotRegular { kind: kind_name(meta) }))
}

/// What `e` says a path is instead of a regular file, when it is that refusal.
pub fn not_regular_kind(e: &Error) -> Option<&'static str> {
    match e {
        Error::Io { source, .. } => source.get_ref().and_then(|s| s.downcast_ref::<NotRegular>()).map(|n| n.kind),
        _ => None,
    }
}

/// What kind of non-regular file `m` describes, for messages ("a FIFO", …).
pub fn kind_name(m: &std::fs::Metadata) -> &'static str {
    let t = m.file_type();
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
    "not a plain file"
}

/// Opens `path` for reading if it is a regular file (symlinks are followed), else fails with
/// an [`Error::Io`] naming the path. Never blocks: the type is checked before opening, and
/// the open itself is non-blocking (on Unix), so a FIFO swapped in between the check and the
/// open is still refused (by the second check, on the opened file) instead of hanging.
pub fn open_regular(path: &Path) -> Result<File> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !meta.is_file() {
        return Err(not_regular(path, &meta));
    }
    let mut opts = std::fs::OpenOptions::new();
    opts.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        // O_NONBLOCK makes opening a FIFO return at once; on a regular file it changes nothing.
        opts.custom_flags(libc::O_NONBLOCK);
    }
    let file = opts.open(path).map_err(|e| Error::io(path, e))?;
    let meta = file.metadata().map_err(|e| Error::io(path, e))?;
    if !meta.is_file() {
        return Err(not_regular(path, &meta));
    }
    Ok(file)
}

/// Reads the regular file at `path` whole, refusing files of more than `max_bytes` bytes
/// ([`Error::LimitExceeded`]) and never reading more than the size it had when opened (a file
/// that grows while it is read is an I/O error, not an endless read).
pub fn read_regular(path: &Path, max_bytes: u64) -> Result<Vec<u8>> {
    read_regular_with_capacity(path, max_bytes, 0)
}

/// [`read_regular`] into a buffer of at least `min_capacity` bytes.
pub(crate) fn read_regular_with_capacity(path: &Path, max_bytes: u64, min_capacity: usize) -> Result<Vec<u8>> {
    let mut file = PieceReader::open(path, max_bytes)?;
    let len = usize::try_from(file.len()).map_err(|_| Error::LimitExceeded { what: "file size", value: file.len(), limit: usize::MAX as u64 })?;
    let mut data = Vec::with_capacity(len.max(min_capacity));
    file.read_more(&mut data, usize::MAX)?;
    Ok(data)
}

/// Bytes per positioned read when [`PieceReader`] reads on every thread.
const READ_PIECE: usize = 1 << 20;

/// A regular file ([`open_regular`]) read from the start in pieces of the caller's choice,
/// never past the size it had when opened: a file that grows or shrinks meanwhile is an I/O
/// error naming the path.
///
/// A large piece is read on every thread (positioned reads of [`READ_PIECE`] bytes into
/// disjoint parts of the buffer): the copy from the page cache and the first touch of the
/// buffer's fresh pages, which in a virtual machine cost as much as the copy, are shared by
/// the threads instead of holding up the start of every tool on one. (`sct-build-tree` on
/// 8.3 M samples, a 200 MB file, spent its first 0.22 s reading on one thread.)
#[derive(Debug)]
pub struct PieceReader {
    path: PathBuf,
    file: File,
    /// Its size when opened.
    len: u64,
    /// Bytes read so far.
    read: u64,
}

impl PieceReader {
    /// Opens the regular file at `path`, refusing one of more than `max_bytes` bytes
    /// ([`Error::LimitExceeded`]).
    pub fn open(path: &Path, max_bytes: u64) -> Result<Self> {
        let file = open_regular(path)?;
        let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
        crate::Limits::check("file size", len, max_bytes)?;
        Ok(PieceReader { path: path.to_path_buf(), file, len, read: 0 })
    }

    /// The file's size when it was opened.
    pub fn len(&self) -> u64 {
        self.len
    }

    /// Whether the file was empty when opened.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Appends the next `n` bytes (or all that are left) to `buf`; whether any are left. On
    /// an error `buf` is left as it was.
    pub fn read_more(&mut self, buf: &mut Vec<u8>, n: usize) -> Result<bool> {
        let want = usize::try_from(self.len - self.read).unwrap_or(usize::MAX).min(n);
        let start = buf.len();
        if let Err(e) = self.read_at(buf, want) {
            buf.truncate(start);
            return Err(if e.kind() == std::io::ErrorKind::UnexpectedEof { self.changed(false) } else { Error::io(&self.path, e) });
        }
        self.read += want as u64;
        // One byte past the size tells a file that grew (without reading the growth).
        if self.read == self.len {
            match read_piece(&self.file, &mut [0u8], self.len) {
                Ok(()) => {
                    buf.truncate(start);
                    return Err(self.changed(true));
                }
                Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {}
                Err(e) => return Err(Error::io(&self.path, e)),
            }
        }
        Ok(self.read < self.len)
    }

    /// Appends the `want` bytes at the current offset to `buf`, on every thread when they
    /// make several pieces. The new bytes are zeroed first (on every thread: the zeroing is
    /// what faults the buffer's new pages in), then read over.
    fn read_at(&self, buf: &mut Vec<u8>, want: usize) -> std::io::Result<()> {
        use rayon::prelude::*;
        let start = buf.len();
        // One thread where a read moves the file's cursor (see `read_piece`).
        if want < 2 * READ_PIECE || !cfg!(any(unix, windows)) {
            buf.resize(start + want, 0);
            return read_piece(&self.file, &mut buf[start..], self.read);
        }
        buf.par_extend(rayon::iter::repeat_n(0u8, want));
        buf[start..]
            .par_chunks_mut(READ_PIECE)
            .enumerate()
            .try_for_each(|(k, piece)| read_piece(&self.file, piece, self.read + (k * READ_PIECE) as u64))
    }

    /// The error for a file whose size changed while it was read.
    fn changed(&self, grew: bool) -> Error {
        let message = format!("the file changed size while it was read ({} bytes when opened, {}{} read)", self.len, self.read, if grew { "+" } else { "" });
        Error::io(&self.path, std::io::Error::other(message))
    }
}

/// Bytes hashed or checksummed per read when a [`Source`] streams a range.
const STREAM_PIECE: u64 = 1 << 20;

/// Largest per-thread read buffer [`Source::read_with`] keeps between reads (the writer's
/// blocks are far smaller: 16,384 raw nodes take 640 KiB).
const SCRATCH_KEEP: usize = 16 << 20;

/// The bytes of an SCT file: in memory, or a regular file read on demand.
///
/// Reads are bounds-checked against the length the file had when opened; a file that shrinks
/// afterwards makes later reads fail with an I/O error naming the path.
#[derive(Debug)]
pub(crate) enum Source<'a> {
    /// Bytes held in memory.
    Bytes(Cow<'a, [u8]>),
    /// A regular file, read with positioned reads (safe from several threads at once).
    File {
        /// Its length when opened.
        len: u64,
        /// Its path, for errors and for reopening.
        path: PathBuf,
        /// What identifies the file opened, checked when it is reopened.
        ident: Ident,
        /// Key of this source in the table of open files.
        key: u64,
    },
}

/// Most sources whose files are open at once (see the module docs).
pub(crate) const OPEN_FILES: usize = 64;

/// What identifies a file: a reopened path must still name the same one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Ident {
    len: u64,
    modified: Option<std::time::SystemTime>,
    #[cfg(unix)]
    dev_ino: (u64, u64),
}

impl Ident {
    fn of(m: &std::fs::Metadata) -> Self {
        Ident {
            len: m.len(),
            modified: m.modified().ok(),
            #[cfg(unix)]
            dev_ino: {
                use std::os::unix::fs::MetadataExt;
                (m.dev(), m.ino())
            },
        }
    }
}

/// The open files of the sources that used them last, most recent first.
static OPEN: std::sync::Mutex<Vec<(u64, std::sync::Arc<File>)>> = std::sync::Mutex::new(Vec::new());
/// Keys of sources.
static NEXT_KEY: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// Files in the table, most recent first (a poisoned lock only means a panic elsewhere; the
/// table itself is always consistent).
fn open_table() -> std::sync::MutexGuard<'static, Vec<(u64, std::sync::Arc<File>)>> {
    OPEN.lock().unwrap_or_else(|e| e.into_inner())
}

/// Puts `file` at the front of the table as source `key`'s, closing the least recently used
/// beyond [`OPEN_FILES`] (each closes once its last in-flight read ends).
fn remember(key: u64, file: std::sync::Arc<File>) {
    let mut t = open_table();
    t.retain(|(k, _)| *k != key);
    t.insert(0, (key, file));
    t.truncate(OPEN_FILES);
}

/// Forgets source `key`'s file (closing it once no read uses it).
fn forget(key: u64) {
    open_table().retain(|(k, _)| *k != key);
}

#[cfg(test)]
thread_local! {
    /// Files this thread opened as a [`Source`] (tests count how often a target is read).
    pub(crate) static OPENS: std::cell::Cell<u64> = const { std::cell::Cell::new(0) };
}

impl Source<'static> {
    /// Opens the regular file at `path` ([`open_regular`]).
    pub fn open(path: &Path) -> Result<Self> {
        #[cfg(test)]
        OPENS.with(|c| c.set(c.get() + 1));
        let file = open_regular(path)?;
        let ident = Ident::of(&file.metadata().map_err(|e| Error::io(path, e))?);
        let key = NEXT_KEY.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        remember(key, std::sync::Arc::new(file));
        Ok(Source::File { len: ident.len, path: path.to_path_buf(), ident, key })
    }
}

impl Drop for Source<'_> {
    fn drop(&mut self) {
        if let Source::File { key, .. } = self {
            forget(*key);
        }
    }
}

/// The open file of source `key` (at `path`, identified by `ident`): from the table, or
/// reopened and checked to be the same file.
fn file_of(key: u64, path: &Path, ident: &Ident) -> Result<std::sync::Arc<File>> {
    {
        let mut t = open_table();
        if let Some(i) = t.iter().position(|(k, _)| *k == key) {
            let entry = t.remove(i);
            let f = entry.1.clone();
            t.insert(0, entry);
            return Ok(f);
        }
    }
    let file = open_regular(path)?;
    let now = Ident::of(&file.metadata().map_err(|e| Error::io(path, e))?);
    if now != *ident {
        return Err(Error::io(path, std::io::Error::other("the file was replaced or changed since it was opened")));
    }
    let file = std::sync::Arc::new(file);
    remember(key, file.clone());
    Ok(file)
}

impl Source<'_> {
    /// Length of the file (when opened).
    pub fn len(&self) -> u64 {
        match self {
            Source::Bytes(b) => b.len() as u64,
            Source::File { len, .. } => *len,
        }
    }

    /// `len` bytes at `offset`: borrowed from memory, or read from the file. A range past
    /// the end is [`Error::Malformed`] naming `what`; a failed read is [`Error::Io`].
    pub fn read(&self, offset: u64, len: u64, what: &str) -> Result<Cow<'_, [u8]>> {
        let end = offset.checked_add(len).filter(|&e| e <= self.len()).ok_or_else(|| {
            Error::malformed(offset, format!("{what} ({len} bytes at {offset}) extends past the end of the file ({} bytes)", self.len()))
        })?;
        match self {
            Source::Bytes(b) => Ok(Cow::Borrowed(&b[offset as usize..end as usize])),
            Source::File { path, ident, key, .. } => {
                // The range lies inside the file as opened, so this allocation is bounded by
                // the file's size.
                let n = usize::try_from(len).map_err(|_| Error::LimitExceeded { what: "read size", value: len, limit: usize::MAX as u64 })?;
                let file = file_of(*key, path, ident)?;
                let mut buf = vec![0u8; n];
                read_exact_at(&file, &mut buf, offset).map_err(|e| Error::io(path, e))?;
                Ok(Cow::Owned(buf))
            }
        }
    }

    /// Calls `f` with the `len` bytes at `offset` ([`Source::read`]), read from a file into a
    /// buffer this thread reuses: blocks are read by the thousand, and a fresh buffer for each
    /// costs its page faults (about 5 % of a raw-profile validation). A buffer grown past
    /// [`SCRATCH_KEEP`] is released after use, so a huge block does not stay allocated.
    pub fn read_with<R>(&self, offset: u64, len: u64, what: &str, f: impl FnOnce(&[u8]) -> R) -> Result<R> {
        let Source::File { path, ident, key, .. } = self else {
            return Ok(f(&self.read(offset, len, what)?));
        };
        let file = file_of(*key, path, ident)?;
        offset.checked_add(len).filter(|&e| e <= self.len()).ok_or_else(|| {
            Error::malformed(offset, format!("{what} ({len} bytes at {offset}) extends past the end of the file ({} bytes)", self.len()))
        })?;
        let n = usize::try_from(len).map_err(|_| Error::LimitExceeded { what: "read size", value: len, limit: usize::MAX as u64 })?;
        thread_local! {
            static SCRATCH: std::cell::RefCell<Vec<u8>> = const { std::cell::RefCell::new(Vec::new()) };
        }
        SCRATCH.with(|cell| {
            let mut buf = cell.take();
            if buf.len() < n {
                buf.resize(n, 0);
            }
            let r = read_exact_at(&file, &mut buf[..n], offset).map_err(|e| Error::io(path, e)).map(|()| f(&buf[..n]));
            if buf.len() <= SCRATCH_KEEP {
                cell.replace(buf);
            }
            r
        })
    }

    /// Calls `f` with consecutive pieces of `len` bytes at `offset`, a piece of at most
    /// [`STREAM_PIECE`] bytes at a time, so that hashing a range needs no buffer of its size.
    pub fn for_each_piece(&self, offset: u64, len: u64, what: &str, mut f: impl FnMut(&[u8])) -> Result<()> {
        if let Source::Bytes(_) = self {
            f(&self.read(offset, len, what)?);
            return Ok(());
        }
        // Bounds first, so a range past the end fails before anything is read.
        offset.checked_add(len).filter(|&e| e <= self.len()).ok_or_else(|| {
            Error::malformed(offset, format!("{what} ({len} bytes at {offset}) extends past the end of the file ({} bytes)", self.len()))
        })?;
        let mut at = 0;
        while at < len {
            let n = (len - at).min(STREAM_PIECE);
            f(&self.read(offset + at, n, what)?);
            at += n;
        }
        Ok(())
    }

    /// CRC-32 of `len` bytes at `offset`, streamed.
    pub fn crc32(&self, offset: u64, len: u64, what: &str) -> Result<u32> {
        if let Source::Bytes(_) = self {
            return Ok(crate::container::crc32(&self.read(offset, len, what)?));
        }
        let mut h = crc32fast::Hasher::new();
        self.for_each_piece(offset, len, what, |p| h.update(p))?;
        Ok(h.finalize())
    }

    /// BLAKE3 of the whole file, streamed.
    pub fn blake3(&self) -> Result<[u8; 32]> {
        let mut h = blake3::Hasher::new();
        self.for_each_piece(0, self.len(), "file", |p| {
            h.update(p);
        })?;
        Ok(*h.finalize().as_bytes())
    }
}

#[cfg(unix)]
fn read_exact_at(file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    use std::os::unix::fs::FileExt;
    file.read_exact_at(buf, offset)
}

#[cfg(windows)]
fn read_exact_at(file: &File, mut buf: &mut [u8], mut offset: u64) -> std::io::Result<()> {
    use std::os::windows::fs::FileExt;
    while !buf.is_empty() {
        match file.seek_read(buf, offset) {
            Ok(0) => return Err(std::io::ErrorKind::UnexpectedEof.into()),
            Ok(n) => {
                buf = &mut buf[n..];
                offset += n as u64;
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

#[cfg(not(any(unix, windows)))]
fn read_exact_at(_file: &File, _buf: &mut [u8], _offset: u64) -> std::io::Result<()> {
    Err(std::io::ErrorKind::Unsupported.into())
}

/// `buf.len()` bytes of a file at `offset` for [`PieceReader`]: positioned reads where the
/// platform has them (safe from several threads), else a seek and a read (the reader owns
/// its file, and reads it on one thread there).
#[cfg(any(unix, windows))]
fn read_piece(file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    read_exact_at(file, buf, offset)
}

#[cfg(not(any(unix, windows)))]
fn read_piece(mut file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    use std::io::{Read, Seek, SeekFrom};
    file.seek(SeekFrom::Start(offset))?;
    file.read_exact(buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A file read in pieces gives its bytes, says when none are left, and never reads past
    /// the size it had when opened: small pieces (one read) and large ones (read on every
    /// thread), whole or in pieces that do not fall on the reads' boundaries.
    #[test]
    fn pieces_read_the_file_as_it_was_opened() {
        let dir = tempfile::tempdir().expect("tempdir");
        let f = dir.path().join("a.obj");
        std::fs::write(&f, b"0123456789").expect("write");
        let mut r = PieceReader::open(&f, 10).expect("open");
        let mut buf = Vec::new();
        assert!(r.read_more(&mut buf, 4).expect("read"));
        assert!(r.read_more(&mut buf, 4).expect("read"));
        assert!(!r.read_more(&mut buf, 4).expect("read"));
        assert_eq!(buf, b"0123456789");

        let big: Vec<u8> = (0..5 * READ_PIECE as u64 + 12_345).map(|i| (i.wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 56) as u8).collect();
        let g = dir.path().join("big");
        std::fs::write(&g, &big).expect("write");
        assert_eq!(read_regular(&g, u64::MAX).expect("read"), big);
        for piece in [1_000, 2 * READ_PIECE + 7, 3 * READ_PIECE - 1] {
            let mut r = PieceReader::open(&g, u64::MAX).expect("open");
            let mut buf = b"head".to_vec();
            while r.read_more(&mut buf, piece).expect("read") {}
            assert_eq!(&buf[4..], &big[..], "pieces of {piece}");
        }

        for (path, piece) in [(&f, 4), (&g, 2 * READ_PIECE)] {
            let len = std::fs::metadata(path).expect("size").len();
            // Grown after opening: an I/O error, not the extra bytes.
            let mut r = PieceReader::open(path, u64::MAX).expect("open");
            assert!(r.read_more(&mut Vec::new(), piece).expect("read"));
            std::fs::OpenOptions::new().append(true).open(path).and_then(|mut w| std::io::Write::write_all(&mut w, b"abc")).expect("append");
            let mut buf = b"kept".to_vec();
            let e = r.read_more(&mut buf, usize::MAX).expect_err("grew");
            assert!(e.to_string().contains("changed size") && e.to_string().contains(&format!("{len} bytes when opened")), "{e}");
            assert_eq!(buf, b"kept");
            // Shrunk after opening: an error, and the buffer as it was.
            let mut r = PieceReader::open(path, u64::MAX).expect("open");
            std::fs::write(path, b"01").expect("truncate");
            let e = r.read_more(&mut buf, usize::MAX).expect_err("shrank");
            assert!(e.to_string().contains("changed size"), "{e}");
            assert_eq!(buf, b"kept");
        }
    }

    #[test]
    fn regular_files_read_with_a_bound() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("a");
        std::fs::write(&p, b"hello").expect("write");
        assert_eq!(read_regular(&p, 5).expect("read"), b"hello");
        assert!(matches!(read_regular(&p, 4), Err(Error::LimitExceeded { what: "file size", value: 5, limit: 4 })));
        // A directory is refused, with its path.
        match open_regular(dir.path()) {
            Err(e @ Error::Io { .. }) => {
                assert_eq!(not_regular_kind(&e), Some("a directory"));
                let Error::Io { path: Some(q), source } = e else { panic!("no path") };
                assert_eq!(q, dir.path());
                assert!(source.to_string().contains("directory"), "{source}");
            }
            other => panic!("{other:?}"),
        }
        // A FIFO (also through a symlink) is refused at once; a device by type, unread.
        #[cfg(unix)]
        {
            let fifo = dir.path().join("pipe");
            assert!(std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo").success());
            let link = dir.path().join("link");
            std::os::unix::fs::symlink(&fifo, &link).expect("symlink");
            for p in [&fifo, &link] {
                assert_eq!(read_regular(p, 1 << 20).map_err(|e| not_regular_kind(&e)).err(), Some(Some("a FIFO")));
            }
            assert_eq!(read_regular(Path::new("/dev/zero"), 1 << 20).map_err(|e| not_regular_kind(&e)).err(), Some(Some("a character device")));
        }
        // Other errors are not refusals by type.
        assert_eq!(not_regular_kind(&read_regular(&p, 4).expect_err("too big")), None);
        assert_eq!(not_regular_kind(&read_regular(&dir.path().join("none"), 4).expect_err("missing")), None);
    }

    /// More sources than may keep their files open: each still reads (reopening its file),
    /// and one whose file was replaced since it was opened fails instead of reading another.
    #[test]
    fn sources_share_a_bounded_set_of_open_files() {
        let dir = tempfile::tempdir().expect("tempdir");
        let n = OPEN_FILES * 3;
        let sources: Vec<(PathBuf, Source)> = (0..n)
            .map(|i| {
                let p = dir.path().join(format!("f{i}"));
                std::fs::write(&p, vec![i as u8; 100]).expect("write");
                let s = Source::open(&p).expect("open");
                (p, s)
            })
            .collect();
        for round in 0..2 {
            for (i, (_, s)) in sources.iter().enumerate() {
                assert_eq!(s.read(10, 5, "x").expect("read")[..], [i as u8; 5][..], "round {round}");
            }
        }
        // Replaced by rename (a new file at the path): refused once it must be reopened.
        let (p, s) = &sources[0];
        let tmp = dir.path().join("new");
        std::fs::write(&tmp, vec![0xAA; 100]).expect("write");
        std::fs::rename(&tmp, p).expect("rename");
        for (_, other) in &sources[1..=OPEN_FILES] {
            other.read(0, 1, "x").expect("read");
        }
        assert!(matches!(s.read(0, 1, "x"), Err(Error::Io { .. })));
    }

    /// A source over a file that shrinks after opening fails with an I/O error on the lost
    /// bytes (a mapped file would raise SIGBUS there).
    #[test]
    fn shrunk_file_is_an_io_error() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("a");
        std::fs::write(&p, vec![7u8; 10_000]).expect("write");
        let s = Source::open(&p).expect("open");
        assert_eq!(s.read(9_000, 1_000, "x").expect("read")[..], [7u8; 1000][..]);
        std::fs::OpenOptions::new().write(true).open(&p).expect("open rw").set_len(100).expect("truncate");
        assert!(matches!(s.read(9_000, 1_000, "x"), Err(Error::Io { .. })));
        assert!(matches!(s.crc32(0, 10_000, "x"), Err(Error::Io { .. })));
        assert!(matches!(s.read(9_000, 2_000, "x"), Err(Error::Malformed { .. })), "past the length at open");
    }
}
