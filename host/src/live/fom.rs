//! The FOM table of a calibration pattern flown under the live view. The board's `$MCRAW`
//! lines (`RAW,ON`) carry the scalar, the body-frame fluxgate and the position of every
//! sample; its `$MCREC` records the compensated value. [`PatternWatch`] keeps both, paired
//! by sample time, over a bounded window ([`WINDOW_S`], at most [`MAX_ROWS`] rows), and
//! runs the report's own code on it: the unlabelled detector
//! ([`crate::qc::manoeuvres::detect`], with [`crate::qc::sets`] splitting pitch, roll and
//! yaw) and the FOM table ([`crate::calibration::fom::fom_table`]). The window becomes a
//! trace exactly as a board log does ([`crate::io::trace::board_log`]), so the table is
//! the one `magcomp report` gives for the same lines.
//!
//! When the pattern has ended ([`pattern_ended`]): the detector, run every
//! [`CHECK_EVERY_S`] of record time, finds a whole cloverleaf — at least
//! [`FULL_SET_HEADINGS`] headings with at least [`MIN_SETS_PER_HEADING`] manoeuvres each —
//! and no manoeuvre has ended in the last [`QUIET_S`]. Not 12 manoeuvres: from the fluxgate
//! alone the detector misses some yaw sets (a yaw shows only its part off the field), and
//! a pattern whose yaws were missed must still be tabulated. The board's `NOT_CONVERGED`
//! flag is not the rule: it tells the filter's state, which a board in survey mode with
//! stored coefficients never leaves, not the pattern's. The table is computed once per
//! pattern; a later one is looked for only after the last tabulated manoeuvre, so a second
//! pattern gives a second table.

use crate::calibration::fom::{fom_table, FomTable};
use crate::flight::Flight;
use crate::io::trace::board_log::{raw_row, raw_trace, COLUMNS};
use crate::qc::manoeuvres::{detect, Pattern};
use magcomp_core::protocol::raw::RawSample;
use magcomp_core::Flags;
use serde::Serialize;
use std::collections::VecDeque;

/// Record time kept (s): half an hour holds a whole AARC pattern (12 sets and 4 turns take
/// 10–20 min) with the level flight around it.
pub const WINDOW_S: f64 = 1800.0;
/// Rows kept whatever the rate: 30 min at 40 Hz, ~7 MB. At the board's 10 Hz the time
/// bound ([`WINDOW_S`]) is the one that acts.
pub const MAX_ROWS: usize = 72_000;
/// Record time between two runs of the detector (s): each run reads the whole window.
pub const CHECK_EVERY_S: f64 = 10.0;
/// A whole AARC cloverleaf: 4 headings, each with its pitch and roll sets at least (a
/// heading with one stray manoeuvre, e.g. turbulence on a transit, is not a leg of it).
pub const FULL_SET_HEADINGS: usize = 4;
pub const MIN_SETS_PER_HEADING: usize = 2;
/// The pattern has ended when no manoeuvre has for this long (s): longer than the pauses
/// between the sets on a leg, shorter than the level flight that follows a pattern.
pub const QUIET_S: f64 = 30.0;
/// A raw line's record follows it by `half_width` samples (the centred derivative): the
/// rows searched, newest first, for a record's sample.
const PAIR_SEARCH_ROWS: usize = 256;

/// One sample: the raw line's columns ([`COLUMNS`]) and its record's compensated value.
#[derive(Clone, Debug)]
struct Row {
    raw: [f64; 9],
    alt_m: f32,
    flags: Flags,
    comp_nt: f64,
    paired: bool,
}

/// What the page gets of a sample's raw line with its record.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RawState {
    /// Height (m) as decoded from the line; NaN when it had none.
    pub alt_m: f32,
    /// A GPS fix (the `NO_GPS` flag clear on the sample).
    pub gps_fix: bool,
}

/// The table pushed to the page, with when and over what it was computed.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct FomMsg {
    /// 1 for the first pattern tabulated since the view started, 2 for the next, …
    pub number: u32,
    /// Record time (s) of the latest sample when the table was computed.
    pub t_s: f64,
    /// The rows it was computed over: raw-line times (s), first and last.
    pub first_t_s: f64,
    pub last_t_s: f64,
    /// The last manoeuvre's end (s): a next pattern is looked for after it.
    pub pattern_end_t_s: f64,
    pub rule: String,
    pub table: FomTable,
    /// When the server sent it (Unix ms).
    pub sent_unix_ms: f64,
}

/// The bounded window of samples and the pattern-end rule.
#[derive(Debug, Default)]
pub struct PatternWatch {
    rows: VecDeque<Row>,
    /// Record time of the next detector run.
    next_check_t_s: Option<f64>,
    /// End of the last tabulated pattern: the next is looked for after it.
    after_t_s: Option<f64>,
    tables: u32,
}

impl PatternWatch {
    pub fn new() -> Self {
        Self::default()
    }

