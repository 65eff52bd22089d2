//! The compensator's account of its own health, so a record is never shown as good when
//! the estimate behind it is not:
//! - [`InnovationMonitor`]: do the innovations agree with what the filter predicts? What
//!   they show beyond it is signal the model lacks (it stays in the output) and, when it is
//!   far above the sensor's noise, the measurement noise the filter must use.
//! - [`envelope_regressors`]: is the interference determined for the attitudes a survey
//!   flies, not only for the ones flown in the last minute? On a straight line the
//!   regressors barely move, so any coefficients "predict" them; the next turn then showed
//!   hundreds of nT of false interference flagged as good (a real survey line: 1,080 clean
//!   records 235 ± 230 nT off).
//! - [`Divergence`]: an interference that swings far more than the raw signal it was
//!   taken from is not the aircraft's.

use crate::epoch::Epoch;

/// Attitude changes a survey flies around the present one (body-frame rotations of the
/// field direction): the calibration manoeuvres' amplitudes (roll ±10°, pitch ±5°,
/// yaw ±5°, as an AARC pattern flies them), at their extremes and with the rotation rate
/// of their mid-swing (5 s period: what the eddy terms see), and the three other headings
/// (about the body z axis: exact for level flight). The interference must be determined
/// for each relative to now; its level is the anomaly's and is never determined.
pub const ENVELOPE_POINTS: usize = 12;

const MANOEUVRES_DEG: [(usize, f32); 3] = [(0, 10.0), (1, 5.0), (2, 5.0)];
const MANOEUVRE_PERIOD_S: f32 = 5.0;
const HEADINGS_DEG: [f32; 3] = [90.0, 180.0, 270.0];

/// `v` rotated by `angle_rad` about body axis `axis` (0 x, 1 y, 2 z).
fn rotated(v: [f32; 3], axis: usize, angle_rad: f32) -> [f32; 3] {
    let (s, c) = (libm::sinf(angle_rad), libm::cosf(angle_rad));
    let (i, j) = ((axis + 1) % 3, (axis + 2) % 3);
    let mut out = v;
    out[i] = c * v[i] - s * v[j];
    out[j] = s * v[i] + c * v[j];
    out
}

/// `axis × v` (the rate of change of a body-fixed vector's direction cosines under a unit
/// rotation rate about `axis`, up to sign).
fn axis_cross(axis: usize, v: [f32; 3]) -> [f32; 3] {
    let (i, j) = ((axis + 1) % 3, (axis + 2) % 3);
    let mut out = [0.0; 3];
    out[i] = -v[j];
    out[j] = v[i];
    out
}

/// The epoch as it would be at envelope point `k` (< [`ENVELOPE_POINTS`]): the same
/// position, field strength and auxiliary channels, another attitude.
pub fn envelope_epoch(ep: &Epoch, k: usize) -> Epoch {
    let mut out = *ep;
    match k {
        0..=8 => {
            let (axis, amp_deg) = MANOEUVRES_DEG[k / 3];
            let amp = amp_deg.to_radians();
            match k % 3 {
                0 | 1 => {
                    let sign = if k.is_multiple_of(3) { 1.0 } else { -1.0 };
                    out.e = rotated(ep.e, axis, sign * amp);
                    out.e_dot_per_s = [0.0; 3];
                }
                _ => {
                    let omega = amp * core::f32::consts::TAU / MANOEUVRE_PERIOD_S;
                    let d = axis_cross(axis, ep.e);
                    out.e_dot_per_s = [omega * d[0], omega * d[1], omega * d[2]];
                }
            }
        }
        _ => {
            out.e = rotated(ep.e, 2, HEADINGS_DEG[k - 9].to_radians());
            out.e_dot_per_s = [0.0; 3];
        }
    }
    out
}

/// Innovation statistics over an exponential window (a plain average until it fills).
#[derive(Clone, Copy, Debug, Default)]
pub struct InnovationMonitor {
    /// Mean ν², each clipped at `CLIP_SIGMA²` × the larger of its predicted variance and
    /// the running mean, so one glitch cannot dominate while a real model error (every
    /// innovation large) still shows within a few windows.
    mean_nu2: f32,
    /// Mean of the predicted variance's state part `H·P·Hᵀ` (without r).
    mean_hph: f32,
    count: u32,
}

const CLIP_SIGMA: f32 = 5.0;

impl InnovationMonitor {
    pub const fn new() -> Self {
        Self {
            mean_nu2: 0.0,
            mean_hph: 0.0,
            count: 0,
        }
    }

    pub fn push(&mut self, nu: f32, s: f32, r: f32, window: u32) {
        if !(nu.is_finite() && s.is_finite() && s > 0.0) {
            return;
        }
        let cap = CLIP_SIGMA * CLIP_SIGMA * s.max(self.mean_nu2);
        let nu2 = (nu * nu).min(cap);
        self.count = self.count.saturating_add(1).min(window.max(1));
        let a = 1.0 / self.count as f32;
        self.mean_nu2 += a * (nu2 - self.mean_nu2);
        self.mean_hph += a * ((s - r).max(0.0) - self.mean_hph);
    }

    /// The measurement variance the innovations show: `E[ν²] − E[H·P·Hᵀ]` (nT²; may be
    /// negative early on, while the state uncertainty dominates).
    pub fn observed_r(&self) -> f32 {
        self.mean_nu2 - self.mean_hph
    }

