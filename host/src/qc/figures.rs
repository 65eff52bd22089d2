//! Figures of merit a survey geophysicist reads: FOM, improvement ratio, residual, and —
//! on simulated data — the error against truth and the oracle floor.

use crate::flight::Flight;
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

/// The manoeuvre band: 0.1–0.9 Hz (the classic TL band; manoeuvres have 4–8 s periods).
pub fn manoeuvre_band(fs_hz: f64) -> (f64, f64) {
    (0.1, 0.9f64.min(0.4 * fs_hz))
}

/// The manoeuvre-band signal of a flight's `x` (scalar or compensated), NaN where `x` is
/// missing and over stretches too short to filter. Time gaps and long missing runs split
/// the filter; isolated missing samples are interpolated for the filter only, so one
/// missing sample costs one sample of every statistic, not the whole flight. None when
/// nothing can be filtered.
pub fn band_passed(flight: &Flight, x: &[f64]) -> Option<Vec<f64>> {
    let fs_hz = flight.sample_rate_hz;
    let (lo, hi) = manoeuvre_band(fs_hz);
    let breaks = crate::qc::gaps::time_breaks(&flight.t_s);
    let gaps = crate::signal::bandpass::Gaps {
        breaks: &breaks,
        max_fill: crate::qc::gaps::MAX_FILL_SAMPLES,
        min_len: 64,
    };
    let v = crate::signal::bandpass::bandpass_gaps(x, 4, lo, hi, fs_hz, &gaps).ok()?;
    v.iter().any(|x| x.is_finite()).then_some(v)
}

/// RMS (mean removed) of the manoeuvre-band signal over its finite samples.
pub fn band_rms_nt(flight: &Flight, x: &[f64]) -> f64 {
    band_passed(flight, x)
        .map(|v| rms_demeaned(&v))
        .unwrap_or(f64::NAN)
}

fn std_of(v: &[f64]) -> f64 {
    let n = v.len() as f64;
    if v.is_empty() {
        return f64::NAN;
    }
    let m = v.iter().sum::<f64>() / n;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n).sqrt()
}

/// RMS after removing the mean, over finite values.
pub fn rms_demeaned(v: &[f64]) -> f64 {
    let f: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    std_of(&f)
}

/// One manoeuvre's contribution to the FOM.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct ManoeuvreFom {
    pub label: String,
    pub t_start: f64,
    pub t_end: f64,
    pub peak_to_peak_nt: f64,
    pub uncompensated_peak_to_peak_nt: f64,
}

/// Is this segment one of the 12 calibration manoeuvres (`cal_hNNN_roll|pitch|yaw`)?
pub fn is_manoeuvre(label: &str) -> bool {
    label.starts_with("cal_")
        && (label.ends_with("_roll") || label.ends_with("_pitch") || label.ends_with("_yaw"))
}

/// Peak-to-peak of the band-passed compensated signal over each labelled manoeuvre.
pub fn fom(flight: &Flight, compensated_nt: &[f64]) -> Option<(f64, Vec<ManoeuvreFom>)> {
    let bp = band_passed(flight, compensated_nt)?;
    let bp_raw = band_passed(flight, &flight.mag_nt)?;
    let mut parts = Vec::new();
    for (label, a, b) in flight.segment_runs() {
        if !is_manoeuvre(&label) {
            continue;
        }
        let p2p = |v: &[f64]| peak_to_peak(&v[a..b]);
        parts.push(ManoeuvreFom {
            label,
            t_start: flight.t_s[a],
            t_end: flight.t_s[b - 1],
            peak_to_peak_nt: p2p(&bp),
            uncompensated_peak_to_peak_nt: p2p(&bp_raw),
        });
    }
    if parts.is_empty() {
        return None;
    }
    Some((parts.iter().map(|p| p.peak_to_peak_nt).sum(), parts))
}

