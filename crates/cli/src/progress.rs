//! Progress for long work: a bar on a terminal, plain lines in farm logs.

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressStyle};

/// Reports steps of a job either as a live bar or as plain log lines.
pub struct Progress {
    bar: Option<ProgressBar>,
    total: u64,
    done: u64,
}

impl Progress {
    /// A reporter for `total` steps.
    pub fn new(total: u64) -> Self {
        let bar = std::io::stderr().is_terminal().then(|| {
            let b = ProgressBar::new(total);
            b.set_style(
                ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} {msg} (eta {eta})")
                    .expect("static template")
                    .progress_chars("=> "),
            );
            b
        });
        Self { bar, total, done: 0 }
    }

    /// One step done; `msg` says where we are.
    pub fn step(&mut self, msg: String) {
        self.done += 1;
        match &self.bar {
            Some(b) => {
                b.set_message(msg);
                b.inc(1);
            }
            None => eprintln!("[{}/{}] {msg}", self.done, self.total),
        }
    }

    /// Removes the bar (plain mode prints nothing).
    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}
