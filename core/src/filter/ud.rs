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
    /// Scratch of the measurement update (`f = Uᵀh`, then the gain direction), written
    /// before it is read: kept here so an update does not zero N floats on the stack first.
    f: [f32; N],
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
            f: [0.0; N],
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
        // A gate that never rejects: the gate's own variance sum is dead code then.
        self.update_gated(h, z, r, |_, _| false)?.ok()
    }

    /// Scalar update with a gate: `reject(ν, s)` sees the innovation and its predicted
    /// variance `s = r + Σ (Uᵀh)_j²·d_j` (the same numbers [`predict`](Self::predict) and
    /// [`predicted_variance`](Self::predicted_variance) give) before anything changes.
    /// One pass over `U` instead of three: `Uᵀh` is the largest part of the update.
    /// `None`: bad input (filter untouched); `Some(Err(ν, s))`: rejected (untouched);
    /// `Some(Ok(innovation))`: updated.
    pub fn update_gated(
        &mut self,
        h: &[f32],
        z: f32,
        r: f32,
        reject: impl FnOnce(f32, f32) -> bool,
    ) -> Option<Result<Innovation, Innovation>> {
        self.update_weighted(h, z, r, |nu, s| (!reject(nu, s)).then_some(r))
    }

    /// Scalar update whose measurement variance the caller may choose after seeing the
    /// innovation `ν` and its predicted variance `s` (computed with `r`): `weigh(ν, s)`
    /// returns the variance to update with (≥ `r`: a robust, e.g. Huber, down-weighting of
    /// an outlier) or `None` to reject. Same returns as [`update_gated`](Self::update_gated);
    /// an accepted innovation reports the variance it was weighed with.
    pub fn update_weighted(
        &mut self,
        h: &[f32],
        z: f32,
        r: f32,
        weigh: impl FnOnce(f32, f32) -> Option<f32>,
    ) -> Option<Result<Innovation, Innovation>> {
        let n = self.n;
        if h.len() < n || !z.is_finite() || r.is_nan() || r <= 0.0 {
            return None;
        }
        let (pred, s_gate) = bierman_prepare(
            self.u.as_flattened(),
            N,
            &self.x[..n],
            &self.d,
            h,
            r,
            &mut self.f,
        )?;
        let innovation = z - pred;
        let Some(r_used) = weigh(innovation, s_gate).filter(|v| v.is_finite() && *v >= r) else {
            return Some(Err(Innovation {
                value: innovation,
                variance: s_gate,
            }));
        };
        let alpha = bierman_apply(
            self.u.as_flattened_mut(),
            N,
            &mut self.d[..n],
            &mut self.f,
            r_used,
        );
        if !(alpha > 0.0 && alpha.is_finite()) {
            return None;
        }
        // f now holds the gain direction b
        let k = innovation / alpha;
        for (xi, bi) in self.x[..n].iter_mut().zip(&self.f[..n]) {
            *xi += bi * k;
        }
        Some(Ok(Innovation {
            value: innovation,
            variance: alpha,
        }))
    }

    /// Innovation variance `h·P·hᵀ + r` without updating (for gating and diagnostics).
    /// The compensator's health checks make 13 of these per envelope evaluation: the
    /// straight-line kernel (same arithmetic, same order) instead of loops compiled, generic
    /// over `N`, at the caller's opt-level "s".
    pub fn predicted_variance(&self, h: &[f32], r: f32) -> f32 {
        predicted_variance_kernel(self.u.as_flattened(), N, &self.d[..self.n], h, r)
    }

    /// True when `d_i` and every `U_ij` of the rows `i < k` are finite: then the terms of
    /// `h·P·hᵀ` that multiply a zero `h_i` (i < k) are exact zeros (`U_ij·0 = ±0`, and a
    /// zero `f_j` adds `+0` to the sum), so
    /// [`predicted_variance_tail`](Self::predicted_variance_tail) may leave them out.
    pub fn leading_rows_finite(&self, k: usize) -> bool {
        let k = k.min(self.n);
        leading_rows_finite_kernel(self.u.as_flattened(), N, self.n, &self.d[..k])
    }

    /// [`predicted_variance`](Self::predicted_variance) of the `h` that is zero on states
    /// `0..k` and `h_tail` on `k..n`, from the trailing block of `U` and `D` alone: the same
    /// value, to the bit, when [`leading_rows_finite(k)`](Self::leading_rows_finite) (the
    /// sum over the trailing columns runs in the same order; what is left out adds exact
    /// zeros). The compensator's interference variances have zeros on all the field
    /// states: 90 of the 210 multiply-adds at 21 states.
    /// `fill` writes `h_tail` (states `k..n`) into the filter's scratch, so no N floats
    /// are zeroed on the stack for it.
    pub fn predicted_variance_tail(
        &mut self,
        k: usize,
        r: f32,
        fill: impl FnOnce(&mut [f32]),
    ) -> f32 {
        let k = k.min(self.n);
        let h = &mut self.f[k..self.n];
        fill(h);
        predicted_variance_kernel(
            &self.u.as_flattened()[k * N + k..],
            N,
            &self.d[k..self.n],
            h,
            r,
        )
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
        let q = dq.len().min(MAX_NOISE);
        if m == 0 || m > MAX_DYNAMIC || m > self.n {
            return;
        }
        // The block sizes the compensator uses (5 field states after 0–2 tie-point clones,
        // 5 noise columns) get loops of compile-time length, fully unrolled (model.md §5:
        // 7,726 → 3,147 instructions); any other shape takes the general loops.
        match thornton_fixed_for(m, q) {
            Some(tu) => {
                let n = self.n;
                tu(
                    &mut self.x[..n],
                    self.u.as_flattened_mut(),
                    N,
                    &mut self.d,
                    phi,
                    g,
                    dq,
                )
            }
            None => self.time_update_any(m, q, phi, g, dq),
        }
    }

    /// `time_update` for any block shape (runtime loop bounds).
    fn time_update_any(
        &mut self,
        m: usize,
        q: usize,
        phi: &[[f32; MAX_DYNAMIC]; MAX_DYNAMIC],
        g: &[[f32; MAX_DYNAMIC]; MAX_NOISE],
        dq: &[f32],
    ) {
        let n = self.n;
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

    /// Multiplies the whole covariance by `k` (`D ← k·D`; `U` is unchanged): the state of a
    /// filter whose prior, process and measurement variances were all `k` times larger,
    /// which gives the same estimate.
    pub fn scale_covariance(&mut self, k: f32) {
        for d in self.d[..self.n].iter_mut() {
            *d *= k;
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
            f: [0.0; N],
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

// ---------------------------------------------------------------------------------------
// Kernels. They are free functions over flat slices (U column-major with a runtime stride)
// and not generic over the capacity N, so they are compiled once, in this crate, at this
// crate's opt-level (the firmware profile gives magcomp-core opt-level 3 and the rest "s";
// a method generic over N would be compiled in the calling crate, at "s", where LLVM
// neither unrolls nor fully expands these loops).

/// Columns `j < STRAIGHT` get straight-line code: the column body is inlined with `j` a
/// constant, so each inner loop has a fixed length and is fully unrolled (model.md §5:
/// 7,726 → 3,147 instructions per step). Covers the paper's model, two tie-point clones
/// and the rate term (27); larger filters run the same body as a loop beyond it.
const STRAIGHT: usize = 28;

/// Runs `$call` with `$j` bound to every column index `< n` in ascending order: each
/// `j < STRAIGHT` as its own copy with `j` a literal (the column functions are
/// `#[inline(always)]`, so their inner loops get a constant length), the rest in a loop.
macro_rules! straight_columns {
    ($n:expr, |$j:ident| $call:expr) => {{
        let n = $n;
        straight_columns!(@ n, $j, $call; 0 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19
            20 21 22 23 24 25 26 27);
        for $j in STRAIGHT..n {
            $call;
        }
    }};
    (@ $n:ident, $j:ident, $call:expr; $($lit:literal)*) => {
        $({
            let $j: usize = $lit;
            if $j < $n {
                $call;
            }
        })*
    };
}
const _: () = assert!(STRAIGHT == 28, "straight_columns! lists 0..28");

/// Accumulators of `bierman_prepare`.
struct Prepared {
    pred: f32,
    s: f32,
}

/// Column `j` of `f = Uᵀh`: `f_j = h_j + Σ_{i<j} U_ij h_i`.
#[allow(clippy::too_many_arguments)] // inlined into straight-line code: no call cost
#[inline(always)]
fn prepare_column(
    j: usize,
    u: &[f32],
    stride: usize,
    x: &[f32],
    d: &[f32],
    h: &[f32],
    f: &mut [f32],
    acc: &mut Prepared,
) {
    let col = &u[j * stride..j * stride + j];
    let mut fj = h[j];
    for (uij, hi) in col.iter().zip(&h[..j]) {
        fj += uij * hi;
    }
    f[j] = fj;
    acc.s += fj * fj * d[j];
    acc.pred += h[j] * x[j];
}

/// Phase 1 of Bierman's update: `f = Uᵀh` into `f[..n]`, with `h·x` and `r + Σ f_j² d_j`.
/// `None` when some `f_j` (or that variance) is not finite (nothing has been changed).
#[inline(never)]
fn bierman_prepare(
    u: &[f32],
    stride: usize,
    x: &[f32],
    d: &[f32],
    h: &[f32],
    r: f32,
    f: &mut [f32],
) -> Option<(f32, f32)> {
    let n = x.len();
    let (d, h, f) = (&d[..n], &h[..n], &mut f[..n]);
    let mut acc = Prepared { pred: 0.0, s: r };
    straight_columns!(n, |j| prepare_column(j, u, stride, x, d, h, f, &mut acc));
    // A non-finite f_j makes s = r + Σ f_j²·d_j non-finite (inf·0 is NaN for a clone's
    // d = 0), so one test at the end replaces one per column. It also catches a non-finite
    // r or d, or an overflowing f_j², which the update would only find after rewriting U.
    acc.s.is_finite().then_some((acc.pred, acc.s))
}

/// Column `j` of `h·P·hᵀ = Σ_j (Uᵀh)_j²·d_j` (as `prepare_column`, without `f` and `h·x`).
#[inline(always)]
fn variance_column(j: usize, u: &[f32], stride: usize, d: &[f32], h: &[f32], s: &mut f32) {
    let col = &u[j * stride..j * stride + j];
    let mut fj = h[j];
    for (uij, hi) in col.iter().zip(&h[..j]) {
        fj += uij * hi;
    }
    *s += fj * fj * d[j];
}

/// [`UdFilter::leading_rows_finite`] over the first `k = d.len()` rows of `n` columns: a
/// plain loop here at opt-level 3 (the generic iterator chain cost ~13 instructions an
/// entry at the firmware's "s").
#[inline(never)]
fn leading_rows_finite_kernel(u: &[f32], stride: usize, n: usize, d: &[f32]) -> bool {
    let k = d.len();
    // v·0 is ±0 for a finite v and NaN otherwise: one multiply-add per entry
    let mut acc = 0.0f32;
    for v in d {
        acc += v * 0.0;
    }
    for j in 0..n {
        for v in &u[j * stride..j * stride + k] {
            acc += v * 0.0;
        }
    }
    acc == 0.0
}

/// `r + h·P·hᵀ` over the `n = d.len()` states, in the order `UdFilter::predicted_variance`
/// always summed it (a non-finite result is returned, not refused: callers test it).
#[inline(never)]
fn predicted_variance_kernel(u: &[f32], stride: usize, d: &[f32], h: &[f32], r: f32) -> f32 {
    let n = d.len();
    let h = &h[..n];
    let mut s = r;
    straight_columns!(n, |j| variance_column(j, u, stride, d, h, &mut s));
    s
}

/// Column `j` of Bierman's update (`alpha` carries the running innovation variance).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn apply_column(
    j: usize,
    u: &mut [f32],
    stride: usize,
    d: &mut [f32],
    fb: &mut [f32],
    alpha: &mut f32,
) {
    // f_j is read before b_j overwrites it; b_i (i < j) replaced f_i in earlier columns
    let fj = fb[j];
    let b = fb;
    let gj = d[j] * fj;
    let alpha_prev = *alpha;
    *alpha += fj * gj;
    let lambda = -fj / alpha_prev;
    d[j] *= alpha_prev / *alpha;
    let col = &mut u[j * stride..j * stride + j];
    for (uij, bi) in col.iter_mut().zip(&mut b[..j]) {
        let v = *uij;
        *uij = v + lambda * *bi;
        *bi += v * gj;
    }
    b[j] = gj;
}

/// Phase 2 of Bierman's update: rewrites `U` and `D` from `f = Uᵀh` (in `fb[..n]`) and
/// returns the innovation variance `α`, with the gain direction `b` in `fb[..n]` (one
/// scratch array: `b_i` overwrites `f_i`, which column i was the last to read).
#[inline(never)]
fn bierman_apply(u: &mut [f32], stride: usize, d: &mut [f32], fb: &mut [f32], r: f32) -> f32 {
    let n = d.len();
    let fb = &mut fb[..n];
    let mut alpha = r;
    straight_columns!(n, |j| apply_column(j, u, stride, d, fb, &mut alpha));
    alpha
}

/// Thornton time update for an `M`-state dynamic block and `Q` noise columns: the same
/// arithmetic in the same order as `UdFilter::time_update_any`, minus terms that are exactly
/// zero (the strictly lower part of `Φ·U₁₁` stays zero through MWGS: row i only ever has
/// rows j > i subtracted from it, and its diagonal stays 1).
#[inline(always)]
fn thornton_fixed<const M: usize, const Q: usize>(
    x: &mut [f32],
    u: &mut [f32],
    stride: usize,
    d: &mut [f32],
    phi: &[[f32; MAX_DYNAMIC]; MAX_DYNAMIC],
    g: &[[f32; MAX_DYNAMIC]; MAX_NOISE],
    dq: &[f32],
) {
    let n = x.len();
    let mut p = [[0.0f32; M]; M];
    for (pi, phii) in p.iter_mut().zip(phi) {
        pi.copy_from_slice(&phii[..M]);
    }
    // x ← Φx (upper triangular: row i uses rows ≥ i, so ascending order is in place)
    let xm = &mut x[..M];
    for i in 0..M {
        let mut s = xm[i];
        for k in i + 1..M {
            s += p[i][k] * xm[k];
        }
        xm[i] = s;
    }
    // U₁₂ ← Φ·U₁₂ (columns m..n, rows 0..m)
    // (one bounds check for the whole block, then a pointer walk over the columns)
    if M < n && M <= stride {
        for col in u[M * stride..n * stride].chunks_exact_mut(stride) {
            let c = &mut col[..M];
            for i in 0..M {
                let mut s = c[i];
                for k in i + 1..M {
                    s += p[i][k] * c[k];
                }
                c[i] = s;
            }
        }
    }
    // Y = [Φ·U₁₁ | G] with weights [D₁ | Dq], in its two blocks: ya (M×M; only the part
    // above the diagonal is stored and used) and yb (M×Q).
    let mut ya = [[0.0f32; M]; M];
    for j in 1..M {
        let col = &u[j * stride..j * stride + M];
        for i in 0..j {
            // (ΦU)_ij = U_ij + Σ_{i<k<j} Φ_ik U_kj + Φ_ij (Φ_ii = U_jj = 1)
            let mut s = col[i] + p[i][j];
            for k in i + 1..j {
                s += p[i][k] * col[k];
            }
            ya[i][j] = s;
        }
    }
    let mut w1 = [0.0f32; M];
    w1.copy_from_slice(&d[..M]);
    let mut wq = [0.0f32; Q];
    wq.copy_from_slice(&dq[..Q]);
    let mut yb = [[0.0f32; Q]; M];
    for (i, row) in yb.iter_mut().enumerate() {
        for (k, v) in row.iter_mut().enumerate() {
            *v = g[k][i];
        }
    }
    // MWGS, last row first (upper UD). y_jj = 1 and y_jk = 0 for k < j throughout. Each
    // row is its own copy with j a literal, so every loop inside has a fixed length and is
    // fully unrolled (a loop over j left the inner loops rolled, with their counters).
    macro_rules! rows_desc {
        ($($j:literal)*) => {$(
            if $j < M {
                mwgs_row::<M, Q>($j, u, stride, d, &w1, &wq, &mut ya, &mut yb);
            }
        )*};
    }
    rows_desc!(7 6 5 4 3 2 1 0);
    const {
        assert!(
            M <= MAX_DYNAMIC && MAX_DYNAMIC == 8,
            "rows_desc! lists 7..=0"
        )
    };
}

/// Row `j` of the MWGS re-factorisation in `thornton_fixed`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn mwgs_row<const M: usize, const Q: usize>(
    j: usize,
    u: &mut [f32],
    stride: usize,
    d: &mut [f32],
    w1: &[f32; M],
    wq: &[f32; Q],
    ya: &mut [[f32; M]; M],
    yb: &mut [[f32; Q]; M],
) {
    // Σ_k w_k y_jk²: the zero terms k < j add nothing, w_j·1·1 = w_j exactly.
    let mut dj = 0.0f32 + w1[j];
    for k in j + 1..M {
        dj += w1[k] * ya[j][k] * ya[j][k];
    }
    for k in 0..Q {
        dj += wq[k] * yb[j][k] * yb[j][k];
    }
    d[j] = dj;
    let (ya_up, ya_j) = ya.split_at_mut(j);
    let (yb_up, yb_j) = yb.split_at_mut(j);
    let (ya_j, yb_j) = (&ya_j[0], &yb_j[0]);
    let uc = &mut u[j * stride..j * stride + j];
    for ((uij_out, yai), ybi) in uc.iter_mut().zip(ya_up.iter_mut()).zip(yb_up.iter_mut()) {
        let uij = if dj > 0.0 {
            let mut s = 0.0f32 + w1[j] * yai[j];
            for k in j + 1..M {
                s += w1[k] * yai[k] * ya_j[k];
            }
            for k in 0..Q {
                s += wq[k] * ybi[k] * yb_j[k];
            }
            s / dj
        } else {
            0.0
        };
        *uij_out = uij;
        // row_i −= u_ij·row_j: column j of ya (y_jj = 1) and the columns after it
        yai[j] -= uij;
        for k in j + 1..M {
            yai[k] -= uij * ya_j[k];
        }
        for k in 0..Q {
            ybi[k] -= uij * yb_j[k];
        }
    }
}

/// Signature of the block-size specific time updates.
type ThorntonFn = fn(
    &mut [f32],
    &mut [f32],
    usize,
    &mut [f32],
    &[[f32; MAX_DYNAMIC]; MAX_DYNAMIC],
    &[[f32; MAX_DYNAMIC]; MAX_NOISE],
    &[f32],
);

/// The block shapes the compensator uses: 5 field states after 0–2 tie-point clones, with
/// the field model's 5 noise columns. Non-generic, so compiled here (see above). The
/// `#[inline(never)]` wrappers are measured, not ceremony: returning the instances
/// `thornton_fixed::<M, 5>` directly doubled the UD step on the M4 (3 874 → 7 747
/// instructions, `scripts/bench-target.sh`).
fn thornton_fixed_for(m: usize, q: usize) -> Option<ThorntonFn> {
    #[inline(never)]
    fn m5(
        x: &mut [f32],
        u: &mut [f32],
        s: usize,
        d: &mut [f32],
        p: &[[f32; MAX_DYNAMIC]; MAX_DYNAMIC],
        g: &[[f32; MAX_DYNAMIC]; MAX_NOISE],
        dq: &[f32],
    ) {
        thornton_fixed::<5, 5>(x, u, s, d, p, g, dq)
    }
    #[inline(never)]
    fn m6(
        x: &mut [f32],
        u: &mut [f32],
        s: usize,
        d: &mut [f32],
        p: &[[f32; MAX_DYNAMIC]; MAX_DYNAMIC],
        g: &[[f32; MAX_DYNAMIC]; MAX_NOISE],
        dq: &[f32],
    ) {
        thornton_fixed::<6, 5>(x, u, s, d, p, g, dq)
    }
    #[inline(never)]
    fn m7(
        x: &mut [f32],
        u: &mut [f32],
        s: usize,
        d: &mut [f32],
        p: &[[f32; MAX_DYNAMIC]; MAX_DYNAMIC],
        g: &[[f32; MAX_DYNAMIC]; MAX_NOISE],
        dq: &[f32],
    ) {
        thornton_fixed::<7, 5>(x, u, s, d, p, g, dq)
    }
    match (m, q) {
        (5, 5) => Some(m5),
        (6, 5) => Some(m6),
        (7, 5) => Some(m7),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::{UdFilter, MAX_DYNAMIC, MAX_NOISE};

    /// Deterministic values in [-1, 1).
    fn lcg(state: &mut u32) -> f32 {
        *state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (*state >> 8) as f32 / (1u32 << 23) as f32 - 1.0
    }

    /// The plain loops the fast kernels replaced: Bierman's update over runtime bounds.
    fn reference_update<const N: usize>(f: &mut UdFilter<N>, h: &[f32], z: f32, r: f32) {
        let n = f.n;
        let mut fv = [0.0f32; N];
        let mut gv = [0.0f32; N];
        let mut pred = 0.0f32;
        for j in 0..n {
            let mut fj = h[j];
            for i in 0..j {
                fj += f.u[j][i] * h[i];
            }
            fv[j] = fj;
            gv[j] = f.d[j] * fj;
            pred += h[j] * f.x[j];
        }
        let innovation = z - pred;
        let mut alpha = r;
        let mut b = [0.0f32; N];
        for j in 0..n {
            let alpha_prev = alpha;
            alpha += fv[j] * gv[j];
            let lambda = -fv[j] / alpha_prev;
            f.d[j] *= alpha_prev / alpha;
            for i in 0..j {
                let uij = f.u[j][i];
                f.u[j][i] = uij + lambda * b[i];
                b[i] += uij * gv[j];
            }
            b[j] = gv[j];
        }
        let k = innovation / alpha;
        for i in 0..n {
            f.x[i] += b[i] * k;
        }
    }

    /// Runs random time and measurement updates through the fast paths and through the
    /// plain loops (`time_update_any`, `reference_update`): the results must be identical
    /// to the bit, for straight-line sizes and for the looped fallback beyond `STRAIGHT`.
    fn fast_paths_match_plain_loops<const N: usize>(n: usize, m: usize) {
        let mut seed = 12_345u32 + n as u32 * 7 + m as u32;
        let sigma: [f32; N] = core::array::from_fn(|i| 0.5 + (i % 5) as f32 * 0.3);
        let mut fast = UdFilter::<N>::new(n, &[0.1; N], &sigma).unwrap();
        let mut slow = fast.clone();
        for step in 0..40 {
            let mut phi = [[0.0f32; MAX_DYNAMIC]; MAX_DYNAMIC];
            let mut g = [[0.0f32; MAX_DYNAMIC]; MAX_NOISE];
            for i in 0..m {
                phi[i][i] = 1.0;
                for v in phi[i].iter_mut().take(m).skip(i + 1) {
                    *v = 0.1 * lcg(&mut seed);
                }
            }
            for (k, col) in g.iter_mut().enumerate() {
                col[m - MAX_NOISE + k] = 1.0;
                for v in col.iter_mut().take(m) {
                    *v += 0.05 * lcg(&mut seed);
                }
            }
            let dq: [f32; MAX_NOISE] = core::array::from_fn(|k| 1e-3 * (k + 1) as f32);
            fast.time_update(m, &phi, &g, &dq);
            slow.time_update_any(m, MAX_NOISE, &phi, &g, &dq);
            let h: [f32; N] = core::array::from_fn(|_| lcg(&mut seed));
            let z = lcg(&mut seed);
            assert!(fast.update(&h[..n], z, 0.01).is_some());
            reference_update(&mut slow, &h[..n], z, 0.01);
            for i in 0..n {
                assert_eq!(fast.x[i].to_bits(), slow.x[i].to_bits(), "x{i} step {step}");
                assert_eq!(fast.d[i].to_bits(), slow.d[i].to_bits(), "d{i} step {step}");
                for j in 0..n {
                    assert_eq!(fast.u[j][i].to_bits(), slow.u[j][i].to_bits(), "u{i},{j}");
                }
            }
        }
        assert!(fast.is_healthy());
    }

    #[test]
    fn fast_paths_match_plain_loops_bit_for_bit() {
        fast_paths_match_plain_loops::<21>(21, 5);
        fast_paths_match_plain_loops::<24>(23, 7);
        fast_paths_match_plain_loops::<32>(27, 6);
        fast_paths_match_plain_loops::<32>(28, 5);
        // beyond the straight-line columns: the looped fallback
        fast_paths_match_plain_loops::<36>(33, 5);
    }

    /// Scaling the covariance by `k` before fusing at `k·r` is the filter that had a `k`-times
    /// prior and fused every sample at `k·r`: the same estimate and covariance, so the
    /// samples fused before the scaling keep their weight relative to the ones after.
    #[test]
    fn scaling_the_covariance_re_weights_the_past_as_a_noise_k_times_larger() {
        let (k, r) = (44.0f32, 0.09f32);
        let sigma0 = [3.0f32, 1.0, 2.0];
        let prior_k: [f32; 3] = core::array::from_fn(|i| sigma0[i] * k.sqrt());
        let mut rescaled = UdFilter::<3>::new(3, &[0.0; 3], &sigma0).unwrap();
        let mut from_start = UdFilter::<3>::new(3, &[0.0; 3], &prior_k).unwrap();
        let sample = |i: usize| {
            let a = i as f32 * 0.7;
            (
                [a.cos(), a.sin(), 1.0],
                2.0 * a.cos() - a.sin() + 0.5 + 0.3 * (3.1 * a).sin(),
            )
        };
        for i in 0..20 {
            let (h, z) = sample(i);
            rescaled.update(&h, z, r).unwrap();
            from_start.update(&h, z, k * r).unwrap();
        }
        rescaled.scale_covariance(k);
        for i in 20..40 {
            let (h, z) = sample(i);
            rescaled.update(&h, z, k * r).unwrap();
            from_start.update(&h, z, k * r).unwrap();
        }
        for i in 0..3 {
            let (a, b) = (rescaled.state()[i], from_start.state()[i]);
            assert!(
                (a - b).abs() <= 1e-4 * b.abs().max(1.0),
                "x{i}: {a} against {b}"
            );
            for j in 0..3 {
                let (a, b) = (rescaled.covariance(i, j), from_start.covariance(i, j));
                assert!(
                    (a - b).abs() <= 1e-4 * b.abs().max(1e-3),
                    "P{i}{j}: {a} against {b}"
                );
            }
        }
        // and not the filter that raised r alone: the first 20 samples weigh k × more there
        let mut raised_alone = UdFilter::<3>::new(3, &[0.0; 3], &sigma0).unwrap();
        for i in 0..40 {
            let (h, z) = sample(i);
            raised_alone
                .update(&h, z, if i < 20 { r } else { k * r })
                .unwrap();
        }
        let moved = (0..3)
            .map(|i| (raised_alone.state()[i] - from_start.state()[i]).abs())
            .fold(0.0f32, f32::max);
        assert!(moved > 1e-3, "{moved}");
    }

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
