//! The third streaming pass: every row read, checked, despiked, compensated (KF in survey
//! mode, or Tolles–Lawson) and written as `compensate` writes it. Rows wait in small
//! queues only as long as their window needs: the despiker's ±0.3 s, the filter's
//! centred derivative, Tolles–Lawson's one-sample difference, one row to learn whether a
//! time gap follows.
use super::rows::{row_sample, Cols, RowFilter};
use super::stats::{year_of_date, year_of_doy, DateSource, Despiker, FluxDespiker, Listed};
use super::{Plan, Progress};
use crate::calibration::coefficients::CoefficientFile;
use crate::calibration::EstimatorSettings;
use crate::estimate::kf::{filter, HostCompensator, KfOptions};
use crate::flight::input::Selection;
use crate::flight::position::PositionChecker;
use crate::io::csv::{csv_text, fixed_cell as num, number_cell};
use crate::io::trace::rows::{for_each_row, Kind, Row};
use crate::io::trace::{ColumnMap, ReadOptions};
use crate::model::spec::{with_model, ModelSpec};
use anyhow::{bail, Context, Result};
use magcomp_core::Flags;
use std::collections::{BTreeSet, VecDeque};
use std::io::Write;
use std::path::Path;

pub(crate) struct Source<'a> {
    pub path: &'a Path,
    pub map: &'a ColumnMap,
    pub sel: &'a Selection,
}

/// `input::fill_gaps` without the column: the first and last finite values and each
/// interior run of missing ones with the values around it.
#[derive(Clone, Debug, Default)]
pub struct GapFill {
    first: Option<(usize, f64)>,
    last: Option<(usize, f64)>,
    runs: Vec<(usize, usize, f64, f64)>,
}

impl GapFill {
    fn push(&mut self, row: usize, v: f64) {
        if !v.is_finite() {
            return;
        }
        if let Some((a, va)) = self.last {
            if row > a + 1 {
                self.runs.push((a, row, va, v));
            }
        }
        self.first.get_or_insert((row, v));
        self.last = Some((row, v));
    }

    /// The filled value of a missing row (NaN when the column has no value at all).
    fn value(&self, row: usize) -> f64 {
        let (Some((f, vf)), Some((l, vl))) = (self.first, self.last) else {
            return f64::NAN;
        };
        if row < f {
            return vf;
        }
        if row > l {
            return vl;
        }
        let k = self.runs.partition_point(|r| r.1 <= row);
        match self.runs.get(k) {
            Some(&(a, b, va, vb)) if a < row && row < b => {
                va + (vb - va) * (row - a) as f64 / (b - a) as f64
            }
            _ => f64::NAN,
        }
    }
}

/// IGRF-14 along the flight, one row at a time (`input::igrf_column`): coefficients
/// recomputed only when the date changes.
#[derive(Default)]
pub struct IgrfScan {
    cache: Option<(f64, crate::flight::igrf::Coefficients)>,
    pub fill: GapFill,
    /// Least and greatest decimal year.
    pub years: (f64, f64),
    /// Least and greatest value (nT), for the change over a flight without a date.
    pub range_nt: (f64, f64),
    started: bool,
}

impl IgrfScan {
    pub fn value(&mut self, year: f64, cols: &Cols, row: &Row) -> Result<f64> {
        let get = |c: Option<usize>| c.map_or(f64::NAN, |i| row.num(i));
        let (lat, lon, alt) = (get(cols.lat), get(cols.lon), get(cols.alt));
        if !(lat.is_finite() && lon.is_finite() && alt.is_finite() && year.is_finite()) {
            return Ok(f64::NAN);
        }
        if self.cache.as_ref().is_none_or(|(cy, _)| *cy != year) {
            self.cache = Some((
                year,
                crate::flight::igrf::Igrf::igrf14().coefficients_at(year)?,
            ));
        }
        Ok(self
            .cache
            .as_ref()
            .map_or(f64::NAN, |(_, c)| c.field(lat, lon, alt).total_nt))
    }

    pub fn push(&mut self, k: usize, year: f64, cols: &Cols, row: &Row) -> Result<()> {
        if !self.started {
            self.years = (f64::INFINITY, f64::NEG_INFINITY);
            self.range_nt = (f64::INFINITY, f64::NEG_INFINITY);
            self.started = true;
        }
        if year.is_finite() {
            self.years = (self.years.0.min(year), self.years.1.max(year));
        }
        let v = self.value(year, cols, row)?;
        if v.is_finite() {
            self.range_nt = (self.range_nt.0.min(v), self.range_nt.1.max(v));
        }
        self.fill.push(k, v);
        Ok(())
    }
}

