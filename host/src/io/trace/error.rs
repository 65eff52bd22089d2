use std::fmt;

/// Everything that can go wrong reading, checking or writing a trace. Each message names
/// the file and line (where there is one) so a user can open the file at the fault.
#[derive(Debug)]
pub enum TraceError {
    /// I/O failure opening, reading or writing `file`.
    Io {
        file: String,
        source: std::io::Error,
    },
    /// The file has no header line (empty, or only comments).
    NoHeader { file: String },
    /// A header problem: empty or duplicate column name.
    Header {
        file: String,
        line: u64,
        msg: String,
    },
    /// A data row has a different number of fields than the header.
    FieldCount {
        file: String,
        line: u64,
        expected: usize,
        found: usize,
    },
    /// A value in a numeric column is not a number.
    Parse {
        file: String,
        line: u64,
        column: String,
        text: String,
    },
    /// A line is not valid UTF-8.
    Utf8 { file: String, line: u64 },
    /// `t` is missing or not strictly increasing. `line` is the file line when read from a
    /// file, or the 1-based data row when checked in memory (`file` is empty then).
    Time {
        file: String,
        line: u64,
        value: f64,
        previous: f64,
    },
    /// The `--map` text itself is malformed, or does not fit the file.
    Map { msg: String },
    /// Required columns are absent.
    MissingColumns {
        missing: Vec<String>,
        available: Vec<String>,
    },
    /// The trace cannot be written as a valid file (ragged columns, bad names...).
    Write { msg: String },
    /// An HDF5 file that is not one, or whose datasets do not form a trace.
    Hdf5 { file: String, msg: String },
    /// A board output log that holds no trace (no `$MCRAW` lines).
    BoardLog { file: String, msg: String },
}

impl fmt::Display for TraceError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TraceError::Io { file, source } => write!(f, "{file}: {source}"),
            TraceError::NoHeader { file } => {
                write!(
                    f,
                    "{file}: no header line (the file is empty or only comments)"
                )
            }
            TraceError::Header { file, line, msg } => write!(f, "{file}:{line}: header: {msg}"),
            TraceError::FieldCount {
                file,
                line,
                expected,
                found,
            } => write!(
                f,
                "{file}:{line}: expected {expected} fields (as in the header), found {found}"
            ),
            TraceError::Parse {
                file,
                line,
                column,
                text,
            } => write!(
                f,
                "{file}:{line}: column '{column}': cannot parse \"{}\" as a number",
                text.escape_debug()
            ),
            TraceError::Utf8 { file, line } => write!(f, "{file}:{line}: not valid UTF-8 text"),
            TraceError::Time {
                file,
                line,
                value,
                previous,
            } => {
                let at = if file.is_empty() {
                    format!("row {line}")
                } else {
                    format!("{file}:{line}")
                };
                if value.is_nan() {
                    write!(
                        f,
                        "{at}: column 't' is missing (t must be present on every row)"
                    )
                } else {
                    write!(
                        f,
                        "{at}: column 't' must be strictly increasing: {value} follows {previous}"
                    )
                }
            }
            TraceError::Map { msg } => write!(f, "column map: {msg}"),
            TraceError::MissingColumns { missing, available } => {
                let quoted: Vec<String> = missing.iter().map(|m| format!("'{m}'")).collect();
                write!(
                    f,
                    "missing required column{} {}; the trace has: {}",
                    if missing.len() == 1 { "" } else { "s" },
                    quoted.join(", "),
                    if available.is_empty() {
                        "(no columns)".to_string()
                    } else {
                        available.join(", ")
                    }
                )?;
                let have: Vec<&str> = available.iter().map(String::as_str).collect();
                write!(f, "{}", super::map::preset_hint(&have))
            }
            TraceError::Write { msg } => write!(f, "cannot write trace: {msg}"),
            TraceError::Hdf5 { file, msg } => write!(f, "{file}: {msg}"),
            TraceError::BoardLog { file, msg } => write!(f, "{file}: {msg}"),
        }
    }
}

impl std::error::Error for TraceError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            TraceError::Io { source, .. } => Some(source),
            _ => None,
        }
    }
}
