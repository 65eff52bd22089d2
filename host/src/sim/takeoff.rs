//! The take-off flight (`--flight takeoff`, [`SimConfig::takeoff`]): from the moment the
//! board powers up on the apron to a survey line, with no calibration manoeuvre at all.
//!
//! | segment | duration | what happens |
//! |---|---|---|
//! | `ground` | 60 s | parked on the apron, engine off: speed 0, the sensor 2 m above ground, heading drawn |
//! | `engine_start` | 30 s | still parked; at 60 s the generator comes on line ([`EngineStart`]) |
//! | `taxi` | ≈ 90–110 s | 6–8 m/s, two 90° turns on the ground (12°/s, no bank) past the apron's steel, stop on the runway, hold |
//! | `takeoff` | ≈ 30 s | roll from 0 to 0.75 × `speed_mps` (peak 2.2 m/s² at 60 m/s), rotation at 0.65 ×, lift-off |
//! | `climb`, `climb_turn` | ≈ 75–100 s | 3–4 m/s through the low-altitude anomaly; from ≈ 60 m up, one or two 90° climbing turns banked 15–25° (as many as the climb lasts) |
//! | `level_off` | 20 s | level at `survey_altitude_m`, accelerate to `speed_mps` |
//! | `line_1001`, `turn`, `line_1002` | | a line of `line_length_m`; with `survey_lines` ≥ 2 a 180° turn onto its reciprocal |
//!
//! Kinematics: the ground speed is a sum of raised-cosine steps, the height the ground
//! height plus the integral of a climb rate that ramps in and out, and the weight leaves
//! the wheels over the 3 s rotation (`airborne` 0 → 1). On the wheels there is no bank and
//! no crab, the attitude is the gear's, and gusts rock the aircraft only as it rolls; in the
//! air the turns are banked (atan(v·ω/g)), the aircraft crabs into the wind and the pitch is
//! the angle of attack (the trim at `speed_mps`, ∝ 1/v² below it) plus the flight-path
//! angle. Nothing divides by the ground speed where it can be 0: the along-track distance
//! simply does not advance while the speed is 0.
//!
//! The apron ([`apron_sources`]): hangar steel beside the first taxi leg and a parked
//! vehicle beside the second, point dipoles a few metres above the ground. They are part
//! of the Earth-side field (`truth_anomaly`, the exact |B_e + B_a|), harmonic outside
//! themselves like the geology, and never scaled by `anomaly_pp_nt` (they are not geology).

use super::anomaly::{Anomaly, Dipole};
use super::flight::{Builder, Climb, Manoeuvre, Plan, SpeedStep, TakeoffProfile, G_MPS2};
use super::hidden::{HiddenEffect, HiddenKind};
use super::signals::{smooth_step, SineSum};
use super::world::{json_vec, random_dir, FieldTrack, VecEffect, World};
use super::{rng_for, stream_of, FlightKind, LocalFrame, SimConfig};
use anyhow::Result;
use nalgebra::Vector3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use std::borrow::Cow;
use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// Parked with the engine off (s); the engine starts at this time.
pub const GROUND_S: f64 = 60.0;
/// Parked with the engine running, before the taxi (s).
pub const ENGINE_START_S: f64 = 30.0;
/// Height of the scalar sensor above the ground while the aircraft stands on its wheels (m).
pub const SENSOR_HEIGHT_M: f64 = 2.0;
const TAXI_TURN_RATE_DEG_S: f64 = 12.0;
/// From brake release to the climb speed (s).
const TAKEOFF_ACCEL_S: f64 = 32.0;
const ROTATION_S: f64 = 3.0;
const LEVEL_OFF_S: f64 = 20.0;
/// Straight climb before each climbing turn (s): the first at ≈ 60–75 m above ground.
const CLIMB_STRAIGHT_S: [f64; 2] = [15.0, 5.0];

