//! Several scalar magnetometers on one aircraft in one filter (model.md §7, issue 19).
//!
//! The anomaly is common to every sensor (to first order in their separation); the
//! aircraft's interference is each sensor's own. The state is
//!
//! `[5 shared field states | S−1 level differences | sensor 0's coefficients | … | sensor S−1's]`
//!
//! and each sensor's scalar sample is one scalar measurement update whose `h` holds the
//! field part and that sensor's regressors (zeros elsewhere). With independent sensor
//! noises, S sequential scalar updates are exactly the joint S-vector update, so the
//! existing Bierman update serves unchanged.
//!
//! The anomaly at sensor j (offset `x_j` forward, `z_j` down from sensor 0, body frame):
//! `B_h + x_j·∂B_h/∂s + x_j²/2·∂²B_h/∂s² + B_z·(dh − z_j) + δ_j`. The along-track and
//! vertical parts are the field states themselves; what they leave (the cross-track
//! gradient × the lateral offset, and each sensor's own unobservable constant, model.md §2)
//! is the level difference `δ_j`: a random walk along the track whose intensity the caller
//! sets from the separation (a lateral gradient that varies over the field's correlation
//! length). Sensor 0 carries no `δ`: the common level is the anomaly's.
//!
//! The difference states move, so they sit in the dynamic block after the field states:
//! 5 + (S − 1) ≤ [`MAX_DYNAMIC`] allows [`MAX_SENSORS`] = 4. Their process noise is a
//! second time update with Φ = I (two successive updates (Φ, Q₁) then (I, Q₂) are the one
//! update (Φ, Q₁ + Q₂)), so [`MAX_NOISE`] stays 5 and the board's single-sensor cost does
//! not change. Fixed size, no heap, f32.

use crate::filter::field::{FieldProcess, FIELD_STATES};
use crate::filter::ud::{Innovation, UdFilter, MAX_DYNAMIC, MAX_NOISE};

/// Most sensors one joint filter holds (5 field + 3 difference states = [`MAX_DYNAMIC`]).
pub const MAX_SENSORS: usize = MAX_DYNAMIC - FIELD_STATES + 1;

/// Why a joint filter could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JointError {
    /// No sensor, or more than [`MAX_SENSORS`].
    Sensors(usize),
    /// The states do not fit the capacity `N`.
    TooManyStates { needed: usize, capacity: usize },
    /// A prior, offset or noise that is not finite (or a 1σ that is not positive).
    BadConfig,
}

/// One sensor's part of the joint filter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointSensor<'a> {
    /// Offset from sensor 0 in the body frame (x forward, y starboard, z down), metres.
    pub offset_m: [f32; 3],
    /// Prior mean and 1σ of each coefficient (physical units, the model's order).
    pub prior_mean: &'a [f32],
    pub prior_sigma: &'a [f32],
    /// Prior 1σ of the level difference to sensor 0 (nT; unused for sensor 0): each
    /// sensor's constant is unobservable on its own, so this is wide.
    pub level_prior_nt: f32,
    /// Random-walk intensity of the level difference (nT²/m of track; unused for sensor 0).
    pub difference_q_nt2_per_m: f32,
}

/// The joint filter: shared field states, per-sensor level differences and coefficients.
#[derive(Clone, Debug)]
pub struct JointFilter<const N: usize> {
    filter: UdFilter<N>,
    field: FieldProcess,
    sensors: usize,
    offset_m: [[f32; 3]; MAX_SENSORS],
    difference_q: [f32; MAX_SENSORS],
    coef_at: [usize; MAX_SENSORS],
    coef_len: [usize; MAX_SENSORS],
    scale: [f32; N],
    n: usize,
    n_dyn: usize,
}

