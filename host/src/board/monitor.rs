//! `magcomp monitor PORT_OR_FILE`: decodes the board's `$MCREC` stream and shows it live.
//!
//! Input: a serial device opened as a file (set it up first, e.g.
//! `stty -F /dev/ttyUSB0 115200 raw -echo`), a recorded file, or `-` for stdin
//! (`socat - /dev/ttyUSB0,b115200,raw | magcomp monitor -`).
//! On a terminal the panel is redrawn in place every `--interval-s` of wall-clock time;
//! otherwise one summary line is printed per `--interval-s` of record time (deterministic
//! for files and logs), and a final summary at the end of the stream.
//! Every line is accounted for: records, CRC failures, malformed records, replies
//! (`$MCACK`/`$MCERR`), boot banners (`$MCBOOT`), frame acknowledgements (`$MCSYN`, HIL
//! builds), raw sample lines (`$MCRAW`, `RAW,ON`), other lines. Missing sequence numbers are counted and listed; the last `STATUS`
//! reply's counters are shown (docs/protocols.md §5).

use crate::board::replay::{counts_text, nt_text};
use anyhow::{Context, Result};
use magcomp_core::protocol::common::crc16_ccitt;
use magcomp_core::protocol::multi_record::{decode_multi_record, MultiRecord};
use magcomp_core::protocol::raw::{decode_raw, RawSample};
use magcomp_core::protocol::record::{decode_record, Record, RecordError};
use magcomp_core::Flags;
use std::collections::VecDeque;
use std::fmt::Write as _;
use std::io::{Read, Write};
use std::time::{Duration, Instant};

/// Lines longer than this are not records (`MAX_RECORD_LEN` is 192): counted, skipped.
pub const MAX_LINE: usize = 512;
/// Gap list kept for display (the count is exact beyond it).
pub const MAX_GAPS: usize = 1000;
/// A jump forward larger than this is a restart or a corrupted-but-valid line, not a gap.
pub const MAX_GAP: u32 = 1_000_000;
/// Records used for the rate estimate.
const RATE_WINDOW: usize = 100;

pub use super::flag_names::FLAG_NAMES;

/// `FLUX_STALE|NO_GPS`, `-` for none; unknown bits as `BIT14`.
pub fn flag_words(f: Flags) -> String {
    let mut s = String::new();
    for bit in 0..16 {
        if f.0 & (1 << bit) == 0 {
            continue;
        }
        if !s.is_empty() {
            s.push('|');
        }
        match FLAG_NAMES.get(bit) {
            Some(n) => s.push_str(n),
            None => {
                let _ = write!(s, "BIT{bit}");
            }
        }
    }
    if s.is_empty() {
        s.push('-');
    }
    s
}

/// Counters over the whole stream.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MonitorStats {
    /// Non-empty lines read.
    pub lines: u64,
    pub records: u64,
    /// `$MCREC` lines whose CRC failed.
    pub crc_errors: u64,
    /// `$MCREC` lines with a good CRC but bad fields, or without a valid frame.
    pub parse_errors: u64,
    /// `$MCACK` / `$MCERR` replies.
    pub replies: u64,
    /// Anything else (noise, overlong lines, board lines with a bad CRC).
    pub other_lines: u64,
    /// `$MCRAW` sample lines (`RAW,ON`), and those whose CRC or fields failed.
    pub raw_lines: u64,
    pub raw_errors: u64,
    /// `$MCBOOT` banners (more than one: the board restarted) and the last one.
    pub boots: u64,
    pub boot: Option<BootBanner>,
    /// `$MCSYN` frame acknowledgements (HIL builds) and the last counts (scalar, flux, GPS).
    pub syncs: u64,
    pub sync: Option<[u64; 3]>,
    /// The last `$MCACK,STATUS` reply.
    pub status: Option<BoardStatus>,
    /// `$MCERR,8,STORAGE` replies: the board could not write its flash.
    pub storage_errors: u64,
    /// Sequence numbers never seen, and the gaps `(first, last)` (first `MAX_GAPS`).
    pub missing: u64,
    pub gaps: Vec<(u32, u32)>,
    /// Sequence going backwards or jumping > `MAX_GAP` (board restart, duplicate).
    pub restarts: u64,
    /// Records carrying each flag bit.
    pub flag_counts: [u64; 16],
    pub first_t_s: Option<f64>,
    pub last: Option<Record>,
    /// Of `records`, the several-magnetometer ones (`$MCMREC`), and the last of them
    /// (counted with their flags; the live view draws each channel from it).
    pub multi_records: u64,
    pub last_multi: Option<MultiRecord>,
}

