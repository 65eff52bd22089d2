//! Classic Tolles–Lawson compensation (host, f64), conformant with MagNav.jl.
//!
//! The baseline the Kalman compensator is compared against: an 18- (or 16-) term design
//! matrix from the vector fluxgate, band-passed zero-phase, ridge regression of the
//! band-passed scalar on it, and `interference = A·c` on unfiltered data.
//!
//! Conventions follow MagNav.jl's `create_TL_A` (see `data/reference/README.md`):
//! `Bt = |flux|`, `B̂ = flux/Bt`; permanent `B̂i`; induced `B̂i·Bj/Bt_scale`; eddy
//! `B̂i·dBj/Bt_scale` with `dB` the central difference **per sample** (one-sided at the
//! ends). Because `dB` is per sample, eddy coefficients depend on the sample rate:
//! a fit made at 10 Hz applies only to 10 Hz data. Set [`EddyRate::PerSecond`] to use
//! `dB/dt` (nT/s) instead, which gives rate-independent eddy coefficients (in s) but is not
//! MagNav's convention.

mod jackknife;
pub use jackknife::jackknife_refits;

use crate::signal::bandpass::{butterworth_bandpass, filtfilt, Sos};

use anyhow::{bail, ensure, Context, Result};
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use std::str::FromStr;

/// MagNav's `Bt_scale`, the field strength (nT) the induced and eddy terms are scaled by:
/// the model's B* under MagNav's name.
pub const BT_SCALE_NT: f64 = magcomp_core::model::B_STAR_NT;

/// Column names of the full 18-term (MagNav) design matrix, in MagNav's order.
pub const TL18_NAMES: [&str; 18] = [
    "perm_x", "perm_y", "perm_z", "ind_xx", "ind_xy", "ind_xz", "ind_yy", "ind_yz", "ind_zz",
    "eddy_xx", "eddy_xy", "eddy_xz", "eddy_yx", "eddy_yy", "eddy_yz", "eddy_zx", "eddy_zy",
    "eddy_zz",
];

/// Which Tolles–Lawson terms make up the design matrix.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum TlTerms {
    /// MagNav's 18 terms (3 permanent, 6 induced, 9 eddy); collinear, needs the ridge.
    Tl18,
    /// The identifiable 16: TL18 without `ind_zz` and `eddy_zz`, which are collinear with
    /// the rest because Σe_i² = 1 and e·ė = 0.
    Tl16,
    /// Whole MagNav groups, e.g. permanent + induced (9 terms).
    Groups {
        permanent: bool,
        induced: bool,
        eddy: bool,
    },
}

impl TlTerms {
    /// Indices into [`TL18_NAMES`] of the columns this selection keeps.
    pub fn columns(&self) -> Vec<usize> {
        match *self {
            TlTerms::Tl18 => (0..18).collect(),
            TlTerms::Tl16 => (0..18).filter(|&j| j != 8 && j != 17).collect(),
            TlTerms::Groups {
                permanent,
                induced,
                eddy,
            } => {
                let mut c = Vec::new();
                if permanent {
                    c.extend(0..3);
                }
                if induced {
                    c.extend(3..9);
                }
                if eddy {
                    c.extend(9..18);
                }
                c
            }
        }
    }

    /// Readable coefficient names (`perm_x`, `ind_xy`, `eddy_zx`, ...).
    pub fn names(&self) -> Vec<String> {
        self.columns()
            .into_iter()
            .map(|j| TL18_NAMES[j].to_string())
            .collect()
    }
}

impl FromStr for TlTerms {
    type Err = anyhow::Error;
    /// `tl18`, `tl16`, or groups joined by `+`: `permanent+induced`, `perm+ind+eddy`.
    fn from_str(s: &str) -> Result<Self> {
        let s = s.trim().to_ascii_lowercase();
        match s.as_str() {
            "tl18" | "18" => return Ok(TlTerms::Tl18),
            "tl16" | "16" => return Ok(TlTerms::Tl16),
            _ => {}
        }
        let (mut permanent, mut induced, mut eddy) = (false, false, false);
        for g in s.split('+') {
            match g.trim() {
                "permanent" | "perm" => permanent = true,
                "induced" | "ind" => induced = true,
                "eddy" => eddy = true,
                other => bail!(
                    "unknown Tolles–Lawson term group {other:?} (expected tl18, tl16, or permanent/induced/eddy joined by '+')"
                ),
            }
        }
        Ok(TlTerms::Groups {
            permanent,
            induced,
            eddy,
        })
    }
}