    /// Rows held now.
    pub fn len(&self) -> usize {
        self.rows.len()
    }
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// A raw line. Its time going back is a board restart: the window starts again.
    pub fn push_raw(&mut self, r: &RawSample) {
        if !r.t_s.is_finite() {
            return;
        }
        if self.rows.back().is_some_and(|b| r.t_s <= b.raw[0]) {
            *self = Self {
                tables: self.tables,
                ..Self::default()
            };
        }
        self.rows.push_back(Row {
            raw: raw_row(r),
            alt_m: r.alt_m,
            flags: r.flags,
            comp_nt: f64::NAN,
            paired: false,
        });
        let newest = r.t_s;
        while self
            .rows
            .front()
            .is_some_and(|f| newest - f.raw[0] > WINDOW_S)
            || self.rows.len() > MAX_ROWS
        {
            self.rows.pop_front();
        }
    }

    /// A record: paired with its sample's raw line by time (both carry it to the
    /// microsecond). None when no raw line of that time is held (`RAW,OFF`).
    pub fn push_record(&mut self, t_s: f64, comp_nt: Option<f64>) -> Option<RawState> {
        let row = self
            .rows
            .iter_mut()
            .rev()
            .take(PAIR_SEARCH_ROWS)
            .find(|row| (row.raw[0] - t_s).abs() < 0.5e-6)?;
        row.comp_nt = comp_nt.unwrap_or(f64::NAN);
        row.paired = true;
        Some(RawState {
            alt_m: row.alt_m,
            gps_fix: !row.flags.contains(Flags::NO_GPS),
        })
    }

    /// Runs the detector when it is due (every [`CHECK_EVERY_S`] of record time `t_s`) and
    /// returns the table when a pattern has ended since the last one.
    pub fn check(&mut self, t_s: f64) -> Option<FomMsg> {
        let due = *self.next_check_t_s.get_or_insert(t_s + CHECK_EVERY_S);
        if t_s < due {
            return None;
        }
        self.next_check_t_s = Some(t_s + CHECK_EVERY_S);
        let (flight, comp_nt) = self.flight()?;
        let pattern = detect(&flight)?;
        let last_t_s = *flight.t_s.last()?;
        let end_t_s = pattern_ended(&pattern, last_t_s)?;
        let table = fom_table(&flight, &pattern, "detected", &comp_nt, None)?;
        self.after_t_s = Some(end_t_s);
        self.tables += 1;
        Some(FomMsg {
            number: self.tables,
            t_s,
            first_t_s: flight.t_s[0],
            last_t_s,
            pattern_end_t_s: end_t_s,
            rule: rule_text(),
            table,
            sent_unix_ms: 0.0,
        })
    }

    /// The rows after the last tabulated pattern, up to the newest with its record, as a
    /// flight (the board log's trace, read as `magcomp report` reads it) and the
    /// compensated values.
    fn flight(&self) -> Option<(Flight, Vec<f64>)> {
        let last = self.rows.iter().rposition(|r| r.paired)?;
        let after = self.after_t_s.unwrap_or(f64::NEG_INFINITY);
        let rows: Vec<&Row> = self
            .rows
            .iter()
            .take(last + 1)
            .filter(|r| r.raw[0] > after)
            .collect();
        // Fewer rows than a pattern's four legs could hold.
        if rows.len() < 100 {
            return None;
        }
        let cols: Vec<Vec<f64>> = (0..COLUMNS.len())
            .map(|k| rows.iter().map(|r| r.raw[k]).collect())
            .collect();
        let flight = Flight::from_trace(&raw_trace(cols), &[], &[]).ok()?;
        let comp = rows.iter().map(|r| r.comp_nt).collect();
        Some((flight, comp))
    }
}

/// The rule, as the page states it under the table.
pub fn rule_text() -> String {
    format!(
        "computed once a pattern has ended: the detector (run every {CHECK_EVERY_S:.0} s) found \
         ≥ {MIN_SETS_PER_HEADING} manoeuvres on each of ≥ {FULL_SET_HEADINGS} headings, then \
         none for {QUIET_S:.0} s"
    )
}

