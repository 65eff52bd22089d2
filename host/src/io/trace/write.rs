//! CSV writer: metadata, header, rows. Numbers use the shortest decimal form that
//! round-trips the f64 exactly, never in scientific notation, so values read back bit-exact and
//! a spreadsheet shows plain decimals. NaN is written as an empty field.
use super::{Trace, TraceError};
use std::io::Write;
use std::path::Path;

/// Writes `trace` to a file, atomically ([`crate::io::output`]): on an error nothing
/// (or the previous file) is left under `path`. A `.xyz` path gets Geosoft XYZ
/// ([`super::XyzWriter`]), anything else CSV.
pub fn write_trace(path: &Path, trace: &Trace) -> anyhow::Result<()> {
    let name = path.display().to_string();
    write_table(path, |w| {
        write_trace_to(w, trace).map_err(|e| rename_io(e, &name))?;
        Ok(())
    })
}

fn rename_io(e: TraceError, name: &str) -> TraceError {
    match e {
        TraceError::Io { source, .. } => TraceError::Io {
            file: name.to_string(),
            source,
        },
        other => other,
    }
}

/// Text that the reader gets back unchanged in a field: quoted when it holds a comma or
/// quote, or has surrounding blanks the reader would trim.
fn write_text(w: &mut impl Write, s: &str) -> std::io::Result<()> {
    if s.contains([',', '"']) || s.trim_ascii() != s || s.starts_with('#') {
        write!(w, "\"{}\"", s.replace('"', "\"\""))
    } else {
        w.write_all(s.as_bytes())
    }
}

/// Writes `trace` as CSV to any writer (buffer it: this writes field by field).
/// Column order: numeric columns, then text columns, each in trace order.
pub fn write_trace_to<W: Write>(mut w: W, trace: &Trace) -> Result<(), TraceError> {
    let bad = |msg: String| TraceError::Write { msg };
    if !trace.is_rectangular() {
        return Err(bad("columns have different lengths".into()));
    }
    for (k, v) in &trace.meta {
        let key_ok = !k.is_empty()
            && k.chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.');
        if !key_ok {
            return Err(bad(format!(
                "metadata key '{k}' must be one word of [A-Za-z0-9_.-]"
            )));
        }
        if v.contains(['\n', '\r']) {
            return Err(bad(format!("metadata '{k}' value contains a line break")));
        }
    }
    let names = trace.column_names();
    if names.is_empty() {
        return Err(bad("the trace has no columns".into()));
    }
    for (i, n) in names.iter().enumerate() {
        if n.is_empty()
            || n.contains([',', '"', '\n', '\r'])
            || n.trim_ascii() != n
            || n.starts_with('#')
        {
            return Err(bad(format!(
                "column name '{n}' cannot be written in a CSV header"
            )));
        }
        if names[..i].contains(n) {
            return Err(bad(format!("duplicate column name '{n}'")));
        }
    }
    for (n, col) in &trace.text {
        if let Some(v) = col.iter().find(|v| v.contains(['\n', '\r'])) {
            return Err(bad(format!(
                "column '{n}': value {v:?} contains a line break"
            )));
        }
    }
    let io = |source| TraceError::Io {
        file: String::new(),
        source,
    };
    (|| -> std::io::Result<()> {
        for (k, v) in &trace.meta {
            writeln!(w, "# {k}: {v}")?;
        }
        writeln!(w, "{}", names.join(","))?;
        let numeric: Vec<&[f64]> = trace.numeric.iter().map(|(_, v)| v.as_slice()).collect();
        let text: Vec<&[String]> = trace.text.iter().map(|(_, v)| v.as_slice()).collect();
        let lone_column = names.len() == 1;
        let mut fast = zmij::Buffer::new();
        for row in 0..trace.len() {
            let mut first = true;
            for col in &numeric {
                if !first {
                    w.write_all(b",")?;
                }
                first = false;
                let v = col[row];
                if v.is_finite() {
                    write_number(&mut w, &mut fast, v)?;
                } else if lone_column {
                    // An empty line would be skipped as blank: spell the missing value.
                    w.write_all(b"nan")?;
                }
            }
            for col in &text {
                if !first {
                    w.write_all(b",")?;
                }
                first = false;
                write_text(&mut w, &col[row])?;
            }
            w.write_all(b"\n")?;
        }
        Ok(())
    })()
    .map_err(io)
}

/// A finite number as [`write_trace_to`] writes it (a streamed table's rows match it);
/// infinities are not data the reader accepts: written as missing (nothing).
pub fn write_number(
    w: &mut (impl Write + ?Sized),
    fast: &mut zmij::Buffer,
    v: f64,
) -> std::io::Result<()> {
    if !v.is_finite() {
        return Ok(());
    }
    // zmij gives the same shortest round-trip digits ~3x faster than Display, but
    // switches to exponent form for very large/small magnitudes; those (rare in traces)
    // go through Display, which never does.
    let s = fast.format_finite(v);
    if s.contains(['e', 'E']) {
        write!(w, "{v}")
    } else {
        w.write_all(s.as_bytes())
    }
}

/// Writes a table to `path` atomically: `f` writes CSV, which a `.xyz` path receives
/// as Geosoft XYZ (`XyzWriter`: same values, `*` for missing, `Line` sections).
pub fn write_table(
    path: &Path,
    f: impl FnOnce(&mut dyn Write) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    write_table_with(path, f)
}

/// As [`write_table`], for a writer that returns a value (the streamed compensation's
/// figures).
pub fn write_table_with<T>(
    path: &Path,
    f: impl FnOnce(&mut dyn Write) -> anyhow::Result<T>,
) -> anyhow::Result<T> {
    crate::io::output::write_with(path, |w| {
        if super::xyz_out::is_xyz_path(path) {
            let mut x = super::xyz_out::XyzWriter::new(w);
            let v = f(&mut x)?;
            x.finish()?;
            Ok(v)
        } else {
            f(w)
        }
    })
}
