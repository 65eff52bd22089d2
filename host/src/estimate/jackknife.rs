//! The flight's own evidence of how well a calibration holds: a delete-a-group jackknife.
//!
//! A filter's covariance is only as good as its model. On flights from an independent
//! simulator the Kalman filter's anomaly states took part of the per-heading interference
//! (`clean_s33`: 0.106 nT against the 0.014 nT its covariance claimed) and an unmodelled
//! scalar lag hid in them entirely (`lag_s32`: 0.79 nT against 0.026). The jackknife needs
//! no model: the airborne flight is cut into [`BLOCKS`] stretches, the coefficients are
//! estimated again without each one, and the spread of the interference those estimates
//! give is the error figure. Both methods get one (`estimate::kf` for the filter, `tl` for
//! Tolles–Lawson), and the default post-flight calibration uses the method whose figure is
//! lower ([`CrossCheck`]).

use crate::flight::Flight;
use serde::{Deserialize, Serialize};
use std::ops::Range;

/// Stretches of the airborne flight left out one at a time. Eight keeps each stretch
/// shorter than one heading's manoeuvres on a cloverleaf, so every refit still sees every
/// heading.
pub const BLOCKS: usize = 8;

/// Shortest stretch (s): below it a block holds too little of any manoeuvre for a refit
/// without it to say anything.
pub const MIN_BLOCK_S: f64 = 20.0;

/// [`BLOCKS`] contiguous stretches of `span`; None when they would be shorter than
/// [`MIN_BLOCK_S`].
pub fn blocks(span: &Range<usize>, sample_rate_hz: f64) -> Option<Vec<Range<usize>>> {
    let len = span.len() / BLOCKS;
    if (len as f64) < MIN_BLOCK_S * sample_rate_hz {
        return None;
    }
    Some(
        (0..BLOCKS)
            .map(|b| {
                let start = span.start + b * len;
                let end = if b + 1 == BLOCKS {
                    span.end
                } else {
                    start + len
                };
                start..end
            })
            .collect(),
    )
}

/// Delete-a-group jackknife covariance of estimates made each without one of `g` groups:
/// `(g − 1)/g · Σ (c_i − c̄)(c_i − c̄)ᵀ` (k×k, row-major).
pub fn covariance(estimates: &[Vec<f64>]) -> Vec<f64> {
    let g = estimates.len();
    let k = estimates.first().map_or(0, Vec::len);
    let mean: Vec<f64> = (0..k)
        .map(|j| estimates.iter().map(|c| c[j]).sum::<f64>() / g as f64)
        .collect();
    let mut cov = vec![0.0; k * k];
    let scale = (g as f64 - 1.0) / g as f64;
    for c in estimates {
        for a in 0..k {
            for b in 0..k {
                cov[a * k + b] += scale * (c[a] - mean[a]) * (c[b] - mean[b]);
            }
        }
    }
    cov
}

/// The jackknife 1σ of an interference series (nT rms over the samples, each refit's mean
/// removed: the level is the anomaly's) from the series the refits give.
pub fn series_sigma_nt(refits: &[Vec<f64>]) -> Option<f64> {
    let deviations = SeriesDeviations::of(refits)?;
    let var: f64 = (0..deviations.rows.len())
        .map(|g| deviations.inner(g, g))
        .sum();
    let sigma = var.sqrt();
    sigma.is_finite().then_some(sigma)
}

/// The number of independent directions [`series_sigma_nt`]'s error is spread over
/// (`crate::qc::error_range`): `(tr G)² / tr(G²)` of the refits' Gram matrix, whose
/// non-zero eigenvalues are those of the jackknife covariance times the regressors' spread.
pub fn series_effective_dimensions(refits: &[Vec<f64>]) -> Option<f64> {
    let deviations = SeriesDeviations::of(refits)?;
    let g = deviations.rows.len();
    let trace: f64 = (0..g).map(|a| deviations.inner(a, a)).sum();
    let trace_sq: f64 = (0..g * g)
        .map(|ab| deviations.inner(ab / g, ab % g).powi(2))
        .sum();
    crate::qc::error_range::participation_ratio(trace, trace_sq)
}

/// Each refit's series about the refits' centre, over the samples every refit has, each
/// refit's mean removed.
struct SeriesDeviations {
    rows: Vec<Vec<f64>>,
    /// `(g − 1)/g / m`: the jackknife's scale over the samples' count.
    scale: f64,
}