/// Decimal year of row `k` by the chosen source.
pub fn row_year(source: &DateSource, row: &Row, k: usize) -> Result<f64> {
    match source {
        DateSource::Given(y) => Ok(*y),
        DateSource::Column(c) => year_of_date(row.text(*c), k),
        DateSource::YearDoy(y, d, names) => year_of_doy(row.num(*y), row.num(*d), names, k),
    }
}

/// A row on its way through the windows.
struct Pending {
    row: usize,
    sample: magcomp_core::AlignedSample,
    mag_nt: f64,
    truth_nt: f64,
    /// First row after a time gap.
    after_gap: bool,
    carried_num: Vec<f64>,
    carried_text: Vec<String>,
}

/// What the pass found beside the output file.
pub(crate) struct RunResult {
    pub model: String,
    pub error_rms_nt: Option<f64>,
    pub predicted_error_nt: Option<f64>,
    pub glitches: Listed<f64>,
    pub flux_glitches: Listed<[f32; 3]>,
    gaps: Vec<(usize, f64, f64)>,
    gap_count: usize,
}

impl RunResult {
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

/// Mean and variance of finite values, one at a time (Welford): `truth::error_rms_nt`.
#[derive(Default)]
struct Spread {
    n: f64,
    mean: f64,
    m2: f64,
}

impl Spread {
    fn push(&mut self, x: f64) {
        if !x.is_finite() {
            return;
        }
        self.n += 1.0;
        let d = x - self.mean;
        self.mean += d / self.n;
        self.m2 += d * (x - self.mean);
    }
    fn rms(&self) -> f64 {
        if self.n == 0.0 {
            f64::NAN
        } else {
            (self.m2 / self.n).sqrt()
        }
    }
}

/// `kf::RegressorSpread::sigma_nt` from running sums: the regressors'
/// covariance over the flight (sums of the deviation from the first row, so no large
/// mean cancels), against the coefficients' covariance.
struct RegressorCov {
    k: usize,
    shift: Option<Vec<f64>>,
    n: f64,
    s1: Vec<f64>,
    s2: Vec<f64>,
}

impl RegressorCov {
    fn new(k: usize) -> Self {
        Self {
            k,
            shift: None,
            n: 0.0,
            s1: vec![0.0; k],
            s2: vec![0.0; k * k],
        }
    }
    fn push(&mut self, r: &[f32]) {
        if !r.iter().all(|v| v.is_finite()) {
            return;
        }
        let shift = self
            .shift
            .get_or_insert_with(|| r.iter().map(|v| *v as f64).collect());
        let d: Vec<f64> = r
            .iter()
            .zip(shift.iter())
            .map(|(v, s)| *v as f64 - s)
            .collect();
        self.n += 1.0;
        for a in 0..self.k {
            self.s1[a] += d[a];
            for b in 0..self.k {
                self.s2[a * self.k + b] += d[a] * d[b];
            }
        }
    }
    fn predicted(&self, covariance: &[f64]) -> Option<f64> {
        let k = self.k;
        if covariance.len() != k * k || self.n < 2.0 {
            return None;
        }
        let mut var = 0.0;
        for a in 0..k {
            for b in 0..k {
                let c = self.s2[a * k + b] / self.n - (self.s1[a] / self.n) * (self.s1[b] / self.n);
                var += covariance[a * k + b] * c;
            }
        }
        var.is_finite().then(|| var.max(0.0).sqrt())
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
    let cols = &plan.cols;
    let mut filter = RowFilter::new(src.sel.clone());
    let mut positions = PositionChecker::default();
    let mut despiker = Despiker::new(plan.sample_rate_hz);
    let mut flux_despiker = FluxDespiker::new(plan.sample_rate_hz);
    let mut waiting: VecDeque<(Pending, u64)> = VecDeque::new();
    let mut glitches = Listed::default();
    let mut flux_glitches = FluxGlitches::default();
    let (mut gaps, mut gap_count) = (Vec::new(), 0usize);
    let mut prev_t: Option<f64> = None;
    let mut k = 0usize;
    let mut progress = Progress::new("pass 3/3 (compensating, writing)", quiet);
    // The row at the queue's front, judged by both despikers (`waiting` is also filled
    // by the row loop, so it is passed in; the findings are kept here).
    let mut judged = |(row, glitch): (usize, bool),
                      flux_glitch: bool,
                      waiting: &mut VecDeque<(Pending, u64)>|
     -> Result<()> {
        let (mut p, line) = waiting.pop_front().context("internal: despiker order")?;
        debug_assert_eq!(p.row, row);
        if glitch {
            glitches.push(line, p.mag_nt);
            p.mag_nt = f64::NAN;
            p.sample.mag = None;
        } else if flux_glitch {
            flux_glitches.take_out(&mut p, line, waiting);
        }
        flux_glitches.passed(&p, flux_glitch && !glitch);
        sink(p)
    };
    for_each_row(src.path, src.map, ReadOptions::default(), |row| {
        if !filter.keep(row, cols)? {
            return Ok(());
        }
        progress.tick();
        let mut rs = row_sample(row, cols, plan.base0, &plan.offsets);
        // Judged as measured, as `Flight::from_trace` judges it (before its calibration).
        let flux_judged = flux_despiker.push(k, rs.sample.flux_nt, rs.mag_nt);
        if let Some(c) = &plan.fluxgate_calibration {
            rs.sample.flux_nt = c.apply(rs.sample.flux_nt.map(f64::from)).map(|v| v as f32);
        }
        positions.check(&mut rs.sample, |_| {});
        if let Some((source, fill)) = &plan.igrf {
            let year = super::apply::row_year(source, row, k)?;
            let mut scan = IgrfScan::default();
            let v = scan.value(year, cols, row)?;
            rs.sample.igrf_nt = if v.is_finite() { v } else { fill.value(k) };
        }
        if let Some(v) = plan.assumed_speed_mps {
            if !rs.sample.ground_speed_mps.is_finite() {
                rs.sample.ground_speed_mps = v as f32;
            }
        }
        let t = rs.sample.t_s;
        let after_gap = prev_t.is_some_and(|t0| t - t0 > plan.gap_limit_s);
        if after_gap {
            if gaps.len() < 3 {
                gaps.push((k, t - prev_t.unwrap_or(t), prev_t.unwrap_or(t)));
            }
            gap_count += 1;
        }
        prev_t = Some(t);
        let p = Pending {
            row: k,
            sample: rs.sample,
            mag_nt: rs.mag_nt,
            truth_nt: rs.truth_interference_nt,
            after_gap,
            carried_num: nums.iter().map(|(_, i)| row.num(*i)).collect(),
            carried_text: texts
                .iter()
                .map(|(_, i)| row.text(*i).to_string())
                .collect(),
        };
        waiting.push_back((p, rs.line));
        if let Some(j) = despiker.push(k, rs.mag_nt) {
            let flux_glitch = flux_judged.is_some_and(|(_, g)| g);
            judged(j, flux_glitch, &mut waiting)?;
        }
        k += 1;
        Ok(())
    })
    .with_context(|| format!("reading {}", src.path.display()))?;
    let flux_rest = flux_despiker.finish();
    for (j, (_, flux_glitch)) in despiker.finish().into_iter().zip(flux_rest) {
        judged(j, flux_glitch, &mut waiting)?;
    }
    progress.done();
    if k != plan.rows {
        bail!(
            "{} changed while it was read: {k} rows now, {} before",
            src.path.display(),
            plan.rows
        );
    }
    Ok(Found {
        glitches,
        flux_glitches: flux_glitches.listed,
        gaps,
        gap_count,
    })
}

/// A fluxgate row found bad in the stream: its scalar is taken as missing (nothing is learnt
/// from it) and its vector bridged from the last good row before and the first row after
/// (still in the queue), as the in-memory path does (`flight::bridge_flux_glitches`).
#[derive(Default)]
struct FluxGlitches {
    listed: Listed<[f32; 3]>,
    /// Time and vector of the last row passed on with a good vector.
    last_good: Option<(f64, [f32; 3])>,
}

impl FluxGlitches {
    fn take_out(&mut self, p: &mut Pending, line: u64, queue: &VecDeque<(Pending, u64)>) {
        self.listed.push(line, p.sample.flux_nt);
        p.mag_nt = f64::NAN;
        p.sample.mag = None;
        let good = |f: &[f32; 3]| f.iter().all(|v| v.is_finite());
        let after = queue
            .iter()
            .map(|(q, _)| (q.sample.t_s, q.sample.flux_nt))
            .find(|(_, f)| good(f));
        let t = p.sample.t_s;
        p.sample.flux_nt = match (self.last_good, after) {
            (Some((ta, a)), Some((tb, b))) if tb > ta => {
                let w = ((t - ta) / (tb - ta)) as f32;
                std::array::from_fn(|k| a[k] + w * (b[k] - a[k]))
            }
            (Some((_, a)), _) => a,
            (None, Some((_, b))) => b,
            (None, None) => [f32::NAN; 3],
        };
    }