/// Unit of the field derivative in the eddy terms.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum EddyRate {
    /// MagNav: central difference per sample (nT/sample).
    PerSample,
    /// Central difference divided by `dt = 1/fs_hz` (nT/s).
    PerSecond,
}

/// Tolles–Lawson fit settings. `Default` is MagNav's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TlConfig {
    pub terms: TlTerms,
    /// Band-pass edges (−3 dB of one pass); `None` fits unfiltered data.
    pub pass_hz: Option<(f64, f64)>,
    pub fs_hz: f64,
    /// Poles of the Butterworth prototype (the band-pass has twice this order).
    pub poles: usize,
    /// Samples dropped at each end of every filtered run (filter start-up); unused when
    /// `pass_hz` is `None`.
    pub trim: usize,
    /// Ridge parameter λ; 0 gives plain least squares (SVD, minimum-norm if rank deficient).
    pub lambda: f64,
    pub bt_scale_nt: f64,
    pub eddy_rate: EddyRate,
}

impl Default for TlConfig {
    fn default() -> Self {
        TlConfig {
            terms: TlTerms::Tl18,
            pass_hz: Some((0.1, 0.9)),
            fs_hz: 10.0,
            poles: 4,
            trim: 20,
            lambda: 0.001,
            bt_scale_nt: BT_SCALE_NT,
            eddy_rate: EddyRate::PerSample,
        }
    }
}

impl TlConfig {
    /// MagNav's defaults for data sampled at `fs_hz`: same 0.1–0.9 Hz band, and the trim
    /// kept at MagNav's 2 s (20 samples at 10 Hz) rather than 20 samples, because the
    /// filter start-up lasts a fixed time, not a fixed number of samples.
    pub fn for_rate(fs_hz: f64) -> Self {
        TlConfig {
            fs_hz,
            trim: (2.0 * fs_hz).round().max(0.0) as usize,
            ..TlConfig::default()
        }
    }

    /// The yardstick of issue 10: MagNav's band-passed TL18 without the ridge (λ = 0),
    /// i.e. ordinary least squares solved by SVD with numpy's `lstsq` cut-off (singular
    /// values below `σ_max·max(m, n)·ε` dropped, minimum-norm solution). On a clean
    /// calibration flight it is what an independent toolchain gets in 20 lines, so the
    /// Kalman filter is measured against it (tests/kf_vs_tl_broad.rs).
    pub fn ols(fs_hz: f64) -> Self {
        TlConfig {
            lambda: 0.0,
            ..TlConfig::for_rate(fs_hz)
        }
    }

    fn validate(&self) -> Result<()> {
        ensure!(
            self.fs_hz.is_finite() && self.fs_hz > 0.0,
            "fs_hz = {} must be finite and positive",
            self.fs_hz
        );
        ensure!(
            self.lambda.is_finite() && self.lambda >= 0.0,
            "ridge lambda = {} must be finite and >= 0",
            self.lambda
        );
        ensure!(
            self.bt_scale_nt.is_finite() && self.bt_scale_nt > 0.0,
            "bt_scale_nt = {} must be finite and positive",
            self.bt_scale_nt
        );
        ensure!(
            !self.terms.columns().is_empty(),
            "no Tolles–Lawson terms selected"
        );
        Ok(())
    }

    fn db_scale(&self) -> f64 {
        match self.eddy_rate {
            EddyRate::PerSample => 1.0,
            EddyRate::PerSecond => self.fs_hz,
        }
    }
}

