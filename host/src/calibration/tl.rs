//! Classic Tolles–Lawson as `calibrate` and `compensate` make it (`crate::estimate::tl`), with its
//! jackknife error figure.

use super::coefficients::{Coefficient, CoefficientFile, Method};
use super::result::Compensation;
use super::EstimatorSettings;
use crate::estimate::tl;
use crate::flight::Flight;
use crate::io::trace::Trace;
use crate::model::corrections::ScalarLag;
use anyhow::{bail, ensure, Context, Result};

pub(super) fn tl_config(flight: &Flight, est: &EstimatorSettings) -> Result<tl::TlConfig> {
    let terms: tl::TlTerms = est.tl_terms.parse()?;
    let mut cfg = tl::TlConfig::for_rate(flight.sample_rate_hz);
    cfg.terms = terms;
    let (lo, hi) = crate::qc::figures::manoeuvre_band(flight.sample_rate_hz);
    cfg.pass_hz = Some((lo, hi));
    if let Some(l) = est.tl_ridge {
        ensure!(
            l.is_finite() && l >= 0.0,
            "--tl-ridge must be a finite λ ≥ 0 (0 = plain least squares), not {l}"
        );
        cfg.lambda = l;
    }
    Ok(cfg)
}

pub(super) fn run_tl_method(
    trace: &Trace,
    est: &EstimatorSettings,
    coeffs: Option<&CoefficientFile>,
) -> Result<(Flight, Compensation)> {
    run_tl_method_aligned(trace, est, coeffs, coeffs.and_then(|c| c.scalar_lag))
}

/// [`run_tl_method`] on the scalar re-aligned by `lag` (a delay the filter's calibration
/// found, or the applied file's): the fit and the compensated output are the re-aligned
/// scalar's, the interference is against the recorded one (`mag − compensated`, as the
/// filter's with a delay), and the file carries the delay so that applying it re-aligns.
pub(super) fn run_tl_method_aligned(
    trace: &Trace,
    est: &EstimatorSettings,
    coeffs: Option<&CoefficientFile>,
    lag: Option<ScalarLag>,
) -> Result<(Flight, Compensation)> {
    let recorded = Flight::from_trace(trace, &[], &[])?;
    let (flight, comp) = match lag {
        Some(l) => {
            let aligned = crate::estimate::corrections::lag::realign(&recorded, l.lag_s);
            let (_, mut comp) = fit_and_apply(aligned, est, coeffs)?;
            for ((i, c), m) in comp
                .interference_nt
                .iter_mut()
                .zip(&comp.compensated_nt)
                .zip(&recorded.mag_nt)
            {
                *i = m - c;
            }
            if let Some(file) = comp.coefficients.as_mut() {
                file.scalar_lag = Some(l);
            }
            (recorded, comp)
        }
        None => fit_and_apply(recorded, est, coeffs)?,
    };
    Ok((flight, comp))
}

