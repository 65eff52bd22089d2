//! The default calibration's fluxgate witness. A fluxgate mounted near the scalar sees the
//! aircraft's field too; `fluxmod` (|B_F| − |B|) turns what it sees into a regressor, as
//! TL18 does implicitly through the fluxgate's B_j in its induced terms. The filter's
//! default model does not carry it, because where the fluxgate sees only the Earth (our
//! simulator, most installations) it adds the fluxgate's noise and nothing else.
//!
//! So the default calibration tries it where the flight shows it can matter — the
//! fluxgate's calibrated modulus misfits by several times what the scalar leaves
//! unexplained ([`MIN_OWN_FIELD_RATIO`]) — and keeps it only where the flight's own
//! evidence is decisive on both counts it has: the jackknife (how much the coefficients
//! move between parts of the flight) and the held-out band figure (how well coefficients
//! from the other parts compensate each part) must each fall by more than the jackknife's
//! resolution. Real SGL boxes (band std of the other box, box 1 → 2 / 2 → 1): `mag_3` with
//! `flux_b` 4.41 / 4.80 → 1.73 / 2.21 nT and `mag_4` with `flux_c` 1.40 / 1.68 → 0.86 / 1.11
//! (TL18-OLS 4.41 / 4.87 and 1.40 / 1.68); where only one figure falls (`mag_4` with
//! `flux_d`, box 1: jackknife 13.1 → 8.7, held out 3.46 → 2.89 nT) it is not kept, and
//! that transfer would have been 2.98 nT against TL18-OLS's 2.91.

use super::cross_check::jackknife_resolution;
use super::result::Compensation;
use super::{kf, EstimatorSettings};
use crate::estimate::fluxgate_witness::{own_field_ratio, MIN_OWN_FIELD_RATIO};
use crate::flight::Flight;
use crate::io::trace::Trace;
use crate::model::spec::ModelSpec;
use anyhow::Result;
use magcomp_core::model::TermKind;

/// What trying the fluxgate as a witness gave: the calibration with `fluxmod`, where it is
/// kept, and the note that says how it went (the caller shows it whichever calibration it
/// finally uses).
#[derive(Default)]
pub struct Witness {
    pub kept: Option<(Flight, Compensation)>,
    pub note: Option<String>,
}

/// Tries the fluxgate as a witness beside `kalman`, the filter's calibration under
/// `model_text`: the calibration with `fluxmod` added is kept where it is decisively better.
pub fn consider(
    trace: &Trace,
    est: &EstimatorSettings,
    kalman: &(Flight, Compensation),
    model_text: &str,
) -> Result<Witness> {
    let spec = ModelSpec::parse(model_text)?;
    if spec.has(TermKind::FluxMod) || !spec.has(TermKind::Induced) {
        return Ok(Witness::default());
    }
    let Some(ratio) = sees_own_field(kalman) else {
        return Ok(Witness::default());
    };
    let with_text = spec.with(TermKind::FluxMod.name())?.text();
    // A candidate that cannot be fitted leaves the filter's calibration as it was.
    let Ok(witnessed) = kf::run_kf_method(trace, est, None, false, &with_text) else {
        return Ok(Witness::default());
    };
    let figures = |c: &Compensation| c.jackknife_nt.zip(c.holdout_band_nt);
    let (Some((jk0, held0)), Some((jk1, held1))) = (figures(&kalman.1), figures(&witnessed.1))
    else {
        return Ok(Witness::default());
    };
    let resolution = jackknife_resolution();
    let evidence = format!(
        "jackknife {jk0:.3} → {jk1:.3} nT, held out in the band {held0:.3} → {held1:.3} nT"
    );
    if jk0 > resolution * jk1 && held0 > resolution * held1 {
        let weight = witness_weight(&witnessed.1);
        let note = format!(
            "the fluxgate sees a field of its own ({ratio:.0}× what the scalar leaves \
             unexplained) and is used as a witness of the interference: `fluxmod` is added \
             to the model ({evidence}; `--method kf` keeps the model as given). Its \
             coefficient is {weight:+.2}: the compensated field takes {:.0} % of its \
             variation from the fluxgate's modulus, so the fluxgate's noise and slow drift \
             enter the survey at that weight (levelling removes a slow drift)",
            100.0 * weight.abs()
        );
        return Ok(Witness {
            kept: Some(witnessed),
            note: Some(note),
        });
    }
    let note = format!(
        "the fluxgate sees a field of its own ({ratio:.0}× what the scalar leaves \
         unexplained), but adding `fluxmod` did not improve the filter's calibration beyond \
         the jackknife's resolution of {resolution:.2}× on both counts ({evidence}): not added"
    );
    Ok(Witness {
        kept: None,
        note: Some(note),
    })
}

/// `fluxmod`'s coefficient (nT/nT): compensated = scalar − c·(|B_F| − |B|) − …, so |c| is
/// the share of the output read from the fluxgate.
fn witness_weight(comp: &Compensation) -> f64 {
    comp.coefficients
        .iter()
        .flat_map(|f| &f.coefficients)
        .find(|c| c.name.starts_with(TermKind::FluxMod.name()))
        .map_or(f64::NAN, |c| c.value)
}

/// The fluxgate's own-field ratio where it reaches [`MIN_OWN_FIELD_RATIO`].
fn sees_own_field((flight, comp): &(Flight, Compensation)) -> Option<f64> {
    let file = comp.coefficients.as_ref()?;
    let unexplained_nt = file
        .model_error_nt
        .unwrap_or(0.0)
        .max(file.noise_nt.unwrap_or(0.0));
    let interference_nt: Vec<f64> = (flight.mag_nt.iter())
        .zip(&comp.compensated_nt)
        .map(|(m, c)| m - c)
        .collect();
    own_field_ratio(flight, &interference_nt, unexplained_nt).filter(|&r| r >= MIN_OWN_FIELD_RATIO)
}