/// A fitted Tolles–Lawson model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TlFit {
    /// Coefficients in nT, in the order of `names`.
    pub coefficients: Vec<f64>,
    /// 1σ of each coefficient (nT): the regression's `s²·diag(...)` (see [`ridge`]) divided
    /// by the band-pass's white-noise power gain (`noise_gain`), because the filtered
    /// residuals are correlated: their in-band density is that of the unfiltered noise, not
    /// of a white sequence with the filtered variance. Assumes the unfiltered residual is
    /// roughly white in the pass band.
    pub sigma: Vec<f64>,
    pub names: Vec<String>,
    pub config: TlConfig,
    /// Rows (after filtering and trimming) the regression used.
    pub rows_used: usize,
    /// Selected rows excluded because the scalar or the fluxgate (or a neighbour the
    /// derivative needs) is not finite.
    pub rows_nonfinite: usize,
    /// Selected finite rows dropped because their contiguous run is too short to filter.
    pub rows_short_runs: usize,
    /// Contiguous runs that contributed.
    pub runs_used: usize,
    /// Residual std of the (band-passed) regression, nT.
    pub residual_std_nt: f64,
    /// Condition number of the (regularised) normal matrix.
    pub cond_normal: f64,
    /// Numerical rank of the regression (equals the term count unless λ = 0 and collinear).
    pub rank: usize,
    /// White-noise power gain of the band-pass (1 without filtering), see `sigma`.
    pub noise_gain: f64,
}

impl TlFit {
    /// Coefficient by name (`"perm_x"`, `"eddy_zy"`, ...).
    pub fn coefficient(&self, name: &str) -> Option<f64> {
        self.names
            .iter()
            .position(|n| n == name)
            .map(|k| self.coefficients[k])
    }
}

impl std::fmt::Display for TlFit {
    /// Human-readable fit report: data accounting first, then one line per coefficient.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let c = &self.config;
        let band = match c.pass_hz {
            Some((lo, hi)) => format!("{lo}–{hi} Hz band-pass ({} poles)", c.poles),
            None => "no band-pass".to_string(),
        };
        writeln!(
            f,
            "Tolles–Lawson {:?}: {} terms, λ = {}, {band} at {} Hz",
            c.terms,
            self.names.len(),
            c.lambda,
            c.fs_hz
        )?;
        writeln!(
            f,
            "rows used {} in {} run(s); excluded: {} non-finite, {} in too-short runs",
            self.rows_used, self.runs_used, self.rows_nonfinite, self.rows_short_runs
        )?;
        writeln!(
            f,
            "residual std {:.4} nT (filtered), rank {}, cond(normal) {:.3e}",
            self.residual_std_nt, self.rank, self.cond_normal
        )?;
        for ((n, v), s) in self.names.iter().zip(&self.coefficients).zip(&self.sigma) {
            writeln!(f, "  {n:8} {v:14.6} ± {s:.6}")?;
        }
        Ok(())
    }
}

/// Central difference per sample, one-sided at the ends (MagNav's `fdm`).
fn central_diff(x: &[f64], out: &mut [f64]) {
    let n = x.len();
    match n {
        0 => {}
        1 => out[0] = 0.0,
        _ => {
            out[0] = x[1] - x[0];
            out[n - 1] = x[n - 1] - x[n - 2];
            for i in 1..n - 1 {
                out[i] = (x[i + 1] - x[i - 1]) / 2.0;
            }
        }
    }
}

/// MagNav's Tolles–Lawson design matrix (rows = samples, columns = `terms.names()`), with
/// the eddy derivative per sample. Non-finite fluxgate rows give non-finite rows (and
/// non-finite eddy terms in their neighbours).
pub fn design_matrix(flux_nt: &[[f64; 3]], terms: &TlTerms, bt_scale: f64) -> DMatrix<f64> {
    design_matrix_scaled(flux_nt, terms, bt_scale, 1.0)
}

