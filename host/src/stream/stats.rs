//! The first two streaming passes: the whole-flight figures the in-memory path takes from
//! its columns (sample rate, main-field direction, tie point, date, core-field gaps, input
//! checks, scalar noise), each computed exactly as `Flight::from_trace`, `input::prepare`,
//! `qc::inputs::check` and `kf::estimate_noise_nt` compute them, from one row at a
//! time.
use super::rows::RowSample;
use crate::flight::position::{PositionChecker, PositionFault};
use crate::flight::{FieldDirection, TieDetector};
use anyhow::Result;
use magcomp_core::compensator::TiePoint;
use std::collections::{BTreeMap, HashMap, VecDeque};

/// A median in bounded memory: the element at index `len / 2` of the sorted values, as the
/// in-memory code takes it.
///
/// Exact (counts of distinct values) while there are at most [`EXACT_DISTINCT`] distinct
/// values — a 1 kHz flight's time steps take a handful, a scalar written to 1e-4 nT a few
/// thousand third differences — so such runs equal the in-memory path bit for bit. Past
/// that (full-precision input: ~46 B per row before, ~1 GB for a 6 h 1 kHz flight) the
/// counts move into a log-bucketed histogram (DDSketch's buckets): the median is then
/// within a relative error of [`MEDIAN_RELATIVE_ERROR`] (0.1 %) of the exact one, in at
/// most ~30 000 buckets (values 1e-15 … 1e15; smaller ones count in the lowest bucket).
#[derive(Clone, Debug, Default)]
pub struct StreamMedian {
    counts: HashMap<u64, u64>,
    /// Bucket index → count, once the exact counts are given up.
    buckets: Option<BTreeMap<i32, u64>>,
    zeros: u64,
    n: u64,
}

/// Distinct values counted exactly (~2 MB of counts) before the histogram takes over.
pub const EXACT_DISTINCT: usize = 1 << 16;

/// The histogram's bound on the median's relative error.
pub const MEDIAN_RELATIVE_ERROR: f64 = 1e-3;

/// γ = (1 + α)/(1 − α): a bucket (γ^(i−1), γ^i] holds values within α of 2γ^i/(γ + 1).
fn gamma() -> f64 {
    (1.0 + MEDIAN_RELATIVE_ERROR) / (1.0 - MEDIAN_RELATIVE_ERROR)
}

fn bucket_of(v: f64) -> i32 {
    (v.clamp(1e-15, 1e15).ln() / gamma().ln()).ceil() as i32
}

fn bucket_value(i: i32) -> f64 {
    let g = gamma();
    2.0 * g.powi(i) / (g + 1.0)
}

impl StreamMedian {
    /// `v` must be ≥ 0 (its bit pattern then sorts as the value).
    pub fn push(&mut self, v: f64) {
        self.n += 1;
        if let Some(b) = self.buckets.as_mut() {
            if v > 0.0 {
                *b.entry(bucket_of(v)).or_default() += 1;
            } else {
                self.zeros += 1;
            }
            return;
        }
        *self.counts.entry(v.to_bits()).or_default() += 1;
        if self.counts.len() > EXACT_DISTINCT {
            let mut b = BTreeMap::new();
            for (k, c) in self.counts.drain() {
                let v = f64::from_bits(k);
                if v > 0.0 {
                    *b.entry(bucket_of(v)).or_default() += c;
                } else {
                    self.zeros += c;
                }
            }
            self.counts.shrink_to_fit();
            self.buckets = Some(b);
        }
    }
    pub fn len(&self) -> u64 {
        self.n
    }
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }
    /// Distinct values (exact counting) or buckets (the histogram) held.
    pub fn distinct(&self) -> usize {
        self.buckets
            .as_ref()
            .map_or(self.counts.len(), BTreeMap::len)
    }
    /// Whether the median is exact (no histogram yet).
    pub fn is_exact(&self) -> bool {
        self.buckets.is_none()
    }
    pub fn median(&self) -> Option<f64> {
        if self.n == 0 {
            return None;
        }
        let mid = self.n / 2;
        if let Some(b) = &self.buckets {
            if self.zeros > mid {
                return Some(0.0);
            }
            let mut seen = self.zeros;
            for (&i, &c) in b {
                seen += c;
                if seen > mid {
                    return Some(bucket_value(i));
                }
            }
            return None;
        }
        let mut keys: Vec<(u64, u64)> = self.counts.iter().map(|(k, c)| (*k, *c)).collect();
        keys.sort_unstable();
        let mut seen = 0;
        for (k, c) in keys {
            seen += c;
            if seen > mid {
                return Some(f64::from_bits(k));
            }
        }
        None
    }
}