/// `$MCBOOT,<board>,<version>[,RST=<cause>][,PANIC=<file:line>][,SYNC]*HHHH`.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct BootBanner {
    pub board: String,
    pub version: String,
    /// The firmware acknowledges frames with `$MCSYN` (feature `hil-sync`).
    pub sync: bool,
    /// Why the board last reset (`IWDG`, `SW`, `POR`, `PIN`, …; docs/protocols.md).
    pub reset_cause: Option<String>,
    /// Where the panic that caused the reset happened.
    pub panic: Option<String>,
}

/// `$MCACK,STATUS,<CAL|SURVEY>,<records>,<err_scalar>,<err_flux>,<err_gps>,<err_uart>,<err_cmd>[,<7 UART counts>[,<flux_suspect>]]*HHHH`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BoardStatus {
    pub survey: bool,
    /// Records emitted so far.
    pub records: u64,
    /// Lines/frames/sentences the parsers rejected, per sensor port.
    pub err_scalar: u64,
    pub err_flux: u64,
    pub err_gps: u64,
    /// UART overrun/framing/noise errors (all ports).
    pub err_uart: u64,
    /// Commands rejected with `$MCERR`.
    pub err_cmd: u64,
    /// Fluxgate frames refused as suspect (firmware from 2026-11-27; None before).
    pub flux_suspect: Option<u64>,
}

/// The body of `$<body>*HHHH` (line end optional) when its CRC-16 is right.
pub fn checked_body(l: &[u8]) -> Option<&[u8]> {
    let mut l = l.strip_prefix(b"$")?;
    while let [rest @ .., b'\r' | b'\n'] = l {
        l = rest;
    }
    let star = l.iter().rposition(|&b| b == b'*')?;
    let (body, crc) = (&l[..star], &l[star + 1..]);
    let crc = std::str::from_utf8(crc).ok()?;
    if crc.len() != 4 {
        return None;
    }
    (u16::from_str_radix(crc, 16).ok()? == crc16_ccitt(body)).then_some(body)
}

/// `$MCBOOT` banner fields (CRC checked).
pub fn parse_boot(l: &[u8]) -> Option<BootBanner> {
    let body = std::str::from_utf8(checked_body(l)?).ok()?;
    let mut f = body.strip_prefix("MCBOOT,")?.split(',');
    let board = f.next()?.to_string();
    let version = f.next()?.to_string();
    let mut b = BootBanner {
        board,
        version,
        ..BootBanner::default()
    };
    let mut next = f.next();
    if let Some(v) = next.and_then(|x| x.strip_prefix("RST=")) {
        b.reset_cause = Some(v.to_string());
        next = f.next();
    }
    if let Some(v) = next.and_then(|x| x.strip_prefix("PANIC=")) {
        b.panic = Some(v.to_string());
        next = f.next();
    }
    b.sync = match next {
        None => false,
        Some("SYNC") => true,
        Some(_) => return None,
    };
    f.next().is_none().then_some(b)
}

/// `$MCSYN` frame counts (scalar, fluxgate, GPS), CRC checked.
pub fn parse_sync(l: &[u8]) -> Option<[u64; 3]> {
    let body = std::str::from_utf8(checked_body(l)?).ok()?;
    let mut f = body.strip_prefix("MCSYN,")?.split(',');
    let mut n = [0u64; 3];
    for v in &mut n {
        *v = f.next()?.parse().ok()?;
    }
    f.next().is_none().then_some(n)
}

