//! NMEA 0183 reader for GGA, RMC, GLL, GNS, VTG and GST.
//!
//! Written here rather than using the `nmea` crate (0.7, evaluated): it parses numeric
//! fields with `nom::number::complete::float` (f32: altitude, speed, track lose digits),
//! pulls in `nom` and `chrono` (time as `NaiveTime`), keeps a merged fix state we do not
//! want, and has no byte-at-a-time framer or per-kind error counters. What the compensator
//! needs is small: exact digits → f64, typed counted errors, and a framer that resyncs.
//!
//! Framing: a sentence starts at `$` and ends at `\r` or `\n` (`\r\n` per the standard;
//! a lone `\n` or `\r` is tolerated). A `$` inside a sentence abandons it (error
//! `Interrupted`) and starts a new one, so the reader resynchronises on the next `$`.
//! Length: at most [`MAX_SENTENCE_LEN`] bytes from `$` to the end of the checksum. The
//! standard says 82 including `\r\n`; real receivers exceed it (u-blox GSV/GNS with many
//! fields, proprietary sentences), so 120 is allowed.
//! Checksum: mandatory. The standard allows sentences without one, but every receiver in
//! the gpsd regression logs sends it, and an unchecked position is worse than none.

use super::common::{fields, hex_val, parse_decimal, xor_checksum, Decimal, POW10};

/// Longest accepted sentence, `$` to the last checksum digit.
pub const MAX_SENTENCE_LEN: usize = 120;

const KNOT_MPS: f64 = 1852.0 / 3600.0;
const KMH_MPS: f64 = 1.0 / 3.6;

/// Which field of a sentence was invalid (for the error report).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Field {
    Time,
    Date,
    Latitude,
    Longitude,
    Quality,
    Satellites,
    Hdop,
    Altitude,
    GeoidSeparation,
    Status,
    Speed,
    Track,
    Mode,
    Sigma,
    /// NMEA 4.1 navigational status (GNS field 13).
    NavStatus,
}

/// Why a sentence was rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NmeaError {
    /// `*hh` present but differs from the XOR of the body.
    Checksum { received: u8, computed: u8 },
    /// No `*hh` (or not two hex digits).
    MissingChecksum,
    /// More than [`MAX_SENTENCE_LEN`] bytes before the line end.
    Overlong,
    /// A `$` arrived before the line end of the previous sentence.
    Interrupted,
    /// A byte outside printable ASCII inside a sentence.
    BadCharacter,
    /// The address field is not `TTSSS` (or a known proprietary form).
    BadAddress,
    /// Too few fields for the sentence type.
    MissingField(Field),
    /// A field with bad syntax or out of range (lat > 90, minutes ≥ 60, ...).
    InvalidField(Field),
}

/// Time of day, UTC.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UtcTime {
    /// Seconds since midnight, exact from the digits (to f64 rounding).
    pub seconds_of_day_s: f64,
}

/// Calendar date from RMC (two-digit year as sent: 2000 + yy assumed for yy < 80).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Date {
    pub year: u16,
    pub month: u8,
    pub day: u8,
}

