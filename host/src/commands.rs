//! The `magcomp` subcommands that calibrate and compensate, as library functions.

use crate::flight::Flight;
use crate::metrics::{
    error_rms_nt, fom, improvement_ratio, manoeuvre_band, oracle_floor_nt, ManoeuvreFom,
};
use crate::model_spec::{ModelSpec, DEFAULT_MODEL};
use crate::pipeline::{run_kf, KfOptions};
use crate::tl;
use crate::trace::{progress_bar, read_trace_with, ColumnMap, ReadOptions, Trace};
use anyhow::{bail, ensure, Context, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Estimation method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// The Kalman filter of the paper: deviation coefficients and the anomaly together.
    Kf,
    /// Classic Tolles–Lawson: band-passed least squares (MagNav.jl conventions).
    Tl,
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
}

impl TraceInput {
    pub fn read(&self) -> Result<Trace> {
        let map = match &self.map {
            Some(m) => ColumnMap::parse(m)?,
            None => ColumnMap::new(),
        };
        let bar = progress_bar(0);
        let mut cb = |done: u64, total: u64| {
            bar.set_length(total);
            bar.set_position(done);
        };
        let opts = ReadOptions {
            progress: Some(&mut cb),
            ..Default::default()
        };
        let t = read_trace_with(&self.trace, &map, opts)
            .with_context(|| format!("reading {}", self.trace.display()))?;
        bar.finish_and_clear();
        let sel = crate::input::Selection::parse(self.lines.as_deref(), self.time.as_deref())?;
        let (t, core) = crate::input::prepare(t, &sel, self.date.as_deref())
            .with_context(|| format!("preparing {}", self.trace.display()))?;
        if let Some(m) = core.message() {
            eprintln!("{m}");
        }
        Ok(t)
    }

    /// Just the file, for code that builds one by hand.
    pub fn new(trace: impl Into<PathBuf>) -> Self {
        TraceInput {
            trace: trace.into(),
            map: None,
            lines: None,
            time: None,
            date: None,
        }
    }
}

/// Estimator settings shared by calibrate and compensate.
#[derive(clap::Args, Clone, Debug)]
pub struct EstimatorArgs {
    /// Model: `+`-joined terms, e.g. `tl16+field` (the paper's), `tl16+field+current:cur_pump`.
    /// Terms: tl16 (= permanent+induced+eddy), field, current:CH, current_rate:CH, lag, rate,
    /// diurnal[:base], induced_high, fluxcal, fluxtemp:CH, periodic:CH.
    #[arg(long, default_value = DEFAULT_MODEL, value_name = "SPEC")]
    pub model: String,
    /// kf: the paper's Kalman filter; tl: classic Tolles–Lawson (18 terms, band-passed).
    #[arg(long, value_enum, default_value_t = Method::Kf)]
    pub method: Method,
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

/// The accuracy an aeromagnetic survey asks of compensation (nT rms).
pub const SURVEY_TOLERANCE_NT: f64 = 0.1;

/// One coefficient with its 1σ.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Coefficient {
    pub name: String,
    pub unit: String,
    pub value: f64,
    pub sigma: f64,
}

