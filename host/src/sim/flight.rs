//! Flight plan and kinematics: pieces (straight legs with manoeuvres, banked turns) whose
//! course, attitude and height are analytic functions of time; only the horizontal track
//! is integrated. Attitude is aerospace ZYX (yaw, pitch, roll), NED navigation frame,
//! body x forward, y starboard, z down.

use super::signals::{smooth_step, SineSum};
use anyhow::{bail, Result};
use std::f64::consts::{PI, TAU};

pub const G_MPS2: f64 = 9.80665;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Manoeuvre {
    Level,
    Roll,
    Pitch,
    Yaw,
}

#[derive(Clone, Copy, Debug)]
pub enum Kind {
    Straight {
        course_rad: f64,
        man: Manoeuvre,
        amp_rad: f64,
        period_s: f64,
    },
    /// Coordinated turn: turn rate ramps in/out over `ramp_s` (raised cosine), so bank
    /// angle and roll rate stay continuous.
    Turn {
        course0_rad: f64,
        rate_rad_s: f64,
        ramp_s: f64,
        plateau_s: f64,
    },
}

#[derive(Clone, Debug)]
pub struct Piece {
    pub t0_s: f64,
    pub dur_s: f64,
    pub kind: Kind,
    pub label: String,
}

/// Smooth change of the nominal height.
#[derive(Clone, Copy, Debug)]
pub struct AltRamp {
    pub t0_s: f64,
    pub dur_s: f64,
    pub dh_m: f64,
}

/// True kinematic state at one instant.
#[derive(Clone, Copy, Debug, Default)]
pub struct KinState {
    pub course_rad: f64,
    pub roll_rad: f64,
    pub pitch_rad: f64,
    pub yaw_rad: f64,
    /// Height above ground (m) and its rate (m/s, up positive).
    pub h_agl_m: f64,
    pub climb_mps: f64,
}

#[derive(Clone, Debug)]
pub struct Plan {
    pub pieces: Vec<Piece>,
    pub speed_mps: f64,
    pub start_ne_m: [f64; 2],
    pub start_course_rad: f64,
    pub h0_agl_m: f64,
    pub alt_ramps: Vec<AltRamp>,
    /// Terrain-drape style undulation: (amplitude m, wavelength m, phase rad).
    pub swing: Option<(f64, f64, f64)>,
    pub trim_pitch_rad: f64,
    /// Turbulence on roll, pitch, yaw (rad).
    pub turb: [SineSum; 3],
    /// Wind speed (m/s) and the direction it blows from (rad): sets the crab angle.
    pub wind: (f64, f64),
    pub cal_centre_ne_m: Option<[f64; 2]>,
    /// A take-off (`takeoff.rs`): speed, height and wheels as functions of time. None =
    /// flying all along at `speed_mps`, at `h0_agl_m` changed by the ramps, swing and
    /// pitch manoeuvres.
    pub takeoff: Option<TakeoffProfile>,
}

fn manoeuvre_env(tau: f64, dur: f64, ramp: f64) -> (f64, f64) {
    let (a, ad) = smooth_step(tau, ramp);
    let (b, bd) = smooth_step(tau - (dur - ramp), ramp);
    (a - b, ad - bd)
}

/// Course change after `tau` seconds of a turn, and the current turn rate.
fn turn_progress(tau: f64, rate: f64, ramp: f64, plateau: f64) -> (f64, f64) {
    let tau = tau.clamp(0.0, 2.0 * ramp + plateau);
    if tau < ramp {
        let a = PI * tau / ramp;
        (
            rate * (tau / 2.0 - ramp / (2.0 * PI) * a.sin()),
            rate * (1.0 - a.cos()) / 2.0,
        )
    } else if tau < ramp + plateau {
        (rate * (ramp / 2.0 + tau - ramp), rate)
    } else {
        let u = tau - ramp - plateau;
        let a = PI * u / ramp;
        (
            rate * (ramp / 2.0 + plateau + u / 2.0 + ramp / (2.0 * PI) * a.sin()),
            rate * (1.0 + a.cos()) / 2.0,
        )
    }
}

