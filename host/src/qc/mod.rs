//! Quality control of a flight: inputs that cannot be compensated (`inputs`), time gaps
//! (`gaps`), the calibration pattern found without labels (`manoeuvres`), the figures of
//! merit a geophysicist reads (`figures`), the range one flight's error falls in beside its
//! predicted figure (`error_range`), the output's high-frequency content beyond the
//! scalar's noise (`high_frequency`), what a real-time run's live readout showed
//! (`live_readout`), and on simulated data the error against truth
//! (`truth`). The checks of a compensation's own result live with it in `calibration`.

pub mod error_range;
pub mod figures;
pub mod gaps;
pub mod high_frequency;
pub mod inputs;
pub mod live_readout;
pub mod manoeuvres;
pub mod sets;
pub mod truth;