/// The file `calibrate` writes and `compensate --coeffs` reads.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CoefficientFile {
    pub format: String,
    pub model: String,
    pub method: Method,
    pub sample_rate_hz: f64,
    #[serde(default)]
    pub sigma1: Option<f64>,
    #[serde(default)]
    pub noise_nt: Option<f64>,
    /// KF: signal the model could not follow beyond the scalar's noise on the calibration
    /// flight (nT rms); `compensate --coeffs` counts it in the predicted error.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model_error_nt: Option<f64>,
    #[serde(default)]
    pub tl_config: Option<tl::TlConfig>,
    /// With `fluxcal`: the fluxgate calibration the coefficients were estimated with
    /// (`B = matrix·B_F + bias_nt`, body frame); apply the same on the board.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fluxgate_calibration: Option<crate::fluxgate::FluxgateCalibration>,
    /// With `lag`: the scalar's estimated delay behind the fluxgate/GPS (s) and its 1σ;
    /// `compensate --coeffs` re-aligns the scalar by it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scalar_lag: Option<crate::preprocess::ScalarLag>,
    /// With `fluxtemp:CH`: the fluxgate's temperature coefficients (bias nT/°C, scale 1/°C,
    /// each with its 1σ) and reference temperature; applied before the direction cosines.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fluxgate_temperature: Option<crate::preprocess::FluxgateTemperature>,
    /// The anomaly process the calibration used (KF; see `pipeline::FIELD_PROFILES`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub field_process: Option<String>,
    /// With `rate`: the coefficients fitted to the flight's crossovers (s, in
    /// `crossover::RATE_LABELS` order) with their test; applied by `compensate --coeffs`
    /// when `applied` (the fit was significant).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rate_crossover: Option<RateCrossover>,
    /// KF: how well the calibration flight determined the interference, by the filter's
    /// own covariance (`pipeline::predicted_interference_error_nt`, nT rms).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub predicted_error_nt: Option<f64>,
    /// KF: the coefficients' covariance (rows in the model's coefficient order, as
    /// `calibrate` writes `coefficients`; physical units), so
    /// that `compensate --coeffs` can predict the error on the flight it compensates.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub covariance: Option<Vec<Vec<f64>>>,
    /// KF on a trace without positions: the ground speed assumed for the anomaly process
    /// (m/s), reused by `compensate --coeffs` unless `--speed-mps` is given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub assumed_speed_mps: Option<f64>,
    pub coefficients: Vec<Coefficient>,
}

/// The crossover fit as the coefficient file and the JSON summary carry it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RateCrossover {
    pub labels: Vec<String>,
    #[serde(flatten)]
    pub fit: crate::crossover::RateFit,
    pub applied: bool,
}

pub const COEFF_FORMAT: &str = "magcomp-coefficients-v1";

/// Per-sample result of either method.
#[derive(Clone, Debug, Default)]
pub struct Compensation {
    pub model: String,
    pub method: Option<Method>,
    pub interference_nt: Vec<f64>,
    pub compensated_nt: Vec<f64>,
    pub anomaly_nt: Option<Vec<f64>>,
    pub innovation_nt: Option<Vec<f64>>,
    pub flags: Option<Vec<u16>>,
    pub coefficients: CoefficientFileOpt,
    pub regressors: Vec<Vec<f32>>,
    /// What the user must know about this result (printed on stderr, `warnings` in JSON).
    pub warnings: Vec<String>,
    /// Why the figures that would pretend (IR, FOM, predicted error) are withheld
    /// (`qc::inputs`); None when they stand.
    pub withheld: Option<String>,
}

pub type CoefficientFileOpt = Option<CoefficientFile>;

/// Summary numbers (`compensate --json`).
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub model: String,
    pub method: Method,
    pub samples: usize,
    /// RMS of the compensated signal in the manoeuvre band (0.1–0.9 Hz) over the flight:
    /// what is left where aircraft interference lives.
    pub residual_rms_nt: f64,
    pub improvement_ratio: Option<f64>,
    pub fom_nt: Option<f64>,
    pub error_rms_nt: Option<f64>,
    pub oracle_floor_nt: Option<f64>,
    /// KF: the predicted interference error on this flight from the coefficients'
    /// covariance: the calibration's own, or, with `--coeffs`, that of the file's
    /// coefficients over this flight's attitudes. No truth needed: a figure that is high
    /// says the calibration left part of this flight's interference undetermined.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub predicted_error_nt: Option<f64>,
    /// KF: the anomaly process used ("stationary" or the chosen local-roughness profile).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub field_process: Option<String>,
    /// With `rate`: the crossover fit (and whether it was applied).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rate_crossover: Option<RateCrossover>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub manoeuvres: Vec<ManoeuvreFom>,
    /// The AARC-style FOM table over the labelled or detected manoeuvres (`qc::fom`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fom_table: Option<crate::qc::fom::FomTable>,
    /// KF: the FOM of (compensated − the filter's anomaly estimate): what the aircraft left.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub aircraft_fom_nt: Option<f64>,
    /// What the user must know about this result (also on stderr); empty when none.
    pub warnings: Vec<String>,
}

