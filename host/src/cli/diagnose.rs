//! `magcomp diagnose`: compare the model with the measurements, find where it fails and
//! which physical effect is missing (`crate::diagnose`), optionally with the report page.
//! With `--coeffs FILE` or `--method`, also the figures and warnings of that compensation
//! on this flight (an applied calibration checked, not re-fitted).

use super::args::{EstimatorArgs, Evaluated, LongFlightArgs, TraceInput};
use super::multi::{MultiArgs, OneSensorRerun, SensorPlan};
use crate::calibration::compensated_trace;
use crate::diagnose::{candidates, diagnose, iterate, DiagnoseOptions, Diagnosis};
use crate::model::spec::{ModelSpec, DEFAULT_MODEL};
use crate::report::calibration::{self, Evaluation};
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

/// `magcomp diagnose`.
#[derive(clap::Args, Debug, Clone)]
pub struct DiagnoseArgs {
    #[command(flatten)]
    pub input: TraceInput,
    /// --model (the model diagnosed), --method and the tuning: with --method or
    /// --coeffs, the compensation whose figures and warnings are shown beside the diagnosis.
    #[command(flatten)]
    pub est: EstimatorArgs,
    #[command(flatten)]
    pub long: LongFlightArgs,
    /// Check an applied calibration: these coefficients (from `calibrate`) on this flight,
    /// not re-fitted (figures and plausibility warnings; `warnings` and `applied` in
    /// --json). The file decides the method and, for the Kalman filter, the model diagnosed.
    #[arg(long, value_name = "COEFFS.json")]
    pub coeffs: Option<PathBuf>,
    /// Print exactly one JSON object on stdout instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Also write the HTML report into this directory.
    #[arg(short = 'o', long, visible_alias = "out", value_name = "DIR")]
    pub report: Option<PathBuf>,
    /// Candidate driver channels, comma-separated globs (case-insensitive), e.g.
    /// `CUR_*,V_*`. Default: every unmapped numeric column except position, navigation,
    /// air data, attitude, time/date, LINE/FLT-like identifiers, other magnetometers
    /// (UNCOMPMAG*, COMPMAG*, mag_*), base stations, fluxgates and constant columns.
    #[arg(long, value_name = "GLOB,...")]
    pub aux: Option<String>,
    /// A channel holding the field without this sensor's interference, e.g. `mag_1_c` (a
    /// compensated stinger): the measurement minus it, where the anomaly cancels, is one
    /// more witness for each candidate (the `ref` column).
    #[arg(long, value_name = "COLUMN")]
    pub reference: Option<String>,
    /// Family-wise false-positive rate over all candidates.
    #[arg(long, default_value_t = 0.01)]
    pub alpha: f64,
    /// Smallest share of the residual variance a significant candidate must explain (the
    /// residual: the filter's one-step innovation, docs/trace-format.md).
    #[arg(long, default_value_t = 0.15)]
    pub min_explained: f64,
    /// Add the best significant candidate and diagnose again, until nothing is significant
    /// (several effects at once); prints the path: model, residual and, with truth, the
    /// error at each step. With `--json`, an array of the steps.
    #[arg(long)]
    pub iterate: bool,
    /// With `--iterate`: the most terms to add.
    #[arg(long, default_value_t = iterate::DEFAULT_MAX_STEPS, value_name = "N")]
    pub max_steps: usize,
    /// `--sensors mag_1,mag_2,…`: discovery across sensors. Each sensor is diagnosed
    /// against every other sensor's compensated field (where the anomaly cancels), and a
    /// term is named for the sensor whose every diagnosis finds it and whose difference with
    /// each other sensor carries it (docs/adding-an-effect.md). One sensor: today's command.
    #[command(flatten)]
    pub multi: MultiArgs,
}

impl OneSensorRerun for DiagnoseArgs {
    fn map_mut(&mut self) -> &mut Option<String> {
        &mut self.input.map
    }
    fn multi_mut(&mut self) -> &mut MultiArgs {
        &mut self.multi
    }
}

