//! Runs the shared core over a flight: post-flight (calibrate on the trace, then apply the
//! final coefficients to every sample) or real-time (the causal filter's own output).

use crate::estimate::fluxcal::{self, FluxgateCalibration, FluxgateFit};
use crate::flight::Flight;
use crate::model::spec::{with_model, ModelSpec};
use anyhow::{bail, Result};
use magcomp_core::compensator::{Compensator, CompensatorConfig, Output};
use magcomp_core::epoch::Epoch;
use magcomp_core::model::{Term, TermKind};
use magcomp_core::AlignedSample;

mod jackknife;
mod parallel;
mod tuning;

pub use jackknife::{KfJackknife, INCONSISTENT_REFITS};
use tuning::{adapted_noise_nt, innovation_nll, select_sigma1};
pub use tuning::{
    estimate_sigma1_for, estimate_sigma1_with, field_profile, known_environment_nt, FIELD_PROFILES,
    FIELD_PROFILE_SCALES, MODEL_ERROR_WARNING_NT,
};

/// Host capacity: 21 paper states + up to 41 extra coefficients + clones.
pub const HOST_STATES: usize = 64;
/// Derivative ring: ±50 samples at 1 kHz.
pub const HOST_WINDOW: usize = 128;
pub type HostCompensator<'a> = Compensator<'a, HOST_STATES, HOST_WINDOW>;

/// What the user can set; `None` = estimated from the data.
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
    /// Per-sample multiplier of the field's process-noise variance (internal: set by the
    /// profile search; `None` = stationary, the paper's model).
    pub field_profile: Option<Vec<f64>>,
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
    /// Coefficient combinations (prior-σ units, model order) held at the prior: the
    /// flight's manoeuvres do not determine them ([`crate::estimate::excitation`]). Set by the
    /// calibration itself; empty = all free.
    pub held_combinations: Vec<Vec<f32>>,
    /// Post-flight calibration: check the coefficients against the flight's own evidence
    /// (the jackknife, [`crate::estimate::jackknife`]: 8 more filter passes). Off by default: the
    /// calibration a user is given turns it on (`calibration`); the runs made for other
    /// ends (a first pass for `fluxcal`/`fluxtemp`, diagnosis, a TL flight's field
    /// estimate) do not report a predicted error.
    pub jackknife: bool,
    /// Samples whose scalar the filter does not learn from (predict only): the
    /// cross-check's refits without one stretch of the flight.
    pub skip_updates: Option<std::ops::Range<usize>>,
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
            sigma2_ratio: 0.1,
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
            field_profile: None,
            rate_crossovers: true,
            rate_crossover_coefficients: None,
            coefficient_covariance: None,
            model_error_nt: None,
            preprocessing: None,
            held_combinations: Vec::new(),
            jackknife: false,
            skip_updates: None,
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

fn base_config(flight: &Flight, opts: &KfOptions, sigma1: f64, noise_nt: f64) -> CompensatorConfig {
    let geometry = (
        flight.sample_rate_hz,
        flight.earth_dir_ned,
        flight.tie_point,
    );
    config_for(geometry, opts, sigma1, noise_nt)
}

/// The filter's configuration from what it needs of a flight (sample rate, main-field
/// direction, tie point): shared with the streaming `compensate` (`crate::stream`).
pub(crate) fn config_for(
    (sample_rate_hz, earth_dir_ned, tie_point): (
        f64,
        Option<[f32; 3]>,
        Option<magcomp_core::compensator::TiePoint>,
    ),
    opts: &KfOptions,
    sigma1: f64,
    noise_nt: f64,
) -> CompensatorConfig {
    let mut cfg = CompensatorConfig::for_rate(sample_rate_hz as f32);
    cfg.sigma1 = sigma1 as f32;
    cfg.sigma2 = (sigma1 * opts.sigma2_ratio) as f32;
    cfg.noise_nt = noise_nt as f32;
    cfg.prior_scale = opts.prior_scale as f32;
    cfg.h0_reanchor_m = opts.h0_reanchor_m as f32;
    cfg.gate_sigma = opts.gate_sigma as f32;
    set_run_mode(&mut cfg, opts.realtime);
    if let Some(hw) = opts.half_width {
        cfg.epoch.half_width = hw.max(1);
    }
    cfg.epoch.earth_dir_ned = earth_dir_ned;
    if opts.tie_points {
        cfg.tie_points[0] = tie_point;
    }
    cfg
}

