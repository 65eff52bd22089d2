//! Is an applied calibration plausible on this flight? Coefficients from another aircraft
//! (or another installation) still produce numbers; these checks say loudly when they fit
//! the flight worse than no compensation at all, or leave far more than they predicted.

use crate::coefficients::CoefficientFile;
use crate::compensation::Compensation;
use crate::flight::Flight;
use crate::metrics::{band_rms_nt, improvement_ratio};

/// The aircraft-only band rms (KF: compensated − anomaly estimate in the manoeuvre band)
/// may exceed the predicted error plus the scalar noise by this factor before the
/// calibration is called implausible. Matching simulated coefficients leave 3–8× (it holds
/// the anomaly estimate's own error);
/// another aircraft's, ~10³× (`qc_applied` test).
pub const AIRCRAFT_RMS_FACTOR: f64 = 20.0;

/// Warnings about `coeffs` applied to `flight` (empty when plausible).
pub fn check(flight: &Flight, comp: &Compensation, coeffs: &CoefficientFile) -> Vec<String> {
    let mut out = Vec::new();
    if comp.withheld.is_some() {
        return out;
    }
    // Without manoeuvres the band holds little interference and IR ≈ 1 means nothing.
    let manoeuvring = crate::qc::inputs::excitation(flight) >= crate::qc::inputs::MIN_EXCITATION;
    if let Some(ir) = improvement_ratio(flight, &comp.compensated_nt).filter(|_| manoeuvring) {
        if ir < 1.0 {
            out.push(format!(
                "THE APPLIED COEFFICIENTS DO NOT FIT THIS FLIGHT: the improvement ratio in the manoeuvre band is {ir:.2} (< 1: compensation added interference). Were they calibrated on this aircraft, with this magnetometer and fluxgate installation and the same --map?"
            ));
        }
    }
    if let (Some(anomaly), Some(pred), Some(noise)) = (
        comp.anomaly_nt.as_deref(),
        comp.coefficients
            .as_ref()
            .and_then(|c| c.predicted_error_nt)
            .or(coeffs.predicted_error_nt),
        coeffs.noise_nt,
    ) {
        let corrected = flight.environment_corrected_nt(&comp.compensated_nt);
        let aircraft: Vec<f64> = corrected.iter().zip(anomaly).map(|(c, a)| c - a).collect();
        let rms = band_rms_nt(flight, &aircraft);
        let expected = pred.hypot(noise);
        if rms > AIRCRAFT_RMS_FACTOR * expected {
            out.push(format!(
                "THE APPLIED COEFFICIENTS DO NOT FIT THIS FLIGHT: what the aircraft left (compensated − anomaly estimate, manoeuvre band) is {rms:.3} nT rms, {:.0}× the {expected:.4} nT the calibration predicts with the scalar noise",
                rms / expected
            ));
        }
    }
    out
}
