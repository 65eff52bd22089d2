//! Several scalar magnetometers on one aircraft in one filter (model.md §7, issue 19).
//!
//! The anomaly is common to every sensor (to first order in their separation); the
//! aircraft's interference is each sensor's own. The state is
//!
//! `[5 field states, the cross-track gradient g_y (with a lateral sensor) | c_1, sensor 1's
//! coefficients | … | sensor S−1's]` (sensor 0's block has no c)
//!
//! and each sensor's scalar sample is one scalar measurement update whose `h` holds the
//! field part and that sensor's regressors (zeros elsewhere). With independent sensor
//! noises, S sequential scalar updates are exactly the joint S-vector update, so the
//! existing Bierman update serves unchanged.
//!
//! The anomaly at sensor j, whose offset from sensor 0 is `a` along the track, `c` across
//! it (starboard) and `d` down at this instant (the body offset turned by the attitude:
//! a wingtip 8 m out rises and falls 1.4 m in a 10° roll):
//! `B_h + a·∂B_h/∂s + a²/2·∂²B_h/∂s² + B_z·(dh − d) + c·g_y + c_j`.
//! The along-track and vertical parts are the paper's field states themselves; the
//! cross-track gradient `g_y`, shared by every sensor, is a random walk along the track
//! (its intensity set by the caller from the anomaly's roughness); `c_j` is sensor j's own
//! constant, unobservable alone (model.md §2), a static state. Sensor 0 has no `c`: the
//! common level is the anomaly's.
//!
//! `g_y` moves, so it sits in the dynamic block after the field states (6 ≤
//! [`MAX_DYNAMIC`]); its process noise is a second time update with Φ = I (two successive
//! updates (Φ, Q₁) then (I, Q₂) are the one update (Φ, Q₁ + Q₂)), so [`MAX_NOISE`] stays 5
//! and the board's single-sensor path does not change. Fixed size, no heap, f32.

use crate::filter::field::{FieldProcess, FIELD_STATES};
use crate::filter::ud::{Innovation, UdFilter, MAX_DYNAMIC, MAX_NOISE};

/// Most sensors one joint filter holds (`mag_1` … `mag_8`).
pub const MAX_SENSORS: usize = 8;

/// Why a joint filter could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JointError {
    /// No sensor, or more than [`MAX_SENSORS`].
    Sensors(usize),
    /// The states do not fit the capacity `N`.
    TooManyStates { needed: usize, capacity: usize },
    /// A prior or noise that is not finite (or a 1σ that is not positive).
    BadConfig,
}

/// One sensor's part of the joint filter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointSensor<'a> {
    /// Prior mean and 1σ of each coefficient (physical units, the model's order).
    pub prior_mean: &'a [f32],
    pub prior_sigma: &'a [f32],
    /// Prior 1σ of its constant against sensor 0 (nT; unused for sensor 0): each sensor's
    /// constant is unobservable on its own, so this is wide.
    pub level_prior_nt: f32,
}

/// Where a sensor is at one instant, relative to sensor 0 (metres): along the track,
/// across it (starboard) and down.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Placement {
    pub along_m: f32,
    pub across_m: f32,
    pub down_m: f32,
}

/// The cross-track gradient's random walk: prior 1σ (nT/m) and intensity (nT²/m³).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LateralGradient {
    pub prior_nt_per_m: f32,
    pub q_nt2_per_m3: f32,
}

/// The joint filter: shared field states (and cross-track gradient), per-sensor constants
/// and coefficients.
#[derive(Clone, Debug)]
pub struct JointFilter<const N: usize> {
    filter: UdFilter<N>,
    field: FieldProcess,
    lateral: Option<LateralGradient>,
    sensors: usize,
    coef_at: [usize; MAX_SENSORS],
    coef_len: [usize; MAX_SENSORS],
    scale: [f32; N],
    n: usize,
    n_dyn: usize,
}

