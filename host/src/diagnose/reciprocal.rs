//! The reciprocal-pass witness (issue 20 item 1): two straight legs over the same ground
//! in opposite directions (`estimate/reciprocal.rs`). A scalar lag τ shifts the anomaly
//! by V·τ backwards along each pass, so the passes line up only when one is moved 2·V·τ;
//! the anomaly states follow each pass as it reads and cannot hide that. It speaks for
//! `lag` alone: of the catalogue's terms only a delay moves the anomaly along the track
//! (`rate`, the other along-track term, is judged at crossovers). The pairs' mean
//! difference, a heading error, would speak for the permanent and induced terms of an
//! applied calibration, but those are judged on the manoeuvres directly; the report draws
//! it.
//!
//! What the passes measure is the scalar's lag behind the *positions*; `lag` corrects its
//! lag behind the *fluxgate* (the attitude). The two are one where the fluxgate and the
//! GPS share a clock, as in our simulator, not always: on the independent `lag_s32` (the
//! scalar 0.166 s behind the fluxgate) the two box pairs read τ +0.036 ± 0.033 s, and
//! `mag − true interference` lines up to 0.5–1.0 m (τ ≤ 0.009 s): that simulator keeps
//! the positions with the scalar. So the verdicts, with τ and σ_τ from [`reciprocal_lag`]
//! (σ_τ ≥ 0.021 s at 10 Hz and 60 m/s: the ground's ±2.5 m):
//! - **supports** `lag` when |τ| > [`SUPPORT_SIGMAS`]·σ_τ: a verdict may rest on it.
//!   Report-style flights (four lines 10 m apart at 300 m, seeds 1–6): a hidden 0.2 s lag
//!   reads 0.158–0.198 s at 4.7–7.9σ (6 of 6), 0.1 s reads 0.050–0.095 s (1 of 6 beyond
//!   3σ), clean |τ| ≤ 0.012 s (≤ 0.6σ).
//! - **none** otherwise: fewer than [`MIN_PAIRS`] pairs whose shift is fixed, no
//!   positions, or |τ| within 3σ. It never contradicts: passes that line up say the scalar
//!   keeps time with the positions, not with the fluxgate (`lag_s32` would have been
//!   vetoed, its error 0.79 nT left in). Where the passes and the refit's τ (from the
//!   manoeuvres) differ by more than [`DISAGREE_SIGMAS`]·σ_τ the reason says so: the
//!   positions and the fluxgate are then not on one clock.

use super::Candidate;
use crate::estimate::reciprocal::{reciprocal_lag, ReciprocalLag, MIN_PAIRS};
use crate::flight::Flight;
use magcomp_core::model::catalog::TermKind;
use serde::Serialize;

/// |τ| beyond this many σ_τ supports `lag`.
pub const SUPPORT_SIGMAS: f64 = 3.0;
/// The passes' τ and the refit's differ when this many σ_τ apart.
pub const DISAGREE_SIGMAS: f64 = 3.0;

/// What the reciprocal passes say of a candidate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Verdict {
    Supports,
    #[serde(rename = "none")]
    NoEvidence,
}

impl Verdict {
    pub fn word(self) -> &'static str {
        match self {
            Verdict::Supports => "supports",
            Verdict::NoEvidence => "none",
        }
    }
}

/// The witness's reading for one candidate.
#[derive(Clone, Debug, Serialize)]
pub struct Reciprocal {
    /// τ from the passes and its 1σ (s); None without pairs.
    pub tau_s: Option<f64>,
    pub sigma_s: Option<f64>,
    /// Pairs with a measured shift, and each one's τ (s).
    pub pairs: usize,
    pub pair_tau_s: Vec<f64>,
    pub verdict: Verdict,
    /// Why, in words.
    pub reason: String,
}

/// The candidates this witness speaks for.
pub fn speaks_for(term: &str) -> bool {
    TermKind::from_name(term) == Some(TermKind::Lag)
}