/// Talker: the two letters after `$`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Talker(pub [u8; 2]);

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gga {
    pub talker: Talker,
    pub time: Option<UtcTime>,
    pub lat_deg: Option<f64>,
    pub lon_deg: Option<f64>,
    /// 0 invalid, 1 GPS, 2 DGPS, 4 RTK fixed, 5 RTK float, 6 dead reckoning...
    pub fix_quality: Option<u8>,
    pub satellites: Option<u8>,
    pub hdop: Option<f32>,
    /// Antenna altitude above mean sea level (m).
    pub alt_msl_m: Option<f64>,
    /// Geoid separation: ellipsoid height = MSL + this (m).
    pub geoid_sep_m: Option<f64>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rmc {
    pub talker: Talker,
    pub time: Option<UtcTime>,
    /// `true` for status `A` (valid), `false` for `V`.
    pub valid: bool,
    pub lat_deg: Option<f64>,
    pub lon_deg: Option<f64>,
    pub speed_mps: Option<f64>,
    pub track_deg: Option<f64>,
    pub date: Option<Date>,
    /// NMEA 2.3 mode indicator: A autonomous, D differential, E estimated, N not valid, ...
    pub mode: Option<u8>,
}

/// Geographic position, latitude/longitude (GLL): a position with time and status but
/// no height, sent instead of or besides GGA by marine and many older receivers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gll {
    pub talker: Talker,
    pub lat_deg: Option<f64>,
    pub lon_deg: Option<f64>,
    /// Absent from NMEA 1.x sentences, which end after the longitude.
    pub time: Option<UtcTime>,
    /// `true` for status `A`; `V` or a missing status (NMEA 1.x) is no fix.
    pub valid: bool,
    /// NMEA 2.3 mode indicator (A autonomous, D differential, E estimated, N not valid...).
    pub mode: Option<u8>,
}

impl Gll {
    /// Status `A`, mode not `N`, and both coordinates present.
    pub fn has_fix(&self) -> bool {
        self.valid && self.mode != Some(b'N') && self.lat_deg.is_some() && self.lon_deg.is_some()
    }
}

/// Longest GNS mode string kept: one letter per constellation (NMEA 4.11 defines six:
/// GPS, GLONASS, Galileo, BeiDou, QZSS, NavIC); two spare.
pub const MAX_GNS_MODES: usize = 8;

/// GNS mode indicator: one letter per constellation, in the standard's order (GPS,
/// GLONASS, Galileo, BeiDou, QZSS, NavIC). `N` = that constellation is not used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GnsModes {
    chars: [u8; MAX_GNS_MODES],
    len: u8,
}

impl GnsModes {
    pub fn as_bytes(&self) -> &[u8] {
        &self.chars[..self.len as usize]
    }
    /// At least one constellation contributes (any letter other than `N`).
    pub fn any_fix(&self) -> bool {
        self.as_bytes().iter().any(|&c| c != b'N')
    }
}

/// GNSS fix data (GNS): the multi-constellation GGA of NMEA 3.0+.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gns {
    pub talker: Talker,
    pub time: Option<UtcTime>,
    pub lat_deg: Option<f64>,
    pub lon_deg: Option<f64>,
    pub modes: GnsModes,
    pub satellites: Option<u8>,
    pub hdop: Option<f32>,
    /// Antenna altitude above mean sea level (m).
    pub alt_msl_m: Option<f64>,
    pub geoid_sep_m: Option<f64>,
    /// NMEA 4.1 navigational status (S safe, C caution, U unsafe, V not valid).
    pub nav_status: Option<u8>,
}