/// Real time (the board, which `--realtime` reproduces) or a post-flight pass: post-flight
/// the calibration is judged at its end, so the causal divergence reset is off, and nothing
/// is learnt on the ground (`GROUND_SPEED_MPS`).
pub(crate) fn set_run_mode(cfg: &mut CompensatorConfig, realtime: bool) {
    cfg.divergence_reset = realtime;
    if !realtime {
        cfg.min_update_speed_mps = magcomp_core::compensator::GROUND_SPEED_MPS;
    }
}

/// Filter passes made by this process (numbers the progress lines).
static PASSES: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// Outputs, interference regressors, coefficients, their covariance (k×k, row-major),
/// filter health.
type Pass = (Vec<Output>, Vec<Vec<f32>>, Vec<f64>, Vec<f64>, bool);

/// One pass of the compensator over all samples; exactly one output per sample.
fn pass(
    flight: &Flight,
    opts: &KfOptions,
    cfg: CompensatorConfig,
    coefficients: Option<&[f64]>,
    keep_regressors: bool,
) -> Result<Pass> {
    let spec = &opts.model;
    let turn = |i: usize| -> bool {
        opts.turn_noise_scale != 1.0
            && flight
                .segments
                .as_ref()
                .is_some_and(|s| s[i].contains("turn"))
    };
    let freeze_at = if opts.realtime && opts.survey_from.is_some() && coefficients.is_none() {
        opts.survey_from
    } else if opts.realtime && opts.freeze_on_survey && coefficients.is_none() {
        flight.segments.as_ref().and_then(|s| {
            let last = s
                .iter()
                .rposition(|l| crate::qc::figures::is_manoeuvre(l))?;
            Some(last + 1)
        })
    } else {
        None
    };
    with_model(spec, |model| {
        let mut comp = HostCompensator::new(model, cfg)
            .map_err(|e| crate::model::errors::cannot_build(&spec.text(), &e))?;
        if let Some(c) = coefficients {
            let c32: Vec<f32> = c.iter().map(|v| *v as f32).collect();
            comp.set_coefficients(&c32).map_err(|e| {
                crate::model::errors::do_not_fit(
                    &spec.text(),
                    c.len(),
                    model.coefficient_count(),
                    &e,
                )
            })?;
        } else {
            for w in &opts.held_combinations {
                if !comp.hold_coefficient_combination(w) {
                    bail!("internal: a held combination does not fit the model");
                }
            }
        }
        let interference_terms: Vec<bool> = model
            .terms
            .iter()
            .flat_map(|t| std::iter::repeat_n(t.is_interference(), t.len()))
            .collect();
        let k = model.coefficient_count();
        let mut outs = Vec::with_capacity(flight.len());
        let mut healthy = true;
        // Post-flight calibration makes a dozen or more passes; each says how it goes.
        let pass_no = PASSES.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        let mut progress = crate::io::progress::Progress::new(
            &format!("Kalman filter pass {pass_no}"),
            crate::io::progress::quiet_progress(false),
        );
        let mut regs = Vec::new();
        let mut buf = vec![0.0f32; k];
        let mut keep = |ep: &Epoch, comp: &HostCompensator| {
            if keep_regressors {
                comp.term_regressors(ep, &mut buf);
                regs.push(
                    buf.iter()
                        .zip(&interference_terms)
                        .map(|(v, &i)| if i { *v } else { 0.0 })
                        .collect::<Vec<f32>>(),
                );
            }
        };
        for (i, s) in flight.samples.iter().enumerate() {
            if freeze_at == Some(i) {
                comp.set_survey_mode(true);
            }
            if let Some(p) = &opts.field_profile {
                comp.set_field_noise_scale(p[i] as f32);
            }
            comp.set_noise_scale(if turn(i) {
                opts.turn_noise_scale as f32
            } else {
                1.0
            });
            let skipped;
            let s = match &opts.skip_updates {
                Some(r) if r.contains(&i) => {
                    // A sample without its scalar predicts and does not update.
                    skipped = AlignedSample { mag: None, ..*s };
                    &skipped
                }
                _ => s,
            };
            if let Some((ep, out)) = comp.push_epoch(s) {
                keep(&ep, &comp);
                outs.push(out);
            }
            healthy &= comp.filter().is_healthy();
            progress.tick();
        }
        progress.done();
        while let Some((ep, out)) = comp.flush_epoch() {
            keep(&ep, &comp);
            outs.push(out);
        }
        if outs.len() != flight.len() {
            bail!(
                "internal: {} outputs for {} samples",
                outs.len(),
                flight.len()
            );
        }
        let mut c = vec![0.0f32; k];
        comp.coefficients(&mut c);
        let covariance = (0..k * k)
            .map(|ij| comp.coefficient_covariance(ij / k, ij % k) as f64)
            .collect();
        healthy &= comp.filter().is_healthy();
        Ok((
            outs,
            regs,
            c.iter().map(|v| *v as f64).collect(),
            covariance,
            healthy,
        ))
    })
}

