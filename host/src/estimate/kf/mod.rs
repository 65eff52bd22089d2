//! Runs the shared core over a flight: post-flight (calibrate on the trace, then apply the
//! final coefficients to every sample) or real-time (the causal filter's own output).

use crate::estimate::fluxcal::{self, FluxgateCalibration, FluxgateFit};
use crate::flight::Flight;
use crate::model::spec::ModelSpec;
use anyhow::Result;
use magcomp_core::compensator::Output;
use std::ops::ControlFlow;

pub(crate) mod filter;
mod parallel;
mod stages;
mod tuning;

pub(crate) use filter::{base_config, build, set_run_mode};
pub use filter::{HostCompensator, HOST_STATES, HOST_WINDOW};
pub use stages::jackknife::{KfJackknife, INCONSISTENT_REFITS};
pub use tuning::{
    estimate_sigma1_for, estimate_sigma1_with, field_profile, known_environment_nt, FIELD_PROFILES,
    FIELD_PROFILE_SCALES, MODEL_ERROR_WARNING_NT,
};

/// σ2 / σ1 of the anomaly process (docs/model.md §3 findings).
pub const SIGMA2_RATIO: f64 = 0.1;

/// What the user can set; `None` = estimated from the data. What the run's stages decide
/// (σ1, noise, held combinations, anomaly process) they hand on as their own types
/// (`stages`), never through these options.
#[derive(Clone, Debug)]
pub struct KfOptions {
    pub model: ModelSpec,
    pub sigma1: Option<f64>,
    pub noise_nt: Option<f64>,
    pub realtime: bool,
    /// Use the detected/declared tie point (revisited centre of the pattern).
    pub tie_points: bool,
    /// Apply these coefficients (survey mode) instead of calibrating.
    pub coefficients: Option<Vec<f64>>,
    /// σ2 = `sigma2_ratio` × σ1 (model.md §3 findings: 0.1).
    pub sigma2_ratio: f64,
    /// Multiplier on the spectrally estimated σ1 (ignored when `sigma1` is given).
    pub sigma1_scale: f64,
    /// Multiplier on every term's prior 1σ.
    pub prior_scale: f64,
    /// Half-width of the centred derivative (samples); `None` = the rate's default.
    pub half_width: Option<usize>,
    /// Re-anchor `h0` when `|h − h0|` exceeds this (m; 0 = fixed h0).
    pub h0_reanchor_m: f64,
    /// Multipliers of the spectral σ1 tried (a whole-flight calibration each, also before a
    /// real-time replay, like the spectral σ1 itself); the one whose compensated
    /// signal has the least FOM over the labelled manoeuvres wins (fewer than two, or no
    /// labels = the spectral σ1 as is).
    pub sigma1_candidates: Vec<f64>,
    /// Real time with segment labels: freeze the coefficients (survey mode) at the first
    /// sample labelled as a survey line, i.e. once the operator has left the calibration
    /// pattern. Without it the filter keeps calibrating on the lines, where the along-track
    /// field and the interference of a single heading cannot be told apart.
    pub freeze_on_survey: bool,
    /// Real time: switch to survey mode at this sample, as the operator's `MODE,SURVEY`
    /// would (before the labels of `freeze_on_survey`). Only the pass whose records are
    /// output freezes; the tuning passes before it see the flight as the board would
    /// without the command, so the estimate up to the switch is the unfrozen run's.
    pub survey_from: Option<usize>,
    /// Innovation gate in σ (0 = off; the core's default is 8).
    pub gate_sigma: f64,
    /// Measurement-noise multiplier on samples labelled as turns (1 = none).
    pub turn_noise_scale: f64,
    /// With `fluxcal` in the model: apply this fluxgate calibration instead of fitting one.
    pub fluxgate_calibration: Option<FluxgateCalibration>,
    /// Post-flight, also try anomaly processes whose σ1 varies along the track with the
    /// local roughness of the anomaly ([`FIELD_PROFILES`]); the one under which the data
    /// are most likely (innovation likelihood of the calibration pass) wins.
    pub field_profiles: bool,
    /// With the `rate` term, post-flight: fit its coefficients to the flight's crossovers
    /// as well (`crossover`), and apply them when the crossover F-test is significant.
    pub rate_crossovers: bool,
    /// Crossover rate coefficients to apply as given (from a coefficient file).
    pub rate_crossover_coefficients: Option<[f64; 6]>,
    /// With `coefficients`: their covariance (k×k, row-major, physical units) from the
    /// calibration, so the run can say how well they determine *this* flight's
    /// interference (`KfRun::predicted_error_nt`).
    pub coefficient_covariance: Option<Vec<f64>>,
    /// With given coefficients: the model error their calibration flight showed (nT rms),
    /// counted in the predicted error.
    pub model_error_nt: Option<f64>,
    /// With `lag`/`fluxtemp`: apply this pre-processing (from a coefficient file) instead of
    /// estimating it ([`crate::estimate::corrections`]).
    pub preprocessing: Option<crate::model::corrections::Preprocessing>,
    /// Post-flight calibration: check the coefficients against the flight's own evidence
    /// (the jackknife, [`crate::estimate::jackknife`]: 8 more filter passes). Off by default: the
    /// calibration a user is given turns it on (`calibration`); the runs made for other
    /// ends (a first pass for `fluxcal`/`fluxtemp`, diagnosis, a TL flight's field
    /// estimate) do not report a predicted error.
    pub jackknife: bool,
}

