//! Asking a running job to stop between iterations. A front end cannot
//! unwind a job from the outside: the Python binding notices Ctrl-C (or a
//! progress callback that raised) while reporting a step, and a farm
//! wrapper may catch SIGTERM. Either asks for a stop here; the optimisation
//! loops call [`check`] after every iteration and end with [`Interrupted`],
//! which the job passes up like any other error (state already committed by
//! a sequence stays on disk, so the job resumes where it stopped).
//!
//! Two flags: one for the calling thread (a Python thread's job stops
//! without stopping a job in another thread) and one for the process (a
//! signal stops every job).

use std::cell::Cell;
use std::sync::atomic::{AtomicBool, Ordering};

thread_local! {
    static THIS_THREAD: Cell<bool> = const { Cell::new(false) };
}
static PROCESS: AtomicBool = AtomicBool::new(false);

/// A job ended early because a stop was requested.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Interrupted;

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("interrupted")
    }
}

impl std::error::Error for Interrupted {}

/// Asks the job running on this thread to stop after its current iteration.
pub fn request() {
    THIS_THREAD.with(|s| s.set(true));
}

/// Asks every job of the process to stop (safe from a signal handler: one
/// atomic store).
pub fn request_all() {
    PROCESS.store(true, Ordering::Relaxed);
}

/// Whether a stop was requested for this thread or the process.
pub fn requested() -> bool {
    THIS_THREAD.with(Cell::get) || PROCESS.load(Ordering::Relaxed)
}

/// Forgets this thread's request (a front end does so before it starts the
/// next job).
pub fn clear() {
    THIS_THREAD.with(|s| s.set(false));
}

/// `Err(Interrupted)` once a stop was requested: the loops' check.
pub fn check() -> Result<(), Interrupted> {
    if requested() {
        Err(Interrupted)
    } else {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A request on one thread stops that thread's job only.
    #[test]
    fn a_thread_request_stays_on_its_thread() {
        request();
        assert_eq!(check(), Err(Interrupted));
        std::thread::spawn(|| assert_eq!(check(), Ok(()))).join().unwrap();
        clear();
        assert_eq!(check(), Ok(()));
    }
}
