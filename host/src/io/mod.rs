//! Files and the terminal: recorded traces read and written, output files never left
//! half-written, progress on stderr. Imports nothing else from the crate.

pub mod bounded;
pub mod console;
pub mod csv;
pub mod output;
pub mod progress;
pub mod trace;
