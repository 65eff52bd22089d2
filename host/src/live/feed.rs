//! The board's lines turned into the live page's messages: the monitor's own decoder
//! ([`Monitor`]) classifies every line and counts gaps and restarts; this adds what the page
//! draws on top of it (the 4th difference, a monotonic chart time, alarms and events) and,
//! from the `$MCRAW` lines (`RAW,ON`), each record's height and GPS state and the FOM
//! table once a calibration pattern has ended ([`super::fom`]). A several-magnetometer
//! record (`$MCMREC`) is drawn too: each channel's compensated field and flags and the
//! pair differences ([`RecordMsg::channels`], [`RecordMsg::diffs_nt`]).

use super::fom::{FomMsg, PatternWatch};
use crate::board::monitor::{flag_words, Monitor, MAX_GAPS};
use crate::board::replay::nt_text;
use magcomp_core::protocol::multi_record::{pair_count, MultiRecord};
use magcomp_core::protocol::record::Record;
use magcomp_core::{Flags, MagCounts};
use serde::Serialize;
use std::time::{Duration, Instant};

/// How long an alarm raised by a single record (lost records, a restart, a rejected
/// innovation, garbage) stays on the banner: long enough for an operator glancing over.
pub const ALARM_HOLD: Duration = Duration::from_secs(5);

/// Default acceptance band of the 4th difference (± nT), the usual survey noise spec.
pub const D4_BAND_NT: f64 = 0.05;

/// One message to the page (JSON, tagged by `kind`).
#[derive(Clone, Debug, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Message {
    Record(Box<RecordMsg>),
    /// The FOM table of a calibration pattern that has just ended.
    Fom(Box<FomMsg>),
    /// The input was lost or came back (`up`), with why.
    Link {
        up: bool,
        text: String,
    },
}

/// A record as the page plots it. Field values are the line's own digits (4 decimals), so
/// the page's numbers compare exactly with the stream's; missing or non-finite → `null`.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct RecordMsg {
    pub seq: u32,
    pub t_s: f64,
    /// Chart time (s): the record time, continued across a board restart (whose clock
    /// starts again) so the strips keep running left to right.
    pub x_s: f64,
    pub raw_nt: Option<f64>,
    pub comp_nt: Option<f64>,
    pub interf_nt: Option<f64>,
    pub anom_nt: Option<f64>,
    pub innov_nt: Option<f64>,
    /// The record's stated 1σ bound on the interference (none while not converged).
    pub sigma_nt: Option<f64>,
    pub flags: u16,
    pub flag_words: String,
    /// Height (m) from this sample's `$MCRAW` line, its digits as sent; None without one
    /// (`RAW,OFF`) or when the line had no height.
    pub alt_m: Option<f64>,
    /// The sample's GPS state from its `$MCRAW` line's flags (`NO_GPS` clear: a fix); None
    /// without a raw line.
    pub gps_fix: Option<bool>,
    /// 4th difference of the compensated field centred on record `d4_seq` (two records
    /// back), once five consecutive records are in: exact from the integer counts.
    pub d4_seq: Option<u32>,
    pub d4_nt: Option<f64>,
    /// `$MCMREC` (2–3 magnetometers on one board): each channel, the first's values also
    /// in the fields above (whose `flags` are every channel's, OR-ed, so the banner raises
    /// any channel's alarm); empty for a `$MCREC`.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub channels: Vec<ChannelMsg>,
    /// With `channels`: the pair differences of the compensated fields (nT, exact from
    /// counts), in the record's order 2−1, 3−1, 3−2 (`None` when either is missing).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub diffs_nt: Vec<Option<f64>>,
    /// Alarms on now (banner), and events that happened with this record (log).
    pub alarms: Vec<String>,
    pub events: Vec<String>,
    pub counts: Counts,
    /// When the server sent it (Unix ms): the page's alarm latency is measured from it.
    pub sent_unix_ms: f64,
}

/// One channel of a several-magnetometer record, as the page draws it (the line's digits).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct ChannelMsg {
    pub raw_nt: Option<f64>,
    pub comp_nt: Option<f64>,
    pub interf_nt: Option<f64>,
    pub sigma_nt: Option<f64>,
    pub flags: u16,
    pub flag_words: String,
}

