//! What a batch's progress display shows: the inputs converting now (not merely the last
//! one started) and an estimate of the time left that weighs each input by its size, so
//! one large asset neither hides behind a count nor makes the estimate swing.

use std::sync::Mutex;
use std::time::Instant;

use crate::batch::{JobResult, JobStatus};

/// A progress report, sent when an input starts and when it finishes.
#[derive(Debug)]
#[non_exhaustive]
pub struct BatchProgress<'a> {
    /// Inputs finished so far (any status).
    pub finished: usize,
    /// Inputs of this run (this shard).
    pub total: usize,
    /// Inputs being converted now (relative paths), oldest first.
    pub running: &'a [String],
    /// The input that just finished; `None` when one just started.
    pub last: Option<&'a JobResult>,
    /// Estimated seconds left; `None` until an input has been converted.
    pub eta_seconds: Option<f64>,
}

/// Seconds left at the rate of the work so far: `done` bytes of inputs converted in
/// `elapsed` seconds, `remaining` bytes of inputs still to convert (running or queued).
/// `None` before anything was converted (no rate yet).
pub fn eta_seconds(elapsed: f64, done: u64, remaining: u64) -> Option<f64> {
    if done == 0 || elapsed.is_nan() || elapsed <= 0.0 {
        return None;
    }
    Some(remaining as f64 * elapsed / done as f64)
}

/// Seconds as `42 s`, `3 min`, `1 h 05 min`.
pub fn format_duration(s: f64) -> String {
    let s = s.max(0.0).round() as u64;
    match s {
        0..=59 => format!("{s} s"),
        60..=3599 => format!("{} min", s.div_ceil(60)),
        _ => format!("{} h {:02} min", s / 3600, (s % 3600) / 60),
    }
}

/// The progress bookkeeping of one batch run (shared by its workers).
pub(crate) struct Tracker {
    start: Instant,
    total: usize,
    state: Mutex<State>,
}

struct State {
    finished: usize,
    running: Vec<(usize, String)>,
    /// Input bytes converted (or failed) so far.
    done_bytes: u64,
    /// Input bytes not yet finished (up-to-date inputs leave the count without adding work).
    remaining_bytes: u64,
}

impl Tracker {
    pub(crate) fn new(total: usize, total_bytes: u64) -> Self {
        Tracker { start: Instant::now(), total, state: Mutex::new(State { finished: 0, running: Vec::new(), done_bytes: 0, remaining_bytes: total_bytes }) }
    }

    fn report(&self, s: &State, last: Option<&JobResult>, send: &(dyn Fn(&BatchProgress<'_>) + Sync)) {
        let running: Vec<String> = s.running.iter().map(|(_, n)| n.clone()).collect();
        let eta = eta_seconds(self.start.elapsed().as_secs_f64(), s.done_bytes, s.remaining_bytes);
        send(&BatchProgress { finished: s.finished, total: self.total, running: &running, last, eta_seconds: eta });
    }

    pub(crate) fn started(&self, i: usize, input: String, send: &(dyn Fn(&BatchProgress<'_>) + Sync)) {
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        s.running.push((i, input));
        self.report(&s, None, send);
    }

    pub(crate) fn finished(&self, i: usize, bytes: u64, job: &JobResult, send: &(dyn Fn(&BatchProgress<'_>) + Sync)) {
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        s.running.retain(|(k, _)| *k != i);
        s.finished += 1;
        s.remaining_bytes = s.remaining_bytes.saturating_sub(bytes);
        if job.status != JobStatus::UpToDate {
            s.done_bytes += bytes;
        }
        self.report(&s, Some(job), send);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eta_weighs_inputs_by_size() {
        assert_eq!(eta_seconds(10.0, 0, 1000), None, "no rate before the first conversion");
        // 1 MB converted in 10 s, 4 MB left: 40 s, however many files that is.
        assert_eq!(eta_seconds(10.0, 1 << 20, 4 << 20), Some(40.0));
        assert_eq!(format_duration(42.0), "42 s");
        assert_eq!(format_duration(61.0), "2 min");
        assert_eq!(format_duration(3900.0), "1 h 05 min");
    }

    #[test]
    fn running_inputs_are_listed_until_they_finish() {
        let t = Tracker::new(2, 300);
        let seen = Mutex::new(Vec::new());
        let send = |p: &BatchProgress<'_>| seen.lock().expect("lock").push((p.running.to_vec(), p.finished, p.eta_seconds.is_some()));
        t.started(0, "big.glb".into(), &send);
        t.started(1, "small.obj".into(), &send);
        let job = JobResult {
            input: "small.obj".into(),
            output: "small.sct".into(),
            status: JobStatus::Converted,
            error: None,
            exit_code: 0,
            samples: 0,
            leaves: 0,
            bytes: 0,
            seconds: 0.0,
            warnings: Vec::new(),
        };
        t.finished(1, 100, &job, &send);
        let seen = seen.into_inner().expect("lock");
        assert_eq!(seen[1].0, ["big.glb", "small.obj"]);
        assert_eq!(seen[2], (vec!["big.glb".to_string()], 1, true), "the big one still runs; an estimate exists");
    }
}
