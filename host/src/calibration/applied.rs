//! Is an applied calibration plausible on this flight? Coefficients from another aircraft
//! (or another installation) still produce numbers; these checks say loudly when they fit
//! the flight worse than no compensation at all, or leave far more than they predicted.

use super::coefficients::CoefficientFile;
use super::result::Compensation;
use crate::flight::Flight;
use crate::qc::figures::{band_rms_nt, improvement_ratio};

/// The aircraft-only band rms (KF: compensated − anomaly estimate in the manoeuvre band)
/// may exceed the predicted error plus the scalar noise by this factor before the
/// calibration is called implausible. Matching simulated coefficients leave 3–8× (it holds
/// the anomaly estimate's own error);
/// another aircraft's, ~10³× (`qc_applied` test).
pub const AIRCRAFT_RMS_FACTOR: f64 = 20.0;

/// Warnings about `coeffs` applied to `flight` (empty when plausible).
pub fn check(flight: &Flight, comp: &Compensation, coeffs: &CoefficientFile) -> Vec<String> {
    let mut out = flag_shares(comp.flags.as_deref().unwrap_or(&[]), coeffs.model_error_nt);
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

/// Share of samples (of all) above which a flag is reported with applied coefficients: a
/// survey with fewer than 1 in 20 samples refused or degraded is usable as flown.
pub const FLAG_SHARE_WARNING: f64 = 0.05;

/// Survey mode: what the flags say about the flight when more than
/// [`FLAG_SHARE_WARNING`] of the samples carry one, and why. Box-1 coefficients applied to
/// the real box 2 had 68 % of the samples refused by the gate and nothing said so.
/// `model_error_nt`: what the calibration itself left unexplained (from the file).
pub fn flag_shares(flags: &[u16], model_error_nt: Option<f64>) -> Vec<String> {
    use magcomp_core::Flags;
    let n = flags.len();
    if n == 0 {
        return Vec::new();
    }
    let groups: [(u16, &str); 6] = [
        (
            Flags::INNOVATION_REJECTED,
            "refused by the innovation gate: the scalar departs from what the coefficients and \
             the anomaly model predict by more than 8σ of the scalar's noise, so the \
             coefficients do not describe this flight to that noise; those samples are \
             compensated but do not update the anomaly estimate",
        ),
        (
            Flags::FLUX_STALE | Flags::DERIVATIVE_DEGRADED,
            "compensated from a held or stale fluxgate frame or a one-sided derivative \
             (fluxgate dropouts or gaps)",
        ),
        (
            Flags::MAG_MISSING,
            "without a scalar value (missing or glitch)",
        ),
        (
            Flags::MAG_SUSPECT,
            "flagged MAG_SUSPECT: the scalar lies beyond 5σ of the prediction, or jumps \
             against its recent readings where the filter cannot judge it",
        ),
        (
            Flags::NO_GPS,
            "without a GPS fix (position and speed held, or assumed with --speed-mps)",
        ),
        (
            Flags::AUX_MISSING,
            "without an auxiliary channel the model uses",
        ),
    ];
    groups
        .iter()
        .filter_map(|(bits, why)| {
            let k = flags.iter().filter(|f| *f & bits != 0).count();
            let share = k as f64 / n as f64;
            // A trace without positions has no fix anywhere: its own warning says so.
            let positionless = *bits == Flags::NO_GPS && k == n;
            (share > FLAG_SHARE_WARNING && !positionless).then(|| {
                let calibration = match model_error_nt {
                    Some(m) if *bits == Flags::INNOVATION_REJECTED => format!(
                        " (the calibration itself left {m:.2} nT rms unexplained: `magcomp \
                         diagnose` names candidates)"
                    ),
                    _ => String::new(),
                };
                format!(
                    "{:.0} % of the samples ({k} of {n}) are {why}{calibration}",
                    100.0 * share
                )
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use magcomp_core::Flags;

    #[test]
    fn flags_above_one_in_twenty_are_reported_with_their_share() {
        let mut flags = vec![0u16; 1000];
        for f in flags.iter_mut().take(60) {
            *f = Flags::INNOVATION_REJECTED;
        }
        for f in flags.iter_mut().skip(500).take(50) {
            *f = Flags::FLUX_STALE;
        }
        let w = flag_shares(&flags, Some(3.2));
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(
            w[0].starts_with("6 % of the samples (60 of 1000) are refused"),
            "{}",
            w[0]
        );
        assert!(w[0].contains("3.20 nT"));
        assert!(flag_shares(&[0u16; 10], None).is_empty());
    }
}
