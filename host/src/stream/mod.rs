//! Streaming `compensate --coeffs`: a calibration applied to a survey of any length in
//! memory bounded by a window, not by the flight.
//!
//! Three passes over the file, one row at a time (`trace::rows`):
//! 1. the figures that need no sample rate: row selection, sample rate (median time
//!    step, `stats::StreamMedian`: exact up to 65 536 distinct values, then within
//!    0.1 %), main-field direction, tie point, position checks, date source, input checks;
//! 2. (only when needed) the scalar's noise (median of the despiked third
//!    difference, as in pass 1) and the core field's gaps (IGRF-14 from positions and date);
//! 3. the core compensator (KF, survey mode) or Tolles–Lawson, sample by sample, each
//!    output row written as it comes to a temporary file renamed at the end.
//!
//! Every per-sample number is computed as the in-memory path computes it (`tests/
//! stream_compensate.rs` holds them equal). What needs the whole flight in memory is not
//! streamed: calibrating, `--realtime`, models with `lag`, `fluxtemp` or
//! `rate`, a coefficient file without σ1; [`unstreamable`] says which, and
//! `compensate` then reads the flight into memory. The summary's band-passed figures
//! (residual, IR, FOM) and the applied-coefficient checks are computed in memory only; a
//! streamed run says so. Several sensors share the three passes, each its own filter or
//! Tolles–Lawson ([`several`]).
mod apply;
pub mod decimate;
mod igrf;
pub mod rows;
pub mod several;
mod stage;
pub mod stats;

use crate::calibration::coefficients::{CoefficientFile, Method};
use crate::calibration::EstimatorSettings;
use crate::flight::input::Selection;
use crate::io::progress::Progress;
use crate::io::trace::rows::for_each_row;
use crate::io::trace::{ColumnMap, ReadOptions};
use crate::model::spec::ModelSpec;
use anyhow::{bail, Context, Result};
use magcomp_core::model::TermKind;
pub use rows::SensorColumns;
use rows::{row_sample, Cols, RowFilter};
use serde::Serialize;
use stats::{DateScan, DateSource, FirstPass, SecondPass};
use std::path::Path;

/// `compensate` streams on its own above this input size (~1.3 M rows of a typical
/// trace, ~1.3 GB in memory); `--stream always|never` decides otherwise.
pub const AUTO_STREAM_BYTES: u64 = 256 << 20;

/// The trace a streamed run reads: the file and the selection and date options every
/// command takes (`cli::args::TraceInput`).
#[derive(Clone, Copy, Debug)]
pub struct StreamInput<'a> {
    pub trace: &'a Path,
    pub map: Option<&'a str>,
    pub lines: Option<&'a str>,
    pub time: Option<&'a str>,
    pub date: Option<&'a str>,
}

/// Why this run cannot be streamed (None: it can).
pub fn unstreamable(
    coeffs: Option<&CoefficientFile>,
    est: &EstimatorSettings,
    realtime: bool,
) -> Option<String> {
    let Some(c) = coeffs else {
        return Some("calibrating (no --coeffs) needs the whole flight".into());
    };
    if realtime {
        return Some("--realtime is run in memory".into());
    }
    if c.method == Method::Tl {
        return c.scalar_lag.map(|_| {
            "a re-aligned scalar (`scalar_lag`) is pre-processed over the whole flight".into()
        });
    }
    let spec = match ModelSpec::parse(&c.model) {
        Ok(s) => s,
        Err(e) => return Some(format!("model '{}': {e}", c.model)),
    };
    if crate::estimate::corrections::needed(&spec) {
        return Some("`lag`/`fluxtemp` pre-process the whole flight".into());
    }
    if spec.calibrates_fluxgate() && c.fluxgate_calibration.is_none() {
        return Some("the model has `fluxcal` but the file has no fluxgate_calibration".into());
    }
    if spec.has(TermKind::Rate) {
        return Some("`rate` needs the flight's crossovers".into());
    }
    if spec.field && est.sigma1.or(c.sigma1).is_none() {
        return Some(
            "the coefficient file has no sigma1 (it is then estimated from the whole flight)"
                .into(),
        );
    }
    None
}

