//! The sampling clock and the true path of the sensor: sample times, and the position at
//! each one integrated from the plan's analytic velocity.

use super::config::SimConfig;
use super::flight::Plan;
use anyhow::{ensure, Result};
use nalgebra::Vector3;

/// The sample times of a flight and what they follow from.
pub(super) struct Clock {
    /// Flight duration (s): the plan's, cut at `max_duration_s`.
    pub(super) dur: f64,
    /// Scalar sample rate (Hz) and its period (s).
    pub(super) rate: f64,
    pub(super) dt: f64,
    /// Number of samples and their times (s from the start).
    pub(super) n: usize,
    pub(super) times: Vec<f64>,
}

impl Clock {
    pub(super) fn new(cfg: &SimConfig, plan: &Plan) -> Result<Self> {
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
        Ok(Clock {
            dur,
            rate,
            dt,
            n,
            times,
        })
    }
}

/// True sensor position at every sample (local NED, m): the horizontal track by the
/// trapezoid rule on the analytic velocity with ≤ 5 ms sub-steps, the height the plan's.
pub(super) fn positions(cfg: &SimConfig, plan: &Plan, clock: &Clock) -> Vec<Vector3<f64>> {
    let dt = clock.dt;
    let sub = (dt / 0.005).ceil().max(1.0) as usize;
    let hs = dt / sub as f64;
    let mut ne = Vec::with_capacity(clock.n);
    let mut p = plan.start_ne_m;
    let mut vel = plan.velocity(0.0);
    for (k, &t) in clock.times.iter().enumerate() {
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
    clock
        .times
        .iter()
        .zip(&ne)
        .map(|(&t, p)| Vector3::new(p[0], p[1], -(cfg.ground_elev_m + plan.height(t).0)))
        .collect()
}
