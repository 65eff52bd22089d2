//! Batch yardsticks for the joint estimation of interference and anomaly on a calibration
//! flight: the model's regressors fitted together with a smooth (polynomial) or harmonic
//! (equivalent-source) anomaly, to show what the filter's along-track anomaly costs.

use super::kf::interference_of;
use crate::flight::Flight;
use nalgebra::{DMatrix, DVector};

/// A yardstick for the joint estimation on a calibration flight (simulated or real): the
/// interference of a batch least-squares fit of the scalar onto the model's regressors
/// *and* a smooth two-dimensional anomaly, a polynomial of total degree `degree` in
/// north/east over the pattern. The scalar is first corrected for the core-field change
/// (`igrf`) and, when the trace has a base station, for the diurnal variation. Where the
/// anomaly is smooth (high altitude) this uses every crossing and overlap of the pattern,
/// which the along-track field process cannot, so it shows how much of the gap between a
/// filter and the oracle floor (which knows the truth) is the price of not knowing the
/// anomaly at all.
pub fn joint_anomaly_fit_interference_nt(
    flight: &Flight,
    regressors: &[Vec<f32>],
    degree: i32,
) -> Option<Vec<f64>> {
    let ne = flight.local_ne_m();
    let y = flight.environment_corrected_nt(&flight.mag_nt);
    let rows = joint_fit_rows(flight, regressors, &y, &ne);
    let half = rows
        .iter()
        .fold(0.0f64, |m, &i| m.max(ne[i][0].abs()).max(ne[i][1].abs()))
        .max(1.0);
    let powers: Vec<(i32, i32)> = (1..=degree)
        .flat_map(|d| (0..=d).map(move |a| (a, d - a)))
        .collect();
    let a = joint_design(&rows, regressors, powers.len(), |i, j| {
        let (a, b) = powers[j];
        (ne[i][0] / half).powi(a) * (ne[i][1] / half).powi(b)
    })?;
    let yv = DVector::from_iterator(rows.len(), rows.iter().map(|&i| y[i]));
    let theta = a.svd(true, true).solve(&yv, 1e-12).ok()?;
    Some(interference_of(regressors, &theta.as_slice()[1..]))
}

/// Where the equivalent sources of [`harmonic_anomaly_fit_interference_nt`] sit and how
/// strongly their strengths are damped.
#[derive(Clone, Copy, Debug)]
pub struct SourceLayer {
    /// Grid spacing of the sources (m).
    pub spacing_m: f64,
    /// Depth of the layer below the mean flight height (m).
    pub depth_m: f64,
    /// Ridge on the source strengths, in units of the normal matrix's diagonal (every
    /// column is scaled to unit norm first).
    pub ridge: f64,
}

/// The second yardstick of the joint estimation, closer to the physics than the
/// polynomial: the anomaly as an equivalent-source layer (point sources `depth/r` on a
/// grid under the track), which is harmonic above the layer like any real anomaly, follows
/// the flight's height changes, and needs no global shape. Fitted together with the
/// model's regressors by damped least squares to `corrected_nt`, the scalar with the
/// core field and the diurnal variation already removed (e.g.
/// [`Flight::environment_corrected_nt`]). Returns the fitted interference.
pub fn harmonic_anomaly_fit_interference_nt(
    flight: &Flight,
    regressors: &[Vec<f32>],
    corrected_nt: &[f64],
    layer: SourceLayer,
) -> Option<Vec<f64>> {
    let ne = flight.local_ne_m();
    let rows = joint_fit_rows(flight, regressors, corrected_nt, &ne);
    let height: Vec<f64> = flight.samples.iter().map(|s| s.alt_m as f64).collect();
    let rows: Vec<usize> = rows
        .into_iter()
        .filter(|&i| height[i].is_finite())
        .collect();
    let p_reg = regressors.first()?.len();
    if rows.is_empty() || !(layer.spacing_m > 0.0 && layer.depth_m > 0.0) {
        return None;
    }
    let layer_height_m =
        rows.iter().map(|&i| height[i]).sum::<f64>() / rows.len() as f64 - layer.depth_m;
    // Sources on a grid over the track's extent plus one depth, kept only near the track:
    // far ones are nearly linear across it and only blur the fit.
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for &i in &rows {
        for k in 0..2 {
            lo[k] = lo[k].min(ne[i][k]);
            hi[k] = hi[k].max(ne[i][k]);
        }
    }
    let reach_m = 1.5 * layer.spacing_m.max(layer.depth_m);
    let track: Vec<[f64; 2]> = rows.iter().step_by(10).map(|&i| ne[i]).collect();
    let mut sources = Vec::new();
    let mut north = lo[0] - layer.depth_m;
    while north <= hi[0] + layer.depth_m {
        let mut east = lo[1] - layer.depth_m;
        while east <= hi[1] + layer.depth_m {
            if track
                .iter()
                .any(|q| (q[0] - north).hypot(q[1] - east) < reach_m)
            {
                sources.push([north, east]);
            }
            east += layer.spacing_m;
        }
        north += layer.spacing_m;
    }
    let a = joint_design(&rows, regressors, sources.len(), |i, j| {
        let q = sources[j];
        let dz = height[i] - layer_height_m;
        layer.depth_m / ((ne[i][0] - q[0]).powi(2) + (ne[i][1] - q[1]).powi(2) + dz * dz).sqrt()
    })?;
    let p = a.ncols();
    // Unit-norm columns keep the normal equations well conditioned (the regressors are
    // ~10⁴ nT, the kernels ≤ 1); the ridge then acts alike on every source.
    let scale: Vec<f64> = (0..p).map(|c| a.column(c).norm().max(1e-300)).collect();
    let a = DMatrix::from_fn(rows.len(), p, |r, c| a[(r, c)] / scale[c]);
    let yv = DVector::from_iterator(rows.len(), rows.iter().map(|&i| corrected_nt[i]));
    let mut normal = a.transpose() * &a;
    for c in 1 + p_reg..p {
        normal[(c, c)] += layer.ridge;
    }
    let theta = normal.cholesky()?.solve(&(a.transpose() * yv));
    let coefficients: Vec<f64> = (1..=p_reg).map(|c| theta[c] / scale[c]).collect();
    Some(interference_of(regressors, &coefficients))
}

/// The joint fits' design matrix over `rows`: a constant, the model's regressors, then
/// `extra` anomaly columns (`anomaly(row, j)`). None when the rows cannot determine it.
fn joint_design(
    rows: &[usize],
    regressors: &[Vec<f32>],
    extra: usize,
    anomaly: impl Fn(usize, usize) -> f64,
) -> Option<DMatrix<f64>> {
    let p_reg = regressors.first()?.len();
    let p = 1 + p_reg + extra;
    if rows.len() <= 2 * p {
        return None;
    }
    Some(DMatrix::from_fn(rows.len(), p, |r, c| {
        let i = rows[r];
        if c == 0 {
            1.0
        } else if c <= p_reg {
            regressors[i][c - 1] as f64
        } else {
            anomaly(i, c - 1 - p_reg)
        }
    }))
}

/// Rows usable by a joint fit: finite scalar, position and regressors.
fn joint_fit_rows(
    flight: &Flight,
    regressors: &[Vec<f32>],
    y: &[f64],
    ne: &[[f64; 2]],
) -> Vec<usize> {
    (0..flight.len().min(regressors.len()).min(y.len()))
        .filter(|&i| {
            y[i].is_finite()
                && ne[i][0].is_finite()
                && ne[i][1].is_finite()
                && regressors[i].iter().all(|v| v.is_finite())
        })
        .collect()
}
