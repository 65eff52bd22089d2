//! The recorded-trace data contract (`docs/trace-format.md`): one row per scalar
//! sample, named columns, `#` metadata, missing values as NaN (never zero).
//!
//! Reading: [`read_trace`] / [`read_trace_from`] (CSV per the contract, the
//! whitespace-separated `.xyz` layout of public survey data, or a MagNav HDF5 file), with
//! a [`ColumnMap`] that renames file columns to canonical names. Writing: [`write_trace`]
//! / [`write_trace_to`] (CSV), or Geosoft XYZ by the `.xyz` extension.
//!
//! Column typing rule (decided once per column, streaming):
//! - `segment` is always text;
//! - the columns trace-format.md defines as numbers (`t`, `mag`, `flux_*`, `lat`, `lon`,
//!   `alt`, `vn`, `ve`, `vd`, `roll`, `pitch`, `yaw`, `base`, `igrf`) and every `truth_*`
//!   column are always numeric, so a bad value there is an error, never a silent text column;
//! - any other column is numeric if its first non-missing value parses as a number, text
//!   otherwise; once numeric, a later unparsable value is an error (naming file, line,
//!   column and text).
//!
//! Missing values: an empty field, `nan` (any case) or `*`; stored as NaN in numeric
//! columns and as an empty string in text columns. Infinite values are rejected.
//! Names are matched after applying the column map.

pub mod board_log;
mod error;
mod h5;
mod map;
mod read;
pub mod rows;
mod view;
mod write;
mod xyz_out;

pub use error::TraceError;
pub use h5::{has_hdf5_extension, is_hdf5, read_hdf5};
pub use map::{preset_hint, ColumnMap, PRESETS};
pub use read::{
    is_hdf5_path, progress_bar, read_trace, read_trace_from, read_trace_from_with, read_trace_with,
    Layout, ReadOptions,
};
pub use view::{aux_column_candidate, column_kind, required_columns, ColumnKind};
pub use write::{write_number, write_table, write_table_with, write_trace, write_trace_to};
pub use xyz_out::{is_xyz_path, XyzWriter};

/// A trace held column-wise in memory. Numeric columns are f64 with NaN for missing values;
/// text columns (e.g. `segment`) are kept as strings.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trace {
    /// `# key: value` metadata lines before the header, in file order.
    pub meta: Vec<(String, String)>,
    /// Numeric columns in file order: (name, values).
    pub numeric: Vec<(String, Vec<f64>)>,
    /// Text columns in file order: (name, values).
    pub text: Vec<(String, Vec<String>)>,
    /// The file and line each row was read from (`None` for a trace made in memory).
    pub origin: Option<RowOrigin>,
}

/// Where the rows of a trace came from, so that a message about a row can name the file
/// and line. Stored as the rows where the line numbering jumps (comments, blank lines,
/// XYZ line separators), one entry for a plain file.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RowOrigin {
    pub file: String,
    /// (row, its file line) for the first row and every row not on the line after its
    /// predecessor's.
    breaks: Vec<(usize, u64)>,
    rows: usize,
    last_line: u64,
}

impl RowOrigin {
    pub fn new(file: &str) -> Self {
        Self {
            file: file.to_string(),
            ..Default::default()
        }
    }

    /// Records that the next row was read from `line`.
    pub fn push(&mut self, line: u64) {
        if self.rows == 0 || line != self.last_line + 1 {
            self.breaks.push((self.rows, line));
        }
        self.rows += 1;
        self.last_line = line;
    }

    /// The file line of data row `row` (0-based).
    pub fn line(&self, row: usize) -> Option<u64> {
        if row >= self.rows {
            return None;
        }
        let k = self.breaks.partition_point(|(r, _)| *r <= row);
        let (r, l) = self.breaks.get(k.checked_sub(1)?)?;
        Some(l + (row - r) as u64)
    }
}

impl Trace {
    pub fn len(&self) -> usize {
        self.numeric
            .first()
            .map(|(_, v)| v.len())
            .or_else(|| self.text.first().map(|(_, v)| v.len()))
            .unwrap_or(0)
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    pub fn col(&self, name: &str) -> Option<&[f64]> {
        self.numeric
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_slice())
    }
    pub fn text_col(&self, name: &str) -> Option<&[String]> {
        self.text
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_slice())
    }
    pub fn meta(&self, key: &str) -> Option<&str> {
        self.meta
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }
    /// Adds or replaces a numeric column.
    pub fn set_col(&mut self, name: &str, values: Vec<f64>) {
        if let Some(slot) = self.numeric.iter_mut().find(|(n, _)| n == name) {
            slot.1 = values;
        } else {
            self.numeric.push((name.to_string(), values));
        }
    }
    /// Adds or replaces a text column.
    pub fn set_text_col(&mut self, name: &str, values: Vec<String>) {
        if let Some(slot) = self.text.iter_mut().find(|(n, _)| n == name) {
            slot.1 = values;
        } else {
            self.text.push((name.to_string(), values));
        }
    }
}
