//! `fluxtemp:CH`: the fluxgate's bias and scale follow a temperature channel,
//! `B = B_F + (T − T_ref)·(b + s∘B_F)`. Like a static miscalibration (`fluxcal`) it bends
//! the direction cosines, and a TL fit hides most of it from the scalar residual; what
//! shows it is the fluxgate's modulus against the scalar (minus the interference estimate).
//! The fit is that of `fluxcal::fit_modulus` with 6 more parameters: the static 9
//! (symmetric scale/non-orthogonality and bias) are fitted alongside as nuisance, so a
//! static miscalibration is not taken for a temperature effect; only the temperature part
//! is applied (a static one is `fluxcal`'s job).

use crate::flight::Flight;
use crate::model::corrections::FluxgateTemperature;
use anyhow::{bail, Result};
use nalgebra::{SMatrix, SVector};

impl FluxgateTemperature {
    /// The flight with its fluxgate corrected; `channel` is the aux index of the
    /// temperature.
    pub fn apply_to_flight(&self, flight: &Flight, channel: usize) -> Flight {
        let mut f = flight.clone();
        for s in &mut f.samples {
            let t = s.aux[channel] as f64;
            s.flux_nt = self.apply(s.flux_nt.map(f64::from), t).map(|v| v as f32);
        }
        f
    }
}