/// Peak-to-peak over the finite values (NaN when there are none).
pub fn peak_to_peak(v: &[f64]) -> f64 {
    let f = v.iter().copied().filter(|x| x.is_finite());
    let (lo, hi) = f.fold((f64::MAX, f64::MIN), |(lo, hi), x| (lo.min(x), hi.max(x)));
    if lo <= hi {
        hi - lo
    } else {
        f64::NAN
    }
}

/// Standard deviation of the band-passed signal before / after compensation, over the
/// manoeuvres when labelled (else the whole flight), on the samples where both are known.
pub fn improvement_ratio(flight: &Flight, compensated_nt: &[f64]) -> Option<f64> {
    let before = band_passed(flight, &flight.mag_nt)?;
    let after = band_passed(flight, compensated_nt)?;
    let rows: Vec<usize> = {
        let m: Vec<usize> = flight
            .segments
            .as_ref()
            .map(|s| (0..s.len()).filter(|&i| is_manoeuvre(&s[i])).collect())
            .unwrap_or_default();
        if m.is_empty() {
            (0..flight.len()).collect()
        } else {
            m
        }
    };
    let rows: Vec<usize> = rows
        .into_iter()
        .filter(|&i| before[i].is_finite() && after[i].is_finite())
        .collect();
    if rows.len() < 2 {
        return None;
    }
    let b: Vec<f64> = rows.iter().map(|&i| before[i]).collect();
    let a: Vec<f64> = rows.iter().map(|&i| after[i]).collect();
    let ir = std_of(&b) / std_of(&a);
    ir.is_finite().then_some(ir)
}

/// Compensation error against the simulator's truth: `interference − truth`, mean removed.
pub fn error_rms_nt(interference_nt: &[f64], truth_nt: &[f64], rows: Option<&[usize]>) -> f64 {
    let d: Vec<f64> = match rows {
        Some(r) => r
            .iter()
            .map(|&i| interference_nt[i] - truth_nt[i])
            .collect(),
        None => interference_nt
            .iter()
            .zip(truth_nt)
            .map(|(a, b)| a - b)
            .collect(),
    };
    rms_demeaned(&d)
}

/// The oracle floor: RMS residual of the least-squares fit of the true interference onto
/// the model's own regressors (plus a constant) — the best any estimator with those terms
/// can do on this flight.
pub fn oracle_floor_nt(regressors: &[Vec<f32>], truth_nt: &[f64]) -> Option<f64> {
    let p = regressors.first()?.len() + 1;
    // Row by row (Givens QR of [1, regressors, truth]): memory p², not rows × p (the
    // whole design matrix, its copy and the SVD's U took ~400 B/row at the summary).
    let mut qr = StreamingLeastSquares::new(p);
    let mut row = vec![0.0; p + 1];
    for (r, &t) in regressors.iter().zip(truth_nt) {
        if !t.is_finite() || !r.iter().all(|v| v.is_finite()) {
            continue;
        }
        row[0] = 1.0;
        for (dst, v) in row[1..p].iter_mut().zip(r) {
            *dst = *v as f64;
        }
        row[p] = t;
        qr.push(&row);
    }
    if qr.rows() <= p {
        return None;
    }
    Some((qr.residual_sum_of_squares() / qr.rows() as f64).sqrt())
}

/// Least squares one row at a time: the upper-triangular factor of the augmented matrix
/// `[A y]` (p + 1 columns) updated by Givens rotations, as stable as a QR of the whole
/// matrix and exact for a rank-deficient `A` (a zero column leaves its rotations idle).
pub struct StreamingLeastSquares {
    /// Row-major (p + 1)², upper triangle used.
    r: Vec<f64>,
    m: usize,
    rows: usize,
    scratch: Vec<f64>,
}

impl StreamingLeastSquares {
    /// `p` regressor columns (the response is the row's last value).
    pub fn new(p: usize) -> Self {
        let m = p + 1;
        Self {
            r: vec![0.0; m * m],
            m,
            rows: 0,
            scratch: vec![0.0; m],
        }
    }