fn tl_config(flight: &Flight, est: &EstimatorArgs) -> Result<tl::TlConfig> {
    let terms: tl::TlTerms = est.tl_terms.parse()?;
    let mut cfg = tl::TlConfig::for_rate(flight.sample_rate_hz);
    cfg.terms = terms;
    let (lo, hi) = manoeuvre_band(flight.sample_rate_hz);
    cfg.pass_hz = Some((lo, hi));
    if let Some(l) = est.tl_ridge {
        ensure!(
            l.is_finite() && l >= 0.0,
            "--tl-ridge must be a finite λ ≥ 0 (0 = plain least squares), not {l}"
        );
        cfg.lambda = l;
    }
    Ok(cfg)
}

/// Runs the chosen method. `coeffs`: apply these instead of calibrating on the trace;
/// their plausibility on this flight is checked (`qc::applied`) and warned about.
pub fn compensate_trace(
    trace: &Trace,
    est: &EstimatorArgs,
    coeffs: Option<&CoefficientFile>,
    realtime: bool,
) -> Result<(Flight, Compensation)> {
    let (flight, mut comp) = run_method(trace, est, coeffs, realtime)?;
    if let Some(c) = coeffs {
        let w = crate::qc::applied::check(&flight, &comp, c);
        comp.warnings.extend(w);
    }
    Ok((flight, comp))
}

