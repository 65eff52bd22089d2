//! Several magnetometers streamed (issue 19): one read of the file per pass drives one
//! [`Feeder`] and one [`SensorStage`] per sensor (the core filter or Tolles–Lawson, by its
//! set's method, built as the one-sensor stream builds them), and each output row is
//! written once every sensor has finished it, in the in-memory several-sensor layout
//! (`cli::multi::output_table`): `t`, per sensor `mag_K`, `interference_mag_K`,
//! `compensated_mag_K`, `anomaly_mag_K` (Kalman filter only), `flags_mag_K`, then the
//! gradients, then `lat`, `lon`, `alt`, `line`, `LINE`. Memory: each sensor's windows (the
//! despiker's ±0.3 s, the filter's derivative, a Tolles–Lawson block), not the flight.
use super::apply::{feed_rows, RunResult};
use super::stage::{Feeder, Figures, Found, Pending, SensorStage, StageRow};
use super::StreamSummary;
use super::{prepare, summary, unstreamable, Opened, Prepared, SensorRun, StreamInput};
use crate::calibration::coefficients::CoefficientFile;
use crate::calibration::EstimatorSettings;
use crate::io::trace::rows::{Kind, RowsHeader};
use crate::io::trace::write_number;
use crate::model::spec::{with_models, ModelSpec};
use anyhow::{bail, Context, Result};
use std::collections::VecDeque;
use std::io::Write;
use std::path::Path;

/// A gradient column of the output: `name` = (compensated `b` − compensated `a`) /
/// `separation_m` (nT/m), `a` and `b` indices into the sensors.
#[derive(Clone, Debug)]
pub struct Gradient {
    pub name: String,
    pub a: usize,
    pub b: usize,
    pub separation_m: f64,
}

/// The input columns the several-sensor output carries, after the sensors' and the
/// gradients' (`cli::multi::output_table`): numeric ones only, as the in-memory table
/// takes them.
const CARRIED: [&str; 5] = ["lat", "lon", "alt", "line", "LINE"];

/// Why these sensors (name, coefficients) cannot be streamed (None: they can): what the
/// one-sensor stream refuses, for any of them.
pub fn several_unstreamable(
    sensors: &[(&str, &CoefficientFile)],
    est: &EstimatorSettings,
    realtime: bool,
) -> Option<String> {
    if realtime {
        return unstreamable(sensors.first().map(|s| s.1), est, true);
    }
    sensors.iter().find_map(|(name, coeffs)| {
        unstreamable(Some(coeffs), est, false).map(|w| format!("{name}: {w}"))
    })
}

/// `compensate` on several sensors streamed: writes `out` and returns each sensor's
/// summary, in the sensors' order.
pub fn compensate_several(
    input: &StreamInput<'_>,
    est: &EstimatorSettings,
    sensors: &[SensorRun<'_>],
    gradients: &[Gradient],
    out: &Path,
    quiet: bool,
) -> Result<Vec<StreamSummary>> {
    let sets: Vec<(&str, &CoefficientFile)> = sensors
        .iter()
        .map(|s| (s.name.as_deref().unwrap_or("mag"), s.coeffs))
        .collect();
    if let Some(why) = several_unstreamable(&sets, est, false) {
        bail!("this run cannot be streamed: {why} (use --stream never)");
    }
    if let Some(g) = gradients.iter().find(|g| {
        g.a.max(g.b) >= sensors.len()
            || g.separation_m.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater)
    }) {
        bail!(
            "internal: gradient {} of unknown sensors or separation",
            g.name
        );
    }
    let opened = Opened::new(input)?;
    let source = opened.source(input.trace);
    let prepared = prepare(&source, input.date, est, sensors, quiet)?;
    // The Kalman-filter sensors' models (Tolles–Lawson needs none).
    let specs: Vec<&ModelSpec> = prepared.iter().filter_map(|p| p.spec.as_ref()).collect();
    let names: Vec<&str> = sensors
        .iter()
        .map(|s| {
            s.name
                .as_deref()
                .context("internal: a sensor without a name")
        })
        .collect::<Result<_>>()?;
    let head = &prepared[0].plan.head;
    let carried: Vec<(String, usize)> = CARRIED
        .iter()
        .filter_map(|c| Some((c.to_string(), head.index(c)?)))
        .filter(|(_, i)| head.kinds[*i] != Kind::Text)
        .collect();
    let kf: Vec<bool> = prepared.iter().map(|p| p.spec.is_some()).collect();
    let table = Table {
        names: &names,
        kf: &kf,
        gradients,
        carried: &carried,
    };
    let runs = with_models(&specs, |models| -> Result<Vec<(String, Found, Figures)>> {
        let mut models = models.into_iter();
        let mut stages = Vec::new();
        for (p, s) in prepared.iter().zip(sensors) {
            let kf_model = match &p.spec {
                Some(spec) => Some((spec, models.next().context("internal: a model short")?)),
                None => None,
            };
            let tl = kf_model.is_none();
            let stage = SensorStage::new(kf_model, &p.plan, est, s.coeffs);
            // A Tolles–Lawson set's refusal names its sensor, as `prepare` names its own.
            stages.push(if tl {
                stage.with_context(|| sensor_context(s))?
            } else {
                stage?
            });
        }
        let model_names: Vec<String> = stages.iter().map(|s| s.model().to_string()).collect();
        let done = crate::io::trace::write_table_with(out, |w| {
            table.header(w, head)?;
            run_all(&source, &prepared, stages, &table, w, quiet)
        })?;
        Ok(model_names
            .into_iter()
            .zip(done)
            .map(|(m, (found, figures))| (m, found, figures))
            .collect())
    })?;
    let mut summaries = Vec::new();
    for (((p, s), (model, found, figures)), name) in
        prepared.into_iter().zip(sensors).zip(runs).zip(names)
    {
        let result = RunResult::of_pass(model, found, figures);
        summaries.push(summary(p, result, s.coeffs, input.trace, Some(name)));
    }
    Ok(summaries)
}

