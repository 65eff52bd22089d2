//! `magcomp calibrate`: estimate the deviation coefficients (with 1σ) from a calibration
//! flight and write them as a coefficient file.

use super::args::{EstimatorArgs, LongFlightArgs, TraceInput};
use super::multi::{MultiArgs, OneSensorRerun, SensorPlan};
use super::multi_calibrate::{self, methods_asked, parse_sensor_methods};
use super::summary_text::{print_summary, print_warnings};
use crate::calibration::coefficients::Method;
use crate::calibration::summary::summarise_with;
use crate::calibration::{compensate_trace, SURVEY_TOLERANCE_NT};
use crate::io::output::check_outputs;
use anyhow::{bail, Context, Result};
use std::path::PathBuf;

#[derive(clap::Args, Clone, Debug)]
pub struct CalibrateArgs {
    #[command(flatten)]
    pub input: TraceInput,
    #[command(flatten)]
    pub est: EstimatorArgs,
    #[command(flatten)]
    pub long: LongFlightArgs,
    #[command(flatten)]
    pub multi: super::multi::MultiArgs,
    /// With `--sensors` naming two or more: a method per sensor, `mag_K=tl|kf`, comma
    /// separated, e.g. `mag_5=tl,mag_3=kf`. `tl`: that sensor alone by Tolles–Lawson, its
    /// set as `--method tl` writes it; `kf`: in the joint Kalman filter, its set neither
    /// cross-checked against TL18-OLS nor witnessed by its fluxgate (as `--method kf`).
    /// The sensors not named follow `--method` (with `--method tl` a sensor named `kf` is
    /// the Kalman filter's); one Kalman-filter sensor left is calibrated alone, as
    /// `calibrate` calibrates one. The file keeps the `--sensors` order.
    #[arg(long, value_name = "mag_K=tl|kf,...")]
    pub sensor_method: Option<String>,
    /// Where to write the coefficients (JSON).
    #[arg(
        short = 'o',
        long = "out",
        visible_alias = "output",
        value_name = "COEFFS.json"
    )]
    pub output: PathBuf,
    /// Print one JSON object with the summary on stdout (as `compensate --json`).
    #[arg(long)]
    pub json: bool,
    /// With `--method tl`: also report the aircraft-only FOM (compensated − the anomaly of
    /// the default model's Kalman filter fitted on this flight). Off by default: that
    /// filter pass costs several times the TL fit. The Kalman method always reports it.
    #[arg(long)]
    pub aircraft_fom: bool,
}

impl OneSensorRerun for CalibrateArgs {
    fn map_mut(&mut self) -> &mut Option<String> {
        &mut self.input.map
    }
    fn multi_mut(&mut self) -> &mut MultiArgs {
        &mut self.multi
    }
}

/// `--sensor-method`, parsed (empty when not given), refused before the trace is read
/// unless `--sensors` names two sensors or more.
fn sensor_methods(a: &CalibrateArgs) -> Result<Vec<(String, Method)>> {
    let Some(text) = &a.sensor_method else {
        return Ok(Vec::new());
    };
    if a.multi.sensors.is_none() {
        bail!("--sensor-method needs --sensors (a method for each of several magnetometers)");
    }
    if !a.multi.names_several(None) {
        bail!(
            "--sensor-method needs two sensors or more in --sensors (one sensor: its method \
             is --method)"
        );
    }
    parse_sensor_methods(text)
}

