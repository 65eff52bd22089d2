//! Small statistics kit for the diagnosis: χ² tail probabilities and quantiles (`statrs`), AR
//! prewhitening, least squares through a Gram matrix.

use nalgebra::{DMatrix, DVector, SymmetricEigen};
use statrs::distribution::{ChiSquared, ContinuousCDF};

/// P(χ²_k > x), from `statrs` (NaN for k ≤ 0 or a NaN argument).
pub fn chi2_sf(x: f64, k: f64) -> f64 {
    if x.is_nan() {
        return f64::NAN;
    }
    ChiSquared::new(k).map_or(f64::NAN, |d| d.sf(x))
}

/// Upper quantile: the x with P(χ²_k > x) = p, from `statrs` (as `1 − p` is formed, a p
/// below ~1e-16 gives +∞).
pub fn chi2_isf(p: f64, k: f64) -> f64 {
    if p.is_nan() {
        return f64::NAN; // statrs panics on a probability outside [0, 1]
    }
    let p = p.clamp(0.0, 1.0);
    ChiSquared::new(k).map_or(f64::NAN, |d| d.inverse_cdf(1.0 - p))
}

/// AR(p) coefficients `a` of `x` (Yule–Walker via Levinson–Durbin), so that
/// `e_t = x_t − Σ a_i x_{t−i}` is close to white. Returns an empty vector when the series
/// is degenerate.
pub fn fit_ar(x: &[f64], p: usize) -> Vec<f64> {
    let n = x.len();
    if n <= 2 * p + 2 {
        return Vec::new();
    }
    let mean = x.iter().sum::<f64>() / n as f64;
    let r: Vec<f64> = (0..=p)
        .map(|k| {
            (k..n)
                .map(|i| (x[i] - mean) * (x[i - k] - mean))
                .sum::<f64>()
                / n as f64
        })
        .collect();
    if r[0].is_nan() || r[0] <= 0.0 {
        return Vec::new();
    }
    let mut a = vec![0.0; p];
    let mut err = r[0];
    for m in 0..p {
        let mut acc = r[m + 1];
        for j in 0..m {
            acc -= a[j] * r[m - j];
        }
        let k = acc / err;
        if !k.is_finite() || k.abs() >= 1.0 {
            a.truncate(m);
            break;
        }
        let prev = a.clone();
        a[m] = k;
        for j in 0..m {
            a[j] = prev[j] - k * prev[m - 1 - j];
        }
        err *= 1.0 - k * k;
    }
    a
}

/// Applies the AR whitening filter: `y_t = x_t − Σ a_i x_{t−i}` for t ≥ p.
pub fn ar_filter(x: &[f64], a: &[f64]) -> Vec<f64> {
    let p = a.len();
    (p..x.len())
        .map(|t| {
            x[t] - a
                .iter()
                .enumerate()
                .map(|(i, ai)| ai * x[t - 1 - i])
                .sum::<f64>()
        })
        .collect()
}

/// Least squares of `y` on the columns `cols` through their Gram matrix, robust to
/// collinear columns (eigen-decomposition with a relative cut-off). `gram` is the Gram of
/// [y, X...] (index 0 = y); `cols` index into it. Returns (coefficients, RSS, rank).
pub fn gram_lstsq(gram: &DMatrix<f64>, cols: &[usize]) -> (Vec<f64>, f64, usize) {
    let k = cols.len();
    let yy = gram[(0, 0)];
    if k == 0 {
        return (Vec::new(), yy, 0);
    }
    // Normalise columns so the cut-off is scale-free (currents in A, rates in nT/s...).
    let d: Vec<f64> = cols
        .iter()
        .map(|&c| {
            let v = gram[(c, c)];
            if v > 0.0 {
                1.0 / v.sqrt()
            } else {
                0.0
            }
        })
        .collect();
    let a = DMatrix::from_fn(k, k, |i, j| gram[(cols[i], cols[j])] * d[i] * d[j]);
    let b = DVector::from_fn(k, |i, _| gram[(cols[i], 0)] * d[i]);
    let eig = SymmetricEigen::new(a);
    let lmax = eig.eigenvalues.iter().cloned().fold(0.0f64, f64::max);
    let tol = lmax * 1e-9;
    let mut z = DVector::zeros(k);
    let mut rank = 0;
    let ub = eig.eigenvectors.transpose() * &b;
    for i in 0..k {
        let l = eig.eigenvalues[i];
        if l > tol {
            rank += 1;
            z += eig.eigenvectors.column(i) * (ub[i] / l);
        }
    }
    let explained: f64 = z.dot(&b);
    let theta: Vec<f64> = (0..k).map(|i| z[i] * d[i]).collect();
    (theta, (yy - explained).max(0.0), rank)
}

