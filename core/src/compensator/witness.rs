//! The fluxgate as a witness, live. A fluxgate mounted near the scalar sees the aircraft's
//! field too, and `fluxmod` (|B_F| − |B|) turns that into a regressor of the interference;
//! where the fluxgate sees only the Earth, the same regressor is the fluxgate's own error
//! and a filter carrying it waits for a coefficient the flight cannot determine. So a board
//! runs both filters on the same samples, the paper model's and the witnessed one, and
//! shows the witnessed one's records only where its own stated bound is decisively tighter
//! — the flight's evidence, read live, as the host's post-flight calibration reads it from
//! the jackknife and the held-out figure.
//!
//! The two filters agree on the interference's variation, not on its level: in calibrate
//! mode neither determines the level (the anomaly states share it; the record's bound
//! covers the variation about the minute's mean). So a switch carries the level across:
//! the newly shown filter's interference is offset by the two filters' disagreement as
//! last seen with both records trusted, and the output has no step (the real boxes flown
//! cold through both: `mag_4`'s box-2 band std 1.10 nT, 11.2 with a step at each of its 3
//! switches), nor does it take a fault one filter showed while flagged.
//!
//! The witness leans on one more sensor, the fluxgate's modulus, whose errors its own bound
//! does not see; and where an effect both filters miss hides in the anomaly states, neither
//! bound sees it. What can be seen is how far the two disagree: a witnessed record states
//! at least the two filters' disagreement (its variation in the compensation band, about a
//! running mean of the band's lower-edge time constant). Simulated cabin current seen by
//! the fluxgate too (`replay_bound`): the witness's own bound was 2.2–8 × below its band
//! error; with the disagreement, 0.68–0.89 × its error.

use super::Output;
use crate::flags::Flags;
use crate::units::MagCounts;

/// How much tighter (×) the witness's stated bound must be before its records are shown:
/// the jackknife resolution the post-flight rule asks for (8 blocks, host
/// `calibration::cross_check`), so live and after landing ask for the same decisiveness.
pub const DECISIVE_RATIO: f32 = 1.46;

/// Whose record is shown.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shown {
    /// The paper model's filter (the board's default).
    Paper,
    /// The filter with the fluxgate as a witness (`fluxmod`).
    Witness,
}

/// The live choice between the two filters, with hysteresis: the witness takes over when
/// it is converged and its bound is [`DECISIVE_RATIO`] × tighter (or the paper filter has
/// not converged), and hands back when it loses convergence or its bound is no longer the
/// tighter one or its record alone is degraded, so two near-equal bounds do not alternate
/// the output sample by sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WitnessChoice {
    shown: Shown,
    /// Fixed by the coefficients loaded or by survey mode: no switching.
    fixed: bool,
    /// Fixed by loaded coefficients: the other filter holds nothing to compare with.
    loaded: bool,
    switches: u32,
    /// Added to the shown filter's interference (nT): the level carried across switches.
    level_nt: f32,
    /// The filters' disagreement (witness − paper interference, nT) while both records are
    /// trusted: its running mean and variance about it over ~`1 / rate` samples.
    disagreement_mean_nt: f32,
    disagreement_var_nt2: f32,
    disagreement_samples: u32,
    rate: f32,
    /// The disagreement at the last sample both filters' records were trusted (converged,
    /// not degraded): what a switch carries the level by, so a fault one filter shows
    /// (a fluxgate step: the witness's interference jumps while flagged) is not carried
    /// into the output.
    trusted_disagreement_nt: Option<f32>,
}

impl WitnessChoice {
    /// `window_samples`: the time constant the disagreement's running mean follows, in
    /// samples (the board's: 1.6 s, the compensation band's lower edge).
    pub fn new(window_samples: u32) -> Self {
        Self {
            shown: Shown::Paper,
            fixed: false,
            loaded: false,
            switches: 0,
            level_nt: 0.0,
            disagreement_mean_nt: 0.0,
            disagreement_var_nt2: 0.0,
            disagreement_samples: 0,
            rate: 1.0 / window_samples.max(1) as f32,
            trusted_disagreement_nt: None,
        }
    }

