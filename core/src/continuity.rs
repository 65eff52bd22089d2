//! A reading judged against its own recent past: the scalar where the filter cannot judge
//! it, and the fluxgate's modulus and vector on every frame. One engine, [`ContinuityCheck`],
//! generic over the reading ([`Reading`]) and with its own floor, so the scalar's
//! arithmetic is exactly what it was before the fluxgate shared it.
//!
//! The scalar ([`ScalarContinuity`]) is judged before the filter has fused a first sample
//! (it has no level yet), on the ground (no updates), and on samples whose regressors are
//! suspect (predict only). A scalar line carries no checksum, so a corrupted digit is a
//! different number; without this check a +4000 nT value at sample 65, or a tens digit
//! changed on the apron, left the board unflagged.
//!
//! The fluxgate ([`FluxContinuity`]): a frame that passes its checksum and parse but reads
//! wrong (an axis 0, a corrupted digit moving the modulus by thousands of nT) would go
//! straight into the regressors; the board has no look-ahead, so this is the causal
//! counterpart of the host's despiker (`host/src/signal/despike.rs`). Its vector side sees
//! what keeps the modulus (an axis near 0 read as 0, a sign flip, swapped axes, a rotation).
//!
//! The prediction is the line through the last two accepted samples; a sample is suspect
//! when it departs from it by more than a floor plus a multiple of the recent departures'
//! robust spread (their median absolute value). A real step (engine start, the apron's
//! steel) is taken as the new level after `STEP_RUN` (3) samples that agree with one another.

use crate::epoch::diff_nt;
use crate::units::MagCounts;

/// Smallest scalar departure ever judged suspect (nT): above the quantum magnetometers'
/// noise (0.002–0.02 nT) and their second differences at rest, below a corrupted units digit.
const SCALAR_FLOOR_NT: f32 = 0.5;
/// Smallest fluxgate-modulus departure ever judged suspect (nT): the host despiker's floor;
/// no real field moves the fluxgate modulus 20 nT between two frames at ≥ 10 Hz beyond what
/// its recent departures show (the fluxgate's own noise and quantisation are ~0.1–1 nT).
pub const FLUX_FLOOR_NT: f32 = 20.0;
/// Multiple of the recent departures' median absolute value: 8 × 1.48 ≈ 12σ for Gaussian
/// departures, so manoeuvres and taxiing (whose departures the median follows) pass.
const SPREAD_FACTOR: f32 = 12.0;
/// Recent departures kept for the spread.
const SPREAD_LEN: usize = 8;
/// Suspect samples in a row that agree with one another before they are taken as a real
/// step to a new level.
const STEP_RUN: u8 = 3;
/// After this long without an accepted sample there is no past to judge against (s).
const MAX_GAP_S: f64 = 2.0;

/// The verdict on one sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Continuity {
    /// Consistent with the recent samples.
    Consistent,
    /// Departs from the recent samples beyond the limit: flagged `MAG_SUSPECT`, not fused.
    Suspect,
    /// Nothing to judge it against (the first sample, or the first after a long gap):
    /// flagged `MAG_SUSPECT`, but the filter may take its level from it.
    Unverified,
}

/// A reading the check can difference (nT).
pub trait Reading: Copy {
    /// `self − earlier` in nT.
    fn diff_nt(self, earlier: Self) -> f32;
}

impl Reading for MagCounts {
    fn diff_nt(self, earlier: Self) -> f32 {
        diff_nt(self, earlier)
    }
}

/// A value already in nT (the fluxgate's modulus).
impl Reading for f32 {
    fn diff_nt(self, earlier: Self) -> f32 {
        self - earlier
    }
}

/// The scalar's check (floor 0.5 nT).
pub type ScalarContinuity = ContinuityCheck<MagCounts>;

impl ContinuityCheck<MagCounts> {
    pub const fn new() -> Self {
        Self::with_floor(SCALAR_FLOOR_NT)
    }
}

impl Default for ContinuityCheck<MagCounts> {
    fn default() -> Self {
        Self::new()
    }
}

#[derive(Clone, Copy, Debug)]
pub struct ContinuityCheck<V: Reading> {
    /// Smallest departure ever judged suspect (nT).
    floor_nt: f32,
    /// The last two accepted samples (time s, reading), newest first.
    last: [Option<(f64, V)>; 2],
    departures: Spread,
    /// The last suspect sample and how many in a row agree with it.
    candidate: Option<(f64, V)>,
    candidate_run: u8,
}