impl Gns {
    /// Some constellation in use, the navigational status not `V`, both coordinates present.
    pub fn has_fix(&self) -> bool {
        self.modes.any_fix()
            && self.nav_status != Some(b'V')
            && self.lat_deg.is_some()
            && self.lon_deg.is_some()
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Vtg {
    pub talker: Talker,
    pub track_deg: Option<f64>,
    /// From the knots field, else from the km/h field.
    pub speed_mps: Option<f64>,
    /// From the km/h field alone (m/s).
    pub speed_kmh_mps: Option<f64>,
    pub mode: Option<u8>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gst {
    pub talker: Talker,
    pub time: Option<UtcTime>,
    pub rms_m: Option<f64>,
    pub sigma_major_m: Option<f64>,
    pub sigma_minor_m: Option<f64>,
    pub orientation_deg: Option<f64>,
    pub sigma_lat_m: Option<f64>,
    pub sigma_lon_m: Option<f64>,
    pub sigma_alt_m: Option<f64>,
}

/// A sentence that passed framing and checksum.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Sentence {
    Gga(Gga),
    Rmc(Rmc),
    Gll(Gll),
    Gns(Gns),
    Vtg(Vtg),
    Gst(Gst),
    /// Valid checksum, type we do not decode (GSV, GSA, proprietary...): counted, not an error.
    Unsupported {
        address: [u8; 5],
    },
}

impl Sentence {
    /// Three-letter type (`GGA`...), or the address for unsupported ones.
    pub fn kind(&self) -> &str {
        match self {
            Sentence::Gga(_) => "GGA",
            Sentence::Rmc(_) => "RMC",
            Sentence::Gll(_) => "GLL",
            Sentence::Gns(_) => "GNS",
            Sentence::Vtg(_) => "VTG",
            Sentence::Gst(_) => "GST",
            Sentence::Unsupported { .. } => "unsupported",
        }
    }

    /// The position of a sentence that reports a valid fix (GGA quality > 0, RMC/GLL
    /// status `A`, GNS with a constellation in use; GLL/GNS mode `N` is no fix), else
    /// `None`. Speed and track are not positions: VTG gives `None`.
    pub fn fix(&self) -> Option<Fix> {
        let (time, lat, lon, alt) = match self {
            Sentence::Gga(g) if g.fix_quality.unwrap_or(0) > 0 => {
                (g.time, g.lat_deg, g.lon_deg, g.alt_msl_m)
            }
            Sentence::Rmc(r) if r.valid => (r.time, r.lat_deg, r.lon_deg, None),
            Sentence::Gll(g) if g.has_fix() => (g.time, g.lat_deg, g.lon_deg, None),
            Sentence::Gns(g) if g.has_fix() => (g.time, g.lat_deg, g.lon_deg, g.alt_msl_m),
            _ => return None,
        };
        Some(Fix {
            time,
            lat_deg: lat?,
            lon_deg: lon?,
            alt_msl_m: alt,
        })
    }

    /// GGA, RMC, GLL or GNS: a sentence that reports a position or its absence.
    pub fn is_position(&self) -> bool {
        matches!(
            self,
            Sentence::Gga(_) | Sentence::Rmc(_) | Sentence::Gll(_) | Sentence::Gns(_)
        )
    }
}

/// A valid position from any position sentence ([`Sentence::fix`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fix {
    pub time: Option<UtcTime>,
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// GGA/GNS only (m above mean sea level).
    pub alt_msl_m: Option<f64>,
}

/// Counters; every `$` that started a sentence ends in exactly one of
/// `ok + unsupported + checksum_errors + missing_checksum + overlong + interrupted +
/// bad_character + bad_address + invalid_fields`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NmeaStats {
    pub ok: u32,
    pub unsupported: u32,
    pub checksum_errors: u32,
    pub missing_checksum: u32,
    pub overlong: u32,
    pub interrupted: u32,
    pub bad_character: u32,
    pub bad_address: u32,
    pub invalid_fields: u32,
    /// Bytes outside any sentence other than CR/LF.
    pub garbage_bytes: u32,
}

