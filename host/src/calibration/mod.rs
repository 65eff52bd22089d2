//! Calibrating and compensating a trace with either method (`calibrate`, `compensate`,
//! `report`, `diagnose` and `demo` call these), the summary figures, and the output CSV.

pub use crate::calibration::coefficients::{
    read_coefficients, refuse_conflicting_settings, Coefficient, CoefficientFile, Method,
    RateCrossover, COEFF_FORMAT,
};
use crate::flight::Flight;
use crate::io::trace::Trace;
use crate::model::spec::DEFAULT_MODEL;
use crate::qc::figures::{fom, improvement_ratio, ManoeuvreFom};
use crate::qc::truth::{error_rms_nt, oracle_floor_nt};
use anyhow::{ensure, Result};

pub mod applied;
pub mod coefficients;
mod cross_check;
pub mod fom;
mod kf;
mod tl;
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
    /// Post-flight calibration with the Kalman filter as the default, not asked for by
    /// name: TL18-OLS is used instead when the flight's own evidence trusts it more
    /// ([`cross_check`]).
    pub cross_check: bool,
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
            cross_check: false,
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
    /// Calibration: the method's jackknife error (nT rms; `crate::estimate::jackknife`).
    pub jackknife_nt: Option<f64>,
    /// The same in the manoeuvre band: what a band-passed figure on another flight sees.
    pub band_jackknife_nt: Option<f64>,
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
    /// Calibration: the manoeuvre-band rms another flight like this one should show after
    /// compensation (`CoefficientFile::predicted_band_rms_nt`); with `--coeffs`, the file's,
    /// to hold against `compensated_band_rms_nt`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub predicted_band_rms_nt: Option<f64>,
    /// Calibration by default: the flight's own check of its coefficients (the jackknife
    /// errors of the filter and of TL18-OLS; which one is used).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cross_check: Option<crate::estimate::jackknife::CrossCheck>,
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
    pub fom_table: Option<crate::calibration::fom::FomTable>,
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
    pub decimated: Option<crate::flight::input::Decimation>,
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
    if let (None, Some(band_jackknife)) = (coeffs, comp.band_jackknife_nt) {
        let own = crate::qc::figures::band_rms_nt(&flight, &comp.compensated_nt);
        if let Some(file) = comp.coefficients.as_mut().filter(|_| own.is_finite()) {
            file.predicted_band_rms_nt = Some(own.hypot(band_jackknife));
        }
    }
    if let Some(c) = coeffs {
        // What the calibration predicted travels with its coefficients.
        if let Some(file) = comp.coefficients.as_mut() {
            file.predicted_band_rms_nt = c.predicted_band_rms_nt;
            file.cross_check.clone_from(&c.cross_check);
        }
        let w = crate::calibration::applied::check(&flight, &comp, c);
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
        Method::Kf if est.cross_check && coeffs.is_none() && !realtime => {
            let kalman = kf::run_kf_method(trace, est, coeffs, realtime, &model_text)?;
            cross_check::choose(trace, est, kalman)
        }
        Method::Kf => kf::run_kf_method(trace, est, coeffs, realtime, &model_text),
        Method::Tl => tl::run_tl_method(trace, est, coeffs),
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
    let band_rms = crate::qc::figures::band_rms_nt(flight, &comp.compensated_nt);
    let withheld = comp.withheld.is_some();
    let f = fom(flight, &comp.compensated_nt).filter(|_| !withheld);
    let table = if withheld {
        None
    } else {
        crate::calibration::fom::compensation_fom_table(flight, comp)
    };
    let (error, oracle) = match &flight.truth_interference_nt {
        Some(t) => (
            Some(error_rms_nt(&comp.interference_nt, t, None)),
            oracle_floor_nt(&comp.regressors, t),
        ),
        None => (None, None),
    };
    let file = comp.coefficients.as_ref();
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
        predicted_error_nt: file
            .and_then(|c| c.predicted_error_nt)
            .filter(|_| !withheld),
        field_process: file.and_then(|c| c.field_process.clone()),
        predicted_band_rms_nt: file
            .and_then(|c| c.predicted_band_rms_nt)
            .filter(|_| !withheld),
        cross_check: file
            .and_then(|c| c.cross_check.clone())
            .filter(|_| !withheld),
        rate_crossover: file.and_then(|c| c.rate_crossover.clone()),
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
    carried: &[(String, crate::flight::input::OutputValues)],
) -> Result<()> {
    crate::io::trace::write_table(path, |mut w| {
        write_output_rows(&mut w, flight, comp, carried)
    })
}

fn write_output_rows(
    w: &mut impl std::io::Write,
    flight: &Flight,
    comp: &Compensation,
    carried: &[(String, crate::flight::input::OutputValues)],
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
                crate::flight::input::OutputValues::Num(v) => write!(w, ",{}", number_cell(v[i]))?,
                crate::flight::input::OutputValues::Text(v) => write!(w, ",{}", csv_text(&v[i]))?,
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
