//! What a live readout showed (`compensate --realtime`): when the filter converged, how much
//! of the flight went out raw while it calibrated, how often it reset. A real-time run's
//! figures of merit are computed over the records it showed converged: before them the
//! output is the raw field, and the switch to compensated is a step of the whole
//! interference (tens of nT) that the band-pass turns into a peak no compensation made
//! (the independent `lag_s32` read IR 0.76, a yaw 110 nT peak-to-peak against 11 raw).

use magcomp_core::Flags;
use serde::{Deserialize, Serialize};

/// Counts of a live run's records, by what the operator saw.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LiveReadout {
    pub records: usize,
    /// Shown raw: the filter had not determined the interference (`NOT_CONVERGED`).
    pub not_converged: usize,
    /// Shown compensated, converged (or in survey mode).
    pub converged: usize,
    /// Of those, the ones an operator takes as good: no degradation flag, no reset.
    pub shown_good: usize,
    /// Time (s) of the first record, and of the first converged one.
    pub first_record_s: Option<f64>,
    pub first_converged_s: Option<f64>,
    /// Converged stretches: the first convergence, and one more after each fall back.
    pub converged_runs: usize,
    /// Records flagged `FILTER_RESET` (divergence detected, last good state restored).
    pub filter_resets: usize,
    /// Converged records whose level between headings is left undetermined
    /// (`LEVEL_UNDETERMINED`: tie-line levelling removes it).
    pub level_undetermined: usize,
    /// Whether the last record counted went out converged.
    #[serde(skip)]
    last_converged: bool,
}

impl LiveReadout {
    /// The counts of `flags`, one per record at times `t_s`.
    pub fn of(t_s: &[f64], flags: &[u16]) -> Self {
        let mut r = Self::default();
        for (&t, &bits) in t_s.iter().zip(flags) {
            r.push(t, bits);
        }
        r
    }

    /// Counts the next record (time `t_s`, flags `bits`) in.
    pub fn push(&mut self, t_s: f64, bits: u16) {
        let f = Flags(bits);
        let converged = is_converged(bits);
        let was_converged = self.last_converged;
        self.records += 1;
        self.first_record_s.get_or_insert(t_s);
        if converged {
            self.converged += 1;
            self.first_converged_s.get_or_insert(t_s);
            self.converged_runs += usize::from(!was_converged);
            self.shown_good += usize::from(!f.degraded() && !f.contains(Flags::FILTER_RESET));
            self.level_undetermined += usize::from(f.contains(Flags::LEVEL_UNDETERMINED));
        } else {
            self.not_converged += 1;
        }
        self.filter_resets += usize::from(f.contains(Flags::FILTER_RESET));
        self.last_converged = converged;
    }

    /// The readout as text (one line, then what the figures cover).
    pub fn text(&self) -> String {
        let share = |k: usize| 100.0 * k as f64 / self.records.max(1) as f64;
        let from = match self.first_converged_s {
            Some(t) => format!(
                "converged from t = {t:.1} s ({:.1} s after the first record)",
                t - self.first_record_s.unwrap_or(t)
            ),
            None => "never converged: the whole flight was shown raw".into(),
        };
        let mut s = format!(
            "live readout: {from}; {} of {} records ({:.1} %) shown compensated, {} raw while \
             calibrating (NOT_CONVERGED); {} convergence{}, {} record{} flagged FILTER_RESET",
            self.converged,
            self.records,
            share(self.converged),
            self.not_converged,
            self.converged_runs,
            if self.converged_runs == 1 { "" } else { "s" },
            self.filter_resets,
            if self.filter_resets == 1 { "" } else { "s" },
        );
        if self.level_undetermined > 0 {
            s.push_str(&format!(
                "; {:.0} % of the converged records LEVEL_UNDETERMINED (their level between \
                 headings is left to tie-line levelling)",
                100.0 * self.level_undetermined as f64 / self.converged.max(1) as f64
            ));
        }
        s
    }
}

