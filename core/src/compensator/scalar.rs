//! The scalar magnetometer as an aid source (as PX4's EKF2 keeps one fusion per file): its
//! innovation, gate and update, and a status record of what the last fusion did.

use super::Compensator;
use crate::continuity::Continuity;
use crate::epoch::Epoch;
use crate::flags::Flags;

/// What the last scalar fusion did: the record PX4 keeps per aid source.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScalarFusion {
    /// Innovation `z − H·x` and its predicted variance `H·P·Hᵀ + r` (nT, nT²; NaN when the
    /// sample was not offered: no scalar, suspect regressors, on the ground).
    pub innovation_nt: f32,
    pub innovation_var_nt2: f32,
    /// `ν² / (gate² · S)`: above 1 the gate refuses the sample (NaN without a gate).
    pub test_ratio: f32,
    /// The sample updated the filter (Huber-weighted while the gate warms up).
    pub fused: bool,
    /// The gate refused it (`INNOVATION_REJECTED`).
    pub rejected: bool,
}

impl ScalarFusion {
    pub const NONE: ScalarFusion = ScalarFusion {
        innovation_nt: f32::NAN,
        innovation_var_nt2: f32::NAN,
        test_ratio: f32::NAN,
        fused: false,
        rejected: false,
    };
}

/// Time constants of the adapted scalar variance: up, and back down (s).
const ADAPT_RISE_S: f32 = 10.0;
const ADAPT_DECAY_S: f32 = 600.0;
/// Ceiling of the adapted variance (nT²): the hundreds of nT of innovations while the
/// coefficients are still unknown are not noise. 5 nT: the SGL cabin `mag_3` without its
/// fluxgate as a witness leaves 4.3 nT in the band; under a 2 nT ceiling its witnessed filter,
/// at 2.0 nT, judged its own convergence against too small a model error and lost it over
/// box 1's last heading.
const ADAPT_MAX_NT2: f32 = 25.0;

/// Updates before the gate arms: until then an innovation beyond it is Huber-weighted.
const GATE_WARM_UP_UPDATES: u32 = 100;

