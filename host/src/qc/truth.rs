//! Yardsticks on simulated data: the compensation error against the simulator's truth, and
//! the oracle floor (the best any estimator with the model's terms can do on the flight).

use super::figures::rms_demeaned;
use crate::signal::lstsq::StreamingLeastSquares;

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
