//! Scalar magnetometer / Larmor counter ASCII lines → exact [`MagCounts`].
//!
//! Accepted line formats (one sample per line, `\r\n`, `\n` or `\r` terminated):
//! - plain field, nT, 1–4 decimals: `53620.4401`
//! - Geometrics style (G-822A / G-858 serial output): `$ 53620.441,0999` — `$`, a space,
//!   the field, a comma, a 4-digit signal-strength/status word 0000–9999.
//! - quality suffix: `53620.4401,Q=97` — signal quality in percent 0–100.
//! - Larmor frequency: `F,174928.51234` in Hz (any number of decimals up to 18 digits),
//!   converted with the configured gyromagnetic ratio (Cs-133: 3.49857 Hz/nT).
//!
//! The field never passes through a float: digits → i64 counts of 1e-4 nT, and the Larmor
//! conversion is an exact rational division in i128 with round-half-up.

use super::common::{parse_decimal, parse_u32, DecimalError, POW10};
use crate::units::MagCounts;

/// Longest accepted line (excluding the terminator).
pub const MAX_SCALAR_LINE: usize = 48;
/// Plausible geomagnetic field range (nT).
pub const MIN_FIELD_NT: i64 = 10_000;
pub const MAX_FIELD_NT: i64 = 100_000;
/// Caesium-133 gyromagnetic ratio, Hz/nT × 1e9 (3.49857 Hz/nT).
pub const CS133_HZ_PER_NT_NANO: u64 = 3_498_570_000;
/// Potassium-39: 6.99812 Hz/nT.
pub const K39_HZ_PER_NT_NANO: u64 = 6_998_120_000;
/// Helium-4 (metastable): 28.02356 Hz/nT.
pub const HE4_HZ_PER_NT_NANO: u64 = 28_023_560_000;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScalarError {
    /// The field value has no digit.
    NoDigits,
    /// More than 4 decimals on a field in nT, or more than 18 digits.
    TooManyDigits,
    /// A character that does not belong to any accepted format.
    BadCharacter,
    /// Field outside 10 000–100 000 nT.
    OutOfRange,
    /// The status/quality suffix is malformed or out of its range.
    BadStatus,
    /// Line longer than [`MAX_SCALAR_LINE`].
    Overlong,
    /// A Larmor line arrived but no gyromagnetic ratio is configured.
    NoLarmorRatio,
    /// A counter line (`M,…`, `multi_scalar`) with fewer than 2 or more than 3 fields.
    ChannelCount,
    /// A further sample of a line that ran into the next (a lost terminator): the reader
    /// owes one line per sample it carried ([`ScalarReader::owed_line`]).
    Merged,
    /// The UART flagged an overrun, framing or noise error while the line was received
    /// ([`super::uart_errors::LineErrors`]): a digit may be wrong or lost, and a scalar line
    /// has no checksum to tell.
    Uart,
}

/// One scalar sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ScalarFrame {
    pub mag: MagCounts,
    /// Signal quality/status as sent (Geometrics 0–9999, `Q=` 0–100), if present.
    pub quality: Option<u16>,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ScalarStats {
    pub ok: u32,
    pub errors: u32,
    pub overlong: u32,
    /// Further samples of rejected lines that carried more than one (a lost terminator),
    /// each handed out as a [`ScalarError::Merged`] line: every sample is one of `ok`,
    /// `errors`, `overlong` or `merged`.
    pub merged: u32,
}

/// Line parser configuration.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ScalarConfig {
    /// Gyromagnetic ratio for `F,` lines, Hz/nT × 1e9; 0 = Larmor lines rejected.
    pub larmor_hz_per_nt_nano: u64,
}

impl Default for ScalarConfig {
    fn default() -> Self {
        Self {
            larmor_hz_per_nt_nano: CS133_HZ_PER_NT_NANO,
        }
    }
}

fn map_dec(e: DecimalError) -> ScalarError {
    match e {
        DecimalError::NoDigits => ScalarError::NoDigits,
        DecimalError::TooManyDigits => ScalarError::TooManyDigits,
        DecimalError::BadCharacter => ScalarError::BadCharacter,
    }
}

fn check_range(c: i64) -> Result<MagCounts, ScalarError> {
    if (MIN_FIELD_NT * 10_000..=MAX_FIELD_NT * 10_000).contains(&c) {
        Ok(MagCounts(c))
    } else {
        Err(ScalarError::OutOfRange)
    }
}