impl DiagnoseArgs {
    /// The trace and the default settings, for code that builds one by hand.
    pub fn new(trace: impl Into<PathBuf>) -> Self {
        DiagnoseArgs {
            input: TraceInput::new(trace),
            est: EstimatorArgs::default(),
            long: LongFlightArgs::default(),
            coeffs: None,
            json: false,
            report: None,
            aux: None,
            reference: None,
            alpha: 0.01,
            min_explained: 0.15,
            iterate: false,
            max_steps: iterate::DEFAULT_MAX_STEPS,
            multi: MultiArgs::default(),
        }
    }
}

pub fn run(args: &DiagnoseArgs) -> Result<()> {
    if !(args.alpha > 0.0 && args.alpha < 1.0) {
        bail!("--alpha must be in (0, 1), got {}", args.alpha);
    }
    if !(0.0..1.0).contains(&args.min_explained) {
        bail!(
            "--min-explained must be in [0, 1), got {}",
            args.min_explained
        );
    }
    let evaluates = args.coeffs.is_some() || args.est.method.is_some();
    if args.iterate && evaluates {
        bail!("--iterate adds terms and re-fits the model: it cannot check one compensation (--coeffs, --method); run them separately");
    }
    let inputs: Vec<&Path> = std::iter::once(args.input.trace.as_path())
        .chain(args.coeffs.as_deref())
        .collect();
    if let Some(dir) = &args.report {
        crate::io::output::refuse_overwriting(
            &inputs,
            &[&dir.join(crate::report::flight_report::REPORT_PAGE)],
        )?;
    }
    crate::io::progress::force_progress(args.long.progress);
    let (trace, decimated) = args.input.read_for_calibration(&args.long)?;
    match args.multi.plan(&trace, args.input.map.as_deref())? {
        SensorPlan::Today => {}
        SensorPlan::One(map) => return run(&args.as_one_sensor(map)),
        SensorPlan::Several(sensors, _) => return run_sensors(args, trace, &sensors),
    }
    // The compensation checked first: a bad --coeffs fails before the long diagnosis.
    let evaluated = if evaluates {
        Some(args.est.evaluate(&trace, args.coeffs.as_deref())?)
    } else {
        None
    };
    // With a compensation checked, what it left is diagnosed under the anomaly model
    // alone: its coefficients stay as given, and a deviation term that explains the
    // filter's residual on it (`induced`, `eddy`, …) says what they do not fit.
    let left = match &evaluated {
        Some(ev) => Some(compensated_trace(&trace, &ev.flight, &ev.comp)?),
        None => None,
    };
    let model = match &left {
        Some(_) => ModelSpec::parse("field")?,
        None => ModelSpec::parse(args.est.model.as_deref().unwrap_or(DEFAULT_MODEL))?,
    };
    // Without position, the diagnosis models the anomaly at --speed-mps, else at the
    // coefficient file's assumed speed, as its compensation did (an evaluated Kalman
    // filter has said so already).
    let speed = args
        .est
        .tuning
        .speed_mps
        .or(evaluated.as_ref().and_then(|ev| ev.assumed_speed_mps));
    let warn = evaluated
        .as_ref()
        .is_none_or(|ev| ev.comp.method != Some(crate::calibration::coefficients::Method::Kf));
    let (left, trace) = match left {
        Some(r) => (
            Some(super::args::diagnosis_trace(r, speed, model.field, warn)?),
            trace,
        ),
        None => (
            None,
            super::args::diagnosis_trace(trace, speed, model.field, warn)?,
        ),
    };
    let diagnosed = left.as_ref().unwrap_or(&trace);
    let opts = diagnose_options(args, &trace)?;
    if args.iterate {
        let stage = crate::io::progress::Stage::new("diagnosis, iterated");
        let it = iterate::iterate(&trace, &model, &opts, args.max_steps)?;
        drop(stage);
        if let Some(dir) = &args.report {
            let path = crate::report::flight_report::write_report(
                &trace,
                &it.models()?,
                it.steps.first().map(|s| &s.diagnosis),
                &sheet_info(&args.input, &trace, &model.text()),
                dir,
            )?;
            if !args.json {
                crate::outln!("report written to {}", path.display());
            }
        }
        if args.json {
            crate::outln!("{}", it.to_json());
        } else {
            crate::out!("{}", it.table());
        }
        return Ok(());
    }
    let stage = crate::io::progress::Stage::new("diagnosis (candidate terms and their tests)");
    let d = diagnose(diagnosed, &model, &opts)?;
    drop(stage);
    if let Some(dir) = &args.report {
        let info = sheet_info(&args.input, &trace, &model.text());
        let path = match &evaluated {
            Some(ev) => write_evaluation(&trace, ev, &info, dir)?,
            None => crate::report::flight_report::write_report(
                &trace,
                std::slice::from_ref(&model),
                Some(&d),
                &info,
                dir,
            )?,
        };
        if !args.json {
            crate::outln!("report written to {}", path.display());
        }
    }
    if args.json {
        crate::outln!("{}", json(&d, evaluated.as_ref(), decimated.as_ref())?);
    } else {
        match &evaluated {
            Some(_) => crate::out!("{}", applied_table(&d)),
            None => crate::out!("{}", d.table()),
        }
        if let Some(ev) = &evaluated {
            crate::outln!("compensation checked ({}):", ev.source);
            super::summary_text::print_summary(&ev.summary);
        }
    }
    if let Some(ev) = &evaluated {
        super::summary_text::print_warnings(&ev.summary);
    }
    Ok(())
}