impl<V: Reading> ContinuityCheck<V> {
    pub const fn with_floor(floor_nt: f32) -> Self {
        Self {
            floor_nt,
            last: [None; 2],
            departures: Spread::new(),
            candidate: None,
            candidate_run: 0,
        }
    }

    /// Forgets the past (keeps the floor).
    pub fn restart(&mut self) {
        *self = Self::with_floor(self.floor_nt);
    }

    /// Judges `mag` at `t_s` against the recent accepted samples and learns from it.
    pub fn judge(&mut self, t_s: f64, mag: V) -> Continuity {
        let Some((t1, x1)) = self.last[0].filter(|(t1, _)| t_s - *t1 <= MAX_GAP_S) else {
            // Nothing to judge against: this sample starts the record, unverified.
            self.restart();
            self.accept(t_s, mag, None);
            return Continuity::Unverified;
        };
        let departure = self.departure_nt(t_s, mag, t1, x1);
        let limit = self.limit_nt();
        if libm::fabsf(departure) <= limit {
            self.accept(t_s, mag, Some(departure));
            return Continuity::Consistent;
        }
        self.suspect(t_s, mag, limit);
        Continuity::Suspect
    }

    /// Records a sample the filter judged and found consistent with its prediction, so the
    /// continuity check stays current while the filter does the judging.
    pub fn accept_judged(&mut self, t_s: f64, mag: V) {
        let departure = self.last[0]
            .filter(|(t1, _)| t_s - *t1 <= MAX_GAP_S)
            .map(|(t1, x1)| self.departure_nt(t_s, mag, t1, x1));
        self.accept(t_s, mag, departure);
    }

    /// Departure of `mag` from the line through the last two accepted samples (from the
    /// last one alone when there is one).
    fn departure_nt(&self, t_s: f64, mag: V, t1: f64, x1: V) -> f32 {
        let step_nt = mag.diff_nt(x1);
        match self.last[1] {
            Some((t2, x2)) if t1 > t2 => {
                let slope_ratio = ((t_s - t1) / (t1 - t2)) as f32;
                step_nt - x1.diff_nt(x2) * slope_ratio
            }
            _ => step_nt,
        }
    }

    fn limit_nt(&self) -> f32 {
        match self.departures.median_abs() {
            Some(spread) => self.floor_nt + SPREAD_FACTOR * spread,
            // One accepted sample: no spread yet, so only a gross departure is suspect.
            None => 100.0 * self.floor_nt,
        }
    }

    fn accept(&mut self, t_s: f64, mag: V, departure_nt: Option<f32>) {
        self.last = [Some((t_s, mag)), self.last[0]];
        if let Some(d) = departure_nt {
            self.departures.push(d);
        }
        self.candidate = None;
        self.candidate_run = 0;
    }

    /// A suspect sample: if it continues a run of suspect samples that agree with one
    /// another (within `limit_nt`) long enough, the run is a real step and its last sample
    /// the new level.
    fn suspect(&mut self, t_s: f64, mag: V, limit_nt: f32) {
        let agrees = self.agrees(t_s, mag, limit_nt);
        self.note_suspect(t_s, mag, agrees);
    }

    /// Whether a suspect `mag` agrees with the last suspect sample (within `limit_nt`).
    fn agrees(&self, t_s: f64, mag: V, limit_nt: f32) -> bool {
        self.candidate.is_some_and(|(tc, xc)| {
            t_s - tc <= MAX_GAP_S && libm::fabsf(mag.diff_nt(xc)) <= limit_nt
        })
    }

    /// Counts a suspect sample into the run; true when the run is a step and `mag` has
    /// been taken as the new level.
    fn note_suspect(&mut self, t_s: f64, mag: V, agrees: bool) -> bool {
        self.candidate_run = if agrees { self.candidate_run + 1 } else { 1 };
        self.candidate = Some((t_s, mag));
        if self.candidate_run >= STEP_RUN {
            // The spread of the old level says nothing about the new one.
            self.restart();
            self.accept(t_s, mag, None);
            return true;
        }
        false
    }
}

/// The last [`SPREAD_LEN`] finite departures (nT) and their median absolute value.
#[derive(Clone, Copy, Debug)]
struct Spread {
    nt: [f32; SPREAD_LEN],
    len: usize,
    next: usize,
}

impl Spread {
    const fn new() -> Self {
        Self {
            nt: [0.0; SPREAD_LEN],
            len: 0,
            next: 0,
        }
    }

