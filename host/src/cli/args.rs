//! Arguments shared by several subcommands: the trace to read, the estimator settings,
//! and `--coeffs` (a `calibrate` file that decides the method and the model).

use crate::calibration::coefficients::{
    read_coefficients, refuse_conflicting_settings, CoefficientFile, Method,
};
use crate::calibration::provenance::Provenance;
use crate::calibration::result::Compensation;
use crate::calibration::summary::{summarise, Summary};
use crate::calibration::{compensate_trace, EstimatorSettings};
use crate::flight::input::Decimation;
use crate::flight::Flight;
use crate::io::trace::{progress_bar, read_trace_with, ColumnMap, ReadOptions, Trace};
use crate::stream::decimate;
use anyhow::{Context, Result};
use clap::builder::PossibleValue;
use std::path::{Path, PathBuf};

impl clap::ValueEnum for Method {
    fn value_variants<'a>() -> &'a [Self] {
        &[Method::Kf, Method::Tl]
    }
    fn to_possible_value(&self) -> Option<PossibleValue> {
        Some(PossibleValue::new(self.name()).help(match self {
            Method::Kf => {
                "the paper's Kalman filter: deviation coefficients and the anomaly together"
            }
            Method::Tl => {
                "classic Tolles–Lawson: band-passed least squares (MagNav.jl conventions)"
            }
        }))
    }
}

/// Options shared by every command that reads a trace.
#[derive(clap::Args, Clone, Debug)]
pub struct TraceInput {
    /// Flight trace: CSV per docs/trace-format.md, whitespace XYZ survey data (`/` comments,
    /// `*` missing), or a MagNav.jl HDF5 file (`.h5`: one dataset per channel).
    pub trace: PathBuf,
    /// Column names of your file, e.g.
    /// `t=TIME,mag=UNCOMPMAG4,flux_x=FLUXB_X,flux_y=FLUXB_Y,flux_z=FLUXB_Z,lat=LAT,lon=LONG,alt=UTM-Z`
    /// (SGL survey XYZ names; docs/trace-format.md lists the canonical ones). Presets:
    /// `magnav` (MagNav HDF5 names), `sgl` (SGL XYZ names), overridable:
    /// `--map magnav,mag=mag_4_uc`.
    #[arg(long, value_name = "CANONICAL=FILE,...")]
    pub map: Option<String>,
    /// Only these lines, by the `line` column (SGL's `LINE`), e.g. `1002.02,1003.01`.
    #[arg(long, value_name = "LINE,...")]
    pub lines: Option<String>,
    /// Only rows with T0 ≤ t ≤ T1 (seconds, the `t` column; `T0:` or `:T1` leave a side open).
    #[arg(long, value_name = "T0:T1", allow_hyphen_values = true)]
    pub time: Option<String>,
    /// Survey date for the core field (IGRF-14) when the file has no `igrf` column and no
    /// `date` or YEAR/DOY columns.
    #[arg(long, value_name = "YYYY-MM-DD")]
    pub date: Option<String>,
    /// Sample rate (Hz) of a trace without a time column: its rows are then taken as
    /// evenly spaced, `t` = row / rate from 0 (docs/trace-format.md). Refused when the
    /// trace has its own `t`.
    #[arg(long, value_name = "HZ")]
    pub rate_hz: Option<f64>,
}

impl TraceInput {
    pub fn read(&self) -> Result<Trace> {
        let map = match &self.map {
            Some(m) => ColumnMap::parse(m)?,
            None => ColumnMap::new(),
        };
        let bar = progress_bar(0);
        // The bar draws on a terminal only; with --progress into a log, a line every 5 s.
        let lines = {
            use std::io::IsTerminal;
            !std::io::stderr().is_terminal() && !crate::io::progress::quiet_progress(false)
        };
        let start = std::time::Instant::now();
        let mut last = start;
        let mut cb = |done: u64, total: u64| {
            bar.set_length(total);
            bar.set_position(done);
            if lines && last.elapsed().as_secs_f64() >= 5.0 {
                last = std::time::Instant::now();
                let mib = |b: u64| b as f64 / (1u64 << 20) as f64;
                crate::errln!(
                    "reading {}: {:.0} of {:.0} MiB, {:.0} MiB/s",
                    self.trace.display(),
                    mib(done),
                    mib(total),
                    mib(done) / start.elapsed().as_secs_f64()
                );
            }
        };
        let opts = ReadOptions {
            progress: Some(&mut cb),
            ..Default::default()
        };
        let mut t = read_trace_with(&self.trace, &map, opts)
            .with_context(|| format!("reading {}", self.trace.display()))?;
        bar.finish_and_clear();
        if let Some(rate) = self.rate_hz {
            add_time_column(&mut t, rate)
                .with_context(|| format!("reading {}", self.trace.display()))?;
        }
        let sel =
            crate::flight::input::Selection::parse(self.lines.as_deref(), self.time.as_deref())?;
        let (t, core) = crate::flight::input::prepare(t, &sel, self.date.as_deref())
            .with_context(|| format!("preparing {}", self.trace.display()))?;
        if let Some(m) = core.message() {
            crate::errln!("{m}");
        }
        Ok(t)
    }

