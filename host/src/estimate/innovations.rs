//! Innovation-domain regression (Friedland's bias separation): the anomaly-field Kalman
//! filter's gains do not depend on the data, so one covariance recursion can filter the
//! scalar signal and every candidate regressor column at once. The innovations of the
//! scalar minus θ·(innovations of the regressors) are exactly the innovations of the
//! filter that also estimates constant coefficients θ (with diffuse priors). So fitting
//! and testing any set of constant-coefficient terms is a least-squares problem on these
//! columns, with the field's absorption of slow signals accounted for — no filter rerun
//! per candidate.

use magcomp_core::filter::field::{FieldProcess, FIELD_STATES};

/// Geometry of each epoch the field model needs.
#[derive(Clone, Debug)]
pub struct Geometry {
    pub ds_m: Vec<f64>,
    pub dh_m: Vec<f64>,
}

/// Settings of the field filter (same meaning as the core's `CompensatorConfig`).
#[derive(Clone, Copy, Debug)]
pub struct FieldSettings {
    /// `None` = no field states: a constant offset only (models without `field`).
    pub sigma1: Option<f64>,
    pub noise_nt: f64,
}

/// Output: per epoch, innovation of every column divided by √S, and S (nT²).
pub struct Innovations {
    /// `cols[c][k]`: whitened innovation of column c at epoch k (NaN: no update).
    pub cols: Vec<Vec<f64>>,
    pub var_nt2: Vec<f64>,
}

/// Runs the field filter over `columns` (column 0 is the scalar relative to its first
/// value; the rest are regressors). NaN in column 0 = missing sample (prediction only).
pub fn filter_columns(geo: &Geometry, columns: &[&[f64]], fs: FieldSettings) -> Innovations {
    let n = geo.ds_m.len();
    let m = columns.len();
    let r = fs.noise_nt * fs.noise_nt;
    let mut cols = vec![vec![f64::NAN; n]; m];
    let mut var = vec![f64::NAN; n];
    match fs.sigma1 {
        Some(s1) => {
            let fp = FieldProcess::new(s1 as f32, (s1 / 10.0) as f32, 1000.0, 100.0);
            let v1 = s1 * s1;
            let v2 = v1 / 100.0;
            let ns = FIELD_STATES;
            let mut p = [[0.0f64; FIELD_STATES]; FIELD_STATES];
            for (i, row) in p.iter_mut().enumerate() {
                row[i] = (fp.scale[i] as f64).powi(2);
            }
            // State estimates for every column: x[c][i].
            let mut x = vec![[0.0f64; FIELD_STATES]; m];
            for k in 0..n {
                let d = geo.ds_m[k].abs();
                if d > 0.0 && d.is_finite() {
                    let mut phi = [[0.0f64; FIELD_STATES]; FIELD_STATES];
                    for (i, row) in phi.iter_mut().enumerate() {
                        row[i] = 1.0;
                    }
                    phi[0][1] = d;
                    phi[0][2] = 0.5 * d * d;
                    phi[1][2] = d;
                    phi[3][4] = d;
                    let (d2, d3) = (d * d, d * d * d);
                    let mut q = [[0.0f64; FIELD_STATES]; FIELD_STATES];
                    let q3 = [
                        [d3 * d2 / 20.0, d2 * d2 / 8.0, d3 / 6.0],
                        [d2 * d2 / 8.0, d3 / 3.0, d2 / 2.0],
                        [d3 / 6.0, d2 / 2.0, d],
                    ];
                    for i in 0..3 {
                        for j in 0..3 {
                            q[i][j] = v1 * q3[i][j];
                        }
                    }
                    q[3][3] = v2 * d3 / 3.0;
                    q[3][4] = v2 * d2 / 2.0;
                    q[4][3] = q[3][4];
                    q[4][4] = v2 * d;
                    // P = Φ P Φᵀ + Q
                    let mut fp_ = [[0.0f64; FIELD_STATES]; FIELD_STATES];
                    for i in 0..ns {
                        for j in 0..ns {
                            fp_[i][j] = (0..ns).map(|l| phi[i][l] * p[l][j]).sum();
                        }
                    }
                    for i in 0..ns {
                        for j in 0..ns {
                            p[i][j] = (0..ns).map(|l| fp_[i][l] * phi[j][l]).sum::<f64>() + q[i][j];
                        }
                    }
                    for xc in x.iter_mut() {
                        let old = *xc;
                        for i in 0..ns {
                            xc[i] = (0..ns).map(|l| phi[i][l] * old[l]).sum();
                        }
                    }
                }
                let dh = if geo.dh_m[k].is_finite() {
                    geo.dh_m[k]
                } else {
                    0.0
                };
                let h = [1.0, 0.0, 0.0, dh, 0.0];
                let ph: Vec<f64> = (0..ns)
                    .map(|i| (0..ns).map(|j| p[i][j] * h[j]).sum())
                    .collect();
                let s = (0..ns).map(|i| h[i] * ph[i]).sum::<f64>() + r;
                var[k] = s;
                if !columns[0][k].is_finite() {
                    continue;
                }
                let kg: Vec<f64> = ph.iter().map(|v| v / s).collect();
                let rs = s.sqrt();
                for (c, xc) in x.iter_mut().enumerate() {
                    let z = columns[c][k];
                    let z = if z.is_finite() { z } else { 0.0 };
                    let nu = z - (0..ns).map(|i| h[i] * xc[i]).sum::<f64>();
                    for i in 0..ns {
                        xc[i] += kg[i] * nu;
                    }
                    cols[c][k] = nu / rs;
                }
                for i in 0..ns {
                    for j in 0..ns {
                        p[i][j] -= kg[i] * ph[j];
                    }
                }
                // Keep P symmetric against rounding.
                #[allow(clippy::needless_range_loop)]
                for i in 0..ns {
                    for j in 0..i {
                        let a = 0.5 * (p[i][j] + p[j][i]);
                        p[i][j] = a;
                        p[j][i] = a;
                    }
                }
            }
        }
        None => {
            // A constant offset with a wide prior: innovations = deviations from the
            // running mean.
            let mut p = 1.0e6f64;
            let mut x = vec![0.0f64; m];
            for k in 0..n {
                let s = p + r;
                var[k] = s;
                if !columns[0][k].is_finite() {
                    continue;
                }
                let g = p / s;
                let rs = s.sqrt();
                for (c, xc) in x.iter_mut().enumerate() {
                    let z = columns[c][k];
                    let z = if z.is_finite() { z } else { 0.0 };
                    let nu = z - *xc;
                    *xc += g * nu;
                    cols[c][k] = nu / rs;
                }
                p *= 1.0 - g;
            }
        }
    }
    Innovations { cols, var_nt2: var }
}
