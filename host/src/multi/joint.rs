//! The joint calibration of several scalar magnetometers (docs/model.md §7): each sensor
//! alone first (today's pipeline: its noise, σ1, fluxgate calibration), then one
//! [`magcomp_core::joint::JointFilter`] over all of them with the anomaly shared, and the
//! joint coefficients applied to every sample, as the single-sensor post-flight run does.

use super::choice::{checked_against_least_squares, choose_result, no_better_than_its_move};
use super::joint_pass::{choose_field_process, pass, prepare, prepare_flights, Pass, Prepared};
use super::lever::{lever_arms, LeverArm};
use super::result::{Alone, JointResult};
use super::sensors::{sensor_trace, SensorSpec};
use crate::calibration::result::Compensation;
use crate::calibration::{
    compensate_trace, fluxgate_witness, CoefficientFile, EstimatorSettings, Method,
};
use crate::estimate::kf::{interference_of, RegressorSpread};
use crate::flight::Flight;
use crate::io::trace::Trace;
use anyhow::{bail, Context, Result};
use magcomp_core::joint::MAX_SENSORS;

fn alone_settings(est: &EstimatorSettings) -> EstimatorSettings {
    EstimatorSettings {
        method: Method::Kf,
        cross_check: false,
        ..est.clone()
    }
}

/// Calibrates `sensors` of `trace` alone and together; with `est.cross_check` (the
/// default), each sensor checked against TL18-OLS.
pub fn calibrate_joint(
    trace: &Trace,
    est: &EstimatorSettings,
    sensors: &[SensorSpec],
) -> Result<JointResult> {
    calibrate_joint_checking(trace, est, sensors, &vec![est.cross_check; sensors.len()])
}

/// [`calibrate_joint`] with the default's checks asked per sensor (`checked[j]`, for
/// `calibrate --sensor-method mag_K=kf`): a sensor not checked is neither cross-checked
/// against TL18-OLS nor offered its fluxgate-witnessed calibration, as `--method kf`.
pub fn calibrate_joint_checking(
    trace: &Trace,
    est: &EstimatorSettings,
    sensors: &[SensorSpec],
    checked: &[bool],
) -> Result<JointResult> {
    if sensors.len() < 2 || sensors.len() > MAX_SENSORS {
        bail!(
            "a joint calibration takes 2 to {MAX_SENSORS} sensors (--sensors names {})",
            sensors.len()
        );
    }
    if checked.len() != sensors.len() {
        bail!(
            "{} sensors but {} cross-check choices",
            sensors.len(),
            checked.len()
        );
    }
    let alone = calibrate_alone(trace, est, sensors, checked)?;
    let files: Vec<CoefficientFile> = alone
        .iter()
        .map(|(_, c, _)| c.coefficients.clone().context("no coefficients"))
        .collect::<Result<_>>()?;
    let flights = prepare_flights(&alone, &files, est)?;
    let mut prepared = prepare(&flights, &files, sensors)?;
    // Each sensor's noise stays its alone calibration's: raising it to the robust joint
    // innovation rms (as the single-sensor run adapts its own) took a 300 m flight with
    // sensors 1 m apart from 0.02 to 19 nT.
    let label = choose_field_process(&mut prepared, &flights[0], &alone[0].1)?;
    let full = pass(&prepared, None)?;
    let refits = jackknife_refits(&prepared, &flights[0], sensors.len())?;
    let kept: Vec<&Compensation> = alone
        .iter()
        .map(|(_, c, w)| w.as_ref().unwrap_or(c))
        .collect();
    let levers = lever_arms(&flights, &kept, sensors);
    let mut results = Vec::new();
    let mut jackknife_nt = Vec::new();
    for (j, ((trace_j, alone_j, witnessed_j), s)) in alone.into_iter().zip(sensors).enumerate() {
        let flight = &flights[j];
        let evidence = SensorEvidence::of(&prepared, j, &refits[j], flight);
        jackknife_nt.push(evidence.jackknife_nt);
        let (mut joint, predicted) = joint_compensation(
            &full,
            j,
            evidence,
            flight,
            &files[j],
            (prepared.field.sigma1 as f64, &label),
            &s.name,
        );
        // The witnessed calibration, where there is one, is the sensor's own candidate.
        let alone_j = witnessed_j.unwrap_or(alone_j);
        let alone_predicted = alone_j
            .coefficients
            .as_ref()
            .and_then(|c| c.predicted_error_nt);
        let predicted = no_better_than_its_move(&mut joint, predicted, &alone_j, alone_predicted);
        let mut r = choose_result(s, alone_j, joint, predicted, alone_predicted, flight);
        if checked[j] {
            checked_against_least_squares(&mut r, &trace_j, est, flight)?;
        }
        r.lever_arm = levers[j];
        if let Some(l) = levers[j].filter(LeverArm::exceeds_noise) {
            r.alone.warnings.push(l.warning(&s.name));
        }
        results.push(r);
    }
    Ok(JointResult {
        sensors: results,
        flights,
        sigma1: prepared.field.sigma1 as f64,
        jackknife_nt,
    })
}