/// The diagnosis table of what a checked compensation left: a significant term is interference the
/// coefficients leave, not a term to add to the anomaly-only model diagnosed.
fn applied_table(d: &Diagnosis) -> String {
    let mut out = String::new();
    for line in d.table().lines() {
        if line.starts_with("suggestion:") {
            if let Some(c) = d.candidates.iter().find(|c| c.significant) {
                out.push_str(&format!(
                    "the applied coefficients leave interference that `{}` explains ({:.0} % of what they left): they do not fit this flight; calibrate on this aircraft\n",
                    c.term,
                    100.0 * c.explained_fraction
                ));
            }
        } else if line.starts_with("no candidate is significant") {
            out.push_str("no candidate is significant: the applied coefficients leave no interference a term explains\n");
        } else {
            out.push_str(line);
            out.push('\n');
        }
    }
    out
}

/// The diagnosis as JSON with `warnings` (the compensation's when one is checked, else
/// the filter's) and, when one is checked, `applied` (its summary, as `compensate --json`).
fn json(
    d: &Diagnosis,
    evaluated: Option<&Evaluated>,
    decimated: Option<&crate::flight::input::Decimation>,
) -> Result<String> {
    let mut v = serde_json::to_value(d)?;
    let warnings = match evaluated {
        Some(ev) => ev.summary.warnings.clone(),
        None => d.run.warnings.clone(),
    };
    if let Some(obj) = v.as_object_mut() {
        obj.insert("warnings".into(), serde_json::to_value(warnings)?);
        if let Some(dec) = decimated {
            obj.insert("decimated".into(), serde_json::to_value(dec)?);
        }
        if let Some(ev) = evaluated {
            let mut applied = serde_json::to_value(&ev.summary)?;
            if let Some(a) = applied.as_object_mut() {
                a.insert("source".into(), ev.source.clone().into());
            }
            obj.insert("applied".into(), applied);
        }
    }
    Ok(serde_json::to_string_pretty(&v)?)
}

