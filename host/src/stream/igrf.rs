//! The core field along a streamed flight (`input::igrf_column` and `input::fill_gaps`
//! one row at a time), shared by the second pass and the compensation pass.
use super::rows::Cols;
use super::stats::{year_of_date, year_of_doy, DateSource};
use crate::io::trace::rows::Row;
use anyhow::Result;

/// `input::fill_gaps` without the column: the first and last finite values and each
/// interior run of missing ones with the values around it.
#[derive(Clone, Debug, Default)]
pub struct GapFill {
    first: Option<(usize, f64)>,
    last: Option<(usize, f64)>,
    runs: Vec<(usize, usize, f64, f64)>,
}

impl GapFill {
    fn push(&mut self, row: usize, v: f64) {
        if !v.is_finite() {
            return;
        }
        if let Some((a, va)) = self.last {
            if row > a + 1 {
                self.runs.push((a, row, va, v));
            }
        }
        self.first.get_or_insert((row, v));
        self.last = Some((row, v));
    }

    /// The filled value of a missing row (NaN when the column has no value at all).
    pub(crate) fn value(&self, row: usize) -> f64 {
        let (Some((f, vf)), Some((l, vl))) = (self.first, self.last) else {
            return f64::NAN;
        };
        if row < f {
            return vf;
        }
        if row > l {
            return vl;
        }
        let k = self.runs.partition_point(|r| r.1 <= row);
        match self.runs.get(k) {
            Some(&(a, b, va, vb)) if a < row && row < b => {
                va + (vb - va) * (row - a) as f64 / (b - a) as f64
            }
            _ => f64::NAN,
        }
    }
}

/// IGRF-14 along the flight, one row at a time (`input::igrf_column`): coefficients
/// recomputed only when the date changes.
#[derive(Default)]
pub struct IgrfScan {
    cache: Option<(f64, crate::flight::igrf::Coefficients)>,
    pub fill: GapFill,
    /// Least and greatest decimal year.
    pub years: (f64, f64),
    /// Least and greatest value (nT), for the change over a flight without a date.
    pub range_nt: (f64, f64),
    started: bool,
    /// Whether `fill` is gathered: only a computed core field is filled; without a date
    /// only the range is wanted, and the gaps (one entry per run of rows without a
    /// position) would be memory for nothing.
    fills: bool,
}

impl IgrfScan {
    /// A scan for pass 2; `fills`: gather the gaps to fill ([`GapFill`]).
    pub fn new(fills: bool) -> Self {
        Self {
            fills,
            ..Self::default()
        }
    }

    pub fn value(&mut self, year: f64, cols: &Cols, row: &Row) -> Result<f64> {
        let get = |c: Option<usize>| c.map_or(f64::NAN, |i| row.num(i));
        let (lat, lon, alt) = (get(cols.lat), get(cols.lon), get(cols.alt));
        if !(lat.is_finite() && lon.is_finite() && alt.is_finite() && year.is_finite()) {
            return Ok(f64::NAN);
        }
        if self.cache.as_ref().is_none_or(|(cy, _)| *cy != year) {
            self.cache = Some((
                year,
                crate::flight::igrf::Igrf::igrf14().coefficients_at(year)?,
            ));
        }
        Ok(self
            .cache
            .as_ref()
            .map_or(f64::NAN, |(_, c)| c.field(lat, lon, alt).total_nt))
    }

    pub fn push(&mut self, k: usize, year: f64, cols: &Cols, row: &Row) -> Result<()> {
        if !self.started {
            self.years = (f64::INFINITY, f64::NEG_INFINITY);
            self.range_nt = (f64::INFINITY, f64::NEG_INFINITY);
            self.started = true;
        }
        if year.is_finite() {
            self.years = (self.years.0.min(year), self.years.1.max(year));
        }
        let v = self.value(year, cols, row)?;
        if v.is_finite() {
            self.range_nt = (self.range_nt.0.min(v), self.range_nt.1.max(v));
        }
        if self.fills {
            self.fill.push(k, v);
        }
        Ok(())
    }
}

/// Decimal year of row `k` by the chosen source.
pub fn row_year(source: &DateSource, row: &Row, k: usize) -> Result<f64> {
    match source {
        DateSource::Given(y) => Ok(*y),
        DateSource::Column(c) => year_of_date(row.text(*c), k),
        DateSource::YearDoy(y, d, names) => year_of_doy(row.num(*y), row.num(*d), names, k),
    }
}
