//! The compensation pass for one sensor, a row at a time: [`Feeder`] turns each selected
//! row into a checked, despiked [`Pending`] sample, [`KfStage`] runs the core filter on
//! them, or [`TlStage`] Tolles–Lawson, and hands back each row with its outputs. They are
//! pushed rows rather than reading the file themselves, so one read of the file can drive
//! one feeder and one stage per sensor (`super::several`) as well as the one-sensor run
//! (`super::apply`).
use super::igrf::{GapCursor, IgrfScan};
use super::rows::row_sample;
use super::stats::{GlitchJudge, Listed, Verdict};
use super::Plan;
use crate::calibration::coefficients::CoefficientFile;
use crate::calibration::EstimatorSettings;
use crate::estimate::kf::{filter, HostCompensator, KfOptions};
use crate::flight::position::PositionChecker;
use crate::io::trace::rows::Row;
use crate::model::spec::ModelSpec;
use anyhow::{Context, Result};
use magcomp_core::compensator::Output;
use magcomp_core::model::Model;
use magcomp_core::Flags;
use std::collections::{BTreeSet, VecDeque};

/// A row on its way through the windows.
pub(crate) struct Pending {
    pub row: usize,
    pub sample: magcomp_core::AlignedSample,
    /// The scalar as the compensation sees it (NaN once found a glitch).
    pub mag_nt: f64,
    /// The scalar as read (the several-sensor output's `mag_K` column).
    pub mag_read_nt: f64,
    pub truth_nt: f64,
    /// First row after a time gap.
    pub after_gap: bool,
    pub carried_num: Vec<f64>,
    pub carried_text: Vec<String>,
}

/// What a [`Feeder`] found on the way: glitches, the first time gaps and their count.
pub(crate) struct Found {
    pub glitches: Listed<f64>,
    pub flux_glitches: Listed<[f32; 3]>,
    pub gaps: Vec<(usize, f64, f64)>,
    pub gap_count: usize,
    /// Rows fed.
    pub rows: usize,
}

/// A row waiting for the despikers: with its file line and its fluxgate as read (f64).
type Waiting = (Pending, u64, [f64; 3]);

/// Fluxgate glitches bridged as in memory (`flight::bridge_flux_glitches`): the row's
/// scalar taken as missing (nothing is learnt from it), its vector drawn between the last
/// good vector before and the first within `despike::bridge_reach` rows after, only ever
/// from rows already judged good (a neighbour still unjudged may be a glitch itself), and
/// from the vectors as read, in f64, before any fluxgate calibration, so the bridged
/// vector is the same to the last bit (Tolles–Lawson's full-precision output showed an
/// f32 bridge). From a glitch until its good row after, rows are held back, in order.
struct FluxBridge {
    listed: Listed<[f32; 3]>,
    reach_rows: usize,
    /// Time and vector (as read) of the last row judged with a good vector.
    last_good: Option<(f64, [f64; 3])>,
    /// Rows held back, each with whether it is a glitch still to bridge.
    held: VecDeque<(Pending, bool)>,
}

impl FluxBridge {
    fn new(sample_rate_hz: f64) -> Self {
        Self {
            listed: Listed::default(),
            reach_rows: crate::signal::despike::bridge_reach(sample_rate_hz),
            last_good: None,
            held: VecDeque::new(),
        }
    }

    /// A judged row; `out` gets the rows whose bridges are known by now, in order.
    fn judged(
        &mut self,
        (mut p, line, raw): Waiting,
        flux_glitch: bool,
        out: &mut dyn FnMut(Pending) -> Result<()>,
    ) -> Result<()> {
        if flux_glitch {
            self.listed.push(line, p.sample.flux_nt);
            p.mag_nt = f64::NAN;
            p.sample.mag = None;
        }
        let (row, t_s) = (p.row, p.sample.t_s);
        self.held.push_back((p, flux_glitch));
        if !flux_glitch && raw.iter().all(|v| v.is_finite()) {
            self.bridge(|_| true, Some((t_s, raw)));
            self.last_good = Some((t_s, raw));
        } else {
            // Glitches whose reach ends here found no good row after.
            let reach = self.reach_rows;
            self.bridge(|g| g + reach <= row, None);
        }
        self.release(out)
    }