    fn push(&mut self, d: f32) {
        if d.is_finite() {
            self.nt[self.next] = d;
            self.next = (self.next + 1) % SPREAD_LEN;
            self.len = (self.len + 1).min(SPREAD_LEN);
        }
    }

    /// The upper median of |departure| (None while empty).
    fn median_abs(&self) -> Option<f32> {
        let n = self.len;
        if n == 0 {
            return None;
        }
        let mut sorted = [0.0f32; SPREAD_LEN];
        for (s, d) in sorted.iter_mut().zip(&self.nt[..n]) {
            *s = libm::fabsf(*d);
        }
        let sorted = &mut sorted[..n];
        sorted.sort_unstable_by(|a, b| a.total_cmp(b));
        Some(sorted[n / 2])
    }
}

/// Angular acceleration (rad/s²) the vector check allows for beyond its recent departures:
/// a body turning at a changing rate moves the field vector off the line through the last
/// two frames by about |B| × α × dt² (SGL flight 1002's calibration manoeuvres and turn
/// entries reach ~0.37 rad/s² equivalent, 200 nT at 10 Hz, with the departures before them
/// ~10 nT); the median follows a manoeuvre within 4 frames, this covers its onset.
pub const FLUX_ANGULAR_ACCEL_RAD_S2: f32 = 0.2;
/// Fraction of the last frames' motion the vector check allows for beyond its recent
/// departures: a change of body rate by that fraction of itself within one frame (a sharp
/// control input; the simulator's pitch manoeuvres change their rate 5 → 10°/s between two
/// 10 Hz frames, ~0.9 rad/s²).
pub const FLUX_RATE_CHANGE: f32 = 1.0;
/// Angular acceleration (rad/s²) allowed while there are no recent departures to scale by
/// (the first departure from the line after a start, a gap or a step): a survey aircraft's
/// gusts and control inputs, ~5× the calibration manoeuvres' 0.37 rad/s².
pub const FLUX_MAX_ANGULAR_ACCEL_RAD_S2: f32 = 2.0;
/// Body rate (rad/s, 34°/s) allowed between the only two frames there are (the first frame
/// judged after a start, a gap or a step): above a survey aircraft's manoeuvres (±10° roll
/// at 5 s, ~13°/s), turns and taxiing.
pub const FLUX_MAX_BODY_RATE_RAD_S: f32 = 0.6;

/// The fluxgate's check on each corrected body-frame frame (f32 nT), judged two ways
/// against the line through the last two accepted frames:
/// - the modulus |B| (floor [`FLUX_FLOOR_NT`]): a corrupted digit, an axis read as 0 where
///   it was large;
/// - the vector: the norm of the frame's vector departure, against [`FLUX_FLOOR_NT`] +
///   [`FLUX_RATE_CHANGE`] × the last two frames' motion scaled to this interval +
///   [`FLUX_ANGULAR_ACCEL_RAD_S2`] × |B| × dt², plus the same multiple of the median of its
///   last 8 norms. It sees what keeps |B| (an axis that read near 0 read as 0, a sign flip
///   of a small axis, two axes swapped, a rotated frame), which the modulus cannot; the
///   motion and dt² terms let a change of body rate and a manoeuvre's onset through, its
///   median the rest. Before any departure is known, physical bounds stand in for the
///   median: a step from the only frame within [`FLUX_MAX_BODY_RATE_RAD_S`] × |B| × dt, the
///   first departure from the line within [`FLUX_MAX_ANGULAR_ACCEL_RAD_S2`] × |B| × dt²
///   (beside the motion term).
///
/// A frame is suspect when either says so, and then not learnt from by either; the same
/// run and gap as the scalar's (3 suspects in a row that agree in both = a real step). Time
/// is the frame's stamp (s); a stamp earlier than the last accepted one (a clock reset)
/// restarts it.
#[derive(Clone, Copy, Debug)]
pub struct FluxContinuity {
    modulus: ContinuityCheck<f32>,
    vector: VectorTrack,
}

/// The vector side of [`FluxContinuity`], accepting and restarting with the modulus engine.
#[derive(Clone, Copy, Debug)]
struct VectorTrack {
    /// The last two accepted frames (time s, vector nT), newest first.
    last: [Option<(f64, [f32; 3])>; 2],
    departures: Spread,
    /// The last suspect frame's departure vector: a run agrees when its frames depart from
    /// the (unchanged) prediction alike, so a step taken while turning still agrees.
    candidate: Option<[f32; 3]>,
}

impl VectorTrack {
    const fn new() -> Self {
        Self {
            last: [None; 2],
            departures: Spread::new(),
            candidate: None,
        }
    }

