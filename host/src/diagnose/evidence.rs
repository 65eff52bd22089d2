//! Evidence the anomaly states cannot hide (issue 20). The innovation test
//! (`regression.rs`) sees only what the anomaly-field filter leaves: an effect that looks
//! like geology to it (a scalar lag shifts the anomaly by V·τ along the track; slow
//! interference on a line) is absorbed into the anomaly states and leaves the innovations
//! almost untouched while the compensated output is wrong. Three more witnesses:
//!
//! - **band**: the band-passed measurement regressed directly on the model's and the
//!   candidate's columns, as Tolles–Lawson does (0.1–0.9 Hz, held out by the same folds).
//!   No anomaly states: what the candidate explains there the filter cannot give away.
//! - **reference**: the same regression on the measurement minus a reference channel the
//!   user names (`--reference mag_1_c`, a compensated stinger): the anomaly cancels there,
//!   so a current that disturbs a cabin sensor stands out against it.
//! - **refit**: the model refitted with the candidate (the whole Kalman calibration, its
//!   jackknife included). A missing effect makes the calibration's parts disagree (its
//!   predicted error, which counts that disagreement, is large) and the anomaly states
//!   carry part of it; the right term brings the parts into agreement and moves the
//!   output. A decoy does neither: on `lag_s32` adding `lag` takes the predicted error from
//!   0.70 to 0.044 nT and moves the output by 0.78 nT (std); the best decoy,
//!   `current:temp_avionics`, 0.70 → 0.66 nT. A refit is also a veto: a term whose refit
//!   raises the predicted error is not recommended, whatever the regressions found.

use super::holdout::{folds, heldout_explained, Folds};
use super::regression::fit_map;
use crate::estimate::corrections::run_kf;
use crate::estimate::kf::{KfOptions, KfRun};
use crate::flight::Flight;
use crate::io::trace::Trace;
use crate::model::spec::ModelSpec;
use crate::signal::bandpass::{bandpass_gaps, Gaps};
use anyhow::Result;
use magcomp_core::model::catalog::TermKind;
use serde::Serialize;

/// The band the direct regression runs in (Hz): the classic Tolles–Lawson band, where the
/// manoeuvres are and the geology at survey height mostly is not.
pub const DIRECT_BAND_HZ: (f64, f64) = (0.1, 0.9);
/// Poles of its Butterworth band-pass (MagNav's).
const DIRECT_BAND_POLES: usize = 4;
/// A refit corroborates (it never names a term alone: on a clean simulated survey box
/// adding `lag` cut the predicted error 0.081 → 0.029 nT and moved the output 0.25 nT,
/// while no other witness saw any of it) when it cuts the predicted error at least this
/// many times …
pub const REFIT_PREDICTED_FALL: f64 = 2.0;
/// … and moves the compensated output (std) by at least its new predicted error and this,
/// and another witness holds at least [`CORROBORATED_SHARE`] of the residual.
pub const CORROBORATED_SHARE: f64 = 0.05;
/// The output change (std) a refit must make, besides its new predicted error.
pub const REFIT_MIN_OUTPUT_CHANGE_NT: f64 = 0.05;
/// A refit whose predicted error rises beyond this factor contradicts the other
/// witnesses: the calibration cannot use the term on this flight. On the independent
/// `clean_s33` the band regression finds 24.5 % for `induced_high` (the exact modulus's
/// second order, which no catalogue term holds), while adding it takes the predicted error
/// from 0.055 to 0.25 nT (4.6×) and the error against truth from 0.106 to 0.118 nT. A
/// real effect's refit can raise it somewhat where the model's predicted error was blind
/// to it (a hidden 12-parameter `periodic:rpm`: 0.249 → 0.289 nT, 1.16×).
pub const REFIT_VETO_RISE: f64 = 2.0;
/// At most this many candidates are refitted (the most significant ones): each refit is a
/// whole calibration.
pub const MAX_REFITS: usize = 4;

/// A least-squares regression of one band-passed target on band-passed columns, judged
/// on held-out pieces of the flight.
pub(super) struct DirectRegression {
    /// Column 0 the target, the others indexed as the diagnosis's `columns`.
    w: Vec<Vec<f64>>,
    rows: Vec<usize>,
    folds: Folds,
    base: Vec<usize>,
    /// Prior penalties of the candidates' columns (noise² / σ²), as in the innovation test.
    penalty: Vec<f64>,
}

impl DirectRegression {
    /// `target` replaces column 0 of `columns`; `prior_sigma[c]` is column `c`'s prior 1σ
    /// (0 or non-finite: unpenalised, as the model's own columns are).
    pub(super) fn new(
        flight: &Flight,
        target: &[f64],
        columns: &[&[f64]],
        base: &[usize],
        prior_sigma: &[f64],
    ) -> Option<Self> {
        let fs = flight.sample_rate_hz;
        let high = DIRECT_BAND_HZ.1.min(0.4 * fs);
        if !(fs.is_finite() && high > DIRECT_BAND_HZ.0) {
            return None;
        }
        let gaps = Gaps {
            breaks: &[],
            max_fill: fs.round().max(1.0) as usize,
            min_len: (20.0 * fs) as usize,
        };
        let pass =
            |x: &[f64]| bandpass_gaps(x, DIRECT_BAND_POLES, DIRECT_BAND_HZ.0, high, fs, &gaps).ok();
        let mut w = vec![pass(target)?];
        for c in &columns[1..] {
            w.push(pass(c)?);
        }
        let rows: Vec<usize> = (0..target.len())
            .filter(|&k| w.iter().all(|c| c[k].is_finite()))
            .collect();
        if rows.len() < 100 {
            return None;
        }
        let folds = folds(flight, &rows);
        let (_, rss0, _, _) = fit_map(&w, &rows, base, &[]);
        let noise2 = rss0 / rows.len() as f64;
        let penalty = (0..w.len())
            .map(|c| match prior_sigma.get(c) {
                Some(&s) if s.is_finite() && s > 0.0 => noise2 / (s * s),
                _ => 0.0,
            })
            .collect();
        Some(Self {
            w,
            rows,
            folds,
            base: base.to_vec(),
            penalty,
        })
    }

