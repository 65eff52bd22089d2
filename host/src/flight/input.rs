//! What happens to a trace between the file and the estimation, the same for every
//! command that reads one (`TraceInput`): row selection by line and time, the survey
//! date, and the core field (`igrf`) when the file does not carry it. Also the columns
//! carried through to `compensate`'s output.

use crate::flight::igrf::{decimal_year, parse_date, Igrf, MODEL_NAME};
use crate::io::trace::Trace;
use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};

/// Metadata keys `prepare` sets, so every later step (and `--json`) can say where the
/// core field came from.
pub const META_CORE_FIELD: &str = "core_field";
pub const META_CORE_FIELD_EPOCH: &str = "core_field_epoch";

/// Below this core-field change over a flight (nT) its omission is not worth a warning.
const NEGLIGIBLE_CORE_CHANGE_NT: f64 = 0.1;

/// Names the line column may have: the canonical one, then the SGL/Geosoft one.
const LINE_COLUMNS: &[&str] = &["line", "LINE"];

/// A row selection: `--lines` and `--time`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Selection {
    /// Line numbers/names as given (`1002.02`); matched as numbers on a numeric line
    /// column, as text on a text one.
    pub lines: Vec<String>,
    /// Inclusive `t` range; either side may be open.
    pub time_s: Option<(f64, f64)>,
}

impl Selection {
    /// From the command-line texts `1002.02,1003.01` and `T0:T1` (`T0:` / `:T1` open).
    pub fn parse(lines: Option<&str>, time: Option<&str>) -> Result<Self> {
        let lines = lines
            .map(|l| {
                l.split(',')
                    .map(|s| s.trim().to_string())
                    .filter(|s| !s.is_empty())
                    .collect::<Vec<_>>()
            })
            .unwrap_or_default();
        let time_s = time
            .map(|t| -> Result<(f64, f64)> {
                let (a, b) = t
                    .split_once(':')
                    .with_context(|| format!("--time '{t}': expected T0:T1 (seconds, `t`)"))?;
                let side = |s: &str, open: f64| -> Result<f64> {
                    let s = s.trim();
                    if s.is_empty() {
                        return Ok(open);
                    }
                    s.parse::<f64>()
                        .ok()
                        .filter(|v| v.is_finite())
                        .with_context(|| format!("--time '{t}': '{s}' is not a number"))
                };
                let (a, b) = (side(a, f64::NEG_INFINITY)?, side(b, f64::INFINITY)?);
                if a > b {
                    bail!("--time '{t}': the start is after the end");
                }
                Ok((a, b))
            })
            .transpose()?;
        Ok(Selection { lines, time_s })
    }

    pub fn is_empty(&self) -> bool {
        self.lines.is_empty() && self.time_s.is_none()
    }

    /// Indices of the selected rows.
    pub fn rows(&self, trace: &Trace) -> Result<Vec<usize>> {
        let n = trace.len();
        let mut keep = vec![true; n];
        if !self.lines.is_empty() {
            let name = LINE_COLUMNS
                .iter()
                .find(|c| trace.col(c).is_some() || trace.text_col(c).is_some())
                .with_context(|| {
                    format!(
                        "--lines needs a line column (`line` or `LINE`; name yours with \
                         --map line=COLUMN); the trace has: {}",
                        trace.column_names().join(", ")
                    )
                })?;
            let matches: Vec<bool> = if let Some(v) = trace.col(name) {
                let wanted = self
                    .lines
                    .iter()
                    .map(|l| {
                        l.parse::<f64>()
                            .with_context(|| format!("--lines: '{l}' is not a line number"))
                    })
                    .collect::<Result<Vec<f64>>>()?;
                v.iter().map(|x| wanted.contains(x)).collect()
            } else {
                let v = trace.text_col(name).unwrap_or_default();
                v.iter().map(|x| self.lines.contains(x)).collect()
            };
            for (k, m) in keep.iter_mut().zip(matches) {
                *k &= m;
            }
            if !keep.iter().any(|&k| k) {
                bail!(
                    "--lines {}: no row of column '{name}' has these lines; it has {}",
                    self.lines.join(","),
                    distinct_values(trace, name)
                );
            }
        }
        if let Some((a, b)) = self.time_s {
            let t = trace
                .col("t")
                .context("--time needs a `t` column (name yours with --map t=COLUMN)")?;
            for (k, &v) in keep.iter_mut().zip(t) {
                *k &= v >= a && v <= b;
            }
        }
        let rows: Vec<usize> = (0..n).filter(|&i| keep[i]).collect();
        if rows.is_empty() {
            bail!("the selection (--lines/--time) keeps no row");
        }
        Ok(rows)
    }
}

