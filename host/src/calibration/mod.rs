//! Calibrating and compensating a trace with either method (`calibrate`, `compensate`,
//! `report`, `diagnose` and `demo` call these), the summary figures, and the output CSV.

pub use crate::calibration::coefficients::{
    read_coefficients, refuse_conflicting_settings, Coefficient, CoefficientFile, Method,
    RateCrossover, COEFF_FORMAT,
};
use crate::flight::Flight;
use crate::io::trace::Trace;
use crate::model::spec::DEFAULT_MODEL;
use anyhow::{ensure, Result};
use result::Compensation;

pub mod applied;
pub mod coefficients;
mod cross_check;
pub mod fluxgate_check;
pub mod fluxgate_witness;
pub mod fom;
mod kf;
mod live_witness;
pub mod provenance;
pub mod result;
pub mod summary;
mod tl;

/// Estimator settings (the command line's `EstimatorArgs`, `cli::args`).
#[derive(Clone, Debug, PartialEq)]
pub struct EstimatorSettings {
    /// Model spec: `+`-joined terms (`model::spec`).
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
    /// Real time: switch to survey mode at this time (s), as the operator's `MODE,SURVEY`
    /// would: the coefficients held then are kept for the rest of the flight.
    pub survey_from_s: Option<f64>,
    /// Real time with the default estimator: the model's witnessed form (`+fluxmod`) runs
    /// beside it and each record is the shown filter's, as on the board
    /// ([`live_witness`]); `--no-witness` turns it off.
    pub live_witness: bool,
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
            survey_from_s: None,
            live_witness: true,
        }
    }
}

/// The accuracy an aeromagnetic survey asks of compensation (nT rms).
pub const SURVEY_TOLERANCE_NT: f64 = 0.1;

/// Runs the chosen method. `coeffs`: apply these instead of calibrating on the trace;
/// their plausibility on this flight is checked (`calibration::applied`) and warned about.
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
        // The fluxgate against the one the coefficients were calibrated with.
        if let Some(rec) = c.provenance.as_ref().and_then(|p| p.fluxgate.as_ref()) {
            let cal = c
                .fluxgate_calibration
                .unwrap_or(crate::estimate::fluxcal::FluxgateCalibration::IDENTITY);
            let now = fluxgate_check::record(&flight, &cal, &comp.interference_nt);
            comp.warnings
                .extend(fluxgate_check::applied_warnings(rec, &now));
        }
    }
    Ok((flight, comp))
}

/// The default's check of a Kalman-filter calibration of `trace` against TL18-OLS on the
/// flight's own evidence ([`cross_check`]): the filter's result, or TL18-OLS's where that
/// evidence trusts it more, as `calibrate` without `--method` chooses for one sensor. Used
/// for each sensor of a several-sensor calibration.
pub fn cross_checked(
    trace: &Trace,
    est: &EstimatorSettings,
    kalman: (Flight, Compensation),
) -> Result<(Flight, Compensation)> {
    cross_check::choose(trace, est, kalman, cross_check::least_squares(trace, est))
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
            // TL18-OLS does not depend on the filter's run: on the other cores beside it.
            let (kalman, least_squares) = std::thread::scope(|s| {
                let tl = s.spawn(|| cross_check::least_squares(trace, est));
                let kalman =
                    kf::run_kf_method(trace, est, coeffs, realtime, &model_text).and_then(|k| {
                        let witness = fluxgate_witness::consider(trace, est, &k, &model_text)?;
                        Ok((witness.kept.unwrap_or(k), witness.note))
                    });
                (
                    kalman,
                    tl.join().expect("the TL18-OLS cross-check panicked"),
                )
            });
            let (kalman, witness_note) = kalman?;
            let (flight, mut comp) = cross_check::choose(trace, est, kalman, least_squares)?;
            comp.warnings.extend(witness_note);
            Ok((flight, comp))
        }
        Method::Kf => {
            let calibrating_live = realtime && coeffs.is_none();
            match live_witness::witnessed_model(est, &model_text, calibrating_live) {
                Some(witnessed) => live_witness::run_pair(trace, est, &model_text, &witnessed),
                None => kf::run_kf_method(trace, est, coeffs, realtime, &model_text),
            }
        }
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
