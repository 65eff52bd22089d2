//! Which coefficient combinations a flight's manoeuvres determine. The Kalman filter uses
//! every frequency, and below the manoeuvre band the interference of a slowly changing
//! attitude (a climb, a turn, a straight line's drift) looks like the Earth's field
//! changing along the track. Where the manoeuvre band does not see a combination, the
//! filter would fit it to geology or the main field: on a real straight survey line it put
//! 88 000 nT into `e1`. Such combinations are held at their prior instead, and the user is
//! told.

use crate::flight::Flight;
use crate::metrics::manoeuvre_band;
use nalgebra::{DMatrix, SymmetricEigen};

/// A prior-1σ change along a combination must move the manoeuvre-band interference by at
/// least this much (nT rms over the flight) for the flight to determine it. Measured
/// excitations of the weakest combinations: 0.038 nT on the simulated 3000 m cloverleaf,
/// 0.047 nT on the real SGL box 1; a simulated straight line (turbulence 0.3°, ±150 m of
/// height over strong geology) has ten combinations at 0.000–0.010 nT and one at 0.034.
/// Held at 0.02 nT, that line's error fell from 0.41 to 0.059 nT (uncompensated: 0.90);
/// the cloverleaf's is unchanged.
pub const EXCITATION_FLOOR_NT: f64 = 0.02;

/// Unit combinations (in prior-σ units over all `k` coefficients, zero on the columns
/// `interference` marks false) whose manoeuvre-band excitation is below
/// [`EXCITATION_FLOOR_NT`], weakest first. `regressors`: per sample, physical; `prior_sigma`:
/// per coefficient.
pub fn unexcited_combinations(
    flight: &Flight,
    regressors: &[Vec<f32>],
    prior_sigma: &[f64],
    interference: &[bool],
) -> Vec<Vec<f32>> {
    let cols: Vec<usize> = (0..prior_sigma.len())
        .filter(|&j| interference[j])
        .collect();
    let n = regressors.len();
    if cols.is_empty() || n < 16 {
        return Vec::new();
    }
    let (lo, hi) = manoeuvre_band(flight.sample_rate_hz);
    let mut a = DMatrix::<f64>::zeros(n, cols.len());
    for (c, &j) in cols.iter().enumerate() {
        let col: Vec<f64> = regressors
            .iter()
            .map(|r| {
                let v = r[j] as f64;
                if v.is_finite() {
                    v
                } else {
                    0.0
                }
            })
            .collect();
        let Ok(bp) = crate::tl::bandpass(&col, 4, lo, hi, flight.sample_rate_hz) else {
            return Vec::new();
        };
        for (i, v) in bp.iter().enumerate() {
            a[(i, c)] = v * prior_sigma[j];
        }
    }
    // AᵀA without a transposed copy of A (n × k, 128 B/row at 16 terms).
    let gram = a.tr_mul(&a) / n as f64;
    let eig = SymmetricEigen::new(gram);
    let mut weak: Vec<(f64, Vec<f32>)> = eig
        .eigenvalues
        .iter()
        .enumerate()
        .filter(|(_, &mu)| mu.max(0.0).sqrt() < EXCITATION_FLOOR_NT)
        .map(|(e, &mu)| {
            let mut w = vec![0.0f32; prior_sigma.len()];
            for (c, &j) in cols.iter().enumerate() {
                w[j] = eig.eigenvectors[(c, e)] as f32;
            }
            (mu, w)
        })
        .collect();
    weak.sort_by(|x, y| x.0.total_cmp(&y.0));
    weak.into_iter().map(|(_, w)| w).collect()
}
