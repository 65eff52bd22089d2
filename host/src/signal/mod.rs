//! Signal and statistics tools on plain series: the zero-phase band-pass, scalar despiking,
//! the statistics kit and least squares. They know nothing of flights or models.

pub mod bandpass;
pub mod despike;
pub mod lstsq;
pub mod stats;
