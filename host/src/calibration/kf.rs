//! The Kalman filter's run as `calibrate` and `compensate` make it: the flight, the filter
//! (`estimate::kf`), and the coefficient file.

use super::coefficients::{Coefficient, CoefficientFile, Method, RateCrossover, COEFF_FORMAT};
use super::result::Compensation;
use super::EstimatorSettings;
use crate::estimate::corrections::run_kf;
use crate::estimate::kf::{KfOptions, KfRun};
use crate::flight::Flight;
use crate::io::trace::Trace;
use crate::model::corrections::ScalarLag;
use crate::model::spec::{InputCorrection, ModelSpec};
use anyhow::{bail, Result};

/// The Kalman filter's calibration (or, with `coeffs`, its application) as a sequence of
/// stages: prepare ([`PreparedFlight`]: the flight read for the model, despiked, checked;
/// an assumed ground speed) → corrections (the scalar's delay looked for here, then
/// `estimate::corrections::CorrectedFlight`: `lag`, `fluxtemp`; the fluxgate's calibration,
/// `estimate::kf::FluxgateStage`) → σ and noise → filter → coefficients → QC
/// (`estimate::kf::stages`) → the coefficient file and the run's records.
pub(super) fn run_kf_method(
    trace: &Trace,
    est: &EstimatorSettings,
    coeffs: Option<&CoefficientFile>,
    realtime: bool,
    model_text: &str,
) -> Result<(Flight, Compensation)> {
    let spec = ModelSpec::parse(model_text)?;
    let PreparedFlight {
        flight,
        qc,
        mut warnings,
        assumed_speed_mps,
    } = PreparedFlight::of(trace, &spec, est, coeffs)?;
    // The default calibration looks for a scalar delay the model was not told of.
    let (spec, detected_lag) = if est.cross_check
        && coeffs.is_none()
        && !realtime
        && !crate::estimate::corrections::needed(&spec)
    {
        with_detected_lag(trace, &flight, spec, assumed_speed_mps, &mut warnings)?
    } else {
        (spec, None)
    };
    let mut opts = kf_options(&spec, est, coeffs, realtime, detected_lag)?;
    if realtime {
        opts.survey_from = est
            .survey_from_s
            .map(|t| flight.t_s.partition_point(|&x| x < t));
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
        run.predicted_error_range_nt = None;
    }
    let file = coefficient_file(&run, &spec, &flight, coeffs, assumed_speed_mps);
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
        jackknife_nt: run
            .jackknife
            .as_ref()
            .map(|j| j.sigma_nt)
            .filter(|_| qc.withheld.is_none()),
        band_jackknife_nt: run
            .jackknife
            .as_ref()
            .and_then(|j| j.band_sigma_nt)
            .filter(|_| qc.withheld.is_none()),
        holdout_band_nt: run
            .jackknife
            .as_ref()
            .and_then(|j| j.holdout_band_nt)
            .filter(|_| qc.withheld.is_none()),
        refit_inflation: run.jackknife.as_ref().map(|j| j.inflation),
        withheld: qc.withheld,
    };
    Ok((flight, comp))
}

/// The prepare stage: the flight read from the trace for the model (its channels, the
/// scalar's glitches blanked and the fluxgate's bridged: `Flight::from_trace`), its inputs
/// checked (`qc::inputs`), and a ground speed assumed where the field model needs one and
/// the trace has no track.
struct PreparedFlight {
    flight: Flight,
    qc: crate::qc::inputs::InputCheck,
    /// The checks' warnings, then the assumed speed's.
    warnings: Vec<String>,
    assumed_speed_mps: Option<f64>,
}

impl PreparedFlight {
    fn of(
        trace: &Trace,
        spec: &ModelSpec,
        est: &EstimatorSettings,
        coeffs: Option<&CoefficientFile>,
    ) -> Result<Self> {
        let mut flight = Flight::from_trace(trace, &spec.channels(), &spec.relative_channels())?;
        let qc = crate::qc::inputs::check(&flight, coeffs.is_none())?;
        let mut warnings = qc.warnings.clone();
        let mut assumed_speed_mps = None;
        if spec.field && !flight.has_track() {
            let given = est.speed_mps.or(coeffs.and_then(|c| c.assumed_speed_mps));
            let (v, warning) = crate::flight::input::assumed_ground_speed(given)?;
            flight.assume_ground_speed(v);
            assumed_speed_mps = Some(v);
            warnings.push(warning);
        }
        Ok(Self {
            flight,
            qc,
            warnings,
            assumed_speed_mps,
        })
    }
}

/// The model with `lag` added, and the delay, when the flight shows one (with a warning
/// saying so); the model as given otherwise.
fn with_detected_lag(
    trace: &Trace,
    flight: &Flight,
    spec: ModelSpec,
    assumed_speed_mps: Option<f64>,
    warnings: &mut Vec<String>,
) -> Result<(ModelSpec, Option<ScalarLag>)> {
    let Some(l) = detect_lag(trace, flight, &spec, assumed_speed_mps)? else {
        return Ok((spec, None));
    };
    warnings.push(format!(
        "the scalar lags the fluxgate by {:.0} ± {:.0} ms: it is re-aligned (the \
         `lag` term is added to the model; `--method kf` keeps the model as given)",
        l.lag_s * 1e3,
        l.sigma_s * 1e3
    ));
    Ok((ModelSpec::parse(&format!("{}+lag", spec.text()))?, Some(l)))
}

