//! Line framing, sensor line parsers, output records and the command protocol as the
//! firmware speaks them on its ports.
//!
//! PLACEHOLDER until `magcomp_core::protocol` (branch `proto`) lands: the firmware and the
//! hil-tests harness (which includes this file with `#[path]`) share it so both ends agree.
//! It depends on `core` and `magcomp_core` only, allocates nothing and never panics on input.
//!
//! Formats (all ASCII lines ending in `\n`, an optional `\r` before it is ignored):
//! - scalar magnetometer: `[$][ ]<total_nt>[,<quality>...]`, total field with up to 4
//!   decimals, parsed exactly into `MagCounts` (1e-4 nT), never through a float;
//! - fluxgate (serial alternative): `<x_nt>,<y_nt>,<z_nt>` in the body frame
//!   (x forward, y starboard, z down), up to 4 decimals;
//! - GPS: NMEA 0183 GGA, RMC, VTG with a mandatory checksum, talkers GP/GN/GL/GA;
//! - output record: `$MCREC,seq,t_s,mag_nt,interference_nt,compensated_nt,anomaly_nt,innovation_nt,flags_hex*HH`
//!   (empty field = missing value);
//! - command: `$MCCMD,<NAME>[,args]*HH`, replies `$MCACK,<NAME>[,values]*HH` or
//!   `$MCERR,<reason>[,NAME]*HH`. `HH` is the NMEA XOR checksum of the bytes between `$` and `*`.
#![allow(dead_code)]

use magcomp_core::{Flags, MagCounts};

/// Longest accepted line (bytes, without the terminator). NMEA allows 82 with `$` and CRLF.
pub const MAX_LINE: usize = 96;

/// What one byte did to a line buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LineEvent {
    /// Byte stored (or ignored): no complete line yet.
    Pending,
    /// A complete line of this many bytes is in `LineBuf::line()`.
    Line(usize),
    /// The line exceeded `MAX_LINE`: it was discarded up to and including its terminator.
    Overflow,
}

/// Byte-at-a-time line framer. Empty lines are ignored (a CR LF pair is one terminator).
pub struct LineBuf {
    buf: [u8; MAX_LINE],
    len: usize,
    overflowed: bool,
}

impl Default for LineBuf {
    fn default() -> Self {
        Self::new()
    }
}

impl LineBuf {
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_LINE],
            len: 0,
            overflowed: false,
        }
    }
    pub fn push(&mut self, b: u8) -> LineEvent {
        match b {
            b'\n' => {
                let n = self.len;
                self.len = 0;
                if core::mem::take(&mut self.overflowed) {
                    LineEvent::Overflow
                } else if n == 0 {
                    LineEvent::Pending
                } else {
                    LineEvent::Line(n)
                }
            }
            b'\r' => LineEvent::Pending,
            _ => {
                if self.len < MAX_LINE {
                    self.buf[self.len] = b;
                    self.len += 1;
                } else {
                    self.overflowed = true;
                }
                LineEvent::Pending
            }
        }
    }
    /// The bytes of the line last reported by `LineEvent::Line(n)`.
    pub fn line(&self, n: usize) -> &[u8] {
        &self.buf[..n.min(MAX_LINE)]
    }
}

/// Typed, countable parser errors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParseError {
    Overflow,
    Syntax,
    Checksum,
    Range,
    Unsupported,
}

/// XOR of all bytes (NMEA checksum of the bytes between `$` and `*`).
pub fn xor_checksum(body: &[u8]) -> u8 {
    body.iter().fold(0, |a, b| a ^ b)
}

fn hex_val(b: u8) -> Option<u8> {
    match b {
        b'0'..=b'9' => Some(b - b'0'),
        b'A'..=b'F' => Some(b - b'A' + 10),
        b'a'..=b'f' => Some(b - b'a' + 10),
        _ => None,
    }
}

