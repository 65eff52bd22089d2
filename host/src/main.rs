//! `magcomp`: airborne magnetometer compensation on the ground, with the same core that
//! flies on the board.

use anyhow::{Context, Result};
use clap::parser::ValueSource;
use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};
use magcomp::commands::{
    compensate_trace, read_coefficients, summarise, write_output_csv, EstimatorArgs, Summary,
    TraceInput, SURVEY_TOLERANCE_NT,
};
use magcomp::output::refuse_overwriting;
use magcomp::sim::SimulateArgs;
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "magcomp",
    version,
    about = "Airborne magnetometer compensation: Tolles–Lawson deviation + stochastic anomaly model, estimated by a Kalman filter (Karshakov & Kharichkin)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate a calibration and/or survey flight with known truth (and, with --capture,
    /// the raw bytes its sensors would have sent).
    Simulate {
        #[command(flatten)]
        sim: Box<SimulateArgs>,
        #[command(flatten)]
        capture: Box<magcomp::capture_sim::CaptureArgs>,
    },
    /// Estimate the deviation coefficients (with 1σ) from a calibration flight.
    Calibrate(Box<CalibrateArgs>),
    /// Remove the aircraft interference from a flight.
    Compensate(Box<CompensateArgs>),
    /// Decode a GPS receiver log with the board's NMEA reader (one JSON object per line).
    Nmea {
        /// NMEA log file (`-` for stdin).
        file: PathBuf,
    },
    /// Compare the model with the measurements, find where it fails and which physical
    /// effect is missing (ranked, with significance).
    Diagnose(Box<magcomp::diagnose::DiagnoseArgs>),
    /// Write a self-contained HTML report with plots for one or more models.
    Report(Box<magcomp::report::flight_report::ReportArgs>),
    /// Run a raw sensor capture through the board's parsers, aligner and filter.
    Replay(magcomp::replay::ReplayArgs),
    /// Decode and show the board's output stream live (a port, a file, or `-`).
    Monitor(magcomp::monitor::MonitorArgs),
    /// Send a `calibrate` coefficient file to the board (SETCOEF, SETFLUX, SAVE lines).
    Upload(magcomp::upload::UploadArgs),
    /// End-to-end demonstration on built-in simulated data (nothing to download).
    Demo(magcomp::demo::DemoArgs),
}

#[derive(clap::Args)]
struct CalibrateArgs {
    #[command(flatten)]
    input: TraceInput,
    #[command(flatten)]
    est: EstimatorArgs,
    /// Where to write the coefficients (JSON).
    #[arg(
        short = 'o',
        long = "out",
        visible_alias = "output",
        value_name = "COEFFS.json"
    )]
    output: PathBuf,
    /// Print one JSON object with the summary on stdout (as `compensate --json`).
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
struct CompensateArgs {
    #[command(flatten)]
    input: TraceInput,
    #[command(flatten)]
    est: EstimatorArgs,
    /// Apply these coefficients (from `calibrate`) instead of calibrating on this trace.
    #[arg(long, value_name = "COEFFS.json")]
    coeffs: Option<PathBuf>,
    /// The causal filter's output sample by sample, as the board produces it (default:
    /// post-flight — calibrate on the whole trace, then apply the final coefficients).
    #[arg(long)]
    realtime: bool,
    /// Output CSV: t,mag,interference,compensated[,anomaly,innovation,flags], then `igrf`
    /// and the input columns the model does not use (LINE, X, Y, …); docs/trace-format.md.
    #[arg(
        short = 'o',
        long = "out",
        visible_alias = "output",
        value_name = "OUT.csv"
    )]
    out: PathBuf,
    /// Print one JSON object with the summary on stdout.
    #[arg(long)]
    json: bool,
    /// Stream the flight (memory bounded by a window, not by the flight): `auto` streams
    /// `--coeffs` runs on inputs ≥ 256 MiB, `always` streams or says why it cannot,
    /// `never` reads the flight into memory. Streaming covers --coeffs (KF survey mode
    /// without lag/fluxtemp/fluxcal/rate, or --method tl); its summary leaves out the
    /// band-passed figures (residual, IR, FOM) and the applied-coefficient checks
    /// (docs/streaming.md).
    #[arg(long, value_enum, default_value_t = magcomp::stream::StreamMode::Auto)]
    stream: magcomp::stream::StreamMode,
}

