//! Ctrl-C (SIGINT) and SIGTERM: remove the temporary files this process is writing
//! ([`sct_format::atomic::remove_pending_temp_files`]), say so, and exit with the
//! conventional status 128 + signal (130, 143). Without this, an interrupted
//! `sct-voxelize` leaves its hidden `.NAME.PID.RANDOM.tmp` (often hundreds of MB) behind.

/// Installs the handler (a thread waiting for the signals; no work in signal context).
/// Call once, early in `main`, before starting worker threads. A no-op where signals are
/// not available or the handler cannot be installed (the default action then applies).
pub fn remove_temp_files_on_signal(tool: &'static str) {
    #[cfg(unix)]
    {
        use signal_hook::consts::{SIGINT, SIGTERM};
        let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM]) else {
            return;
        };
        let spawned = std::thread::Builder::new().name("signals".into()).spawn(move || {
            if let Some(sig) = signals.forever().next() {
                let removed = sct_format::atomic::remove_pending_temp_files();
                let name = if sig == SIGINT { "SIGINT" } else { "SIGTERM" };
                eprintln!("{tool}: interrupted by {name}; {removed} temporary file(s) removed, nothing written");
                std::process::exit(128 + sig);
            }
        });
        drop(spawned);
    }
    #[cfg(not(unix))]
    let _ = tool;
}
