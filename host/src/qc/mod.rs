//! Quality control of a flight and of a compensation: inputs that cannot be compensated
//! (`inputs`), time gaps (`gaps`), the calibration pattern found without labels
//! (`manoeuvres`), the AARC-style FOM table (`fom`), and the plausibility of applied
//! coefficients (`applied`).

pub mod applied;
pub mod fom;
pub mod gaps;
pub mod inputs;
pub mod manoeuvres;