impl NmeaStats {
    pub fn errors(&self) -> u32 {
        self.checksum_errors
            + self.missing_checksum
            + self.overlong
            + self.interrupted
            + self.bad_character
            + self.bad_address
            + self.invalid_fields
    }
    fn count(&mut self, r: &Result<Sentence, NmeaError>) {
        let c = match r {
            Ok(Sentence::Unsupported { .. }) => &mut self.unsupported,
            Ok(_) => &mut self.ok,
            Err(NmeaError::Checksum { .. }) => &mut self.checksum_errors,
            Err(NmeaError::MissingChecksum) => &mut self.missing_checksum,
            Err(NmeaError::Overlong) => &mut self.overlong,
            Err(NmeaError::Interrupted) => &mut self.interrupted,
            Err(NmeaError::BadCharacter) => &mut self.bad_character,
            Err(NmeaError::BadAddress) => &mut self.bad_address,
            Err(NmeaError::MissingField(_)) | Err(NmeaError::InvalidField(_)) => {
                &mut self.invalid_fields
            }
        };
        *c = c.saturating_add(1);
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    Idle,
    InSentence,
    /// After an overlong error: drop bytes to the line end.
    Skip,
}

/// Byte-at-a-time NMEA reader (fixed 120-byte buffer).
#[derive(Clone, Debug)]
pub struct NmeaReader {
    buf: [u8; MAX_SENTENCE_LEN],
    len: usize,
    state: State,
    pub stats: NmeaStats,
}

impl Default for NmeaReader {
    fn default() -> Self {
        Self::new()
    }
}

impl NmeaReader {
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_SENTENCE_LEN],
            len: 0,
            state: State::Idle,
            stats: NmeaStats {
                ok: 0,
                unsupported: 0,
                checksum_errors: 0,
                missing_checksum: 0,
                overlong: 0,
                interrupted: 0,
                bad_character: 0,
                bad_address: 0,
                invalid_fields: 0,
                garbage_bytes: 0,
            },
        }
    }

    /// True while a sentence has started and not yet ended (it will produce one result).
    pub fn in_sentence(&self) -> bool {
        self.state == State::InSentence
    }

    /// Feeds one byte; returns a result when a sentence ends (or is abandoned).
    pub fn push(&mut self, b: u8) -> Option<Result<Sentence, NmeaError>> {
        let r = self.step(b);
        if let Some(r) = &r {
            self.stats.count(r);
        }
        r
    }

    fn step(&mut self, b: u8) -> Option<Result<Sentence, NmeaError>> {
        match (self.state, b) {
            (State::InSentence, b'$') => {
                self.start();
                Some(Err(NmeaError::Interrupted))
            }
            (_, b'$') => {
                self.start();
                None
            }
            (State::InSentence, b'\r' | b'\n') => {
                self.state = State::Idle;
                Some(parse_sentence(&self.buf[..self.len]))
            }
            (State::InSentence, _) => {
                if self.len == MAX_SENTENCE_LEN {
                    self.state = State::Skip;
                    return Some(Err(NmeaError::Overlong));
                }
                self.buf[self.len] = b;
                self.len += 1;
                None
            }
            (State::Skip, b'\r' | b'\n') => {
                self.state = State::Idle;
                None
            }
            (State::Skip, _) => None,
            (State::Idle, b'\r' | b'\n') => None,
            (State::Idle, _) => {
                self.stats.garbage_bytes = self.stats.garbage_bytes.saturating_add(1);
                None
            }
        }
    }

    fn start(&mut self) {
        self.buf[0] = b'$';
        self.len = 1;
        self.state = State::InSentence;
    }
}

