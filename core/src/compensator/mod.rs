//! The compensator: epoch builder + model terms + UD filter, one output per scalar sample.
//!
//! State layout (dynamic states first so the time update touches only the leading block):
//! `[offset (models without field) | tie-point clones | field (5) | term coefficients…]`.
//! All states are scaled by their prior 1σ (model.md §5, the paper's normalisation).

use crate::continuity::ScalarContinuity;
use crate::epoch::{AlignedSample, Epoch, EpochBuilder, EpochConfig};
use crate::filter::field::{FieldProcess, FIELD_STATES};
use crate::filter::ud::{UdFilter, MAX_DYNAMIC, MAX_NOISE};
use crate::flags::Flags;
use crate::model::{Model, TermKind, MAX_TERM_STATES};
use crate::units::MagCounts;

mod config;
pub mod health;
mod jitter;
mod loops;
mod scalar;
mod ties;
pub mod witness;
pub use config::CompensatorConfig;
use health::{CoefficientHistory, Divergence, HeadingCoverage, InnovationMonitor};
use loops::{change_regressor, change_regressor_all, dot, dot3, masked_dot, masked_dot3};
pub use scalar::ScalarFusion;
use ties::{TieState, TIE_STATE_INIT};

/// Ground speed below which an aircraft is on the ground (m/s): above a fast taxi, below
/// any survey speed. See [`CompensatorConfig::min_update_speed_mps`].
pub const GROUND_SPEED_MPS: f32 = 15.0;

/// The survey envelope is evaluated at every this many `NOT_CONVERGED` evaluations
/// (every 32 epochs with `converged_every` = 8: 3.2 s at 10 Hz).
const ENVELOPE_EVERY: u32 = 4;

/// Which coefficients an interference is computed with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Coefficients {
    /// The terms' prior means (zero, or the loaded coefficients').
    Prior,
    /// The filter's present estimate.
    Current,
    /// The estimate at the last evaluation that found the filter converged.
    LastGood,
}

/// Largest number of tie points (revisited locations such as the cloverleaf centre).
pub const MAX_TIE_POINTS: usize = 2;

/// A revisited location: the first pass stores the field there, later passes tie to it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TiePoint {
    pub lat_deg: f64,
    pub lon_deg: f64,
}

/// One output record per scalar sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Output {
    pub t_s: f64,
    pub mag: Option<MagCounts>,
    /// Estimated aircraft interference (nT).
    pub interference_nt: f32,
    /// `mag − interference`, exact to 1e-4 nT.
    pub compensated: Option<MagCounts>,
    /// Field-state estimate `B_h + B_z·(h − h0)` (nT) relative to the first reference (the
    /// flight's first scalar reading less the core-field change), whatever the epoch
    /// builder re-referenced since: on the real boxes the raw scalar drifts thousands of nT
    /// and each re-reference stepped this 2 000 nT.
    pub anomaly_nt: f32,
    /// Innovation and its predicted variance (NaN when no update was made).
    pub innovation_nt: f32,
    pub innovation_var_nt2: f32,
    /// The record's stated 1σ bound on the interference (nT): how well the coefficients
    /// determine it (its variation about the last minute's mean; the level is the
    /// anomaly's), widened by the innovations' excess over their prediction, plus the model
    /// error they show. NaN while `NOT_CONVERGED` (the output is then the prior's).
    pub interference_sigma_nt: f32,
    pub flags: Flags,
}

/// Errors of configuration or coefficient loading.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CompensatorError {
    /// The model needs more states than the compile-time capacity `N`.
    TooManyStates { needed: usize, capacity: usize },
    /// The derivative window does not fit the ring capacity `W`.
    WindowTooLarge,
    /// A prior or setting is not finite/positive.
    BadConfig,
    /// Coefficient slice of the wrong length or with non-finite values.
    BadCoefficients,
}