impl<const N: usize, const W: usize> Compensator<'_, N, W> {
    /// Fuses the epoch's scalar difference `ep.dmag_nt` with regressors `h` (scaled);
    /// `frozen_nt` is the interference of the frozen coefficients (survey mode, where they
    /// are no states). Regressors built from a held fluxgate frame or a derivative across a
    /// lost one are wrong by the field's change over the gap: such a sample predicts, it
    /// does not update (a capture with 1 % of its fluxgate bytes corrupted loses 28 % of the
    /// frames; learning from those samples left the calibration 1.1–1.6 nT off).
    pub(super) fn fuse_scalar(
        &mut self,
        ep: &Epoch,
        h: &[f32; N],
        frozen_nt: f32,
        flags: &mut Flags,
    ) -> ScalarFusion {
        let on_ground = ep.reported_speed_mps < self.cfg.min_update_speed_mps;
        let offered = ep.dmag_nt.is_finite() && !ep.regressors_suspect && !on_ground;
        // Until it has fused a sample the filter has no level to predict from (its prior
        // spans thousands of nT), and where it does not update it does not look: there the
        // scalar is judged against its own recent readings.
        let judged_here = !offered || self.updates == 0;
        if judged_here {
            let verdict = match ep.mag {
                Some(m) if ep.dmag_nt.is_finite() => self.continuity.judge(ep.t_s, m),
                _ => Continuity::Consistent,
            };
            if verdict != Continuity::Consistent {
                flags.set(Flags::MAG_SUSPECT);
            }
            // An unverified first reading still gives the filter its level (the anomaly
            // estimate of the first record is otherwise the prior's); a jump does not.
            if !offered || verdict == Continuity::Suspect {
                return ScalarFusion::NONE;
            }
        }
        // The spread a reading is judged against includes the model error the recent
        // innovations show beyond the configured noise: on a real installation it is
        // 0.2–2 nT where the board assumes 0.02, and judged by the prediction alone 99 % of
        // the real SGL boxes' readings were "suspect". Taken before this sample joins it.
        self.follow_variance_factor();
        let r = self.scalar_variance_nt2();
        let model_error_var = (self.innovations.observed_r() - r).max(0.0);
        let status = self.fuse_offered(ep, h, frozen_nt, r, flags);
        let suspect_sigma = self.cfg.suspect_sigma;
        let beyond = suspect_sigma > 0.0
            && status.innovation_nt * status.innovation_nt
                > suspect_sigma * suspect_sigma * (status.innovation_var_nt2 + model_error_var);
        if beyond {
            flags.set(Flags::MAG_SUSPECT);
        } else if let (Some(m), true, false) = (ep.mag, status.fused, judged_here) {
            self.continuity.accept_judged(ep.t_s, m);
        }
        status
    }

    /// The configured scalar variance (nT²): `noise_nt`, times the present noise scale.
    fn configured_variance_nt2(&self) -> f32 {
        let sigma = self.cfg.noise_nt * self.noise_scale;
        sigma * sigma
    }

    /// The scalar's variance for the next update (nT²): the configured noise, raised in
    /// real time to what the recent innovations show (`adaptive_noise`).
    fn scalar_variance_nt2(&self) -> f32 {
        let configured = self.configured_variance_nt2();
        if self.cfg.adaptive_noise {
            configured.max(self.adapted_r)
        } else {
            configured
        }
    }

    /// Expresses the covariance in the variance factor the adapted scalar variance shows
    /// (`adapted_r / configured`, at least 1): every sample fused so far is re-weighted as if
    /// it had been fused at today's noise, so each keeps the weight of every other. Raising
    /// the measurement noise alone fused the pattern's first manoeuvres at the floor's
    /// weight, ~44 × the rest on real box 1's `mag_3`, and locked their unmodelled part into
    /// the coefficients (box 2 at 2.13 nT band std where post-flight gives 1.57; now 1.60).
    /// Exact where every state is constant (the information is the sum of `h·hᵀ / r`); the
    /// field states' covariance is scaled too and relaxes within the anomaly's correlation
    /// distance under its process noise, which is left as configured: the ground's roughness
    /// does not grow with the installation's model error. Scaling the coefficients' block
    /// alone (field states untouched) moved `mag_4` with `flux_d` from 1.12 to 1.23 × its
    /// post-flight calibration and kept `mag_3` at 1.28 ×; the whole covariance keeps the
    /// four real-box pairs within 1.12 ×. The trade: flown on in calibrate mode through a
    /// second pattern, the paper filter follows it more (docs/model.md §5).
    fn follow_variance_factor(&mut self) {
        if !self.cfg.adaptive_noise {
            return;
        }
        let factor = (self.adapted_r / self.configured_variance_nt2()).max(1.0);
        if factor.is_finite() && factor != self.variance_factor {
            self.filter.scale_covariance(factor / self.variance_factor);
            self.variance_factor = factor;
        }
    }

    /// Follows the innovations' measurement variance with a long memory: a real
    /// installation's model error is largest at the manoeuvre peaks, which carry the
    /// information, so a level learnt on a quiet leg must not be what the next manoeuvre
    /// is fused with (tried: the 30 s window alone flew box 2 at 18.6 nT band rms).
    fn adapt_scalar_variance(&mut self) {
        let observed = self.innovations.observed_r();
        if !(self.cfg.adaptive_noise && observed.is_finite()) {
            return;
        }
        // The consistency window is 30 s of epochs (`for_rate`).
        let rate_hz = (self.cfg.consistency_window_epochs.max(1) as f32 / 30.0).max(0.1);
        self.adapted_r = follow_variance(self.adapted_r, observed, rate_hz);
    }

    /// The gated update of an offered sample with scalar variance `r` (warm-up:
    /// Huber-weighted beyond the gate).
    fn fuse_offered(
        &mut self,
        ep: &Epoch,
        h: &[f32; N],
        frozen_nt: f32,
        r: f32,
        flags: &mut Flags,
    ) -> ScalarFusion {
        let z = if self.survey {
            ep.dmag_nt - frozen_nt
        } else {
            ep.dmag_nt
        };
        let gate = self.cfg.gate_sigma;
        let warming_up = self.updates <= GATE_WARM_UP_UPDATES;
        let gating = gate > 0.0 && !warming_up && self.reject_run < self.cfg.gate_max_run;
        // The gate sees ν and its predicted variance from the same pass over U that the
        // update uses (one Uᵀh instead of three).
        let mut status = ScalarFusion::NONE;
        match self.filter.update_weighted(h, z, r, |nu, s| {
            let beyond = gate > 0.0 && nu * nu > gate * gate * s;
            match (beyond, gating, warming_up) {
                (false, ..) => Some(r),
                (true, true, _) => None,
                (true, false, true) => Some(r + nu * nu / (gate * gate) - s),
                // forced in after a run of rejections: taken at face value, so a real
                // change cannot lock the filter out
                (true, false, false) => Some(r),
            }
        }) {
            Some(Err(rejected)) => {
                self.reject_run += 1;
                flags.set(Flags::INNOVATION_REJECTED);
                status.innovation_nt = rejected.value;
                status.innovation_var_nt2 = rejected.variance;
                status.rejected = true;
            }
            Some(Ok(inn)) => {
                self.reject_run = 0;
                self.updates = self.updates.saturating_add(1);
                status.innovation_nt = inn.value;
                status.innovation_var_nt2 = inn.variance;
                status.fused = true;
            }
            None => {}
        }
        if gate > 0.0 {
            let s = status.innovation_var_nt2;
            status.test_ratio = status.innovation_nt * status.innovation_nt / (gate * gate * s);
        }
        self.innovations.push(
            status.innovation_nt,
            status.innovation_var_nt2,
            r,
            self.cfg.consistency_window_epochs,
        );
        self.adapt_scalar_variance();
        status
    }
}

