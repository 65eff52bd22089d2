//! What the compensated output carries at high frequency beyond the scalar's own noise:
//! interference the model does not follow (eddy currents of a buffeted airframe, a lag
//! that re-alignment at the sample rate cannot undo), which stays in the output.
//!
//! One scalar cannot tell its white noise from white-looking interference sample by
//! sample, but the two differ over a flight: the sensor's noise is the same everywhere,
//! the interference rises and falls with heading and manoeuvre. The quietest windows bound
//! the noise from above, and what the others carry beyond it is interference left in the
//! output. A lower bound: the quietest windows hold some of it too.
//!
//! Why it matters: the coefficients' covariance says nothing of it, yet the error against
//! the truth counts it. On the independent simulator's `lag_s32` the output's third
//! difference held 0.078 nT where the scalar's noise is 0.013 (0.044–0.113 by heading),
//! most of the 0.083 nT error against the truth, none of it in the 0.044 nT predicted.

use super::gaps::time_breaks;

/// The window the output's high-frequency level is measured over (s).
pub const WINDOW_S: f64 = 30.0;
/// Fewest samples a window may hold (a slow flight's 30 s).
const MIN_WINDOW_SAMPLES: usize = 60;
/// Fewest windows the quietest-tenth floor is read from.
const MIN_WINDOWS: usize = 10;
/// The floor is the level this share of windows lies below.
const QUIET_SHARE: f64 = 0.1;
/// The standard normal quantile of `QUIET_SHARE`, negated: how far, in its sampling
/// spread, the quietest tenth of windows of a stationary noise lies below its level.
const QUIET_SHARE_Z: f64 = 1.2816;
/// How many times its own scatter the excess must reach to count.
const SIGNIFICANCE: f64 = 2.0;

/// The output's high-frequency content: what lies beyond its quietest windows (a lower
/// bound of the interference there) and all of it (an upper bound, the scalar's noise
/// included).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HighFrequency {
    /// The rms (nT) beyond the quietest windows' level (the scalar's noise): a lower bound
    /// of the interference there (the coefficient file's `unfollowed_high_frequency_nt`).
    pub unfollowed_nt: f64,
    /// The whole flight's third-difference level (nT rms, white-equivalent).
    pub output_nt: f64,
}

impl HighFrequency {
    /// The most of the output's high frequency that can be interference the model does
    /// not follow: all of it where some was found beyond the quietest windows (the
    /// quietest may hold as much again: on `lag_s32` the part found was 0.059 nT, the
    /// error's own above 1 Hz 0.066, the output's whole 0.078); none where none was.
    pub fn upper_nt(&self) -> f64 {
        if self.unfollowed_nt > 0.0 {
            self.output_nt.max(self.unfollowed_nt)
        } else {
            0.0
        }
    }
}

/// The compensated output's high-frequency content over the whole flight; `None` when the
/// flight is too short for [`MIN_WINDOWS`] windows. The level is the third difference's
/// mean square (white noise of σ gives σ²; the anomaly, the core field and the slow
/// interference give nothing at 10 Hz), taken per [`WINDOW_S`] window; no difference spans
/// a time gap or a missing value.
pub fn high_frequency(compensated_nt: &[f64], t_s: &[f64], rate_hz: f64) -> Option<HighFrequency> {
    let levels = window_levels(compensated_nt, t_s, rate_hz);
    if levels.len() < MIN_WINDOWS {
        return None;
    }
    let mean = levels.iter().map(|l| l.mean_square).sum::<f64>() / levels.len() as f64;
    let mut sorted: Vec<f64> = levels.iter().map(|l| l.mean_square).collect();
    sorted.sort_by(f64::total_cmp);
    let quiet = sorted[(QUIET_SHARE * sorted.len() as f64) as usize];
    // A stationary noise's windows scatter about its level by their sampling spread, so
    // its quietest tenth lies ~1.28 spreads below: without this the estimate read ~0.5 ×
    // the noise on flights whose output is noise alone. The spread is read from the
    // windows' own two halves (each window's mean square is their mean).
    let mut half_differences: Vec<f64> = levels.iter().map(|l| l.half_difference.abs()).collect();
    half_differences.sort_by(f64::total_cmp);
    let spread = half_differences[half_differences.len() / 2] / 0.6745 / 2.0;
    let floor = (quiet + QUIET_SHARE_Z * spread).min(mean);
    // Only an excess beyond what the estimate itself scatters by counts: the quietest
    // tenth's level (sd 1.71 spreads/√n, a quantile's) and the mean (1 spread/√n) put
    // ~2 spreads/√n of scatter on their difference; twice that is the bar. Without it a
    // flight whose output is the sensor's noise alone read 0.002 nT at 0.01 nT of noise.
    let scatter = 2.0 * spread / (levels.len() as f64).sqrt();
    let excess = mean - floor;
    Some(HighFrequency {
        unfollowed_nt: if excess > SIGNIFICANCE * scatter {
            excess.sqrt()
        } else {
            0.0
        },
        output_nt: mean.max(0.0).sqrt(),
    })
}

