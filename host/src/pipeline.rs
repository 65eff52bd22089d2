//! Runs the shared core over a flight: post-flight (calibrate on the trace, then apply the
//! final coefficients to every sample) or real-time (the causal filter's own output).

use crate::flight::Flight;
use crate::fluxgate::{self, FluxgateCalibration, FluxgateFit};
use crate::metrics::interference_of;
use crate::model_spec::{with_model, ModelSpec};
use anyhow::{bail, Result};
use magcomp_core::compensator::{Compensator, CompensatorConfig, Output};
use magcomp_core::epoch::Epoch;
use magcomp_core::model::Term;
use magcomp_core::spectrum::{estimate_sigma1, Sigma1Config};

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
    /// estimating it ([`crate::preprocess`]).
    pub preprocessing: Option<crate::preprocess::Preprocessing>,
    /// Coefficient combinations (prior-σ units, model order) held at the prior: the
    /// flight's manoeuvres do not determine them ([`crate::excitation`]). Set by the
    /// calibration itself; empty = all free.
    pub held_combinations: Vec<Vec<f32>>,
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
    /// [`predicted_interference_error_nt`] on this flight: of the calibration, or of the
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
    pub rate_crossover: Option<(crate::crossover::RateFit, bool)>,
    /// With `fluxcal`: the fluxgate calibration used, and its fit when made on this flight.
    pub fluxgate_calibration: Option<FluxgateCalibration>,
    pub fluxgate_fit: Option<FluxgateFit>,
    /// What the run found the user must know (undetermined coefficients, …).
    pub warnings: Vec<String>,
    /// With `lag`/`fluxtemp`: what was done to the flight before the filter.
    pub preprocessing: Option<crate::preprocess::Preprocessing>,
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
    let freeze_at = if opts.realtime && opts.freeze_on_survey && coefficients.is_none() {
        flight.segments.as_ref().and_then(|s| {
            let last = s.iter().rposition(|l| crate::metrics::is_manoeuvre(l))?;
            Some(last + 1)
        })
    } else {
        None
    };
    with_model(spec, |model| {
        let mut comp = HostCompensator::new(model, cfg)
            .map_err(|e| anyhow::anyhow!("cannot build the filter for '{}': {e:?}", spec.text()))?;
        if let Some(c) = coefficients {
            let c32: Vec<f32> = c.iter().map(|v| *v as f32).collect();
            comp.set_coefficients(&c32).map_err(|e| {
                anyhow::anyhow!(
                    "the coefficients do not fit model '{}' ({} values for {} coefficients): {e:?}",
                    spec.text(),
                    c.len(),
                    model.coefficient_count()
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
        let mut progress = crate::stream::Progress::new(
            &format!("Kalman filter pass {pass_no}"),
            crate::stream::quiet_progress(false),
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
fn choose_field_profile(
    flight: &Flight,
    opts: &KfOptions,
    cfg: CompensatorConfig,
) -> Result<(KfOptions, String)> {
    let (outs, regs, c, _, _) = pass(flight, opts, cfg, None, true)?;
    let interference = interference_of(&regs, &c);
    let mut best = (
        innovation_nll(&outs),
        opts.clone(),
        String::from("stationary"),
    );
    let stationary = vec![1.0; flight.len()];
    let local: Vec<Vec<f64>> = FIELD_PROFILES
        .iter()
        .map(|&p| field_profile(flight, &interference, cfg.noise_nt as f64, p))
        .collect();
    for (k, profile) in std::iter::once(&stationary).chain(&local).enumerate() {
        for &m in &FIELD_PROFILE_SCALES {
            if k == 0 && m == 1.0 {
                continue; // the stationary pass above
            }
            let mut o = opts.clone();
            o.field_profile = Some(profile.iter().map(|v| v * m).collect());
            let (outs, ..) = pass(flight, &o, cfg, None, false)?;
            let nll = innovation_nll(&outs);
            if nll < best.0 {
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
                best = (nll, o, label);
            }
        }
    }
    Ok((best.1, best.2))
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
/// (k×k) and `C` the covariance of the interference regressors over the flight. It is the
/// error against the truth to expect when the model holds, and a calibration flight's
/// quality figure without any truth: high where the pattern left a combination of terms
/// unobserved (a strong anomaly that changes between the headings, too few manoeuvres).
pub fn predicted_interference_error_nt(regressors: &[Vec<f32>], covariance: &[f64]) -> Option<f64> {
    let k = regressors.first()?.len();
    if covariance.len() != k * k {
        return None;
    }
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
    let mut regressor_cov = vec![0.0; k * k];
    for r in &rows {
        let d: Vec<f64> = (0..k).map(|j| r[j] as f64 - mean[j]).collect();
        for a in 0..k {
            for b in 0..k {
                regressor_cov[a * k + b] += d[a] * d[b] / n;
            }
        }
    }
    let var: f64 = covariance
        .iter()
        .zip(&regressor_cov)
        .map(|(p, c)| p * c)
        .sum();
    var.is_finite().then(|| var.max(0.0).sqrt())
}

/// σ1 from the along-track spectrum of (scalar − interference estimate).
pub fn estimate_sigma1_for(flight: &Flight, interference_nt: &[f64]) -> Option<f64> {
    estimate_sigma1_with(flight, interference_nt, None)
}

/// What the scalar holds that is neither anomaly nor interference and that the model
/// attributes to its own environment terms: for single-channel ones (`diurnal`) their prior
/// mean × channel (β₀ = 1 × base). Left in, a base-station micropulsation would raise σ1
/// and the field states would take it instead of the term. (The core-field change is left
/// in: the σ1 selection and the consistency checks were validated with it there.)
pub fn known_environment_nt(flight: &Flight, spec: &ModelSpec) -> Vec<f64> {
    let terms = spec.build_terms();
    let env_terms: Vec<(usize, f64)> = terms
        .iter()
        .filter(|t| !t.is_interference() && t.len() == 1)
        .filter_map(|t| t.channel().map(|c| (c, t.prior_mean(0) as f64)))
        .collect();
    flight
        .samples
        .iter()
        .map(|s| {
            env_terms
                .iter()
                .map(|&(c, m)| {
                    let v = s.aux[c] as f64;
                    if v.is_finite() {
                        m * v
                    } else {
                        0.0
                    }
                })
                .sum()
        })
        .collect()
}

/// σ1 from (scalar − interference − known environment) against along-track distance.
pub fn estimate_sigma1_with(
    flight: &Flight,
    interference_nt: &[f64],
    environment_nt: Option<&[f64]>,
) -> Option<f64> {
    let s = flight.along_track_m();
    let z: Vec<f64> = flight
        .mag_nt
        .iter()
        .zip(interference_nt)
        .enumerate()
        .map(|(k, (m, i))| m - i - environment_nt.map_or(0.0, |e| e[k]))
        .collect();
    let cfg = Sigma1Config::default();
    // Sized by the samples, never by a coordinate (issue 13: one bad latitude asked for 53 GB).
    let mut scratch = vec![0.0; magcomp_core::spectrum::sigma1_scratch_len(&s, &z, &cfg)];
    estimate_sigma1(&s, &z, &cfg, &mut scratch).map(|e| e.sigma1)
}

/// The trade's FOM of the compensated signal over the labelled calibration manoeuvres
/// (`None` without labels). A label-free score (residual power in the manoeuvre band over
/// the most active stretches) was tried and picked σ1 far too small at 3000 m.
fn selection_score(flight: &Flight, interference_nt: &[f64]) -> Option<(f64, usize)> {
    let comp: Vec<f64> = flight
        .mag_nt
        .iter()
        .zip(interference_nt)
        .map(|(m, i)| m - i)
        .collect();
    crate::metrics::fom(flight, &comp).map(|(f, parts)| (f, parts.len()))
}

/// Post-flight choice of σ1 among `spectral × candidate`: the spectral fit matches the
/// anomaly's power at 1–8 km, but a potential field's spectrum falls faster than k⁻⁶
/// towards the manoeuvre wavelengths, so at low altitude the k⁻⁶ model with that σ1 lets
/// the field absorb manoeuvre-band interference. Each candidate is a full calibration;
/// the least FOM over the labelled manoeuvres wins (segment labels are user data of a
/// calibration flight); without labels the spectral σ1 is kept.
fn select_sigma1(flight: &Flight, opts: &KfOptions, spectral: f64, noise_nt: f64) -> Result<f64> {
    let labelled = flight
        .segments
        .as_ref()
        .is_some_and(|s| s.iter().any(|l| crate::metrics::is_manoeuvre(l)));
    if opts.sigma1_candidates.len() < 2 || !labelled {
        return Ok(spectral);
    }
    // A candidate must beat the best so far by more than the sensor noise can explain
    // (one noise σ per manoeuvre): at 3000 m all candidates tie within noise and the
    // FOM's own scatter would otherwise pick a needlessly rigid field.
    let mut best = (f64::INFINITY, spectral);
    for &m in &opts.sigma1_candidates {
        let s1 = spectral * m;
        let cfg = base_config(flight, opts, s1, noise_nt);
        let interf = calibrated_interference(flight, opts, cfg)?;
        if let Some((score, parts)) = selection_score(flight, &interf) {
            if score < best.0 - parts as f64 * noise_nt {
                best = (score, s1);
            }
        }
    }
    Ok(best.1)
}

/// Non-stationary anomaly processes tried post-flight: (third-difference step in samples at
/// 10 Hz, half-window in samples, normalise by the median instead of the mean). The step
/// sets the wavelengths whose roughness is measured (≈ 0.3–1 km at 60 m/s), the window
/// how local it is (±0.45–1.8 km).
pub const FIELD_PROFILES: [(usize, usize, bool); 5] = [
    (15, 75, true),
    (15, 150, true),
    (30, 150, true),
    (30, 150, false),
    (30, 300, true),
];

/// Multipliers of σ1² tried with every profile (and with the stationary process). The
/// spectral σ1 (fitted at 1–8 km) is an upper bound: a potential field's spectrum falls
/// faster than k⁻⁶ towards shorter wavelengths, and a looser field takes what the model's
/// other terms should explain (with `diurnal`, ×2 took the anomaly-map error 0.11 → 0.47 nT).
pub const FIELD_PROFILE_SCALES: [f64; 3] = [0.25, 0.5, 1.0];

/// Local roughness of the anomaly along the track relative to the flight's typical one:
/// the windowed power of the third difference of (scalar − interference estimate) above
/// its white-noise floor. Over a shallow source the anomaly is far rougher than the
/// flight's single σ1 says and the field states must be freer there (and stiffer over
/// quiet ground), or the coefficients take what the field cannot follow.
pub fn field_profile(
    flight: &Flight,
    interference_nt: &[f64],
    noise_nt: f64,
    (step, half_window, median): (usize, usize, bool),
) -> Vec<f64> {
    let n = flight.len();
    // The step is in 10 Hz samples; keep its length in metres at other rates.
    let step = ((step as f64 * flight.sample_rate_hz / 10.0).round() as usize).max(1);
    let half_window = ((half_window as f64 * flight.sample_rate_hz / 10.0).round() as usize).max(1);
    let z: Vec<f64> = flight
        .mag_nt
        .iter()
        .zip(interference_nt)
        .map(|(m, i)| m - i)
        .collect();
    let mut d3 = vec![0.0; n];
    for i in 0..n.saturating_sub(3 * step) {
        let v = z[i + 3 * step] - 3.0 * z[i + 2 * step] + 3.0 * z[i + step] - z[i];
        d3[i + 3 * step / 2] = if v.is_finite() { v * v } else { 0.0 };
    }
    let mut prefix = vec![0.0; n + 1];
    for i in 0..n {
        prefix[i + 1] = prefix[i] + d3[i];
    }
    let floor = 20.0 * noise_nt * noise_nt;
    let local: Vec<f64> = (0..n)
        .map(|i| {
            let a = i.saturating_sub(half_window);
            let b = (i + half_window + 1).min(n);
            ((prefix[b] - prefix[a]) / (b - a) as f64 - floor).max(0.0)
        })
        .collect();
    let typical = if median {
        let mut sorted = local.clone();
        sorted.sort_by(|a, b| a.total_cmp(b));
        sorted[n / 2]
    } else {
        local.iter().sum::<f64>() / n.max(1) as f64
    }
    .max(1e-12);
    local
        .iter()
        .map(|l| (l / typical).clamp(0.05, 400.0))
        .collect()
}

/// Mean negative log-likelihood of the innovations (`ln S + ν²/S`): lower = the data are
/// more probable under the filter's model.
fn innovation_nll(outs: &[Output]) -> f64 {
    let (sum, n) = outs
        .iter()
        .filter(|o| {
            o.innovation_nt.is_finite()
                && o.innovation_var_nt2.is_finite()
                && o.innovation_var_nt2 > 0.0
        })
        .fold((0.0f64, 0usize), |(s, n), o| {
            let (v, var) = (o.innovation_nt as f64, o.innovation_var_nt2 as f64);
            (s + var.ln() + v * v / var, n + 1)
        });
    if n == 0 {
        f64::INFINITY
    } else {
        sum / n as f64
    }
}

/// The measurement noise the filter needs on this flight: the scalar's own noise plus what
/// the model cannot follow (a real aircraft's unmodelled interference, fluxgate noise in
/// the regressors). Estimated from the innovations of a calibration pass, whose variance
/// the filter predicts as `S = H·P·Hᵀ + r`: `r = E[ν²] − E[H·P·Hᵀ]`, with medians (of a
/// χ²₁ variable, median/0.455 is its mean) so manoeuvre transients and glitches do not
/// inflate it. Never below the sensor noise `floor_nt`. On our simulator the model is
/// right and `r` stays at the sensor's noise; on the real SGL boxes the sensor noise
/// (0.02 nT) was ~100× too small, and the 8σ gate refused 69 % of the samples.
fn adapted_noise_nt(flight: &Flight, opts: &KfOptions, sigma1: f64, floor_nt: f64) -> Result<f64> {
    // Only where the sensor's figure is grossly wrong: the gate then refuses many samples.
    // A model error of a few times the sensor noise is better left to the terms the
    // diagnosis adds and to the field states.
    let (outs, ..) = pass(
        flight,
        opts,
        base_config(flight, opts, sigma1, floor_nt),
        None,
        false,
    )?;
    let refused = outs
        .iter()
        .filter(|o| o.flags.contains(magcomp_core::Flags::INNOVATION_REJECTED))
        .count();
    if (refused as f64) < MAX_REFUSED_SHARE * outs.len() as f64 {
        return Ok(floor_nt);
    }
    // Ungated: with a noise far too small, a gated filter refuses most samples, never
    // converges, and its large H·P·Hᵀ then "explains" the innovations.
    let opts = &KfOptions {
        gate_sigma: 0.0,
        ..opts.clone()
    };
    let mut noise_nt = floor_nt;
    for _ in 0..4 {
        let cfg = base_config(flight, opts, sigma1, noise_nt);
        let (outs, ..) = pass(flight, opts, cfg, None, false)?;
        let r = noise_nt * noise_nt;
        let (mut nu2, mut hph): (Vec<f64>, Vec<f64>) = outs
            .iter()
            .filter(|o| o.innovation_nt.is_finite() && o.innovation_var_nt2.is_finite())
            .map(|o| {
                let nu = o.innovation_nt as f64;
                (nu * nu, (o.innovation_var_nt2 as f64 - r).max(0.0))
            })
            .unzip();
        if nu2.len() < 16 {
            return Ok(noise_nt);
        }
        let model_var = median(&mut nu2) / 0.4549 - median(&mut hph);
        let next = model_var.max(floor_nt * floor_nt).sqrt();
        let converged = (next / noise_nt - 1.0).abs() < 0.1;
        noise_nt = next;
        if converged {
            break;
        }
    }
    Ok(noise_nt)
}

/// Unexplained signal (nT rms) above which the model error is a warning: below it, the
/// survey tolerance is not at stake.
pub const MODEL_ERROR_WARNING_NT: f64 = 0.05;

/// Share of samples the gate may refuse with the sensor's noise before the noise is
/// estimated from the innovations instead (the real boxes: 69 %). At 5 % the estimate also
/// fired on simulated low-altitude flights over strong geology and on flights with a hidden
/// effect, and the inflated noise cost them accuracy (300 m seed 3: 0.61 nT).
const MAX_REFUSED_SHARE: f64 = 0.3;

fn median(v: &mut [f64]) -> f64 {
    let mid = v.len() / 2;
    v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    v[mid]
}

/// Default σ1 multipliers searched post-flight.
pub const SIGMA1_CANDIDATES: [f64; 4] = [1.0, 0.3, 0.1, 0.03];

/// Default σ1 when the track is too short for the spectrum (the paper's 1000 m value).
pub const DEFAULT_SIGMA1: f64 = 1.0e-6;

/// Runs the compensator over a flight. With `lag` or `fluxtemp` in the model the flight is
/// first pre-processed (scalar re-aligned, fluxgate corrected for temperature:
/// [`crate::preprocess`]), then [`run_kf_estimator`] runs on it.
pub fn run_kf(flight: &Flight, opts: &KfOptions) -> Result<KfRun> {
    if crate::preprocess::needed(&opts.model) {
        return crate::preprocess::run_kf_preprocessed(flight, opts);
    }
    run_kf_estimator(flight, opts)
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
    let (calibration, fit) = match opts.fluxgate_calibration {
        Some(c) => (c, None),
        None if opts.realtime => (fluxgate::FluxgateCalibration::IDENTITY, None),
        None => {
            // `fluxcal` adds no filter state, so the first pass is the model without it.
            let mut first = run_kf_on(flight, opts)?;
            let fitted = fluxgate::fit_flight(flight, &first.interference_nt)
                .and_then(fluxgate::FluxgateFit::determined);
            match fitted {
                Ok(fit) => (fit.calibration, Some(fit)),
                Err(reason) => {
                    first.warnings.push(format!(
                        "fluxgate not calibrated against the scalar, used as measured: {reason:#}"
                    ));
                    first.fluxgate_calibration = Some(fluxgate::FluxgateCalibration::IDENTITY);
                    return Ok(first);
                }
            }
        }
    };
    let mut run = run_kf_on(&fluxgate::calibrated_flight(flight, &calibration), opts)?;
    run.fluxgate_calibration = Some(calibration);
    run.fluxgate_fit = fit;
    Ok(run)
}

fn run_kf_on(flight: &Flight, opts: &KfOptions) -> Result<KfRun> {
    if flight.is_empty() {
        bail!("no samples");
    }
    let spec = &opts.model;
    // The filter's r covers sensor noise plus what the model cannot follow (fluxgate noise
    // in the regressors, residual model error): never below 5 pT.
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
            // A first post-flight pass with the paper's σ1 gives the interference estimate
            // that is removed before the spectrum is taken.
            let cfg = base_config(flight, opts, DEFAULT_SIGMA1, noise_nt);
            let interf = calibrated_interference(flight, opts, cfg)?;
            let spectral =
                estimate_sigma1_with(flight, &interf, Some(&known_environment_nt(flight, spec)))
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
    // follow: interference it lacks a term for. It stays in the compensated output, so it
    // belongs in the predicted error (on the real SGL boxes the coefficient covariance
    // alone predicted 0.85–1.2 nT where the box-to-box transfer left 3.0–4.4 nT).
    let model_error_nt = match opts.coefficients {
        Some(_) => opts.model_error_nt,
        None => (noise_nt > sensor_noise_nt)
            .then(|| (noise_nt * noise_nt - sensor_noise_nt * sensor_noise_nt).sqrt()),
    };
    let cfg = base_config(flight, opts, sigma1, noise_nt);
    let mut warnings = Vec::new();
    let held;
    // Post-flight only: which combinations the flight excites is known at its end, and the
    // board (which real time reproduces) cannot know it in advance.
    let opts = if opts.coefficients.is_none() && opts.held_combinations.is_empty() && !opts.realtime
    {
        let (_, regs, ..) = pass(flight, opts, cfg, None, true)?;
        let terms = spec.build_terms();
        let prior: Vec<f64> = terms
            .iter()
            .flat_map(|t| (0..t.len()).map(|i| t.prior_sigma(i) as f64 * opts.prior_scale))
            .collect();
        let interference: Vec<bool> = terms
            .iter()
            .flat_map(|t| std::iter::repeat_n(t.is_interference(), t.len()))
            .collect();
        let span = crate::excitation::airborne_span(flight);
        let weak =
            crate::excitation::unexcited_combinations(flight, &regs[span], &prior, &interference);
        if !weak.is_empty() {
            warnings.push(crate::excitation::warning(
                weak.len(),
                interference.iter().filter(|i| **i).count(),
                true,
            ));
        }
        let mut o = opts.clone();
        o.held_combinations = weak;
        held = o;
        &held
    } else {
        opts
    };
    let profiled;
    let mut field_process = String::from("stationary");
    // Only when σ1 itself is estimated: a σ1 the user gives is taken as the model.
    let opts = if opts.field_profiles
        && spec.field
        && opts.sigma1.is_none()
        && opts.field_profile.is_none()
        && opts.coefficients.is_none()
    {
        let (o, label) = choose_field_profile(flight, opts, cfg)?;
        profiled = o;
        field_process = label;
        &profiled
    } else {
        opts
    };
    let (cal_outs, regs, coeffs, covariance, cal_healthy) = match &opts.coefficients {
        Some(c) => pass(flight, opts, cfg, Some(c), true)?,
        None => pass(flight, opts, cfg, None, true)?,
    };
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
    // Given coefficients predict this flight's error only with their own covariance.
    let (coefficient_covariance, predicted_error_nt) =
        match (&opts.coefficients, &opts.coefficient_covariance) {
            (Some(_), Some(given)) => {
                (given.clone(), predicted_interference_error_nt(&regs, given))
            }
            (Some(_), None) => (covariance, None),
            (None, _) => {
                let predicted = predicted_interference_error_nt(&regs, &covariance);
                (covariance, predicted)
            }
        };
    let predicted_error_nt = predicted_error_nt.map(|p| p.hypot(model_error_nt.unwrap_or(0.0)));
    if let Some(m) = model_error_nt.filter(|m| *m > MODEL_ERROR_WARNING_NT) {
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
        sigma1,
        noise_nt,
        model_error_nt,
        warnings,
        filter_healthy: healthy,
        field_process: if spec.field {
            field_process
        } else {
            String::from("none")
        },
        ..Default::default()
    };
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
    if spec.terms.iter().any(|t| t.name == "rate") {
        apply_rate_crossovers(flight, opts, &mut run);
    }
    Ok(run)
}

/// Significance the crossover rate fit needs before it is applied: without evidence the
/// fit would only add its own noise (0.02–0.04 nT on clean simulated flights).
pub const RATE_CROSSOVER_ALPHA: f64 = 0.01;

/// The `rate` term's crossover step (post-flight; see [`crate::crossover`]). The filter's
/// own `rate` states see the anisotropic part only where `e` changes within a pass; the
/// crossovers see what the filter cannot: the part that, on one pass, is a shift of the
/// anomaly along the track.
fn apply_rate_crossovers(flight: &Flight, opts: &KfOptions, run: &mut KfRun) {
    let regs = crate::crossover::rate_regressors(flight);
    let coefficients = match opts.rate_crossover_coefficients {
        Some(c) => c,
        None if opts.rate_crossovers && !opts.realtime && opts.coefficients.is_none() => {
            let crossings = crate::crossover::find_crossings(flight);
            let Some(fit) =
                crate::crossover::fit_rate(flight, &crossings, &run.compensated_nt, &regs)
            else {
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
    let correction = crate::crossover::rate_correction_nt(&regs, &coefficients);
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
