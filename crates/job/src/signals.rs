//! SIGINT and SIGTERM on a farm: the first asks the running job to stop
//! after its current iteration (`nst3d_core::stop`), so outputs are never
//! half-written (they are written whole and renamed) and a sequence keeps
//! its last committed sweep or frame; the process then exits with
//! 128 + the signal (130, 143), and a rerun resumes. A second signal ends
//! the process at once with the same status.

use std::sync::atomic::{AtomicI32, Ordering};

use signal_hook::consts::{SIGINT, SIGTERM};
use signal_hook::iterator::Signals;

/// The first stop signal received, 0 while none.
static RECEIVED: AtomicI32 = AtomicI32::new(0);

/// Starts the thread that turns SIGINT/SIGTERM into a stop request.
pub fn install() {
    let Ok(mut signals) = Signals::new([SIGINT, SIGTERM]) else {
        // Without handlers the signals keep their default (ending the process).
        return;
    };
    std::thread::spawn(move || {
        for sig in signals.forever() {
            if RECEIVED.compare_exchange(0, sig, Ordering::SeqCst, Ordering::SeqCst).is_ok() {
                nst3d_core::stop::request_all();
                eprintln!(
                    "nst3d: {} received: stopping after the current iteration (send it again to stop at once)",
                    name(sig)
                );
            } else {
                std::process::exit(128 + sig);
            }
        }
    });
}

/// The signal that stopped the job, if one came.
pub fn received() -> Option<i32> {
    match RECEIVED.load(Ordering::SeqCst) {
        0 => None,
        s => Some(s),
    }
}

/// `SIGINT` or `SIGTERM`.
pub fn name(sig: i32) -> &'static str {
    if sig == SIGINT {
        "SIGINT"
    } else {
        "SIGTERM"
    }
}
