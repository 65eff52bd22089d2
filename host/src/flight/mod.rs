//! A trace turned into what the core consumes: one `AlignedSample` per row, with the
//! absolute field kept exact, plus what the host needs around it (segments, truth,
//! tie point, main-field direction).

pub mod igrf;
pub mod input;
pub mod position;

use crate::io::trace::Trace;
use anyhow::{bail, Context, Result};
use magcomp_core::compensator::TiePoint;
use magcomp_core::epoch::EARTH_RADIUS_M;
use magcomp_core::{AlignedSample, MagCounts, MAX_AUX};
use std::collections::HashMap;

/// Columns every trace must have. Position (`lat`, `lon`, `alt`) is optional: Tolles–Lawson
/// needs none, and the Kalman filter models the anomaly in time at an assumed ground speed
/// when there is none (`--speed-mps`); it is never silently frozen in place.
pub const REQUIRED: &[&str] = &["t", "mag", "flux_x", "flux_y", "flux_z"];

#[derive(Clone, Debug)]
pub struct Flight {
    pub t_s: Vec<f64>,
    pub mag_nt: Vec<f64>,
    pub samples: Vec<AlignedSample>,
    pub segments: Option<Vec<String>>,
    pub truth_interference_nt: Option<Vec<f64>>,
    pub truth_anomaly_nt: Option<Vec<f64>>,
    /// Aux channel names in aux-index order.
    pub channels: Vec<String>,
    pub sample_rate_hz: f64,
    pub tie_point: Option<TiePoint>,
    pub earth_dir_ned: Option<[f32; 3]>,
}

/// A numeric column the caller cannot do without: the error lists what the trace has and
/// suggests `--map`.
pub(crate) fn col<'a>(trace: &'a Trace, name: &str) -> Result<&'a [f64]> {
    trace.col(name).with_context(|| {
        let have: Vec<&str> = trace.numeric.iter().map(|(n, _)| n.as_str()).collect();
        format!(
            "the trace has no numeric column '{name}' (it has: {}); use --map {name}=COLUMN to name it{}",
            have.join(", "),
            crate::io::trace::preset_hint(&have)
        )
    })
}

impl Flight {
    /// `channels`: aux columns the model reads; `relative`: those whose first value is
    /// subtracted (e.g. a base-station field).
    pub fn from_trace(trace: &Trace, channels: &[String], relative: &[String]) -> Result<Self> {
        let t = checked_time(trace, channels)?;
        let n = t.len();
        let mag = col(trace, "mag")?;
        let fx = col(trace, "flux_x")?;
        let fy = col(trace, "flux_y")?;
        let fz = col(trace, "flux_z")?;
        let mut samples = aligned_samples(trace, t, channels, relative)?;
        // Out-of-range, non-finite or jumping positions: missing, flagged, warned about.
        let faults = crate::flight::position::check_positions(&mut samples);
        if let Some(w) = crate::flight::position::faults_warning(&faults, trace.origin.as_ref()) {
            crate::flight::position::warn_once(&w);
        }
        let mut dts: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
        dts.sort_by(|a, b| a.total_cmp(b));
        let sample_rate_hz = 1.0 / dts[dts.len() / 2];
        let tie_point = tie_point_of(trace, t, &samples);
        let mut mag_nt = mag.to_vec();
        let glitches = crate::signal::despike::glitches(&mag_nt, sample_rate_hz);
        for &i in &glitches {
            mag_nt[i] = f64::NAN;
            samples[i].mag = None;
        }
        if let Some(w) = glitch_warning(&glitches, mag, trace.origin.as_ref()) {
            crate::flight::position::warn_once(&w);
        }
        let flux: Vec<[f64; 3]> = (0..n).map(|i| [fx[i], fy[i], fz[i]]).collect();
        let [cfx, cfy, cfz] = bridge_flux_glitches(
            trace,
            t,
            &flux,
            mag,
            &mut mag_nt,
            &mut samples,
            sample_rate_hz,
        );
        let earth_dir_ned = attitude_cols(trace)
            .and_then(|(r, p, y)| main_field_direction(&cfx, &cfy, &cfz, r, p, y));
        Ok(Self {
            t_s: t.to_vec(),
            mag_nt,
            samples,
            segments: trace.text_col("segment").map(|s| s.to_vec()),
            truth_interference_nt: trace.col("truth_interference").map(|v| v.to_vec()),
            truth_anomaly_nt: trace.col("truth_anomaly").map(|v| v.to_vec()),
            channels: channels.to_vec(),
            sample_rate_hz,
            tie_point,
            earth_dir_ned,
        })
    }

    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether any sample has a horizontal position.
    pub fn has_position(&self) -> bool {
        self.samples
            .iter()
            .any(|s| s.lat_deg.is_finite() && s.lon_deg.is_finite())
    }

