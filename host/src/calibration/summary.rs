//! What a compensation reports: the summary figures (`compensate --json`) and the output
//! CSV.

use super::coefficients::{Method, RateCrossover};
use super::fom::FomTable;
use super::result::Compensation;
use crate::flight::Flight;
use crate::io::csv::{csv_text, fixed_cell, number_cell};
use crate::qc::figures::{fom, improvement_ratio, ManoeuvreFom};
use crate::qc::live_readout::{converged_only, live_error_rms_nt, LiveReadout};
use crate::qc::truth::{error_rms_nt, oracle_floor_nt};
use anyhow::Result;
use serde::{Deserialize, Serialize};
use std::path::Path;

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
    /// The range (nT, low and high, 90 %) one flight's actual error falls in beside
    /// `predicted_error_nt` (`crate::qc::error_range`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub predicted_error_range_nt: Option<[f64; 2]>,
    /// The output's high-frequency content beyond the scalar's noise, counted in
    /// `predicted_error_nt` (`CoefficientFile::unfollowed_high_frequency_nt`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unfollowed_high_frequency_nt: Option<f64>,
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
    /// The AARC-style FOM table over the labelled or detected manoeuvres (`calibration::fom`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fom_table: Option<crate::calibration::fom::FomTable>,
    /// The FOM of (compensated − a field estimate): what the aircraft left. The field
    /// estimate is the KF's anomaly; for TL, that of the default model's filter fitted on
    /// this flight (`calibration::fom::compensation_fom_table`; needs positions).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub aircraft_fom_nt: Option<f64>,
    /// What the user must know about this result (also on stderr); empty when none.
    pub warnings: Vec<String>,
    /// The flight was calibrated on an anti-aliased decimated copy (a long, fast flight:
    /// docs/streaming.md); the figures above are the copy's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub decimated: Option<crate::flight::input::Decimation>,
    /// Real time (`--realtime`): what the live readout showed. The figures above (band rms,
    /// IR, FOM, error vs truth) are then over the records it showed converged; the
    /// predicted error is that of the coefficients held at the end.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub live: Option<LiveReadout>,
}

/// FOM, IR, compensated band rms, and error/oracle against truth when the trace has it.
pub fn summarise(flight: &Flight, comp: &Compensation) -> Summary {
    summarise_with(flight, comp, true)
}

/// [`summarise`]; `fit_field_estimate` false leaves out the aircraft-only figures of a
/// compensation without its own anomaly estimate (TL), which need a whole Kalman pass.
pub fn summarise_with(flight: &Flight, comp: &Compensation, fit_field_estimate: bool) -> Summary {
    match live_view(flight, comp) {
        Some((seen, shown, live)) => {
            let mut s = summarise_output(&seen, &shown, fit_field_estimate);
            // Manoeuvres flown before convergence have no live figures.
            s.manoeuvres.retain(|m| {
                m.peak_to_peak_nt.is_finite() && m.uncompensated_peak_to_peak_nt.is_finite()
            });
            s.fom_table = s.fom_table.and_then(FomTable::measured_only);
            s.fom_nt = s.fom_table.as_ref().map(|t| t.fom_nt);
            s.aircraft_fom_nt = s.fom_table.as_ref().and_then(|t| t.aircraft_fom_nt);
            if let (Some(truth), Some(flags)) = (&flight.truth_interference_nt, &comp.flags) {
                s.error_rms_nt = live_error_rms_nt(&comp.interference_nt, truth, flags);
            }
            Summary {
                live: Some(live),
                ..s
            }
        }
        None => summarise_output(flight, comp, fit_field_estimate),
    }
}

/// A real-time run's records as its figures see them: the flight and the output with the
/// records shown raw (not converged) blanked, and the readout's counts. None for a
/// post-flight compensation.
fn live_view(flight: &Flight, comp: &Compensation) -> Option<(Flight, Compensation, LiveReadout)> {
    let flags = comp
        .flags
        .as_deref()
        .filter(|f| comp.is_live() && f.len() == flight.len())?;
    let live = LiveReadout::of(&flight.t_s, flags);
    let mut seen = flight.clone();
    seen.mag_nt = converged_only(&flight.mag_nt, flags);
    let mut shown = comp.clone();
    shown.compensated_nt = converged_only(&comp.compensated_nt, flags);
    shown.interference_nt = converged_only(&comp.interference_nt, flags);
    shown.anomaly_nt = comp.anomaly_nt.as_deref().map(|a| converged_only(a, flags));
    Some((seen, shown, live))
}

fn summarise_output(flight: &Flight, comp: &Compensation, fit_field_estimate: bool) -> Summary {
    let band_rms = crate::qc::figures::band_rms_nt(flight, &comp.compensated_nt);
    let withheld = comp.withheld.is_some();
    let f = fom(flight, &comp.compensated_nt).filter(|_| !withheld);
    let table = if withheld {
        None
    } else {
        crate::calibration::fom::compensation_fom_table(flight, comp, fit_field_estimate)
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
        predicted_error_range_nt: file
            .and_then(|c| c.predicted_error_range_nt)
            .filter(|_| !withheld),
        unfollowed_high_frequency_nt: file
            .and_then(|c| c.unfollowed_high_frequency_nt)
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
        live: None,
    }
}

/// Writes `t,mag,interference,compensated[,anomaly,innovation,flags]`, then `carried`
/// (`input::carried_columns`: `igrf` and the other input columns); CSV, or
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
