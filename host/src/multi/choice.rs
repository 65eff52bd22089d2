//! Which set each sensor keeps: the joint one where its predicted error is at most the
//! alone one's, and then the one-sensor cross-check against TL18-OLS (issue 17: never worse
//! than classic Tolles–Lawson after landing).

use super::result::SensorResult;
use super::sensors::SensorSpec;
use crate::calibration::result::Compensation;
use crate::calibration::{cross_checked, EstimatorSettings, Method};
use crate::flight::Flight;
use crate::io::trace::Trace;
use anyhow::{Context, Result};

/// The default for several sensors checks each sensor's kept calibration against TL18-OLS
/// as the one-sensor default does (issue 17: never worse than classic Tolles–Lawson after
/// landing): where the flight's evidence trusts least squares more, its set is the
/// sensor's own (`alone`), with the cross-check's warning.
pub(super) fn checked_against_least_squares(
    r: &mut SensorResult,
    trace: &Trace,
    est: &EstimatorSettings,
    flight: &Flight,
) -> Result<()> {
    let (_, checked) = cross_checked(trace, est, (flight.clone(), r.chosen().clone()))
        .with_context(|| format!("{}: the TL18-OLS cross-check", r.spec.name))?;
    if checked.method == Some(Method::Tl) {
        r.truth_error_alone_nt = flight
            .truth_interference_nt
            .as_ref()
            .map(|t| crate::qc::truth::error_rms_nt(&checked.interference_nt, t, None));
        r.alone = checked;
        r.joint_chosen = false;
    } else {
        // The filter's set kept: with the check's record in its file and its warning (the
        // two methods disagreeing beyond their errors), as the one-sensor default keeps them.
        *r.chosen_mut() = checked;
    }
    Ok(())
}

/// The joint calibration's predicted error, held to what its move from the sensor's own
/// calibration shows. The joint estimate adds the other sensors' data to this one's; were
/// it efficient, the two would be nested and `var(alone − joint) = var(alone) − var(joint)`
/// (Hausman), so its error cannot be below `sqrt(alone_predicted² − d²)`, with `d` the
/// rms of their interferences' difference on this flight. Its covariance alone counted
/// the anomaly shared by every sensor as pinning this one's coefficients further than its
/// move from the alone set shows: at 3000 m (stinger + wingtips, seeds 1–10) the kept
/// stinger's actual/predicted was 0.64–2.90, mean square 2.18 (an honest rms gives 1), while
/// its joint and alone interferences differed by only 0.001–0.003 nT against errors of
/// 0.004–0.014. Held this way: 0.50–1.53, mean square 1.15. The range is widened alike.
/// Returns the figure the choice and the result use; `joint`'s file carries it.
pub(super) fn no_better_than_its_move(
    joint: &mut Compensation,
    predicted: Option<f64>,
    alone: &Compensation,
    alone_predicted: Option<f64>,
) -> Option<f64> {
    let (p, a) = (predicted?, alone_predicted);
    // Their difference, mean removed, as an error against truth is measured.
    let moved_nt =
        crate::qc::truth::error_rms_nt(&alone.interference_nt, &joint.interference_nt, None);
    let floor = a
        .filter(|_| moved_nt.is_finite())
        .map_or(0.0, |a| (a * a - moved_nt * moved_nt).max(0.0).sqrt());
    if floor <= p {
        return Some(p);
    }
    if let Some(file) = joint.coefficients.as_mut() {
        let scale = floor / p;
        file.predicted_error_nt = Some(floor);
        file.predicted_error_range_nt = file.predicted_error_range_nt.map(|r| r.map(|v| v * scale));
    }
    Some(floor)
}

/// The sensor's result: the joint calibration where its predicted error is at most the
/// alone one's, else the alone one with a warning saying why.
pub(super) fn choose_result(
    s: &SensorSpec,
    mut alone: Compensation,
    joint: Compensation,
    predicted: Option<f64>,
    alone_predicted: Option<f64>,
    flight: &Flight,
) -> SensorResult {
    let truth = flight.truth_interference_nt.as_ref();
    let err = |i: &[f64]| truth.map(|t| crate::qc::truth::error_rms_nt(i, t, None));
    let truth_error_alone_nt = err(&alone.interference_nt);
    let truth_error_joint_nt = err(&joint.interference_nt);
    let joint_chosen = match (predicted, alone_predicted) {
        (Some(p), Some(a)) => p <= a,
        (Some(_), None) => true,
        _ => false,
    };
    if !joint_chosen {
        alone.warnings.push(format!(
            "{}: the joint calibration predicts {} nT against {} nT alone: the sensor's \
             own calibration is kept (the anomaly differences between the sensors hold \
             more than the joint model describes)",
            s.name,
            predicted.map_or("?".into(), |p| format!("{p:.4}")),
            alone_predicted.map_or("?".into(), |p| format!("{p:.4}")),
        ));
    }
    SensorResult {
        joint_chosen,
        lever_arm: None,
        spec: s.clone(),
        alone,
        joint,
        predicted_error_nt: predicted,
        truth_error_alone_nt,
        truth_error_joint_nt,
    }
}
