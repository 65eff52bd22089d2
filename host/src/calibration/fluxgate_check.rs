//! What the calibration flight's fluxgate looked like, recorded in the coefficient file
//! (`provenance.fluxgate`), and the check of an applied flight's fluxgate against it.
//!
//! Coefficients hold for the fluxgate they were estimated with: a sign flipped on one axis
//! after calibration gave 11.96 nT (526×) and a +500 nT bias change 7.7×, both without a
//! warning. Two figures give them away without a truth: the calibrated modulus against the
//! scalar (`|M·B_F + b| − (mag − interference)`: a bias change moves its mean and, as the
//! attitude turns it, its spread), and the main-field direction the fluxgate and the INS
//! give together (a negated or swapped axis turns it, or the fluxgate stops turning with
//! the INS: the directions no longer average coherently over the headings).

use crate::estimate::fluxcal::{flight_flux, FluxgateCalibration};
use crate::flight::{FieldDirection, Flight};
use serde::{Deserialize, Serialize};

/// The fluxgate on one flight, through a calibration.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct FluxgateRecord {
    /// Mean and rms about it of `|M·B_F + b| − (mag − interference)` (nT).
    pub modulus_mean_nt: f64,
    pub modulus_sd_nt: f64,
    /// Main-field direction (NED unit vector) from the calibrated fluxgate and the INS.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub field_dir_ned: Option<[f64; 3]>,
    /// Length of the mean of the per-sample NED directions (1 = all agree): below
    /// [`MIN_COHERENCE`] the fluxgate does not turn with the INS.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub field_dir_coherence: Option<f64>,
    /// Determinant of the calibration matrix (< 0: a left-handed frame).
    pub determinant: f64,
}

/// The directions of a right-handed fluxgate agree to better than ~1° (the aircraft's
/// field is ≤ 1,000 nT of ~50,000); a swapped or negated axis on a pattern of four
/// headings leaves only the vertical part coherent (sin I ≈ 0.94 at I = 70°).
pub const MIN_COHERENCE: f64 = 0.99;
/// Main-field directions of the calibration and the applied flight more than this apart
/// (degrees) do not come from the same fluxgate frame: the field's direction changes by
/// ~1° per 100 km.
pub const MAX_DIRECTION_CHANGE_DEG: f64 = 10.0;

pub fn record(
    flight: &Flight,
    cal: &FluxgateCalibration,
    interference_nt: &[f64],
) -> FluxgateRecord {
    let flux = flight_flux(flight);
    let mut d = Vec::new();
    let mut dir = FieldDirection::default();
    for (i, b) in flux.iter().enumerate() {
        let c = cal.apply(*b);
        let m = flight.mag_nt[i] - interference_nt.get(i).copied().unwrap_or(f64::NAN);
        let r = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt() - m;
        if r.is_finite() {
            d.push(r);
        }
        dir.push(c, flight.samples[i].attitude_deg.map(f64::from));
    }
    let n = d.len().max(1) as f64;
    let mean = d.iter().sum::<f64>() / n;
    let sd = (d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
    FluxgateRecord {
        modulus_mean_nt: mean,
        modulus_sd_nt: sd,
        field_dir_ned: dir.finish().map(|v| v.map(f64::from)),
        field_dir_coherence: dir.coherence(),
        determinant: cal.determinant(),
    }
}

/// At calibration: a frame that is left-handed or does not turn with the INS, in words.
pub fn frame_warning(r: &FluxgateRecord) -> Option<String> {
    if r.determinant <= 0.0 {
        return Some(format!(
            "the fluxgate calibration's matrix has determinant {:.3}: a left-handed frame",
            r.determinant
        ));
    }
    match r.field_dir_coherence {
        Some(c) if c < MIN_COHERENCE => Some(format!(
            "the fluxgate does not turn with the INS: its main-field directions agree to \
             only {c:.3} (a right-handed fluxgate aligned with the INS gives > {MIN_COHERENCE}): \
             two axes swapped or one negated (a left-handed frame)? The coefficients hold for \
             this wiring only"
        )),
        _ => None,
    }
}

/// On an applied flight: how its fluxgate disagrees with the calibration's, in words.
pub fn applied_warnings(cal: &FluxgateRecord, now: &FluxgateRecord) -> Vec<String> {
    let mut w = Vec::new();
    // The spread of the calibration flight plus room for a survey's other attitudes and
    // ground; a +500 nT bias moves the mean or the spread by hundreds of nT.
    let tol = 5.0 * cal.modulus_sd_nt + 20.0;
    let shift = now.modulus_mean_nt - cal.modulus_mean_nt;
    if shift.abs() > tol || now.modulus_sd_nt > tol {
        w.push(format!(
            "the fluxgate disagrees with the one the coefficients were calibrated with: its \
             calibrated modulus minus the scalar is {:.1} ± {:.1} nT here against {:.1} ± {:.1} nT \
             at calibration (tolerance {tol:.1} nT): a changed fluxgate bias or scale, a sign \
             or wiring change? The compensation is not to be trusted",
            now.modulus_mean_nt, now.modulus_sd_nt, cal.modulus_mean_nt, cal.modulus_sd_nt
        ));
    }
    if let (Some(a), Some(b)) = (cal.field_dir_ned, now.field_dir_ned) {
        let cos = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]).clamp(-1.0, 1.0);
        let deg = cos.acos().to_degrees();
        if deg > MAX_DIRECTION_CHANGE_DEG {
            w.push(format!(
                "the fluxgate's main-field direction is {deg:.0}° from the calibration's \
                 (more than {MAX_DIRECTION_CHANGE_DEG}°): an axis negated or swapped since \
                 calibration? The compensation is not to be trusted"
            ));
        }
    }
    if let Some(f) = frame_warning(now) {
        w.push(f);
    }
    w
}