/// The monitor's counters, as the page's status line shows them.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct Counts {
    pub records: u64,
    pub crc_errors: u64,
    pub malformed: u64,
    pub other_lines: u64,
    /// `$MCRAW` lines read: none means the board's `RAW` output is off.
    pub raw_lines: u64,
    pub missing: u64,
    pub restarts: u64,
    pub boots: u64,
    pub rate_hz: Option<f64>,
    pub board: Option<String>,
}

/// `d4 = (x[i-2] − 4x[i-1] + 6x[i] − 4x[i+1] + x[i+2]) / 16`, in counts then nT. The /16
/// makes white noise of σ come out with σ·√(70)/16 ≈ 0.52 σ and a step of h with at most
/// 6h/16: the normalisation the RMS and Pico test displays use.
pub fn fourth_difference_nt(x: &[MagCounts; 5]) -> f64 {
    let c = x[0].0 - 4 * x[1].0 + 6 * x[2].0 - 4 * x[3].0 + x[4].0;
    c as f64 / 16.0 / magcomp_core::units::COUNTS_PER_NT as f64
}

/// What the page needs beyond the monitor's counters.
#[derive(Debug, Default)]
pub struct Feed {
    monitor: Monitor,
    /// The last records' `(seq, compensated)`, newest last, consecutive only.
    ring: Vec<(u32, MagCounts)>,
    x_offset_s: f64,
    last_x_s: Option<f64>,
    seen: SeenCounts,
    not_converged: Option<bool>,
    lost_until: Option<(Instant, String)>,
    restart_until: Option<Instant>,
    rejected_until: Option<Instant>,
    garbage_until: Option<Instant>,
    /// The raw lines' window and the pattern-end rule.
    watch: PatternWatch,
    fom: Option<FomMsg>,
}

/// Counter values at the previous record, to tell what changed since.
#[derive(Debug, Default, Clone, Copy)]
struct SeenCounts {
    missing: u64,
    restarts: u64,
    boots: u64,
    garbage: u64,
}

impl Feed {
    pub fn new() -> Self {
        Self::default()
    }
    pub fn monitor(&self) -> &Monitor {
        &self.monitor
    }

    /// One line of the board's output; the page's message if it was a record.
    pub fn push_line(&mut self, line: &[u8], now: Instant, unix_ms: f64) -> Option<RecordMsg> {
        let multi_before = self.monitor.stats().multi_records;
        let r = self.monitor.push_line(line);
        if let Some(raw) = self.monitor.take_raw() {
            self.watch.push_raw(&raw);
        }
        if self.monitor.stats().multi_records > multi_before {
            let m = self.monitor.stats().last_multi?;
            return Some(self.multi_record(&m, now, unix_ms));
        }
        Some(self.record(&r?, now, unix_ms))
    }

    /// A `$MCMREC`: the first channel through [`Self::record`] (strips, 4th difference,
    /// height), its flags every channel's so the banner says any channel's state; then
    /// every channel and the pair differences.
    fn multi_record(&mut self, m: &MultiRecord, now: Instant, unix_ms: f64) -> RecordMsg {
        let n = usize::from(m.channels).min(m.ch.len());
        let c0 = &m.ch[0];
        let first = Record {
            seq: m.seq,
            t_s: m.t_s,
            mag: c0.mag,
            interference_nt: c0.interference_nt,
            compensated: c0.compensated,
            anomaly_nt: f32::NAN,
            innovation_nt: f32::NAN,
            sigma_nt: c0.sigma_nt,
            flags: m.ch[..n]
                .iter()
                .fold(Flags::empty(), |f, c| f.union(c.flags)),
        };
        let mut msg = self.record(&first, now, unix_ms);
        msg.channels = m.ch[..n]
            .iter()
            .map(|c| ChannelMsg {
                raw_nt: c.mag.map(MagCounts::to_nt_f64),
                comp_nt: c.compensated.map(MagCounts::to_nt_f64),
                interf_nt: as_sent(c.interference_nt),
                sigma_nt: as_sent(c.sigma_nt),
                flags: c.flags.0,
                flag_words: flag_words(c.flags),
            })
            .collect();
        msg.diffs_nt = m.diff[..pair_count(n)]
            .iter()
            .map(|d| d.map(MagCounts::to_nt_f64))
            .collect();
        msg
    }