/// The real-time compensator. `N`: state capacity; `W`: derivative ring capacity.
pub struct Compensator<'a, const N: usize, const W: usize> {
    model: Model<'a>,
    cfg: CompensatorConfig,
    builder: EpochBuilder<W>,
    filter: UdFilter<N>,
    field: Option<FieldProcess>,
    /// Φ and G of the field's time update: `discretise` fills them once (at reset), each
    /// epoch rewrites only the entries that depend on the step (`discretise_step`).
    phi: [[f32; MAX_DYNAMIC]; MAX_DYNAMIC],
    g: [[f32; MAX_DYNAMIC]; MAX_NOISE],
    scale: [f32; N],
    /// Per state: a coefficient of an interference term, and its prior mean (physical; 0
    /// for other states). Formed at reset so the per-epoch sums make no `dyn` calls.
    interference: [bool; N],
    /// Every term is an interference term (no mask needed).
    all_interference: bool,
    prior_phys: [f32; N],
    /// Sine and cosine of each envelope point's rotation (health.rs), formed once.
    envelope_rotations: health::EnvelopeRotations,
    n_offset: usize,
    n_clone: usize,
    field_at: usize,
    terms_at: usize,
    n_dyn: usize,
    n: usize,
    survey: bool,
    last_reference: Option<MagCounts>,
    /// The first reference: the anomaly is output relative to it, so that the epoch
    /// builder's re-referencing (every 2 000 nT of drift) does not step the output.
    first_reference: Option<MagCounts>,
    reject_run: u32,
    /// The scalar against its own recent past, where the filter cannot judge it.
    continuity: ScalarContinuity,
    /// What the last scalar fusion did.
    scalar: ScalarFusion,
    ties: [TieState; MAX_TIE_POINTS],
    updates: u32,
    /// The model has a term for the external (diurnal) field.
    models_diurnal: bool,
    /// Sum of all `h0` re-anchoring shifts (m).
    h0_shift_m: f32,
    /// Multiplier on the measurement noise σ for the next epochs (1 = as configured).
    noise_scale: f32,
    field_noise_scale: f32,
    /// `NOT_CONVERGED` as last evaluated, and epochs until the next evaluation.
    not_converged: bool,
    converged_countdown: u32,
    /// Predicted 1σ of the interference estimate at the last evaluation (nT; NaN before).
    interference_sigma_nt: f32,
    /// Running mean of the physical interference regressors (for `NOT_CONVERGED`).
    regressor_mean: [f32; N],
    regressor_mean_count: u32,
    /// Innovation statistics over `consistency_window_epochs`.
    innovations: InnovationMonitor,
    /// Real time: the scalar variance the innovations have shown, held with a long
    /// memory (nT²; 0 before any): rises within seconds, decays over minutes.
    adapted_r: f32,
    /// The variance factor the covariance is expressed in (1 at the configured noise; see
    /// `follow_variance_factor` in scalar.rs).
    variance_factor: f32,
    /// The output interference's sample-to-sample jitter (part of the record's bound).
    jitter: jitter::InterferenceJitter,
    /// The survey envelope's variance at its last evaluation (nT²), and evaluations until
    /// the next one.
    envelope_var: f32,
    envelope_countdown: u32,
    /// The interference variation's 1σ at the last `NOT_CONVERGED` evaluation, widened by
    /// the innovations' excess (nT): the record's bound is built from it.
    coefficient_sigma_nt: f32,
    /// The same from the filter's covariance alone (no movement): what a survey-mode
    /// record carries after the coefficients were frozen in flight.
    model_sigma_nt: f32,
    divergence: Divergence,
    /// Term coefficients (scaled states) at the last evaluation that found the filter
    /// converged and consistent: where a divergence resets to.
    last_good: [f32; N],
    has_last_good: bool,
    /// The coefficients over the last window, and how far the interference they give
    /// moved over it (nT², at the last envelope evaluation).
    history: CoefficientHistory<N>,
    movement_var: f32,
    /// The same two for the change between headings and for the level at the present
    /// attitude (nT², at the last envelope evaluation): what `LEVEL_UNDETERMINED` reports.
    heading_var: f32,
    level_movement_var: f32,
    /// `LEVEL_UNDETERMINED` as last evaluated (held in survey mode after an in-flight
    /// calibration: the frozen coefficients keep what was not determined).
    level_undetermined: bool,
    /// Headings manoeuvred on (`NOT_CONVERGED` until all four sectors are).
    coverage: HeadingCoverage,
}

impl<'a, const N: usize, const W: usize> Compensator<'a, N, W> {
    /// Builds a compensator (host use: returned by value, so it passes through the stack;
    /// a board keeps one in a `static` with [`placeholder`](Self::placeholder) and
    /// [`reset_in_place`](Self::reset_in_place) instead).
    pub fn new(model: Model<'a>, cfg: CompensatorConfig) -> Result<Self, CompensatorError> {
        let mut c = Self::placeholder(model);
        c.reset_in_place(model, cfg)?;
        Ok(c)
    }

