//! `magcomp report`: the self-contained HTML page. Without `--coeffs`/`--method`, the
//! diagnosis page of one or more models (`report::flight_report`; a trace without
//! position at the `--speed-mps` ground speed); with them, the page of that one
//! compensation (`report::calibration`): an applied calibration checked on this flight,
//! or Tolles–Lawson / the Kalman filter fitted on it.

use super::args::Evaluated;
use super::args::{EstimatorArgs, TraceInput, TuningArgs};
use super::multi::{sets_of, MultiArgs, MultiCoefficients, OneSensorRerun, SensorPlan};
use crate::calibration::coefficients::Method;
use crate::calibration::summary::summarise;
use crate::calibration::EstimatorSettings;
use crate::io::trace::Trace;
use crate::model::spec::ModelSpec;
use crate::multi::joint::apply_each;
use crate::multi::sensors::{parse_pairs, sensor_trace, separation_m, SensorSpec};
use crate::qc::figures::FOURTH_DIFFERENCE_LIMIT_NT;
use crate::report::flight_report::{write_report, REPORT_PAGE};
use crate::report::qc_sheet::SheetInfo;
use crate::report::sensors::{SensorRow, SensorsPage};
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

/// `magcomp report`.
#[derive(clap::Args, Debug, Clone)]
pub struct ReportArgs {
    #[command(flatten)]
    pub input: TraceInput,
    /// Model spec; give it twice (or more) to compare before/after, e.g.
    /// `--model tl16+field --model tl16+field+current:cur_pump`. Default: the default
    /// model (`tl16+field+fluxcal`); with --coeffs, the file's.
    #[arg(long)]
    pub model: Vec<String>,
    /// Evaluate one compensation instead of diagnosing models: kf (the Kalman filter
    /// calibrated on this flight) or tl (classic Tolles–Lawson fitted on it). With
    /// --coeffs, the file decides.
    #[arg(long, value_enum)]
    pub method: Option<Method>,
    /// Check an applied calibration: these coefficients (from `calibrate`) on this
    /// flight, not re-fitted; the page warns at the top when they do not fit it.
    #[arg(long, value_name = "COEFFS.json")]
    pub coeffs: Option<PathBuf>,
    #[command(flatten)]
    pub tuning: TuningArgs,
    /// Several magnetometers: each sensor's own page and an overview page with their
    /// compensated fields and differences. A several-sensor `--coeffs` file brings its own
    /// sensors.
    #[command(flatten)]
    pub multi: MultiArgs,
    /// The QC sheet's 4th-difference noise band (±nT): the page gives the share of samples
    /// within it. 0.05 nT is a common survey-contract figure; give your contract's.
    #[arg(long, value_name = "NT", default_value_t = FOURTH_DIFFERENCE_LIMIT_NT)]
    pub d4_limit_nt: f64,
    /// Output directory (created); the page is DIR/index.html.
    #[arg(
        short = 'o',
        long = "out",
        visible_alias = "output",
        value_name = "DIR"
    )]
    pub out: PathBuf,
}

impl ReportArgs {
    /// Just the trace and the output directory, for code that builds one by hand.
    pub fn new(trace: impl Into<PathBuf>, out: impl Into<PathBuf>) -> Self {
        ReportArgs {
            input: TraceInput::new(trace),
            model: Vec::new(),
            method: None,
            coeffs: None,
            tuning: TuningArgs::default(),
            multi: MultiArgs::default(),
            d4_limit_nt: FOURTH_DIFFERENCE_LIMIT_NT,
            out: out.into(),
        }
    }

    /// What the QC sheet shows of the input: its provenance and the noise band.
    fn sheet_info(&self, trace: &crate::io::trace::Trace, model: &str) -> Result<SheetInfo> {
        if !(self.d4_limit_nt.is_finite() && self.d4_limit_nt > 0.0) {
            bail!(
                "--d4-limit-nt must be a positive number of nT, not {}",
                self.d4_limit_nt
            );
        }
        Ok(SheetInfo {
            this_flight: Some(self.input.provenance(trace, model)?),
            d4_limit_nt: self.d4_limit_nt,
        })
    }

    /// One compensation is evaluated (rather than models diagnosed).
    fn evaluates(&self) -> bool {
        self.coeffs.is_some() || self.method.is_some()
    }
}

impl OneSensorRerun for ReportArgs {
    fn map_mut(&mut self) -> &mut Option<String> {
        &mut self.input.map
    }
    fn multi_mut(&mut self) -> &mut MultiArgs {
        &mut self.multi
    }
}