impl KfOptions {
    pub fn new(model: ModelSpec) -> Self {
        Self {
            model,
            sigma1: None,
            noise_nt: None,
            realtime: false,
            tie_points: true,
            coefficients: None,
            sigma2_ratio: SIGMA2_RATIO,
            sigma1_scale: 1.0,
            prior_scale: 1.0,
            half_width: None,
            h0_reanchor_m: 0.0,
            sigma1_candidates: SIGMA1_CANDIDATES.to_vec(),
            turn_noise_scale: 1.0,
            freeze_on_survey: true,
            survey_from: None,
            gate_sigma: 8.0,
            fluxgate_calibration: None,
            field_profiles: true,
            rate_crossovers: true,
            rate_crossover_coefficients: None,
            coefficient_covariance: None,
            model_error_nt: None,
            preprocessing: None,
            jackknife: false,
        }
    }
}

/// Per-sample results and the estimated coefficients.
#[derive(Clone, Debug, Default)]
pub struct KfRun {
    pub interference_nt: Vec<f64>,
    pub compensated_nt: Vec<f64>,
    pub anomaly_nt: Vec<f64>,
    pub innovation_nt: Vec<f64>,
    pub innovation_var_nt2: Vec<f64>,
    /// Each record's stated 1σ bound on its interference (nT; NaN while not converged):
    /// [`magcomp_core::Output::interference_sigma_nt`], real time only (post-flight the
    /// whole-flight figure `predicted_error_nt` holds for every sample).
    pub interference_sigma_nt: Vec<f64>,
    pub flags: Vec<u16>,
    /// Regressors of the interference terms per sample (for oracle floors and diagnosis).
    pub regressors: Vec<Vec<f32>>,
    pub coefficient_names: Vec<(String, String)>,
    pub coefficients: Vec<f64>,
    pub coefficient_sigmas: Vec<f64>,
    /// [`RegressorSpread::sigma_nt`] on this flight: of the calibration, or of the
    /// given coefficients when their covariance was given too (None otherwise).
    pub predicted_error_nt: Option<f64>,
    /// The range one flight's actual error falls in beside it (nT, low and high;
    /// `crate::qc::error_range`).
    pub predicted_error_range_nt: Option<[f64; 2]>,
    /// The output's high-frequency content beyond the scalar's noise, counted in the
    /// predicted error (`crate::qc::high_frequency`).
    pub unfollowed_high_frequency_nt: Option<f64>,
    /// The coefficients' covariance (k×k, row-major, physical units): the calibration's,
    /// or the one given with the coefficients.
    pub coefficient_covariance: Vec<f64>,
    pub sigma1: f64,
    pub noise_nt: f64,
    /// Signal the model could not follow beyond the sensor's noise (nT rms): the part of
    /// the estimated measurement noise above the scalar's own; `None` when the noise was
    /// not estimated from the innovations.
    pub model_error_nt: Option<f64>,
    /// The filter's UD factors stayed finite with non-negative D (covariance positive
    /// semi-definite) after every sample of the final pass.
    pub filter_healthy: bool,
    /// The anomaly process the run used: "stationary" (the paper's) or the local-roughness
    /// profile and σ1² scale the likelihood chose.
    pub field_process: String,
    /// The `rate` term's crossover fit, and whether it was applied (significant).
    pub rate_crossover: Option<(crate::estimate::crossover::RateFit, bool)>,
    /// With `fluxcal`: the fluxgate calibration used, and its fit when made on this flight.
    pub fluxgate_calibration: Option<FluxgateCalibration>,
    pub fluxgate_fit: Option<FluxgateFit>,
    /// What the run found the user must know (undetermined coefficients, …).
    pub warnings: Vec<String>,
    /// With `lag`/`fluxtemp`: what was done to the flight before the filter.
    pub preprocessing: Option<crate::model::corrections::Preprocessing>,
    /// Post-flight calibration: the filter's jackknife (counted in `coefficient_covariance`
    /// and `predicted_error_nt`).
    pub jackknife: Option<KfJackknife>,
}