    /// `(t_s − t₁) / (t₁ − t₂)` for the last two accepted frames (None with fewer), once
    /// per frame: f64 is soft-float on the board.
    fn ratio(&self, t_s: f64) -> Option<f32> {
        match self.last {
            [Some((t1, _)), Some((t2, _))] if t1 > t2 => Some(((t_s - t1) / (t1 - t2)) as f32),
            _ => None,
        }
    }

    /// `v` minus the line through the last two accepted frames (`ratio` of [`Self::ratio`];
    /// the last one alone when there is one; `v` itself when there is none).
    fn departure(&self, ratio: Option<f32>, v: [f32; 3]) -> [f32; 3] {
        match (self.last, ratio) {
            ([Some((_, v1)), Some((_, v2))], Some(r)) => {
                core::array::from_fn(|k| v[k] - v1[k] - (v1[k] - v2[k]) * r)
            }
            ([Some((_, v1)), _], _) => core::array::from_fn(|k| v[k] - v1[k]),
            _ => v,
        }
    }

    /// The limit on the departure's norm, `dt_s` after an accepted frame of modulus
    /// `m1_nt`.
    fn limit_nt(&self, ratio: Option<f32>, dt_s: f32, m1_nt: f32) -> f32 {
        let (r, v1, v2) = match (ratio, self.last) {
            (Some(r), [Some((_, v1)), Some((_, v2))]) => (r, v1, v2),
            // No line yet: the step from the only frame is the body's rotation over dt.
            _ => {
                return FLUX_FLOOR_NT
                    + FLUX_ANGULAR_ACCEL_RAD_S2 * m1_nt * dt_s * dt_s
                    + FLUX_MAX_BODY_RATE_RAD_S * m1_nt * dt_s
            }
        };
        // The body rate may change by up to itself within a frame: allow the last frames'
        // motion over this interval again.
        let motion = modulus_nt(core::array::from_fn(|k| v1[k] - v2[k])) * r;
        match self.departures.median_abs() {
            Some(spread) => {
                FLUX_FLOOR_NT
                    + FLUX_RATE_CHANGE * motion
                    + FLUX_ANGULAR_ACCEL_RAD_S2 * m1_nt * dt_s * dt_s
                    + SPREAD_FACTOR * spread
            }
            // The first departure from the line: no spread to scale by yet.
            None => {
                FLUX_FLOOR_NT
                    + FLUX_RATE_CHANGE * motion
                    + FLUX_MAX_ANGULAR_ACCEL_RAD_S2 * m1_nt * dt_s * dt_s
            }
        }
    }

    fn accept(&mut self, t_s: f64, v: [f32; 3], departure_nt: Option<f32>) {
        self.last = [Some((t_s, v)), self.last[0]];
        if let Some(d) = departure_nt {
            self.departures.push(d);
        }
        self.candidate = None;
    }
}

impl FluxContinuity {
    pub const fn new() -> Self {
        Self {
            modulus: ContinuityCheck::with_floor(FLUX_FLOOR_NT),
            vector: VectorTrack::new(),
        }
    }

    /// Forgets the past (a new calibration, a restart).
    pub fn restart(&mut self) {
        *self = Self::new();
    }

    /// Judges the frame `v` (body frame, nT) stamped `t_s`. A frame that is not finite is
    /// `Suspect` and not learnt from.
    pub fn judge(&mut self, t_s: f64, v: [f32; 3]) -> Continuity {
        self.judge_with_margins(t_s, v).0
    }

