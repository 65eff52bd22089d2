//! Calibrating a long, fast flight on an anti-aliased, decimated copy read row by row.
//!
//! Calibration and diagnosis hold the whole flight in memory (~1.2 KB/row for
//! `calibrate`, ~2.4 KB/row for `diagnose`): a 6 h flight at 1 kHz (21.6 M rows) would need
//! 26 / 52 GB. Above [`DECIMATE_ABOVE_ROWS`] rows sampled faster than
//! [`DECIMATED_RATE_HZ`], the flight is read in two streaming passes (count and time step,
//! then the low-pass and decimation) into a copy at ≤ 100 Hz, and that copy is calibrated
//! or diagnosed. `compensate` then applies the coefficients to the full-rate file with the
//! streaming apply (`stream::compensate`).
//!
//! Why 100 Hz is honest: the interference lives at the manoeuvres (0.1–1 Hz) and the eddy
//! terms' derivatives of the direction cosines follow the attitude (a few Hz at most), and
//! the Kalman filter's centred derivative spans several samples at any rate. The
//! low-pass is a Blackman-windowed sinc cut at half the output rate, 7·M + 1 taps for a
//! factor M (71 at 1 kHz): its gain is 1 within 1e-5 up to 2 Hz and 5e-5 up to 10 Hz (at
//! 1 kHz → 100 Hz), and below 3e-4 (−70 dB) from 0.9 × the output rate, so nothing folds
//! into 0–10 Hz. It is symmetric (no
//! delay): each output keeps the time of its centre row. Positions, altitude, attitude,
//! velocities, the core field, line and date columns are taken at the centre row (yaw
//! wraps, lines are labels); the scalar, the fluxgate and every other numeric column are
//! filtered. Text columns are the centre row's. Scalar glitches are taken out before the
//! filter (the streaming despiker), or one +4000 nT value would become a 70-sample bump.
//! The filter does not reach across a time gap (more than 1.5 median steps) or rows left
//! out by `--lines`/`--time`: near such an edge its taps are cut symmetrically (the first
//! row of a stretch is taken as it is).
use super::rows::{Cols, RowFilter};
use super::stats::{Despiker, StreamMedian};
use super::StreamInput;
use crate::flight::input::{Decimation, Selection};
use crate::io::progress::Progress;
use crate::io::trace::rows::{for_each_row, Kind, RowsHeader};
use crate::io::trace::{ColumnMap, ReadOptions, RowOrigin, Trace};
use anyhow::{Context, Result};
use std::collections::VecDeque;

/// A flight with more rows than this (sampled faster than [`DECIMATED_RATE_HZ`]) is
/// calibrated and diagnosed on a decimated copy: in memory it would take ≥ 2.4 GB for
/// `calibrate` and ≥ 4.8 GB for `diagnose`.
pub const DECIMATE_ABOVE_ROWS: usize = 2_000_000;

/// The decimated copy's highest sample rate.
pub const DECIMATED_RATE_HZ: f64 = 100.0;

/// The decimation factor for a flight of `rows` at `sample_rate_hz`: None when it stays
/// at its own rate.
pub fn factor_for(rows: usize, sample_rate_hz: f64, above_rows: usize) -> Option<usize> {
    let fast = sample_rate_hz.is_finite() && sample_rate_hz > DECIMATED_RATE_HZ * (1.0 + 1e-9);
    if rows <= above_rows || !fast {
        return None;
    }
    Some((sample_rate_hz / DECIMATED_RATE_HZ - 1e-9).ceil() as usize)
}

