//! Helpers of the model-discovery tests (`diagnose_evidence`, `diagnose_reciprocal`,
//! `report_reciprocal`): the reciprocal-pass flights, the term a diagnosis names and the
//! error against truth of a Kalman calibration.

use magcomp::calibration::summary::summarise;
use magcomp::calibration::{compensate_trace, EstimatorSettings, Method};
use magcomp::diagnose::Diagnosis;
use magcomp::io::trace::Trace;
use magcomp::sim::{parse_hidden, FlightKind, Geology, GeologyPreset, SimConfig};

/// The reciprocal flights (seed 3): a calibration and `survey_lines` survey lines of 5 km
/// flown back and forth 10 m apart over strong geology, with a hidden scalar lag of `lag_s`
/// seconds when given.
pub fn reciprocal_flights(lag_s: Option<f64>, survey_lines: usize) -> SimConfig {
    SimConfig {
        seed: 3,
        flight: FlightKind::CalibrationSurvey,
        geology: Geology::preset(GeologyPreset::Strong),
        survey_lines,
        line_spacing_m: 10.0,
        line_length_m: 5000.0,
        hidden: lag_s
            .map(|t| vec![parse_hidden(&format!("lag:{t}")).expect("hidden")])
            .unwrap_or_default(),
        ..SimConfig::default()
    }
}

/// The term a diagnosis names: its first significant candidate.
pub fn named(d: &Diagnosis) -> Option<&str> {
    d.candidates
        .iter()
        .find(|c| c.significant)
        .map(|c| c.term.as_str())
}

/// Error against truth (nT) of the Kalman calibration with exactly this model.
pub fn error_nt(trace: &Trace, model: &str) -> f64 {
    let est = EstimatorSettings {
        model: model.into(),
        method: Method::Kf,
        ..EstimatorSettings::default()
    };
    let (flight, comp) = compensate_trace(trace, &est, None, false).expect("calibrate");
    summarise(&flight, &comp).error_rms_nt.expect("truth")
}
