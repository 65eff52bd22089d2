//! The default post-flight calibration: the Kalman filter, checked against TL18-OLS on the
//! flight's own evidence (each method's jackknife, [`crate::estimate::jackknife`]); the method whose
//! coefficients move less between parts of the flight is used, and the summary and the
//! coefficient file say which and why (`cross_check`).
//!
//! Why both: the filter uses what band-passed least squares throws away (the levels between
//! headings, the anomaly), and wins where its model holds (16 broad simulated calibrations:
//! 0.12–0.78 × TL18-OLS) and over geology (TL18-OLS fits the anomaly); where an unmodelled
//! effect or a rougher anomaly lets the anomaly states take interference, least squares has
//! nothing to be fooled by (`clean_s33`: 0.106 nT filter, 0.032 nT TL18-OLS).

use super::result::Compensation;
use super::{tl, EstimatorSettings};
use crate::estimate::jackknife::{CrossCheck, Estimator, BLOCKS};
use crate::estimate::kf::INCONSISTENT_REFITS;
use crate::flight::Flight;
use crate::io::trace::Trace;
use crate::model::corrections::ScalarLag;
use anyhow::Result;

/// The two methods agree when their interference differs by at most this many times their
/// combined jackknife error: the independent `clean_s33` 0.079 nT against 0.058 (1.4×),
/// the real boxes' `mag_3` 11–94 nT against 36–81 (0.3–1.2×); the strong-geology 300 m
/// flights 56–135 nT against 0.3–0.7 (≥ 100×).
pub const DISAGREEMENT_SIGMAS: f64 = 3.0;

/// The TL18-OLS calibration of `trace` the filter's is checked against; None when TL
/// cannot fit the flight (no fluxgate rows in the air, say). It needs nothing of the
/// filter's run, so `calibrate` computes it beside the filter.
pub(super) fn least_squares(
    trace: &Trace,
    est: &EstimatorSettings,
) -> Option<(Flight, Compensation)> {
    least_squares_aligned(trace, est, None)
}

/// [`least_squares`] on the scalar re-aligned by `lag`.
fn least_squares_aligned(
    trace: &Trace,
    est: &EstimatorSettings,
    lag: Option<ScalarLag>,
) -> Option<(Flight, Compensation)> {
    let tl_est = EstimatorSettings {
        tl_terms: "tl18".into(),
        tl_ridge: Some(0.0),
        ..est.clone()
    };
    tl::run_tl_method_aligned(trace, &tl_est, None, lag).ok()
}

/// `kalman`: the filter's calibration of `trace`, `least_squares` TL18-OLS's
/// ([`least_squares`]). Returns the filter's, or TL18-OLS's, with the cross-check
/// attached; the filter's as it is when either figure is missing. Where the filter found
/// and re-aligned a scalar delay, TL18-OLS is fitted again on the scalar re-aligned alike
/// (its file then carries the delay): without it a delayed `clean_s33` kept the filter's
/// per-heading offsets, 0.11 nT off the truth where TL18-OLS on the re-aligned scalar is
/// 0.03.
pub(super) fn choose(
    trace: &Trace,
    est: &EstimatorSettings,
    kalman: (Flight, Compensation),
    least_squares: Option<(Flight, Compensation)>,
) -> Result<(Flight, Compensation)> {
    let Some(kf_nt) = kalman.1.jackknife_nt else {
        return Ok(kalman);
    };
    let lag = kalman.1.coefficients.as_ref().and_then(|c| c.scalar_lag);
    let least_squares = match lag {
        Some(_) => least_squares_aligned(trace, est, lag),
        None => least_squares,
    };
    // A flight TL cannot fit (no fluxgate rows in the air, say) leaves the filter's result.
    let Some(least_squares) = least_squares else {
        return Ok(kalman);
    };
    let Some(tl_nt) = least_squares.1.jackknife_nt else {
        return Ok(kalman);
    };
    let difference: Vec<f64> = (kalman.1.interference_nt.iter())
        .zip(&least_squares.1.interference_nt)
        .map(|(a, b)| a - b)
        .collect();
    let disagreement_nt = crate::qc::figures::rms_demeaned(&difference);
    let band_disagreement_nt =
        Some(crate::qc::figures::band_rms_nt(&kalman.0, &difference)).filter(|d| d.is_finite());
    // Two estimates of one interference that differ beyond their errors: one of them is
    // wrong, and the jackknife cannot say which (a band-passed fit over strong geology
    // takes the anomaly into its coefficients the same way in every block: 56–135 nT off
    // at 300 m with a 0.3–0.7 nT jackknife). Judged in the manoeuvre band where both are
    // determined: least squares fits band-passed data, so its slow part and level are
    // whatever its coefficients make of them, and a full-band difference counts that as
    // disagreement (real box 1, `mag_4` with `flux_c`: 66 nT full band against jackknives
    // of 12.4 and 7.9 nT kept the filter, which transfers to box 2 at 3.31 nT against
    // TL18-OLS's 1.43).
    let band_jackknives = kalman
        .1
        .band_jackknife_nt
        .zip(least_squares.1.band_jackknife_nt);
    let consistent = match (band_disagreement_nt, band_jackknives) {
        (Some(d), Some((kf_band, tl_band))) => d <= DISAGREEMENT_SIGMAS * kf_band.hypot(tl_band),
        _ => disagreement_nt <= DISAGREEMENT_SIGMAS * kf_nt.hypot(tl_nt),
    };
    let (tl_lower, why) = tl_evidence(&kalman.1, &least_squares.1, (kf_nt, tl_nt));
    let chosen = if tl_lower && consistent {
        Estimator::TollesLawsonOls
    } else {
        Estimator::KalmanFilter
    };
    let blocked = tl_lower && !consistent;
    let figures = CrossCheck {
        blocks: crate::estimate::jackknife::BLOCKS,
        kalman_filter_jackknife_nt: kf_nt,
        tolles_lawson_jackknife_nt: tl_nt,
        kalman_filter_band_jackknife_nt: kalman.1.band_jackknife_nt,
        tolles_lawson_band_jackknife_nt: least_squares.1.band_jackknife_nt,
        disagreement_nt,
        band_disagreement_nt,
        kalman_filter_refit_inflation: kalman.1.refit_inflation,
        kalman_filter_holdout_band_nt: kalman.1.holdout_band_nt,
        tolles_lawson_holdout_band_nt: least_squares.1.holdout_band_nt,
        chosen,
    };
    let (flight, mut comp) = match chosen {
        Estimator::KalmanFilter if blocked => {
            let (flight, mut comp) = kalman;
            comp.warnings.push(format!(
                "Tolles–Lawson (TL18-OLS) looks better ({why}), but the two methods differ by \
                 {disagreement_nt:.3} nT rms, more than {DISAGREEMENT_SIGMAS} × their \
                 jackknife errors ({kf_nt:.3} and {tl_nt:.3} nT): one of them is wrong, and \
                 the filter's result is kept (least squares has no anomaly model; over geology \
                 it fits the anomaly). Check the calibration's altitude and `magcomp diagnose`"
            ));
            (flight, comp)
        }
        Estimator::KalmanFilter => kalman,
        Estimator::TollesLawsonOls => {
            let (flight, mut comp) = least_squares;
            if let Some(l) = lag {
                comp.warnings.push(format!(
                    "the scalar lags the fluxgate by {:.0} ± {:.0} ms: TL18-OLS was fitted on \
                     it re-aligned, and the coefficient file carries the delay (`scalar_lag`), \
                     which `compensate` applies",
                    l.lag_s * 1e3,
                    l.sigma_s * 1e3
                ));
            }
            comp.warnings.push(format!(
                "Tolles–Lawson (TL18, band-passed least squares) is used, not the Kalman \
                 filter: {why}; the two differ by {disagreement_nt:.3} nT rms. The anomaly \
                 states probably took part \
                 of the interference: an effect the model lacks, or an anomaly rougher than \
                 its process (`magcomp diagnose`). `--method kf` forces the filter"
            ));
            (flight, comp)
        }
    };
    if let Some(c) = comp.coefficients.as_mut() {
        c.cross_check = Some(figures);
    }
    Ok((flight, comp))
}