    /// The FOM table computed with the last record, once.
    pub fn take_fom(&mut self) -> Option<FomMsg> {
        self.fom.take()
    }

    /// Samples held for the FOM table (bounded: `fom::WINDOW_S`, `fom::MAX_ROWS`).
    pub fn window_rows(&self) -> usize {
        self.watch.len()
    }

    fn record(&mut self, r: &Record, now: Instant, unix_ms: f64) -> RecordMsg {
        // The counters, not the whole stats (their gap list runs to 1000 entries), per record.
        let counts = self.counts();
        let garbage = counts.crc_errors
            + counts.malformed
            + counts.other_lines
            + self.monitor.stats().raw_errors;
        let restarted =
            counts.restarts > self.seen.restarts || counts.boots > self.seen.boots.max(1);
        let lost = counts.missing - self.seen.missing;
        let mut events = Vec::new();
        if restarted {
            events.push(format!("board restart (sequence now {})", r.seq));
            self.restart_until = Some(now + ALARM_HOLD);
            self.ring.clear();
        }
        if lost > 0 {
            let gaps = &self.monitor.stats().gaps;
            // Past MAX_GAPS the list stops growing: its last entry is not this gap.
            let gap = match gaps.last() {
                Some((a, b)) if gaps.len() < MAX_GAPS => format!(" (seq {a}–{b})"),
                _ => String::new(),
            };
            events.push(format!("lost {lost} records{gap}"));
            self.lost_until = Some((now + ALARM_HOLD, format!("LOST {lost} records{gap}")));
            self.ring.clear();
        }
        if garbage > self.seen.garbage {
            let n = garbage - self.seen.garbage;
            events.push(format!("{n} undecodable line(s)"));
            self.garbage_until = Some(now + ALARM_HOLD);
        }
        let rejected = r.flags.0 & (Flags::INNOVATION_REJECTED | Flags::TIE_REJECTED);
        if rejected != 0 {
            self.rejected_until = Some(now + ALARM_HOLD);
        }
        let nc = r.flags.contains(Flags::NOT_CONVERGED);
        if self.not_converged.is_some_and(|was| was != nc) {
            events.push(if nc { "not converged" } else { "converged" }.to_string());
        }
        self.not_converged = Some(nc);
        self.seen = SeenCounts {
            missing: counts.missing,
            restarts: counts.restarts,
            boots: counts.boots.max(self.seen.boots),
            garbage,
        };
        let (d4_seq, d4_nt) = self.fourth_difference(r);
        let x_s = self.chart_time(r.t_s);
        let raw = self
            .watch
            .push_record(r.t_s, r.compensated.map(MagCounts::to_nt_f64));
        if let Some(f) = self.watch.check(r.t_s) {
            events.push(format!(
                "FOM table {}: pattern ended at {:.1} s, FOM {:.3} nT, IR {:.2}",
                f.number, f.pattern_end_t_s, f.table.fom_nt, f.table.improvement_ratio
            ));
            self.fom = Some(FomMsg {
                sent_unix_ms: unix_ms,
                ..f
            });
        }
        RecordMsg {
            seq: r.seq,
            t_s: r.t_s,
            x_s,
            raw_nt: r.mag.map(MagCounts::to_nt_f64),
            comp_nt: r.compensated.map(MagCounts::to_nt_f64),
            interf_nt: as_sent(r.interference_nt),
            anom_nt: as_sent(r.anomaly_nt),
            innov_nt: as_sent(r.innovation_nt),
            sigma_nt: as_sent(r.sigma_nt),
            flags: r.flags.0,
            flag_words: flag_words(r.flags),
            alt_m: raw.and_then(|s| as_sent(s.alt_m)),
            gps_fix: raw.map(|s| s.gps_fix),
            d4_seq,
            d4_nt,
            channels: Vec::new(),
            diffs_nt: Vec::new(),
            alarms: self.alarms(r.flags, now),
            events,
            counts,
            sent_unix_ms: unix_ms,
        }
    }