    fn passed(&mut self, p: &Pending, bridged: bool) {
        if !bridged && p.sample.flux_nt.iter().all(|v| v.is_finite()) {
            self.last_good = Some((p.sample.t_s, p.sample.flux_nt));
        }
    }
}

/// What [`feed`] found on the way: glitches, the first time gaps and their count.
struct Found {
    glitches: Listed<f64>,
    flux_glitches: Listed<[f32; 3]>,
    gaps: Vec<(usize, f64, f64)>,
    gap_count: usize,
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
    match spec {
        Some(spec) => run_kf(src, plan, est, coeffs, spec, out, quiet, &header, igrf),
        None => run_tl(src, plan, coeffs, out, quiet, &header, igrf),
    }
}

type Header<'a> = dyn Fn(&mut dyn Write, &str, bool) -> Result<()> + 'a;

#[allow(clippy::too_many_arguments)]
fn run_kf(
    src: &Source,
    plan: &Plan,
    est: &EstimatorSettings,
    coeffs: &CoefficientFile,
    spec: &ModelSpec,
    out: &Path,
    quiet: bool,
    header: &Header,
    igrf: bool,
) -> Result<RunResult> {
    let opts = KfOptions::new(spec.clone());
    let sigma1 = est
        .sigma1
        .or(coeffs.sigma1)
        .context("internal: no sigma1")?;
    let cfg = filter::config_for(
        (plan.sample_rate_hz, plan.earth_dir_ned, plan.tie_point),
        &opts,
        sigma1,
        plan.noise_nt,
    );
    let given: Vec<f64> = coeffs.coefficients.iter().map(|c| c.value).collect();
    let covariance = coeffs.covariance.as_ref().map(|rows| rows.concat());
    with_model(spec, |model| {
        let mut comp = filter::build(spec, model, cfg, Some(&given), &[])?;
        let interference_terms = filter::interference_mask(&model);
        let k = model.coefficient_count();
        let mut buf = vec![0.0f32; k];
        let mut regs = RegressorCov::new(k);
        let mut error = Spread::default();
        let truth = plan.cols.truth_interference.is_some();
        crate::io::trace::write_table_with(out, |w| {
            header(w, &spec.text(), true)?;
            // Rows in the filter (awaiting their output), and outputs waiting for the
            // next row (a time gap after them flags them too).
            let mut in_filter: VecDeque<Pending> = VecDeque::new();
            let mut ready: VecDeque<(Pending, magcomp_core::compensator::Output)> = VecDeque::new();
            let mut gap_rows: BTreeSet<usize> = BTreeSet::new();
            let mut newest = 0usize;
            let mut emit = |p: Pending,
                            o: magcomp_core::compensator::Output,
                            w: &mut dyn Write,
                            gap_rows: &mut BTreeSet<usize>|
             -> Result<()> {
                let i = o.interference_nt as f64;
                let c = match o.compensated {
                    Some(c) => c.to_nt_f64(),
                    None => p.mag_nt - i,
                };
                let mut flags = o.flags.0;
                if gap_rows.remove(&p.row) {
                    flags |= Flags::DERIVATIVE_DEGRADED;
                }
                if truth {
                    error.push(i - p.truth_nt);
                }
                write_row(
                    w,
                    &p,
                    i,
                    c,
                    Some((o.anomaly_nt as f64, o.innovation_nt as f64, flags)),
                    igrf,
                )
            };
            let mut step = |ep_out: Option<(
                magcomp_core::epoch::Epoch,
                magcomp_core::compensator::Output,
            )>,
                            comp: &HostCompensator,
                            in_filter: &mut VecDeque<Pending>,
                            ready: &mut VecDeque<(Pending, magcomp_core::compensator::Output)>|
             -> Result<()> {
                if let Some((ep, o)) = ep_out {
                    filter::interference_regressors(comp, &ep, &interference_terms, &mut buf);
                    regs.push(&buf);
                    let p = in_filter
                        .pop_front()
                        .context("internal: more outputs than samples")?;
                    ready.push_back((p, o));
                }
                Ok(())
            };
            let found = feed(src, plan, quiet, |p| {
                if p.after_gap {
                    gap_rows.insert(p.row);
                    if p.row > 0 {
                        gap_rows.insert(p.row - 1);
                    }
                }
                newest = p.row;
                comp.set_noise_scale(1.0);
                let r = comp.push_epoch(&p.sample);
                in_filter.push_back(p);
                step(r, &comp, &mut in_filter, &mut ready)?;
                // A row is written once the row after it has been seen.
                while ready.front().is_some_and(|(p, _)| p.row < newest) {
                    let (p, o) = ready.pop_front().context("internal")?;
                    emit(p, o, w, &mut gap_rows)?;
                }
                Ok(())
            })?;
            while let Some(r) = comp.flush_epoch() {
                step(Some(r), &comp, &mut in_filter, &mut ready)?;
            }
            if !in_filter.is_empty() {
                bail!("internal: {} samples without an output", in_filter.len());
            }
            while let Some((p, o)) = ready.pop_front() {
                emit(p, o, w, &mut gap_rows)?;
            }
            Ok(RunResult {
                model: spec.text(),
                error_rms_nt: truth.then(|| error.rms()),
                predicted_error_nt: covariance.as_ref().and_then(|c| regs.predicted(c)),
                glitches: found.glitches,
                flux_glitches: found.flux_glitches,
                gaps: found.gaps,
                gap_count: found.gap_count,
            })
        })
    })
}

/// Rows per Tolles–Lawson design block (one row of context either side).
const TL_BLOCK: usize = 1024;

fn run_tl(
    src: &Source,
    plan: &Plan,
    coeffs: &CoefficientFile,
    out: &Path,
    quiet: bool,
    header: &Header,
    igrf: bool,
) -> Result<RunResult> {
    let cfg = coeffs
        .tl_config
        .clone()
        .context("the coefficient file has no Tolles–Lawson configuration")?;
    let fit = coeffs.tl_fit(cfg);
    if fit.coefficients.len() != fit.config.terms.columns().len() {
        bail!(
            "{} Tolles–Lawson coefficients for {} terms",
            fit.coefficients.len(),
            fit.config.terms.columns().len()
        );
    }
    let model = format!("{:?}", fit.config.terms).to_lowercase();
    let truth = plan.cols.truth_interference.is_some();
    let mut error = Spread::default();
    crate::io::trace::write_table_with(out, |w| {
        header(w, &model, false)?;
        let mut block: VecDeque<Pending> = VecDeque::new();
        let mut context: Option<[f64; 3]> = None;
        let flux = |p: &Pending| p.sample.flux_nt.map(f64::from);
        // Interference of the first `count` rows of the block: the design over the
        // previous row (context), the block, so every centred difference is the whole
        // stretch's.
        let mut emit = |count: usize,
                        block: &mut VecDeque<Pending>,
                        context: &mut Option<[f64; 3]>,
                        w: &mut dyn Write|
         -> Result<()> {
            let rows: Vec<[f64; 3]> = context
                .iter()
                .copied()
                .chain(block.iter().map(flux))
                .collect();
            let off = context.is_some() as usize;
            let inter = crate::estimate::tl::interference(&fit, &rows);
            for j in 0..count {
                let p = block.pop_front().context("internal: TL block")?;
                let i = inter[off + j];
                if truth {
                    error.push(i - p.truth_nt);
                }
                write_row(w, &p, i, p.mag_nt - i, None, igrf)?;
                *context = Some(flux(&p));
            }
            Ok(())
        };
        let found = feed(src, plan, quiet, |p| {
            if p.after_gap {
                // A new stretch: no difference across the gap.
                let n = block.len();
                emit(n, &mut block, &mut context, w)?;
                context = None;
            }
            block.push_back(p);
            if block.len() > TL_BLOCK {
                emit(TL_BLOCK, &mut block, &mut context, w)?;
            }
            Ok(())
        })?;
        let n = block.len();
        emit(n, &mut block, &mut context, w)?;
        Ok(RunResult {
            model: model.clone(),
            error_rms_nt: truth.then(|| error.rms()),
            predicted_error_nt: None,
            glitches: found.glitches,
            flux_glitches: found.flux_glitches,
            gaps: found.gaps,
            gap_count: found.gap_count,
        })
    })
}
