//! Files and the terminal: recorded traces read and written, output files never left
//! half-written, progress on stderr.

pub mod output;
pub mod progress;
pub mod trace;