/// What a streamed run reports (`compensate --json` when streamed).
#[derive(Clone, Debug, Serialize)]
pub struct StreamSummary {
    pub model: String,
    pub method: Method,
    pub samples: usize,
    pub streamed: bool,
    pub error_rms_nt: Option<f64>,
    pub predicted_error_nt: Option<f64>,
    pub sample_rate_hz: f64,
    pub noise_nt: Option<f64>,
    /// Figures the in-memory path gives that a streamed run does not compute.
    pub not_computed: Vec<String>,
    pub warnings: Vec<String>,
    /// Post-flight on a long, fast flight: the coefficients were calibrated on this
    /// decimated copy, then applied here at the full rate (`decimate`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub decimated: Option<crate::flight::input::Decimation>,
}

/// The core field as `input::prepare` decides it.
#[derive(Clone, Debug, PartialEq)]
enum Core {
    FromFile,
    Computed(DateSource, String),
    /// No date: the change over the flight is only reported.
    Missing,
    NoPosition,
}

/// Everything the third pass needs from the first two.
pub(crate) struct Plan {
    pub cols: Cols,
    pub head: crate::io::trace::rows::RowsHeader,
    pub rows: usize,
    pub sample_rate_hz: f64,
    pub gap_limit_s: f64,
    pub earth_dir_ned: Option<[f32; 3]>,
    pub tie_point: Option<magcomp_core::compensator::TiePoint>,
    pub base0: Option<f64>,
    pub offsets: Vec<f64>,
    pub assumed_speed_mps: Option<f64>,
    pub noise_nt: f64,
    pub igrf: Option<(DateSource, igrf::GapFill)>,
    /// The coefficient file's fluxgate calibration, applied to every fluxgate vector before
    /// the compensator (as `kf::run_kf_estimator` does in memory).
    pub fluxgate_calibration: Option<crate::estimate::fluxcal::FluxgateCalibration>,
}

/// One sensor of a streamed run: the columns it is read from and its coefficients;
/// `name` (several sensors) prefixes its errors and names it in its warnings.
pub struct SensorRun<'a> {
    pub name: Option<String>,
    pub columns: SensorColumns,
    pub coeffs: &'a CoefficientFile,
}

/// What passes 1 and 2 settle for one sensor.
pub(crate) struct Prepared {
    pub plan: Plan,
    pub spec: Option<ModelSpec>,
    pub warnings: Vec<String>,
    /// Why the predicted error is withheld.
    withheld: Option<String>,
    position_faults: stats::Listed<crate::flight::position::PositionFault>,
}

/// The file and the selection a streamed run reads, parsed once.
pub(crate) struct Opened {
    map: ColumnMap,
    sel: Selection,
}

impl Opened {
    pub fn new(input: &StreamInput<'_>) -> Result<Self> {
        let map = match input.map {
            Some(m) => ColumnMap::parse(m)?,
            None => ColumnMap::new(),
        };
        let sel = Selection::parse(input.lines, input.time)?;
        Ok(Self { map, sel })
    }
    pub fn source<'a>(&'a self, path: &'a Path) -> apply::Source<'a> {
        apply::Source {
            path,
            map: &self.map,
            sel: &self.sel,
        }
    }
}