/// The pattern-end rule: `Some(end of the last manoeuvre)` when `pattern` is a whole
/// cloverleaf (≥ [`FULL_SET_HEADINGS`] headings with ≥ [`MIN_SETS_PER_HEADING`] manoeuvres
/// each) and its last manoeuvre ended at least [`QUIET_S`] before `now_t_s`.
pub fn pattern_ended(pattern: &Pattern, now_t_s: f64) -> Option<f64> {
    let headings = pattern
        .legs
        .iter()
        .filter(|l| l.manoeuvres.len() >= MIN_SETS_PER_HEADING)
        .count();
    let end = pattern
        .manoeuvres()
        .map(|m| m.t_end)
        .fold(f64::MIN, f64::max);
    (headings >= FULL_SET_HEADINGS && now_t_s - end >= QUIET_S).then_some(end)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::qc::manoeuvres::{Leg, Manoeuvre};
    use magcomp_core::MagCounts;

    /// `legs` headings with `per_leg` manoeuvres each, 20 s apart, the last ending at
    /// `last_end_t_s`.
    fn pattern(legs: usize, per_leg: usize, last_end_t_s: f64) -> Pattern {
        let n = legs * per_leg;
        let t0 = last_end_t_s - 20.0 * n as f64;
        let legs = (0..legs)
            .map(|l| Leg {
                heading_deg: 90.0 * l as f64,
                tag: format!("h{:03}", 90 * l),
                start: 0,
                end: 0,
                manoeuvres: (0..per_leg)
                    .map(|k| {
                        let t = t0 + 20.0 * (l * per_leg + k) as f64;
                        Manoeuvre {
                            kind: ["pitch", "roll", "yaw"][k % 3].into(),
                            label: String::new(),
                            start: 0,
                            end: 0,
                            t_start: t,
                            t_end: t + 20.0,
                            amplitude_deg: 5.0,
                        }
                    })
                    .collect(),
            })
            .collect();
        Pattern {
            heading_source: "track".into(),
            manoeuvre_source: "fluxgate".into(),
            legs,
        }
    }

    #[test]
    fn the_pattern_ends_with_a_full_set_and_quiet_after_it() {
        let end = 1000.0;
        // A full set, quiet for QUIET_S: ended, at its last manoeuvre's end.
        assert_eq!(pattern_ended(&pattern(4, 3, end), end + QUIET_S), Some(end));
        assert_eq!(pattern_ended(&pattern(4, 3, end), end + 300.0), Some(end));
        // The last manoeuvre ended too recently: the set may still go on.
        assert_eq!(
            pattern_ended(&pattern(4, 3, end), end + QUIET_S - 0.1),
            None
        );
        // Yaws the detector missed: still a pattern.
        assert_eq!(pattern_ended(&pattern(4, 2, end), end + QUIET_S), Some(end));
        // Three headings (the fourth not flown yet), however many manoeuvres.
        assert_eq!(pattern_ended(&pattern(3, 4, end), end + 100.0), None);
        // The fourth heading with only its first set: a stray manoeuvre, or a leg begun.
        let mut short = pattern(4, 3, end);
        short.legs[3].manoeuvres.truncate(1);
        assert_eq!(pattern_ended(&short, end + 100.0), None);
        // A fifth heading with one stray manoeuvre moves the end to it.
        let mut stray = pattern(4, 3, end);
        stray.legs.push(pattern(1, 1, end + 50.0).legs.remove(0));
        assert_eq!(pattern_ended(&stray, end + 60.0), None);
        assert_eq!(pattern_ended(&stray, end + 80.0), Some(end + 50.0));
    }

    /// A raw sample at `t_s` with its height and flags (level, at one point).
    pub(crate) fn raw(t_s: f64, alt_m: f32, flags: u16) -> RawSample {
        RawSample {
            k: 0,
            t_s,
            mag: Some(MagCounts(540_000_000)),
            flux_nt: [10_000.0, 2_000.0, 50_000.0],
            lat_deg: 45.0,
            lon_deg: -75.0,
            alt_m,
            ground_speed_mps: 60.0,
            flags: Flags(flags),
        }
    }

    #[test]
    fn records_pair_with_their_raw_line_and_the_window_is_bounded() {
        let mut w = PatternWatch::new();
        // 40 min at 10 Hz: only the last WINDOW_S are held.
        let n = 24_000;
        for i in 0..n {
            w.push_raw(&raw(100.0 + f64::from(i) * 0.1, 500.0, 0));
        }
        assert_eq!(w.len(), (WINDOW_S * 10.0) as usize + 1);
        let t_last = 100.0 + f64::from(n - 1) * 0.1;
        assert!(w.rows.front().unwrap().raw[0] >= t_last - WINDOW_S - 1e-6);
        // At 100 Hz the row bound acts.
        let mut fast = PatternWatch::new();
        for i in 0..(MAX_ROWS + 5_000) {
            fast.push_raw(&raw(i as f64 * 0.01, 1.0, 0));
        }
        assert_eq!(fast.len(), MAX_ROWS);

        // A record finds its sample (two samples back, as the board sends it).
        let mut w = PatternWatch::new();
        w.push_raw(&raw(10.0, 512.25, 0));
        w.push_raw(&raw(10.1, 513.5, Flags::NO_GPS));
        w.push_raw(&raw(10.2, f32::NAN, Flags::NO_GPS));
        let s = w.push_record(10.1, Some(1.0)).unwrap();
        assert_eq!((s.alt_m, s.gps_fix), (513.5, false));
        assert_eq!(w.push_record(10.0, None).unwrap().alt_m, 512.25);
        assert!(w.push_record(10.2, None).unwrap().alt_m.is_nan());
        assert_eq!(w.push_record(10.05, None), None);
        // The clock going back (board restart) starts the window again.
        w.push_raw(&raw(0.0, 1.0, 0));
        assert_eq!(w.len(), 1);
        assert_eq!(w.push_record(10.1, None), None);
    }

    #[test]
    fn no_table_without_raw_lines_or_a_pattern() {
        let mut w = PatternWatch::new();
        for i in 0..2_000 {
            let t = f64::from(i) * 0.1;
            assert!(w.check(t).is_none());
            w.push_raw(&raw(t, 500.0, 0));
            w.push_record(t, Some(54_000.0));
        }
        assert_eq!(w.tables, 0);
    }
}
