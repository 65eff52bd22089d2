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
//! streamed run says so.
mod apply;
pub mod decimate;
pub mod rows;
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
        return None;
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
    pub igrf: Option<(DateSource, apply::GapFill)>,
    /// The coefficient file's fluxgate calibration, applied to every fluxgate vector before
    /// the compensator (as `kf::run_kf_estimator` does in memory).
    pub fluxgate_calibration: Option<crate::estimate::fluxcal::FluxgateCalibration>,
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
    let map = match input.map {
        Some(m) => ColumnMap::parse(m)?,
        None => ColumnMap::new(),
    };
    let sel = Selection::parse(input.lines, input.time)?;
    let spec = match coeffs.method {
        Method::Kf => Some(ModelSpec::parse(&coeffs.model)?),
        Method::Tl => None,
    };
    let channels = spec.as_ref().map(|s| s.channels()).unwrap_or_default();
    let relative = spec
        .as_ref()
        .map(|s| s.relative_channels())
        .unwrap_or_default();
    let path = input.trace;
    let source = apply::Source {
        path,
        map: &map,
        sel: &sel,
    };
    let mut warnings = Vec::new();

    let given_year = match input.date {
        Some(d) => {
            let (y, doy) = crate::flight::igrf::parse_date(d).context("--date")?;
            Some(crate::flight::igrf::decimal_year(y, doy, 0.0))
        }
        None => None,
    };
    let p1 = first_pass(&source, &channels, quiet)?;
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
    let sample_rate_hz = 1.0 / median_dt;
    let withheld = input_checks(first, n, sample_rate_hz, &mut warnings)?;
    let core = choose_core(&p1, given_year)?;

    let need_noise = spec.is_some() && est.noise_nt.is_none();
    let (second, igrf_scan) = second_pass(&source, &p1.cols, &core, need_noise, median_dt, quiet)?;
    let noise_nt = match est.noise_nt {
        Some(v) => v,
        None => {
            let sensor = second.noise_nt().unwrap_or(0.02);
            (sensor * sensor + 0.005f64.powi(2)).sqrt()
        }
    };
    let igrf = core_field(&core, &igrf_scan);

    let mut assumed_speed_mps = None;
    if let Some(spec) = &spec {
        if spec.field && !(first.has_position || first.has_speed) {
            let given = est.speed_mps.or(coeffs.assumed_speed_mps);
            let (v, warning) = crate::flight::input::assumed_ground_speed(given)?;
            assumed_speed_mps = Some(v);
            warnings.push(warning);
        }
    }
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
    let plan = Plan {
        tie_point: first.tie_point(&head.meta),
        earth_dir_ned: first.field_dir.finish(),
        base0: first.base0,
        cols,
        head,
        rows: n,
        sample_rate_hz,
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
    let result = apply::run(&source, &plan, est, coeffs, spec.as_ref(), out, quiet)?;
    if let Some(w) = stats::glitch_warning(path, &result.glitches) {
        crate::flight::position::warn_once(&w);
    }
    if let Some(w) = stats::flux_glitch_warning(path, &result.flux_glitches) {
        crate::flight::position::warn_once(&w);
    }
    if let Some(w) = stats::faults_warning(path, &first.position_faults) {
        crate::flight::position::warn_once(&w);
    }
    if let Some(w) = result.gaps_warning() {
        warnings.push(w);
    }
    warnings.extend(withheld.iter().map(|why| {
        format!("{why}: improvement ratio, FOM and predicted error are withheld (null)")
    }));
    Ok(StreamSummary {
        model: result.model,
        method: coeffs.method,
        samples: n,
        streamed: true,
        error_rms_nt: result.error_rms_nt,
        predicted_error_nt: result.predicted_error_nt.filter(|_| withheld.is_none()),
        sample_rate_hz,
        noise_nt: spec.as_ref().map(|_| noise_nt),
        not_computed: NOT_COMPUTED_STREAMED.map(String::from).to_vec(),
        warnings,
        decimated: None,
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

/// What pass 1 learns: the columns, the file's header, the flight figures, and the dates
/// its date columns give.
struct FirstPassOut {
    cols: Cols,
    head: crate::io::trace::rows::RowsHeader,
    first: FirstPass,
    date_col: DateScan,
    doy_scans: Vec<DateScan>,
}

/// Pass 1: resolves the columns on the first row, then gathers the flight figures
/// ([`FirstPass`]) and scans the date columns over the selected rows.
fn first_pass(
    source: &apply::Source<'_>,
    channels: &[String],
    quiet: bool,
) -> Result<FirstPassOut> {
    let path = source.path;
    let mut cols: Option<Cols> = None;
    let mut filter = RowFilter::new(source.sel.clone());
    let mut first = FirstPass::new(channels.len());
    let mut date_col = DateScan::default();
    let mut doy_scans: Vec<DateScan> = Vec::new();
    let mut progress = Progress::new("pass 1/3 (flight figures)", quiet);
    let head = for_each_row(path, source.map, ReadOptions::default(), |row| {
        let c = match &mut cols {
            Some(c) => c,
            None => {
                let c = Cols::resolve(row.names, channels)?;
                doy_scans = vec![DateScan::default(); c.year_doy.len()];
                cols.insert(c)
            }
        };
        if !filter.keep(row, c)? {
            return Ok(());
        }
        progress.tick();
        let k = first.rows;
        let mut rs = row_sample(row, c, None, &[]);
        first.push(&mut rs);
        if let Some(d) = c.date {
            scan_year(&mut date_col, stats::year_of_date(row.text(d), k));
        }
        for ((y, d, names), scan) in c.year_doy.iter().zip(&mut doy_scans) {
            scan_year(scan, stats::year_of_doy(row.num(*y), row.num(*d), names, k));
        }
        Ok(())
    })
    .with_context(|| format!("reading {}", path.display()))?;
    progress.done();
    let mut cols = cols.with_context(|| format!("{}: no data rows", path.display()))?;
    filter.finish(&head, &cols)?;
    cols.check_kinds(&head, channels)?;
    Ok(FirstPassOut {
        cols,
        head,
        first,
        date_col,
        doy_scans,
    })
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

/// Pass 2 (only when needed): the scalar's noise (KF without --noise-nt) and the core
/// field's gaps and range.
fn second_pass(
    source: &apply::Source<'_>,
    cols: &Cols,
    core: &Core,
    need_noise: bool,
    median_dt: f64,
    quiet: bool,
) -> Result<(SecondPass, apply::IgrfScan)> {
    let need_igrf = matches!(core, Core::Computed(..) | Core::Missing);
    let mut second = SecondPass::new(1.0 / median_dt, median_dt);
    let mut igrf_scan = apply::IgrfScan::default();
    if need_noise || need_igrf {
        let mut filter = RowFilter::new(source.sel.clone());
        let mut progress = Progress::new("pass 2/3 (noise, core field)", quiet);
        let mut k = 0usize;
        let date = match core {
            Core::Computed(s, _) => Some(s.clone()),
            _ => None,
        };
        for_each_row(source.path, source.map, ReadOptions::default(), |row| {
            if !filter.keep(row, cols)? {
                return Ok(());
            }
            progress.tick();
            if need_noise {
                let flux = cols.flux.map(|i| row.num(i) as f32);
                second.push(k, row.line, row.num(cols.t), row.num(cols.mag), flux);
            }
            if need_igrf {
                let year = match &date {
                    Some(s) => apply::row_year(s, row, k)?,
                    None => 2025.0,
                };
                igrf_scan.push(k, year, cols, row)?;
            }
            k += 1;
            Ok(())
        })
        .with_context(|| format!("reading {}", source.path.display()))?;
        second.finish();
        progress.done();
    }
    Ok((second, igrf_scan))
}

/// What the compensation pass computes the core field from (`None`: the file's, or none),
/// with the note `input::prepare` prints.
fn core_field(core: &Core, igrf_scan: &apply::IgrfScan) -> Option<(DateSource, apply::GapFill)> {
    match core {
        Core::Computed(source, label) => {
            let (y0, y1) = igrf_scan.years;
            eprintln!(
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
                eprintln!("{m}");
            }
            None
        }
        Core::NoPosition | Core::FromFile => None,
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
