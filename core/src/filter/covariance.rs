//! The same filter in plain covariance form, f32 — kept only as the benchmark yardstick the
//! square-root form is compared with (model.md §5: it is the form that diverged in f32 in
//! harsh cases). Same structure: only the leading `m` states move.

use super::ud::{Innovation, MAX_DYNAMIC, MAX_NOISE};

#[derive(Clone, Debug)]
pub struct CovFilter<const N: usize> {
    x: [f32; N],
    p: [[f32; N]; N],
    n: usize,
}

impl<const N: usize> CovFilter<N> {
    pub fn new(n: usize, sigma0: &[f32]) -> Option<Self> {
        if n > N || sigma0.len() < n {
            return None;
        }
        let mut p = [[0.0; N]; N];
        for i in 0..n {
            p[i][i] = sigma0[i] * sigma0[i];
        }
        Some(Self { x: [0.0; N], p, n })
    }

    pub fn state(&self) -> &[f32] {
        &self.x[..self.n]
    }

    /// `P ← ΦPΦᵀ + G·Dq·Gᵀ` on the leading `m` states (Φ unit upper triangular there).
    pub fn time_update(
        &mut self,
        m: usize,
        phi: &[[f32; MAX_DYNAMIC]; MAX_DYNAMIC],
        g: &[[f32; MAX_DYNAMIC]; MAX_NOISE],
        dq: &[f32],
    ) {
        let n = self.n;
        for i in 0..m {
            let mut s = self.x[i];
            for k in i + 1..m {
                s += phi[i][k] * self.x[k];
            }
            self.x[i] = s;
        }
        // Rows 0..m: P ← ΦP (row i uses rows ≥ i: ascending order works in place).
        for i in 0..m {
            for j in 0..n {
                let mut s = self.p[i][j];
                for k in i + 1..m {
                    s += phi[i][k] * self.p[k][j];
                }
                self.p[i][j] = s;
            }
        }
        // Columns 0..m: P ← PΦᵀ.
        for j in 0..n {
            for i in 0..m {
                let mut s = self.p[j][i];
                for k in i + 1..m {
                    s += phi[i][k] * self.p[j][k];
                }
                self.p[j][i] = s;
            }
        }
        for (k, dqk) in dq.iter().enumerate().take(MAX_NOISE) {
            for i in 0..m {
                for j in 0..m {
                    self.p[i][j] += g[k][i] * g[k][j] * dqk;
                }
            }
        }
    }

    /// Scalar update in the symmetric form `P ← P − K·(Ph)ᵀ`.
    pub fn update(&mut self, h: &[f32], z: f32, r: f32) -> Option<Innovation> {
        let n = self.n;
        let mut ph = [0.0f32; N];
        let mut pred = 0.0;
        for i in 0..n {
            let mut s = 0.0;
            for j in 0..n {
                s += self.p[i][j] * h[j];
            }
            ph[i] = s;
            pred += h[i] * self.x[i];
        }
        let mut s = r;
        for i in 0..n {
            s += h[i] * ph[i];
        }
        if !(s > 0.0 && s.is_finite()) {
            return None;
        }
        let nu = z - pred;
        let inv = 1.0 / s;
        for i in 0..n {
            self.x[i] += ph[i] * inv * nu;
            let ki = ph[i] * inv;
            for j in 0..n {
                self.p[i][j] -= ki * ph[j];
            }
        }
        Some(Innovation {
            value: nu,
            variance: s,
        })
    }
}
