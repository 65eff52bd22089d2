//! The range one flight's actual error falls in, beside the predicted figure.
//!
//! The predicted error is an rms expectation, `sqrt(E[e²])`, of the interference error the
//! coefficients' uncertainty leaves. On one flight, `e²` is a weighted sum `Σ λ_i z_i²` over
//! the independent directions of that uncertainty (the eigenvalues `λ_i` of `P·C`, the
//! coefficients' covariance times the regressors' spread). A calibration pattern leaves
//! most of its error in very few directions: the effective number
//! `n = (Σ λ)² / Σ λ²` is 1.5–3.5 on simulated cloverleaves at 300 and 3000 m. Then
//! `e² / E[e²]` is spread as `χ²_n / n` (Satterthwaite's approximation), and even a
//! perfectly honest figure sees the actual error below a third of itself on ~10 % of
//! flights at `n = 2`. The range says how far one flight may fall from the figure.

use statrs::distribution::{ChiSquared, ContinuousCDF};

/// Probability that the actual error lies in the range.
pub const RANGE_PROBABILITY: f64 = 0.9;

/// `(Σ λ)² / Σ λ²` of `P·C` for symmetric `P` and `C` (k×k, row-major): the number of
/// independent directions the error is spread over. None when the sizes differ or the
/// figure is not finite.
pub fn effective_dimensions(p: &[f64], c: &[f64], k: usize) -> Option<f64> {
    if k == 0 || p.len() != k * k || c.len() != k * k {
        return None;
    }
    let pc: Vec<f64> = (0..k * k)
        .map(|ab| {
            let (a, b) = (ab / k, ab % k);
            (0..k).map(|j| p[a * k + j] * c[j * k + b]).sum()
        })
        .collect();
    let trace: f64 = (0..k).map(|a| pc[a * k + a]).sum();
    // tr((PC)²) = Σ_ab (PC)_ab (PC)_ba.
    let trace_sq: f64 = (0..k * k)
        .map(|ab| pc[ab] * pc[(ab % k) * k + ab / k])
        .sum();
    participation_ratio(trace, trace_sq)
}

/// `(Σ λ)² / Σ λ²` from a matrix's trace and the trace of its square: the effective number
/// of directions, whichever matrix carries the eigenvalues. None when not finite.
pub fn participation_ratio(trace: f64, trace_of_square: f64) -> Option<f64> {
    let n = trace * trace / trace_of_square;
    (n.is_finite() && n > 0.0).then_some(n)
}

/// The [`RANGE_PROBABILITY`] range (nT, low and high) of one flight's actual error, for a
/// coefficients' part `coefficient_part_nt` spread over `effective_dimensions` directions
/// and a model error that every flight of the installation carries alike, known to lie in
/// `model_error_nt` (low, high: `crate::qc::high_frequency::unexplained_range_nt`).
pub fn range_nt(
    coefficient_part_nt: f64,
    model_error_nt: [f64; 2],
    effective_dimensions: f64,
) -> Option<[f64; 2]> {
    let chi = ChiSquared::new(effective_dimensions).ok()?;
    let tail = (1.0 - RANGE_PROBABILITY) / 2.0;
    let at = |q: f64, model_error_nt: f64| {
        let scaled = coefficient_part_nt.powi(2) * chi.inverse_cdf(q) / effective_dimensions;
        (scaled + model_error_nt.powi(2)).sqrt()
    };
    let range = [
        at(tail, model_error_nt[0]),
        at(1.0 - tail, model_error_nt[1]),
    ];
    range.iter().all(|v| v.is_finite()).then_some(range)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_direction_counts_one_and_equal_directions_count_all() {
        let c: Vec<f64> = (0..9).map(|i| if i % 4 == 0 { 1.0 } else { 0.0 }).collect();
        let one = [4.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        assert!((effective_dimensions(&one, &c, 3).unwrap() - 1.0).abs() < 1e-12);
        assert!((effective_dimensions(&c, &c, 3).unwrap() - 3.0).abs() < 1e-12);
        assert_eq!(effective_dimensions(&one, &c[..4], 3), None);
    }

    #[test]
    fn the_range_is_the_chi_square_quantiles_and_narrows_with_more_directions() {
        // χ²_2: the 5 % and 95 % points are −2 ln 0.95 and −2 ln 0.05.
        let [lo, hi] = range_nt(1.0, [0.0; 2], 2.0).unwrap();
        assert!(
            (lo - (-2.0 * 0.95f64.ln() / 2.0).sqrt()).abs() < 1e-6,
            "{lo}"
        );
        assert!(
            (hi - (-2.0 * 0.05f64.ln() / 2.0).sqrt()).abs() < 1e-6,
            "{hi}"
        );
        let [lo40, hi40] = range_nt(1.0, [0.0; 2], 40.0).unwrap();
        assert!(lo40 > lo && hi40 < hi && lo40 > 0.8 && hi40 < 1.2);
        // A model error that every flight carries raises the low end to it.
        let [lo_m, hi_m] = range_nt(1.0, [2.0, 3.0], 2.0).unwrap();
        let expected = (4.0 - 2.0 * 0.95f64.ln() / 2.0).sqrt();
        assert!((lo_m - expected).abs() < 1e-6, "{lo_m}");
        // …and one known only to lie between 2 and 3 raises the high end to 3's.
        let expected = (9.0 - 2.0 * 0.05f64.ln() / 2.0).sqrt();
        assert!((hi_m - expected).abs() < 1e-6, "{hi_m}");
    }
}
