//! The compensator's tunables, in one record (as PX4's EKF2 keeps its parameters): noise,
//! field process, priors, gates, tie points, self-checks.

use super::{TiePoint, MAX_TIE_POINTS};
use crate::epoch::EpochConfig;

/// Filter settings. `for_rate` gives the defaults for a sample rate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CompensatorConfig {
    pub epoch: EpochConfig,
    /// Scalar measurement noise 1σ (nT): sensor noise plus what the model cannot follow.
    pub noise_nt: f32,
    /// The scalar's own noise 1σ (nT; 0 = `noise_nt`). Where `noise_nt` was widened to
    /// cover what the model cannot follow (a real aircraft's unmodelled interference, as
    /// post-flight tuning finds it), the innovations' excess over this is that model error:
    /// it stays in the compensated output, so it is in the record's bound and sets the
    /// tolerance `NOT_CONVERGED` is judged against.
    pub sensor_noise_nt: f32,
    /// Field-model driving noise (nT/m^2.5); σ2 ≈ σ1/10 (model.md §3 findings).
    pub sigma1: f32,
    pub sigma2: f32,
    /// Length over which the field priors are set (m).
    pub field_length_m: f32,
    /// Prior 1σ of the field at the first sample relative to the reference (nT).
    pub bh_prior_nt: f32,
    /// Multiplier on every term's prior 1σ.
    pub prior_scale: f32,
    /// Innovation gate in σ (0 = off). After `gate_max_run` consecutive rejections the
    /// next sample is accepted anyway, so a real change cannot lock the filter out.
    pub gate_sigma: f32,
    /// While the gate is not armed (the first 100 updates) an innovation beyond
    /// `gate_sigma` is not taken at face value but Huber-weighted: it updates the filter as if its variance were `ν²/k²`
    /// (k = `gate_sigma`), so its pull is that of a k-σ innovation whatever its size. An
    /// unweighted +4000 nT glitch in the first seconds used to ruin a whole calibration
    /// (245 000 nT of interference at the end). Tried as a weighting at 1.5–3σ on every
    /// sample, it made the real SGL boxes 1.1–2.5× worse: their model error is largest at
    /// the manoeuvre peaks, which carry the information; on the sample forced in after
    /// `gate_max_run` rejections it kept a filter that was wrong from re-syncing (a clean
    /// survey then showed a false `rate` at its crossovers).
    pub gate_max_run: u32,
    /// A scalar innovation beyond this many σ of its prediction flags the record
    /// `MAG_SUSPECT` (0 = never), in every phase: warm-up, gated, forced in. Below
    /// `gate_sigma`, so a value the gate still fuses (a corrupted tenths digit, 0.1–0.9 nT)
    /// is not shown as good.
    pub suspect_sigma: f32,
    /// Real time: the scalar's variance `r` is raised to what the last
    /// `consistency_window_epochs` of innovations show (`E[ν²] − E[H·P·Hᵀ]`) when that is
    /// larger. A real installation's model error (0.2–2 nT) is 10–100× the sensor's 0.02
    /// nT: with `r` at the sensor's, the board refused 45–82 % of the real SGL boxes'
    /// samples at its gate, took one in six at face value, and flew box 2 at 21 / 48 nT
    /// band rms (mag_5 / mag_3, raw 11 / 144) flagged converged. On for the board and
    /// `replay` ([`crate::acquisition::compensator_config`]); the host tunes `noise_nt` on
    /// the whole flight instead, `--realtime` included (off there).
    pub adaptive_noise: bool,
    /// Tie points and the radius within which a pass counts as a revisit (m).
    pub tie_points: [Option<TiePoint>; MAX_TIE_POINTS],
    pub tie_radius_m: f32,
    /// Lower bound of the horizontal gradient assumed in the tie variance (nT/m).
    pub tie_gradient_floor_nt_per_m: f32,
    /// External-field drift assumed between two passes when no base station is recorded
    /// (nT/s; 10 nT/h, a quiet day). With a base station the tie uses its difference.
    pub tie_drift_nt_per_s: f32,
    /// A tie whose innovation exceeds this many σ of its predicted spread is refused and
    /// flagged (`TIE_REJECTED`; 0 = never): a wrong tie pins the field to a false value
    /// and pushes the difference into the coefficients. The tie's variance assumes the
    /// gradient across the track is like the one along it; over strong shallow sources it
    /// is not, and 3–6σ ties made the 400 m flights' error 0.042 / 0.082 nT instead of
    /// 0.022 / 0.042 (3σ: 0.022 / 0.042; 8σ only caught grossly wrong ties, such as a
    /// `base` channel whose diurnal variation was already removed from the scalar:
    /// 0.007 → 0.33 nT).
    pub tie_gate_sigma: f32,
    /// Re-anchor the reference height `h0` to the flown height whenever `|h − h0|`
    /// exceeds this (m; 0 = never). `B_h` is then re-expressed exactly as the field at the
    /// new `h0` (`B_h ← B_h + B_z·Δh0`), so `B_z·(h − h0)` stays a local linearisation:
    /// with a fixed `h0` and altitude changes of ±100 m over strong anomalies the secant
    /// slope the filter learns differs from the local gradient that pitch manoeuvres see.
    pub h0_reanchor_m: f32,
    /// Calibrate mode: `NOT_CONVERGED` is set while the predicted 1σ of the interference
    /// *variation* exceeds this (nT; 0 = never set): `sqrt(dᵀ P d)` with `d` the
    /// interference regressors minus their running mean over `converged_window_epochs`.
    /// The constant part of the interference is inseparable from the anomaly level (it
    /// stays ~2 nT uncertain for ever) and is removed by levelling anyway; what a survey
    /// needs at 0.1 nT is the part that moves with attitude.
    pub converged_sigma_nt: f32,
    /// The 1σ above is evaluated every this many epochs (≥ 1); the flag holds in between.
    pub converged_every: u32,
    /// Length of the running mean the variation is taken about (epochs; ~60 s).
    pub converged_window_epochs: u32,
    /// Window of the innovation statistics (epochs; ~30 s): the model error they show and
    /// the filter's consistency (NIS), which widens its account of its own uncertainty.
    pub consistency_window_epochs: u32,
    /// Reset to the last good coefficients when the interference runs away from the raw
    /// signal or beyond what the priors allow (`FILTER_RESET`).
    pub divergence_reset: bool,
    /// Below this reported ground speed (m/s; 0 = never) the aircraft is on the ground
    /// (parked, engine start, taxi): samples predict but do not update the filter. There
    /// the field is dominated by steel metres away (hangars, vehicles: tens to hundreds of
    /// nT over tens of metres, far beyond the anomaly process) and by engine-start
    /// transients; a simulated take-off calibrated on them left 9.6 nT of error. 15 m/s is
    /// above a fast taxi and below any survey speed (helicopters survey at 25–50 m/s).
    /// A sample without a reported speed updates. Off by default (0): post-flight
    /// calibration sets [`GROUND_SPEED_MPS`](super::GROUND_SPEED_MPS); in real time a take-off learnt only in the air
    /// converged on the climb turns with errors 3.5× its stated bound, where learning the
    /// apron too keeps it (honestly) `NOT_CONVERGED` — the board turns this on once the
    /// bound is honest.
    pub min_update_speed_mps: f32,
}

impl CompensatorConfig {
    pub fn for_rate(sample_rate_hz: f32) -> Self {
        Self {
            epoch: EpochConfig::for_rate(sample_rate_hz),
            noise_nt: 0.02,
            sensor_noise_nt: 0.0,
            sigma1: 1.0e-6,
            sigma2: 1.0e-7,
            field_length_m: 1000.0,
            bh_prior_nt: 100.0,
            prior_scale: 1.0,
            gate_sigma: 8.0,
            gate_max_run: 5,
            suspect_sigma: 5.0,
            adaptive_noise: false,
            tie_points: [None; MAX_TIE_POINTS],
            tie_radius_m: 60.0,
            tie_gradient_floor_nt_per_m: 0.001,
            tie_drift_nt_per_s: 10.0 / 3600.0,
            tie_gate_sigma: 3.0,
            h0_reanchor_m: 0.0,
            converged_sigma_nt: 0.1,
            converged_every: 8,
            converged_window_epochs: (60.0 * sample_rate_hz.max(1.0)) as u32,
            consistency_window_epochs: (30.0 * sample_rate_hz.max(1.0)) as u32,
            divergence_reset: true,
            min_update_speed_mps: 0.0,
        }
    }
}
