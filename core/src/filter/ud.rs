//! The UD filter proper. States are scaled by the caller so priors are O(1).

// Index loops mirror the equations (several arrays indexed together, triangular ranges)
// and compile to the fixed-length loops the instruction counts in model.md §5 were taken on.
#![allow(clippy::needless_range_loop)]

/// Innovation of one scalar measurement update.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Innovation {
    /// `z − h·x̂⁻` (measurement units).
    pub value: f32,
    /// Its predicted variance `h·P⁻·hᵀ + r`.
    pub variance: f32,
}

/// Largest block the time update re-factorises: tie-point clones plus the field states.
pub const MAX_DYNAMIC: usize = 8;
/// Largest number of process-noise columns (the field model has 5).
pub const MAX_NOISE: usize = 5;

/// UD-factorised Kalman filter over `n ≤ N` states. `U` is stored column-major
/// (`u[j][i] = U_ij`) so the inner loops of both updates run over contiguous memory.
#[derive(Clone, Debug)]
pub struct UdFilter<const N: usize> {
    x: [f32; N],
    u: [[f32; N]; N],
    d: [f32; N],
    n: usize,
}

impl<const N: usize> UdFilter<N> {
    /// `n` active states with independent priors `x0 ± sigma0` (already scaled).
    /// Returns `None` when `n > N` or a prior is not finite and positive.
    pub fn new(n: usize, x0: &[f32], sigma0: &[f32]) -> Option<Self> {
        if n > N || x0.len() < n || sigma0.len() < n {
            return None;
        }
        let mut f = Self {
            x: [0.0; N],
            u: [[0.0; N]; N],
            d: [0.0; N],
            n,
        };
        for i in 0..n {
            if !(sigma0[i].is_finite() && sigma0[i] > 0.0 && x0[i].is_finite()) {
                return None;
            }
            f.x[i] = x0[i];
            f.u[i][i] = 1.0;
            f.d[i] = sigma0[i] * sigma0[i];
        }
        Some(f)
    }