/// Warnings go to stderr always, whatever else is printed.
fn print_warnings(s: &Summary) {
    for w in &s.warnings {
        eprintln!("warning: {w}");
    }
}

fn print_summary(s: &Summary) {
    println!("model {} ({:?}), {} samples", s.model, s.method, s.samples);
    println!(
        "  residual in manoeuvre band: {:.4} nT rms",
        s.residual_rms_nt
    );
    if let Some(ir) = s.improvement_ratio {
        println!("  improvement ratio:          {ir:.2}");
    }
    if let Some(f) = s.fom_nt {
        println!("  figure of merit (FOM):      {f:.3} nT");
    }
    if let Some(a) = s.aircraft_fom_nt {
        println!("  aircraft-only FOM:          {a:.3} nT (compensated − KF anomaly)");
    }
    if let Some(t) = &s.fom_table {
        println!("{}", magcomp::qc::fom::format_table(t));
    }
    if let Some(p) = s.predicted_error_nt {
        println!(
            "  predicted error (filter):   {p:.4} nT rms (how well the calibration determined it)"
        );
    }
    if let Some(e) = s.error_rms_nt {
        println!("  error vs truth:             {e:.4} nT rms");
    }
    if let Some(o) = s.oracle_floor_nt {
        println!("  oracle floor of the model:  {o:.4} nT rms (filter regressors only)");
    }
    if let Some(r) = &s.rate_crossover {
        println!(
            "  rate at {} crossovers:      differences {:.3} → {:.3} nT rms, p = {:.1e}, {}",
            r.fit.crossings,
            r.fit.rms_before_nt,
            r.fit.rms_after_nt,
            r.fit.p_value,
            if r.applied {
                "applied"
            } else {
                "not significant, not applied"
            }
        );
        for (l, (v, e)) in r
            .labels
            .iter()
            .zip(r.fit.coefficients.iter().zip(&r.fit.sigmas))
        {
            println!("    {l:<10} {v:>9.4} ± {e:.4} s");
        }
    }
}