/// Each sensor alone ([`Alone`]): its single-sensor calibration is what the joint run
/// starts from; the witnessed one (`calibration::fluxgate_witness`) competes with the
/// joint one where the sensor is `checked` (the default's checks).
fn calibrate_alone(
    trace: &Trace,
    est: &EstimatorSettings,
    sensors: &[SensorSpec],
    checked: &[bool],
) -> Result<Vec<Alone>> {
    let est1 = alone_settings(est);
    let mut alone = Vec::new();
    for (s, &checked) in sensors.iter().zip(checked) {
        let t = sensor_trace(trace, s);
        let run = compensate_trace(&t, &est1, None, false)
            .with_context(|| format!("{} alone", s.name))?;
        // As the single-sensor default: `--method kf` keeps the model as given.
        let witness = if checked {
            fluxgate_witness::consider(&t, &est1, &run, &est1.model)
                .with_context(|| format!("{} alone, with its fluxgate as a witness", s.name))?
        } else {
            fluxgate_witness::Witness::default()
        };
        let mut comp = run.1;
        // The note goes with the calibration the sensor is offered.
        let witnessed = match witness.kept {
            Some((_, mut kept)) => {
                kept.warnings.extend(witness.note);
                Some(kept)
            }
            None => {
                comp.warnings.extend(witness.note);
                None
            }
        };
        alone.push((t, comp, witnessed));
    }
    Ok(alone)
}

/// Per sensor, the coefficients of the joint pass refitted with each jackknife block left
/// out: the flight's own evidence, as the single-sensor calibration (model.md §5b).
fn jackknife_refits(
    prepared: &Prepared,
    flight0: &Flight,
    sensors: usize,
) -> Result<Vec<Vec<Vec<f64>>>> {
    let span = crate::estimate::excitation::airborne_span(flight0);
    let blocks = crate::estimate::jackknife::blocks(&span, flight0.sample_rate_hz);
    let mut refits: Vec<Vec<Vec<f64>>> = vec![Vec::new(); sensors];
    for b in blocks.iter().flatten() {
        let p = pass(prepared, Some(b.clone()))?;
        for (j, c) in p.coefficients.into_iter().enumerate() {
            refits[j].push(c);
        }
    }
    Ok(refits)
}

/// What one sensor's regressors and jackknife refits say of its joint coefficients.
struct SensorEvidence {
    /// Per sample: the sensor's regressors with the environment terms' zeroed.
    interf_regs: Vec<Vec<f32>>,
    spread: Option<RegressorSpread>,
    /// The refits' covariance (None with fewer than two refits).
    jackknife_cov: Option<Vec<f64>>,
    jackknife_nt: Option<f64>,
    band_jackknife_nt: Option<f64>,
}

impl SensorEvidence {
    fn of(prepared: &Prepared, j: usize, refits: &[Vec<f64>], flight: &Flight) -> Self {
        let interf_regs: Vec<Vec<f32>> = prepared.regs[j]
            .iter()
            .map(|r| {
                r.iter()
                    .zip(&prepared.interference[j])
                    .map(|(v, i)| if *i { *v } else { 0.0 })
                    .collect()
            })
            .collect();
        let spread = RegressorSpread::of(&interf_regs);
        let jackknife_cov =
            (refits.len() >= 2).then(|| crate::estimate::jackknife::covariance(refits));
        let jackknife_nt = jackknife_cov
            .as_ref()
            .and_then(|c| spread.as_ref()?.sigma_nt(c));
        let band_jackknife_nt = (refits.len() >= 2)
            .then(|| {
                let series: Vec<Vec<f64>> = refits
                    .iter()
                    .map(|c| interference_of(&interf_regs, c))
                    .collect();
                crate::estimate::jackknife::band_sigma_nt(flight, &series)
            })
            .flatten();
        Self {
            interf_regs,
            spread,
            jackknife_cov,
            jackknife_nt,
            band_jackknife_nt,
        }
    }
}