    /// The end of the flight: the last glitches have no good row after.
    fn finish(mut self, out: &mut dyn FnMut(Pending) -> Result<()>) -> Result<Listed<[f32; 3]>> {
        self.bridge(|_| true, None);
        self.release(out)?;
        Ok(self.listed)
    }

    /// The held glitches whose row `due` accepts, bridged to `after`.
    fn bridge(&mut self, due: impl Fn(usize) -> bool, after: Option<(f64, [f64; 3])>) {
        for (p, pending) in self.held.iter_mut().filter(|(p, g)| *g && due(p.row)) {
            let v = crate::flight::bridged_vector(p.sample.t_s, self.last_good, after);
            p.sample.flux_nt = v.map(|x| x as f32);
            *pending = false;
        }
    }

    /// The held rows up to the first glitch still to bridge.
    fn release(&mut self, out: &mut dyn FnMut(Pending) -> Result<()>) -> Result<()> {
        while self.held.front().is_some_and(|(_, g)| !g) {
            let (p, _) = self.held.pop_front().context("internal: held rows")?;
            out(p)?;
        }
        Ok(())
    }
}

/// Each selected row, checked, despiked and with its core field, handed on in order once
/// the despikers' windows have judged it (and, after a fluxgate glitch, once its bridge is
/// known).
pub(crate) struct Feeder<'p> {
    plan: &'p Plan,
    /// Input columns carried to the output: numeric, text.
    nums: Vec<usize>,
    texts: Vec<usize>,
    positions: PositionChecker,
    judge: GlitchJudge,
    waiting: VecDeque<Waiting>,
    glitches: Listed<f64>,
    bridge: FluxBridge,
    gaps: Vec<(usize, f64, f64)>,
    gap_count: usize,
    prev_t: Option<f64>,
    k: usize,
    /// A computed core field: the model at the row's date (kept: its coefficients are
    /// interpolated once per date, not per row), and where its gaps are read.
    core: Option<(IgrfScan, GapCursor)>,
}

impl<'p> Feeder<'p> {
    pub fn new(plan: &'p Plan, nums: Vec<usize>, texts: Vec<usize>) -> Self {
        Self {
            plan,
            nums,
            texts,
            positions: PositionChecker::default(),
            judge: GlitchJudge::new(plan.sample_rate_hz),
            waiting: VecDeque::new(),
            glitches: Listed::default(),
            bridge: FluxBridge::new(plan.sample_rate_hz),
            gaps: Vec::new(),
            gap_count: 0,
            prev_t: None,
            k: 0,
            core: plan
                .igrf
                .as_ref()
                .map(|(_, fill)| (IgrfScan::default(), fill.cursor())),
        }
    }

    /// A selected row; `sink` gets the rows judged by now.
    pub fn push(&mut self, row: &Row, sink: &mut dyn FnMut(Pending) -> Result<()>) -> Result<()> {
        let (plan, k) = (self.plan, self.k);
        let cols = &plan.cols;
        let mut rs = row_sample(row, cols, plan.base0, &plan.offsets);
        self.positions.check(&mut rs.sample, |_| {});
        if let (Some((source, _)), Some((scan, gaps))) = (&plan.igrf, &mut self.core) {
            let year = super::igrf::row_year(source, row, k)?;
            let v = scan.value(year, cols, row)?;
            rs.sample.igrf_nt = if v.is_finite() { v } else { gaps.value(k)? };
        }
        if let Some(v) = plan.assumed_speed_mps {
            if !rs.sample.ground_speed_mps.is_finite() {
                rs.sample.ground_speed_mps = v as f32;
            }
        }
        let t = rs.sample.t_s;
        let after_gap = self.prev_t.is_some_and(|t0| t - t0 > plan.gap_limit_s);
        if after_gap {
            let t0 = self.prev_t.unwrap_or(t);
            if self.gaps.len() < 3 {
                self.gaps.push((k, t - t0, t0));
            }
            self.gap_count += 1;
        }
        self.prev_t = Some(t);
        let p = Pending {
            row: k,
            sample: rs.sample,
            mag_nt: rs.mag_nt,
            mag_read_nt: rs.mag_nt,
            truth_nt: rs.truth_interference_nt,
            after_gap,
            carried_num: self.nums.iter().map(|&i| row.num(i)).collect(),
            carried_text: self
                .texts
                .iter()
                .map(|&i| row.text(i).to_string())
                .collect(),
        };
        self.waiting.push_back((p, rs.line, rs.raw_flux));
        // Judged as measured, as `Flight::from_trace` judges it (before its calibration).
        if let Some(v) = self.judge.push(k, rs.mag_nt, rs.raw_flux) {
            self.judged(v, sink)?;
        }
        self.k += 1;
        Ok(())
    }