    /// [`Self::judge`], with each check's departure as a fraction of its limit (modulus,
    /// vector; 0 when not judged): how close a record came (measurements and tests).
    pub fn judge_with_margins(&mut self, t_s: f64, v: [f32; 3]) -> (Continuity, [f32; 2]) {
        let m = modulus_nt(v);
        if !m.is_finite() {
            return (Continuity::Suspect, [0.0; 2]);
        }
        let last = self.modulus.last[0].filter(|(t1, _)| t_s >= *t1 && t_s - *t1 <= MAX_GAP_S);
        let Some((t1, m1)) = last else {
            // Nothing to judge against (the first frame, a gap, the clock went back).
            self.restart();
            self.modulus.accept(t_s, m, None);
            self.vector.accept(t_s, v, None);
            return (Continuity::Unverified, [0.0; 2]);
        };
        let dm = self.modulus.departure_nt(t_s, m, t1, m1);
        let lm = self.modulus.limit_nt();
        let ratio = self.vector.ratio(t_s);
        let dv = self.vector.departure(ratio, v);
        let nv = modulus_nt(dv);
        let lv = self.vector.limit_nt(ratio, (t_s - t1) as f32, m1);
        let margins = [libm::fabsf(dm) / lm, nv / lv];
        if libm::fabsf(dm) <= lm && nv <= lv {
            self.modulus.accept(t_s, m, Some(dm));
            // A step from the only frame is the rotation itself, not a departure from a
            // line: it would set the spread to the body rate.
            self.vector.accept(t_s, v, ratio.map(|_| nv));
            return (Continuity::Consistent, margins);
        }
        let agrees = self.modulus.agrees(t_s, m, lm)
            && self
                .vector
                .candidate
                .is_some_and(|c| modulus_nt(core::array::from_fn(|k| dv[k] - c[k])) <= lv);
        if self.modulus.note_suspect(t_s, m, agrees) {
            // A real step: the new level for both.
            self.vector = VectorTrack::new();
            self.vector.accept(t_s, v, None);
        } else {
            self.vector.candidate = Some(dv);
        }
        (Continuity::Suspect, margins)
    }
}

impl Default for FluxContinuity {
    fn default() -> Self {
        Self::new()
    }
}

/// |v| (nT).
pub fn modulus_nt(v: [f32; 3]) -> f32 {
    libm::sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
}

/// Shortest time (s) and fewest frames an axis must repeat the same value while another
/// axis moves before it is judged stuck: a real fluxgate's noise and the aircraft's motion
/// change every axis from frame to frame (SGL 2020's fluxgates never repeat a value twice
/// in a row in flight), and 2 s is one turbulence period.
const STUCK_MIN_S: f64 = 2.0;
const STUCK_MIN_FRAMES: u32 = 20;
/// How far (nT) another axis must move meanwhile: the aircraft is moving, so the stuck
/// axis should have too. At rest nothing moves and no axis is judged.
const STUCK_OTHERS_MOVE_NT: f32 = 5.0;

/// An axis that repeats one value while the others move (a dead channel, an axis read as 0
/// from power-up): the continuity check sees a change, not a channel that never changes.
/// From the second frame on, until every axis has been seen to change once since the
/// start, the frames are not trusted either: an axis that has never moved cannot be told
/// from a dead one (a real fluxgate's noise moves every axis between its first two frames,
/// so a working one loses none; the first frame, which nothing can judge, is taken, and
/// its record is already `DERIVATIVE_DEGRADED`).
#[derive(Clone, Copy, Debug, Default)]
pub struct StuckAxis {
    /// Per axis: the frame where its current run of one value began, its time and the
    /// frames since.
    runs: [Option<([f32; 3], f64, u32)>; 3],
    /// Per axis: it has changed since the start.
    moved: [bool; 3],
    /// Frames judged since the start (saturating).
    frames: u32,
}

impl StuckAxis {
    pub const fn new() -> Self {
        Self {
            runs: [None; 3],
            moved: [false; 3],
            frames: 0,
        }
    }

    /// Forgets every run (a restart).
    pub fn restart(&mut self) {
        *self = Self::new();
    }

    /// The frame `v` at `t_s`: true from the second frame while an axis has not changed
    /// since the start, when one has held one value for at least `STUCK_MIN_S` and
    /// `STUCK_MIN_FRAMES` while another moved `STUCK_OTHERS_MOVE_NT`, and when the whole
    /// frame has held as long.
    pub fn judge(&mut self, t_s: f64, v: [f32; 3]) -> bool {
        let mut stuck = false;
        self.frames = self.frames.saturating_add(1);
        for (axis, run) in self.runs.iter_mut().enumerate() {
            if run.is_some_and(|(start, _, _)| start[axis] != v[axis]) {
                self.moved[axis] = true;
            }
            match run {
                Some((start, t0, frames)) if start[axis] == v[axis] && t_s >= *t0 => {
                    *frames = frames.saturating_add(1);
                    let others_moved = (0..3)
                        .filter(|&b| b != axis)
                        .any(|b| (v[b] - start[b]).abs() > STUCK_OTHERS_MOVE_NT);
                    stuck |=
                        *frames >= STUCK_MIN_FRAMES && t_s - *t0 >= STUCK_MIN_S && others_moved;
                }
                _ => *run = Some((v, t_s, 1)),
            }
        }
        // The whole frame repeated (a reader that resends its last buffer): nothing moved,
        // which the aircraft cannot hold for 2 s in the air, and a fluxgate's noise not
        // even at rest.
        let frozen = self.runs.iter().all(|r| {
            r.is_some_and(|(_, t0, frames)| frames >= STUCK_MIN_FRAMES && t_s - t0 >= STUCK_MIN_S)
        });
        stuck || frozen || (self.frames >= 2 && self.moved.contains(&false))
    }
}