/// What the output carries beyond the scalar's noise, as the predicted error counts it:
/// the larger of the model error (the innovations' excess over the whole band) and the
/// high-frequency part (the output's above its quietest windows). Both measure the same
/// thing, so they are not summed.
pub fn unexplained_nt(model_error_nt: Option<f64>, high_frequency_nt: Option<f64>) -> Option<f64> {
    match (model_error_nt, high_frequency_nt) {
        (Some(m), Some(h)) => Some(m.max(h)),
        (m, h) => m.or(h),
    }
}

/// The range of what the output carries beyond the scalar's noise: [`unexplained_nt`] at
/// the low end; at the high end, the larger of the model error and all the output's high
/// frequency where part of it was found to be interference ([`HighFrequency::upper_nt`]).
/// The figure counts the low end; one flight's error range spans both.
pub fn unexplained_range_nt(
    model_error_nt: Option<f64>,
    high_frequency: Option<HighFrequency>,
) -> [f64; 2] {
    let low = unexplained_nt(model_error_nt, high_frequency.map(|h| h.unfollowed_nt));
    let high = unexplained_nt(model_error_nt, high_frequency.map(|h| h.upper_nt()));
    [low.unwrap_or(0.0), high.unwrap_or(0.0)]
}

/// Above this (nT rms) the unfollowed high frequency is worth a warning: it is then half a
/// survey's 0.1 nT tolerance, as for the model error (`kf::MODEL_ERROR_WARNING_NT`).
pub const WARNING_NT: f64 = 0.05;

/// The warning for a high-frequency residual above [`WARNING_NT`].
pub fn warning(high_frequency_nt: Option<f64>) -> Option<String> {
    let h = high_frequency_nt.filter(|h| *h > WARNING_NT)?;
    Some(format!(
        "the compensated output carries {h:.3} nT rms at high frequency beyond the scalar's \
         own noise (its quietest minutes): interference the model does not follow (a \
         scalar lag, eddy currents of a buffeted airframe) or noise from the ground (power \
         lines), counted in the predicted error. `magcomp diagnose` names candidates"
    ))
}

/// One window's third-difference mean square (nT²) and the difference between its two
/// halves' mean squares.
struct WindowLevel {
    mean_square: f64,
    half_difference: f64,
}

fn window_levels(compensated_nt: &[f64], t_s: &[f64], rate_hz: f64) -> Vec<WindowLevel> {
    if !(rate_hz.is_finite() && rate_hz > 0.0) || compensated_nt.len() != t_s.len() {
        return Vec::new();
    }
    let window = ((WINDOW_S * rate_hz).round() as usize).max(MIN_WINDOW_SAMPLES);
    // A difference ending at i spans a gap when a gap's first sample is among i−2..=i.
    let mut spans_gap = vec![false; t_s.len()];
    for b in time_breaks(t_s) {
        spans_gap[b..(b + 3).min(t_s.len())].fill(true);
    }
    // d3² / 20: white noise of σ gives σ² (the third difference's variance is 20σ²).
    let d3_squared: Vec<Option<f64>> = (0..compensated_nt.len())
        .map(|i| {
            if i < 3 || spans_gap[i] {
                return None;
            }
            let w = &compensated_nt[i - 3..=i];
            let d3 = w[3] - 3.0 * w[2] + 3.0 * w[1] - w[0];
            d3.is_finite().then_some(d3 * d3 / 20.0)
        })
        .collect();
    d3_squared
        .chunks_exact(window)
        .filter_map(|chunk| {
            let (a, b) = chunk.split_at(window / 2);
            let (ma, mb) = (mean_of_valid(a, window / 4)?, mean_of_valid(b, window / 4)?);
            Some(WindowLevel {
                mean_square: (ma + mb) / 2.0,
                half_difference: ma - mb,
            })
        })
        .collect()
}

