//! Which lines a UART error may have touched. The board counts each port's overrun, framing
//! and noise errors in the UART interrupt, before the byte enters the driver's ring; the
//! task that parses the port reads the ring in chunks and only sees that the count grew.
//! The bad byte (or the gap an overrun left) is then somewhere in the chunk just read, so
//! every line completed from that chunk is suspect, and so is the line still open at its end
//! (the next one to complete). A scalar line carries no checksum: such a line is rejected
//! ([`ScalarError::Uart`](super::scalar::ScalarError::Uart), one record flagged
//! `PARSE_ERROR`), as a fluxgate frame is (`FluxError::Uart`); NMEA keeps its own checksum.
//! Conservative: an error in one line of a chunk rejects the chunk's other lines too.

/// The tracker for one port, fed the port's error count after every read.
#[derive(Clone, Copy, Debug, Default)]
pub struct LineErrors {
    /// The port's error count at the last read.
    seen: u32,
    /// Lines completing now may hold the bad byte.
    open: bool,
    /// The count grew on the chunk being parsed: every line it completes is suspect, not
    /// only the first.
    whole_chunk: bool,
}

impl LineErrors {
    /// Starts from the port's error count now (errors before the task started touch no
    /// line it will parse).
    pub const fn new(count: u32) -> Self {
        Self {
            seen: count,
            open: false,
            whole_chunk: false,
        }
    }

    /// A read returned a chunk; `count` is the port's error count after it.
    pub fn after_read(&mut self, count: u32) {
        self.whole_chunk = count != self.seen;
        self.seen = count;
        self.open |= self.whole_chunk;
    }

    /// A line (or a sample of a merged line) completed from the chunk being parsed: whether
    /// a UART error may be in it.
    pub fn line_done(&mut self) -> bool {
        let suspect = self.open;
        // A chunk without an error of its own clears the line left open by the last one.
        if !self.whole_chunk {
            self.open = false;
        }
        suspect
    }

    /// How many errors the port has had (wrapping), as last seen.
    pub fn count(&self) -> u32 {
        self.seen
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec::Vec;

    /// Feeds chunks of (error count after the read, lines completed in it) and returns the
    /// verdict of each line.
    fn verdicts(chunks: &[(u32, usize)]) -> Vec<bool> {
        let mut t = LineErrors::new(0);
        let mut out = Vec::new();
        for &(count, lines) in chunks {
            t.after_read(count);
            for _ in 0..lines {
                out.push(t.line_done());
            }
        }
        out
    }

    #[test]
    fn no_error_touches_no_line() {
        assert_eq!(verdicts(&[(0, 1), (0, 2), (0, 0), (0, 1)]), [false; 4]);
    }

    #[test]
    fn an_error_rejects_its_chunks_lines_and_the_line_left_open() {
        // chunk 2 has the error and completes two lines; the third line was open at its
        // end and completes in chunk 3; chunk 3's second line and chunk 4's are clean
        assert_eq!(
            verdicts(&[(0, 1), (1, 2), (1, 2), (1, 1)]),
            [false, true, true, true, false, false]
        );
    }

    #[test]
    fn the_open_line_stays_suspect_through_chunks_that_complete_nothing() {
        assert_eq!(verdicts(&[(3, 0), (3, 0), (3, 0), (3, 2)]), [true, false]);
    }

    #[test]
    fn errors_on_consecutive_chunks_and_a_wrapping_count() {
        let mut t = LineErrors::new(u32::MAX);
        t.after_read(u32::MAX);
        assert!(!t.line_done());
        t.after_read(0); // wrapped: one more error
        assert!(t.line_done());
        t.after_read(1);
        assert!(t.line_done() && t.line_done());
        t.after_read(1);
        assert!(t.line_done());
        assert!(!t.line_done());
        assert_eq!(t.count(), 1);
    }
}
