//! The figures the filter's noise model is fitted to, from the flight itself: the
//! anomaly's σ1 from the along-track spectrum, the FOM that chooses among its candidates,
//! the local-roughness profiles of the anomaly process, the innovations' likelihood. The
//! stages that make passes for them are in `stages` (`noise`, `field_process`).

use crate::flight::Flight;
use crate::model::spec::ModelSpec;
use magcomp_core::compensator::Output;
use magcomp_core::model::Term;
use magcomp_core::spectrum::{estimate_sigma1, Sigma1Config};
/// σ1 from the along-track spectrum of (scalar − interference estimate).
pub fn estimate_sigma1_for(flight: &Flight, interference_nt: &[f64]) -> Option<f64> {
    estimate_sigma1_with(flight, interference_nt, None)
}

/// What the scalar holds that is neither anomaly nor interference and that the model
/// attributes to its own environment terms: for single-channel ones (`diurnal`) their prior
/// mean × channel (β₀ = 1 × base). Left in, a base-station micropulsation would raise σ1
/// and the field states would take it instead of the term. (The core-field change is left
/// in: the σ1 selection and the consistency checks were validated with it there.)
pub fn known_environment_nt(flight: &Flight, spec: &ModelSpec) -> Vec<f64> {
    let terms = spec.build_terms();
    let env_terms: Vec<(usize, f64)> = terms
        .iter()
        .filter(|t| !t.is_interference() && t.len() == 1)
        .filter_map(|t| t.channel().map(|c| (c, t.prior_mean(0) as f64)))
        .collect();
    flight
        .samples
        .iter()
        .map(|s| {
            env_terms
                .iter()
                .map(|&(c, m)| {
                    let v = s.aux[c] as f64;
                    if v.is_finite() {
                        m * v
                    } else {
                        0.0
                    }
                })
                .sum()
        })
        .collect()
}

/// σ1 from (scalar − interference − known environment) against along-track distance.
pub fn estimate_sigma1_with(
    flight: &Flight,
    interference_nt: &[f64],
    environment_nt: Option<&[f64]>,
) -> Option<f64> {
    let s = flight.along_track_m();
    let z: Vec<f64> = flight
        .mag_nt
        .iter()
        .zip(interference_nt)
        .enumerate()
        .map(|(k, (m, i))| m - i - environment_nt.map_or(0.0, |e| e[k]))
        .collect();
    let cfg = Sigma1Config::default();
    // Sized by the samples, never by a coordinate (issue 13: one bad latitude asked for 53 GB).
    let mut scratch = vec![0.0; magcomp_core::spectrum::sigma1_scratch_len(&s, &z, &cfg)];
    estimate_sigma1(&s, &z, &cfg, &mut scratch).map(|e| e.sigma1)
}

/// The trade's FOM of the compensated signal over the labelled calibration manoeuvres
/// (`None` without labels). A label-free score (residual power in the manoeuvre band over
/// the most active stretches) was tried and picked σ1 far too small at 3000 m.
pub(super) fn selection_score(flight: &Flight, interference_nt: &[f64]) -> Option<(f64, usize)> {
    let comp: Vec<f64> = flight
        .mag_nt
        .iter()
        .zip(interference_nt)
        .map(|(m, i)| m - i)
        .collect();
    crate::qc::figures::fom(flight, &comp).map(|(f, parts)| (f, parts.len()))
}

/// Non-stationary anomaly processes tried post-flight: (third-difference step in samples at
/// 10 Hz, half-window in samples, normalise by the median instead of the mean). The step
/// sets the wavelengths whose roughness is measured (≈ 0.3–1 km at 60 m/s), the window
/// how local it is (±0.45–1.8 km).
pub const FIELD_PROFILES: [(usize, usize, bool); 5] = [
    (15, 75, true),
    (15, 150, true),
    (30, 150, true),
    (30, 150, false),
    (30, 300, true),
];

/// Multipliers of σ1² tried with every profile (and with the stationary process). The
/// spectral σ1 (fitted at 1–8 km) is an upper bound: a potential field's spectrum falls
/// faster than k⁻⁶ towards shorter wavelengths, and a looser field takes what the model's
/// other terms should explain (with `diurnal`, ×2 took the anomaly-map error 0.11 → 0.47 nT).
pub const FIELD_PROFILE_SCALES: [f64; 3] = [0.25, 0.5, 1.0];

/// Local roughness of the anomaly along the track relative to the flight's typical one:
/// the windowed power of the third difference of (scalar − interference estimate) above
/// its white-noise floor. Over a shallow source the anomaly is far rougher than the
/// flight's single σ1 says and the field states must be freer there (and stiffer over
/// quiet ground), or the coefficients take what the field cannot follow.
pub fn field_profile(
    flight: &Flight,
    interference_nt: &[f64],
    noise_nt: f64,
    (step, half_window, median): (usize, usize, bool),
) -> Vec<f64> {
    let n = flight.len();
    // The step is in 10 Hz samples; keep its length in metres at other rates.
    let step = ((step as f64 * flight.sample_rate_hz / 10.0).round() as usize).max(1);
    let half_window = ((half_window as f64 * flight.sample_rate_hz / 10.0).round() as usize).max(1);
    let z: Vec<f64> = flight
        .mag_nt
        .iter()
        .zip(interference_nt)
        .map(|(m, i)| m - i)
        .collect();
    let mut d3 = vec![0.0; n];
    for i in 0..n.saturating_sub(3 * step) {
        let v = z[i + 3 * step] - 3.0 * z[i + 2 * step] + 3.0 * z[i + step] - z[i];
        d3[i + 3 * step / 2] = if v.is_finite() { v * v } else { 0.0 };
    }
    let mut prefix = vec![0.0; n + 1];
    for i in 0..n {
        prefix[i + 1] = prefix[i] + d3[i];
    }
    let floor = 20.0 * noise_nt * noise_nt;
    let local: Vec<f64> = (0..n)
        .map(|i| {
            let a = i.saturating_sub(half_window);
            let b = (i + half_window + 1).min(n);
            ((prefix[b] - prefix[a]) / (b - a) as f64 - floor).max(0.0)
        })
        .collect();
    let typical = if median {
        let mut sorted = local.clone();
        sorted.sort_by(|a, b| a.total_cmp(b));
        sorted[n / 2]
    } else {
        local.iter().sum::<f64>() / n.max(1) as f64
    }
    .max(1e-12);
    local
        .iter()
        .map(|l| (l / typical).clamp(0.05, 400.0))
        .collect()
}

/// Mean negative log-likelihood of the innovations (`ln S + ν²/S`): lower = the data are
/// more probable under the filter's model.
pub(super) fn innovation_nll(outs: &[Output]) -> f64 {
    let (sum, n) = outs
        .iter()
        .filter(|o| {
            o.innovation_nt.is_finite()
                && o.innovation_var_nt2.is_finite()
                && o.innovation_var_nt2 > 0.0
        })
        .fold((0.0f64, 0usize), |(s, n), o| {
            let (v, var) = (o.innovation_nt as f64, o.innovation_var_nt2 as f64);
            (s + var.ln() + v * v / var, n + 1)
        });
    if n == 0 {
        f64::INFINITY
    } else {
        sum / n as f64
    }
}

/// Unexplained signal (nT rms) above which the model error is a warning: below it, the
/// survey tolerance is not at stake.
pub const MODEL_ERROR_WARNING_NT: f64 = 0.05;

pub(super) fn median(v: &mut [f64]) -> f64 {
    let mid = v.len() / 2;
    v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    v[mid]
}