/// `despike::glitches` over a stream: a sample is judged once its `half` neighbours on
/// either side are in (or the flight has ended). Holds `2·half + 1` raw values.
pub struct Despiker {
    half: usize,
    /// (row, raw mag) of the window; the front is the oldest.
    window: VecDeque<(usize, f64)>,
    /// Next row to judge.
    next: usize,
    neighbours: Vec<f64>,
    /// The rows around the one judged, in order (NaN where none).
    rows: Vec<f64>,
}

impl Despiker {
    pub fn new(sample_rate_hz: f64) -> Self {
        let half = crate::signal::despike::half_window(sample_rate_hz);
        Self {
            half,
            window: VecDeque::with_capacity(2 * half + 2),
            next: 0,
            neighbours: Vec::with_capacity(2 * half + 1),
            rows: Vec::with_capacity(2 * half + 1),
        }
    }

    pub fn delay(&self) -> usize {
        self.half
    }

    /// Adds row `row`'s raw scalar; returns the judged (row, is_glitch) if one is due.
    pub fn push(&mut self, row: usize, mag: f64) -> Option<(usize, bool)> {
        self.window.push_back((row, mag));
        if row >= self.next + self.half {
            let out = self.judge(self.next);
            self.next += 1;
            self.trim();
            return Some(out);
        }
        None
    }

    /// The rows not yet judged, at the end of the flight.
    pub fn finish(&mut self) -> Vec<(usize, bool)> {
        let mut out = Vec::new();
        while let Some(&(last, _)) = self.window.back() {
            if self.next > last {
                break;
            }
            out.push(self.judge(self.next));
            self.next += 1;
            self.trim();
        }
        out
    }

    fn trim(&mut self) {
        while self
            .window
            .front()
            .is_some_and(|(r, _)| r + self.half < self.next)
        {
            self.window.pop_front();
        }
    }

    fn judge(&mut self, i: usize) -> (usize, bool) {
        // The rows around `i` in order, a missing row as NaN (the window holds each row
        // once, oldest first).
        let lo = i.saturating_sub(self.half);
        let last = self.window.back().map_or(i, |(r, _)| *r);
        self.rows.clear();
        self.rows.resize(last.min(i + self.half) + 1 - lo, f64::NAN);
        for &(r, m) in &self.window {
            if let Some(slot) = r.checked_sub(lo).and_then(|k| self.rows.get_mut(k)) {
                *slot = m;
            }
        }
        let glitch = crate::signal::despike::judge(&self.rows, i - lo, &mut self.neighbours);
        (i, glitch)
    }
}

/// A row's verdicts: whether its scalar, and whether its fluxgate vector, is a glitch.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Verdict {
    pub row: usize,
    pub scalar: bool,
    pub flux: bool,
}