/// Parses one sentence from `$` to the checksum (trailing CR/LF allowed).
pub fn parse_sentence(line: &[u8]) -> Result<Sentence, NmeaError> {
    let mut line = line;
    while let [rest @ .., b'\r' | b'\n'] = line {
        line = rest;
    }
    if line.len() > MAX_SENTENCE_LEN {
        return Err(NmeaError::Overlong);
    }
    if line.iter().any(|&b| !(0x20..=0x7E).contains(&b)) {
        return Err(NmeaError::BadCharacter);
    }
    let body = match line {
        [b'$', body @ ..] => body,
        _ => return Err(NmeaError::BadAddress),
    };
    let star = body
        .iter()
        .rposition(|&b| b == b'*')
        .ok_or(NmeaError::MissingChecksum)?;
    let (payload, cs) = (&body[..star], &body[star + 1..]);
    let received = match cs {
        [h, l] => match (hex_val(*h), hex_val(*l)) {
            (Some(h), Some(l)) => (h << 4) | l,
            _ => return Err(NmeaError::MissingChecksum),
        },
        _ => return Err(NmeaError::MissingChecksum),
    };
    let computed = xor_checksum(payload);
    if computed != received {
        return Err(NmeaError::Checksum { received, computed });
    }
    let mut it = fields(payload);
    let address = it.next().unwrap_or(b"");
    let mut addr = [0u8; 5];
    if address.first() == Some(&b'P') {
        // Proprietary ($PGLOR, $PSTMC...): valid but not decoded.
        let n = address.len().min(5);
        addr[..n].copy_from_slice(&address[..n]);
        return Ok(Sentence::Unsupported { address: addr });
    }
    if address.len() != 5 || !address.iter().all(|b| b.is_ascii_uppercase()) {
        return Err(NmeaError::BadAddress);
    }
    addr.copy_from_slice(address);
    let talker = Talker([address[0], address[1]]);
    // GP GPS, GN multi-GNSS, GL GLONASS, GA Galileo, BD/GB BeiDou, QZ QZSS, GI NavIC.
    let known = matches!(
        &talker.0,
        b"GP" | b"GN" | b"GL" | b"GA" | b"BD" | b"GB" | b"QZ" | b"GQ" | b"GI"
    );
    if !known {
        return Ok(Sentence::Unsupported { address: addr });
    }
    let mut f = [&b""[..]; 20];
    let mut n = 0;
    for x in it {
        if n < f.len() {
            f[n] = x;
            n += 1;
        }
    }
    let f = &f[..n];
    match &address[2..] {
        b"GGA" => parse_gga(talker, f).map(Sentence::Gga),
        b"RMC" => parse_rmc(talker, f).map(Sentence::Rmc),
        b"GLL" => parse_gll(talker, f).map(Sentence::Gll),
        b"GNS" => parse_gns(talker, f).map(Sentence::Gns),
        b"VTG" => parse_vtg(talker, f).map(Sentence::Vtg),
        b"GST" => parse_gst(talker, f).map(Sentence::Gst),
        _ => Ok(Sentence::Unsupported { address: addr }),
    }
}

fn get<'a>(f: &[&'a [u8]], i: usize, which: Field) -> Result<&'a [u8], NmeaError> {
    f.get(i).copied().ok_or(NmeaError::MissingField(which))
}

/// Fields after the last one a receiver sent are treated as empty (older NMEA versions
/// end RMC/VTG before the mode field).
fn opt_get<'a>(f: &[&'a [u8]], i: usize) -> &'a [u8] {
    f.get(i).copied().unwrap_or(b"")
}

fn num(s: &[u8], which: Field) -> Result<Option<Decimal>, NmeaError> {
    if s.is_empty() {
        return Ok(None);
    }
    parse_decimal(s)
        .map(Some)
        .map_err(|_| NmeaError::InvalidField(which))
}

fn num_f64(s: &[u8], which: Field) -> Result<Option<f64>, NmeaError> {
    Ok(num(s, which)?.map(Decimal::to_f64))
}

fn nonneg_f64(s: &[u8], which: Field, max: f64) -> Result<Option<f64>, NmeaError> {
    match num_f64(s, which)? {
        Some(v) if !(0.0..=max).contains(&v) => Err(NmeaError::InvalidField(which)),
        v => Ok(v),
    }
}

fn two(s: &[u8]) -> Option<u32> {
    match s {
        [a, b] if a.is_ascii_digit() && b.is_ascii_digit() => {
            Some(((a - b'0') * 10 + (b - b'0')) as u32)
        }
        _ => None,
    }
}