    /// Held-out share of the band-passed target the candidate's columns remove beyond the
    /// model's.
    pub(super) fn heldout_share(&self, cand: &[usize]) -> f64 {
        heldout_explained(
            &self.w,
            &self.rows,
            &self.folds,
            &self.base,
            cand,
            &self.penalty,
        )
    }

    /// The target's band rms (nT) and what is left of it after the model's columns.
    pub(super) fn rms_nt(&self) -> (f64, f64) {
        let n = self.rows.len().max(1) as f64;
        let target = (self.rows.iter().map(|&k| self.w[0][k].powi(2)).sum::<f64>() / n).sqrt();
        let (_, rss, _, _) = fit_map(&self.w, &self.rows, &self.base, &[]);
        (target, (rss / n).sqrt())
    }

    /// The band-passed target and the fit of the model's and the candidate's columns (NaN
    /// outside the regression's rows), for the report's plot.
    pub(super) fn fit_series(&self, cand: &[usize]) -> (Vec<f64>, Vec<f64>) {
        let mut idx = self.base.clone();
        idx.extend_from_slice(cand);
        let (e, _, _, _) = fit_map(&self.w, &self.rows, &idx, &self.penalty);
        let mut fitted = vec![f64::NAN; self.w[0].len()];
        for (i, &k) in self.rows.iter().enumerate() {
            fitted[k] = self.w[0][k] - e[i];
        }
        let target = (0..self.w[0].len())
            .map(|k| {
                if fitted[k].is_finite() {
                    self.w[0][k]
                } else {
                    f64::NAN
                }
            })
            .collect();
        (target, fitted)
    }
}

/// What refitting the whole model with a candidate changes.
#[derive(Clone, Debug, Serialize)]
pub struct Refit {
    /// Predicted error of the model as diagnosed, and with the candidate (nT): each counts
    /// how far the calibration's parts disagree (the jackknife).
    pub predicted_before_nt: f64,
    pub predicted_after_nt: f64,
    /// Std of the change the candidate makes to the compensated field (nT).
    pub output_change_nt: f64,
    /// The refit is evidence ([`REFIT_PREDICTED_FALL`], [`REFIT_MIN_OUTPUT_CHANGE_NT`]).
    pub supports: bool,
    /// The refit's predicted error rose beyond [`REFIT_VETO_RISE`]: not recommended,
    /// whatever the other witnesses say.
    pub contradicts: bool,
    /// For `lag`: the τ the refit estimated from the manoeuvres (s), shown beside the
    /// reciprocal passes' τ.
    pub lag_s: Option<f64>,
}

/// The model as diagnosed, calibrated with its jackknife (its predicted error and output
/// are what a candidate's refit is compared with).
pub(super) fn calibrated(flight: &Flight, model: &ModelSpec) -> Result<KfRun> {
    run_kf(
        flight,
        &KfOptions {
            jackknife: true,
            ..KfOptions::new(model.clone())
        },
    )
}

/// `model` + `term` calibrated on the trace: what [`diagnose`](super::diagnose) of that
/// model starts from, so `--iterate` reuses it when it adds the term. None when it fails.
pub(super) fn refit_run(trace: &Trace, model: &ModelSpec, term: &str) -> Option<KfRun> {
    let spec = model.with(term).ok()?;
    // The flight again: a channel term brings its channel.
    let flight = Flight::from_trace(trace, &spec.channels(), &spec.relative_channels()).ok()?;
    calibrated(&flight, &spec).ok()
}

/// Compares `run` (`term` added, from [`refit_run`]) with `base` (from [`calibrated`]).
/// None when either run has no predicted error.
pub(super) fn refit(term: &str, run: &KfRun, base: &KfRun) -> Option<Refit> {
    let before = base.predicted_error_nt?;
    let after = run.predicted_error_nt?;
    let change: Vec<f64> = run
        .compensated_nt
        .iter()
        .zip(&base.compensated_nt)
        .map(|(a, b)| a - b)
        .filter(|d| d.is_finite())
        .collect();
    if change.len() < 100 {
        return None;
    }
    let mean = change.iter().sum::<f64>() / change.len() as f64;
    let output_change_nt =
        (change.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / change.len() as f64).sqrt();
    let supports = after * REFIT_PREDICTED_FALL <= before
        && output_change_nt >= after.max(REFIT_MIN_OUTPUT_CHANGE_NT);
    Some(Refit {
        predicted_before_nt: before,
        predicted_after_nt: after,
        output_change_nt,
        supports,
        contradicts: after > REFIT_VETO_RISE * before,
        lag_s: (TermKind::from_name(term) == Some(TermKind::Lag))
            .then(|| {
                run.preprocessing
                    .as_ref()?
                    .scalar_lag
                    .as_ref()
                    .map(|l| l.lag_s)
            })
            .flatten(),
    })
}
