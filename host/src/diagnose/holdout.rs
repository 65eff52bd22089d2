//! Out-of-sample verdicts (issue 12, item 3): a candidate's improvement is scored on
//! manoeuvres it was not fitted on. In-sample, a term with many regressors fits part of any
//! residual (geology along a line, noise); held out, only a real effect keeps its share.
//!
//! Folds are whole units of the flight: the labelled segments (`segment` column), else the
//! manoeuvres `qc` detects, else (no pattern: a survey line) four equal stretches of time.
//! Units go to [`MAX_FOLDS`] folds in turn, every row belonging to the unit it follows, so
//! neighbouring manoeuvres (same heading, same kind) land in different folds. Each fold is
//! scored with the coefficients fitted on all the others, in the innovation domain where
//! the candidate test runs (`regression::fit`).

use super::regression::{fit, residual_of};
use crate::flight::Flight;

/// Most folds: five leave 80 % for each fit.
pub const MAX_FOLDS: usize = 5;

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

/// Folds over `rows` (sorted sample indices).
pub fn folds(flight: &Flight, rows: &[usize]) -> Folds {
    let (starts, source) = unit_starts(flight);
    let k = starts.len().clamp(2, MAX_FOLDS);
    let mut members = vec![Vec::new(); k];
    for (i, &r) in rows.iter().enumerate() {
        let unit = starts.partition_point(|&s| s <= r).saturating_sub(1);
        members[unit % k].push(i);
    }
    members.retain(|m| !m.is_empty());
    Folds { source, members }
}

/// Sum over folds of the held-out RSS of the columns `idx` of `w` (0 = the scalar),
/// each fold scored with the fit on the others.
fn heldout_rss(w: &[Vec<f64>], rows: &[usize], folds: &Folds, idx: &[usize]) -> f64 {
    let mut total = 0.0;
    for (f, test) in folds.members.iter().enumerate() {
        let train: Vec<usize> = folds
            .members
            .iter()
            .enumerate()
            .filter(|(g, _)| *g != f)
            .flat_map(|(_, m)| m.iter().map(|&i| rows[i]))
            .collect::<std::collections::BTreeSet<_>>()
            .into_iter()
            .collect();
        let (_, _, _, theta) = fit(w, &train, idx);
        let mut all = vec![0usize];
        all.extend_from_slice(idx);
        let sel: Vec<Vec<f64>> = all
            .iter()
            .map(|&c| test.iter().map(|&i| w[c][rows[i]]).collect())
            .collect();
        total += residual_of(&sel, &theta).iter().map(|v| v * v).sum::<f64>();
    }
    total
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
) -> f64 {
    let (e0, rss0, _, _) = fit(w, rows, base);
    let mut local = vec![e0];
    for &c in cand {
        let mut cw = vec![w[c].clone()];
        cw.extend(base.iter().map(|&b| w[b].clone()));
        let idx: Vec<usize> = (1..cw.len()).collect();
        local.push(fit(&cw, rows, &idx).0);
    }
    let local_rows: Vec<usize> = (0..rows.len()).collect();
    let idx: Vec<usize> = (1..local.len()).collect();
    let rss1 = heldout_rss(&local, &local_rows, folds, &idx);
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
        let real = heldout_explained(&w, &rows, &folds, &[], &[1]);
        let spurious = heldout_explained(&w, &rows, &folds, &[1], &[2]);
        // Signal variance 0.32, noise 1/12: 79 % explained.
        assert!((real - 0.32 / (0.32 + 1.0 / 12.0)).abs() < 0.03, "{real}");
        assert!(spurious <= 0.001, "{spurious}");
    }
}