    /// The choice at a scalar rate: the disagreement is followed over the time constant of
    /// the compensation band's lower edge, 1 / (2π · 0.1 Hz) = 1.6 s, so it is taken in the
    /// band the records' bound is judged in (their slow level difference is the anomaly's).
    pub fn for_rate(scalar_hz: f64) -> Self {
        const BAND_LOW_HZ: f64 = 0.1;
        let window = libm::round(scalar_hz / (2.0 * core::f64::consts::PI * BAND_LOW_HZ));
        Self::new(window.max(1.0) as u32)
    }

    /// The two filters' disagreement (nT, 1σ about its running mean; 0 before both records
    /// were trusted together).
    pub fn disagreement_nt(&self) -> f32 {
        libm::sqrtf(self.disagreement_var_nt2.max(0.0))
    }

    fn follow_disagreement(&mut self, paper: &Output, witness: &Output) {
        if self.loaded {
            return;
        }
        let trusted = |o: &Output| !o.flags.contains(Flags::NOT_CONVERGED) && !o.flags.degraded();
        let d = witness.interference_nt - paper.interference_nt;
        if !(trusted(paper) && trusted(witness) && d.is_finite()) {
            return;
        }
        self.trusted_disagreement_nt = Some(d);
        // Exponentially weighted mean and variance (West's update: no cancellation of
        // large squares in f32, the level difference being tens to hundreds of nT).
        let a = if self.disagreement_samples == 0 {
            1.0
        } else {
            // the first samples weigh as a plain mean until the window fills
            self.rate.max(1.0 / (self.disagreement_samples + 1) as f32)
        };
        let delta = d - self.disagreement_mean_nt;
        self.disagreement_mean_nt += a * delta;
        self.disagreement_var_nt2 = (1.0 - a) * (self.disagreement_var_nt2 + a * delta * delta);
        self.disagreement_samples = self.disagreement_samples.saturating_add(1);
    }

    /// The choice is no longer the flight's to make: the loaded coefficients are `shown`'s,
    /// and they set the level.
    pub fn fix(&mut self, shown: Shown) {
        self.shown = shown;
        self.fixed = true;
        self.loaded = true;
        self.level_nt = 0.0;
    }

    /// Survey mode after calibrating in flight: the filter shown now stays shown, at the
    /// level it has.
    pub fn freeze(&mut self) {
        self.fixed = true;
    }

    /// The flight chooses again (calibrate mode).
    pub fn release(&mut self) {
        self.fixed = false;
        self.loaded = false;
    }

    pub fn shown(&self) -> Shown {
        self.shown
    }

    /// Times the shown filter changed (the operator's status).
    pub fn switches(&self) -> u32 {
        self.switches
    }

    /// The record shown for this sample, from the two filters' records of it: the chosen
    /// one's, its interference carried at the shown level, flagged [`Flags::WITNESS`] when
    /// it is the witness's.
    pub fn show(&mut self, paper: Output, witness: Output) -> Output {
        self.follow_disagreement(&paper, &witness);
        let before = self.shown;
        let now = self.choose(&paper, &witness);
        let of = |s: Shown| match s {
            Shown::Paper => paper,
            Shown::Witness => witness,
        };
        if now != before {
            // witness − paper, as last seen with both trusted (this sample's when it is)
            let d = self
                .trusted_disagreement_nt
                .unwrap_or(witness.interference_nt - paper.interference_nt);
            self.level_nt += match now {
                Shown::Witness => -d,
                Shown::Paper => d,
            };
        }
        let mut out = of(now);
        if self.level_nt != 0.0 {
            out.interference_nt += self.level_nt;
            out.compensated = out.mag.map(|m: MagCounts| m.minus_nt(out.interference_nt));
            // The level moved from the anomaly to the interference: their sum is the field.
            out.anomaly_nt -= self.level_nt;
        }
        if now == Shown::Witness {
            out.flags.set(Flags::WITNESS);
            if !self.loaded {
                // NaN (not converged) stays NaN
                out.interference_sigma_nt = out.interference_sigma_nt.max(self.disagreement_nt());
            }
        }
        out
    }