/// Two jackknife figures closer than this factor cannot be told apart: each is a spread
/// over [`BLOCKS`] refits, so the log of each has a standard error of 1/√(2(g − 1)) and
/// the log of their ratio 1/√(g − 1) (g = 8: a factor of 1.46).
pub fn jackknife_resolution() -> f64 {
    (1.0 / ((BLOCKS - 1) as f64).sqrt()).exp()
}

/// Whether the flight's evidence favours least squares, and that evidence in words.
///
/// The jackknife decides where it can. Where it cannot (its two figures within
/// [`jackknife_resolution`]) and the filter's refits move far beyond its own covariances
/// ([`INCONSISTENT_REFITS`]: its model does not hold, the anomaly states take
/// interference, and a spread misses the bias that leaves), the model-free held-out figure
/// decides (`holdout_band_nt`). Real boxes, `mag_4` with `flux_d`: jackknives 13.1 / 13.7
/// nT filter against 14.9 / 15.4 TL18-OLS, refits 93 / 71× beyond the filter's
/// covariances, held out 3.46 / 3.60 nT filter against 3.42 / 3.26; TL18-OLS transfers to
/// the other box at 2.91 / 3.02 nT, the filter at 3.36 / 3.16. The held-out figure alone
/// would not do: it favours least squares wherever a pattern flies over the same ground
/// again, since least squares' coefficients fit the recurring anomaly (our cloverleaf,
/// broad seed 2: held out 0.025 nT TL18-OLS against 0.032 filter, true error 0.130 against
/// 0.015; its jackknives, 0.047 against 0.026, decide).
fn tl_evidence(
    kalman: &Compensation,
    least_squares: &Compensation,
    jackknives: (f64, f64),
) -> (bool, String) {
    let (kf_nt, tl_nt) = jackknives;
    let tie = kf_nt.max(tl_nt) < jackknife_resolution() * kf_nt.min(tl_nt);
    let model_fails = kalman
        .refit_inflation
        .is_some_and(|f| f > INCONSISTENT_REFITS);
    let holdouts = kalman.holdout_band_nt.zip(least_squares.holdout_band_nt);
    match holdouts {
        Some((kf_held, tl_held)) if tie && model_fails => (
            tl_held < kf_held,
            format!(
                "the two jackknives ({kf_nt:.3} and {tl_nt:.3} nT) cannot be told apart, the \
                 filter's refits moved {:.0}× more than its model allows, and held out, its \
                 coefficients compensate the flight's other stretches at {kf_held:.3} nT in \
                 the band against least squares' {tl_held:.3} nT",
                kalman.refit_inflation.unwrap_or(f64::NAN)
            ),
        ),
        _ => (
            tl_nt < kf_nt,
            format!(
                "the filter's coefficients moved more between parts of this flight (jackknife \
                 {kf_nt:.3} nT rms) than least squares' ({tl_nt:.3} nT)"
            ),
        ),
    }
}
