//! `magcomp report`: the self-contained HTML page. Without `--coeffs`/`--method`, the
//! diagnosis page of one or more models (`report::flight_report`; a trace without
//! position at the `--speed-mps` ground speed); with them, the page of that one
//! compensation (`report::calibration`): an applied calibration checked on this flight,
//! or Tolles–Lawson / the Kalman filter fitted on it.

use super::args::{EstimatorArgs, TraceInput, TuningArgs};
use crate::calibration::coefficients::Method;
use crate::model::spec::ModelSpec;
use crate::qc::figures::FOURTH_DIFFERENCE_LIMIT_NT;
use crate::report::flight_report::{write_report, REPORT_PAGE};
use crate::report::qc_sheet::SheetInfo;
use anyhow::{bail, Result};
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

pub fn run(args: &ReportArgs) -> Result<()> {
    let inputs: Vec<&Path> = std::iter::once(args.input.trace.as_path())
        .chain(args.coeffs.as_deref())
        .collect();
    let page_path = args.out.join(REPORT_PAGE);
    crate::io::output::refuse_overwriting(&inputs, &[&page_path])?;
    let trace = args.input.read()?;
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
        super::compensate::print_warnings(&ev.summary);
        println!("report written to {}", path.display());
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
    println!("report written to {}", path.display());
    Ok(())
}
