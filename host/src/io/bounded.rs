//! Reading with a bound: a line no longer than its format allows, a file no larger, and
//! error messages that quote only a short excerpt of what was read. Without these,
//! `compensate /dev/zero` grew one line until an 8 GB allocation aborted, and a 1 GB
//! coefficient file was read whole and echoed into an error.

use anyhow::{bail, Context, Result};
use std::io::{BufRead, Read};
use std::path::Path;

/// The largest coefficient file read (a `calibrate` file is a few KB to a few hundred KB).
pub const MAX_COEFFICIENT_FILE_BYTES: u64 = 4 << 20;

/// Appends the next line (with its `\n`) to `buf`, as `BufRead::read_until`, but fails
/// once the line passes `max` bytes instead of growing without end. Returns the bytes read
/// (0 at the end of the input).
pub fn read_line_bounded<R: BufRead + ?Sized>(
    r: &mut R,
    buf: &mut Vec<u8>,
    max: usize,
) -> Result<usize> {
    let start = buf.len();
    let n = r
        .take(max as u64 + 1)
        .read_until(b'\n', buf)
        .context("reading a line")?;
    if buf.len() - start > max && buf.last() != Some(&b'\n') {
        bail!(
            "a line is longer than {max} bytes (it begins \"{}\"): not a file of this format",
            excerpt(&String::from_utf8_lossy(&buf[start..]))
        );
    }
    Ok(n)
}

/// Reads `path` as text, refusing a file larger than `max` bytes (checked as it is read,
/// so a device or a growing file is refused too). `what` names the file for the message.
pub fn read_to_string_bounded(path: &Path, max: u64, what: &str) -> Result<String> {
    let f = std::fs::File::open(path).with_context(|| format!("reading {}", path.display()))?;
    let mut bytes = Vec::new();
    f.take(max + 1)
        .read_to_end(&mut bytes)
        .with_context(|| format!("reading {}", path.display()))?;
    if bytes.len() as u64 > max {
        bail!(
            "{} is larger than {} MiB: not a {what}",
            path.display(),
            max >> 20
        );
    }
    String::from_utf8(bytes)
        .map_err(|_| anyhow::anyhow!("{} is not text (not UTF-8): not a {what}", path.display()))
}

/// At most the first 60 characters of `s` on one line, `…` when cut: what an error quotes
/// of the input.
pub fn excerpt(s: &str) -> String {
    const MAX: usize = 60;
    let line = s.lines().next().unwrap_or("");
    let mut out: String = line
        .chars()
        .take(MAX)
        .map(|c| if c.is_control() { '?' } else { c })
        .collect();
    if line.chars().count() > MAX || s.lines().nth(1).is_some() {
        out.push('…');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_past_the_bound_is_refused_and_quoted_short() {
        let long = vec![b'0'; 10_000];
        let mut r = std::io::Cursor::new(long);
        let mut buf = Vec::new();
        let e = read_line_bounded(&mut r, &mut buf, 100).unwrap_err();
        assert!(e.to_string().contains("longer than 100 bytes"), "{e}");
        assert!(e.to_string().len() < 200, "{e}");
        let mut r = std::io::Cursor::new(b"ab\ncd".to_vec());
        buf.clear();
        assert_eq!(read_line_bounded(&mut r, &mut buf, 3).unwrap(), 3);
        assert_eq!(buf, b"ab\n");
        assert!(excerpt(&"x".repeat(1000)).chars().count() <= 61);
    }
}