    /// A compensator with no states, usable in a `static` initialiser (`const`): call
    /// [`reset_in_place`](Self::reset_in_place) before use (until then `push` only
    /// delays samples and outputs zero interference).
    pub const fn placeholder(model: Model<'a>) -> Self {
        Self {
            model,
            cfg: CompensatorConfig {
                epoch: EpochConfig {
                    half_width: 1,
                    earth_dir_ned: None,
                    h0_m: None,
                },
                noise_nt: 1.0,
                sensor_noise_nt: 0.0,
                sigma1: 1.0,
                sigma2: 1.0,
                field_length_m: 1.0,
                bh_prior_nt: 1.0,
                prior_scale: 1.0,
                gate_sigma: 0.0,
                gate_max_run: 0,
                suspect_sigma: 0.0,
                adaptive_noise: false,
                tie_points: [None; MAX_TIE_POINTS],
                tie_radius_m: 0.0,
                tie_gradient_floor_nt_per_m: 0.0,
                tie_drift_nt_per_s: 0.0,
                tie_gate_sigma: 0.0,
                h0_reanchor_m: 0.0,
                converged_sigma_nt: 0.0,
                converged_every: 1,
                converged_window_epochs: 1,
                consistency_window_epochs: 1,
                divergence_reset: false,
                min_update_speed_mps: 0.0,
            },
            builder: EpochBuilder::empty(),
            filter: UdFilter::empty(),
            field: None,
            phi: [[0.0; MAX_DYNAMIC]; MAX_DYNAMIC],
            g: [[0.0; MAX_DYNAMIC]; MAX_NOISE],
            scale: [1.0; N],
            interference: [false; N],
            all_interference: true,
            prior_phys: [0.0; N],
            envelope_rotations: health::EnvelopeRotations::ZERO,
            n_offset: 0,
            n_clone: 0,
            field_at: 0,
            terms_at: 0,
            n_dyn: 0,
            n: 0,
            survey: false,
            last_reference: None,
            first_reference: None,
            reject_run: 0,
            continuity: ScalarContinuity::new(),
            scalar: ScalarFusion::NONE,
            ties: [TIE_STATE_INIT; MAX_TIE_POINTS],
            updates: 0,
            models_diurnal: false,
            h0_shift_m: 0.0,
            noise_scale: 1.0,
            field_noise_scale: 1.0,
            not_converged: false,
            converged_countdown: 0,
            interference_sigma_nt: f32::NAN,
            regressor_mean: [0.0; N],
            regressor_mean_count: 0,
            innovations: InnovationMonitor::new(),
            adapted_r: 0.0,
            variance_factor: 1.0,
            jitter: jitter::InterferenceJitter::new(),
            envelope_var: f32::INFINITY,
            envelope_countdown: 0,
            coefficient_sigma_nt: f32::NAN,
            model_sigma_nt: f32::NAN,
            divergence: Divergence::new(),
            last_good: [0.0; N],
            has_last_good: false,
            history: CoefficientHistory::new(),
            movement_var: f32::INFINITY,
            heading_var: f32::INFINITY,
            level_movement_var: f32::INFINITY,
            level_undetermined: false,
            coverage: HeadingCoverage::new(),
        }
    }

    /// (Re)initialises in place for `model` and `cfg`: afterwards the compensator is
    /// exactly what [`new`](Self::new) returns, without a second ~N² filter on the stack.
    /// On error it is left unchanged.
    pub fn reset_in_place(
        &mut self,
        model: Model<'a>,
        cfg: CompensatorConfig,
    ) -> Result<(), CompensatorError> {
        if !(cfg.noise_nt > 0.0 && cfg.prior_scale > 0.0 && cfg.sigma1 > 0.0 && cfg.sigma2 > 0.0) {
            return Err(CompensatorError::BadConfig);
        }
        if cfg.epoch.half_width == 0 || 2 * cfg.epoch.half_width + 1 > W {
            return Err(CompensatorError::WindowTooLarge);
        }
        let n_offset = usize::from(!model.field);
        let n_clone = if model.field {
            cfg.tie_points.iter().filter(|t| t.is_some()).count()
        } else {
            0
        };
        let field_at = n_offset + n_clone;
        let terms_at = field_at + if model.field { FIELD_STATES } else { 0 };
        let n = terms_at + model.coefficient_count();
        if n > N {
            return Err(CompensatorError::TooManyStates {
                needed: n,
                capacity: N,
            });
        }
        if terms_at > MAX_DYNAMIC || model.terms.iter().any(|t| t.len() > MAX_TERM_STATES) {
            return Err(CompensatorError::TooManyStates {
                needed: n,
                capacity: N,
            });
        }
        let field = model.field.then(|| {
            FieldProcess::new(cfg.sigma1, cfg.sigma2, cfg.field_length_m, cfg.bh_prior_nt)
        });
        let mut scale = [1.0f32; N];
        if n_offset == 1 {
            scale[0] = 1000.0;
        }
        if let Some(f) = &field {
            for c in 0..n_clone {
                scale[n_offset + c] = f.scale[0];
            }
            scale[field_at..field_at + FIELD_STATES].copy_from_slice(&f.scale);
        }
        let mut at = terms_at;
        for t in model.terms {
            for i in 0..t.len() {
                scale[at + i] = t.prior_sigma(i) * cfg.prior_scale;
            }
            at += t.len();
        }
        if scale[..n].iter().any(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(CompensatorError::BadConfig);
        }
        let mut x0 = [0.0f32; N];
        let mut at = terms_at;
        for t in model.terms {
            for i in 0..t.len() {
                x0[at + i] = t.prior_mean(i) / scale[at + i];
            }
            at += t.len();
        }
        if x0[..n].iter().any(|v| !v.is_finite()) {
            return Err(CompensatorError::BadConfig);
        }
        // everything checked: nothing below can fail
        let ok = self.filter.reset(n, &x0, &[1.0; N]) && self.builder.reset(cfg.epoch);
        debug_assert!(ok);
        self.model = model;
        self.cfg = cfg;
        self.field = field;
        if let Some(f) = &field {
            let mut dq = [0.0f32; MAX_NOISE];
            f.discretise(1.0, field_at, &mut self.phi, &mut self.g, &mut dq);
        }
        self.scale = scale;
        self.interference = [false; N];
        self.prior_phys = [0.0; N];
        let mut at = terms_at;
        for t in model.terms {
            let is_interference = t.is_interference();
            for i in 0..t.len() {
                self.interference[at + i] = is_interference;
                self.prior_phys[at + i] = t.prior_mean(i);
            }
            at += t.len();
        }
        self.all_interference = model.terms.iter().all(|t| t.is_interference());
        self.envelope_rotations = health::EnvelopeRotations::new();
        self.n_offset = n_offset;
        self.n_clone = n_clone;
        self.field_at = field_at;
        self.terms_at = terms_at;
        self.n_dyn = terms_at;
        self.n = n;
        self.survey = false;
        self.last_reference = None;
        self.first_reference = None;
        self.reject_run = 0;
        self.continuity = ScalarContinuity::new();
        self.scalar = ScalarFusion::NONE;
        self.ties = [TIE_STATE_INIT; MAX_TIE_POINTS];
        self.updates = 0;
        self.models_diurnal = model
            .terms
            .iter()
            .any(|t| !t.is_interference() && t.kind() == Some(TermKind::Diurnal));
        self.h0_shift_m = 0.0;
        self.noise_scale = 1.0;
        self.field_noise_scale = 1.0;
        self.not_converged = false;
        self.converged_countdown = 0;
        self.interference_sigma_nt = f32::NAN;
        self.regressor_mean = [0.0; N];
        self.regressor_mean_count = 0;
        self.innovations = InnovationMonitor::new();
        self.adapted_r = 0.0;
        self.variance_factor = 1.0;
        self.jitter = jitter::InterferenceJitter::new();
        self.envelope_var = f32::INFINITY;
        self.envelope_countdown = 0;
        self.coefficient_sigma_nt = f32::NAN;
        self.model_sigma_nt = f32::NAN;
        self.divergence = Divergence::new();
        self.last_good = [0.0; N];
        self.has_last_good = false;
        self.history = CoefficientHistory::new();
        self.movement_var = f32::INFINITY;
        self.heading_var = f32::INFINITY;
        self.level_movement_var = f32::INFINITY;
        self.level_undetermined = false;
        self.coverage = HeadingCoverage::new();
        Ok(())
    }

