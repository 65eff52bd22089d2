//! `magcomp upload`: send a `calibrate` coefficient file to the board as command lines
//! (`crate::upload`).

use crate::coefficients::read_coefficients;
use crate::upload::upload_lines;
use anyhow::{Context, Result};
use std::io::Write;
use std::path::PathBuf;

/// Send a `calibrate` coefficient file to the board (SETCOEF, SETFLUX, SETLAG, SETFTEMP, SAVE lines).
#[derive(clap::Args, Debug, Clone)]
pub struct UploadArgs {
    /// Coefficient file from `magcomp calibrate` (Kalman-filter method).
    #[arg(value_name = "COEFFS.json")]
    pub coeffs: PathBuf,

    /// Where to write the command lines: the board's output/command port (a serial device
    /// set up with `stty`, 921 600 Bd) or `-` for stdout. Watch the replies with
    /// `magcomp monitor` on the same port.
    #[arg(long, default_value = "-", value_name = "PORT")]
    pub to: String,

    /// Model compiled into the board (its coefficients must be this model's).
    #[arg(long, default_value = crate::model_spec::BOARD_MODEL, value_name = "SPEC")]
    pub board_model: String,

    /// Do not end with `SAVE` (the values then last until the board restarts).
    #[arg(long)]
    pub no_save: bool,
}

pub fn run(args: &UploadArgs) -> Result<()> {
    if args.to != "-" {
        crate::output::refuse_overwriting(&[&args.coeffs], &[std::path::Path::new(&args.to)])?;
    }
    let file = read_coefficients(&args.coeffs)?;
    let lines = upload_lines(&file, &args.board_model, !args.no_save)?;
    if let Some(r) = file.rate_crossover.as_ref().filter(|r| r.applied) {
        eprintln!(
            "note: the crossover rate fit's isotropic part ({:.4} s · d|B|/dt, the anomaly read {:.4} s late) has no board coefficient; the board compensates the rest",
            r.fit.coefficients[5], r.fit.coefficients[5]
        );
    }
    let text: String = lines.concat();
    if args.to == "-" {
        std::io::stdout().write_all(text.as_bytes())?;
    } else {
        let mut port = std::fs::OpenOptions::new()
            .write(true)
            .open(&args.to)
            .with_context(|| format!("opening {}", args.to))?;
        port.write_all(text.as_bytes())
            .with_context(|| format!("writing {}", args.to))?;
        eprintln!(
            "sent {} command lines to {} (replies: magcomp monitor {})",
            lines.len(),
            args.to,
            args.to
        );
    }
    Ok(())
}