/// [`design_matrix`] with the per-sample derivative multiplied by `db_scale`
/// (`fs_hz` gives nT/s).
pub fn design_matrix_scaled(
    flux_nt: &[[f64; 3]],
    terms: &TlTerms,
    bt_scale: f64,
    db_scale: f64,
) -> DMatrix<f64> {
    let n = flux_nt.len();
    let cols = terms.columns();
    let mut b = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
    let mut db = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
    for (i, f) in flux_nt.iter().enumerate() {
        for k in 0..3 {
            b[k][i] = f[k];
        }
    }
    for k in 0..3 {
        central_diff(&b[k], &mut db[k]);
        if db_scale != 1.0 {
            db[k].iter_mut().for_each(|v| *v *= db_scale);
        }
    }
    const IND: [(usize, usize); 6] = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)];
    let mut a = DMatrix::<f64>::zeros(n, cols.len());
    for i in 0..n {
        let (x, y, z) = (b[0][i], b[1][i], b[2][i]);
        // Same operation order as MagNav so the matrix matches to rounding.
        let bt = (x * x + y * y + z * z).sqrt();
        let hat = [x / bt, y / bt, z / bt];
        for (c, &j) in cols.iter().enumerate() {
            a[(i, c)] = match j {
                0..=2 => hat[j],
                3..=8 => {
                    let (p, q) = IND[j - 3];
                    hat[p] * b[q][i] / bt_scale
                }
                _ => {
                    let (p, q) = ((j - 9) / 3, (j - 9) % 3);
                    hat[p] * db[q][i] / bt_scale
                }
            };
        }
    }
    a
}

/// Result of [`ridge`].
#[derive(Clone, Debug, PartialEq)]
pub struct Ridge {
    pub coefficients: Vec<f64>,
    pub sigma: Vec<f64>,
    pub residual_std: f64,
    pub cond_normal: f64,
    pub rank: usize,
}

/// Ridge regression `c = (AᵀA + λI)⁻¹Aᵀy` (MagNav's normal-equation form, Cholesky).
/// λ = 0 solves plain least squares by SVD (minimum-norm when A is rank deficient).
///
/// 1σ: `s²·diag(N⁻¹ AᵀA N⁻¹)` with `N = AᵀA + λI` (the covariance of the ridge
/// estimator; `s²(AᵀA)⁺` for λ = 0), `s²` the residual variance over `rows − rank` dof.
pub fn ridge(a: &DMatrix<f64>, y: &[f64], lambda: f64) -> Result<Ridge> {
    let (m, p) = a.shape();
    ensure!(y.len() == m, "ridge: {} rows in A but {} in y", m, y.len());
    ensure!(p > 0, "ridge: no columns");
    ensure!(
        lambda.is_finite() && lambda >= 0.0,
        "ridge: lambda {lambda} must be finite and >= 0"
    );
    ensure!(
        a.iter().all(|v| v.is_finite()) && y.iter().all(|v| v.is_finite()),
        "ridge: non-finite values in A or y"
    );
    let yv = DVector::from_column_slice(y);
    let ata = a.tr_mul(a);
    let (coef, cov_unscaled, cond, rank) = if lambda > 0.0 {
        let mut n_mat = ata.clone();
        for i in 0..p {
            n_mat[(i, i)] += lambda;
        }
        let eig = n_mat.symmetric_eigenvalues();
        let cond = eig.max() / eig.min();
        let chol = n_mat
            .clone()
            .cholesky()
            .context("ridge: regularised normal matrix is not positive definite")?;
        let coef = chol.solve(&a.tr_mul(&yv));
        let n_inv = chol.inverse();
        let cov = &n_inv * &ata * &n_inv;
        (coef, cov, cond, p)
    } else {
        ensure!(
            m >= p,
            "least squares needs at least {p} rows for {p} terms, got {m}"
        );
        let svd = a.clone().svd(true, true);
        let (u, v_t) = (svd.u.as_ref().unwrap(), svd.v_t.as_ref().unwrap());
        let s = &svd.singular_values;
        let s_max = s.max();
        let tol = s_max * (m.max(p) as f64) * f64::EPSILON;
        let s_inv: Vec<f64> = s
            .iter()
            .map(|&v| if v > tol { 1.0 / v } else { 0.0 })
            .collect();
        let rank = s_inv.iter().filter(|&&v| v > 0.0).count();
        ensure!(rank > 0, "least squares: design matrix is all zero");
        let s_min = s
            .iter()
            .copied()
            .filter(|&v| v > tol)
            .fold(f64::MAX, f64::min);
        let uty = u.tr_mul(&yv);
        let w = DVector::from_iterator(s.len(), uty.iter().zip(&s_inv).map(|(a, b)| a * b));
        let coef = v_t.tr_mul(&w);
        let mut vs = v_t.transpose();
        for (k, &si) in s_inv.iter().enumerate() {
            vs.column_mut(k).scale_mut(si);
        }
        let cov = &vs * vs.transpose();
        (coef, cov, (s_max / s_min).powi(2), rank)
    };
    let resid = &yv - a * &coef;
    let dof = m.saturating_sub(rank);
    ensure!(
        dof > 0,
        "ridge: {m} rows leave no residual degrees of freedom for {rank} terms"
    );
    let s2 = resid.norm_squared() / dof as f64;
    let sigma = (0..p)
        .map(|i| (s2 * cov_unscaled[(i, i)].max(0.0)).sqrt())
        .collect();
    Ok(Ridge {
        coefficients: coef.iter().copied().collect(),
        sigma,
        residual_std: s2.sqrt(),
        cond_normal: cond,
        rank,
    })
}