    /// Mean normalised innovation squared under measurement variance `r` (1 when the
    /// filter's account of its own uncertainty holds).
    pub fn nis(&self, r: f32) -> f32 {
        let s = self.mean_hph + r;
        if s > 0.0 {
            self.mean_nu2 / s
        } else {
            f32::NAN
        }
    }
}

/// Running spread of the raw scalar and of the estimated interference over a window:
/// the interference is part of the raw signal, so its spread cannot exceed the raw
/// signal's by much (the anomaly can cancel part of it, not hundreds of nT of it).
#[derive(Clone, Copy, Debug, Default)]
pub struct Divergence {
    raw: RunningSpread,
    interference: RunningSpread,
}

/// An interference whose spread exceeds `RATIO` × the raw signal's plus `MARGIN_NT` is
/// taken for divergence: on the real survey line the diverged real-time interference swung
/// 230 nT (and, on the board path, tens of thousands of nT) where the raw stinger moved by
/// a few nT; on calibration patterns the two spreads are alike (the interference is most
/// of the raw signal).
const RATIO: f32 = 3.0;
const MARGIN_NT: f32 = 10.0;

impl Divergence {
    pub const fn new() -> Self {
        Self {
            raw: RunningSpread::new(),
            interference: RunningSpread::new(),
        }
    }

    /// Feeds one epoch; true when the interference has run away from the raw signal.
    pub fn push(&mut self, raw_nt: f32, interference_nt: f32, window: u32) -> bool {
        if !(raw_nt.is_finite() && interference_nt.is_finite()) {
            return false;
        }
        self.raw.push(raw_nt, window);
        self.interference.push(interference_nt, window);
        self.raw.count >= window / 4 && self.interference.sd() > RATIO * self.raw.sd() + MARGIN_NT
    }
}

#[derive(Clone, Copy, Debug, Default)]
struct RunningSpread {
    mean: f32,
    var: f32,
    count: u32,
}

impl RunningSpread {
    const fn new() -> Self {
        Self {
            mean: 0.0,
            var: 0.0,
            count: 0,
        }
    }

    fn push(&mut self, v: f32, window: u32) {
        self.count = self.count.saturating_add(1).min(window.max(1));
        let a = 1.0 / self.count as f32;
        let d = v - self.mean;
        self.mean += a * d;
        self.var = (1.0 - a) * (self.var + a * d * d);
    }
    fn sd(&self) -> f32 {
        libm::sqrtf(self.var.max(0.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotations_keep_unit_length_and_turn_by_the_angle() {
        let e = [0.3f32, -0.2, 0.932_737_9];
        for axis in 0..3 {
            let r = rotated(e, axis, 0.3);
            let n: f32 = r.iter().map(|v| v * v).sum();
            assert!((n - 1.0).abs() < 1e-5);
            let dot: f32 = r.iter().zip(e).map(|(a, b)| a * b).sum();
            // the component along the axis is kept; the rest turns by 0.3 rad
            let along = e[axis] * e[axis];
            let cos = (dot - along) / (1.0 - along);
            assert!((cos - 0.3f32.cos()).abs() < 1e-4, "axis {axis}: {cos}");
        }
        // a heading reversal about z flips the horizontal components
        let r = rotated(e, 2, core::f32::consts::PI);
        assert!((r[0] + e[0]).abs() < 1e-6 && (r[1] + e[1]).abs() < 1e-6 && r[2] == e[2]);
    }

    #[test]
    fn monitor_sees_a_model_error_beyond_the_predicted_variance() {
        let mut m = InnovationMonitor::default();
        // innovations of ±2 nT where the filter predicts 0.02² + 0.01 nT²
        for k in 0..2000 {
            let nu = if k % 2 == 0 { 2.0 } else { -2.0 };
            m.push(nu, 0.0004 + 0.01, 0.0004, 300);
        }
        assert!((m.observed_r() - 3.99).abs() < 0.05, "{}", m.observed_r());
        assert!(m.nis(0.0004) > 300.0);
        // consistent innovations: NIS ≈ 1
        let mut m = InnovationMonitor::default();
        for k in 0..2000 {
            let nu = if k % 2 == 0 { 0.1 } else { -0.1 };
            m.push(nu, 0.01, 0.004, 300);
        }
        assert!((m.nis(0.004) - 1.0).abs() < 0.01);
    }

    #[test]
    fn one_glitch_does_not_make_a_model_error() {
        let mut m = InnovationMonitor::default();
        for k in 0..600 {
            let nu = if k == 400 {
                4000.0
            } else if k % 2 == 0 {
                0.02
            } else {
                -0.02
            };
            m.push(nu, 0.0004, 0.0004, 300);
        }
        assert!(m.nis(0.0004) < 1.2, "{}", m.nis(0.0004));
    }

    #[test]
    fn divergence_is_an_interference_far_beyond_the_raw_signal() {
        let mut d = Divergence::default();
        let mut hit = false;
        for k in 0..600 {
            let raw = 30.0 * libm::sinf(k as f32 * 0.3);
            hit |= d.push(raw, 0.9 * raw, 600);
        }
        assert!(!hit, "an interference that follows the raw signal");
        let mut hit_at = None;
        for k in 600..1200 {
            let raw = 3.0 * libm::sinf(k as f32 * 0.3);
            if d.push(raw, 300.0 * libm::sinf(k as f32 * 0.05), 600) && hit_at.is_none() {
                hit_at = Some(k);
            }
        }
        assert!(hit_at.is_some_and(|k| k < 800), "{hit_at:?}");
    }
}