/// Largest difference between the fluxgate's modulus and the scalar field, as a fraction of
/// the scalar, that a working fluxgate shows. SGL 2020's uncalibrated fluxgates differ from
/// their scalars by up to 12 % (6,176 nT, `flux_c` against `mag_4` through calibration
/// box 1: scale, offset and the cabin's own field). An axis read as 0 from power-up, which
/// the continuity check cannot see (it has no past), takes that axis's component away: on
/// the vertical axis 60–95 % of the field.
pub const FLUX_SCALAR_MAX_FRACTION: f32 = 0.2;

/// The fluxgate frame `flux_nt` reads no field an aircraft carrying the scalar that reads
/// `scalar_nt` can see: their moduli differ by more than [`FLUX_SCALAR_MAX_FRACTION`].
pub fn flux_disagrees_with_scalar(flux_nt: [f32; 3], scalar_nt: f32) -> bool {
    let m = modulus_nt(flux_nt);
    m.is_finite()
        && scalar_nt.is_finite()
        && scalar_nt > 0.0
        && (m - scalar_nt).abs() > FLUX_SCALAR_MAX_FRACTION * scalar_nt
}

#[cfg(test)]
mod tests {
    use super::*;

    fn nt(v: f64) -> MagCounts {
        MagCounts::from_nt_f64(v).unwrap()
    }

    /// 10 Hz, a slow ramp with 0.01 nT of alternating noise.
    fn quiet(i: usize) -> f64 {
        50_000.0 + 0.3 * i as f64 + if i.is_multiple_of(2) { 0.01 } else { -0.01 }
    }

    #[test]
    fn the_first_sample_is_unverified_and_a_quiet_record_passes() {
        let mut c = ScalarContinuity::new();
        assert_eq!(c.judge(0.0, nt(quiet(0))), Continuity::Unverified);
        for i in 1..200 {
            assert_eq!(
                c.judge(i as f64 * 0.1, nt(quiet(i))),
                Continuity::Consistent,
                "sample {i}"
            );
        }
    }

    #[test]
    fn a_changed_digit_is_suspect_and_the_next_sample_is_not() {
        for (digit_nt, sign) in [(1.0, 1.0), (4000.0, 1.0), (10.0, -1.0), (2.0, -1.0)] {
            let mut c = ScalarContinuity::new();
            for i in 0..50 {
                c.judge(i as f64 * 0.1, nt(quiet(i)));
            }
            let bad = quiet(50) + sign * digit_nt;
            assert_eq!(c.judge(5.0, nt(bad)), Continuity::Suspect, "{digit_nt}");
            assert_eq!(c.judge(5.1, nt(quiet(51))), Continuity::Consistent);
        }
    }

    #[test]
    fn a_real_step_becomes_the_new_level_after_a_short_run() {
        let mut c = ScalarContinuity::new();
        for i in 0..50 {
            c.judge(i as f64 * 0.1, nt(quiet(i)));
        }
        let mut verdicts = [Continuity::Consistent; 8];
        for (k, v) in verdicts.iter_mut().enumerate() {
            let i = 50 + k;
            *v = c.judge(i as f64 * 0.1, nt(quiet(i) + 35.0));
        }
        // Three suspect (the run that proves the step), then consistent again.
        assert_eq!(&verdicts[..3], &[Continuity::Suspect; 3]);
        assert!(verdicts[4..].iter().all(|v| *v == Continuity::Consistent));
    }

    #[test]
    fn a_wild_first_sample_costs_only_a_short_run() {
        let mut c = ScalarContinuity::new();
        c.judge(0.0, nt(quiet(0) + 400.0));
        let suspect = (1..100)
            .filter(|&i| c.judge(i as f64 * 0.1, nt(quiet(i))) == Continuity::Suspect)
            .count();
        assert!(suspect <= STEP_RUN as usize, "{suspect}");
    }

    #[test]
    fn manoeuvres_pass() {
        // A 20 nT, 3 s interference swing at 10 Hz.
        let mut c = ScalarContinuity::new();
        let x = |i: usize| {
            quiet(i) + 20.0 * libm::sin(i as f64 * 0.1 * 2.0 * core::f64::consts::PI / 3.0)
        };
        c.judge(0.0, nt(x(0)));
        let suspect = (1..600)
            .filter(|&i| c.judge(i as f64 * 0.1, nt(x(i))) == Continuity::Suspect)
            .count();
        assert_eq!(suspect, 0);
    }