/// Population-style std check MagNav uses to skip filtering constant columns.
fn is_constant(x: &[f64]) -> bool {
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    let var = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    var.sqrt() <= f64::EPSILON
}

/// Scalar gaps of at most 10 ms between usable rows (`ok`), filled by linear
/// interpolation so the band-pass runs across them, and which rows were filled. At 1 kHz
/// 1 % of glitches taken out left no run long enough for the filter (4,001 samples) and
/// the fit failed; 10 ms is far shorter than any manoeuvre, so the straight line is
/// within the sensor's noise. At 10 Hz nothing is bridged (a run simply ends).
fn bridge_short_gaps(mag_nt: &[f64], ok: &[bool], fs_hz: f64) -> (Vec<f64>, Vec<bool>) {
    let longest = (0.01 * fs_hz).floor() as usize;
    let mut filled = mag_nt.to_vec();
    let mut bridged = vec![false; mag_nt.len()];
    let good = |i: usize| ok[i] && mag_nt[i].is_finite();
    let mut i = 1;
    while i < mag_nt.len() {
        if good(i) || !ok[i] || !good(i - 1) {
            i += 1;
            continue;
        }
        let start = i;
        while i < mag_nt.len() && ok[i] && !mag_nt[i].is_finite() {
            i += 1;
        }
        if i < mag_nt.len() && good(i) && i - start <= longest {
            let (a, b) = (mag_nt[start - 1], mag_nt[i]);
            let span = (i - start + 1) as f64;
            for (k, j) in (start..i).enumerate() {
                filled[j] = a + (b - a) * (k + 1) as f64 / span;
                bridged[j] = true;
            }
        }
    }
    (filled, bridged)
}