    /// Whether the along-track distance is known for the anomaly process: positions, or a
    /// ground speed on the samples (measured, or assumed with [`Self::assume_ground_speed`]).
    pub fn has_track(&self) -> bool {
        self.has_position() || self.samples.iter().any(|s| s.ground_speed_mps.is_finite())
    }

    /// A flight without positions: the anomaly is modelled in time, as if flown at
    /// `speed_mps` (the along-track distance is `speed × t`). Samples with a ground speed
    /// of their own keep it.
    pub fn assume_ground_speed(&mut self, speed_mps: f64) {
        for s in &mut self.samples {
            if !s.ground_speed_mps.is_finite() {
                s.ground_speed_mps = speed_mps as f32;
            }
        }
    }

    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Cumulative along-track distance (m) from positions, or from the ground speed where a
    /// flight has no positions (as the epoch builder measures it).
    pub fn along_track_m(&self) -> Vec<f64> {
        let mut s = Vec::with_capacity(self.len());
        let mut acc = 0.0;
        if !self.has_position() {
            let mut prev_t: Option<f64> = None;
            for smp in &self.samples {
                if let Some(t0) = prev_t {
                    let ds = smp.ground_speed_mps.abs() as f64 * (smp.t_s - t0);
                    if ds.is_finite() && ds > 0.0 {
                        acc += ds;
                    }
                }
                prev_t = Some(smp.t_s);
                s.push(acc);
            }
            return s;
        }
        let mut prev: Option<(f64, f64)> = None;
        for smp in &self.samples {
            if smp.lat_deg.is_finite() && smp.lon_deg.is_finite() {
                if let Some(p) = prev {
                    acc += crate::flight::position::flat_distance_m(p, (smp.lat_deg, smp.lon_deg));
                }
                prev = Some((smp.lat_deg, smp.lon_deg));
            }
            s.push(acc);
        }
        s
    }

    /// North/east (m) of every sample relative to the first fix, flat-earth; NaN where a
    /// sample has no fix (all NaN without any).
    pub fn local_ne_m(&self) -> Vec<[f64; 2]> {
        let Some(first) = self
            .samples
            .iter()
            .find(|s| s.lat_deg.is_finite() && s.lon_deg.is_finite())
        else {
            return vec![[f64::NAN; 2]; self.len()];
        };
        let (lat0, lon0) = (first.lat_deg, first.lon_deg);
        let coslat = lat0.to_radians().cos();
        self.samples
            .iter()
            .map(|s| {
                [
                    (s.lat_deg - lat0).to_radians() * EARTH_RADIUS_M,
                    (s.lon_deg - lon0).to_radians() * EARTH_RADIUS_M * coslat,
                ]
            })
            .collect()
    }