/// Checks `$body*HH` and returns `body`.
pub fn checked_body(line: &[u8]) -> Result<&[u8], ParseError> {
    let line = trim(line);
    if line.len() < 4 || line[0] != b'$' {
        return Err(ParseError::Syntax);
    }
    let star = line.len() - 3;
    if line[star] != b'*' {
        return Err(ParseError::Checksum);
    }
    let hi = hex_val(line[star + 1]).ok_or(ParseError::Checksum)?;
    let lo = hex_val(line[star + 2]).ok_or(ParseError::Checksum)?;
    let body = &line[1..star];
    if xor_checksum(body) != (hi << 4) | lo {
        return Err(ParseError::Checksum);
    }
    Ok(body)
}

fn trim(mut s: &[u8]) -> &[u8] {
    while let [b' ' | b'\t' | b'\r', rest @ ..] = s {
        s = rest;
    }
    while let [rest @ .., b' ' | b'\t' | b'\r'] = s {
        s = rest;
    }
    s
}

/// Exact decimal → integer units of 10^-4: `-12.5` → -125000. At most 4 decimals,
/// at most 12 integer digits; anything else is a syntax error.
pub fn parse_counts(s: &[u8]) -> Result<i64, ParseError> {
    let s = trim(s);
    let (neg, digits) = match s.first() {
        Some(b'-') => (true, &s[1..]),
        Some(b'+') => (false, &s[1..]),
        _ => (false, s),
    };
    let mut int_part: i64 = 0;
    let mut frac: i64 = 0;
    let mut frac_digits = 0u32;
    let mut n_int = 0;
    let mut seen_dot = false;
    for &b in digits {
        match b {
            b'0'..=b'9' if !seen_dot => {
                n_int += 1;
                if n_int > 12 {
                    return Err(ParseError::Range);
                }
                int_part = int_part * 10 + i64::from(b - b'0');
            }
            b'0'..=b'9' => {
                frac_digits += 1;
                if frac_digits > 4 {
                    return Err(ParseError::Syntax);
                }
                frac = frac * 10 + i64::from(b - b'0');
            }
            b'.' if !seen_dot => seen_dot = true,
            _ => return Err(ParseError::Syntax),
        }
    }
    if n_int == 0 && frac_digits == 0 {
        return Err(ParseError::Syntax);
    }
    let v = int_part * 10_000 + frac * 10i64.pow(4 - frac_digits);
    Ok(if neg { -v } else { v })
}

/// Plausible range of a total-field reading (nT): outside it the line is rejected.
pub const SCALAR_MIN_NT: i64 = 15_000;
pub const SCALAR_MAX_NT: i64 = 110_000;

/// Scalar magnetometer line → exact reading.
pub fn parse_scalar(line: &[u8]) -> Result<MagCounts, ParseError> {
    let mut s = trim(line);
    if let [b'$', rest @ ..] = s {
        s = rest;
    }
    let field = s.split(|&b| b == b',').next().unwrap_or(&[]);
    let c = parse_counts(field)?;
    if !(SCALAR_MIN_NT * 10_000..=SCALAR_MAX_NT * 10_000).contains(&c) {
        return Err(ParseError::Range);
    }
    Ok(MagCounts(c))
}

/// Largest fluxgate component accepted (nT).
pub const FLUX_MAX_NT: i64 = 100_000;

/// Fluxgate ASCII line → body-frame vector (nT).
pub fn parse_flux(line: &[u8]) -> Result<[f32; 3], ParseError> {
    let mut out = [0f32; 3];
    let mut it = trim(line).split(|&b| b == b',');
    for v in out.iter_mut() {
        let c = parse_counts(it.next().ok_or(ParseError::Syntax)?)?;
        if c.abs() > FLUX_MAX_NT * 10_000 {
            return Err(ParseError::Range);
        }
        // via f64 so the host and the board round identically
        *v = (c as f64 / 10_000.0) as f32;
    }
    if it.next().is_some() {
        return Err(ParseError::Syntax);
    }
    Ok(out)
}

