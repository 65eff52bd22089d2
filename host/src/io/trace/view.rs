//! Typed view of a trace for the estimation code: required columns, fluxgate vectors,
//! auxiliary channels, validation.
use super::{Trace, TraceError};

/// Columns every trace must have (trace-format.md), in contract order.
pub fn required_columns() -> &'static [&'static str] {
    &[
        "t", "mag", "flux_x", "flux_y", "flux_z", "lat", "lon", "alt",
    ]
}

/// Numeric columns defined by trace-format.md (required and optional).
const DEFINED_NUMERIC: &[&str] = &[
    "t",
    "mag",
    "flux_x",
    "flux_y",
    "flux_z",
    "lat",
    "lon",
    "alt",
    "vn",
    "ve",
    "vd",
    "roll",
    "pitch",
    "yaw",
    "base",
    "igrf",
    "ground_speed",
];

/// How the reader types a column, from its canonical name alone.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ColumnKind {
    /// Always numeric: a bad value is an error.
    Numeric,
    /// Always text (`segment`).
    Text,
    /// Numeric if its first non-missing value parses as a number, else text.
    Auto,
}

/// The typing rule for a canonical column name (see the module docs).
pub fn column_kind(name: &str) -> ColumnKind {
    if name == "segment" {
        ColumnKind::Text
    } else if DEFINED_NUMERIC.contains(&name) || name.starts_with("truth_") {
        ColumnKind::Numeric
    } else {
        ColumnKind::Auto
    }
}

/// True if a numeric column of this name is a candidate auxiliary channel: not defined by
/// trace-format.md, not `segment`, not `truth_*`.
pub fn aux_column_candidate(name: &str) -> bool {
    column_kind(name) == ColumnKind::Auto
}

impl Trace {
    /// Checks that every named column exists (numeric or text). The error lists all the
    /// missing ones and every column the trace has.
    pub fn require(&self, names: &[&str]) -> Result<(), TraceError> {
        let missing: Vec<String> = names
            .iter()
            .filter(|n| self.col(n).is_none() && self.text_col(n).is_none())
            .map(|n| n.to_string())
            .collect();
        if missing.is_empty() {
            Ok(())
        } else {
            Err(TraceError::MissingColumns {
                missing,
                available: self.column_names(),
            })
        }
    }

    /// `require(required_columns())`.
    pub fn require_contract(&self) -> Result<(), TraceError> {
        self.require(required_columns())
    }

    /// All column names, numeric first then text, each in file order.
    pub fn column_names(&self) -> Vec<String> {
        self.numeric
            .iter()
            .map(|(n, _)| n.clone())
            .chain(self.text.iter().map(|(n, _)| n.clone()))
            .collect()
    }

    /// Fluxgate vectors `[flux_x, flux_y, flux_z]` (nT, body frame) per row, or None if any
    /// of the three columns is absent. Missing values stay NaN.
    pub fn flux(&self) -> Option<Vec<[f64; 3]>> {
        let (x, y, z) = (
            self.col("flux_x")?,
            self.col("flux_y")?,
            self.col("flux_z")?,
        );
        Some(
            x.iter()
                .zip(y)
                .zip(z)
                .map(|((&x, &y), &z)| [x, y, z])
                .collect(),
        )
    }

    /// Names of the numeric columns that are candidate auxiliary channels (currents,
    /// voltages, rpm...): not defined by trace-format.md and not `truth_*`. File order.
    pub fn aux_columns(&self) -> Vec<&str> {
        self.numeric
            .iter()
            .map(|(n, _)| n.as_str())
            .filter(|n| aux_column_candidate(n))
            .collect()
    }

    /// Names of the `truth_*` columns (simulated data only; for scoring, never estimation).
    pub fn truth_columns(&self) -> Vec<&str> {
        self.numeric
            .iter()
            .map(|(n, _)| n.as_str())
            .filter(|n| n.starts_with("truth_"))
            .collect()
    }

    /// Checks that `t` is present on every row and strictly increasing. The error names the
    /// 1-based data row (the reader does the same check with file line numbers).
    /// A trace without a `t` column is an error too.
    pub fn check_time(&self) -> Result<(), TraceError> {
        let t = self.col("t").ok_or_else(|| TraceError::MissingColumns {
            missing: vec!["t".into()],
            available: self.column_names(),
        })?;
        let mut prev = f64::NEG_INFINITY;
        for (i, &v) in t.iter().enumerate() {
            if v.is_nan() || v <= prev {
                return Err(TraceError::Time {
                    file: String::new(),
                    line: i as u64 + 1,
                    value: v,
                    previous: prev,
                });
            }
            prev = v;
        }
        Ok(())
    }

    /// True if all columns have the same length (what `write_trace` needs).
    pub fn is_rectangular(&self) -> bool {
        let n = self.len();
        self.numeric.iter().all(|(_, v)| v.len() == n)
            && self.text.iter().all(|(_, v)| v.len() == n)
    }
}
