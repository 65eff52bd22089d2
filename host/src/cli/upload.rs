//! `magcomp upload`: send a `calibrate` coefficient file to the board as command lines
//! (`crate::board::upload`), each acknowledged, resent when damaged, and read back
//! (`crate::board::link`).

use crate::board::link::{command_line, upload, BoardLink, ExchangeOptions, LineSource};
use crate::board::upload::{sensor_commands, upload_commands};
use crate::calibration::coefficients::read_coefficients;
use anyhow::{bail, Context, Result};
use std::io::Write;
use std::os::unix::fs::FileTypeExt;
use std::os::unix::net::UnixStream;
use std::path::PathBuf;
use std::time::Duration;

/// Send a `calibrate` coefficient file to the board (SETCOEF, SETFLUX, SETLAG, SETFTEMP, SAVE
/// lines), each line acknowledged by the board, then read back.
#[derive(clap::Args, Debug, Clone)]
pub struct UploadArgs {
    /// Coefficient file from `magcomp calibrate` (Kalman-filter method).
    #[arg(value_name = "COEFFS.json")]
    pub coeffs: PathBuf,

    /// The board's output/command port: a serial device (set up with `stty ... raw`,
    /// 921 600 Bd), a unix socket (ser2net, socat, QEMU), or `-` to print the lines to
    /// stdout. On a port every line must be acknowledged (resent up to 3 times when it
    /// arrives damaged or unanswered), SAVE is sent only then, and every value is read back
    /// (see README.md, "Uploading coefficients").
    #[arg(long, default_value = "-", value_name = "PORT")]
    pub to: String,

    /// Model compiled into the board (its coefficients must be this model's). Default:
    /// the coefficient file's model, its input corrections (fluxcal, lag, fluxtemp) aside.
    #[arg(long, value_name = "SPEC")]
    pub board_model: Option<String>,

    /// Do not end with `SAVE` (the values then last until the board restarts).
    #[arg(long)]
    pub no_save: bool,

    /// Write the lines to the port without reading the board's replies (no retry, no
    /// read-back): only for a port whose replies cannot be read.
    #[arg(long)]
    pub no_verify: bool,

    /// `--to` is a regular file: write the lines into it (replacing its content), for a
    /// board loaded from a file. Without this a regular file is refused: it is not a port.
    #[arg(long)]
    pub to_file: bool,

    /// How long to wait for the board's reply to a line before ending it with a bare
    /// line break and resending it (SAVE: 5× this).
    #[arg(long, default_value_t = 2.0, value_name = "S")]
    pub reply_timeout_s: f64,
}

/// The port: written by the exchange, its clone read by the line thread.
enum Port {
    Tty(std::fs::File),
    Socket(UnixStream),
}

fn open_port(path: &str, read: bool) -> Result<Port> {
    let meta = std::fs::metadata(path).with_context(|| format!("opening {path}"))?;
    if meta.file_type().is_socket() {
        return Ok(Port::Socket(
            UnixStream::connect(path).with_context(|| format!("connecting to {path}"))?,
        ));
    }
    if meta.is_file() {
        bail!("{path} is a regular file, not the board's port: nothing can answer there (to write the lines into it, replacing its content, add --to-file)");
    }
    Ok(Port::Tty(
        std::fs::OpenOptions::new()
            .read(read)
            .write(true)
            .open(path)
            .with_context(|| format!("opening {path}"))?,
    ))
}