/// The filter's options: the user's settings, a detected delay, and what an applied
/// coefficient file fixes.
fn kf_options(
    spec: &ModelSpec,
    est: &EstimatorSettings,
    coeffs: Option<&CoefficientFile>,
    realtime: bool,
    detected_lag: Option<ScalarLag>,
) -> Result<KfOptions> {
    let mut opts = KfOptions::new(spec.clone());
    if let Some(l) = detected_lag {
        opts.preprocessing = Some(crate::model::corrections::Preprocessing {
            scalar_lag: Some(l),
            fluxgate_temperature: None,
        });
    }
    opts.sigma1 = est.sigma1.or(coeffs.and_then(|c| c.sigma1));
    opts.noise_nt = est.noise_nt;
    opts.realtime = realtime;
    // The calibration the user is given reports the flight's own evidence.
    opts.jackknife = true;
    if let Some(c) = coeffs {
        apply_coefficient_file(&mut opts, spec, c)?;
    }
    Ok(opts)
}

/// Fixes the filter's coefficients, their covariance and the input corrections to the
/// file's; refuses a file without the corrections the model needs.
fn apply_coefficient_file(
    opts: &mut KfOptions,
    spec: &ModelSpec,
    c: &CoefficientFile,
) -> Result<()> {
    opts.coefficients = Some(c.coefficients.iter().map(|c| c.value).collect());
    if spec.calibrates_fluxgate() && c.fluxgate_calibration.is_none() {
        bail!("the model has `fluxcal` but the coefficient file has no fluxgate_calibration");
    }
    opts.fluxgate_calibration = c.fluxgate_calibration;
    if spec.corrects(InputCorrection::Lag) && c.scalar_lag.is_none() {
        bail!("the model has `lag` but the coefficient file has no scalar_lag");
    }
    if spec.corrects(InputCorrection::FluxTemp) && c.fluxgate_temperature.is_none() {
        bail!("the model has `fluxtemp` but the coefficient file has no fluxgate_temperature");
    }
    opts.preprocessing = Some(crate::model::corrections::Preprocessing {
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
    Ok(())
}

/// The coefficient file of the run: what it calibrated, or, with `coeffs` applied, the
/// applied file's figures where the run held them fixed.
fn coefficient_file(
    run: &KfRun,
    spec: &ModelSpec,
    flight: &Flight,
    coeffs: Option<&CoefficientFile>,
    assumed_speed_mps: Option<f64>,
) -> CoefficientFile {
    CoefficientFile {
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
                labels: crate::estimate::crossover::RATE_LABELS
                    .map(String::from)
                    .to_vec(),
                fit: fit.clone(),
                applied: *applied,
            }),
            (None, Some(c)) => c.rate_crossover.clone(),
            (None, None) => None,
        },
        predicted_error_nt: run.predicted_error_nt,
        predicted_error_range_nt: run.predicted_error_range_nt,
        unfollowed_high_frequency_nt: run.unfollowed_high_frequency_nt,
        assumed_speed_mps,
        cross_check: None,
        predicted_band_rms_nt: None,
        provenance: None,
        unsealed: false,
        // Applied coefficients keep the σ and covariance their calibration found: the
        // filter run here holds them fixed and reports its prior σ (±200 nT, …), which says
        // nothing about how well they were determined.
        covariance: coeffs.and_then(|c| c.covariance.clone()).or_else(|| {
            let k = run.coefficients.len();
            (run.coefficient_covariance.len() == k * k && k > 0).then(|| {
                run.coefficient_covariance
                    .chunks(k)
                    .map(|row| row.to_vec())
                    .collect()
            })
        }),
        coefficients: run
            .coefficient_names
            .iter()
            .zip(run.coefficients.iter().zip(&run.coefficient_sigmas))
            .map(|((n, u), (v, s))| Coefficient {
                name: n.clone(),
                unit: u.clone(),
                value: *v,
                sigma: coeffs
                    .and_then(|c| c.coefficients.iter().find(|k| &k.name == n))
                    .map_or(*s, |k| k.sigma),
            })
            .collect(),
    }
}

/// The delay is looked for on at most this long a stretch (s): the one richest in
/// manoeuvres, where the interference changes fast and a delay shows. On a whole 82-minute
/// calibration + survey flight the search took 15 of the calibration's 19 s.
const LAG_SEARCH_S: f64 = 1200.0;

/// [`crate::estimate::corrections::lag::detect`] on the flight, or on its [`LAG_SEARCH_S`] stretch
/// where the fluxgate's direction turns most.
fn detect_lag(
    trace: &Trace,
    flight: &Flight,
    spec: &ModelSpec,
    assumed_speed_mps: Option<f64>,
) -> Result<Option<ScalarLag>> {
    let window = (LAG_SEARCH_S * flight.sample_rate_hz) as usize;
    if flight.len() <= window {
        return Ok(crate::estimate::corrections::lag::detect(flight, spec));
    }
    let flux = crate::estimate::fluxcal::flight_flux(flight);
    let unit = |b: &[f64; 3]| {
        let n = (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt();
        b.map(|v| v / n)
    };
    // Running sum of the direction's turn between samples (0 where it is unknown).
    let mut turned = vec![0.0f64; flux.len() + 1];
    for i in 1..flux.len() {
        let (a, b) = (unit(&flux[i - 1]), unit(&flux[i]));
        let step = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
        turned[i + 1] = turned[i] + if step.is_finite() { step } else { 0.0 };
    }
    let start = (0..=flux.len() - window)
        .max_by(|&a, &b| {
            (turned[a + window] - turned[a]).total_cmp(&(turned[b + window] - turned[b]))
        })
        .unwrap_or(0);
    let rows: Vec<usize> = (start..start + window).collect();
    let part = crate::flight::input::take_rows(trace, &rows);
    let mut stretch = Flight::from_trace(&part, &spec.channels(), &spec.relative_channels())?;
    if let Some(v) = assumed_speed_mps {
        stretch.assume_ground_speed(v);
    }
    Ok(crate::estimate::corrections::lag::detect(&stretch, spec))
}