/// Whether a record went out converged (compensated, not raw while calibrating).
pub fn is_converged(flags: u16) -> bool {
    !Flags(flags).contains(Flags::NOT_CONVERGED)
}

/// `x` where the record went out converged, NaN elsewhere: the live figures' input.
pub fn converged_only(x: &[f64], flags: &[u16]) -> Vec<f64> {
    x.iter()
        .zip(flags)
        .map(|(&v, &f)| if is_converged(f) { v } else { f64::NAN })
        .collect()
}

/// A live run's interference error against the simulator's truth (nT rms) over the records
/// it showed converged, each converged stretch's mean removed: a convergence states the
/// interference's variation, not its level (which the anomaly states share), and a new
/// convergence may settle on another level. None without converged records.
pub fn live_error_rms_nt(interference_nt: &[f64], truth_nt: &[f64], flags: &[u16]) -> Option<f64> {
    let (mut sum_sq, mut n) = (0.0, 0usize);
    let mut run: Vec<f64> = Vec::new();
    let mut close = |run: &mut Vec<f64>| {
        let m = run.iter().sum::<f64>() / run.len().max(1) as f64;
        sum_sq += run.iter().map(|e| (e - m).powi(2)).sum::<f64>();
        n += run.len();
        run.clear();
    };
    for ((&i, &t), &f) in interference_nt.iter().zip(truth_nt).zip(flags) {
        let e = i - t;
        if is_converged(f) && e.is_finite() {
            run.push(e);
        } else if !is_converged(f) && !run.is_empty() {
            close(&mut run);
        }
    }
    close(&mut run);
    (n > 0).then(|| (sum_sq / n as f64).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_each_convergence_and_what_went_out_raw() {
        let nc = Flags::NOT_CONVERGED;
        let lu = Flags::LEVEL_UNDETERMINED;
        let flags = [
            nc,
            nc,
            lu,
            lu | Flags::FLUX_STALE,
            nc | Flags::FILTER_RESET,
            0,
            0,
        ];
        let t: Vec<f64> = (0..flags.len()).map(|k| 10.0 + k as f64).collect();
        let r = LiveReadout::of(&t, &flags);
        assert_eq!(
            r,
            LiveReadout {
                records: 7,
                not_converged: 3,
                converged: 4,
                shown_good: 3,
                first_record_s: Some(10.0),
                first_converged_s: Some(12.0),
                converged_runs: 2,
                filter_resets: 1,
                level_undetermined: 2,
                last_converged: true,
            }
        );
        let text = r.text();
        assert!(
            text.contains("converged from t = 12.0 s (2.0 s after the first record)"),
            "{text}"
        );
        assert!(text.contains("4 of 7 records (57.1 %)"), "{text}");
        assert!(text.contains("2 convergences, 1 record flagged"), "{text}");
        assert!(text.contains("50 % of the converged"), "{text}");
        let x = converged_only(&[1.0; 7], &flags);
        assert_eq!(x.iter().filter(|v| v.is_nan()).count(), 3);
    }

    #[test]
    fn the_live_error_removes_each_convergences_level() {
        let nc = Flags::NOT_CONVERGED;
        let flags = [0, 0, nc, 0, 0, nc];
        let truth = [0.0; 6];
        // Two stretches at levels 5 and −3, each ±1 about it; the raw record is ignored.
        let interference = [6.0, 4.0, 99.0, -2.0, -4.0, 0.0];
        let e = live_error_rms_nt(&interference, &truth, &flags).expect("converged");
        assert!((e - 1.0).abs() < 1e-12, "{e}");
        assert_eq!(live_error_rms_nt(&[1.0], &[0.0], &[nc]), None);
    }

    #[test]
    fn a_flight_never_converged_says_so() {
        let r = LiveReadout::of(&[0.0, 0.1], &[Flags::NOT_CONVERGED; 2]);
        assert_eq!(r.first_converged_s, None);
        assert!(r.text().contains("never converged"), "{}", r.text());
    }
}