impl<const N: usize> JointFilter<N> {
    /// A filter for `sensors` (sensor 0 first) over the anomaly process `field`.
    pub fn new(field: FieldProcess, sensors: &[JointSensor]) -> Result<Self, JointError> {
        let s = sensors.len();
        if s == 0 || s > MAX_SENSORS {
            return Err(JointError::Sensors(s));
        }
        let n_dyn = FIELD_STATES + s - 1;
        let mut coef_at = [0usize; MAX_SENSORS];
        let mut coef_len = [0usize; MAX_SENSORS];
        let mut at = n_dyn;
        for (j, sensor) in sensors.iter().enumerate() {
            if sensor.prior_mean.len() != sensor.prior_sigma.len() {
                return Err(JointError::BadConfig);
            }
            coef_at[j] = at;
            coef_len[j] = sensor.prior_mean.len();
            at += coef_len[j];
        }
        let n = at;
        if n > N {
            return Err(JointError::TooManyStates {
                needed: n,
                capacity: N,
            });
        }
        let mut scale = [1.0f32; N];
        let mut x0 = [0.0f32; N];
        scale[..FIELD_STATES].copy_from_slice(&field.scale);
        let mut offset_m = [[0.0f32; 3]; MAX_SENSORS];
        let mut difference_q = [0.0f32; MAX_SENSORS];
        for (j, sensor) in sensors.iter().enumerate() {
            offset_m[j] = sensor.offset_m;
            if j > 0 {
                scale[FIELD_STATES + j - 1] = sensor.level_prior_nt;
                difference_q[j] = sensor.difference_q_nt2_per_m;
            }
            for i in 0..coef_len[j] {
                scale[coef_at[j] + i] = sensor.prior_sigma[i];
                x0[coef_at[j] + i] = sensor.prior_mean[i] / sensor.prior_sigma[i];
            }
        }
        let finite = |v: &f32| v.is_finite();
        if scale[..n].iter().any(|v| !(v.is_finite() && *v > 0.0))
            || !x0[..n].iter().all(finite)
            || !offset_m.iter().flatten().all(finite)
            || difference_q.iter().any(|q| !(q.is_finite() && *q >= 0.0))
        {
            return Err(JointError::BadConfig);
        }
        let filter = UdFilter::new(n, &x0, &[1.0; N]).ok_or(JointError::BadConfig)?;
        Ok(Self {
            filter,
            field,
            sensors: s,
            offset_m,
            difference_q,
            coef_at,
            coef_len,
            scale,
            n,
            n_dyn,
        })
    }

    pub fn sensors(&self) -> usize {
        self.sensors
    }
    pub fn state_count(&self) -> usize {
        self.n
    }
    pub fn filter(&self) -> &UdFilter<N> {
        &self.filter
    }
    /// Where sensor `j`'s coefficients start in the state, and how many.
    pub fn coefficient_block(&self, j: usize) -> (usize, usize) {
        (self.coef_at[j], self.coef_len[j])
    }

    /// Time update over `ds_m` metres of track: the field's dynamics (model.md §3) and the
    /// level differences' random walks. None without movement.
    pub fn predict(&mut self, ds_m: f32, field_noise_scale: f32) {
        if !(ds_m > 0.0 && ds_m.is_finite()) {
            return;
        }
        let mut phi = [[0.0f32; MAX_DYNAMIC]; MAX_DYNAMIC];
        let mut g = [[0.0f32; MAX_DYNAMIC]; MAX_NOISE];
        let mut dq = [0.0f32; MAX_NOISE];
        self.field.discretise(ds_m, 0, &mut phi, &mut g, &mut dq);
        for v in dq.iter_mut() {
            *v *= field_noise_scale;
        }
        self.filter.time_update(self.n_dyn, &phi, &g, &dq);
        if self.sensors > 1 {
            // Φ = I: only the differences' noise (the field's was added above).
            for (i, row) in phi.iter_mut().enumerate() {
                for (k, v) in row.iter_mut().enumerate() {
                    *v = if i == k { 1.0 } else { 0.0 };
                }
            }
            for col in g.iter_mut() {
                *col = [0.0; MAX_DYNAMIC];
            }
            let q = self.sensors - 1;
            for k in 0..q {
                let at = FIELD_STATES + k;
                g[k][at] = 1.0;
                dq[k] = self.difference_q[k + 1] * ds_m / (self.scale[at] * self.scale[at]);
            }
            self.filter.time_update(self.n_dyn, &phi, &g, &dq[..q]);
        }
    }

