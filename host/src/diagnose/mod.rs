//! Model discovery (`magcomp diagnose`): compare the model with the measurements, find
//! where it fails (time windows, labelled segments, frequency bands), and test every
//! catalogue term the model lacks against the residual.
//!
//! How a candidate is tested (see `estimate/innovations.rs`): the anomaly-field filter is run once
//! over the scalar and over the regressors of the model's terms and of every candidate
//! term; in that innovation domain adding a constant-coefficient term is ordinary least
//! squares. Each candidate is a nested-model F-test (model vs model + candidate, with the
//! model's coefficients refitted), on residuals prewhitened by an AR fit so autocorrelated
//! misfit does not pass for many independent samples, with the rank the candidate really
//! adds as its degrees of freedom. Family-wise error over all candidates is held by
//! Bonferroni (α / number of candidates), and a candidate must also explain a material
//! share (default 15 %) of the residual variance. The second condition is what holds the
//! false-positive rate on real data: the paper's model is an approximation, and on clean
//! simulated flights its residual holds a genuine ~0.005 nT misfit that behaves like a
//! scalar lag (−τ·dB/dt; `rate` explains up to 10.7 % of the residual over 40 seeds) and is
//! "significant" by any test that counts 7000 samples.
//!
//! The innovations are not the only witness (`evidence.rs`): what the anomaly states can
//! absorb leaves them almost untouched, so a candidate is material when any of the
//! innovations (held out), the band-passed measurement regressed directly, the measurement
//! minus a reference channel (`--reference`), a refit of the whole model (its parts come
//! to agree, the output moves) or, for `lag`, reciprocal passes over the same ground
//! (`reciprocal.rs`: the passes line up only when shifted by 2·V·τ) carries it. The table
//! says which. "The model explains the
//! data" is said only when the mean NIS and every band's power are within
//! [`EXPLAINED_FACTOR`] of what the model expects (`Diagnosis::verdict`).

pub mod candidates;
pub mod custom;
mod effect_tests;
pub mod evidence;
mod failures;
pub mod holdout;
mod identifiability;
pub mod iterate;
mod lag_detector;
mod ranking;
pub mod reciprocal;
mod regression;
pub mod sensors;
mod table;
mod workspace;

pub use evidence::Refit;
pub use failures::residual_spectrum;
pub use iterate::{iterate, Iteration, IterationStep};

use crate::estimate::kf::KfRun;
use crate::flight::Flight;
use crate::io::trace::Trace;
use crate::model::spec::{InputCorrection, ModelSpec, TermSpec};
use crate::signal::stats::median;
use anyhow::{Context, Result};
use failures::{band_failures, segment_stats, time_failures};
use magcomp_core::model::catalog::{AnyTerm, ChannelUse, TermKind, CATALOG};
use magcomp_core::model::Term;
use regression::ColTerm;
use serde::Serialize;
use std::collections::HashMap;
use workspace::{CandidateSpec, CandidateTest, Tested, Workspace};

/// A term that is not (yet) in the core catalogue, tested alongside it: how a user checks
/// a new physical effect before pasting it into `core/src/model` (docs/adding-an-effect.md).
pub struct ExtraTerm {
    /// Base name as it would appear in a model spec (`scalar_lag`).
    pub name: &'static str,
    /// One line a geophysicist understands.
    pub effect: &'static str,
    /// Channel term: instantiated for every auxiliary column, like `current:CH`.
    pub needs_channel: bool,
    /// Builds the term; the argument is the aux index of its channel.
    pub make: fn(usize) -> Box<dyn Term>,
}

/// Most f64 values (regressor columns + innovations) the diagnosis holds: 2 GB.
const MAX_VALUES: usize = 250_000_000;