/// "1002.02, 1003.01 (2 lines)" for error messages.
fn distinct_values(trace: &Trace, name: &str) -> String {
    let mut seen: Vec<String> = Vec::new();
    let mut push = |s: String| {
        if !seen.contains(&s) {
            seen.push(s);
        }
    };
    if let Some(v) = trace.col(name) {
        v.iter()
            .filter(|x| x.is_finite())
            .for_each(|x| push(x.to_string()));
    } else if let Some(v) = trace.text_col(name) {
        v.iter().for_each(|x| push(x.clone()));
    }
    let shown: Vec<&str> = seen.iter().take(20).map(String::as_str).collect();
    format!(
        "{}{} ({} values)",
        shown.join(", "),
        if seen.len() > 20 { ", …" } else { "" },
        seen.len()
    )
}

/// The ground speed the Kalman filter assumes for a trace without positions or speed
/// (`--speed-mps`, else the coefficient file's): the speed and the warning that says so.
/// An error without one, or with one that is not a positive speed.
pub fn assumed_ground_speed(given_mps: Option<f64>) -> Result<(f64, String)> {
    match given_mps {
        Some(v) if v.is_finite() && v > 0.0 => Ok((
            v,
            format!(
                "the trace has no position: the anomaly is modelled in time, at the assumed ground speed of {v} m/s (--speed-mps)"
            ),
        )),
        Some(v) => bail!("--speed-mps must be a positive speed in m/s, not {v}"),
        None => bail!(
            "the trace has no position (lat/lon) and no ground speed: the Kalman filter's anomaly model needs the along-track distance. Give the aircraft's ground speed with --speed-mps (e.g. --speed-mps 60) to model the anomaly in time, or use --method tl"
        ),
    }
}

/// The trace restricted to `rows` (every column, metadata kept).
pub fn take_rows(trace: &Trace, rows: &[usize]) -> Trace {
    Trace {
        meta: trace.meta.clone(),
        numeric: trace
            .numeric
            .iter()
            .map(|(n, v)| (n.clone(), rows.iter().map(|&i| v[i]).collect()))
            .collect(),
        text: trace
            .text
            .iter()
            .map(|(n, v)| (n.clone(), rows.iter().map(|&i| v[i].clone()).collect()))
            .collect(),
        // the kept rows still name their own file lines in messages
        origin: trace.origin.as_ref().map(|o| {
            let mut kept = crate::io::trace::RowOrigin::new(&o.file);
            for &i in rows {
                kept.push(o.line(i).unwrap_or(0));
            }
            kept
        }),
    }
}

/// Decimal year of every row, from (first found): `--date YYYY-MM-DD`, a text `date`
/// column (YYYY-MM-DD), or year and day-of-year columns (`year`/`doy`, SGL's
/// `YEAR`/`DOY`). Day resolution: over a day the core field's secular change is < 0.5 nT
/// and nearly uniform, so the change along a flight, which is what the filter removes, is
/// unaffected. None when the trace has no date.
pub fn row_years(trace: &Trace, date: Option<&str>) -> Result<Option<(Vec<f64>, String)>> {
    let n = trace.len();
    if let Some(d) = date {
        let (y, doy) = parse_date(d).context("--date")?;
        return Ok(Some((vec![decimal_year(y, doy, 0.0); n], "--date".into())));
    }
    if let Some(col) = trace.text_col("date") {
        let mut out = Vec::with_capacity(n);
        for (i, v) in col.iter().enumerate() {
            if v.is_empty() {
                out.push(f64::NAN);
                continue;
            }
            let (y, doy) =
                parse_date(v).with_context(|| format!("column 'date', data row {}", i + 1))?;
            out.push(decimal_year(y, doy, 0.0));
        }
        if out.iter().any(|y| y.is_finite()) {
            return Ok(Some((out, "column date".into())));
        }
    }
    for (yc, dc) in [("year", "doy"), ("YEAR", "DOY")] {
        if let (Some(y), Some(d)) = (trace.col(yc), trace.col(dc)) {
            let mut out = Vec::with_capacity(n);
            for (i, (&y, &d)) in y.iter().zip(d).enumerate() {
                if !(y.is_finite() && d.is_finite()) {
                    out.push(f64::NAN);
                    continue;
                }
                if y.fract() != 0.0 || !(1.0..=366.0).contains(&d) {
                    bail!(
                        "columns '{yc}'/'{dc}', data row {}: {y}/{d} is not a year and day of year",
                        i + 1
                    );
                }
                out.push(decimal_year(y as i32, d.floor() as u32, 0.0));
            }
            // An all-missing pair (a file whose logger left them empty) is no date.
            if out.iter().any(|y| y.is_finite()) {
                return Ok(Some((out, format!("columns {yc}/{dc}"))));
            }
        }
    }
    Ok(None)
}