/// Gives each candidate the witness speaks for its reading. The pairs and τ are found once
/// per diagnosis, on the model's output, and only when there is such a candidate.
pub(super) fn attach(flight: &Flight, compensated_nt: &[f64], candidates: &mut [Candidate]) {
    if !candidates.iter().any(|c| speaks_for(&c.term)) {
        return;
    }
    let found = reciprocal_lag(flight, compensated_nt);
    for c in candidates.iter_mut().filter(|c| speaks_for(&c.term)) {
        let r = Reciprocal::new(&found);
        if r.tested() {
            c.evidence_tested.push("reciprocal".into());
        }
        c.reciprocal = Some(r);
    }
}

impl Reciprocal {
    /// The reading before the other witnesses are known: supports or none.
    pub fn new(found: &Result<ReciprocalLag, String>) -> Self {
        let mut r = match found {
            Ok(l) => Self {
                tau_s: Some(l.tau_s),
                sigma_s: Some(l.sigma_s),
                pairs: l.pair_tau_s.len(),
                pair_tau_s: l.pair_tau_s.clone(),
                verdict: Verdict::NoEvidence,
                reason: String::new(),
            },
            Err(why) => Self {
                tau_s: None,
                sigma_s: None,
                pairs: 0,
                pair_tau_s: Vec::new(),
                verdict: Verdict::NoEvidence,
                reason: format!("no reciprocal passes ({why})"),
            },
        };
        r.judge(None);
        r
    }

    /// Whether the passes hold τ at all (at least [`MIN_PAIRS`] pairs).
    pub fn tested(&self) -> bool {
        self.pairs >= MIN_PAIRS && self.tau_s.is_some()
    }

    /// The verdict, and the reason with the lag the refit estimated (s) beside τ.
    pub fn judge(&mut self, refit_tau_s: Option<f64>) {
        let (Some(tau), Some(sigma)) = (self.tau_s, self.sigma_s) else {
            return;
        };
        let z = (tau / sigma).abs();
        self.verdict = if z > SUPPORT_SIGMAS {
            Verdict::Supports
        } else {
            Verdict::NoEvidence
        };
        self.reason = format!("τ {tau:+.3} ± {sigma:.3} s, {z:.1}σ from 0");
        if let Some(fit) = refit_tau_s.filter(|t| (t - tau).abs() > DISAGREE_SIGMAS * sigma) {
            self.reason.push_str(&format!(
                "; the manoeuvres give {fit:+.3} s: the positions and the fluxgate are not on \
                 one clock (apart by {:+.3} s)",
                fit - tau
            ));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reading(tau_s: f64, sigma_s: f64) -> Reciprocal {
        Reciprocal::new(&Ok(ReciprocalLag {
            tau_s,
            sigma_s,
            floor_s: sigma_s,
            pair_tau_s: vec![tau_s; 3],
            loose_pairs: 0,
            speed_mps: 58.0,
        }))
    }

    #[test]
    fn verdicts_follow_the_sigmas() {
        assert_eq!(reading(0.16, 0.03).verdict, Verdict::Supports);
        assert_eq!(reading(-0.16, 0.03).verdict, Verdict::Supports);
        assert_eq!(reading(0.08, 0.03).verdict, Verdict::NoEvidence);
        // Passes that line up beside a lag from the manoeuvres: said, not a veto.
        let mut r = reading(0.036, 0.033);
        r.judge(Some(0.164));
        assert_eq!(r.verdict, Verdict::NoEvidence);
        assert!(
            r.reason.contains("manoeuvres give +0.164 s"),
            "{}",
            r.reason
        );
        r.judge(Some(0.05));
        assert!(!r.reason.contains("manoeuvres"), "{}", r.reason);
        let none = Reciprocal::new(&Err("no positions".into()));
        assert!(!none.tested() && none.verdict == Verdict::NoEvidence);
        assert!(none.reason.starts_with("no reciprocal passes"));
    }
}