/// Settings of the diagnosis.
#[derive(Clone, Debug)]
pub struct DiagnoseOptions {
    /// Family-wise false-positive rate over all candidates.
    pub alpha: f64,
    /// Smallest share of the residual variance a significant candidate must explain.
    pub min_explained: f64,
    /// Length of the windows of the time-domain consistency test (s).
    pub window_s: f64,
    /// Order of the AR prewhitening filter.
    pub ar_order: usize,
    /// `fluxcal` (and `fluxtemp:CH`) is material only when the model refitted with the
    /// correction changes the compensated field by at least this (nT rms): a tenth of a
    /// survey's 0.1 nT. Clean simulated fluxgates (30 nT bias, 0.1 % scale) change it by
    /// ≤ 0.004 nT, a 300 nT / 0.7 % one by 0.02–0.03.
    pub min_fluxcal_change_nt: f64,
    /// Which auxiliary columns are candidates (`--aux`); None: all but navigation, time,
    /// identifiers, other magnetometers, fluxgates and constants (`candidates`).
    pub aux: Option<candidates::AuxSelection>,
    /// A channel holding the field without this sensor's interference (`--reference
    /// mag_1_c`, a compensated stinger): the measurement minus it is a further witness.
    pub reference: Option<String>,
    /// Judge `lag` on reciprocal passes over the same ground too (`reciprocal.rs`); off
    /// only to compare a diagnosis with and without that witness.
    pub reciprocal_passes: bool,
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        Self {
            alpha: 0.01,
            min_explained: 0.15,
            window_s: 20.0,
            ar_order: 10,
            min_fluxcal_change_nt: 0.01,
            aux: None,
            reference: None,
            reciprocal_passes: true,
        }
    }
}

/// A time window where the residual is inconsistent with the rest of the flight.
#[derive(Clone, Debug, Serialize)]
pub struct Failure {
    pub t_start: f64,
    pub t_end: f64,
    pub rms_nt: f64,
    pub label: String,
}

/// A frequency band where the residual's spectrum exceeds what the model expects.
#[derive(Clone, Debug, Serialize)]
pub struct BandFailure {
    pub f_lo_hz: f64,
    pub f_hi_hz: f64,
    /// Residual power / model-predicted power in the band.
    pub excess: f64,
}

/// Residual statistics of one labelled segment.
#[derive(Clone, Debug, Serialize)]
pub struct SegmentStat {
    pub label: String,
    pub t_start: f64,
    pub t_end: f64,
    pub rms_nt: f64,
    /// Mean normalised innovation squared (1 when the model is consistent).
    pub nis: f64,
}

/// A candidate term tested against the residual.
#[derive(Clone, Debug, Serialize)]
pub struct Candidate {
    /// Exactly what the user appends to the model: `--model "SPEC+TERM"`.
    pub term: String,
    pub effect: String,
    /// Share of the residual variance the term explains. `fluxcal` and `fluxtemp:CH` leave
    /// the scalar residual nearly unchanged and are judged by the model refitted with them
    /// (`effect_tests::fluxgate_share`): the variance of the change the refit makes to the
    /// compensation relative to the residual's (capped at 1), for `fluxcal` at most the
    /// fall of the predicted error and 0 when the refit leaves more residual.
    pub explained_fraction: f64,
    pub residual_rms_after_nt: f64,
    pub significant: bool,
    /// Explains at least the materiality bar (`--min-explained`; for `fluxcal`, changes the
    /// compensation by at least `min_fluxcal_change_nt`). A candidate with a tiny p that is
    /// not material is not significant.
    pub material: bool,
    /// Number of independent parameters the term adds on this flight.
    pub added_parameters: usize,
    /// Nested-model F statistic on the prewhitened residual.
    pub f_statistic: f64,
    /// Tail probability of that statistic (before the Bonferroni correction).
    pub p_value: f64,
    /// How far a prior-1σ change of its best-determined coefficients moves the
    /// manoeuvre-band interference beyond the model's own terms (nT; `identifiability.rs`).
    /// None for candidates that are not regressors (`field`, `fluxcal`, `fluxtemp`).
    pub excitation_nt: Option<f64>,
    /// Share of the residual variance it removes on held-out pieces of the flight (each
    /// fitted on all the others, `holdout.rs`): what materiality is judged on. None for
    /// candidates not tested as regressors.
    pub heldout_explained_fraction: Option<f64>,
    /// Held-out residual rms after adding it (nT): the predicted error fall.
    pub heldout_rms_after_nt: Option<f64>,
    /// Held-out share of the band-passed (0.1–0.9 Hz) measurement it removes beyond the
    /// model's columns, regressed directly with no anomaly states (`evidence.rs`).
    pub band_heldout_fraction: Option<f64>,
    /// The same on the measurement minus the `--reference` channel.
    pub reference_heldout_fraction: Option<f64>,
    /// The whole model refitted with it: predicted error before/after, output change.
    pub refit: Option<Refit>,
    /// With `fluxcal`/`fluxtemp`: the change the model refitted with the correction makes to
    /// the compensated field (nT std; None when not refitted).
    pub fluxgate_change_nt: Option<f64>,
    /// For `lag`: what reciprocal passes over the same ground say (`reciprocal.rs`).
    pub reciprocal: Option<reciprocal::Reciprocal>,
    /// The witnesses it was tested by (`innovations`, `band`, `reference`, `refit`,
    /// `fluxgate`, `crossovers`, `reciprocal`).
    pub evidence_tested: Vec<String>,
    /// The witnesses that found it material: what the verdict rests on.
    pub evidence: Vec<String>,
}