/// Outcome of the modulus fit.
#[derive(Clone, Debug)]
pub struct FluxTempFit {
    pub correction: FluxgateTemperature,
    /// Residual sum of squares of the modulus with the 9 static parameters only, and with
    /// the 6 temperature ones too (nT²), over `samples` rows.
    pub rss_static_nt2: f64,
    pub rss_full_nt2: f64,
    pub samples: usize,
    /// Residual of the full fit per used row (nT).
    pub residual_nt: Vec<f64>,
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

const P: usize = 15;

/// `M·(B_F + d·(bT + sT∘B_F)) + b` for parameters s11 s22 s33 s12 s13 s23 b1 b2 b3 bT1..3
/// sT1..3 (the temperature ones zero and fixed when `free` is 9).
fn model(p: &SVector<f64, P>, b: [f64; 3], d: f64) -> ([f64; 3], [[f64; 3]; 3], [f64; 3]) {
    let m = [
        [1.0 + p[0], p[3], p[4]],
        [p[3], 1.0 + p[1], p[5]],
        [p[4], p[5], 1.0 + p[2]],
    ];
    let c: [f64; 3] = std::array::from_fn(|i| b[i] + d * (p[9 + i] + p[12 + i] * b[i]));
    let v = std::array::from_fn(|i| (0..3).map(|j| m[i][j] * c[j]).sum::<f64>() + p[6 + i]);
    (v, m, c)
}

/// Gauss–Newton on the first `free` parameters; returns them, the residual per row and the
/// normal matrix at the solution.
fn solve(
    flux: &[[f64; 3]],
    temp: &[f64],
    reference: &[f64],
    rows: &[usize],
    free: usize,
) -> Result<(SVector<f64, P>, Vec<f64>, SMatrix<f64, P, P>)> {
    let rss = |p: &SVector<f64, P>| -> f64 {
        rows.iter()
            .map(|&i| (reference[i] - norm(model(p, flux[i], temp[i]).0)).powi(2))
            .sum()
    };
    let mut p = SVector::<f64, P>::zeros();
    let mut rss_p = rss(&p);
    let mut jtj = SMatrix::<f64, P, P>::zeros();
    for _ in 0..10 {
        jtj = SMatrix::zeros();
        let mut jtr = SVector::<f64, P>::zeros();
        for &i in rows {
            let (b, d) = (flux[i], temp[i]);
            let (v, m, c) = model(&p, b, d);
            let nv = norm(v);
            let u = [v[0] / nv, v[1] / nv, v[2] / nv];
            // ∂|v|/∂c = Mᵀu (the temperature part enters through c).
            let w: [f64; 3] = std::array::from_fn(|j| (0..3).map(|i| m[i][j] * u[i]).sum());
            let mut j = SVector::<f64, P>::zeros();
            let g = [
                u[0] * c[0],
                u[1] * c[1],
                u[2] * c[2],
                u[0] * c[1] + u[1] * c[0],
                u[0] * c[2] + u[2] * c[0],
                u[1] * c[2] + u[2] * c[1],
                u[0],
                u[1],
                u[2],
                w[0] * d,
                w[1] * d,
                w[2] * d,
                w[0] * d * b[0],
                w[1] * d * b[1],
                w[2] * d * b[2],
            ];
            for k in 0..free {
                j[k] = g[k];
            }
            let r = reference[i] - nv;
            jtj += j * j.transpose();
            jtr += j * r;
        }
        for k in free..P {
            jtj[(k, k)] = 1.0;
        }
        let Some(step) = jtj.cholesky().map(|c| c.solve(&jtr)) else {
            bail!("the flight's attitudes and temperatures do not determine the fluxgate's temperature coefficients");
        };
        // Step halving: on a cloverleaf the z scale and bias are nearly collinear (the field
        // stays near the z axis), and with a misfit the static model cannot follow (a
        // drift, when only the 9 are free) a full Gauss–Newton step along that direction
        // made the modulus misfit 40 → 9,000 nT sd. Never accept a step that increases it.
        let mut step = step;
        let mut accepted = false;
        for _ in 0..30 {
            let r = rss(&(p + step));
            if r <= rss_p {
                p += step;
                rss_p = r;
                accepted = true;
                break;
            }
            step *= 0.5;
        }
        if !accepted || step.amax() < 1e-12 * (1.0 + p.amax()) {
            break;
        }
    }
    let resid = rows
        .iter()
        .map(|&i| reference[i] - norm(model(&p, flux[i], temp[i]).0))
        .collect();
    Ok((p, resid, jtj))
}

/// Fits the temperature coefficients (with the static calibration as nuisance) so that the
/// corrected fluxgate's modulus equals `reference_nt`. `temp_degc` per sample.
pub fn fit_modulus(
    flux: &[[f64; 3]],
    temp_degc: &[f64],
    reference_nt: &[f64],
    channel: &str,
) -> Result<FluxTempFit> {
    let rows: Vec<usize> = (0..flux.len())
        .filter(|&i| {
            flux[i].iter().all(|v| v.is_finite())
                && reference_nt[i].is_finite()
                && temp_degc[i].is_finite()
                && norm(flux[i]) > 1000.0
        })
        .collect();
    if rows.len() < 100 {
        bail!(
            "only {} samples with a fluxgate vector, a scalar reading and temperature '{channel}': too few to fit the fluxgate's temperature coefficients",
            rows.len()
        );
    }
    let t_ref = rows.iter().map(|&i| temp_degc[i]).sum::<f64>() / rows.len() as f64;
    let d: Vec<f64> = temp_degc.iter().map(|t| t - t_ref).collect();
    let spread = (rows.iter().map(|&i| d[i] * d[i]).sum::<f64>() / rows.len() as f64).sqrt();
    if spread < 1e-3 {
        bail!("temperature '{channel}' does not vary over the flight: its coefficients cannot be fitted");
    }
    let (_, r0, _) = solve(flux, &d, reference_nt, &rows, 9)?;
    let (p, r1, jtj) = solve(flux, &d, reference_nt, &rows, P)?;
    let rss0: f64 = r0.iter().map(|v| v * v).sum();
    let rss1: f64 = r1.iter().map(|v| v * v).sum();
    // 1σ from the normal matrix, the residual variance and the residual's lag-1
    // correlation (the modulus misfit is smooth, not white).
    let rho = crate::signal::stats::lag1_autocorr(&r1).clamp(-0.99, 0.99);
    let inflate = (1.0 + rho) / (1.0 - rho);
    let var = rss1 / (rows.len() as f64 - P as f64).max(1.0) * inflate;
    let cov = jtj
        .try_inverse()
        .unwrap_or_else(|| SMatrix::from_element(f64::NAN));
    let sd = |k: usize| (cov[(k, k)] * var).max(0.0).sqrt();
    let mut residual_nt = vec![f64::NAN; flux.len()];
    for (&i, v) in rows.iter().zip(&r1) {
        residual_nt[i] = *v;
    }
    Ok(FluxTempFit {
        correction: FluxgateTemperature {
            channel: channel.to_string(),
            reference_degc: t_ref,
            bias_nt_per_degc: [p[9], p[10], p[11]],
            bias_sigma_nt_per_degc: [sd(9), sd(10), sd(11)],
            scale_per_degc: [p[12], p[13], p[14]],
            scale_sigma_per_degc: [sd(12), sd(13), sd(14)],
        },
        rss_static_nt2: rss0,
        rss_full_nt2: rss1,
        samples: rows.len(),
        residual_nt,
    })
}

/// The flight's fit: reference = scalar − `interference_nt`, temperature = aux `channel`.
pub fn fit_flight(flight: &Flight, channel: usize, interference_nt: &[f64]) -> Result<FluxTempFit> {
    let reference: Vec<f64> = flight
        .mag_nt
        .iter()
        .zip(interference_nt)
        .map(|(m, i)| m - i)
        .collect();
    let temp: Vec<f64> = flight
        .samples
        .iter()
        .map(|s| s.aux[channel] as f64)
        .collect();
    let name = flight
        .channels
        .get(channel)
        .cloned()
        .unwrap_or_else(|| format!("aux {channel}"));
    fit_modulus(
        &crate::estimate::fluxcal::flight_flux(flight),
        &temp,
        &reference,
        &name,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bias drifting with temperature on top of a static miscalibration: the fit recovers
    /// the drift, not the static part.
    #[test]
    fn recovers_a_temperature_bias_beside_a_static_miscalibration() {
        let f_nt = 52_000.0;
        let bias_t = [0.6, 0.0, -0.3];
        let static_bias = [120.0, -80.0, 40.0];
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut flux, mut temp, mut reference) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..3000 {
            let (th, ph) = (
                next() * std::f64::consts::PI,
                next() * std::f64::consts::TAU,
            );
            let b = [
                th.sin() * ph.cos() * f_nt,
                th.sin() * ph.sin() * f_nt,
                th.cos() * f_nt,
            ];
            let t = 20.0 - 15.0 * (k as f64 / 3000.0) + 2.0 * (k as f64 / 200.0).sin();
            // Raw reading: true field minus the static bias minus the drift (so that the
            // static calibration plus the temperature correction give the truth back).
            let d = t - 12.5;
            flux.push(std::array::from_fn(|i| {
                b[i] - static_bias[i] - d * bias_t[i]
            }));
            temp.push(t);
            reference.push(f_nt);
        }
        let fit = fit_modulus(&flux, &temp, &reference, "temp_flux").unwrap();
        let c = &fit.correction;
        for (est, truth) in c.bias_nt_per_degc.iter().zip(bias_t) {
            assert!((est - truth).abs() < 0.01, "{:?}", c.bias_nt_per_degc);
        }
        assert!(fit.rss_full_nt2 < 1e-6 * fit.rss_static_nt2, "{fit:?}");
        let e = fit_modulus(&flux, &vec![20.0; flux.len()], &reference, "t").unwrap_err();
        assert!(e.to_string().contains("does not vary"), "{e}");
    }
}
