//! The joint calibration of several scalar magnetometers (docs/model.md §7): each sensor
//! alone first (today's pipeline: its noise, σ1, fluxgate calibration), then one
//! [`magcomp_core::joint::JointFilter`] over all of them with the anomaly shared, and the
//! joint coefficients applied to every sample, as the single-sensor post-flight run does.

use super::lever::{lever_arms, LeverArm};
use super::sensors::{sensor_trace, SensorSpec};
use crate::calibration::result::Compensation;
use crate::calibration::{
    compensate_trace, cross_checked, fluxgate_witness, CoefficientFile, EstimatorSettings, Method,
};
use crate::estimate::kf::{interference_of, RegressorSpread};
use crate::flight::Flight;
use crate::io::trace::Trace;
use crate::model::spec::{with_model, ModelSpec};
use anyhow::{bail, Context, Result};
use magcomp_core::compensator::{CompensatorConfig, GROUND_SPEED_MPS};
use magcomp_core::epoch::{Epoch, EpochBuilder, EpochConfig};
use magcomp_core::filter::FieldProcess;
use magcomp_core::joint::{JointFilter, JointSensor, LateralGradient, Placement, MAX_SENSORS};

/// Host capacity: 6 field + 4 × (1 + 16 + up to 14 model-term) coefficients.
pub const JOINT_STATES: usize = 136;
type HostJoint = JointFilter<JOINT_STATES>;

/// A sensor whose position is not known is taken this far (m) to starboard of the first:
/// the cabin sensors of the SGL Caravan are 1–3 m apart, a wingtip ~10 m.
pub const UNKNOWN_SEPARATION_M: f64 = 5.0;

/// Innovation gate (σ), as the single-sensor filter's default.
const GATE_SIGMA: f32 = 8.0;

/// Prior 1σ of a sensor's level difference to the first (nT): each sensor's constant is
/// unobservable on its own (a cabin sensor carries ~2,000 nT of the aircraft).
const LEVEL_PRIOR_NT: f32 = 1.0e4;

/// One sensor of the joint run: as calibrated alone and jointly.
#[derive(Clone, Debug)]
pub struct SensorResult {
    pub spec: SensorSpec,
    /// This sensor's own calibration: today's single-sensor filter (`--method kf`), or
    /// TL18-OLS where the default's cross-check kept least squares
    /// ([`checked_against_least_squares`]).
    pub alone: Compensation,
    /// The joint calibration: its coefficient file (the alone file's settings, the joint
    /// coefficients, covariance and predicted error) and per-sample output.
    pub joint: Compensation,
    pub predicted_error_nt: Option<f64>,
    /// The joint estimate is this sensor's result: its predicted error (covariance,
    /// jackknife, model error; no truth) is at most the alone calibration's. Otherwise the
    /// alone calibration is kept, with a warning ([`SensorResult::chosen`]).
    pub joint_chosen: bool,
    /// What the sensor's own lever arm does on this flight ([`super::lever`]): beyond the
    /// noise its alone calibration allowed for, that calibration's predicted error is a
    /// lower bound (its warnings say so).
    pub lever_arm: Option<LeverArm>,
    /// Error against the simulator's truth (nT rms, mean removed), alone and joint.
    pub truth_error_alone_nt: Option<f64>,
    pub truth_error_joint_nt: Option<f64>,
}

impl SensorResult {
    /// The result kept for this sensor: the joint one, or the alone one where the flight's
    /// own evidence says the joint one is worse.
    pub fn chosen(&self) -> &Compensation {
        if self.joint_chosen {
            &self.joint
        } else {
            &self.alone
        }
    }

    /// Its predicted error (nT).
    pub fn chosen_predicted_nt(&self) -> Option<f64> {
        if self.joint_chosen {
            self.predicted_error_nt
        } else {
            self.alone.coefficients.as_ref()?.predicted_error_nt
        }
    }

    /// The kept predicted error is a lower bound: the alone calibration is kept and its
    /// lever arm's signal exceeds the noise it allowed for.
    pub fn chosen_predicted_is_lower_bound(&self) -> bool {
        !self.joint_chosen && self.lever_arm.is_some_and(|l| l.exceeds_noise())
    }

    /// Its error against the simulator's truth (nT).
    pub fn chosen_truth_error_nt(&self) -> Option<f64> {
        if self.joint_chosen {
            self.truth_error_joint_nt
        } else {
            self.truth_error_alone_nt
        }
    }
}

