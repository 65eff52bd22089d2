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

mod aircraft;
pub mod anomaly;
mod assemble;
mod config;
mod effects;
mod environment;
pub mod flight;
pub mod geo;
pub mod hidden;
pub mod multi;
pub mod physics;
mod plan;
mod sensors;
pub mod signals;
pub mod takeoff;
mod trajectory;
mod world;

use aircraft::draw_aircraft;
pub use anomaly::{Anomaly, Dipole, Geology, GeologyPreset};
use assemble::{metadata, recorded_columns, set_truth_columns, Recorded};
pub use config::{FlightKind, SimConfig};
use effects::Effects;
use environment::environment;
pub use flight::{KinState, Plan};
pub use geo::{EarthField, LocalFrame};
pub use hidden::{parse_hidden, HiddenEffect, HiddenKind};
pub use physics::Physics;
use plan::build_plan;
use trajectory::Clock;
use world::*;

use crate::io::trace::Trace;
use anyhow::{ensure, Result};
use flight::{heading_tag, Builder, Manoeuvre};
use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, StandardNormal, UnitSphere};
use signals::{CurrentWave, RpmWave, SineSum, SmoothWalk, TempWave};
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

/// Simulates a flight and also returns the ground truth behind it: plan → trajectory →
/// environment field → aircraft → hidden effects and the clean scalar → sensors and their
/// errors → trace (recorded columns, truth columns, metadata).
pub fn simulate_detailed(cfg: &SimConfig) -> Result<SimOutput> {
    cfg.validate()?;
    let cfg: &SimConfig = &takeoff::with_engine(cfg);
    let frame = LocalFrame {
        lat0_deg: cfg.start_lat_deg,
        lon0_deg: cfg.start_lon_deg,
    };
    let plan = build_plan(cfg, &mut rng_for(cfg.seed, 1))?;
    let clock = Clock::new(cfg, &plan)?;
    let pos_ned = trajectory::positions(cfg, &plan, &clock);
    let (env, field) = environment(cfg, &frame, &plan, &clock, &pos_ned);
    let (diurnal, micro) = diurnal_draws(cfg, clock.dur);
    let aircraft = draw_aircraft(cfg);
    let world = World {
        plan,
        field,
        e0: env.e0,
        diurnal,
        micro,
        k: aircraft.k,
        l: aircraft.l,
        m: aircraft.m,
    };
    let times = &clock.times;

    // Pass 1: the instant state at each sample.
    let insts: Vec<Inst> = times.iter().map(|&t| world.inst(t)).collect();
    // Hidden effects, then pass 2: scalar, interference and hidden contributions.
    let mut effects = Effects::draw(cfg, &world, times, clock.dur);
    effects.scale_to_target(cfg, times, &insts);
    let mut scalar = effects.scalar_track(cfg, &world, times, &insts);

    // Sensors.
    let mag = sensors::scalar_readings(cfg, &scalar.mag_clean);
    let mut flux = sensors::fluxgate_readings(cfg, &aircraft, &mut effects, times, &insts);
    let recorded = Recorded {
        mag,
        flux: std::mem::take(&mut flux.flux),
        ins_err_deg: sensors::ins_errors(cfg, &clock),
        gps: sensors::gps_readings(cfg, &frame, &world, &clock, &pos_ned),
    };

    // The trace.
    let mut trace = Trace::default();
    for (name, v) in recorded_columns(cfg, &clock, &insts, recorded) {
        trace.set_col(name, v);
    }
    for (name, v) in std::mem::take(&mut effects.aux) {
        trace.set_col(&name, v);
    }
    set_truth_columns(
        &mut trace,
        cfg,
        &insts,
        env.e0,
        &effects,
        &mut scalar,
        &mut flux,
    );
    trace.set_text_col(
        "segment",
        times
            .iter()
            .map(|&t| world.plan.label(t).to_string())
            .collect(),
    );
    let engine = effects.vector.iter().find_map(|(_, e, _)| e.engine());
    trace.meta = metadata(cfg, &clock, &frame, &world, &env, &aircraft, effects);

    let truth = SimTruth {
        plan: world.plan.clone(),
        frame,
        anomaly: env.anomaly,
        apron: env.apron,
        engine,
        ground_elev_m: cfg.ground_elev_m,
        k_nt: aircraft.k,
        l: aircraft.l,
        m_s: aircraft.m,
        pos_ned_m: pos_ned,
        att_rad: insts.iter().map(|i| i.att).collect(),
        b_body_nt: insts.iter().map(|i| i.b_body).collect(),
        db_body_nt_s: insts.iter().map(|i| i.db_body).collect(),
        delta_b_nt: insts.iter().map(|i| i.delta_b).collect(),
        mag_clean_nt: scalar.mag_clean,
    };
    Ok(SimOutput { trace, truth })
}