/// A decoded NMEA sentence (the fields the aligner needs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Nmea {
    Gga {
        time_s: f64,
        lat_deg: f64,
        lon_deg: f64,
        alt_msl_m: f32,
        fix: u8,
    },
    Rmc {
        time_s: f64,
        valid: bool,
        lat_deg: f64,
        lon_deg: f64,
        speed_mps: f32,
        track_deg: f32,
    },
    Vtg {
        speed_mps: f32,
        track_deg: f32,
    },
    /// Valid checksum, sentence not used (GSA, GSV...).
    Other,
}

const KNOT_MPS: f64 = 1852.0 / 3600.0;

fn parse_f64(s: &[u8]) -> Result<f64, ParseError> {
    Ok(parse_counts(s)? as f64 / 10_000.0)
}

fn parse_time(s: &[u8]) -> Result<f64, ParseError> {
    if s.len() < 6 || !s[..6].iter().all(u8::is_ascii_digit) {
        return Err(ParseError::Syntax);
    }
    let d = |i: usize| f64::from(s[i] - b'0');
    let (h, m) = (d(0) * 10.0 + d(1), d(2) * 10.0 + d(3));
    let sec = parse_f64(&s[4..])?;
    if h >= 24.0 || m >= 60.0 || sec >= 61.0 {
        return Err(ParseError::Range);
    }
    Ok(h * 3600.0 + m * 60.0 + sec)
}

/// `ddmm.mmmm` / `dddmm.mmmm` + hemisphere → signed degrees.
fn parse_latlon(v: &[u8], hemi: &[u8], deg_digits: usize) -> Result<f64, ParseError> {
    if v.len() < deg_digits + 2 || !v[..deg_digits].iter().all(u8::is_ascii_digit) {
        return Err(ParseError::Syntax);
    }
    let deg = v[..deg_digits]
        .iter()
        .fold(0.0, |a, &b| a * 10.0 + f64::from(b - b'0'));
    let min = parse_f64(&v[deg_digits..])?;
    if min >= 60.0 || deg > if deg_digits == 2 { 90.0 } else { 180.0 } {
        return Err(ParseError::Range);
    }
    let x = deg + min / 60.0;
    match hemi {
        b"N" | b"E" => Ok(x),
        b"S" | b"W" => Ok(-x),
        _ => Err(ParseError::Syntax),
    }
}

fn opt_f64(s: &[u8]) -> Result<f64, ParseError> {
    if s.is_empty() {
        Ok(f64::NAN)
    } else {
        parse_f64(s)
    }
}

/// One NMEA line (checksum required).
pub fn parse_nmea(line: &[u8]) -> Result<Nmea, ParseError> {
    let body = checked_body(line)?;
    let mut f: [&[u8]; 16] = [&[]; 16];
    let mut n = 0;
    for part in body.split(|&b| b == b',') {
        if n < f.len() {
            f[n] = part;
            n += 1;
        }
    }
    let id = f[0];
    if id.len() != 5 || !matches!(&id[..2], b"GP" | b"GN" | b"GL" | b"GA") {
        return Err(ParseError::Unsupported);
    }
    match &id[2..] {
        b"GGA" if n >= 10 => {
            let fix = match f[6] {
                [d @ b'0'..=b'9'] => d - b'0',
                _ => return Err(ParseError::Syntax),
            };
            let (lat, lon) = if fix == 0 && f[2].is_empty() {
                (f64::NAN, f64::NAN)
            } else {
                (parse_latlon(f[2], f[3], 2)?, parse_latlon(f[4], f[5], 3)?)
            };
            Ok(Nmea::Gga {
                time_s: parse_time(f[1])?,
                lat_deg: lat,
                lon_deg: lon,
                alt_msl_m: opt_f64(f[9])? as f32,
                fix,
            })
        }
        b"RMC" if n >= 9 => {
            let valid = f[2] == b"A";
            let (lat, lon) = if f[3].is_empty() {
                (f64::NAN, f64::NAN)
            } else {
                (parse_latlon(f[3], f[4], 2)?, parse_latlon(f[5], f[6], 3)?)
            };
            Ok(Nmea::Rmc {
                time_s: parse_time(f[1])?,
                valid,
                lat_deg: lat,
                lon_deg: lon,
                speed_mps: (opt_f64(f[7])? * KNOT_MPS) as f32,
                track_deg: opt_f64(f[8])? as f32,
            })
        }
        b"VTG" if n >= 8 => Ok(Nmea::Vtg {
            track_deg: opt_f64(f[1])? as f32,
            speed_mps: (opt_f64(f[5])? * KNOT_MPS) as f32,
        }),
        b"GGA" | b"RMC" | b"VTG" => Err(ParseError::Syntax),
        _ => Ok(Nmea::Other),
    }
}

