//! Sensor and port protocols: bytes → typed frames, and records/commands → bytes.
//!
//! Every parser is `no_std`, allocation-free and total: any byte sequence yields frames or
//! typed, counted errors, never a panic, and the parser resynchronises at the next frame
//! start. Formats are documented in `docs/protocols.md`.

pub mod aligner;
pub mod capture;
pub mod command;
pub mod common;
pub mod fluxgate;
pub mod lag_line;
pub mod multi_raw;
pub mod multi_record;
pub mod multi_scalar;
pub mod nmea;
pub mod raw;
pub mod record;
pub mod scalar;
pub mod uart_errors;
