//! The regression behind the candidate tests: regressor columns of terms built with the
//! core's own epoch builder and term code, least-squares fits of blocks of them in the
//! anomaly filter's innovation domain, and the nested F-test on prewhitened residuals.

use super::ExtraTerm;
use crate::estimate::innovations::Geometry;
use crate::estimate::kf::HOST_WINDOW;
use crate::flight::Flight;
use crate::io::trace::Trace;
use crate::model::spec::TermSpec;
use crate::signal::stats::{ar_filter, chi2_sf, fit_ar, gram_lstsq, gram_of, median};
use anyhow::{bail, Context, Result};
use magcomp_core::compensator::CompensatorConfig;
use magcomp_core::epoch::EpochBuilder;
use magcomp_core::model::catalog::{info, AnyTerm};
use magcomp_core::model::Term;
use magcomp_core::MAX_AUX;

/// Regressor columns of terms, built with the core's epoch builder and term code (so a
/// new catalogue term is tested here without any change), plus the epoch geometry.
pub(crate) struct TermColumns {
    /// Per term: its columns (`len()` of them).
    pub(crate) cols: Vec<Vec<Vec<f64>>>,
    pub(crate) geometry: Geometry,
}

/// A term to build columns for: a catalogue term by spec, or a user's extra term.
pub(crate) struct ColTerm<'a> {
    pub(crate) spec: TermSpec,
    pub(crate) extra: Option<&'a ExtraTerm>,
}

pub(crate) fn build_columns(trace: &Trace, cterms: &[ColTerm], fs_hz: f64) -> Result<TermColumns> {
    build_columns_with(trace, cterms, fs_hz, false)
}

/// [`build_columns`]; with `attitude_only` the direction cosines (and their rate) are the
/// INS attitude's `e_ref` instead of the fluxgate's, so the columns hold only the variation
/// attitude drives (no geology's field direction). Epochs without `e_ref` keep the fluxgate's.
pub(crate) fn build_columns_with(
    trace: &Trace,
    cterms: &[ColTerm],
    fs_hz: f64,
    attitude_only: bool,
) -> Result<TermColumns> {
    let terms: Vec<TermSpec> = cterms.iter().map(|c| c.spec.clone()).collect();
    let n = trace.len();
    let mut cols: Vec<Vec<Vec<f64>>> = vec![Vec::new(); terms.len()];
    let mut geometry: Option<Geometry> = None;
    // Batches of at most MAX_AUX channels (an epoch carries that many).
    let mut batches: Vec<(Vec<String>, Vec<usize>)> = Vec::new();
    for (i, t) in terms.iter().enumerate() {
        let placed = batches.iter_mut().find(|(chans, _)| match &t.channel {
            None => true,
            Some(c) => chans.contains(c) || chans.len() < MAX_AUX,
        });
        match placed {
            Some((chans, idx)) => {
                if let Some(c) = &t.channel {
                    if !chans.contains(c) {
                        chans.push(c.clone());
                    }
                }
                idx.push(i);
            }
            None => batches.push((t.channel.iter().cloned().collect(), vec![i])),
        }
    }
    if batches.is_empty() {
        batches.push((Vec::new(), Vec::new()));
    }
    for (chans, idx) in &batches {
        let relative: Vec<String> = idx
            .iter()
            .filter(|&&i| info(&terms[i].name).is_some_and(|ti| ti.relative_channel))
            .filter_map(|&i| terms[i].channel.clone())
            .collect();
        let flight = Flight::from_trace(trace, chans, &relative)?;
        let mut ecfg = CompensatorConfig::for_rate(fs_hz as f32).epoch;
        ecfg.earth_dir_ned = flight.earth_dir_ned;
        let mut builder = EpochBuilder::<HOST_WINDOW>::new(ecfg)
            .context("the derivative window does not fit at this sample rate")?;
        let mut epochs = Vec::with_capacity(n);
        for s in &flight.samples {
            if let Some(ep) = builder.push(s) {
                epochs.push(ep);
            }
        }
        while let Some(ep) = builder.flush() {
            epochs.push(ep);
        }
        if epochs.len() != n {
            bail!("internal: {} epochs for {n} samples", epochs.len());
        }
        if attitude_only {
            use_attitude_direction(&mut epochs, ecfg.half_width);
        }
        if geometry.is_none() {
            geometry = Some(Geometry {
                ds_m: epochs.iter().map(|e| e.ds_m as f64).collect(),
                dh_m: epochs.iter().map(|e| e.dh_m as f64).collect(),
            });
        }
        for &i in idx {
            let t = &terms[i];
            let ch = t
                .channel
                .as_ref()
                .and_then(|c| chans.iter().position(|x| x == c))
                .unwrap_or(0);
            let term: Box<dyn Term> = match cterms[i].extra {
                Some(x) => (x.make)(ch),
                None => Box::new(
                    AnyTerm::make(&t.name, ch)
                        .with_context(|| format!("unknown term '{}'", t.name))?,
                ),
            };
            let l = term.len();
            let mut c = vec![vec![0.0f64; n]; l];
            let mut buf = [0.0f32; magcomp_core::model::MAX_TERM_STATES];
            for (k, ep) in epochs.iter().enumerate() {
                term.regressors(ep, &mut buf[..l]);
                for j in 0..l {
                    c[j][k] = buf[j] as f64;
                }
            }
            cols[i] = c;
        }
    }
    Ok(TermColumns {
        cols,
        geometry: geometry.context("internal: no epochs")?,
    })
}

