//! Figures of merit a survey geophysicist reads: FOM, improvement ratio, residual, and —
//! on simulated data — the error against truth and the oracle floor.

use crate::flight::Flight;
use crate::tl::bandpass;
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

/// The manoeuvre band: 0.1–0.9 Hz (the classic TL band; manoeuvres have 4–8 s periods).
pub fn manoeuvre_band(fs_hz: f64) -> (f64, f64) {
    (0.1, 0.9f64.min(0.4 * fs_hz))
}

fn band_passed(x: &[f64], fs_hz: f64) -> Option<Vec<f64>> {
    let (lo, hi) = manoeuvre_band(fs_hz);
    if x.len() < 64 || !x.iter().all(|v| v.is_finite()) {
        return None;
    }
    bandpass(x, 4, lo, hi, fs_hz).ok()
}

fn std_of(v: &[f64]) -> f64 {
    let n = v.len() as f64;
    if v.is_empty() {
        return f64::NAN;
    }
    let m = v.iter().sum::<f64>() / n;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n).sqrt()
}

/// RMS after removing the mean, over finite values.
pub fn rms_demeaned(v: &[f64]) -> f64 {
    let f: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    std_of(&f)
}

/// One manoeuvre's contribution to the FOM.
#[derive(Clone, Debug, Serialize)]
pub struct ManoeuvreFom {
    pub label: String,
    pub t_start: f64,
    pub t_end: f64,
    pub peak_to_peak_nt: f64,
    pub uncompensated_peak_to_peak_nt: f64,
}

/// Is this segment one of the 12 calibration manoeuvres (`cal_hNNN_roll|pitch|yaw`)?
pub fn is_manoeuvre(label: &str) -> bool {
    label.starts_with("cal_")
        && (label.ends_with("_roll") || label.ends_with("_pitch") || label.ends_with("_yaw"))
}

/// Peak-to-peak of the band-passed compensated signal over each labelled manoeuvre.
pub fn fom(flight: &Flight, compensated_nt: &[f64]) -> Option<(f64, Vec<ManoeuvreFom>)> {
    let bp = band_passed(compensated_nt, flight.sample_rate_hz)?;
    let bp_raw = band_passed(&flight.mag_nt, flight.sample_rate_hz)?;
    let mut parts = Vec::new();
    for (label, a, b) in flight.segment_runs() {
        if !is_manoeuvre(&label) {
            continue;
        }
        let p2p = |v: &[f64]| {
            let s = &v[a..b];
            s.iter().cloned().fold(f64::MIN, f64::max) - s.iter().cloned().fold(f64::MAX, f64::min)
        };
        parts.push(ManoeuvreFom {
            label,
            t_start: flight.t_s[a],
            t_end: flight.t_s[b - 1],
            peak_to_peak_nt: p2p(&bp),
            uncompensated_peak_to_peak_nt: p2p(&bp_raw),
        });
    }
    if parts.is_empty() {
        return None;
    }
    Some((parts.iter().map(|p| p.peak_to_peak_nt).sum(), parts))
}

/// Standard deviation of the band-passed signal before / after compensation, over the
/// manoeuvres when labelled (else the whole flight).
pub fn improvement_ratio(flight: &Flight, compensated_nt: &[f64]) -> Option<f64> {
    let before = band_passed(&flight.mag_nt, flight.sample_rate_hz)?;
    let after = band_passed(compensated_nt, flight.sample_rate_hz)?;
    let rows: Vec<usize> = {
        let m: Vec<usize> = flight
            .segments
            .as_ref()
            .map(|s| (0..s.len()).filter(|&i| is_manoeuvre(&s[i])).collect())
            .unwrap_or_default();
        if m.is_empty() {
            (0..flight.len()).collect()
        } else {
            m
        }
    };
    let b: Vec<f64> = rows.iter().map(|&i| before[i]).collect();
    let a: Vec<f64> = rows.iter().map(|&i| after[i]).collect();
    Some(std_of(&b) / std_of(&a))
}

/// Compensation error against the simulator's truth: `interference − truth`, mean removed.
pub fn error_rms_nt(interference_nt: &[f64], truth_nt: &[f64], rows: Option<&[usize]>) -> f64 {
    let d: Vec<f64> = match rows {
        Some(r) => r
            .iter()
            .map(|&i| interference_nt[i] - truth_nt[i])
            .collect(),
        None => interference_nt
            .iter()
            .zip(truth_nt)
            .map(|(a, b)| a - b)
            .collect(),
    };
    rms_demeaned(&d)
}

/// The oracle floor: RMS residual of the least-squares fit of the true interference onto
/// the model's own regressors (plus a constant) — the best any estimator with those terms
/// can do on this flight.
pub fn oracle_floor_nt(regressors: &[Vec<f32>], truth_nt: &[f64]) -> Option<f64> {
    let rows: Vec<usize> = (0..truth_nt.len().min(regressors.len()))
        .filter(|&i| truth_nt[i].is_finite() && regressors[i].iter().all(|v| v.is_finite()))
        .collect();
    let p = regressors.first()?.len() + 1;
    if rows.len() <= p {
        return None;
    }
    let a = DMatrix::from_fn(rows.len(), p, |r, c| {
        if c == 0 {
            1.0
        } else {
            regressors[rows[r]][c - 1] as f64
        }
    });
    let y = DVector::from_iterator(rows.len(), rows.iter().map(|&i| truth_nt[i]));
    let svd = a.clone().svd(true, true);
    let x = svd.solve(&y, 1e-12).ok()?;
    let r = y - a * x;
    Some((r.norm_squared() / rows.len() as f64).sqrt())
}
