//! Figures of merit a survey geophysicist reads: FOM, improvement ratio, the manoeuvre-band
//! residual.

use crate::flight::Flight;
use serde::Serialize;

/// The manoeuvre band: 0.1–0.9 Hz (the classic TL band; manoeuvres have 4–8 s periods).
pub fn manoeuvre_band(fs_hz: f64) -> (f64, f64) {
    (0.1, 0.9f64.min(0.4 * fs_hz))
}

/// The manoeuvre-band signal of a flight's `x` (scalar or compensated), NaN where `x` is
/// missing and over stretches too short to filter. Time gaps and long missing runs split
/// the filter; isolated missing samples are interpolated for the filter only, so one
/// missing sample costs one sample of every statistic, not the whole flight. None when
/// nothing can be filtered.
pub fn band_passed(flight: &Flight, x: &[f64]) -> Option<Vec<f64>> {
    let fs_hz = flight.sample_rate_hz;
    let (lo, hi) = manoeuvre_band(fs_hz);
    let breaks = crate::qc::gaps::time_breaks(&flight.t_s);
    let gaps = crate::signal::bandpass::Gaps {
        breaks: &breaks,
        max_fill: crate::qc::gaps::MAX_FILL_SAMPLES,
        min_len: 64,
    };
    let v = crate::signal::bandpass::bandpass_gaps(x, 4, lo, hi, fs_hz, &gaps).ok()?;
    v.iter().any(|x| x.is_finite()).then_some(v)
}

/// RMS (mean removed) of the manoeuvre-band signal over its finite samples.
pub fn band_rms_nt(flight: &Flight, x: &[f64]) -> f64 {
    band_passed(flight, x)
        .map(|v| rms_demeaned(&v))
        .unwrap_or(f64::NAN)
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
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
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
    let bp = band_passed(flight, compensated_nt)?;
    let bp_raw = band_passed(flight, &flight.mag_nt)?;
    let mut parts = Vec::new();
    for (label, a, b) in flight.segment_runs() {
        if !is_manoeuvre(&label) {
            continue;
        }
        let p2p = |v: &[f64]| peak_to_peak(&v[a..b]);
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

/// Peak-to-peak over the finite values (NaN when there are none).
pub fn peak_to_peak(v: &[f64]) -> f64 {
    let f = v.iter().copied().filter(|x| x.is_finite());
    let (lo, hi) = f.fold((f64::MAX, f64::MIN), |(lo, hi), x| (lo.min(x), hi.max(x)));
    if lo <= hi {
        hi - lo
    } else {
        f64::NAN
    }
}

/// The rows the improvement ratio is taken over: the labelled manoeuvres (`cal_*_roll|pitch|yaw`
/// in `segment`), else the manoeuvres detected without labels (`qc::manoeuvres`), else the
/// whole flight.
pub fn pattern_rows(flight: &Flight) -> Vec<usize> {
    let labelled: Vec<usize> = flight
        .segments
        .as_ref()
        .map(|s| (0..s.len()).filter(|&i| is_manoeuvre(&s[i])).collect())
        .unwrap_or_default();
    if !labelled.is_empty() {
        return labelled;
    }
    match crate::qc::manoeuvres::detect(flight) {
        Some(p) => p.manoeuvres().flat_map(|m| m.start..m.end).collect(),
        None => (0..flight.len()).collect(),
    }
}

/// The improvement ratio, IR: the standard deviation of the 0.1–0.9 Hz band-passed
/// uncompensated scalar over that of the band-passed compensated one, over the calibration
/// pattern ([`pattern_rows`]), on the samples where both are known. The one definition
/// every figure called IR uses (docs/model.md §6a).
pub fn improvement_ratio(flight: &Flight, compensated_nt: &[f64]) -> Option<f64> {
    let before = band_passed(flight, &flight.mag_nt)?;
    let after = band_passed(flight, compensated_nt)?;
    improvement_ratio_of_bands(&before, &after, &pattern_rows(flight))
}

/// [`improvement_ratio`] of signals already band-passed, over `rows`.
pub fn improvement_ratio_of_bands(before: &[f64], after: &[f64], rows: &[usize]) -> Option<f64> {
    let rows: Vec<usize> = rows
        .iter()
        .copied()
        .filter(|&i| before[i].is_finite() && after[i].is_finite())
        .collect();
    if rows.len() < 2 {
        return None;
    }
    let b: Vec<f64> = rows.iter().map(|&i| before[i]).collect();
    let a: Vec<f64> = rows.iter().map(|&i| after[i]).collect();
    let ir = std_of(&b) / std_of(&a);
    ir.is_finite().then_some(ir)
}

/// The acceptance band of the 4th-difference noise (±nT): a common survey-contract
/// figure for a caesium magnetometer's noise envelope at 10 Hz; the contract's own figure
/// applies where it differs.
pub const FOURTH_DIFFERENCE_LIMIT_NT: f64 = 0.05;

/// The aeromagnetic noise figure: the 4th difference normalised by 16,
/// `d4[i] = (x[i-2] − 4x[i-1] + 6x[i] − 4x[i+1] + x[i+2]) / 16` (nT), which passes white
/// noise at √70/16 ≈ 0.52 of its σ and a cubic trend not at all. NaN at the ends, where a
/// sample of the five is missing, and across time gaps.
pub fn fourth_difference_nt(flight: &Flight, x: &[f64]) -> Vec<f64> {
    let breaks = crate::qc::gaps::time_breaks(&flight.t_s);
    let n = x.len();
    (0..n)
        .map(|i| {
            if i < 2 || i + 2 >= n || breaks.iter().any(|&b| b + 2 > i && b <= i + 2) {
                return f64::NAN;
            }
            (x[i - 2] - 4.0 * x[i - 1] + 6.0 * x[i] - 4.0 * x[i + 1] + x[i + 2]) / 16.0
        })
        .collect()
}

/// The 4th-difference noise of one signal: rms, peak |d4| and the share of samples
/// within ±`limit_nt`.
#[derive(Clone, Debug, Serialize)]
pub struct NoiseFigure {
    pub rms_nt: f64,
    pub peak_nt: f64,
    pub within_limit: f64,
}

/// [`NoiseFigure`] of a 4th difference over its finite samples; None when there are none.
pub fn noise_figure(d4_nt: &[f64], limit_nt: f64) -> Option<NoiseFigure> {
    let f: Vec<f64> = d4_nt.iter().copied().filter(|v| v.is_finite()).collect();
    if f.is_empty() {
        return None;
    }
    let n = f.len() as f64;
    Some(NoiseFigure {
        rms_nt: (f.iter().map(|v| v * v).sum::<f64>() / n).sqrt(),
        peak_nt: f.iter().fold(0.0, |m, v| m.max(v.abs())),
        within_limit: f.iter().filter(|v| v.abs() <= limit_nt).count() as f64 / n,
    })
}
