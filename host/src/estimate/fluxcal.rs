//! Scalar calibration of the fluxgate against the scalar magnetometer ("fluxcal").
//!
//! A fluxgate's bias, axis scale and non-orthogonality distort the direction cosines `e`
//! that every Tolles–Lawson regressor is built from. A rigid misalignment does not matter
//! to the compensation (the coefficients rotate with it) and is not observable from the
//! modulus, so the calibration is the classic 9-parameter one: a symmetric matrix
//! `M = I + S` (3 scales, 3 non-orthogonalities) and a bias `b`, chosen so that
//! `|M·B_F + b|` equals the scalar field at every sample (Gauss–Newton, f64).
//!
//! The reference modulus is the scalar reading minus the aircraft interference the
//! compensator estimated: the fluxgate sees the geological anomaly too, so it stays in.

use crate::flight::Flight;
use anyhow::{bail, Result};
use nalgebra::{SMatrix, SVector};
use serde::{Deserialize, Serialize};

/// `B_cal = matrix · B_F + bias_nt`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FluxgateCalibration {
    pub matrix: [[f64; 3]; 3],
    pub bias_nt: [f64; 3],
}

impl FluxgateCalibration {
    pub const IDENTITY: Self = Self {
        matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        bias_nt: [0.0; 3],
    };

    pub fn apply(&self, b: [f64; 3]) -> [f64; 3] {
        let m = &self.matrix;
        [
            m[0][0] * b[0] + m[0][1] * b[1] + m[0][2] * b[2] + self.bias_nt[0],
            m[1][0] * b[0] + m[1][1] * b[1] + m[1][2] * b[2] + self.bias_nt[1],
            m[2][0] * b[0] + m[2][1] * b[1] + m[2][2] * b[2] + self.bias_nt[2],
        ]
    }

    /// The board's form (f32, `SETFLUX` order); `None` unless it is a plausible one.
    pub fn to_board(&self) -> Option<magcomp_core::protocol::fluxgate::FluxCalibration> {
        let mut v = [0f32; 12];
        for i in 0..3 {
            for j in 0..3 {
                v[3 * i + j] = self.matrix[i][j] as f32;
            }
            v[9 + i] = self.bias_nt[i] as f32;
        }
        magcomp_core::protocol::fluxgate::FluxCalibration::from_array(&v)
    }

    /// Determinant of the matrix: negative for a left-handed frame.
    pub fn determinant(&self) -> f64 {
        let m = &self.matrix;
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    }

    /// `None` if the calibration is one a working fluxgate can need, else what is wrong, in
    /// words ([`MAX_BIAS_NT`], [`MAX_SCALE_ERROR`], [`MAX_NON_ORTHOGONALITY`], a
    /// right-handed frame). A fit outside them was made from bad data (one row with
    /// `flux_z` = 0 gave a −38,736 nT bias and a z scale of 1.75), or the axes are
    /// swapped or negated; either way it must not reach the survey or the board.
    pub fn physical_problem(&self) -> Option<String> {
        let m = &self.matrix;
        if m.iter()
            .flatten()
            .chain(&self.bias_nt)
            .any(|v| !v.is_finite())
        {
            return Some("the fluxgate calibration has a value that is not a number".into());
        }
        let det = self.determinant();
        if det <= 0.0 {
            return Some(format!(
                "the fluxgate calibration's matrix has determinant {det:.3}: it maps the \
                 fluxgate to a left-handed frame (an axis negated or two axes swapped)"
            ));
        }
        for (i, axis) in ["x", "y", "z"].iter().enumerate() {
            if self.bias_nt[i].abs() > MAX_BIAS_NT {
                return Some(format!(
                    "the fluxgate calibration's {axis} bias is {:.0} nT, beyond the ±{MAX_BIAS_NT:.0} nT \
                     a fluxgate and its installation can have",
                    self.bias_nt[i]
                ));
            }
            if (m[i][i] - 1.0).abs() > MAX_SCALE_ERROR {
                return Some(format!(
                    "the fluxgate calibration's {axis} scale is {:.4}, beyond 1 ± {MAX_SCALE_ERROR}",
                    m[i][i]
                ));
            }
            for j in (0..3).filter(|&j| j != i) {
                if m[i][j].abs() > MAX_NON_ORTHOGONALITY {
                    return Some(format!(
                        "the fluxgate calibration's non-orthogonality term ({}, {}) is {:.4} \
                         ({:.1}°), beyond {MAX_NON_ORTHOGONALITY} ({:.1}°)",
                        i + 1,
                        j + 1,
                        m[i][j],
                        m[i][j].asin().to_degrees(),
                        MAX_NON_ORTHOGONALITY.asin().to_degrees()
                    ));
                }
            }
        }
        None
    }