/// `compensate --coeffs` streamed: writes `out` and returns the summary. `quiet`: no
/// progress lines. Three passes over the file: flight figures (pass 1, [`first_pass`]),
/// the scalar's noise and the core field's gaps (pass 2, [`second_pass`]), then the
/// compensation itself ([`apply::run`]).
pub fn compensate(
    input: &StreamInput<'_>,
    est: &EstimatorSettings,
    coeffs: &CoefficientFile,
    out: &Path,
    quiet: bool,
) -> Result<StreamSummary> {
    if let Some(why) = unstreamable(Some(coeffs), est, false) {
        bail!("this run cannot be streamed: {why} (use --stream never)");
    }
    let opened = Opened::new(input)?;
    let source = opened.source(input.trace);
    let one = SensorRun {
        name: None,
        columns: SensorColumns::canonical(),
        coeffs,
    };
    let mut prepared = prepare(&source, input.date, est, std::slice::from_ref(&one), quiet)?;
    let p = prepared.pop().context("internal: no sensor prepared")?;
    let result = apply::run(&source, &p.plan, est, coeffs, p.spec.as_ref(), out, quiet)?;
    Ok(summary(p, result, coeffs, input.trace, None))
}

/// The summary of one sensor's pass, its warnings said (glitches, positions: once, on
/// stderr, as the in-memory path says them), `name` naming the sensor of several.
pub(crate) fn summary(
    p: Prepared,
    result: apply::RunResult,
    coeffs: &CoefficientFile,
    path: &Path,
    name: Option<&str>,
) -> StreamSummary {
    let label = match name {
        Some(n) => format!("{} ({n})", path.display()),
        None => path.display().to_string(),
    };
    let mut warnings = p.warnings;
    if let Some(w) = stats::glitch_warning(&label, &result.glitches) {
        crate::flight::position::warn_once(&w);
    }
    if let Some(w) = stats::flux_glitch_warning(&label, &result.flux_glitches) {
        crate::flight::position::warn_once(&w);
    }
    // The positions are the same for every sensor: said once, naming none.
    if let Some(w) = stats::faults_warning(&path.display().to_string(), &p.position_faults) {
        crate::flight::position::warn_once(&w);
    }
    if let Some(w) = result.gaps_warning() {
        warnings.push(w);
    }
    warnings.extend(p.withheld.iter().map(|why| {
        format!("{why}: improvement ratio, FOM and predicted error are withheld (null)")
    }));
    StreamSummary {
        model: result.model,
        method: coeffs.method,
        samples: p.plan.rows,
        streamed: true,
        error_rms_nt: result.error_rms_nt,
        predicted_error_nt: result.predicted_error_nt.filter(|_| p.withheld.is_none()),
        sample_rate_hz: p.plan.sample_rate_hz,
        noise_nt: p.spec.as_ref().map(|_| p.plan.noise_nt),
        not_computed: NOT_COMPUTED_STREAMED.map(String::from).to_vec(),
        warnings,
        decimated: None,
    }
}