/// The take-off's flight plan (see the module documentation); `rng` is the plan's stream.
pub(super) fn build_plan(cfg: &SimConfig, rng: &mut ChaCha8Rng) -> Result<Plan> {
    let v = cfg.speed_mps;
    let (v_climb, v_rot) = (0.75 * v, 0.65 * v);
    let sign = |r: &mut ChaCha8Rng| if r.gen_bool(0.5) { 1.0 } else { -1.0 };
    let course0 = rng.gen_range(0.0..TAU);
    let v_taxi = rng.gen_range(6.0..8.0);
    let legs_s = [rng.gen_range(18.0..26.0), rng.gen_range(28.0..40.0)];
    let taxi_turns = [sign(rng) * FRAC_PI_2, sign(rng) * FRAC_PI_2];
    let pass = [rng.gen_range(0.5..0.8), rng.gen_range(0.3..0.7)];
    let climb_rate = rng.gen_range(3.0..4.0);
    let bank = rng.gen_range(15f64..25.0).to_radians();
    let climb_turns = [sign(rng) * FRAC_PI_2, sign(rng) * FRAC_PI_2];
    let reciprocal = sign(rng) * PI;
    let ground_att_rad = [
        rng.gen_range(-0.5f64..0.5).to_radians(),
        rng.gen_range(0.0f64..1.0).to_radians(),
    ];
    let turb_rad = cfg.turbulence_deg.to_radians();
    let turb = [
        SineSum::random(3, 2.0, 15.0, turb_rad, rng),
        SineSum::random(3, 2.0, 15.0, turb_rad * 0.7, rng),
        SineSum::random(3, 3.0, 20.0, turb_rad * 0.7, rng),
    ];
    let trim_pitch_rad = rng.gen_range(1.5f64..3.0).to_radians();
    let wind = (cfg.wind_mps, rng.gen_range(0.0..TAU));

    let level =
        |b: &mut Builder, dur: f64, label: &str| b.straight(dur, Manoeuvre::Level, 0.0, 1.0, label);
    // The builder's speed only sets the turns' displacement, which nothing here uses: the
    // track is integrated from `Plan::velocity`.
    let mut b = Builder::new([0.0, 0.0], course0, 0.0, TAXI_TURN_RATE_DEG_S.to_radians());
    b.ramp_s = 2.0;
    level(&mut b, GROUND_S, "ground");
    level(&mut b, ENGINE_START_S, "engine_start");
    let mut speed_steps = vec![SpeedStep {
        t0_s: b.t_s,
        dur_s: 10.0,
        dv_mps: v_taxi,
    }];
    b.speed = v_taxi;
    let mut apron_pass_s = [0.0; 2];
    for k in 0..2 {
        apron_pass_s[k] = b.t_s + pass[k] * legs_s[k];
        level(&mut b, legs_s[k], "taxi");
        b.turn_labelled(taxi_turns[k], "taxi");
    }
    // Line up: roll on 3 s, stop within 8 s, hold 10 s.
    speed_steps.push(SpeedStep {
        t0_s: b.t_s + 3.0,
        dur_s: 8.0,
        dv_mps: -v_taxi,
    });
    level(&mut b, 21.0, "taxi");
    // Roll from brake release to the climb speed; rotation as the speed passes v_rot,
    // lift-off halfway through it.
    let t_roll = b.t_s;
    speed_steps.push(SpeedStep {
        t0_s: t_roll,
        dur_s: TAKEOFF_ACCEL_S,
        dv_mps: v_climb,
    });
    let t_rot = t_roll + TAKEOFF_ACCEL_S * (1.0 - 2.0 * v_rot / v_climb).acos() / PI;
    let climb = {
        let (t0, r_in, r_out) = (t_rot + ROTATION_S / 2.0, 4.0, 10.0);
        let dh = cfg.survey_altitude_m - SENSOR_HEIGHT_M;
        Climb {
            t0_s: t0,
            ramp_in_s: r_in,
            // ∫ climb rate = rate · (t_level − t0 − r_in/2 + r_out/2) = dh.
            t_level_s: t0 + dh / climb_rate + r_in / 2.0 - r_out / 2.0,
            ramp_out_s: r_out,
            rate_mps: climb_rate,
        }
    };
    b.speed = v_climb;
    let climbing = (climb.t0_s + climb.ramp_in_s).min(climb.t_level_s);
    level(&mut b, climbing - t_roll, "takeoff");
    b.max_rate = G_MPS2 * bank.tan() / v_climb;
    b.ramp_s = 3.0;
    for (d, straight_s) in climb_turns.into_iter().zip(CLIMB_STRAIGHT_S) {
        let turn_s = d.abs() / b.max_rate + b.ramp_s;
        if b.t_s + straight_s + turn_s > climb.t_level_s {
            break;
        }
        level(&mut b, straight_s, "climb");
        b.turn_labelled(d, "climb_turn");
    }
    let rest_s = climb.t_level_s - b.t_s;
    level(&mut b, rest_s, "climb");
    speed_steps.push(SpeedStep {
        t0_s: b.t_s,
        dur_s: LEVEL_OFF_S,
        dv_mps: v - v_climb,
    });
    level(&mut b, LEVEL_OFF_S, "level_off");
    b.speed = v;
    b.max_rate = cfg.turn_rate_deg_s.to_radians();
    level(&mut b, cfg.line_length_m / v, "line_1001");
    if cfg.survey_lines >= 2 {
        b.turn_labelled(reciprocal, "turn");
        level(&mut b, cfg.line_length_m / v, "line_1002");
    }
    Ok(Plan {
        pieces: b.pieces,
        speed_mps: v,
        start_ne_m: [0.0, 0.0],
        start_course_rad: course0,
        h0_agl_m: SENSOR_HEIGHT_M,
        alt_ramps: Vec::new(),
        swing: None,
        trim_pitch_rad,
        turb,
        wind,
        cal_centre_ne_m: None,
        takeoff: Some(TakeoffProfile {
            speed_steps,
            cruise_mps: v,
            ground_height_m: SENSOR_HEIGHT_M,
            rotation_s: (t_rot, ROTATION_S),
            climb,
            ground_att_rad,
            engine_on_s: GROUND_S,
            apron_pass_s,
        }),
    })
}