    /// The interference for physical regressors `phys` with the coefficients of `source`.
    fn interference_from(&self, phys: &[f32; N], source: Coefficients) -> f32 {
        let x = match source {
            Coefficients::LastGood => &self.last_good[..],
            _ => self.filter.state(),
        };
        // the terms' coefficients in model order, so the same sum in the same order
        let r = self.terms_at..self.n;
        let (mask, ps) = (&self.interference[r.clone()], &phys[r.clone()]);
        match (source, self.all_interference) {
            (Coefficients::Prior, true) => dot(&self.prior_phys[r], ps),
            (Coefficients::Prior, false) => masked_dot(mask, &self.prior_phys[r], ps),
            (_, true) => dot3(&x[r.clone()], &self.scale[r], ps),
            (_, false) => masked_dot3(mask, &x[r.clone()], &self.scale[r], ps),
        }
    }

    /// Predicted variance (nT²) of the interference difference between regressors `phys`
    /// and `other` (interference terms only). `lead`: 0, or `terms_at` when
    /// `filter.leading_rows_finite(terms_at)` (the envelope checks it once for its 12
    /// points): the difference is zero on the states before the terms, which then drop out
    /// exactly.
    fn interference_change_variance(
        &mut self,
        phys: &[f32; N],
        other: &[f32; N],
        lead: usize,
    ) -> f32 {
        let r = lead..self.n;
        let (mask, scale) = (&self.interference[r.clone()], &self.scale[r.clone()]);
        let (p, o) = (&phys[r.clone()], &other[r]);
        if lead == self.terms_at && self.all_interference {
            self.filter
                .predicted_variance_tail(lead, 0.0, |d| change_regressor_all(p, o, scale, d))
        } else {
            self.filter
                .predicted_variance_tail(lead, 0.0, |d| change_regressor(mask, p, o, scale, d))
        }
    }

    /// How much the interference at physical regressors `phys` differs between the present
    /// coefficients and `old` (scaled states, as `filter.state()`), nT: at one attitude,
    /// a change of the compensated output over time that no levelling removes.
    fn interference_moved(&self, phys: &[f32; N], old: &[f32; N]) -> f32 {
        let x = self.filter.state();
        let mut moved = 0.0f32;
        for i in self.terms_at..self.n {
            if self.interference[i] {
                moved += phys[i] * self.scale[i] * (x[i] - old[i]);
            }
        }
        moved
    }