impl SeriesDeviations {
    fn of(refits: &[Vec<f64>]) -> Option<Self> {
        let g = refits.len();
        let n = refits.first()?.len();
        if g < 2 || refits.iter().any(|r| r.len() != n) {
            return None;
        }
        let finite: Vec<usize> = (0..n)
            .filter(|&i| refits.iter().all(|r| r[i].is_finite()))
            .collect();
        if finite.len() < 2 {
            return None;
        }
        let m = finite.len() as f64;
        let demeaned: Vec<Vec<f64>> = refits
            .iter()
            .map(|r| {
                let mean = finite.iter().map(|&i| r[i]).sum::<f64>() / m;
                finite.iter().map(|&i| r[i] - mean).collect()
            })
            .collect();
        let centre: Vec<f64> = (0..finite.len())
            .map(|j| demeaned.iter().map(|d| d[j]).sum::<f64>() / g as f64)
            .collect();
        let rows = demeaned
            .into_iter()
            .map(|d| d.iter().zip(&centre).map(|(v, c)| v - c).collect())
            .collect();
        Some(Self {
            rows,
            scale: (g as f64 - 1.0) / g as f64 / m,
        })
    }

    /// The Gram matrix's element (a, b).
    fn inner(&self, a: usize, b: usize) -> f64 {
        let dot: f64 = self.rows[a]
            .iter()
            .zip(&self.rows[b])
            .map(|(x, y)| x * y)
            .sum();
        self.scale * dot
    }
}

/// The refits' manoeuvre-band signals (`figures::band_passed`); None when one cannot be
/// filtered.
fn band_passed_refits(flight: &Flight, refits: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
    refits
        .iter()
        .map(|s| crate::qc::figures::band_passed(flight, s))
        .collect()
}

/// [`series_sigma_nt`] of the refits' manoeuvre-band signals (`figures::band_passed`):
/// what a band-passed figure on another flight sees of the error; None when a refit's
/// series cannot be filtered.
pub fn band_sigma_nt(flight: &Flight, refits: &[Vec<f64>]) -> Option<f64> {
    series_sigma_nt(&band_passed_refits(flight, refits)?)
}

/// [`band_sigma_nt`] and [`holdout_band_nt`] of the same refits (the interference over the
/// whole flight without each block of `span`), each refit band-passed once for both.
pub fn band_figures(
    flight: &Flight,
    span: &Range<usize>,
    refits: &[Vec<f64>],
) -> (Option<f64>, Option<f64>) {
    match band_passed_refits(flight, refits) {
        Some(band) => (series_sigma_nt(&band), holdout_band_nt(flight, span, &band)),
        None => (None, None),
    }
}

/// Blocked cross-validation in the manoeuvre band (nT rms): each block of `span`
/// compensated by the refit that did not see it (`band_refits[b]`: the band-passed
/// interference over the whole flight without block `b`). Unlike the jackknife's spread,
/// this sees a bias too: coefficients that fit their own data but predict other
/// manoeuvres badly (the anomaly states or the anomaly itself took part of the
/// interference). It is what a band-passed figure of merit on another flight measures, the
/// geology's band signal included, so only differences between methods on one flight mean
/// anything. None when the blocks do not match the refits or the scalar cannot be filtered.
fn holdout_band_nt(flight: &Flight, span: &Range<usize>, band_refits: &[Vec<f64>]) -> Option<f64> {
    let blocks = blocks(span, flight.sample_rate_hz)?;
    if blocks.len() != band_refits.len() {
        return None;
    }
    // Band-passing is linear: band(mag − refit) = band(mag) − band(refit), and filtering
    // whole series leaves no edge where two refits meet.
    let mag = crate::qc::figures::band_passed(flight, &flight.mag_nt)?;
    let (mut sum, mut n) = (0.0, 0usize);
    for (block, band) in blocks.iter().zip(band_refits) {
        for i in block.clone() {
            let r = mag.get(i)? - band.get(i)?;
            if r.is_finite() {
                sum += r * r;
                n += 1;
            }
        }
    }
    (n > 1).then(|| (sum / n as f64).sqrt())
}

/// Which method's coefficients the flight's evidence trusts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Estimator {
    /// The paper's Kalman filter: coefficients and anomaly states together.
    KalmanFilter,
    /// Band-passed least-squares Tolles–Lawson, 18 terms, no ridge (TL18-OLS).
    TollesLawsonOls,
}