    // The fluxgate's check.

    /// 10 Hz, a fluxgate vector whose modulus ramps slowly (0.5 nT/frame) with 0.3 nT of
    /// alternating noise, turning slowly in the body frame.
    fn flux_quiet(i: usize) -> [f32; 3] {
        let m = 52_000.0 + 0.5 * i as f64 + if i.is_multiple_of(2) { 0.3 } else { -0.3 };
        flux_at(i, m)
    }

    fn flux_at(i: usize, modulus: f64) -> [f32; 3] {
        let a = i as f64 * 0.01;
        let (s, c) = (libm::sin(a), libm::cos(a));
        let u = [0.6 * c, 0.6 * s, 0.8];
        u.map(|x| (x * modulus) as f32)
    }

    fn flux_judge_all(f: impl Fn(usize) -> [f32; 3], n: usize) -> [usize; 3] {
        let mut c = FluxContinuity::new();
        let mut counts = [0; 3];
        for i in 0..n {
            let k = match c.judge(i as f64 * 0.1, f(i)) {
                Continuity::Consistent => 0,
                Continuity::Suspect => 1,
                Continuity::Unverified => 2,
            };
            counts[k] += 1;
        }
        counts
    }

    #[test]
    fn flux_quiet_and_manoeuvring_records_pass() {
        assert_eq!(flux_judge_all(flux_quiet, 2000), [1999, 0, 1]);
        // A manoeuvre: the modulus swings ±300 nT at 0.3 Hz (its second difference
        // reaches 10.7 nT per frame at 10 Hz), plus the noise.
        let swing = |i: usize| {
            let t = i as f64 * 0.1;
            let m = 52_000.0
                + 300.0 * libm::sin(2.0 * core::f64::consts::PI * 0.3 * t)
                + if i.is_multiple_of(2) { 0.3 } else { -0.3 };
            flux_at(i, m)
        };
        assert_eq!(flux_judge_all(swing, 2000), [1999, 0, 1]);
    }

    #[test]
    fn a_flux_frame_read_wrong_is_suspect_and_the_next_is_not() {
        let zero_z = |v: [f32; 3]| [v[0], v[1], 0.0];
        let plus_5000 = |v: [f32; 3]| [v[0], v[1], v[2] + 5000.0];
        let zero_x = |v: [f32; 3]| [0.0, v[1], v[2]];
        // A glitch just above the floor and the spread (the quiet record's departures are
        // ~1.2 nT: limit ≈ 20 + 12 × 1.2 ≈ 34 nT), not one below it.
        let plus_60 = |v: [f32; 3]| [v[0], v[1], v[2] + 60.0 / 0.8];
        let fs: [&dyn Fn([f32; 3]) -> [f32; 3]; 4] = [&zero_z, &plus_5000, &zero_x, &plus_60];
        for (k, f) in fs.iter().enumerate() {
            let mut c = FluxContinuity::new();
            for i in 0..100 {
                c.judge(i as f64 * 0.1, flux_quiet(i));
            }
            assert_eq!(
                c.judge(10.0, f(flux_quiet(100))),
                Continuity::Suspect,
                "{k}"
            );
            for i in 101..120 {
                assert_eq!(
                    c.judge(i as f64 * 0.1, flux_quiet(i)),
                    Continuity::Consistent,
                    "{k} {i}"
                );
            }
        }
        let mut c = FluxContinuity::new();
        for i in 0..100 {
            c.judge(i as f64 * 0.1, flux_quiet(i));
        }
        let small = |v: [f32; 3]| [v[0], v[1], v[2] + 10.0 / 0.8];
        assert_eq!(
            c.judge(10.0, small(flux_quiet(100))),
            Continuity::Consistent
        );
    }

    #[test]
    fn a_real_flux_step_is_taken_after_three_frames() {
        let mut c = FluxContinuity::new();
        for i in 0..100 {
            c.judge(i as f64 * 0.1, flux_quiet(i));
        }
        let stepped = |i: usize| {
            let m =
                52_000.0 + 0.5 * i as f64 + 500.0 + if i.is_multiple_of(2) { 0.3 } else { -0.3 };
            flux_at(i, m)
        };
        let verdicts: [Continuity; 20] =
            core::array::from_fn(|k| c.judge((100 + k) as f64 * 0.1, stepped(100 + k)));
        assert_eq!(&verdicts[..3], &[Continuity::Suspect; 3]);
        assert!(
            verdicts[3..].iter().all(|v| *v == Continuity::Consistent),
            "{verdicts:?}"
        );
    }