impl Candidate {
    /// A candidate not yet tested: nothing explained, not significant.
    fn new(term: &str, effect: &str, residual_rms_nt: f64) -> Self {
        Self {
            term: term.to_string(),
            effect: effect.to_string(),
            explained_fraction: 0.0,
            residual_rms_after_nt: residual_rms_nt,
            significant: false,
            material: false,
            added_parameters: 0,
            f_statistic: 0.0,
            p_value: 1.0,
            excitation_nt: None,
            heldout_explained_fraction: None,
            heldout_rms_after_nt: None,
            band_heldout_fraction: None,
            reference_heldout_fraction: None,
            refit: None,
            fluxgate_change_nt: None,
            reciprocal: None,
            evidence_tested: Vec::new(),
            evidence: Vec::new(),
        }
    }
}

/// A candidate this flight cannot determine: listed, not tested or ranked.
#[derive(Clone, Debug, Serialize)]
pub struct Untestable {
    pub term: String,
    pub effect: String,
    /// Why, in words.
    pub reason: String,
    pub excitation_nt: Option<f64>,
}

/// Time series behind the diagnosis, for the report.
#[derive(Clone, Debug, Default)]
pub struct DiagnosisSeries {
    pub t_s: Vec<f64>,
    /// Residual (innovation of the model refitted in the innovation domain), nT.
    pub residual_nt: Vec<f64>,
    /// Its predicted standard deviation √S, nT.
    pub predicted_sd_nt: Vec<f64>,
    /// The band-passed measurement and its direct fit by the model's columns and the
    /// named candidate's (`evidence.rs`), for the report's plot.
    pub direct_fit: Option<DirectFit>,
}

/// The band-passed measurement regressed directly: the target and its fit (nT, NaN
/// outside the regression's rows).
#[derive(Clone, Debug, Default)]
pub struct DirectFit {
    /// The candidate fitted beside the model's columns (None: the model's alone).
    pub term: Option<String>,
    pub target_nt: Vec<f64>,
    pub fitted_nt: Vec<f64>,
}

