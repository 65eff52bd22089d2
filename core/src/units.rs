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
        MagCounts(self.0 - round_to_i64(nt * COUNTS_PER_NT as f32))
    }
}

/// `libm::roundf(y) as i64` (halves away from zero; NaN → 0, saturating) without `libm`'s
/// software rounding where `|y| < 2^31` (once per record on the M4): the truncation `t` is
/// the FPU's conversion and `y − t` is exact (the bits of `y` below its units), so comparing
/// it with ±½ decides the rounding exactly.
fn round_to_i64(y: f32) -> i64 {
    if libm::fabsf(y) < 2_147_483_648.0 {
        let t = y as i32;
        let f = y - t as f32;
        return i64::from(t) + i64::from(f >= 0.5) - i64::from(f <= -0.5);
    }
    libm::roundf(y) as i64
}

#[cfg(test)]
mod tests {
    use super::round_to_i64;

    #[test]
    fn fast_rounding_equals_libm() {
        let check = |y: f32| assert_eq!(round_to_i64(y), libm::roundf(y) as i64, "{y:e}");
        // every float of magnitude 2^22 to 2^23 (spacing ½: a half at every other one),
        // every 61st of magnitude 2^-2 to 2^25 and their negatives, every 4099th bit pattern
        for b in 4_194_304f32.to_bits()..=8_388_608f32.to_bits() {
            check(f32::from_bits(b));
        }
        for b in (0.25f32.to_bits()..=33_554_432f32.to_bits()).step_by(61) {
            check(f32::from_bits(b));
            check(-f32::from_bits(b));
        }
        for b in (0..u32::MAX).step_by(4099) {
            check(f32::from_bits(b));
        }
        for y in [
            0.0,
            -0.0,
            0.5,
            -0.5,
            2_147_483_520.0,
            -2_147_483_648.0,
            2_147_483_648.0,
        ] {
            check(y);
        }
        for y in [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MAX,
            f32::MIN,
            1e-45,
        ] {
            check(y);
        }
    }
}