/// The mean of the values present, when at least `min_count` are.
fn mean_of_valid(values: &[Option<f64>], min_count: usize) -> Option<f64> {
    let (sum, count) = values
        .iter()
        .flatten()
        .fold((0.0, 0usize), |(s, c), v| (s + v, c + 1));
    (count >= min_count.max(1)).then(|| sum / count as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unfollowed_high_frequency_nt(out: &[f64], t_s: &[f64], rate_hz: f64) -> Option<f64> {
        high_frequency(out, t_s, rate_hz).map(|h| h.unfollowed_nt)
    }
    use rand::{Rng, SeedableRng};
    use rand_distr::StandardNormal;

    fn noise(n: usize, sigma_nt: f64, seed: u64) -> Vec<f64> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        (0..n)
            .map(|_| sigma_nt * rng.sample::<f64, _>(StandardNormal))
            .collect()
    }

    fn times(n: usize) -> Vec<f64> {
        (0..n).map(|i| i as f64 * 0.1).collect()
    }

    #[test]
    fn stationary_noise_leaves_little_beyond_itself() {
        // 20 min at 10 Hz of 0.01 nT noise: what is "beyond" it is the estimate's own
        // scatter, a small part of the noise (uncorrected it read ~0.5 × the noise).
        for seed in 1..=8 {
            let out = noise(12_000, 0.01, seed);
            let x = unfollowed_high_frequency_nt(&out, &times(out.len()), 10.0).unwrap();
            assert!(x < 0.35 * 0.01, "seed {seed}: {x}");
        }
    }

    #[test]
    fn interference_in_some_windows_is_found_beside_the_noise() {
        // 0.01 nT noise everywhere; in the middle half, 0.05 nT more of white-looking
        // interference: its share of the flight's mean square is 0.05² / 2.
        let n = 12_000;
        let mut out = noise(n, 0.01, 3);
        for (v, extra) in out[n / 4..3 * n / 4].iter_mut().zip(noise(n / 2, 0.05, 4)) {
            *v += extra;
        }
        let x = unfollowed_high_frequency_nt(&out, &times(n), 10.0).unwrap();
        let expected = (0.05f64.powi(2) / 2.0).sqrt();
        assert!((x / expected - 1.0).abs() < 0.1, "{x} vs {expected}");
        // The whole output's level: the interference's and the noise's mean squares.
        let h = high_frequency(&out, &times(n), 10.0).unwrap();
        let whole = (expected.powi(2) + 0.01f64.powi(2)).sqrt();
        assert!((h.output_nt / whole - 1.0).abs() < 0.1, "{h:?} vs {whole}");
        assert_eq!(h.upper_nt(), h.output_nt);
        let [low, high] = unexplained_range_nt(Some(0.01), Some(h));
        assert_eq!((low, high), (h.unfollowed_nt, h.output_nt));
        // Noise alone: nothing found, so nothing is allowed for either.
        let quiet = high_frequency(&noise(n, 0.01, 5), &times(n), 10.0).unwrap();
        assert_eq!(quiet.upper_nt(), 0.0);
        assert_eq!(
            unexplained_range_nt(Some(0.002), Some(quiet)),
            [0.002, 0.002]
        );
    }

    #[test]
    fn the_larger_of_model_error_and_high_frequency_is_unexplained() {
        assert_eq!(unexplained_nt(Some(0.3), Some(0.05)), Some(0.3));
        assert_eq!(unexplained_nt(Some(0.01), Some(0.05)), Some(0.05));
        assert_eq!(unexplained_nt(None, Some(0.05)), Some(0.05));
        assert_eq!(unexplained_nt(Some(0.3), None), Some(0.3));
        assert_eq!(unexplained_nt(None, None), None);
    }

    #[test]
    fn warned_above_half_a_survey_tolerance() {
        assert_eq!(warning(Some(0.04)), None);
        assert_eq!(warning(None), None);
        assert!(warning(Some(0.06))
            .unwrap()
            .contains("0.060 nT rms at high frequency"));
    }

    #[test]
    fn slow_signal_gaps_and_short_flights() {
        // A slow anomaly (a 200 nT, 60 s sine) adds nothing at the third difference.
        let n = 12_000;
        let t = times(n);
        let slow: Vec<f64> = noise(n, 0.01, 5)
            .iter()
            .zip(&t)
            .map(|(e, t)| e + 200.0 * (std::f64::consts::TAU * t / 60.0).sin())
            .collect();
        assert!(unfollowed_high_frequency_nt(&slow, &t, 10.0).unwrap() < 0.0035);
        // A 100 nT step across a time gap is not differenced.
        let mut gapped_t = t.clone();
        let mut stepped = noise(n, 0.01, 6);
        for i in n / 2..n {
            gapped_t[i] += 60.0;
            stepped[i] += 100.0;
        }
        assert!(unfollowed_high_frequency_nt(&stepped, &gapped_t, 10.0).unwrap() < 0.0035);
        // Fewer than ten windows: no figure.
        assert_eq!(
            unfollowed_high_frequency_nt(&slow[..2_000], &t[..2_000], 10.0),
            None
        );
    }
}
