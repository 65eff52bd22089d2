//! The record flags' names, bit by bit (`magcomp_core::Flags`), for every display of them.

/// Flag bits as words, in bit order.
pub const FLAG_NAMES: [&str; 15] = [
    "FLUX_STALE",
    "NO_GPS",
    "PARSE_ERROR",
    "MAG_MISSING",
    "INNOVATION_REJECTED",
    "FILTER_RESET",
    "TIE_POINT",
    "AUX_MISSING",
    "SURVEY_MODE",
    "NOT_CONVERGED",
    "DERIVATIVE_DEGRADED",
    "TIE_REJECTED",
    "LEVEL_UNDETERMINED",
    "MAG_SUSPECT",
    "WITNESS",
];