fn main() -> Result<()> {
    let matches = Cli::command().get_matches();
    let cli = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    // Which estimator settings the user gave on the command line (not defaults).
    let given = |name: &str| {
        matches
            .subcommand()
            .is_some_and(|(_, m)| m.value_source(name) == Some(ValueSource::CommandLine))
    };
    match cli.command {
        Command::Simulate { sim, capture } => {
            let (sim, capture) = (*sim, *capture);
            let out = sim
                .output
                .clone()
                .unwrap_or_else(|| PathBuf::from("flight.csv"));
            let outputs: Vec<&std::path::Path> = std::iter::once(out.as_path())
                .chain(capture.capture.as_deref())
                .collect();
            refuse_overwriting(&[], &outputs)?;
            let cfg = sim.to_config()?;
            let trace = magcomp::sim::simulate(&cfg)?;
            magcomp::trace::write_trace(&out, &trace)?;
            eprintln!("wrote {} rows to {}", trace.len(), out.display());
            if let Some(c) = capture.write_if_requested(&trace)? {
                eprintln!("{c:?}");
            }
        }
        Command::Diagnose(a) => {
            magcomp::diagnose::run_diagnose(&a)?;
        }
        Command::Report(a) => {
            magcomp::report::flight_report::run_report(&a)?;
        }
        Command::Replay(a) => {
            magcomp::replay::run_replay(&a)?;
        }
        Command::Monitor(a) => {
            magcomp::monitor::run_monitor(&a)?;
        }
        Command::Upload(a) => {
            magcomp::upload::run_upload(&a)?;
        }
        Command::Calibrate(a) => {
            refuse_overwriting(&[&a.input.trace], &[&a.output])?;
            let trace = a.input.read()?;
            let (flight, comp) = compensate_trace(&trace, &a.est, None, false)?;
            let file = comp.coefficients.clone().context("no coefficients")?;
            magcomp::output::write_file(&a.output, serde_json::to_string_pretty(&file)?)?;
            let mut s = summarise(&flight, &comp);
            if let Some(p) = file.predicted_error_nt.filter(|p| *p > SURVEY_TOLERANCE_NT) {
                s.warnings.push(format!(
                    "this flight determined the interference only to {p:.3} nT rms \
                     (filter covariance), more than a survey's {SURVEY_TOLERANCE_NT} nT: \
                     fly the pattern higher, over quieter ground, or with more manoeuvres"
                ));
            }
            if a.json {
                println!("{}", serde_json::to_string(&s)?);
            } else {
                println!("{:<28} {:>12} {:>10}  unit", "coefficient", "value", "1σ");
                for c in &file.coefficients {
                    println!(
                        "{:<28} {:>12.4} {:>10.4}  {}",
                        c.name, c.value, c.sigma, c.unit
                    );
                }
                print_summary(&s);
            }
            print_warnings(&s);
            eprintln!("wrote {}", a.output.display());
        }
        Command::Compensate(a) => {
            let inputs: Vec<&std::path::Path> = std::iter::once(a.input.trace.as_path())
                .chain(a.coeffs.as_deref())
                .collect();
            refuse_overwriting(&inputs, &[&a.out])?;
            let coeffs = a.coeffs.as_deref().map(read_coefficients).transpose()?;
            if let Some(c) = &coeffs {
                magcomp::commands::refuse_conflicting_settings(
                    c,
                    given("method").then_some(a.est.method),
                    given("model").then_some(a.est.model.as_str()),
                )?;
            }
            if magcomp::stream::run_compensate_if_streamed(
                &a.input,
                &a.est,
                coeffs.as_ref(),
                a.realtime,
                a.stream,
                &a.out,
                a.json,
            )? {
                return Ok(());
            }
            let trace = a.input.read()?;
            let (flight, comp) = compensate_trace(&trace, &a.est, coeffs.as_ref(), a.realtime)?;
            let carried = magcomp::input::carried_columns(&trace, &flight.channels);
            write_output_csv(&a.out, &flight, &comp, &carried)?;
            let s = summarise(&flight, &comp);
            if a.json {
                let mut v = serde_json::to_value(&s)?;
                // Where the core field came from: the file, or the model and epoch used.
                for key in [
                    magcomp::input::META_CORE_FIELD,
                    magcomp::input::META_CORE_FIELD_EPOCH,
                ] {
                    if let (Some(m), Some(obj)) = (trace.meta(key), v.as_object_mut()) {
                        obj.insert(key.into(), m.parse::<f64>().map_or(m.into(), Into::into));
                    }
                }
                println!("{v}");
            } else {
                print_summary(&s);
                eprintln!("wrote {}", a.out.display());
            }
            print_warnings(&s);
        }
        Command::Nmea { file } => {
            let stdout = std::io::stdout();
            let out = std::io::BufWriter::new(stdout.lock());
            let stats = if file.as_os_str() == "-" {
                magcomp::nmea_cmd::decode_log(std::io::stdin().lock(), out)?
            } else {
                let f = std::fs::File::open(&file)
                    .with_context(|| format!("opening {}", file.display()))?;
                magcomp::nmea_cmd::decode_log(std::io::BufReader::new(f), out)?
            };
            eprintln!("{stats:?}");
        }
        Command::Demo(a) => magcomp::demo::run(&a)?,
    }
    Ok(())
}
