//! What every candidate test shares: the flight as the model prepared it, the model's
//! calibration, every term's regressor columns, the anomaly filter's innovations of them,
//! the held-out folds and the direct (band and reference) regressions; and the tests
//! themselves, one per kind of candidate (a regressor term, a fluxgate correction, the
//! anomaly states).

use super::effect_tests::{
    calibrated_trace, explained_of, fluxcal_test, fluxgate_share, fluxtemp_test,
    interference_for_fluxgate, rate_crossover_test,
};
use super::evidence::{self, DirectRegression};
use super::holdout::{self, Folds};
use super::regression::{
    build_columns, build_columns_with, fit_map, nested_test, usable_rows, Block, ColTerm,
    TermColumns,
};
use super::{identifiability, prior_sigma_of, Candidate, DiagnoseOptions, Untestable, MAX_VALUES};
use crate::estimate::innovations::{filter_columns, FieldSettings, Innovations};
use crate::estimate::kf::{estimate_sigma1_for, KfRun, DEFAULT_SIGMA1};
use crate::flight::{scalar_relative_nt, Flight};
use crate::io::trace::Trace;
use crate::model::spec::{InputCorrection, ModelSpec};
use crate::signal::stats::{chi2_sf, lag1_autocorr};
use anyhow::{bail, Context, Result};
use magcomp_core::model::catalog::{info, AnyTerm, TermKind};
use magcomp_core::model::Term;

/// How a candidate is tested.
pub(super) enum CandidateTest<'a> {
    /// A term that adds regressors (`lag` by its first-order form).
    Regressor(ColTerm<'a>),
    /// The anomaly states: the filter itself changes.
    Field,
    /// A fluxgate correction (`fluxcal`, `fluxtemp:CH`): tested on the fluxgate modulus.
    Fluxgate(InputCorrection, Option<String>),
}

/// A candidate: the text a user appends to the model, and its test.
pub(super) type CandidateSpec<'a> = (String, CandidateTest<'a>);

/// The outcome of one candidate's test.
pub(super) enum Tested {
    Ranked(Box<Candidate>),
    Untestable(Untestable),
}

/// Shared state of one diagnosis (module notes).
pub(super) struct Workspace<'a> {
    pub(super) original_trace: &'a Trace,
    /// The flight the model sees (re-aligned scalar, corrected fluxgate).
    pub(super) flight: Flight,
    pub(super) model: &'a ModelSpec,
    pub(super) opts: &'a DiagnoseOptions,
    pub(super) run: KfRun,
    /// Column 0: the scalar relative to its first value, core-field change removed.
    y: Vec<f64>,
    tc: TermColumns,
    /// The same columns from the INS attitude's field direction: what attitude drives.
    tc_att: TermColumns,
    /// Per term (model's first, then candidates'): its columns' indices in `columns()`.
    pub(super) blocks: Vec<Block>,
    pub(super) base_idx: Vec<usize>,
    pub(super) inn: Innovations,
    /// The anomaly filter's settings `inn` was made with.
    field: FieldSettings,
    pub(super) rows: Vec<usize>,
    pub(super) sd: Vec<f64>,
    /// The model's residual (nT) on `rows`.
    pub(super) e0: Vec<f64>,
    rss0w: f64,
    pub(super) penalty: Vec<f64>,
    pub(super) residual_rms: f64,
    pub(super) folds: Folds,
    /// The band-passed measurement regressed directly (`evidence.rs`).
    pub(super) band: Option<DirectRegression>,
    /// The band-passed measurement minus the user's reference channel, regressed directly.
    pub(super) reference: Option<DirectRegression>,
    /// Number of candidates (the Bonferroni divisor).
    pub(super) m: f64,
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

