//! `magcomp diagnose`: compare the model with the measurements, find where it fails and
//! which physical effect is missing (`crate::diagnose`), optionally with the report page.

use super::args::TraceInput;
use crate::diagnose::{candidates, diagnose, iterate, DiagnoseOptions};
use crate::model_spec::ModelSpec;
use anyhow::{bail, Result};
use std::path::PathBuf;

/// `magcomp diagnose`.
#[derive(clap::Args, Debug, Clone)]
pub struct DiagnoseArgs {
    #[command(flatten)]
    pub input: TraceInput,
    /// Model spec, e.g. `tl16+field+current:cur_pump`.
    #[arg(long, default_value = crate::model_spec::DEFAULT_MODEL)]
    pub model: String,
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
    /// Family-wise false-positive rate over all candidates.
    #[arg(long, default_value_t = 0.01)]
    pub alpha: f64,
    /// Smallest share of the residual variance a significant candidate must explain.
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
    if let Some(dir) = &args.report {
        crate::output::refuse_overwriting(
            &[&args.input.trace],
            &[&dir.join(crate::report::flight_report::REPORT_PAGE)],
        )?;
    }
    let trace = args.input.read()?;
    let model = ModelSpec::parse(&args.model)?;
    let aux = args
        .aux
        .as_deref()
        .map(candidates::AuxSelection::parse)
        .transpose()?;
    if let Some(sel) = &aux {
        candidates::check_selection(&trace, sel)?;
    }
    let opts = DiagnoseOptions {
        alpha: args.alpha,
        min_explained: args.min_explained,
        aux,
        ..Default::default()
    };
    if args.iterate {
        let it = iterate::iterate(&trace, &model, &opts, args.max_steps)?;
        if let Some(dir) = &args.report {
            let path = crate::report::flight_report::write_report(
                &trace,
                &it.models()?,
                it.steps.first().map(|s| &s.diagnosis),
                dir,
            )?;
            if !args.json {
                println!("report written to {}", path.display());
            }
        }
        if args.json {
            println!("{}", it.to_json());
        } else {
            print!("{}", it.table());
        }
        return Ok(());
    }
    let d = diagnose(&trace, &model, &opts)?;
    if let Some(dir) = &args.report {
        let path = crate::report::flight_report::write_report(
            &trace,
            std::slice::from_ref(&model),
            Some(&d),
            dir,
        )?;
        if !args.json {
            println!("report written to {}", path.display());
        }
    }
    if args.json {
        println!("{}", d.to_json());
    } else {
        print!("{}", d.table());
    }
    Ok(())
}
