//! How candidates are judged and ordered: a verdict from every witness (`evidence.rs`),
//! the refits that corroborate or veto, and the ranking with its parsimony rule.

use super::reciprocal::Verdict;
use super::regression::fit_map;
use super::workspace::Workspace;
use super::{evidence, Candidate, DiagnoseOptions, RECALIBRATE};
use crate::estimate::kf::KfRun;
use magcomp_core::model::catalog::TermKind;
use std::collections::HashMap;

/// Sets `material`, `significant` and the evidence the verdict rests on: statistically
/// significant (Bonferroni over the `m` candidates) and material by at least one witness.
pub(super) fn judge(c: &mut Candidate, opts: &DiagnoseOptions, m: f64) {
    let bar = opts.min_explained;
    let mut rests_on = Vec::new();
    let primary = c.evidence_tested.first().cloned().unwrap_or_default();
    let primary_material = match c.fluxgate_change_nt {
        Some(change) => c.explained_fraction >= bar && change >= opts.min_fluxcal_change_nt,
        None => c.heldout_explained_fraction.unwrap_or(c.explained_fraction) >= bar,
    };
    if primary_material {
        rests_on.push(primary);
    }
    if c.band_heldout_fraction.is_some_and(|b| b >= bar) {
        rests_on.push("band".to_string());
    }
    if c.reference_heldout_fraction.is_some_and(|r| r >= bar) {
        rests_on.push("reference".to_string());
    }
    let corroborated = [
        c.heldout_explained_fraction,
        c.band_heldout_fraction,
        c.reference_heldout_fraction,
    ]
    .iter()
    .flatten()
    .any(|&share| share >= evidence::CORROBORATED_SHARE);
    if corroborated && c.refit.as_ref().is_some_and(|r| r.supports) {
        rests_on.push("refit".to_string());
    }
    // The passes' τ beside the refit's (from the manoeuvres), when there is one.
    let refit_tau_s = c.refit.as_ref().and_then(|r| r.lag_s);
    if let Some(r) = c.reciprocal.as_mut() {
        r.judge(refit_tau_s);
        if r.verdict == Verdict::Supports {
            rests_on.push("reciprocal".to_string());
        }
    }
    c.material = !rests_on.is_empty();
    let vetoed = c.refit.as_ref().is_some_and(|r| r.contradicts);
    c.significant = c.p_value < opts.alpha / m && c.material && !vetoed;
    c.evidence = rests_on;
}

/// Refits the model with the statistically significant candidates (those another witness
/// found material first, then the most significant; at most [`evidence::MAX_REFITS`]):
/// where the anomaly states absorbed an effect, only the refit shows it, and a term the
/// calibration cannot use shows there as a rise of its predicted error. Candidates
/// refitted by their own test (`fluxcal`, `fluxtemp:CH`) are not refitted again. Returns
/// the refitted runs by term.
pub(super) fn refit_candidates(
    ws: &Workspace,
    candidates: &mut [Candidate],
) -> HashMap<String, KfRun> {
    let mut runs = HashMap::new();
    // Without deviation terms in the model (an applied calibration checked) its
    // predicted error is the model error alone, no yardstick for a refit's.
    if ws.run.predicted_error_nt.is_none() || ws.model.terms.is_empty() {
        return runs;
    }
    let mut order: Vec<usize> = (0..candidates.len())
        .filter(|&i| {
            let c = &candidates[i];
            c.p_value < ws.opts.alpha / ws.m
                && c.term != RECALIBRATE
                && c.term != "field"
                && c.refit.is_none()
                && ws.model.with(&c.term).is_ok()
        })
        .collect();
    order.sort_by(|&a, &b| {
        let (a, b) = (&candidates[a], &candidates[b]);
        b.material
            .cmp(&a.material)
            .then(b.f_statistic.total_cmp(&a.f_statistic))
    });
    for &i in order.iter().take(evidence::MAX_REFITS) {
        let c = &mut candidates[i];
        let run = evidence::refit_run(ws.original_trace, ws.model, &c.term);
        c.refit = run
            .as_ref()
            .and_then(|run| evidence::refit(&c.term, run, &ws.run));
        if c.refit.is_some() {
            c.evidence_tested.push("refit".into());
        }
        judge(c, ws.opts, ws.m);
        if let Some(run) = run {
            runs.insert(c.term.clone(), run);
        }
    }
    runs
}

/// What a term adds to the model, not to its test: `lag` is detected through 9
/// first-order columns but added as one delay τ. Counted as its test's rank, a lagged pump
/// current's first-order form (`current_rate`, 3) won the parsimony rule against the
/// delay that explains the current's part and the attitude's (seed 4).
fn parameters(c: &Candidate) -> usize {
    if TermKind::from_name(&c.term) == Some(TermKind::Lag) {
        1
    } else {
        c.added_parameters
    }
}

/// Significant first; then by explained share penalised for the parameters added (BIC):
/// a 6-parameter term that explains 0.1 % more than a 1-parameter one nested in it is not
/// the better explanation. In-sample shares rank (the closest explanation first, even
/// when it is not recommended): what is recommended was already judged held out.
pub(super) fn rank(
    ws: &Workspace,
    candidates: &mut Vec<Candidate>,
    cand_cols: &HashMap<String, Vec<usize>>,
) {
    let n_rows = ws.rows.len() as f64;
    let bic = |c: &Candidate| {
        n_rows * (1.0 / (1.0 - c.explained_fraction).max(1e-12)).ln()
            - parameters(c) as f64 * n_rows.ln()
    };
    candidates.sort_by(|a, b| {
        b.significant
            .cmp(&a.significant)
            .then(bic(b).total_cmp(&bic(a)))
    });
    // Parsimony: if a significant candidate with fewer parameters leaves the leader
    // nothing material to add (< min_explained of what remains), the smaller one is the
    // better explanation (e.g. a 1-regressor lag inside the 6-regressor rate term's span).
    for _ in 0..3 {
        let Some(top) = candidates.first() else { break };
        let Some(top_idx) = cand_cols.get(&top.term) else {
            break;
        };
        let mut best: Option<usize> = None;
        for (j, c) in candidates.iter().enumerate().skip(1) {
            if !c.significant || parameters(c) >= parameters(top) {
                continue;
            }
            let Some(ci) = cand_cols.get(&c.term) else {
                continue;
            };
            let mut with_c = ws.base_idx.clone();
            with_c.extend_from_slice(ci);
            let (_, rss_c, _, _) = fit_map(&ws.inn.cols, &ws.rows, &with_c, &ws.penalty);
            with_c.extend_from_slice(top_idx);
            let (_, rss_ct, _, _) = fit_map(&ws.inn.cols, &ws.rows, &with_c, &ws.penalty);
            let inc = if rss_c > 0.0 {
                1.0 - rss_ct / rss_c
            } else {
                0.0
            };
            if inc < ws.opts.min_explained && best.is_none_or(|b| bic(c) > bic(&candidates[b])) {
                best = Some(j);
            }
        }
        match best {
            Some(j) => {
                let c = candidates.remove(j);
                candidates.insert(0, c);
            }
            None => break,
        }
    }
}
