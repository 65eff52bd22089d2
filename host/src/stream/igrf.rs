//! The core field along a streamed flight (`input::igrf_column` and `input::fill_gaps`
//! one row at a time), shared by the second pass and the compensation pass.
use super::rows::Cols;
use super::stats::{year_of_date, year_of_doy, DateSource};
use crate::io::trace::rows::Row;
use anyhow::{Context, Result};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::os::unix::fs::FileExt;
use std::sync::Arc;

/// One interior run of missing values: the last finite row before it and the first after,
/// with their values.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Run {
    before: usize,
    after: usize,
    v_before: f64,
    v_after: f64,
}

const RUN_BYTES: usize = 32;
/// Runs read at a time by a [`GapCursor`] (4 KiB).
const RUNS_PER_READ: usize = 128;

impl Run {
    fn to_bytes(self) -> [u8; RUN_BYTES] {
        let mut b = [0u8; RUN_BYTES];
        b[..8].copy_from_slice(&(self.before as u64).to_le_bytes());
        b[8..16].copy_from_slice(&(self.after as u64).to_le_bytes());
        b[16..24].copy_from_slice(&self.v_before.to_le_bytes());
        b[24..].copy_from_slice(&self.v_after.to_le_bytes());
        b
    }

    fn from_bytes(b: &[u8]) -> Self {
        let word = |i: usize| {
            let mut w = [0u8; 8];
            w.copy_from_slice(&b[i..i + 8]);
            w
        };
        Self {
            before: u64::from_le_bytes(word(0)) as usize,
            after: u64::from_le_bytes(word(8)) as usize,
            v_before: f64::from_le_bytes(word(16)),
            v_after: f64::from_le_bytes(word(24)),
        }
    }
}

/// `input::fill_gaps` without the column, as pass 2 gathers it: the first and last finite
/// values, and each interior run of missing ones with the values around it written to an
/// unnamed temporary file (the system removes it however the run ends). A run is one GPS
/// dropout, and a long flight can hold millions: kept in memory they grew the streamed
/// pass by 32 B each (issue 21: streamed `compensate` in constant memory).
#[derive(Default)]
pub struct GapWriter {
    /// First, last and the count so far (its `runs` file is set at the end).
    fill: GapFill,
    out: Option<BufWriter<File>>,
}

impl GapWriter {
    fn push(&mut self, row: usize, v: f64) -> Result<()> {
        if !v.is_finite() {
            return Ok(());
        }
        let fill = &mut self.fill;
        if let Some((a, va)) = fill.last {
            if row > a + 1 {
                let run = Run {
                    before: a,
                    after: row,
                    v_before: va,
                    v_after: v,
                };
                let out = match &mut self.out {
                    Some(out) => out,
                    None => self.out.insert(BufWriter::new(
                        tempfile::tempfile()
                            .context("a temporary file for the core field's gaps")?,
                    )),
                };
                out.write_all(&run.to_bytes())?;
                fill.count += 1;
            }
        }
        fill.first.get_or_insert((row, v));
        fill.last = Some((row, v));
        Ok(())
    }

    /// The runs written, for the compensation pass to read.
    fn finish(self) -> Result<GapFill> {
        let mut fill = self.fill;
        if let Some(out) = self.out {
            let file = out
                .into_inner()
                .map_err(|e| e.into_error())
                .context("writing the core field's gaps")?;
            fill.runs = Some(Arc::new(file));
        }
        Ok(fill)
    }
}

/// The gathered fill (cheap to clone: the runs stay in their file); each reader of it
/// takes a [`GapCursor`].
#[derive(Clone, Debug, Default)]
pub struct GapFill {
    first: Option<(usize, f64)>,
    last: Option<(usize, f64)>,
    runs: Option<Arc<File>>,
    count: u64,
}

impl GapFill {
    pub fn cursor(&self) -> GapCursor {
        GapCursor {
            fill: self.clone(),
            next: 0,
            buffered: Vec::new(),
            at: 0,
        }
    }
}

/// Reads a [`GapFill`]'s runs forward as the rows go by: a pass asks rows in order, so it
/// holds one block of runs, not all of them.
pub struct GapCursor {
    fill: GapFill,
    /// The index of the first run not yet read from the file.
    next: u64,
    buffered: Vec<Run>,
    /// The run of `buffered` the rows have reached.
    at: usize,
}

