//! Flight simulator behind `magcomp simulate`.
//!
//! Deliberately independent of the compensator's equations, so that it can judge them:
//! - geology = buried point dipoles (induced along the main field + optional remanence):
//!   harmonic in the air by construction; field vector and gradient tensor exact;
//! - main field = tilted centred dipole with IGRF-2020 degree-1 coefficients (or a uniform
//!   F/I/D); `igrf` column = its modulus at the sample;
//! - every scalar is an exact modulus: `mag = |B + ΔB| + noise`, `ΔB = K + L·B + M·dB/dt` in
//!   body axes with the exact dB/dt (analytic attitude rates + exact field gradient · v);
//! - the sensors carry errors the model does not know: fluxgate own field, bias (≈30 nT),
//!   scale (1e-3), misalignment (0.07°), noise (0.5 nT); INS noise (0.03°, correlated);
//!   GPS Gauss–Markov error (1 m / 1.5 m, τ = 60 s) + white noise.
//!
//! Conventions: local flat-earth NED frame at the start point (north/east m, down =
//! −height above sea level), aerospace ZYX attitude, body x forward / y starboard / z down.
//! Truth columns satisfy `mag − noise = igrf + truth_anomaly + truth_diurnal +
//! truth_interference` exactly, each term an exact modulus difference taken in that order.
//! `fluxcal` does not change the scalar, so its column is not part of `truth_interference`.
//! The `broad` physics profile (`physics.rs`, issue 10) widens the aircraft, the fluxgate
//! (which then also sees the aircraft's eddy field), navigation errors, diurnal (no base
//! station) and geology, and writes `igrf` at the GPS position: there `truth_core`
//! takes `igrf`'s place in the identity above.
//!
//! Above 20 Hz the environment field (main + anomaly) is evaluated exactly at 50 ms knots
//! (10 ms on a take-off, which taxis metres from the apron's steel) with its exact time
//! derivative and Hermite-interpolated between them (error < 1e-4 nT, tested), which keeps
//! 20 min at 1 kHz at ~1.5 s in release builds.

pub mod anomaly;
mod config;
pub mod flight;
pub mod geo;
pub mod hidden;
pub mod physics;
mod plan;
pub mod signals;
pub mod takeoff;
mod world;

pub use anomaly::{Anomaly, Dipole, Geology, GeologyPreset};
pub use config::{FlightKind, SimConfig};
pub use flight::{KinState, Plan};
pub use geo::{EarthField, LocalFrame};
pub use hidden::{parse_hidden, HiddenEffect, HiddenKind};
pub use physics::Physics;
use plan::build_plan;
use world::*;

use crate::io::trace::Trace;
use anyhow::{ensure, Result};
use flight::{heading_tag, Builder, Manoeuvre};
use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, StandardNormal, UnitSphere};
use signals::{gauss_markov, CurrentWave, RpmWave, SineSum, SmoothWalk, TempWave};
use std::f64::consts::TAU;

/// Ground truth behind a simulated trace, for tests and scoring.
#[derive(Clone, Debug)]
pub struct SimTruth {
    pub plan: Plan,
    pub frame: LocalFrame,
    /// Every Earth-side source: the geology, then the apron's (take-off).
    pub anomaly: Anomaly,
    /// The apron's steel (take-off; empty otherwise), also in `anomaly`.
    pub apron: Anomaly,
    /// The take-off's engine start (its field is in `truth_hidden_engine`, not `delta_b_nt`).
    pub engine: Option<takeoff::EngineStart>,
    pub ground_elev_m: f64,
    pub k_nt: Vector3<f64>,
    pub l: Matrix3<f64>,
    pub m_s: Matrix3<f64>,
    /// Per sample: true sensor position (local NED, m), true attitude (roll, pitch, yaw rad),
    /// external field in body axes (nT) and its exact time derivative (nT/s),
    /// the aircraft field ΔB = K + L·B + M·dB/dt (nT), and the noise-free scalar (nT).
    pub pos_ned_m: Vec<Vector3<f64>>,
    pub att_rad: Vec<[f64; 3]>,
    pub b_body_nt: Vec<Vector3<f64>>,
    pub db_body_nt_s: Vec<Vector3<f64>>,
    pub delta_b_nt: Vec<Vector3<f64>>,
    pub mag_clean_nt: Vec<f64>,
}

pub struct SimOutput {
    pub trace: Trace,
    pub truth: SimTruth,
}

/// Simulates a flight and returns the recorded trace (see `trace-format.md`).
pub fn simulate(cfg: &SimConfig) -> Result<Trace> {
    Ok(simulate_detailed(cfg)?.trace)
}

