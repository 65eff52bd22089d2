//! A heading's manoeuvre window split into its pitch, roll and yaw parts without INS,
//! from the rotation the fluxgate sees.
//!
//! The field's direction `u` in the fluxgate frame turns as the aircraft rotates; `u × du/dt`
//! is the body rate's part perpendicular to the field (rad/s). Its horizontal part (about
//! the cone axis, `manoeuvres::cone_frame`) lies along two fixed body axes: the roll axis
//! carries the larger share (an AARC pattern rolls ±10°, pitches ±5°, at similar periods:
//! about 4× the energy), the pitch axis the other. A yaw about the vertical shows only its
//! projection off the field (`sin` of the field's angle from the vertical, ~0.3 at high
//! latitude) and on some headings looks like a roll, so yaw is taken from the order in which
//! AARC sets are flown on each heading: pitch, roll, then yaw.

use crate::flight::Flight;
use nalgebra::{Matrix2, Vector3};

/// A roll or pitch set is active above this rate envelope (deg/s): a ±5° pitch at a
/// 4–8 s period turns at 4–8 deg/s, level flight between sets below 1.
const MIN_RATE_DEG_S: f64 = 1.5;
/// Envelope window (s), largest pause inside one part (s), shortest part (s).
const ENVELOPE_S: f64 = 5.0;
const MAX_PAUSE_S: f64 = 3.0;
const MIN_PART_S: f64 = 6.0;
/// The roll ends where the rate envelope falls below this share of its peak: the yaw
/// that follows turns ~3× slower in the fluxgate's view.
const ROLL_END_FRACTION: f64 = 0.5;
/// A yaw is active above this rate envelope (deg/s): the fluxgate sees a ±5° yaw at ~0.3×
/// its rate, 1–3 deg/s on the real boxes, while level flight between sets stays below 1.
const MIN_YAW_RATE_DEG_S: f64 = 1.0;

/// Rate envelopes per sample (deg/s): total, along the pitch axis, along the roll axis.
pub struct Rates {
    total: Vec<f64>,
    pitch: Vec<f64>,
    roll: Vec<f64>,
    fs_hz: f64,
}

/// The fluxgate's view of the body rates over the flight; `axis` is the cone axis (the
/// aircraft's vertical in the fluxgate frame), `h1`, `h2` horizontal axes completing it.
pub fn fluxgate_rates(flight: &Flight, frame: &[Vector3<f64>; 3], band_hz: (f64, f64)) -> Rates {
    let n = flight.len();
    let fs = flight.sample_rate_hz;
    let u: Vec<Vector3<f64>> = flight
        .samples
        .iter()
        .map(|s| {
            let b = Vector3::from(s.flux_nt.map(f64::from));
            b / b.norm()
        })
        .collect();
    let w: Vec<Vector3<f64>> = (0..n)
        .map(|i| {
            let (a, b) = (i.saturating_sub(1), (i + 1).min(n - 1));
            let du = (u[b] - u[a]) * fs / (b - a).max(1) as f64;
            u[i].cross(&du)
        })
        .collect();
    let breaks = crate::qc::gaps::time_breaks(&flight.t_s);
    let gaps = crate::signal::bandpass::Gaps {
        breaks: &breaks,
        max_fill: crate::qc::gaps::MAX_FILL_SAMPLES,
        min_len: 64,
    };
    let comp: Vec<Vec<f64>> = (0..3)
        .map(|k| {
            let x: Vec<f64> = w.iter().map(|v| v[k]).collect();
            crate::signal::bandpass::bandpass_gaps(&x, 4, band_hz.0, band_hz.1, fs, &gaps)
                .unwrap_or_else(|_| vec![f64::NAN; n])
        })
        .collect();
    let wf: Vec<Vector3<f64>> = (0..n)
        .map(|i| Vector3::new(comp[0][i], comp[1][i], comp[2][i]))
        .collect();
    let [vertical, h1, h2] = frame;
    let roll_axis = roll_axis(&wf, h1, h2);
    let pitch_axis = vertical.cross(&roll_axis);
    // The share of the rate each body axis explains: projected on that axis's direction
    // perpendicular to the field (the only part the fluxgate sees).
    let along = |e: &Vector3<f64>| -> Vec<f64> {
        (0..n)
            .map(|i| {
                let p = e - u[i] * e.dot(&u[i]);
                let v = wf[i].dot(&(p / p.norm()));
                if v.is_finite() {
                    v * v
                } else {
                    0.0
                }
            })
            .collect()
    };
    let total: Vec<f64> = wf
        .iter()
        .map(|v| {
            let s = v.norm_squared();
            if s.is_finite() {
                s
            } else {
                0.0
            }
        })
        .collect();
    let k = ((ENVELOPE_S * fs).round() as usize).max(1);
    let env = |sq: &[f64]| -> Vec<f64> {
        crate::signal::stats::moving_mean(sq, k)
            .into_iter()
            .map(|m| (2.0 * m).sqrt().to_degrees())
            .collect()
    };
    Rates {
        total: env(&total),
        pitch: env(&along(&pitch_axis)),
        roll: env(&along(&roll_axis)),
        fs_hz: fs,
    }
}