/// `hhmmss[.sss]` → seconds of day, from the integer digits and an exactly-scaled fraction.
pub fn parse_time(s: &[u8]) -> Result<Option<UtcTime>, NmeaError> {
    if s.is_empty() {
        return Ok(None);
    }
    let bad = NmeaError::InvalidField(Field::Time);
    if s.len() < 6 {
        return Err(bad);
    }
    let h = two(&s[0..2]).ok_or(bad)?;
    let m = two(&s[2..4]).ok_or(bad)?;
    let sec = two(&s[4..6]).ok_or(bad)?;
    // 60 allowed for a leap second.
    if h > 23 || m > 59 || sec > 60 {
        return Err(bad);
    }
    let frac = match &s[6..] {
        [] => 0.0,
        [b'.', digits @ ..] => {
            if digits.is_empty() {
                0.0
            } else {
                let d = parse_decimal(digits).map_err(|_| bad)?;
                if d.scale != 0 || digits.len() > 9 || digits[0] == b'-' || digits[0] == b'+' {
                    return Err(bad);
                }
                d.mantissa as f64 / POW10[digits.len()] as f64
            }
        }
        _ => return Err(bad),
    };
    Ok(Some(UtcTime {
        seconds_of_day_s: (h * 3600 + m * 60 + sec) as f64 + frac,
    }))
}

/// `[d]ddmm.mmmm` + hemisphere → signed degrees. Minutes are kept as an exact integer
/// `mm·10^k + frac`, so the only rounding is one division and one addition (< 1e-13 deg).
pub fn parse_coord(value: &[u8], hemi: &[u8], is_lat: bool) -> Result<Option<f64>, NmeaError> {
    let which = if is_lat {
        Field::Latitude
    } else {
        Field::Longitude
    };
    let bad = NmeaError::InvalidField(which);
    if value.is_empty() && hemi.is_empty() {
        return Ok(None);
    }
    let sign = match (is_lat, hemi) {
        (true, b"N") | (false, b"E") => 1.0,
        (true, b"S") | (false, b"W") => -1.0,
        _ => return Err(bad),
    };
    if value.first().is_some_and(|&b| b == b'-' || b == b'+') {
        return Err(bad);
    }
    let d = parse_decimal(value).map_err(|_| bad)?;
    if d.int_digits < 3 || d.scale > 12 {
        return Err(bad);
    }
    let p = POW10[d.scale as usize];
    let int = d.mantissa / p;
    let frac = d.mantissa % p;
    let deg = int / 100;
    let min_scaled = (int % 100) * p + frac; // minutes × 10^scale, exact
    if min_scaled >= 60 * p {
        return Err(bad);
    }
    let v = deg as f64 + min_scaled as f64 / (60 * p) as f64;
    let limit = if is_lat { 90.0 } else { 180.0 };
    if v > limit {
        return Err(bad);
    }
    Ok(Some(sign * v))
}

fn small_u8(s: &[u8], which: Field) -> Result<Option<u8>, NmeaError> {
    if s.is_empty() {
        return Ok(None);
    }
    match super::common::parse_u32(s) {
        Some(v) if v <= 255 => Ok(Some(v as u8)),
        _ => Err(NmeaError::InvalidField(which)),
    }
}

fn mode_char(s: &[u8]) -> Result<Option<u8>, NmeaError> {
    match s {
        [] => Ok(None),
        [c] if c.is_ascii_uppercase() => Ok(Some(*c)),
        _ => Err(NmeaError::InvalidField(Field::Mode)),
    }
}

/// Antenna altitude (m above MSL): a receiver below the Dead Sea floor or above the
/// ionosphere is a corrupt field.
fn altitude(s: &[u8]) -> Result<Option<f64>, NmeaError> {
    let alt = num_f64(s, Field::Altitude)?;
    if alt.is_some_and(|a| !(-2000.0..=100_000.0).contains(&a)) {
        return Err(NmeaError::InvalidField(Field::Altitude));
    }
    Ok(alt)
}