/// The core-field value (nT) at every row from IGRF-14; rows without a position or a
/// date are interpolated from their neighbours (the filter removes the change since the
/// first sample, so a gap must not read as a jump). Coefficients are computed once per
/// distinct date.
pub fn igrf_column(lat: &[f64], lon: &[f64], alt_m: &[f64], years: &[f64]) -> Result<Vec<f64>> {
    let model = Igrf::igrf14();
    let mut cache: Option<(f64, crate::flight::igrf::Coefficients)> = None;
    let mut out = vec![f64::NAN; lat.len()];
    for i in 0..lat.len() {
        let y = years[i];
        if !(lat[i].is_finite() && lon[i].is_finite() && alt_m[i].is_finite() && y.is_finite()) {
            continue;
        }
        if cache.as_ref().is_none_or(|(cy, _)| *cy != y) {
            cache = Some((y, model.coefficients_at(y)?));
        }
        if let Some((_, c)) = &cache {
            out[i] = c.field(lat[i], lon[i], alt_m[i]).total_nt;
        }
    }
    fill_gaps(&mut out);
    Ok(out)
}

/// Linear interpolation over NaN runs, the nearest value at the ends.
pub(crate) fn fill_gaps(v: &mut [f64]) {
    let idx: Vec<usize> = (0..v.len()).filter(|&i| v[i].is_finite()).collect();
    let (Some(&first), Some(&last)) = (idx.first(), idx.last()) else {
        return;
    };
    for i in 0..first {
        v[i] = v[first];
    }
    for i in last + 1..v.len() {
        v[i] = v[last];
    }
    for w in idx.windows(2) {
        let (a, b) = (w[0], w[1]);
        for i in a + 1..b {
            v[i] = v[a] + (v[b] - v[a]) * (i - a) as f64 / (b - a) as f64;
        }
    }
}

/// What `prepare` did about the core field, for stderr.
#[derive(Clone, Debug, PartialEq)]
pub enum CoreField {
    /// The file's own `igrf` column.
    FromFile,
    /// Computed: model name, first and last epoch (decimal years), where the date came from.
    Computed {
        model: String,
        epochs: (f64, f64),
        date_source: String,
    },
    /// Not removed; the change IGRF-14 at 2025.0 would show over the flight (nT).
    Missing { change_nt: Option<f64> },
}

/// Selects rows and adds the `igrf` column where the file has none and a date is known.
/// Sets `core_field` / `core_field_epoch` metadata.
pub fn prepare(
    mut trace: Trace,
    sel: &Selection,
    date: Option<&str>,
) -> Result<(Trace, CoreField)> {
    if !sel.is_empty() {
        let rows = sel.rows(&trace)?;
        trace = take_rows(&trace, &rows);
    }
    if trace.col("igrf").is_some() {
        trace
            .meta
            .push((META_CORE_FIELD.into(), "igrf column of the file".into()));
        return Ok((trace, CoreField::FromFile));
    }
    let (Some(lat), Some(lon), Some(alt)) = (trace.col("lat"), trace.col("lon"), trace.col("alt"))
    else {
        // Without a position there is nothing to compute; the estimation will say what
        // is missing.
        return Ok((trace, CoreField::Missing { change_nt: None }));
    };
    match row_years(&trace, date)? {
        Some((years, source)) => {
            let g = igrf_column(lat, lon, alt, &years)?;
            let finite = years.iter().copied().filter(|y| y.is_finite());
            let (y0, y1) = finite.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| {
                (a.min(y), b.max(y))
            });
            trace.set_col("igrf", g);
            trace
                .meta
                .push((META_CORE_FIELD.into(), format!("{MODEL_NAME} ({source})")));
            trace
                .meta
                .push((META_CORE_FIELD_EPOCH.into(), format!("{y0:.3}")));
            Ok((
                trace,
                CoreField::Computed {
                    model: MODEL_NAME.into(),
                    epochs: (y0, y1),
                    date_source: source,
                },
            ))
        }
        None => {
            let g = igrf_column(lat, lon, alt, &vec![2025.0; lat.len()])?;
            let finite = g.iter().copied().filter(|v| v.is_finite());
            let (lo, hi) = finite.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                (a.min(v), b.max(v))
            });
            let change_nt = (hi >= lo).then_some(hi - lo);
            Ok((trace, CoreField::Missing { change_nt }))
        }
    }
}