/// The low-pass for decimation by `factor`: a Blackman-windowed sinc cut at half the
/// output rate, `7·factor + 1` taps, unit sum.
pub fn lowpass_taps(factor: usize) -> Vec<f64> {
    let half = (7 * factor).div_ceil(2);
    let len = 2 * half + 1;
    let fc = 0.5 / factor as f64; // cycles per input sample
    let pi = std::f64::consts::PI;
    let mut w: Vec<f64> = (0..len)
        .map(|i| {
            let k = i as f64 - half as f64;
            let sinc = if k == 0.0 {
                2.0 * fc
            } else {
                (2.0 * pi * fc * k).sin() / (pi * k)
            };
            let x = i as f64 / (len - 1) as f64;
            let blackman = 0.42 - 0.5 * (2.0 * pi * x).cos() + 0.08 * (4.0 * pi * x).cos();
            sinc * blackman
        })
        .collect();
    let sum: f64 = w.iter().sum();
    w.iter_mut().for_each(|v| *v /= sum);
    w
}

/// Pass 1: the selected rows, the median time step (`StreamMedian`) and the columns' final kinds.
pub fn scan(input: &StreamInput<'_>, quiet: bool) -> Result<(usize, f64, Vec<Kind>)> {
    let map = column_map(input)?;
    let mut filter = RowFilter::new(Selection::parse(input.lines, input.time)?);
    let mut cols: Option<Cols> = None;
    let mut dt = StreamMedian::default();
    let mut prev_t = f64::NAN;
    let mut progress = Progress::new("decimation pass 1/2 (rows, time step)", quiet);
    let head = for_each_row(input.trace, &map, ReadOptions::default(), |row| {
        let c = match &mut cols {
            Some(c) => c,
            None => cols.insert(Cols::resolve(row.names, &[])?),
        };
        if !filter.keep(row, c)? {
            return Ok(());
        }
        progress.tick();
        let t = row.num(c.t);
        if prev_t.is_finite() && t > prev_t {
            dt.push(t - prev_t);
        }
        prev_t = t;
        Ok(())
    })
    .with_context(|| format!("reading {}", input.trace.display()))?;
    progress.done();
    let cols = cols.with_context(|| format!("{}: no data rows", input.trace.display()))?;
    filter.finish(&head, &cols)?;
    Ok((filter.kept, dt.median().unwrap_or(f64::NAN), head.kinds))
}

fn column_map(input: &StreamInput<'_>) -> Result<ColumnMap> {
    Ok(match input.map {
        Some(m) => ColumnMap::parse(m)?,
        None => ColumnMap::new(),
    })
}

/// A selected row held in the filter's window.
#[derive(Default)]
struct Held {
    /// Selected-row number (the despiker's).
    k: usize,
    /// Contiguous stretch it belongs to (a new one after a gap or left-out rows).
    stretch: u64,
    /// Position in its stretch (every `factor`-th, from 0, is kept).
    pos: usize,
    line: u64,
    nums: Vec<f64>,
    texts: Vec<String>,
}

/// Numeric columns taken at the centre row rather than filtered.
const SAMPLED: [&str; 14] = [
    "t",
    "lat",
    "lon",
    "alt",
    "vn",
    "ve",
    "vd",
    "roll",
    "pitch",
    "yaw",
    "igrf",
    "ground_speed",
    "year",
    "doy",
];

struct Decimator {
    factor: usize,
    taps: Vec<f64>,
    half: usize,
    /// Per column: filtered (else the centre row's value).
    filtered: Vec<bool>,
    numeric: Vec<bool>,
    mag: usize,
    window: VecDeque<Held>,
    spare: Vec<Held>,
    /// Index in `window` of the next row to decide on.
    next: usize,
    /// Rows with k ≤ this have been judged by the despiker.
    judged: Option<usize>,
    /// Stretches that have ended (a later row started a new one).
    closed_through: Option<u64>,
    out_nums: Vec<Vec<f64>>,
    out_texts: Vec<Vec<String>>,
    origin: RowOrigin,
    glitches: usize,
}

impl Decimator {
    fn ready(&self, i: usize) -> bool {
        let c = &self.window[i];
        let stretch_done = self.closed_through.is_some_and(|s| s >= c.stretch);
        let last_in_window = self
            .window
            .iter()
            .rev()
            .find(|h| h.stretch == c.stretch)
            .map_or(c.k, |h| h.k);
        let need = if stretch_done {
            last_in_window
        } else {
            c.k + self.half
        };
        (stretch_done || last_in_window >= c.k + self.half)
            && self.judged.is_some_and(|j| j >= need)
    }

