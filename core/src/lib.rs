//! magcomp-core: the compensator core shared by the firmware and the host tools.
//!
//! `no_std`, no allocation, f32 inside the filter. The data flow is
//! `protocol` (bytes → frames) → `epoch` (aligned samples → epochs with e, ė, V, Δh) →
//! `model` (regressors of the chosen terms) → `filter` (square-root Kalman filter) →
//! `compensator` (one output record per scalar sample).
#![cfg_attr(not(feature = "std"), no_std)]
#![forbid(unsafe_code)]
// Numeric kernels index several arrays in lockstep (U, D, h, Φ); iterator chains would hide
// the algebra that the comments refer to.
#![allow(clippy::needless_range_loop)]
// `!(x > 0.0)` is deliberate: it rejects NaN together with non-positive values.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod acquisition;
pub mod compensator;
pub mod continuity;
pub mod epoch;
pub mod filter;
pub mod flags;
pub mod joint;
pub mod model;
pub mod protocol;
pub mod spectrum;
pub mod units;

pub use compensator::{Compensator, CompensatorConfig, Output};
pub use epoch::{AlignedSample, Epoch, EpochBuilder, MAX_AUX};
pub use flags::Flags;
pub use units::MagCounts;