/// (rate, plateau, duration) of a turn through `delta` rad.
fn turn_shape(delta: f64, max_rate: f64, ramp: f64) -> (f64, f64, f64) {
    if delta.abs() >= max_rate * ramp {
        let plateau = delta.abs() / max_rate - ramp;
        (max_rate * delta.signum(), plateau, 2.0 * ramp + plateau)
    } else {
        (delta / ramp, 0.0, 2.0 * ramp)
    }
}

/// Horizontal displacement (north, east) of a turn starting on course `c0`.
fn turn_displacement(c0: f64, delta: f64, v: f64, max_rate: f64, ramp: f64, n: usize) -> [f64; 2] {
    let (rate, plateau, dur) = turn_shape(delta, max_rate, ramp);
    let h = dur / n as f64;
    let mut d = [0.0, 0.0];
    // Simpson's rule on the velocity.
    for i in 0..=n {
        let w = if i == 0 || i == n {
            1.0
        } else if i % 2 == 1 {
            4.0
        } else {
            2.0
        };
        let c = c0 + turn_progress(i as f64 * h, rate, ramp, plateau).0;
        d[0] += w * c.cos();
        d[1] += w * c.sin();
    }
    [d[0] * v * h / 3.0, d[1] * v * h / 3.0]
}

/// Builds a plan piece by piece while tracking the exact end pose.
pub struct Builder {
    pub pieces: Vec<Piece>,
    pub t_s: f64,
    pub pos: [f64; 2],
    pub course: f64,
    pub speed: f64,
    pub max_rate: f64,
    pub ramp_s: f64,
}

impl Builder {
    pub fn new(pos: [f64; 2], course: f64, speed: f64, max_rate: f64) -> Self {
        Builder {
            pieces: Vec::new(),
            t_s: 0.0,
            pos,
            course,
            speed,
            max_rate,
            ramp_s: 3.0,
        }
    }

    pub fn straight(
        &mut self,
        dur_s: f64,
        man: Manoeuvre,
        amp_rad: f64,
        period_s: f64,
        label: &str,
    ) {
        if dur_s <= 1e-9 {
            return;
        }
        self.pieces.push(Piece {
            t0_s: self.t_s,
            dur_s,
            kind: Kind::Straight {
                course_rad: self.course,
                man,
                amp_rad,
                period_s,
            },
            label: label.to_string(),
        });
        self.t_s += dur_s;
        self.pos[0] += self.speed * dur_s * self.course.cos();
        self.pos[1] += self.speed * dur_s * self.course.sin();
    }

    pub fn turn(&mut self, delta: f64) {
        self.turn_labelled(delta, "turn");
    }

    /// A turn through `delta` rad whose segment label is `label`.
    pub fn turn_labelled(&mut self, delta: f64, label: &str) {
        if delta.abs() < 1e-9 {
            return;
        }
        let (rate, plateau, dur) = turn_shape(delta, self.max_rate, self.ramp_s);
        let d = turn_displacement(
            self.course,
            delta,
            self.speed,
            self.max_rate,
            self.ramp_s,
            4000,
        );
        self.pieces.push(Piece {
            t0_s: self.t_s,
            dur_s: dur,
            kind: Kind::Turn {
                course0_rad: self.course,
                rate_rad_s: rate,
                ramp_s: self.ramp_s,
                plateau_s: plateau,
            },
            label: label.to_string(),
        });
        self.t_s += dur;
        self.pos[0] += d[0];
        self.pos[1] += d[1];
        self.course = (self.course + delta).rem_euclid(TAU);
    }

