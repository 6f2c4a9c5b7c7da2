//! How a long job talks to whoever started it. The library never prints:
//! the command line turns these calls into a progress bar and stderr lines,
//! a Python binding into callbacks, a test into nothing at all.

/// Receives a job's progress and messages. Every method has an empty
/// default, so a caller implements only what it shows.
pub trait Reporter {
    /// The job is about to run `steps` optimisation steps (the length of a
    /// progress bar). Called once, before the first [`Reporter::step`].
    fn begin(&mut self, steps: u64) {
        let _ = steps;
    }
    /// One step done; `message` says where the job is (octave, iteration, loss).
    fn step(&mut self, message: &str) {
        let _ = message;
    }
    /// The steps are over (the bar can go).
    fn end(&mut self) {}
    /// A remark about the input or a choice the job made on the user's
    /// behalf (a grid not copied, frames without velocity): worth reading,
    /// never an error.
    fn note(&mut self, message: &str) {
        let _ = message;
    }
    /// Where the job stands (resuming, frames kept, the sequence's box).
    fn status(&mut self, message: &str) {
        let _ = message;
    }
    /// A part of the job failed while the rest goes on (one frame of a
    /// sequence); the job's error at the end says how many.
    fn warn(&mut self, message: &str) {
        let _ = message;
    }
    /// A result worth keeping in a log (one finished frame of a sequence).
    fn result(&mut self, message: &str) {
        let _ = message;
    }
}

/// A [`Reporter`] that shows nothing (tests, batch callers that only want
/// the returned report).
#[derive(Clone, Copy, Debug, Default)]
pub struct Silent;

impl Reporter for Silent {}

/// Makes a panic (a bug) print one line, `nst3d: internal error: MESSAGE at
/// FILE:LINE (please report this)`, instead of a backtrace an artist cannot
/// act on.
pub fn one_line_panics() {
    std::panic::set_hook(Box::new(|info| {
        let payload = info.payload();
        let msg = payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown".into());
        let at = info.location().map(|l| format!(" at {}:{}", l.file(), l.line())).unwrap_or_default();
        eprintln!("nst3d: internal error: {msg}{at} (please report this)");
    }));
}

/// An error and its causes on one line: the message a user sees (the
/// command line after `nst3d: error:`, the Python package in its
/// exception). Library errors often repeat their cause in their own
/// message; a cause already said is not said twice.
pub fn one_line(e: &(dyn std::error::Error + 'static)) -> String {
    let mut msg = String::new();
    let mut cause = Some(e);
    while let Some(c) = cause {
        let s = c.to_string();
        if !msg.contains(&s) {
            if !msg.is_empty() {
                msg.push_str(": ");
            }
            msg.push_str(&s);
        }
        cause = c.source();
    }
    msg.replace('\n', " ")
}