impl KfRun {
    /// The scalar's own noise (nT): the run's noise without the model error it adapted for.
    pub fn sensor_noise_nt(&self) -> f64 {
        let me = self.model_error_nt.unwrap_or(0.0);
        (self.noise_nt * self.noise_nt - me * me).max(0.0).sqrt()
    }
}

/// Robust white-noise level of the scalar: the third difference of white noise has
/// variance 20σ²; the median absolute deviation ignores manoeuvres and spikes.
pub fn estimate_noise_nt(mag_nt: &[f64]) -> Option<f64> {
    let mut d3: Vec<f64> = mag_nt
        .windows(4)
        .map(|w| w[3] - 3.0 * w[2] + 3.0 * w[1] - w[0])
        .filter(|v| v.is_finite())
        .map(f64::abs)
        .collect();
    if d3.len() < 16 {
        return None;
    }
    let mid = d3.len() / 2;
    d3.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    Some(d3[mid] * 1.4826 / 20f64.sqrt())
}
/// How well the flight determined the interference, by the filter's own account: the rms
/// over the flight of the 1σ of the interference estimate with its mean removed (the
/// level is the anomaly's), `sqrt(tr(P·C))` with `P` the coefficient covariance
/// (k×k) and `C` the covariance of the interference regressors over the flight (this
/// struct, computed once for the many `P` the jackknife holds against it). It is the
/// error against the truth to expect when the model holds, and a calibration flight's
/// quality figure without any truth: high where the pattern left a combination of terms
/// unobserved (a strong anomaly that changes between the headings, too few manoeuvres).
pub struct RegressorSpread {
    k: usize,
    covariance: Vec<f64>,
}

impl RegressorSpread {
    /// None without regressors or with fewer than two finite rows.
    pub fn of(regressors: &[Vec<f32>]) -> Option<Self> {
        let k = regressors.first()?.len();
        let rows: Vec<&Vec<f32>> = regressors
            .iter()
            .filter(|r| r.iter().all(|v| v.is_finite()))
            .collect();
        if rows.len() < 2 {
            return None;
        }
        let n = rows.len() as f64;
        let mean: Vec<f64> = (0..k)
            .map(|j| rows.iter().map(|r| r[j] as f64).sum::<f64>() / n)
            .collect();
        let mut covariance = vec![0.0; k * k];
        for r in &rows {
            let d: Vec<f64> = (0..k).map(|j| r[j] as f64 - mean[j]).collect();
            for a in 0..k {
                for b in 0..k {
                    covariance[a * k + b] += d[a] * d[b] / n;
                }
            }
        }
        Some(Self { k, covariance })
    }

    /// `sqrt(tr(P·C))` (nT) for the coefficient covariance `P` (k×k); None when `P` has
    /// another size or the figure is not finite.
    pub fn sigma_nt(&self, coefficient_covariance: &[f64]) -> Option<f64> {
        if coefficient_covariance.len() != self.k * self.k {
            return None;
        }
        let var: f64 = coefficient_covariance
            .iter()
            .zip(&self.covariance)
            .map(|(p, c)| p * c)
            .sum();
        var.is_finite().then(|| var.max(0.0).sqrt())
    }