/// The joint run over all sensors.
#[derive(Clone, Debug)]
pub struct JointResult {
    pub sensors: Vec<SensorResult>,
    /// Per sensor, its flight (sensor 0's carries the shared track).
    pub flights: Vec<Flight>,
    pub sigma1: f64,
    /// The jackknife figure of each sensor (nT), included in its predicted error.
    pub jackknife_nt: Vec<Option<f64>>,
}

/// What the joint filter needs of each sensor, prepared once for every pass.
struct Prepared {
    specs: Vec<ModelSpec>,
    /// Per sensor, per sample: every term's regressors (model order, physical units).
    regs: Vec<Vec<Vec<f32>>>,
    /// Per sensor: which regressors are interference (the rest: environment terms).
    interference: Vec<Vec<bool>>,
    prior_mean: Vec<Vec<f32>>,
    prior_sigma: Vec<Vec<f32>>,
    /// Per sensor, per sample: the scalar relative to its first value, core-field change
    /// removed (NaN: no update).
    z: Vec<Vec<f64>>,
    /// Per sample (shared): track step and height above h0.
    ds_m: Vec<f32>,
    dh_m: Vec<f32>,
    noise_nt: Vec<f64>,
    /// Per sensor, per sample: where it is relative to sensor 0.
    places: Vec<Vec<Placement>>,
    lateral: Option<LateralGradient>,
    held: Vec<Vec<Vec<f32>>>,
    field: FieldProcess,
    /// Per-sample multiplier of the field's process noise (the anomaly process chosen by
    /// the joint innovation likelihood; 1 = stationary).
    field_profile: Vec<f64>,
}

/// One forward pass: final coefficients and their covariance per sensor, per-sample anomaly
/// and innovation per sensor.
struct Pass {
    coefficients: Vec<Vec<f64>>,
    covariance: Vec<Vec<f64>>,
    anomaly: Vec<Vec<f64>>,
    innovation: Vec<Vec<f64>>,
    healthy: bool,
    /// Innovation negative log-likelihood of the pass (Σ ν²/s + ln s over the updates).
    nll: f64,
}

fn alone_settings(est: &EstimatorSettings) -> EstimatorSettings {
    EstimatorSettings {
        method: Method::Kf,
        cross_check: false,
        ..est.clone()
    }
}

/// Calibrates `sensors` of `trace` alone and together.
pub fn calibrate_joint(
    trace: &Trace,
    est: &EstimatorSettings,
    sensors: &[SensorSpec],
) -> Result<JointResult> {
    if sensors.len() < 2 || sensors.len() > MAX_SENSORS {
        bail!(
            "a joint calibration takes 2 to {MAX_SENSORS} sensors (--sensors names {})",
            sensors.len()
        );
    }
    let alone = calibrate_alone(trace, est, sensors)?;
    let files: Vec<CoefficientFile> = alone
        .iter()
        .map(|(_, c, _)| c.coefficients.clone().context("no coefficients"))
        .collect::<Result<_>>()?;
    let flights = prepare_flights(&alone, &files, est)?;
    let mut prepared = prepare(&flights, &files, sensors)?;
    // Each sensor's noise stays its alone calibration's: raising it to the robust joint
    // innovation rms (as the single-sensor run adapts its own) took a 300 m flight with
    // sensors 1 m apart from 0.02 to 19 nT.
    let label = choose_field_process(&mut prepared, &flights[0], &alone[0].1)?;
    let full = pass(&prepared, None)?;
    let refits = jackknife_refits(&prepared, &flights[0], sensors.len())?;
    let kept: Vec<&Compensation> = alone
        .iter()
        .map(|(_, c, w)| w.as_ref().unwrap_or(c))
        .collect();
    let levers = lever_arms(&flights, &kept, sensors);
    let mut results = Vec::new();
    let mut jackknife_nt = Vec::new();
    for (j, ((trace_j, alone_j, witnessed_j), s)) in alone.into_iter().zip(sensors).enumerate() {
        let flight = &flights[j];
        let evidence = SensorEvidence::of(&prepared, j, &refits[j], flight);
        jackknife_nt.push(evidence.jackknife_nt);
        let (joint, predicted) = joint_compensation(
            &full,
            j,
            evidence,
            flight,
            &files[j],
            (prepared.field.sigma1 as f64, &label),
            &s.name,
        );
        // The witnessed calibration, where there is one, is the sensor's own candidate.
        let alone_j = witnessed_j.unwrap_or(alone_j);
        let alone_predicted = alone_j
            .coefficients
            .as_ref()
            .and_then(|c| c.predicted_error_nt);
        let mut r = choose_result(s, alone_j, joint, predicted, alone_predicted, flight);
        if est.cross_check {
            checked_against_least_squares(&mut r, &trace_j, est, flight)?;
        }
        r.lever_arm = levers[j];
        if let Some(l) = levers[j].filter(LeverArm::exceeds_noise) {
            r.alone.warnings.push(l.warning(&s.name));
        }
        results.push(r);
    }
    Ok(JointResult {
        sensors: results,
        flights,
        sigma1: prepared.field.sigma1 as f64,
        jackknife_nt,
    })
}

