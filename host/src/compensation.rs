//! Calibrating and compensating a trace with either method (`calibrate`, `compensate`,
//! `report`, `diagnose` and `demo` call these), the summary figures, and the output CSV.

pub use crate::coefficients::{
    read_coefficients, refuse_conflicting_settings, Coefficient, CoefficientFile, Method,
    RateCrossover, COEFF_FORMAT,
};
use crate::flight::Flight;
use crate::metrics::{
    error_rms_nt, fom, improvement_ratio, manoeuvre_band, oracle_floor_nt, ManoeuvreFom,
};
use crate::model_spec::{ModelSpec, DEFAULT_MODEL};
use crate::pipeline::{run_kf, KfOptions};
use crate::tl;
use crate::trace::Trace;
use anyhow::{bail, ensure, Context, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Estimator settings (the command line's `EstimatorArgs`, `cli::args`).
#[derive(Clone, Debug, PartialEq)]
pub struct EstimatorSettings {
    /// Model spec: `+`-joined terms (`model_spec`).
    pub model: String,
    pub method: Method,
    /// Field-model roughness σ1 (nT/m^2.5); None: fitted to the data.
    pub sigma1: Option<f64>,
    /// Scalar measurement noise 1σ (nT); None: estimated from the data.
    pub noise_nt: Option<f64>,
    /// Tolles–Lawson terms of `Method::Tl` (`tl18`, `tl16`, groups).
    pub tl_terms: String,
    /// Ridge λ of `Method::Tl`; None: MagNav's default.
    pub tl_ridge: Option<f64>,
    /// Assumed ground speed (m/s) for a trace without positions.
    pub speed_mps: Option<f64>,
}

impl Default for EstimatorSettings {
    fn default() -> Self {
        Self {
            model: DEFAULT_MODEL.into(),
            method: Method::Kf,
            sigma1: None,
            noise_nt: None,
            tl_terms: "tl18".into(),
            tl_ridge: None,
            speed_mps: None,
        }
    }
}

/// The accuracy an aeromagnetic survey asks of compensation (nT rms).
pub const SURVEY_TOLERANCE_NT: f64 = 0.1;

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
    /// Real time: each record's stated 1σ bound on its interference (nT; empty while not
    /// converged); the `interference_sigma` column.
    pub interference_sigma_nt: Option<Vec<f64>>,
    pub coefficients: CoefficientFileOpt,
    pub regressors: Vec<Vec<f32>>,
    /// What the user must know about this result (printed on stderr, `warnings` in JSON).
    pub warnings: Vec<String>,
    /// Why the figures that would pretend (IR, FOM, predicted error) are withheld
    /// (`qc::inputs`); None when they stand.
    pub withheld: Option<String>,
}

pub type CoefficientFileOpt = Option<CoefficientFile>;

/// Summary numbers (`compensate --json`). Deserializable so that summaries written by
/// earlier versions (with the old key names) can be read back.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Summary {
    pub model: String,
    pub method: Method,
    pub samples: usize,
    /// RMS of the compensated signal in the manoeuvre band (0.1–0.9 Hz) over the flight:
    /// what is left where aircraft interference lives. Not the diagnosis's "residual" (the
    /// filter's one-step innovation); the key was `residual_rms_nt` before.
    #[serde(alias = "residual_rms_nt")]
    pub compensated_band_rms_nt: f64,
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
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub manoeuvres: Vec<ManoeuvreFom>,
    /// The AARC-style FOM table over the labelled or detected manoeuvres (`qc::fom`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fom_table: Option<crate::qc::fom::FomTable>,
    /// The FOM of (compensated − a field estimate): what the aircraft left. The field
    /// estimate is the KF's anomaly; for TL, that of the default model's filter fitted on
    /// this flight (`qc::fom::compensation_fom_table`; needs positions).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub aircraft_fom_nt: Option<f64>,
    /// What the user must know about this result (also on stderr); empty when none.
    pub warnings: Vec<String>,
    /// The flight was calibrated on an anti-aliased decimated copy (a long, fast flight:
    /// docs/streaming.md); the figures above are the copy's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub decimated: Option<crate::stream::decimate::Decimation>,
}