/// `Flight::from_trace`'s glitch tests over a stream: the scalar's
/// ([`crate::signal::despike::glitches`]), then the fluxgate's
/// ([`crate::signal::despike::flux_glitches`]) on its modulus `|B_F|` and on `|B_F| − mag`.
/// In memory that second series has the scalar's glitches taken out (NaN), so it is fed
/// only once the scalar's verdict is in: a row is judged `2·half` rows after it came in.
/// (Fed the raw scalar, a scalar glitch was also a fluxgate one, and its neighbours were
/// judged against a different window.)
pub struct GlitchJudge {
    scalar: Despiker,
    modulus: Despiker,
    against_scalar: Despiker,
    /// Rows not yet judged by the scalar's rule: (`|B_F|`, mag), in order.
    unjudged: VecDeque<(f64, f64)>,
    /// Rows judged by the scalar and the modulus, waiting for `|B_F| − mag`: (scalar
    /// glitch, modulus glitch), in order.
    half_judged: VecDeque<(bool, bool)>,
}

impl GlitchJudge {
    pub fn new(sample_rate_hz: f64) -> Self {
        Self {
            scalar: Despiker::new(sample_rate_hz),
            modulus: Despiker::new(sample_rate_hz),
            against_scalar: Despiker::new(sample_rate_hz),
            unjudged: VecDeque::new(),
            half_judged: VecDeque::new(),
        }
    }

    /// Adds a row (its scalar and fluxgate as read, f64 as in memory); returns the
    /// verdicts on a row when one is due.
    pub fn push(&mut self, row: usize, mag_nt: f64, flux_nt: [f64; 3]) -> Option<Verdict> {
        let modulus = crate::signal::despike::modulus_nt(&flux_nt);
        self.unjudged.push_back((modulus, mag_nt));
        let s = self.scalar.push(row, mag_nt);
        let m = self.modulus.push(row, modulus);
        debug_assert_eq!(s.map(|v| v.0), m.map(|v| v.0));
        self.half_way(s?, m?)
    }

    /// The rows still in the windows, at the end of the flight.
    pub fn finish(&mut self) -> Vec<Verdict> {
        let (s, m) = (self.scalar.finish(), self.modulus.finish());
        let mut out: Vec<Verdict> = s
            .into_iter()
            .zip(m)
            .filter_map(|(s, m)| self.half_way(s, m))
            .collect();
        for a in self.against_scalar.finish() {
            out.extend(self.verdict(a));
        }
        out
    }

    /// A row judged by the scalar and the modulus: on to `|B_F| − mag`.
    fn half_way(&mut self, (row, scalar): (usize, bool), m: (usize, bool)) -> Option<Verdict> {
        let (modulus, mag_nt) = self.unjudged.pop_front()?;
        self.half_judged.push_back((scalar, m.1));
        let mag_nt = if scalar { f64::NAN } else { mag_nt };
        let a = self.against_scalar.push(row, modulus - mag_nt)?;
        self.verdict(a)
    }

    fn verdict(&mut self, (row, against): (usize, bool)) -> Option<Verdict> {
        let (scalar, modulus) = self.half_judged.pop_front()?;
        Some(Verdict {
            row,
            scalar,
            flux: modulus || against,
        })
    }
}

/// Up to `MAX_LISTED` examples and a total, for a warning that names lines.
#[derive(Clone, Debug)]
pub struct Listed<T> {
    pub first: Vec<(u64, T)>,
    pub total: usize,
}

impl<T> Default for Listed<T> {
    fn default() -> Self {
        Self {
            first: Vec::new(),
            total: 0,
        }
    }
}

impl<T> Listed<T> {
    pub const MAX_LISTED: usize = 5;
    pub fn push(&mut self, line: u64, v: T) {
        if self.first.len() < Self::MAX_LISTED {
            self.first.push((line, v));
        }
        self.total += 1;
    }
}

/// Pass 1: what needs no sample rate.
#[derive(Default)]
pub struct FirstPass {
    pub rows: usize,
    pub dt: StreamMedian,
    pub mag_finite: usize,
    pub mag_range: (f64, f64),
    pub first_mag: Option<f64>,
    pub flux_field_rows: usize,
    pub flux_range: [(f64, f64); 3],
    /// First finite value of each model channel that is relative (and of `base`).
    pub channel_offsets: Vec<Option<f64>>,
    pub base0: Option<f64>,
    pub has_position: bool,
    pub has_speed: bool,
    pub positions: PositionChecker,
    pub position_faults: Listed<PositionFault>,
    pub tie: TieDetector,
    pub field_dir: FieldDirection,
    pub prev_t: Option<f64>,
    /// Whether this pass looks for the tie point (its cells grow with the ground covered;
    /// several sensors share one track, so only the first looks).
    pub finds_tie: bool,
}