impl<'a> Workspace<'a> {
    pub(super) fn build(
        trace: &'a Trace,
        original_flight: Flight,
        model: &'a ModelSpec,
        opts: &'a DiagnoseOptions,
        run: KfRun,
        cand_specs: &[CandidateSpec<'a>],
    ) -> Result<Self> {
        let fs = original_flight.sample_rate_hz;
        let n = original_flight.len();
        let mut all_terms: Vec<ColTerm> = model
            .terms
            .iter()
            .map(|t| ColTerm {
                spec: t.clone(),
                extra: None,
            })
            .collect();
        all_terms.extend(cand_specs.iter().filter_map(|(_, c)| match c {
            CandidateTest::Regressor(c) => Some(ColTerm {
                spec: c.spec.clone(),
                extra: c.extra,
            }),
            _ => None,
        }));
        refuse_too_large(&all_terms, n)?;
        // With `lag`/`fluxtemp` in the model the scalar and the regressors are those of the
        // prepared flight (re-aligned scalar, temperature-corrected fluxgate).
        let prepared;
        let (prep_trace, flight) = match &run.preprocessing {
            Some(p) => {
                prepared = crate::estimate::corrections::apply_to_trace(trace, p, fs)?;
                let f =
                    Flight::from_trace(&prepared, &model.channels(), &model.relative_channels())?;
                (&prepared, f)
            }
            None => (trace, original_flight),
        };
        // With `fluxcal` in the model every regressor is built from the calibrated fluxgate.
        let calibrated;
        let prep_trace = match &run.fluxgate_calibration {
            Some(cal) => {
                calibrated = calibrated_trace(prep_trace, cal)?;
                &calibrated
            }
            None => prep_trace,
        };
        let tc = build_columns(prep_trace, &all_terms, fs)?;
        let tc_att = build_columns_with(prep_trace, &all_terms, fs, true)?;
        let y = scalar_relative_nt(&flight);
        let mut blocks: Vec<Block> = Vec::new();
        let mut next = 1;
        for cols in &tc.cols {
            blocks.push(Block {
                idx: (next..next + cols.len()).collect(),
            });
            next += cols.len();
        }
        let n_model = model.terms.len();
        let base_idx: Vec<usize> = blocks[..n_model]
            .iter()
            .flat_map(|b| b.idx.clone())
            .collect();
        let columns = columns_of(&y, &tc);
        let settings = FieldSettings {
            sigma1: model.field.then_some(run.sigma1),
            noise_nt: run.noise_nt,
        };
        let inn = filter_columns(&tc.geometry, &columns, settings);
        let rows = usable_rows(&inn.cols, &inn.var_nt2);
        if rows.len() < 100 {
            bail!("only {} usable samples: too few to diagnose", rows.len());
        }
        let sd: Vec<f64> = rows.iter().map(|&k| inn.var_nt2[k].sqrt()).collect();
        let (e0w, rss0w, _, _) = fit_map(&inn.cols, &rows, &base_idx, &[]);
        // A candidate's coefficients are fitted against their prior, as the filter fits
        // them (penalty = noise / σ², the maximum a posteriori fit): on real aircraft an
        // unpenalised fit explained 68 % of a calibration box's residual with the cubic
        // induced term at ~22,000 nT (prior 1σ 50) against the permanent coefficients
        // moved ~57,000 nT, a fit no run of the model reaches, and the next box came out
        // worse. The model's own coefficients stay as the data put them.
        let noise_w2 = rss0w / rows.len() as f64;
        let mut prior_sigma = vec![0.0; columns.len()];
        for (ct, b) in all_terms.iter().zip(&blocks).skip(n_model) {
            for (&c, sigma) in b.idx.iter().zip(prior_sigma_of(ct)) {
                prior_sigma[c] = sigma;
            }
        }
        let penalty: Vec<f64> = prior_sigma
            .iter()
            .map(|&s| {
                if s.is_finite() && s > 0.0 {
                    noise_w2 / (s * s)
                } else {
                    0.0
                }
            })
            .collect();
        let e0: Vec<f64> = e0w.iter().zip(&sd).map(|(a, s)| a * s).collect();
        let residual_rms = rms(&e0);
        let folds = holdout::folds(&flight, &rows);
        let band = DirectRegression::new(&flight, &y, &columns, &base_idx, &prior_sigma);
        let reference = match &opts.reference {
            Some(name) => {
                let target = reference_target(trace, &flight, name)?;
                DirectRegression::new(&flight, &target, &columns, &base_idx, &prior_sigma)
            }
            None => None,
        };
        Ok(Self {
            original_trace: trace,
            flight,
            model,
            opts,
            run,
            y,
            tc,
            tc_att,
            blocks,
            base_idx,
            inn,
            field: settings,
            rows,
            sd,
            e0,
            rss0w,
            penalty,
            residual_rms,
            folds,
            band,
            reference,
            m: cand_specs.len().max(1) as f64,
        })
    }

    /// Tests one regressor candidate (block `bi`).
    pub(super) fn test_regressor(&self, text: &str, ct: &ColTerm, bi: usize) -> Tested {
        let b = &self.blocks[bi];
        let fs = self.flight.sample_rate_hz;
        let base_att: Vec<&[f64]> = self.tc_att.cols[..self.model.terms.len()]
            .iter()
            .flatten()
            .map(|c| c.as_slice())
            .collect();
        let cand_att: Vec<&[f64]> = self.tc_att.cols[bi].iter().map(|c| c.as_slice()).collect();
        let name = text.split(':').next().unwrap_or(text);
        let effect = match ct.extra {
            Some(x) => x.effect,
            None => info(name).map(|i| i.effect).unwrap_or(""),
        };
        let excitation_nt = identifiability::candidate_excitation_nt(
            &base_att,
            &cand_att,
            &prior_sigma_of(ct),
            fs,
            ct.spec.channel.is_some(),
        );
        let floor = crate::estimate::excitation::EXCITATION_FLOOR_NT;
        // Environment terms (`diurnal`) are not driven by manoeuvres: the field states, not
        // the attitude, separate them.
        let environment = AnyTerm::make(name, 0).is_some_and(|t| !t.is_interference());
        if let Some(x) = excitation_nt.filter(|x| *x < floor && !environment) {
            return Tested::Untestable(Untestable {
                term: text.to_string(),
                effect: effect.to_string(),
                reason: format!(
                    "not excited: a prior-1σ change moves the manoeuvre-band interference by {x:.4} nT beyond the model's own terms (< {floor} nT); fly roll, pitch and yaw manoeuvres on four headings"
                ),
                excitation_nt,
            });
        }
        let mut c = self.regressor_candidate(text, effect, &b.idx);
        c.excitation_nt = excitation_nt;
        if ct.spec.kind() == Some(TermKind::Rate) {
            // On one pass `rate` is a shift of the anomaly along the track, which the
            // residual cannot show (issue 4): only crossovers test it.
            match rate_crossover_test(&self.flight, &self.run, self.residual_rms, effect) {
                Some((effect, explained, after, q, f, p)) => {
                    c.effect = effect;
                    c.explained_fraction = explained;
                    c.residual_rms_after_nt = after;
                    c.added_parameters = q;
                    c.f_statistic = f;
                    c.p_value = p;
                    // Judged at the crossovers, not on held-out manoeuvres.
                    c.heldout_explained_fraction = None;
                    c.heldout_rms_after_nt = None;
                    c.evidence_tested.push("crossovers".into());
                }
                None => {
                    return Tested::Untestable(Untestable {
                        term: text.to_string(),
                        effect: effect.to_string(),
                        reason: "no crossovers: on single passes the term is a shift of the anomaly along the track; it is tested only where lines cross".into(),
                        excitation_nt,
                    });
                }
            }
        }
        Tested::Ranked(Box::new(c))
    }

    /// A candidate made of the columns `idx`, tested in the innovation domain and in the
    /// direct regressions (the verdict is set by `judge`).
    pub(super) fn regressor_candidate(&self, text: &str, effect: &str, idx: &[usize]) -> Candidate {
        let mut full = self.base_idx.clone();
        full.extend_from_slice(idx);
        // Explained share in the whitened domain (what the test sees: samples weighted by
        // the model's own predicted variance).
        let (_, rss1w, _, _) = fit_map(&self.inn.cols, &self.rows, &full, &self.penalty);
        let explained = if self.rss0w > 0.0 {
            (1.0 - rss1w / self.rss0w).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let (f, p, q) = nested_test(
            &self.inn.cols,
            &self.rows,
            &self.base_idx,
            idx,
            self.opts.ar_order,
        );
        let heldout = holdout::heldout_explained(
            &self.inn.cols,
            &self.rows,
            &self.folds,
            &self.base_idx,
            idx,
            &self.penalty,
        );
        let mut c = Candidate::new(text, effect, self.residual_rms);
        c.explained_fraction = explained;
        c.residual_rms_after_nt = self.residual_rms * (1.0 - explained).sqrt();
        c.added_parameters = q;
        c.f_statistic = f;
        c.p_value = p;
        c.heldout_explained_fraction = Some(heldout);
        c.heldout_rms_after_nt = Some(self.residual_rms * (1.0 - heldout).max(0.0).sqrt());
        c.evidence_tested.push("innovations".into());
        c.band_heldout_fraction = self.band.as_ref().map(|d| d.heldout_share(idx));
        if c.band_heldout_fraction.is_some() {
            c.evidence_tested.push("band".into());
        }
        c.reference_heldout_fraction = self.reference.as_ref().map(|d| d.heldout_share(idx));
        if c.reference_heldout_fraction.is_some() {
            c.evidence_tested.push("reference".into());
        }
        c
    }

    /// `fluxcal` or `fluxtemp:CH`, tested on the fluxgate and judged by the model refitted
    /// with it, which is also returned (`--iterate` starts from it).
    pub(super) fn test_fluxgate(
        &self,
        text: &str,
        correction: InputCorrection,
        channel: Option<&str>,
    ) -> Result<(Tested, Option<KfRun>)> {
        let t = match (correction, channel) {
            (InputCorrection::FluxTemp, Some(ch)) => {
                fluxtemp_test(self.original_trace, &self.flight, &self.run, ch)?
            }
            _ => fluxcal_test(&self.flight, &self.run)?,
        };
        let mut c = Candidate::new(text, &t.effect, self.residual_rms);
        // The static calibration's 9 parameters; a temperature drift adds 6 to them.
        c.added_parameters = if correction == InputCorrection::FluxCal {
            9
        } else {
            6
        };
        c.f_statistic = t.f;
        c.p_value = t.p;
        c.evidence_tested.push("fluxgate".into());
        // A calibration that does not fit the fluxgate down to its noise: another effect
        // drives whatever it would change, so nothing is claimed and no refit is spent.
        // Nor without the model's predicted error to compare the refit's with (no deviation
        // terms), as for the other candidates' refits.
        let refittable = self.run.predicted_error_nt.is_some() && !self.model.terms.is_empty();
        let run = if t.fits_to_noise && refittable {
            evidence::refit_run(self.original_trace, self.model, text)
        } else {
            None
        };
        match run
            .as_ref()
            .and_then(|r| Some((r, evidence::refit(text, r, &self.run)?)))
        {
            Some((r, refit)) => {
                let left = self.residuals_left([&self.run, r]);
                let share = fluxgate_share(correction, &refit, self.residual_rms, left);
                c.effect = format!(
                    "{}; the model refitted with it changes the compensated field by {:.3} nT rms, its predicted error {:.4} → {:.4} nT, the residual {:.4} → {:.4} nT (share: {})",
                    t.effect,
                    refit.output_change_nt,
                    refit.predicted_before_nt,
                    refit.predicted_after_nt,
                    left[0],
                    left[1],
                    if correction == InputCorrection::FluxTemp {
                        "that change against the residual: the predicted error and the residual do not see a slow drift"
                    } else {
                        "the predicted error's fall, at most that change against the residual, none if the residual rises"
                    }
                );
                c.explained_fraction = share;
                c.residual_rms_after_nt = self.residual_rms * (1.0 - share).sqrt();
                c.fluxgate_change_nt = Some(refit.output_change_nt);
                c.refit = Some(refit);
                c.evidence_tested.push("refit".into());
            }
            None if t.fits_to_noise => {
                c.effect = format!(
                    "{}; the model could not be refitted with it: no share claimed",
                    t.effect
                );
            }
            None => {}
        }
        Ok((Tested::Ranked(Box::new(c)), run))
    }

    /// The residual each run leaves (nT rms on `rows`): the scalar less the run's
    /// interference through the anomaly filter the diagnosis's residual comes from, on the
    /// samples both runs have (a sample one lacks is left out of both).
    fn residuals_left(&self, runs: [&KfRun; 2]) -> [f64; 2] {
        let interferences = runs.map(|r| interference_for_fluxgate(&self.flight, r));
        let present =
            |k: usize| self.y[k].is_finite() && interferences.iter().all(|i| i[k].is_finite());
        // Relative to the first value, as `y` is: the field states start at zero.
        let targets: Vec<Vec<f64>> = interferences
            .iter()
            .map(|i| {
                let i0 = i.iter().copied().find(|v| v.is_finite()).unwrap_or(0.0);
                (0..self.y.len())
                    .map(|k| {
                        if present(k) {
                            self.y[k] - (i[k] - i0)
                        } else {
                            f64::NAN
                        }
                    })
                    .collect()
            })
            .collect();
        let columns: Vec<&[f64]> = targets.iter().map(Vec::as_slice).collect();
        let inn = filter_columns(&self.tc.geometry, &columns, self.field);
        let used: Vec<usize> = self
            .rows
            .iter()
            .copied()
            .filter(|&k| inn.var_nt2[k].is_finite() && inn.cols.iter().all(|c| c[k].is_finite()))
            .collect();
        let rms = |c: &[f64]| {
            let ss: f64 = used.iter().map(|&k| c[k] * c[k] * inn.var_nt2[k]).sum();
            (ss / used.len().max(1) as f64).sqrt()
        };
        [rms(&inn.cols[0]), rms(&inn.cols[1])]
    }

    /// `field`: it changes the filter itself, not the regressors: rerun it with field
    /// states (σ1 from the along-track spectrum) and compare residuals.
    pub(super) fn test_field(&self) -> Tested {
        let s1 =
            estimate_sigma1_for(&self.flight, &self.run.interference_nt).unwrap_or(DEFAULT_SIGMA1);
        let columns = columns_of(&self.y, &self.tc);
        let inn_f = filter_columns(
            &self.tc.geometry,
            &columns,
            FieldSettings {
                sigma1: Some(s1),
                noise_nt: self.run.noise_nt,
            },
        );
        let rows_f: Vec<usize> = usable_rows(&inn_f.cols, &inn_f.var_nt2)
            .into_iter()
            .filter(|k| self.rows.binary_search(k).is_ok())
            .collect();
        let (e1w, _, _, _) = fit_map(&inn_f.cols, &rows_f, &self.base_idx, &self.penalty);
        let e1: Vec<f64> = e1w
            .iter()
            .zip(&rows_f)
            .map(|(a, &k)| a * inn_f.var_nt2[k].sqrt())
            .collect();
        let after = rms(&e1);
        let e0_sub: Vec<f64> = rows_f
            .iter()
            .filter_map(|k| self.rows.binary_search(k).ok().map(|i| self.e0[i]))
            .collect();
        let before = rms(&e0_sub);
        // Not nested in the linear sense: an approximate F with the 5 field states as
        // parameters and the effective sample count from the lag-1 correlation.
        let rho = lag1_autocorr(&e1).clamp(-0.99, 0.99);
        let n_eff = (e1.len() as f64 * (1.0 - rho) / (1.0 + rho)).max(10.0);
        let q = 5usize;
        let f = if after > 0.0 {
            ((before * before - after * after).max(0.0) / q as f64) / (after * after / n_eff)
        } else {
            0.0
        };
        let mut c = Candidate::new(
            "field",
            "geological anomaly and its vertical gradient (the paper's 5 field states): slowly varying field along the track",
            self.residual_rms,
        );
        c.explained_fraction = explained_of(before, after);
        c.residual_rms_after_nt = after;
        c.added_parameters = q;
        c.f_statistic = f;
        c.p_value = chi2_sf(f * q as f64, q as f64);
        c.evidence_tested.push("innovations".into());
        Tested::Ranked(Box::new(c))
    }
}

/// Every regressor column and its innovations are held in memory (f64): refuse what would
/// not fit rather than thrash (1 h at 1 kHz with 20 candidates ≈ 40 GB).
fn refuse_too_large(all_terms: &[ColTerm], n: usize) -> Result<()> {
    let total_cols: usize = all_terms
        .iter()
        .map(|c| match c.extra {
            Some(x) => (x.make)(0).len(),
            None => AnyTerm::make(&c.spec.name, 0).map_or(0, |t| t.len()),
        })
        .sum::<usize>()
        + 1;
    if 2 * n * total_cols > MAX_VALUES {
        bail!(
            "the trace is too large to diagnose at once ({n} rows × {total_cols} columns): \
             split it into flights or resample it to ≤ 20 Hz"
        );
    }
    Ok(())
}

/// Column 0 the scalar, then every term's columns in order.
fn columns_of<'c>(y: &'c [f64], tc: &'c TermColumns) -> Vec<&'c [f64]> {
    std::iter::once(y)
        .chain(tc.cols.iter().flatten().map(|c| c.as_slice()))
        .collect()
}

/// The scalar minus the user's reference channel (nT): the anomaly and the core field
/// cancel, the interference and the reference's own errors remain.
fn reference_target(trace: &Trace, flight: &Flight, name: &str) -> Result<Vec<f64>> {
    let reference = trace.col(name).with_context(|| {
        format!("--reference {name}: the trace has no such column (its columns: see docs/trace-format.md)")
    })?;
    if reference.len() != flight.len() {
        bail!(
            "--reference {name}: {} values for a flight of {} samples",
            reference.len(),
            flight.len()
        );
    }
    Ok(flight
        .mag_nt
        .iter()
        .zip(reference)
        .map(|(m, r)| m - r)
        .collect())
}