/// Each sensor alone: its trace, today's single-sensor calibration (`--method kf`) of it,
/// which the joint run starts from, and, where the sensor's fluxgate is a decisive witness
/// of its interference, that calibration with `fluxmod` added
/// (`calibration::fluxgate_witness`), which competes with the joint one.
type Alone = (Trace, Compensation, Option<Compensation>);

fn calibrate_alone(
    trace: &Trace,
    est: &EstimatorSettings,
    sensors: &[SensorSpec],
) -> Result<Vec<Alone>> {
    let est1 = alone_settings(est);
    let mut alone = Vec::new();
    for s in sensors {
        let t = sensor_trace(trace, s);
        let run = compensate_trace(&t, &est1, None, false)
            .with_context(|| format!("{} alone", s.name))?;
        // As the single-sensor default: `--method kf` keeps the model as given.
        let witness = if est.cross_check {
            fluxgate_witness::consider(&t, &est1, &run, &est1.model)
                .with_context(|| format!("{} alone, with its fluxgate as a witness", s.name))?
        } else {
            fluxgate_witness::Witness::default()
        };
        let mut comp = run.1;
        // The note goes with the calibration the sensor is offered.
        let witnessed = match witness.kept {
            Some((_, mut kept)) => {
                kept.warnings.extend(witness.note);
                Some(kept)
            }
            None => {
                comp.warnings.extend(witness.note);
                None
            }
        };
        alone.push((t, comp, witnessed));
    }
    Ok(alone)
}

/// Per sensor, the coefficients of the joint pass refitted with each jackknife block left
/// out: the flight's own evidence, as the single-sensor calibration (model.md §5b).
fn jackknife_refits(
    prepared: &Prepared,
    flight0: &Flight,
    sensors: usize,
) -> Result<Vec<Vec<Vec<f64>>>> {
    let span = crate::estimate::excitation::airborne_span(flight0);
    let blocks = crate::estimate::jackknife::blocks(&span, flight0.sample_rate_hz);
    let mut refits: Vec<Vec<Vec<f64>>> = vec![Vec::new(); sensors];
    for b in blocks.iter().flatten() {
        let p = pass(prepared, Some(b.clone()))?;
        for (j, c) in p.coefficients.into_iter().enumerate() {
            refits[j].push(c);
        }
    }
    Ok(refits)
}

/// What one sensor's regressors and jackknife refits say of its joint coefficients.
struct SensorEvidence {
    /// Per sample: the sensor's regressors with the environment terms' zeroed.
    interf_regs: Vec<Vec<f32>>,
    spread: Option<RegressorSpread>,
    /// The refits' covariance (None with fewer than two refits).
    jackknife_cov: Option<Vec<f64>>,
    jackknife_nt: Option<f64>,
    band_jackknife_nt: Option<f64>,
}

impl SensorEvidence {
    fn of(prepared: &Prepared, j: usize, refits: &[Vec<f64>], flight: &Flight) -> Self {
        let interf_regs: Vec<Vec<f32>> = prepared.regs[j]
            .iter()
            .map(|r| {
                r.iter()
                    .zip(&prepared.interference[j])
                    .map(|(v, i)| if *i { *v } else { 0.0 })
                    .collect()
            })
            .collect();
        let spread = RegressorSpread::of(&interf_regs);
        let jackknife_cov =
            (refits.len() >= 2).then(|| crate::estimate::jackknife::covariance(refits));
        let jackknife_nt = jackknife_cov
            .as_ref()
            .and_then(|c| spread.as_ref()?.sigma_nt(c));
        let band_jackknife_nt = (refits.len() >= 2)
            .then(|| {
                let series: Vec<Vec<f64>> = refits
                    .iter()
                    .map(|c| interference_of(&interf_regs, c))
                    .collect();
                crate::estimate::jackknife::band_sigma_nt(flight, &series)
            })
            .flatten();
        Self {
            interf_regs,
            spread,
            jackknife_cov,
            jackknife_nt,
            band_jackknife_nt,
        }
    }
}