    /// `values` (the scalar, or a compensated scalar) with the core-field model's change
    /// and, when a base station is recorded, the diurnal variation since the first sample
    /// removed (nT): what the anomaly alone should explain. A sample without either keeps
    /// its value uncorrected for it.
    pub fn environment_corrected_nt(&self, values: &[f64]) -> Vec<f64> {
        let s = &self.samples;
        let igrf0 = s.iter().map(|x| x.igrf_nt).find(|v| v.is_finite());
        let base0 = s.iter().map(|x| x.base_nt).find(|v| v.is_finite());
        s.iter()
            .zip(values)
            .map(|(x, v)| {
                let core = match igrf0 {
                    Some(g) if x.igrf_nt.is_finite() => x.igrf_nt - g,
                    _ => 0.0,
                };
                let ext = match base0 {
                    Some(b) if x.base_nt.is_finite() => (x.base_nt - b) as f64,
                    _ => 0.0,
                };
                v - core - ext
            })
            .collect()
    }

    /// Indices of the rows whose segment label starts with `prefix`.
    pub fn segment_rows(&self, prefix: &str) -> Vec<usize> {
        match &self.segments {
            Some(seg) => (0..seg.len())
                .filter(|&i| seg[i].starts_with(prefix))
                .collect(),
            None => Vec::new(),
        }
    }

    /// Contiguous runs of equal segment labels: (label, first row, last row + 1).
    pub fn segment_runs(&self) -> Vec<(String, usize, usize)> {
        let mut runs = Vec::new();
        if let Some(seg) = &self.segments {
            let mut start = 0;
            for i in 1..=seg.len() {
                if i == seg.len() || seg[i] != seg[start] {
                    runs.push((seg[start].clone(), start, i));
                    start = i;
                }
            }
        }
        runs
    }
}

/// The point the track passes most often on distinct passes (≥ 3), e.g. the cloverleaf
/// centre: a 40 m grid, passes separated by ≥ 30 s.
/// Name of the optional ground-speed column (m/s; used where `vn`/`ve` are absent).
pub const GROUND_SPEED_COLUMN: &str = "ground_speed";

/// `trace` with a constant [`GROUND_SPEED_COLUMN`] of `speed_mps` when it has no track
/// (neither position nor a ground speed), so that every flight built from it — the
/// diagnosis builds its own — models the anomaly in time at that speed. Returns whether
/// the speed was added; a trace with a track is returned unchanged.
pub fn with_assumed_ground_speed(trace: &Trace, speed_mps: f64) -> Result<(Trace, bool)> {
    if !(speed_mps.is_finite() && speed_mps > 0.0) {
        bail!("--speed-mps must be a positive speed in m/s, not {speed_mps}");
    }
    if Flight::from_trace(trace, &[], &[])?.has_track() {
        return Ok((trace.clone(), false));
    }
    let mut out = trace.clone();
    out.set_col(GROUND_SPEED_COLUMN, vec![speed_mps; trace.len()]);
    Ok((out, true))
}

pub fn detect_tie_point(t: &[f64], lat: &[f64], lon: &[f64]) -> Option<TiePoint> {
    let mut d = TieDetector::default();
    for i in 0..t.len() {
        d.push(t[i], lat[i], lon[i]);
    }
    d.finish()
}

/// [`detect_tie_point`] fed one fix at a time; memory grows with the area covered (one
/// entry per 40 m cell flown over), not with the samples nor with the passes over a cell.
#[derive(Clone, Debug, Default)]
pub struct TieDetector {
    coslat: Option<f64>,
    cells: HashMap<(i64, i64), Cell>,
}

/// Per 40 m cell. Only the count of distinct passes and the time of the latest sample are
/// kept: a list of every pass grew with the flight (a survey re-flying its lines, or the
/// streaming benchmark's repeated track, added one entry per cell per pass).
#[derive(Clone, Debug, Default)]
struct Cell {
    passes: usize,
    /// Time of the latest sample in the cell (a pass is distinct after a 30 s absence).
    last_t: Option<f64>,
    lat_sum: f64,
    lon_sum: f64,
    samples: usize,
}