/// Field in nT with at most 4 decimals → counts, exactly.
pub fn parse_field_nt(s: &[u8]) -> Result<MagCounts, ScalarError> {
    let d = parse_decimal(s).map_err(map_dec)?;
    if d.scale > 4 {
        return Err(ScalarError::TooManyDigits);
    }
    // scale ≤ 4 and ≤ 18 digits: rescale cannot overflow past i64 for 14-digit integers,
    // and overflow is reported as out of range.
    check_range(d.rescale(4).ok_or(ScalarError::OutOfRange)?)
}

/// Larmor frequency (Hz, digits) / ratio → counts, exact rational rounding.
pub fn larmor_to_counts(freq_hz: &[u8], hz_per_nt_nano: u64) -> Result<MagCounts, ScalarError> {
    if hz_per_nt_nano == 0 {
        return Err(ScalarError::NoLarmorRatio);
    }
    let d = parse_decimal(freq_hz).map_err(map_dec)?;
    if d.mantissa < 0 {
        return Err(ScalarError::OutOfRange);
    }
    // counts = f·1e4 / γ = mant·1e4·1e9 / (γ_nano·10^scale); < 1e18·1e13 fits i128.
    let num = d.mantissa as i128 * 10_000 * 1_000_000_000;
    let den = hz_per_nt_nano as i128 * POW10[d.scale as usize] as i128;
    let c = (2 * num + den) / (2 * den);
    check_range(i64::try_from(c).map_err(|_| ScalarError::OutOfRange)?)
}

/// Parses one line (terminator stripped or not) in any of the accepted formats.
pub fn parse_scalar_line(line: &[u8], cfg: &ScalarConfig) -> Result<ScalarFrame, ScalarError> {
    let mut line = line;
    while let [rest @ .., b'\r' | b'\n' | b' '] = line {
        line = rest;
    }
    if let [b'$', b' ', rest @ ..] = line {
        let comma = rest
            .iter()
            .position(|&b| b == b',')
            .ok_or(ScalarError::BadStatus)?;
        let mag = parse_field_nt(&rest[..comma])?;
        let st = &rest[comma + 1..];
        if st.len() != 4 {
            return Err(ScalarError::BadStatus);
        }
        let q = parse_u32(st).ok_or(ScalarError::BadStatus)?;
        return Ok(ScalarFrame {
            mag,
            quality: Some(q as u16),
        });
    }
    if let [b'F', b',', rest @ ..] = line {
        return Ok(ScalarFrame {
            mag: larmor_to_counts(rest, cfg.larmor_hz_per_nt_nano)?,
            quality: None,
        });
    }
    match line.iter().position(|&b| b == b',') {
        None => Ok(ScalarFrame {
            mag: parse_field_nt(line)?,
            quality: None,
        }),
        Some(c) => {
            let mag = parse_field_nt(&line[..c])?;
            let q = match &line[c + 1..] {
                [b'Q', b'=', d @ ..] if !d.is_empty() && d.len() <= 3 => {
                    parse_u32(d).filter(|&q| q <= 100)
                }
                _ => None,
            }
            .ok_or(ScalarError::BadStatus)?;
            Ok(ScalarFrame {
                mag,
                quality: Some(q as u16),
            })
        }
    }
}

/// Most samples one rejected line is taken to carry: a sensor line is 8–40 bytes, so a
/// longer run without a terminator is garbage, not lost terminators.
pub const MAX_MERGED_SAMPLES: u16 = 4;

/// Byte-at-a-time line reader for the scalar port.
///
/// Every sample must yield one record, and the board's time is the sample count: a line
/// that ran into the next because its terminator was lost (`53620.440153620.4402`) is two
/// samples, and read as one it would shift every later record's time by one period. A
/// rejected line of about `n` times the good lines' length is taken as `n` samples
/// (rounded, at most [`MAX_MERGED_SAMPLES`]): the line's own error, then `n − 1`
/// [`ScalarError::Merged`] lines from [`owed_line`](Self::owed_line). A sensor's lines
/// keep their length within a few bytes (fixed decimals; a counter line's empty channel),
/// so the length counts samples whatever the format, and a corrupted byte does not change
/// it; the good lines' length is the midpoint of the shortest and the longest seen. A
/// line cut short or with a byte lost stays one sample.
#[derive(Clone, Debug)]
pub struct ScalarReader {
    buf: [u8; MAX_SCALAR_LINE],
    len: usize,
    overlong: bool,
    /// Bytes of the current line, those beyond the buffer included.
    seen: u16,
    /// Shortest and longest line that parsed (0 before the first).
    good_len: (u16, u16),
    /// Further samples the last rejected line carried, not yet handed out.
    owed: u16,
    pub cfg: ScalarConfig,
    pub stats: ScalarStats,
}