/// Sensor `j`'s joint calibration (its alone file's settings with the joint coefficients,
/// covariance and predicted error) applied to its flight, and that predicted error.
/// `field` is the joint σ1 and the anomaly process's label.
fn joint_compensation(
    full: &Pass,
    j: usize,
    evidence: SensorEvidence,
    flight: &Flight,
    alone_file: &CoefficientFile,
    (sigma1, label): (f64, &str),
    name: &str,
) -> (Compensation, Option<f64>) {
    let SensorEvidence {
        interf_regs,
        spread,
        jackknife_cov,
        jackknife_nt: jk,
        band_jackknife_nt: band_jk,
    } = evidence;
    let k = full.coefficients[j].len();
    let mut cov = full.covariance[j].clone();
    if let Some(c) = &jackknife_cov {
        for (a, b) in cov.iter_mut().zip(c) {
            *a += b;
        }
    }
    let cov_sigma = spread
        .as_ref()
        .and_then(|s| s.sigma_nt(&full.covariance[j]));
    let model_error = alone_file.model_error_nt.unwrap_or(0.0);
    let predicted =
        cov_sigma.map(|c| (c * c + jk.unwrap_or(0.0).powi(2) + model_error * model_error).sqrt());
    let interference_nt = interference_of(&interf_regs, &full.coefficients[j]);
    let compensated_nt: Vec<f64> = flight
        .mag_nt
        .iter()
        .zip(&interference_nt)
        .map(|(m, i)| m - i)
        .collect();
    let mut file = alone_file.clone();
    for (c, (v, i)) in file
        .coefficients
        .iter_mut()
        .zip(full.coefficients[j].iter().zip(0..k))
    {
        c.value = *v;
        c.sigma = cov[i * k + i].max(0.0).sqrt();
    }
    file.covariance = Some(cov.chunks(k).map(<[f64]>::to_vec).collect());
    file.sigma1 = Some(sigma1);
    file.predicted_error_nt = predicted;
    file.cross_check = None;
    file.rate_crossover = None;
    file.field_process = Some(label.to_string());
    let own_band = crate::qc::figures::band_rms_nt(flight, &compensated_nt);
    file.predicted_band_rms_nt = band_jk
        .filter(|_| own_band.is_finite())
        .map(|b| own_band.hypot(b));
    let mut warnings = Vec::new();
    if !full.healthy {
        warnings.push(format!(
            "{name}: the joint filter's covariance lost positive definiteness"
        ));
    }
    let joint = Compensation {
        model: file.model.clone(),
        method: Some(Method::Kf),
        interference_nt,
        compensated_nt,
        anomaly_nt: Some(full.anomaly[j].clone()),
        innovation_nt: Some(full.innovation[j].clone()),
        flags: None,
        interference_sigma_nt: None,
        coefficients: Some(file),
        regressors: interf_regs,
        warnings,
        jackknife_nt: jk,
        band_jackknife_nt: band_jk,
        holdout_band_nt: None,
        refit_inflation: None,
        withheld: None,
    };
    (joint, predicted)
}

/// The default for several sensors checks each sensor's kept calibration against TL18-OLS
/// as the one-sensor default does (issue 17: never worse than classic Tolles–Lawson after
/// landing): where the flight's evidence trusts least squares more, its set is the
/// sensor's own (`alone`), with the cross-check's warning.
fn checked_against_least_squares(
    r: &mut SensorResult,
    trace: &Trace,
    est: &EstimatorSettings,
    flight: &Flight,
) -> Result<()> {
    let (_, checked) = cross_checked(trace, est, (flight.clone(), r.chosen().clone()))
        .with_context(|| format!("{}: the TL18-OLS cross-check", r.spec.name))?;
    if checked.method == Some(Method::Tl) {
        r.truth_error_alone_nt = flight
            .truth_interference_nt
            .as_ref()
            .map(|t| crate::qc::truth::error_rms_nt(&checked.interference_nt, t, None));
        r.alone = checked;
        r.joint_chosen = false;
    }
    Ok(())
}