/// Fit Tolles–Lawson coefficients to `mag_nt` (scalar, nT) from `flux_nt` (fluxgate, nT).
///
/// `select` marks the rows to use (e.g. the calibration manoeuvres). Rows that are not
/// finite are excluded too; the remaining rows are split into contiguous runs, each run
/// is band-passed on its own and trimmed by `cfg.trim` at both ends, and runs too short
/// for that are dropped (counted in the result). Errors, never panics, on mismatched
/// lengths, invalid settings, or too little usable data.
pub fn fit(
    flux_nt: &[[f64; 3]],
    mag_nt: &[f64],
    cfg: &TlConfig,
    select: Option<&[bool]>,
) -> Result<TlFit> {
    let n = flux_nt.len();
    ensure!(
        mag_nt.len() == n,
        "fluxgate has {n} samples but the scalar has {}",
        mag_nt.len()
    );
    if let Some(s) = select {
        ensure!(
            s.len() == n,
            "selection has {} entries for {n} samples",
            s.len()
        );
    }
    cfg.validate()?;
    let sos = match cfg.pass_hz {
        Some((lo, hi)) => Some(butterworth_bandpass(cfg.poles, lo, hi, cfg.fs_hz)?),
        None => None,
    };
    let a = design_matrix_scaled(flux_nt, &cfg.terms, cfg.bt_scale_nt, cfg.db_scale());
    let p = a.ncols();

    let selected = |i: usize| select.is_none_or(|s| s[i]);
    let design_ok: Vec<bool> = (0..n)
        .map(|i| selected(i) && a.row(i).iter().all(|v| v.is_finite()))
        .collect();
    let (mag_nt, bridged) = bridge_short_gaps(mag_nt, &design_ok, cfg.fs_hz);
    let mag_nt = &mag_nt[..];
    let usable: Vec<bool> = (0..n)
        .map(|i| design_ok[i] && mag_nt[i].is_finite())
        .collect();
    let n_selected = (0..n).filter(|&i| selected(i)).count();
    let rows_nonfinite =
        n_selected - usable.iter().filter(|&&u| u).count() + bridged.iter().filter(|&&b| b).count();
    ensure!(
        n_selected > 0,
        "no samples selected for the Tolles–Lawson fit"
    );
    ensure!(
        rows_nonfinite < n_selected,
        "all {n_selected} selected samples have a non-finite scalar or fluxgate value"
    );

    // Contiguous runs of usable rows.
    let mut runs = Vec::new();
    let mut i = 0;
    while i < n {
        if usable[i] {
            let start = i;
            while i < n && usable[i] {
                i += 1;
            }
            runs.push(start..i);
        } else {
            i += 1;
        }
    }
    let trim = if sos.is_some() { cfg.trim } else { 0 };
    let min_len = match &sos {
        Some(s) => (2 * trim + 1).max(s.default_pad_len() + 1),
        None => (p + 1).min(n_selected).max(1),
    };
    let (good, short): (Vec<_>, Vec<_>) = runs.into_iter().partition(|r| r.len() >= min_len);
    let rows_short_runs: usize = short.iter().map(|r| r.len()).sum();
    // Bridged rows carry the band-pass across their gap; they are not fitted.
    let fitted =
        |r: &std::ops::Range<usize>| (r.start + trim..r.end - trim).filter(|&i| !bridged[i]);
    let rows_used: usize = good.iter().map(|r| fitted(r).count()).sum();
    ensure!(
        rows_used > p,
        "only {rows_used} usable rows for {p} Tolles–Lawson terms ({} selected, {rows_nonfinite} non-finite, {rows_short_runs} in runs shorter than {min_len} samples)",
        n_selected
    );

    let mut af = DMatrix::<f64>::zeros(rows_used, p);
    let mut yf = Vec::with_capacity(rows_used);
    let mut row0 = 0;
    for r in &good {
        let keep: Vec<usize> = fitted(r).map(|i| i - r.start).collect();
        for c in 0..p {
            let col: Vec<f64> = a.column(c).rows(r.start, r.len()).iter().copied().collect();
            let col = match &sos {
                Some(s) if !is_constant(&col) => filtfilt(s, &col)?,
                _ => col,
            };
            for (k, &j) in keep.iter().enumerate() {
                af[(row0 + k, c)] = col[j];
            }
        }
        let y = &mag_nt[r.clone()];
        let y = match &sos {
            Some(s) => filtfilt(s, y)?,
            None => y.to_vec(),
        };
        yf.extend(keep.iter().map(|&j| y[j]));
        row0 += keep.len();
    }

    let sol = ridge(&af, &yf, cfg.lambda)?;
    let noise_gain = sos.as_ref().map_or(1.0, Sos::filtfilt_noise_gain);
    Ok(TlFit {
        coefficients: sol.coefficients,
        sigma: sol.sigma.iter().map(|s| s / noise_gain.sqrt()).collect(),
        names: cfg.terms.names(),
        config: cfg.clone(),
        rows_used,
        rows_nonfinite,
        rows_short_runs,
        runs_used: good.len(),
        residual_std_nt: sol.residual_std,
        cond_normal: sol.cond_normal,
        rank: sol.rank,
        noise_gain,
    })
}