    /// Turn–straight–turn so that the track ends on the line through `target` on course
    /// `course1`, at least `d_min` before `target`. Returns the remaining distance to
    /// `target` (≥ d_min), which the caller flies straight.
    pub fn connect(&mut self, target: [f64; 2], course1: f64, d_min: f64) -> Result<f64> {
        let v = self.speed;
        if v <= 0.0 {
            bail!("cannot join flight legs at a ground speed of {v} m/s");
        }
        let c0 = self.course;
        let signed = |from: f64, to: f64, dir: f64| -> f64 {
            let d = (dir * (to - from)).rem_euclid(TAU);
            dir * d
        };
        let solve = |d1: f64, d2: f64, n: usize| -> Option<(f64, f64, f64)> {
            let cm = c0 + d1;
            let p1 = turn_displacement(c0, d1, v, self.max_rate, self.ramp_s, n);
            let p2 = turn_displacement(cm, d2, v, self.max_rate, self.ramp_s, n);
            let rhs = [
                target[0] - self.pos[0] - p1[0] - p2[0],
                target[1] - self.pos[1] - p1[1] - p2[1],
            ];
            let (a, b) = ([cm.cos(), cm.sin()], [course1.cos(), course1.sin()]);
            let det = a[0] * b[1] - a[1] * b[0];
            if det.abs() < 1e-3 {
                return None;
            }
            let s = (rhs[0] * b[1] - rhs[1] * b[0]) / det;
            let d = (a[0] * rhs[1] - a[1] * rhs[0]) / det;
            if s < 0.0 || d < d_min {
                return None;
            }
            let t = turn_shape(d1, self.max_rate, self.ramp_s).2
                + turn_shape(d2, self.max_rate, self.ramp_s).2
                + (s + d) / v;
            Some((s, d, t))
        };
        let mut best: Option<(f64, f64, f64)> = None; // (time, d1, d2)
        for dir1 in [1.0, -1.0] {
            for dir2 in [1.0, -1.0] {
                for k in 0..360 {
                    let cm = (k as f64).to_radians();
                    let d1 = signed(c0, cm, dir1);
                    let d2 = signed(cm, course1, dir2);
                    if let Some((_, _, t)) = solve(d1, d2, 60) {
                        if best.is_none_or(|b| t < b.0) {
                            best = Some((t, d1, d2));
                        }
                    }
                }
            }
        }
        let Some((_, d1, d2)) = best else {
            bail!("cannot join the flight legs: the turn radius is too large for the requested geometry");
        };
        let Some((s, _, _)) = solve(d1, d2, 4000) else {
            bail!("cannot join the flight legs (geometry)");
        };
        self.turn(d1);
        self.straight(s / v, Manoeuvre::Level, 0.0, 1.0, "turn");
        self.turn(d2);
        // Remaining distance along the new course; the cross-track miss is only the
        // integration error of the turns (millimetres).
        let rem =
            (target[0] - self.pos[0]) * course1.cos() + (target[1] - self.pos[1]) * course1.sin();
        Ok(rem)
    }
}

impl Plan {
    pub fn duration_s(&self) -> f64 {
        self.pieces.last().map(|p| p.t0_s + p.dur_s).unwrap_or(0.0)
    }

    pub fn piece_index(&self, t: f64) -> usize {
        let i = self.pieces.partition_point(|p| p.t0_s <= t);
        i.saturating_sub(1).min(self.pieces.len().saturating_sub(1))
    }

    /// Course (rad) and turn rate (rad/s) at t.
    pub fn course(&self, t: f64) -> (f64, f64) {
        if self.pieces.is_empty() {
            return (self.start_course_rad, 0.0);
        }
        let p = &self.pieces[self.piece_index(t)];
        match p.kind {
            Kind::Straight { course_rad, .. } => (course_rad, 0.0),
            Kind::Turn {
                course0_rad,
                rate_rad_s,
                ramp_s,
                plateau_s,
            } => {
                let (dc, r) = turn_progress(t - p.t0_s, rate_rad_s, ramp_s, plateau_s);
                (course0_rad + dc, r)
            }
        }
    }

    /// Ground speed (m/s) at t.
    pub fn speed(&self, t: f64) -> f64 {
        match &self.takeoff {
            Some(p) => p.speed(t),
            None => self.speed_mps,
        }
    }

    /// Horizontal velocity (north, east) and vertical rate (up) at t.
    pub fn velocity(&self, t: f64) -> [f64; 3] {
        let (c, _) = self.course(t);
        let (_, climb) = self.height(t);
        let v = self.speed(t);
        [v * c.cos(), v * c.sin(), climb]
    }