fn parse_gga(talker: Talker, f: &[&[u8]]) -> Result<Gga, NmeaError> {
    // time,lat,N,lon,E,quality,sats,hdop,alt,M,sep,M,age,station
    let alt_unit = opt_get(f, 9);
    let sep_unit = opt_get(f, 11);
    if !(alt_unit.is_empty() || alt_unit == b"M") {
        return Err(NmeaError::InvalidField(Field::Altitude));
    }
    if !(sep_unit.is_empty() || sep_unit == b"M") {
        return Err(NmeaError::InvalidField(Field::GeoidSeparation));
    }
    let alt = altitude(get(f, 8, Field::Altitude)?)?;
    Ok(Gga {
        talker,
        time: parse_time(get(f, 0, Field::Time)?)?,
        lat_deg: parse_coord(
            get(f, 1, Field::Latitude)?,
            get(f, 2, Field::Latitude)?,
            true,
        )?,
        lon_deg: parse_coord(
            get(f, 3, Field::Longitude)?,
            get(f, 4, Field::Longitude)?,
            false,
        )?,
        fix_quality: small_u8(get(f, 5, Field::Quality)?, Field::Quality)?,
        satellites: small_u8(get(f, 6, Field::Satellites)?, Field::Satellites)?,
        hdop: nonneg_f64(get(f, 7, Field::Hdop)?, Field::Hdop, 1000.0)?.map(|v| v as f32),
        alt_msl_m: alt,
        geoid_sep_m: num_f64(opt_get(f, 10), Field::GeoidSeparation)?,
    })
}

fn parse_date(s: &[u8]) -> Result<Option<Date>, NmeaError> {
    if s.is_empty() {
        return Ok(None);
    }
    let bad = NmeaError::InvalidField(Field::Date);
    if s.len() != 6 {
        return Err(bad);
    }
    let d = two(&s[0..2]).ok_or(bad)?;
    let m = two(&s[2..4]).ok_or(bad)?;
    let y = two(&s[4..6]).ok_or(bad)?;
    if !(1..=31).contains(&d) || !(1..=12).contains(&m) {
        return Err(bad);
    }
    Ok(Some(Date {
        year: if y < 80 {
            2000 + y as u16
        } else {
            1900 + y as u16
        },
        month: m as u8,
        day: d as u8,
    }))
}

fn parse_rmc(talker: Talker, f: &[&[u8]]) -> Result<Rmc, NmeaError> {
    // time,status,lat,N,lon,E,speed_kn,track,date,magvar,E,mode[,navstatus]
    let valid = match get(f, 1, Field::Status)? {
        b"A" => true,
        b"V" | b"" => false,
        _ => return Err(NmeaError::InvalidField(Field::Status)),
    };
    Ok(Rmc {
        talker,
        time: parse_time(get(f, 0, Field::Time)?)?,
        valid,
        lat_deg: parse_coord(
            get(f, 2, Field::Latitude)?,
            get(f, 3, Field::Latitude)?,
            true,
        )?,
        lon_deg: parse_coord(
            get(f, 4, Field::Longitude)?,
            get(f, 5, Field::Longitude)?,
            false,
        )?,
        speed_mps: nonneg_f64(get(f, 6, Field::Speed)?, Field::Speed, 100_000.0)?
            .map(|k| k * KNOT_MPS),
        track_deg: nonneg_f64(get(f, 7, Field::Track)?, Field::Track, 360.0)?,
        date: parse_date(get(f, 8, Field::Date)?)?,
        mode: mode_char(opt_get(f, 11))?,
    })
}

fn parse_gll(talker: Talker, f: &[&[u8]]) -> Result<Gll, NmeaError> {
    // lat,N,lon,E[,time,status[,mode]]: NMEA 1.x stops after the longitude.
    let valid = match opt_get(f, 5) {
        b"A" => true,
        b"V" | b"" => false,
        _ => return Err(NmeaError::InvalidField(Field::Status)),
    };
    Ok(Gll {
        talker,
        lat_deg: parse_coord(
            get(f, 0, Field::Latitude)?,
            get(f, 1, Field::Latitude)?,
            true,
        )?,
        lon_deg: parse_coord(
            get(f, 2, Field::Longitude)?,
            get(f, 3, Field::Longitude)?,
            false,
        )?,
        time: parse_time(opt_get(f, 4))?,
        valid,
        mode: mode_char(opt_get(f, 6))?,
    })
}

