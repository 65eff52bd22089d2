//! Pre-processing of a flight before the estimator, for the model terms that change the
//! filter's *input* rather than adding states: `lag` (the scalar re-aligned by its
//! estimated delay) and `fluxtemp:CH` (the fluxgate corrected for its temperature drift).
//! [`run_kf`], the entry point every caller uses, prepares the flight when the model names
//! one of them; the estimator (`kf::run_kf_estimator`) then runs unchanged on the prepared
//! flight. `run_kf` lives here, above the filter, so the filter never calls up into its
//! own pre-processing.
//!
//! Order: the lag first (its estimate uses band-passed data, which a few nT of fluxgate
//! drift hardly move), then the temperature fit on the re-aligned flight (its reference,
//! scalar − interference, must be read at the fluxgate's instants).

pub mod fluxtemp;
pub mod lag;

use crate::estimate::kf::{run_kf_estimator, KfOptions, KfRun};
use crate::flight::Flight;
use crate::io::trace::Trace;
use crate::model::corrections::Preprocessing;
use crate::model::spec::{InputCorrection, ModelSpec};
use anyhow::{bail, Context, Result};
use std::borrow::Cow;

/// Whether the model names a term handled here.
pub fn needed(spec: &ModelSpec) -> bool {
    spec.corrects(InputCorrection::Lag) || spec.corrects(InputCorrection::FluxTemp)
}

fn fluxtemp_channel(spec: &ModelSpec) -> Option<String> {
    spec.correction(InputCorrection::FluxTemp)
        .and_then(|t| t.channel.clone())
}

/// Applies `prep` to a flight (whose aux channels are `spec`'s).
pub fn apply_to_flight(flight: &Flight, prep: &Preprocessing) -> Result<Flight> {
    let mut f = match &prep.scalar_lag {
        Some(l) => lag::realign(flight, l.lag_s),
        None => flight.clone(),
    };
    if let Some(c) = &prep.fluxgate_temperature {
        let idx = flight
            .channels
            .iter()
            .position(|x| *x == c.channel)
            .with_context(|| {
                format!(
                    "the fluxgate temperature correction reads channel '{}', which the model does not",
                    c.channel
                )
            })?;
        f = c.apply_to_flight(&f, idx);
    }
    Ok(f)
}

/// Applies `prep` to a trace's `mag` and fluxgate columns (the diagnosis builds its
/// regressors from the trace). `fs_hz`: the flight's sample rate.
pub fn apply_to_trace(trace: &Trace, prep: &Preprocessing, fs_hz: f64) -> Result<Trace> {
    let mut out = trace.clone();
    if let Some(l) = &prep.scalar_lag {
        let mag = trace.col("mag").context("the trace has no 'mag' column")?;
        let m0 = mag.iter().copied().find(|v| v.is_finite()).unwrap_or(0.0);
        let rel: Vec<f64> = mag.iter().map(|v| v - m0).collect();
        let shifted = lag::shifted(&rel, l.lag_s * fs_hz);
        out.set_col("mag", shifted.iter().map(|v| v + m0).collect());
    }
    if let Some(c) = &prep.fluxgate_temperature {
        let flux = trace
            .flux()
            .context("the trace has no fluxgate columns flux_x, flux_y, flux_z")?;
        let temp = trace
            .col(&c.channel)
            .with_context(|| format!("the trace has no temperature column '{}'", c.channel))?;
        let cal: Vec<[f64; 3]> = flux
            .iter()
            .zip(temp)
            .map(|(b, t)| c.apply(*b, *t))
            .collect();
        for (ax, name) in ["flux_x", "flux_y", "flux_z"].iter().enumerate() {
            out.set_col(name, cal.iter().map(|b| b[ax]).collect());
        }
    }
    Ok(out)
}

