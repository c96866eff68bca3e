//! Atomic output: write to a temporary file beside the target, then rename, so a reader
//! (or a crash) never sees a partial file.

use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

mod writeback;

/// Calls `fill` with a buffered writer on a temporary file next to `path`, then renames it
/// over `path`. On any error the temporary file is removed and `path` is untouched.
///
/// What `path` is decides how it is written (symlinks followed):
/// - absent, or a regular file: written atomically (temporary file beside it, renamed over
///   it);
/// - a symlink to a regular file: the link's final target is written atomically (the
///   temporary file beside the target), so the link itself survives;
/// - a character device or a FIFO (`/dev/null`, `/dev/stdout`, a named pipe, also through
///   a symlink): written through directly, neither replaced nor synced — a device node must
///   never become a regular file. A writer that seeks back (the SCT writer patches its
///   header) fails on a FIFO with the OS's "illegal seek";
/// - a directory, a block device, a socket or a dangling symlink: refused
///   ([`Error::Misuse`]), nothing written.
///
/// The temporary file is `.NAME.PID.HOSTRAND.tmp` (HOSTRAND: 16 hex digits, the first 8
/// naming this host and PID namespace ([`host_tag`]), the last 8 random), created
/// exclusively: two writers never share one, even with equal PIDs (containers on shared
/// storage). While it exists it is listed in this process's registry
/// ([`remove_pending_temp_files`], for a signal handler). Batch mode removes stale ones by
/// that pattern, at once when the host tag is this host's and the PID is gone.
pub fn write_atomic<T>(path: &Path, fill: impl FnOnce(&mut BufWriter<File>) -> Result<T>) -> Result<T> {
    write_atomic_with(path, fill)
}

