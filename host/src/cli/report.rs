//! `magcomp report`: the self-contained HTML page for one or more models
//! (`crate::report::flight_report`).

use super::args::TraceInput;
use crate::model_spec::ModelSpec;
use crate::report::flight_report::{write_report, REPORT_PAGE};
use anyhow::Result;
use std::path::PathBuf;

/// `magcomp report`.
#[derive(clap::Args, Debug, Clone)]
pub struct ReportArgs {
    #[command(flatten)]
    pub input: TraceInput,
    /// Model spec; give it twice (or more) to compare before/after, e.g.
    /// `--model tl16+field --model tl16+field+current:cur_pump`. Default: the default
    /// model (`tl16+field`).
    #[arg(long)]
    pub model: Vec<String>,
    /// Output directory (created); the page is DIR/index.html.
    #[arg(
        short = 'o',
        long = "out",
        visible_alias = "output",
        value_name = "DIR"
    )]
    pub out: PathBuf,
}

pub fn run(args: &ReportArgs) -> Result<()> {
    crate::output::refuse_overwriting(&[&args.input.trace], &[&args.out.join(REPORT_PAGE)])?;
    let trace = args.input.read()?;
    let default = [crate::model_spec::DEFAULT_MODEL.to_string()];
    let given: &[String] = if args.model.is_empty() {
        &default
    } else {
        &args.model
    };
    let models = given
        .iter()
        .map(|m| ModelSpec::parse(m))
        .collect::<Result<Vec<_>>>()?;
    let path = write_report(&trace, &models, None, &args.out)?;
    println!("report written to {}", path.display());
    Ok(())
}
