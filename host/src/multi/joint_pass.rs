//! The joint filter's passes (docs/model.md §7): each sensor's flight prepared as its
//! alone calibration saw it, the shared anomaly process chosen, and one forward pass of
//! [`magcomp_core::joint::JointFilter`] over every sensor (optionally with a jackknife
//! block left out).

use super::result::Alone;
use super::sensors::SensorSpec;
use crate::calibration::result::Compensation;
use crate::calibration::{CoefficientFile, EstimatorSettings};
use crate::flight::Flight;
use crate::model::spec::{with_model, ModelSpec};
use anyhow::{bail, Context, Result};
use magcomp_core::compensator::{CompensatorConfig, GROUND_SPEED_MPS};
use magcomp_core::epoch::{Epoch, EpochBuilder, EpochConfig};
use magcomp_core::filter::FieldProcess;
use magcomp_core::joint::{JointFilter, JointSensor, LateralGradient, Placement};

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

/// What the joint filter needs of each sensor, prepared once for every pass.
pub(super) struct Prepared {
    pub(super) specs: Vec<ModelSpec>,
    /// Per sensor, per sample: every term's regressors (model order, physical units).
    pub(super) regs: Vec<Vec<Vec<f32>>>,
    /// Per sensor: which regressors are interference (the rest: environment terms).
    pub(super) interference: Vec<Vec<bool>>,
    pub(super) prior_mean: Vec<Vec<f32>>,
    pub(super) prior_sigma: Vec<Vec<f32>>,
    /// Per sensor, per sample: the scalar relative to its first value, core-field change
    /// removed (NaN: no update).
    pub(super) z: Vec<Vec<f64>>,
    /// Per sample (shared): track step and height above h0.
    pub(super) ds_m: Vec<f32>,
    pub(super) dh_m: Vec<f32>,
    pub(super) noise_nt: Vec<f64>,
    /// Per sensor, per sample: where it is relative to sensor 0.
    pub(super) places: Vec<Vec<Placement>>,
    pub(super) lateral: Option<LateralGradient>,
    pub(super) held: Vec<Vec<Vec<f32>>>,
    pub(super) field: FieldProcess,
    /// Per-sample multiplier of the field's process noise (the anomaly process chosen by
    /// the joint innovation likelihood; 1 = stationary).
    pub(super) field_profile: Vec<f64>,
}

/// One forward pass: final coefficients and their covariance per sensor, per-sample anomaly
/// and innovation per sensor.
pub(super) struct Pass {
    pub(super) coefficients: Vec<Vec<f64>>,
    pub(super) covariance: Vec<Vec<f64>>,
    pub(super) anomaly: Vec<Vec<f64>>,
    pub(super) innovation: Vec<Vec<f64>>,
    pub(super) healthy: bool,
    /// Innovation negative log-likelihood of the pass (Σ ν²/s + ln s over the updates).
    pub(super) nll: f64,
}

/// Each sensor's flight as its alone calibration saw it: assumed speed, its pre-processing
/// (`lag`, `fluxtemp`) and fluxgate calibration applied.
pub(super) fn prepare_flights(
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

pub(super) fn prepare(
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
pub(super) fn choose_field_process(
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
pub(super) fn pass(p: &Prepared, skip: Option<std::ops::Range<usize>>) -> Result<Pass> {
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