/// Calibrates on the whole flight and applies the final coefficients to every sample
/// (the interference regressors of the calibration pass times the final coefficients:
/// the same numbers a second, survey-mode pass would give).
/// The stationary anomaly process (the paper's) and the [`FIELD_PROFILES`], each at the
/// [`FIELD_PROFILE_SCALES`] of the spectral σ1², run as calibration passes; the one with
/// the least innovation NLL wins. The scales are bounded (¼–1 × σ1²): an unbounded
/// likelihood search for σ1 runs away when the data hold an effect the model lacks
/// (model.md §3).
///
/// `family`: only that process (0 the stationary, k the k-th profile) at its scales, beside
/// the stationary at 1 × σ1² (a second run on the calibrated fluxgate: the first run's
/// choice of family, its scale chosen again). Returns the options, their label and the
/// family chosen.
fn choose_field_profile(
    flight: &Flight,
    opts: &KfOptions,
    cfg: CompensatorConfig,
    family: Option<usize>,
) -> Result<(KfOptions, String, usize)> {
    let (outs, regs, c, _, _) = pass(flight, opts, cfg, None, true)?;
    let interference = interference_of(&regs, &c);
    let mut best = (
        innovation_nll(&outs),
        opts.clone(),
        String::from("stationary"),
        0,
    );
    let stationary = vec![1.0; flight.len()];
    let local: Vec<Vec<f64>> = FIELD_PROFILES
        .iter()
        .map(|&p| field_profile(flight, &interference, cfg.noise_nt as f64, p))
        .collect();
    let trials: Vec<(usize, f64)> = (0..=local.len())
        .flat_map(|k| FIELD_PROFILE_SCALES.iter().map(move |&m| (k, m)))
        // The stationary process at 1 × σ1² is the pass above.
        .filter(|&(k, m)| !(k == 0 && m == 1.0))
        .filter(|&(k, _)| family.is_none_or(|f| f == k))
        .collect();
    let profile = |k: usize, m: f64| -> KfOptions {
        let p = if k == 0 { &stationary } else { &local[k - 1] };
        KfOptions {
            field_profile: Some(p.iter().map(|v| v * m).collect()),
            ..opts.clone()
        }
    };
    // Independent passes (on the cores); the choice runs in their order.
    let nlls = parallel::map(&trials, |&(k, m)| {
        let (outs, ..) = pass(flight, &profile(k, m), cfg, None, false)?;
        Ok::<_, anyhow::Error>(innovation_nll(&outs))
    });
    for (&(k, m), nll) in trials.iter().zip(nlls) {
        let nll = nll?;
        if nll < best.0 {
            let o = profile(k, m);
            let label = match k {
                0 => format!("stationary, {m} × σ1²"),
                _ => {
                    let (step, half, median) = FIELD_PROFILES[k - 1];
                    format!(
                        "local roughness (step {step}, ±{half} samples at 10 Hz, {}), {m} × σ1²",
                        if median { "median" } else { "mean" }
                    )
                }
            };
            best = (nll, o, label, k);
        }
    }
    Ok((best.1, best.2, best.3))
}

