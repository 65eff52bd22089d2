//! magcomp host library: everything the `magcomp` command does, reusable from tests and
//! benches. The estimation itself is `magcomp_core`, the same code that runs on the board.
//!
//! Folders, bottom layer first; each imports only the ones above it in this list
//! (`tests/layout.rs` holds the order):
//! - `io`: trace files read and written, atomic output files, progress on the terminal;
//! - `signal`: band-pass, despiking, the statistics and least-squares kit;
//! - `model`: the model as users name it (terms, input-correction records);
//! - `flight`: a trace turned into what the core consumes (selection, IGRF, positions);
//! - `sim`: the independent flight simulator;
//! - `qc`: checks and figures of a flight (inputs, gaps, manoeuvres, FOM, truth yardsticks);
//! - `estimate`: the estimators (the core's filter over a flight, Tolles–Lawson, fluxgate
//!   calibration, input corrections, crossovers, jackknife, excitation);
//! - `calibration`: calibrating and compensating as the commands do, the coefficient file;
//! - `board`: the board seen from the host (link, upload, replay, monitor, captures, NMEA);
//! - `diagnose`: model discovery;
//! - `stream`: long flights in bounded memory;
//! - `report`: plots and the HTML report;
//! - `live`: the live view of the board's stream in the browser (`monitor --web`);
//! - `cli`: one file per subcommand.

pub mod board;
pub mod calibration;
pub mod cli;
pub mod diagnose;
pub mod estimate;
pub mod flight;
pub mod io;
pub mod live;
pub mod model;
pub mod multi;
pub mod qc;
pub mod report;
pub mod signal;
pub mod sim;
pub mod stream;
