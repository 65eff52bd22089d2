//! `magcomp monitor`: decode and show the board's output stream live (a port, a file, or
//! `-`), optionally saving the records (`crate::board::monitor`), or as a chart recorder in
//! the browser (`--web`, `crate::live`).

use crate::board::monitor::{monitor_stream, Display, MonitorStats};
use anyhow::{Context, Result};
use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::time::Duration;

/// Decode and show the compensator's output stream live (values, flags, rates, errors).
#[derive(clap::Args, Clone, Debug)]
pub struct MonitorArgs {
    /// Serial device (configure it with `stty`), a recorded file, `-` for stdin, or (with
    /// `--web`) `tcp:HOST:PORT`.
    #[arg(value_name = "PORT_OR_FILE")]
    pub input: String,

    /// Save the decoded records as a trace-like CSV
    /// (t,mag,interference,compensated,anomaly,innovation,sigma,flags,seq); with `--web`, the
    /// first input's.
    #[arg(short = 'o', long, visible_alias = "out", value_name = "TRACE.csv")]
    pub save: Option<PathBuf>,

    /// Refresh period on a terminal (wall-clock s); summary period otherwise (record s).
    #[arg(long, default_value_t = 1.0, value_name = "S")]
    pub interval_s: f64,

    /// No live output: only the final summary.
    #[arg(long)]
    pub quiet: bool,

    /// Keep reading at the end of a file that a logger is still writing (stop with Ctrl-C).
    #[arg(long)]
    pub follow: bool,

    /// Serve a live chart-recorder page instead of printing (open the printed address in a
    /// browser; stop with Ctrl-C). A lost port is reopened every second. With the board's
    /// `$MCRAW` lines (`RAW,ON`) it also draws height and GPS state and shows the FOM table
    /// once a calibration pattern has ended (docs/protocols.md §10d′).
    #[arg(long)]
    pub web: bool,

    /// With `--web`: address to listen on (port 0 picks a free one; the address is printed).
    #[arg(long, default_value = "127.0.0.1:8022", value_name = "ADDR:PORT")]
    pub listen: String,

    /// With `--web`: play a recorded file at its records' own pace (their time stamps).
    #[arg(long)]
    pub realtime: bool,

    /// With `--web`: acceptance band of the 4th difference of the compensated field (± nT,
    /// d4 normalised by 1/16).
    #[arg(long, default_value_t = crate::live::feed::D4_BAND_NT, value_name = "NT")]
    pub d4_band_nt: f64,

    /// With `--web`: `stty` settings for a serial device, applied at every (re)open (a USB
    /// adapter pulled and put back loses them), e.g. "115200 raw -echo".
    #[arg(long, value_name = "SETTINGS")]
    pub stty: Option<String>,

    /// With `--web`: another board output to follow (a further sensor), drawn beside the
    /// first with its gradient to it; repeatable.
    #[arg(long, value_name = "PORT_OR_FILE")]
    pub also: Vec<String>,

    /// With `--web`: records kept on the strips.
    #[arg(long, default_value_t = 1200, value_name = "N")]
    pub window_records: usize,
}

/// `--web`: serve the live page until stopped.
fn run_web(args: &MonitorArgs) -> Result<MonitorStats> {
    anyhow::ensure!(
        !args.quiet,
        "--web shows the stream in the browser: --quiet is for the text monitor"
    );
    anyhow::ensure!(
        args.d4_band_nt.is_finite() && args.d4_band_nt > 0.0,
        "--d4-band-nt must be > 0"
    );
    anyhow::ensure!(
        (10..=100_000).contains(&args.window_records),
        "--window-records must be 10..=100000"
    );
    let inputs = std::iter::once(&args.input)
        .chain(&args.also)
        .map(|name| crate::live::source::Input {
            name: name.clone(),
            follow: args.follow,
            realtime: args.realtime,
            stty: args.stty.clone(),
        })
        .collect();
    let settings = crate::live::server::PageSettings {
        d4_band_nt: args.d4_band_nt,
        window_records: args.window_records,
    };
    // The first input's records, as the text monitor saves them.
    let save = open_save(args)?.map(|w| Box::new(w) as Box<dyn Write + Send>);
    crate::live::server::serve(inputs, save, &args.listen, &settings)?;
    Ok(MonitorStats::default())
}

pub fn run(args: &MonitorArgs) -> Result<MonitorStats> {
    if args.web {
        return run_web(args);
    }
    anyhow::ensure!(
        !args.realtime && args.stty.is_none() && args.also.is_empty(),
        "--realtime, --stty and --also are for --web (set a port up with `stty` for the text monitor)"
    );
    anyhow::ensure!(
        args.interval_s.is_finite() && args.interval_s > 0.0,
        "--interval-s must be > 0"
    );
    let stdout = std::io::stdout();
    let display = if args.quiet {
        Display::Quiet
    } else if stdout.is_terminal() {
        Display::Live(Duration::from_secs_f64(args.interval_s))
    } else {
        Display::Summary(args.interval_s)
    };
    let mut save_file = open_save(args)?;
    let save: Option<&mut dyn Write> = save_file.as_mut().map(|w| w as &mut dyn Write);
    let mut out = stdout.lock();
    let stats = if args.input == "-" {
        monitor_stream(
            std::io::stdin().lock(),
            "stdin",
            display,
            args.follow,
            &mut out,
            save,
        )?
    } else {
        let f =
            std::fs::File::open(&args.input).with_context(|| format!("opening {}", args.input))?;
        monitor_stream(f, &args.input, display, args.follow, &mut out, save)?
    };
    if let (Some(w), Some(p)) = (save_file.as_mut(), &args.save) {
        w.flush()
            .with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(stats)
}

/// `--save`: the CSV opened for appending, its header skipped when it has rows already.
fn open_save(args: &MonitorArgs) -> Result<Option<SkipLines<std::io::BufWriter<std::fs::File>>>> {
    let Some(p) = &args.save else {
        return Ok(None);
    };
    let input = std::path::Path::new(&args.input);
    let inputs: &[&std::path::Path] = if args.input == "-" { &[] } else { &[input] };
    crate::io::output::check_outputs(inputs, &[p])?;
    // A file that has rows already keeps its one header: the new session's three header
    // lines (two comments and the column names) are not repeated in the middle of it.
    let has_rows = std::fs::metadata(p).is_ok_and(|m| m.is_file() && m.len() > 0);
    // Appended, as documented: a restarted monitor must not empty the log it adds to.
    let file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(p)
        .with_context(|| format!("opening {}", p.display()))?;
    Ok(Some(SkipLines {
        inner: std::io::BufWriter::new(file),
        skip: if has_rows { 3 } else { 0 },
    }))
}

/// Passes writes through after dropping the first `skip` lines.
struct SkipLines<W: Write> {
    inner: W,
    skip: usize,
}

impl<W: Write> Write for SkipLines<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let mut rest = buf;
        while self.skip > 0 {
            match rest.iter().position(|&b| b == b'\n') {
                Some(i) => {
                    self.skip -= 1;
                    rest = &rest[i + 1..];
                }
                None => return Ok(buf.len()),
            }
        }
        self.inner.write_all(rest)?;
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}