    /// The row at the queue's front, judged.
    fn judged(&mut self, v: Verdict, sink: &mut dyn FnMut(Pending) -> Result<()>) -> Result<()> {
        let (mut p, line, raw) = self
            .waiting
            .pop_front()
            .context("internal: despiker order")?;
        debug_assert_eq!(p.row, v.row);
        if v.scalar {
            self.glitches.push(line, p.mag_nt);
            p.mag_nt = f64::NAN;
            p.sample.mag = None;
        }
        let plan = self.plan;
        self.bridge
            .judged((p, line, raw), v.flux, &mut |p| calibrated(plan, p, sink))
    }

    /// The end of the flight: the rows still in the windows, then what was found.
    pub fn finish(mut self, sink: &mut dyn FnMut(Pending) -> Result<()>) -> Result<Found> {
        for v in self.judge.finish() {
            self.judged(v, sink)?;
        }
        let plan = self.plan;
        let flux_glitches = self.bridge.finish(&mut |p| calibrated(plan, p, sink))?;
        Ok(Found {
            glitches: self.glitches,
            flux_glitches,
            gaps: self.gaps,
            gap_count: self.gap_count,
            rows: self.k,
        })
    }
}

/// A judged, bridged row to `sink` with the fluxgate calibration applied: after the
/// bridging, as in memory (`fluxcal::calibrated_flight` on the flight).
fn calibrated(
    plan: &Plan,
    mut p: Pending,
    sink: &mut dyn FnMut(Pending) -> Result<()>,
) -> Result<()> {
    if let Some(c) = &plan.fluxgate_calibration {
        p.sample.flux_nt = c.apply(p.sample.flux_nt.map(f64::from)).map(|v| v as f32);
    }
    sink(p)
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

/// Running error against the simulated truth: what the TL pass keeps too.
#[derive(Default)]
pub(crate) struct TruthError(Spread);

impl TruthError {
    pub fn push(&mut self, interference_nt: f64, truth_nt: f64) {
        self.0.push(interference_nt - truth_nt);
    }
    pub fn rms(&self) -> f64 {
        self.0.rms()
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

/// A row with its sensor's outputs, as `compensate` writes them.
pub(crate) struct StageRow {
    pub p: Pending,
    pub interference_nt: f64,
    pub compensated_nt: f64,
    /// The filter's anomaly and innovation (Tolles–Lawson has none: None).
    pub anomaly: Option<(f64, f64)>,
    pub flags: u16,
}

/// The figures a stage gathered over the flight.
pub(crate) struct Figures {
    pub error_rms_nt: Option<f64>,
    pub predicted_error_nt: Option<f64>,
}

/// The core filter in survey mode (`filter::config_for`/`filter::build`, as the in-memory
/// path builds it) over rows pushed in order; each row comes back once the row after it
/// has been seen (a time gap after it flags it too).
pub(crate) struct KfStage<'m> {
    /// The model's text, as the in-memory run names it.
    model: String,
    comp: Box<HostCompensator<'m>>,
    mask: Vec<bool>,
    buf: Vec<f32>,
    regs: RegressorCov,
    error: TruthError,
    truth: bool,
    covariance: Option<Vec<f64>>,
    /// Rows in the filter (awaiting their output).
    in_filter: VecDeque<Pending>,
    /// Outputs waiting for the next row.
    ready: VecDeque<(Pending, Output)>,
    gap_rows: BTreeSet<usize>,
    newest: usize,
}

impl<'m> KfStage<'m> {
    pub fn new(
        spec: &ModelSpec,
        model: Model<'m>,
        plan: &Plan,
        est: &EstimatorSettings,
        coeffs: &CoefficientFile,
    ) -> Result<Self> {
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
        let mask = filter::interference_mask(&model);
        let k = model.coefficient_count();
        let comp = Box::new(filter::build(&spec.text(), model, cfg, Some(&given), &[])?);
        Ok(Self {
            model: spec.text(),
            comp,
            mask,
            buf: vec![0.0f32; k],
            regs: RegressorCov::new(k),
            error: TruthError::default(),
            truth: plan.cols.truth_interference.is_some(),
            covariance: coeffs.covariance.as_ref().map(|rows| rows.concat()),
            in_filter: VecDeque::new(),
            ready: VecDeque::new(),
            gap_rows: BTreeSet::new(),
            newest: 0,
        })
    }

    /// A row from the [`Feeder`]; `out` gets the rows finished by now.
    pub fn push(&mut self, p: Pending, out: &mut dyn FnMut(StageRow) -> Result<()>) -> Result<()> {
        if p.after_gap {
            self.gap_rows.insert(p.row);
            if p.row > 0 {
                self.gap_rows.insert(p.row - 1);
            }
        }
        self.newest = p.row;
        self.comp.set_noise_scale(1.0);
        let r = self.comp.push_epoch(&p.sample);
        self.in_filter.push_back(p);
        self.step(r)?;
        // A row is written once the row after it has been seen.
        while self.ready.front().is_some_and(|(p, _)| p.row < self.newest) {
            let (p, o) = self.ready.pop_front().context("internal")?;
            self.emit(p, o, out)?;
        }
        Ok(())
    }

    /// The end of the flight: the filter flushed, every row handed on.
    pub fn finish(mut self, out: &mut dyn FnMut(StageRow) -> Result<()>) -> Result<Figures> {
        while let Some(r) = self.comp.flush_epoch() {
            self.step(Some(r))?;
        }
        if !self.in_filter.is_empty() {
            anyhow::bail!(
                "internal: {} samples without an output",
                self.in_filter.len()
            );
        }
        while let Some((p, o)) = self.ready.pop_front() {
            self.emit(p, o, out)?;
        }
        Ok(Figures {
            error_rms_nt: self.truth.then(|| self.error.rms()),
            predicted_error_nt: self
                .covariance
                .as_ref()
                .and_then(|c| self.regs.predicted(c)),
        })
    }

    fn step(&mut self, ep_out: Option<(magcomp_core::epoch::Epoch, Output)>) -> Result<()> {
        if let Some((ep, o)) = ep_out {
            filter::interference_regressors(&self.comp, &ep, &self.mask, &mut self.buf);
            self.regs.push(&self.buf);
            let p = self
                .in_filter
                .pop_front()
                .context("internal: more outputs than samples")?;
            self.ready.push_back((p, o));
        }
        Ok(())
    }

    fn emit(
        &mut self,
        p: Pending,
        o: Output,
        out: &mut dyn FnMut(StageRow) -> Result<()>,
    ) -> Result<()> {
        let i = o.interference_nt as f64;
        let c = match o.compensated {
            Some(c) => c.to_nt_f64(),
            None => p.mag_nt - i,
        };
        let mut flags = o.flags.0;
        if self.gap_rows.remove(&p.row) {
            flags |= Flags::DERIVATIVE_DEGRADED;
        }
        if self.truth {
            self.error.push(i, p.truth_nt);
        }
        out(StageRow {
            p,
            interference_nt: i,
            compensated_nt: c,
            anomaly: Some((o.anomaly_nt as f64, o.innovation_nt as f64)),
            flags,
        })
    }
}

/// Rows per Tolles–Lawson design block (one row of context either side).
const TL_BLOCK: usize = 1024;

/// Tolles–Lawson over rows pushed in order, as the in-memory path computes it per stretch
/// between time gaps: in blocks of [`TL_BLOCK`] rows, each with the row before and after
/// it as context, so every centred difference is the whole stretch's.
pub(crate) struct TlStage {
    fit: crate::estimate::tl::TlFit,
    model: String,
    block: VecDeque<Pending>,
    /// The fluxgate of the last row handed on, in this stretch.
    context: Option<[f64; 3]>,
    truth: bool,
    error: TruthError,
}

impl TlStage {
    pub fn new(plan: &Plan, coeffs: &CoefficientFile) -> Result<Self> {
        let cfg = coeffs
            .tl_config
            .clone()
            .context("the coefficient file has no Tolles–Lawson configuration")?;
        let fit = coeffs.tl_fit(cfg);
        let terms = fit.config.terms.columns().len();
        if fit.coefficients.len() != terms {
            anyhow::bail!(
                "{} Tolles–Lawson coefficients for {terms} terms",
                fit.coefficients.len()
            );
        }
        Ok(Self {
            model: format!("{:?}", fit.config.terms).to_lowercase(),
            fit,
            block: VecDeque::new(),
            context: None,
            truth: plan.cols.truth_interference.is_some(),
            error: TruthError::default(),
        })
    }

    /// A row from the [`Feeder`]; `out` gets the rows finished by now.
    pub fn push(&mut self, p: Pending, out: &mut dyn FnMut(StageRow) -> Result<()>) -> Result<()> {
        if p.after_gap {
            // A new stretch: no difference across the gap.
            self.emit(self.block.len(), out)?;
            self.context = None;
        }
        self.block.push_back(p);
        // One row stays behind: the next block's first difference needs it.
        if self.block.len() > TL_BLOCK {
            self.emit(TL_BLOCK, out)?;
        }
        Ok(())
    }

    /// The end of the flight: every row handed on.
    pub fn finish(mut self, out: &mut dyn FnMut(StageRow) -> Result<()>) -> Result<Figures> {
        self.emit(self.block.len(), out)?;
        Ok(Figures {
            error_rms_nt: self.truth.then(|| self.error.rms()),
            predicted_error_nt: None,
        })
    }

    /// The first `count` rows of the block: the design over the context row and the block.
    fn emit(&mut self, count: usize, out: &mut dyn FnMut(StageRow) -> Result<()>) -> Result<()> {
        let flux = |p: &Pending| p.sample.flux_nt.map(f64::from);
        let rows: Vec<[f64; 3]> = self
            .context
            .iter()
            .copied()
            .chain(self.block.iter().map(flux))
            .collect();
        let off = usize::from(self.context.is_some());
        let inter = crate::estimate::tl::interference(&self.fit, &rows);
        for j in 0..count {
            let p = self.block.pop_front().context("internal: TL block")?;
            let i = inter[off + j];
            if self.truth {
                self.error.push(i, p.truth_nt);
            }
            self.context = Some(flux(&p));
            // As `calibration::tl` flags a sample without a usable scalar.
            let flags = if p.sample.mag.is_none() {
                Flags::MAG_MISSING
            } else {
                0
            };
            out(StageRow {
                compensated_nt: p.mag_nt - i,
                interference_nt: i,
                anomaly: None,
                flags,
                p,
            })?;
        }
        Ok(())
    }
}

/// One sensor's compensation, by its coefficient file's method.
pub(crate) enum SensorStage<'m> {
    Kf(KfStage<'m>),
    Tl(TlStage),
}

impl<'m> SensorStage<'m> {
    /// The stage a set's method asks for: the core filter with the set's model (and its
    /// built `Model`), or Tolles–Lawson without one.
    pub fn new(
        kf_model: Option<(&ModelSpec, Model<'m>)>,
        plan: &Plan,
        est: &EstimatorSettings,
        coeffs: &CoefficientFile,
    ) -> Result<Self> {
        Ok(match kf_model {
            Some((spec, model)) => Self::Kf(KfStage::new(spec, model, plan, est, coeffs)?),
            None => Self::Tl(TlStage::new(plan, coeffs)?),
        })
    }

    /// The model's name, as the in-memory run gives it.
    pub fn model(&self) -> &str {
        match self {
            Self::Kf(s) => &s.model,
            Self::Tl(s) => &s.model,
        }
    }

    pub fn is_kf(&self) -> bool {
        matches!(self, Self::Kf(_))
    }

    pub fn push(&mut self, p: Pending, out: &mut dyn FnMut(StageRow) -> Result<()>) -> Result<()> {
        match self {
            Self::Kf(s) => s.push(p, out),
            Self::Tl(s) => s.push(p, out),
        }
    }

    pub fn finish(self, out: &mut dyn FnMut(StageRow) -> Result<()>) -> Result<Figures> {
        match self {
            Self::Kf(s) => s.finish(out),
            Self::Tl(s) => s.finish(out),
        }
    }
}