pub fn run(args: &ReportArgs) -> Result<()> {
    let inputs: Vec<&Path> = std::iter::once(args.input.trace.as_path())
        .chain(args.coeffs.as_deref())
        .collect();
    let page_path = args.out.join(REPORT_PAGE);
    crate::io::output::refuse_overwriting(&inputs, &[&page_path])?;
    let trace = args.input.read()?;
    let multi = match args.coeffs.as_deref() {
        Some(path) => super::multi::load_multi(path)?,
        None => None,
    };
    if args.multi.applies(multi.as_ref()) {
        let coeffs = (args.coeffs.as_deref(), multi);
        let plan = args
            .multi
            .plan_with(&trace, args.input.map.as_deref(), coeffs)?;
        match plan {
            SensorPlan::Today => {}
            SensorPlan::One(map) => return run(&args.as_one_sensor(map)),
            SensorPlan::Several(sensors, multi) => {
                return run_sensors(args, &trace, (&sensors, multi.as_ref()))
            }
        }
    }
    if args.evaluates() {
        if args.model.len() > 1 {
            bail!("--coeffs and --method evaluate one compensation: give at most one --model (several --model compare models by their diagnosis, without these)");
        }
        let est = EstimatorArgs {
            model: args.model.first().cloned(),
            method: args.method,
            tuning: args.tuning.clone(),
        };
        let mut ev = est.evaluate(&trace, args.coeffs.as_deref())?;
        // The page shows the summary's warnings: provenance ones included.
        if let Some(p) = args.coeffs.as_deref() {
            let c = crate::calibration::coefficients::read_coefficients(p)?;
            ev.summary
                .warnings
                .extend(args.input.provenance_warnings(Some(&trace), &c));
        }
        let info = args.sheet_info(&trace, &ev.summary.model)?;
        let path = super::diagnose::write_evaluation(&trace, &ev, &info, &args.out)?;
        super::summary_text::print_warnings(&ev.summary);
        crate::outln!("report written to {}", path.display());
        return Ok(());
    }
    let default = [crate::model::spec::DEFAULT_MODEL.to_string()];
    let given: &[String] = if args.model.is_empty() {
        &default
    } else {
        &args.model
    };
    let models = given
        .iter()
        .map(|m| ModelSpec::parse(m))
        .collect::<Result<Vec<_>>>()?;
    let field = models.iter().any(|m| m.field);
    let info = args.sheet_info(&trace, &models[0].text())?;
    let trace = super::args::diagnosis_trace(trace, args.tuning.speed_mps, field, true)?;
    let path = write_report(&trace, &models, None, &info, &args.out)?;
    crate::outln!("report written to {}", path.display());
    Ok(())
}

/// `report` on several magnetometers (`super::multi::report`).
fn run_sensors(
    args: &ReportArgs,
    trace: &Trace,
    (sensors, multi): (&[SensorSpec], Option<&MultiCoefficients>),
) -> Result<()> {
    if args.model.len() > 1 || args.method.is_some() {
        bail!("a report on several magnetometers shows each sensor's calibration: give at most one --model and no --method");
    }
    let est = EstimatorArgs {
        model: args.model.first().cloned(),
        method: None,
        tuning: args.tuning.clone(),
    };
    let path = several_sensor_pages(
        trace,
        &est.settings(),
        (sensors, args.multi.gradients.as_deref()),
        multi,
        &|model| args.sheet_info(trace, model),
        &args.out,
    )?;
    crate::outln!("report written to {}", path.display());
    Ok(())
}

/// `report --sensors` (or `--coeffs` naming a several-sensor file): each sensor's own
/// calibration page in `out/<sensor>/` (the page `report --coeffs` writes for one sensor),
/// and the overview page (`crate::report::sensors`) in `out/`. `sheet` gives the QC
/// sheet's information for a model.
fn several_sensor_pages(
    trace: &Trace,
    est: &EstimatorSettings,
    (sensors, gradients): (&[SensorSpec], Option<&str>),
    coeffs: Option<&MultiCoefficients>,
    sheet: &dyn Fn(&str) -> Result<SheetInfo>,
    out: &Path,
) -> Result<std::path::PathBuf> {
    let pairs = match gradients {
        Some(g) => parse_pairs(g, sensors)?,
        None => Vec::new(),
    };
    let gradients = pairs
        .iter()
        .map(|&(a, b)| {
            let sep = separation_m(&sensors[a], &sensors[b]).filter(|m| *m > 0.0);
            sep.map(|m| (a, b, m)).with_context(|| {
                format!(
                    "--gradients {}-{}: both positions must be known and apart",
                    sensors[a].name, sensors[b].name
                )
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let (files, joint) = sets_of(trace, est, sensors, coeffs)?;
    let source = match coeffs {
        Some(m) => format!("Coefficients from {}", m.path.display()),
        None => "Calibrated jointly on this flight".into(),
    };
    let mut evaluated = Vec::new();
    for ((s, (flight, comp)), file) in sensors
        .iter()
        .zip(apply_each(trace, est, sensors, &files)?)
        .zip(&files)
    {
        let ev = Evaluated {
            summary: summarise(&flight, &comp),
            flight,
            comp,
            source: format!("{source} (sensor {})", s.name),
            coefficient_provenance: file.provenance.clone(),
            assumed_speed_mps: file.assumed_speed_mps,
        };
        let info = sheet(&ev.summary.model)?;
        super::diagnose::write_evaluation(&sensor_trace(trace, s), &ev, &info, &out.join(&s.name))?;
        for w in &ev.summary.warnings {
            crate::errln!("warning: {}: {w}", s.name);
        }
        evaluated.push(ev);
    }
    let rows = sensors
        .iter()
        .zip(&evaluated)
        .zip(&joint)
        .map(|((s, ev), joint)| SensorRow {
            name: &s.name,
            scalar_column: &s.scalar_column,
            fluxgate: s.fluxgate_name(),
            position_m: s.position_m,
            joint: Some(*joint),
            flight: &ev.flight,
            comp: &ev.comp,
            href: format!("{}/{}", s.name, crate::report::flight_report::REPORT_PAGE),
        })
        .collect();
    let page = crate::report::sensors::build(&SensorsPage {
        source,
        sensors: rows,
        gradients,
    });
    let path = out.join(crate::report::flight_report::REPORT_PAGE);
    page.write(&path)?;
    Ok(path)
}