/// `$MCACK,STATUS` fields (CRC checked).
pub fn parse_status(l: &[u8]) -> Option<BoardStatus> {
    let body = std::str::from_utf8(checked_body(l)?).ok()?;
    let mut f = body.strip_prefix("MCACK,STATUS,")?.split(',');
    let survey = match f.next()? {
        "CAL" => false,
        "SURVEY" => true,
        _ => return None,
    };
    let mut n = [0u64; 6];
    for v in &mut n {
        *v = f.next()?.parse().ok()?;
    }
    // firmware from 2026-11-25 appends the UART errors by kind (3) and by port (4):
    // accepted, not shown; from 2026-11-27 the fluxgate frames refused as suspect
    let rest: Vec<&str> = f.collect();
    let extra_ok = matches!(rest.len(), 0 | 7 | 8) && rest.iter().all(|v| v.parse::<u64>().is_ok());
    let flux_suspect = rest.get(7).and_then(|v| v.parse().ok());
    extra_ok.then_some(BoardStatus {
        survey,
        records: n[0],
        err_scalar: n[1],
        err_flux: n[2],
        err_gps: n[3],
        err_uart: n[4],
        err_cmd: n[5],
        flux_suspect,
    })
}

/// The decoder state behind the display.
#[derive(Clone, Debug, Default)]
pub struct Monitor {
    stats: MonitorStats,
    expected: Option<u32>,
    recent_t_s: VecDeque<f64>,
    flagged: super::flagged_share::FlaggedShare,
    /// The last raw line decoded and not yet taken ([`Monitor::take_raw`]).
    last_raw: Option<RawSample>,
}

impl Monitor {
    pub fn new() -> Self {
        Self::default()
    }
    pub fn stats(&self) -> &MonitorStats {
        &self.stats
    }

    /// The raw sample line (`$MCRAW`) last read, once.
    pub fn take_raw(&mut self) -> Option<RawSample> {
        self.last_raw.take()
    }

    /// One line (with or without its terminator); returns the record if it is one.
    pub fn push_line(&mut self, line: &[u8]) -> Option<Record> {
        let mut l = line;
        while let [rest @ .., b'\r' | b'\n' | b' ' | b'\t'] = l {
            l = rest;
        }
        // Idle-line NULs and blanks before a record are not part of it.
        while let [b' ' | b'\t' | b'\r' | 0, rest @ ..] = l {
            l = rest;
        }
        if l.is_empty() {
            return None;
        }
        let s = &mut self.stats;
        s.lines += 1;
        if l.len() > MAX_LINE {
            s.other_lines += 1;
            return None;
        }
        if l.starts_with(b"$MCACK") || l.starts_with(b"$MCERR") {
            s.replies += 1;
            if let Some(st) = parse_status(l) {
                s.status = Some(st);
            } else if checked_body(l) == Some(b"MCERR,8,STORAGE") {
                s.storage_errors += 1;
            }
            return None;
        }
        if l.starts_with(b"$MCBOOT") {
            match parse_boot(l) {
                Some(b) => {
                    s.boots += 1;
                    s.boot = Some(b);
                }
                None => s.other_lines += 1,
            }
            return None;
        }
        if l.starts_with(b"$MCRAW") {
            match decode_raw(l) {
                Ok(r) => {
                    s.raw_lines += 1;
                    self.last_raw = Some(r);
                }
                Err(_) => s.raw_errors += 1,
            }
            return None;
        }
        // A several-sensor board's raw line: counted as one, its shared part kept.
        if l.starts_with(b"$MCMRAW") {
            match magcomp_core::protocol::multi_raw::decode_multi_raw(l) {
                Ok(r) => {
                    s.raw_lines += 1;
                    self.last_raw = Some(r.shared);
                }
                Err(_) => s.raw_errors += 1,
            }
            return None;
        }
        if l.starts_with(b"$MCSYN") {
            match parse_sync(l) {
                Some(n) => {
                    s.syncs += 1;
                    s.sync = Some(n);
                }
                None => s.other_lines += 1,
            }
            return None;
        }
        if l.starts_with(b"$MCMREC") {
            match decode_multi_record(l) {
                Ok(r) => {
                    let flags = r.ch[..usize::from(r.channels)]
                        .iter()
                        .fold(Flags::empty(), |f, c| f.union(c.flags));
                    self.track(r.seq, r.t_s, flags);
                    let s = &mut self.stats;
                    s.multi_records += 1;
                    s.last_multi = Some(r);
                }
                Err(RecordError::Crc { .. }) => s.crc_errors += 1,
                Err(_) => s.parse_errors += 1,
            }
            return None;
        }
        if !l.starts_with(b"$MCREC") {
            // A record whose `$` or prefix was corrupted: its CRC cannot be checked.
            if l.windows(6).any(|w| w == b"MCREC,") || l.windows(7).any(|w| w == b"MCMREC,") {
                s.parse_errors += 1;
            } else {
                s.other_lines += 1;
            }
            return None;
        }
        match decode_record(l) {
            Ok(r) => {
                self.record(&r);
                Some(r)
            }
            Err(RecordError::Crc { .. }) => {
                s.crc_errors += 1;
                None
            }
            Err(_) => {
                s.parse_errors += 1;
                None
            }
        }
    }