impl FirstPass {
    pub fn new(channels: usize) -> Self {
        Self {
            mag_range: (f64::MAX, f64::MIN),
            flux_range: [(f64::MAX, f64::MIN); 3],
            channel_offsets: vec![None; channels],
            finds_tie: true,
            ..Default::default()
        }
    }

    pub fn push(&mut self, rs: &mut RowSample) {
        let s = &mut rs.sample;
        if let Some(t0) = self.prev_t {
            self.dt.push(s.t_s - t0);
        }
        self.prev_t = Some(s.t_s);
        self.rows += 1;
        if rs.mag_nt.is_finite() {
            self.mag_finite += 1;
            self.mag_range = (
                self.mag_range.0.min(rs.mag_nt),
                self.mag_range.1.max(rs.mag_nt),
            );
            self.first_mag.get_or_insert(rs.mag_nt);
        }
        let b = s.flux_nt.map(f64::from);
        let m = (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt();
        if m.is_finite() && m >= 1_000.0 {
            self.flux_field_rows += 1;
        }
        for (k, r) in self.flux_range.iter_mut().enumerate() {
            if b[k].is_finite() {
                *r = (r.0.min(b[k]), r.1.max(b[k]));
            }
        }
        for (o, v) in self.channel_offsets.iter_mut().zip(&rs.raw_channels) {
            if v.is_finite() {
                o.get_or_insert(*v);
            }
        }
        if rs.raw_base.is_finite() {
            self.base0.get_or_insert(rs.raw_base);
        }
        if let Some(a) = rs.raw_attitude {
            self.field_dir.push(rs.raw_flux, a);
        }
        let line = rs.line;
        self.positions
            .check(s, |f| self.position_faults.push(line, f));
        if s.lat_deg.is_finite() && s.lon_deg.is_finite() {
            self.has_position = true;
        }
        if s.ground_speed_mps.is_finite() {
            self.has_speed = true;
        }
        if self.finds_tie {
            self.tie.push(s.t_s, s.lat_deg, s.lon_deg);
        }
    }

    pub fn sample_rate_hz(&self) -> Option<f64> {
        self.dt.median().map(|d| 1.0 / d)
    }

    pub fn tie_point(&self, meta: &[(String, String)]) -> Option<TiePoint> {
        let m = |k: &str| {
            meta.iter()
                .find(|(key, _)| key == k)
                .and_then(|(_, v)| v.trim().parse().ok())
        };
        match (m("cal_centre_lat"), m("cal_centre_lon")) {
            (Some(lat_deg), Some(lon_deg)) => Some(TiePoint { lat_deg, lon_deg }),
            _ => self.tie.finish(),
        }
    }
}

/// Pass 2 (needs the sample rate): glitches, time gaps, the scalar's noise.
pub struct SecondPass {
    /// Bad fluxgate rows are taken out of the scalar too (as `Flight::from_trace` does
    /// before the noise is estimated).
    judge: GlitchJudge,
    pub gap_limit_s: f64,
    pub prev_t: Option<f64>,
    /// (data row, gap length, t before) of the first gaps, and their count.
    pub gaps: Vec<(usize, f64, f64)>,
    pub gap_count: usize,
    pub glitches: Listed<f64>,
    /// Despiked scalar of the last 4 judged rows, for the third difference.
    last4: VecDeque<f64>,
    pub d3: StreamMedian,
    pending: VecDeque<(usize, u64, f64)>,
}

impl SecondPass {
    pub fn new(sample_rate_hz: f64, median_dt_s: f64) -> Self {
        Self {
            judge: GlitchJudge::new(sample_rate_hz),
            gap_limit_s: crate::qc::gaps::GAP_FACTOR * median_dt_s,
            prev_t: None,
            gaps: Vec::new(),
            gap_count: 0,
            glitches: Listed::default(),
            last4: VecDeque::with_capacity(4),
            d3: StreamMedian::default(),
            pending: VecDeque::new(),
        }
    }