fn calibrated_interference(
    flight: &Flight,
    opts: &KfOptions,
    cfg: CompensatorConfig,
) -> Result<Vec<f64>> {
    let (_, regs, c, _, _) = pass(flight, opts, cfg, None, true)?;
    Ok(interference_of(&regs, &c))
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
/// calibrated against the scalar (the stored calibration, or one fitted on this flight to
/// the scalar minus a first pass's interference) and the filter runs on the calibrated
/// fluxgate. A fit the flight does not determine is not applied: the fluxgate is used as
/// measured (identity calibration) and a warning says so. In real time without a stored
/// calibration the fluxgate is used as measured, as on the board before `SETFLUX`.
pub fn run_kf_estimator(flight: &Flight, opts: &KfOptions) -> Result<KfRun> {
    if !opts.model.calibrates_fluxgate() {
        return run_kf_on(flight, opts);
    }
    let mut not_calibrated = None;
    let mut tuning = None;
    let (calibration, fit) = match opts.fluxgate_calibration {
        Some(c) => (c, None),
        None if opts.realtime => (fluxcal::FluxgateCalibration::IDENTITY, None),
        None => {
            // `fluxcal` adds no filter state, so the first pass is the model without it.
            let (mut first, tuned) = run_kf_tuned(flight, &first_pass(opts), None)?;
            tuning = Some(tuned);
            let fitted = fluxcal::fit_flight(flight, &first.interference_nt)
                .and_then(fluxcal::FluxgateFit::determined)
                .and_then(fluxcal::FluxgateFit::physical);
            match fitted {
                Ok(fit) => (fit.calibration, Some(fit)),
                Err(reason) => {
                    let warning = format!(
                        "fluxgate not calibrated against the scalar, used as measured: {reason:#}"
                    );
                    if !opts.jackknife {
                        first.warnings.push(warning);
                        first.fluxgate_calibration = Some(fluxcal::FluxgateCalibration::IDENTITY);
                        return Ok(first);
                    }
                    // The first pass made no jackknife: the final pass, on the fluxgate
                    // as measured, does.
                    not_calibrated = Some(warning);
                    (fluxcal::FluxgateCalibration::IDENTITY, None)
                }
            }
        }
    };
    // The second run keeps the first's σ1 (the fluxgate's calibration moves the
    // interference by far less than what chose it) and chooses its noise and anomaly
    // process again, from innovations without the fluxgate's error.
    let calibrated = fluxcal::calibrated_flight(flight, &calibration);
    let (mut run, _) = run_kf_tuned(&calibrated, opts, tuning.as_ref())?;
    run.warnings.extend(not_calibrated);
    run.fluxgate_calibration = Some(calibration);
    run.fluxgate_fit = fit;
    Ok(run)
}

fn run_kf_on(flight: &Flight, opts: &KfOptions) -> Result<KfRun> {
    run_kf_tuned(flight, opts, None).map(|(run, _)| run)
}

/// What a run chose for its filter from the flight (σ1: the spectrum and the candidates'
/// passes), for a second run on the same flight to reuse.
struct Tuning {
    noise: FilterNoise,
    /// The anomaly process family chosen (0 the stationary, k the k-th profile).
    field_family: Option<usize>,
}

/// The run in stages: the filter's noise and anomaly process (`reuse`d, or chosen on the
/// flight), the excitation check, the calibration pass, the jackknife, the output pass.
fn run_kf_tuned(
    flight: &Flight,
    opts: &KfOptions,
    reuse: Option<&Tuning>,
) -> Result<(KfRun, Tuning)> {
    let survey_from = opts.survey_from;
    let unfrozen;
    let opts = if survey_from.is_some() {
        unfrozen = KfOptions {
            survey_from: None,
            ..opts.clone()
        };
        &unfrozen
    } else {
        opts
    };
    if flight.is_empty() {
        bail!("no samples");
    }
    let spec = &opts.model;
    // σ1 is reused; the noise is adapted again: what the first run's innovations showed
    // beyond the sensor's noise included the fluxgate's error its calibration took out.
    let noise = match reuse {
        Some(t) => FilterNoise::of(
            flight,
            &KfOptions {
                sigma1: Some(t.noise.sigma1),
                ..opts.clone()
            },
        )?,
        None => FilterNoise::of(flight, opts)?,
    };
    let mut cfg = base_config(flight, opts, noise.sigma1, noise.noise_nt);
    // The record's bound and the convergence tolerance count what the widened noise
    // covers beyond the sensor's own as model error (it stays in the output).
    cfg.sensor_noise_nt = noise.sensor_noise_nt as f32;
    let mut warnings = Vec::new();
    let held = hold_unexcited_combinations(flight, opts, cfg, &mut warnings)?;
    let opts = held.as_ref().unwrap_or(opts);
    // The anomaly process is chosen again: the innovations that choose it carried the
    // fluxgate's error before its calibration (reusing the first run's choice cost the
    // joint filter at 300 m over strong geology 0.028 → 0.045 nT on a sensor, `multi_sim`).
    // Within the first run's family: its scale is what the fluxgate's error moved.
    let family = reuse.and_then(|t| t.field_family);
    let profiled = profile_field(flight, opts, cfg, family)?;
    let tuning = Tuning {
        noise,
        field_family: profiled.as_ref().map(|p| p.2),
    };
    let (opts, field_process) = match &profiled {
        Some((o, label, _)) => (o, label.clone()),
        None => (opts, String::from("stationary")),
    };
    let (cal_outs, regs, coeffs, covariance, cal_healthy) = match &opts.coefficients {
        Some(c) => pass(flight, opts, cfg, Some(c), true)?,
        None => {
            let output = KfOptions {
                survey_from,
                ..opts.clone()
            };
            pass(flight, &output, cfg, None, true)?
        }
    };
    let spread = RegressorSpread::of(&regs);
    let (covariance, jackknife) = with_jackknife(
        flight,
        opts,
        cfg,
        (&regs, spread.as_ref()),
        (&coeffs, covariance),
        &mut warnings,
    )?;
    let (outs, coeffs, healthy) = if opts.realtime || opts.coefficients.is_some() {
        (cal_outs, coeffs, cal_healthy)
    } else {
        let (o, _, _, _, h) = pass(flight, opts, cfg, Some(&coeffs), false)?;
        (o, coeffs, cal_healthy && h)
    };
    let k = coeffs.len();
    let coefficient_sigmas = (0..k)
        .map(|i| covariance[i * k + i].max(0.0).sqrt())
        .collect();
    let (coefficient_covariance, predicted_error_nt) =
        predicted_error(opts, spread.as_ref(), covariance, noise.model_error_nt);
    if let Some(m) = noise.model_error_nt.filter(|m| *m > MODEL_ERROR_WARNING_NT) {
        let sensor_noise_nt = noise.sensor_noise_nt;
        warnings.push(format!(
            "the model leaves {m:.2} nT rms of the signal unexplained beyond the scalar's own \
             noise ({sensor_noise_nt:.3} nT): an effect the model lacks stays in the compensated \
             output and is counted in the predicted error. `magcomp diagnose` names candidates \
             (docs/adding-an-effect.md)"
        ));
    }
    let mut run = KfRun {
        coefficient_names: spec.coefficient_names(),
        coefficient_sigmas,
        predicted_error_nt,
        coefficient_covariance,
        coefficients: coeffs,
        regressors: regs,
        sigma1: noise.sigma1,
        noise_nt: noise.noise_nt,
        model_error_nt: noise.model_error_nt,
        warnings,
        filter_healthy: healthy,
        jackknife,
        field_process: if spec.field {
            field_process
        } else {
            String::from("none")
        },
        ..Default::default()
    };
    push_outputs(&mut run, &outs, flight);
    if spec.has(TermKind::Rate) {
        apply_rate_crossovers(flight, opts, &mut run);
    }
    Ok((run, tuning))
}

/// The filter's noise levels for one run: σ1 of the anomaly process, the measurement
/// noise r, and how much of r is the sensor's own.
#[derive(Clone, Copy)]
struct FilterNoise {
    /// The scalar's own noise (nT), before any widening for model error.
    sensor_noise_nt: f64,
    /// The measurement noise the filter uses (nT).
    noise_nt: f64,
    sigma1: f64,
    /// What `noise_nt` covers beyond the sensor's noise (see [`KfRun::model_error_nt`]).
    model_error_nt: Option<f64>,
}

impl FilterNoise {
    fn of(flight: &Flight, opts: &KfOptions) -> Result<Self> {
        let spec = &opts.model;
        // The filter's r covers sensor noise plus what the model cannot follow (fluxgate
        // noise in the regressors, residual model error): never below 5 pT.
        let noise_nt = match opts.noise_nt {
            Some(v) => v,
            None => {
                let sensor = estimate_noise_nt(&flight.mag_nt).unwrap_or(0.02);
                (sensor * sensor + 0.005f64.powi(2)).sqrt()
            }
        };
        let sigma1 = match opts.sigma1 {
            Some(v) => v,
            None if spec.field => {
                // A first post-flight pass with the paper's σ1 gives the interference
                // estimate that is removed before the spectrum is taken.
                let cfg = base_config(flight, opts, DEFAULT_SIGMA1, noise_nt);
                let interf = calibrated_interference(flight, opts, cfg)?;
                let spectral = estimate_sigma1_with(
                    flight,
                    &interf,
                    Some(&known_environment_nt(flight, spec)),
                )
                .unwrap_or(DEFAULT_SIGMA1)
                    * opts.sigma1_scale;
                select_sigma1(flight, opts, spectral, noise_nt)?
            }
            None => DEFAULT_SIGMA1,
        };
        let sensor_noise_nt = noise_nt;
        let noise_nt = match (opts.noise_nt, &opts.coefficients) {
            (None, None) => adapted_noise_nt(flight, opts, sigma1, noise_nt)?,
            _ => noise_nt,
        };
        // What the innovations show beyond the sensor's noise is signal the model cannot
        // follow: interference it lacks a term for. It stays in the compensated output, so
        // it belongs in the predicted error (on the real SGL boxes the coefficient
        // covariance alone predicted 0.85–1.2 nT where the box-to-box transfer left
        // 3.0–4.4 nT).
        let model_error_nt = match opts.coefficients {
            Some(_) => opts.model_error_nt,
            None => (noise_nt > sensor_noise_nt)
                .then(|| (noise_nt * noise_nt - sensor_noise_nt * sensor_noise_nt).sqrt()),
        };
        Ok(Self {
            sensor_noise_nt,
            noise_nt,
            sigma1,
            model_error_nt,
        })
    }
}

/// The options with the combinations this flight does not excite held at their prior
/// (and a warning naming how many), or None when that check does not apply. Post-flight
/// only: which combinations the flight excites is known at its end, and the board (which
/// real time reproduces) cannot know it in advance.
fn hold_unexcited_combinations(
    flight: &Flight,
    opts: &KfOptions,
    cfg: CompensatorConfig,
    warnings: &mut Vec<String>,
) -> Result<Option<KfOptions>> {
    if opts.coefficients.is_some() || !opts.held_combinations.is_empty() || opts.realtime {
        return Ok(None);
    }
    let (_, regs, ..) = pass(flight, opts, cfg, None, true)?;
    let terms = opts.model.build_terms();
    let prior: Vec<f64> = terms
        .iter()
        .flat_map(|t| (0..t.len()).map(|i| t.prior_sigma(i) as f64 * opts.prior_scale))
        .collect();
    let interference: Vec<bool> = terms
        .iter()
        .flat_map(|t| std::iter::repeat_n(t.is_interference(), t.len()))
        .collect();
    let span = crate::estimate::excitation::airborne_span(flight);
    let weak = crate::estimate::excitation::unexcited_combinations(
        flight,
        &regs[span],
        &prior,
        &interference,
    );
    if !weak.is_empty() {
        warnings.push(crate::estimate::excitation::warning(
            weak.len(),
            interference.iter().filter(|i| **i).count(),
            true,
        ));
    }
    let mut o = opts.clone();
    o.held_combinations = weak;
    Ok(Some(o))
}

/// The options with the anomaly process the likelihood chose, and its label; None when
/// the stationary process stays. Only when σ1 itself is estimated: a σ1 the user gives is
/// taken as the model.
fn profile_field(
    flight: &Flight,
    opts: &KfOptions,
    cfg: CompensatorConfig,
    family: Option<usize>,
) -> Result<Option<(KfOptions, String, usize)>> {
    if opts.field_profiles
        && opts.model.field
        && opts.sigma1.is_none()
        && opts.field_profile.is_none()
        && opts.coefficients.is_none()
    {
        choose_field_profile(flight, opts, cfg, family).map(Some)
    } else {
        Ok(None)
    }
}

/// The coefficients' covariance with the jackknife's added, and the jackknife, when it
/// applies. Post-flight: what the flight's own parts say of the coefficients, beside what
/// the filter's model says (`crate::estimate::jackknife`); the covariance carries both.
fn with_jackknife(
    flight: &Flight,
    opts: &KfOptions,
    cfg: CompensatorConfig,
    (regs, spread): (&[Vec<f32>], Option<&RegressorSpread>),
    (coeffs, covariance): (&[f64], Vec<f64>),
    warnings: &mut Vec<String>,
) -> Result<(Vec<f64>, Option<KfJackknife>)> {
    let checked = opts.jackknife && !opts.realtime && opts.coefficients.is_none();
    let Some(spread) = spread.filter(|_| checked) else {
        return Ok((covariance, None));
    };
    let Some(j) =
        jackknife::kf_jackknife(flight, opts, cfg, (regs, spread), (coeffs, &covariance))?
    else {
        return Ok((covariance, None));
    };
    // Summed, not the larger of the two: on the broad simulated flights the filter's
    // covariance and the jackknife each came out at 0.5–0.8 × the actual error (the model
    // error they both miss is most of it), their sum at 0.57–1.99 ×; the price is 2–3 ×
    // pessimism over strong geology.
    let total = covariance
        .iter()
        .zip(&j.covariance)
        .map(|(a, b)| a + b)
        .collect();
    if j.inflation > jackknife::INCONSISTENT_REFITS {
        warnings.push(j.lower_bound_warning());
    }
    Ok((total, Some(j)))
}

/// The covariance the run reports and the flight's predicted error (with the model error
/// added). Given coefficients predict this flight's error only with their own covariance.
fn predicted_error(
    opts: &KfOptions,
    spread: Option<&RegressorSpread>,
    covariance: Vec<f64>,
    model_error_nt: Option<f64>,
) -> (Vec<f64>, Option<f64>) {
    let (covariance, predicted) = match (&opts.coefficients, &opts.coefficient_covariance) {
        (Some(_), Some(given)) => (given.clone(), spread.and_then(|s| s.sigma_nt(given))),
        (Some(_), None) => (covariance, None),
        (None, _) => {
            let predicted = spread.and_then(|s| s.sigma_nt(&covariance));
            (covariance, predicted)
        }
    };
    let predicted = predicted.map(|p| p.hypot(model_error_nt.unwrap_or(0.0)));
    (covariance, predicted)
}

/// The filter's per-sample records into the run's columns (nT).
fn push_outputs(run: &mut KfRun, outs: &[Output], flight: &Flight) {
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
fn apply_rate_crossovers(flight: &Flight, opts: &KfOptions, run: &mut KfRun) {
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
