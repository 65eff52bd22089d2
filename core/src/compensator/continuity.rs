//! The scalar judged against its own recent past, where the filter cannot judge it: before
//! the filter has fused a first sample (it has no level yet), on the ground (no updates),
//! and on samples whose regressors are suspect (predict only). A scalar line carries no
//! checksum, so a corrupted digit is a different number; without this check a +4000 nT
//! value at sample 65, or a tens digit changed on the apron, left the board unflagged.
//!
//! The prediction is the line through the last two accepted samples; a sample is suspect
//! when it departs from it by more than a floor plus a multiple of the recent departures'
//! robust spread (their median absolute value). A real step (engine start, the apron's
//! steel) is taken as the new level after [`STEP_RUN`] samples that agree with one another.

use crate::epoch::diff_nt;
use crate::units::MagCounts;

/// Smallest departure ever judged suspect (nT): above the quantum magnetometers' noise
/// (0.002–0.02 nT) and their second differences at rest, below a corrupted units digit.
const FLOOR_NT: f32 = 0.5;
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

#[derive(Clone, Copy, Debug)]
pub struct ScalarContinuity {
    /// The last two accepted samples (time s, reading), newest first.
    last: [Option<(f64, MagCounts)>; 2],
    departures_nt: [f32; SPREAD_LEN],
    departures_len: usize,
    departures_next: usize,
    /// The last suspect sample and how many in a row agree with it.
    candidate: Option<(f64, MagCounts)>,
    candidate_run: u8,
}

impl ScalarContinuity {
    pub const fn new() -> Self {
        Self {
            last: [None; 2],
            departures_nt: [0.0; SPREAD_LEN],
            departures_len: 0,
            departures_next: 0,
            candidate: None,
            candidate_run: 0,
        }
    }

    /// Judges `mag` at `t_s` against the recent accepted samples and learns from it.
    pub fn judge(&mut self, t_s: f64, mag: MagCounts) -> Continuity {
        let Some((t1, x1)) = self.last[0].filter(|(t1, _)| t_s - *t1 <= MAX_GAP_S) else {
            // Nothing to judge against: this sample starts the record, unverified.
            *self = Self::new();
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
    pub fn accept_judged(&mut self, t_s: f64, mag: MagCounts) {
        let departure = self.last[0]
            .filter(|(t1, _)| t_s - *t1 <= MAX_GAP_S)
            .map(|(t1, x1)| self.departure_nt(t_s, mag, t1, x1));
        self.accept(t_s, mag, departure);
    }

    /// Departure of `mag` from the line through the last two accepted samples (from the
    /// last one alone when there is one).
    fn departure_nt(&self, t_s: f64, mag: MagCounts, t1: f64, x1: MagCounts) -> f32 {
        let step_nt = diff_nt(mag, x1);
        match self.last[1] {
            Some((t2, x2)) if t1 > t2 => {
                let slope_ratio = ((t_s - t1) / (t1 - t2)) as f32;
                step_nt - diff_nt(x1, x2) * slope_ratio
            }
            _ => step_nt,
        }
    }

    fn limit_nt(&self) -> f32 {
        let n = self.departures_len;
        if n == 0 {
            // One accepted sample: no spread yet, so only a gross departure is suspect.
            return 100.0 * FLOOR_NT;
        }
        let mut sorted = [0.0f32; SPREAD_LEN];
        for (s, d) in sorted.iter_mut().zip(&self.departures_nt[..n]) {
            *s = libm::fabsf(*d);
        }
        let sorted = &mut sorted[..n];
        sorted.sort_unstable_by(|a, b| a.total_cmp(b));
        FLOOR_NT + SPREAD_FACTOR * sorted[n / 2]
    }

    fn accept(&mut self, t_s: f64, mag: MagCounts, departure_nt: Option<f32>) {
        self.last = [Some((t_s, mag)), self.last[0]];
        if let Some(d) = departure_nt.filter(|d| d.is_finite()) {
            self.departures_nt[self.departures_next] = d;
            self.departures_next = (self.departures_next + 1) % SPREAD_LEN;
            self.departures_len = (self.departures_len + 1).min(SPREAD_LEN);
        }
        self.candidate = None;
        self.candidate_run = 0;
    }

    /// A suspect sample: if it continues a run of suspect samples that agree with one
    /// another (within `limit_nt`) long enough, the run is a real step and its last sample
    /// the new level.
    fn suspect(&mut self, t_s: f64, mag: MagCounts, limit_nt: f32) {
        let agrees = self.candidate.is_some_and(|(tc, xc)| {
            t_s - tc <= MAX_GAP_S && libm::fabsf(diff_nt(mag, xc)) <= limit_nt
        });
        self.candidate_run = if agrees { self.candidate_run + 1 } else { 1 };
        self.candidate = Some((t_s, mag));
        if self.candidate_run >= STEP_RUN {
            // The spread of the old level says nothing about the new one.
            *self = Self::new();
            self.accept(t_s, mag, None);
        }
    }
}

impl Default for ScalarContinuity {
    fn default() -> Self {
        Self::new()
    }
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
}