/// The default post-flight calibration's cross-check (nT rms over the flight, the
/// interference's mean removed).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CrossCheck {
    pub blocks: usize,
    /// The Kalman filter's jackknife error.
    pub kalman_filter_jackknife_nt: f64,
    /// TL18-OLS's jackknife error.
    pub tolles_lawson_jackknife_nt: f64,
    /// The two in the manoeuvre band (0.1–0.9 Hz): what a band-passed figure of merit on
    /// another flight sees of the coefficients' error.
    pub kalman_filter_band_jackknife_nt: Option<f64>,
    pub tolles_lawson_band_jackknife_nt: Option<f64>,
    /// RMS difference between the two methods' interference over the flight.
    pub disagreement_nt: f64,
    /// The same in the manoeuvre band, where both methods' coefficients are determined:
    /// what decides whether they agree.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub band_disagreement_nt: Option<f64>,
    /// How far the filter's refits moved over what its covariances allow
    /// (`crate::estimate::kf::KfJackknife::inflation`): beyond
    /// `crate::estimate::kf::INCONSISTENT_REFITS` its model does not hold.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kalman_filter_refit_inflation: Option<f64>,
    /// Each method's blocked cross-validation in the band ([`holdout_band_nt`]): how well
    /// coefficients fitted without a stretch compensate it. What decides when the filter's
    /// model does not hold.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kalman_filter_holdout_band_nt: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tolles_lawson_holdout_band_nt: Option<f64>,
    pub chosen: Estimator,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jackknife_covariance_of_the_mean_is_the_sample_variance_over_n() {
        // Leave-one-out means of x: their jackknife variance is exactly s²/n.
        let x = [1.0, 4.0, 2.0, 8.0, 5.0];
        let n = x.len() as f64;
        let total: f64 = x.iter().sum();
        let loo: Vec<Vec<f64>> = x.iter().map(|v| vec![(total - v) / (n - 1.0)]).collect();
        let mean = total / n;
        let s2 = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
        let cov = covariance(&loo);
        assert!((cov[0] - s2 / n).abs() < 1e-12, "{} vs {}", cov[0], s2 / n);
    }

    #[test]
    fn series_sigma_ignores_levels_and_sees_shape() {
        // Refits that differ only by a constant agree on the interference's shape.
        let base: Vec<f64> = (0..100).map(|i| (i as f64 * 0.1).sin()).collect();
        let shifted: Vec<Vec<f64>> = (0..4)
            .map(|k| base.iter().map(|v| v + k as f64).collect())
            .collect();
        assert!(series_sigma_nt(&shifted).unwrap() < 1e-12);
        // Refits whose amplitude differs by ±a give a spread of the order of a·rms(base).
        let scaled: Vec<Vec<f64>> = [0.9, 1.1, 0.9, 1.1]
            .iter()
            .map(|s| base.iter().map(|v| v * s).collect())
            .collect();
        let sigma = series_sigma_nt(&scaled).unwrap();
        let mean = base.iter().sum::<f64>() / 100.0;
        let rms = (base.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / 100.0).sqrt();
        // (g−1)/g · Σ (0.1·b)² over 4 refits = 0.03·b²: σ = √0.03 · rms.
        assert!((sigma / rms - 0.03f64.sqrt()).abs() < 0.02, "{sigma} {rms}");
        // All of that spread is along one shape.
        let n = series_effective_dimensions(&scaled).unwrap();
        assert!((n - 1.0).abs() < 1e-9, "{n}");
    }

    #[test]
    fn refits_spread_alike_over_two_shapes_count_two_directions() {
        let sine: Vec<f64> = (0..200).map(|i| (i as f64 * 0.1).sin()).collect();
        let cosine: Vec<f64> = (0..200).map(|i| (i as f64 * 0.1).cos()).collect();
        // ±1 along each shape in turn: the centre is zero, each shape carries half.
        let refits: Vec<Vec<f64>> = [(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)]
            .iter()
            .map(|(a, b)| (0..200).map(|i| a * sine[i] + b * cosine[i]).collect())
            .collect();
        let n = series_effective_dimensions(&refits).unwrap();
        assert!((n - 2.0).abs() < 0.05, "{n}");
    }
}