    /// Largest angle (rad) between the raw and the calibrated direction over `flux`.
    pub fn max_direction_change_rad(&self, flux: &[[f64; 3]]) -> f64 {
        flux.iter()
            .filter(|b| b.iter().all(|v| v.is_finite()))
            .map(|&b| self.direction_change_rad(b))
            .fold(0.0, f64::max)
    }

    /// Angle (rad) between the raw and the calibrated direction of `b`.
    pub fn direction_change_rad(&self, b: [f64; 3]) -> f64 {
        let c = self.apply(b);
        let dot = (b[0] * c[0] + b[1] * c[1] + b[2] * c[2]) / (norm(b) * norm(c));
        dot.clamp(-1.0, 1.0).acos()
    }
}

/// Outcome of a fit.
#[derive(Clone, Debug, Serialize)]
pub struct FluxgateFit {
    pub calibration: FluxgateCalibration,
    /// Standard deviation of `|B_F| − F` before and of `|M·B_F + b| − F` after (nT).
    pub modulus_sd_before_nt: f64,
    pub modulus_sd_after_nt: f64,
    /// Samples used.
    pub samples: usize,
    /// RMS over the flight of the 1σ direction error (rad) the fitted calibration leaves,
    /// from the fit's covariance: where the attitudes do not determine the calibration (a
    /// straight line sees the field from one direction only) it is large, and applying the
    /// fit would turn fluxgate noise into direction errors.
    pub direction_sigma_rad: f64,
    /// RMS over the flight of the angle (rad) by which the calibration turns the direction.
    pub direction_change_rad: f64,
    /// `|B_F| − F` per sample before the fit (NaN where unused), for the report.
    #[serde(skip)]
    pub residual_before_nt: Vec<f64>,
    /// Residual of the fit per sample (NaN where unused).
    #[serde(skip)]
    pub residual_nt: Vec<f64>,
}

/// Largest fluxgate calibration bias (nT per axis) accepted. Sensor offsets are tens of nT
/// (Bartington Mag-03: ±5 nT; aerial three-axis units: ≤ 100 nT); the rest is the
/// aircraft's permanent field at the fluxgate, which an installation keeps to hundreds of
/// nT and a poor one to ~1,000–2,000 nT. 5,000 nT leaves room for a bad one and still
/// refuses what only bad data gives (−38,736 nT from one zero row).
pub const MAX_BIAS_NT: f64 = 5_000.0;
/// Largest |scale − 1| accepted: sensors are within ~0.5 % and soft iron in the aircraft
/// adds ~1 %; 5 % is several times either (a zero row gave 1.75).
pub const MAX_SCALE_ERROR: f64 = 0.05;
/// Largest off-diagonal term accepted (≈ half the sine of the angle between two axes'
/// departure from 90°, symmetric form): sensors are orthogonal to ≤ 0.5°; 0.05 (≈ 2.9°)
/// is several times that plus soft iron.
pub const MAX_NON_ORTHOGONALITY: f64 = 0.05;

/// A fitted calibration is applied when the direction uncertainty it leaves is below this
/// share of the direction correction it makes. On calibration patterns the fluxgate in the
/// aircraft's field is turned by 2–12 mrad with 0.1 mrad uncertainty (1–2 %); on a straight
/// line without manoeuvres the uncertainty (3.6 mrad) exceeds the correction (2.7 mrad):
/// the fit there would turn fluxgate noise and geology into direction errors.
pub const MAX_DIRECTION_SIGMA_SHARE: f64 = 0.25;

impl FluxgateFit {
    /// The fit, if within physical bounds ([`FluxgateCalibration::physical_problem`]).
    pub fn physical(self) -> Result<Self> {
        match self.calibration.physical_problem() {
            None => Ok(self),
            Some(p) => bail!("{p}: refused (bad fluxgate data, or swapped or negated axes)"),
        }
    }

