//! `magcomp`: airborne magnetometer compensation on the ground, with the same core that
//! flies on the board. Parses the command line and hands it to `magcomp::cli`.

use std::process::ExitCode;

use anyhow::Result;
use clap::Parser;
use magcomp::cli::{self, Cli, Command};
use magcomp::io::console;

fn main() -> ExitCode {
    // Printed here rather than by `Result`'s `Termination`, which panics when stderr is
    // a closed pipe.
    if let Err(e) = run(Cli::parse().command) {
        magcomp::errln!("Error: {e:?}");
        return ExitCode::FAILURE;
    }
    match console::lost_text() {
        Some(lost) => {
            magcomp::errln!("Error: {lost}");
            ExitCode::FAILURE
        }
        None => ExitCode::SUCCESS,
    }
}

fn run(command: Command) -> Result<()> {
    match command {
        Command::Simulate { sim, capture } => cli::simulate::run(&sim, &capture),
        Command::Calibrate(a) => cli::calibrate::run(&a),
        Command::Compensate(a) => cli::compensate::run(&a),
        Command::Nmea(a) => cli::nmea::run(&a),
        Command::Diagnose(a) => cli::diagnose::run(&a),
        Command::Report(a) => cli::report::run(&a),
        Command::Capture(a) => cli::capture::run(&a),
        Command::Replay(a) => cli::replay::run(&a).map(drop),
        Command::Monitor(a) => cli::monitor::run(&a).map(drop),
        Command::Upload(a) => cli::upload::run(&a),
        Command::Demo(a) => cli::demo::run(&a),
    }
}
