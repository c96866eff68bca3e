//! Items made on every thread and handed on in index order as soon as each is next, with no
//! barrier between groups of items: a thread that finishes early takes the next item, and
//! handing on (the samples writer compresses and writes) is done by whichever thread made
//! the item that is next, while the others keep making. Batches with a join between them
//! would leave threads idle at every batch's end, and the handing on of the last batch
//! would overlap little.
//!
//! At most `window` items are made ahead of the next one to hand on (memory is bounded as
//! with batches). A thread that meets the bound does not wait: it stops, free for other work
//! of the pool (the compression the writer runs in parallel), and is started again once the
//! window moves. No thread ever blocks, so nothing here can deadlock the pool.

use std::collections::VecDeque;
use std::sync::{Mutex, MutexGuard};

/// Makes items `0..n` (`make(state, i)`, each thread with a state from `init`, reused item
/// after item) on the pool's threads and calls `emit` with them in index order, as soon as
/// each is the next; at most `window` (≥ 1) items are made but not yet emitted. Stops at the
/// first error of `emit` and returns it. `emit` runs on one thread at a time.
pub(super) fn make_in_order<S, T, E>(
    n: usize,
    window: usize,
    init: &(dyn Fn() -> S + Sync),
    make: &(dyn Fn(&mut S, usize) -> T + Sync),
    emit: &mut (dyn FnMut(T) -> Result<(), E> + Send),
) -> Result<(), E>
where
    S: Send,
    T: Send,
    E: Send,
{
    let threads = rayon::current_num_threads().clamp(1, n.max(1));
    let line = Line {
        n,
        window: window.max(1),
        threads,
        init,
        make,
        emit: Mutex::new(emit),
        states: Mutex::new(Vec::new()),
        queue: Mutex::new(Queue { ready: VecDeque::new(), next: 0, emitted: 0, taken: 0, workers: threads, emitting: false, failed: None }),
    };
    let shared = &line;
    rayon::scope(|s| {
        for _ in 0..threads {
            s.spawn(move |s| work(s, shared));
        }
    });
    let q = line.queue.into_inner().unwrap_or_else(|p| p.into_inner());
    match q.failed {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

/// What the threads share.
struct Line<'a, S, T, E> {
    n: usize,
    window: usize,
    threads: usize,
    init: &'a (dyn Fn() -> S + Sync),
    make: &'a (dyn Fn(&mut S, usize) -> T + Sync),
    /// Held by the one thread emitting (see [`Queue::emitting`]).
    emit: Mutex<&'a mut (dyn FnMut(T) -> Result<(), E> + Send)>,
    /// States of threads that stopped, for those started later.
    states: Mutex<Vec<S>>,
    queue: Mutex<Queue<T, E>>,
}

/// The items made and not yet emitted, and who does what.
struct Queue<T, E> {
    /// Slot `k`: item `next + k`, once made.
    ready: VecDeque<Option<T>>,
    /// The first item not yet taken for emitting.
    next: usize,
    /// Items emitted (`0..emitted`); items may be taken up to `emitted + window`.
    emitted: usize,
    /// Items taken by makers (`0..taken`).
    taken: usize,
    /// Threads making items now.
    workers: usize,
    /// Whether a thread is emitting: it emits every item that is next, then clears this.
    emitting: bool,
    /// The error of `emit` that stopped the line.
    failed: Option<E>,
}

fn lock<X>(m: &Mutex<X>) -> MutexGuard<'_, X> {
    // A poisoned lock means a panicking thread, whose panic the scope passes on.
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// One thread's part: take the next item, make it, put it in its slot, and emit what is next
/// unless another thread is emitting; stop when no item may be taken.
fn work<'s, 'a: 's, S, T, E>(s: &rayon::Scope<'s>, line: &'s Line<'a, S, T, E>)
where
    S: Send,
    T: Send,
    E: Send,
{
    let mut state = lock(&line.states).pop().unwrap_or_else(|| (line.init)());
    loop {
        let i = {
            let mut q = lock(&line.queue);
            if q.failed.is_some() || q.taken >= line.n || q.taken >= q.emitted + line.window {
                q.workers -= 1;
                break;
            }
            q.taken += 1;
            q.taken - 1
        };
        let item = (line.make)(&mut state, i);
        let mut q = lock(&line.queue);
        // Items not yet emitted were not taken for emitting: `next ≤ i`.
        let k = i - q.next;
        if q.ready.len() <= k {
            q.ready.resize_with(k + 1, || None);
        }
        q.ready[k] = Some(item);
        if q.emitting || q.failed.is_some() {
            continue;
        }
        q.emitting = true;
        loop {
            let mut run = Vec::new();
            while let Some(Some(_)) = q.ready.front() {
                run.extend(q.ready.pop_front().flatten());
                q.next += 1;
            }
            if run.is_empty() {
                q.emitting = false;
                break;
            }
            drop(q);
            let count = run.len();
            let emitted = {
                let mut emit = lock(&line.emit);
                run.into_iter().try_for_each(|t| (*emit)(t))
            };
            q = lock(&line.queue);
            if let Err(e) = emitted {
                q.failed = Some(e);
                q.emitting = false;
                break;
            }
            q.emitted += count;
            // The window moved: threads that stopped at it start again.
            let restart = if q.taken < line.n { line.threads - q.workers } else { 0 };
            q.workers += restart;
            for _ in 0..restart {
                s.spawn(move |s| work(s, line));
            }
        }
    }
    lock(&line.states).push(state);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Items of uneven cost come out in index order, all of them, on 1 to 4 threads and with
    /// windows from 1 up; no more than `window` are made but not yet emitted at any time.
    #[test]
    fn items_are_emitted_in_order_within_the_window() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        for threads in [1, 2, 3, 4] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            for (n, window) in [(0, 4), (1, 1), (9, 1), (9, 2), (40, 3), (200, 8)] {
                let made = AtomicUsize::new(0);
                let mut got = Vec::new();
                let mut most_ahead = 0;
                let r = pool.install(|| {
                    make_in_order(
                        n,
                        window,
                        &|| 0u64,
                        &|calls: &mut u64, i: usize| {
                            *calls += 1;
                            // Uneven work: every seventh item is slow.
                            if i % 7 == 3 {
                                std::thread::sleep(std::time::Duration::from_millis(2));
                            }
                            made.fetch_add(1, Ordering::SeqCst);
                            i
                        },
                        &mut |i: usize| -> Result<(), ()> {
                            // Made and not yet emitted, this one included.
                            most_ahead = most_ahead.max(made.load(Ordering::SeqCst) - got.len());
                            got.push(i);
                            Ok(())
                        },
                    )
                });
                assert_eq!(r, Ok(()));
                assert_eq!(got, (0..n).collect::<Vec<_>>(), "{threads} threads, n {n}, window {window}");
                assert!(most_ahead <= window, "{threads} threads, window {window}: {most_ahead} made ahead");
            }
        }
    }

    /// The first error of `emit` stops the line and is returned; nothing after it is emitted.
    #[test]
    fn an_emit_error_stops_the_line() {
        for threads in [1, 2, 3] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            let mut got = Vec::new();
            let r = pool.install(|| {
                make_in_order(100, 4, &|| (), &|_: &mut (), i: usize| i, &mut |i: usize| {
                    if i == 10 {
                        return Err(format!("full at {i}"));
                    }
                    got.push(i);
                    Ok(())
                })
            });
            assert_eq!(r, Err("full at 10".to_string()));
            assert_eq!(got, (0..10).collect::<Vec<_>>());
        }
    }
}