impl<const N: usize> JointFilter<N> {
    /// A filter for `sensors` (sensor 0 first) over the anomaly process `field`; with
    /// `lateral`, the cross-track gradient is a state.
    pub fn new(
        field: FieldProcess,
        lateral: Option<LateralGradient>,
        sensors: &[JointSensor],
    ) -> Result<Self, JointError> {
        let s = sensors.len();
        if s == 0 || s > MAX_SENSORS {
            return Err(JointError::Sensors(s));
        }
        let n_dyn = FIELD_STATES + usize::from(lateral.is_some());
        debug_assert!(n_dyn <= MAX_DYNAMIC);
        let mut coef_at = [0usize; MAX_SENSORS];
        let mut coef_len = [0usize; MAX_SENSORS];
        let mut at = n_dyn;
        for (j, sensor) in sensors.iter().enumerate() {
            if sensor.prior_mean.len() != sensor.prior_sigma.len() {
                return Err(JointError::BadConfig);
            }
            if j > 0 {
                at += 1; // c_j
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
        if let Some(l) = lateral {
            scale[FIELD_STATES] = l.prior_nt_per_m;
            if !(l.q_nt2_per_m3.is_finite() && l.q_nt2_per_m3 >= 0.0) {
                return Err(JointError::BadConfig);
            }
        }
        for (j, sensor) in sensors.iter().enumerate() {
            if j > 0 {
                scale[coef_at[j] - 1] = sensor.level_prior_nt;
            }
            for i in 0..coef_len[j] {
                scale[coef_at[j] + i] = sensor.prior_sigma[i];
                x0[coef_at[j] + i] = sensor.prior_mean[i] / sensor.prior_sigma[i];
            }
        }
        if scale[..n].iter().any(|v| !(v.is_finite() && *v > 0.0))
            || !x0[..n].iter().all(|v| v.is_finite())
        {
            return Err(JointError::BadConfig);
        }
        let filter = UdFilter::new(n, &x0, &[1.0; N]).ok_or(JointError::BadConfig)?;
        Ok(Self {
            filter,
            field,
            lateral,
            sensors: s,
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
    /// cross-track gradient's random walk. None without movement.
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
        if let Some(l) = self.lateral {
            // Φ = I: only the gradient's noise (the field's was added above).
            for (i, row) in phi.iter_mut().enumerate() {
                for (k, v) in row.iter_mut().enumerate() {
                    *v = if i == k { 1.0 } else { 0.0 };
                }
            }
            for col in g.iter_mut() {
                *col = [0.0; MAX_DYNAMIC];
            }
            let at = FIELD_STATES;
            g[0][at] = 1.0;
            let q = [l.q_nt2_per_m3 * ds_m / (self.scale[at] * self.scale[at])];
            self.filter.time_update(self.n_dyn, &phi, &g, &q);
        }
    }

    /// The scaled measurement row of sensor `j` at `place`, height `dh_m` above `h0`, with
    /// the physical regressors `phys` of its terms.
    fn row(&self, j: usize, place: Placement, dh_m: f32, phys: &[f32], h: &mut [f32; N]) {
        *h = [0.0; N];
        let a = place.along_m;
        let dh = if dh_m.is_finite() { dh_m } else { 0.0 } - place.down_m;
        let field_h = [1.0, a, 0.5 * a * a, dh, 0.0];
        for k in 0..FIELD_STATES {
            h[k] = field_h[k] * self.scale[k];
        }
        if self.lateral.is_some() {
            h[FIELD_STATES] = place.across_m * self.scale[FIELD_STATES];
        }
        let at = self.coef_at[j];
        if j > 0 {
            h[at - 1] = self.scale[at - 1];
        }
        for i in 0..self.coef_len[j].min(phys.len()) {
            h[at + i] = phys[i] * self.scale[at + i];
        }
    }

    /// One sensor's scalar sample `z_nt` (relative to its own first value) with noise
    /// variance `r_nt2`; rejected (filter untouched, `Err`) when the innovation is beyond
    /// `gate_sigma` of its predicted 1σ (0 = no gate). `None`: bad input.
    #[allow(clippy::too_many_arguments)]
    pub fn update(
        &mut self,
        j: usize,
        place: Placement,
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
        self.row(j, place, dh_m, phys, &mut h);
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

    /// The anomaly at sensor `j` at `place` as the filter has it (nT, relative to sensor
    /// 0's first value), with the sensor's constant.
    pub fn anomaly_nt(&self, j: usize, place: Placement, dh_m: f32) -> f32 {
        let mut h = [0.0f32; N];
        self.row(j, place, dh_m, &[], &mut h);
        self.filter.predict(&h[..self.n])
    }

    /// The cross-track gradient and its 1σ (nT/m), when it is a state.
    pub fn lateral_gradient(&self) -> Option<(f32, f32)> {
        self.lateral?;
        let i = FIELD_STATES;
        Some((
            self.filter.state()[i] * self.scale[i],
            libm::sqrtf(self.filter.variance(i).max(0.0)) * self.scale[i],
        ))
    }

    /// Sensor `j`'s constant against sensor 0 and its 1σ (nT); (0, 0) for sensor 0.
    pub fn level_nt(&self, j: usize) -> (f32, f32) {
        if j == 0 || j >= self.sensors {
            return (0.0, 0.0);
        }
        let d = self.coef_at[j] - 1;
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
                prior_mean: &m0,
                prior_sigma: &s0,
                level_prior_nt: 1.0,
            },
            JointSensor {
                prior_mean: &m0,
                prior_sigma: &s0,
                level_prior_nt: 50.0,
            },
        ];
        let lat = Some(LateralGradient {
            prior_nt_per_m: 0.5,
            q_nt2_per_m3: 1e-4,
        });
        let mut f = JointFilter::<16>::new(field(), lat, &sensors).unwrap();
        f.predict(60.0, 1.0);
        let (p0, p1) = (
            Placement::default(),
            Placement {
                along_m: -3.0,
                across_m: 8.0,
                down_m: 0.5,
            },
        );
        let p = dense(f.filter());
        let x: Vec<f64> = f.filter().state().iter().map(|v| *v as f64).collect();
        let n = f.state_count();
        let (phys_a, phys_b) = ([0.3f32, -0.7, 0.6], [0.5f32, 0.2, -0.8]);
        let mut h = [[0.0f32; 16]; 2];
        f.row(0, p0, 12.0, &phys_a, &mut h[0]);
        f.row(1, p1, 12.0, &phys_b, &mut h[1]);
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
        f.update(0, p0, 12.0, &phys_a, z[0] as f32, r[0] as f32, 0.0)
            .unwrap()
            .unwrap();
        f.update(1, p1, 12.0, &phys_b, z[1] as f32, r[1] as f32, 0.0)
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

    /// A shared anomaly with no interference: sensor 1, 10 m to starboard, sees it with a
    /// constant offset and a cross-track gradient; the filter finds both.
    #[test]
    fn the_constant_and_the_lateral_gradient_are_found() {
        let m = [0.0f32; 1];
        let s = [1.0f32; 1];
        let sensors = [
            JointSensor {
                prior_mean: &m,
                prior_sigma: &s,
                level_prior_nt: 1.0,
            },
            JointSensor {
                prior_mean: &m,
                prior_sigma: &s,
                level_prior_nt: 1000.0,
            },
        ];
        let lat = Some(LateralGradient {
            prior_nt_per_m: 1.0,
            q_nt2_per_m3: 1e-8,
        });
        let mut f = JointFilter::<16>::new(field(), lat, &sensors).unwrap();
        let p1 = |k: usize| Placement {
            along_m: 0.0,
            across_m: 10.0 + 2.0 * libm::sinf(k as f32 * 0.3),
            down_m: 0.0,
        };
        for k in 0..2000 {
            let a = 5.0 * libm::sinf(k as f32 * 0.01);
            f.predict(6.0, 1.0);
            f.update(0, Placement::default(), 0.0, &[0.0], a, 1e-4, 0.0);
            f.update(
                1,
                p1(k),
                0.0,
                &[0.0],
                a + 250.0 + 0.3 * p1(k).across_m,
                1e-4,
                0.0,
            );
        }
        let (c, sc) = f.level_nt(1);
        let (g, sg) = f.lateral_gradient().unwrap();
        assert!((c - 250.0).abs() < 0.1 && sc < 0.5, "{c} ± {sc}");
        assert!((g - 0.3).abs() < 0.01 && sg < 0.05, "{g} ± {sg}");
        let a = 5.0 * libm::sinf(1999.0 * 0.01);
        assert!((f.anomaly_nt(0, Placement::default(), 0.0) - a).abs() < 0.05);
        assert!(f.filter().is_healthy());
    }

    #[test]
    fn sizes_are_checked() {
        let m = [0.0f32; 16];
        let s = [1.0f32; 16];
        let one = JointSensor {
            prior_mean: &m,
            prior_sigma: &s,
            level_prior_nt: 1.0,
        };
        assert_eq!(
            JointFilter::<64>::new(field(), None, &[one; 9]).unwrap_err(),
            JointError::Sensors(9)
        );
        assert!(matches!(
            JointFilter::<32>::new(field(), None, &[one; 2]).unwrap_err(),
            JointError::TooManyStates { needed: 38, .. }
        ));
        let lat = Some(LateralGradient {
            prior_nt_per_m: 1.0,
            q_nt2_per_m3: 0.0,
        });
        assert_eq!(
            JointFilter::<80>::new(field(), lat, &[one; 4])
                .unwrap()
                .state_count(),
            6 + 3 + 64
        );
    }
}