    /// What the innovations show beyond the configured (sensor) noise (nT rms) over the
    /// last `consistency_window_epochs`: signal the model does not describe, which stays
    /// in the compensated output.
    pub fn model_error_nt(&self) -> f32 {
        let sensor_nt = self.sensor_floor_nt();
        let r_sensor = sensor_nt * sensor_nt;
        let excess = self.innovations.observed_r() - r_sensor;
        if excess > 0.0 {
            libm::sqrtf(excess)
        } else {
            0.0
        }
    }

    /// The scalar's own noise (nT) that model errors are counted beyond: the configured
    /// sensor noise, or `noise_nt` where none is configured (`sensor_noise_nt` 0), never
    /// above `noise_nt`.
    fn sensor_floor_nt(&self) -> f32 {
        if self.cfg.sensor_noise_nt > 0.0 {
            self.cfg.sensor_noise_nt.min(self.cfg.noise_nt)
        } else {
            self.cfg.noise_nt
        }
    }

    /// The record's stated 1σ bound on its interference (see [`Output`]).
    fn interference_bound_nt(&self) -> f32 {
        if self.survey {
            let r = self.cfg.noise_nt * self.cfg.noise_nt;
            // Frozen after calibrating in flight: what the filter last knew of its
            // coefficients stays in the bound (loaded ones carry theirs in their file).
            // Not the movement: at the pattern's end that is the last heading's
            // improvement (0.6 nT where the frozen coefficients were 0.025 nT off).
            let c = if self.model_sigma_nt.is_finite() {
                self.model_sigma_nt
            } else {
                0.0
            };
            return libm::sqrtf(
                self.innovations.observed_r().max(r) + c * c + self.jitter.variance_nt2(),
            );
        }
        if self.not_converged {
            return f32::NAN;
        }
        let m = self.model_error_nt();
        let c = self.coefficient_sigma_nt;
        libm::sqrtf(c * c + m * m + self.jitter.variance_nt2())
    }

    /// Feeds the divergence check with this epoch's raw signal and the interference the
    /// current coefficients give; true when a filter that had converged once has run away:
    /// its interference swings far beyond the raw signal, or departs from what the last
    /// good coefficients give at this attitude by more than `PRIOR_SIGMAS` × what the
    /// priors allow there (no aircraft's field changes that much between two estimates).
    fn diverged(&mut self, ep: &Epoch, phys: &[f32; N]) -> bool {
        /// The real survey line's diverged real-time interference reached −883 nT
        /// (board path −28,391 nT) where the priors allow ~250 nT at 1σ. Measured from the
        /// last good coefficients, not from zero: a real aircraft can exceed its prior
        /// (the SGL cabin `mag_3` carries ~2,000 nT that changes with attitude), and then
        /// a test against zero reset a good estimate at every sample.
        const PRIOR_SIGMAS: f32 = 6.0;
        if !self.cfg.divergence_reset || !self.has_last_good {
            return false;
        }
        let estimate = self.interference_from(phys, Coefficients::Current);
        let departure = estimate - self.interference_from(phys, Coefficients::LastGood);
        let mut prior_var = 0.0f32;
        for i in self.terms_at..self.n {
            if self.interference[i] {
                let m = libm::fabsf(self.prior_phys[i]) + self.scale[i];
                prior_var += (m * phys[i]) * (m * phys[i]);
            }
        }
        let window = self.cfg.converged_window_epochs;
        let runaway = self.divergence.push(ep.dmag_nt, estimate, window);
        runaway || libm::fabsf(departure) > PRIOR_SIGMAS * libm::sqrtf(prior_var)
    }

    /// Divergence: back to the coefficients of the last converged, consistent evaluation,
    /// with the prior's uncertainty; the field states and tie points start again. The next
    /// records are `NOT_CONVERGED` until it has re-learnt.
    fn reset_to_last_good(&mut self) {
        let mut x0 = [0.0f32; N];
        x0[self.terms_at..self.n].copy_from_slice(&self.last_good[self.terms_at..self.n]);
        let ok = self.filter.reset(self.n, &x0, &[1.0; N]);
        debug_assert!(ok);
        // the prior is the configured one; the next fusion expresses it in the factor
        self.variance_factor = 1.0;
        self.ties = [TIE_STATE_INIT; MAX_TIE_POINTS];
        self.regressor_mean_count = 0;
        self.not_converged = true;
        self.converged_countdown = 0;
        self.envelope_countdown = 0;
        self.divergence = Divergence::new();
        self.history = CoefficientHistory::new();
        self.movement_var = f32::INFINITY;
        self.heading_var = f32::INFINITY;
        self.level_movement_var = f32::INFINITY;
        self.updates = 0;
        self.reject_run = 0;
    }

    /// Predicted 1σ of the interference estimate (nT) at the last `NOT_CONVERGED`
    /// evaluation (calibrate mode, every `cfg.converged_every` epochs; NaN before the first).
    pub fn interference_sigma_nt(&self) -> f32 {
        self.interference_sigma_nt
    }