/// Everything `diagnose` finds.
#[derive(Clone, Debug, Serialize)]
pub struct Diagnosis {
    pub model: String,
    pub residual_rms_nt: f64,
    pub failures: Vec<Failure>,
    pub candidates: Vec<Candidate>,
    /// Candidates the flight cannot determine (not ranked).
    pub untestable: Vec<Untestable>,
    /// Bands whose residual power exceeds [`EXPLAINED_FACTOR`] × the model's.
    pub bands: Vec<BandFailure>,
    /// The largest band power ratio (residual / model), every band counted.
    pub band_excess_max: f64,
    pub segments: Vec<SegmentStat>,
    /// Mean normalised innovation squared over the flight.
    pub nis: f64,
    /// No pattern (neither labelled segments nor detected manoeuvres): a survey line,
    /// where slow interference can hide in the anomaly.
    pub straight_line: bool,
    /// The band-passed measurement's rms and what the model's columns leave of it (nT).
    pub band_rms_nt: Option<(f64, f64)>,
    /// The `--reference` channel, when one was given.
    pub reference: Option<String>,
    #[serde(skip)]
    pub series: DiagnosisSeries,
    #[serde(skip)]
    pub run: KfRun,
}

impl Diagnosis {
    /// The JSON object of `magcomp diagnose --json`.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"))
    }
}

/// Candidate term texts for a trace and a model: every catalogue term the model lacks,
/// channel terms for every auxiliary column, `diurnal` when a base station is recorded,
/// `fluxcal` (tested on the fluxgate itself), `fluxtemp` for temperature channels (on the
/// fluxgate too), `periodic` for rotation-rate (rpm-like) channels, `field` when the model
/// has none.
pub fn candidate_terms(trace: &Trace, model: &ModelSpec) -> Vec<String> {
    candidate_terms_with(trace, model, None)
}

/// [`candidate_terms`] over the channels `aux` selects (`--aux` globs; default
/// [`candidates::default_channels`]).
pub fn candidate_terms_with(
    trace: &Trace,
    model: &ModelSpec,
    aux: Option<&candidates::AuxSelection>,
) -> Vec<String> {
    let aux: Vec<&str> = candidates::channels(trace, aux);
    let present = |kind: TermKind, ch: Option<&str>| {
        model
            .terms
            .iter()
            .any(|t| t.kind() == Some(kind) && (ch.is_none() || t.channel.as_deref() == ch))
    };
    let mut out = Vec::new();
    if !model.field {
        out.push("field".to_string());
    }
    for ti in CATALOG {
        match ti.channel {
            ChannelUse::None => {
                // `fluxmod` is offered by `diagnose_with` only where the fluxgate sees a
                // field of its own (its regressor holds the scalar itself).
                if present(ti.kind, None) || ti.kind == TermKind::FluxMod {
                    continue;
                }
                out.push(ti.name.to_string());
            }
            ChannelUse::Default(d) => {
                if trace.col(d).is_some() && !present(ti.kind, Some(d)) {
                    out.push(format!("{}:{d}", ti.name));
                }
            }
            // `fluxtemp` only for temperature channels: it is tested on the fluxgate modulus
            // with a model run each, and a current is not a temperature.
            ChannelUse::Required if ti.kind == TermKind::FluxTemp => {
                for ch in aux.iter().filter(|c| temp_like(c)) {
                    if !present(ti.kind, Some(ch)) {
                        out.push(format!("{}:{ch}", ti.name));
                    }
                }
            }
            ChannelUse::Required => {
                for ch in &aux {
                    if ti.kind == TermKind::Periodic && !rpm_like(ch, trace.col(ch).unwrap_or(&[]))
                    {
                        continue;
                    }
                    if !present(ti.kind, Some(ch)) {
                        out.push(format!("{}:{ch}", ti.name));
                    }
                }
            }
        }
    }
    out
}

/// A temperature channel: named like one (`temp`, `tmp`, `degc`, case-insensitive).
fn temp_like(name: &str) -> bool {
    let lname = name.to_ascii_lowercase();
    ["temp", "tmp", "degc"].iter().any(|k| lname.contains(k))
}

/// A rotation-rate channel: named like one, or positive with hundreds of units (rpm).
fn rpm_like(name: &str, v: &[f64]) -> bool {
    let lname = name.to_ascii_lowercase();
    if lname.contains("rpm") || lname.contains("rev") {
        return true;
    }
    let min = v
        .iter()
        .copied()
        .filter(|x| x.is_finite())
        .fold(f64::MAX, f64::min);
    min >= 0.0 && median(v) >= 300.0
}

