//! The same estimation problem in plain covariance form, f64 (host only): the yardstick
//! the f32 square-root filter is tested against. Same epochs, same regressors, same field
//! process; no scaling tricks, Joseph-form update.

use crate::flight::Flight;
use crate::model::spec::{with_model, ModelSpec};
use anyhow::{bail, Result};
use magcomp_core::epoch::{EpochBuilder, EpochConfig};
use nalgebra::{DMatrix, DVector};

/// Per-sample output of the reference filter (real-time, causal).
#[derive(Clone, Debug, Default)]
pub struct ReferenceRun {
    pub interference_nt: Vec<f64>,
    pub innovation_nt: Vec<f64>,
    pub coefficients: Vec<f64>,
}

/// Runs the f64 covariance filter. `sigma1`, `sigma2` (nT/m^2.5), `noise_nt` as in the
/// square-root filter; priors from the same terms (`prior_sigma`) and the same field
/// scales (`FieldProcess::new`).
pub fn run_reference(
    flight: &Flight,
    spec: &ModelSpec,
    sigma1: f64,
    sigma2: f64,
    noise_nt: f64,
) -> Result<ReferenceRun> {
    with_model(spec, |model| {
        let mut ecfg = EpochConfig::for_rate(flight.sample_rate_hz as f32);
        ecfg.earth_dir_ned = flight.earth_dir_ned;
        let Some(mut builder) = EpochBuilder::<128>::new(ecfg) else {
            bail!("derivative window too large");
        };
        let field = model.field;
        let nf = if field { 5 } else { 1 };
        let k = model.coefficient_count();
        let n = nf + k;
        let mut p = DMatrix::<f64>::zeros(n, n);
        if field {
            let fp = magcomp_core::filter::FieldProcess::new(
                sigma1 as f32,
                sigma2 as f32,
                1000.0,
                100.0,
            );
            for i in 0..5 {
                p[(i, i)] = (fp.scale[i] as f64).powi(2);
            }
        } else {
            p[(0, 0)] = 1000.0f64.powi(2);
        }
        let mut at = nf;
        let mut interference_mask = vec![false; n];
        let mut x_prior: Vec<(usize, f64)> = Vec::new();
        for t in model.terms {
            for i in 0..t.len() {
                p[(at + i, at + i)] = (t.prior_sigma(i) as f64).powi(2);
                x_prior.push((at + i, t.prior_mean(i) as f64));
                interference_mask[at + i] = t.is_interference();
            }
            at += t.len();
        }
        let mut x = DVector::<f64>::zeros(n);
        for (i, m) in &x_prior {
            x[*i] = *m;
        }
        let r = noise_nt * noise_nt;
        let mut out = ReferenceRun::default();
        let mut buf = [0.0f32; 16];
        let mut last_ref = None;
        let mut step = |ep: magcomp_core::Epoch, x: &mut DVector<f64>, p: &mut DMatrix<f64>| {
            // Keep B_h continuous across re-referencing, as the core does.
            if let Some(old) = last_ref.replace(ep.reference) {
                if old != ep.reference && field {
                    x[0] += (old.0 - ep.reference.0) as f64 / 1e4;
                }
            }
            if field && ep.ds_m > 0.0 {
                let d = ep.ds_m as f64;
                let mut phi = DMatrix::<f64>::identity(n, n);
                phi[(0, 1)] = d;
                phi[(0, 2)] = d * d / 2.0;
                phi[(1, 2)] = d;
                phi[(3, 4)] = d;
                let mut q = DMatrix::<f64>::zeros(n, n);
                let (s1, s2) = (sigma1 * sigma1, sigma2 * sigma2);
                let q3 = [
                    [d.powi(5) / 20.0, d.powi(4) / 8.0, d.powi(3) / 6.0],
                    [d.powi(4) / 8.0, d.powi(3) / 3.0, d * d / 2.0],
                    [d.powi(3) / 6.0, d * d / 2.0, d],
                ];
                for i in 0..3 {
                    for j in 0..3 {
                        q[(i, j)] = s1 * q3[i][j];
                    }
                }
                q[(3, 3)] = s2 * d.powi(3) / 3.0;
                q[(3, 4)] = s2 * d * d / 2.0;
                q[(4, 3)] = s2 * d * d / 2.0;
                q[(4, 4)] = s2 * d;
                *x = &phi * &*x;
                *p = &phi * &*p * phi.transpose() + q;
            }
            let mut h = DVector::<f64>::zeros(n);
            if field {
                h[0] = 1.0;
                h[3] = ep.dh_m as f64;
            } else {
                h[0] = 1.0;
            }
            let mut at = nf;
            for t in model.terms {
                let l = t.len();
                t.regressors(&ep, &mut buf[..l]);
                for i in 0..l {
                    h[at + i] = buf[i] as f64;
                }
                at += l;
            }
            let mut innovation = f64::NAN;
            if ep.dmag_nt.is_finite() {
                let ph = &*p * &h;
                let s = h.dot(&ph) + r;
                let nu = ep.dmag_nt as f64 - h.dot(&*x);
                let kg = &ph / s;
                *x += &kg * nu;
                let ikh = DMatrix::<f64>::identity(n, n) - &kg * h.transpose();
                *p = &ikh * &*p * ikh.transpose() + &kg * kg.transpose() * r;
                innovation = nu;
            }
            let interf: f64 = (nf..n)
                .filter(|&i| interference_mask[i])
                .map(|i| x[i] * h[i])
                .sum();
            (interf, innovation)
        };
        for s in &flight.samples {
            if let Some(ep) = builder.push(s) {
                let (i, nu) = step(ep, &mut x, &mut p);
                out.interference_nt.push(i);
                out.innovation_nt.push(nu);
            }
        }
        while let Some(ep) = builder.flush() {
            let (i, nu) = step(ep, &mut x, &mut p);
            out.interference_nt.push(i);
            out.innovation_nt.push(nu);
        }
        out.coefficients = (nf..n).map(|i| x[i]).collect();
        Ok(out)
    })
}