impl ScalarReader {
    pub const fn new(cfg: ScalarConfig) -> Self {
        Self {
            buf: [0; MAX_SCALAR_LINE],
            len: 0,
            overlong: false,
            seen: 0,
            good_len: (0, 0),
            owed: 0,
            cfg,
            stats: ScalarStats {
                ok: 0,
                errors: 0,
                overlong: 0,
                merged: 0,
            },
        }
    }

    /// Feeds one byte; a non-empty line yields exactly one result at its terminator.
    /// Single-field formats only: a counter line (`M,…`) is an error here, as it always
    /// was ([`push_line`](Self::push_line) reads both).
    pub fn push(&mut self, b: u8) -> Option<Result<ScalarFrame, ScalarError>> {
        self.push_with(b, |l, cfg| {
            super::multi_scalar::ScalarLine::Single(parse_scalar_line(l, cfg))
        })
        .map(|l| match l {
            super::multi_scalar::ScalarLine::Single(r) => r,
            super::multi_scalar::ScalarLine::Multi(_) => Err(ScalarError::BadCharacter),
        })
    }

    /// Feeds one byte; a non-empty line yields exactly one line at its terminator: a single
    /// field or a multi-channel counter line (`multi_scalar`).
    pub fn push_line(&mut self, b: u8) -> Option<super::multi_scalar::ScalarLine> {
        self.push_with(b, super::multi_scalar::parse_scalar_any)
    }

    fn push_with(
        &mut self,
        b: u8,
        parse: impl FnOnce(&[u8], &ScalarConfig) -> super::multi_scalar::ScalarLine,
    ) -> Option<super::multi_scalar::ScalarLine> {
        use super::multi_scalar::ScalarLine;
        if b == b'\r' || b == b'\n' {
            let r = if self.overlong {
                ScalarLine::Single(Err(ScalarError::Overlong))
            } else if self.len == 0 {
                return None;
            } else {
                parse(&self.buf[..self.len], &self.cfg)
            };
            let seen = self.seen;
            self.len = 0;
            self.seen = 0;
            self.overlong = false;
            match &r {
                ScalarLine::Single(Ok(_)) | ScalarLine::Multi(_) => {
                    self.stats.ok = self.stats.ok.saturating_add(1);
                    self.good_len = match self.good_len {
                        (0, _) => (seen, seen),
                        (lo, hi) => (lo.min(seen), hi.max(seen)),
                    };
                }
                ScalarLine::Single(Err(e)) => {
                    if *e == ScalarError::Overlong {
                        self.stats.overlong = self.stats.overlong.saturating_add(1)
                    } else {
                        self.stats.errors = self.stats.errors.saturating_add(1)
                    }
                    self.owed = self.samples_in(seen) - 1;
                }
            }
            return Some(r);
        }
        self.seen = self.seen.saturating_add(1);
        if self.len == MAX_SCALAR_LINE {
            self.overlong = true;
        } else {
            self.buf[self.len] = b;
            self.len += 1;
        }
        None
    }

    /// Samples a rejected line of `seen` bytes carried: its length over the good lines'
    /// (the midpoint of the shortest and longest), rounded, 1 to [`MAX_MERGED_SAMPLES`]
    /// (1 before any good line).
    fn samples_in(&self, seen: u16) -> u16 {
        let (lo, hi) = self.good_len;
        let twice_typical = u32::from(lo) + u32::from(hi);
        if twice_typical == 0 {
            return 1;
        }
        let rounded = (4 * u32::from(seen) + twice_typical) / (2 * twice_typical);
        rounded.clamp(1, u32::from(MAX_MERGED_SAMPLES)) as u16
    }

    /// The next further sample of a line that ran into the next, as a rejected line (call
    /// after each line until None): one per sample it carried beyond the first.
    pub fn owed_line(&mut self) -> Option<super::multi_scalar::ScalarLine> {
        if self.owed == 0 {
            return None;
        }
        self.owed -= 1;
        self.stats.merged = self.stats.merged.saturating_add(1);
        Some(super::multi_scalar::ScalarLine::Single(Err(
            ScalarError::Merged,
        )))
    }

    /// Bytes buffered for a line not yet terminated.
    pub fn pending(&self) -> bool {
        self.len > 0 || self.overlong
    }
}
