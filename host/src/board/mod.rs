//! The board seen from the host: the verified command link, coefficient upload, replay of
//! raw captures through the firmware's acquisition code, the live record monitor, NMEA
//! decoding with the board's reader, and simulated flights written as raw captures.

pub mod capture;
pub mod flag_names;
pub mod flagged_share;
pub mod link;
pub mod monitor;
pub mod nmea;
pub mod replay;
pub mod upload;
