//! `diagnose --iterate`: several effects at once. The best significant candidate is added
//! to the model and the diagnosis re-run on the new model, until nothing is significant or
//! a step limit is reached; the path (model, residual, error against truth when the trace
//! has it) is what the user reads. Each step is a full [`Diagnosis`], so a term is only
//! added when it is significant under everything already added (a lag found beside a pump
//! current is tested with the current in the model).

use super::{diagnose_from, DiagnoseOptions, Diagnosis};
use crate::flight::Flight;
use crate::io::trace::Trace;
use crate::model::spec::ModelSpec;
use anyhow::{Context, Result};
use serde::Serialize;

/// Default most terms `--iterate` adds.
pub const DEFAULT_MAX_STEPS: usize = 5;

/// One model on the path.
#[derive(Clone, Debug, Serialize)]
pub struct IterationStep {
    /// 0 for the starting model.
    pub step: usize,
    /// The diagnosis of this step's model (its `model`, `residual_rms_nt`, candidates…).
    #[serde(flatten)]
    pub diagnosis: Diagnosis,
    /// Compensation error against the simulator's truth (demeaned rms, nT); `None` without
    /// truth columns.
    pub error_rms_nt: Option<f64>,
    /// The term added to reach the next step; `None` on the last step.
    pub added: Option<String>,
}

/// The whole path and why it ended.
#[derive(Clone, Debug, Serialize)]
pub struct Iteration {
    pub steps: Vec<IterationStep>,
    pub stopped: String,
}

impl Iteration {
    /// The models of the path, in order (for the report).
    pub fn models(&self) -> Result<Vec<ModelSpec>> {
        self.steps
            .iter()
            .map(|s| ModelSpec::parse(&s.diagnosis.model))
            .collect()
    }

    /// `magcomp diagnose --iterate --json`: an array of the steps, each the diagnosis
    /// object of its model with `step`, `error_rms_nt` and `added` (the last step also
    /// carries `stopped`).
    pub fn to_json(&self) -> String {
        let mut v = serde_json::to_value(&self.steps).unwrap_or_default();
        if let Some(last) = v.as_array_mut().and_then(|a| a.last_mut()) {
            if let Some(o) = last.as_object_mut() {
                o.insert("stopped".into(), self.stopped.clone().into());
            }
        }
        serde_json::to_string_pretty(&v).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"))
    }

    /// The path a person reads, then the last step's full table.
    pub fn table(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(s, "model discovery path:");
        let _ = writeln!(
            s,
            "  {:<4} {:<56} {:>11} {:>8} {:>10}  added next",
            "step", "model", "residual nT", "NIS", "error nT"
        );
        for st in &self.steps {
            let d = &st.diagnosis;
            let added = match &st.added {
                Some(t) => {
                    let c = d.candidates.iter().find(|c| &c.term == t);
                    match c {
                        Some(c) => format!(
                            "{t} (explains {:.1}%, F {:.1})",
                            100.0 * c.explained_fraction,
                            c.f_statistic
                        ),
                        None => t.clone(),
                    }
                }
                None => "—".into(),
            };
            let _ = writeln!(
                s,
                "  {:<4} {:<56} {:>11.4} {:>8.2} {:>10}  {added}",
                st.step,
                d.model,
                d.residual_rms_nt,
                d.nis,
                st.error_rms_nt
                    .map_or("—".to_string(), |e| format!("{e:.4}")),
            );
        }
        let _ = writeln!(s, "stopped: {}", self.stopped);
        if let Some(last) = self.steps.last() {
            let _ = writeln!(s);
            s.push_str(&last.diagnosis.table());
        }
        s
    }
}

/// The compensation error of a diagnosis's run against the trace's truth, if it has any.
fn error_of(trace: &Trace, model: &ModelSpec, d: &Diagnosis) -> Result<Option<f64>> {
    if trace.col("truth_interference").is_none() {
        return Ok(None);
    }
    let flight = Flight::from_trace(trace, &model.channels(), &model.relative_channels())?;
    Ok(crate::estimate::corrections::error_against_truth_nt(
        trace, &flight, &d.run,
    ))
}

/// Adds the best significant candidate and re-diagnoses, at most `max_steps` times. A
/// step starts from the previous step's refit of the term it adds when there is one (the
/// same calibration of the same model on the same flight), not a second calibration.
pub fn iterate(
    trace: &Trace,
    start: &ModelSpec,
    opts: &DiagnoseOptions,
    max_steps: usize,
) -> Result<Iteration> {
    let mut model = start.clone();
    let mut steps = Vec::new();
    let mut calibrated = None;
    let stopped = loop {
        let step = steps.len();
        let (d, mut refits) = diagnose_from(trace, &model, opts, &[], calibrated.take())
            .with_context(|| format!("step {step}: diagnosing model {}", model.text()))?;
        let error_rms_nt = error_of(trace, &model, &d)?;
        let next = d
            .candidates
            .iter()
            .find(|c| c.significant)
            .map(|c| c.term.clone());
        let d_verdict = d.verdict();
        let push = |added: Option<String>| {
            steps.push(IterationStep {
                step,
                diagnosis: d,
                error_rms_nt,
                added,
            })
        };
        let Some(term) = next else {
            push(None);
            break d_verdict;
        };
        if step >= max_steps {
            push(None);
            break format!(
                "after {max_steps} added terms (--max-steps); the last model still has a significant candidate, {term}"
            );
        }
        calibrated = refits.remove(&term);
        push(Some(term.clone()));
        model = model
            .with(&term)
            .with_context(|| format!("adding the candidate '{term}' to {}", model.text()))?;
    };
    Ok(Iteration { steps, stopped })
}
