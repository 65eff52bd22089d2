//! The coefficients stage: the calibration pass with everything the stages before it
//! chose (or the given coefficients applied), and, post-flight, the output pass that
//! applies the final coefficients to every sample.

use super::super::KfOptions;
use super::filter_pass::{self, CalibrationPass, PassSetup, StationaryPass};
use crate::flight::Flight;
use anyhow::Result;

/// The calibration pass: with given coefficients, their pass (survey mode); else the
/// filter calibrating under `filter`, switched to survey mode at `KfOptions::survey_from`
/// in real time. `made`: the stationary pass an earlier stage made, taken when it is this
/// very pass.
pub(crate) fn calibration_pass(
    flight: &Flight,
    opts: &KfOptions,
    filter: &PassSetup,
    made: Option<StationaryPass>,
) -> Result<CalibrationPass> {
    if let Some(c) = &opts.coefficients {
        return filter_pass::run(flight, opts, &PassSetup::plain(filter.cfg), Some(c), true);
    }
    if filter.field_profile.is_none() && opts.survey_from.is_none() {
        let key = (filter.cfg, filter.held);
        return Ok(StationaryPass::at(flight, opts, key, made)?.pass);
    }
    drop(made);
    let setup = PassSetup {
        survey_from: opts.survey_from,
        ..filter.clone()
    };
    filter_pass::run(flight, opts, &setup, None, true)
}

/// The records the run outputs and whether the filter stayed healthy: the calibration
/// pass's own in real time or with given coefficients; post-flight, a survey-mode pass
/// with the final coefficients (the calibration is judged at its end).
pub(crate) fn output_pass(
    flight: &Flight,
    opts: &KfOptions,
    filter: &PassSetup,
    calibration: CalibrationPass,
) -> Result<CalibrationPass> {
    if opts.realtime || opts.coefficients.is_some() {
        return Ok(calibration);
    }
    let applied = filter_pass::run(flight, opts, filter, Some(&calibration.coefficients), false)?;
    Ok(CalibrationPass {
        outputs: applied.outputs,
        healthy: calibration.healthy && applied.healthy,
        ..calibration
    })
}