impl TieDetector {
    pub fn push(&mut self, t: f64, lat: f64, lon: f64) {
        const CELL_M: f64 = 40.0;
        if !(lat.is_finite() && lon.is_finite()) {
            return;
        }
        let coslat = *self.coslat.get_or_insert(lat.to_radians().cos());
        let n = lat.to_radians() * EARTH_RADIUS_M;
        let e = lon.to_radians() * EARTH_RADIUS_M * coslat;
        let key = ((n / CELL_M).floor() as i64, (e / CELL_M).floor() as i64);
        let c = self.cells.entry(key).or_default();
        if c.last_t.is_none_or(|last| t - last > 30.0) {
            c.passes += 1;
        }
        c.last_t = Some(t);
        c.lat_sum += lat;
        c.lon_sum += lon;
        c.samples += 1;
    }

    pub fn finish(&self) -> Option<TiePoint> {
        // Ties broken by the cell's key: a HashMap's order is random per run, and the
        // same flight must give the same tie point every time.
        let (_, best) = self
            .cells
            .iter()
            .max_by_key(|(key, c)| (c.passes, c.samples, std::cmp::Reverse(**key)))?;
        (best.passes >= 3).then(|| TiePoint {
            lat_deg: best.lat_sum / best.samples as f64,
            lon_deg: best.lon_sum / best.samples as f64,
        })
    }
}

/// Main-field direction in NED: the fluxgate direction rotated by the INS attitude,
/// averaged over the flight (fluxgate errors fixed in the body frame largely cancel over
/// the headings of a calibration pattern).
pub(crate) fn main_field_direction(
    fx: &[f64],
    fy: &[f64],
    fz: &[f64],
    roll: &[f64],
    pitch: &[f64],
    yaw: &[f64],
) -> Option<[f32; 3]> {
    let mut acc = FieldDirection::default();
    for i in 0..fx.len() {
        acc.push([fx[i], fy[i], fz[i]], [roll[i], pitch[i], yaw[i]]);
    }
    acc.finish()
}

/// [`main_field_direction`] accumulated one sample at a time.
#[derive(Clone, Debug, Default)]
pub struct FieldDirection {
    acc: [f64; 3],
    count: usize,
}