    fn counts(&self) -> Counts {
        let st = self.monitor.stats();
        Counts {
            records: st.records,
            crc_errors: st.crc_errors,
            malformed: st.parse_errors,
            other_lines: st.other_lines,
            raw_lines: st.raw_lines,
            missing: st.missing,
            restarts: st.restarts,
            boots: st.boots,
            rate_hz: self.monitor.rate_hz(),
            board: st.boot.as_ref().map(|b| {
                let cause = b.reset_cause.as_deref().unwrap_or("?");
                format!("{} {} (last reset {cause})", b.board, b.version)
            }),
        }
    }

    /// The 4th difference centred two records back, over five consecutive records.
    fn fourth_difference(&mut self, r: &Record) -> (Option<u32>, Option<f64>) {
        let consecutive = self
            .ring
            .last()
            .is_some_and(|&(s, _)| s.wrapping_add(1) == r.seq);
        match r.compensated {
            Some(c) => {
                if !consecutive {
                    self.ring.clear();
                }
                self.ring.push((r.seq, c));
                if self.ring.len() > 5 {
                    self.ring.remove(0);
                }
            }
            // A missing value breaks the run as a lost record does.
            None => self.ring.clear(),
        }
        match self.ring.as_slice() {
            [a, b, c, d, e] => (
                Some(c.0),
                Some(fourth_difference_nt(&[a.1, b.1, c.1, d.1, e.1])),
            ),
            _ => (None, None),
        }
    }

    /// Record time, shifted after a backward jump so the chart time keeps increasing.
    fn chart_time(&mut self, t_s: f64) -> f64 {
        if !t_s.is_finite() {
            return self.last_x_s.unwrap_or(0.0);
        }
        if let Some(last_x) = self.last_x_s {
            if t_s + self.x_offset_s <= last_x {
                // Restart: continue one record period (the last measured, else 0.1 s) on.
                let dt = self.monitor.rate_hz().map_or(0.1, |h| 1.0 / h.max(1e-3));
                self.x_offset_s = last_x + dt.min(1.0) - t_s;
            }
        }
        let x = t_s + self.x_offset_s;
        self.last_x_s = Some(x);
        x
    }

    fn alarms(&mut self, flags: Flags, now: Instant) -> Vec<String> {
        let mut a = Vec::new();
        if flags.contains(Flags::NOT_CONVERGED) {
            a.push("NOT CONVERGED".to_string());
        }
        if flags.degraded() {
            let bits = Flags(flags.0 & DEGRADED_BITS);
            a.push(format!("DEGRADED {}", flag_words(bits)));
        }
        let on = |until: Option<Instant>| until.is_some_and(|u| now < u);
        if on(self.rejected_until) {
            a.push("REJECTED innovations".to_string());
        }
        if let Some((until, text)) = &self.lost_until {
            if now < *until {
                a.push(text.clone());
            }
        }
        if on(self.restart_until) {
            a.push("BOARD RESTART".to_string());
        }
        if on(self.garbage_until) {
            a.push("GARBAGE lines".to_string());
        }
        a.extend(self.monitor.flagged_alarm());
        a
    }
}

/// The flags `Flags::degraded` looks at (shown by name on the banner).
const DEGRADED_BITS: u16 = Flags::FLUX_STALE
    | Flags::NO_GPS
    | Flags::MAG_MISSING
    | Flags::AUX_MISSING
    | Flags::DERIVATIVE_DEGRADED
    | Flags::MAG_SUSPECT;

