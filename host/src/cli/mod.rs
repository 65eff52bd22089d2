//! The command layer: one file per subcommand with its clap arguments and the code that
//! reads the inputs, calls the processing modules and prints or writes the results.
//! Nothing outside `cli` imports it (checked by `tests/layout.rs`): processing takes plain
//! settings (`calibration::EstimatorSettings`, `diagnose::DiagnoseOptions`, …), never clap
//! structs.

pub mod args;
pub mod calibrate;
pub mod capture;
pub mod compensate;
pub mod demo;
pub mod diagnose;
pub mod monitor;
pub mod multi;
pub mod multi_calibrate;
pub mod multi_stream;
pub mod nmea;
pub mod replay;
pub mod report;
pub mod simulate;
pub mod summary_text;
pub mod upload;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "magcomp",
    version,
    about = "Airborne magnetometer compensation: Tolles–Lawson deviation + stochastic anomaly model, estimated by a Kalman filter (Karshakov & Kharichkin)"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    /// Simulate a calibration and/or survey flight with known truth (and, with --capture,
    /// the raw bytes its sensors would have sent).
    Simulate {
        #[command(flatten)]
        sim: Box<simulate::SimulateArgs>,
        #[command(flatten)]
        capture: Box<simulate::CaptureArgs>,
    },
    /// Estimate the deviation coefficients (with 1σ) from a calibration flight.
    Calibrate(Box<calibrate::CalibrateArgs>),
    /// Remove the aircraft interference from a flight.
    Compensate(Box<compensate::CompensateArgs>),
    /// Decode a GPS receiver log with the board's NMEA reader (one JSON object per line).
    Nmea(nmea::NmeaArgs),
    /// Compare the model with the measurements, find where it fails and which physical
    /// effect is missing (ranked, with significance).
    Diagnose(Box<diagnose::DiagnoseArgs>),
    /// Write a self-contained HTML report with plots for one or more models.
    Report(Box<report::ReportArgs>),
    /// Write a trace (a recorded real flight, CSV/XYZ/HDF5) as a raw board capture for
    /// `replay` and the HIL rig.
    Capture(Box<capture::CaptureCmdArgs>),
    /// Run a raw sensor capture through the board's parsers, aligner and filter.
    Replay(replay::ReplayArgs),
    /// Decode and show the board's output stream live (a port, a file, or `-`).
    Monitor(monitor::MonitorArgs),
    /// Send a `calibrate` coefficient file to the board (SETCOEF, SETFLUX, SAVE lines).
    Upload(upload::UploadArgs),
    /// End-to-end demonstration on built-in simulated data (nothing to download).
    Demo(demo::DemoArgs),
}

/// Runs one command to its exit status: 0 done, 1 with `Error: …` on stderr. The error is
/// printed here rather than by `Result`'s `Termination`, which panics when stderr is a
/// closed pipe; text lost to another error (a full disk) fails the command too.
pub fn run(command: Command) -> std::process::ExitCode {
    use std::process::ExitCode;
    if let Err(e) = dispatch(command) {
        crate::errln!("Error: {e:?}");
        return ExitCode::FAILURE;
    }
    match crate::io::console::lost_text() {
        Some(lost) => {
            crate::errln!("Error: {lost}");
            ExitCode::FAILURE
        }
        None => ExitCode::SUCCESS,
    }
}

fn dispatch(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Simulate { sim, capture } => simulate::run(&sim, &capture),
        Command::Calibrate(a) => calibrate::run(&a),
        Command::Compensate(a) => compensate::run(&a),
        Command::Nmea(a) => nmea::run(&a),
        Command::Diagnose(a) => diagnose::run(&a),
        Command::Report(a) => report::run(&a),
        Command::Capture(a) => capture::run(&a),
        Command::Replay(a) => replay::run(&a).map(drop),
        Command::Monitor(a) => monitor::run(&a).map(drop),
        Command::Upload(a) => upload::run(&a),
        Command::Demo(a) => demo::run(&a),
    }
}