impl FieldDirection {
    /// Fluxgate vector (nT) and attitude (roll, pitch, yaw in degrees) of one sample.
    pub fn push(&mut self, b: [f64; 3], a: [f64; 3]) {
        let nb = (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt();
        if !(nb.is_finite() && nb > 1.0 && a.iter().all(|v| v.is_finite())) {
            return;
        }
        let r = body_from_ned(a[0].to_radians(), a[1].to_radians(), a[2].to_radians());
        // e_ned = R_bnᵀ · e_body
        for (j, acc_j) in self.acc.iter_mut().enumerate() {
            *acc_j += (r[0][j] * b[0] + r[1][j] * b[1] + r[2][j] * b[2]) / nb;
        }
        self.count += 1;
    }

    /// Length of the mean of the per-sample directions (1 = all agree): a fluxgate that
    /// does not turn with the INS (swapped or negated axes) gives less.
    pub fn coherence(&self) -> Option<f64> {
        (self.count > 0).then(|| {
            let a = self.acc;
            (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt() / self.count as f64
        })
    }

    pub fn finish(&self) -> Option<[f32; 3]> {
        if self.count == 0 {
            return None;
        }
        let acc = self.acc;
        let norm = (acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2]).sqrt();
        (norm > 0.0).then(|| {
            [
                (acc[0] / norm) as f32,
                (acc[1] / norm) as f32,
                (acc[2] / norm) as f32,
            ]
        })
    }
}

/// Rotation NED → body for ZYX (yaw, pitch, roll) Euler angles.
pub fn body_from_ned(roll: f64, pitch: f64, yaw: f64) -> [[f64; 3]; 3] {
    let (sr, cr) = roll.sin_cos();
    let (sp, cp) = pitch.sin_cos();
    let (sy, cy) = yaw.sin_cos();
    [
        [cp * cy, cp * sy, -sp],
        [sr * sp * cy - cr * sy, sr * sp * sy + cr * cy, sr * cp],
        [cr * sp * cy + sr * sy, cr * sp * sy - sr * cy, cr * cp],
    ]
}

/// "trace.csv: 2 scalar glitch(es) taken as missing …" naming the lines, or None.
fn glitch_warning(
    rows: &[usize],
    mag: &[f64],
    origin: Option<&crate::io::trace::RowOrigin>,
) -> Option<String> {
    const MAX_LISTED: usize = 5;
    if rows.is_empty() {
        return None;
    }
    let file = origin.map_or("trace".to_string(), |o| o.file.clone());
    let mut msg = format!(
        "{file}: {} scalar glitch(es) far outside their neighbours, taken as missing (samples flagged MAG_MISSING):",
        rows.len()
    );
    for &r in rows.iter().take(MAX_LISTED) {
        let at = match origin.and_then(|o| o.line(r)) {
            Some(l) => format!("line {l}"),
            None => format!("data row {}", r + 1),
        };
        msg.push_str(&format!("\n  {at}: mag = {}", mag[r]));
    }
    if rows.len() > MAX_LISTED {
        msg.push_str(&format!("\n  … and {} more", rows.len() - MAX_LISTED));
    }
    Some(msg)
}

/// "trace.csv: 1 fluxgate sample(s) inconsistent …" naming the lines.
fn flux_glitch_warning(
    rows: &[usize],
    flux: &[[f64; 3]],
    mag: &[f64],
    origin: Option<&crate::io::trace::RowOrigin>,
) -> String {
    const MAX_LISTED: usize = 5;
    let file = origin.map_or("trace".to_string(), |o| o.file.clone());
    let mut msg = format!(
        "{file}: {} fluxgate sample(s) inconsistent with their neighbours or with the scalar \
         (|B_F| − mag), taken as missing (samples flagged MAG_MISSING, vector bridged from \
         the neighbours):",
        rows.len()
    );
    for &r in rows.iter().take(MAX_LISTED) {
        let at = match origin.and_then(|o| o.line(r)) {
            Some(l) => format!("line {l}"),
            None => format!("data row {}", r + 1),
        };
        let b = flux[r];
        msg.push_str(&format!(
            "\n  {at}: flux = ({}, {}, {}), |B_F| = {:.1}, mag = {}",
            b[0],
            b[1],
            b[2],
            (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt(),
            mag[r]
        ));
    }
    if rows.len() > MAX_LISTED {
        msg.push_str(&format!("\n  … and {} more", rows.len() - MAX_LISTED));
    }
    msg
}

/// The flight's first finite scalar reading (0 without any): what the relative scalars are
/// taken from, so the sums run on tens of nT, not 50 000.
pub fn first_reading_nt(flight: &Flight) -> f64 {
    flight
        .mag_nt
        .iter()
        .copied()
        .find(|v| v.is_finite())
        .unwrap_or(0.0)
}

/// The scalar relative to its first value, with the core-field model's change removed as
/// the core's epoch builder does (the main-field gradient is not the anomaly): what the
/// filter's interference + field states model. f64, exact.
pub fn scalar_relative_nt(flight: &Flight) -> Vec<f64> {
    let m0 = first_reading_nt(flight);
    let igrf0 = flight
        .samples
        .iter()
        .map(|s| s.igrf_nt)
        .find(|v| v.is_finite());
    flight
        .mag_nt
        .iter()
        .zip(&flight.samples)
        .map(|(v, s)| match igrf0 {
            Some(i0) if s.igrf_nt.is_finite() => v - m0 - (s.igrf_nt - i0),
            _ => v - m0,
        })
        .collect()
}

/// The trace's time column, after checking the required columns, the number of channels
/// and rows, and that time strictly increases.
fn checked_time<'a>(trace: &'a Trace, channels: &[String]) -> Result<&'a [f64]> {
    for c in REQUIRED {
        col(trace, c)?;
    }
    if channels.len() > MAX_AUX {
        bail!("at most {MAX_AUX} auxiliary channels can be used at once");
    }
    let n = trace.len();
    if n < 3 {
        bail!("the trace has {n} rows; at least 3 are needed");
    }
    let t = col(trace, "t")?;
    for i in 1..n {
        if t[i].partial_cmp(&t[i - 1]) != Some(std::cmp::Ordering::Greater) {
            bail!(
                "time is not strictly increasing at data row {} (t = {} after {})",
                i + 1,
                t[i],
                t[i - 1]
            );
        }
    }
    Ok(t)
}