/// The compensation error against the simulator's truth (demeaned rms, nT), net of the
/// scalar's own noise. Without `lag` that is `run.interference_nt` against
/// `truth_interference`. With `lag` the compensated output is `mag(t + τ̂) − i(t)`, and a
/// τ̂ off by δ is mostly absorbed by the eddy coefficients (a shift of the interference is,
/// to first order, `δ·dI/dt`, inside the eddy span), so `i` must be compared with what the
/// re-aligned noise-free scalar holds beyond the true field at t: `I(t) + S(t+δ) − S(t)`,
/// with `I = truth_interference − truth_hidden_lag` and `S = I + igrf + truth_anomaly +
/// truth_diurnal` (δ = τ̂ − `truth_lag_s`). `None` without truth.
pub fn error_against_truth_nt(trace: &Trace, flight: &Flight, run: &KfRun) -> Option<f64> {
    let truth = flight.truth_interference_nt.as_ref()?;
    let plain = || crate::qc::truth::error_rms_nt(&run.interference_nt, truth, None);
    let Some(l) = run.preprocessing.as_ref().and_then(|p| p.scalar_lag) else {
        return Some(plain());
    };
    let cols = (
        trace.col("truth_hidden_lag"),
        trace.col("igrf"),
        trace.col("truth_anomaly"),
        trace.col("truth_diurnal"),
        trace
            .meta("truth_lag_s")
            .and_then(|v| v.trim().parse::<f64>().ok()),
    );
    let (Some(hidden), Some(igrf), Some(anom), Some(diur), Some(tau)) = cols else {
        return Some(plain());
    };
    let i_true: Vec<f64> = truth.iter().zip(hidden).map(|(a, b)| a - b).collect();
    let s: Vec<f64> = (0..i_true.len())
        .map(|k| i_true[k] + igrf[k] - igrf[0] + anom[k] + diur[k])
        .collect();
    let s_shifted = lag::shifted(&s, (l.lag_s - tau) * flight.sample_rate_hz);
    let aligned = lag::realign(flight, l.lag_s);
    let d: Vec<f64> = (0..s.len())
        .map(|k| {
            let est = aligned.mag_nt[k] - run.compensated_nt[k];
            est - (i_true[k] + s_shifted[k] - s[k])
        })
        .collect();
    Some(crate::qc::figures::rms_demeaned(&d))
}

/// Runs the compensator over a flight. With `lag` or `fluxtemp` in the model the flight is
/// first corrected ([`CorrectedFlight`]: scalar re-aligned, fluxgate corrected for
/// temperature), then [`run_kf_estimator`] runs on it.
pub fn run_kf(flight: &Flight, opts: &KfOptions) -> Result<KfRun> {
    let corrected = CorrectedFlight::prepare(flight, opts)?;
    let mut run = run_kf_estimator(&corrected.flight, opts)?;
    corrected.finish(&mut run, flight);
    Ok(run)
}

/// The corrections stage: the flight the estimator runs on, with the input corrections the
/// model names (`lag`, `fluxtemp:CH`) estimated (or taken from `opts.preprocessing`) and
/// applied; the flight as given, not copied, when it names none.
pub struct CorrectedFlight<'f> {
    pub flight: Cow<'f, Flight>,
    /// What was applied; `None` when the model names no input correction.
    pub preprocessing: Option<Preprocessing>,
}

impl<'f> CorrectedFlight<'f> {
    /// The lag first (its estimate uses band-passed data, which a few nT of fluxgate drift
    /// hardly move), then the temperature fit on the re-aligned flight (module docs).
    pub fn prepare(flight: &'f Flight, opts: &KfOptions) -> Result<Self> {
        if !needed(&opts.model) {
            return Ok(Self {
                flight: Cow::Borrowed(flight),
                preprocessing: None,
            });
        }
        let given = opts.preprocessing.clone().unwrap_or_default();
        let mut prep = Preprocessing::default();
        // Each correction makes its own copy: the flight is not cloned first.
        let mut f = Cow::Borrowed(flight);
        if opts.model.corrects(InputCorrection::Lag) {
            let l = match given.scalar_lag {
                Some(l) => l,
                None => lag::estimate(flight, &opts.model)?,
            };
            f = Cow::Owned(lag::realign(&f, l.lag_s));
            prep.scalar_lag = Some(l);
        }
        if let Some(ch) = fluxtemp_channel(&opts.model) {
            let idx = f
                .channels
                .iter()
                .position(|x| *x == ch)
                .context("internal: the flight lacks the model's temperature channel")?;
            let c = match given.fluxgate_temperature {
                Some(c) if c.channel == ch => c,
                Some(c) => bail!(
                    "the fluxgate temperature correction is for channel '{}', the model reads '{ch}'",
                    c.channel
                ),
                None => {
                    // A first pass of the estimator gives the interference removed from the
                    // scalar reference (the fluxgate does not see the aircraft's field there).
                    let first = run_kf_estimator(&f, &crate::estimate::kf::first_pass(opts))?;
                    fluxtemp::fit_flight(&f, idx, &first.interference_nt)?.correction
                }
            };
            f = Cow::Owned(c.apply_to_flight(&f, idx));
            prep.fluxgate_temperature = Some(c);
        }
        Ok(Self {
            flight: f,
            preprocessing: Some(prep),
        })
    }

    /// The run as the recorded flight sees it: with a delay, the interference against the
    /// *recorded* scalar (`mag − compensated`), so it includes what the delay did to the
    /// reading, as a compensated output must; the corrections applied, in the run.
    pub fn finish(self, run: &mut KfRun, recorded: &Flight) {
        let Some(prep) = self.preprocessing else {
            return;
        };
        if prep.scalar_lag.is_some() {
            for ((i, c), m) in run
                .interference_nt
                .iter_mut()
                .zip(&run.compensated_nt)
                .zip(&recorded.mag_nt)
            {
                *i = m - c;
            }
        }
        run.preprocessing = Some(prep);
    }
}
