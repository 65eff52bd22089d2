//! A run of the filter over a flight, in stages, each a type holding what it decided and
//! taking what the stages before it decided:
//!
//! 1. [`noise`]: σ1 of the anomaly process and the measurement noise ([`NoiseStage`]);
//! 2. [`excitation`]: the coefficient combinations the flight does not determine, held at
//!    their prior ([`ExcitationStage`]);
//! 3. [`field_process`]: the anomaly process, stationary or following the anomaly's local
//!    roughness ([`FieldProcessStage`]);
//! 4. the filter these three define (one [`PassSetup`]), and [`coefficients`]: the
//!    calibration pass under it ([`CalibrationPass`]);
//! 5. [`qc`]: the jackknife, the covariance, the predicted error, the warnings
//!    ([`QcStage`]);
//! 6. the output pass with the final coefficients, and the run's records.
//!
//! Every stage is made of [`filter_pass`]es; the stationary calibration pass at one
//! configuration ([`StationaryPass`]) is made once and handed on to the stages that start
//! from it. Before them come the stages that prepare the flight, each a type too: the
//! flight read, despiked and checked (`calibration::kf::PreparedFlight`; the scalar's
//! delay looked for there), its input corrections (`lag`, `fluxtemp`:
//! `crate::estimate::corrections::CorrectedFlight`), and with `fluxcal` the fluxgate's
//! calibration between a first run and a second (`crate::estimate::kf::FluxgateStage`),
//! which reuses the first run's [`Reusable`] (σ1 and the anomaly process's family; the
//! noise is chosen again, see [`calibrate`]).

mod coefficients;
mod excitation;
mod field_process;
pub(crate) mod filter_pass;
pub(crate) mod jackknife;
mod noise;
mod qc;

use super::{apply_rate_crossovers, push_outputs, KfOptions, KfRun};
use anyhow::{bail, Result};
use excitation::ExcitationStage;
use field_process::FieldProcessStage;
use filter_pass::{CalibrationPass, PassSetup, StationaryPass};
use magcomp_core::compensator::CompensatorConfig;
use magcomp_core::model::TermKind;
use noise::NoiseStage;
use qc::QcStage;

/// What a first run chose on the flight that a second run on the same flight (with the
/// fluxgate calibrated) reuses.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Reusable {
    /// σ1 (the spectrum and the candidates' passes): the fluxgate's calibration moves the
    /// interference by far less than what chose it.
    pub sigma1: f64,
    /// The anomaly process family chosen (0 the stationary, k the k-th profile).
    pub field_family: Option<usize>,
}

/// The run in stages (see the module's list). `reuse`: what a first run on the same
/// flight chose.
pub(crate) fn calibrate(
    flight: &crate::flight::Flight,
    opts: &KfOptions,
    reuse: Option<&Reusable>,
) -> Result<(KfRun, Reusable)> {
    if flight.is_empty() {
        bail!("no samples");
    }
    // σ1 is reused; the noise is adapted again: what the first run's innovations showed
    // beyond the sensor's noise included the fluxgate's error its calibration took out.
    let sigma1 = reuse.map(|r| r.sigma1).or(opts.sigma1);
    let (noise, made) = NoiseStage::choose(flight, opts, sigma1)?;
    let cfg = noise.filter_config(flight, opts);
    let (excitation, made) = excitation_stage(flight, opts, cfg, made)?;
    // The anomaly process is chosen again: the innovations that choose it carried the
    // fluxgate's error before its calibration (reusing the first run's choice cost the
    // joint filter at 300 m over strong geology 0.028 → 0.045 nT on a sensor, `multi_sim`).
    // Within the first run's family: its scale is what the fluxgate's error moved.
    let family = reuse.and_then(|r| r.field_family);
    let model_error = noise.model_error_nt.is_some();
    let (field, made) = field_process_stage(
        flight,
        opts,
        (cfg, &excitation.held, model_error),
        made,
        family,
    )?;
    let filter = PassSetup {
        field_profile: field.profile.as_deref(),
        ..PassSetup::held(cfg, &excitation.held)
    };
    let calibration = coefficients::calibration_pass(flight, opts, &filter, made)?;
    let qc = QcStage::check(flight, opts, &filter, &calibration, &noise)?;
    let output = coefficients::output_pass(flight, opts, &filter, calibration)?;
    let reusable = Reusable {
        sigma1: noise.sigma1,
        field_family: field.family,
    };
    Ok((
        report(flight, opts, (noise, excitation, field, qc), output),
        reusable,
    ))
}

/// The excitation stage on the stationary pass at `cfg` (nothing held), post-flight.
fn excitation_stage(
    flight: &crate::flight::Flight,
    opts: &KfOptions,
    cfg: CompensatorConfig,
    made: Option<StationaryPass>,
) -> Result<(ExcitationStage, Option<StationaryPass>)> {
    if !ExcitationStage::applies(opts) {
        return Ok((ExcitationStage::default(), made));
    }
    let stationary = StationaryPass::at(flight, opts, (cfg, &[]), made)?;
    let stage = ExcitationStage::check(flight, opts, &stationary.pass.regressors);
    Ok((stage, Some(stationary)))
}

/// The anomaly-process stage on the stationary pass at `cfg` with `held` held, when the
/// choice runs (`model_error`: the noise stage found error beyond the sensor's noise).
fn field_process_stage(
    flight: &crate::flight::Flight,
    opts: &KfOptions,
    (cfg, held, model_error): (CompensatorConfig, &[Vec<f32>], bool),
    made: Option<StationaryPass>,
    family: Option<usize>,
) -> Result<(FieldProcessStage, Option<StationaryPass>)> {
    if !FieldProcessStage::applies(opts, model_error) {
        return Ok((FieldProcessStage::stationary(), made));
    }
    let stationary = StationaryPass::at(flight, opts, (cfg, held), made)?;
    let stage = FieldProcessStage::choose(flight, opts, (cfg, held), &stationary.pass, family)?;
    Ok((stage, Some(stationary)))
}

/// The run's record of what the stages decided and of the output pass.
fn report(
    flight: &crate::flight::Flight,
    opts: &KfOptions,
    (noise, excitation, field, qc): (NoiseStage, ExcitationStage, FieldProcessStage, QcStage),
    output: CalibrationPass,
) -> KfRun {
    let spec = &opts.model;
    let mut warnings: Vec<String> = excitation.warning.into_iter().collect();
    warnings.extend(qc.warnings);
    let mut run = KfRun {
        coefficient_names: spec.coefficient_names(),
        coefficient_sigmas: qc.sigmas,
        predicted_error_nt: qc.predicted_error_nt,
        predicted_error_range_nt: qc.predicted_error_range_nt,
        unfollowed_high_frequency_nt: qc.high_frequency_nt,
        coefficient_covariance: qc.covariance,
        coefficients: output.coefficients,
        regressors: output.regressors,
        sigma1: noise.sigma1,
        noise_nt: noise.noise_nt,
        model_error_nt: noise.model_error_nt,
        warnings,
        filter_healthy: output.healthy,
        jackknife: qc.jackknife,
        field_process: if spec.field {
            field.label
        } else {
            String::from("none")
        },
        ..Default::default()
    };
    push_outputs(&mut run, &output.outputs, flight);
    if spec.has(TermKind::Rate) {
        apply_rate_crossovers(flight, opts, &mut run);
    }
    run
}
