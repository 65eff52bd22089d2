//! Candidates that are not regressors of the scalar residual: `fluxcal`, tested on the
//! fluxgate's own modulus, and `rate` on a flight with crossovers, tested at the crossings.

use super::stats::{chi2_sf, lag1_autocorr};
use crate::flight::Flight;
use crate::fluxgate::{self, FluxgateCalibration};
use crate::model_spec::ModelSpec;
use crate::pipeline::{run_kf, KfOptions, KfRun};
use crate::trace::Trace;
use anyhow::{Context, Result};

/// The trace with its fluxgate columns corrected by a scalar calibration.
pub(crate) fn calibrated_trace(trace: &Trace, cal: &FluxgateCalibration) -> Result<Trace> {
    let flux = trace
        .flux()
        .context("the trace has no fluxgate columns flux_x, flux_y, flux_z")?;
    let cal_flux: Vec<[f64; 3]> = flux.iter().map(|b| cal.apply(*b)).collect();
    let mut out = trace.clone();
    for (ax, name) in ["flux_x", "flux_y", "flux_z"].iter().enumerate() {
        out.set_col(name, cal_flux.iter().map(|b| b[ax]).collect());
    }
    Ok(out)
}

pub(crate) struct FluxcalTest {
    pub(crate) effect: String,
    pub(crate) change_nt: f64,
    pub(crate) fits_to_noise: bool,
    pub(crate) f: f64,
    pub(crate) p: f64,
}

/// `rate` on a flight with crossovers (survey lines and ties): on one straight pass most of
/// `eᵀNe·d|B|/dt` is a shift of the anomaly along the track, which the residual cannot
/// show; at the crossings it is a difference between the passes. The test is the crossover
/// fit's F-test and the share is that of the crossover differences' variance the term
/// explains. `None` without enough crossings (the residual test stands then).
pub(crate) fn rate_crossover_test(
    flight: &Flight,
    run: &KfRun,
    residual_rms: f64,
    effect: &str,
) -> Option<(String, f64, f64, usize, f64, f64)> {
    let regs = crate::crossover::rate_regressors(flight);
    let crossings = crate::crossover::find_crossings(flight);
    let fit = crate::crossover::fit_rate(flight, &crossings, &run.compensated_nt, &regs)?;
    let change = crate::metrics::rms_demeaned(&fit.correction_nt(&regs));
    let share = explained_of(fit.rms_before_nt, fit.rms_after_nt);
    Some((
        format!(
            "{effect}; tested at {} crossovers: their differences {:.3} → {:.3} nT rms with the term (share: of the crossover differences), which changes the compensated field by {:.3} nT rms",
            fit.crossings, fit.rms_before_nt, fit.rms_after_nt, change
        ),
        share,
        residual_rms * (1.0 - share).sqrt(),
        fit.added_parameters,
        fit.f_statistic,
        fit.p_value,
    ))
}

/// `fluxcal` is not a regressor: it is tested on the fluxgate itself. The 9-parameter
/// scalar calibration is fitted to the scalar minus the interference estimate; the F-test
/// is on the fluxgate modulus (effective sample count from the residual's lag-1
/// correlation), and what makes it material is how much the compensation changes when the
/// filter runs on the calibrated fluxgate.
pub(crate) fn fluxcal_test(flight: &Flight, model: &ModelSpec, run: &KfRun) -> Result<FluxcalTest> {
    let fit = match fluxgate::fit_flight(flight, &run.interference_nt) {
        Ok(f) => f,
        Err(e) => {
            return Ok(FluxcalTest {
                effect: format!("fluxgate calibration: not testable on this flight ({e})"),
                fits_to_noise: false,
                change_nt: 0.0,
                f: 0.0,
                p: 1.0,
            })
        }
    };
    let rerun = run_kf(
        &flight.with_fluxgate_calibration(&fit.calibration),
        &KfOptions::new(model.clone()),
    )?;
    let change_nt =
        crate::metrics::error_rms_nt(&rerun.interference_nt, &run.interference_nt, None);
    let resid: Vec<f64> = fit
        .residual_nt
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .collect();
    let rho = lag1_autocorr(&resid).clamp(-0.99, 0.99);
    let n_eff = (resid.len() as f64 * (1.0 - rho) / (1.0 + rho)).max(20.0);
    let (v0, v1) = (
        fit.modulus_sd_before_nt.powi(2),
        fit.modulus_sd_after_nt.powi(2),
    );
    let q = 9.0;
    let f = if v1 > 0.0 {
        ((v0 - v1).max(0.0) / q) / (v1 / (n_eff - q).max(1.0))
    } else {
        0.0
    };
    let p = chi2_sf(f * q, q);
    // The calibration must fit the fluxgate down to its own white noise: when the scalar
    // reference still holds a large unmodelled effect (a current the fluxgate does not
    // see), the fit absorbs part of it and the "change" it makes is that effect reshuffled.
    // White noise of the calibrated modulus from its third differences (robust to the
    // smooth misfit the sd includes).
    let noise_nt = crate::pipeline::estimate_noise_nt(&resid).unwrap_or(0.0);
    // Not fitting down to the noise makes the change immaterial (share 0 below), not the
    // F-test insignificant: F and p stay what the test gave, so the table never shows a
    // huge F with p = 1.
    let fits_to_noise = fit.modulus_sd_after_nt <= 2.0 * noise_nt.max(0.05);
    // With INS attitude: the installation check the compensation does not need.
    let ins = fluxgate::ins_misalignment_rad(flight, &fit.calibration)
        .map(|w| {
            format!(
                "; against the INS, misaligned {:.2}° about the roll axis and {:.2}° about the pitch axis",
                w[0].to_degrees(),
                w[1].to_degrees()
            )
        })
        .unwrap_or_default();
    Ok(FluxcalTest {
        effect: format!(
            "fluxgate calibration error (bias, scale, non-orthogonality): |B_fluxgate| − B varies by {:.1} nT sd, {:.2} nT after a 9-parameter calibration (fluxgate noise {:.2} nT{}), which changes the compensated field by {:.3} nT rms (share: that change against the residual){ins}",
            fit.modulus_sd_before_nt,
            fit.modulus_sd_after_nt,
            noise_nt,
            if fits_to_noise { "" } else { "; not down to its noise: another effect is in the way" },
            change_nt
        ),
        change_nt,
        fits_to_noise,
        f,
        p,
    })
}

pub(crate) fn explained_of(before: f64, after: f64) -> f64 {
    if before > 0.0 {
        (1.0 - (after / before).powi(2)).clamp(0.0, 1.0)
    } else {
        0.0
    }
}