/// Position (north, east, m) at `t`, integrated from the plan's velocity as the simulator
/// integrates the track (trapezoid, ≤ 5 ms steps).
fn position_at(plan: &Plan, t: f64) -> [f64; 2] {
    let n = (t / 0.005).ceil().max(1.0) as usize;
    let h = t / n as f64;
    let mut p = plan.start_ne_m;
    let mut v0 = plan.velocity(0.0);
    for j in 1..=n {
        let v1 = plan.velocity(j as f64 * h);
        p[0] += 0.5 * h * (v0[0] + v1[0]);
        p[1] += 0.5 * h * (v0[1] + v1[1]);
        v0 = v1;
    }
    p
}

/// The apron's steel, drawn from the seed's `apron` stream: hangar steel 20–35 m beside the
/// first taxi leg, 4 m above ground, induced moment 1.5–4 × 10⁴ A·m² along the field plus
/// up to 30 % remanent; a parked fuel truck or tug 5–10 m beside the second leg, 1 m above
/// ground, 400–1000 A·m² plus up to 80 % remanent. Either side of the track. Empty without a take-off.
pub fn apron_sources(
    plan: &Plan,
    earth_dir: Vector3<f64>,
    ground_elev_m: f64,
    seed: u64,
) -> Anomaly {
    let Some(p) = &plan.takeoff else {
        return Anomaly::default();
    };
    let mut r = rng_for(seed, stream_of("apron"));
    // (beside the track m, above ground m, induced moment A·m², largest remanent fraction)
    let kinds = [
        (20.0..35.0, 4.0, 1.5e4..4e4, 0.3),
        (5.0..10.0, 1.0, 400.0..1000.0, 0.8),
    ];
    let sources = p
        .apron_pass_s
        .iter()
        .zip(kinds)
        .map(|(&t, (off, up, m, q))| {
            let at = position_at(plan, t);
            let c = plan.course(t).0;
            let side = if r.gen_bool(0.5) { 1.0 } else { -1.0 };
            let off = side * r.gen_range(off);
            let m = r.gen_range(m);
            let rem = random_dir(&mut r) * (m * q * r.gen::<f64>());
            Dipole {
                pos_ned_m: Vector3::new(
                    at[0] - off * c.sin(),
                    at[1] + off * c.cos(),
                    -(ground_elev_m + up),
                ),
                moment_am2: earth_dir.normalize() * m + rem,
            }
        })
        .collect();
    Anomaly { sources }
}

/// Draws the apron (empty without a take-off), adds its exact field and rate to the
/// environment track at the knots and its sources to `anomaly`; called after any
/// `anomaly_pp_nt` scaling, which is for the geology. Returns the apron.
pub(super) fn add_apron(
    field: &mut FieldTrack,
    anomaly: &mut Anomaly,
    plan: &Plan,
    knots: &[usize],
    pos_ned: &[Vector3<f64>],
    earth_dir: Vector3<f64>,
    cfg: &SimConfig,
) -> Anomaly {
    let apron = apron_sources(plan, earth_dir, cfg.ground_elev_m, cfg.seed);
    if apron.sources.is_empty() {
        return apron;
    }
    for (j, &k) in knots.iter().enumerate() {
        let v = plan.velocity(field.t[j]);
        let (ba, ga) = apron.field_and_gradient(&pos_ned[k]);
        field.ba[j] += ba;
        field.dba[j] += ga * Vector3::new(v[0], v[1], -v[2]);
    }
    anomaly.sources.extend(apron.sources.iter().cloned());
    apron
}