/// A fixed-size text buffer implementing `core::fmt::Write`; overflow is an error, not a panic.
pub struct TextBuf<const N: usize> {
    buf: [u8; N],
    len: usize,
}

impl<const N: usize> Default for TextBuf<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> TextBuf<N> {
    pub const fn new() -> Self {
        Self {
            buf: [0; N],
            len: 0,
        }
    }
    pub fn as_bytes(&self) -> &[u8] {
        &self.buf[..self.len]
    }
    pub fn clear(&mut self) {
        self.len = 0;
    }
}

impl<const N: usize> core::fmt::Write for TextBuf<N> {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        let end = self.len + s.len();
        if end > N {
            return Err(core::fmt::Error);
        }
        self.buf[self.len..end].copy_from_slice(s.as_bytes());
        self.len = end;
        Ok(())
    }
}

/// A line to send: `$<body>*HH\r\n`.
pub type Line = TextBuf<200>;

/// Wraps `body` (already in `out`, starting after a `$`) with the checksum and CRLF.
/// Returns false if the line did not fit.
pub fn finish_sentence<const N: usize>(out: &mut TextBuf<N>) -> bool {
    use core::fmt::Write;
    let cs = xor_checksum(out.as_bytes().get(1..).unwrap_or(&[]));
    write!(out, "*{cs:02X}\r\n").is_ok()
}

/// Writes an exact reading as a decimal with 4 places.
pub fn write_counts<W: core::fmt::Write>(w: &mut W, c: MagCounts) -> core::fmt::Result {
    let sign = if c.0 < 0 { "-" } else { "" };
    let a = c.0.unsigned_abs();
    write!(w, "{sign}{}.{:04}", a / 10_000, a % 10_000)
}

fn write_f32<W: core::fmt::Write>(w: &mut W, v: f32) -> core::fmt::Result {
    if v.is_finite() {
        write!(w, "{v:.4}")
    } else {
        Ok(())
    }
}

/// One output record: exactly one per scalar sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Record {
    pub seq: u32,
    pub t_s: f64,
    pub mag: Option<MagCounts>,
    pub interference_nt: f32,
    pub compensated: Option<MagCounts>,
    pub anomaly_nt: f32,
    pub innovation_nt: f32,
    pub flags: Flags,
}

pub fn encode_record(r: &Record, out: &mut Line) -> bool {
    use core::fmt::Write;
    out.clear();
    let mut f = || -> core::fmt::Result {
        write!(out, "$MCREC,{},{:.4},", r.seq, r.t_s)?;
        if let Some(m) = r.mag {
            write_counts(out, m)?;
        }
        out.write_str(",")?;
        write_f32(out, r.interference_nt)?;
        out.write_str(",")?;
        if let Some(c) = r.compensated {
            write_counts(out, c)?;
        }
        out.write_str(",")?;
        write_f32(out, r.anomaly_nt)?;
        out.write_str(",")?;
        write_f32(out, r.innovation_nt)?;
        write!(out, ",{:04X}", r.flags.0)
    };
    f().is_ok() && finish_sentence(out)
}

