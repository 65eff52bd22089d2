//! The diagnosis as a person reads it: the ranked table with each candidate's witnesses,
//! and the verdict ("suggestion", "recalibrate", "explains the data" within
//! [`EXPLAINED_FACTOR`], or "unexplained" with where and what could).

use super::reciprocal::Verdict;
use super::{evidence, Candidate, Diagnosis, EXPLAINED_FACTOR, RECALIBRATE};

impl Diagnosis {
    /// The ranked table a person reads.
    pub fn table(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "model {}: residual rms {:.4} nT, mean NIS {:.2} (1 = as the model expects)",
            self.model, self.residual_rms_nt, self.nis
        );
        if let Some((band, left)) = self.band_rms_nt {
            let _ = writeln!(
                s,
                "band-passed measurement ({:.1}–{:.1} Hz): {band:.4} nT rms, {left:.4} nT left by the model's terms fitted directly",
                evidence::DIRECT_BAND_HZ.0,
                evidence::DIRECT_BAND_HZ.1
            );
        }
        if self.failures.is_empty() {
            let _ = writeln!(s, "no time window stands out");
        } else {
            let _ = writeln!(s, "where it fails:");
            for f in &self.failures {
                let _ = writeln!(
                    s,
                    "  {:>8.1}–{:<8.1} s  rms {:>8.4} nT  {}",
                    f.t_start, f.t_end, f.rms_nt, f.label
                );
            }
        }
        for b in &self.bands {
            let _ = writeln!(
                s,
                "  band {:.3}–{:.3} Hz: {:.1}× the model's predicted power",
                b.f_lo_hz, b.f_hi_hz, b.excess
            );
        }
        self.candidate_rows(&mut s);
        if !self.untestable.is_empty() {
            let _ = writeln!(s, "not testable on this flight (not ranked):");
            for u in &self.untestable {
                let _ = writeln!(s, "  {:<29} {}", u.term, u.reason);
            }
        }
        let _ = writeln!(s, "{}", self.verdict());
        s
    }

    /// The candidates' rows of [`table`](Self::table), and the refits made.
    fn candidate_rows(&self, s: &mut String) {
        use std::fmt::Write;
        let pct = |v: Option<f64>| v.map_or("—".to_string(), |h| format!("{:.1}%", 100.0 * h));
        let _ = writeln!(s, "candidate terms (best first):");
        let _ = writeln!(
            s,
            "  {:<4} {:<24} {:>9} {:>9} {:>7} {:>7} {:>7} {:>12} {:>4} {:>9} {:>9} {:>7}  {:<22} effect",
            "rank",
            "term",
            "explained",
            "held-out",
            "band",
            "ref",
            "recip",
            "rms after nT",
            "dof",
            "F",
            "p",
            "signif.",
            "rests on"
        );
        for (i, c) in self.candidates.iter().enumerate() {
            let _ = writeln!(
                s,
                "  {:<4} {:<24} {:>8.1}% {:>9} {:>7} {:>7} {:>7} {:>12.4} {:>4} {:>9.1} {:>9.1e} {:>7}  {:<22} {}",
                i + 1,
                c.term,
                100.0 * c.explained_fraction,
                pct(c.heldout_explained_fraction),
                pct(c.band_heldout_fraction),
                pct(c.reference_heldout_fraction),
                c.reciprocal.as_ref().map_or("—", |r| r.verdict.word()),
                c.heldout_rms_after_nt.unwrap_or(c.residual_rms_after_nt),
                c.added_parameters,
                c.f_statistic,
                c.p_value,
                if c.significant {
                    "YES"
                } else if !c.material {
                    "small"
                } else {
                    "no"
                },
                if c.evidence.is_empty() {
                    "—".to_string()
                } else {
                    c.evidence.join("+")
                },
                c.effect
            );
        }
        let _ = writeln!(
            s,
            "  (held-out: share of the filter's innovations it removes on manoeuvres it was not fitted on; band: of the {:.1}–{:.1} Hz measurement regressed directly, no anomaly states; ref: of the measurement minus --reference; recip: reciprocal passes over the same ground, for lag; small: material by no witness, whatever its p)",
            evidence::DIRECT_BAND_HZ.0,
            evidence::DIRECT_BAND_HZ.1
        );
        for c in &self.candidates {
            if let Some(r) = &c.reciprocal {
                let _ = writeln!(
                    s,
                    "reciprocal passes for {} ({} pair(s), τ = shift / 2V): {}: {}",
                    c.term,
                    r.pairs,
                    r.verdict.word(),
                    r.reason
                );
                if let Some(tau) = r.tau_s.filter(|_| r.verdict == Verdict::Supports) {
                    let _ = writeln!(
                        s,
                        "  (τ {tau:+.3} s is a starting value for `{}`'s estimate)",
                        c.term
                    );
                }
            }
        }
        let refits: Vec<&Candidate> = self
            .candidates
            .iter()
            .filter(|c| c.refit.is_some())
            .collect();
        if !refits.is_empty() {
            let _ = writeln!(s, "whole model refitted with the candidate (predicted error counts the disagreement of the calibration's parts):");
            for c in refits {
                if let Some(r) = &c.refit {
                    let _ = writeln!(
                        s,
                        "  {:<24} predicted error {:.4} → {:.4} nT, output moves {:.4} nT (std){}",
                        c.term,
                        r.predicted_before_nt,
                        r.predicted_after_nt,
                        r.output_change_nt,
                        if r.contradicts {
                            ": the calibration cannot use it here (not recommended)"
                        } else if r.supports {
                            ": material"
                        } else {
                            ""
                        }
                    );
                }
            }
        }
    }

    /// Within [`EXPLAINED_FACTOR`] of what the model expects: mean NIS and every band.
    pub fn within_expectation(&self) -> bool {
        self.nis <= EXPLAINED_FACTOR && self.band_excess_max <= EXPLAINED_FACTOR
    }

    /// The conclusion, in one or two sentences: the term to add, a calibration that no
    /// longer fits, a model that explains the data, or a residual nothing here explains.
    pub fn verdict(&self) -> String {
        if let Some(c) = self.candidates.iter().find(|c| c.significant) {
            let on = c.evidence.join(" + ");
            if c.term == RECALIBRATE {
                return format!(
                    "recalibrate: a fresh calibration on this flight would remove {:.0} % of what the applied coefficients leave ({on}): they no longer fit; calibrate on a pattern flight",
                    100.0 * c.band_heldout_fraction.unwrap_or(c.explained_fraction).max(0.0)
                );
            }
            return format!(
                "suggestion: --model \"{}+{}\" (material by: {on})",
                self.model, c.term
            );
        }
        if self.within_expectation() {
            return format!(
                "no candidate is significant: the model explains the data (mean NIS {:.2}, every band's power within {:.1}× of what it expects; at most {EXPLAINED_FACTOR}× is required)",
                self.nis, self.band_excess_max
            );
        }
        let mut s = format!(
            "unexplained: the residual is larger than the model expects (mean NIS {:.2}, bands up to {:.1}× its power",
            self.nis, self.band_excess_max
        );
        if let Some(f) = self.failures.first() {
            s.push_str(&format!(
                "; {} time window(s), the first {:.0}–{:.0} s",
                self.failures.len(),
                f.t_start,
                f.t_end
            ));
        }
        s.push_str(&format!(
            "; residual rms {:.4} nT) and no catalogue term explains it",
            self.residual_rms_nt
        ));
        let unusable: Vec<&str> = self
            .candidates
            .iter()
            .filter(|c| c.material && !c.significant)
            .map(|c| c.term.as_str())
            .collect();
        if !unusable.is_empty() {
            s.push_str(&format!(
                " the calibration can use ({} fit part of it, but refitted with them it predicts a larger error)",
                unusable.join(", ")
            ));
        }
        if let Some(c) = self.candidates.iter().find(|c| c.term == RECALIBRATE) {
            s.push_str(&format!(
                "; a fresh calibration on this flight would remove {:.0} % of it held out ({:.0} % in the band)",
                100.0 * c.heldout_explained_fraction.unwrap_or(0.0).max(0.0),
                100.0 * c.band_heldout_fraction.unwrap_or(0.0).max(0.0)
            ));
        }
        s.push_str(
            ". What could: an effect the catalogue lacks (docs/adding-an-effect.md), a channel \
             not given (a current or voltage: --aux), a sensor fault, or an anomaly rougher \
             than the field model",
        );
        if self.straight_line {
            s.push_str(
                ". On a straight line slow interference can hide in the anomaly: fly the \
                 calibration pattern, or name a reference channel (--reference)",
            );
        }
        s
    }
}
