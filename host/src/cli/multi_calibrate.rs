//! `calibrate --sensors` (2–8 sensors): one coefficient file holding every sensor's set
//! (`multi::MultiFile`). Without `--method` the joint Kalman filter, each sensor checked
//! against TL18-OLS; `--method kf` the joint filter alone; `--method tl` each sensor alone
//! by Tolles–Lawson; `--sensor-method mag_K=tl|kf,…` a method per sensor, the others as
//! `--method` says (docs/trace-format.md "Several magnetometers").

use super::multi::{MultiFile, SensorEntry, MULTI_FORMAT};
use crate::calibration::coefficients::{to_sealed_json, CoefficientFile, Method};
use crate::calibration::{compensate_trace, EstimatorSettings};
use crate::io::trace::Trace;
use crate::multi::joint::calibrate_joint_checking;
use crate::multi::sensors::{sensor_trace, SensorSpec};
use crate::multi::SensorResult;
use anyhow::{bail, Context, Result};
use serde_json::value::RawValue;
use std::path::Path;

/// Parses `--sensor-method mag_K=tl|kf,…` (comma separated): each named sensor's method,
/// in the order given. A sensor named twice, an entry without `=` and a method other than
/// `tl`/`kf` are refused, each naming the entry.
pub fn parse_sensor_methods(text: &str) -> Result<Vec<(String, Method)>> {
    let mut out: Vec<(String, Method)> = Vec::new();
    for entry in text.split(',').map(str::trim).filter(|e| !e.is_empty()) {
        let Some((name, method)) = entry.split_once('=').map(|(n, m)| (n.trim(), m.trim())) else {
            bail!("--sensor-method entry '{entry}': expected SENSOR=METHOD, e.g. mag_5=tl");
        };
        let Ok(method) = method.parse::<Method>() else {
            bail!(
                "--sensor-method entry '{entry}': unknown method '{method}': the choices are \
                 tl (Tolles–Lawson, the sensor calibrated alone) and kf (the Kalman filter)"
            );
        };
        if out.iter().any(|(n, _)| n == name) {
            bail!("--sensor-method names {name} twice");
        }
        out.push((name.to_string(), method));
    }
    if out.is_empty() {
        bail!("--sensor-method names no sensor (expected mag_K=tl or mag_K=kf, comma separated)");
    }
    Ok(out)
}

/// Each of `sensors`' method asked by `--sensor-method` (`asked`, parsed), `None` where
/// none was: a name that `--sensors` does not give is refused.
pub fn methods_asked(
    asked: &[(String, Method)],
    sensors: &[SensorSpec],
) -> Result<Vec<Option<Method>>> {
    if let Some((name, _)) = asked
        .iter()
        .find(|(n, _)| !sensors.iter().any(|s| s.name == *n))
    {
        let names: Vec<&str> = sensors.iter().map(|s| s.name.as_str()).collect();
        bail!(
            "--sensor-method names {name}, which is not among --sensors ({})",
            names.join(", ")
        );
    }
    Ok(sensors
        .iter()
        .map(|s| asked.iter().find(|(n, _)| *n == s.name).map(|(_, m)| *m))
        .collect())
}

/// One sensor calibrated: its file entry, its stderr summary line and warnings.
struct Calibrated {
    entry: SensorEntry,
    summary: String,
    /// Why it was calibrated so, where `--sensor-method` does not say it.
    note: Option<&'static str>,
    warnings: Vec<String>,
}

/// `calibrate --sensors`: each sensor by its method (`asked[j]`, from `--sensor-method`,
/// else `est.method`), in one file in `sensors`' order. The Kalman-filter sensors are
/// calibrated jointly (one anomaly); the default's checks (TL18-OLS, the fluxgate witness)
/// where `est` has them and no method was asked for the sensor by name. One Kalman-filter
/// sensor left is calibrated alone, as `calibrate` calibrates one; a Tolles–Lawson one
/// alone, as `--method tl` calibrates each (there is no joint Tolles–Lawson: it has no
/// anomaly states to share). `sigma1` is the joint run's, when there is one.
pub fn calibrate(
    trace: &Trace,
    est: &EstimatorSettings,
    sensors: &[SensorSpec],
    asked: &[Option<Method>],
    out: &Path,
) -> Result<()> {
    let n = sensors.len();
    let asked_for = |j: usize| asked.get(j).copied().flatten();
    let method = |j: usize| asked_for(j).unwrap_or(est.method);
    let checked = |j: usize| est.cross_check && asked_for(j).is_none();
    let kalman: Vec<usize> = (0..n).filter(|&j| method(j) == Method::Kf).collect();
    crate::errln!("{}", header(kalman.len(), n));
    let kf = EstimatorSettings {
        method: Method::Kf,
        ..est.clone()
    };
    let mut done: Vec<Option<Calibrated>> = (0..n).map(|_| None).collect();
    let sigma1 = match kalman[..] {
        [] => None,
        [j] => {
            let one = EstimatorSettings {
                cross_check: checked(j),
                ..kf
            };
            let mut c = alone(trace, &one, &sensors[j])?;
            c.note = Some("the one Kalman-filter sensor: as `calibrate` calibrates one");
            done[j] = Some(c);
            None
        }
        _ => {
            let specs: Vec<SensorSpec> = kalman.iter().map(|&j| sensors[j].clone()).collect();
            let checks: Vec<bool> = kalman.iter().map(|&j| checked(j)).collect();
            let r = calibrate_joint_checking(trace, &kf, &specs, &checks)?;
            for (&j, s) in kalman.iter().zip(&r.sensors) {
                done[j] = Some(joint(s)?);
            }
            Some(r.sigma1)
        }
    };
    let tl = EstimatorSettings {
        method: Method::Tl,
        cross_check: false,
        ..est.clone()
    };
    for j in (0..n).filter(|&j| method(j) == Method::Tl) {
        done[j] = Some(alone(trace, &tl, &sensors[j])?);
    }
    let mut entries = Vec::new();
    for (j, c) in done.into_iter().enumerate() {
        let c = c.with_context(|| format!("{}: not calibrated", sensors[j].name))?;
        let by_name = asked_for(j).map(|_| "--sensor-method");
        let notes: Vec<&str> = by_name.into_iter().chain(c.note).collect();
        if notes.is_empty() {
            crate::errln!("{}", c.summary);
        } else {
            crate::errln!("{} ({})", c.summary, notes.join("; "));
        }
        for w in &c.warnings {
            crate::errln!("warning: {w}");
        }
        entries.push(c.entry);
    }
    write_multi(out, sigma1, entries)
}

