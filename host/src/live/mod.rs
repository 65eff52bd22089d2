//! `magcomp monitor --web`: the board's output stream as a chart recorder in the browser.
//! [`source`] follows the port (reopening it after a pulled cable), [`feed`] turns the
//! monitor's decoded records into the page's messages (4th difference, alarms, events,
//! height and GPS state from the `$MCRAW` lines), [`fom`] tabulates a calibration pattern
//! from those lines once it has ended, [`server`] serves the page (`assets/live.html`,
//! uPlot vendored in `assets/uplot/`) and pushes the messages over a websocket.

pub mod feed;
pub mod fom;
pub mod server;
pub mod source;
