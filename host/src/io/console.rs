//! Text for the person at the terminal, on stdout and stderr. `println!` panics when the
//! reader has gone (`magcomp compensate … | head`, `2>&1 | tail -0`): Rust ignores
//! SIGPIPE, and restoring it needs `unsafe`. Here a closed pipe drops the text and the
//! work goes on, so the files a command writes are still written whole; any other write
//! error (a full disk under `> log.txt`) is kept and reported when the command ends.
use std::fmt;
use std::io::{ErrorKind, Write};
use std::sync::Mutex;

/// The first error other than a closed pipe met while writing terminal text.
static LOST_TEXT: Mutex<Option<String>> = Mutex::new(None);

/// Writes to stdout; what `outln!` and `out!` expand to.
pub fn write_stdout(args: fmt::Arguments) {
    let result = std::io::stdout().lock().write_fmt(args);
    keep_unless_closed_pipe(result, "stdout");
}

/// Writes to stderr; what `errln!` expands to.
pub fn write_stderr(args: fmt::Arguments) {
    let result = std::io::stderr().lock().write_fmt(args);
    keep_unless_closed_pipe(result, "stderr");
}

fn keep_unless_closed_pipe(result: std::io::Result<()>, stream: &str) {
    let Err(e) = result else { return };
    if e.kind() == ErrorKind::BrokenPipe {
        return;
    }
    if let Ok(mut lost) = LOST_TEXT.lock() {
        lost.get_or_insert_with(|| format!("text written to {stream} was lost: {e}"));
    }
}

/// The first terminal text lost to an error other than a closed pipe, if any: `cli::run`
/// turns it into a failing exit status.
pub fn lost_text() -> Option<String> {
    LOST_TEXT.lock().ok().and_then(|lost| lost.clone())
}

/// `println!` that survives a closed pipe (see the module's doc).
#[macro_export]
macro_rules! outln {
    () => {
        $crate::io::console::write_stdout(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::io::console::write_stdout(format_args!("{}\n", format_args!($($arg)*)))
    };
}

/// `print!` that survives a closed pipe.
#[macro_export]
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::io::console::write_stdout(format_args!($($arg)*))
    };
}

/// `eprintln!` that survives a closed pipe.
#[macro_export]
macro_rules! errln {
    () => {
        $crate::io::console::write_stderr(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::io::console::write_stderr(format_args!("{}\n", format_args!($($arg)*)))
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_closed_pipe_is_not_kept_as_lost_text_but_another_error_is() {
        keep_unless_closed_pipe(Err(ErrorKind::BrokenPipe.into()), "stdout");
        assert_eq!(lost_text(), None);
        keep_unless_closed_pipe(Err(ErrorKind::StorageFull.into()), "stdout");
        keep_unless_closed_pipe(Err(ErrorKind::Other.into()), "stderr");
        let lost = lost_text().expect("a full disk is kept");
        assert!(
            lost.starts_with("text written to stdout was lost"),
            "{lost}"
        );
    }
}