fn tl_config(flight: &Flight, est: &EstimatorSettings) -> Result<tl::TlConfig> {
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
    est: &EstimatorSettings,
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
    est: &EstimatorSettings,
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
                interference_sigma_nt: realtime.then_some(run.interference_sigma_nt),
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
            // Nor on the ground (parked, taxiing), where the filter does not learn either.
            let span = crate::excitation::airborne_span(&flight);
            for (i, s) in select.iter_mut().enumerate() {
                *s &= span.contains(&i);
            }
            let fit = match coeffs {
                Some(c) => {
                    let cfg = c
                        .tl_config
                        .clone()
                        .context("the coefficient file has no Tolles–Lawson configuration")?;
                    c.tl_fit(cfg)
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
            let coefficients = fit
                .names
                .iter()
                .zip(fit.coefficients.iter().zip(&fit.sigma))
                .map(|(n, (v, s))| Coefficient {
                    name: n.clone(),
                    unit: "nT".into(),
                    value: *v,
                    sigma: *s,
                })
                .collect();
            let file = CoefficientFile {
                tl_config: Some(fit.config.clone()),
                ..CoefficientFile::new(
                    format!("{:?}", fit.config.terms).to_lowercase(),
                    Method::Tl,
                    flight.sample_rate_hz,
                    coefficients,
                )
            };
            let mut warnings = qc.warnings;
            // A calibration only: applied coefficients were judged where they were fitted.
            if coeffs.is_none() {
                warnings.extend(crate::excitation::tl_warning(&flight));
            }
            let comp = Compensation {
                model: file.model.clone(),
                method: Some(Method::Tl),
                interference_nt: interference,
                compensated_nt: compensated,
                coefficients: Some(file),
                regressors,
                warnings,
                withheld: qc.withheld,
                ..Default::default()
            };
            Ok((flight, comp))
        }
    }
}

/// `trace` with the compensation applied: its scalar replaced by the compensated one (and
/// the simulator's truth interference by what the compensation left of it), so that a
/// diagnosis of it under a model without deviation terms studies the calibration as
/// applied, not re-fitted.
pub fn compensated_trace(trace: &Trace, flight: &Flight, comp: &Compensation) -> Result<Trace> {
    let n = trace.len();
    ensure!(
        flight.len() == n && comp.compensated_nt.len() == n,
        "internal: {} compensated samples for {n} rows",
        comp.compensated_nt.len()
    );
    let mut out = trace.clone();
    out.set_col("mag", comp.compensated_nt.clone());
    if let Some(t) = trace.col("truth_interference") {
        let left = t
            .iter()
            .zip(&comp.interference_nt)
            .map(|(t, i)| t - i)
            .collect();
        out.set_col("truth_interference", left);
    }
    Ok(out)
}

/// FOM, IR, compensated band rms, and error/oracle against truth when the trace has it.
pub fn summarise(flight: &Flight, comp: &Compensation) -> Summary {
    let band_rms = crate::metrics::band_rms_nt(flight, &comp.compensated_nt);
    let withheld = comp.withheld.is_some();
    let f = fom(flight, &comp.compensated_nt).filter(|_| !withheld);
    let table = if withheld {
        None
    } else {
        crate::qc::fom::compensation_fom_table(flight, comp)
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
        compensated_band_rms_nt: band_rms,
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
        decimated: None,
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
        if comp.interference_sigma_nt.is_some() {
            write!(w, ",interference_sigma")?;
        }
    } else {
        write!(w, "t,mag,interference,compensated")?;
    }
    for (name, _) in carried {
        write!(w, ",{name}")?;
    }
    writeln!(w)?;
    let num = fixed_cell;
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
            if let Some(s) = &comp.interference_sigma_nt {
                write!(w, ",{}", num(s[i], 4))?;
            }
        }
        for (_, col) in carried {
            match col {
                // Carried values are written as read (shortest round-trip form).
                crate::input::OutputValues::Num(v) => write!(w, ",{}", number_cell(v[i]))?,
                crate::input::OutputValues::Text(v) => write!(w, ",{}", csv_text(&v[i]))?,
            }
        }
        writeln!(w)?;
    }
    Ok(())
}

/// An output cell of a computed value: `d` decimals, empty when missing. The streamed path
/// (`stream::apply`) writes its rows with the same cells, so the two files are identical.
pub(crate) fn fixed_cell(v: f64, d: usize) -> String {
    if v.is_finite() {
        format!("{v:.d$}")
    } else {
        String::new()
    }
}

/// An output cell of a carried input number: as read, empty when missing.
pub(crate) fn number_cell(v: f64) -> String {
    if v.is_finite() {
        v.to_string()
    } else {
        String::new()
    }
}

/// An output cell of text, quoted when it holds a comma, a quote or a newline.
pub(crate) fn csv_text(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}
