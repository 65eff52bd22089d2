//! The model as users name it: the terms of a model spec, and the records of the input
//! corrections (scalar lag, fluxgate temperature) a calibration applies before the filter.

pub mod corrections;
pub mod errors;
pub mod spec;