    fn record(&mut self, r: &Record) {
        self.track(r.seq, r.t_s, r.flags);
        self.stats.last = Some(*r);
    }

    /// A record of either kind: counted, its flags, its sequence number and time.
    fn track(&mut self, seq: u32, t_s: f64, flags: Flags) {
        let s = &mut self.stats;
        s.records += 1;
        for (bit, c) in s.flag_counts.iter_mut().enumerate() {
            if flags.0 & (1 << bit) != 0 {
                *c += 1;
            }
        }
        match self.expected {
            Some(e) if seq == e => {}
            Some(e) if seq > e && seq - e <= MAX_GAP => {
                s.missing += u64::from(seq - e);
                if s.gaps.len() < MAX_GAPS {
                    s.gaps.push((e, seq - 1));
                }
            }
            Some(_) => s.restarts += 1,
            None => {}
        }
        self.expected = Some(seq.wrapping_add(1));
        if t_s.is_finite() {
            s.first_t_s.get_or_insert(t_s);
            if self.recent_t_s.len() == RATE_WINDOW {
                self.recent_t_s.pop_front();
            }
            self.recent_t_s.push_back(t_s);
        }
        self.flagged.push(flags);
    }

    /// `FLAGGED …` when more than 5 % of the last minute's records were refused or
    /// degraded, with the commonest flags (issue 17 item 3).
    pub fn flagged_alarm(&self) -> Option<String> {
        self.flagged.alarm(&FLAG_NAMES)
    }

    /// Record rate (Hz) from the time stamps of the last records.
    pub fn rate_hz(&self) -> Option<f64> {
        let (a, b) = (self.recent_t_s.front()?, self.recent_t_s.back()?);
        let span = b - a;
        (span > 0.0).then(|| (self.recent_t_s.len() - 1) as f64 / span)
    }

    fn gap_text(&self) -> String {
        let g = &self.stats.gaps;
        let mut s = String::new();
        for (a, b) in g.iter().rev().take(5).rev() {
            if !s.is_empty() {
                s.push_str(", ");
            }
            if a == b {
                let _ = write!(s, "{a}");
            } else {
                let _ = write!(s, "{a}-{b}");
            }
        }
        if g.len() > 5 {
            s = format!("… {s}");
        }
        s
    }

    /// One line: counts, rate, errors, last values.
    pub fn summary_line(&self) -> String {
        let s = &self.stats;
        let mut o = format!(
            "records {} rate {} Hz | crc {} bad {} other {} replies {} | missing {}",
            s.records,
            self.rate_hz().map_or("-".into(), |r| format!("{r:.2}")),
            s.crc_errors,
            s.parse_errors,
            s.other_lines,
            s.replies,
            s.missing
        );
        if s.raw_lines + s.raw_errors > 0 {
            let _ = write!(o, " | raw {} bad {}", s.raw_lines, s.raw_errors);
        }
        if s.restarts > 0 {
            let _ = write!(o, " restarts {}", s.restarts);
        }
        if s.boots > 1 {
            let _ = write!(o, " boots {}", s.boots);
        }
        if s.storage_errors > 0 {
            let _ = write!(o, " storage errors {}", s.storage_errors);
        }
        if let Some(st) = &s.status {
            let _ = write!(o, " | status {}", status_text(st));
        }
        if let Some(a) = self.flagged_alarm() {
            let _ = write!(o, " | {a}");
        }
        if let Some(r) = &s.last {
            let _ = write!(
                o,
                " | seq {} t {:.3} comp {} flags {}",
                r.seq,
                r.t_s,
                counts_text(r.compensated),
                flag_words(r.flags)
            );
        }
        o
    }