    pub fn len(&self) -> usize {
        self.n
    }
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }
    pub fn state(&self) -> &[f32] {
        &self.x[..self.n]
    }
    pub fn state_mut(&mut self) -> &mut [f32] {
        &mut self.x[..self.n]
    }
    pub fn d(&self) -> &[f32] {
        &self.d[..self.n]
    }
    /// `U_ij` (unit upper triangular).
    pub fn u(&self, i: usize, j: usize) -> f32 {
        if i == j {
            1.0
        } else if i < j {
            self.u[j][i]
        } else {
            0.0
        }
    }

    /// Variance of state `i`: `P_ii = Σ_j≥i U_ij² d_j`.
    pub fn variance(&self, i: usize) -> f32 {
        let mut p = self.d[i];
        for j in i + 1..self.n {
            let uij = self.u[j][i];
            p += uij * uij * self.d[j];
        }
        p
    }

    /// Covariance `P_ij`.
    pub fn covariance(&self, i: usize, j: usize) -> f32 {
        let (a, b) = if i <= j { (i, j) } else { (j, i) };
        // P_ab = Σ_k≥b U_ak U_bk d_k
        let mut p = 0.0;
        for k in b..self.n {
            p += self.u(a, k) * self.u(b, k) * self.d[k];
        }
        p
    }

    /// Bierman's scalar measurement update with regressor `h` (scaled), measurement `z` and
    /// noise variance `r`. Returns the innovation before the update. A non-finite input or
    /// a non-positive innovation variance leaves the filter untouched and returns `None`.
    pub fn update(&mut self, h: &[f32], z: f32, r: f32) -> Option<Innovation> {
        let n = self.n;
        if h.len() < n || !z.is_finite() || r.is_nan() || r <= 0.0 {
            return None;
        }
        // f = Uᵀh, g = D f
        let mut f = [0.0f32; N];
        let mut g = [0.0f32; N];
        let mut pred = 0.0f32;
        for j in 0..n {
            let col = &self.u[j];
            let mut fj = h[j];
            for i in 0..j {
                fj += col[i] * h[i];
            }
            if !fj.is_finite() {
                return None;
            }
            f[j] = fj;
            g[j] = self.d[j] * fj;
            pred += h[j] * self.x[j];
        }
        let innovation = z - pred;
        let mut alpha = r;
        let mut b = [0.0f32; N];
        for j in 0..n {
            let alpha_prev = alpha;
            alpha += f[j] * g[j];
            let lambda = -f[j] / alpha_prev;
            self.d[j] *= alpha_prev / alpha;
            let col = &mut self.u[j];
            let gj = g[j];
            for i in 0..j {
                let uij = col[i];
                col[i] = uij + lambda * b[i];
                b[i] += uij * gj;
            }
            b[j] = gj;
        }
        if !(alpha > 0.0 && alpha.is_finite()) {
            return None;
        }
        let k = innovation / alpha;
        for i in 0..n {
            self.x[i] += b[i] * k;
        }
        Some(Innovation {
            value: innovation,
            variance: alpha,
        })
    }

    /// Innovation variance `h·P·hᵀ + r` without updating (for gating and diagnostics).
    pub fn predicted_variance(&self, h: &[f32], r: f32) -> f32 {
        let mut s = r;
        for j in 0..self.n {
            let mut fj = h[j];
            for i in 0..j {
                fj += self.u[j][i] * h[i];
            }
            s += fj * fj * self.d[j];
        }
        s
    }

    /// `h·x̂`.
    pub fn predict(&self, h: &[f32]) -> f32 {
        let mut p = 0.0;
        for i in 0..self.n {
            p += h[i] * self.x[i];
        }
        p
    }

    /// Time update of the leading `m` states: `x ← Φx`, `P ← ΦPΦᵀ + G·Dq·Gᵀ`, where
    /// `phi` (m×m, unit upper triangular) acts on states `0..m` and the rest are constant.
    /// `g` (m×q, column-major `g[k][i]`) and `dq` (q) give the process noise in UD form.
    /// Thornton's MWGS re-factorises the m×m block; the coupling to the constant states
    /// is carried by `Φ·U₁₂` exactly.
    pub fn time_update(
        &mut self,
        m: usize,
        phi: &[[f32; MAX_DYNAMIC]; MAX_DYNAMIC],
        g: &[[f32; MAX_DYNAMIC]; MAX_NOISE],
        dq: &[f32],
    ) {
        let n = self.n;
        let q = dq.len().min(MAX_NOISE);
        if m == 0 || m > MAX_DYNAMIC || m > n {
            return;
        }
        // x ← Φx (upper triangular: row i uses rows ≥ i, so ascending order is in place)
        for i in 0..m {
            let mut s = self.x[i];
            for (k, xk) in self.x.iter().enumerate().take(m).skip(i + 1) {
                s += phi[i][k] * xk;
            }
            self.x[i] = s;
        }
        // U₁₂ ← Φ·U₁₂ (columns m..n, rows 0..m)
        for j in m..n {
            let col = &mut self.u[j];
            for i in 0..m {
                let mut s = col[i];
                for k in i + 1..m {
                    s += phi[i][k] * col[k];
                }
                col[i] = s;
            }
        }
        // Y = [Φ·U₁₁ | G] with weights [D₁ | Dq]; row i of Y is the i-th dynamic state.
        const W: usize = MAX_DYNAMIC + MAX_NOISE;
        let mut y = [[0.0f32; W]; MAX_DYNAMIC];
        let mut w = [0.0f32; W];
        for i in 0..m {
            y[i][i] = 1.0;
            for j in i + 1..m {
                // (ΦU)_ij = U_ij + Σ_{i<k<j} Φ_ik U_kj + Φ_ij (Φ_ii = U_jj = 1)
                let col = &self.u[j];
                let mut s = col[i] + phi[i][j];
                for k in i + 1..j {
                    s += phi[i][k] * col[k];
                }
                y[i][j] = s;
            }
        }
        for (j, wj) in w.iter_mut().enumerate().take(m) {
            *wj = self.d[j];
        }
        for k in 0..q {
            w[m + k] = dq[k];
            for (i, row) in y.iter_mut().enumerate().take(m) {
                row[m + k] = g[k][i];
            }
        }
        let cols = m + q;
        // MWGS, last row first (upper UD).
        for j in (0..m).rev() {
            let mut dj = 0.0f32;
            for k in 0..cols {
                dj += w[k] * y[j][k] * y[j][k];
            }
            self.d[j] = dj;
            for i in 0..j {
                let uij = if dj > 0.0 {
                    let mut s = 0.0f32;
                    for k in 0..cols {
                        s += w[k] * y[i][k] * y[j][k];
                    }
                    s / dj
                } else {
                    0.0
                };
                self.u[j][i] = uij;
                let (upper, lower) = y.split_at_mut(j);
                let yj = &lower[0];
                let yi = &mut upper[i];
                for k in 0..cols {
                    yi[k] -= uij * yj[k];
                }
            }
        }
    }

    /// Makes state `c` an exact copy of state `b` (`c < b`, both in the dynamic block):
    /// the row of `U` for `c` becomes that of `b` and `d_c = 0`. Used to hold the field
    /// value at a tie point for a later pseudo-measurement (model.md §3).
    pub fn clone_state(&mut self, c: usize, b: usize) {
        if c >= b || b >= self.n {
            return;
        }
        self.x[c] = self.x[b];
        for j in c + 1..self.n {
            self.u[j][c] = if j < b {
                0.0
            } else if j == b {
                1.0
            } else {
                self.u[j][b]
            };
        }
        self.d[c] = 0.0;
    }

    /// Exact change of variables `x_a ← x_a + c·x_b` with `a < b` (the transformation
    /// `T = I + c·e_a·e_bᵀ` is unit upper triangular, so `U ← T·U` stays unit upper
    /// triangular and `D` is unchanged).
    pub fn add_scaled_state(&mut self, a: usize, b: usize, c: f32) {
        if a >= b || b >= self.n || !c.is_finite() {
            return;
        }
        self.x[a] += c * self.x[b];
        self.u[b][a] += c;
        for j in b + 1..self.n {
            let ubj = self.u[j][b];
            self.u[j][a] += c * ubj;
        }
    }

    /// Forgets every correlation between states `0..m` and `m..n` (sets U₁₂ = 0).
    /// Used when the constant states become known (survey mode, loaded coefficients):
    /// afterwards measurement updates with zero regressors on `m..n` leave them unchanged.
    pub fn decouple(&mut self, m: usize) {
        for j in m..self.n {
            for i in 0..m.min(j) {
                self.u[j][i] = 0.0;
            }
        }
    }

    /// True when every `d_i` is finite and non-negative and every `d_i` of a state not
    /// meant to be a clone is positive: the covariance is positive (semi-)definite.
    pub fn is_healthy(&self) -> bool {
        self.d[..self.n].iter().all(|d| d.is_finite() && *d >= 0.0)
            && self.x[..self.n].iter().all(|x| x.is_finite())
    }
}

