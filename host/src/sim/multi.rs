//! Several scalar magnetometers on the simulated aircraft (issue 19 item 4).
//!
//! The flight is [`simulate_detailed`]'s: its scalar is sensor `mag_1`, at the
//! trajectory's point. Every further sensor sits at its own body-frame offset: the
//! anomaly is evaluated exactly at that point (the geology's dipoles, so the true gradient
//! is physical), the main field and the diurnal are the first sensor's (their change over
//! metres is < 0.05 nT), and it carries its own permanent/induced/eddy set (drawn as the
//! simulator draws one, from its own seed) and its own noise. All sensors share the
//! flight's fluxgate. Hidden effects act on `mag_1` only.
//!
//! Columns added: `mag_K`, `truth_interference_mag_K`, `truth_anomaly_mag_K` (`mag_1`'s
//! are copies of `mag`, `truth_interference`, `truth_anomaly`), and metadata
//! `mag_K_position_m: X,Y,Z` (body frame, metres from the trajectory's point).

use super::aircraft::draw_aircraft;
use super::sensors::scalar_readings;
use super::{dcm_ned_to_body, simulate_detailed, SimConfig};
use crate::io::trace::Trace;
use anyhow::{ensure, Result};
use nalgebra::Vector3;

/// Body-frame offsets of a stinger (the simulated point), two wingtips and a cabin sensor:
/// the wingtips 6 m ahead of the stinger and 8 m out, the cabin 9 m ahead.
pub const STINGER_WINGTIPS_CABIN_M: [[f64; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [6.0, -8.0, -0.5],
    [6.0, 8.0, -0.5],
    [9.0, 0.0, 0.5],
];

/// Simulates `cfg` with a scalar at each of `offsets_m` (the first must be the origin).
pub fn simulate_multi(cfg: &SimConfig, offsets_m: &[[f64; 3]]) -> Result<Trace> {
    ensure!(
        !offsets_m.is_empty() && offsets_m.len() <= 8 && offsets_m[0] == [0.0; 3],
        "1 to 8 sensors, the first at the origin"
    );
    let out = simulate_detailed(cfg)?;
    let (mut trace, truth) = (out.trace, out.truth);
    let n = truth.pos_ned_m.len();
    ensure!(n == trace.len(), "internal: truth and trace lengths differ");
    let dt = 1.0 / cfg.sample_rate_hz;
    for (k, off) in offsets_m.iter().enumerate() {
        let name = format!("mag_{}", k + 1);
        trace.meta.push((
            format!("{name}_position_m"),
            format!("{},{},{}", off[0], off[1], off[2]),
        ));
        if k == 0 {
            for (from, to) in [
                ("mag", name.clone()),
                ("truth_interference", format!("truth_interference_{name}")),
                ("truth_anomaly", format!("truth_anomaly_{name}")),
            ] {
                let v = trace.col(from).expect("simulated column").to_vec();
                trace.set_col(&to, v);
            }
            continue;
        }
        let r = Vector3::new(off[0], off[1], off[2]);
        // The anomaly's change from the first sensor to this one, in body axes.
        let delta: Vec<Vector3<f64>> = (0..n)
            .map(|i| {
                let [roll, pitch, yaw] = truth.att_rad[i];
                let c = dcm_ned_to_body(roll, pitch, yaw);
                let p = truth.pos_ned_m[i] + c.transpose() * r;
                c * (truth.anomaly.field_ned_nt(&p)
                    - truth.anomaly.field_ned_nt(&truth.pos_ned_m[i]))
            })
            .collect();
        let sensor_cfg = SimConfig {
            seed: cfg.seed.wrapping_mul(1000).wrapping_add(k as u64 * 7919),
            ..cfg.clone()
        };
        let a = draw_aircraft(&sensor_cfg);
        let mut clean = Vec::with_capacity(n);
        let mut interference = Vec::with_capacity(n);
        let mut anomaly = Vec::with_capacity(n);
        let anomaly_1 = trace.col("truth_anomaly").expect("simulated column");
        for i in 0..n {
            let b1 = truth.b_body_nt[i];
            let b = b1 + delta[i];
            // d(Δ)/dt by centred differences: Δ changes over seconds, the samples are ≤ 0.1 s.
            let (lo, hi) = (i.saturating_sub(1), (i + 1).min(n - 1));
            let d_delta = (delta[hi] - delta[lo]) / ((hi - lo).max(1) as f64 * dt);
            let db = truth.db_body_nt_s[i] + d_delta;
            let dbv = a.k + a.l * b + a.m * db;
            let total = (b + dbv).norm();
            clean.push(total);
            interference.push(total - b.norm());
            anomaly.push(anomaly_1[i] + b.norm() - b1.norm());
        }
        trace.set_col(&name, scalar_readings(&sensor_cfg, &clean));
        trace.set_col(&format!("truth_interference_{name}"), interference);
        trace.set_col(&format!("truth_anomaly_{name}"), anomaly);
    }
    Ok(trace)
}