fn fit_and_apply(
    flight: Flight,
    est: &EstimatorSettings,
    coeffs: Option<&CoefficientFile>,
) -> Result<(Flight, Compensation)> {
    let qc = crate::qc::inputs::check(&flight, coeffs.is_none())?;
    let flux = crate::estimate::fluxcal::flight_flux(&flight);
    // Not across a time gap: the rows beside it are left out, which splits the
    // band-passed fit there.
    let mut select = vec![true; flight.len()];
    for i in crate::qc::gaps::gap_neighbours(&qc.breaks) {
        select[i] = false;
    }
    // Nor on the ground (parked, taxiing), where the filter does not learn either.
    let span = crate::estimate::excitation::airborne_span(&flight);
    for (i, s) in select.iter_mut().enumerate() {
        *s &= span.contains(&i);
    }
    let fit = match coeffs {
        Some(c) => {
            let cfg = c
                .tl_config
                .clone()
                .context("the coefficient file has no Tolles–Lawson configuration")?;
            c.tl_fit(cfg)
        }
        None => tl::fit(
            &flux,
            &flight.mag_nt,
            &tl_config(&flight, est)?,
            Some(&select),
        )?,
    };
    if fit.coefficients.len() != fit.config.terms.columns().len() {
        bail!(
            "{} Tolles–Lawson coefficients for {} terms",
            fit.coefficients.len(),
            fit.config.terms.columns().len()
        );
    }
    // Per stretch between time gaps: no derivative spans a gap.
    let stretches = crate::qc::gaps::stretches(flight.len(), &qc.breaks);
    let interference: Vec<f64> = stretches
        .iter()
        .flat_map(|r| tl::interference(&fit, &flux[r.clone()]))
        .collect();
    let compensated: Vec<f64> = flight
        .mag_nt
        .iter()
        .zip(&interference)
        .map(|(m, i)| m - i)
        .collect();
    let regressors = stretches
        .iter()
        .flat_map(|r| {
            let a = tl::design_matrix_scaled(
                &flux[r.clone()],
                &fit.config.terms,
                fit.config.bt_scale_nt,
                match fit.config.eddy_rate {
                    tl::EddyRate::PerSample => 1.0,
                    tl::EddyRate::PerSecond => fit.config.fs_hz,
                },
            );
            (0..a.nrows())
                .map(|r| {
                    (0..a.ncols())
                        .map(|c| a[(r, c)] as f32)
                        .collect::<Vec<f32>>()
                })
                .collect::<Vec<_>>()
        })
        .collect();
    let coefficients = fit
        .names
        .iter()
        .zip(fit.coefficients.iter().zip(&fit.sigma))
        .map(|(n, (v, s))| Coefficient {
            name: n.clone(),
            unit: "nT".into(),
            value: *v,
            sigma: *s,
        })
        .collect();
    // The fit's own covariance assumes white residuals; the jackknife does not
    // (`crate::estimate::jackknife`). A calibration only.
    let refits = match coeffs {
        None if qc.withheld.is_none() => {
            tl::jackknife_refits(&flux, &flight.mag_nt, &fit.config, &select, &span)
        }
        _ => None,
    };
    // The refits' scatter, and what the output carries at high frequency beyond the
    // scalar's noise (`crate::qc::high_frequency`): it stays in the output alike.
    let coefficient_part_nt = refits
        .as_ref()
        .and_then(|r| crate::estimate::jackknife::series_sigma_nt(r));
    let high_frequency =
        crate::qc::high_frequency::high_frequency(&compensated, &flight.t_s, flight.sample_rate_hz);
    let high_frequency_nt = high_frequency.map(|h| h.unfollowed_nt);
    let unexplained_nt = crate::qc::high_frequency::unexplained_range_nt(None, high_frequency);
    let predicted_error_nt = coefficient_part_nt.map(|c| c.hypot(unexplained_nt[0]));
    let predicted_error_range_nt = refits.as_ref().and_then(|r| {
        let n = crate::estimate::jackknife::series_effective_dimensions(r)?;
        crate::qc::error_range::range_nt(coefficient_part_nt?, unexplained_nt, n)
    });
    let (band_jackknife_nt, holdout_band_nt) = refits.as_ref().map_or((None, None), |r| {
        crate::estimate::jackknife::band_figures(&flight, &span, r)
    });
    let file = CoefficientFile {
        tl_config: Some(fit.config.clone()),
        predicted_error_nt,
        predicted_error_range_nt,
        unfollowed_high_frequency_nt: high_frequency_nt,
        ..CoefficientFile::new(
            format!("{:?}", fit.config.terms).to_lowercase(),
            Method::Tl,
            flight.sample_rate_hz,
            coefficients,
        )
    };
    let mut warnings = qc.warnings;
    // A calibration only: applied coefficients were judged where they were fitted.
    if coeffs.is_none() {
        warnings.extend(crate::estimate::excitation::tl_warning(&flight));
    }
    warnings.extend(crate::qc::high_frequency::warning(high_frequency_nt));
    // A sample without a usable scalar value (missing, or a glitch the despiker took
    // out) is flagged as the filter's output flags it, so either method's file says which
    // rows were refused.
    let flags = flight
        .samples
        .iter()
        .map(|s| {
            if s.mag.is_none() {
                magcomp_core::Flags::MAG_MISSING
            } else {
                0
            }
        })
        .collect();
    let comp = Compensation {
        model: file.model.clone(),
        method: Some(Method::Tl),
        interference_nt: interference,
        compensated_nt: compensated,
        flags: Some(flags),
        coefficients: Some(file),
        regressors,
        warnings,
        jackknife_nt: coefficient_part_nt,
        band_jackknife_nt,
        holdout_band_nt,
        refit_inflation: None,
        withheld: qc.withheld,
        ..Default::default()
    };
    Ok((flight, comp))
}