fn run_method(
    trace: &Trace,
    est: &EstimatorArgs,
    coeffs: Option<&CoefficientFile>,
    realtime: bool,
) -> Result<(Flight, Compensation)> {
    let method = coeffs.map(|c| c.method).unwrap_or(est.method);
    let model_text = coeffs.map(|c| c.model.clone()).unwrap_or(est.model.clone());
    match method {
        Method::Kf => {
            let spec = ModelSpec::parse(&model_text)?;
            let mut flight =
                Flight::from_trace(trace, &spec.channels(), &spec.relative_channels())?;
            let qc = crate::qc::inputs::check(&flight, coeffs.is_none())?;
            let mut warnings = qc.warnings.clone();
            let mut assumed_speed_mps = None;
            if spec.field && !flight.has_track() {
                match est.speed_mps.or(coeffs.and_then(|c| c.assumed_speed_mps)) {
                    Some(v) if v.is_finite() && v > 0.0 => {
                        flight.assume_ground_speed(v);
                        assumed_speed_mps = Some(v);
                        warnings.push(format!(
                            "the trace has no position: the anomaly is modelled in time, at the assumed ground speed of {v} m/s (--speed-mps)"
                        ));
                    }
                    Some(v) => bail!("--speed-mps must be a positive speed in m/s, not {v}"),
                    None => bail!(
                        "the trace has no position (lat/lon) and no ground speed: the Kalman filter's anomaly model needs the along-track distance. Give the aircraft's ground speed with --speed-mps (e.g. --speed-mps 60) to model the anomaly in time, or use --method tl"
                    ),
                }
            }
            let mut opts = KfOptions::new(spec.clone());
            opts.sigma1 = est.sigma1.or(coeffs.and_then(|c| c.sigma1));
            opts.noise_nt = est.noise_nt;
            opts.realtime = realtime;
            if let Some(c) = coeffs {
                opts.coefficients = Some(c.coefficients.iter().map(|c| c.value).collect());
                if spec.calibrates_fluxgate() && c.fluxgate_calibration.is_none() {
                    bail!("the model has `fluxcal` but the coefficient file has no fluxgate_calibration");
                }
                opts.fluxgate_calibration = c.fluxgate_calibration;
                if spec.terms.iter().any(|t| t.name == "lag") && c.scalar_lag.is_none() {
                    bail!("the model has `lag` but the coefficient file has no scalar_lag");
                }
                if spec.terms.iter().any(|t| t.name == "fluxtemp")
                    && c.fluxgate_temperature.is_none()
                {
                    bail!("the model has `fluxtemp` but the coefficient file has no fluxgate_temperature");
                }
                opts.preprocessing = Some(crate::preprocess::Preprocessing {
                    scalar_lag: c.scalar_lag,
                    fluxgate_temperature: c.fluxgate_temperature.clone(),
                });
                opts.rate_crossover_coefficients = c
                    .rate_crossover
                    .as_ref()
                    .filter(|r| r.applied)
                    .map(|r| r.fit.coefficients);
                opts.coefficient_covariance = c.covariance.as_ref().map(|rows| rows.concat());
                opts.model_error_nt = c.model_error_nt;
            }
            let mut run = run_kf(&flight, &opts)?;
            warnings.extend(run.warnings.iter().cloned());
            // Samples next to a time gap: their derivatives span it.
            for i in crate::qc::gaps::gap_neighbours(&qc.breaks) {
                if let Some(f) = run.flags.get_mut(i) {
                    *f |= magcomp_core::flags::Flags::DERIVATIVE_DEGRADED;
                }
            }
            if qc.withheld.is_some() {
                run.predicted_error_nt = None;
            }
            let file = CoefficientFile {
                format: COEFF_FORMAT.into(),
                model: spec.text(),
                method: Method::Kf,
                sample_rate_hz: flight.sample_rate_hz,
                sigma1: Some(run.sigma1),
                noise_nt: Some(run.noise_nt),
                model_error_nt: run.model_error_nt,
                tl_config: None,
                fluxgate_calibration: run.fluxgate_calibration,
                scalar_lag: run.preprocessing.as_ref().and_then(|p| p.scalar_lag),
                fluxgate_temperature: run
                    .preprocessing
                    .as_ref()
                    .and_then(|p| p.fluxgate_temperature.clone()),
                field_process: Some(run.field_process.clone()),
                rate_crossover: match (&run.rate_crossover, coeffs) {
                    (Some((fit, applied)), _) => Some(RateCrossover {
                        labels: crate::crossover::RATE_LABELS.map(String::from).to_vec(),
                        fit: fit.clone(),
                        applied: *applied,
                    }),
                    (None, Some(c)) => c.rate_crossover.clone(),
                    (None, None) => None,
                },
                predicted_error_nt: run.predicted_error_nt,
                assumed_speed_mps,
                covariance: {
                    let k = run.coefficients.len();
                    (run.coefficient_covariance.len() == k * k && k > 0).then(|| {
                        run.coefficient_covariance
                            .chunks(k)
                            .map(|row| row.to_vec())
                            .collect()
                    })
                },
                coefficients: run
                    .coefficient_names
                    .iter()
                    .zip(run.coefficients.iter().zip(&run.coefficient_sigmas))
                    .map(|((n, u), (v, s))| Coefficient {
                        name: n.clone(),
                        unit: u.clone(),
                        value: *v,
                        sigma: *s,
                    })
                    .collect(),
            };
            let comp = Compensation {
                model: spec.text(),
                method: Some(Method::Kf),
                interference_nt: run.interference_nt,
                compensated_nt: run.compensated_nt,
                anomaly_nt: Some(run.anomaly_nt),
                innovation_nt: Some(run.innovation_nt),
                flags: Some(run.flags),
                coefficients: Some(file),
                regressors: run.regressors,
                warnings,
                withheld: qc.withheld,
            };
            Ok((flight, comp))
        }
        Method::Tl => {
            let flight = Flight::from_trace(trace, &[], &[])?;
            let qc = crate::qc::inputs::check(&flight, coeffs.is_none())?;
            let flux = crate::fluxgate::flight_flux(&flight);
            // Not across a time gap: the rows beside it are left out, which splits the
            // band-passed fit there.
            let mut select = vec![true; flight.len()];
            for i in crate::qc::gaps::gap_neighbours(&qc.breaks) {
                select[i] = false;
            }
            let fit = match coeffs {
                Some(c) => {
                    let cfg = c
                        .tl_config
                        .clone()
                        .context("the coefficient file has no Tolles–Lawson configuration")?;
                    tl::TlFit {
                        coefficients: c.coefficients.iter().map(|c| c.value).collect(),
                        sigma: c.coefficients.iter().map(|c| c.sigma).collect(),
                        names: c.coefficients.iter().map(|c| c.name.clone()).collect(),
                        config: cfg,
                        rows_used: 0,
                        rows_nonfinite: 0,
                        rows_short_runs: 0,
                        runs_used: 0,
                        residual_std_nt: f64::NAN,
                        cond_normal: f64::NAN,
                        rank: 0,
                        noise_gain: 1.0,
                    }
                }
                None => tl::fit(
                    &flux,
                    &flight.mag_nt,
                    &tl_config(&flight, est)?,
                    Some(&select),
                )?,
            };
            if fit.coefficients.len() != fit.config.terms.columns().len() {
                bail!(
                    "{} Tolles–Lawson coefficients for {} terms",
                    fit.coefficients.len(),
                    fit.config.terms.columns().len()
                );
            }
            // Per stretch between time gaps: no derivative spans a gap.
            let stretches = crate::qc::gaps::stretches(flight.len(), &qc.breaks);
            let interference: Vec<f64> = stretches
                .iter()
                .flat_map(|r| tl::interference(&fit, &flux[r.clone()]))
                .collect();
            let compensated = flight
                .mag_nt
                .iter()
                .zip(&interference)
                .map(|(m, i)| m - i)
                .collect();
            let regressors = stretches
                .iter()
                .flat_map(|r| {
                    let a = tl::design_matrix_scaled(
                        &flux[r.clone()],
                        &fit.config.terms,
                        fit.config.bt_scale_nt,
                        match fit.config.eddy_rate {
                            tl::EddyRate::PerSample => 1.0,
                            tl::EddyRate::PerSecond => fit.config.fs_hz,
                        },
                    );
                    (0..a.nrows())
                        .map(|r| {
                            (0..a.ncols())
                                .map(|c| a[(r, c)] as f32)
                                .collect::<Vec<f32>>()
                        })
                        .collect::<Vec<_>>()
                })
                .collect();
            let file = CoefficientFile {
                format: COEFF_FORMAT.into(),
                model: format!("{:?}", fit.config.terms).to_lowercase(),
                method: Method::Tl,
                sample_rate_hz: flight.sample_rate_hz,
                sigma1: None,
                noise_nt: None,
                model_error_nt: None,
                tl_config: Some(fit.config.clone()),
                fluxgate_calibration: None,
                scalar_lag: None,
                fluxgate_temperature: None,
                field_process: None,
                rate_crossover: None,
                predicted_error_nt: None,
                covariance: None,
                assumed_speed_mps: None,
                coefficients: fit
                    .names
                    .iter()
                    .zip(fit.coefficients.iter().zip(&fit.sigma))
                    .map(|(n, (v, s))| Coefficient {
                        name: n.clone(),
                        unit: "nT".into(),
                        value: *v,
                        sigma: *s,
                    })
                    .collect(),
            };
            let comp = Compensation {
                model: file.model.clone(),
                method: Some(Method::Tl),
                interference_nt: interference,
                compensated_nt: compensated,
                coefficients: Some(file),
                regressors,
                warnings: qc.warnings,
                withheld: qc.withheld,
                ..Default::default()
            };
            Ok((flight, comp))
        }
    }
}