/// Sensor `j`'s joint calibration (its alone file's settings with the joint coefficients,
/// covariance and predicted error) applied to its flight, and that predicted error.
/// `field` is the joint σ1 and the anomaly process's label.
fn joint_compensation(
    full: &Pass,
    j: usize,
    evidence: SensorEvidence,
    flight: &Flight,
    alone_file: &CoefficientFile,
    (sigma1, label): (f64, &str),
    name: &str,
) -> (Compensation, Option<f64>) {
    let SensorEvidence {
        interf_regs,
        spread,
        jackknife_cov,
        jackknife_nt: jk,
        band_jackknife_nt: band_jk,
    } = evidence;
    let k = full.coefficients[j].len();
    let mut cov = full.covariance[j].clone();
    if let Some(c) = &jackknife_cov {
        for (a, b) in cov.iter_mut().zip(c) {
            *a += b;
        }
    }
    let cov_sigma = spread
        .as_ref()
        .and_then(|s| s.sigma_nt(&full.covariance[j]));
    let interference_nt = interference_of(&interf_regs, &full.coefficients[j]);
    let compensated_nt: Vec<f64> = flight
        .mag_nt
        .iter()
        .zip(&interference_nt)
        .map(|(m, i)| m - i)
        .collect();
    // What the sensor's own calibration found beyond its noise, and what this output
    // carries at high frequency beyond it (`crate::qc::high_frequency`).
    let high_frequency = crate::qc::high_frequency::high_frequency(
        &compensated_nt,
        &flight.t_s,
        flight.sample_rate_hz,
    );
    let high_frequency_nt = high_frequency.map(|h| h.unfollowed_nt);
    let model_error =
        crate::qc::high_frequency::unexplained_range_nt(alone_file.model_error_nt, high_frequency);
    let predicted = cov_sigma
        .map(|c| (c * c + jk.unwrap_or(0.0).powi(2) + model_error[0] * model_error[0]).sqrt());
    let mut file = alone_file.clone();
    for (c, (v, i)) in file
        .coefficients
        .iter_mut()
        .zip(full.coefficients[j].iter().zip(0..k))
    {
        c.value = *v;
        c.sigma = cov[i * k + i].max(0.0).sqrt();
    }
    file.covariance = Some(cov.chunks(k).map(<[f64]>::to_vec).collect());
    file.sigma1 = Some(sigma1);
    file.predicted_error_nt = predicted;
    file.unfollowed_high_frequency_nt = high_frequency_nt;
    // The covariance and the jackknife summed, spread as their sum is.
    file.predicted_error_range_nt = spread
        .as_ref()
        .and_then(|s| s.error_range_nt(&cov, model_error));
    file.cross_check = None;
    file.rate_crossover = None;
    file.field_process = Some(label.to_string());
    let own_band = crate::qc::figures::band_rms_nt(flight, &compensated_nt);
    file.predicted_band_rms_nt = band_jk
        .filter(|_| own_band.is_finite())
        .map(|b| own_band.hypot(b));
    let mut warnings = Vec::new();
    if !full.healthy {
        warnings.push(format!(
            "{name}: the joint filter's covariance lost positive definiteness"
        ));
    }
    let joint = Compensation {
        model: file.model.clone(),
        method: Some(Method::Kf),
        interference_nt,
        compensated_nt,
        anomaly_nt: Some(full.anomaly[j].clone()),
        innovation_nt: Some(full.innovation[j].clone()),
        flags: None,
        interference_sigma_nt: None,
        coefficients: Some(file),
        regressors: interf_regs,
        warnings,
        jackknife_nt: jk,
        band_jackknife_nt: band_jk,
        holdout_band_nt: None,
        refit_inflation: None,
        withheld: None,
    };
    (joint, predicted)
}

/// Applies each sensor's coefficients (a joint calibration's, or any) to its columns of
/// `trace`: exactly `compensate --coeffs` on that sensor alone.
pub fn apply_each(
    trace: &Trace,
    est: &EstimatorSettings,
    sensors: &[SensorSpec],
    files: &[CoefficientFile],
) -> Result<Vec<(Flight, Compensation)>> {
    if sensors.len() != files.len() {
        bail!(
            "{} sensors but {} coefficient sets",
            sensors.len(),
            files.len()
        );
    }
    sensors
        .iter()
        .zip(files)
        .map(|(s, f)| {
            compensate_trace(
                &sensor_trace(trace, s),
                &alone_settings(est),
                Some(f),
                false,
            )
            .with_context(|| format!("{} with its coefficients", s.name))
        })
        .collect()
}