/// `e ← e_ref` and `ė ←` its centred difference over ±`h` epochs, where `e_ref` is known.
fn use_attitude_direction(epochs: &mut [magcomp_core::epoch::Epoch], h: usize) {
    let n = epochs.len();
    let refs: Vec<([f32; 3], f64)> = epochs.iter().map(|e| (e.e_ref, e.t_s)).collect();
    let ok = |k: usize| refs[k].0.iter().all(|v| v.is_finite());
    for (k, ep) in epochs.iter_mut().enumerate() {
        if !ok(k) {
            continue;
        }
        ep.e = refs[k].0;
        let (a, b) = (k.saturating_sub(h), (k + h).min(n - 1));
        let dt = refs[b].1 - refs[a].1;
        if b > a && ok(a) && ok(b) && dt > 0.0 {
            for i in 0..3 {
                ep.e_dot_per_s[i] = ((refs[b].0[i] - refs[a].0[i]) as f64 / dt) as f32;
            }
        }
    }
}

/// One term block of the regression.
pub(crate) struct Block {
    /// Column indices into the Gram matrix (0 = the scalar).
    pub(crate) idx: Vec<usize>,
}

/// Rows usable for the regression: an update was made and the filter has settled.
pub(crate) fn usable_rows(w: &[Vec<f64>], var: &[f64]) -> Vec<usize> {
    let med = median(var);
    (0..var.len())
        .filter(|&k| var[k] <= 10.0 * med && w.iter().all(|c| c[k].is_finite()))
        .collect()
}

/// Fit of a set of blocks: residual in the whitened domain, RSS, rank.
pub(crate) fn fit(
    w: &[Vec<f64>],
    rows: &[usize],
    idx: &[usize],
) -> (Vec<f64>, f64, usize, Vec<f64>) {
    fit_map(w, rows, idx, &[])
}

/// [`fit`] with the coefficients' priors: `penalty[c]` (indexed like `w`; empty = none) is
/// added to column `c`'s Gram diagonal, the maximum a posteriori fit for a zero-mean prior
/// of variance noise/penalty, which is how the filter itself weighs a coefficient against
/// the data. RSS is the data part only.
pub(crate) fn fit_map(
    w: &[Vec<f64>],
    rows: &[usize],
    idx: &[usize],
    penalty: &[f64],
) -> (Vec<f64>, f64, usize, Vec<f64>) {
    let mut all = vec![0usize];
    all.extend_from_slice(idx);
    let sel: Vec<Vec<f64>> = all
        .iter()
        .map(|&c| rows.iter().map(|&k| w[c][k]).collect())
        .collect();
    let refs: Vec<&[f64]> = sel.iter().map(|v| v.as_slice()).collect();
    let mut g = gram_of(&refs);
    add_penalty(&mut g, &all, penalty);
    let local: Vec<usize> = (1..all.len()).collect();
    let (theta, _, rank) = gram_lstsq(&g, &local);
    let e = residual_of(&sel, &theta);
    // RSS from the explicit residual, not yy − θ·b: near-collinear columns (e.g. `lag`'s
    // d(e_i e_j)/dt against the eddy terms) make the latter cancel catastrophically.
    let rss = e.iter().map(|v| v * v).sum();
    (e, rss, rank, theta)
}

/// Adds `penalty[all[i]]` to the diagonal of `g` (whose row/column `i` is column `all[i]`).
pub(crate) fn add_penalty(g: &mut nalgebra::DMatrix<f64>, all: &[usize], penalty: &[f64]) {
    for (i, &c) in all.iter().enumerate() {
        if let Some(p) = penalty.get(c) {
            g[(i, i)] += p;
        }
    }
}

/// `sel[0] − Σ θ_j·sel[j+1]`.
pub(crate) fn residual_of(sel: &[Vec<f64>], theta: &[f64]) -> Vec<f64> {
    let mut e = sel[0].clone();
    for (j, th) in theta.iter().enumerate() {
        for (ek, xk) in e.iter_mut().zip(&sel[j + 1]) {
            *ek -= th * xk;
        }
    }
    e
}

/// Nested F-test of `base ∪ cand` against `base` on AR-prewhitened data.
pub(crate) fn nested_test(
    w: &[Vec<f64>],
    rows: &[usize],
    base: &[usize],
    cand: &[usize],
    ar_order: usize,
) -> (f64, f64, usize) {
    let mut full: Vec<usize> = base.to_vec();
    full.extend_from_slice(cand);
    let (e_full, _, _, _) = fit(w, rows, &full);
    let a = fit_ar(&e_full, ar_order);
    let mut all = vec![0usize];
    all.extend_from_slice(&full);
    let pw: Vec<Vec<f64>> = all
        .iter()
        .map(|&c| {
            let v: Vec<f64> = rows.iter().map(|&k| w[c][k]).collect();
            ar_filter(&v, &a)
        })
        .collect();
    let refs: Vec<&[f64]> = pw.iter().map(|v| v.as_slice()).collect();
    let g = gram_of(&refs);
    let nb = base.len();
    let (th0, _, r0) = gram_lstsq(&g, &(1..=nb).collect::<Vec<_>>());
    let (th1, _, r1) = gram_lstsq(&g, &(1..all.len()).collect::<Vec<_>>());
    let rss_of = |th: &[f64]| residual_of(&pw, th).iter().map(|v| v * v).sum::<f64>();
    let (rss0, rss1) = (rss_of(&th0), rss_of(&th1));
    let q = r1.saturating_sub(r0);
    let n = pw[0].len();
    let dof2 = n.saturating_sub(r1 + a.len()) as f64;
    if q == 0 || dof2 < 1.0 || rss1.is_nan() || rss1 <= 0.0 {
        return (0.0, 1.0, q);
    }
    let f = ((rss0 - rss1).max(0.0) / q as f64) / (rss1 / dof2);
    // dof2 is thousands: q·F is χ²_q to well within what a significance level needs.
    (f, chi2_sf(f * q as f64, q as f64), q)
}