    #[test]
    fn flux_after_a_gap_or_a_clock_reset_is_unverified() {
        let mut c = FluxContinuity::new();
        for i in 0..50 {
            c.judge(i as f64 * 0.1, flux_quiet(i));
        }
        // 3 s without a frame, then a level 800 nT away: nothing to judge it against.
        assert_eq!(c.judge(7.9, flux_at(79, 52_800.0)), Continuity::Unverified);
        assert_eq!(c.judge(8.0, flux_at(80, 52_800.5)), Continuity::Consistent);
        // The clock went back (a restart): a fresh start.
        assert_eq!(c.judge(0.0, flux_quiet(0)), Continuity::Unverified);
        assert_eq!(
            c.judge(0.1, [f32::NAN, 0.0, 0.0]),
            Continuity::Suspect,
            "not finite"
        );
        assert_eq!(c.judge(0.2, flux_quiet(2)), Continuity::Consistent);
    }

    #[test]
    fn an_axis_that_never_moves_while_the_others_do_is_stuck_after_two_seconds() {
        // 10 Hz, the aircraft rolling: x and y swing by hundreds of nT, z reads 0.
        let frame = |k: u32| {
            let a = k as f32 * 0.3;
            [15_000.0 * libm::cosf(a), 15_000.0 * libm::sinf(a), 0.0]
        };
        // Never seen to move: the first frame is taken (nothing can judge it), the
        // second and every one after it are not trusted.
        let mut check = StuckAxis::new();
        assert!(!check.judge(0.0, frame(0)));
        assert!((1..40u32).all(|k| check.judge(f64::from(k) * 0.1, frame(k))));
        // Once it moves, it is trusted; stuck again while the others move, it is judged
        // stuck on the run's 21st frame (2.0 s).
        assert!(!check.judge(4.0, [1.0, 2.0, 3.0]));
        let first = (41..80u32)
            .find(|&k| check.judge(f64::from(k) * 0.1, frame(k)))
            .expect("judged stuck");
        assert_eq!(first, 61, "the run began at frame 41: {first}");
    }

    #[test]
    fn a_fluxgate_at_rest_or_in_motion_is_never_stuck() {
        // At rest a fluxgate's noise moves every axis: nothing is judged.
        let noise = |k: u32| [0.1, -0.1, 0.05].map(|a| if k.is_multiple_of(2) { a } else { -a });
        let mut rest = StuckAxis::new();
        assert!((0..100u32).all(|k| {
            let n = noise(k);
            !rest.judge(
                f64::from(k) * 0.1,
                [15_000.0 + n[0], -800.0 + n[1], 49_000.0 + n[2]],
            )
        }));
        let mut moving = StuckAxis::new();
        moving.judge(0.0, [0.0; 3]);
        assert!((1..100u32).all(|k| {
            let a = k as f32 * 0.05;
            !moving.judge(
                f64::from(k) * 0.1,
                [
                    15_000.0 + 50.0 * libm::sinf(a),
                    -800.0 + 30.0 * libm::cosf(a),
                    49_000.0 + a,
                ],
            )
        }));
    }

    #[test]
    fn a_frame_repeated_whole_for_two_seconds_is_frozen() {
        let mut check = StuckAxis::new();
        assert!(!check.judge(0.0, [15_000.0, -800.0, 49_000.0]));
        assert!(!check.judge(0.1, [15_000.1, -800.1, 49_000.1]));
        let frozen = [15_000.2, -800.2, 49_000.2];
        let first = (2..60u32)
            .find(|&k| check.judge(f64::from(k) * 0.1, frozen))
            .expect("judged frozen");
        assert_eq!(first, 22, "the run began at frame 2: {first}");
    }

    #[test]
    fn a_fluxgate_modulus_far_from_the_scalar_is_no_field() {
        // SGL's worst uncalibrated fluxgate, 12 % off, passes; a vertical axis read as 0
        // does not.
        assert!(!flux_disagrees_with_scalar(
            [45_000.0, 0.0, 30_000.0],
            48_000.0
        ));
        assert!(flux_disagrees_with_scalar(
            [15_552.0, -794.0, 0.0],
            51_522.0
        ));
        assert!(!flux_disagrees_with_scalar(
            [15_552.0, -794.0, 0.0],
            f32::NAN
        ));
    }
}
