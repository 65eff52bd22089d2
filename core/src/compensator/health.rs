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
//! - [`CoefficientHistory`]: an estimate still moving is not yet known to the tolerance.
//! - [`HeadingCoverage`]: a heading not yet flown is not known, whatever the covariance
//!   extrapolates to it.
//!
//! `Compensator::convergence` puts them together into `NOT_CONVERGED`.

use super::{Compensator, ENVELOPE_EVERY};
use crate::epoch::Epoch;
use crate::flags::Flags;

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

/// Envelope points 0–8 are the manoeuvres about the present attitude, 9–11 the other
/// headings.
pub const fn is_manoeuvre_point(k: usize) -> bool {
    k < 3 * MANOEUVRES_DEG.len()
}

/// `v` rotated by `angle_rad` about body axis `axis` (0 x, 1 y, 2 z).
#[cfg(test)]
fn rotated(v: [f32; 3], axis: usize, angle_rad: f32) -> [f32; 3] {
    rotated_sc(v, axis, (libm::sinf(angle_rad), libm::cosf(angle_rad)))
}

/// `v` rotated about body axis `axis` by the angle whose sine and cosine are `(s, c)`.
fn rotated_sc(v: [f32; 3], axis: usize, (s, c): (f32, f32)) -> [f32; 3] {
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

/// The rotation of envelope point `k` (axis, angle in rad), `None` for the rate points.
fn envelope_rotation(k: usize) -> Option<(usize, f32)> {
    match k {
        0..=8 => {
            let (axis, amp_deg) = MANOEUVRES_DEG[k / 3];
            let amp = amp_deg.to_radians();
            match k % 3 {
                0 | 1 => {
                    let sign = if k.is_multiple_of(3) { 1.0 } else { -1.0 };
                    Some((axis, sign * amp))
                }
                _ => None,
            }
        }
        _ => Some((2, HEADINGS_DEG[k - 9].to_radians())),
    }
}

/// Sine and cosine of every envelope point's rotation ((0, 0) for the rate points):
/// formed once, not with 18 soft-float `sinf`/`cosf` calls per envelope evaluation.
#[derive(Clone, Copy, Debug)]
pub struct EnvelopeRotations([(f32, f32); ENVELOPE_POINTS]);

impl EnvelopeRotations {
    pub const ZERO: Self = Self([(0.0, 0.0); ENVELOPE_POINTS]);

    pub fn new() -> Self {
        Self(core::array::from_fn(|k| match envelope_rotation(k) {
            Some((_, a)) => (libm::sinf(a), libm::cosf(a)),
            None => (0.0, 0.0),
        }))
    }
}

impl Default for EnvelopeRotations {
    fn default() -> Self {
        Self::new()
    }
}

/// The epoch as it would be at envelope point `k` (< [`ENVELOPE_POINTS`]): the same
/// position, field strength and auxiliary channels, another attitude.
pub fn envelope_epoch(ep: &Epoch, k: usize) -> Epoch {
    let sc = envelope_rotation(k).map_or((0.0, 0.0), |(_, a)| (libm::sinf(a), libm::cosf(a)));
    envelope_epoch_sc(ep, k, sc)
}

/// [`envelope_epoch`] with the sine and cosine of the point's rotation given.
fn envelope_epoch_sc(ep: &Epoch, k: usize, sc: (f32, f32)) -> Epoch {
    let mut out = *ep;
    envelope_attitude(ep, k, sc, &mut out);
    out
}

/// Sets `out.e` and `out.e_dot_per_s` to those of envelope point `k` of `ep` (the rest of
/// `out` is left as it is: the envelope reuses one copy of the epoch for all points).
fn envelope_attitude(ep: &Epoch, k: usize, sc: (f32, f32), out: &mut Epoch) {
    out.e = ep.e;
    out.e_dot_per_s = ep.e_dot_per_s;
    match k {
        0..=8 => {
            let (axis, amp_deg) = MANOEUVRES_DEG[k / 3];
            let amp = amp_deg.to_radians();
            match k % 3 {
                0 | 1 => {
                    out.e = rotated_sc(ep.e, axis, sc);
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
            out.e = rotated_sc(ep.e, 2, sc);
            out.e_dot_per_s = [0.0; 3];
        }
    }
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

/// Snapshots of the filter's term coefficients kept over the last window.
pub const HISTORY: usize = 4;

/// How far the coefficient estimate has moved over the last `converged_window_epochs`: a
/// covariance only says how far the estimate *should* move if the model holds. On an
/// independently simulated cloverleaf (broad physics) the filter declared itself
/// converged after one heading and a turn while 16 nT off, its estimate still moving by
/// tens of nT a minute; the movement is what gives that away.
pub struct CoefficientHistory<const N: usize> {
    ring: [[f32; N]; HISTORY],
    len: usize,
    next: usize,
    countdown: u32,
}

impl<const N: usize> CoefficientHistory<N> {
    pub const fn new() -> Self {
        Self {
            ring: [[0.0; N]; HISTORY],
            len: 0,
            next: 0,
            countdown: 0,
        }
    }

    /// Called once an epoch with the filter's state: a snapshot every
    /// `window_epochs / HISTORY` epochs.
    pub fn push(&mut self, state: &[f32], window_epochs: u32) {
        if self.countdown == 0 {
            self.countdown = (window_epochs / HISTORY as u32).max(1);
            let n = state.len().min(N);
            self.ring[self.next][..n].copy_from_slice(&state[..n]);
            self.next = (self.next + 1) % HISTORY;
            self.len = (self.len + 1).min(HISTORY);
        }
        self.countdown -= 1;
    }

    /// The oldest snapshot (about a window old) once the ring is full.
    pub fn oldest(&self) -> Option<&[f32; N]> {
        (self.len == HISTORY).then(|| &self.ring[self.next])
    }
}

impl<const N: usize> Default for CoefficientHistory<N> {
    fn default() -> Self {
        Self::new()
    }
}

/// A window is a manoeuvre when the field direction travels at least this far in it
/// (rad) ...
const MANOEUVRE_PATH_RAD: f32 = 0.3;
/// ... and ends up less than this share of that from where it started: swings, not a
/// turn (which carries the direction steadily around).
const MANOEUVRE_NET_SHARE: f32 = 0.3;
/// Largest heading gap (rad, 120°) around the compass without manoeuvres: four headings
/// 90° apart leave 93–111° on the flights measured (the windows' directions scatter with
/// the swings), three of four leave 180°.
const MAX_GAP_RAD: f32 = 2.094_395;
/// Smallest mean distance of the windows' directions from their axis (rad): below it the
/// heading barely changes the field direction (near a magnetic pole) and nothing was
/// covered. The flights measured (inclination 56–70°) spread 0.21–0.53.
const MIN_SPREAD: f32 = 0.03;
/// Manoeuvre windows kept (the oldest overwritten): a pattern of four headings fills 10–18.
const MAX_WINDOWS: usize = 48;

/// Have the manoeuvres been flown around the compass? A filter's covariance carries the
/// interference to headings it has not manoeuvred on from the levels of steady flight and
/// turns, where the anomaly states take part of it: on simulated cloverleaves (ours, and an
/// independent simulator's) the output was then 0.2–1.5 nT off at a stated 0.04–0.09 nT 1σ
/// until the last heading's manoeuvres were flown. (Band-passed least squares, which uses
/// the manoeuvres only, is what an AARC solves at the end of the pattern.)
///
/// Frame-free: the fluxgate's axes need not be the body's. The field direction in the
/// fluxgate frame goes round a cone about the aircraft's vertical as the heading changes,
/// so the mean directions of the manoeuvre windows go round their mean axis once every
/// heading has been flown, with no gap wider than [`MAX_GAP_RAD`]. Measured: complete at
/// the last heading's first manoeuvres on our cloverleaves (630–730 s), at 1030 s on the
/// independent `clean_s33` and 1010 s on `lag_s32` (their last headings), at 520 s of the
/// real box 1 (650 s) and 450 s into box 2; never on a take-off and straight lines.
#[derive(Clone, Copy, Debug)]
pub struct HeadingCoverage {
    start: [f32; 3],
    sum: [f32; 3],
    path_rad: f32,
    epochs: u32,
    /// Mean field directions of the manoeuvre windows (a ring).
    directions: [[f32; 3]; MAX_WINDOWS],
    windows: usize,
    /// Epochs since the directions first went round (0 before).
    complete_epochs: u32,
}

impl HeadingCoverage {
    pub const fn new() -> Self {
        Self {
            start: [0.0; 3],
            sum: [0.0; 3],
            path_rad: 0.0,
            epochs: 0,
            directions: [[0.0; 3]; MAX_WINDOWS],
            windows: 0,
            complete_epochs: 0,
        }
    }

    /// One epoch's field direction `e`, its rate and the time step; `window_epochs`: the
    /// manoeuvre window's length.
    pub fn push(&mut self, e: &[f32; 3], e_dot: &[f32; 3], dt_s: f32, window_epochs: u32) {
        if self.complete_epochs > 0 {
            self.complete_epochs = self.complete_epochs.saturating_add(1);
        }
        if !e.iter().chain(e_dot).all(|v| v.is_finite()) {
            return;
        }
        if self.epochs == 0 {
            self.start = *e;
            self.sum = [0.0; 3];
            self.path_rad = 0.0;
        }
        self.epochs += 1;
        for (s, v) in self.sum.iter_mut().zip(e) {
            *s += v;
        }
        if dt_s.is_finite() && dt_s > 0.0 {
            self.path_rad += norm(e_dot) * dt_s;
        }
        if self.epochs < window_epochs.max(1) {
            return;
        }
        self.epochs = 0;
        let net = norm(&[
            e[0] - self.start[0],
            e[1] - self.start[1],
            e[2] - self.start[2],
        ]);
        let length = norm(&self.sum);
        if self.path_rad < MANOEUVRE_PATH_RAD
            || net >= MANOEUVRE_NET_SHARE * self.path_rad
            || !(length > 0.0)
        {
            return;
        }
        self.directions[self.windows % MAX_WINDOWS] = self.sum.map(|v| v / length);
        self.windows += 1;
        if self.complete_epochs == 0 && self.goes_round() {
            self.complete_epochs = 1;
        }
    }

    /// Epochs since every heading's manoeuvres were first seen (0: not yet). The last
    /// heading's first swings complete the round; its other manoeuvres still move the
    /// estimate (0.28 nT at a stated 0.024 nT on our cloverleaf when the flag cleared
    /// then), so `NOT_CONVERGED` waits a window after this.
    pub fn epochs_complete(&self) -> u32 {
        self.complete_epochs
    }

    /// The manoeuvre windows' directions go round their mean axis without a wide gap.
    fn goes_round(&self) -> bool {
        let n = self.windows.min(MAX_WINDOWS);
        if n < 4 {
            return false;
        }
        let d = &self.directions[..n];
        let mut axis = [0.0f32; 3];
        for v in d {
            for (a, x) in axis.iter_mut().zip(v) {
                *a += x;
            }
        }
        let length = norm(&axis);
        if !(length > 0.0) {
            return false;
        }
        let axis = axis.map(|v| v / length);
        let off_axis = |v: &[f32; 3]| {
            let along = dot(v, &axis);
            [
                v[0] - along * axis[0],
                v[1] - along * axis[1],
                v[2] - along * axis[2],
            ]
        };
        // Azimuths about the axis from the first window's direction.
        let reference = off_axis(&d[0]);
        let spread = d.iter().map(|v| norm(&off_axis(v))).sum::<f32>() / n as f32;
        let r = norm(&reference);
        if !(spread >= MIN_SPREAD) || !(r > 0.1 * spread) {
            return false;
        }
        let x_axis = reference.map(|v| v / r);
        let y_axis = cross(&axis, &x_axis);
        let mut azimuths = [0.0f32; MAX_WINDOWS];
        for (a, v) in azimuths.iter_mut().zip(d) {
            let phi = libm::atan2f(dot(v, &y_axis), dot(v, &x_axis));
            *a = if phi < 0.0 {
                phi + core::f32::consts::TAU
            } else {
                phi
            };
        }
        let azimuths = &mut azimuths[..n];
        azimuths.sort_unstable_by(|a, b| a.total_cmp(b));
        let wrap = azimuths[0] + core::f32::consts::TAU - azimuths[n - 1];
        let widest = azimuths
            .windows(2)
            .map(|w| w[1] - w[0])
            .fold(wrap, f32::max);
        widest <= MAX_GAP_RAD
    }
}

fn dot(a: &[f32; 3], b: &[f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn norm(a: &[f32; 3]) -> f32 {
    libm::sqrtf(dot(a, a))
}

fn cross(a: &[f32; 3], b: &[f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

impl Default for HeadingCoverage {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize, const W: usize> Compensator<'_, N, W> {
    /// Calibrate mode: sets `NOT_CONVERGED` while the interference is not determined:
    /// the predicted 1σ of its variation about the last minute's mean, or of its change to
    /// any attitude of the survey envelope ([`envelope_epoch`]: the manoeuvres and
    /// the other headings), widened by the innovations' excess over their prediction
    /// (mean NIS), exceeds `cfg.converged_sigma_nt`. Evaluated every `cfg.converged_every`
    /// epochs (O(n²) per envelope point), the flag held in between.
    /// `phys`: the epoch's physical regressors (as in `process`).
    pub(super) fn convergence(&mut self, ep: &Epoch, phys: &[f32; N], flags: &mut Flags) {
        if self.survey || !(self.cfg.converged_sigma_nt > 0.0) {
            if self.level_undetermined {
                flags.set(Flags::LEVEL_UNDETERMINED);
            }
            return;
        }
        // Running mean: a plain average until the window fills, then exponential.
        self.regressor_mean_count = self
            .regressor_mean_count
            .saturating_add(1)
            .min(self.cfg.converged_window_epochs.max(1));
        let alpha = 1.0 / self.regressor_mean_count as f32;
        let r = self.terms_at..self.n;
        for (m, p) in self.regressor_mean[r.clone()].iter_mut().zip(&phys[r]) {
            *m += alpha * (p - *m);
        }
        self.history
            .push(self.filter.state(), self.cfg.converged_window_epochs);
        self.coverage.push(
            &ep.e,
            &ep.e_dot_per_s,
            ep.dt_s,
            self.cfg.converged_window_epochs / 6,
        );
        if self.converged_countdown == 0 {
            self.converged_countdown = self.cfg.converged_every.max(1);
            let mean = self.regressor_mean;
            let window_var = self.interference_change_variance(phys, &mean, 0);
            // The envelope (12 × O(n²)) every `ENVELOPE_EVERY`-th evaluation: on the
            // Cortex-M4 it doubled `Compensator::push` when made at every one (7 953 →
            // 14 680 instructions on average, 21 states); the envelope moves with the
            // heading, slowly, and the window figure is still checked every evaluation.
            if self.envelope_countdown == 0 {
                self.envelope_countdown = ENVELOPE_EVERY;
                self.evaluate_envelope(ep, phys, &mean);
            }
            self.envelope_countdown -= 1;
            // against the variance in use: the covariance is expressed in it (the factor)
            let nis = self
                .innovations
                .nis(self.cfg.noise_nt * self.cfg.noise_nt * self.variance_factor);
            let inflation = if nis.is_finite() { nis.max(1.0) } else { 1.0 };
            // What the estimate moved over the last window is not the model's variance:
            // it is not widened by the innovations, only taken when larger.
            let band_var = window_var.max(self.envelope_var) * inflation;
            let var = band_var.max(self.movement_var);
            self.interference_sigma_nt = if var > 0.0 {
                libm::sqrtf(var)
            } else {
                var.max(0.0)
            };
            self.coefficient_sigma_nt =
                libm::sqrtf((window_var * inflation).max(self.movement_var).max(0.0));
            self.model_sigma_nt = libm::sqrtf(band_var.max(0.0));
            // A survey's tolerance, or what the model cannot describe when that is larger:
            // more flying then no longer shrinks the record's bound, whose model-error part
            // already dominates. On the real SGL boxes (model error 0.2–0.8 nT) the
            // coefficient part fell to 0.05–0.3 nT by the end of box 1 and never to 0.1,
            // and the coefficients held then compensate box 2 as well as a post-flight
            // calibration of box 1 (band std 0.75 / 4.04 / 3.34 nT against 0.79 / 4.40 /
            // 3.37 for mag_5 / mag_3 / mag_4). Not the noise alone: a limit at the sensor
            // noise cleared after the first heading (55 s) and the output then swung
            // 110–170 nT on the next headings; the heading coverage below prevents that.
            let limit = self
                .cfg
                .converged_sigma_nt
                .max(self.model_error_nt())
                .max(self.manoeuvre_model_error_nt());
            // NaN (a broken filter) counts as not converged; so does the first window,
            // before there is any variation to judge.
            // Only headings manoeuvred on count: what the covariance says of the others
            // rests on levels and turns, where the anomaly states take part of the
            // interference.
            // Hysteresis: once converged, only a bound twice the limit sets the flag again.
            // The estimate keeps chasing what the model lacks by about the model error
            // (real boxes: 0.05–1 nT a minute), which is in the bound, not a lack of
            // determination; without it the flag flickered on 40–90 % of box 2's records.
            let lim = if self.not_converged {
                limit
            } else {
                2.0 * limit
            };
            self.not_converged = !(var <= lim * lim)
                || self.regressor_mean_count < self.cfg.converged_window_epochs / 4
                || self.coverage.epochs_complete() < self.cfg.converged_window_epochs;
            let level_var = (self.heading_var * inflation).max(self.level_movement_var);
            self.level_undetermined = !(level_var <= limit * limit);
            if !self.not_converged && inflation < 3.0 {
                self.last_good[self.terms_at..self.n]
                    .copy_from_slice(&self.filter.state()[self.terms_at..self.n]);
                self.has_last_good = true;
            }
        }
        self.converged_countdown -= 1;
        if self.not_converged {
            flags.set(Flags::NOT_CONVERGED);
        } else if self.level_undetermined {
            flags.set(Flags::LEVEL_UNDETERMINED);
        }
    }

    /// The model error the manoeuvres show (nT): the adapted scalar variance, which rises
    /// within seconds of a manoeuvre and decays over minutes (board; 0 where the noise is
    /// not adapted). The envelope is the interference's change over a manoeuvre, so it is
    /// judged against the model error of a manoeuvre, not of the last 30 s, which on a
    /// straight leg shows half of it (real box 1, `mag_3` with its fluxgate as witness, over
    /// box 1's last minute: 0.95–1.9 nT where the adapted variance held 1.9–2.0 nT).
    fn manoeuvre_model_error_nt(&self) -> f32 {
        if !self.cfg.adaptive_noise {
            return 0.0;
        }
        // Beyond the same floor as `model_error_nt` (a board without a configured sensor
        // noise counted its whole adapted noise as model error here).
        let sensor_nt = self.sensor_floor_nt();
        libm::sqrtf((self.adapted_r - sensor_nt * sensor_nt).max(0.0))
    }

    /// The survey envelope at this epoch ([`envelope_epoch`]), split by what levelling can
    /// and cannot remove. The manoeuvres about the present attitude are the interference's
    /// variation within a minute: its predicted variance (`envelope_var`) and how far it
    /// moved over the last window, relative to the present attitude and to the window's
    /// mean (`movement_var`) — the record's bound. The other headings and the level at the
    /// present attitude are what a pattern without revisits leaves to the anomaly states
    /// (on a real box the legs of each heading lie over other ground): their variance and
    /// movement (`heading_var`, `level_movement_var`) go to `LEVEL_UNDETERMINED`.
    /// NaN (a broken filter) propagates, so it counts as not converged.
    fn evaluate_envelope(&mut self, ep: &Epoch, phys: &[f32; N], mean: &[f32; N]) {
        fn worst(a: f32, b: f32) -> f32 {
            if a.is_nan() || b.is_nan() {
                f32::NAN
            } else {
                a.max(b)
            }
        }
        let oldest = self.history.oldest().copied();
        let level_moved = match &oldest {
            Some(old) => self.interference_moved(phys, old),
            None => f32::INFINITY,
        };
        let mut band_moved = match &oldest {
            Some(old) => libm::fabsf(level_moved - self.interference_moved(mean, old)),
            None => f32::INFINITY,
        };
        let (mut band_var, mut heading_var, mut heading_moved) = (0.0f32, 0.0f32, 0.0f32);
        // the states before the terms drop out of the 12 variances exactly when finite
        // (checked once here; not worth its cost for the single window variance)
        let lead = if self.filter.leading_rows_finite(self.terms_at) {
            self.terms_at
        } else {
            0
        };
        let mut other = [0.0f32; N];
        let mut at = *ep;
        for k in 0..ENVELOPE_POINTS {
            // only the interference terms' entries are read below
            envelope_attitude(ep, k, self.envelope_rotations.0[k], &mut at);
            self.term_regressors(&at, &mut other[self.terms_at..self.n]);
            let v = self.interference_change_variance(phys, &other, lead);
            let moved = match &oldest {
                Some(old) => libm::fabsf(self.interference_moved(&other, old) - level_moved),
                None => f32::INFINITY,
            };
            if is_manoeuvre_point(k) {
                band_var = worst(band_var, v);
                band_moved = worst(band_moved, moved);
            } else {
                heading_var = worst(heading_var, v);
                heading_moved = worst(heading_moved, moved);
            }
        }
        self.envelope_var = band_var;
        self.movement_var = band_moved * band_moved;
        self.heading_var = heading_var;
        self.level_movement_var = worst(heading_moved * heading_moved, level_moved * level_moved);
    }
}
