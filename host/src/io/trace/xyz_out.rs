//! Geosoft XYZ output for survey users: a [`std::io::Write`] adapter that takes the CSV
//! our writers produce and writes it as XYZ, line by line, so every writer (the trace
//! writer, `compensate`'s output) gets XYZ by the output's extension with the very same
//! printed values.
//!
//! Layout (read back by the XYZ reader, `read.rs`): `# key: value` metadata become
//! `/ key: value`, the header becomes `/ name name …` (the last comment before the data),
//! fields are separated by blanks, a missing value is `*`, and when there is a `line` /
//! `LINE` column a `Line NNNN` line opens each run of rows of one line (Geosoft's line
//! sections). The `flags` column, hexadecimal in CSV, is written as a decimal integer
//! (Geosoft channels are numbers). Text with blanks cannot be an XYZ field: an error.
use std::io::{self, Write};
use std::path::Path;

/// Whether `path` asks for XYZ output (`.xyz`, any case).
pub fn is_xyz_path(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("xyz"))
}

/// CSV in, XYZ out. Call [`XyzWriter::finish`] after the last write.
pub struct XyzWriter<W: Write> {
    out: W,
    /// The current incomplete CSV line.
    pending: Vec<u8>,
    header: Option<Vec<String>>,
    line_col: Option<usize>,
    flags_col: Option<usize>,
    current_line: Option<String>,
    fields: Vec<String>,
}

fn bad(msg: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidData, msg)
}

impl<W: Write> XyzWriter<W> {
    pub fn new(out: W) -> Self {
        XyzWriter {
            out,
            pending: Vec::new(),
            header: None,
            line_col: None,
            flags_col: None,
            current_line: None,
            fields: Vec::new(),
        }
    }

    /// Writes what is left (a last line without `\n`) and returns the inner writer.
    pub fn finish(mut self) -> io::Result<W> {
        if !self.pending.is_empty() {
            let line = std::mem::take(&mut self.pending);
            self.line(&line)?;
        }
        self.out.flush()?;
        Ok(self.out)
    }

    fn split_csv(&mut self, text: &str) -> io::Result<()> {
        self.fields.clear();
        let mut scratch = String::new();
        let fields = &mut self.fields;
        super::read::csv_fields(text, &mut scratch, |_, f| {
            fields.push(f.to_string());
            Ok(())
        })
        .map_err(|e| bad(e.to_string()))?;
        Ok(())
    }

    fn line(&mut self, raw: &[u8]) -> io::Result<()> {
        let text = std::str::from_utf8(raw).map_err(|_| bad("output is not UTF-8".into()))?;
        let text = text.trim_end_matches(['\r', '\n']);
        if text.trim().is_empty() {
            return Ok(());
        }
        if let Some(c) = text.strip_prefix('#') {
            if self.header.is_none() {
                writeln!(self.out, "/{c}")?;
            }
            return Ok(());
        }
        if self.header.is_none() {
            self.split_csv(text)?;
            let names = std::mem::take(&mut self.fields);
            if let Some(n) = names.iter().find(|n| n.contains(char::is_whitespace)) {
                return Err(bad(format!(
                    "column name '{n}' has blanks: an XYZ header cannot hold it"
                )));
            }
            self.line_col = names.iter().position(|n| n == "line" || n == "LINE");
            self.flags_col = names.iter().position(|n| n == "flags");
            writeln!(self.out, "/ {}", names.join(" "))?;
            self.header = Some(names);
            return Ok(());
        }
        self.split_csv(text)?;
        if let Some(k) = self.line_col {
            let v = self.fields.get(k).map(String::as_str).unwrap_or("");
            if !v.is_empty() && self.current_line.as_deref() != Some(v) {
                writeln!(self.out, "Line {v}")?;
                self.current_line = Some(v.to_string());
            }
        }
        let names = self.header.as_deref().unwrap_or_default();
        for (i, f) in self.fields.iter().enumerate() {
            if i > 0 {
                self.out.write_all(b" ")?;
            }
            if f.is_empty() {
                self.out.write_all(b"*")?;
            } else if Some(i) == self.flags_col && f.starts_with("0x") {
                let v = u32::from_str_radix(&f[2..], 16)
                    .map_err(|_| bad(format!("flags value '{f}' is not hexadecimal")))?;
                write!(self.out, "{v}")?;
            } else if f.contains(char::is_whitespace) {
                let col = names.get(i).map(String::as_str).unwrap_or("?");
                return Err(bad(format!(
                    "column '{col}': the value '{f}' has blanks, which an XYZ field cannot hold \
                     (write CSV instead)"
                )));
            } else {
                self.out.write_all(f.as_bytes())?;
            }
        }
        self.out.write_all(b"\n")
    }
}

impl<W: Write> Write for XyzWriter<W> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let mut rest = buf;
        while let Some(k) = rest.iter().position(|&b| b == b'\n') {
            if self.pending.is_empty() {
                self.line(&rest[..k])?;
            } else {
                self.pending.extend_from_slice(&rest[..k]);
                let line = std::mem::take(&mut self.pending);
                self.line(&line)?;
            }
            rest = &rest[k + 1..];
        }
        self.pending.extend_from_slice(rest);
        Ok(buf.len())
    }
    fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn convert(csv: &str) -> io::Result<String> {
        let mut w = XyzWriter::new(Vec::new());
        // In odd pieces, as a buffered writer would hand them over.
        for chunk in csv.as_bytes().chunks(7) {
            w.write_all(chunk)?;
        }
        Ok(String::from_utf8(w.finish()?).unwrap())
    }

    #[test]
    fn lines_open_sections_missing_is_a_star_flags_are_decimal() {
        let xyz = convert(
            "# model: tl16+field\nt,mag,flags,LINE,note\n\
             1,5.5,0x0010,1002.01,a\n2,,0x0000,1002.01,\n3,6,0x0208,1003.01,b\n",
        )
        .unwrap();
        assert_eq!(
            xyz,
            "/ model: tl16+field\n/ t mag flags LINE note\nLine 1002.01\n1 5.5 16 1002.01 a\n\
             2 * 0 1002.01 *\nLine 1003.01\n3 6 520 1003.01 b\n"
        );
    }

    #[test]
    fn text_with_blanks_is_refused() {
        let e = convert("t,segment\n1,\"a b\"\n").unwrap_err();
        assert!(e.to_string().contains("segment"), "{e}");
    }
}