/// The sensor's result: the joint calibration where its predicted error is at most the
/// alone one's, else the alone one with a warning saying why.
fn choose_result(
    s: &SensorSpec,
    mut alone: Compensation,
    joint: Compensation,
    predicted: Option<f64>,
    alone_predicted: Option<f64>,
    flight: &Flight,
) -> SensorResult {
    let truth = flight.truth_interference_nt.as_ref();
    let err = |i: &[f64]| truth.map(|t| crate::qc::truth::error_rms_nt(i, t, None));
    let truth_error_alone_nt = err(&alone.interference_nt);
    let truth_error_joint_nt = err(&joint.interference_nt);
    let joint_chosen = match (predicted, alone_predicted) {
        (Some(p), Some(a)) => p <= a,
        (Some(_), None) => true,
        _ => false,
    };
    if !joint_chosen {
        alone.warnings.push(format!(
            "{}: the joint calibration predicts {} nT against {} nT alone: the sensor's \
             own calibration is kept (the anomaly differences between the sensors hold \
             more than the joint model describes)",
            s.name,
            predicted.map_or("?".into(), |p| format!("{p:.4}")),
            alone_predicted.map_or("?".into(), |p| format!("{p:.4}")),
        ));
    }
    SensorResult {
        joint_chosen,
        lever_arm: None,
        spec: s.clone(),
        alone,
        joint,
        predicted_error_nt: predicted,
        truth_error_alone_nt,
        truth_error_joint_nt,
    }
}

/// Each sensor's flight as its alone calibration saw it: assumed speed, its pre-processing
/// (`lag`, `fluxtemp`) and fluxgate calibration applied.
fn prepare_flights(
    alone: &[Alone],
    files: &[CoefficientFile],
    est: &EstimatorSettings,
) -> Result<Vec<Flight>> {
    let mut flights = Vec::new();
    for ((t, _, _), file) in alone.iter().zip(files) {
        let spec = ModelSpec::parse(&file.model)?;
        let mut f = Flight::from_trace(t, &spec.channels(), &spec.relative_channels())?;
        if spec.field && !f.has_track() {
            let (v, _) = crate::flight::input::assumed_ground_speed(
                est.speed_mps.or(file.assumed_speed_mps),
            )?;
            f.assume_ground_speed(v);
        }
        let prep = crate::model::corrections::Preprocessing {
            scalar_lag: file.scalar_lag,
            fluxgate_temperature: file.fluxgate_temperature.clone(),
        };
        let mut f = crate::estimate::corrections::apply_to_flight(&f, &prep)?;
        if let Some(c) = &file.fluxgate_calibration {
            f = crate::estimate::fluxcal::calibrated_flight(&f, c);
        }
        flights.push(f);
    }
    let n = flights[0].len();
    if flights.iter().any(|f| f.len() != n) {
        bail!("internal: the sensors' flights differ in length");
    }
    Ok(flights)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    }
}

fn prepare(
    flights: &[Flight],
    files: &[CoefficientFile],
    sensors: &[SensorSpec],
) -> Result<Prepared> {
    let rate = flights[0].sample_rate_hz;
    let cfg = CompensatorConfig::for_rate(rate as f32);
    let field = shared_field(files, &cfg)?;
    let mut specs = Vec::new();
    let mut regs = Vec::new();
    let mut interference = Vec::new();
    let mut prior_mean = Vec::new();
    let mut prior_sigma = Vec::new();
    let mut z = Vec::new();
    let mut held = Vec::new();
    let (mut ds_m, mut dh_m) = (Vec::new(), Vec::new());
    for (j, (flight, file)) in flights.iter().zip(files).enumerate() {
        let rows = SensorRows::of(flight, file, rate)?;
        if j == 0 {
            (ds_m, dh_m) = (rows.ds_m, rows.dh_m);
        }
        specs.push(rows.spec);
        regs.push(rows.regs);
        interference.push(rows.interference);
        prior_mean.push(rows.prior_mean);
        prior_sigma.push(rows.prior_sigma);
        z.push(rows.z);
        held.push(rows.held);
    }
    let offsets_m = body_offsets_m(sensors);
    let places = placements(&flights[0], &offsets_m);
    // The cross-track gradient: as large as the along-track one's scale g, wandering by
    // about g over the field's correlation length L (a random walk of g²/L per metre).
    let lateral = offsets_m.iter().any(|o| o[1].abs() > 0.1).then(|| {
        let g = field.scale[1];
        LateralGradient {
            prior_nt_per_m: g,
            q_nt2_per_m3: g * g / cfg.field_length_m,
        }
    });
    Ok(Prepared {
        specs,
        regs,
        interference,
        prior_mean,
        prior_sigma,
        z,
        ds_m,
        dh_m,
        noise_nt: files.iter().map(|f| f.noise_nt.unwrap_or(0.02)).collect(),
        places,
        lateral,
        held,
        field,
        field_profile: vec![1.0; flights[0].len()],
    })
}

