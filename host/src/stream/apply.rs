//! The third streaming pass: every row read, checked, despiked, compensated (KF in survey
//! mode, or Tolles–Lawson) and written as `compensate` writes it. Rows wait in small
//! queues only as long as their window needs: the despiker's ±0.3 s, the filter's
//! centred derivative, Tolles–Lawson's one-sample difference, one row to learn whether a
//! time gap follows.
use super::rows::RowFilter;
use super::stage::{Feeder, Figures, Found, Pending, SensorStage, StageRow};
use super::stats::Listed;
use super::{Plan, Progress};
use crate::calibration::coefficients::CoefficientFile;
use crate::calibration::EstimatorSettings;
use crate::flight::input::Selection;
use crate::io::csv::{csv_text, fixed_cell as num, number_cell};
use crate::io::trace::rows::{for_each_row, Kind, Row};
use crate::io::trace::{ColumnMap, ReadOptions};
use crate::model::spec::{with_model, ModelSpec};
use anyhow::{bail, Context, Result};
use std::io::Write;
use std::path::Path;

pub(crate) struct Source<'a> {
    pub path: &'a Path,
    pub map: &'a ColumnMap,
    pub sel: &'a Selection,
}

/// What the pass found beside the output file.
pub(crate) struct RunResult {
    pub model: String,
    pub error_rms_nt: Option<f64>,
    pub predicted_error_nt: Option<f64>,
    pub glitches: Listed<f64>,
    pub flux_glitches: Listed<[f32; 3]>,
    pub gaps: Vec<(usize, f64, f64)>,
    pub gap_count: usize,
}

impl RunResult {
    /// A pass's result: what its feeder found and the figures its stage gathered.
    pub fn of_pass(model: String, found: Found, figures: Figures) -> Self {
        Self {
            model,
            error_rms_nt: figures.error_rms_nt,
            predicted_error_nt: figures.predicted_error_nt,
            glitches: found.glitches,
            flux_glitches: found.flux_glitches,
            gaps: found.gaps,
            gap_count: found.gap_count,
        }
    }

    /// `qc::gaps::gaps_warning`'s text.
    pub fn gaps_warning(&self) -> Option<String> {
        if self.gap_count == 0 {
            return None;
        }
        let shown: Vec<String> = self
            .gaps
            .iter()
            .map(|(i, dt, t0)| format!("{dt:.1} s at t = {t0} (data row {})", i + 1))
            .collect();
        Some(format!(
            "{} time gap(s) longer than {} sample spacings ({}{}): the samples on either side are flagged DERIVATIVE_DEGRADED, Tolles–Lawson and the band-pass are not run across them",
            self.gap_count,
            crate::qc::gaps::GAP_FACTOR,
            shown.join(", "),
            if self.gap_count > 3 { ", …" } else { "" }
        ))
    }
}

/// The columns `input::carried_columns` carries: `igrf` or not, then (output name,
/// column) of the numeric and the text ones.
struct Carried {
    igrf: bool,
    nums: Vec<(String, usize)>,
    texts: Vec<(String, usize)>,
}

fn carried(plan: &Plan) -> Carried {
    let rename = crate::flight::input::carried_name;
    let h = &plan.head;
    let igrf = plan.cols.igrf.is_some() || plan.igrf.is_some();
    let nums = (0..h.names.len())
        .filter(|&i| h.kinds[i] != Kind::Text)
        .filter(|&i| crate::flight::input::is_carried(&h.names[i]))
        .map(|i| (rename(&h.names[i]), i))
        .collect();
    let texts = (0..h.names.len())
        .filter(|&i| h.kinds[i] == Kind::Text)
        .map(|i| (rename(&h.names[i]), i))
        .collect();
    Carried { igrf, nums, texts }
}

/// Output of one row: `summary::write_output_rows`' layout.
fn write_row(
    w: &mut (impl Write + ?Sized),
    p: &Pending,
    interference: f64,
    compensated: f64,
    kf: Option<(f64, f64, u16)>,
    igrf: bool,
) -> Result<()> {
    write!(
        w,
        "{},{},{},{}",
        p.sample.t_s,
        num(p.mag_nt, 4),
        num(interference, 4),
        num(compensated, 4)
    )?;
    if let Some((a, nu, f)) = kf {
        write!(w, ",{},{},{:#06x}", num(a, 4), num(nu, 5), f)?;
    }
    if igrf {
        write!(w, ",{}", number_cell(p.sample.igrf_nt))?;
    }
    for &v in &p.carried_num {
        write!(w, ",{}", number_cell(v))?;
    }
    for t in &p.carried_text {
        write!(w, ",{}", csv_text(t))?;
    }
    writeln!(w)?;
    Ok(())
}

