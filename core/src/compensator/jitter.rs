//! The interference's own sample-to-sample jitter: noisy regressors (a fluxgate's noise
//! times the coefficients) put it into every record, and the coefficients' covariance
//! does not see it. On the board's simulated broad flights it was the part of the error a
//! straight leg showed beyond the covariance's bound (34 % of the records beyond 3σ without
//! it, about the minute's mean).

/// The 4th difference `(x₋₂ − 4x₋₁ + 6x₀ − 4x₊₁ + x₊₂)/16` passes white noise with variance
/// 70/256 and the interference's manoeuvres (periods ≥ 2 s at 10 Hz) with < 2 % of their
/// amplitude, so its mean square measures the jitter alone.
const D4_WHITE_GAIN: f32 = 70.0 / 256.0;

#[derive(Clone, Copy, Debug)]
pub(crate) struct InterferenceJitter {
    last: [f32; 5],
    filled: u8,
    mean_d4_sq: f32,
    count: u32,
}

impl InterferenceJitter {
    pub(crate) const fn new() -> Self {
        Self {
            last: [0.0; 5],
            filled: 0,
            mean_d4_sq: 0.0,
            count: 0,
        }
    }

    /// Follows one output interference over a window of `window` records; a missing value
    /// restarts the difference (not the mean).
    pub(crate) fn push(&mut self, interference_nt: f32, window: u32) {
        if !interference_nt.is_finite() {
            self.filled = 0;
            return;
        }
        self.last.rotate_left(1);
        self.last[4] = interference_nt;
        self.filled = (self.filled + 1).min(5);
        if self.filled < 5 {
            return;
        }
        let [a, b, c, d, e] = self.last;
        let d4 = (a - 4.0 * b + 6.0 * c - 4.0 * d + e) / 16.0;
        self.count = self.count.saturating_add(1).min(window.max(1));
        self.mean_d4_sq += (d4 * d4 - self.mean_d4_sq) / self.count as f32;
    }

    /// The jitter's variance (nT²; 0 before five records).
    pub(crate) fn variance_nt2(&self) -> f32 {
        if self.count == 0 {
            0.0
        } else {
            self.mean_d4_sq / D4_WHITE_GAIN
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn white_noise_is_measured_and_a_manoeuvre_is_not() {
        // A 5 s, 20 nT manoeuvre at 10 Hz plus ±0.01 nT alternating "noise" (white-like
        // at the Nyquist rate, where the 4th difference has gain 1: the variance is over-read
        // by 1/0.273, a conservative floor).
        let mut j = InterferenceJitter::new();
        for k in 0..600 {
            let t = k as f32 / 10.0;
            let m = 20.0 * libm::sinf(2.0 * core::f32::consts::PI * t / 5.0);
            j.push(m, 300);
        }
        assert!(libm::sqrtf(j.variance_nt2()) < 0.01, "{}", j.variance_nt2());
        let mut j = InterferenceJitter::new();
        for k in 0..600 {
            let noise = if k % 2 == 0 { 0.01 } else { -0.01 };
            j.push(noise, 300);
        }
        let sigma = libm::sqrtf(j.variance_nt2());
        assert!((0.015..0.025).contains(&sigma), "{sigma}");
        j.push(f32::NAN, 300);
        assert!(j.variance_nt2() > 0.0, "a gap keeps the mean");
    }
}
