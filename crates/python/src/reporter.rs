//! Progress and messages of a job, handed to Python callbacks; Ctrl-C and a
//! callback that raises stop the job at its next iteration.

use nst3d_core::{stop, Reporter};
use pyo3::prelude::*;

use crate::Nst3dError;

/// A [`Reporter`] calling `progress(done, total, message)` after every step
/// and `log(level, message)` for notes (`"note"`, `"status"`, `"warning"`,
/// `"result"`). Each call takes the GIL for its duration only and first
/// runs Python's signal handlers: a `KeyboardInterrupt` (or any exception
/// a callback raises) is kept and the job asked to stop
/// ([`nst3d_core::stop`]), so it ends after the iteration in progress.
pub struct PyReporter {
    progress: Option<Py<PyAny>>,
    log: Option<Py<PyAny>>,
    total: u64,
    done: u64,
    error: Option<PyErr>,
}

/// Runs `f` under the GIL after Python's signal handlers; its first
/// failure is kept in `error` and asks the job to stop.
fn call(error: &mut Option<PyErr>, f: impl FnOnce(Python<'_>) -> PyResult<()>) {
    if error.is_some() {
        return;
    }
    if let Err(e) = Python::attach(|py| py.check_signals().and_then(|()| f(py))) {
        *error = Some(e);
        stop::request();
    }
}

impl PyReporter {
    fn say(&mut self, level: &str, message: &str) {
        let log = &self.log;
        call(&mut self.error, |py| match log {
            Some(l) => l.call1(py, (level, message)).map(drop),
            None => Ok(()),
        });
    }

    fn step_to(&mut self, message: String) {
        let (done, total, progress) = (self.done, self.total, &self.progress);
        call(&mut self.error, |py| match progress {
            Some(p) => p.call1(py, (done, total, message)).map(drop),
            None => Ok(()),
        });
    }
}

impl Reporter for PyReporter {
    fn begin(&mut self, steps: u64) {
        self.total = steps;
        self.done = 0;
        self.step_to(String::new());
    }

    fn step(&mut self, message: &str) {
        self.done += 1;
        self.step_to(message.to_string());
    }

    fn note(&mut self, message: &str) {
        self.say("note", message);
    }

    fn status(&mut self, message: &str) {
        self.say("status", message);
    }

    fn warn(&mut self, message: &str) {
        self.say("warning", message);
    }

    fn result(&mut self, message: &str) {
        self.say("result", message);
    }
}

/// Runs `job` with the GIL released and a [`PyReporter`]; a Python
/// exception raised while reporting (Ctrl-C, a failing callback) is
/// re-raised, any other failure becomes [`Nst3dError`] with the command
/// line's one-line message.
pub fn run_job<T: Send>(
    py: Python<'_>,
    progress: Option<Py<PyAny>>,
    log: Option<Py<PyAny>>,
    job: impl FnOnce(&mut dyn Reporter) -> anyhow::Result<T> + Send,
) -> PyResult<T> {
    let mut rep = PyReporter { progress, log, total: 0, done: 0, error: None };
    let out = py.detach(|| {
        stop::clear();
        let r = job(&mut rep);
        stop::clear();
        r
    });
    if let Some(e) = rep.error.take() {
        return Err(e);
    }
    out.map_err(|e| Nst3dError::new_err(nst3d_core::report::one_line(e.as_ref())))
}
