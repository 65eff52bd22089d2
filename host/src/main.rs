//! `magcomp`: airborne magnetometer compensation on the ground, with the same core that
//! flies on the board. Parses the command line and hands it to `magcomp::cli`.

use clap::Parser;
use magcomp::cli::{self, Cli};

fn main() -> std::process::ExitCode {
    cli::run(Cli::parse().command)
}
