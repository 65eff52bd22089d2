//! Whether the fluxgate sees a field of its own: the aircraft's field at the fluxgate,
//! which the `fluxmod` term (|B_F| − |B|) turns into a witness of the interference at the
//! scalar (TL18 spans the same through the fluxgate's B_j in its induced terms). Geology
//! cancels in the comparison, so the test cannot be fooled by the anomaly.

use crate::estimate::fluxcal::{self, FluxgateFit};
use crate::flight::Flight;

/// The fluxgate's calibrated misfit must exceed this many times the scalar's unexplained
/// rms before `fluxmod` is considered (`diagnose`'s candidate, the default calibration's
/// witness). A real survey aircraft's fluxgate: 31 nT after calibration against a 3.7 nT
/// residual; our simulator's: its 0.5 nT noise.
pub const MIN_OWN_FIELD_RATIO: f64 = 5.0;

/// How many times the scalar's unexplained signal (`unexplained_nt`: its model error or
/// noise) the fluxgate's modulus misfits after its 9-parameter calibration against the
/// scalar minus `interference_nt`: a ratio well above 1 is a field the fluxgate sees and
/// the scalar's residual cannot account for. `None` where the fit cannot be made.
pub fn own_field_ratio(
    flight: &Flight,
    interference_nt: &[f64],
    unexplained_nt: f64,
) -> Option<f64> {
    let fit = fluxcal::fit_flight(flight, interference_nt).ok()?;
    // Against the larger of what the scalar leaves unexplained and the fluxgate's own
    // white noise.
    let rms = unexplained_nt.max(calibrated_modulus_noise_nt(&fit).1);
    (rms > 0.0).then(|| fit.modulus_sd_after_nt / rms)
}

/// The calibrated modulus' finite residuals and their white noise (nT, from third
/// differences: robust to the smooth misfit the sd includes).
pub fn calibrated_modulus_noise_nt(fit: &FluxgateFit) -> (Vec<f64>, f64) {
    let resid: Vec<f64> = fit
        .residual_nt
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .collect();
    let noise = crate::estimate::kf::estimate_noise_nt(&resid).unwrap_or(0.0);
    (resid, noise)
}