/// Passes 1 and 2 over `source` for every sensor at once: each sensor's flight figures,
/// checks and noise, the core field (the same for all) decided once.
pub(crate) fn prepare(
    source: &apply::Source<'_>,
    date: Option<&str>,
    est: &EstimatorSettings,
    sensors: &[SensorRun<'_>],
    quiet: bool,
) -> Result<Vec<Prepared>> {
    if sensors.is_empty() {
        bail!("no sensor to compensate");
    }
    let given_year = match date {
        Some(d) => {
            let (y, doy) = crate::flight::igrf::parse_date(d).context("--date")?;
            Some(crate::flight::igrf::decimal_year(y, doy, 0.0))
        }
        None => None,
    };
    let specs = sensors
        .iter()
        .map(|s| match s.coeffs.method {
            Method::Kf => ModelSpec::parse(&s.coeffs.model).map(Some),
            Method::Tl => Ok(None),
        })
        .collect::<Result<Vec<_>>>()?;
    let channels: Vec<Vec<String>> = specs
        .iter()
        .map(|s| s.as_ref().map(|s| s.channels()).unwrap_or_default())
        .collect();
    let wanted: Vec<(&SensorColumns, &[String])> = sensors
        .iter()
        .zip(&channels)
        .map(|(s, c)| (&s.columns, c.as_slice()))
        .collect();
    let p1s = first_pass(source, &wanted, quiet)?;
    let named = |s: &SensorRun, e: anyhow::Error| match &s.name {
        Some(n) => e.context(format!("{n} with its coefficients")),
        None => e,
    };
    let mut checked = Vec::new();
    for (s, p1) in sensors.iter().zip(&p1s) {
        let mut warnings = Vec::new();
        let c =
            check_first(p1, &channels[checked.len()], &mut warnings).map_err(|e| named(s, e))?;
        checked.push((c, warnings));
    }
    let first0 = p1s.first().context("internal: no sensor")?;
    let core = choose_core(first0, given_year)?;
    let median_dt = checked[0].0 .1;
    let need_noise: Vec<bool> = specs
        .iter()
        .map(|s| s.is_some() && est.noise_nt.is_none())
        .collect();
    let cols: Vec<&Cols> = p1s.iter().map(|p| &p.cols).collect();
    let (seconds, igrf_scan) = second_pass(source, &cols, &core, &need_noise, median_dt, quiet)?;
    let igrf = core_field(&core, &igrf_scan);
    let core_meta = core_meta(&core, &igrf_scan);
    let tie_point = first0.first.tie_point(&first0.head.meta);
    let mut out = Vec::new();
    let parts = sensors.iter().zip(p1s).zip(specs).zip(seconds);
    for ((((s, p1), spec), second), ((withheld, median_dt), warnings)) in parts.zip(checked) {
        let settled = Settled {
            spec,
            withheld,
            median_dt,
            noise_from_scalar: second.noise_nt(),
            igrf: igrf.clone(),
            core_meta: core_meta.clone(),
            tie_point,
            warnings,
        };
        out.push(plan_of(s, p1, settled, est).map_err(|e| named(s, e))?);
    }
    Ok(out)
}

/// Pass 1's checks for one sensor: rows, channels, the input checks; returns why figures
/// are withheld and the median time step.
fn check_first(
    p1: &FirstPassOut,
    channels: &[String],
    warnings: &mut Vec<String>,
) -> Result<(Option<String>, f64)> {
    let first = &p1.first;
    let n = first.rows;
    if channels.len() > magcomp_core::MAX_AUX {
        bail!(
            "at most {} auxiliary channels can be used at once",
            magcomp_core::MAX_AUX
        );
    }
    if n < 3 {
        bail!("the trace has {n} rows; at least 3 are needed");
    }
    let median_dt = first.dt.median().context("no time step")?;
    let withheld = input_checks(first, n, 1.0 / median_dt, warnings)?;
    Ok((withheld, median_dt))
}

/// What passes 1 and 2 settled for one sensor besides its first pass.
struct Settled {
    spec: Option<ModelSpec>,
    withheld: Option<String>,
    median_dt: f64,
    noise_from_scalar: Option<f64>,
    igrf: Option<(DateSource, igrf::GapFill)>,
    core_meta: Vec<(String, String)>,
    tie_point: Option<magcomp_core::compensator::TiePoint>,
    warnings: Vec<String>,
}

/// One sensor's [`Plan`] for the compensation pass.
fn plan_of(
    s: &SensorRun<'_>,
    p1: FirstPassOut,
    settled: Settled,
    est: &EstimatorSettings,
) -> Result<Prepared> {
    let Settled {
        spec,
        withheld,
        median_dt,
        noise_from_scalar,
        igrf,
        core_meta,
        tie_point,
        mut warnings,
    } = settled;
    let coeffs = s.coeffs;
    let noise_nt = match est.noise_nt {
        Some(v) => v,
        None => {
            let sensor = noise_from_scalar.unwrap_or(0.02);
            (sensor * sensor + 0.005f64.powi(2)).sqrt()
        }
    };
    let first = &p1.first;
    let mut assumed_speed_mps = None;
    if let Some(spec) = &spec {
        if spec.field && !(first.has_position || first.has_speed) {
            let given = est.speed_mps.or(coeffs.assumed_speed_mps);
            let (v, warning) = crate::flight::input::assumed_ground_speed(given)?;
            assumed_speed_mps = Some(v);
            warnings.push(warning);
        }
    }
    let (channels, relative) = match &spec {
        Some(s) => (s.channels(), s.relative_channels()),
        None => Default::default(),
    };
    let offsets = channels
        .iter()
        .zip(&first.channel_offsets)
        .map(|(c, o)| {
            if relative.contains(c) {
                o.unwrap_or(0.0)
            } else {
                0.0
            }
        })
        .collect();
    let FirstPassOut {
        cols, head, first, ..
    } = p1;
    let mut plan = Plan {
        tie_point,
        earth_dir_ned: first.field_dir.finish(),
        base0: first.base0,
        cols,
        head,
        rows: first.rows,
        sample_rate_hz: 1.0 / median_dt,
        gap_limit_s: crate::qc::gaps::GAP_FACTOR * median_dt,
        offsets,
        assumed_speed_mps,
        noise_nt,
        igrf,
        fluxgate_calibration: match coeffs.method {
            Method::Kf => coeffs.fluxgate_calibration,
            Method::Tl => None,
        },
    };
    // The file's metadata as `input::prepare` leaves it: where the core field came from.
    plan.head.meta.extend(core_meta);
    Ok(Prepared {
        plan,
        spec,
        warnings,
        withheld,
        position_faults: first.position_faults,
    })
}

/// Figures the in-memory path gives that a streamed run does not compute.
const NOT_COMPUTED_STREAMED: [&str; 6] = [
    "compensated_band_rms_nt",
    "improvement_ratio",
    "fom_nt",
    "fom_table",
    "oracle_floor_nt",
    "applied-coefficient checks",
];

/// What pass 1 learns of one sensor: the columns, the file's header, the flight figures,
/// and the dates its date columns give.
struct FirstPassOut {
    cols: Cols,
    head: crate::io::trace::rows::RowsHeader,
    first: FirstPass,
    date_col: DateScan,
    doy_scans: Vec<DateScan>,
}

/// Pass 1: resolves each sensor's columns (`wanted`: its columns and model channels) on
/// the first row, then gathers each one's flight figures ([`FirstPass`]) and scans the
/// date columns over the selected rows.
fn first_pass(
    source: &apply::Source<'_>,
    wanted: &[(&SensorColumns, &[String])],
    quiet: bool,
) -> Result<Vec<FirstPassOut>> {
    let path = source.path;
    let mut cols: Vec<Cols> = Vec::new();
    let mut filter = RowFilter::new(source.sel.clone());
    let mut firsts: Vec<FirstPass> = wanted
        .iter()
        .map(|(_, c)| FirstPass::new(c.len()))
        .collect();
    // One track for every sensor: its tie point is looked for once ([`prepare`]).
    for f in firsts.iter_mut().skip(1) {
        f.finds_tie = false;
    }
    let mut date_col = DateScan::default();
    let mut doy_scans: Vec<DateScan> = Vec::new();
    let mut progress = Progress::new("pass 1/3 (flight figures)", quiet);
    let head = for_each_row(path, source.map, ReadOptions::default(), |row| {
        if cols.is_empty() {
            for (sensor, channels) in wanted {
                cols.push(Cols::resolve_sensor(row.names, channels, sensor)?);
            }
            doy_scans = vec![DateScan::default(); cols[0].year_doy.len()];
        }
        let c0 = &cols[0];
        if !filter.keep(row, c0)? {
            return Ok(());
        }
        progress.tick();
        let k = firsts[0].rows;
        for (c, first) in cols.iter().zip(&mut firsts) {
            let mut rs = row_sample(row, c, None, &[]);
            first.push(&mut rs);
        }
        // The date columns are the same for every sensor: scanned once.
        if let Some(d) = c0.date {
            scan_year(&mut date_col, stats::year_of_date(row.text(d), k));
        }
        for ((y, d, names), scan) in c0.year_doy.iter().zip(&mut doy_scans) {
            scan_year(scan, stats::year_of_doy(row.num(*y), row.num(*d), names, k));
        }
        Ok(())
    })
    .with_context(|| format!("reading {}", path.display()))?;
    progress.done();
    if cols.is_empty() {
        bail!("{}: no data rows", path.display());
    }
    filter.finish(&head, &cols[0])?;
    let mut out = Vec::new();
    for ((mut c, first), (_, channels)) in cols.into_iter().zip(firsts).zip(wanted) {
        c.check_kinds(&head, channels)?;
        out.push(FirstPassOut {
            cols: c,
            head: head.clone(),
            first,
            date_col: date_col.clone(),
            doy_scans: doy_scans.clone(),
        });
    }
    Ok(out)
}

/// The core field, as `input::prepare` decides it: the file's `igrf`, else computed for
/// `--date`, else for the file's date or year/day columns, else missing.
fn choose_core(p1: &FirstPassOut, given_year: Option<f64>) -> Result<Core> {
    let cols = &p1.cols;
    if cols.igrf.is_some() {
        return Ok(Core::FromFile);
    }
    if cols.lat.is_none() || cols.lon.is_none() || cols.alt.is_none() {
        return Ok(Core::NoPosition);
    }
    if let Some(y) = given_year {
        return Ok(Core::Computed(DateSource::Given(y), "--date".into()));
    }
    if let Some(d) = cols.date {
        if let Some(e) = &p1.date_col.error {
            bail!("{e}");
        }
        if p1.date_col.any {
            return Ok(Core::Computed(DateSource::Column(d), "column date".into()));
        }
    }
    for ((y, d, names), scan) in cols.year_doy.iter().zip(&p1.doy_scans) {
        if let Some(e) = &scan.error {
            bail!("{e}");
        }
        if scan.any {
            return Ok(Core::Computed(
                DateSource::YearDoy(*y, *d, names.clone()),
                format!("columns {names}"),
            ));
        }
    }
    Ok(Core::Missing)
}

/// Pass 2 (only when needed): each sensor's scalar noise (KF without --noise-nt, as
/// `need_noise` says) and the core field's gaps and range (the same for every sensor).
fn second_pass(
    source: &apply::Source<'_>,
    cols: &[&Cols],
    core: &Core,
    need_noise: &[bool],
    median_dt: f64,
    quiet: bool,
) -> Result<(Vec<SecondPass>, igrf::IgrfScan)> {
    let need_igrf = matches!(core, Core::Computed(..) | Core::Missing);
    let mut seconds: Vec<SecondPass> = cols
        .iter()
        .map(|_| SecondPass::new(1.0 / median_dt, median_dt))
        .collect();
    let mut igrf_scan = igrf::IgrfScan::new(matches!(core, Core::Computed(..)));
    if need_noise.iter().any(|&n| n) || need_igrf {
        let c0 = cols.first().context("internal: no sensor")?;
        let mut filter = RowFilter::new(source.sel.clone());
        let mut progress = Progress::new("pass 2/3 (noise, core field)", quiet);
        let mut k = 0usize;
        let date = match core {
            Core::Computed(s, _) => Some(s.clone()),
            _ => None,
        };
        for_each_row(source.path, source.map, ReadOptions::default(), |row| {
            if !filter.keep(row, c0)? {
                return Ok(());
            }
            progress.tick();
            for ((c, second), _) in cols
                .iter()
                .zip(&mut seconds)
                .zip(need_noise)
                .filter(|(_, &n)| n)
            {
                let flux = c.flux.map(|i| row.num(i));
                second.push(k, row.line, row.num(c.t), row.num(c.mag), flux);
            }
            if need_igrf {
                let year = match &date {
                    Some(s) => igrf::row_year(s, row, k)?,
                    None => 2025.0,
                };
                igrf_scan.push(k, year, c0, row)?;
            }
            k += 1;
            Ok(())
        })
        .with_context(|| format!("reading {}", source.path.display()))?;
        for second in &mut seconds {
            second.finish();
        }
        igrf_scan.finish()?;
        progress.done();
    }
    Ok((seconds, igrf_scan))
}

/// What the compensation pass computes the core field from (`None`: the file's, or none),
/// with the note `input::prepare` prints.
fn core_field(core: &Core, igrf_scan: &igrf::IgrfScan) -> Option<(DateSource, igrf::GapFill)> {
    match core {
        Core::Computed(source, label) => {
            let (y0, y1) = igrf_scan.years;
            crate::errln!(
                "{}",
                crate::flight::input::CoreField::Computed {
                    model: crate::flight::igrf::MODEL_NAME.into(),
                    epochs: (y0, y1),
                    date_source: label.clone(),
                }
                .message()
                .unwrap_or_default()
            );
            Some((source.clone(), igrf_scan.fill.clone()))
        }
        Core::Missing => {
            let (lo, hi) = igrf_scan.range_nt;
            let change_nt = (hi >= lo).then_some(hi - lo);
            if let Some(m) = (crate::flight::input::CoreField::Missing { change_nt }).message() {
                crate::errln!("{m}");
            }
            None
        }
        Core::NoPosition | Core::FromFile => None,
    }
}

/// The metadata `input::prepare` adds to the trace: where the core field came from.
fn core_meta(core: &Core, igrf_scan: &igrf::IgrfScan) -> Vec<(String, String)> {
    use crate::flight::input::{META_CORE_FIELD, META_CORE_FIELD_EPOCH};
    match core {
        Core::FromFile => vec![(META_CORE_FIELD.into(), "igrf column of the file".into())],
        Core::Computed(_, label) => vec![
            (
                META_CORE_FIELD.into(),
                format!("{} ({label})", crate::flight::igrf::MODEL_NAME),
            ),
            (
                META_CORE_FIELD_EPOCH.into(),
                format!("{:.3}", igrf_scan.years.0),
            ),
        ],
        Core::Missing | Core::NoPosition => Vec::new(),
    }
}

fn scan_year(scan: &mut DateScan, year: Result<f64>) {
    match year {
        Ok(y) => scan.any |= y.is_finite(),
        Err(e) => {
            if scan.error.is_none() {
                scan.error = Some(format!("{e:#}"));
            }
        }
    }
}

/// `qc::inputs::check` for a flight applied coefficients (not calibrating): the same
/// errors and warnings; returns why figures are withheld.
fn input_checks(
    first: &FirstPass,
    n: usize,
    sample_rate_hz: f64,
    warnings: &mut Vec<String>,
) -> Result<Option<String>> {
    use crate::qc::inputs::{MIN_DURATION_S, MIN_SAMPLES};
    if first.mag_finite == 0 {
        bail!(
            "the scalar column `mag` has no value on any of the {n} rows (all missing or NaN): nothing to compensate"
        );
    }
    if first.mag_range.1 - first.mag_range.0 == 0.0 && first.mag_finite > 1 {
        bail!(
            "the scalar column `mag` is constant ({} nT on all {} finite rows): a stuck or placeholder magnetometer cannot be compensated",
            first.first_mag.unwrap_or(f64::NAN),
            first.mag_finite
        );
    }
    if first.flux_field_rows == 0 {
        bail!(
            "the fluxgate (flux_x, flux_y, flux_z) reads less than 1000 nT or nothing on every row (all zero or missing): the direction of the field is unknown, nothing can be compensated"
        );
    }
    if first.flux_field_rows < n / 2 {
        warnings.push(format!(
            "the fluxgate reads less than 1000 nT or nothing on {} of {n} rows",
            n - first.flux_field_rows
        ));
    }
    let flux_constant = first
        .flux_range
        .iter()
        .all(|(lo, hi)| lo <= hi && hi - lo == 0.0);
    let duration_s = n as f64 / sample_rate_hz;
    let short = duration_s < MIN_DURATION_S || n < MIN_SAMPLES;
    Ok(if flux_constant {
        Some("the fluxgate reads the same vector on every row".into())
    } else if short {
        Some(format!(
            "the flight is only {duration_s:.1} s / {n} samples long (less than {MIN_DURATION_S} s or {MIN_SAMPLES} samples)"
        ))
    } else {
        None
    })
}
