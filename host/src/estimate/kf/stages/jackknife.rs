//! The filter's jackknife ([`crate::estimate::jackknife`]): the calibration pass again without each
//! stretch of the airborne flight (its scalar samples predict and do not update), with
//! everything else the calibration chose (σ1, noise, anomaly process, held combinations).

use super::super::{interference_of, parallel, KfOptions, RegressorSpread};
use super::filter_pass::{self, PassSetup};
use crate::flight::Flight;
use anyhow::Result;

/// The filter's jackknife: its figure (nT rms) and the coefficients' covariance (k×k).
#[derive(Clone, Debug, Default)]
pub struct KfJackknife {
    pub blocks: usize,
    pub sigma_nt: f64,
    /// The same in the manoeuvre band (0.1–0.9 Hz): what a band-passed figure of merit on
    /// another flight sees of it.
    pub band_sigma_nt: Option<f64>,
    /// Blocked cross-validation in the band (`crate::estimate::jackknife::holdout_band_nt`).
    pub holdout_band_nt: Option<f64>,
    pub covariance: Vec<f64>,
    /// How far the refits moved from the full calibration, over what the filter's own
    /// covariances say they should have (≈ 1 when its model holds).
    pub inflation: f64,
}

/// Refits that move this many times more than the filter's covariances allow (in
/// variance) say the model does not hold: measured 0.5–1.3 on simulated flights whose
/// interference the model describes, 7.6–9.7 where the anomaly states took interference
/// (independent `clean_s33`, broad seed 2, a low-altitude strong anomaly), 360 with an
/// unmodelled 0.17 s lag (`lag_s32`).
pub const INCONSISTENT_REFITS: f64 = 4.0;

impl KfJackknife {
    /// Said when the refits disagree beyond [`INCONSISTENT_REFITS`].
    pub fn lower_bound_warning(&self) -> String {
        format!(
            "the calibration's parts disagree {:.0}× more than the filter's model allows: an \
             effect the model lacks (or an anomaly rougher than its process) hides in the \
             anomaly states, and the predicted error ({:.3} nT from the jackknife) is a lower \
             bound. `magcomp diagnose` names candidates",
            self.inflation, self.sigma_nt
        )
    }
}

/// None when the airborne flight is too short to cut into blocks.
pub(crate) fn kf_jackknife(
    flight: &Flight,
    opts: &KfOptions,
    filter: &PassSetup,
    (regs, spread): (&[Vec<f32>], &RegressorSpread),
    full: (&[f64], &[f64]),
) -> Result<Option<KfJackknife>> {
    let (full_coefficients, full_covariance) = full;
    let span = crate::estimate::excitation::airborne_span(flight);
    let Some(blocks) = crate::estimate::jackknife::blocks(&span, flight.sample_rate_hz) else {
        return Ok(None);
    };
    let mut refits = Vec::with_capacity(blocks.len());
    let variance = |cov: &[f64]| spread.sigma_nt(cov).map(|s| s * s);
    let Some(full_var) = variance(full_covariance) else {
        return Ok(None);
    };
    let (mut moved, mut expected) = (0.0, 0.0);
    // The refits are independent passes (on the cores); they are summed in order.
    let passes = parallel::map(&blocks, |block| {
        let setup = PassSetup {
            skip_updates: Some(block.clone()),
            ..filter.clone()
        };
        filter_pass::run(flight, opts, &setup, None, false).map(|p| (p.coefficients, p.covariance))
    });
    for refit in passes {
        let (c, p) = refit?;
        // Nested estimates: var(c_k − c) = P_k − P when the model holds.
        let d: Vec<f64> = c
            .iter()
            .zip(full_coefficients)
            .map(|(a, b)| a - b)
            .collect();
        let outer: Vec<f64> = d
            .iter()
            .flat_map(|a| d.iter().map(move |b| a * b))
            .collect();
        moved += variance(&outer).unwrap_or(f64::NAN);
        expected += (variance(&p).unwrap_or(f64::NAN) - full_var).max(0.0);
        refits.push(c);
    }
    let inflation = if expected > 0.0 {
        moved / expected
    } else {
        f64::NAN
    };
    let covariance = crate::estimate::jackknife::covariance(&refits);
    let series: Vec<Vec<f64>> = refits.iter().map(|c| interference_of(regs, c)).collect();
    let (band_sigma_nt, holdout_band_nt) =
        crate::estimate::jackknife::band_figures(flight, &span, &series);
    Ok(spread.sigma_nt(&covariance).map(|sigma_nt| KfJackknife {
        blocks: blocks.len(),
        sigma_nt,
        band_sigma_nt,
        holdout_band_nt,
        covariance,
        inflation,
    }))
}