    /// The file column read as the scalar (`mag`, or the one `--map` names for it): the
    /// sensor, and with it the installation, coefficients belong to.
    pub fn sensor(&self) -> String {
        self.map
            .as_deref()
            .and_then(|m| ColumnMap::parse(m).ok())
            .and_then(|m| m.file_column("mag").map(String::from))
            .unwrap_or_else(|| "mag".into())
    }

    /// `YYYY-MM-DD` of the flight (its first dated row, or `--date`), when known.
    pub fn flight_date(&self, trace: Option<&Trace>) -> Option<String> {
        let Some(trace) = trace else {
            return self.date.clone();
        };
        let (years, _) = crate::flight::input::row_years(trace, self.date.as_deref())
            .ok()
            .flatten()?;
        let y = years.into_iter().find(|y| y.is_finite())?;
        crate::calibration::provenance::date_of_decimal_year(y)
    }

    /// What a coefficient file calibrated on `trace` (read from this input) records of it.
    pub fn provenance(&self, trace: &Trace, model: &str) -> Result<Provenance> {
        let t = trace.col("t").unwrap_or(&[]);
        Ok(Provenance {
            source_file: self.trace.display().to_string(),
            source_sha256: crate::calibration::provenance::sha256_file(&self.trace)?,
            column_map: self.map.clone(),
            sensor: self.sensor(),
            lines: self.lines.clone(),
            time_window: self.time.clone(),
            t_first_s: t.first().copied().unwrap_or(f64::NAN),
            t_last_s: t.last().copied().unwrap_or(f64::NAN),
            flight_date: self.flight_date(Some(trace)),
            model: model.to_string(),
            magcomp_version: crate::calibration::provenance::magcomp_version(),
            fluxgate: None,
        })
    }

    /// The warnings for applying `coeffs` to this input (`trace`: when read; a streamed
    /// run knows the date from `--date` only). None for a file without provenance.
    pub fn provenance_warnings(
        &self,
        trace: Option<&Trace>,
        coeffs: &CoefficientFile,
    ) -> Vec<String> {
        let mut out = match &coeffs.provenance {
            Some(p) => crate::calibration::provenance::warnings(
                p,
                &self.sensor(),
                self.flight_date(trace).as_deref(),
            ),
            None => Vec::new(),
        };
        if coeffs.unsealed {
            out.push(format!(
                "the coefficient file has {}",
                crate::calibration::coefficients::UNSEALED_NOTE
            ));
        }
        out
    }

    /// The trace for a calibration or a diagnosis: a long flight sampled faster than
    /// 100 Hz is read into an anti-aliased decimated copy (`stream::decimate`), anything
    /// else as [`TraceInput::read`] reads it. The decimation, when made, is returned (and
    /// said on stderr).
    pub fn read_for_calibration(
        &self,
        long: &LongFlightArgs,
    ) -> Result<(Trace, Option<Decimation>)> {
        let size = std::fs::metadata(&self.trace).map(|m| m.len()).unwrap_or(0);
        // No trace row is shorter than 10 bytes (t, mag and three fluxgate values): a
        // smaller file cannot hold that many rows, and is read without a counting pass.
        let may_be_long = (size / 10) as usize > long.decimate_above_rows;
        // A trace without time (`--rate-hz`) is read whole: the streaming readers need `t`.
        if long.full_rate
            || !may_be_long
            || crate::io::trace::is_hdf5_path(&self.trace)
            || self.rate_hz.is_some()
        {
            return Ok((self.read()?, None));
        }
        let input = self.stream_input();
        let quiet = crate::io::progress::quiet_progress(long.progress);
        let (rows, dt, kinds) = decimate::scan(&input, quiet)?;
        let Some(factor) = decimate::factor_for(rows, 1.0 / dt, long.decimate_above_rows) else {
            return Ok((self.read()?, None));
        };
        let (t, d) = decimate::read_decimated(&input, factor, (rows, dt, &kinds), quiet)?;
        let (t, core) = crate::flight::input::prepare(
            t,
            &crate::flight::input::Selection::default(),
            self.date.as_deref(),
        )
        .with_context(|| format!("preparing {}", self.trace.display()))?;
        if let Some(m) = core.message() {
            crate::errln!("{m}");
        }
        crate::errln!("note: {}", d.message());
        Ok((t, Some(d)))
    }