    /// The live panel (one string of lines).
    pub fn panel(&self, source: &str) -> String {
        let s = &self.stats;
        let mut o = String::new();
        let _ = writeln!(o, "magcomp monitor — {source}");
        if let Some(b) = &s.boot {
            let _ = writeln!(
                o,
                "  board          {} {}{}{}{} (boots {})",
                b.board,
                b.version,
                if b.sync { " SYNC" } else { "" },
                b.reset_cause
                    .as_deref()
                    .map(|c| format!(", reset {c}"))
                    .unwrap_or_default(),
                b.panic
                    .as_deref()
                    .map(|p| format!(", after a panic at {p}"))
                    .unwrap_or_default(),
                s.boots
            );
        }
        match &s.last {
            Some(r) => {
                let _ = writeln!(o, "  seq            {}", r.seq);
                let _ = writeln!(o, "  t              {:.6} s", r.t_s);
                let _ = writeln!(o, "  mag            {} nT", counts_text(r.mag));
                let _ = writeln!(o, "  interference   {} nT", nt_text(r.interference_nt));
                let _ = writeln!(o, "  compensated    {} nT", counts_text(r.compensated));
                let _ = writeln!(o, "  anomaly        {} nT", nt_text(r.anomaly_nt));
                let _ = writeln!(o, "  innovation     {} nT", nt_text(r.innovation_nt));
                let _ = writeln!(o, "  bound (1σ)     {} nT", nt_text(r.sigma_nt));
                let _ = writeln!(
                    o,
                    "  flags          {:04X} {}",
                    r.flags.0,
                    flag_words(r.flags)
                );
            }
            None => {
                let _ = writeln!(o, "  (no record yet)");
            }
        }
        let _ = writeln!(
            o,
            "  rate           {} Hz",
            self.rate_hz().map_or("-".into(), |r| format!("{r:.2}"))
        );
        let _ = writeln!(
            o,
            "  records {}  crc errors {}  malformed {}  other lines {}  replies {}",
            s.records, s.crc_errors, s.parse_errors, s.other_lines, s.replies
        );
        let _ = writeln!(
            o,
            "  missing seq {} in {} gaps{}{}",
            s.missing,
            s.gaps.len(),
            if s.gaps.is_empty() { "" } else { ": " },
            self.gap_text()
        );
        if s.restarts > 0 {
            let _ = writeln!(o, "  restarts/out of order {}", s.restarts);
        }
        if let Some(st) = &s.status {
            let _ = writeln!(o, "  board status   {}", status_text(st));
        }
        if s.storage_errors > 0 {
            let _ = writeln!(o, "  flash write failures {}", s.storage_errors);
        }
        if let Some(n) = &s.sync {
            let _ = writeln!(
                o,
                "  frames taken   scalar {} flux {} gps {} ($MCSYN {})",
                n[0], n[1], n[2], s.syncs
            );
        }
        let mut fl = String::new();
        for (bit, c) in s.flag_counts.iter().enumerate() {
            if *c > 0 {
                let name = FLAG_NAMES.get(bit).copied().unwrap_or("?");
                let _ = write!(fl, " {name} {c}");
            }
        }
        let _ = writeln!(o, "  flagged:{}", if fl.is_empty() { " none" } else { &fl });
        o
    }
}