    /// One row `[a_1 … a_p, y]`.
    pub fn push(&mut self, row: &[f64]) {
        let m = self.m;
        let mut x = std::mem::take(&mut self.scratch);
        x.copy_from_slice(&row[..m]);
        for k in 0..m {
            if x[k] == 0.0 {
                continue;
            }
            let rkk = self.r[k * m + k];
            let h = rkk.hypot(x[k]);
            let (c, s) = (rkk / h, x[k] / h);
            let row_k = &mut self.r[k * m..(k + 1) * m];
            for (a, b) in row_k[k..].iter_mut().zip(&mut x[k..]) {
                let (ra, xb) = (*a, *b);
                *a = c * ra + s * xb;
                *b = c * xb - s * ra;
            }
        }
        self.scratch = x;
        self.rows += 1;
    }

    pub fn rows(&self) -> usize {
        self.rows
    }

    /// ‖y − A·x̂‖² of the least-squares fit. Directions of `A` with a singular value below
    /// 1e-10 of the largest (a duplicated column, which the rotations leave as rounding
    /// noise rather than exact zeros) are left out of the fit, as a truncated SVD of the
    /// whole matrix would: `R` has `A`'s singular values.
    pub fn residual_sum_of_squares(&self) -> f64 {
        let (m, p) = (self.m, self.m - 1);
        let ryy = self.r[m * m - 1];
        let rp = DMatrix::from_fn(p, p, |i, j| if j >= i { self.r[i * m + j] } else { 0.0 });
        let rhs = DVector::from_fn(p, |i, _| self.r[i * m + p]);
        let svd = rp.clone().svd(true, true);
        let tol = 1e-10 * svd.singular_values.max();
        let left = match svd.solve(&rhs, tol) {
            Ok(x) => (rhs - rp * x).norm_squared(),
            Err(_) => rhs.norm_squared(),
        };
        ryy * ryy + left
    }
}

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

/// The interference of constant coefficients over every sample's regressors (nT).
pub fn interference_of(regressors: &[Vec<f32>], coefficients: &[f64]) -> Vec<f64> {
    regressors
        .iter()
        .map(|r| r.iter().zip(coefficients).map(|(x, c)| *x as f64 * c).sum())
        .collect()
}

#[cfg(test)]
mod streaming_ls_tests {
    use super::StreamingLeastSquares;
    use nalgebra::{DMatrix, DVector};

    /// The row-by-row fit leaves the same residual as the SVD of the whole matrix, also
    /// with a zero column (a non-interference term's regressor) and a duplicated one.
    #[test]
    fn residual_matches_the_whole_matrix_svd() {
        let n = 500;
        let p = 5;
        let a = DMatrix::from_fn(n, p, |i, j| match j {
            0 => 1.0,
            1 => (i as f64 * 0.37).sin() * 300.0,
            2 => 0.0,
            3 => (i as f64 * 0.11).cos() * 20.0,
            _ => (i as f64 * 0.37).sin() * 300.0, // = column 1
        });
        let y = DVector::from_fn(n, |i, _| {
            5.0 + 0.3 * a[(i, 1)] - 2.0 * a[(i, 3)] + ((i * 7919) % 101) as f64 * 0.01
        });
        let x = a.clone().svd(true, true).solve(&y, 1e-9).unwrap();
        let svd_rss = (&y - &a * x).norm_squared();
        let mut ls = StreamingLeastSquares::new(p);
        for i in 0..n {
            let mut row: Vec<f64> = (0..p).map(|j| a[(i, j)]).collect();
            row.push(y[i]);
            ls.push(&row);
        }
        let rss = ls.residual_sum_of_squares();
        assert!(svd_rss > 1.0, "the noise leaves a residual: {svd_rss}");
        assert!(
            (rss / svd_rss - 1.0).abs() < 1e-9,
            "streamed {rss} vs svd {svd_rss}"
        );
    }
}