/// FOM, IR, residual, and error/oracle against truth when the trace has it.
pub fn summarise(flight: &Flight, comp: &Compensation) -> Summary {
    let residual = crate::metrics::band_rms_nt(flight, &comp.compensated_nt);
    let withheld = comp.withheld.is_some();
    let f = fom(flight, &comp.compensated_nt).filter(|_| !withheld);
    let table = if withheld {
        None
    } else {
        crate::qc::fom::flight_fom_table(flight, &comp.compensated_nt, comp.anomaly_nt.as_deref())
    };
    let (error, oracle) = match &flight.truth_interference_nt {
        Some(t) => (
            Some(error_rms_nt(&comp.interference_nt, t, None)),
            oracle_floor_nt(&comp.regressors, t),
        ),
        None => (None, None),
    };
    Summary {
        model: comp.model.clone(),
        method: comp.method.unwrap_or(Method::Kf),
        samples: flight.len(),
        residual_rms_nt: residual,
        improvement_ratio: improvement_ratio(flight, &comp.compensated_nt).filter(|_| !withheld),
        fom_nt: f.as_ref().map(|f| f.0).or(table.as_ref().map(|t| t.fom_nt)),
        aircraft_fom_nt: table.as_ref().and_then(|t| t.aircraft_fom_nt),
        fom_table: table,
        error_rms_nt: error,
        oracle_floor_nt: oracle,
        predicted_error_nt: comp
            .coefficients
            .as_ref()
            .and_then(|c| c.predicted_error_nt)
            .filter(|_| !withheld),
        field_process: comp
            .coefficients
            .as_ref()
            .and_then(|c| c.field_process.clone()),
        rate_crossover: comp
            .coefficients
            .as_ref()
            .and_then(|c| c.rate_crossover.clone()),
        manoeuvres: f.map(|f| f.1).unwrap_or_default(),
        warnings: comp.warnings.clone(),
    }
}

