//! Running long work from Python: the work runs on its own thread (in a rayon pool of the
//! requested size) with the GIL released, while the calling thread wakes every 50 ms to report
//! progress and to check for Ctrl-C. Ctrl-C or an exception raised by the progress callback
//! sets the cancellation flag; the work stops before its next sample and keeps what it has.

use pyo3::exceptions::PyKeyboardInterrupt;
use pyo3::prelude::*;
use render_session::Control;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Condvar, Mutex};
use std::time::Duration;

/// How often the calling thread wakes.
const POLL: Duration = Duration::from_millis(50);

/// What the work returned, and whether Ctrl-C stopped it.
pub(crate) struct Outcome<T> {
    pub value: T,
    pub interrupted: bool,
    /// The units the work reported done.
    pub done: u64,
}

/// A pool of `threads` workers (all cores when `None`).
pub(crate) fn pool(threads: Option<usize>) -> PyResult<rayon::ThreadPool> {
    if let Some(t) = threads
        && !(1..=render_base::MAX_THREADS).contains(&t)
    {
        return Err(crate::error(format!(
            "threads = {t}: expected 1 to {} threads",
            render_base::MAX_THREADS
        )));
    }
    let mut b = rayon::ThreadPoolBuilder::new();
    if let Some(t) = threads {
        b = b.num_threads(t);
    }
    b.build().map_err(crate::error)
}

/// Whether `callback` takes two positional arguments (`progress(done, total)`), by
/// `inspect.signature`; a callable without a signature (a builtin such as `print`) takes them
/// as `*args` and is given both too.
fn takes_total(py: Python<'_>, callback: &Bound<'_, PyAny>) -> bool {
    let Ok(inspect) = py.import("inspect") else {
        return false;
    };
    match inspect.call_method1("signature", (callback,)) {
        Ok(signature) => signature.call_method1("bind", (0, 0)).is_ok(),
        Err(_) => true,
    }
}

/// Runs `work(control)` on `threads` threads with the GIL released; the units `work` reports to
/// its control reach `progress(done, total)` on the calling thread (`progress(done)` for a
/// callable of one argument), and Ctrl-C cancels it. An exception from the callback cancels the
/// work and is returned once it has stopped.
pub(crate) fn run_polled<T: Send>(
    py: Python<'_>,
    threads: Option<usize>,
    progress: Option<&Bound<'_, PyAny>>,
    total: u64,
    work: impl FnOnce(&Control) -> T + Send,
) -> PyResult<Outcome<T>> {
    let with_total = progress.is_some_and(|cb| takes_total(py, cb));
    let pool = pool(threads)?;
    let cancel = AtomicBool::new(false);
    let done = AtomicU64::new(0);
    // Set by the worker when it returns; the calling thread waits on it up to `POLL` at a time.
    let finished = (Mutex::new(false), Condvar::new());
    let mut failure: Option<PyErr> = None;
    let mut interrupted = false;
    let joined = std::thread::scope(|s| {
        let (cancel, done, pool, signal) = (&cancel, &done, &pool, &finished);
        let handle = s.spawn(move || {
            let report = |n| {
                done.fetch_add(n, Ordering::Relaxed);
            };
            let control = Control::new(cancel, &report);
            let v = pool.install(|| work(&control));
            *signal.0.lock().unwrap_or_else(|p| p.into_inner()) = true;
            signal.1.notify_all();
            v
        });
        let mut reported = u64::MAX;
        loop {
            let is_finished = py.detach(|| {
                let guard = finished.0.lock().unwrap_or_else(|p| p.into_inner());
                let (guard, _) = finished
                    .1
                    .wait_timeout_while(guard, POLL, |f| !*f)
                    .unwrap_or_else(|p| p.into_inner());
                *guard
            });
            if failure.is_none()
                && !interrupted
                && let Err(e) = py.check_signals()
            {
                if e.is_instance_of::<PyKeyboardInterrupt>(py) {
                    interrupted = true;
                } else {
                    failure = Some(e);
                }
                cancel.store(true, Ordering::SeqCst);
            }
            if let Some(cb) = progress.filter(|_| failure.is_none() && !interrupted) {
                let n = done.load(Ordering::Relaxed);
                if n != reported {
                    reported = n;
                    let called = if with_total {
                        cb.call1((n, total))
                    } else {
                        cb.call1((n,))
                    };
                    if let Err(e) = called {
                        // Ctrl-C that Python raised inside the callback is still Ctrl-C.
                        if e.is_instance_of::<PyKeyboardInterrupt>(py) {
                            interrupted = true;
                        } else {
                            failure = Some(e);
                        }
                        cancel.store(true, Ordering::SeqCst);
                    }
                }
            }
            if is_finished {
                break;
            }
        }
        handle.join()
    });
    let value =
        joined.map_err(|_| crate::error("the render thread panicked (a bug: please report it)"))?;
    match failure {
        Some(e) => Err(e),
        None => Ok(Outcome {
            value,
            interrupted,
            done: done.load(Ordering::Relaxed),
        }),
    }
}