    pub fn push(&mut self, row: usize, line: u64, t_s: f64, mag_nt: f64, flux_nt: [f64; 3]) {
        if let Some(t0) = self.prev_t {
            if t_s - t0 > self.gap_limit_s {
                if self.gaps.len() < 3 {
                    self.gaps.push((row, t_s - t0, t0));
                }
                self.gap_count += 1;
            }
        }
        self.prev_t = Some(t_s);
        self.pending.push_back((row, line, mag_nt));
        if let Some(v) = self.judge.push(row, mag_nt, flux_nt) {
            self.judged(v);
        }
    }

    pub fn finish(&mut self) {
        for v in self.judge.finish() {
            self.judged(v);
        }
    }

    fn judged(&mut self, verdict: Verdict) {
        let Some((r, line, mag)) = self.pending.pop_front() else {
            return;
        };
        debug_assert_eq!(r, verdict.row);
        if verdict.scalar {
            self.glitches.push(line, mag);
        }
        let v = if verdict.scalar || verdict.flux {
            f64::NAN
        } else {
            mag
        };
        if self.last4.len() == 4 {
            self.last4.pop_front();
        }
        self.last4.push_back(v);
        if self.last4.len() == 4 {
            let w = &self.last4;
            let d = w[3] - 3.0 * w[2] + 3.0 * w[1] - w[0];
            if d.is_finite() {
                self.d3.push(d.abs());
            }
        }
    }

    /// `kf::estimate_noise_nt` of the despiked scalar.
    pub fn noise_nt(&self) -> Option<f64> {
        if self.d3.len() < 16 {
            return None;
        }
        self.d3.median().map(|m| m * 1.4826 / 20f64.sqrt())
    }
}

/// `input::prepare`'s core field from a date: the decimal year of a row by the source
/// the first pass chose.
#[derive(Clone, Debug, PartialEq)]
pub enum DateSource {
    Given(f64),
    Column(usize),
    YearDoy(usize, usize, String),
}

/// Per candidate date source: any finite year, and the first bad value.
#[derive(Default, Clone, Debug)]
pub struct DateScan {
    pub any: bool,
    pub error: Option<String>,
}

/// Decimal year of `text` in a `date` column (NaN when empty).
pub fn year_of_date(text: &str, row: usize) -> Result<f64> {
    use anyhow::Context;
    if text.is_empty() {
        return Ok(f64::NAN);
    }
    let (y, doy) = crate::flight::igrf::parse_date(text)
        .with_context(|| format!("column 'date', data row {}", row + 1))?;
    Ok(crate::flight::igrf::decimal_year(y, doy, 0.0))
}

/// Decimal year of a year/day-of-year pair (NaN when either is missing).
pub fn year_of_doy(y: f64, d: f64, names: &str, row: usize) -> Result<f64> {
    if !(y.is_finite() && d.is_finite()) {
        return Ok(f64::NAN);
    }
    if y.fract() != 0.0 || !(1.0..=366.0).contains(&d) {
        let (yc, dc) = names.split_once('/').unwrap_or((names, ""));
        anyhow::bail!(
            "columns '{yc}'/'{dc}', data row {}: {y}/{d} is not a year and day of year",
            row + 1
        );
    }
    Ok(crate::flight::igrf::decimal_year(
        y as i32,
        d.floor() as u32,
        0.0,
    ))
}

/// `Flight::from_trace`'s glitch warning from the listed glitches.
pub fn glitch_warning(label: &str, g: &Listed<f64>) -> Option<String> {
    if g.total == 0 {
        return None;
    }
    let mut msg = format!(
        "{}: {} scalar glitch(es) far outside their neighbours, taken as missing (samples flagged MAG_MISSING):",
        label,
        g.total
    );
    for (line, v) in &g.first {
        msg.push_str(&format!("\n  line {line}: mag = {v}"));
    }
    if g.total > g.first.len() {
        msg.push_str(&format!("\n  … and {} more", g.total - g.first.len()));
    }
    Some(msg)
}

/// The stream's fluxgate-glitch warning (the in-memory path's words).
pub fn flux_glitch_warning(label: &str, g: &Listed<[f32; 3]>) -> Option<String> {
    if g.total == 0 {
        return None;
    }
    let mut msg = format!(
        "{}: {} fluxgate sample(s) inconsistent with their neighbours or with the scalar \
         (|B_F| − mag), taken as missing (samples flagged MAG_MISSING, vector bridged from \
         the neighbours):",
        label, g.total
    );
    for (line, v) in &g.first {
        msg.push_str(&format!(
            "\n  line {line}: flux = ({}, {}, {})",
            v[0], v[1], v[2]
        ));
    }
    if g.total > g.first.len() {
        msg.push_str(&format!("\n  … and {} more", g.total - g.first.len()));
    }
    Some(msg)
}

/// `position::faults_warning` from the listed faults.
pub fn faults_warning(label: &str, f: &Listed<PositionFault>) -> Option<String> {
    if f.total == 0 {
        return None;
    }
    let mut msg = format!(
        "{}: {} unusable position(s), treated as missing (samples flagged NO_GPS):",
        label, f.total
    );
    for (line, v) in &f.first {
        msg.push_str(&format!("\n  line {line}: {v}"));
    }
    if f.total > f.first.len() {
        msg.push_str(&format!("\n  … and {} more", f.total - f.first.len()));
    }
    Some(msg)
}

#[cfg(test)]
mod tests {
    use super::{GlitchJudge, Verdict};
    use crate::signal::despike;