/// `truth_apron_sources`: `[[lat, lon, height above ground m, moment N, E, D A·m²], …]`.
pub(super) fn apron_meta(
    apron: &Anomaly,
    frame: &LocalFrame,
    ground_elev_m: f64,
) -> Option<(String, String)> {
    if apron.sources.is_empty() {
        return None;
    }
    let rows: Vec<String> = apron
        .sources
        .iter()
        .map(|s| {
            let (lat, lon) = frame.to_geo(s.pos_ned_m.x, s.pos_ned_m.y);
            let m = &s.moment_am2;
            format!(
                "[{lat:.9},{lon:.9},{:.3},{:.6e},{:.6e},{:.6e}]",
                -s.pos_ned_m.z - ground_elev_m,
                m.x,
                m.y,
                m.z
            )
        })
        .collect();
    Some((
        "truth_apron_sources".into(),
        format!("[{}]", rows.join(",")),
    ))
}

/// The engine's electrical system coming on line: the generator's current through the
/// aircraft's wiring gives a field at the scalar sensor fixed in body axes, which the
/// compensation model does not know (`truth_hidden_engine`). 0 before the start, then a
/// 1 s raised-cosine step to `dc_nt` with the battery's recharge on top, decaying:
/// `dc · step · (1 + a·e^{−(t − t_on)/τ})`.
#[derive(Clone, Debug, PartialEq)]
pub struct EngineStart {
    pub t_on_s: f64,
    /// Steady field once the transient has died (nT, body axes), 5–20 nT.
    pub dc_nt: Vector3<f64>,
    /// Steady generator current (A), 25–45 A: what the channel shows, if one is logged.
    pub amps: f64,
    /// Transient: overshoot `a` (0.5–1) and its decay time τ (3–8 s).
    pub overshoot: f64,
    pub tau_s: f64,
}

impl EngineStart {
    /// The current relative to its steady value (0 up to `t_on_s`).
    pub fn level(&self, t: f64) -> f64 {
        let u = t - self.t_on_s;
        if u <= 0.0 {
            return 0.0;
        }
        smooth_step(u, 1.0).0 * (1.0 + self.overshoot * (-u / self.tau_s).exp())
    }
    /// Field at the scalar sensor (nT, body axes).
    pub fn field(&self, t: f64) -> Vector3<f64> {
        self.dc_nt * self.level(t)
    }
    /// Generator current (A).
    pub fn current(&self, t: f64) -> f64 {
        self.amps * self.level(t)
    }
}

/// Draws the engine-start effect from `r` (its hidden effect's stream). Its direction is
/// one the scalar sees: at least half of it along the field where the aircraft stands.
/// Writes the current to `channel` when one is named.
pub(super) fn engine_effect(
    world: &World,
    channel: Option<&str>,
    times: &[f64],
    aux: &mut Vec<(String, Vec<f64>)>,
    meta: &mut Vec<(String, String)>,
    r: &mut ChaCha8Rng,
) -> VecEffect {
    let t_on = world.plan.takeoff.as_ref().map_or(0.0, |p| p.engine_on_s);
    let e = world.inst(t_on).b_body.normalize();
    let dir = std::iter::repeat_with(|| random_dir(r))
        .find(|d| d.dot(&e).abs() >= 0.5)
        .expect("half the sphere qualifies");
    let law = EngineStart {
        t_on_s: t_on,
        dc_nt: dir * r.gen_range(5.0..20.0),
        amps: r.gen_range(25.0..45.0),
        overshoot: r.gen_range(0.5..1.0),
        tau_s: r.gen_range(3.0..8.0),
    };
    meta.push(("truth_engine_start_s".into(), format!("{t_on}")));
    meta.push(("truth_engine_dc_nt".into(), json_vec(&law.dc_nt)));
    if let Some(ch) = channel {
        aux.push((
            ch.to_string(),
            times.iter().map(|&t| law.current(t)).collect(),
        ));
        meta.push((
            "truth_c_engine_nt_per_a".into(),
            json_vec(&(law.dc_nt / law.amps)),
        ));
    }
    VecEffect::Engine(law)
}

/// Rate of the exact field knots above which the simulator interpolates (Hz): a take-off
/// taxis metres from the apron's steel, where 50 ms knots (0.4 m) would leave ~1e-3 nT.
pub(super) fn knot_rate_hz(cfg: &SimConfig) -> f64 {
    match cfg.flight {
        FlightKind::Takeoff => 100.0,
        _ => 20.0,
    }
}

/// A take-off always starts its engine: adds the `engine` effect (no channel) when the
/// configuration does not name it.
pub(super) fn with_engine(cfg: &SimConfig) -> Cow<'_, SimConfig> {
    let named = cfg
        .hidden
        .iter()
        .any(|h| matches!(h.kind, HiddenKind::Engine { .. }));
    if cfg.flight != FlightKind::Takeoff || named {
        return Cow::Borrowed(cfg);
    }
    let mut c = cfg.clone();
    c.hidden.push(HiddenEffect {
        kind: HiddenKind::Engine { channel: None },
        window_s: None,
    });
    Cow::Owned(c)
}
