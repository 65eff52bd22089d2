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
    if let Some(p) = file.predicted_error_nt.filter(|p| *p > SURVEY_TOLERANCE_NT) {
        // The predicted error is the coefficients' uncertainty and the model error together;
        // the advice depends on which dominates.
        let advice = match file.model_error_nt {
            Some(m) if m > 0.7 * p => {
                "most of it is signal the model cannot follow: add the missing effect \
                 (`magcomp diagnose`)"
            }
            _ => "fly the pattern higher, over quieter ground, or with more manoeuvres",
        };
        s.warnings.push(format!(
            "the predicted error of this calibration is {p:.3} nT rms, more than a \
             survey's {SURVEY_TOLERANCE_NT} nT: {advice}"
        ));
    }
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
