//! Early write-back of a file being written: its data is flushed to the device while the
//! writer still works, so the closing `fsync` waits for the tail alone. Without it that
//! `fsync` waits for the whole file after the work is done — time no thread count shortens
//! (about a tenth of a small conversion on two cores).

use std::fs::File;
use std::sync::mpsc::{self, RecvTimeoutError};
use std::time::Duration;

/// Time between early write-backs: short against a run that writes for seconds, long
/// enough that a small file is written before the first one (none is then made).
const EVERY: Duration = Duration::from_millis(20);

/// Runs `work` (which writes a file) while another thread syncs the file's data through
/// `shared`, a second handle of it, every [`EVERY`]; returns what `work` returned and the
/// first error of those syncs. That error must fail the write: on Linux a failed write-back
/// is reported to one `fsync` only, so the closing `sync_all` could succeed over lost data.
/// Without a second handle (`shared` failed) the file is written without early syncs: the
/// closing `sync_all` does it all.
pub(super) fn with_early_writeback<T>(shared: std::io::Result<File>, work: impl FnOnce() -> T) -> (T, std::io::Result<()>) {
    let Ok(shared) = shared else {
        return (work(), Ok(()));
    };
    let (stop, stopped) = mpsc::channel::<()>();
    std::thread::scope(|s| {
        let syncer = std::thread::Builder::new().name("sct-writeback".into()).spawn_scoped(s, move || {
            while let Err(RecvTimeoutError::Timeout) = stopped.recv_timeout(EVERY) {
                shared.sync_data()?;
            }
            Ok(())
        });
        let value = work();
        drop(stop);
        let synced = match syncer {
            Ok(h) => h.join().unwrap_or_else(|_| Err(std::io::Error::other("the write-back thread panicked"))),
            // No thread to spare: the closing sync does it all.
            Err(_) => Ok(()),
        };
        (value, synced)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    /// A write that outlasts several intervals is synced early and keeps its bytes and its
    /// value; a sync that fails (a device without fsync) is returned, not dropped; a short
    /// write and one without a second handle just run.
    #[test]
    fn early_syncs_run_during_the_work_and_their_errors_are_returned() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("f");
        let mut file = File::create(&path).expect("create");
        let (value, synced) = with_early_writeback(file.try_clone(), || {
            for k in 0..6u8 {
                file.write_all(&[k; 4096]).expect("write");
                std::thread::sleep(EVERY);
            }
            7
        });
        assert_eq!((value, synced.is_ok()), (7, true));
        let bytes = std::fs::read(&path).expect("read");
        assert_eq!(bytes.len(), 6 * 4096);
        assert!(bytes.chunks(4096).enumerate().all(|(k, c)| c.iter().all(|&b| usize::from(b) == k)));

        // fsync of a character device fails (EINVAL): the work still ends, with the error.
        let null = std::fs::OpenOptions::new().write(true).open("/dev/null").expect("open /dev/null");
        let (value, synced) = with_early_writeback(Ok(null), || {
            std::thread::sleep(3 * EVERY);
            "done"
        });
        assert_eq!(value, "done");
        assert!(synced.is_err(), "the failed early sync is reported");

        let (value, synced) = with_early_writeback(Ok(file), || 1);
        assert_eq!((value, synced.is_ok()), (1, true));
        let (value, synced) = with_early_writeback(Err(std::io::Error::other("no handle")), || 2);
        assert_eq!((value, synced.is_ok()), (2, true));
    }
}
