//! Progress reporting: bars on a terminal, one log line per stage otherwise.

use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use mlt_bake::Observer;

/// Progress bars on a terminal, one log line per stage otherwise.
pub struct Reporter {
    pub start: Instant,
    quiet: bool,
    bar: Mutex<Option<ProgressBar>>,
    tty: bool,
    /// Put before every line (the job's name in a batch).
    pub prefix: String,
}

impl Reporter {
    pub fn new(quiet: bool) -> Reporter {
        Reporter {
            start: Instant::now(),
            quiet,
            bar: Mutex::new(None),
            tty: std::io::stderr().is_terminal(),
            prefix: String::new(),
        }
    }

    /// A log line with the time since the start (nothing with `quiet`).
    pub fn line(&self, msg: &str) {
        if !self.quiet {
            let elapsed = self.start.elapsed().as_secs_f64();
            let text = format!("[{elapsed:8.2}s] {}{msg}", self.prefix);
            match self.bar.lock().ok().and_then(|b| b.clone()) {
                Some(bar) => bar.println(text),
                None => eprintln!("{text}"),
            }
        }
    }
}

impl Observer for Reporter {
    fn stage(&self, name: &str) {
        // Bars only for a single bake on a terminal; concurrent jobs log lines.
        if self.quiet || !self.tty || !self.prefix.is_empty() {
            return;
        }
        let bar = ProgressBar::new_spinner().with_message(name.to_string());
        if let Ok(style) = ProgressStyle::with_template("{spinner} {msg} {pos}/{len} [{elapsed}]") {
            bar.set_style(style);
        }
        bar.enable_steady_tick(std::time::Duration::from_millis(120));
        if let Ok(mut b) = self.bar.lock() {
            if let Some(old) = b.replace(bar) {
                old.finish_and_clear();
            }
        }
    }

    fn progress(&self, done: u64, total: u64) {
        if let Ok(b) = self.bar.lock() {
            if let Some(bar) = b.as_ref() {
                bar.set_length(total);
                bar.set_position(done);
            }
        }
    }

    fn step(&self, done: u64, total: u64, detail: &str) {
        self.progress(done, total);
        self.line(detail);
    }

    fn done(&self, name: &str, secs: f64, detail: &str) {
        if let Ok(mut b) = self.bar.lock() {
            if let Some(bar) = b.take() {
                bar.finish_and_clear();
            }
        }
        self.line(&format!("{name}: {detail} ({secs:.2} s)"));
    }

    fn warn(&self, message: &str) {
        // Warnings show even with --quiet.
        eprintln!("warning: {}{message}", self.prefix);
    }
}