pub fn run(a: &CalibrateArgs) -> Result<()> {
    check_outputs(&[&a.input.trace], &[&a.output])?;
    crate::io::progress::force_progress(a.long.progress);
    let asked = sensor_methods(a)?;
    let (trace, decimated) = a.input.read_for_calibration(&a.long)?;
    match a.multi.plan(&trace, a.input.map.as_deref())? {
        SensorPlan::Today => {}
        SensorPlan::One(map) => return run(&a.as_one_sensor(map)),
        SensorPlan::Several(sensors, _) => {
            let asked = methods_asked(&asked, &sensors)?;
            return multi_calibrate::calibrate(
                &trace,
                &a.est.settings(),
                &sensors,
                &asked,
                &a.output,
            );
        }
    }
    let stage = crate::io::progress::Stage::new("calibration (all filter passes)");
    let (flight, comp) = compensate_trace(&trace, &a.est.settings(), None, false)?;
    drop(stage);
    let mut file = comp.coefficients.clone().context("no coefficients")?;
    let mut provenance = a.input.provenance(&trace, &file.model)?;
    // What this flight's fluxgate looked like, for `compensate --coeffs` to check against.
    let record = crate::calibration::fluxgate_check::record(
        &flight,
        &file
            .fluxgate_calibration
            .unwrap_or(crate::estimate::fluxcal::FluxgateCalibration::IDENTITY),
        &comp.interference_nt,
    );
    let frame_warning = crate::calibration::fluxgate_check::frame_warning(&record);
    provenance.fluxgate = Some(record);
    file.provenance = Some(provenance);
    crate::io::output::write_file(
        &a.output,
        crate::calibration::coefficients::to_sealed_json(&file)?,
    )?;
    let stage = crate::io::progress::Stage::new("summary figures (FOM, IR, oracle floor)");
    let mut s = summarise_with(
        &flight,
        &comp,
        comp.method != Some(Method::Tl) || a.aircraft_fom,
    );
    drop(stage);
    s.decimated = decimated;
    s.warnings.extend(frame_warning);
    s.warnings.extend(predicted_error_warning(
        file.predicted_error_nt,
        file.model_error_nt,
        comp.refit_inflation,
    ));
    if a.json {
        crate::outln!(
            "{}",
            super::summary_text::with_printed_warnings(serde_json::to_value(&s)?)
        );
    } else {
        crate::outln!("{:<28} {:>12} {:>10}  unit", "coefficient", "value", "1σ");
        for c in &file.coefficients {
            crate::outln!(
                "{:<28} {:>12.4} {:>10.4}  {}",
                c.name,
                c.value,
                c.sigma,
                c.unit
            );
        }
        print_summary(&s);
        if comp.method == Some(Method::Tl) && !a.aircraft_fom && flight.has_track() {
            // Say what was left out, and how to get it.
            crate::outln!(
                "  aircraft-only FOM:          not computed (add --aircraft-fom: one Kalman pass)"
            );
        }
    }
    print_warnings(&s);
    crate::errln!("wrote {}", a.output.display());
    Ok(())
}

/// The warning for a predicted error above a survey's tolerance, with the advice that fits
/// what dominates it: the model error (add the missing effect), the calibration's parts
/// disagreeing beyond the model (`refit_inflation` above `INCONSISTENT_REFITS`: the figure
/// is a lower bound and a missing effect likely), or the coefficients' uncertainty (fly
/// higher, quieter, more manoeuvres).
fn predicted_error_warning(
    predicted_error_nt: Option<f64>,
    model_error_nt: Option<f64>,
    refit_inflation: Option<f64>,
) -> Option<String> {
    let p = predicted_error_nt.filter(|p| *p > SURVEY_TOLERANCE_NT)?;
    let lower_bound = refit_inflation.is_some_and(|i| i > crate::estimate::kf::INCONSISTENT_REFITS);
    let advice = match model_error_nt {
        Some(m) if m > 0.7 * p => {
            "most of it is signal the model cannot follow: add the missing effect \
             (`magcomp diagnose`)"
        }
        // More of the same pattern would not help: a hidden 0.3 nT/A pump current on
        // `clean_s33` was told to fly higher; `diagnose` names it at 99 % and the error
        // falls 0.90 → 0.11 nT with it.
        _ if lower_bound => {
            "it is a lower bound, as the calibration's parts disagree beyond what its \
             model allows; an effect it lacks is likely (`magcomp diagnose` names \
             candidates), and if none is named, fly the pattern higher or over quieter \
             ground"
        }
        _ => "fly the pattern higher, over quieter ground, or with more manoeuvres",
    };
    Some(format!(
        "the predicted error of this calibration is {p:.3} nT rms, more than a survey's \
         {SURVEY_TOLERANCE_NT} nT: {advice}"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_advice_follows_what_dominates_the_predicted_error() {
        assert_eq!(predicted_error_warning(Some(0.05), None, Some(40.0)), None);
        let model = predicted_error_warning(Some(0.3), Some(0.25), Some(40.0)).unwrap();
        assert!(model.contains("add the missing effect"), "{model}");
        let parts = predicted_error_warning(Some(0.244), Some(0.02), Some(44.0)).unwrap();
        assert!(parts.contains("0.244 nT rms"), "{parts}");
        assert!(
            parts.contains("lower bound") && parts.contains("diagnose"),
            "{parts}"
        );
        let spread = predicted_error_warning(Some(0.2), Some(0.02), Some(1.5)).unwrap();
        assert!(spread.contains("with more manoeuvres"), "{spread}");
        assert!(!spread.contains("lower bound"), "{spread}");
    }
}