/// Prior 1σ of each of a candidate's coefficients (the scale `identifiability` measures in).
fn prior_sigma_of(c: &ColTerm) -> Vec<f64> {
    let term: Option<Box<dyn Term>> = match c.extra {
        Some(x) => Some((x.make)(0)),
        None => AnyTerm::make(&c.spec.name, 0).map(|t| Box::new(t) as Box<dyn Term>),
    };
    term.map_or_else(Vec::new, |t| {
        (0..t.len()).map(|i| t.prior_sigma(i) as f64).collect()
    })
}

/// A model "explains the data" only when its mean NIS and every band's residual power are
/// within this factor of what it expects.
pub const EXPLAINED_FACTOR: f64 = 2.0;

/// Diagnoses `trace` under `model`.
pub fn diagnose(trace: &Trace, model: &ModelSpec, opts: &DiagnoseOptions) -> Result<Diagnosis> {
    diagnose_with(trace, model, opts, &[])
}

/// Like [`diagnose`], also testing user terms that are not in the core catalogue.
pub fn diagnose_with(
    trace: &Trace,
    model: &ModelSpec,
    opts: &DiagnoseOptions,
    extra: &[ExtraTerm],
) -> Result<Diagnosis> {
    Ok(diagnose_from(trace, model, opts, extra, None)?.0)
}

/// `model` calibrated on `trace` as [`diagnose`] calibrates it first: what
/// [`diagnose_calibrated`] starts from, so diagnoses of one flight against several
/// references (`sensors`) calibrate it once.
pub(crate) fn calibrate_for_diagnosis(trace: &Trace, model: &ModelSpec) -> Result<KfRun> {
    let flight = Flight::from_trace(trace, &model.channels(), &model.relative_channels())?;
    evidence::calibrated(&flight, model)
}

/// [`diagnose`] from `calibrated` ([`calibrate_for_diagnosis`] of the same trace's
/// model channels: a reference column added since does not change it).
pub(crate) fn diagnose_calibrated(
    trace: &Trace,
    model: &ModelSpec,
    opts: &DiagnoseOptions,
    calibrated: KfRun,
) -> Result<Diagnosis> {
    Ok(diagnose_from(trace, model, opts, &[], Some(calibrated))?.0)
}

/// [`diagnose_with`], starting from `calibrated` when given (`model` calibrated on the
/// trace by `evidence::calibrated`, e.g. the previous step's refit of the term `--iterate`
/// adds); also returns the candidates' refitted runs by term.
fn diagnose_from(
    trace: &Trace,
    model: &ModelSpec,
    opts: &DiagnoseOptions,
    extra: &[ExtraTerm],
    calibrated: Option<KfRun>,
) -> Result<(Diagnosis, HashMap<String, KfRun>)> {
    let flight = Flight::from_trace(trace, &model.channels(), &model.relative_channels())?;
    let run = match calibrated {
        Some(run) => run,
        None => evidence::calibrated(&flight, model)?,
    };
    let cand_specs = candidate_specs(trace, model, opts, extra, &flight, &run)?;
    let ws = Workspace::build(trace, flight, model, opts, run, &cand_specs)?;
    let mut candidates = Vec::new();
    let mut untestable = Vec::new();
    let mut cand_cols: HashMap<String, Vec<usize>> = HashMap::new();
    let mut fluxgate_refits = HashMap::new();
    let mut bi = model.terms.len();
    for (text, spec) in &cand_specs {
        let tested = match spec {
            CandidateTest::Regressor(ct) => {
                bi += 1;
                let t = ws.test_regressor(text, ct, bi - 1);
                if matches!(t, Tested::Ranked(_)) {
                    cand_cols.insert(text.clone(), ws.blocks[bi - 1].idx.clone());
                }
                t
            }
            CandidateTest::Field => ws.test_field(),
            CandidateTest::Fluxgate(fix, ch) => {
                let (t, run) = ws.test_fluxgate(text, *fix, ch.as_deref())?;
                fluxgate_refits.extend(run.map(|r| (text.clone(), r)));
                t
            }
        };
        match tested {
            Tested::Ranked(c) => candidates.push(*c),
            Tested::Untestable(u) => untestable.push(u),
        }
    }
    if let Some(c) = recalibration_candidate(&ws, &cand_cols) {
        candidates.push(c);
    }
    if opts.reciprocal_passes {
        reciprocal::attach(&ws.flight, &ws.run.compensated_nt, &mut candidates);
    }
    for c in &mut candidates {
        ranking::judge(c, opts, ws.m);
    }
    let mut refits = ranking::refit_candidates(&ws, &mut candidates);
    refits.extend(fluxgate_refits);
    ranking::rank(&ws, &mut candidates, &cand_cols);
    Ok((conclude(ws, candidates, untestable, &cand_cols), refits))
}

