//! Running without the GIL: rayon threads and progress delivered on the
//! calling thread.

use std::sync::mpsc;
use std::time::{Duration, Instant};

use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;

use odocal::Progress;

/// Runs `f` with `threads` rayon threads (the global pool when None);
/// `threads` as `convert::opt_threads` checks it.
pub(crate) fn with_threads<T: Send>(threads: Option<usize>, f: impl FnOnce() -> T + Send) -> PyResult<T> {
    match threads {
        None => Ok(f()),
        Some(n) if n == 0 || n > odocal::settings::MAX_THREADS => Err(crate::OdocalError::new_err(format!(
            "threads is a number of worker threads, 1 … {}, got {n}",
            odocal::settings::MAX_THREADS
        ))),
        Some(n) => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| PyRuntimeError::new_err(format!("building a thread pool: {e}")))?;
            Ok(pool.install(f))
        }
    }
}

/// Minimum interval between two progress calls for the same stage.
const PROGRESS_INTERVAL: Duration = Duration::from_millis(100);

/// Runs `work` without the GIL. With a callback, `work` runs on a helper
/// thread and this thread forwards its progress events to
/// `callback(stage, done, total)`, re-attaching to Python for each call
/// (coalesced to one call per [`PROGRESS_INTERVAL`] and stage change). An
/// exception from the callback, or a pending signal (Ctrl-C), stops the
/// calls and is raised once the work has finished (the library cannot be
/// interrupted mid-calibration).
pub(crate) fn run_detached<T: Send>(
    py: Python<'_>,
    callback: Option<Py<PyAny>>,
    work: impl FnOnce(Option<&(dyn Fn(Progress) + Sync)>) -> T + Send,
) -> PyResult<T> {
    let Some(callback) = callback else {
        return Ok(py.detach(|| work(None)));
    };
    let (result, deferred) = py.detach(|| {
        std::thread::scope(|s| {
            let (tx, rx) = mpsc::channel::<Progress>();
            let worker = s.spawn(move || {
                let send = move |e: Progress| {
                    let _ = tx.send(e); // a receiver gone only means nobody listens
                };
                work(Some(&send))
            });
            let mut deferred: Option<PyErr> = None;
            let (mut stage, mut done, mut total) = (String::new(), 0u64, 0u64);
            let (mut dirty, mut last) = (false, Instant::now());
            let call = |stage: &str, done: u64, total: u64, deferred: &mut Option<PyErr>| {
                if deferred.is_some() {
                    return;
                }
                Python::attach(|py| {
                    if let Err(e) = py.check_signals().and_then(|_| callback.call1(py, (stage, done, total)).map(drop))
                    {
                        *deferred = Some(e);
                    }
                });
            };
            loop {
                match rx.recv_timeout(PROGRESS_INTERVAL) {
                    Ok(Progress::Stage { name, total: t }) => {
                        if dirty {
                            call(&stage, done, total, &mut deferred);
                        }
                        (stage, done, total) = (name.to_string(), 0, t);
                        call(&stage, done, total, &mut deferred);
                        (dirty, last) = (false, Instant::now());
                    }
                    Ok(Progress::Advance(k)) => {
                        done += k;
                        dirty = true;
                    }
                    Err(mpsc::RecvTimeoutError::Timeout) => {}
                    Err(mpsc::RecvTimeoutError::Disconnected) => break,
                }
                if dirty && last.elapsed() >= PROGRESS_INTERVAL {
                    call(&stage, done, total, &mut deferred);
                    (dirty, last) = (false, Instant::now());
                }
            }
            if dirty {
                call(&stage, done, total, &mut deferred);
            }
            (worker.join(), deferred)
        })
    });
    let result = result.map_err(|_| PyRuntimeError::new_err("odocal panicked during the calibration (a bug)"))?;
    match deferred {
        Some(e) => Err(e),
        None => Ok(result),
    }
}