/// What a sensor's error is prefixed with, as `prepare` prefixes its own.
fn sensor_context(s: &SensorRun<'_>) -> String {
    format!(
        "{} with its coefficients",
        s.name.as_deref().unwrap_or("mag")
    )
}

/// The compensation pass: every row to every sensor's feeder and filter, each output row
/// written once all sensors have it.
fn run_all(
    source: &super::apply::Source<'_>,
    prepared: &[Prepared],
    stages: Vec<SensorStage<'_>>,
    table: &Table<'_>,
    w: &mut dyn Write,
    quiet: bool,
) -> Result<Vec<(Found, Figures)>> {
    let carried: Vec<usize> = table.carried.iter().map(|(_, i)| *i).collect();
    let mut feeders: Vec<Feeder> = prepared
        .iter()
        .enumerate()
        // The carried columns are the same for every sensor: the first one holds them.
        .map(|(i, p)| {
            Feeder::new(
                &p.plan,
                if i == 0 { carried.clone() } else { vec![] },
                vec![],
            )
        })
        .collect();
    let mut stages = stages;
    let mut queues: Vec<VecDeque<StageRow>> = prepared.iter().map(|_| VecDeque::new()).collect();
    let mut fast = zmij::Buffer::new();
    let plans: Vec<&super::Plan> = prepared.iter().map(|p| &p.plan).collect();
    feed_rows(source, &plans, quiet, |row| {
        for ((feeder, stage), q) in feeders.iter_mut().zip(&mut stages).zip(&mut queues) {
            feeder.push(row, &mut |p: Pending| {
                stage.push(p, &mut |r| {
                    q.push_back(r);
                    Ok(())
                })
            })?;
        }
        table.write_ready(w, &mut queues, &mut fast)
    })?;
    let mut out = Vec::new();
    for ((feeder, mut stage), q) in feeders.into_iter().zip(stages).zip(&mut queues) {
        let mut queue = |r| {
            q.push_back(r);
            Ok(())
        };
        let found = feeder.finish(&mut |p| stage.push(p, &mut queue))?;
        let figures = stage.finish(&mut queue)?;
        out.push((found, figures));
    }
    table.write_ready(w, &mut queues, &mut fast)?;
    if let Some(q) = queues.iter().find(|q| !q.is_empty()) {
        bail!(
            "internal: {} rows of one sensor without the others'",
            q.len()
        );
    }
    if let Some((f, _)) = out.iter().find(|(f, _)| f.rows != prepared[0].plan.rows) {
        bail!("internal: {} rows fed of {}", f.rows, prepared[0].plan.rows);
    }
    Ok(out)
}

/// The output's layout.
struct Table<'a> {
    names: &'a [&'a str],
    /// Per sensor: a Kalman-filter set (an `anomaly_mag_K` column; Tolles–Lawson has none).
    kf: &'a [bool],
    gradients: &'a [Gradient],
    carried: &'a [(String, usize)],
}

impl Table<'_> {
    /// The metadata and the column names, as `write_trace` writes them (a table of no
    /// rows through the same writer, so the same checks).
    fn header(&self, w: &mut dyn Write, head: &RowsHeader) -> Result<()> {
        let mut t = crate::io::trace::Trace {
            meta: head.meta.clone(),
            ..Default::default()
        };
        let mut col = |n: String| t.numeric.push((n, Vec::new()));
        col("t".into());
        for (n, &kf) in self.names.iter().zip(self.kf) {
            col(n.to_string());
            for what in ["interference", "compensated", "anomaly", "flags"] {
                if kf || what != "anomaly" {
                    col(format!("{what}_{n}"));
                }
            }
        }
        for g in self.gradients {
            col(g.name.clone());
        }
        for (c, _) in self.carried {
            col(c.clone());
        }
        crate::io::trace::write_trace_to(w, &t)?;
        Ok(())
    }

    /// Writes the rows every sensor has finished.
    fn write_ready(
        &self,
        w: &mut dyn Write,
        queues: &mut [VecDeque<StageRow>],
        fast: &mut zmij::Buffer,
    ) -> Result<()> {
        while queues.iter().all(|q| !q.is_empty()) {
            let rows: Vec<StageRow> = queues
                .iter_mut()
                .map(|q| q.pop_front().context("internal"))
                .collect::<Result<_>>()?;
            let first = &rows[0].p;
            if rows.iter().any(|r| r.p.row != first.row) {
                bail!("internal: the sensors' rows out of step");
            }
            let mut cells = vec![first.sample.t_s];
            for r in &rows {
                // As the in-memory table (`cli::multi::output_table`): to 0.1 pT.
                let interference_nt = crate::io::csv::rounded(r.interference_nt, 4);
                cells.extend([r.p.mag_read_nt, interference_nt, r.compensated_nt]);
                cells.extend(r.anomaly.map(|(a, _)| crate::io::csv::rounded(a, 4)));
                cells.push(f64::from(r.flags));
            }
            for g in self.gradients {
                let (a, b) = (rows[g.a].compensated_nt, rows[g.b].compensated_nt);
                cells.push((b - a) / g.separation_m);
            }
            cells.extend(&first.carried_num);
            for (k, v) in cells.iter().enumerate() {
                if k > 0 {
                    w.write_all(b",")?;
                }
                write_number(w, fast, *v)?;
            }
            w.write_all(b"\n")?;
        }
        Ok(())
    }
}