    /// The fit, if the flight's attitudes determine it ([`MAX_DIRECTION_SIGMA_SHARE`]);
    /// otherwise an error saying why.
    pub fn determined(self) -> Result<Self> {
        if self.direction_sigma_rad <= MAX_DIRECTION_SIGMA_SHARE * self.direction_change_rad {
            return Ok(self);
        }
        bail!(
            "the flight's attitudes do not determine the fluxgate calibration: it would turn \
             the direction by {:.1e} rad rms with an uncertainty of {:.1e} rad (a calibration \
             is applied when its uncertainty is below {} of its correction)",
            self.direction_change_rad,
            self.direction_sigma_rad,
            MAX_DIRECTION_SIGMA_SHARE
        )
    }
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// Parameter order: s11, s22, s33, s12, s13, s23, b1, b2, b3.
fn calibration_of(p: &SVector<f64, 9>) -> FluxgateCalibration {
    FluxgateCalibration {
        matrix: [
            [1.0 + p[0], p[3], p[4]],
            [p[3], 1.0 + p[1], p[5]],
            [p[4], p[5], 1.0 + p[2]],
        ],
        bias_nt: [p[6], p[7], p[8]],
    }
}

/// Full Gauss–Newton steps of [`fit_modulus`] (a well-scaled fluxgate converges in 3–4);
/// halved steps do not count, up to [`MAX_DAMPED_STEPS`] in all.
const MAX_GAUSS_NEWTON_STEPS: usize = 8;
const MAX_DAMPED_STEPS: usize = 30;
/// Halvings of one step before it is given up.
const MAX_STEP_HALVINGS: usize = 30;

/// Fits the 9-parameter calibration so that `|M·B_F + b| = reference_nt`.
pub fn fit_modulus(flux: &[[f64; 3]], reference_nt: &[f64]) -> Result<FluxgateFit> {
    let rows: Vec<usize> = (0..flux.len().min(reference_nt.len()))
        .filter(|&i| {
            flux[i].iter().all(|v| v.is_finite())
                && reference_nt[i].is_finite()
                && norm(flux[i]) > 1000.0
        })
        .collect();
    if rows.len() < 100 {
        bail!(
            "only {} samples with a fluxgate vector and a scalar reading: too few to calibrate the fluxgate",
            rows.len()
        );
    }
    let sum_sq = |p: &SVector<f64, 9>| {
        let cal = calibration_of(p);
        rows.iter()
            .map(|&i| (reference_nt[i] - norm(cal.apply(flux[i]))).powi(2))
            .sum::<f64>()
    };
    let mut p = SVector::<f64, 9>::zeros();
    let mut cost = sum_sq(&p);
    let mut jtj = SMatrix::<f64, 9, 9>::zeros();
    // Gauss–Newton: nearly linear where |δ| ≪ |B|. A fluxgate whose scale is far off (the
    // SGL aircraft's `flux_c`: 1.5 µT of modulus misfit) makes the full step overshoot, and
    // undamped it diverged (9.7 µT misfit after, 1.2 µT before): a step is halved until the
    // misfit falls.
    let mut full_steps = 0;
    for _ in 0..MAX_DAMPED_STEPS {
        if full_steps == MAX_GAUSS_NEWTON_STEPS {
            break;
        }
        let cal = calibration_of(&p);
        jtj = SMatrix::<f64, 9, 9>::zeros();
        let mut jtr = SVector::<f64, 9>::zeros();
        for &i in &rows {
            let b = flux[i];
            let v = cal.apply(b);
            let nv = norm(v);
            let u = [v[0] / nv, v[1] / nv, v[2] / nv];
            let j = SVector::<f64, 9>::from_column_slice(&[
                u[0] * b[0],
                u[1] * b[1],
                u[2] * b[2],
                u[0] * b[1] + u[1] * b[0],
                u[0] * b[2] + u[2] * b[0],
                u[1] * b[2] + u[2] * b[1],
                u[0],
                u[1],
                u[2],
            ]);
            let r = reference_nt[i] - nv;
            jtj += j * j.transpose();
            jtr += j * r;
        }
        let Some(mut step) = jtj.cholesky().map(|c| c.solve(&jtr)) else {
            bail!("the flight's attitudes do not determine the fluxgate calibration (too few headings or attitudes)");
        };
        // Only a step that raises the misfit beyond rounding is halved, so a fit that
        // converges takes exactly the steps it took undamped.
        let mut trial_cost = sum_sq(&(p + step));
        let mut halved = false;
        for _ in 0..MAX_STEP_HALVINGS {
            if trial_cost <= cost * (1.0 + 1e-9) {
                break;
            }
            step *= 0.5;
            halved = true;
            trial_cost = sum_sq(&(p + step));
        }
        full_steps += usize::from(!halved);
        if trial_cost > cost * (1.0 + 1e-9) {
            break; // no step lowers the misfit: p is the minimum to rounding
        }
        p += step;
        cost = trial_cost;
        if step.amax() < 1e-12 * (1.0 + p.amax()) {
            break;
        }
    }
    let cal = calibration_of(&p);
    let mut residual_before_nt = vec![f64::NAN; flux.len()];
    let mut residual_nt = vec![f64::NAN; flux.len()];
    for &i in &rows {
        residual_before_nt[i] = norm(flux[i]) - reference_nt[i];
        residual_nt[i] = norm(cal.apply(flux[i])) - reference_nt[i];
    }
    // Over the fitted rows (the others are NaN).
    let sd = |v: &[f64]| {
        let m = rows.iter().map(|&i| v[i]).sum::<f64>() / rows.len() as f64;
        (rows.iter().map(|&i| (v[i] - m).powi(2)).sum::<f64>() / rows.len() as f64).sqrt()
    };
    let modulus_sd_after_nt = sd(&residual_nt);
    Ok(FluxgateFit {
        calibration: cal,
        modulus_sd_before_nt: sd(&residual_before_nt),
        modulus_sd_after_nt,
        samples: rows.len(),
        direction_sigma_rad: direction_sigma_rad(flux, &rows, &cal, &jtj, modulus_sd_after_nt),
        direction_change_rad: {
            let sq: f64 = rows
                .iter()
                .map(|&i| cal.direction_change_rad(flux[i]).powi(2))
                .sum();
            (sq / rows.len() as f64).sqrt()
        },
        residual_before_nt,
        residual_nt,
    })
}

/// RMS over `rows` (every 10th) of the 1σ angle between the true and the calibrated
/// direction, from the parameter covariance `σ²·(JᵀJ)⁻¹`: only the part of a parameter error
/// perpendicular to the field turns the direction cosines. Infinite when `JᵀJ` is singular.
fn direction_sigma_rad(
    flux: &[[f64; 3]],
    rows: &[usize],
    cal: &FluxgateCalibration,
    jtj: &SMatrix<f64, 9, 9>,
    sigma_nt: f64,
) -> f64 {
    let Some(inv) = jtj.cholesky().map(|c| c.inverse()) else {
        return f64::INFINITY;
    };
    let cov = inv * (sigma_nt * sigma_nt);
    let (mut sum, mut n) = (0.0, 0usize);
    for &i in rows.iter().step_by(10) {
        let b = flux[i];
        let v = cal.apply(b);
        let nv = norm(v);
        let u = [v[0] / nv, v[1] / nv, v[2] / nv];
        // dv/dp in the parameter order s11, s22, s33, s12, s13, s23, b1, b2, b3.
        let mut d = SMatrix::<f64, 3, 9>::zeros();
        d[(0, 0)] = b[0];
        d[(1, 1)] = b[1];
        d[(2, 2)] = b[2];
        d[(0, 3)] = b[1];
        d[(1, 3)] = b[0];
        d[(0, 4)] = b[2];
        d[(2, 4)] = b[0];
        d[(1, 5)] = b[2];
        d[(2, 5)] = b[1];
        d[(0, 6)] = 1.0;
        d[(1, 7)] = 1.0;
        d[(2, 8)] = 1.0;
        let uv = nalgebra::Vector3::new(u[0], u[1], u[2]);
        let g = (nalgebra::Matrix3::identity() - uv * uv.transpose()) * d / nv;
        sum += (g * cov * g.transpose()).trace();
        n += 1;
    }
    if n == 0 {
        return f64::INFINITY;
    }
    (sum / n as f64).sqrt()
}

/// The flight's fluxgate fitted to its scalar minus `interference_nt` (a compensator
/// pass's estimate: the aircraft field at the scalar sensor is not seen by the fluxgate).
pub fn fit_flight(flight: &Flight, interference_nt: &[f64]) -> Result<FluxgateFit> {
    let reference: Vec<f64> = flight
        .mag_nt
        .iter()
        .zip(interference_nt)
        .map(|(m, i)| m - i)
        .collect();
    fit_modulus(&flight_flux(flight), &reference)
}

/// The same flight with its fluxgate corrected by a scalar calibration (`fluxcal`).
pub fn calibrated_flight(flight: &Flight, cal: &FluxgateCalibration) -> Flight {
    let mut f = flight.clone();
    for s in &mut f.samples {
        s.flux_nt = cal.apply(s.flux_nt.map(f64::from)).map(|v| v as f32);
    }
    f
}

/// The flight's fluxgate vectors in f64.
pub fn flight_flux(flight: &Flight) -> Vec<[f64; 3]> {
    flight
        .samples
        .iter()
        .map(|s| s.flux_nt.map(f64::from))
        .collect()
}

/// Roll- and pitch-axis misalignment (rad, about body x and y) of the calibrated fluxgate
/// against the INS: the small rotation ω with `e_fluxgate ≈ e_ins + ω × e_ins`, least
/// squares over the flight, `e_ins` from the INS attitude and the main-field direction. The
/// trace gives no main-field direction, so it is estimated from the same fluxgate and INS;
/// a rotation about the vertical then looks like a declination error and is not reported.
/// The compensation does not need it (the TL coefficients rotate with the fluxgate): it is
/// an installation check. `None` without INS attitude.
pub fn ins_misalignment_rad(flight: &Flight, cal: &FluxgateCalibration) -> Option<[f64; 2]> {
    let flux: Vec<[f64; 3]> = flight_flux(flight).iter().map(|b| cal.apply(*b)).collect();
    let att: Vec<[f64; 3]> = flight
        .samples
        .iter()
        .map(|s| s.attitude_deg.map(f64::from))
        .collect();
    let col = |v: &Vec<[f64; 3]>, i: usize| v.iter().map(|x| x[i]).collect::<Vec<f64>>();
    let e_ned = crate::flight::main_field_direction(
        &col(&flux, 0),
        &col(&flux, 1),
        &col(&flux, 2),
        &col(&att, 0),
        &col(&att, 1),
        &col(&att, 2),
    )?
    .map(f64::from);
    let mut ata = SMatrix::<f64, 3, 3>::zeros();
    let mut atd = SVector::<f64, 3>::zeros();
    let mut used = 0usize;
    for (b, a) in flux.iter().zip(&att) {
        let nb = norm(*b);
        if !(nb > 1000.0 && a.iter().all(|v| v.is_finite())) {
            continue;
        }
        let r =
            crate::flight::body_from_ned(a[0].to_radians(), a[1].to_radians(), a[2].to_radians());
        let e = SVector::<f64, 3>::from_fn(|i, _| (0..3).map(|j| r[i][j] * e_ned[j]).sum());
        let d = SVector::<f64, 3>::from_fn(|i, _| b[i] / nb) - e;
        // ω × e = −[e]× ω
        let m = SMatrix::<f64, 3, 3>::new(0.0, e[2], -e[1], -e[2], 0.0, e[0], e[1], -e[0], 0.0);
        ata += m.transpose() * m;
        atd += m.transpose() * d;
        used += 1;
    }
    if used < 100 {
        return None;
    }
    // [e]× is singular along e: the normal matrix is full rank only with attitude variety.
    let w = ata.try_inverse()? * atd;
    Some([w[0], w[1]])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A known distortion of a field seen on many attitudes is recovered.
    #[test]
    fn recovers_a_known_bias_scale_and_non_orthogonality() {
        let truth = FluxgateCalibration {
            matrix: [
                [1.006, 0.002, -0.001],
                [0.002, 0.993, 0.0015],
                [-0.001, 0.0015, 1.004],
            ],
            bias_nt: [320.0, -250.0, 410.0],
        };
        // Sensor reading B_F such that truth.apply(B_F) is the true field: invert truth.
        let m = nalgebra::Matrix3::from_fn(|i, j| truth.matrix[i][j]);
        let minv = m.try_inverse().unwrap();
        let f_nt = 52_000.0;
        let mut flux = Vec::new();
        let mut reference = Vec::new();
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..2000 {
            let (th, ph) = (
                next() * std::f64::consts::PI,
                next() * std::f64::consts::TAU,
            );
            let b =
                nalgebra::Vector3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()) * f_nt;
            let raw = minv * (b - nalgebra::Vector3::from(truth.bias_nt));
            flux.push([raw[0], raw[1], raw[2]]);
            reference.push(f_nt);
        }
        let fit = fit_modulus(&flux, &reference).unwrap();
        for i in 0..3 {
            assert!((fit.calibration.bias_nt[i] - truth.bias_nt[i]).abs() < 1e-3);
            for j in 0..3 {
                assert!((fit.calibration.matrix[i][j] - truth.matrix[i][j]).abs() < 1e-9);
            }
        }
        assert!(
            fit.modulus_sd_before_nt > 100.0,
            "{}",
            fit.modulus_sd_before_nt
        );
        assert!(
            fit.modulus_sd_after_nt < 1e-6,
            "{}",
            fit.modulus_sd_after_nt
        );
    }

    #[test]
    fn too_few_samples_is_a_clear_error() {
        let e = fit_modulus(&[[50_000.0, 0.0, 0.0]; 10], &[50_000.0; 10]).unwrap_err();
        assert!(e.to_string().contains("too few"), "{e}");
    }
}