    /// Emits (or skips) every row whose window is complete, and forgets rows no longer
    /// needed.
    fn drain(&mut self) {
        while self.next < self.window.len() && self.ready(self.next) {
            if self.window[self.next].pos.is_multiple_of(self.factor) {
                self.emit(self.next);
            }
            self.next += 1;
        }
        let keep_from = self.window.get(self.next).map(|h| h.k);
        while let Some(front) = self.window.front() {
            let old = match keep_from {
                Some(k) => front.k + self.half < k,
                None => true,
            };
            if !old {
                break;
            }
            let h = self.window.pop_front().expect("front exists");
            self.spare.push(h);
            self.next -= 1;
        }
    }

    fn emit(&mut self, i: usize) {
        let c = &self.window[i];
        self.origin.push(c.line);
        // The window holds consecutive rows (row k at k − k0) and a stretch is contiguous;
        // near its edge the taps are cut symmetrically, so a ramp stays unbiased.
        let k0 = self.window[0].k;
        let ci = c.k - k0;
        let from = c.k.saturating_sub(self.half).max(k0) - k0;
        let to = (c.k + self.half - k0).min(self.window.len() - 1);
        let first = (from..=ci)
            .find(|&j| self.window[j].stretch == c.stretch)
            .unwrap_or(ci);
        let last = (ci..=to)
            .rev()
            .find(|&j| self.window[j].stretch == c.stretch)
            .unwrap_or(ci);
        let reach = (ci - first).min(last - ci);
        let (lo, hi) = (ci - reach, ci + reach);
        for col in 0..self.out_nums.len() {
            if !self.numeric[col] {
                self.out_texts[col].push(c.texts[col].clone());
                continue;
            }
            if !self.filtered[col] {
                self.out_nums[col].push(c.nums[col]);
                continue;
            }
            let (mut sum, mut weight, mut all) = (0.0, 0.0, 0.0);
            for h in self.window.range(lo..=hi) {
                let w = self.taps[h.k + self.half - c.k];
                all += w;
                let v = h.nums[col];
                if v.is_finite() {
                    sum += w * v;
                    weight += w;
                }
            }
            // Fewer than half the taps' weight: too little to stand for the sample.
            self.out_nums[col].push(if weight >= 0.5 * all {
                sum / weight
            } else {
                f64::NAN
            });
        }
    }

    fn judge(&mut self, (k, glitch): (usize, bool)) {
        if glitch {
            if let Some(h) = self.window.iter_mut().find(|h| h.k == k) {
                h.nums[self.mag] = f64::NAN;
                self.glitches += 1;
            }
        }
        self.judged = Some(k);
    }
}

