//! Exact representation of the absolute scalar field.
//!
//! f32 has a 24-bit mantissa: at 50 000 nT one ULP is ~0.004 nT, the order of the sensor
//! noise (model.md §5). The absolute reading is therefore kept as an integer count of
//! 0.1 pT (1e-4 nT) and only differences against an exact reference reach f32.

/// Counts of 1e-4 nT per nT.
pub const COUNTS_PER_NT: i64 = 10_000;

/// An absolute scalar-magnetometer reading in integer units of 1e-4 nT.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Default)]
pub struct MagCounts(pub i64);

impl MagCounts {
    /// Rounds an f64 value in nT to the nearest count (host side; f64 holds 1e-4 nT exactly
    /// up to ~1e11 nT, far above any geomagnetic field).
    pub fn from_nt_f64(nt: f64) -> Option<Self> {
        if !nt.is_finite() || nt.abs() > 1.0e9 {
            return None;
        }
        Some(Self(libm::round(nt * COUNTS_PER_NT as f64) as i64))
    }
    pub fn to_nt_f64(self) -> f64 {
        self.0 as f64 / COUNTS_PER_NT as f64
    }
    /// Difference `self - reference` in nT as f32: exact integer subtraction first.
    pub fn diff_nt(self, reference: MagCounts) -> f32 {
        ((self.0 - reference.0) as f64 / COUNTS_PER_NT as f64) as f32
    }
    /// `self - nt` rounded to counts: used to form the compensated absolute value exactly.
    pub fn minus_nt(self, nt: f32) -> MagCounts {
        MagCounts(self.0 - libm::roundf(nt * COUNTS_PER_NT as f32) as i64)
    }
}