impl CoreField {
    /// One line for stderr; the warning when the core field is not removed.
    pub fn message(&self) -> Option<String> {
        match self {
            CoreField::FromFile => None,
            CoreField::Computed {
                model,
                epochs,
                date_source,
            } => Some(if (epochs.1 - epochs.0).abs() < 1e-9 {
                format!(
                    "core field: {model} at {:.3} (date from {date_source})",
                    epochs.0
                )
            } else {
                format!(
                    "core field: {model} at {:.3}–{:.3} (date from {date_source})",
                    epochs.0, epochs.1
                )
            }),
            // A flight that stays in one place loses nothing (e.g. a file without real
            // positions).
            CoreField::Missing { change_nt: Some(c) } if *c < NEGLIGIBLE_CORE_CHANGE_NT => None,
            CoreField::Missing { change_nt } => Some(format!(
                "warning: no `igrf` column and no date (a `date` column, YEAR/DOY columns or \
                 --date YYYY-MM-DD): the core field's change along the flight is not removed{}; \
                 it biases long lines and north–south flights (docs/trace-format.md)",
                match change_nt {
                    Some(c) =>
                        format!(" (here it changes by {c:.1} nT over the flight's positions)"),
                    None => String::new(),
                }
            )),
        }
    }
}

/// An extra column for `compensate`'s output.
#[derive(Clone, Debug, PartialEq)]
pub enum OutputValues {
    Num(Vec<f64>),
    Text(Vec<String>),
}

/// The output name of a carried input column: `in_` before a name an output column has.
pub fn carried_name(name: &str) -> String {
    const OUTPUT: &[&str] = &[
        "t",
        "mag",
        "interference",
        "compensated",
        "anomaly",
        "innovation",
        "flags",
        "igrf",
    ];
    if OUTPUT.contains(&name) {
        format!("in_{name}")
    } else {
        name.to_string()
    }
}

/// Whether input column `name` goes to `compensate`'s output: every one but `t` (the
/// output's own, the same values) and `igrf` (written once, as the core field used), so
/// the output is gridding-ready (t, lat, lon, compensated) without a join.
pub fn is_carried(name: &str) -> bool {
    name != "t" && name != "igrf"
}

/// The input columns carried to the output row for row, mapped (`lat`, `lon`, the
/// fluxgate, …) and unmapped (line, UTM X/Y, other channels, text labels), so nobody has
/// to join by time; first `igrf`, the core field used. Names that would collide with an
/// output column get an `in_` prefix (the input `mag` is `in_mag`).
pub fn carried_columns(trace: &Trace) -> Vec<(String, OutputValues)> {
    let rename = carried_name;
    let mut out = Vec::new();
    if let Some(g) = trace.col("igrf") {
        out.push(("igrf".to_string(), OutputValues::Num(g.to_vec())));
    }
    for (n, v) in &trace.numeric {
        if is_carried(n) {
            out.push((rename(n), OutputValues::Num(v.clone())));
        }
    }
    for (n, v) in &trace.text {
        out.push((rename(n), OutputValues::Text(v.clone())));
    }
    out
}

/// What a decimated calibration did (on stderr, and `decimated` in `--json`). Defined with
/// the input rather than in `stream::decimate`, which makes the copy, because the
/// calibration summary reports it and the calibration sits below the streaming layer.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Decimation {
    pub rows_in: usize,
    pub rows_out: usize,
    pub factor: usize,
    pub sample_rate_in_hz: f64,
    pub sample_rate_out_hz: f64,
    pub lowpass_taps: usize,
    /// Scalar glitches taken as missing before the low-pass.
    pub glitches_removed: usize,
}

impl Decimation {
    pub fn message(&self) -> String {
        format!(
            "the flight ({} rows at {:.4} Hz) is calibrated on an anti-aliased copy decimated \
             by {} to {:.4} Hz ({} rows; {} scalar glitch(es) taken out first) to keep memory \
             bounded (docs/streaming.md; --full-rate reads it whole)",
            self.rows_in,
            self.sample_rate_in_hz,
            self.factor,
            self.sample_rate_out_hz,
            self.rows_out,
            self.glitches_removed
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaps_are_interpolated() {
        let mut v = [f64::NAN, 1.0, f64::NAN, f64::NAN, 4.0, f64::NAN];
        fill_gaps(&mut v);
        assert_eq!(v, [1.0, 1.0, 2.0, 3.0, 4.0, 4.0]);
    }

    #[test]
    fn time_ranges_parse() {
        let s = Selection::parse(None, Some("10:20.5")).unwrap();
        assert_eq!(s.time_s, Some((10.0, 20.5)));
        let s = Selection::parse(None, Some(":5")).unwrap();
        assert_eq!(s.time_s, Some((f64::NEG_INFINITY, 5.0)));
        assert!(Selection::parse(None, Some("5")).is_err());
        assert!(Selection::parse(None, Some("9:5")).is_err());
    }
}