/// The one anomaly's process: its roughness is the geology's. Each sensor's own σ1 also
/// holds what its model lacks; the median of them is taken.
fn shared_field(files: &[CoefficientFile], cfg: &CompensatorConfig) -> Result<FieldProcess> {
    let sigma1 = median(files.iter().filter_map(|f| f.sigma1).collect());
    if !(sigma1.is_finite() && sigma1 > 0.0) {
        bail!("the sensors' calibrations gave no σ1");
    }
    Ok(FieldProcess::new(
        sigma1 as f32,
        (0.1 * sigma1) as f32,
        cfg.field_length_m,
        cfg.bh_prior_nt,
    ))
}

/// Body offsets from sensor 0; an unknown position is [`UNKNOWN_SEPARATION_M`] to
/// starboard.
fn body_offsets_m(sensors: &[SensorSpec]) -> Vec<[f64; 3]> {
    let p0 = sensors[0].position_m;
    sensors
        .iter()
        .enumerate()
        .map(|(j, s)| match (p0, s.position_m) {
            _ if j == 0 => [0.0; 3],
            (Some(a), Some(b)) => [b[0] - a[0], b[1] - a[1], b[2] - a[2]],
            _ => [0.0, UNKNOWN_SEPARATION_M, 0.0],
        })
        .collect()
}

/// One sensor's part of [`Prepared`], from its flight and its alone calibration's model.
struct SensorRows {
    spec: ModelSpec,
    regs: Vec<Vec<f32>>,
    interference: Vec<bool>,
    prior_mean: Vec<f32>,
    prior_sigma: Vec<f32>,
    z: Vec<f64>,
    held: Vec<Vec<f32>>,
    /// Its track step and height above h0 per sample (sensor 0's are the shared ones).
    ds_m: Vec<f32>,
    dh_m: Vec<f32>,
}

impl SensorRows {
    fn of(flight: &Flight, file: &CoefficientFile, rate: f64) -> Result<Self> {
        let spec = ModelSpec::parse(&file.model)?;
        let epochs = epochs_of(flight, rate)?;
        let ModelRows {
            regs,
            interference,
            prior_mean,
            prior_sigma,
        } = model_rows(&spec, &epochs);
        let rel = crate::flight::scalar_relative_nt(flight);
        let z: Vec<f64> = epochs
            .iter()
            .zip(rel)
            .map(|(ep, v)| {
                let on_ground = ep.reported_speed_mps < GROUND_SPEED_MPS;
                if ep.dmag_nt.is_finite() && !ep.regressors_suspect && !on_ground {
                    v
                } else {
                    f64::NAN
                }
            })
            .collect();
        // The combinations this flight's manoeuvres leave undetermined are held at the
        // prior, as in the single-sensor calibration (estimate::excitation).
        let span = crate::estimate::excitation::airborne_span(flight);
        let ps64: Vec<f64> = prior_sigma.iter().map(|v| *v as f64).collect();
        let held = crate::estimate::excitation::unexcited_combinations(
            flight,
            &regs[span],
            &ps64,
            &interference,
        );
        Ok(Self {
            spec,
            ds_m: epochs.iter().map(|e| e.ds_m).collect(),
            dh_m: epochs.iter().map(|e| e.dh_m).collect(),
            regs,
            interference,
            prior_mean,
            prior_sigma,
            z,
            held,
        })
    }
}

/// The flight's epochs, one per sample (the builder flushed at the end).
fn epochs_of(flight: &Flight, rate: f64) -> Result<Vec<Epoch>> {
    let epoch_cfg = EpochConfig {
        earth_dir_ned: flight.earth_dir_ned,
        ..EpochConfig::for_rate(rate as f32)
    };
    let mut builder = EpochBuilder::<{ crate::estimate::kf::HOST_WINDOW }>::new(epoch_cfg)
        .context("internal: epoch builder")?;
    let mut epochs = Vec::with_capacity(flight.len());
    for s in &flight.samples {
        epochs.extend(builder.push(s));
    }
    while let Some(e) = builder.flush() {
        epochs.push(e);
    }
    if epochs.len() != flight.len() {
        bail!(
            "internal: {} epochs for {} samples",
            epochs.len(),
            flight.len()
        );
    }
    Ok(epochs)
}