/// The stderr summary's first line, for `kalman` Kalman-filter sensors of `n`.
fn header(kalman: usize, n: usize) -> &'static str {
    match kalman {
        0 => "several magnetometers, each its own Tolles–Lawson calibration (no joint one):",
        k if k == n => "several magnetometers, one anomaly (docs/model.md §7):",
        1 => "several magnetometers, each calibrated alone by its method (--sensor-method):",
        _ => {
            "several magnetometers, the Kalman-filter ones jointly, one anomaly \
             (docs/model.md §7), the others alone by Tolles–Lawson (--sensor-method):"
        }
    }
}

/// A sensor of the joint run: the set kept (joint, alone, or TL18-OLS by the cross-check).
fn joint(s: &SensorResult) -> Result<Calibrated> {
    let file = s.chosen().coefficients.clone().context("no coefficients")?;
    let alone_p = s
        .alone
        .coefficients
        .as_ref()
        .and_then(|c| c.predicted_error_nt);
    let summary = format!(
        "{}: predicted error joint {}, alone {} nT: {} kept, method {}",
        label(&s.spec),
        fmt(s.predicted_error_nt),
        fmt(alone_p),
        if s.joint_chosen { "joint" } else { "alone" },
        file.method.name()
    );
    let lower_bound = s.lever_arm.is_some_and(|l| l.exceeds_noise());
    Ok(Calibrated {
        entry: entry(
            &s.spec,
            &file,
            (s.joint_chosen, s.predicted_error_nt),
            (alone_p, lower_bound),
        )?,
        summary,
        note: None,
        // The joint run's own warnings whichever set is kept, then the alone set's when
        // that one is (the joint one's are not said twice).
        warnings: (s.joint.warnings.iter())
            .chain(if s.joint_chosen {
                &[]
            } else {
                &s.alone.warnings[..]
            })
            .cloned()
            .collect(),
    })
}

/// Sensor `s` calibrated alone with `est`, as `calibrate` calibrates one sensor.
fn alone(trace: &Trace, est: &EstimatorSettings, s: &SensorSpec) -> Result<Calibrated> {
    let (_, comp) = compensate_trace(&sensor_trace(trace, s), est, None, false)
        .with_context(|| format!("{} alone", s.name))?;
    let file = comp.coefficients.clone().context("no coefficients")?;
    let summary = format!(
        "{}: predicted error {} nT: alone, method {}",
        label(s),
        fmt(file.predicted_error_nt),
        file.method.name()
    );
    Ok(Calibrated {
        entry: entry(s, &file, (false, None), (file.predicted_error_nt, false))?,
        summary,
        note: None,
        warnings: comp.warnings,
    })
}

/// `  mag_K (its column, fluxgate flux_…)`.
fn label(s: &SensorSpec) -> String {
    format!(
        "  {} ({}, fluxgate {})",
        s.name,
        s.scalar_column,
        s.fluxgate_name()
    )
}

/// Sensor `s`'s entry holding `file`: whether it is the joint estimate's and the joint
/// predicted error; the alone one and whether that is a lower bound (`multi::lever`).
fn entry(
    s: &SensorSpec,
    file: &CoefficientFile,
    (joint, joint_predicted): (bool, Option<f64>),
    (alone_predicted, lower_bound): (Option<f64>, bool),
) -> Result<SensorEntry> {
    Ok(SensorEntry {
        name: s.name.clone(),
        scalar_column: s.scalar_column.clone(),
        flux_columns: s.flux_columns.clone(),
        position_m: s.position_m,
        joint,
        joint_predicted_error_nt: joint_predicted,
        alone_predicted_error_nt: alone_predicted,
        alone_predicted_is_lower_bound: lower_bound,
        coefficients: embedded(&to_sealed_json(file)?)?,
    })
}

/// A sealed one-sensor file's text as it sits in a several-sensor file's `sensors` entry:
/// the characters kept (so its checksum holds), the lines indented to the entry's depth.
fn embedded(sealed: &str) -> Result<Box<RawValue>> {
    let text = sealed.trim_end().replace('\n', "\n      ");
    Ok(RawValue::from_string(text)?)
}

fn write_multi(out: &Path, sigma1: Option<f64>, sensors: Vec<SensorEntry>) -> Result<()> {
    let m = MultiFile {
        format: MULTI_FORMAT.into(),
        sigma1,
        sensors,
    };
    crate::io::output::write_file(out, serde_json::to_string_pretty(&m)?)?;
    crate::errln!("wrote {}", out.display());
    Ok(())
}

fn fmt(v: Option<f64>) -> String {
    v.map_or("–".into(), |v| format!("{v:.4}"))
}
