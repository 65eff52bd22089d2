//! Post-flight compensation with terms that are not in the core catalogue (yet): the
//! same two passes as `corrections::run_kf` (calibrate on the flight, then apply the final
//! coefficients), with a model built from any `Term` values. Lets a user check a new
//! effect end to end before it is pasted into `core/src/model` (docs/adding-an-effect.md).

use crate::estimate::kf;
use crate::flight::Flight;
use anyhow::{bail, Result};
use magcomp_core::model::{Model, Term};

/// Interference estimate per sample (nT) and the final coefficients, post-flight.
/// `sigma1` as in [`crate::estimate::kf::KfRun`] (take it from a run of the catalogue model on
/// the same flight); `noise_nt` the scalar's own noise ([`crate::estimate::kf::KfRun::sensor_noise_nt`]),
/// not the run's adapted noise: that one counts the very effect being added as model
/// error (a sensor-temperature drift at 10° N: 0.163 nT left with it, 0.086 without).
pub fn post_flight_with_terms(
    flight: &Flight,
    field: bool,
    terms: &[&dyn Term],
    sigma1: f64,
    noise_nt: f64,
) -> Result<(Vec<f64>, Vec<f64>)> {
    let geometry = (
        flight.sample_rate_hz,
        flight.earth_dir_ned,
        flight.tie_point,
    );
    let mut cfg = kf::base_config(geometry, sigma1, noise_nt, kf::SIGMA2_RATIO);
    kf::set_run_mode(&mut cfg, false);
    let model = Model { field, terms };
    let k = model.coefficient_count();
    // Named by its terms in the filter's errors, as a catalogue model by its text.
    let names: Vec<&str> = terms.iter().map(|t| t.name()).collect();
    let label = format!("{}{}", if field { "field+" } else { "" }, names.join("+"));
    let mut comp = kf::build(&label, model, cfg, None, &[])?;
    for s in &flight.samples {
        comp.push(s);
    }
    while comp.flush().is_some() {}
    let mut c = vec![0.0f32; k];
    comp.coefficients(&mut c);
    let c64: Vec<f64> = c.iter().map(|v| *v as f64).collect();
    let mut apply = kf::build(&label, model, cfg, Some(&c64), &[])?;
    let mut out = Vec::with_capacity(flight.len());
    for s in &flight.samples {
        if let Some(o) = apply.push(s) {
            out.push(o.interference_nt as f64);
        }
    }
    while let Some(o) = apply.flush() {
        out.push(o.interference_nt as f64);
    }
    if out.len() != flight.len() {
        bail!(
            "internal: {} outputs for {} samples",
            out.len(),
            flight.len()
        );
    }
    Ok((out, c64))
}