/// The horizontal direction carrying most of the horizontal rate over the active samples.
fn roll_axis(wf: &[Vector3<f64>], h1: &Vector3<f64>, h2: &Vector3<f64>) -> Vector3<f64> {
    let mut c = Matrix2::zeros();
    let threshold = MIN_RATE_DEG_S.to_radians();
    for v in wf.iter().filter(|v| v.norm() > threshold) {
        let h = nalgebra::Vector2::new(v.dot(h1), v.dot(h2));
        c += h * h.transpose();
    }
    let eig = c.symmetric_eigen();
    let major = if eig.eigenvalues[0] >= eig.eigenvalues[1] {
        0
    } else {
        1
    };
    let e = eig.eigenvectors.column(major);
    h1 * e[0] + h2 * e[1]
}

/// The pitch, roll and yaw parts of leg rows `a..b` (each `(kind, start, end)`), in that
/// order; None when the leg does not show a pitch set followed by a roll
/// set (the caller keeps the numbered manoeuvres then).
pub fn split_leg(r: &Rates, a: usize, b: usize) -> Option<Vec<(&'static str, usize, usize)>> {
    let samples_of = |s: f64| ((s * r.fs_hz).round() as usize).max(1);
    let active = |i: usize| r.total[i] > MIN_RATE_DEG_S;
    let pitchy = |i: usize| active(i) && r.pitch[i] > r.roll[i];
    let rolly = |i: usize| active(i) && r.roll[i] > r.pitch[i];
    let pause = samples_of(MAX_PAUSE_S);
    let min_len = samples_of(MIN_PART_S);
    let pitch = runs_of(pitchy, a, b, pause)
        .into_iter()
        .filter(|(s, e)| e - s >= min_len)
        .max_by_key(|(s, e)| e - s)?;
    let roll_run = runs_of(rolly, pitch.1, b, pause)
        .into_iter()
        .find(|(s, e)| e - s >= min_len)?;
    let peak = (roll_run.0..roll_run.1)
        .map(|i| r.total[i])
        .fold(0.0, f64::max);
    let roll_end = (roll_run.0..roll_run.1)
        .rev()
        .find(|&i| r.total[i] >= ROLL_END_FRACTION * peak)
        .map_or(roll_run.1, |i| i + 1);
    let mut parts = vec![("pitch", pitch.0, pitch.1), ("roll", roll_run.0, roll_end)];
    let yawing = |i: usize| r.total[i] > MIN_YAW_RATE_DEG_S;
    if let Some(yaw) = runs_of(yawing, roll_end, b, pause)
        .into_iter()
        .find(|(s, e)| e - s >= min_len)
    {
        parts.push(("yaw", yaw.0, yaw.1));
    }
    Some(parts)
}

/// Runs of rows in `a..b` where `on` holds, joined across pauses up to `pause` rows.
fn runs_of(on: impl Fn(usize) -> bool, a: usize, b: usize, pause: usize) -> Vec<(usize, usize)> {
    let mut out: Vec<(usize, usize)> = Vec::new();
    let mut i = a;
    while i < b {
        if !on(i) {
            i += 1;
            continue;
        }
        let s = i;
        while i < b && on(i) {
            i += 1;
        }
        match out.last_mut() {
            Some(last) if s - last.1 <= pause => last.1 = i,
            _ => out.push((s, i)),
        }
    }
    out
}