    /// Chooses for this sample from the two filters' records of it.
    pub fn choose(&mut self, paper: &Output, witness: &Output) -> Shown {
        if self.fixed {
            return self.shown;
        }
        let bound = |o: &Output| {
            let usable = !o.flags.contains(Flags::NOT_CONVERGED)
                && o.interference_sigma_nt.is_finite()
                && o.interference_sigma_nt > 0.0;
            usable.then_some(o.interference_sigma_nt)
        };
        let next = match (bound(paper), bound(witness)) {
            (_, None) => Shown::Paper,
            // The witness's own fault (its fluxgate stepped, a suspect modulus): the paper
            // filter's, which reads the fluxgate for its direction only, at the level last
            // seen with both trusted.
            _ if witness.flags.degraded() && !paper.flags.degraded() => Shown::Paper,
            // A shared cause (the ends of the stream, a gap, a GPS outage): no switch on
            // degraded records.
            _ if paper.flags.degraded() || witness.flags.degraded() => self.shown,
            (None, Some(_)) => Shown::Witness,
            (Some(p), Some(w)) => match self.shown {
                Shown::Paper if w * DECISIVE_RATIO < p => Shown::Witness,
                Shown::Witness if w > p => Shown::Paper,
                keep => keep,
            },
        };
        if next != self.shown {
            self.switches = self.switches.saturating_add(1);
            self.shown = next;
        }
        next
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn out(sigma_nt: f32, converged: bool) -> Output {
        let mut flags = Flags::empty();
        if !converged {
            flags.set(Flags::NOT_CONVERGED);
        }
        Output {
            t_s: 0.0,
            mag: None,
            interference_nt: 0.0,
            compensated: None,
            anomaly_nt: 0.0,
            innovation_nt: f32::NAN,
            innovation_var_nt2: f32::NAN,
            interference_sigma_nt: if converged { sigma_nt } else { f32::NAN },
            flags,
        }
    }

    #[test]
    fn the_witness_is_shown_only_when_decisively_tighter_and_handed_back_when_not() {
        let mut c = WitnessChoice::new(600);
        // not converged: the paper filter's, whatever its bound
        assert_eq!(c.choose(&out(4.0, true), &out(1.0, false)), Shown::Paper);
        // tighter but not decisively (4.0 / 3.0 = 1.33 < 1.46)
        assert_eq!(c.choose(&out(4.0, true), &out(3.0, true)), Shown::Paper);
        // decisively tighter
        assert_eq!(c.choose(&out(4.0, true), &out(2.0, true)), Shown::Witness);
        // held while still the tighter, even without the margin
        assert_eq!(c.choose(&out(4.0, true), &out(3.9, true)), Shown::Witness);
        // handed back once looser
        assert_eq!(c.choose(&out(4.0, true), &out(4.1, true)), Shown::Paper);
        // and back on the witness's loss of convergence
        assert_eq!(c.choose(&out(4.0, true), &out(1.0, true)), Shown::Witness);
        assert_eq!(c.choose(&out(4.0, true), &out(1.0, false)), Shown::Paper);
        assert_eq!(c.switches(), 4);
    }

    #[test]
    fn a_converged_witness_is_shown_while_the_paper_filter_is_not() {
        let mut c = WitnessChoice::new(600);
        assert_eq!(c.choose(&out(0.0, false), &out(2.0, true)), Shown::Witness);
    }

    #[test]
    fn a_switch_carries_the_level_so_the_output_has_no_step() {
        let with = |sigma: f32, interference_nt: f32| {
            let mut o = out(sigma, true);
            o.interference_nt = interference_nt;
            o.mag = MagCounts::from_nt_f64(53_000.0);
            o
        };
        let mut c = WitnessChoice::new(600);
        let a = c.show(with(4.0, 120.0), with(3.0, 40.0));
        assert_eq!(a.interference_nt, 120.0);
        assert!(!a.flags.contains(Flags::WITNESS));
        // the witness is shown: its variation (+1 nT) at the paper filter's level
        let b = c.show(with(4.0, 121.5), with(1.0, 41.0));
        assert!(b.flags.contains(Flags::WITNESS));
        assert_eq!(b.interference_nt, 121.5);
        assert_eq!(b.compensated, MagCounts::from_nt_f64(53_000.0 - 121.5));
        // the level leaves the witness's anomaly: anomaly + interference stays its field
        assert_eq!(b.anomaly_nt + b.interference_nt, 41.0);
        let b2 = c.show(with(4.0, 125.0), with(1.0, 42.0));
        assert_eq!(
            b2.interference_nt, 122.5,
            "the witness's variation, not the paper's"
        );
        // handed back: the paper filter continues from the shown value
        let d = c.show(with(4.0, 126.0), with(5.0, 42.5));
        assert!(!d.flags.contains(Flags::WITNESS));
        assert_eq!(d.interference_nt, 123.0);
        // loaded coefficients set the level: no offset
        c.fix(Shown::Paper);
        assert_eq!(
            c.show(with(4.0, 126.0), with(1.0, 42.5)).interference_nt,
            126.0
        );
    }

    #[test]
    fn a_witnessed_record_states_at_least_the_two_filters_disagreement() {
        let with = |sigma: f32, interference_nt: f32| {
            let mut o = out(sigma, true);
            o.interference_nt = interference_nt;
            o
        };
        let mut c = WitnessChoice::new(100);
        let mut last = with(0.0, 0.0);
        for k in 0..400 {
            // they disagree by ±2 nT about a 300 nT level difference; the witness claims 0.2
            let wobble = if k % 2 == 0 { 2.0 } else { -2.0 };
            last = c.show(with(4.0, 10.0), with(0.2, 310.0 + wobble));
        }
        assert!(last.flags.contains(Flags::WITNESS));
        assert!(
            (c.disagreement_nt() - 2.0).abs() < 0.1,
            "{}",
            c.disagreement_nt()
        );
        assert!((last.interference_sigma_nt - c.disagreement_nt()).abs() < 1e-6);
        // a paper record keeps its own bound
        let p = c.show(with(4.0, 10.0), with(5.0, 310.0));
        assert!(!p.flags.contains(Flags::WITNESS));
        assert_eq!(p.interference_sigma_nt, 4.0);
    }

    #[test]
    fn a_jump_the_shown_witness_makes_while_flagged_is_not_carried_into_the_output() {
        let with = |sigma: f32, interference_nt: f32, degraded: bool| {
            let mut o = out(sigma, true);
            o.interference_nt = interference_nt;
            if degraded {
                o.flags.set(Flags::FLUX_STALE);
            }
            o
        };
        let mut c = WitnessChoice::new(16);
        assert!(c
            .show(with(4.0, -827.0, false), with(1.0, -843.0, false))
            .flags
            .contains(Flags::WITNESS));
        // The fluxgate steps: the witness's interference jumps 426 nT, its record alone
        // flagged: the paper filter's is shown, at the level shown before the fault.
        let fault = c.show(with(4.0, -827.3, false), with(1.0, -1269.0, true));
        assert!(!fault.flags.contains(Flags::WITNESS));
        assert!(
            (fault.interference_nt - -827.3).abs() < 0.01,
            "{}",
            fault.interference_nt
        );
        // trusted again, the witness's bound tighter: shown again, still continuous
        let again = c.show(with(4.0, -827.4, false), with(1.0, -1269.1, false));
        assert!(again.flags.contains(Flags::WITNESS));
        assert!(
            (again.interference_nt - -827.4).abs() < 0.01,
            "{}",
            again.interference_nt
        );
        // both flagged (a shared cause): the shown filter holds, flagged
        let shared = c.show(with(0.5, -827.5, true), with(1.0, -1269.2, true));
        assert!(shared.flags.contains(Flags::WITNESS) && shared.flags.degraded());
    }

    #[test]
    fn loaded_coefficients_fix_the_choice() {
        let mut c = WitnessChoice::new(600);
        c.fix(Shown::Witness);
        assert_eq!(c.choose(&out(1.0, true), &out(9.0, false)), Shown::Witness);
        c.fix(Shown::Paper);
        assert_eq!(c.choose(&out(9.0, true), &out(1.0, true)), Shown::Paper);
        assert_eq!(c.switches(), 0);
    }
}
