//! What a joint calibration hands back: each sensor's result (alone, joint, the set kept)
//! and the run's shared figures.

use super::lever::LeverArm;
use super::sensors::SensorSpec;
use crate::calibration::result::Compensation;
use crate::flight::Flight;
use crate::io::trace::Trace;

/// A sensor calibrated alone: its trace, today's single-sensor calibration (`--method kf`)
/// of it, and that calibration with `fluxmod` added where the sensor's fluxgate is a
/// decisive witness of its interference.
pub(super) type Alone = (Trace, Compensation, Option<Compensation>);

/// One sensor of the joint run: as calibrated alone and jointly.
#[derive(Clone, Debug)]
pub struct SensorResult {
    pub spec: SensorSpec,
    /// This sensor's own calibration: today's single-sensor filter (`--method kf`), or
    /// TL18-OLS where the default's cross-check kept least squares
    /// (`multi::choice`).
    pub alone: Compensation,
    /// The joint calibration: its coefficient file (the alone file's settings, the joint
    /// coefficients, covariance and predicted error) and per-sample output.
    pub joint: Compensation,
    pub predicted_error_nt: Option<f64>,
    /// The joint estimate is this sensor's result: its predicted error (covariance,
    /// jackknife, model error; no truth) is at most the alone calibration's. Otherwise the
    /// alone calibration is kept, with a warning ([`SensorResult::chosen`]).
    pub joint_chosen: bool,
    /// What the sensor's own lever arm does on this flight ([`super::lever`]): beyond the
    /// noise its alone calibration allowed for, that calibration's predicted error is a
    /// lower bound (its warnings say so).
    pub lever_arm: Option<LeverArm>,
    /// Error against the simulator's truth (nT rms, mean removed), alone and joint.
    pub truth_error_alone_nt: Option<f64>,
    pub truth_error_joint_nt: Option<f64>,
}

impl SensorResult {
    /// The result kept for this sensor: the joint one, or the alone one where the flight's
    /// own evidence says the joint one is worse.
    pub fn chosen(&self) -> &Compensation {
        if self.joint_chosen {
            &self.joint
        } else {
            &self.alone
        }
    }

    /// The kept calibration, to replace or amend.
    pub fn chosen_mut(&mut self) -> &mut Compensation {
        if self.joint_chosen {
            &mut self.joint
        } else {
            &mut self.alone
        }
    }

    /// Its predicted error (nT).
    pub fn chosen_predicted_nt(&self) -> Option<f64> {
        if self.joint_chosen {
            self.predicted_error_nt
        } else {
            self.alone.coefficients.as_ref()?.predicted_error_nt
        }
    }

    /// The kept predicted error is a lower bound: the alone calibration is kept and its
    /// lever arm's signal exceeds the noise it allowed for.
    pub fn chosen_predicted_is_lower_bound(&self) -> bool {
        !self.joint_chosen && self.lever_arm.is_some_and(|l| l.exceeds_noise())
    }

    /// Its error against the simulator's truth (nT).
    pub fn chosen_truth_error_nt(&self) -> Option<f64> {
        if self.joint_chosen {
            self.truth_error_joint_nt
        } else {
            self.truth_error_alone_nt
        }
    }
}

/// The joint run over all sensors.
#[derive(Clone, Debug)]
pub struct JointResult {
    pub sensors: Vec<SensorResult>,
    /// Per sensor, its flight (sensor 0's carries the shared track).
    pub flights: Vec<Flight>,
    pub sigma1: f64,
    /// The jackknife figure of each sensor (nT), included in its predicted error.
    pub jackknife_nt: Vec<Option<f64>>,
}
