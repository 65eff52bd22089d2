//! `magcomp demo`: the whole job on built-in simulated data — calibration flight, survey
//! flight, Kalman filter and Tolles–Lawson side by side against the simulator's truth.

use crate::calibration::summary::{summarise, write_output_csv};
use crate::calibration::{compensate_trace, EstimatorSettings, Method};
use crate::io::trace::write_trace;
use crate::sim::{simulate, FlightKind, Geology, GeologyPreset, SimConfig};
use anyhow::{Context, Result};
use std::path::PathBuf;

#[derive(clap::Args, Clone, Debug)]
pub struct DemoArgs {
    /// Folder for the simulated traces, coefficients and compensated outputs.
    #[arg(long, default_value = "demo-out", value_name = "DIR")]
    pub out: PathBuf,
    /// Seed of the simulated aircraft, geology and flights.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// Simulator physics: `classic` or `broad` (issue 10's wider aircraft, fluxgate and
    /// navigation errors, no base station; see `magcomp simulate --physics`).
    #[arg(long, default_value = "classic", value_name = "PROFILE")]
    pub physics: String,
}

/// The method as named (no cross-check: the demo shows each method on its own).
fn est(method: Method) -> EstimatorSettings {
    EstimatorSettings {
        method,
        ..EstimatorSettings::default()
    }
}

fn fmt(v: Option<f64>, d: usize) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{x:.d$}"),
        _ => "-".into(),
    }
}

pub fn run(args: &DemoArgs) -> Result<()> {
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    // One geology for both flights: the broad profile's per-flight anomaly scaling is off.
    let profile = match crate::sim::Physics::parse(&args.physics)? {
        crate::sim::Physics::Classic => SimConfig::default(),
        crate::sim::Physics::Broad => SimConfig::broad(args.seed),
    };
    let base = SimConfig {
        seed: args.seed,
        geology: Geology::preset(GeologyPreset::Moderate),
        anomaly_pp_nt: None,
        ..profile
    };
    crate::outln!("== 1. Simulated flights (seed {}) ==", args.seed);
    let cal_cfg = SimConfig {
        flight: FlightKind::Calibration,
        cal_altitude_m: 3000.0,
        ..base.clone()
    };
    let cal = simulate(&cal_cfg)?;
    let cal_path = args.out.join("calibration.csv");
    write_trace(&cal_path, &cal)?;
    crate::outln!(
        "calibration: cloverleaf at 3000 m, 4 headings x roll/pitch/yaw, {} samples at 10 Hz -> {}",
        cal.len(),
        cal_path.display()
    );
    let survey_cfg = SimConfig {
        flight: FlightKind::Survey,
        survey_altitude_m: 300.0,
        ..base.clone()
    };
    let survey = simulate(&survey_cfg)?;
    let survey_path = args.out.join("survey.csv");
    write_trace(&survey_path, &survey)?;
    crate::outln!(
        "survey: lines 0/180 deg at 300 m over moderate geology, {} samples -> {}",
        survey.len(),
        survey_path.display()
    );

    crate::outln!("\n== 2. Calibration flight: calibrate and compensate ==");
    let mut rows = Vec::new();
    let mut coeffs = Vec::new();
    for method in [Method::Kf, Method::Tl] {
        let (flight, comp) = compensate_trace(&cal, &est(method), None, false)?;
        let s = summarise(&flight, &comp);
        let name = if method == Method::Kf { "kf" } else { "tl" };
        write_output_csv(
            &args.out.join(format!("calibration-{name}.csv")),
            &flight,
            &comp,
            &[],
        )?;
        let file = comp.coefficients.clone().context("no coefficients")?;
        crate::io::output::write_file(
            &args.out.join(format!("coeffs-{name}.json")),
            serde_json::to_string_pretty(&file)?,
        )?;
        coeffs.push(file);
        rows.push((format!("{name} ({})", s.model), s));
    }
    crate::outln!(
        "{:<22} {:>10} {:>10} {:>12} {:>12} {:>14}",
        "method",
        "FOM nT",
        "IR",
        "error nT",
        "oracle nT",
        "predicted nT"
    );
    for (n, s) in &rows {
        crate::outln!(
            "{:<22} {:>10} {:>10} {:>12} {:>12} {:>14}",
            n,
            fmt(s.fom_nt, 3),
            fmt(s.improvement_ratio, 1),
            fmt(s.error_rms_nt, 4),
            fmt(s.oracle_floor_nt, 4),
            fmt(s.predicted_error_nt, 4)
        );
    }
    crate::outln!(
        "(predicted: the KF's own figure for how well the flight determined the \
         interference, from its covariance; no truth needed)"
    );

    crate::outln!("\n== 3. Survey flight: apply the calibration coefficients ==");
    crate::outln!(
        "{:<22} {:>12} {:>14}",
        "method",
        "error nT",
        "uncompensated"
    );
    for file in &coeffs {
        let (flight, comp) = compensate_trace(&survey, &est(file.method), Some(file), false)?;
        let s = summarise(&flight, &comp);
        let name = if file.method == Method::Kf {
            "kf"
        } else {
            "tl"
        };
        write_output_csv(
            &args.out.join(format!("survey-{name}.csv")),
            &flight,
            &comp,
            &[],
        )?;
        let raw = flight
            .truth_interference_nt
            .as_ref()
            .map(|t| crate::qc::figures::rms_demeaned(t));
        crate::outln!(
            "{:<22} {:>12} {:>14}",
            format!("{name} ({})", s.model),
            fmt(s.error_rms_nt, 4),
            fmt(raw, 3)
        );
    }
    discovery_loop(args)?;
    crate::outln!("\noutputs in {}", args.out.display());
    Ok(())
}

