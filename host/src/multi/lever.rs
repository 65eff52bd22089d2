//! An off-centre sensor's own lever arm, judged on the flight (docs/model.md §7).
//!
//! The aircraft turns about the trajectory's point (the INS), so a sensor `r` from it
//! moves by `Cᵀ(t)·r` in every manoeuvre: a wingtip 8 m out rises and falls 1.4 m in a 10°
//! roll. Calibrated alone, the sensor's model places the anomaly on the trajectory: what
//! the anomaly's gradient makes of that motion is signal the model lacks, in the manoeuvre
//! band and correlated with attitude, i.e. with the coefficients. It biases them, and
//! neither the filter's covariance (its model has no such signal) nor the jackknife
//! (every refit flies the same geology) counts it. Simulated, 300 m over strong geology,
//! seeds 1–4: the wingtips' alone calibrations were 0.08–0.34 nT off the truth, 1.0–2.4 ×
//! their predicted error; given the stinger's anomaly instead of their own (no lever arm)
//! the same sensors were 0.03–0.22 nT off, 0.6–1.8 × predicted. The stinger sits at the
//! trajectory's point and is not affected.
//!
//! Its size is measured here without truth: the motion from the INS attitude and the
//! sensor's position, band-passed; the gradient from the sensors' own compensated signals,
//! their difference over their separation. Where the product exceeds the noise the filter
//! was told of, the sensor's alone predicted error is a lower bound, and its warning says so.

use super::sensors::SensorSpec;
use crate::calibration::result::Compensation;
use crate::flight::Flight;
use crate::qc::figures::{band_passed, rms_demeaned};

/// Sensors closer than this (m) say nothing of the gradient beyond their noise.
const MIN_SEPARATION_M: f64 = 1.0;

/// What one sensor's lever arm does on this flight.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LeverArm {
    /// The anomaly's gradient between the sensors (nT/m, rms): the median over the pairs
    /// of their compensated difference (mean removed) over their separation.
    pub gradient_nt_per_m: f64,
    /// The sensor's attitude-driven motion in the manoeuvre band (m rms, the three axes).
    pub motion_band_m: f64,
    /// Their product: the unmodelled signal the motion makes (nT rms, band).
    pub signal_band_nt: f64,
    /// The noise the sensor's alone calibration assumed (nT).
    pub noise_nt: f64,
}

impl LeverArm {
    /// The signal exceeds the noise the filter allowed for: its figure is a lower bound.
    pub fn exceeds_noise(&self) -> bool {
        self.signal_band_nt > self.noise_nt
    }

    pub fn warning(&self, name: &str) -> String {
        format!(
            "{name}: its attitude moves it {:.2} m (rms, manoeuvre band) through an anomaly \
             gradient of {:.3} nT/m (between the sensors): {:.3} nT of signal its own model \
             lacks, beyond the {:.3} nT noise it allowed for. It biases the coefficients and \
             neither the covariance nor the jackknife counts it: the predicted error is a \
             lower bound",
            self.motion_band_m, self.gradient_nt_per_m, self.signal_band_nt, self.noise_nt
        )
    }
}

/// Per sensor, its lever arm on this flight; None where its position (or any two
/// positions ≥ 1 m apart, or the attitude) is unknown, or the sensors' flights differ in
/// length. `comps`: each sensor's alone calibration as kept.
pub fn lever_arms(
    flights: &[Flight],
    comps: &[&Compensation],
    sensors: &[SensorSpec],
) -> Vec<Option<LeverArm>> {
    let none = vec![None; sensors.len()];
    let n = flights.first().map_or(0, Flight::len);
    if flights.len() != sensors.len()
        || comps.len() != sensors.len()
        || flights.iter().any(|f| f.len() != n)
        || comps.iter().any(|c| c.compensated_nt.len() != n)
    {
        return none;
    }
    let Some(gradient) = gradient_nt_per_m(comps, sensors) else {
        return none;
    };
    sensors
        .iter()
        .zip(flights.iter().zip(comps))
        .map(|(s, (f, c))| {
            let motion_band_m = motion_band_m(f, s.position_m?)?;
            let noise_nt = c.coefficients.as_ref()?.noise_nt?;
            Some(LeverArm {
                gradient_nt_per_m: gradient,
                motion_band_m,
                signal_band_nt: gradient * motion_band_m,
                noise_nt,
            })
        })
        .collect()
}

/// The median over sensor pairs ≥ [`MIN_SEPARATION_M`] apart of rms(difference of their
/// compensated signals, mean removed) / separation.
fn gradient_nt_per_m(comps: &[&Compensation], sensors: &[SensorSpec]) -> Option<f64> {
    let mut g = Vec::new();
    for a in 0..sensors.len() {
        for b in a + 1..sensors.len() {
            let sep = super::separation_m(&sensors[a], &sensors[b])?;
            if sep < MIN_SEPARATION_M {
                continue;
            }
            let d: Vec<f64> = comps[a]
                .compensated_nt
                .iter()
                .zip(&comps[b].compensated_nt)
                .map(|(x, y)| x - y)
                .filter(|v| v.is_finite())
                .collect();
            let r = rms_demeaned(&d) / sep;
            if r.is_finite() {
                g.push(r);
            }
        }
    }
    g.sort_by(f64::total_cmp);
    match g.len() {
        0 => None,
        k if k % 2 == 1 => Some(g[k / 2]),
        k => Some(0.5 * (g[k / 2 - 1] + g[k / 2])),
    }
}

/// The sensor's motion about the trajectory's point in the manoeuvre band: `Cᵀ(t)·r` (NED)
/// band-passed per axis, the axes' rms summed in quadrature. None without attitude.
fn motion_band_m(flight: &Flight, r: [f64; 3]) -> Option<f64> {
    let r = nalgebra::Vector3::new(r[0], r[1], r[2]);
    let mut axes = [const { Vec::new() }; 3];
    for s in &flight.samples {
        let [roll, pitch, yaw] = s.attitude_deg.map(|a| (a as f64).to_radians());
        let p = crate::sim::dcm_ned_to_body(roll, pitch, yaw).transpose() * r;
        for (axis, v) in axes.iter_mut().zip(p.iter()) {
            axis.push(*v);
        }
    }
    let mut sum = 0.0;
    for axis in &axes {
        let band = band_passed(flight, axis)?;
        let v = rms_demeaned(&band);
        if !v.is_finite() {
            return None;
        }
        sum += v * v;
    }
    Some(sum.sqrt())
}