/// Writes `t,mag,interference,compensated[,anomaly,innovation,flags]`, then `carried`
/// (`input::carried_columns`: `igrf` and the input's unconsumed columns); CSV, or
/// Geosoft XYZ for a `.xyz` path.
pub fn write_output_csv(
    path: &Path,
    flight: &Flight,
    comp: &Compensation,
    carried: &[(String, crate::input::OutputValues)],
) -> Result<()> {
    crate::output::write_table(path, |mut w| {
        write_output_rows(&mut w, flight, comp, carried)
    })
}

fn write_output_rows(
    w: &mut impl std::io::Write,
    flight: &Flight,
    comp: &Compensation,
    carried: &[(String, crate::input::OutputValues)],
) -> Result<()> {
    writeln!(w, "# model: {}", comp.model)?;
    writeln!(
        w,
        "# method: {}",
        if comp.method == Some(Method::Tl) {
            "tl"
        } else {
            "kf"
        }
    )?;
    let kf = comp.anomaly_nt.is_some();
    if kf {
        write!(w, "t,mag,interference,compensated,anomaly,innovation,flags")?;
    } else {
        write!(w, "t,mag,interference,compensated")?;
    }
    for (name, _) in carried {
        write!(w, ",{name}")?;
    }
    writeln!(w)?;
    let num = |v: f64, d: usize| {
        if v.is_finite() {
            format!("{v:.d$}")
        } else {
            String::new()
        }
    };
    for i in 0..flight.len() {
        write!(
            w,
            "{},{},{},{}",
            flight.t_s[i],
            num(flight.mag_nt[i], 4),
            num(comp.interference_nt[i], 4),
            num(comp.compensated_nt[i], 4)
        )?;
        if kf {
            write!(
                w,
                ",{},{},{:#06x}",
                num(
                    comp.anomaly_nt.as_ref().map(|v| v[i]).unwrap_or(f64::NAN),
                    4
                ),
                num(
                    comp.innovation_nt
                        .as_ref()
                        .map(|v| v[i])
                        .unwrap_or(f64::NAN),
                    5
                ),
                comp.flags.as_ref().map(|v| v[i]).unwrap_or(0)
            )?;
        }
        for (_, col) in carried {
            match col {
                // Carried values are written as read (shortest round-trip form).
                crate::input::OutputValues::Num(v) => write!(w, ",{}", num_carried(v[i]))?,
                crate::input::OutputValues::Text(v) => write!(w, ",{}", csv_text(&v[i]))?,
            }
        }
        writeln!(w)?;
    }
    Ok(())
}

fn num_carried(v: f64) -> String {
    if v.is_finite() {
        v.to_string()
    } else {
        String::new()
    }
}