fn parse_gns(talker: Talker, f: &[&[u8]]) -> Result<Gns, NmeaError> {
    // time,lat,N,lon,E,modes,sats,hdop,alt,sep,age,station[,navstatus]
    let m = get(f, 5, Field::Mode)?;
    if m.len() > MAX_GNS_MODES || !m.iter().all(|c| c.is_ascii_uppercase()) {
        return Err(NmeaError::InvalidField(Field::Mode));
    }
    let mut modes = GnsModes {
        chars: [0; MAX_GNS_MODES],
        len: m.len() as u8,
    };
    modes.chars[..m.len()].copy_from_slice(m);
    let nav_status = match opt_get(f, 12) {
        [] => None,
        [c @ (b'S' | b'C' | b'U' | b'V')] => Some(*c),
        _ => return Err(NmeaError::InvalidField(Field::NavStatus)),
    };
    Ok(Gns {
        talker,
        time: parse_time(get(f, 0, Field::Time)?)?,
        lat_deg: parse_coord(
            get(f, 1, Field::Latitude)?,
            get(f, 2, Field::Latitude)?,
            true,
        )?,
        lon_deg: parse_coord(
            get(f, 3, Field::Longitude)?,
            get(f, 4, Field::Longitude)?,
            false,
        )?,
        modes,
        satellites: small_u8(get(f, 6, Field::Satellites)?, Field::Satellites)?,
        hdop: nonneg_f64(get(f, 7, Field::Hdop)?, Field::Hdop, 1000.0)?.map(|v| v as f32),
        alt_msl_m: altitude(get(f, 8, Field::Altitude)?)?,
        geoid_sep_m: num_f64(opt_get(f, 9), Field::GeoidSeparation)?,
        nav_status,
    })
}

fn parse_vtg(talker: Talker, f: &[&[u8]]) -> Result<Vtg, NmeaError> {
    // NMEA ≥ 2.0: track,T,magtrack,M,knots,N,kmh,K[,mode]
    // NMEA 1.x:   track,magtrack,knots,kmh (no unit letters)
    let (track, kn, kmh, mode) = if opt_get(f, 1) == b"T" || f.len() >= 8 {
        (
            get(f, 0, Field::Track)?,
            get(f, 4, Field::Speed)?,
            get(f, 6, Field::Speed)?,
            opt_get(f, 8),
        )
    } else {
        (
            get(f, 0, Field::Track)?,
            get(f, 2, Field::Speed)?,
            get(f, 3, Field::Speed)?,
            &b""[..],
        )
    };
    let kmh_mps = nonneg_f64(kmh, Field::Speed, 200_000.0)?.map(|v| v * KMH_MPS);
    let kn_mps = nonneg_f64(kn, Field::Speed, 100_000.0)?.map(|v| v * KNOT_MPS);
    Ok(Vtg {
        talker,
        track_deg: nonneg_f64(track, Field::Track, 360.0)?,
        speed_mps: kn_mps.or(kmh_mps),
        speed_kmh_mps: kmh_mps,
        mode: mode_char(mode)?,
    })
}

fn parse_gst(talker: Talker, f: &[&[u8]]) -> Result<Gst, NmeaError> {
    // time,rms,major,minor,orient,lat,lon,alt
    let s = |i: usize| -> Result<Option<f64>, NmeaError> {
        nonneg_f64(get(f, i, Field::Sigma)?, Field::Sigma, 1.0e7)
    };
    Ok(Gst {
        talker,
        time: parse_time(get(f, 0, Field::Time)?)?,
        rms_m: s(1)?,
        sigma_major_m: s(2)?,
        sigma_minor_m: s(3)?,
        orientation_deg: nonneg_f64(get(f, 4, Field::Sigma)?, Field::Sigma, 360.0)?,
        sigma_lat_m: s(5)?,
        sigma_lon_m: s(6)?,
        sigma_alt_m: s(7)?,
    })
}