    /// Height above ground and climb rate.
    pub fn height(&self, t: f64) -> (f64, f64) {
        if let Some(p) = &self.takeoff {
            return p.height(t);
        }
        let mut h = self.h0_agl_m;
        let mut hd = 0.0;
        for r in &self.alt_ramps {
            let (a, ad) = smooth_step(t - r.t0_s, r.dur_s);
            h += r.dh_m * a;
            hd += r.dh_m * ad;
        }
        if let Some((amp, wl, ph)) = self.swing {
            let k = TAU / wl;
            let s = self.speed_mps * t;
            h += amp * (k * s + ph).sin();
            hd += amp * k * self.speed_mps * (k * s + ph).cos();
        }
        if !self.pieces.is_empty() {
            let p = &self.pieces[self.piece_index(t)];
            if let Kind::Straight {
                man: Manoeuvre::Pitch,
                amp_rad,
                period_s,
                ..
            } = p.kind
            {
                // Altitude excursion whose slope gives the pitch swing; it returns to the
                // nominal height after whole cycles.
                let tau = t - p.t0_s;
                let w = TAU / period_s;
                let a = self.speed_mps * amp_rad.tan() / w;
                let (e, ed) = manoeuvre_env(tau, p.dur_s, period_s / 2.0);
                h += a * e * (1.0 - (w * tau).cos());
                hd += a * (ed * (1.0 - (w * tau).cos()) + e * w * (w * tau).sin());
            }
        }
        (h, hd)
    }

    /// Full attitude and height at t.
    pub fn state(&self, t: f64) -> KinState {
        if let Some(p) = &self.takeoff {
            return p.state(self, t);
        }
        let (course, rate) = self.course(t);
        let (h, climb) = self.height(t);
        let v = self.speed_mps;
        let bank = (v * rate / G_MPS2).atan();
        let (mut man_roll, mut man_yaw) = (0.0, 0.0);
        if !self.pieces.is_empty() {
            let p = &self.pieces[self.piece_index(t)];
            if let Kind::Straight {
                man,
                amp_rad,
                period_s,
                ..
            } = p.kind
            {
                let tau = t - p.t0_s;
                let (e, _) = manoeuvre_env(tau, p.dur_s, period_s / 2.0);
                let s = amp_rad * e * (TAU * tau / period_s).sin();
                match man {
                    Manoeuvre::Roll => man_roll = s,
                    Manoeuvre::Yaw => man_yaw = s,
                    _ => {}
                }
            }
        }
        let (w_speed, w_from) = self.wind;
        let crab = (w_speed * (w_from - course).sin() / v)
            .clamp(-0.5, 0.5)
            .asin();
        KinState {
            course_rad: course,
            roll_rad: bank + man_roll + self.turb[0].value(t),
            pitch_rad: self.trim_pitch_rad + (climb / v).atan() + self.turb[1].value(t),
            yaw_rad: course + crab + man_yaw + self.turb[2].value(t),
            h_agl_m: h,
            climb_mps: climb,
        }
    }

    pub fn label(&self, t: f64) -> &str {
        if self.pieces.is_empty() {
            return "turn";
        }
        &self.pieces[self.piece_index(t)].label
    }
}

/// Heading label as in `cal_h045_roll`.
pub fn heading_tag(course_rad: f64) -> String {
    let deg = (course_rad.to_degrees().round() as i64).rem_euclid(360);
    format!("h{deg:03}")
}

// The take-off profile lives with the plan that holds it; `takeoff.rs` builds it.

/// A smooth change of the ground speed: `dv · smooth_step(t − t0, dur)`.
#[derive(Clone, Copy, Debug)]
pub struct SpeedStep {
    pub t0_s: f64,
    pub dur_s: f64,
    pub dv_mps: f64,
}

/// Climb rate `rate · (smooth_step(t − t0, ramp_in) − smooth_step(t − t_level, ramp_out))`.
#[derive(Clone, Copy, Debug)]
pub struct Climb {
    pub t0_s: f64,
    pub ramp_in_s: f64,
    pub t_level_s: f64,
    pub ramp_out_s: f64,
    pub rate_mps: f64,
}

/// What a take-off adds to a [`Plan`]: speed, height and the wheels as functions of time.
#[derive(Clone, Debug)]
pub struct TakeoffProfile {
    /// The speed is the sum of these steps (0 before the first).
    pub speed_steps: Vec<SpeedStep>,
    /// Survey speed (m/s): where the angle of attack is the plan's trim.
    pub cruise_mps: f64,
    /// Sensor height above ground on the wheels (m).
    pub ground_height_m: f64,
    /// Rotation (start, duration), s: the weight leaves the wheels.
    pub rotation_s: (f64, f64),
    pub climb: Climb,
    /// Roll and pitch of the aircraft standing on its gear (rad).
    pub ground_att_rad: [f64; 2],
    /// When the engine (and its generator) starts (s).
    pub engine_on_s: f64,
    /// When the taxi passes the hangar and the vehicle (s).
    pub apron_pass_s: [f64; 2],
}