fn csv_text(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// `--coeffs` decides the method and the model: a `--method` or `--model` given beside
/// it that says otherwise is an error, not silently overridden.
pub fn refuse_conflicting_settings(
    coeffs: &CoefficientFile,
    method: Option<Method>,
    model: Option<&str>,
) -> Result<()> {
    let name = |m: Method| if m == Method::Tl { "tl" } else { "kf" };
    if let Some(m) = method.filter(|m| *m != coeffs.method) {
        bail!(
            "--method {} conflicts with the coefficient file, which holds {} coefficients: drop --method (the file decides) or give a {} coefficient file",
            name(m),
            name(coeffs.method),
            name(m)
        );
    }
    if let Some(m) = model {
        let same = coeffs.method == Method::Kf
            && ModelSpec::parse(m).map(|s| s.text()).ok().as_deref() == Some(coeffs.model.as_str());
        if !same {
            bail!(
                "--model {m} conflicts with the coefficient file's model '{}': drop --model (the file decides) or calibrate that model",
                coeffs.model
            );
        }
    }
    Ok(())
}

/// Reads a coefficient file written by `calibrate`. Coefficients are matched to the
/// file's model by name, whatever their order in the file, and returned in the model's
/// order (the covariance is in the model's order already); a name the model lacks, one
/// it needs that is
/// missing, or one given twice is an error naming it.
pub fn read_coefficients(path: &Path) -> Result<CoefficientFile> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let c: CoefficientFile = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a magcomp coefficient file", path.display()))?;
    if c.format != COEFF_FORMAT {
        bail!("{}: unknown format '{}'", path.display(), c.format);
    }
    if let Some(bad) = c.coefficients.iter().find(|c| !c.value.is_finite()) {
        bail!(
            "{}: coefficient '{}' is not finite",
            path.display(),
            bad.name
        );
    }
    let names = c
        .model_coefficient_names()
        .with_context(|| path.display().to_string())?;
    c.in_order_of(&names)
        .with_context(|| format!("{} (model '{}')", path.display(), c.model))
}

impl CoefficientFile {
    /// The names of the coefficients the file's model has, in the model's order: the KF
    /// model's `term.label`s, or the Tolles–Lawson terms of its configuration.
    pub fn model_coefficient_names(&self) -> Result<Vec<String>> {
        Ok(match self.method {
            Method::Kf => ModelSpec::parse(&self.model)?
                .coefficient_names()
                .into_iter()
                .map(|(n, _)| n)
                .collect(),
            Method::Tl => self
                .tl_config
                .as_ref()
                .context("the coefficient file has no Tolles–Lawson configuration")?
                .terms
                .names(),
        })
    }

    /// The same file with its coefficients (and the crossover fit's coefficients) in the
    /// order of `names`, matched by name; the covariance's size is checked.
    pub fn in_order_of(&self, names: &[String]) -> Result<CoefficientFile> {
        let order = order_by_name(
            self.coefficients.iter().map(|c| c.name.as_str()),
            names,
            "coefficient",
        )?;
        let mut out = self.clone();
        out.coefficients = order
            .iter()
            .map(|&i| self.coefficients[i].clone())
            .collect();
        if let Some(cov) = &self.covariance {
            // Unnamed rows: in the model's order, whatever the order of the entries.
            let k = names.len();
            if cov.len() != k || cov.iter().any(|r| r.len() != k) {
                bail!("the covariance is not {k} × {k} (one row and column per coefficient of the model)");
            }
        }
        if let Some(r) = &self.rate_crossover {
            let want = crate::crossover::RATE_LABELS.map(String::from);
            let o = order_by_name(
                r.labels.iter().map(String::as_str),
                &want,
                "rate_crossover label",
            )?;
            let mut r2 = r.clone();
            for (k, &i) in o.iter().enumerate() {
                r2.fit.coefficients[k] = r.fit.coefficients[i];
                r2.fit.sigmas[k] = r.fit.sigmas[i];
            }
            r2.labels = want.to_vec();
            out.rate_crossover = Some(r2);
        }
        Ok(out)
    }
}

/// For each of `want`, the index of the entry of `have` with that name; an entry that is
/// not wanted, a wanted one that is missing, or a name given twice is an error naming it.
pub(crate) fn order_by_name<'a>(
    have: impl Iterator<Item = &'a str>,
    want: &[String],
    what: &str,
) -> Result<Vec<usize>> {
    let have: Vec<&str> = have.collect();
    for (i, n) in have.iter().enumerate() {
        if !want.iter().any(|w| w == n) {
            bail!(
                "unknown {what} '{n}' (the model's are: {})",
                want.join(", ")
            );
        }
        if have[..i].contains(n) {
            bail!("{what} '{n}' is given twice");
        }
    }
    want.iter()
        .map(|w| {
            have.iter().position(|n| n == w).with_context(|| {
                format!(
                    "{what} '{w}' is missing ({} of {} given)",
                    have.len(),
                    want.len()
                )
            })
        })
        .collect()
}