    /// The scaled measurement row of sensor `j` at height `dh_m` above `h0` with the
    /// physical regressors `phys` of its terms.
    fn row(&self, j: usize, dh_m: f32, phys: &[f32], h: &mut [f32; N]) {
        *h = [0.0; N];
        let [x, _, z] = self.offset_m[j];
        let dh = if dh_m.is_finite() { dh_m - z } else { 0.0 };
        let field_h = [1.0, x, 0.5 * x * x, dh, 0.0];
        for k in 0..FIELD_STATES {
            h[k] = field_h[k] * self.scale[k];
        }
        if j > 0 {
            h[FIELD_STATES + j - 1] = self.scale[FIELD_STATES + j - 1];
        }
        let at = self.coef_at[j];
        for i in 0..self.coef_len[j].min(phys.len()) {
            h[at + i] = phys[i] * self.scale[at + i];
        }
    }

    /// One sensor's scalar sample `z_nt` (relative to its own first value) with noise
    /// variance `r_nt2`; rejected (filter untouched, `Err`) when the innovation is beyond
    /// `gate_sigma` of its predicted 1σ (0 = no gate). `None`: bad input.
    pub fn update(
        &mut self,
        j: usize,
        dh_m: f32,
        phys: &[f32],
        z_nt: f32,
        r_nt2: f32,
        gate_sigma: f32,
    ) -> Option<Result<Innovation, Innovation>> {
        if j >= self.sensors {
            return None;
        }
        let mut h = [0.0f32; N];
        self.row(j, dh_m, phys, &mut h);
        self.filter
            .update_gated(&h[..self.n], z_nt, r_nt2, |nu, s| {
                gate_sigma > 0.0 && nu * nu > gate_sigma * gate_sigma * s
            })
    }

    /// Holds a combination of sensor `j`'s coefficients at its present value (as
    /// [`crate::compensator::Compensator::hold_coefficient_combination`]: `w` in prior-σ
    /// units, measured unchanged with a variance of 1e-6 of the prior). False if `w` does
    /// not fit the block or is not finite.
    pub fn hold_combination(&mut self, j: usize, w: &[f32]) -> bool {
        if j >= self.sensors || w.len() != self.coef_len[j] || w.iter().any(|v| !v.is_finite()) {
            return false;
        }
        let mut h = [0.0f32; N];
        let at = self.coef_at[j];
        h[at..at + w.len()].copy_from_slice(w);
        let z = self.filter.predict(&h[..self.n]);
        let norm2: f32 = w.iter().map(|v| v * v).sum();
        matches!(
            self.filter
                .update_gated(&h[..self.n], z, 1e-6 * norm2.max(1e-12), |_, _| false),
            Some(Ok(_))
        )
    }

    /// The prediction of sensor `j`'s sample (anomaly + level difference + interference).
    pub fn predict_measurement(&self, j: usize, dh_m: f32, phys: &[f32]) -> f32 {
        let mut h = [0.0f32; N];
        self.row(j, dh_m, phys, &mut h);
        self.filter.predict(&h[..self.n])
    }

    /// Sensor `j`'s coefficients (physical units) into `out`; returns how many.
    pub fn coefficients(&self, j: usize, out: &mut [f32]) -> usize {
        let (at, len) = (self.coef_at[j], self.coef_len[j]);
        let x = self.filter.state();
        let k = len.min(out.len());
        for i in 0..k {
            out[i] = x[at + i] * self.scale[at + i];
        }
        k
    }

    /// Covariance of sensor `j`'s coefficients `a`, `b` (physical units).
    pub fn coefficient_covariance(&self, j: usize, a: usize, b: usize) -> f32 {
        let (ia, ib) = (self.coef_at[j] + a, self.coef_at[j] + b);
        self.filter.covariance(ia, ib) * self.scale[ia] * self.scale[ib]
    }