/// [`write_atomic`] for a `fill` that fails with its caller's error type (a writer fed by a
/// sampler fails with the sampler's errors too), into which this function's own I/O errors
/// convert.
pub fn write_atomic_with<T, E: From<Error>>(path: &Path, fill: impl FnOnce(&mut BufWriter<File>) -> std::result::Result<T, E>) -> std::result::Result<T, E> {
    let target = match output_kind(path)? {
        Output::Direct => return write_direct(path, fill),
        Output::Atomic(target) => target,
    };
    let (file, tmp) = create_temp(&target)?;
    let result = (|| -> std::result::Result<T, E> {
        // A second handle for the thread that writes the data back early.
        let shared = file.try_clone();
        let mut w = BufWriter::with_capacity(1 << 20, file);
        let (value, early) = writeback::with_early_writeback(shared, || -> std::result::Result<T, E> {
            let value = fill(&mut w)?;
            w.flush().map_err(|e| Error::io(&tmp, e))?;
            Ok(value)
        });
        let value = value?;
        early.map_err(|e| Error::io(&tmp, e))?;
        let file = w.into_inner().map_err(|e| Error::io(&tmp, e.into_error()))?;
        file.sync_all().map_err(|e| Error::io(&tmp, e))?;
        std::fs::rename(&tmp, &target).map_err(|e| Error::io(&target, e))?;
        Ok(value)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    unregister(&tmp);
    result
}

/// How [`write_atomic`] writes a path.
enum Output {
    /// Temporary file and rename onto this path (the path itself, or a symlink's target).
    Atomic(PathBuf),
    /// Straight through the existing node.
    Direct,
}

fn output_kind(path: &Path) -> Result<Output> {
    let refuse = |what: &str| Err(Error::Misuse(format!("{}: is {what}; not written (give a regular file as output)", path.display())));
    // `out/` names a directory whatever exists: never write `out` (or a temporary file
    // beside it) instead.
    if path.as_os_str().as_encoded_bytes().ends_with(b"/") || path.file_name().is_none() {
        return Err(Error::Misuse(format!("{}: names a directory; give the output file's name (e.g. {})", path.display(), path.join("model.sct").display())));
    }
    let link = match std::fs::symlink_metadata(path) {
        Ok(m) => m,
        // A missing file, or a parent that is not a directory: creating the temporary file
        // beside it reports which.
        Err(e) if matches!(e.kind(), std::io::ErrorKind::NotFound | std::io::ErrorKind::NotADirectory) => return Ok(Output::Atomic(path.to_path_buf())),
        Err(e) => return Err(Error::io(path, e)),
    };
    let meta = if link.file_type().is_symlink() {
        match std::fs::metadata(path) {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return refuse("a dangling symlink"),
            Err(e) => return Err(Error::io(path, e)),
        }
    } else {
        link.clone()
    };
    let t = meta.file_type();
    if t.is_file() {
        if link.file_type().is_symlink() {
            // Replace the file the link leads to, not the link.
            return std::fs::canonicalize(path).map(Output::Atomic).map_err(|e| Error::io(path, e));
        }
        return Ok(Output::Atomic(path.to_path_buf()));
    }
    if t.is_dir() {
        return refuse("a directory");
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_char_device() || t.is_fifo() {
            return Ok(Output::Direct);
        }
        if t.is_block_device() {
            return refuse("a block device");
        }
        if t.is_socket() {
            return refuse("a socket");
        }
    }
    refuse("not a regular file")
}

/// Writes through an existing device or FIFO: no temporary file, no rename, no sync (a
/// device may refuse fsync; there is nothing durable to sync).
fn write_direct<T, E: From<Error>>(path: &Path, fill: impl FnOnce(&mut BufWriter<File>) -> std::result::Result<T, E>) -> std::result::Result<T, E> {
    let file = std::fs::OpenOptions::new().write(true).open(path).map_err(|e| Error::io(path, e))?;
    let mut w = BufWriter::with_capacity(1 << 20, file);
    let value = fill(&mut w)?;
    w.flush().map_err(|e| Error::io(path, e))?;
    Ok(value)
}

/// Creates `.NAME.PID.RANDOM.tmp` beside `target`, exclusively (`create_new`): an existing
/// file of that name (another writer's) is never opened, a new name is drawn instead.
fn create_temp(target: &Path) -> Result<(File, PathBuf)> {
    let dir = target.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = target.file_name().ok_or_else(|| Error::Misuse(format!("{} is not a file path", target.display())))?;
    let mut last = None;
    for _ in 0..16 {
        let mut tmp_name = std::ffi::OsString::from(".");
        tmp_name.push(name);
        tmp_name.push(format!(".{}.{}{:08x}.tmp", std::process::id(), host_tag(), random_u64() as u32));
        let tmp = dir.join(tmp_name);
        // Created and registered under the registry's lock: a signal handler emptying the
        // registry sees every temporary file that exists, and none is created after it.
        let mut pending = lock_pending();
        if pending.closed {
            return Err(Error::io(target, std::io::Error::new(std::io::ErrorKind::Interrupted, "interrupted; not written")));
        }
        match std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp) {
            Ok(f) => {
                pending.paths.push(tmp.clone());
                return Ok((f, tmp));
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => last = Some(Error::io(&tmp, e)),
            // Name the directory and the output, not the hidden temporary file.
            Err(e) => return Err(output_dir_error(dir, target, e)),
        }
    }
    Err(last.unwrap_or_else(|| Error::Misuse("no temporary file name could be created".into())))
}

/// Temporary files this process is writing now (see [`remove_pending_temp_files`]).
struct Pending {
    paths: Vec<PathBuf>,
    /// Set by [`remove_pending_temp_files`]: no temporary file is created after it.
    closed: bool,
}

static PENDING: std::sync::Mutex<Pending> = std::sync::Mutex::new(Pending { paths: Vec::new(), closed: false });

fn lock_pending() -> std::sync::MutexGuard<'static, Pending> {
    PENDING.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

fn unregister(tmp: &Path) {
    lock_pending().paths.retain(|x| x != tmp);
}

/// Removes every temporary file this process is writing now, refuses to create new ones
/// from then on, and returns how many it removed: for a SIGINT/SIGTERM handler, so an
/// interrupted run leaves nothing behind. Writers whose files vanish fail; the process is
/// expected to exit.
pub fn remove_pending_temp_files() -> usize {
    let paths = {
        let mut p = lock_pending();
        p.closed = true;
        std::mem::take(&mut p.paths)
    };
    paths.iter().filter(|p| std::fs::remove_file(p).is_ok()).count()
}

/// The temporary files this process is writing now.
pub fn pending_temp_files() -> Vec<PathBuf> {
    lock_pending().paths.clone()
}

/// 8 hex digits naming this host and PID namespace: temporary files whose name carries it
/// were written by a process whose PID can be checked here (see [`process_is_gone`]).
/// Hash of the host name and, on Linux, the PID namespace's inode; "00000000" when neither
/// is known.
pub fn host_tag() -> &'static str {
    static TAG: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    TAG.get_or_init(|| {
        let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
            .or_else(|_| std::fs::read_to_string("/etc/hostname"))
            .or_else(|_| std::env::var("HOSTNAME").map_err(std::io::Error::other))
            .unwrap_or_default();
        let ns = std::fs::read_link("/proc/self/ns/pid").map(|p| p.display().to_string()).unwrap_or_default();
        if host.trim().is_empty() && ns.is_empty() {
            return "00000000".into();
        }
        let h = blake3::hash(format!("{}\0{ns}", host.trim()).as_bytes());
        h.to_hex()[..8].to_string()
    })
}

/// Whether the temporary file named `.NAME.PID.HOSTRAND.tmp` was written on this host (its
/// host tag is [`host_tag`]) by a process that no longer runs. `false` whenever it cannot
/// tell (another host, an older name without a host tag, no `/proc`).
pub fn process_is_gone(pid: u32, hostrand: &str) -> bool {
    let tag = host_tag();
    if tag == "00000000" || hostrand.len() != 16 || &hostrand[..8] != tag || !Path::new("/proc/self").exists() {
        return false;
    }
    pid != std::process::id() && !Path::new("/proc").join(pid.to_string()).exists()
}

/// Why a temporary file could not be created in `dir`, for the user: the directory is
/// missing, is not a directory, or is not writable.
fn output_dir_error(dir: &Path, target: &Path, e: std::io::Error) -> Error {
    let why = match std::fs::metadata(dir) {
        Err(m) if m.kind() == std::io::ErrorKind::NotFound => format!("its directory {} does not exist", dir.display()),
        Ok(m) if !m.is_dir() => format!("{} is not a directory", dir.display()),
        _ => format!("cannot create a file in {}: {e}", dir.display()),
    };
    Error::io(target, std::io::Error::new(e.kind(), why))
}

/// 64 unpredictable bits without a dependency: std's `RandomState` keys come from the OS's
/// random source (per process and thread), mixed with a counter and the clock so that
/// successive calls differ too.
fn random_u64() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u64(COUNTER.fetch_add(1, Ordering::Relaxed));
    h.write_u128(std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos()));
    h.write_u32(std::process::id());
    h.finish()
}

