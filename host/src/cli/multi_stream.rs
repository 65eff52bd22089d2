//! `compensate --sensors --stream`: several magnetometers streamed (issue 19) — the plan
//! and the several-sensor coefficient file as the in-memory run reads them
//! (`super::multi`), the rows through `stream::several`, one filter (or Tolles–Lawson) per
//! sensor, and each sensor's summary as the one-sensor stream gives it.

use super::args::TraceInput;
use super::multi::{gradient_separation_m, sets_of, MultiArgs, MultiCoefficients, SensorPlan};
use super::summary_text::{print_stream_text, with_printed_warnings};
use crate::calibration::EstimatorSettings;
use crate::io::trace::ColumnMap;
use crate::multi::sensors::parse_pairs;
use crate::stream::several::{compensate_several, several_unstreamable, Gradient};
use crate::stream::{SensorColumns, SensorRun, StreamSummary};
use anyhow::{bail, Result};
use std::path::Path;

/// What `compensate` on several sensors needs to stream them.
pub struct SeveralStreamed<'a> {
    pub input: &'a TraceInput,
    pub multi: &'a MultiArgs,
    pub coeffs: Option<&'a Path>,
    pub est: EstimatorSettings,
    pub realtime: bool,
    pub json: bool,
    pub out: &'a Path,
    /// No progress lines.
    pub quiet: bool,
}

impl SeveralStreamed<'_> {
    /// Why several sensors are compensated in memory (None: they can be streamed): calibrating
    /// them (the joint estimate needs the whole flight), what the one-sensor stream refuses
    /// for any of their coefficient sets, and inputs every stream reads whole.
    pub fn why_not(&self, multi: Option<&MultiCoefficients>) -> Option<String> {
        let a = self;
        let Some(m) = multi else {
            return Some(
                "several magnetometers without a several-sensor --coeffs file are calibrated \
             jointly, which needs the whole flight"
                    .into(),
            );
        };
        let named = a.named_sensors();
        let sets: Vec<(&str, &crate::calibration::coefficients::CoefficientFile)> = m
            .file
            .sensors
            .iter()
            .zip(&m.sets)
            .filter(|(e, _)| named.as_ref().is_none_or(|n| n.contains(&e.name)))
            .map(|(e, c)| (e.name.as_str(), c))
            .collect();
        several_unstreamable(&sets, &a.est, a.realtime).or_else(|| {
            if crate::io::trace::is_hdf5_path(&a.input.trace) {
                Some("HDF5 files are read into memory".into())
            } else if a.input.rate_hz.is_some() {
                Some("a trace without time (--rate-hz) is read into memory".into())
            } else {
                None
            }
        })
    }

    /// The sensors `--sensors` names (`mag_K`, as `multi::sensors::parse_sensors` spells
    /// them), None without it; a name it would refuse is left to the plan to refuse.
    fn named_sensors(&self) -> Option<Vec<String>> {
        let text = self.multi.sensors.as_ref()?;
        Some(
            text.split(',')
                .filter_map(|e| {
                    let name = e.split([':', '@']).next()?.trim();
                    let k: usize = name.strip_prefix("mag_")?.parse().ok()?;
                    Some(format!("mag_{k}"))
                })
                .collect(),
        )
    }

    /// Streams the sensors of `m` (or those `--sensors` names): the plan from the file's
    /// header, then `stream::several::compensate_several`, then each sensor's summary.
    pub fn run(&self, m: &MultiCoefficients) -> Result<()> {
        let a = self;
        let map = match &a.input.map {
            Some(text) => ColumnMap::parse(text)?,
            None => ColumnMap::new(),
        };
        // The sensors are resolved against the header (names and the metadata above the first
        // row), as the in-memory run resolves them against the whole trace.
        let head = crate::io::trace::rows::read_head(&a.input.trace, &map)?;
        let header = head.empty_trace();
        let plan =
            a.multi
                .plan_with(&header, a.input.map.as_deref(), (a.coeffs, Some(m.clone())))?;
        let SensorPlan::Several(sensors, Some(multi)) = plan else {
            bail!("internal: several sensors planned as one");
        };
        let est = &a.est;
        let (files, _) = sets_of(&header, est, &sensors, Some(&multi))?;
        let pairs = match &a.multi.gradients {
            Some(g) => parse_pairs(g, &sensors)?,
            None => Vec::new(),
        };
        let gradients = pairs
            .iter()
            .map(|&(i, j)| {
                Ok(Gradient {
                    name: format!("gradient_{}_{}", sensors[i].name, sensors[j].name),
                    a: i,
                    b: j,
                    separation_m: gradient_separation_m(&sensors, i, j)?,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let runs: Vec<SensorRun> = sensors
            .iter()
            .zip(&files)
            .map(|(s, f)| SensorRun {
                name: Some(s.name.clone()),
                columns: SensorColumns {
                    scalar: s.scalar_column.clone(),
                    flux: s.flux_columns.clone(),
                    truth: vec![
                        format!("truth_interference_{}", s.name),
                        "truth_interference".into(),
                    ],
                },
                coeffs: f,
            })
            .collect();
        let mut summaries = compensate_several(
            &a.input.stream_input(),
            est,
            &runs,
            &gradients,
            a.out,
            a.quiet,
        )?;
        for (s, f) in summaries.iter_mut().zip(&files) {
            s.warnings.extend(a.input.provenance_warnings(None, f));
        }
        let names: Vec<&str> = sensors.iter().map(|s| s.name.as_str()).collect();
        print_summaries(&names, &summaries, a.json)?;
        crate::errln!("wrote {}", a.out.display());
        Ok(())
    }
}

/// Each sensor's summary, as the one-sensor stream prints it: text under the sensor's
/// name, or one JSON document `{"sensors": [...]}` (each entry's `sensor` its name, its
/// `warnings` also those printed for it as found); warnings on stderr, named.
fn print_summaries(names: &[&str], summaries: &[StreamSummary], json: bool) -> Result<()> {
    if json {
        let entries = names
            .iter()
            .zip(summaries)
            .map(|(name, s)| {
                let mut v = with_printed_warnings(serde_json::to_value(s)?);
                // Printed warnings naming another sensor are that sensor's.
                if let Some(w) = v.get_mut("warnings").and_then(|w| w.as_array_mut()) {
                    w.retain(|w| {
                        let text = w.as_str().unwrap_or("");
                        names
                            .iter()
                            .all(|n| n == name || !text.contains(&format!("({n})")))
                    });
                }
                if let Some(o) = v.as_object_mut() {
                    o.insert("sensor".into(), name.to_string().into());
                }
                Ok(v)
            })
            .collect::<Result<Vec<_>>>()?;
        crate::outln!("{}", serde_json::json!({ "sensors": entries }));
    }
    for (name, s) in names.iter().zip(summaries) {
        if !json {
            crate::outln!("{name}:");
            print_stream_text(s);
        }
        for w in &s.warnings {
            crate::errln!("warning: {name}: {w}");
        }
    }
    Ok(())
}