/// Issue 4's loop: a flight whose interference holds an effect the model does not know
/// (a pump current), diagnosed, the named term added, the error against truth falling.
fn discovery_loop(args: &DemoArgs) -> Result<()> {
    use crate::diagnose::{diagnose, DiagnoseOptions};
    use crate::model::spec::ModelSpec;
    crate::outln!("\n== 4. Model discovery: a flight with an effect the model does not know ==");
    let cfg = SimConfig {
        seed: args.seed,
        hidden: vec![crate::sim::parse_hidden("current:cur_pump")?],
        decoys: vec!["cur_fan".into(), "cur_avionics".into()],
        ..Default::default()
    };
    let trace = simulate(&cfg)?;
    let path = args.out.join("hidden-effect.csv");
    write_trace(&path, &trace)?;
    crate::outln!(
        "calibration flight with a hidden pump current and two decoy channels -> {}",
        path.display()
    );
    let model = ModelSpec::parse("tl16+field")?;
    let d = diagnose(&trace, &model, &DiagnoseOptions::default())?;
    crate::outln!("{}", d.table());
    let named = d
        .candidates
        .iter()
        .find(|c| c.significant)
        .context("no significant candidate")?;
    let better = model.with(&named.term)?;
    let mut rows = Vec::new();
    for spec in [&model, &better] {
        let e = EstimatorSettings {
            model: spec.text(),
            ..est(Method::Kf)
        };
        let (flight, comp) = compensate_trace(&trace, &e, None, false)?;
        rows.push((spec.text(), summarise(&flight, &comp)));
    }
    crate::outln!(
        "{:<36} {:>12} {:>10} {:>12}",
        "model",
        "band rms nT",
        "FOM nT",
        "error nT"
    );
    for (m, s) in &rows {
        crate::outln!(
            "{:<36} {:>12} {:>10} {:>12}",
            m,
            fmt(Some(s.compensated_band_rms_nt), 4),
            fmt(s.fom_nt, 3),
            fmt(s.error_rms_nt, 4)
        );
    }
    let report_dir = args.out.join("report");
    let page = crate::report::flight_report::write_report(
        &trace,
        &[model, better],
        Some(&d),
        &Default::default(),
        &report_dir,
    )?;
    crate::outln!("report with plots (before/after): {}", page.display());
    Ok(())
}