pub fn run(args: &UploadArgs) -> Result<()> {
    if args.to != "-" {
        crate::io::output::refuse_overwriting(&[&args.coeffs], &[std::path::Path::new(&args.to)])?;
    }
    if !(args.reply_timeout_s.is_finite() && args.reply_timeout_s > 0.0) {
        bail!(
            "--reply-timeout-s must be a positive number of seconds, not {}",
            args.reply_timeout_s
        );
    }
    if args.to_file {
        crate::io::output::check_writable(std::path::Path::new(&args.to))?;
    }
    // a several-sensor file (`calibrate --sensors`): each sensor to its counter channel
    let files = match crate::cli::multi::load_multi(&args.coeffs)? {
        Some(m) => m.sets,
        None => vec![read_coefficients(&args.coeffs)?],
    };
    let file = &files[0];
    let board_model = match &args.board_model {
        Some(m) => m.clone(),
        None => filter_model(&file.model)?,
    };
    let cmds = match files.len() {
        1 => upload_commands(file, &board_model, !args.no_save)?,
        _ => sensor_commands(&files, &board_model, !args.no_save)?,
    };
    if let Some(r) = file.rate_crossover.as_ref().filter(|r| r.applied) {
        crate::errln!(
            "note: the crossover rate fit's isotropic part ({:.4} s · d|B|/dt, the anomaly read {:.4} s late) has no board coefficient; the board compensates the rest",
            r.fit.coefficients[5], r.fit.coefficients[5]
        );
    }
    let text: String = cmds
        .iter()
        .map(command_line)
        .collect::<Result<Vec<_>>>()?
        .concat();
    if args.to == "-" {
        std::io::stdout().write_all(text.as_bytes())?;
        return Ok(());
    }
    if args.to_file {
        // Written whole and renamed (or through a device): never the start of an old file
        // left behind its end, as an open without truncation did to a flight trace.
        crate::io::output::write_file(std::path::Path::new(&args.to), &text)?;
        crate::errln!("wrote {} command lines to {}", cmds.len(), args.to);
        return Ok(());
    }
    if args.no_verify {
        let mut port: Box<dyn Write> = match open_port(&args.to, false)? {
            Port::Tty(f) => Box::new(f),
            Port::Socket(s) => Box::new(s),
        };
        port.write_all(text.as_bytes())
            .and_then(|()| port.flush())
            .with_context(|| format!("writing {}", args.to))?;
        crate::errln!(
            "sent {} command lines to {} unverified (replies: magcomp monitor {})",
            cmds.len(),
            args.to,
            args.to
        );
        return Ok(());
    }
    let opts = ExchangeOptions {
        reply_timeout: Duration::from_secs_f64(args.reply_timeout_s),
        ..ExchangeOptions::default()
    };
    let (writer, lines): (Box<dyn Write>, LineSource) = match open_port(&args.to, true)? {
        Port::Tty(f) => {
            let r = f
                .try_clone()
                .with_context(|| format!("opening {}", args.to))?;
            (Box::new(f), LineSource::spawn(r))
        }
        Port::Socket(s) => {
            let r = s
                .try_clone()
                .with_context(|| format!("opening {}", args.to))?;
            (Box::new(s), LineSource::spawn(r))
        }
    };
    let mut link = BoardLink::new(writer, lines, opts);
    let s = upload(&mut link, &cmds).with_context(|| format!("uploading to {}", args.to))?;
    let e = s.exchange;
    crate::outln!(
        "sent {} lines to {}: {} acknowledged, {} resends ({} damaged, {} unanswered){}; read-back OK: {} of {} values equal the file ({} resends); survey mode on with this set",
        e.lines_sent,
        args.to,
        e.acknowledged,
        e.resends,
        e.transport_errors,
        e.timeouts,
        if args.no_save { ", not saved (--no-save)" } else { ", saved" },
        s.read_back_ok,
        s.read_back.lines_sent,
        s.read_back.resends
    );
    Ok(())
}

/// A model's filter terms: what the board's compiled model must be for its coefficients
/// (`fluxcal`, `lag`, `fluxtemp` correct the inputs and add no filter state).
fn filter_model(model: &str) -> Result<String> {
    use crate::model::spec::{ModelSpec, BOARD_COEFFICIENTS, BOARD_MODEL};
    let filter = ModelSpec::parse(model)?.without_input_corrections().text();
    // The board's own model and its witnessed form load into the board's 17-value vector.
    if filter == ModelSpec::parse(BOARD_MODEL)?.text()
        || filter == ModelSpec::parse(BOARD_COEFFICIENTS)?.text()
    {
        return Ok(BOARD_COEFFICIENTS.to_string());
    }
    Ok(filter)
}