/// In-place (re)initialisation, so a board can keep the filter in a `static` and restart
/// it without building a second one on the stack (the filter is N² floats).
impl<const N: usize> UdFilter<N> {
    /// A filter with no states, usable in a `static` initialiser; [`reset`](Self::reset)
    /// gives it its states.
    pub const fn empty() -> Self {
        Self {
            x: [0.0; N],
            u: [[0.0; N]; N],
            d: [0.0; N],
            n: 0,
        }
    }

    /// Re-initialises in place to exactly what [`new`](Self::new) builds with the same
    /// arguments. Returns false, leaving the filter unchanged, where `new` returns `None`.
    pub fn reset(&mut self, n: usize, x0: &[f32], sigma0: &[f32]) -> bool {
        if n > N || x0.len() < n || sigma0.len() < n {
            return false;
        }
        if (0..n).any(|i| !(sigma0[i].is_finite() && sigma0[i] > 0.0 && x0[i].is_finite())) {
            return false;
        }
        self.x.fill(0.0);
        self.d.fill(0.0);
        for col in self.u.iter_mut() {
            col.fill(0.0);
        }
        for i in 0..n {
            self.x[i] = x0[i];
            self.u[i][i] = 1.0;
            self.d[i] = sigma0[i] * sigma0[i];
        }
        self.n = n;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::UdFilter;

    #[test]
    fn add_scaled_state_is_the_exact_change_of_variables() {
        let mut f = UdFilter::<4>::new(4, &[1.0, 2.0, 3.0, 4.0], &[1.0, 2.0, 0.5, 1.5]).unwrap();
        // Correlate the states with two updates.
        f.update(&[1.0, 0.5, -0.3, 0.2], 1.0, 0.1).unwrap();
        f.update(&[0.2, -1.0, 0.7, 0.4], -0.5, 0.2).unwrap();
        let mut p = [[0.0f32; 4]; 4];
        for (i, row) in p.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = f.covariance(i, j);
            }
        }
        let x: [f32; 4] = f.state().try_into().unwrap();
        let (a, b, c) = (1, 3, -0.7f32);
        f.add_scaled_state(a, b, c);
        // T = I + c·e_a·e_bᵀ: x' = T x, P' = T P Tᵀ.
        let t = |i: usize, k: usize| -> f32 {
            (if i == k { 1.0 } else { 0.0 }) + if i == a && k == b { c } else { 0.0 }
        };
        for i in 0..4 {
            let xi: f32 = (0..4).map(|k| t(i, k) * x[k]).sum();
            assert!((f.state()[i] - xi).abs() < 1e-5);
            for j in 0..4 {
                let mut pij = 0.0;
                for k in 0..4 {
                    for l in 0..4 {
                        pij += t(i, k) * p[k][l] * t(j, l);
                    }
                }
                assert!((f.covariance(i, j) - pij).abs() < 1e-5, "P[{i}][{j}]");
            }
        }
        assert!(f.is_healthy());
    }
}