pub(crate) fn rng_for(seed: u64, stream: u64) -> ChaCha8Rng {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    r.set_stream(stream);
    r
}

/// Stream id from a name, so adding one effect never changes another's random draws.
pub(crate) fn stream_of(name: &str) -> u64 {
    name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    }) | (1 << 40)
}

/// Direction cosine matrix NED → body for aerospace ZYX angles.
pub fn dcm_ned_to_body(roll: f64, pitch: f64, yaw: f64) -> Matrix3<f64> {
    let (sr, cr) = roll.sin_cos();
    let (sp, cp) = pitch.sin_cos();
    let (sy, cy) = yaw.sin_cos();
    Matrix3::new(
        cp * cy,
        cp * sy,
        -sp,
        sr * sp * cy - cr * sy,
        sr * sp * sy + cr * cy,
        sr * cp,
        cr * sp * cy + sr * sy,
        cr * sp * sy - sr * cy,
        cr * cp,
    )
}

/// Simulates a flight and also returns the ground truth behind it.
pub fn simulate_detailed(cfg: &SimConfig) -> Result<SimOutput> {
    cfg.validate()?;
    let cfg: &SimConfig = &takeoff::with_engine(cfg);
    let seed = cfg.seed;
    let frame = LocalFrame {
        lat0_deg: cfg.start_lat_deg,
        lon0_deg: cfg.start_lon_deg,
    };
    let plan = build_plan(cfg, &mut rng_for(seed, 1))?;
    let mut dur = plan.duration_s();
    if let Some(m) = cfg.max_duration_s {
        dur = dur.min(m);
    }
    let rate = cfg.sample_rate_hz;
    let dt = 1.0 / rate;
    let n = (dur * rate).floor() as usize;
    ensure!(n >= 2, "the flight is too short");
    ensure!(
        n <= 8_000_000,
        "{n} samples is more than this simulator holds in memory (8 M ≈ 4 GB; 2.2 h at 1 kHz)"
    );
    let times: Vec<f64> = (0..n).map(|k| k as f64 * dt).collect();

    // Horizontal track: trapezoid on the analytic velocity with ≤ 5 ms sub-steps.
    let sub = (dt / 0.005).ceil().max(1.0) as usize;
    let hs = dt / sub as f64;
    let mut ne = Vec::with_capacity(n);
    let mut p = plan.start_ne_m;
    let mut vel = plan.velocity(0.0);
    for (k, &t) in times.iter().enumerate() {
        if k > 0 {
            for j in 0..sub {
                let ta = t - dt + j as f64 * hs;
                let v1 = plan.velocity(ta + hs);
                p[0] += 0.5 * hs * (vel[0] + v1[0]);
                p[1] += 0.5 * hs * (vel[1] + v1[1]);
                vel = v1;
            }
        }
        ne.push(p);
    }
    let pos_ned: Vec<Vector3<f64>> = times
        .iter()
        .zip(&ne)
        .map(|(&t, p)| Vector3::new(p[0], p[1], -(cfg.ground_elev_m + plan.height(t).0)))
        .collect();

    // Earth field direction at the start: induced magnetisation and diurnal direction.
    let be0 = cfg
        .earth
        .field_ned_nt(cfg.start_lat_deg, cfg.start_lon_deg, cfg.ground_elev_m);
    let e0 = be0.normalize();

    // Geology under the flight, with a margin that reaches the sources that matter.
    let (mut n0, mut n1, mut e0m, mut e1m) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    let mut hmax: f64 = 0.0;
    for p in &pos_ned {
        n0 = n0.min(p.x);
        n1 = n1.max(p.x);
        e0m = e0m.min(p.y);
        e1m = e1m.max(p.y);
        hmax = hmax.max(-p.z - cfg.ground_elev_m);
    }
    let margin = (2.0 * (hmax + cfg.geology.depth_max_m)).clamp(2000.0, 15_000.0);
    let anomaly = Anomaly::generate(
        &cfg.geology,
        ([n0 - margin, n1 + margin], [e0m - margin, e1m + margin]),
        cfg.ground_elev_m,
        e0,
        &mut rng_for(seed, 2),
    );

    // Field track at knots.
    let q = (rate / takeoff::knot_rate_hz(cfg)).ceil().max(1.0) as usize;
    let mut knots: Vec<usize> = (0..n).step_by(q).collect();
    if *knots.last().unwrap_or(&0) != n - 1 {
        knots.push(n - 1);
    }
    let mut field = FieldTrack {
        t: Vec::with_capacity(knots.len()),
        be: Vec::with_capacity(knots.len()),
        dbe: Vec::with_capacity(knots.len()),
        ba: Vec::with_capacity(knots.len()),
        dba: Vec::with_capacity(knots.len()),
        dt_knot: q as f64 * dt,
    };
    let earth_at = |p: &Vector3<f64>| {
        let (lat, lon) = frame.to_geo(p.x, p.y);
        cfg.earth.field_ned_nt(lat, lon, -p.z)
    };
    for &k in &knots {
        let t = times[k];
        let p = pos_ned[k];
        let v = plan.velocity(t);
        let v_ned = Vector3::new(v[0], v[1], -v[2]);
        // The main field changes over thousands of km: a ±0.5 s difference is exact.
        let dbe = (earth_at(&(p + v_ned * 0.5)) - earth_at(&(p - v_ned * 0.5))) / 1.0;
        let (ba, ga) = anomaly.field_and_gradient(&p);
        field.t.push(t);
        field.be.push(earth_at(&p));
        field.dbe.push(dbe);
        field.ba.push(ba);
        field.dba.push(ga * v_ned);
    }
    // The field is linear in the moments, so scaling them scales the track exactly.
    let mut anomaly = anomaly;
    if let Some(target) = cfg.anomaly_pp_nt {
        let tmi = |k: usize| (field.be[k] + field.ba[k]).norm() - field.be[k].norm();
        let (lo, hi) = (0..field.t.len()).fold((f64::MAX, f64::MIN), |(a, b), k| {
            let v = tmi(k);
            (a.min(v), b.max(v))
        });
        if hi > lo {
            let f = target / (hi - lo);
            field.ba.iter_mut().for_each(|v| *v *= f);
            field.dba.iter_mut().for_each(|v| *v *= f);
            anomaly.sources.iter_mut().for_each(|s| s.moment_am2 *= f);
        }
    }
    let apron = takeoff::add_apron(&mut field, &mut anomaly, &plan, &knots, &pos_ned, e0, cfg);

    let (diurnal, micro) = diurnal_draws(cfg, dur);

    // Aircraft (Cessna Caravan-like). Permanent K: ~10–60 nT per axis; induced L: a few
    // 1e-4 (×50 000 nT → tens of nT); eddy M: ~1e-4 s (×~1e4 nT/s in a 5° manoeuvre → ~1 nT).
    let mut ra = rng_for(seed, 4);
    let ifs = cfg.interference_scale;
    let sign = |r: &mut ChaCha8Rng| if r.gen_bool(0.5) { 1.0 } else { -1.0 };
    let k = Vector3::from_fn(|_, _| sign(&mut ra) * ra.gen_range(10.0..60.0)) * ifs;
    let l = Matrix3::from_fn(|i, j| {
        let w = if i == j { 4e-4 } else { 2e-4 };
        ra.sample::<f64, _>(StandardNormal) * w
    }) * ifs;
    let m = Matrix3::from_fn(|_, _| ra.sample::<f64, _>(StandardNormal) * 6e-5) * ifs;
    let broad = (cfg.physics == Physics::Broad).then(|| {
        let law = physics::broad_aircraft(seed, ifs);
        (law, physics::broad_fluxgate(seed, &law, ifs))
    });
    let (k, l, m) = match &broad {
        Some((law, _)) => (law.k_nt, law.l, law.m_s),
        None => (k, l, m),
    };

    let world = World {
        plan,
        field,
        e0,
        diurnal,
        micro,
        k,
        l,
        m,
    };

    // Pass 1: the instant state at each sample.
    let insts: Vec<Inst> = times.iter().map(|&t| world.inst(t)).collect();

    // Hidden vector effects and auxiliary channels.
    let mut aux: Vec<(String, Vec<f64>)> = Vec::new();
    let mut meta_extra: Vec<(String, String)> = Vec::new();
    let mut vec_effects: Vec<(usize, VecEffect, f64)> = Vec::new(); // (hidden idx, law, scale)
    let mut lag: Option<(usize, f64)> = None;
    let mut fluxcal: Option<usize> = None;
    let mut fluxtemp: Option<(usize, hidden::FluxTempDrift)> = None;
    for (hi, h) in cfg.hidden.iter().enumerate() {
        let mut r = rng_for(seed, stream_of(&h.name()));
        let eff = match &h.kind {
            HiddenKind::Current { channel } | HiddenKind::CurrentRate { channel } => {
                let wave = CurrentWave::random(dur, &mut r);
                aux.push((
                    channel.clone(),
                    times.iter().map(|&t| wave.eval(t).0).collect(),
                ));
                Some(VecEffect::Current {
                    dir: random_dir(&mut r),
                    wave,
                    rate: matches!(h.kind, HiddenKind::CurrentRate { .. }),
                })
            }
            HiddenKind::Periodic { channel } => {
                let rpm = RpmWave::random(&mut r);
                aux.push((channel.clone(), times.iter().map(|&t| rpm.rpm(t)).collect()));
                Some(VecEffect::Periodic {
                    dir: random_dir(&mut r),
                    rpm,
                    phase: [r.gen_range(0.0..TAU), r.gen_range(0.0..TAU)],
                    h2: r.gen_range(0.2..0.5),
                })
            }
            HiddenKind::Rate => {
                // N (s): not scaled to a target std, 0.01–0.03 s on the diagonal, so the term
                // is ~1 nT only where d|B|/dt is tens of nT/s (low over strong sources). This
                // is a deliberately exaggerated *extra* eddy path: the airframe's own eddy
                // response to flying through gradients is already in every flight through
                // `M·dB/dt` (db_body includes the anomaly gradient · velocity), and M is only
                // ~6e-5–1e-4 s, i.e. ~0.001 nT here. Even at this size `rate` is not
                // observable on a calibration pattern alone, only at the crossovers of a
                // survey with tie lines (tests/diagnose_effects.rs).
                let mut nm = Matrix3::from_fn(|_, _| r.sample::<f64, _>(StandardNormal) * 0.008);
                nm = (nm + nm.transpose()) / 2.0;
                for i in 0..3 {
                    nm[(i, i)] = sign(&mut r) * r.gen_range(0.01..0.03);
                }
                meta_extra.push(("truth_N_s".into(), json_mat(&nm)));
                Some(VecEffect::Rate { n: nm })
            }
            HiddenKind::InducedHigh => {
                let c: [f64; 10] = std::array::from_fn(|_| r.sample::<f64, _>(StandardNormal));
                Some(VecEffect::InducedHigh { c })
            }
            HiddenKind::Lag { lag_s } => {
                lag = Some((hi, *lag_s));
                None
            }
            HiddenKind::FluxCal => {
                fluxcal = Some(hi);
                None
            }
            HiddenKind::FluxTemp {
                channel,
                max_nt_per_degc,
            } => {
                let drift = hidden::FluxTempDrift::random(*max_nt_per_degc, &mut r);
                // Recorded with 0.01 °C noise; the drift follows the true temperature.
                aux.push((
                    channel.clone(),
                    times
                        .iter()
                        .map(|&t| drift.temp.eval(t).0 + 0.01 * r.sample::<f64, _>(StandardNormal))
                        .collect(),
                ));
                meta_extra.push((
                    "truth_fluxtemp_bias_nt_per_degc".into(),
                    json_vec(&drift.bias_nt_per_degc),
                ));
                fluxtemp = Some((hi, drift));
                None
            }
            HiddenKind::Diurnal => None,
            HiddenKind::Engine { channel } => Some(takeoff::engine_effect(
                &world,
                channel.as_deref(),
                &times,
                &mut aux,
                &mut meta_extra,
                &mut r,
            )),
        };
        if let Some(e) = eff {
            vec_effects.push((hi, e, 1.0));
        }
    }
    aux.extend(decoy_channels(cfg, dur, &times));

    // Scale each effect (except the physical `rate`) to the target std inside its window,
    // measured on its projection on the field direction (what the scalar sees).
    for (hi, eff, scale) in vec_effects.iter_mut() {
        let h = &cfg.hidden[*hi];
        let target = match eff {
            VecEffect::Rate { .. } | VecEffect::Engine(_) => continue,
            VecEffect::Periodic { .. } => cfg.hidden_std_nt / 2.0,
            _ => cfg.hidden_std_nt,
        };
        let proj: Vec<f64> = times
            .iter()
            .zip(&insts)
            .filter(|(&t, _)| h.active(t))
            .map(|(&t, i)| {
                let tot = i.b_body + i.delta_b;
                eff.field(t, i).dot(&tot) / tot.norm()
            })
            .collect();
        let sd = std_dev(proj.iter().copied());
        *scale = if sd > 1e-12 { target / sd } else { 0.0 };
        match eff {
            VecEffect::Current { dir, rate, .. } => {
                let key = if *rate { "nt_per_a_per_s" } else { "nt_per_a" };
                meta_extra.push((
                    format!("truth_c_{}_{key}", h.name()),
                    json_vec(&(*dir * *scale)),
                ));
            }
            VecEffect::Periodic { dir, .. } => {
                meta_extra.push((
                    format!("truth_c_{}_nt", h.name()),
                    json_vec(&(*dir * *scale)),
                ));
            }
            _ => {}
        }
    }

    // Noise-free scalar at an instant, with per-effect incremental contributions.
    let scalar_at = |t: f64, i: &Inst, contrib: &mut [f64]| -> f64 {
        let mut tot = i.b_body + i.delta_b;
        let mut prev = tot.norm();
        for (slot, (hi, eff, scale)) in vec_effects.iter().enumerate() {
            if !cfg.hidden[*hi].active(t) {
                contrib[slot] = 0.0;
                continue;
            }
            tot += eff.field(t, i) * *scale;
            let now = tot.norm();
            contrib[slot] = now - prev;
            prev = now;
        }
        prev
    };

    // Pass 2: scalar, interference and hidden contributions.
    let mut mag_clean = vec![0.0; n];
    let mut hid_cols: Vec<Vec<f64>> = vec![vec![0.0; n]; vec_effects.len()];
    let mut lag_col = vec![0.0; n];
    let mut contrib = vec![0.0; vec_effects.len()];
    let mut scratch = vec![0.0; vec_effects.len()];
    for (kk, (&t, i)) in times.iter().zip(&insts).enumerate() {
        let s_now = scalar_at(t, i, &mut contrib);
        for (col, c) in hid_cols.iter_mut().zip(&contrib) {
            col[kk] = *c;
        }
        let mut s = s_now;
        if let Some((hi, lag_s)) = lag {
            if cfg.hidden[hi].active(t) {
                // The sensor reports at t what it measured at t − τ (clamped at the start).
                let tl = (t - lag_s).max(0.0);
                let il = world.inst(tl);
                s = scalar_at(tl, &il, &mut scratch);
                lag_col[kk] = s - s_now;
            }
        }
        mag_clean[kk] = s;
    }

    // Sensors.
    let mut rn = rng_for(seed, 6);
    let mag: Vec<f64> = mag_clean
        .iter()
        .map(|m| m + cfg.scalar_noise_nt * rn.sample::<f64, _>(StandardNormal))
        .collect();

    // Fluxgate: own aircraft field, bias, scale, misalignment, white noise.
    let mut rf = rng_for(seed, 5);
    let kf = Vector3::from_fn(|_, _| rf.sample::<f64, _>(StandardNormal) * 8.0) * ifs;
    let lf = Matrix3::from_fn(|_, _| rf.sample::<f64, _>(StandardNormal) * 5e-5) * ifs;
    let flux_bias = Vector3::from_fn(|_, _| rf.sample::<f64, _>(StandardNormal) * 30.0);
    let flux_scale = Matrix3::from_diagonal(&Vector3::from_fn(|_, _| {
        1.0 + rf.sample::<f64, _>(StandardNormal) * 1e-3
    }));
    let flux_rot = small_rotation(0.07f64.to_radians(), &mut rf);
    // Broad: the aircraft's eddy field reaches the fluxgate too, and its errors are one
    // scale/cross-coupling matrix (rotation = identity) and a 10–50 nT bias.
    let (kf, lf, mf, flux_bias, flux_scale, flux_rot) = match &broad {
        Some((_, fg)) => (
            fg.aircraft.k_nt,
            fg.aircraft.l,
            fg.aircraft.m_s,
            fg.bias_nt,
            fg.matrix,
            Matrix3::identity(),
        ),
        None => (kf, lf, Matrix3::zeros(), flux_bias, flux_scale, flux_rot),
    };
    let mut rfc = rng_for(seed, stream_of("fluxcal"));
    let bad_bias = Vector3::from_fn(|_, _| sign(&mut rfc) * rfc.gen_range(200.0..500.0));
    let bad_scale = Matrix3::from_diagonal(&Vector3::from_fn(|_, _| {
        1.0 + sign(&mut rfc) * rfc.gen_range(0.005..0.01)
    }));
    let bad_rot = Rotation3::from_euler_angles(
        sign(&mut rfc) * rfc.gen_range(0.3f64..0.5).to_radians(),
        sign(&mut rfc) * rfc.gen_range(0.3f64..0.5).to_radians(),
        sign(&mut rfc) * rfc.gen_range(0.3f64..0.5).to_radians(),
    )
    .into_inner();
    meta_extra.push(("truth_flux_K_nt".into(), json_vec(&kf)));
    meta_extra.push(("truth_flux_L".into(), json_mat(&lf)));
    if broad.is_some() {
        meta_extra.push(("truth_flux_M_s".into(), json_mat(&mf)));
    }
    meta_extra.push(("truth_flux_bias_nt".into(), json_vec(&flux_bias)));
    meta_extra.push((
        "truth_flux_matrix".into(),
        json_mat(&(flux_scale * flux_rot)),
    ));
    if fluxcal.is_some() {
        meta_extra.push(("truth_fluxcal_bias_nt".into(), json_vec(&bad_bias)));
        meta_extra.push((
            "truth_fluxcal_matrix".into(),
            json_mat(&(bad_scale * bad_rot)),
        ));
    }
    let mut rfn = rng_for(seed, 7);
    let mut flux = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
    let mut fluxcal_col = vec![0.0; n];
    let mut fluxtemp_col = vec![0.0; n];
    for (kk, (&t, i)) in times.iter().zip(&insts).enumerate() {
        let bad = fluxcal.is_some_and(|hi| cfg.hidden[hi].active(t));
        let (sc, rot, bias) = if bad {
            (&bad_scale, &bad_rot, &bad_bias)
        } else {
            (&flux_scale, &flux_rot, &flux_bias)
        };
        let a = sc * rot;
        let f_static = a * (i.b_body + kf + lf * i.b_body + mf * i.db_body) + bias;
        // (mf·d²B/dt² left out of the rate: the fluxcal truth column is a first-order figure.)
        let f_static_dot = a * (i.db_body + lf * i.db_body);
        let f_clean = match &fluxtemp {
            Some((hi, drift)) if cfg.hidden[*hi].active(t) => {
                let (f, f_dot) = drift.apply(t, &f_static, &f_static_dot);
                // What the drift alone does to a TL compensation (against the static
                // fluxgate, which the clean flight has too).
                let (em, emd) = unit_and_rate(&f, &f_dot);
                let (es, esd) = unit_and_rate(&f_static, &f_static_dot);
                let b = i.b_body.norm();
                let bd = i.b_body.dot(&i.db_body) / b;
                fluxtemp_col[kk] = tl_scalar(&k, &l, &m, b, bd, &em, &emd)
                    - tl_scalar(&k, &l, &m, b, bd, &es, &esd);
                f
            }
            _ => f_static,
        };
        for (ax, col) in flux.iter_mut().enumerate() {
            col[kk] = f_clean[ax] + cfg.flux_noise_nt * rfn.sample::<f64, _>(StandardNormal);
        }
        if bad {
            let (em, emd) = unit_and_rate(&f_static, &f_static_dot);
            let (et, etd) = unit_and_rate(&i.b_body, &i.db_body);
            let b = i.b_body.norm();
            let bd = et.dot(&i.db_body);
            fluxcal_col[kk] =
                tl_scalar(&k, &l, &m, b, bd, &em, &emd) - tl_scalar(&k, &l, &m, b, bd, &et, &etd);
        }
    }

    // INS: correlated drift + white noise.
    let mut ri = rng_for(seed, 8);
    let ins_sd = cfg.ins_noise_deg;
    let ins: Vec<Vec<f64>> = (0..3)
        .map(|_| {
            let gm = gauss_markov(n, dt, ins_sd, 100.0, &mut ri);
            gm.into_iter()
                .map(|x| x + ins_sd * 0.3 * ri.sample::<f64, _>(StandardNormal))
                .collect()
        })
        .collect();

    // GPS: Gauss–Markov position error + white noise; velocity noise.
    let mut rg = rng_for(seed, 9);
    let gps_n = gauss_markov(n, dt, cfg.gps_sigma_h_m, cfg.gps_tau_s, &mut rg);
    let gps_e = gauss_markov(n, dt, cfg.gps_sigma_h_m, cfg.gps_tau_s, &mut rg);
    let gps_u = gauss_markov(n, dt, cfg.gps_sigma_v_m, cfg.gps_tau_s, &mut rg);
    let mut rb = rng_for(seed, 10);

    let mut cols: Vec<(&str, Vec<f64>)> = vec![
        ("t", times.clone()),
        ("mag", mag),
        ("flux_x", std::mem::take(&mut flux[0])),
        ("flux_y", std::mem::take(&mut flux[1])),
        ("flux_z", std::mem::take(&mut flux[2])),
    ];
    let mut lat = Vec::with_capacity(n);
    let mut lon = Vec::with_capacity(n);
    let mut alt = Vec::with_capacity(n);
    let (mut vn, mut ve, mut vd) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    for kk in 0..n {
        let p = &pos_ned[kk];
        let white = |r: &mut ChaCha8Rng, s: f64| s * r.sample::<f64, _>(StandardNormal);
        let (la, lo) = frame.to_geo(
            p.x + gps_n[kk] + white(&mut rg, 0.1),
            p.y + gps_e[kk] + white(&mut rg, 0.1),
        );
        lat.push(la);
        lon.push(lo);
        alt.push(-p.z + gps_u[kk] + white(&mut rg, 0.2));
        let v = world.plan.velocity(times[kk]);
        vn[kk] = v[0] + white(&mut rg, 0.03);
        ve[kk] = v[1] + white(&mut rg, 0.03);
        vd[kk] = -v[2] + white(&mut rg, 0.05);
    }
    cols.extend([
        ("lat", lat),
        ("lon", lon),
        ("alt", alt),
        ("vn", vn),
        ("ve", ve),
        ("vd", vd),
    ]);
    for (ax, name) in ["roll", "pitch", "yaw"].iter().enumerate() {
        let v: Vec<f64> = insts
            .iter()
            .zip(&ins[ax])
            .map(|(i, e)| {
                let d = i.att[ax].to_degrees() + e;
                if ax == 2 {
                    d.rem_euclid(360.0)
                } else {
                    d
                }
            })
            .collect();
        cols.push((name, v));
    }
    let base: Vec<f64> = insts
        .iter()
        .map(|i| i.d_nt + i.d_micro_nt + 0.01 * rb.sample::<f64, _>(StandardNormal))
        .collect();
    if cfg.base_station {
        cols.push(("base", base));
    }
    let core_exact: Vec<f64> = insts.iter().map(|i| i.be.norm()).collect();
    if cfg.physics == Physics::Broad {
        // As a user computes it: the core-field model at the GPS position, whose slow
        // altitude error (2 m, 60 s) moves it by a few hundredths of a nT; the exact value
        // goes to `truth_core`.
        let (lat, lon, alt) = (
            trace_col(&cols, "lat"),
            trace_col(&cols, "lon"),
            trace_col(&cols, "alt"),
        );
        let igrf = (0..n)
            .map(|k| cfg.earth.field_ned_nt(lat[k], lon[k], alt[k]).norm())
            .collect();
        cols.push(("igrf", igrf));
        cols.push(("truth_core", core_exact));
    } else {
        cols.push(("igrf", core_exact));
    }

    let mut trace = Trace::default();
    let truth_anom: Vec<f64> = insts
        .iter()
        .map(|i| (i.be + i.ba).norm() - i.be.norm())
        .collect();
    let truth_diurnal: Vec<f64> = insts
        .iter()
        .map(|i| (i.be + i.ba + e0 * (i.d_nt + i.d_micro_nt)).norm() - (i.be + i.ba).norm())
        .collect();
    let truth_interf: Vec<f64> = mag_clean
        .iter()
        .zip(&insts)
        .map(|(m, i)| m - i.b_body.norm())
        .collect();
    for (name, v) in cols {
        trace.set_col(name, v);
    }
    for (name, v) in aux {
        trace.set_col(&name, v);
    }
    trace.set_col("truth_interference", truth_interf);
    trace.set_col("truth_anomaly", truth_anom);
    trace.set_col("truth_diurnal", truth_diurnal);
    for (slot, (hi, _, _)) in vec_effects.iter().enumerate() {
        trace.set_col(
            &cfg.hidden[*hi].column(),
            std::mem::take(&mut hid_cols[slot]),
        );
    }
    if let Some((hi, _)) = lag {
        trace.set_col(&cfg.hidden[hi].column(), lag_col);
    }
    if let Some(hi) = fluxcal {
        trace.set_col(&cfg.hidden[hi].column(), fluxcal_col);
    }
    if let Some((hi, _)) = &fluxtemp {
        trace.set_col(&cfg.hidden[*hi].column(), fluxtemp_col);
    }
    if let Some(h) = cfg.hidden.iter().find(|h| h.kind == HiddenKind::Diurnal) {
        let v: Vec<f64> = insts
            .iter()
            .map(|i| {
                let b0 = i.be + i.ba + e0 * i.d_nt;
                (b0 + e0 * i.d_micro_nt).norm() - b0.norm()
            })
            .collect();
        trace.set_col(&h.column(), v);
    }
    trace.set_text_col(
        "segment",
        times
            .iter()
            .map(|&t| world.plan.label(t).to_string())
            .collect(),
    );

    // Metadata.
    let mut meta: Vec<(String, String)> = vec![
        ("source".into(), "magcomp simulate".into()),
        ("sample_rate_hz".into(), format!("{rate}")),
        ("seed".into(), format!("{seed}")),
        ("flight".into(), cfg.flight.name().into()),
        ("altitude_m".into(), format!("{}", world.plan.h0_agl_m)),
        ("duration_s".into(), format!("{}", n as f64 * dt)),
        ("speed_mps".into(), format!("{}", cfg.speed_mps)),
        ("ground_elev_m".into(), format!("{}", cfg.ground_elev_m)),
        (
            "alt_reference".into(),
            "height above sea level; flat ground at ground_elev_m".into(),
        ),
        (
            "base_reference".into(),
            "base column = diurnal variation recorded at the base station (nT, reference removed)"
                .into(),
        ),
        (
            "earth_field_model".into(),
            match cfg.earth {
                EarthField::Dipole => {
                    "tilted centred dipole, IGRF-2020 degree 1 (g10, g11, h11), spherical Earth"
                        .into()
                }
                EarthField::Fixed {
                    f_nt,
                    inc_deg,
                    dec_deg,
                } => {
                    format!("uniform F={f_nt} nT I={inc_deg} deg D={dec_deg} deg")
                }
            },
        ),
        (
            "anomaly_sources".into(),
            format!("{}", anomaly.sources.len()),
        ),
        ("truth_K_nt".into(), json_vec(&k)),
        ("truth_L".into(), json_mat(&l)),
        ("truth_M_s".into(), json_mat(&m)),
    ];
    if cfg.physics != Physics::Classic {
        meta.push(("physics".into(), cfg.physics.name().into()));
    }
    if !cfg.base_station {
        meta.retain(|(k, _)| k != "base_reference");
    }
    if let Some(a) = cfg.anomaly_pp_nt {
        meta.push(("anomaly_pp_nt".into(), format!("{a}")));
    }
    if cfg.flight.has_calibration() {
        meta.push(("cal_altitude_m".into(), format!("{}", cfg.cal_altitude_m)));
    }
    if cfg.flight != FlightKind::Calibration {
        meta.push((
            "survey_altitude_m".into(),
            format!("{}", cfg.survey_altitude_m),
        ));
    }
    if cfg.flight.has_survey() {
        meta.push(("line_spacing_m".into(), format!("{}", cfg.line_spacing_m)));
        if cfg.tie_lines > 0 {
            meta.push(("tie_spacing_m".into(), format!("{}", cfg.tie_spacing_m)));
        }
        meta.push((
            "line_heading_deg".into(),
            format!("{}", cfg.line_heading_deg),
        ));
    }
    if let Some(c) = world.plan.cal_centre_ne_m {
        let (la, lo) = frame.to_geo(c[0], c[1]);
        meta.push(("cal_centre_lat".into(), format!("{la:.9}")));
        meta.push(("cal_centre_lon".into(), format!("{lo:.9}")));
    }
    if cfg.altitude_swing_m > 0.0 {
        meta.push((
            "altitude_swing_m".into(),
            format!("{}", cfg.altitude_swing_m),
        ));
    }
    if !cfg.hidden.is_empty() {
        let specs: Vec<String> = cfg
            .hidden
            .iter()
            .map(|h| match h.window_s {
                Some((a, b)) => format!("{}@{a}:{b}", h.name()),
                None => h.name(),
            })
            .collect();
        meta.push(("hidden".into(), specs.join(" ")));
    }
    if !cfg.decoys.is_empty() {
        meta.push(("decoys".into(), cfg.decoys.join(" ")));
    }
    if let Some((_, lag_s)) = lag {
        meta.push(("truth_lag_s".into(), format!("{lag_s}")));
    }
    meta.extend(takeoff::apron_meta(&apron, &frame, cfg.ground_elev_m));
    meta.extend(meta_extra);
    trace.meta = meta;

    let truth = SimTruth {
        plan: world.plan.clone(),
        frame,
        anomaly,
        apron,
        engine: vec_effects.iter().find_map(|(_, e, _)| e.engine()),
        ground_elev_m: cfg.ground_elev_m,
        k_nt: k,
        l,
        m_s: m,
        pos_ned_m: pos_ned,
        att_rad: insts.iter().map(|i| i.att).collect(),
        b_body_nt: insts.iter().map(|i| i.b_body).collect(),
        db_body_nt_s: insts.iter().map(|i| i.db_body).collect(),
        delta_b_nt: insts.iter().map(|i| i.delta_b).collect(),
        mag_clean_nt: mag_clean,
    };
    Ok(SimOutput { trace, truth })
}