/// ∫₀^τ `smooth_step(·, d)`.
fn step_integral(tau: f64, d: f64) -> f64 {
    if tau <= 0.0 {
        0.0
    } else if tau >= d {
        tau - d / 2.0
    } else {
        tau / 2.0 - d / (2.0 * PI) * (PI * tau / d).sin()
    }
}

impl TakeoffProfile {
    /// Ground speed (m/s).
    pub fn speed(&self, t: f64) -> f64 {
        self.speed_steps
            .iter()
            .map(|s| s.dv_mps * smooth_step(t - s.t0_s, s.dur_s).0)
            .sum()
    }

    /// Height above ground and climb rate.
    pub fn height(&self, t: f64) -> (f64, f64) {
        let c = &self.climb;
        let h =
            step_integral(t - c.t0_s, c.ramp_in_s) - step_integral(t - c.t_level_s, c.ramp_out_s);
        let hd =
            smooth_step(t - c.t0_s, c.ramp_in_s).0 - smooth_step(t - c.t_level_s, c.ramp_out_s).0;
        (self.ground_height_m + c.rate_mps * h, c.rate_mps * hd)
    }

    /// 0 while the weight is on the wheels, 1 flying (raised cosine over the rotation).
    pub fn airborne(&self, t: f64) -> f64 {
        smooth_step(t - self.rotation_s.0, self.rotation_s.1).0
    }

    /// Attitude and height at `t` (the plan gives course, turn rate, trim, wind, gusts).
    pub fn state(&self, plan: &Plan, t: f64) -> KinState {
        let (course, rate) = plan.course(t);
        let (h, climb) = self.height(t);
        let v = self.speed(t);
        let air = self.airborne(t);
        let [g_roll, g_pitch] = self.ground_att_rad;
        // Flying only (weighted by `air`, > 0 from the rotation speed on); the floors keep
        // every term finite where the aircraft stands still.
        let bank = (v * rate / G_MPS2).atan();
        let (w_speed, w_from) = plan.wind;
        let crab = (w_speed * (w_from - course).sin() / v.max(1.0))
            .clamp(-0.5, 0.5)
            .asin();
        let aoa = plan.trim_pitch_rad * (self.cruise_mps / v.max(0.5 * self.cruise_mps)).powi(2);
        let fly_pitch = aoa + climb.atan2(v);
        // Gusts rock a rolling aircraft a little and a parked one not at all.
        let gust = air + (1.0 - air) * 0.3 * v / (v + 5.0);
        KinState {
            course_rad: course,
            roll_rad: g_roll + air * (bank - g_roll) + gust * plan.turb[0].value(t),
            pitch_rad: g_pitch + air * (fly_pitch - g_pitch) + gust * plan.turb[1].value(t),
            yaw_rad: course + air * crab + gust * plan.turb[2].value(t),
            h_agl_m: h,
            climb_mps: climb,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turn_progress_is_consistent() {
        let (rate, plateau, dur) = turn_shape(1.5, 0.05, 3.0);
        let (dc, r) = turn_progress(dur, rate, 3.0, plateau);
        assert!((dc - 1.5).abs() < 1e-12 && r.abs() < 1e-12);
        let h = 1e-5;
        for k in 1..40 {
            let t = k as f64 * dur / 40.0;
            let num = (turn_progress(t + h, rate, 3.0, plateau).0
                - turn_progress(t - h, rate, 3.0, plateau).0)
                / (2.0 * h);
            assert!((num - turn_progress(t, rate, 3.0, plateau).1).abs() < 1e-6);
        }
    }

    #[test]
    fn connector_reaches_target_line() {
        let mut b = Builder::new([0.0, 0.0], 0.0, 60.0, 3f64.to_radians());
        let tgt = [500.0, 200.0];
        let d = b.connect(tgt, PI, 300.0).unwrap();
        assert!(d >= 300.0 - 1e-6);
        b.straight(d / 60.0, Manoeuvre::Level, 0.0, 1.0, "x");
        assert!(
            (b.pos[0] - tgt[0]).abs() < 0.01 && (b.pos[1] - tgt[1]).abs() < 0.01,
            "{:?}",
            b.pos
        );
    }
}