    /// The same input for the streaming readers.
    pub fn stream_input(&self) -> crate::stream::StreamInput<'_> {
        crate::stream::StreamInput {
            trace: &self.trace,
            map: self.map.as_deref(),
            lines: self.lines.as_deref(),
            time: self.time.as_deref(),
            date: self.date.as_deref(),
        }
    }

    /// Just the file, for code that builds one by hand.
    pub fn new(trace: impl Into<PathBuf>) -> Self {
        TraceInput {
            trace: trace.into(),
            map: None,
            lines: None,
            time: None,
            date: None,
            rate_hz: None,
        }
    }
}

/// Gives a trace without a time column `t` = row / `rate_hz` (`--rate-hz`), so a
/// positionless, timeless export needs no awk to be read.
fn add_time_column(t: &mut Trace, rate_hz: f64) -> Result<()> {
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        anyhow::bail!("--rate-hz must be a positive number of samples per second, not {rate_hz}");
    }
    if t.col("t").is_some() {
        anyhow::bail!(
            "--rate-hz is for a trace without a time column, and this one has `t`: leave --rate-hz out"
        );
    }
    let n = t.len();
    t.set_col("t", (0..n).map(|i| i as f64 / rate_hz).collect());
    Ok(())
}

/// How `calibrate`, post-flight `compensate` and `diagnose` keep a long flight's memory
/// bounded (docs/streaming.md).
#[derive(clap::Args, Clone, Debug)]
pub struct LongFlightArgs {
    /// Calibrate (or diagnose) on an anti-aliased copy decimated to at most 100 Hz when
    /// the flight has more rows than this and is sampled faster than 100 Hz; `compensate`
    /// then applies the coefficients at the full rate, streamed (docs/streaming.md).
    #[arg(long, value_name = "ROWS", default_value_t = decimate::DECIMATE_ABOVE_ROWS)]
    pub decimate_above_rows: usize,
    /// Never decimate: the whole flight at its own rate, in memory (~1.2 KB per row for
    /// calibrate, ~2.4 KB for diagnose).
    #[arg(long)]
    pub full_rate: bool,
    /// Progress lines (stage, rows, rows/s) on stderr even when it is not a terminal.
    #[arg(long)]
    pub progress: bool,
}

impl Default for LongFlightArgs {
    fn default() -> Self {
        Self {
            decimate_above_rows: decimate::DECIMATE_ABOVE_ROWS,
            full_rate: false,
            progress: false,
        }
    }
}

/// Estimator settings shared by calibrate, compensate, report and diagnose.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct EstimatorArgs {
    /// Model: `+`-joined terms, e.g. `tl16+field` (the paper's), `tl16+field+current:cur_pump`.
    /// Terms: tl16 (= permanent+induced+eddy), field, current:CH, current_rate:CH, lag, rate,
    /// diurnal[:base], induced_high, fluxcal, fluxtemp:CH, periodic:CH.
    /// Default: `tl16+field+fluxcal` (the paper's, with the fluxgate calibrated against the
    /// scalar first); where a coefficient file is applied, the file's.
    #[arg(long, value_name = "SPEC")]
    pub model: Option<String>,
    /// kf: the paper's Kalman filter; tl: classic Tolles–Lawson (18 terms, band-passed).
    /// Default: kf; where a coefficient file is applied, the file's.
    #[arg(long, value_enum)]
    pub method: Option<Method>,
    #[command(flatten)]
    pub tuning: TuningArgs,
}

/// The estimator's tuning, shared by every command that estimates (`report` has its own
/// `--model`, given several times to compare models).
#[derive(clap::Args, Clone, Debug)]
pub struct TuningArgs {
    /// Field-model roughness σ1 (nT/m^2.5), the same along the whole track (the paper's
    /// stationary anomaly). Default: fitted to the along-track spectrum, and, post-flight,
    /// the anomaly process whose σ1 follows the local roughness of the anomaly (or the
    /// stationary one) that makes the data most likely (reported as `field_process`).
    #[arg(long, value_name = "NT_PER_M2_5")]
    pub sigma1: Option<f64>,
    /// Scalar measurement noise 1σ (nT); default: estimated from the data.
    #[arg(long, value_name = "NT")]
    pub noise_nt: Option<f64>,
    /// Tolles–Lawson terms for --method tl: tl18 (MagNav), tl16, or groups like permanent+induced.
    #[arg(long, default_value = "tl18", value_name = "TERMS")]
    pub tl_terms: String,
    /// Ridge parameter λ of --method tl (default MagNav's 0.001); 0 gives plain
    /// band-passed least squares (TL18-OLS, the yardstick of the Kalman filter).
    #[arg(long, value_name = "LAMBDA", allow_negative_numbers = true)]
    pub tl_ridge: Option<f64>,
    /// Assumed ground speed (m/s) for a trace without positions (no lat/lon): the Kalman
    /// filter then models the anomaly in time, as if flown at this speed (docs/trace-format.md).
    /// Ignored when the trace has positions or a ground speed of its own.
    #[arg(long, value_name = "M_PER_S")]
    pub speed_mps: Option<f64>,
}