    /// The anomaly at sensor `j` as the filter has it (nT, relative to sensor 0's first
    /// value), with its level difference.
    pub fn anomaly_nt(&self, j: usize, dh_m: f32) -> f32 {
        let x = self.filter.state();
        let [ox, _, oz] = self.offset_m[j];
        let dh = if dh_m.is_finite() { dh_m - oz } else { 0.0 };
        let s = &self.scale;
        let mut a = x[0] * s[0] + ox * x[1] * s[1] + 0.5 * ox * ox * x[2] * s[2] + dh * x[3] * s[3];
        if j > 0 {
            let d = FIELD_STATES + j - 1;
            a += x[d] * s[d];
        }
        a
    }

    /// Sensor `j`'s level difference to sensor 0 and its 1σ (nT); (0, 0) for sensor 0.
    pub fn difference_nt(&self, j: usize) -> (f32, f32) {
        if j == 0 || j >= self.sensors {
            return (0.0, 0.0);
        }
        let d = FIELD_STATES + j - 1;
        (
            self.filter.state()[d] * self.scale[d],
            libm::sqrtf(self.filter.variance(d).max(0.0)) * self.scale[d],
        )
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec::Vec;

    fn field() -> FieldProcess {
        FieldProcess::new(1e-6, 1e-7, 1000.0, 100.0)
    }

    /// Dense covariance of the filter in scaled states (f64).
    fn dense<const N: usize>(f: &UdFilter<N>) -> Vec<Vec<f64>> {
        let n = f.len();
        (0..n)
            .map(|i| (0..n).map(|j| f.covariance(i, j) as f64).collect())
            .collect()
    }

    /// Two sensors' sequential scalar updates are the joint 2-vector update (independent
    /// noises): the state and covariance agree with the batch Kalman formulas.
    #[test]
    fn sequential_scalar_updates_are_the_joint_update() {
        let (m0, s0) = ([1.0f32, -2.0, 0.5], [10.0f32, 10.0, 10.0]);
        let sensors = [
            JointSensor {
                offset_m: [0.0; 3],
                prior_mean: &m0,
                prior_sigma: &s0,
                level_prior_nt: 1.0,
                difference_q_nt2_per_m: 0.0,
            },
            JointSensor {
                offset_m: [-3.0, 8.0, 0.5],
                prior_mean: &m0,
                prior_sigma: &s0,
                level_prior_nt: 50.0,
                difference_q_nt2_per_m: 1e-4,
            },
        ];
        let mut f = JointFilter::<16>::new(field(), &sensors).unwrap();
        f.predict(60.0, 1.0);
        let p = dense(f.filter());
        let x: Vec<f64> = f.filter().state().iter().map(|v| *v as f64).collect();
        let n = f.state_count();
        let (phys_a, phys_b) = ([0.3f32, -0.7, 0.6], [0.5f32, 0.2, -0.8]);
        let mut h = [[0.0f32; 16]; 2];
        f.row(0, 12.0, &phys_a, &mut h[0]);
        f.row(1, 12.0, &phys_b, &mut h[1]);
        let (z, r) = ([5.0f64, -3.0], [0.04f64, 0.09]);
        // Batch: K = P Hᵀ (H P Hᵀ + R)⁻¹.
        let hp: Vec<Vec<f64>> = (0..2)
            .map(|a| {
                (0..n)
                    .map(|j| (0..n).map(|i| h[a][i] as f64 * p[i][j]).sum())
                    .collect()
            })
            .collect();
        let mut s = [[0.0f64; 2]; 2];
        for a in 0..2 {
            for b in 0..2 {
                s[a][b] = (0..n).map(|i| hp[a][i] * h[b][i] as f64).sum::<f64>()
                    + if a == b { r[a] } else { 0.0 };
            }
        }
        let det = s[0][0] * s[1][1] - s[0][1] * s[1][0];
        let si = [
            [s[1][1] / det, -s[0][1] / det],
            [-s[1][0] / det, s[0][0] / det],
        ];
        let nu: Vec<f64> = (0..2)
            .map(|a| z[a] - (0..n).map(|i| h[a][i] as f64 * x[i]).sum::<f64>())
            .collect();
        let xb: Vec<f64> = (0..n)
            .map(|i| {
                x[i] + (0..2)
                    .map(|a| (0..2).map(|b| hp[a][i] * si[a][b] * nu[b]).sum::<f64>())
                    .sum::<f64>()
            })
            .collect();
        let pb = |i: usize, j: usize| {
            p[i][j]
                - (0..2)
                    .map(|a| (0..2).map(|b| hp[a][i] * si[a][b] * hp[b][j]).sum::<f64>())
                    .sum::<f64>()
        };
        f.update(0, 12.0, &phys_a, z[0] as f32, r[0] as f32, 0.0)
            .unwrap()
            .unwrap();
        f.update(1, 12.0, &phys_b, z[1] as f32, r[1] as f32, 0.0)
            .unwrap()
            .unwrap();
        let ps = dense(f.filter());
        for i in 0..n {
            let xi = f.filter().state()[i] as f64;
            assert!((xi - xb[i]).abs() < 1e-4 * (1.0 + xb[i].abs()), "x[{i}]");
            for j in 0..n {
                assert!(
                    (ps[i][j] - pb(i, j)).abs() < 1e-4 * (1.0 + p[i][i].max(p[j][j])),
                    "P[{i}][{j}] {} vs {}",
                    ps[i][j],
                    pb(i, j)
                );
            }
        }
    }

    /// A shared anomaly with no interference: both sensors see it, sensor 1 offset by a
    /// constant; the difference state finds the offset, the field states the anomaly.
    #[test]
    fn the_difference_state_takes_the_offset_between_sensors() {
        let m = [0.0f32; 1];
        let s = [1.0f32; 1];
        let sensors = [
            JointSensor {
                offset_m: [0.0; 3],
                prior_mean: &m,
                prior_sigma: &s,
                level_prior_nt: 1.0,
                difference_q_nt2_per_m: 0.0,
            },
            JointSensor {
                offset_m: [0.0, 10.0, 0.0],
                prior_mean: &m,
                prior_sigma: &s,
                level_prior_nt: 1000.0,
                difference_q_nt2_per_m: 1e-6,
            },
        ];
        let mut f = JointFilter::<16>::new(field(), &sensors).unwrap();
        for k in 0..2000 {
            let a = 5.0 * libm::sinf(k as f32 * 0.01);
            f.predict(6.0, 1.0);
            f.update(0, 0.0, &[0.0], a, 1e-4, 0.0);
            f.update(1, 0.0, &[0.0], a + 250.0, 1e-4, 0.0);
        }
        let (d, sd) = f.difference_nt(1);
        assert!((d - 250.0).abs() < 0.05 && sd < 0.1, "{d} ± {sd}");
        let a = 5.0 * libm::sinf(1999.0 * 0.01);
        assert!((f.anomaly_nt(0, 0.0) - a).abs() < 0.05);
        assert!((f.anomaly_nt(1, 0.0) - a - 250.0).abs() < 0.05);
        assert!(f.filter().is_healthy());
    }

    #[test]
    fn sizes_are_checked() {
        let m = [0.0f32; 16];
        let s = [1.0f32; 16];
        let one = JointSensor {
            offset_m: [0.0; 3],
            prior_mean: &m,
            prior_sigma: &s,
            level_prior_nt: 1.0,
            difference_q_nt2_per_m: 0.0,
        };
        assert_eq!(
            JointFilter::<64>::new(field(), &[one; 5]).unwrap_err(),
            JointError::Sensors(5)
        );
        assert!(matches!(
            JointFilter::<32>::new(field(), &[one; 2]).unwrap_err(),
            JointError::TooManyStates { needed: 38, .. }
        ));
        assert_eq!(
            JointFilter::<80>::new(field(), &[one; 4])
                .unwrap()
                .state_count(),
            72
        );
    }
}