/// BLAKE3 hash of a file's bytes, lowercase hex (streams; memory stays small). Only a
/// regular file is hashed, opened through [`crate::fsio::open_regular`]: a FIFO would block
/// `open` and a device never ends, and a type check before a plain `open` would still block
/// on a FIFO swapped in between. The file is hashed up to the size it had when opened; one
/// that changes size meanwhile is an I/O error, not a hash of neither version.
pub fn hash_file(path: &Path) -> Result<String> {
    let file = crate::fsio::open_regular(path)?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let mut h = blake3::Hasher::new();
    // One byte past the size, so that a file that grew is told apart without hashing more.
    let read = std::io::copy(&mut file.take(len.saturating_add(1)), &mut h).map_err(|e| Error::io(path, e))?;
    if read != len {
        let e = std::io::Error::other(format!("the file changed size while it was hashed ({len} bytes when opened, {read} read)"));
        return Err(Error::io(path, e));
    }
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
    use super::*;

    fn put(path: &Path, bytes: &[u8]) -> Result<()> {
        write_atomic(path, |w| w.write_all(bytes).map_err(|e| Error::io(path, e)))
    }

    /// Two writers of one output at once (equal PIDs, as in two containers on shared
    /// storage, look alike here: one process): each has its own temporary file, so the
    /// published file is one writer's bytes whole, never a mix. The barriers force the
    /// interleaving that corrupted it when both opened `.NAME.PID.tmp`: both create, the
    /// first writes a long file, the second a short one over it, then both publish.
    #[test]
    fn concurrent_writers_never_publish_a_mix() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("out.sct");
        let long = vec![b'a'; 1 << 20];
        let short = vec![b'b'; 1 << 19];
        let barrier = std::sync::Barrier::new(2);
        std::thread::scope(|s| {
            for (i, bytes) in [&long, &short].into_iter().enumerate() {
                let (path, barrier) = (&path, &barrier);
                s.spawn(move || {
                    let r = write_atomic(path, |w| {
                        barrier.wait();
                        if i == 1 {
                            barrier.wait();
                        }
                        w.write_all(bytes).and_then(|_| w.flush()).map_err(|e| Error::io(path, e))?;
                        if i == 0 {
                            barrier.wait();
                        }
                        barrier.wait();
                        Ok(())
                    });
                    r.expect("each writer succeeds");
                });
            }
        });
        let got = std::fs::read(&path).expect("read");
        assert!(got == long || got == short, "published a mix of two writers ({} bytes)", got.len());
        let left: Vec<_> = std::fs::read_dir(dir.path()).expect("dir").flatten().map(|e| e.file_name()).collect();
        assert_eq!(left.len(), 1, "temporary files left: {left:?}");
    }

    /// The temporary name keeps the `.NAME.PID.` prefix and `.tmp` suffix batch cleanup
    /// looks for, with a random part between.
    #[test]
    fn temp_names_are_distinct_and_recognisable() {
        let dir = tempfile::tempdir().expect("tempdir");
        let target = dir.path().join("m.sct");
        let (_a, ta) = create_temp(&target).expect("temp");
        let (_b, tb) = create_temp(&target).expect("temp");
        assert_ne!(ta, tb);
        let n = ta.file_name().and_then(|n| n.to_str()).expect("utf-8").to_string();
        let rest = n.strip_prefix(&format!(".m.sct.{}.", std::process::id())).and_then(|r| r.strip_suffix(".tmp")).expect("pattern");
        assert!(rest.len() == 16 && rest.bytes().all(|b| b.is_ascii_hexdigit()), "{n}");
    }

    /// A symlink to a regular file: the target gets the new bytes, the link stays a link.
    #[cfg(unix)]
    #[test]
    fn symlink_to_a_regular_file_survives() {
        let dir = tempfile::tempdir().expect("tempdir");
        let real = dir.path().join("real.sct");
        let link = dir.path().join("link.sct");
        std::fs::write(&real, b"old").expect("write");
        std::os::unix::fs::symlink(&real, &link).expect("symlink");
        put(&link, b"new").expect("write through link");
        assert!(std::fs::symlink_metadata(&link).expect("lstat").file_type().is_symlink());
        assert_eq!(std::fs::read(&real).expect("read"), b"new");
    }

    /// A FIFO is written through, not replaced by a regular file: the reader gets the
    /// bytes and the path is still a FIFO.
    #[cfg(unix)]
    #[test]
    fn fifo_is_written_through_not_replaced() {
        use std::io::Read;
        use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
        let dir = tempfile::tempdir().expect("tempdir");
        let fifo = dir.path().join("out.sct");
        assert!(std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo").success());
        // Non-blocking read end first, so the writer's open finds a reader and never waits.
        let mut reader = std::fs::OpenOptions::new().read(true).custom_flags(libc_o_nonblock()).open(&fifo).expect("open read end");
        put(&fifo, b"through the pipe").expect("write");
        assert!(std::fs::symlink_metadata(&fifo).expect("lstat").file_type().is_fifo(), "the FIFO was replaced");
        let mut got = Vec::new();
        let _ = reader.read_to_end(&mut got);
        assert_eq!(got, b"through the pipe");
    }

    /// O_NONBLOCK on Linux (the tests' platform; sct-format has no libc dependency).
    #[cfg(unix)]
    fn libc_o_nonblock() -> i32 {
        if cfg!(any(target_os = "macos", target_os = "ios", target_os = "freebsd", target_os = "openbsd", target_os = "netbsd")) {
            0x0004
        } else {
            0o4000
        }
    }

    /// A character device (`/dev/null`) is written through and stays a device; a directory
    /// is refused.
    #[cfg(unix)]
    #[test]
    fn device_is_written_through_and_directory_refused() {
        use std::os::unix::fs::FileTypeExt;
        let null = Path::new("/dev/null");
        put(null, b"discarded").expect("write to /dev/null");
        assert!(std::fs::symlink_metadata(null).expect("lstat").file_type().is_char_device());
        let dir = tempfile::tempdir().expect("tempdir");
        assert!(matches!(put(dir.path(), b"x"), Err(Error::Misuse(_))));
    }

    /// The parallel hash is BLAKE3's, around every split size.
    #[test]
    fn hash_bytes_is_blake3() {
        let data: Vec<u8> = (0..5_300_000u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect();
        for len in [0, 1, 1024, 1025, 1 << 20, (1 << 20) + 1, (2 << 20) + 1024, (3 << 20) + 7, 4 << 20, data.len()] {
            assert_eq!(super::hash_bytes(&data[..len]), blake3::hash(&data[..len]).to_hex().to_string(), "{len}");
        }
    }

    /// `-o out/` and `-o missing/dir/x.sct` say what is wrong with the output path: no
    /// "Not a directory" from a rename, no hidden temporary file's name.
    #[test]
    fn output_path_errors_name_the_output() {
        let dir = tempfile::tempdir().expect("tempdir");
        let slash = format!("{}/", dir.path().join("out").display());
        let e = put(Path::new(&slash), b"x").unwrap_err().to_string();
        assert!(e.contains("names a directory"), "{e}");
        assert!(!dir.path().join("out").exists(), "nothing written");
        let missing = dir.path().join("missing/dir/x.sct");
        let e = put(&missing, b"x").unwrap_err().to_string();
        assert!(e.contains("does not exist") && e.contains("x.sct") && !e.contains(".x.sct."), "{e}");
        let file = dir.path().join("file");
        put(&file, b"x").expect("write");
        let e = put(&file.join("x.sct"), b"x").unwrap_err().to_string();
        assert!(e.contains("not a directory") && !e.contains(".x.sct."), "{e}");
    }

    /// A file being written is in the registry a signal handler empties; once published
    /// (or failed) it is not.
    #[test]
    fn temporary_files_are_registered_while_written() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("r.sct");
        put(&path, b"x").expect("write");
        let seen = write_atomic(&path, |_| {
            let tmp = pending_temp_files().into_iter().find(|p| p.parent() == Some(dir.path()));
            Ok(tmp)
        })
        .expect("write");
        let tmp = seen.expect("registered while written");
        assert!(tmp.file_name().expect("name").to_string_lossy().contains(host_tag()));
        assert!(!pending_temp_files().contains(&tmp), "unregistered once published");
        assert!(!tmp.exists());
        // A PID that never ran here, with this host's tag, is gone; another host's is unknown.
        let ours = format!("{}{:08x}", host_tag(), 7);
        if Path::new("/proc/self").exists() && host_tag() != "00000000" {
            assert!(process_is_gone(u32::MAX - 1, &ours));
        }
        assert!(!process_is_gone(std::process::id(), &ours), "this process runs");
    }

    /// A FIFO (directly or through a symlink) is refused at once, not waited on, and a
    /// directory or device is refused by type; a regular file hashes as its bytes.
    #[cfg(unix)]
    #[test]
    fn hash_file_reads_only_regular_files_without_blocking() {
        let dir = tempfile::tempdir().expect("tempdir");
        let f = dir.path().join("a");
        std::fs::write(&f, b"abc").expect("write");
        assert_eq!(hash_file(&f).expect("hash"), blake3::hash(b"abc").to_hex().to_string());
        let fifo = dir.path().join("pipe");
        assert!(std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo").success());
        let link = dir.path().join("link");
        std::os::unix::fs::symlink(&fifo, &link).expect("symlink");
        for p in [fifo, link, dir.path().to_path_buf(), PathBuf::from("/dev/zero")] {
            // On a thread, so that a regression fails the test instead of hanging it.
            let (tx, rx) = std::sync::mpsc::channel();
            let q = p.clone();
            std::thread::spawn(move || tx.send(hash_file(&q).map_err(|e| e.to_string())));
            match rx.recv_timeout(std::time::Duration::from_secs(10)).expect("hash_file returned") {
                Err(e) => assert!(e.contains("not a regular file") && e.contains(&*p.to_string_lossy()), "{e}"),
                Ok(h) => panic!("{} hashed as {h}", p.display()),
            }
        }
    }
}