    /// The range one flight's error falls in (`crate::qc::error_range::range_nt`): the
    /// covariance's part [`Self::sigma_nt`], spread over its effective number of
    /// directions, with a model error in `model_error_nt` (low, high) carried by every
    /// flight alike.
    pub fn error_range_nt(
        &self,
        coefficient_covariance: &[f64],
        model_error_nt: [f64; 2],
    ) -> Option<[f64; 2]> {
        let coefficient_part_nt = self.sigma_nt(coefficient_covariance)?;
        let n = crate::qc::error_range::effective_dimensions(
            coefficient_covariance,
            &self.covariance,
            self.k,
        )?;
        crate::qc::error_range::range_nt(coefficient_part_nt, model_error_nt, n)
    }
}

/// Default σ1 multipliers searched post-flight.
pub const SIGMA1_CANDIDATES: [f64; 4] = [1.0, 0.3, 0.1, 0.03];

/// Default σ1 when the track is too short for the spectrum (the paper's 1000 m value).
pub const DEFAULT_SIGMA1: f64 = 1.0e-6;

/// The options of a first pass whose interference only prepares the flight (`fluxcal`,
/// `fluxtemp`): no jackknife, which only the final pass reports.
pub(crate) fn first_pass(opts: &KfOptions) -> KfOptions {
    KfOptions {
        jackknife: false,
        ..opts.clone()
    }
}

/// The estimator on a flight as given. With `fluxcal` in the model the fluxgate is first
/// calibrated ([`FluxgateStage`]) and the filter runs on the calibrated fluxgate, reusing
/// what the stage's first run chose.
pub fn run_kf_estimator(flight: &Flight, opts: &KfOptions) -> Result<KfRun> {
    if !opts.model.calibrates_fluxgate() {
        return run_kf_on(flight, opts);
    }
    let stage = match FluxgateStage::choose(flight, opts)? {
        ControlFlow::Continue(stage) => stage,
        ControlFlow::Break(first) => return Ok(first),
    };
    // The second run keeps the first's σ1 (the fluxgate's calibration moves the
    // interference by far less than what chose it) and chooses its noise and anomaly
    // process again, from innovations without the fluxgate's error.
    let calibrated = fluxcal::calibrated_flight(flight, &stage.calibration);
    let (mut run, _) = stages::calibrate(&calibrated, opts, stage.reusable.as_ref())?;
    run.warnings.extend(stage.not_calibrated);
    run.fluxgate_calibration = Some(stage.calibration);
    run.fluxgate_fit = stage.fit;
    Ok(run)
}

/// The fluxgate's calibration of a `fluxcal` model (an input correction that adds no
/// filter state): the stored one, or one fitted on this flight to the scalar minus a first
/// run's interference. A fit the flight does not determine is not applied: the fluxgate is
/// used as measured (identity calibration) and a warning says so. In real time without a
/// stored calibration the fluxgate is used as measured, as on the board before `SETFLUX`.
struct FluxgateStage {
    calibration: FluxgateCalibration,
    /// The fit made on this flight, when it was applied.
    fit: Option<FluxgateFit>,
    /// Why the fluxgate is used as measured, when a fit was refused.
    not_calibrated: Option<String>,
    /// What the first run chose that the second reuses (σ1, the anomaly process's family).
    reusable: Option<stages::Reusable>,
}