/// Host side (hil-tests, monitor): `$MCREC` line → record. `None` if malformed.
pub fn decode_record(line: &[u8]) -> Option<Record> {
    let body = checked_body(line).ok()?;
    let s = core::str::from_utf8(body).ok()?;
    let mut it = s.split(',');
    if it.next()? != "MCREC" {
        return None;
    }
    let seq = it.next()?.parse().ok()?;
    let t_s = it.next()?.parse().ok()?;
    let opt_counts = |s: &str| {
        if s.is_empty() {
            Ok(None)
        } else {
            parse_counts(s.as_bytes()).map(|c| Some(MagCounts(c)))
        }
    };
    let opt_f32 = |s: &str| {
        if s.is_empty() {
            Some(f32::NAN)
        } else {
            s.parse().ok()
        }
    };
    let mag = opt_counts(it.next()?).ok()?;
    let interference_nt = opt_f32(it.next()?)?;
    let compensated = opt_counts(it.next()?).ok()?;
    let anomaly_nt = opt_f32(it.next()?)?;
    let innovation_nt = opt_f32(it.next()?)?;
    let flags = Flags(u16::from_str_radix(it.next()?, 16).ok()?);
    if it.next().is_some() {
        return None;
    }
    Some(Record {
        seq,
        t_s,
        mag,
        interference_nt,
        compensated,
        anomaly_nt,
        innovation_nt,
        flags,
    })
}

/// Operating mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Estimate the deviation coefficients (calibration pattern).
    Calibrate,
    /// Apply the stored coefficients; field states keep running.
    Survey,
}

/// Largest coefficient magnitude accepted by `SETC` (dimensionless/nT; generous bound).
pub const COEF_ABS_MAX: f32 = 1.0e6;

/// A well-formed command.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Command {
    /// `PING` → `$MCACK,PING`
    Ping,
    /// `STATUS` → `$MCACK,STATUS,mode,seq,err_scalar,err_flux,err_gps,err_cmd`
    Status,
    /// `MODE,CAL|SURVEY`
    Mode(Mode),
    /// `GETC,i` → `$MCACK,GETC,i,value`
    GetCoef { index: u16 },
    /// `SETC,i,value`
    SetCoef { index: u16, value: f32 },
    /// `SAVE`: write the coefficients to flash (blob with version and CRC).
    Save,
    /// `LOAD`: read the coefficients back from flash.
    Load,
    /// `FLUSH`: end of stream, emit the records still held for the centred derivative.
    Flush,
}

/// Why a command was rejected (the reason word in `$MCERR`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CmdError {
    Checksum,
    Syntax,
    Unknown,
    Bounds,
    Overflow,
    Busy,
    Storage,
}

impl CmdError {
    pub const fn word(self) -> &'static str {
        match self {
            CmdError::Checksum => "CHECKSUM",
            CmdError::Syntax => "SYNTAX",
            CmdError::Unknown => "UNKNOWN",
            CmdError::Bounds => "BOUNDS",
            CmdError::Overflow => "OVERFLOW",
            CmdError::Busy => "BUSY",
            CmdError::Storage => "STORAGE",
        }
    }
}