/// `CAL records 400 | errors scalar 0 flux 0 gps 0 uart 0 cmd 0 | flux suspect 0`.
pub fn status_text(st: &BoardStatus) -> String {
    let suspect = st
        .flux_suspect
        .map_or(String::new(), |n| format!(" | flux suspect {n}"));
    format!(
        "{} records {} | errors scalar {} flux {} gps {} uart {} cmd {}{suspect}",
        if st.survey { "SURVEY" } else { "CAL" },
        st.records,
        st.err_scalar,
        st.err_flux,
        st.err_gps,
        st.err_uart,
        st.err_cmd
    )
}

/// Header and rows of the saved CSV (a trace-like file: `t` first, `#` metadata).
pub const SAVE_HEADER: &str = "t,mag,interference,compensated,anomaly,innovation,sigma,flags,seq";

/// The saved CSV's three header lines (two comments, the column names).
pub fn write_save_header(w: &mut dyn Write, source: &str) -> std::io::Result<()> {
    writeln!(w, "# source: magcomp monitor")?;
    writeln!(w, "# input: {source}")?;
    writeln!(w, "{SAVE_HEADER}")
}

pub fn save_row(r: &Record) -> String {
    format!(
        "{:.6},{},{},{},{},{},{},{},{}",
        r.t_s,
        counts_text(r.mag),
        nt_text(r.interference_nt),
        counts_text(r.compensated),
        nt_text(r.anomaly_nt),
        nt_text(r.innovation_nt),
        nt_text(r.sigma_nt),
        r.flags.0,
        r.seq
    )
}

/// Cuts a byte stream into lines for [`Monitor::push_line`], across reads. A line longer
/// than [`MAX_LINE`] is not kept (a babbling port must not grow memory): it is handed on
/// as `MAX_LINE + 1` bytes of `?`, which the monitor counts as an other line.
#[derive(Clone, Debug, Default)]
pub struct LineSplitter {
    line: Vec<u8>,
    overlong: bool,
}

impl LineSplitter {
    /// Calls `each` with every line `bytes` completes (without its `\n`).
    pub fn push<E>(
        &mut self,
        bytes: &[u8],
        mut each: impl FnMut(&[u8]) -> Result<(), E>,
    ) -> Result<(), E> {
        for &b in bytes {
            if b == b'\n' {
                self.emit(&mut each)?;
            } else if self.line.len() > MAX_LINE {
                self.overlong = true;
            } else {
                self.line.push(b);
            }
        }
        Ok(())
    }

    /// Hands on the unterminated rest at the end of the stream, if any.
    pub fn finish<E>(&mut self, mut each: impl FnMut(&[u8]) -> Result<(), E>) -> Result<(), E> {
        if self.overlong || !self.line.is_empty() {
            self.emit(&mut each)?;
        }
        Ok(())
    }

    /// Drops a partial line: the bytes after a reconnection do not continue it.
    pub fn clear(&mut self) {
        self.line.clear();
        self.overlong = false;
    }

    fn emit<E>(&mut self, each: &mut impl FnMut(&[u8]) -> Result<(), E>) -> Result<(), E> {
        let r = if self.overlong {
            each(&[b'?'; MAX_LINE + 1])
        } else {
            each(&self.line)
        };
        self.clear();
        r
    }
}

/// How the stream is shown.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Display {
    /// Redraw the panel in place (ANSI) every period of wall-clock time.
    Live(Duration),
    /// A summary line per this many seconds of record time.
    Summary(f64),
    /// Nothing until the end.
    Quiet,
}

