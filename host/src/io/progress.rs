//! Progress on stderr for every stage of `calibrate`, `compensate` and `diagnose` that
//! takes more than a second: rows and rows/s for a pass over the samples, the time for
//! a stage without rows. Only when stderr is a terminal, or with `--progress` (a log
//! file then records it).
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// `--progress` given: progress lines even when stderr is not a terminal.
static FORCED: AtomicBool = AtomicBool::new(false);

/// Set once by a command from its `--progress` flag.
pub fn force_progress(on: bool) {
    FORCED.store(on, Ordering::Relaxed);
}

/// No progress lines: stderr is not a terminal (a log, a pipe) and `--progress` was not
/// given.
pub fn quiet_progress(progress_flag: bool) -> bool {
    use std::io::IsTerminal;
    !progress_flag && !FORCED.load(Ordering::Relaxed) && !std::io::stderr().is_terminal()
}

/// Rows/s on stderr for a stage that runs longer than a second.
pub struct Progress {
    stage: String,
    start: Instant,
    last: Instant,
    rows: u64,
    quiet: bool,
}

impl Progress {
    pub fn new(stage: &str, quiet: bool) -> Self {
        let now = Instant::now();
        Self {
            stage: stage.into(),
            start: now,
            last: now,
            rows: 0,
            quiet,
        }
    }
    pub fn tick(&mut self) {
        self.rows += 1;
        if self.quiet || !self.rows.is_multiple_of(65_536) {
            return;
        }
        let now = Instant::now();
        if now.duration_since(self.last).as_secs_f64() >= 5.0
            || (self.last == self.start && now.duration_since(self.start).as_secs_f64() >= 1.0)
        {
            self.last = now;
            let s = now.duration_since(self.start).as_secs_f64();
            crate::errln!(
                "{}: {} rows, {:.0} rows/s",
                self.stage,
                self.rows,
                self.rows as f64 / s
            );
        }
    }
    pub fn done(&self) {
        let s = self.start.elapsed().as_secs_f64();
        if !self.quiet && s >= 1.0 {
            crate::errln!(
                "{}: {} rows in {s:.1} s, {:.0} rows/s",
                self.stage,
                self.rows,
                self.rows as f64 / s
            );
        }
    }
}

/// A stage without a row count: its time on stderr when it ends, if it took a second or
/// more.
pub struct Stage {
    name: String,
    start: Instant,
}

impl Stage {
    pub fn new(name: &str) -> Self {
        Self {
            name: name.into(),
            start: Instant::now(),
        }
    }
}

impl Drop for Stage {
    fn drop(&mut self) {
        let s = self.start.elapsed().as_secs_f64();
        if s >= 1.0 && !quiet_progress(false) {
            crate::errln!("{}: {s:.1} s", self.name);
        }
    }
}
