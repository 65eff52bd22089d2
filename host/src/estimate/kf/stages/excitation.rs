//! The excitation stage: the coefficient combinations this flight's manoeuvres do not
//! determine are held at their prior ([`crate::estimate::excitation`]). Post-flight only:
//! which combinations the flight excites is known at its end, and the board (which real
//! time reproduces) cannot know it in advance.

use super::super::KfOptions;
use crate::estimate::excitation::{airborne_span, unexcited_combinations, warning};
use crate::flight::Flight;
use magcomp_core::model::Term;

/// What the excitation check decided.
#[derive(Clone, Debug, Default)]
pub(crate) struct ExcitationStage {
    /// Combinations (prior-σ units, model order) held at the prior; empty = all free.
    pub held: Vec<Vec<f32>>,
    /// Names how many were held (None when none was).
    pub warning: Option<String>,
}

impl ExcitationStage {
    /// Whether the check runs: a post-flight calibration.
    pub fn applies(opts: &KfOptions) -> bool {
        opts.coefficients.is_none() && !opts.realtime
    }

    /// The check on a calibration pass's interference regressors (nothing held).
    pub fn check(flight: &Flight, opts: &KfOptions, regressors: &[Vec<f32>]) -> Self {
        let terms = opts.model.build_terms();
        let prior: Vec<f64> = terms
            .iter()
            .flat_map(|t| (0..t.len()).map(|i| t.prior_sigma(i) as f64 * opts.prior_scale))
            .collect();
        let interference: Vec<bool> = terms
            .iter()
            .flat_map(|t| std::iter::repeat_n(t.is_interference(), t.len()))
            .collect();
        let span = airborne_span(flight);
        let held = unexcited_combinations(flight, &regressors[span], &prior, &interference);
        let warning = (!held.is_empty()).then(|| {
            warning(
                held.len(),
                interference.iter().filter(|i| **i).count(),
                true,
            )
        });
        Self { held, warning }
    }
}