/// Aircraft interference `A·c` (nT) on unfiltered fluxgate data; NaN where the fluxgate
/// (or a neighbour the derivative needs) is not finite.
pub fn interference(fit: &TlFit, flux_nt: &[[f64; 3]]) -> Vec<f64> {
    let a = design_matrix_scaled(
        flux_nt,
        &fit.config.terms,
        fit.config.bt_scale_nt,
        fit.config.db_scale(),
    );
    let c = DVector::from_column_slice(&fit.coefficients);
    (a * c).iter().copied().collect()
}

/// Compensated scalar `mag − A·c` (MagNav's `mag_1_c`; no mean removal).
pub fn compensate(fit: &TlFit, flux_nt: &[[f64; 3]], mag_nt: &[f64]) -> Result<Vec<f64>> {
    ensure!(
        flux_nt.len() == mag_nt.len(),
        "fluxgate has {} samples but the scalar has {}",
        flux_nt.len(),
        mag_nt.len()
    );
    Ok(interference(fit, flux_nt)
        .into_iter()
        .zip(mag_nt)
        .map(|(i, m)| m - i)
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small design and its numpy reference (`numpy.linalg.lstsq(A, y, rcond=None)`,
    /// numpy 2.4; the script is in the comment of each case).
    fn small() -> (DMatrix<f64>, Vec<f64>) {
        let a = DMatrix::from_row_slice(
            7,
            3,
            &[
                1.0, 0.5, -2.0, 0.3, -1.2, 0.7, 2.1, 0.0, 1.1, -0.4, 0.9, 0.2, 1.5, 1.5, -0.3, 0.0,
                -0.7, 2.4, 0.8, 0.1, -1.6,
            ],
        );
        let y = vec![0.9, -1.3, 2.2, 0.4, 1.8, -0.5, 1.1];
        (a, y)
    }

    #[test]
    fn ols_reproduces_numpy_lstsq() {
        let (a, y) = small();
        let r = ridge(&a, &y, TlConfig::ols(10.0).lambda).unwrap();
        // np.linalg.lstsq(A, y, rcond=None)[0]
        let numpy = [0.8208241022300332, 0.7373361916108405, 0.018469332066400012];
        for (c, n) in r.coefficients.iter().zip(numpy) {
            assert!((c - n).abs() < 1e-12, "{c} vs numpy {n}");
        }
        assert_eq!(r.rank, 3);
        // The ridge MagNav uses is a different estimator: it moves the solution.
        let rr = ridge(&a, &y, 1.0).unwrap();
        assert!((rr.coefficients[0] - numpy[0]).abs() > 1e-3);
    }

    #[test]
    fn ols_is_minimum_norm_when_rank_deficient() {
        // Third column = first + second (TL18's ind_xx + ind_yy + ind_zz = |B|/Bt_scale is
        // the same kind of collinearity): numpy returns the minimum-norm solution.
        let (a0, y) = small();
        let a = DMatrix::from_fn(7, 3, |i, j| match j {
            2 => a0[(i, 0)] + a0[(i, 1)],
            _ => a0[(i, j)],
        });
        let r = ridge(&a, &y, 0.0).unwrap();
        // np.linalg.lstsq(np.column_stack([A[:,0], A[:,1], A[:,0]+A[:,1]]), y, rcond=None)[0]
        let numpy = [0.3066405509363911, 0.20825646174721502, 0.5148970126836059];
        for (c, n) in r.coefficients.iter().zip(numpy) {
            assert!((c - n).abs() < 1e-10, "{c} vs numpy {n}");
        }
        assert_eq!(r.rank, 2);
    }

    #[test]
    fn ols_config_is_magnav_without_ridge() {
        let o = TlConfig::ols(10.0);
        assert_eq!(o.lambda, 0.0);
        assert_eq!(
            TlConfig {
                lambda: TlConfig::default().lambda,
                ..o
            },
            TlConfig::for_rate(10.0)
        );
    }
}
