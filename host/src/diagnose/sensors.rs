//! Discovery across sensors (issue 19 item 5): which sensor a missing effect belongs to.
//!
//! Each sensor is diagnosed once against every other sensor's compensated field as its
//! reference (`DiagnoseOptions::reference`): the difference cancels the anomaly and the
//! core field, and leaves the two sensors' interference errors. An effect of sensor K's
//! own (a cabin current near it) is in K's measurement, so it shows in K's own witnesses
//! and in the difference with every other sensor. Another sensor J sees it only in its
//! difference with K (as K's compensation error, with the sign reversed), never in its
//! own measurement nor against a third sensor. A term is named for K only where every one
//! of K's diagnoses finds it significant and its difference with that sensor carries it.

use super::{DiagnoseOptions, Diagnosis};
use crate::calibration::{compensate_trace, EstimatorSettings};
use crate::io::trace::Trace;
use crate::model::spec::ModelSpec;
use crate::multi::sensors::{sensor_trace, SensorSpec};
use anyhow::{ensure, Context, Result};

/// One sensor's diagnoses against the others.
#[derive(Debug)]
pub struct SensorFinding {
    pub sensor: String,
    /// The terms named for this sensor: significant in each of its diagnoses, carried by
    /// its difference with each other sensor (its `reference` witness material).
    pub named: Vec<String>,
    /// Per other sensor: that sensor's name and this sensor's diagnosis against it.
    pub against: Vec<(String, Diagnosis)>,
}

/// The JSON of `diagnose --sensors --json`: per sensor, the terms named for it and each
/// diagnosis against another sensor.
pub fn to_json(findings: &[SensorFinding]) -> String {
    let value: Vec<serde_json::Value> = findings
        .iter()
        .map(|f| {
            serde_json::json!({
                "sensor": f.sensor,
                "named": f.named,
                "against": f.against.iter().map(|(other, d)| serde_json::json!({
                    "sensor": other,
                    "diagnosis": d,
                })).collect::<Vec<_>>(),
            })
        })
        .collect();
    serde_json::to_string_pretty(&value).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"))
}

/// The reference column holding sensor `name`'s compensated field. A `mag_*` name, so
/// the diagnosis never takes it for an auxiliary candidate.
fn reference_column(name: &str) -> String {
    format!("{name}_compensated")
}

/// Diagnoses each of `sensors` (two or more) under `model`, against each other sensor's
/// field compensated by its own calibration under `est`.
pub fn diagnose_sensors(
    trace: &Trace,
    sensors: &[SensorSpec],
    model: &ModelSpec,
    opts: &DiagnoseOptions,
    est: &EstimatorSettings,
) -> Result<Vec<SensorFinding>> {
    ensure!(
        sensors.len() >= 2,
        "discovery across sensors needs two sensors or more"
    );
    let own: Vec<Trace> = sensors.iter().map(|s| sensor_trace(trace, s)).collect();
    let compensated: Vec<Vec<f64>> = own
        .iter()
        .zip(sensors)
        .map(|(t, s)| {
            compensate_trace(t, est, None, false)
                .map(|(_, c)| c.compensated_nt)
                .with_context(|| format!("{}: its own calibration", s.name))
        })
        .collect::<Result<_>>()?;
    let mut findings = Vec::with_capacity(sensors.len());
    for (k, s) in sensors.iter().enumerate() {
        // the sensor's own calibration: the reference column added below is no channel of
        // the model, so it is the same for every other sensor
        let calibrated = super::calibrate_for_diagnosis(&own[k], model)
            .with_context(|| format!("{}: its calibration for the diagnosis", s.name))?;
        let mut against = Vec::with_capacity(sensors.len() - 1);
        for (j, other) in sensors.iter().enumerate().filter(|&(j, _)| j != k) {
            let column = reference_column(&other.name);
            let mut t = own[k].clone();
            t.set_col(&column, compensated[j].clone());
            let o = DiagnoseOptions {
                reference: Some(column),
                ..opts.clone()
            };
            let d = super::diagnose_calibrated(&t, model, &o, calibrated.clone())
                .with_context(|| format!("{} against {}", s.name, other.name))?;
            against.push((other.name.clone(), d));
        }
        findings.push(SensorFinding {
            sensor: s.name.clone(),
            named: named_in_every(&against),
            against,
        });
    }
    Ok(findings)
}

/// The terms every diagnosis finds significant with its reference witness material.
fn named_in_every(against: &[(String, Diagnosis)]) -> Vec<String> {
    let carried = |d: &Diagnosis, term: &str| {
        d.candidates
            .iter()
            .any(|c| c.term == term && c.significant && c.evidence.iter().any(|e| e == "reference"))
    };
    let Some((_, first)) = against.first() else {
        return Vec::new();
    };
    first
        .candidates
        .iter()
        .map(|c| c.term.clone())
        .filter(|term| against.iter().all(|(_, d)| carried(d, term)))
        .collect()
}
