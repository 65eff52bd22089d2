//! Out-of-sample verdicts (issue 12, item 3): a candidate's improvement is scored on
//! manoeuvres it was not fitted on. In-sample, a term with many regressors fits part of any
//! residual (geology along a line, noise); held out, only a real effect keeps its share.
//!
//! Folds are pieces of the flight's units: the labelled segments (`segment` column), else
//! the manoeuvres `qc` detects, else (no pattern: a survey line) four equal stretches of
//! time; every row belongs to the unit it follows, and units longer than [`MAX_PIECE_S`]
//! are cut into equal pieces no longer than that. Each piece is held out in turn and
//! scored with the coefficients fitted on all the others (blocked leave-one-out, cheap
//! through Gram-matrix downdates), in the innovation domain where the candidate test runs.
//! Five folds dealt from the pieces were tried first: a pump current confined to 300 s of
//! a 700 s flight then had most of its evidence in one fold, and fitted without it the
//! coefficients were wrong (−33 % held out for a real effect); dealt in turn, a cloverleaf's
//! five segments per heading made each fold one kind of segment.

use super::regression::{add_penalty, fit_map};
use crate::flight::Flight;
use crate::signal::stats::{gram_lstsq, gram_of};
/// Longest piece of a unit (s): about one manoeuvre.
pub const MAX_PIECE_S: f64 = 30.0;

/// How the folds were formed, for the report.
#[derive(Clone, Debug, PartialEq)]
pub struct Folds {
    /// `segments`, `manoeuvres` or `time`.
    pub source: &'static str,
    /// Indices into `rows` (the regression's usable rows), per fold.
    pub members: Vec<Vec<usize>>,
}

/// Unit start rows of the flight (sorted) and where they came from.
fn unit_starts(flight: &Flight) -> (Vec<usize>, &'static str) {
    let runs = flight.segment_runs();
    if runs.len() >= 2 {
        return (runs.iter().map(|r| r.1).collect(), "segments");
    }
    if let Some(p) = crate::qc::manoeuvres::detect(flight) {
        let mut s: Vec<usize> = p.manoeuvres().map(|m| m.start).collect();
        s.sort_unstable();
        if s.len() >= 2 {
            return (s, "manoeuvres");
        }
    }
    let n = flight.len();
    ((0..4).map(|i| i * n / 4).collect(), "time")
}

/// Folds over `rows` (sorted sample indices): one per piece that holds usable rows.
pub fn folds(flight: &Flight, rows: &[usize]) -> Folds {
    let (starts, source) = unit_starts(flight);
    let n = flight.len();
    let max_len = ((MAX_PIECE_S * flight.sample_rate_hz) as usize).max(1);
    // Piece starts: each unit [a, b) cut into ⌈(b − a)/max_len⌉ equal pieces.
    let mut pieces = Vec::new();
    for (u, &a) in starts.iter().enumerate() {
        let b = starts.get(u + 1).copied().unwrap_or(n).max(a + 1);
        let m = (b - a).div_ceil(max_len);
        pieces.extend((0..m).map(|j| a + j * (b - a) / m));
    }
    let mut members = vec![Vec::new(); pieces.len()];
    for (i, &r) in rows.iter().enumerate() {
        let p = pieces.partition_point(|&s| s <= r).saturating_sub(1);
        members[p].push(i);
    }
    members.retain(|m| !m.is_empty());
    Folds { source, members }
}