/// Reads `input` to its end, showing progress on `out` and saving records to `save`.
/// With `follow`, the end of `input` is waited on (polled every 200 ms), never reached.
pub fn monitor_stream<R: Read, W: Write>(
    mut input: R,
    source: &str,
    display: Display,
    follow: bool,
    out: &mut W,
    mut save: Option<&mut dyn Write>,
) -> Result<MonitorStats> {
    let mut m = Monitor::new();
    if let Some(w) = save.as_mut() {
        write_save_header(w, source)?;
    }
    if let Display::Live(_) = display {
        write!(out, "\x1b[2J")?;
    }
    let mut buf = [0u8; 4096];
    let mut lines = LineSplitter::default();
    let mut last_draw = Instant::now();
    let mut next_summary_t: Option<f64> = None;
    let mut handle =
        |m: &mut Monitor, l: &[u8], out: &mut W, save: &mut Option<&mut dyn Write>| -> Result<()> {
            if let Some(r) = m.push_line(l) {
                if let Some(w) = save.as_mut() {
                    writeln!(w, "{}", save_row(&r))?;
                }
                if let (Display::Summary(p), true) = (display, r.t_s.is_finite()) {
                    let due = *next_summary_t.get_or_insert(r.t_s + p);
                    if r.t_s >= due {
                        writeln!(out, "{}", m.summary_line())?;
                        // Skip forward over silent stretches instead of printing a burst.
                        let k = ((r.t_s - due) / p).floor() + 1.0;
                        next_summary_t = Some(due + k * p);
                    }
                }
            }
            Ok(())
        };
    loop {
        let n = match input.read(&mut buf) {
            Ok(0) if follow => {
                if let Some(w) = save.as_mut() {
                    w.flush()?;
                }
                std::thread::sleep(Duration::from_millis(200));
                0
            }
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e).context(format!("reading {source}")),
        };
        lines.push(&buf[..n], |l| handle(&mut m, l, out, &mut save))?;
        if let Display::Live(period) = display {
            if last_draw.elapsed() >= period {
                draw(out, &m, source)?;
                last_draw = Instant::now();
            }
        }
    }
    lines.finish(|l| handle(&mut m, l, out, &mut save))?;
    match display {
        Display::Live(_) => draw(out, &m, source)?,
        _ => writeln!(out, "end of stream: {}", m.summary_line())?,
    }
    out.flush()?;
    Ok(m.stats().clone())
}

fn draw<W: Write>(out: &mut W, m: &Monitor, source: &str) -> Result<()> {
    // Home, each line cleared to its end, then the rest of the screen.
    let mut s = String::from("\x1b[H");
    for l in m.panel(source).lines() {
        s.push_str(l);
        s.push_str("\x1b[K\n");
    }
    s.push_str("\x1b[J");
    out.write_all(s.as_bytes())?;
    out.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn multi_sensor_records_are_counted_with_their_flags_and_sequence() {
        use magcomp_core::protocol::multi_record::{
            encode_multi_record, ChannelRecord, MAX_MULTI_RECORD_LEN,
        };
        let mut m = Monitor::new();
        let mut buf = [0u8; MAX_MULTI_RECORD_LEN];
        for seq in [0u32, 1, 3] {
            let mut ch = [ChannelRecord::MISSING; 3];
            ch[0].flags = Flags(Flags::NO_GPS);
            let r = MultiRecord {
                seq,
                t_s: f64::from(seq) * 0.1,
                channels: 2,
                ch,
                diff: [None; 3],
            };
            let n = encode_multi_record(&r, &mut buf).unwrap();
            // the live view draws single-sensor records: nothing returned
            assert!(m.push_line(&buf[..n]).is_none());
        }
        buf[10] ^= 1;
        m.push_line(&buf[..buf.iter().position(|&b| b == b'\n').unwrap()]);
        let s = m.stats();
        assert_eq!((s.records, s.multi_records, s.crc_errors), (3, 3, 1));
        assert_eq!((s.missing, s.other_lines, s.parse_errors), (1, 0, 0));
        assert_eq!(s.flag_counts[1], 3, "NO_GPS");
        // channel 2 is not carried: its MISSING flag is not counted
        assert_eq!(s.flag_counts[3], 3, "MAG_MISSING of channel 1 only");
        assert_eq!(s.last_multi.map(|r| r.seq), Some(3));
    }

    #[test]
    fn flag_words_decode_bits() {
        assert_eq!(flag_words(Flags(0)), "-");
        assert_eq!(flag_words(Flags(0b11)), "FLUX_STALE|NO_GPS");
        assert_eq!(flag_words(Flags(1 << 8 | 1 << 14)), "SURVEY_MODE|WITNESS");
        assert_eq!(flag_words(Flags(1 << 15)), "BIT15");
    }
}
