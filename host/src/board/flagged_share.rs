//! The share of recent records the board flagged, and why (issue 17 item 3): in survey mode
//! with uploaded coefficients the operator must hear when more than 5 % of the records are
//! refused at the gate or degraded, not only see one record's flags go by.

use magcomp_core::Flags;
use std::collections::VecDeque;

/// Records judged: the last 600 (a minute at 10 Hz).
pub const WINDOW_RECORDS: usize = 600;
/// Fewer records than this say nothing yet.
const MIN_RECORDS: usize = 100;
/// Above this share the stream says so (issue 17 item 3).
pub const ALARM_SHARE: f64 = 0.05;

/// The flags that count: refused at the gate, or less trustworthy than normal.
const COUNTED: u16 = Flags::INNOVATION_REJECTED
    | Flags::TIE_REJECTED
    | Flags::FLUX_STALE
    | Flags::NO_GPS
    | Flags::MAG_MISSING
    | Flags::AUX_MISSING
    | Flags::DERIVATIVE_DEGRADED
    | Flags::MAG_SUSPECT;

/// Records carrying any counted flag, and each counted flag's records.
#[derive(Clone, Debug, Default)]
struct FlagCounts {
    flagged: usize,
    per_bit: [usize; 16],
}

impl FlagCounts {
    /// Counts a record's counted flags in (`add`) or out.
    fn count(&mut self, flags: u16, add: bool) {
        let f = flags & COUNTED;
        let step = |c: &mut usize| {
            if add {
                *c += 1
            } else {
                *c -= 1
            }
        };
        if f != 0 {
            step(&mut self.flagged);
        }
        for (bit, c) in self.per_bit.iter_mut().enumerate() {
            if f & (1 << bit) != 0 {
                step(c);
            }
        }
    }
}

#[derive(Clone, Debug, Default)]
pub struct FlaggedShare {
    recent: VecDeque<u16>,
    counts: FlagCounts,
}

impl FlaggedShare {
    pub fn push(&mut self, flags: Flags) {
        if self.recent.len() == WINDOW_RECORDS {
            if let Some(old) = self.recent.pop_front() {
                self.counts.count(old, false);
            }
        }
        self.recent.push_back(flags.0);
        self.counts.count(flags.0, true);
    }

    /// Share of the window's records flagged (None before `MIN_RECORDS`).
    pub fn share(&self) -> Option<f64> {
        (self.recent.len() >= MIN_RECORDS)
            .then(|| self.counts.flagged as f64 / self.recent.len() as f64)
    }

    /// `FLAGGED 12.0 % of the last 600 records: INNOVATION_REJECTED 10.0 %, …` (the three
    /// commonest flags) when the share exceeds [`ALARM_SHARE`].
    pub fn alarm(&self, names: &[&str]) -> Option<String> {
        let share = self.share().filter(|&s| s > ALARM_SHARE)?;
        Some(format!(
            "FLAGGED {:.1} % of the last {} records: {}",
            100.0 * share,
            self.recent.len(),
            commonest(&self.counts.per_bit, self.recent.len(), names)
        ))
    }
}

/// The three commonest counted flags and their shares of `n` records.
fn commonest(per_bit: &[usize; 16], n: usize, names: &[&str]) -> String {
    let mut why: Vec<(usize, usize)> = per_bit
        .iter()
        .enumerate()
        .filter(|(_, &c)| c > 0)
        .map(|(b, &c)| (b, c))
        .collect();
    why.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    let reasons: Vec<String> = why
        .iter()
        .take(3)
        .map(|&(b, c)| {
            let name = names.get(b).copied().unwrap_or("bit");
            format!("{name} {:.1} %", 100.0 * c as f64 / n as f64)
        })
        .collect();
    reasons.join(", ")
}

/// The same over a whole replay: the records shown converged (calibrating records are
/// expected to be refused while the filter learns).
#[derive(Clone, Debug, Default)]
pub struct FlagTally {
    shown: usize,
    counts: FlagCounts,
}

impl FlagTally {
    pub fn push(&mut self, flags: Flags) {
        if flags.contains(Flags::NOT_CONVERGED) {
            return;
        }
        self.shown += 1;
        self.counts.count(flags.0, true);
    }

    /// The warning when more than [`ALARM_SHARE`] of the records shown converged were
    /// refused or degraded.
    pub fn warning(&self, names: &[&str]) -> Option<String> {
        let share = self.counts.flagged as f64 / self.shown.max(1) as f64;
        (self.shown > 0 && share > ALARM_SHARE).then(|| {
            format!(
                "{:.1} % of the {} records shown converged were refused at the gate or degraded: {}",
                100.0 * share,
                self.shown,
                commonest(&self.counts.per_bit, self.shown, names)
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::board::flag_names::FLAG_NAMES;

    #[test]
    fn says_so_above_five_percent_and_why() {
        let mut s = FlaggedShare::default();
        for i in 0..WINDOW_RECORDS {
            // 4 % rejected, 1 % suspect, NOT_CONVERGED (not counted) on all.
            let f = match i % 100 {
                0..=3 => Flags::INNOVATION_REJECTED,
                4 => Flags::MAG_SUSPECT,
                _ => 0,
            };
            s.push(Flags(f | Flags::NOT_CONVERGED));
        }
        assert!((s.share().unwrap() - 0.05).abs() < 1e-12);
        assert_eq!(s.alarm(&FLAG_NAMES), None, "5 % is not above 5 %");
        for _ in 0..12 {
            s.push(Flags(Flags::MAG_SUSPECT));
        }
        // The window dropped 4 rejected and 1 suspect record and took 12 suspect ones.
        let a = s.alarm(&FLAG_NAMES).expect("above 5 %");
        assert_eq!(
            a,
            "FLAGGED 6.2 % of the last 600 records: INNOVATION_REJECTED 3.3 %, MAG_SUSPECT 2.8 %"
        );
        // The window moves on: a clean minute clears it.
        for _ in 0..WINDOW_RECORDS {
            s.push(Flags(0));
        }
        assert_eq!(s.share(), Some(0.0));
        assert_eq!(s.alarm(&FLAG_NAMES), None);
    }

    #[test]
    fn a_replay_tally_counts_the_records_shown_converged() {
        let mut t = FlagTally::default();
        for i in 0..1000 {
            t.push(Flags(Flags::NOT_CONVERGED | Flags::INNOVATION_REJECTED));
            t.push(Flags(if i % 10 == 0 { Flags::NO_GPS } else { 0 }));
        }
        assert_eq!(
            t.warning(&FLAG_NAMES).as_deref(),
            Some(
                "10.0 % of the 1000 records shown converged were refused at the gate or \
                 degraded: NO_GPS 10.0 %"
            )
        );
        let mut clean = FlagTally::default();
        clean.push(Flags(Flags::NOT_CONVERGED | Flags::MAG_SUSPECT));
        assert_eq!(clean.warning(&FLAG_NAMES), None);
    }
}