/// The value as the record or raw line carried it (4 decimals), or `None` when empty.
fn as_sent(v: f32) -> Option<f64> {
    nt_text(v).parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;
    use magcomp_core::protocol::record::{encode_record, MAX_RECORD_LEN};

    fn line(seq: u32, comp: i64, flags: u16) -> Vec<u8> {
        let r = Record {
            seq,
            t_s: 100.0 + f64::from(seq) * 0.1,
            mag: Some(MagCounts(comp + 123_456)),
            interference_nt: 12.3456,
            compensated: Some(MagCounts(comp)),
            anomaly_nt: f32::NAN,
            innovation_nt: 0.0,
            sigma_nt: 0.25,
            flags: Flags(flags),
        };
        let mut b = [0u8; MAX_RECORD_LEN];
        let n = encode_record(&r, &mut b).unwrap();
        b[..n].to_vec()
    }

    #[test]
    fn fourth_difference_is_exact_and_restarts_after_a_gap() {
        // A single count spike at seq 4: d4 centred on it is 6/16 count.
        let now = Instant::now();
        let mut f = Feed::new();
        let comp = |s: u32| 500_000_000 + if s == 4 { 1 } else { 0 };
        let mut out = Vec::new();
        for s in (0..8).chain(10..16) {
            out.push(f.push_line(&line(s, comp(s), 0), now, 0.0).unwrap());
        }
        let d4: Vec<(Option<u32>, Option<f64>)> = out.iter().map(|m| (m.d4_seq, m.d4_nt)).collect();
        assert_eq!(d4[3], (None, None));
        assert_eq!(d4[6], (Some(4), Some(6.0 / 16.0 / 1e4)));
        // After the gap (8, 9 lost) four records pass before the first d4.
        assert_eq!(d4[8..12].iter().filter(|d| d.0.is_some()).count(), 0);
        assert_eq!(d4[12].0, Some(12));
        assert!(out[8]
            .alarms
            .iter()
            .any(|a| a.starts_with("LOST 2 records")));
        assert_eq!(out[8].interf_nt, Some(12.3456));
        assert_eq!(out[8].anom_nt, None);
    }

    #[test]
    fn a_raw_line_gives_its_record_height_and_gps_state_and_is_no_garbage() {
        use magcomp_core::protocol::raw::{encode_raw, RawSample, MAX_RAW_LEN};
        let now = Instant::now();
        let mut f = Feed::new();
        let raw = |seq: u32, alt_m: f32, flags: u16| {
            let t_s = 100.0 + f64::from(seq) * 0.1;
            let r = RawSample {
                k: seq,
                ..crate::live::fom::tests::raw(t_s, alt_m, flags)
            };
            let mut b = [0u8; MAX_RAW_LEN];
            let n = encode_raw(&r, &mut b).unwrap();
            b[..n].to_vec()
        };
        // Records without raw lines: no height.
        let m = f.push_line(&line(0, 1, 0), now, 0.0).unwrap();
        assert_eq!((m.alt_m, m.gps_fix, m.counts.raw_lines), (None, None, 0));
        // The raw lines come before their records (two samples ahead, as on the board).
        assert!(f.push_line(&raw(1, 1234.5625, 0), now, 0.0).is_none());
        assert!(f
            .push_line(&raw(2, 1235.0, Flags::NO_GPS), now, 0.0)
            .is_none());
        let m1 = f.push_line(&line(1, 1, 0), now, 0.0).unwrap();
        let m2 = f.push_line(&line(2, 1, 0), now, 0.0).unwrap();
        assert_eq!((m1.alt_m, m1.gps_fix), (Some(1234.5625), Some(true)));
        assert_eq!((m2.alt_m, m2.gps_fix), (Some(1235.0), Some(false)));
        assert_eq!(m2.counts.raw_lines, 2);
        assert!(m2.alarms.is_empty(), "{:?}", m2.alarms);
        assert_eq!(m2.counts.other_lines, 0);
        assert_eq!(f.window_rows(), 2);
        // A raw line with a broken checksum is garbage.
        let mut bad = raw(3, 1.0, 0);
        bad[8] = b'9';
        f.push_line(&bad, now, 0.0);
        let m3 = f.push_line(&line(3, 1, 0), now, 0.0).unwrap();
        assert!(m3.alarms.contains(&"GARBAGE lines".to_string()));
        assert_eq!(m3.alt_m, None);
    }

    #[test]
    fn a_multi_record_gives_every_channel_and_the_pair_differences() {
        use magcomp_core::protocol::multi_record::{
            encode_multi_record, ChannelRecord, MultiRecord, MAX_MULTI_RECORD_LEN,
        };
        let now = Instant::now();
        let mut f = Feed::new();
        let ch = |comp: Option<i64>, flags: u16| ChannelRecord {
            mag: comp.map(|c| MagCounts(c + 100_000)),
            interference_nt: 10.0,
            compensated: comp.map(MagCounts),
            sigma_nt: 0.25,
            flags: Flags(flags),
        };
        let line = |seq: u32, chans: [ChannelRecord; 3]| {
            let r = MultiRecord::new(seq, 100.0 + f64::from(seq) * 0.1, 3, chans);
            let mut b = [0u8; MAX_MULTI_RECORD_LEN];
            let n = encode_multi_record(&r, &mut b).unwrap();
            b[..n].to_vec()
        };
        let m0 = f
            .push_line(
                &line(
                    0,
                    [
                        ch(Some(500_000_000), 0),
                        ch(Some(500_012_345), 0),
                        ch(Some(499_990_000), 0),
                    ],
                ),
                now,
                0.0,
            )
            .expect("a multi record is drawn");
        assert_eq!(m0.channels.len(), 3);
        assert_eq!(m0.comp_nt, Some(50_000.0));
        let comps: Vec<_> = m0.channels.iter().map(|c| c.comp_nt).collect();
        assert_eq!(comps, [Some(50_000.0), Some(50_001.234_5), Some(49_999.0)]);
        assert_eq!(m0.diffs_nt, [Some(1.2345), Some(-1.0), Some(-2.2345)]);
        assert_eq!(m0.channels[1].interf_nt, Some(10.0));
        assert!(m0.alarms.is_empty(), "{:?}", m0.alarms);
        // Channel 2 missing: its pairs empty, its flag its own, the banner says it.
        let m1 = f
            .push_line(
                &line(
                    1,
                    [
                        ch(Some(500_000_001), 0),
                        ch(None, Flags::MAG_MISSING),
                        ch(Some(499_990_000), 0),
                    ],
                ),
                now,
                0.0,
            )
            .unwrap();
        assert_eq!(m1.diffs_nt, [None, Some(-1.0001), None]);
        assert_eq!(m1.channels[1].flags, Flags::MAG_MISSING);
        assert_eq!((m1.channels[0].flags, m1.channels[2].flags), (0, 0));
        assert_eq!(m1.flags, Flags::MAG_MISSING);
        assert!(
            m1.alarms.iter().any(|a| a.contains("MAG_MISSING")),
            "{:?}",
            m1.alarms
        );
        assert_eq!((m1.counts.records, m1.counts.missing), (2, 0));
        // A single-sensor record carries no channels (its JSON unchanged).
        let m2 = f.push_line(&super::tests::line(5, 1, 0), now, 0.0).unwrap();
        assert!(m2.channels.is_empty() && m2.diffs_nt.is_empty());
        let json = serde_json::to_value(&m2).unwrap();
        assert!(json.get("channels").is_none() && json.get("diffs_nt").is_none());
    }

    #[test]
    fn alarms_restart_and_chart_time() {
        let now = Instant::now();
        let mut f = Feed::new();
        let nc = Flags::NOT_CONVERGED | Flags::FLUX_STALE;
        let m0 = f.push_line(&line(0, 1, nc), now, 0.0).unwrap();
        assert_eq!(m0.alarms, ["NOT CONVERGED", "DEGRADED FLUX_STALE"]);
        let m1 = f.push_line(&line(1, 1, 0), now, 0.0).unwrap();
        assert!(m1.alarms.is_empty());
        assert_eq!(m1.events, ["converged"]);
        assert!(f.push_line(b"garbage\xff", now, 0.0).is_none());
        let m2 = f.push_line(&line(0, 1, 0), now, 0.0).unwrap();
        assert!(m2.alarms.contains(&"BOARD RESTART".to_string()));
        assert!(m2.alarms.contains(&"GARBAGE lines".to_string()));
        assert!(m2.x_s > m1.x_s, "{} {}", m2.x_s, m1.x_s);
        let later = f.push_line(&line(1, 1, 0), now + ALARM_HOLD, 0.0).unwrap();
        assert!(later.alarms.is_empty(), "{:?}", later.alarms);
    }
}