/// Roll, pitch and yaw columns, when the trace has all three.
fn attitude_cols(trace: &Trace) -> Option<(&[f64], &[f64], &[f64])> {
    match (trace.col("roll"), trace.col("pitch"), trace.col("yaw")) {
        (Some(r), Some(p), Some(y)) => Some((r, p, y)),
        _ => None,
    }
}

/// The trace's rows as the compensator's samples: scalar, fluxgate, position, base
/// station (from its first value), core field, ground speed, attitude, and the model's
/// channels (`relative` ones from their first value).
fn aligned_samples(
    trace: &Trace,
    t: &[f64],
    channels: &[String],
    relative: &[String],
) -> Result<Vec<AlignedSample>> {
    let n = t.len();
    let mag = col(trace, "mag")?;
    let fx = col(trace, "flux_x")?;
    let fy = col(trace, "flux_y")?;
    let fz = col(trace, "flux_z")?;
    let nan = vec![f64::NAN; n];
    let lat = trace.col("lat").unwrap_or(&nan);
    let lon = trace.col("lon").unwrap_or(&nan);
    let alt = trace.col("alt").unwrap_or(&nan);
    let igrf = trace.col("igrf");
    let base = trace.col("base");
    let base0 = base.and_then(|b| b.iter().copied().find(|v| v.is_finite()));
    let vn = trace.col("vn");
    let ve = trace.col("ve");
    let ground_speed = trace.col("ground_speed");
    let att = attitude_cols(trace);
    let mut aux_cols: Vec<(&[f64], f64)> = Vec::new();
    for c in channels {
        let v = col(trace, c).with_context(|| format!("the model reads channel '{c}'"))?;
        let offset = if relative.contains(c) {
            v.iter().copied().find(|x| x.is_finite()).unwrap_or(0.0)
        } else {
            0.0
        };
        aux_cols.push((v, offset));
    }
    let mut samples = Vec::with_capacity(n);
    for i in 0..n {
        let mut s = AlignedSample::empty(t[i]);
        s.mag = MagCounts::from_nt_f64(mag[i]);
        s.flux_nt = [fx[i] as f32, fy[i] as f32, fz[i] as f32];
        s.lat_deg = lat[i];
        s.lon_deg = lon[i];
        s.alt_m = alt[i] as f32;
        if let (Some(b), Some(b0)) = (base, base0) {
            s.base_nt = (b[i] - b0) as f32;
        }
        if let Some(g) = igrf {
            s.igrf_nt = g[i];
        }
        if let (Some(vn), Some(ve)) = (vn, ve) {
            s.ground_speed_mps = vn[i].hypot(ve[i]) as f32;
        } else if let Some(gs) = ground_speed {
            s.ground_speed_mps = gs[i] as f32;
        }
        if let Some((r, p, y)) = att {
            s.attitude_deg = [r[i] as f32, p[i] as f32, y[i] as f32];
        }
        for (k, (v, off)) in aux_cols.iter().enumerate() {
            s.aux[k] = (v[i] - off) as f32;
        }
        samples.push(s);
    }
    Ok(samples)
}