/// One step of the adapted scalar variance (nT²) towards the innovations' `observed_nt2`
/// at `rate_hz` epochs per second. The observation is `E[ν²] − E[H·P·Hᵀ]`, negative while
/// the state's uncertainty explains more than the innovations show (the first minutes of
/// a cold start): that is no evidence of model error, so it counts as 0. Followed as it
/// was, the variance learnt −85 to −19,000 nT² on the real boxes' first 100 s and left
/// the floor only 110–350 s in, after the manoeuvres had been fused.
fn follow_variance(adapted_nt2: f32, observed_nt2: f32, rate_hz: f32) -> f32 {
    let observed_nt2 = observed_nt2.clamp(0.0, ADAPT_MAX_NT2);
    let tau_s = if observed_nt2 > adapted_nt2 {
        ADAPT_RISE_S
    } else {
        ADAPT_DECAY_S
    };
    let a = (1.0 / (tau_s * rate_hz)).min(1.0);
    adapted_nt2 + a * (observed_nt2 - adapted_nt2)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A cold start's negative observations leave the variance at 0, so model error that
    /// appears afterwards is followed at once (within 3 rise times), not after the
    /// negative level has decayed (the 600 s decay).
    #[test]
    fn adapted_variance_never_goes_negative_and_rises_at_once() {
        let rate_hz = 10.0;
        let mut r = 0.0;
        for _ in 0..1000 {
            r = follow_variance(r, -500.0, rate_hz);
            assert!(r >= 0.0, "{r}");
        }
        for _ in 0..(3.0 * ADAPT_RISE_S * rate_hz) as usize {
            r = follow_variance(r, 1.0, rate_hz);
        }
        assert!(r > 0.9, "after 3 rise times {r} nT² of 1");
        for _ in 0..100_000 {
            r = follow_variance(r, 50.0, rate_hz);
        }
        assert!(r <= ADAPT_MAX_NT2, "{r}");
    }
}
