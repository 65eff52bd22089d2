//! The QC stage: what the flight's own parts say of the coefficients (the jackknife), the
//! covariance the run reports, the flight's predicted error and the warnings a user must
//! read.

use super::super::{interference_of, KfOptions, RegressorSpread, MODEL_ERROR_WARNING_NT};
use super::filter_pass::{CalibrationPass, PassSetup};
use super::jackknife::{kf_jackknife, KfJackknife, INCONSISTENT_REFITS};
use super::noise::NoiseStage;
use crate::flight::Flight;
use anyhow::Result;

/// What the QC stage found.
pub(crate) struct QcStage {
    /// The coefficients' covariance (k×k, row-major, physical units) the run reports.
    pub covariance: Vec<f64>,
    /// Each coefficient's 1σ.
    pub sigmas: Vec<f64>,
    /// `RegressorSpread::sigma_nt` on this flight with the model error added.
    pub predicted_error_nt: Option<f64>,
    /// The range one flight's actual error falls in (`crate::qc::error_range`).
    pub predicted_error_range_nt: Option<[f64; 2]>,
    pub jackknife: Option<KfJackknife>,
    /// The output's high-frequency content beyond the scalar's noise
    /// (`crate::qc::high_frequency`), counted in the predicted error.
    pub high_frequency_nt: Option<f64>,
    /// In order: the jackknife's (refits inconsistent), the model error's.
    pub warnings: Vec<String>,
}

impl QcStage {
    /// The checks on the calibration pass made under `filter`.
    pub fn check(
        flight: &Flight,
        opts: &KfOptions,
        filter: &PassSetup,
        calibration: &CalibrationPass,
        noise: &NoiseStage,
    ) -> Result<Self> {
        let mut warnings = Vec::new();
        let spread = RegressorSpread::of(&calibration.regressors);
        let (covariance, jackknife) = with_jackknife(
            flight,
            opts,
            filter,
            calibration,
            spread.as_ref(),
            &mut warnings,
        )?;
        let k = calibration.coefficients.len();
        let sigmas = (0..k)
            .map(|i| covariance[i * k + i].max(0.0).sqrt())
            .collect();
        let high_frequency = output_high_frequency(flight, calibration);
        let high_frequency_nt = high_frequency.map(|h| h.unfollowed_nt);
        let unexplained_nt =
            crate::qc::high_frequency::unexplained_range_nt(noise.model_error_nt, high_frequency);
        let (covariance, predicted) =
            predicted_error(opts, spread.as_ref(), covariance, unexplained_nt);
        if let Some(m) = noise.model_error_nt.filter(|m| *m > MODEL_ERROR_WARNING_NT) {
            let sensor_noise_nt = noise.sensor_noise_nt;
            warnings.push(format!(
                "the model leaves {m:.2} nT rms of the signal unexplained beyond the scalar's \
                 own noise ({sensor_noise_nt:.3} nT): an effect the model lacks stays in the \
                 compensated output and is counted in the predicted error. `magcomp diagnose` \
                 names candidates (docs/adding-an-effect.md)"
            ));
        }
        warnings.extend(crate::qc::high_frequency::warning(high_frequency_nt));
        Ok(Self {
            high_frequency_nt,
            covariance,
            sigmas,
            predicted_error_nt: predicted.map(|p| p.figure_nt),
            predicted_error_range_nt: predicted.and_then(|p| p.range_nt),
            jackknife,
            warnings,
        })
    }
}

/// The output of the calibration's final coefficients above its quietest windows at high
/// frequency (`crate::qc::high_frequency`). Not the pass's own records: while the filter
/// converges its coefficients move from sample to sample (on `lag_s32` that read 0.56 nT).
fn output_high_frequency(
    flight: &Flight,
    calibration: &CalibrationPass,
) -> Option<crate::qc::high_frequency::HighFrequency> {
    if calibration.regressors.len() != flight.len() {
        return None;
    }
    let interference = interference_of(&calibration.regressors, &calibration.coefficients);
    let compensated: Vec<f64> = flight
        .mag_nt
        .iter()
        .zip(&interference)
        .map(|(mag, i)| mag - i)
        .collect();
    crate::qc::high_frequency::high_frequency(&compensated, &flight.t_s, flight.sample_rate_hz)
}

/// The coefficients' covariance with the jackknife's added, and the jackknife, when it
/// applies. Post-flight: what the flight's own parts say of the coefficients, beside what
/// the filter's model says (`crate::estimate::jackknife`); the covariance carries both.
fn with_jackknife(
    flight: &Flight,
    opts: &KfOptions,
    filter: &PassSetup,
    calibration: &CalibrationPass,
    spread: Option<&RegressorSpread>,
    warnings: &mut Vec<String>,
) -> Result<(Vec<f64>, Option<KfJackknife>)> {
    let covariance = &calibration.covariance;
    let checked = opts.jackknife && !opts.realtime && opts.coefficients.is_none();
    let Some(spread) = spread.filter(|_| checked) else {
        return Ok((covariance.clone(), None));
    };
    let regs = &calibration.regressors;
    let full = (&calibration.coefficients[..], &covariance[..]);
    let Some(j) = kf_jackknife(flight, opts, filter, (regs, spread), full)? else {
        return Ok((covariance.clone(), None));
    };
    // Summed, not the larger of the two: on the broad simulated flights the filter's
    // covariance and the jackknife each came out at 0.5–0.8 × the actual error (the model
    // error they both miss is most of it), their sum at 0.57–1.99 ×; the price is 2–3 ×
    // pessimism over strong geology.
    let total = covariance
        .iter()
        .zip(&j.covariance)
        .map(|(a, b)| a + b)
        .collect();
    if j.inflation > INCONSISTENT_REFITS {
        warnings.push(j.lower_bound_warning());
    }
    Ok((total, Some(j)))
}

/// The flight's predicted error (the model error added) and the range one flight's actual
/// error falls in beside it.
#[derive(Clone, Copy)]
struct PredictedError {
    figure_nt: f64,
    range_nt: Option<[f64; 2]>,
}

/// The covariance the run reports and the flight's predicted error (with the model error
/// added: its low end, `model_error_nt` being what the output carries beyond the scalar's
/// noise, low and high). Given coefficients predict this flight's error only with their
/// own covariance.
fn predicted_error(
    opts: &KfOptions,
    spread: Option<&RegressorSpread>,
    covariance: Vec<f64>,
    model_error_nt: [f64; 2],
) -> (Vec<f64>, Option<PredictedError>) {
    let covariance = match (&opts.coefficients, &opts.coefficient_covariance) {
        (Some(_), Some(given)) => given.clone(),
        (Some(_), None) => return (covariance, None),
        (None, _) => covariance,
    };
    let predicted = spread.and_then(|s| {
        Some(PredictedError {
            figure_nt: s.sigma_nt(&covariance)?.hypot(model_error_nt[0]),
            range_nt: s.error_range_nt(&covariance, model_error_nt),
        })
    });
    (covariance, predicted)
}