/// Sum over folds of the held-out RSS of `w[0]` on the columns `idx` of `w` (rows
/// `0..w[0].len()`), each fold scored with the fit on all the others.
fn heldout_rss(w: &[Vec<f64>], folds: &Folds, idx: &[usize], penalty: &[f64]) -> f64 {
    let mut all = vec![0usize];
    all.extend_from_slice(idx);
    let fold_gram = |m: &Vec<usize>| {
        let sel: Vec<Vec<f64>> = all
            .iter()
            .map(|&c| m.iter().map(|&i| w[c][i]).collect())
            .collect();
        let refs: Vec<&[f64]> = sel.iter().map(|v| v.as_slice()).collect();
        (gram_of(&refs), sel)
    };
    let per_fold: Vec<_> = folds.members.iter().map(fold_gram).collect();
    let total = per_fold.iter().fold(
        nalgebra::DMatrix::zeros(all.len(), all.len()),
        |acc, (g, _)| acc + g,
    );
    let local: Vec<usize> = (1..all.len()).collect();
    per_fold
        .iter()
        .map(|(g, sel)| {
            let mut rest = &total - g;
            add_penalty(&mut rest, &all, penalty);
            let (theta, _, _) = gram_lstsq(&rest, &local);
            (0..sel[0].len())
                .map(|k| {
                    let e = sel[0][k]
                        - theta
                            .iter()
                            .zip(&sel[1..])
                            .map(|(t, c)| t * c[k])
                            .sum::<f64>();
                    e * e
                })
                .sum::<f64>()
        })
        .sum()
}

/// Held-out share of the model's residual that adding `cand` removes, in [−1, 1]
/// (negative: the term makes held-out data worse; −1: by the residual's whole variance or
/// more). The model's own coefficients come from the whole flight and the candidate's
/// columns are taken beyond the model's span there: an ill-conditioned model (a straight
/// line, where the filter holds combinations at the prior) would otherwise extrapolate
/// wildly from a few folds, and what is judged is what the *candidate* adds.
pub(crate) fn heldout_explained(
    w: &[Vec<f64>],
    rows: &[usize],
    folds: &Folds,
    base: &[usize],
    cand: &[usize],
    penalty: &[f64],
) -> f64 {
    let (e0, rss0, _, _) = fit_map(w, rows, base, penalty);
    let mut local = vec![e0];
    // The candidate's priors, carried to its local columns (1, 2, …).
    let mut local_penalty = vec![0.0];
    for &c in cand {
        let mut cw = vec![w[c].clone()];
        cw.extend(base.iter().map(|&b| w[b].clone()));
        let idx: Vec<usize> = (1..cw.len()).collect();
        let base_penalty: Vec<f64> = std::iter::once(0.0)
            .chain(base.iter().map(|&b| penalty.get(b).copied().unwrap_or(0.0)))
            .collect();
        local.push(fit_map(&cw, rows, &idx, &base_penalty).0);
        local_penalty.push(penalty.get(c).copied().unwrap_or(0.0));
    }
    let idx: Vec<usize> = (1..local.len()).collect();
    let rss1 = heldout_rss(&local, folds, &idx, &local_penalty);
    if rss0 > 0.0 {
        (1.0 - rss1 / rss0).clamp(-1.0, 1.0)
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A regressor that carries the signal keeps its share held out; a pure-noise one with
    /// as many samples does not (its held-out share is ≤ 0).
    #[test]
    fn held_out_share_of_a_real_and_a_spurious_regressor() {
        use rand::{Rng, SeedableRng};
        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let n = 4000;
        let x: Vec<f64> = (0..n).map(|k| (k as f64 * 0.37).sin()).collect();
        let junk: Vec<f64> = (0..n).map(|_| r.gen_range(-1.0..1.0)).collect();
        let y: Vec<f64> = x.iter().map(|v| 0.8 * v + r.gen_range(-0.5..0.5)).collect();
        let w = vec![y, x, junk];
        let rows: Vec<usize> = (0..n).collect();
        let folds = Folds {
            source: "time",
            members: (0..4)
                .map(|f| (f * n / 4..(f + 1) * n / 4).collect())
                .collect(),
        };
        let real = heldout_explained(&w, &rows, &folds, &[], &[1], &[]);
        let spurious = heldout_explained(&w, &rows, &folds, &[1], &[2], &[]);
        // Signal variance 0.32, noise 1/12: 79 % explained.
        assert!((real - 0.32 / (0.32 + 1.0 / 12.0)).abs() < 0.03, "{real}");
        assert!(spurious <= 0.001, "{spurious}");
    }
}
