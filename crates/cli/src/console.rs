//! What the user sees of a job: a progress bar on a terminal, plain lines
//! in farm logs, and the library's notes on stderr.

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressStyle};
use nst3d_core::Reporter;

/// A [`Reporter`] for the terminal or a log file.
#[derive(Default)]
pub struct Console {
    bar: Option<ProgressBar>,
    total: u64,
    done: u64,
}

impl Console {
    /// Prints `line` with `print`, above the bar if one is showing.
    fn say(&self, print: impl FnOnce()) {
        match &self.bar {
            Some(b) => b.suspend(print),
            None => print(),
        }
    }
}

/// The run's header, printed once per process when the first long work
/// starts (not before, so a refused input stays a one-line error): which
/// arithmetic the products run in and on how many threads.
fn header() {
    static SHOWN: std::sync::Once = std::sync::Once::new();
    SHOWN.call_once(|| {
        eprintln!(
            "nst3d: precision {} → {}, {} threads",
            nst3d_core::precision::current(),
            nst3d_core::precision::path().describe(),
            rayon::current_num_threads()
        );
    });
}

impl Reporter for Console {
    fn begin(&mut self, steps: u64) {
        header();
        self.total = steps;
        self.done = 0;
        self.bar = std::io::stderr().is_terminal().then(|| {
            let b = ProgressBar::new(steps);
            b.set_style(
                ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} {msg} (eta {eta})")
                    .expect("static template")
                    .progress_chars("=> "),
            );
            b
        });
    }

    fn step(&mut self, message: &str) {
        self.done += 1;
        match &self.bar {
            Some(b) => {
                b.set_message(message.to_string());
                b.inc(1);
            }
            None => eprintln!("[{}/{}] {message}", self.done, self.total),
        }
    }

    fn end(&mut self) {
        if let Some(b) = self.bar.take() {
            b.finish_and_clear();
        }
    }

    fn note(&mut self, message: &str) {
        self.say(|| eprintln!("nst3d: note: {message}"));
    }

    fn status(&mut self, message: &str) {
        self.say(|| eprintln!("{message}"));
    }

    fn warn(&mut self, message: &str) {
        self.say(|| eprintln!("nst3d: {message}"));
    }

    fn result(&mut self, message: &str) {
        self.say(|| println!("{message}"));
    }
}

/// `"s"` when `n` is not one, for counts in messages.
pub fn plural(n: usize) -> &'static str {
    if n == 1 {
        ""
    } else {
        "s"
    }
}