/// The calibration's tie point: the trace's `cal_centre_lat`/`lon`, else detected from the
/// (checked) positions.
fn tie_point_of(trace: &Trace, t: &[f64], samples: &[AlignedSample]) -> Option<TiePoint> {
    let lat: Vec<f64> = samples.iter().map(|s| s.lat_deg).collect();
    let lon: Vec<f64> = samples.iter().map(|s| s.lon_deg).collect();
    match (
        trace
            .meta("cal_centre_lat")
            .and_then(|v| v.trim().parse().ok()),
        trace
            .meta("cal_centre_lon")
            .and_then(|v| v.trim().parse().ok()),
    ) {
        (Some(lat_deg), Some(lon_deg)) => Some(TiePoint { lat_deg, lon_deg }),
        _ => detect_tie_point(t, &lat, &lon),
    }
}

/// Fluxgate glitches: the row's scalar is taken as missing (nothing is learnt from it) and
/// its vector is bridged from the neighbours, so that no regressor, rate or direction
/// estimate sees the bad value: between the last good vector before and the first within
/// `despike::bridge_reach` rows after (else the one before is held). A row that is also a
/// scalar glitch is bridged too; a scalar glitch's own vector is good. Returns the
/// bridged axes.
fn bridge_flux_glitches(
    trace: &Trace,
    t: &[f64],
    flux: &[[f64; 3]],
    mag: &[f64],
    mag_nt: &mut [f64],
    samples: &mut [AlignedSample],
    sample_rate_hz: f64,
) -> [Vec<f64>; 3] {
    let n = flux.len();
    let flux_bad = crate::signal::despike::flux_glitches(flux, mag_nt, sample_rate_hz);
    let reach = crate::signal::despike::bridge_reach(sample_rate_hz);
    let mut cf: [Vec<f64>; 3] = std::array::from_fn(|k| flux.iter().map(|f| f[k]).collect());
    if !flux_bad.is_empty() {
        let usable =
            |i: usize| flux_bad.binary_search(&i).is_err() && flux[i].iter().all(|v| v.is_finite());
        for &i in &flux_bad {
            mag_nt[i] = f64::NAN;
            samples[i].mag = None;
            let at = |j: usize| (t[j], flux[j]);
            let before = (0..i).rev().find(|&j| usable(j)).map(at);
            let after = (i + 1..n).take(reach).find(|&j| usable(j)).map(at);
            let v = bridged_vector(t[i], before, after);
            samples[i].flux_nt = v.map(|x| x as f32);
            (cf[0][i], cf[1][i], cf[2][i]) = (v[0], v[1], v[2]);
        }
        crate::flight::position::warn_once(&flux_glitch_warning(
            &flux_bad,
            flux,
            mag,
            trace.origin.as_ref(),
        ));
    }
    cf
}

/// A bridged fluxgate vector at `t_s`: on the line between the good (time, vector) before
/// and after it, else the one there is (NaN without either). The stream bridges with it too.
pub(crate) fn bridged_vector(
    t_s: f64,
    before: Option<(f64, [f64; 3])>,
    after: Option<(f64, [f64; 3])>,
) -> [f64; 3] {
    match (before, after) {
        (Some((ta, a)), Some((tb, b))) if tb > ta => {
            let w = (t_s - ta) / (tb - ta);
            std::array::from_fn(|k| a[k] + w * (b[k] - a[k]))
        }
        (Some((_, a)), _) => a,
        (None, Some((_, b))) => b,
        (None, None) => [f64::NAN; 3],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two cells flown over alike (three passes, the same samples each) tie; every detector
    /// must pick the same one (each HashMap iterates in its own random order).
    #[test]
    fn tied_cells_give_the_same_tie_point_every_time() {
        let fly = || {
            let mut d = TieDetector::default();
            for pass in 0..3 {
                let t0 = pass as f64 * 100.0;
                // 0.01° of longitude apart: ~700 m, two cells far from each other
                d.push(t0, 45.0, 7.0);
                d.push(t0 + 50.0, 45.0, 7.01);
            }
            d.finish().expect("three passes over each cell")
        };
        let first = fly();
        for _ in 0..50 {
            assert_eq!(fly(), first);
        }
    }
}
