//! magcomp host library: everything the `magcomp` command does, reusable from tests and
//! benches. The estimation itself is `magcomp_core`, the same code that runs on the board.

pub mod board_link;
pub mod capture_sim;
pub mod cli;
pub mod coefficients;
pub mod compensation;
pub mod crossover;
pub mod despike;
pub mod diagnose;
pub mod excitation;
pub mod flight;
pub mod fluxgate;
pub mod igrf;
pub mod input;
pub mod jackknife;
pub mod metrics;
pub mod model_spec;
pub mod monitor;
pub mod nmea_cmd;
pub mod output;
pub mod pipeline;
pub mod position;
pub mod preprocess;
pub mod qc;
pub mod reference_kf;
pub mod replay;
pub mod report;
pub mod sim;
pub mod stream;
pub mod tl;
pub mod trace;
pub mod upload;