/// Gram matrix of the given column vectors (all the same length).
pub fn gram_of(cols: &[&[f64]]) -> DMatrix<f64> {
    let k = cols.len();
    let mut g = DMatrix::zeros(k, k);
    for i in 0..k {
        for j in i..k {
            let v: f64 = cols[i].iter().zip(cols[j]).map(|(a, b)| a * b).sum();
            g[(i, j)] = v;
            g[(j, i)] = v;
        }
    }
    g
}

/// Median of finite values (NaN if none).
/// Mean of the finite values (0 when there are none).
pub fn finite_mean(v: &[f64]) -> f64 {
    let f: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    f.iter().sum::<f64>() / f.len().max(1) as f64
}

pub fn median(v: &[f64]) -> f64 {
    let mut f: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if f.is_empty() {
        return f64::NAN;
    }
    let m = f.len() / 2;
    f.select_nth_unstable_by(m, |a, b| a.total_cmp(b));
    f[m]
}

/// Lag-1 autocorrelation.
pub fn lag1_autocorr(x: &[f64]) -> f64 {
    let n = x.len();
    if n < 3 {
        return 0.0;
    }
    let m = x.iter().sum::<f64>() / n as f64;
    let v: f64 = x.iter().map(|a| (a - m) * (a - m)).sum();
    if v.is_nan() || v <= 0.0 {
        return 0.0;
    }
    (1..n).map(|i| (x[i] - m) * (x[i - 1] - m)).sum::<f64>() / v
}

/// Centred moving mean over `w` samples (shorter at the ends).
pub fn moving_mean(v: &[f64], w: usize) -> Vec<f64> {
    let n = v.len();
    let h = w / 2;
    let mut cum = vec![0.0; n + 1];
    for i in 0..n {
        cum[i + 1] = cum[i] + v[i];
    }
    (0..n)
        .map(|i| {
            let (a, b) = (i.saturating_sub(h), (i + h + 1).min(n));
            (cum[b] - cum[a]) / (b - a) as f64
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chi2_matches_known_values() {
        // Table values (Abramowitz & Stegun 26.4; NIST/SEMATECH e-Handbook 1.3.6.7.4).
        for (p, k, x) in [
            (0.05, 1.0, 3.841_459),
            (0.01, 1.0, 6.634_897),
            (0.05, 2.0, 5.991_465),
            (0.05, 10.0, 18.307_038),
            (0.001, 5.0, 20.515_006),
            (0.05, 100.0, 124.342_113),
        ] {
            assert!(
                (chi2_sf(x, k) - p).abs() < 1e-6 * p.max(1e-3),
                "sf({x}, {k})"
            );
            assert!((chi2_isf(p, k) - x).abs() < 1e-5 * x, "isf({p}, {k})");
        }
        assert!(chi2_sf(400.0, 3.0) < 1e-80);
        assert_eq!(chi2_sf(0.0, 3.0), 1.0);
        assert!(chi2_sf(f64::NAN, 3.0).is_nan());
        assert!(chi2_sf(1.0, 0.0).is_nan());
        assert!(chi2_isf(f64::NAN, 3.0).is_nan());
        assert_eq!(chi2_isf(2.0, 3.0), 0.0);
        // The diagnosis' F statistics are Wald forms F·q ~ χ²_q: F(0.95; 3, ∞) = 7.8147 / 3.
        assert!((chi2_isf(0.05, 3.0) / 3.0 - 2.604_9).abs() < 1e-4);
    }

    #[test]
    fn ar_whitens_an_ar1_series() {
        let mut x = vec![0.0f64; 5000];
        let mut s = 1u64;
        for i in 1..x.len() {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let u = ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5;
            x[i] = 0.9 * x[i - 1] + u;
        }
        let a = fit_ar(&x, 3);
        assert!((a[0] - 0.9).abs() < 0.03, "{a:?}");
        let w = ar_filter(&x, &a);
        assert!(lag1_autocorr(&w).abs() < 0.05);
    }

    #[test]
    fn lstsq_handles_collinear_columns() {
        let x1: Vec<f64> = (0..100).map(|i| (i as f64 * 0.1).sin()).collect();
        let x2: Vec<f64> = x1.iter().map(|v| 2.0 * v).collect();
        let y: Vec<f64> = x1.iter().map(|v| 3.0 * v).collect();
        let g = gram_of(&[&y, &x1, &x2]);
        let (_, rss, rank) = gram_lstsq(&g, &[1, 2]);
        assert_eq!(rank, 1);
        assert!(rss < 1e-9);
    }
}
