//! The estimators: the core's Kalman filter run over a flight (`kf`), Tolles–Lawson (`tl`),
//! the fluxgate's scalar calibration (`fluxcal`), the input corrections estimated before
//! the filter (`corrections`: lag, fluxgate temperature), the `rate` term's crossovers,
//! reciprocal passes over the same ground (a lag's τ from their shift), the jackknife error
//! figure, what the manoeuvres excite, and the f64 reference filter.
//! Nothing here knows of coefficient files, reports or commands.

pub mod corrections;
pub mod crossover;
pub mod excitation;
pub mod fluxcal;
pub mod fluxgate_witness;
pub mod innovations;
pub mod jackknife;
pub mod joint_fit;
pub mod kf;
pub mod reciprocal;
pub mod reference_kf;
pub mod tl;
