//! Square-root (UD) Kalman filter, fixed size, f32, no allocation.
//!
//! `P = U·D·Uᵀ` with `U` unit upper triangular and `D` diagonal (Bierman–Thornton).
//! The states that move (tie-point clones and the 5 field states) are stored first: then
//! `Φ·U` stays unit upper triangular and only that leading block is re-factorised by the
//! modified weighted Gram–Schmidt (MWGS) time update — O(n·m²) with m ≤ 7 instead of O(n³)
//! (model.md §5). The scalar measurement update is Bierman's, O(n²).

pub mod covariance;
pub mod field;
pub mod ud;

pub use field::FieldProcess;
pub use ud::{Innovation, UdFilter};