impl Default for TuningArgs {
    /// As the command line's defaults.
    fn default() -> Self {
        Self {
            sigma1: None,
            noise_nt: None,
            tl_terms: EstimatorSettings::default().tl_terms,
            tl_ridge: None,
            speed_mps: None,
        }
    }
}

/// One compensation of a flight as `report`/`diagnose --coeffs|--method` evaluate it.
pub struct Evaluated {
    pub flight: Flight,
    pub comp: Compensation,
    pub summary: Summary,
    /// Where the coefficients came from, for the reader.
    pub source: String,
    /// The `--coeffs` file's provenance (None when fitted on this flight, or for a file
    /// written before provenance was recorded).
    pub coefficient_provenance: Option<Provenance>,
    /// The coefficient file's ground speed for a trace without positions (`--speed-mps`
    /// it was calibrated with), for the diagnosis that follows.
    pub assumed_speed_mps: Option<f64>,
}

impl EstimatorArgs {
    /// Compensates `trace` as `compensate` would (post-flight): with the coefficient file
    /// when given (its plausibility checked, `calibration::applied`), else calibrating on the trace.
    pub fn evaluate(&self, trace: &Trace, coeffs: Option<&Path>) -> Result<Evaluated> {
        let file = self.coefficients(coeffs)?;
        let (flight, comp) = compensate_trace(trace, &self.settings(), file.as_ref(), false)?;
        let summary = summarise(&flight, &comp);
        let source = match coeffs {
            Some(p) => format!("coefficients from {}", p.display()),
            None => "calibrated on this flight".into(),
        };
        Ok(Evaluated {
            flight,
            comp,
            summary,
            source,
            coefficient_provenance: file.as_ref().and_then(|f| f.provenance.clone()),
            assumed_speed_mps: file.as_ref().and_then(|f| f.assumed_speed_mps),
        })
    }

    /// The settings, defaults filled in.
    pub fn settings(&self) -> EstimatorSettings {
        let d = EstimatorSettings::default();
        EstimatorSettings {
            model: self.model.clone().unwrap_or(d.model),
            method: self.method.unwrap_or(d.method),
            sigma1: self.tuning.sigma1,
            noise_nt: self.tuning.noise_nt,
            tl_terms: self.tuning.tl_terms.clone(),
            tl_ridge: self.tuning.tl_ridge,
            speed_mps: self.tuning.speed_mps,
            // The default method is checked against TL18-OLS; a method asked for by name
            // is used as asked.
            cross_check: self.method.is_none(),
            survey_from_s: None,
            live_witness: true,
        }
    }

    /// Reads `--coeffs` when given, refusing a `--method`/`--model` that contradicts it
    /// (the file decides both).
    pub fn coefficients(&self, coeffs: Option<&Path>) -> Result<Option<CoefficientFile>> {
        let Some(path) = coeffs else {
            return Ok(None);
        };
        let c = read_coefficients(path)?;
        refuse_conflicting_settings(&c, self.method, self.model.as_deref())?;
        Ok(Some(c))
    }
}

/// The trace a diagnosis reads (it builds its own flights from it). Without a track
/// (position or ground speed) and with `speed_mps`, it gets that ground speed as its
/// `ground_speed` column, and (`warn`) the user is told so on stderr; without either, a
/// model with the anomaly process (`field`) is refused as the compensation refuses it: the
/// filter would hold the anomaly in place and call its changes interference.
pub fn diagnosis_trace(
    trace: Trace,
    speed_mps: Option<f64>,
    field: bool,
    warn: bool,
) -> Result<Trace> {
    let Some(v) = speed_mps else {
        if field && !Flight::from_trace(&trace, &[], &[])?.has_track() {
            anyhow::bail!(
                "the trace has no position (lat/lon) and no ground speed: the Kalman filter's anomaly model needs the along-track distance. Give the aircraft's ground speed with --speed-mps (e.g. --speed-mps 60) to model the anomaly in time"
            );
        }
        return Ok(trace);
    };
    let (out, added) = crate::flight::with_assumed_ground_speed(&trace, v)?;
    if added && warn {
        crate::errln!(
            "warning: the trace has no position: the anomaly is modelled in time, at the assumed ground speed of {v} m/s (--speed-mps)"
        );
    }
    Ok(out)
}