/// Pass 2: the selected rows low-passed and decimated by `factor` into a trace (the
/// selection applied, no core field added yet: `input::prepare` does that).
pub fn read_decimated(
    input: &StreamInput<'_>,
    factor: usize,
    (rows_in, median_dt_s, kinds): (usize, f64, &[Kind]),
    quiet: bool,
) -> Result<(Trace, Decimation)> {
    let map = column_map(input)?;
    let mut filter = RowFilter::new(Selection::parse(input.lines, input.time)?);
    let taps = lowpass_taps(factor);
    let half = taps.len() / 2;
    let sample_rate_hz = 1.0 / median_dt_s;
    let mut despiker = Despiker::new(sample_rate_hz);
    let mut cols: Option<Cols> = None;
    let mut dec: Option<Decimator> = None;
    let (mut k, mut stretch, mut pos) = (0usize, 0u64, 0usize);
    let (mut prev_t, mut prev_index) = (f64::NAN, None::<usize>);
    let mut progress = Progress::new("decimation pass 2/2 (low-pass, decimate)", quiet);
    let file = input.trace.display().to_string();
    let head: RowsHeader = for_each_row(input.trace, &map, ReadOptions::default(), |row| {
        let c = match &mut cols {
            Some(c) => c,
            None => cols.insert(Cols::resolve(row.names, &[])?),
        };
        if !filter.keep(row, c)? {
            return Ok(());
        }
        progress.tick();
        let d = dec.get_or_insert_with(|| {
            let n = row.names.len();
            // Column kinds are final only after a whole pass: the first pass's.
            let line = c.line;
            let filtered = row
                .names
                .iter()
                .enumerate()
                .map(|(i, name)| !SAMPLED.contains(&name.as_str()) && Some(i) != line)
                .collect();
            Decimator {
                factor,
                taps: taps.clone(),
                half,
                filtered,
                numeric: (0..n).map(|i| kinds.get(i) != Some(&Kind::Text)).collect(),
                mag: c.mag,
                window: VecDeque::with_capacity(taps.len() + 64),
                spare: Vec::new(),
                next: 0,
                judged: None,
                closed_through: None,
                out_nums: vec![Vec::new(); n],
                out_texts: vec![Vec::new(); n],
                origin: RowOrigin::new(&file),
                glitches: 0,
            }
        });
        let t = row.num(c.t);
        let gap = prev_t.is_finite() && t - prev_t > 1.5 * median_dt_s;
        let skipped = prev_index.is_some_and(|p| row.index != p + 1);
        if k > 0 && (gap || skipped) {
            d.closed_through = Some(stretch);
            stretch += 1;
            pos = 0;
        }
        prev_t = t;
        prev_index = Some(row.index);
        let mut h = d.spare.pop().unwrap_or_default();
        h.k = k;
        h.stretch = stretch;
        h.pos = pos;
        h.line = row.line;
        h.nums.clear();
        h.texts.resize(row.names.len(), String::new());
        for i in 0..row.names.len() {
            h.nums.push(row.num(i));
            h.texts[i].clear();
            h.texts[i].push_str(row.text(i));
        }
        let mag = row.num(c.mag);
        d.window.push_back(h);
        if let Some(j) = despiker.push(k, mag) {
            d.judge(j);
        }
        d.drain();
        k += 1;
        pos += 1;
        Ok(())
    })
    .with_context(|| format!("reading {}", input.trace.display()))?;
    progress.done();
    let cols = cols.with_context(|| format!("{}: no data rows", input.trace.display()))?;
    filter.finish(&head, &cols)?;
    let mut d = dec.context("no rows selected")?;
    for j in despiker.finish() {
        d.judge(j);
    }
    d.closed_through = Some(stretch);
    d.drain();
    let mut trace = Trace {
        meta: head.meta.clone(),
        origin: Some(d.origin),
        ..Trace::default()
    };
    let mut rows_out = 0;
    for (i, name) in head.names.iter().enumerate() {
        if kinds.get(i) == Some(&Kind::Text) {
            let v = std::mem::take(&mut d.out_texts[i]);
            rows_out = v.len();
            trace.text.push((name.clone(), v));
        } else {
            let v = std::mem::take(&mut d.out_nums[i]);
            rows_out = v.len();
            trace.numeric.push((name.clone(), v));
        }
    }
    let rate_out = sample_rate_hz / factor as f64;
    Ok((
        trace,
        Decimation {
            rows_in,
            rows_out,
            factor,
            sample_rate_in_hz: sample_rate_hz,
            sample_rate_out_hz: rate_out,
            lowpass_taps: taps.len(),
            glitches_removed: d.glitches,
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::{factor_for, lowpass_taps};

    fn gain(taps: &[f64], f_per_sample: f64) -> f64 {
        let half = (taps.len() / 2) as f64;
        taps.iter()
            .enumerate()
            .map(|(i, w)| w * (2.0 * std::f64::consts::PI * f_per_sample * (i as f64 - half)).cos())
            .sum::<f64>()
            .abs()
    }

    /// 1 kHz → 100 Hz: flat to 1e-5 up to 2 Hz (the manoeuvres), 5e-5 up to 10 Hz,
    /// ≤ 3e-4 (−70 dB) from 90 Hz on.
    #[test]
    fn lowpass_keeps_the_band_and_stops_what_would_alias() {
        let taps = lowpass_taps(10);
        assert_eq!(taps.len(), 71);
        for (f_hz, tol) in [
            (0.0, 1e-12),
            (0.1, 1e-5),
            (1.0, 1e-5),
            (2.0, 1e-5),
            (5.0, 5e-5),
            (10.0, 5e-5),
        ] {
            let g = gain(&taps, f_hz / 1000.0);
            assert!((g - 1.0).abs() < tol, "{f_hz} Hz: gain {g}");
        }
        for f_hz in (90..=500).step_by(5) {
            let g = gain(&taps, f_hz as f64 / 1000.0);
            assert!(g < 3e-4, "{f_hz} Hz: gain {g}");
        }
    }

    /// A 1 kHz file with a 2 s time gap and a +4000 nT glitch: no output value mixes the
    /// two sides of the gap (the scalar steps by 1000 nT there), each stretch gives
    /// ⌈rows / 10⌉ outputs at its own rows' times, the glitch leaves no trace, and a ramp
    /// (the fluxgate) comes out unbiased: the filter is symmetric.
    #[test]
    fn stretches_stay_apart_and_glitches_are_taken_out() {
        use super::{read_decimated, scan};
        use crate::stream::StreamInput;
        let path =
            std::env::temp_dir().join(format!("magcomp-decimate-{}.csv", std::process::id()));
        let mut text = String::from("t,mag,flux_x,flux_y,flux_z,segment\n");
        let mut times = Vec::new();
        for i in 0..3000usize {
            // rows 0..1234 then, after a 2 s gap, rows 1234..3000
            let t = i as f64 * 0.001 + if i >= 1234 { 2.0 } else { 0.0 };
            let mag =
                if i >= 1234 { 51_000.0 } else { 50_000.0 } + if i == 600 { 4000.0 } else { 0.0 };
            text.push_str(&format!("{t:.3},{mag},{},0,40000,line\n", 10.0 * t));
            times.push(t);
        }
        std::fs::write(&path, text).unwrap();
        let input = StreamInput {
            trace: &path,
            map: None,
            lines: None,
            time: None,
            date: None,
        };
        let (rows, dt, kinds) = scan(&input, true).unwrap();
        assert_eq!(rows, 3000);
        let (trace, d) = read_decimated(&input, 10, (rows, dt, &kinds), true).unwrap();
        std::fs::remove_file(&path).ok();
        assert_eq!(d.rows_out, 124 + 177);
        assert_eq!(trace.len(), 301);
        assert_eq!(d.glitches_removed, 1);
        let (t, mag, fx) = (
            trace.col("t").unwrap(),
            trace.col("mag").unwrap(),
            trace.col("flux_x").unwrap(),
        );
        for (j, (&t, &m)) in t.iter().zip(mag).enumerate() {
            let want = if j < 124 { 50_000.0 } else { 51_000.0 };
            assert!((m - want).abs() < 1e-6, "output {j} (t = {t}): {m}");
            assert!(
                (fx[j] - 10.0 * t).abs() < 1e-9,
                "output {j}: ramp {} at t = {t}",
                fx[j]
            );
        }
        assert_eq!(t[123], times[1230]);
        assert_eq!(t[124], times[1234]);
        assert_eq!(trace.text_col("segment").unwrap()[0], "line");
    }

    #[test]
    fn only_long_fast_flights_are_decimated() {
        assert_eq!(factor_for(21_600_000, 1000.0, 2_000_000), Some(10));
        assert_eq!(factor_for(21_600_000, 250.0, 2_000_000), Some(3));
        assert_eq!(factor_for(21_600_000, 100.0, 2_000_000), None);
        assert_eq!(factor_for(1_000_000, 1000.0, 2_000_000), None);
        assert_eq!(factor_for(10, 1000.0, 0), Some(10));
    }
}