/// The model's regressors per epoch (model order, physical units), which of them are
/// interference, and the terms' prior means and 1σ.
struct ModelRows {
    regs: Vec<Vec<f32>>,
    interference: Vec<bool>,
    prior_mean: Vec<f32>,
    prior_sigma: Vec<f32>,
}

fn model_rows(spec: &ModelSpec, epochs: &[Epoch]) -> ModelRows {
    with_model(spec, |model| {
        let k = model.coefficient_count();
        let mut buf = vec![0.0f32; k];
        let rows: Vec<Vec<f32>> = epochs
            .iter()
            .map(|ep| {
                let mut at = 0;
                for t in model.terms {
                    let l = t.len();
                    t.regressors(ep, &mut buf[at..at + l]);
                    at += l;
                }
                buf.clone()
            })
            .collect();
        let mask: Vec<bool> = model
            .terms
            .iter()
            .flat_map(|t| std::iter::repeat_n(t.is_interference(), t.len()))
            .collect();
        let pm: Vec<f32> = model
            .terms
            .iter()
            .flat_map(|t| (0..t.len()).map(|i| t.prior_mean(i)))
            .collect();
        let ps: Vec<f32> = model
            .terms
            .iter()
            .flat_map(|t| (0..t.len()).map(|i| t.prior_sigma(i)))
            .collect();
        ModelRows {
            regs: rows,
            interference: mask,
            prior_mean: pm,
            prior_sigma: ps,
        }
    })
}

/// The anomaly process of the joint filter: the stationary one and the local-roughness
/// profiles of the single-sensor calibration ([`crate::estimate::kf::FIELD_PROFILES`],
/// from sensor 0's alone interference), each at the σ1² scales it tries; the one under
/// which the sensors' samples are most likely (joint innovation likelihood) wins. Over
/// strong shallow geology the anomaly is far rougher in places than one σ1 says, and a
/// stationary process let the coefficients take what the field could not follow.
fn choose_field_process(
    p: &mut Prepared,
    flight0: &Flight,
    alone0: &Compensation,
) -> Result<String> {
    use crate::estimate::kf::{field_profile, FIELD_PROFILES, FIELD_PROFILE_SCALES};
    let base = p.field;
    let cfg = CompensatorConfig::for_rate(flight0.sample_rate_hz as f32);
    let noise0 = p.noise_nt[0];
    let mut candidates: Vec<(String, Vec<f64>)> =
        vec![("stationary".into(), vec![1.0; flight0.len()])];
    for (k, prof) in FIELD_PROFILES.iter().enumerate() {
        candidates.push((
            format!("local roughness profile {}", k + 1),
            field_profile(flight0, &alone0.interference_nt, noise0, *prof),
        ));
    }
    let mut best: Option<(f64, String, FieldProcess, Vec<f64>)> = None;
    for (label, profile) in candidates {
        for scale in FIELD_PROFILE_SCALES {
            let s1 = base.sigma1 as f64 * scale.sqrt();
            p.field = FieldProcess::new(
                s1 as f32,
                (0.1 * s1) as f32,
                cfg.field_length_m,
                cfg.bh_prior_nt,
            );
            p.field_profile.clone_from(&profile);
            let nll = pass(p, None)?.nll;
            if nll.is_finite() && best.as_ref().is_none_or(|b| nll < b.0) {
                best = Some((
                    nll,
                    format!("{label}, {scale} × σ1² (joint)"),
                    p.field,
                    profile.clone(),
                ));
            }
        }
    }
    let (_, label, field, profile) = best.context("no anomaly process gave a finite likelihood")?;
    p.field = field;
    p.field_profile = profile;
    Ok(label)
}