/// Reads the selected rows again and hands each, checked, despiked and with its core
/// field, to `sink` (in order); returns the glitches and gaps found.
fn feed(
    src: &Source,
    plan: &Plan,
    quiet: bool,
    mut sink: impl FnMut(Pending) -> Result<()>,
) -> Result<Found> {
    let Carried { nums, texts, .. } = carried(plan);
    let index = |c: Vec<(String, usize)>| c.into_iter().map(|(_, i)| i).collect();
    let mut feeder = Feeder::new(plan, index(nums), index(texts));
    feed_rows(src, &[plan], quiet, |row| feeder.push(row, &mut sink))?;
    feeder.finish(&mut sink)
}

/// Reads the selected rows of `src` once, handing each to `on_row`; every plan must
/// have counted the same rows in its first pass (the file must not change meanwhile).
pub(crate) fn feed_rows(
    src: &Source,
    plans: &[&Plan],
    quiet: bool,
    mut on_row: impl FnMut(&Row) -> Result<()>,
) -> Result<()> {
    let first = plans.first().context("internal: no plan")?;
    let cols = &first.cols;
    let mut filter = RowFilter::new(src.sel.clone());
    let mut k = 0usize;
    let mut progress = Progress::new("pass 3/3 (compensating, writing)", quiet);
    for_each_row(src.path, src.map, ReadOptions::default(), |row| {
        if !filter.keep(row, cols)? {
            return Ok(());
        }
        progress.tick();
        k += 1;
        on_row(row)
    })
    .with_context(|| format!("reading {}", src.path.display()))?;
    progress.done();
    if k != first.rows {
        bail!(
            "{} changed while it was read: {k} rows now, {} before",
            src.path.display(),
            first.rows
        );
    }
    Ok(())
}

/// The third pass; writes `out`.
pub(crate) fn run(
    src: &Source,
    plan: &Plan,
    est: &EstimatorSettings,
    coeffs: &CoefficientFile,
    spec: Option<&ModelSpec>,
    out: &Path,
    quiet: bool,
) -> Result<RunResult> {
    let Carried { igrf, nums, texts } = carried(plan);
    let header = |w: &mut dyn Write, model: &str, kf: bool| -> Result<()> {
        writeln!(w, "# model: {model}")?;
        writeln!(w, "# method: {}", if kf { "kf" } else { "tl" })?;
        if kf {
            write!(w, "t,mag,interference,compensated,anomaly,innovation,flags")?;
        } else {
            write!(w, "t,mag,interference,compensated")?;
        }
        if igrf {
            write!(w, ",igrf")?;
        }
        for (n, _) in nums.iter().chain(&texts) {
            write!(w, ",{n}")?;
        }
        writeln!(w)?;
        Ok(())
    };
    let run = (src, plan, quiet, igrf);
    match spec {
        Some(spec) => with_model(spec, |model| {
            let stage = SensorStage::new(Some((spec, model)), plan, est, coeffs)?;
            run_stage(run, stage, out, &header)
        }),
        None => run_stage(
            run,
            SensorStage::new(None, plan, est, coeffs)?,
            out,
            &header,
        ),
    }
}

type Header<'a> = dyn Fn(&mut dyn Write, &str, bool) -> Result<()> + 'a;

/// Every row through `stage` (either method: the same pass), each written as it comes back.
fn run_stage(
    (src, plan, quiet, igrf): (&Source, &Plan, bool, bool),
    mut stage: SensorStage<'_>,
    out: &Path,
    header: &Header,
) -> Result<RunResult> {
    let model = stage.model().to_string();
    crate::io::trace::write_table_with(out, |w| {
        header(w, &model, stage.is_kf())?;
        let mut emit = |r: StageRow| {
            let kf = r.anomaly.map(|(a, nu)| (a, nu, r.flags));
            write_row(w, &r.p, r.interference_nt, r.compensated_nt, kf, igrf)
        };
        let found = feed(src, plan, quiet, |p| stage.push(p, &mut emit))?;
        let figures = stage.finish(&mut emit)?;
        Ok(RunResult::of_pass(model, found, figures))
    })
}