    /// The stream's verdicts are `Flight::from_trace`'s on every row, whatever the
    /// flight's length (a short one is judged at its end only): scalar and fluxgate
    /// glitches on one row, side by side, in the first and last rows.
    #[test]
    fn the_stream_judges_every_row_as_in_memory() {
        for n in [3, 7, 12, 40, 200] {
            let mut mag: Vec<f64> = (0..n).map(|i| 52_000.0 + 0.3 * i as f64).collect();
            let mut flux: Vec<[f64; 3]> = (0..n)
                .map(|i| [20_000.0 + i as f64, 1_000.0, 47_000.0])
                .collect();
            for &i in &[0, n / 2, n - 1] {
                flux[i][2] = 0.0;
            }
            mag[n / 2] += 4000.0;
            mag[(n / 2 + 1).min(n - 1)] -= 4000.0;
            let scalar = despike::glitches(&mag, 10.0);
            let mut despiked = mag.clone();
            for &i in &scalar {
                despiked[i] = f64::NAN;
            }
            let bad = despike::flux_glitches(&flux, &despiked, 10.0);
            if n >= 12 {
                // Found in memory: the cases are there (the second scalar glitch's own
                // vector is good, its |B_F| − mag NaN in memory).
                assert_eq!(scalar, [n / 2, n / 2 + 1], "{n} rows");
                assert_eq!(bad, [0, n / 2, n - 1], "{n} rows");
            }
            let expected: Vec<Verdict> = (0..n)
                .map(|row| Verdict {
                    row,
                    scalar: scalar.contains(&row),
                    flux: bad.contains(&row),
                })
                .collect();
            let mut judge = GlitchJudge::new(10.0);
            let mut got: Vec<Verdict> = (0..n)
                .filter_map(|i| judge.push(i, mag[i], flux[i]))
                .collect();
            got.extend(judge.finish());
            assert_eq!(got, expected, "{n} rows");
        }
    }
}