    /// What the last scalar fusion did (innovation, test ratio, fused or refused).
    pub fn scalar_fusion(&self) -> ScalarFusion {
        self.scalar
    }

    pub fn model(&self) -> &Model<'a> {
        &self.model
    }
    pub fn config(&self) -> &CompensatorConfig {
        &self.cfg
    }
    /// Total number of filter states.
    pub fn state_count(&self) -> usize {
        self.n
    }
    /// Index of the first term coefficient in the state vector.
    pub fn coefficient_offset(&self) -> usize {
        self.terms_at
    }
    pub fn filter(&self) -> &UdFilter<N> {
        &self.filter
    }
    pub fn is_survey_mode(&self) -> bool {
        self.survey
    }

    /// Survey mode: coefficients are frozen (applied, not estimated); the field states keep
    /// running. Switching decouples the coefficients from the field states.
    pub fn set_survey_mode(&mut self, on: bool) {
        if on && !self.survey {
            self.filter.decouple(self.n_dyn);
        }
        self.survey = on;
    }

    /// Multiplies the measurement noise σ of the epochs processed from now on (e.g. to
    /// down-weight stretches the user knows the model follows poorly). Non-finite or
    /// non-positive values reset it to 1.
    pub fn set_noise_scale(&mut self, k: f32) {
        self.noise_scale = if k.is_finite() && k > 0.0 { k } else { 1.0 };
    }

    /// Multiplies the field's process-noise variance (σ1², σ2²) from now on: an anomaly is
    /// rougher over a near source than the flight's average σ1 says (1 = stationary).
    pub fn set_field_noise_scale(&mut self, k: f32) {
        self.field_noise_scale = if k.is_finite() && k > 0.0 { k } else { 1.0 };
    }

    /// Term coefficients in physical units (nT, nT·s, …), model order.
    pub fn coefficients(&self, out: &mut [f32]) -> usize {
        let k = self.n - self.terms_at;
        let x = self.filter.state();
        for (i, o) in out.iter_mut().enumerate().take(k) {
            *o = x[self.terms_at + i] * self.scale[self.terms_at + i];
        }
        k.min(out.len())
    }

    /// 1σ of each term coefficient from the filter covariance, physical units.
    pub fn coefficient_sigmas(&self, out: &mut [f32]) -> usize {
        let k = self.n - self.terms_at;
        for (i, o) in out.iter_mut().enumerate().take(k) {
            let j = self.terms_at + i;
            *o = libm::sqrtf(self.filter.variance(j).max(0.0)) * self.scale[j];
        }
        k.min(out.len())
    }

    /// Covariance of term coefficients `i` and `j` (model order) from the filter, physical
    /// units: with the regressors it gives how well the flight so far has determined the
    /// interference, `σ² = dᵀ·P·d`.
    pub fn coefficient_covariance(&self, i: usize, j: usize) -> f32 {
        let (a, b) = (self.terms_at + i, self.terms_at + j);
        if a >= self.n || b >= self.n {
            return f32::NAN;
        }
        self.filter.covariance(a, b) * self.scale[a] * self.scale[b]
    }

    /// Holds a combination of the term coefficients at its current value (the prior, before
    /// any sample): `Σ w_i·θ_i/σ_i` (σ_i the prior 1σ, so `w` is in prior units) is
    /// measured as unchanged with a variance of 1e-6 of the prior. For combinations a flight
    /// cannot determine (no attitude excitation): left free, the filter would trade the
    /// Earth's field or geology into them. Returns false if `w` has the wrong length or
    /// is not finite.
    pub fn hold_coefficient_combination(&mut self, w: &[f32]) -> bool {
        let k = self.n - self.terms_at;
        if w.len() != k || w.iter().any(|v| !v.is_finite()) {
            return false;
        }
        let mut h = [0.0f32; N];
        h[self.terms_at..self.n].copy_from_slice(w);
        let z = self.filter.predict(&h);
        let norm2: f32 = w.iter().map(|v| v * v).sum();
        matches!(
            self.filter
                .update_gated(&h, z, 1e-6 * norm2.max(1e-12), |_, _| false),
            Some(Ok(_))
        )
    }

    /// Loads known coefficients (physical units) and switches to survey mode.
    pub fn set_coefficients(&mut self, coeffs: &[f32]) -> Result<(), CompensatorError> {
        let k = self.n - self.terms_at;
        if coeffs.len() != k || coeffs.iter().any(|c| !c.is_finite()) {
            return Err(CompensatorError::BadCoefficients);
        }
        self.set_survey_mode(true);
        // Loaded coefficients: the in-flight calibration's own account no longer applies.
        self.coefficient_sigma_nt = f32::NAN;
        self.model_sigma_nt = f32::NAN;
        self.level_undetermined = false;
        let at = self.terms_at;
        let x = self.filter.state_mut();
        for (i, c) in coeffs.iter().enumerate() {
            x[at + i] = c / self.scale[at + i];
        }
        Ok(())
    }

    /// Field states (physical units): B_h (nT, relative to the reference), ∂B_h/∂s (nT/m),
    /// ∂²B_h/∂s² (nT/m²), B_z (nT/m), ∂B_z/∂s (nT/m²).
    pub fn field_state(&self) -> Option<[f32; FIELD_STATES]> {
        self.field?;
        let x = self.filter.state();
        let mut f = [0.0; FIELD_STATES];
        for (i, v) in f.iter_mut().enumerate() {
            *v = x[self.field_at + i] * self.scale[self.field_at + i];
        }
        Some(f)
    }

    /// Pushes one aligned scalar sample; returns the output of the sample
    /// `half_width` samples back (exactly one output per pushed sample overall, with
    /// [`flush`](Self::flush) at the end of the stream).
    pub fn push(&mut self, s: &AlignedSample) -> Option<Output> {
        // by reference: moving the epoch out of the `Option` copied its 216 bytes
        let ep = self.builder.push(s);
        ep.as_ref().map(|ep| self.process(ep))
    }

    /// Emits the samples still held for the centred derivative (end of stream).
    pub fn flush(&mut self) -> Option<Output> {
        let ep = self.builder.flush()?;
        Some(self.process(&ep))
    }

    /// Like `push`, but also hands the epoch to the caller (host diagnostics).
    pub fn push_epoch(&mut self, s: &AlignedSample) -> Option<(Epoch, Output)> {
        let ep = self.builder.push(s)?;
        let out = self.process(&ep);
        Some((ep, out))
    }

    pub fn flush_epoch(&mut self) -> Option<(Epoch, Output)> {
        let ep = self.builder.flush()?;
        let out = self.process(&ep);
        Some((ep, out))
    }

    /// Regressors of all term coefficients for an epoch (physical, unscaled), model order.
    /// Returns false if any term lacked an input.
    pub fn term_regressors(&self, ep: &Epoch, out: &mut [f32]) -> bool {
        let mut ok = true;
        let mut at = 0;
        for t in self.model.terms {
            let l = t.len();
            // a term writes all of `out[..l]` (`Term::regressors`): straight into place
            // (12 times per envelope evaluation), through a scratch only past the end
            match out.get_mut(at..at + l) {
                Some(o) => ok &= t.regressors(ep, o),
                None => ok &= t.regressors(ep, &mut [0.0f32; MAX_TERM_STATES][..l]),
            }
            at += l;
        }
        ok
    }

    fn process(&mut self, ep: &Epoch) -> Output {
        let mut flags = ep.flags;
        if self.survey {
            flags.set(Flags::SURVEY_MODE);
        }
        // Before the first valid reading the builder has no reference yet (it reports 0):
        // taking that as one would shift the field states by the whole 50 000 nT.
        if ep.mag.is_some() {
            self.rereference(ep.reference);
        }
        self.predict_field(ep);
        // Regressors: scaled for the filter, physical for the interference sum.
        let mut h = [0.0f32; N];
        let mut phys = [0.0f32; N];
        let (mut interference, frozen) = self.regressors(ep, &mut h, &mut phys, &mut flags);
        self.scalar = self.fuse_scalar(ep, &h, frozen, &mut flags);
        flags.set(self.tie_points(ep));
        self.convergence(ep, &phys, &mut flags);
        let mut dh_out = ep.dh_m;
        if self.field.is_some()
            && self.cfg.h0_reanchor_m > 0.0
            && ep.dh_m.is_finite()
            && libm::fabsf(ep.dh_m) > self.cfg.h0_reanchor_m
        {
            self.reanchor_h0(ep.dh_m);
            dh_out = 0.0;
        }
        if !self.survey && self.diverged(ep, &phys) {
            self.reset_to_last_good();
            flags.set(Flags::FILTER_RESET | Flags::NOT_CONVERGED);
        }
        // Outputs from the updated state.
        let x = self.filter.state();
        if !self.survey {
            // Until the flight has determined the interference, the output is the prior's
            // (zero, or the loaded coefficients'): a half-learnt estimate put ~9 000 nT
            // excursions into the first 30 s of a real box.
            // Once it had converged, a filter that is moving again shows what its last
            // good coefficients give, flagged: not a jump back to the raw field.
            let source = match (self.not_converged, self.has_last_good) {
                (false, _) => Coefficients::Current,
                (true, true) => Coefficients::LastGood,
                (true, false) => Coefficients::Prior,
            };
            interference = self.interference_from(&phys, source);
        }
        // The jitter of what is shown as converged: the prior's or a moving estimate's
        // output is not the record's bound's business.
        if self.not_converged && !self.survey {
            self.jitter = jitter::InterferenceJitter::new();
        } else {
            self.jitter
                .push(interference, self.cfg.consistency_window_epochs);
        }
        let anomaly_nt = if self.field.is_some() {
            let a = self.field_at;
            x[a] * self.scale[a] + x[a + 3] * self.scale[a + 3] * dh_out
        } else {
            x[0] * self.scale[0]
        } + self.reference_shift_nt();
        Output {
            t_s: ep.t_s,
            mag: ep.mag,
            interference_nt: interference,
            compensated: ep.mag.map(|m| m.minus_nt(interference)),
            anomaly_nt,
            innovation_nt: self.scalar.innovation_nt,
            innovation_var_nt2: self.scalar.innovation_var_nt2,
            interference_sigma_nt: self.interference_bound_nt(),
            flags,
        }
    }

    /// Time update of the field states over the distance flown since the last epoch (the
    /// anomaly is a process in space, model.md §3); none without movement.
    fn predict_field(&mut self, ep: &Epoch) {
        if let Some(f) = self.field {
            if ep.ds_m > 0.0 && ep.ds_m.is_finite() {
                let mut dq = [0.0f32; MAX_NOISE];
                f.discretise_step(ep.ds_m, self.field_at, &mut self.phi, &mut self.g, &mut dq);
                if self.field_noise_scale != 1.0 {
                    for v in dq.iter_mut() {
                        *v *= self.field_noise_scale;
                    }
                }
                self.filter.time_update(self.n_dyn, &self.phi, &self.g, &dq);
            }
        }
    }

    /// The epoch's regressors, physical (`phys`, for the interference sums) and scaled by
    /// the states' prior 1σ (`h`, for the filter; survey mode: the dynamic states only, the
    /// frozen coefficients are no states). Returns the interference of the present
    /// coefficients and the sum over every term (what survey mode subtracts); zeros in
    /// calibrate mode, which reads neither.
    fn regressors(
        &self,
        ep: &Epoch,
        h: &mut [f32; N],
        phys: &mut [f32; N],
        flags: &mut Flags,
    ) -> (f32, f32) {
        if self.n_offset == 1 {
            phys[0] = 1.0;
        }
        if self.field.is_some() {
            phys[self.field_at] = 1.0;
            phys[self.field_at + 3] = ep.dh_m;
        }
        let mut at = self.terms_at;
        for t in self.model.terms {
            let l = t.len();
            // a term writes all of `out[..l]` (`Term::regressors`): straight into place
            if !t.regressors(ep, &mut phys[at..at + l]) {
                flags.set(Flags::AUX_MISSING);
            }
            at += l;
        }
        let x = self.filter.state();
        let mut interference = 0.0f32;
        let mut frozen = 0.0f32;
        let mut at = self.terms_at;
        // calibrate mode: `process` computes the interference from the updated state and
        // the frozen sum is survey mode's; neither sum is read
        let terms = if self.survey { self.model.terms } else { &[] };
        for t in terms {
            // once per term: a `dyn` call the optimiser cannot hoist out of the loop itself
            let is_interference = t.is_interference();
            let l = t.len();
            let (xs, ss, ps) = (&x[at..at + l], &self.scale[at..at + l], &phys[at..at + l]);
            for ((xi, si), pi) in xs.iter().zip(ss).zip(ps) {
                let c = xi * si * pi;
                frozen += c;
                if is_interference {
                    interference += c;
                }
            }
            at += l;
        }
        let upto = if self.survey { self.n_dyn } else { self.n };
        for ((hi, p), sc) in h[..upto]
            .iter_mut()
            .zip(&phys[..upto])
            .zip(&self.scale[..upto])
        {
            *hi = p * sc;
        }
        (interference, frozen)
    }

    /// Moves `h0` by `delta_m` (to the current height): `B_h ← B_h + B_z·Δ`, exactly.
    fn reanchor_h0(&mut self, delta_m: f32) {
        let bh = self.field_at;
        let bz = self.field_at + 3;
        let c = delta_m * self.scale[bz] / self.scale[bh];
        self.filter.add_scaled_state(bh, bz, c);
        self.builder.shift_h0(delta_m);
        self.h0_shift_m += delta_m;
    }

    /// The current reference less the first (nT): what the states, held relative to the
    /// current one, need added to be relative to the first.
    fn reference_shift_nt(&self) -> f32 {
        match (self.last_reference, self.first_reference) {
            (Some(now), Some(first)) => now.diff_nt(first),
            _ => 0.0,
        }
    }

    /// Keeps the field states continuous when the builder moves its exact reference.
    fn rereference(&mut self, reference: MagCounts) {
        self.first_reference.get_or_insert(reference);
        let Some(old) = self.last_reference.replace(reference) else {
            return;
        };
        if old == reference {
            return;
        }
        let shift_nt = old.diff_nt(reference);
        let main = if self.field.is_some() {
            self.field_at
        } else {
            0
        };
        let first_clone = self.n_offset;
        let n_clone = self.n_clone;
        let scale = self.scale;
        let x = self.filter.state_mut();
        x[main] += shift_nt / scale[main];
        for i in first_clone..first_clone + n_clone {
            x[i] += shift_nt / scale[i];
        }
    }
}