impl FluxgateStage {
    /// The stage, or (`Break`) the first run itself when it is the result: the fit was
    /// refused and no jackknife is asked, so a second run on the fluxgate as measured
    /// would repeat it.
    fn choose(flight: &Flight, opts: &KfOptions) -> Result<ControlFlow<KfRun, Self>> {
        let given = |calibration| Self {
            calibration,
            fit: None,
            not_calibrated: None,
            reusable: None,
        };
        if let Some(c) = opts.fluxgate_calibration {
            return Ok(ControlFlow::Continue(given(c)));
        }
        if opts.realtime {
            return Ok(ControlFlow::Continue(given(FluxgateCalibration::IDENTITY)));
        }
        // `fluxcal` adds no filter state, so the first run is the model without it.
        let (mut first, chosen) = stages::calibrate(flight, &first_pass(opts), None)?;
        let fitted = fluxcal::fit_flight(flight, &first.interference_nt)
            .and_then(FluxgateFit::determined)
            .and_then(FluxgateFit::physical);
        let reusable = Some(chosen);
        match fitted {
            Ok(fit) => Ok(ControlFlow::Continue(Self {
                calibration: fit.calibration,
                fit: Some(fit),
                not_calibrated: None,
                reusable,
            })),
            Err(reason) => {
                let warning = format!(
                    "fluxgate not calibrated against the scalar, used as measured: {reason:#}"
                );
                if !opts.jackknife {
                    first.warnings.push(warning);
                    first.fluxgate_calibration = Some(FluxgateCalibration::IDENTITY);
                    return Ok(ControlFlow::Break(first));
                }
                // The first run made no jackknife: the final run, on the fluxgate as
                // measured, does.
                Ok(ControlFlow::Continue(Self {
                    calibration: FluxgateCalibration::IDENTITY,
                    fit: None,
                    not_calibrated: Some(warning),
                    reusable,
                }))
            }
        }
    }
}

fn run_kf_on(flight: &Flight, opts: &KfOptions) -> Result<KfRun> {
    stages::calibrate(flight, opts, None).map(|(run, _)| run)
}

/// The filter's per-sample records into the run's columns (nT).
pub(crate) fn push_outputs(run: &mut KfRun, outs: &[Output], flight: &Flight) {
    for (o, mag) in outs.iter().zip(&flight.mag_nt) {
        let i = o.interference_nt as f64;
        run.interference_nt.push(i);
        run.compensated_nt.push(match o.compensated {
            Some(c) => c.to_nt_f64(),
            None => mag - i,
        });
        run.anomaly_nt.push(o.anomaly_nt as f64);
        run.innovation_nt.push(o.innovation_nt as f64);
        run.innovation_var_nt2.push(o.innovation_var_nt2 as f64);
        run.interference_sigma_nt
            .push(o.interference_sigma_nt as f64);
        run.flags.push(o.flags.0);
    }
}

/// Significance the crossover rate fit needs before it is applied: without evidence the
/// fit would only add its own noise (0.02–0.04 nT on clean simulated flights).
pub const RATE_CROSSOVER_ALPHA: f64 = 0.01;

/// The `rate` term's crossover step (post-flight; see [`crate::estimate::crossover`]). The filter's
/// own `rate` states see the anisotropic part only where `e` changes within a pass; the
/// crossovers see what the filter cannot: the part that, on one pass, is a shift of the
/// anomaly along the track.
pub(crate) fn apply_rate_crossovers(flight: &Flight, opts: &KfOptions, run: &mut KfRun) {
    let regs = crate::estimate::crossover::rate_regressors(flight);
    let coefficients = match opts.rate_crossover_coefficients {
        Some(c) => c,
        None if opts.rate_crossovers && !opts.realtime && opts.coefficients.is_none() => {
            let crossings = crate::estimate::crossover::find_crossings(flight);
            let Some(fit) = crate::estimate::crossover::fit_rate(
                flight,
                &crossings,
                &run.compensated_nt,
                &regs,
            ) else {
                return;
            };
            let apply = fit.p_value < RATE_CROSSOVER_ALPHA;
            let c = fit.coefficients;
            run.rate_crossover = Some((fit, apply));
            if !apply {
                return;
            }
            c
        }
        None => return,
    };
    let correction = crate::estimate::crossover::rate_correction_nt(&regs, &coefficients);
    for ((i, c), v) in run
        .interference_nt
        .iter_mut()
        .zip(run.compensated_nt.iter_mut())
        .zip(correction)
    {
        *i += v;
        *c -= v;
    }
}

/// The interference of constant coefficients over every sample's regressors (nT).
pub fn interference_of(regressors: &[Vec<f32>], coefficients: &[f64]) -> Vec<f64> {
    regressors
        .iter()
        .map(|r| r.iter().zip(coefficients).map(|(x, c)| *x as f64 * c).sum())
        .collect()
}