impl GapCursor {
    /// The filled value of a missing row (NaN when the column has no value at all); rows
    /// in increasing order.
    pub(crate) fn value(&mut self, row: usize) -> Result<f64> {
        let (Some((f, vf)), Some((l, vl))) = (self.fill.first, self.fill.last) else {
            return Ok(f64::NAN);
        };
        if row < f {
            return Ok(vf);
        }
        if row > l {
            return Ok(vl);
        }
        loop {
            match self.buffered.get(self.at).copied() {
                Some(r) if r.after <= row => self.at += 1,
                Some(r) if r.before < row => {
                    let (a, b) = (r.before, r.after);
                    return Ok(
                        r.v_before + (r.v_after - r.v_before) * (row - a) as f64 / (b - a) as f64
                    );
                }
                Some(_) => return Ok(f64::NAN),
                None if !self.read_block()? => return Ok(f64::NAN),
                None => {}
            }
        }
    }

    /// The next block of runs; false when all were read.
    fn read_block(&mut self) -> Result<bool> {
        let Some(file) = &self.fill.runs else {
            return Ok(false);
        };
        let n = (self.fill.count - self.next).min(RUNS_PER_READ as u64) as usize;
        if n == 0 {
            return Ok(false);
        }
        let mut bytes = vec![0u8; n * RUN_BYTES];
        file.read_exact_at(&mut bytes, self.next * RUN_BYTES as u64)
            .context("reading the core field's gaps back")?;
        self.buffered = bytes.chunks_exact(RUN_BYTES).map(Run::from_bytes).collect();
        self.next += n as u64;
        self.at = 0;
        Ok(true)
    }
}

/// IGRF-14 along the flight, one row at a time (`input::igrf_column`): coefficients
/// recomputed only when the date changes.
#[derive(Default)]
pub struct IgrfScan {
    cache: Option<(f64, crate::flight::igrf::Coefficients)>,
    gaps: GapWriter,
    /// The gaps gathered, once [`finish`](Self::finish) was called.
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
            self.gaps.push(k, v)?;
        }
        Ok(())
    }

    /// Ends the scan: the gaps gathered become [`fill`](Self::fill).
    pub fn finish(&mut self) -> Result<()> {
        self.fill = std::mem::take(&mut self.gaps).finish()?;
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The cursor fills every row as `input::fill_gaps` does, across several blocks of runs
    /// (one missing row in three: ~400 runs, more than three reads).
    #[test]
    fn the_cursor_fills_as_the_column_is_filled() {
        let n = 1200;
        let truth: Vec<f64> = (0..n).map(|k| 50_000.0 + 0.37 * k as f64).collect();
        let column: Vec<f64> = (0..n)
            .map(|k| {
                if k % 3 == 1 || k < 5 || k > n - 4 {
                    f64::NAN
                } else {
                    truth[k]
                }
            })
            .collect();
        let mut writer = GapWriter::default();
        for (k, &v) in column.iter().enumerate() {
            writer.push(k, v).unwrap();
        }
        let fill = writer.finish().unwrap();
        let finite: Vec<usize> = (0..n).filter(|&k| column[k].is_finite()).collect();
        let runs = finite.windows(2).filter(|w| w[1] > w[0] + 1).count();
        assert!(runs > 3 * RUNS_PER_READ, "{runs} runs");
        assert_eq!(fill.count, runs as u64);
        let mut filled = column.clone();
        crate::flight::input::fill_gaps(&mut filled);
        for _ in 0..2 {
            // two cursors over one fill read the same
            let mut cursor = fill.cursor();
            for (k, &v) in column.iter().enumerate() {
                let got = if v.is_finite() {
                    v
                } else {
                    cursor.value(k).unwrap()
                };
                assert_eq!(got.to_bits(), filled[k].to_bits(), "row {k}");
            }
        }
    }

    #[test]
    fn an_empty_column_fills_nothing() {
        let fill = GapWriter::default().finish().unwrap();
        assert!(fill.cursor().value(3).unwrap().is_nan());
    }
}