/// The QC sheet's knowledge of the input (its provenance when it can be hashed) with the
/// default noise band.
fn sheet_info(
    input: &super::args::TraceInput,
    trace: &crate::io::trace::Trace,
    model: &str,
) -> crate::report::qc_sheet::SheetInfo {
    crate::report::qc_sheet::SheetInfo {
        this_flight: input.provenance(trace, model).ok(),
        ..Default::default()
    }
}

/// The page of the checked compensation (`report --coeffs`'s).
pub(super) fn write_evaluation(
    trace: &crate::io::trace::Trace,
    ev: &Evaluated,
    info: &crate::report::qc_sheet::SheetInfo,
    dir: &Path,
) -> Result<PathBuf> {
    let page = calibration::build(
        trace,
        &Evaluation {
            flight: &ev.flight,
            comp: &ev.comp,
            summary: &ev.summary,
            source: ev.source.clone(),
            info,
            coefficient_provenance: ev.coefficient_provenance.as_ref(),
        },
    );
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create report directory {}", dir.display()))?;
    let path = dir.join(crate::report::flight_report::REPORT_PAGE);
    page.write(&path)?;
    Ok(path)
}

/// `diagnose --sensors`: each sensor against the others' compensated fields
/// (`crate::diagnose::sensors`).
fn run_sensors(
    args: &DiagnoseArgs,
    trace: crate::io::trace::Trace,
    sensors: &[crate::multi::sensors::SensorSpec],
) -> Result<()> {
    if args.coeffs.is_some() || args.iterate || args.report.is_some() || args.reference.is_some() {
        bail!(
            "diagnose --sensors takes each other sensor as the reference and diagnoses the \
             model given: run --coeffs, --iterate, --report and --reference on one sensor"
        );
    }
    if args.multi.gradients.is_some() {
        bail!("--gradients belongs to compensate: diagnose --sensors writes no gradients");
    }
    let model = ModelSpec::parse(args.est.model.as_deref().unwrap_or(DEFAULT_MODEL))?;
    let trace = super::args::diagnosis_trace(trace, args.est.tuning.speed_mps, model.field, true)?;
    let opts = diagnose_options(args, &trace)?;
    let stage = crate::io::progress::Stage::new("diagnosis of each sensor against the others");
    let findings = crate::diagnose::sensors::diagnose_sensors(
        &trace,
        sensors,
        &model,
        &opts,
        &args.est.settings(),
    )?;
    drop(stage);
    if args.json {
        crate::outln!("{}", crate::diagnose::sensors::to_json(&findings));
        return Ok(());
    }
    crate::outln!(
        "discovery across sensors, model {}: each sensor against the others' compensated fields",
        model.text()
    );
    for f in &findings {
        let named = if f.named.is_empty() {
            "nothing".to_string()
        } else {
            f.named.join(", ")
        };
        crate::outln!("{}: named {named}", f.sensor);
        for (other, d) in &f.against {
            let significant: Vec<String> = (d.candidates.iter())
                .filter(|c| c.significant)
                .map(|c| format!("{} ({})", c.term, c.evidence.join("+")))
                .collect();
            crate::outln!(
                "  against {other}: residual {:.3} nT; significant: {}",
                d.residual_rms_nt,
                if significant.is_empty() {
                    "none".to_string()
                } else {
                    significant.join(", ")
                }
            );
        }
    }
    Ok(())
}

/// The diagnosis settings the arguments give; an `--aux` selection that matches no column
/// of `trace` is refused.
fn diagnose_options(
    args: &DiagnoseArgs,
    trace: &crate::io::trace::Trace,
) -> Result<DiagnoseOptions> {
    let aux = args
        .aux
        .as_deref()
        .map(candidates::AuxSelection::parse)
        .transpose()?;
    if let Some(sel) = &aux {
        candidates::check_selection(trace, sel)?;
    }
    Ok(DiagnoseOptions {
        alpha: args.alpha,
        min_explained: args.min_explained,
        aux,
        reference: args.reference.clone(),
        ..Default::default()
    })
}