/// Each sensor's place relative to sensor 0 at each sample: its body offset turned by the
/// INS attitude (a wingtip rises and falls in a roll), along and across the heading
/// (the track's direction up to the crab angle); without attitude, the offset as it is in
/// level flight.
fn placements(flight: &Flight, offsets_m: &[[f64; 3]]) -> Vec<Vec<Placement>> {
    offsets_m
        .iter()
        .map(|o| {
            let r = nalgebra::Vector3::new(o[0], o[1], o[2]);
            flight
                .samples
                .iter()
                .map(|s| {
                    let [roll, pitch, yaw] = s.attitude_deg.map(|a| (a as f64).to_radians());
                    if !(roll.is_finite() && pitch.is_finite() && yaw.is_finite()) {
                        return Placement {
                            along_m: o[0] as f32,
                            across_m: o[1] as f32,
                            down_m: o[2] as f32,
                        };
                    }
                    let ned = crate::sim::dcm_ned_to_body(roll, pitch, yaw).transpose() * r;
                    let (sy, cy) = yaw.sin_cos();
                    Placement {
                        along_m: (ned[0] * cy + ned[1] * sy) as f32,
                        across_m: (-ned[0] * sy + ned[1] * cy) as f32,
                        down_m: ned[2] as f32,
                    }
                })
                .collect()
        })
        .collect()
}

/// One forward pass of the joint filter; `skip`: samples that predict and do not update
/// (the jackknife's left-out stretch).
fn pass(p: &Prepared, skip: Option<std::ops::Range<usize>>) -> Result<Pass> {
    let s = p.specs.len();
    let sensors: Vec<JointSensor> = (0..s)
        .map(|j| JointSensor {
            prior_mean: &p.prior_mean[j],
            prior_sigma: &p.prior_sigma[j],
            level_prior_nt: LEVEL_PRIOR_NT,
        })
        .collect();
    let mut f: Box<HostJoint> = Box::new(
        HostJoint::new(p.field, p.lateral, &sensors)
            .map_err(|e| anyhow::anyhow!("cannot build the joint filter: {e:?}"))?,
    );
    for (j, ws) in p.held.iter().enumerate() {
        for w in ws {
            if !f.hold_combination(j, w) {
                bail!("internal: a held combination does not fit sensor {j}");
            }
        }
    }
    let n = p.ds_m.len();
    let mut anomaly = vec![vec![f64::NAN; n]; s];
    let mut innovation = vec![vec![f64::NAN; n]; s];
    let mut healthy = true;
    let mut nll = 0.0;
    for i in 0..n {
        f.predict(p.ds_m[i], p.field_profile[i] as f32);
        let skipped = skip.as_ref().is_some_and(|r| r.contains(&i));
        for j in 0..s {
            let z = p.z[j][i];
            let phys = &p.regs[j][i];
            if z.is_finite() && !skipped {
                let r = (p.noise_nt[j] * p.noise_nt[j]) as f32;
                let place = p.places[j][i];
                if let Some(u) = f.update(j, place, p.dh_m[i], phys, z as f32, r, GATE_SIGMA) {
                    innovation[j][i] = match u {
                        Ok(v) => {
                            let (nu, sv) = (v.value as f64, v.variance as f64);
                            nll += nu * nu / sv + sv.ln();
                            nu
                        }
                        Err(v) => v.value as f64,
                    };
                }
            }
            anomaly[j][i] = f.anomaly_nt(j, p.places[j][i], p.dh_m[i]) as f64;
        }
        healthy &= f.filter().is_healthy();
    }
    let mut coefficients = Vec::new();
    let mut covariance = Vec::new();
    for j in 0..s {
        let (_, k) = f.coefficient_block(j);
        let mut c = vec![0.0f32; k];
        f.coefficients(j, &mut c);
        coefficients.push(c.iter().map(|v| *v as f64).collect());
        covariance.push(
            (0..k * k)
                .map(|ab| f.coefficient_covariance(j, ab / k, ab % k) as f64)
                .collect(),
        );
    }
    Ok(Pass {
        coefficients,
        covariance,
        anomaly,
        innovation,
        healthy,
        nll,
    })
}

/// Applies each sensor's coefficients (a joint calibration's, or any) to its columns of
/// `trace`: exactly `compensate --coeffs` on that sensor alone.
pub fn apply_each(
    trace: &Trace,
    est: &EstimatorSettings,
    sensors: &[SensorSpec],
    files: &[CoefficientFile],
) -> Result<Vec<(Flight, Compensation)>> {
    if sensors.len() != files.len() {
        bail!(
            "{} sensors but {} coefficient sets",
            sensors.len(),
            files.len()
        );
    }
    sensors
        .iter()
        .zip(files)
        .map(|(s, f)| {
            compensate_trace(
                &sensor_trace(trace, s),
                &alone_settings(est),
                Some(f),
                false,
            )
            .with_context(|| format!("{} with its coefficients", s.name))
        })
        .collect()
}
