//! Which coefficient combinations a flight's manoeuvres determine. The Kalman filter uses
//! every frequency, and below the manoeuvre band the interference of a slowly changing
//! attitude (a climb, a turn, a straight line's drift) looks like the Earth's field
//! changing along the track. Where the manoeuvre band does not see a combination, the
//! filter would fit it to geology or the main field: on a real straight survey line it put
//! 88 000 nT into `e1`. Such combinations are held at their prior instead, and the user is
//! told.

use crate::flight::Flight;
use crate::qc::figures::manoeuvre_band;
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
        let Ok(bp) = crate::signal::bandpass::bandpass(&col, 4, lo, hi, flight.sample_rate_hz)
        else {
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

/// The warning for `weak` of `total` interference combinations not excited; `held`: the
/// estimator holds them at their prior (the Kalman filter) rather than fitting them to
/// whatever the flight holds (Tolles–Lawson's least squares).
pub fn warning(weak: usize, total: usize, held: bool) -> String {
    let what = if held {
        "they are held at their prior instead of being fitted to the Earth's field, so what \
         they describe is not compensated"
    } else {
        "least squares fits them anyway, to the Earth's field and the noise in that band, so \
         the coefficients along them are not the aircraft's and move the output where \
         the attitude departs from this flight's"
    };
    format!(
        "{weak} of {total} coefficient combinations are not excited by manoeuvres on this flight \
         (a prior 1σ of them moves the manoeuvre-band interference by less than \
         {EXCITATION_FLOOR_NT} nT): {what}. Calibrate on a pattern with roll, pitch and yaw \
         manoeuvres on four headings"
    )
}

/// The paper's 16 deviation regressors of every sample (physical units, as the filter forms
/// them from the fluxgate; no filter is run).
pub fn paper_regressors(flight: &Flight) -> Vec<Vec<f32>> {
    let model = magcomp_core::model::Model::paper();
    let mut cfg = magcomp_core::epoch::EpochConfig::for_rate(flight.sample_rate_hz as f32);
    cfg.earth_dir_ned = flight.earth_dir_ned;
    let Some(mut builder) = magcomp_core::EpochBuilder::<128>::new(cfg) else {
        return Vec::new();
    };
    let k = model.coefficient_count();
    let mut rows = Vec::with_capacity(flight.len());
    let mut row_of = |ep: &magcomp_core::Epoch| {
        let mut row = vec![0.0f32; k];
        let mut at = 0;
        for t in model.terms {
            t.regressors(ep, &mut row[at..at + t.len()]);
            at += t.len();
        }
        rows.push(row);
    };
    for s in &flight.samples {
        if let Some(ep) = builder.push(s) {
            row_of(&ep);
        }
    }
    while let Some(ep) = builder.flush() {
        row_of(&ep);
    }
    rows
}

/// What a Tolles–Lawson calibration on `flight` cannot determine: the warning the Kalman
/// filter gives, from the same test on the paper's 16 regressors at their priors (TL18's
/// own columns are collinear by construction, so their weakest direction says nothing
/// about the flight). None when the manoeuvres excite every combination.
pub fn tl_warning(flight: &Flight) -> Option<String> {
    let model = magcomp_core::model::Model::paper();
    let prior: Vec<f64> = model
        .terms
        .iter()
        .flat_map(|t| (0..t.len()).map(|i| t.prior_sigma(i) as f64))
        .collect();
    let interference = vec![true; prior.len()];
    let regressors = paper_regressors(flight);
    let span = airborne_span(flight);
    let weak = unexcited_combinations(flight, &regressors[span], &prior, &interference);
    (!weak.is_empty()).then(|| warning(weak.len(), prior.len(), false))
}

/// The rows from the first to the last sample flown at or above
/// [`magcomp_core::compensator::GROUND_SPEED_MPS`] (a sample without a reported speed counts
/// as flying): what a post-flight calibration learns from. On the ground (parked, taxiing)
/// heading changes excite every combination, but the filter does not learn there
/// (`CompensatorConfig::min_update_speed_mps`), so they cannot count.
pub fn airborne_span(flight: &Flight) -> std::ops::Range<usize> {
    let min_speed_mps = magcomp_core::compensator::GROUND_SPEED_MPS;
    let flying = |s: &magcomp_core::AlignedSample| {
        s.ground_speed_mps.is_nan() || s.ground_speed_mps >= min_speed_mps
    };
    let first = flight.samples.iter().position(flying).unwrap_or(0);
    let last = flight.samples.iter().rposition(flying).map_or(0, |i| i + 1);
    first..last.max(first)
}
