//! The core's configuration errors in words: its enums (`BadConfig`, `BadCoefficients`)
//! are names for code, not for the user reading an error.

use magcomp_core::acquisition::AcqError;
use magcomp_core::compensator::CompensatorError;

/// What went wrong when the filter was built or given its coefficients.
pub fn compensator_error(e: &CompensatorError) -> String {
    match e {
        CompensatorError::TooManyStates { needed, capacity } => format!(
            "the model needs {needed} filter states, more than the {capacity} this filter holds"
        ),
        CompensatorError::WindowTooLarge => {
            "the derivative window is larger than the filter's ring holds".into()
        }
        CompensatorError::BadConfig => {
            "a filter setting (a prior σ, the noise, the sample rate or σ1) is not a finite positive number".into()
        }
        CompensatorError::BadCoefficients => {
            "the coefficients are the wrong number for the model or are not finite".into()
        }
    }
}

/// What went wrong when the board's acquisition was set up.
pub fn acquisition_error(e: &AcqError) -> String {
    match e {
        AcqError::BadRate => {
            "a sample rate is not finite, not positive, or above what the board takes".into()
        }
        AcqError::Compensator(c) => compensator_error(c),
    }
}

/// "cannot build the filter for 'SPEC': …", in words.
pub fn cannot_build(spec: &str, e: &CompensatorError) -> anyhow::Error {
    anyhow::anyhow!(
        "cannot build the filter for '{spec}': {}",
        compensator_error(e)
    )
}

/// "the coefficients do not fit model 'SPEC' (n values for k coefficients): …".
pub fn do_not_fit(spec: &str, given: usize, needed: usize, e: &CompensatorError) -> anyhow::Error {
    anyhow::anyhow!(
        "the coefficients do not fit model '{spec}' ({given} values for {needed} coefficients): {}",
        compensator_error(e)
    )
}