/// Parses a command line; `n_coef` bounds the coefficient index.
pub fn parse_command(line: &[u8], n_coef: usize) -> Result<Command, CmdError> {
    let body = checked_body(line).map_err(|e| match e {
        ParseError::Checksum => CmdError::Checksum,
        _ => CmdError::Syntax,
    })?;
    let s = core::str::from_utf8(body).map_err(|_| CmdError::Syntax)?;
    let mut it = s.split(',');
    if it.next() != Some("MCCMD") {
        return Err(CmdError::Unknown);
    }
    let name = it.next().ok_or(CmdError::Syntax)?;
    let mut arg = || it.next().ok_or(CmdError::Syntax);
    let index = |a: &str| -> Result<u16, CmdError> {
        let i: u16 = a.parse().map_err(|_| CmdError::Syntax)?;
        if usize::from(i) >= n_coef {
            Err(CmdError::Bounds)
        } else {
            Ok(i)
        }
    };
    let cmd = match name {
        "PING" => Command::Ping,
        "STATUS" => Command::Status,
        "SAVE" => Command::Save,
        "LOAD" => Command::Load,
        "FLUSH" => Command::Flush,
        "MODE" => match arg()? {
            "CAL" => Command::Mode(Mode::Calibrate),
            "SURVEY" => Command::Mode(Mode::Survey),
            _ => return Err(CmdError::Bounds),
        },
        "GETC" => Command::GetCoef {
            index: index(arg()?)?,
        },
        "SETC" => {
            let index = index(arg()?)?;
            let value: f32 = arg()?.parse().map_err(|_| CmdError::Syntax)?;
            if !value.is_finite() || value.abs() > COEF_ABS_MAX {
                return Err(CmdError::Bounds);
            }
            Command::SetCoef { index, value }
        }
        _ => return Err(CmdError::Unknown),
    };
    if it.next().is_some() {
        return Err(CmdError::Syntax);
    }
    Ok(cmd)
}

/// `$<body>*HH\r\n` for a command body such as `MCCMD,MODE,SURVEY` (host side).
pub fn sentence(body: &str, out: &mut Line) -> bool {
    use core::fmt::Write;
    out.clear();
    write!(out, "${body}").is_ok() && finish_sentence(out)
}

/// Coefficient blob stored in flash: `"MCCF"`, format version u16, count u16, count × f32
/// (little endian), CRC-32 (IEEE) of everything before it.
pub const BLOB_MAGIC: [u8; 4] = *b"MCCF";
pub const BLOB_VERSION: u16 = 1;

pub fn crc32(data: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in data {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = (crc >> 1) ^ (0xEDB8_8320 & (crc & 1).wrapping_neg());
        }
    }
    !crc
}

/// Encodes the blob into `out`; returns its length or `None` if `out` is too small.
pub fn encode_blob(coefs: &[f32], out: &mut [u8]) -> Option<usize> {
    let n = 8 + 4 * coefs.len() + 4;
    if out.len() < n || coefs.len() > usize::from(u16::MAX) {
        return None;
    }
    out[..4].copy_from_slice(&BLOB_MAGIC);
    out[4..6].copy_from_slice(&BLOB_VERSION.to_le_bytes());
    out[6..8].copy_from_slice(&(coefs.len() as u16).to_le_bytes());
    for (i, c) in coefs.iter().enumerate() {
        out[8 + 4 * i..12 + 4 * i].copy_from_slice(&c.to_le_bytes());
    }
    let crc = crc32(&out[..n - 4]);
    out[n - 4..n].copy_from_slice(&crc.to_le_bytes());
    Some(n)
}

/// Decodes a blob into `coefs` (its count must equal `coefs.len()`).
pub fn decode_blob(data: &[u8], coefs: &mut [f32]) -> Result<(), ParseError> {
    if data.len() < 12 || data[..4] != BLOB_MAGIC {
        return Err(ParseError::Syntax);
    }
    let u16_at = |i: usize| u16::from_le_bytes([data[i], data[i + 1]]);
    if u16_at(4) != BLOB_VERSION {
        return Err(ParseError::Unsupported);
    }
    let count = usize::from(u16_at(6));
    let n = 8 + 4 * count + 4;
    if count != coefs.len() || data.len() < n {
        return Err(ParseError::Range);
    }
    let crc = u32::from_le_bytes([data[n - 4], data[n - 3], data[n - 2], data[n - 1]]);
    if crc32(&data[..n - 4]) != crc {
        return Err(ParseError::Checksum);
    }
    for (i, c) in coefs.iter_mut().enumerate() {
        let o = 8 + 4 * i;
        *c = f32::from_le_bytes([data[o], data[o + 1], data[o + 2], data[o + 3]]);
    }
    Ok(())
}