/// The candidates of a diagnosis, each with how it is tested (`workspace::CandidateSpec`).
fn candidate_specs<'a>(
    trace: &Trace,
    model: &ModelSpec,
    opts: &DiagnoseOptions,
    extra: &'a [ExtraTerm],
    flight: &Flight,
    run: &KfRun,
) -> Result<Vec<CandidateSpec<'a>>> {
    let mut cand_texts = candidate_terms_with(trace, model, opts.aux.as_ref());
    // `fluxmod` (|B_F| − |B|) holds the scalar itself, so against any residual it soaks up
    // part of a missing effect (23 % of a hidden pump current): it is offered only where
    // the fluxgate sees a field of its own, several times what the scalar leaves
    // unexplained (a real survey aircraft's fluxgate: 31 nT after calibration against a
    // 3.7 nT residual; our simulator's: its 0.5 nT noise).
    if !model.has(TermKind::FluxMod)
        && effect_tests::fluxgate_own_field_ratio(flight, run)
            .is_some_and(|r| r >= crate::estimate::fluxgate_witness::MIN_OWN_FIELD_RATIO)
    {
        cand_texts.push(TermKind::FluxMod.name().into());
    }
    let mut specs: Vec<CandidateSpec> = Vec::new();
    for c in &cand_texts {
        if c == "field" {
            specs.push((c.clone(), CandidateTest::Field));
            continue;
        }
        let spec = ModelSpec::parse(c)?;
        let t = spec
            .terms
            .into_iter()
            .next()
            .context("internal: empty candidate")?;
        let test = match t.input_correction() {
            // Not regressors: each changes the filter's input.
            Some(fix @ (InputCorrection::FluxCal | InputCorrection::FluxTemp)) => {
                CandidateTest::Fluxgate(fix, t.channel.clone())
            }
            // `lag` is a delay (no regressors): it is detected by its first-order form.
            Some(InputCorrection::Lag) => CandidateTest::Regressor(ColTerm {
                spec: t,
                extra: Some(&lag_detector::LAG_DETECTOR),
            }),
            None => CandidateTest::Regressor(ColTerm {
                spec: t,
                extra: None,
            }),
        };
        specs.push((c.clone(), test));
    }
    for x in extra {
        let chans: Vec<Option<String>> = if x.needs_channel {
            candidates::channels(trace, opts.aux.as_ref())
                .iter()
                .map(|c| Some(c.to_string()))
                .collect()
        } else {
            vec![None]
        };
        for ch in chans {
            let spec = TermSpec {
                name: x.name.to_string(),
                channel: ch,
            };
            specs.push((
                spec.text(),
                CandidateTest::Regressor(ColTerm {
                    spec,
                    extra: Some(x),
                }),
            ));
        }
    }
    Ok(specs)
}

/// The deviation groups a fresh calibration fits.
const DEVIATION_GROUPS: [&str; 3] = ["permanent", "induced", "eddy"];

