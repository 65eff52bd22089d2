//! Discrete dynamics of the anomaly model (model.md §3, the paper's eqs 6–8).
//!
//! Along-track distance `s` is the independent variable. `B_h` is third-order integrated
//! white noise (states `B_h, ∂B_h/∂s, ∂²B_h/∂s²`), the vertical gradient `B_z` second-order
//! (`B_z, ∂B_z/∂s`). Over a step `d` (m):
//! `Φ3 = [[1,d,d²/2],[0,1,d],[0,0,1]]`, `Q3 = σ1²[[d⁵/20,d⁴/8,d³/6],[d⁴/8,d³/3,d²/2],[d³/6,d²/2,d]]`,
//! `Φ2 = [[1,d],[0,1]]`, `Q2 = σ2²[[d³/3,d²/2],[d²/2,d]]`.
//! Q is used in its exact UD factorisation, derived by hand:
//! `Q3 = U3·diag(d⁵/720, d³/12, d)·U3ᵀ` with `U3 = [[1,d/2,d²/6],[0,1,d/2],[0,0,1]]`,
//! `Q2 = U2·diag(d³/12, d)·U2ᵀ` with `U2 = [[1,d/2],[0,1]]` — so no f32 factorisation of an
//! ill-conditioned 5×5 matrix is ever needed.

use super::ud::{MAX_DYNAMIC, MAX_NOISE};

/// Number of field states.
pub const FIELD_STATES: usize = 5;

/// Field-state parameters and their scaling.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldProcess {
    /// Driving-noise intensity of `∂³B_h/∂s³` (nT/m^2.5).
    pub sigma1: f32,
    /// Driving-noise intensity of `∂²B_z/∂s²` (nT/m^2.5).
    pub sigma2: f32,
    /// Scale (≈ prior 1σ) of each field state in physical units:
    /// nT, nT/m, nT/m², nT/m, nT/m².
    pub scale: [f32; FIELD_STATES],
}

impl FieldProcess {
    /// Scales from the process itself: over a length `l0_m` the model lets `B_h` wander by
    /// ~σ1·l0^2.5, its gradient by σ1·l0^1.5, its curvature by σ1·l0^0.5 (the paper's p11,
    /// p22 reasoning). `bh_prior_nt` covers the unknown offset of the first sample.
    pub fn new(sigma1: f32, sigma2: f32, l0_m: f32, bh_prior_nt: f32) -> Self {
        let s1 = sigma1.max(1e-12);
        let s2 = sigma2.max(1e-12);
        let l15 = libm::powf(l0_m, 1.5);
        let l05 = libm::sqrtf(l0_m);
        let l25 = l15 * l0_m;
        Self {
            sigma1: s1,
            sigma2: s2,
            scale: [
                bh_prior_nt.max(3.0 * s1 * l25),
                3.0 * s1 * l15,
                3.0 * s1 * l05,
                3.0 * s2 * l15,
                3.0 * s2 * l05,
            ],
        }
    }

    /// Fills Φ, G and Dq for a step of `ds_m` metres, in scaled states, with the field
    /// states at offset `off` of the dynamic block (the clones before them keep Φ = I).
    pub fn discretise(
        &self,
        ds_m: f32,
        off: usize,
        phi: &mut [[f32; MAX_DYNAMIC]; MAX_DYNAMIC],
        g: &mut [[f32; MAX_DYNAMIC]; MAX_NOISE],
        dq: &mut [f32; MAX_NOISE],
    ) {
        for (i, row) in phi.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = if i == j { 1.0 } else { 0.0 };
            }
        }
        for col in g.iter_mut() {
            *col = [0.0; MAX_DYNAMIC];
        }
        for k in 0..FIELD_STATES {
            g[k][off + k] = 1.0;
        }
        self.discretise_step(ds_m, off, phi, g, dq);
    }

    /// The part of [`discretise`](Self::discretise) that depends on the step: writes only
    /// the entries of Φ and G that vary with `ds_m`, and all of `dq`. On arrays
    /// `discretise` filled once (for any step, at the same `off`) it gives exactly what
    /// `discretise` gives: the compensator keeps Φ and G and so neither zeroes nor refills
    /// 104 floats every epoch.
    pub fn discretise_step(
        &self,
        ds_m: f32,
        off: usize,
        phi: &mut [[f32; MAX_DYNAMIC]; MAX_DYNAMIC],
        g: &mut [[f32; MAX_DYNAMIC]; MAX_NOISE],
        dq: &mut [f32; MAX_NOISE],
    ) {
        let d = ds_m.abs();
        let s = &self.scale;
        // Physical Φ and U_q entries, then x̃ = x/s: Φ̃_ij = Φ_ij s_j/s_i, Ũ_ij = U_ij s_j/s_i.
        let d2 = d * d;
        let p = [(0, 1, d), (0, 2, 0.5 * d2), (1, 2, d), (3, 4, d)];
        for &(i, j, v) in &p {
            phi[off + i][off + j] = v * s[j] / s[i];
        }
        let uq = [
            (0, 1, 0.5 * d),
            (0, 2, d2 / 6.0),
            (1, 2, 0.5 * d),
            (3, 4, 0.5 * d),
        ];
        for &(i, j, v) in &uq {
            g[j][off + i] = v * s[j] / s[i];
        }
        let v1 = self.sigma1 * self.sigma1;
        let v2 = self.sigma2 * self.sigma2;
        let d3 = d2 * d;
        let dphys = [
            v1 * d3 * d2 / 720.0,
            v1 * d3 / 12.0,
            v1 * d,
            v2 * d3 / 12.0,
            v2 * d,
        ];
        for k in 0..FIELD_STATES {
            dq[k] = dphys[k] / (s[k] * s[k]);
        }
    }
}