/// With an applied calibration checked (the model diagnosed holds none of the deviation
/// terms), the whole deviation model refitted on the flight is one more candidate: how
/// much a fresh calibration would remove, which no single group shows when the
/// coefficients are off in several at once.
fn recalibration_candidate(
    ws: &Workspace,
    cand_cols: &HashMap<String, Vec<usize>>,
) -> Option<Candidate> {
    let groups: Option<Vec<&Vec<usize>>> =
        DEVIATION_GROUPS.iter().map(|g| cand_cols.get(*g)).collect();
    let idx: Vec<usize> = groups?.into_iter().flatten().copied().collect();
    let mut c = ws.regressor_candidate(
        RECALIBRATE,
        "the whole deviation model (permanent + induced + eddy) refitted on this flight: \
         what a fresh calibration would remove that the applied coefficients leave",
        &idx,
    );
    c.excitation_nt = None;
    Some(c)
}

/// The candidate that stands for a fresh calibration.
pub const RECALIBRATE: &str = "recalibrate";

/// Where the model fails, and the diagnosis.
fn conclude(
    ws: Workspace,
    candidates: Vec<Candidate>,
    untestable: Vec<Untestable>,
    cand_cols: &HashMap<String, Vec<usize>>,
) -> Diagnosis {
    let flight = &ws.flight;
    let n = flight.len();
    let t_rows: Vec<f64> = ws.rows.iter().map(|&k| flight.t_s[k]).collect();
    let nis_k: Vec<f64> = ws
        .e0
        .iter()
        .zip(&ws.sd)
        .map(|(e, s)| (e / s).powi(2))
        .collect();
    let nis = nis_k.iter().sum::<f64>() / nis_k.len() as f64;
    let failures = time_failures(flight, &t_rows, &ws.e0, ws.opts.window_s);
    let all_bands = band_failures(&ws.e0, &ws.sd, flight.sample_rate_hz);
    let band_excess_max = all_bands.iter().map(|b| b.excess).fold(0.0, f64::max);
    let bands = all_bands
        .into_iter()
        .filter(|b| b.excess > EXPLAINED_FACTOR)
        .collect();
    let segments = segment_stats(flight, &ws.rows, &ws.e0, &nis_k);
    let mut residual_full = vec![f64::NAN; n];
    let mut sd_full = vec![f64::NAN; n];
    for (i, &k) in ws.rows.iter().enumerate() {
        residual_full[k] = ws.e0[i];
        sd_full[k] = ws.sd[i];
    }
    let top = candidates.iter().find(|c| c.significant);
    // The model's columns, with the named candidate's when it is a regressor.
    let named = top.and_then(|c| Some((c.term.clone(), band_columns_of(cand_cols, &c.term)?)));
    let direct_fit = ws.band.as_ref().map(|band| {
        let (term, idx) = named.map_or((None, Vec::new()), |(t, idx)| (Some(t), idx));
        let (target_nt, fitted_nt) = band.fit_series(&idx);
        DirectFit {
            term,
            target_nt,
            fitted_nt,
        }
    });
    let band_rms_nt = ws.band.as_ref().map(|b| b.rms_nt());
    Diagnosis {
        model: ws.model.text(),
        residual_rms_nt: ws.residual_rms,
        failures,
        candidates,
        untestable,
        bands,
        band_excess_max,
        segments,
        nis,
        straight_line: ws.folds.source == "time",
        band_rms_nt,
        reference: ws.opts.reference.clone(),
        series: DiagnosisSeries {
            t_s: flight.t_s.clone(),
            residual_nt: residual_full,
            predicted_sd_nt: sd_full,
            direct_fit,
        },
        run: ws.run,
    }
}

/// The columns of a regressor candidate by its text (None for the others).
fn band_columns_of(cand_cols: &HashMap<String, Vec<usize>>, term: &str) -> Option<Vec<usize>> {
    if term == RECALIBRATE {
        let groups: Option<Vec<&Vec<usize>>> =
            DEVIATION_GROUPS.iter().map(|g| cand_cols.get(*g)).collect();
        return Some(groups?.into_iter().flatten().copied().collect());
    }
    cand_cols.get(term).cloned()
}
