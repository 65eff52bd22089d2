//! Command protocol on the output port, and the coefficient blob stored in flash.
//!
//! Commands (one line each, checksum mandatory: NMEA `*HH` XOR so an operator can type
//! them with any NMEA tool, or `*HHHH` CRC-16/CCITT as used by the records):
//! ```text
//! $MCCMD,MODE,SURVEY*HH    $MCCMD,MODE,CAL*HH      $MCCMD,STATUS*HH
//! $MCCMD,GETCOEF*HH        $MCCMD,GETCOEF,3*HH     $MCCMD,SETCOEF,3,-1.25E-2*HH
//! $MCCMD,SAVE*HH           $MCCMD,RESET*HH         $MCCMD,FLUSH*HH
//! $MCCMD,GETFLUX*HH        $MCCMD,GETFLUX,9*HH     $MCCMD,SETFLUX,9,312.5*HH
//! $MCCMD,GETLAG*HH         $MCCMD,SETLAG,2.05E-1*HH
//! $MCCMD,GETFTEMP*HH       $MCCMD,GETFTEMP,4*HH    $MCCMD,SETFTEMP,1,4.0E-1*HH
//! $MCCMD,FACTORY,ERASE*HH
//! $MCCMD,GETCOEF,2,ALL*HH  $MCCMD,GETCOEF,2,3*HH   $MCCMD,SETCOEF,2,3,-1.25E-2*HH
//! ```
//! With several magnetometers (`multi_scalar`) `GETCOEF`/`SETCOEF` address a sensor
//! 0–2 as their first argument when they have one more; the forms without it are sensor
//! 0's, as they always were (a single-sensor board's files and tools keep working).
//! `GETFLUX`/`SETFLUX` address the fluxgate's scalar calibration (`fluxcal`), 12 values:
//! the matrix row by row (0–8), then the bias in nT (9–11). `GETLAG`/`SETLAG` the scalar's
//! delay τ in seconds (`lag`, 0 – [`MAX_LAG_S`]): the board pairs each scalar sample with
//! the fluxgate at t − τ (`lag_line`). `GETFTEMP`/`SETFTEMP` the fluxgate's temperature
//! drift (`fluxtemp`, [`FLUX_TEMP_LEN`] values): T_ref (°C), b (nT/°C) ×3, s (1/°C) ×3.
//! Replies (CRC-16, like records): `$MCACK,<CMD>[,<values>]*HHHH` and
//! `$MCERR,<code>,<TEXT>*HHHH`.

use super::common::{
    crc16_ccitt, crc32, fields, hex_val, parse_float_field, parse_hex_u32, parse_u32, xor_checksum,
    Cursor,
};
pub use super::fluxgate::FLUX_TEMP_LEN;
use super::lag_line::MAX_LAG_S;
use crate::model::TermKind;

/// Longest command line.
pub const MAX_COMMAND_LEN: usize = 96;
/// Coefficients must satisfy |v| < this.
pub const MAX_COEF_ABS: f32 = 1.0e6;
/// Values of the fluxgate's scalar calibration: 3×3 matrix row-major, then 3 biases (nT).
pub const FLUX_CAL_LEN: usize = 12;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    Survey,
    Cal,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Command {
    Mode(Mode),
    Status,
    /// One coefficient, or all when `None`.
    GetCoef(Option<u16>),
    SetCoef {
        index: u16,
        value: f32,
    },
    Save,
    Reset,
    /// Emit pending records now.
    Flush,
    /// One value of the fluxgate calibration, or all 12 when `None`.
    GetFlux(Option<u16>),
    SetFlux {
        index: u16,
        value: f32,
    },
    /// The scalar's delay τ (s).
    GetLag,
    SetLag(f32),
    /// The fluxgate's temperature drift: [`FLUX_TEMP_LEN`] values.
    GetFluxTemp(Option<u16>),
    SetFluxTemp {
        index: u16,
        value: f32,
    },
    /// `RAW,ON` / `RAW,OFF`: a `$MCRAW` line per scalar sample besides its record
    /// (`protocol::raw`).
    Raw(bool),
    /// `FACTORY,ERASE`: erase the store and return to the boot defaults (the argument makes
    /// it hard to send by accident).
    FactoryReset,
    /// `GETCOEF,<sensor>,<index>|ALL`: sensor 1 or 2 of a counter line (sensor 0 is
    /// [`Command::GetCoef`]).
    GetSensorCoef {
        sensor: u8,
        index: Option<u16>,
    },
    /// `SETCOEF,<sensor>,<index>,<value>`, sensor 1 or 2 (0 is [`Command::SetCoef`]).
    SetSensorCoef {
        sensor: u8,
        index: u16,
        value: f32,
    },
}

/// Sensors `GETCOEF`/`SETCOEF` address (the counter line's channels).
pub const MAX_SENSORS: usize = crate::protocol::multi_scalar::MAX_CHANNELS;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CommandError {
    /// Not `$MCCMD,...*hh`.
    Framing,
    BadChecksum,
    UnknownCommand,
    /// Missing, extra or unparseable argument.
    BadArgument,
    IndexOutOfBounds,
    /// Not finite or |v| ≥ 1e6.
    ValueOutOfBounds,
    Overlong,
}

impl CommandError {
    /// Numeric code sent in `$MCERR`.
    pub fn code(self) -> u8 {
        match self {
            CommandError::Framing => 1,
            CommandError::BadChecksum => 2,
            CommandError::UnknownCommand => 3,
            CommandError::BadArgument => 4,
            CommandError::IndexOutOfBounds => 5,
            CommandError::ValueOutOfBounds => 6,
            CommandError::Overlong => 7,
        }
    }
    pub fn text(self) -> &'static str {
        match self {
            CommandError::Framing => "FRAMING",
            CommandError::BadChecksum => "CHECKSUM",
            CommandError::UnknownCommand => "UNKNOWN",
            CommandError::BadArgument => "BADARG",
            CommandError::IndexOutOfBounds => "INDEX",
            CommandError::ValueOutOfBounds => "VALUE",
            CommandError::Overlong => "OVERLONG",
        }
    }

    /// The error with this `$MCERR` code.
    pub fn from_code(code: u8) -> Option<Self> {
        [
            CommandError::Framing,
            CommandError::BadChecksum,
            CommandError::UnknownCommand,
            CommandError::BadArgument,
            CommandError::IndexOutOfBounds,
            CommandError::ValueOutOfBounds,
            CommandError::Overlong,
        ]
        .into_iter()
        .find(|e| e.code() == code)
    }

    /// The errors a well-formed command gets only when its bytes were damaged on the line (a
    /// byte lost or changed, two lines run together): it was not executed, and resending it
    /// is the remedy. The others are the board's verdict on the command itself.
    pub fn is_transport(self) -> bool {
        matches!(
            self,
            CommandError::Framing | CommandError::BadChecksum | CommandError::Overlong
        )
    }
}

/// A reply line, as the sender of a command reads it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reply<'a> {
    /// `$MCACK,<CMD>[,<values>]`: the text after `MCACK,` (without the CRC).
    Ack(&'a [u8]),
    /// `$MCERR,<code>,<TEXT>` for the command line received.
    Refused(CommandError),
    /// `$MCERR` the board raised on its own account (`8,STORAGE`: the flash write failed).
    BoardError(&'a [u8]),
}

/// Classifies an output line; `None` for records and for replies whose CRC fails.
pub fn parse_reply(line: &[u8]) -> Option<Reply<'_>> {
    let payload = check_reply(line)?;
    if let Some(ack) = payload.strip_prefix(b"MCACK,") {
        return Some(Reply::Ack(ack));
    }
    let err = payload.strip_prefix(b"MCERR,")?;
    let code = err.split(|&b| b == b',').next().and_then(parse_u32);
    Some(
        match code
            .and_then(|c| u8::try_from(c).ok())
            .and_then(CommandError::from_code)
        {
            Some(e) => Reply::Refused(e),
            None => Reply::BoardError(err),
        },
    )
}

/// A command line's payload between `$` and `*`, once its framing, length and checksum
/// (2 hex digits XOR or 4 hex digits CRC-16) hold; trailing CR, LF and spaces are ignored.
fn checked_payload(line: &[u8]) -> Result<&[u8], CommandError> {
    let mut line = line;
    while let [rest @ .., b'\r' | b'\n' | b' '] = line {
        line = rest;
    }
    if line.len() > MAX_COMMAND_LEN {
        return Err(CommandError::Overlong);
    }
    let body = line.strip_prefix(b"$").ok_or(CommandError::Framing)?;
    let star = body
        .iter()
        .rposition(|&b| b == b'*')
        .ok_or(CommandError::BadChecksum)?;
    let (payload, cs) = (&body[..star], &body[star + 1..]);
    let ok = match cs.len() {
        2 => match (hex_val(cs[0]), hex_val(cs[1])) {
            (Some(h), Some(l)) => (h << 4 | l) == xor_checksum(payload),
            _ => false,
        },
        4 => parse_hex_u32(cs).is_some_and(|v| v as u16 == crc16_ccitt(payload)),
        _ => false,
    };
    if ok {
        Ok(payload)
    } else {
        Err(CommandError::BadChecksum)
    }
}

/// Parses one command line; `n_coef` is the model's state count (index bound).
pub fn parse_command(line: &[u8], n_coef: usize) -> Result<Command, CommandError> {
    let mut it = fields(checked_payload(line)?);
    if it.next() != Some(b"MCCMD") {
        return Err(CommandError::Framing);
    }
    let name = it.next().ok_or(CommandError::UnknownCommand)?;
    let a1 = it.next();
    let a2 = it.next();
    let a3 = it.next();
    if it.next().is_some() {
        return Err(CommandError::BadArgument);
    }
    let index_below = |s: &[u8], n: usize| -> Result<u16, CommandError> {
        let i = parse_u32(s).ok_or(CommandError::BadArgument)?;
        if (i as usize) < n {
            Ok(i as u16)
        } else {
            Err(CommandError::IndexOutOfBounds)
        }
    };
    let value = |v: &[u8]| -> Result<f32, CommandError> {
        if v.is_empty() {
            return Err(CommandError::BadArgument);
        }
        let value = parse_float_field(v).map_err(|_| CommandError::BadArgument)? as f32;
        if !value.is_finite() || libm::fabsf(value) >= MAX_COEF_ABS {
            return Err(CommandError::ValueOutOfBounds);
        }
        Ok(value)
    };
    let sensor_form = match (name, a3) {
        (b"SETCOEF", Some(_)) | (b"GETCOEF", None) if a2.is_some() => true,
        (_, Some(_)) => return Err(CommandError::BadArgument),
        _ => false,
    };
    if sensor_form {
        let sensor = index_below(a1.unwrap_or_default(), MAX_SENSORS)? as u8;
        let index = match a2 {
            Some(b"ALL") if a3.is_none() => None,
            Some(i) => Some(index_below(i, n_coef)?),
            None => return Err(CommandError::BadArgument),
        };
        return match (index, a3) {
            (Some(index), Some(v)) => {
                let value = value(v)?;
                Ok(match sensor {
                    0 => Command::SetCoef { index, value },
                    sensor => Command::SetSensorCoef {
                        sensor,
                        index,
                        value,
                    },
                })
            }
            (None, Some(_)) => Err(CommandError::BadArgument),
            (index, None) => Ok(match sensor {
                0 => Command::GetCoef(index),
                sensor => Command::GetSensorCoef { sensor, index },
            }),
        };
    }
    // `GET<X>[,i]` and `SET<X>,i,v` over a table of `n` values.
    let get = |n: usize, make: fn(Option<u16>) -> Command| match (a1, a2) {
        (None, None) => Ok(make(None)),
        (Some(i), None) => Ok(make(Some(index_below(i, n)?))),
        _ => Err(CommandError::BadArgument),
    };
    let set = |n: usize, make: fn(u16, f32) -> Command| match (a1, a2) {
        (Some(i), Some(v)) => {
            let index = index_below(i, n)?;
            Ok(make(index, value(v)?))
        }
        _ => Err(CommandError::BadArgument),
    };
    let none = |c: Command| {
        if a1.is_none() {
            Ok(c)
        } else {
            Err(CommandError::BadArgument)
        }
    };
    match name {
        b"MODE" => match (a1, a2) {
            (Some(b"SURVEY"), None) => Ok(Command::Mode(Mode::Survey)),
            (Some(b"CAL"), None) => Ok(Command::Mode(Mode::Cal)),
            _ => Err(CommandError::BadArgument),
        },
        b"STATUS" => none(Command::Status),
        b"SAVE" => none(Command::Save),
        b"RESET" => none(Command::Reset),
        b"FLUSH" => none(Command::Flush),
        b"FACTORY" => match (a1, a2) {
            (Some(b"ERASE"), None) => Ok(Command::FactoryReset),
            _ => Err(CommandError::BadArgument),
        },
        b"RAW" => match (a1, a2) {
            (Some(b"ON"), None) => Ok(Command::Raw(true)),
            (Some(b"OFF"), None) => Ok(Command::Raw(false)),
            _ => Err(CommandError::BadArgument),
        },
        b"GETCOEF" => get(n_coef, Command::GetCoef),
        b"SETCOEF" => set(n_coef, |index, value| Command::SetCoef { index, value }),
        b"GETFLUX" => get(FLUX_CAL_LEN, Command::GetFlux),
        b"GETLAG" => none(Command::GetLag),
        b"GETFTEMP" => get(FLUX_TEMP_LEN, Command::GetFluxTemp),
        b"SETFTEMP" => set(FLUX_TEMP_LEN, |index, value| Command::SetFluxTemp {
            index,
            value,
        }),
        b"SETLAG" => match (a1, a2) {
            (Some(v), None) => {
                let v = value(v)?;
                if (0.0..=MAX_LAG_S).contains(&v) {
                    Ok(Command::SetLag(v))
                } else {
                    Err(CommandError::ValueOutOfBounds)
                }
            }
            _ => Err(CommandError::BadArgument),
        },
        b"SETFLUX" => set(FLUX_CAL_LEN, |index, value| Command::SetFlux {
            index,
            value,
        }),
        _ => Err(CommandError::UnknownCommand),
    }
}

/// Writes a command line (host monitor, tests) with the XOR checksum.
pub fn encode_command(cmd: &Command, out: &mut [u8]) -> Option<usize> {
    use super::common::BufferFull;
    fn get(c: &mut Cursor, name: &[u8], i: Option<u16>) -> Result<(), BufferFull> {
        c.bytes(name)?;
        match i {
            Some(i) => {
                c.byte(b',')?;
                c.u64(i as u64)
            }
            None => Ok(()),
        }
    }
    fn set(c: &mut Cursor, name: &[u8], index: u16, value: f32) -> Result<(), BufferFull> {
        get(c, name, Some(index))?;
        c.byte(b',')?;
        c.sci(value as f64)
    }
    let mut c = Cursor::new(out);
    (|| {
        c.bytes(b"$MCCMD,")?;
        match *cmd {
            Command::Mode(Mode::Survey) => c.bytes(b"MODE,SURVEY")?,
            Command::Mode(Mode::Cal) => c.bytes(b"MODE,CAL")?,
            Command::Status => c.bytes(b"STATUS")?,
            Command::GetCoef(i) => get(&mut c, b"GETCOEF", i)?,
            Command::SetCoef { index, value } => set(&mut c, b"SETCOEF", index, value)?,
            Command::Save => c.bytes(b"SAVE")?,
            Command::Reset => c.bytes(b"RESET")?,
            Command::Flush => c.bytes(b"FLUSH")?,
            Command::FactoryReset => c.bytes(b"FACTORY,ERASE")?,
            Command::Raw(true) => c.bytes(b"RAW,ON")?,
            Command::Raw(false) => c.bytes(b"RAW,OFF")?,
            Command::GetFlux(i) => get(&mut c, b"GETFLUX", i)?,
            Command::SetFlux { index, value } => set(&mut c, b"SETFLUX", index, value)?,
            Command::GetLag => c.bytes(b"GETLAG")?,
            Command::GetFluxTemp(i) => get(&mut c, b"GETFTEMP", i)?,
            Command::SetFluxTemp { index, value } => set(&mut c, b"SETFTEMP", index, value)?,
            Command::SetLag(v) => {
                c.bytes(b"SETLAG,")?;
                c.sci(v as f64)?
            }
            Command::GetSensorCoef { sensor, index } => {
                get(&mut c, b"GETCOEF", Some(sensor.into()))?;
                match index {
                    Some(i) => get(&mut c, b"", Some(i))?,
                    None => c.bytes(b",ALL")?,
                }
            }
            Command::SetSensorCoef {
                sensor,
                index,
                value,
            } => {
                get(&mut c, b"SETCOEF", Some(sensor.into()))?;
                set(&mut c, b"", index, value)?
            }
        }
        let x = xor_checksum(&c.written()[1..]);
        c.byte(b'*')?;
        c.hex_u8(x)?;
        c.bytes(b"\r\n")
    })()
    .ok()?;
    Some(c.pos())
}

/// `$MCACK,<name>[,<field>...]*HHHH\r\n`; fields are written as given (ASCII).
pub fn encode_ack(name: &[u8], args: &[&[u8]], out: &mut [u8]) -> Option<usize> {
    let mut c = Cursor::new(out);
    (|| {
        c.bytes(b"$MCACK,")?;
        c.bytes(name)?;
        for a in args {
            c.byte(b',')?;
            c.bytes(a)?;
        }
        super::common::finish_crc(&mut c)
    })()
    .ok()?;
    Some(c.pos())
}

/// `$MCACK,GETCOEF,<index>,<value>*HHHH\r\n`, value with 9 significant digits.
pub fn encode_ack_coef(index: u16, value: f32, out: &mut [u8]) -> Option<usize> {
    encode_ack_indexed(b"GETCOEF", index, value, out)
}

/// `$MCACK,<name>,<index>,<value>*HHHH\r\n` (`GETCOEF`, `GETFLUX`, `SETFLUX`…).
pub fn encode_ack_indexed(name: &[u8], index: u16, value: f32, out: &mut [u8]) -> Option<usize> {
    let mut c = Cursor::new(out);
    (|| {
        c.bytes(b"$MCACK,")?;
        c.bytes(name)?;
        c.byte(b',')?;
        c.u64(index as u64)?;
        c.byte(b',')?;
        c.sci(value as f64)?;
        super::common::finish_crc(&mut c)
    })()
    .ok()?;
    Some(c.pos())
}

/// `$MCERR,<code>,<TEXT>*HHHH\r\n`.
pub fn encode_error(e: CommandError, out: &mut [u8]) -> Option<usize> {
    let mut c = Cursor::new(out);
    (|| {
        c.bytes(b"$MCERR,")?;
        c.u64(e.code() as u64)?;
        c.byte(b',')?;
        c.bytes(e.text().as_bytes())?;
        super::common::finish_crc(&mut c)
    })()
    .ok()?;
    Some(c.pos())
}

/// A decoded `$MCACK`/`$MCERR` reply: the payload after `$` (CRC checked).
pub fn check_reply(line: &[u8]) -> Option<&[u8]> {
    super::record::check_crc_line(line, b"MC").ok()
}

/// Byte-at-a-time command line reader.
#[derive(Clone, Debug)]
pub struct CommandReader {
    buf: [u8; MAX_COMMAND_LEN],
    len: usize,
    overlong: bool,
    pub n_coef: usize,
    pub ok: u32,
    pub errors: u32,
}

impl CommandReader {
    pub const fn new(n_coef: usize) -> Self {
        Self {
            buf: [0; MAX_COMMAND_LEN],
            len: 0,
            overlong: false,
            n_coef,
            ok: 0,
            errors: 0,
        }
    }

    pub fn push(&mut self, b: u8) -> Option<Result<Command, CommandError>> {
        if b == b'\r' || b == b'\n' {
            if self.len == 0 && !self.overlong {
                return None;
            }
            let r = if self.overlong {
                Err(CommandError::Overlong)
            } else {
                parse_command(&self.buf[..self.len], self.n_coef)
            };
            self.len = 0;
            self.overlong = false;
            if r.is_ok() {
                self.ok = self.ok.saturating_add(1);
            } else {
                self.errors = self.errors.saturating_add(1);
            }
            return Some(r);
        }
        if self.len == MAX_COMMAND_LEN {
            self.overlong = true;
        } else {
            self.buf[self.len] = b;
            self.len += 1;
        }
        None
    }
}

// ---------------------------------------------------------------------------------------
// Coefficient blob (flash):
//   0  4   magic "MCCF"
//   4  2   format version, u16 LE (= 1)
//   6  2   coefficient count n, u16 LE
//   8  4   model id/hash, u32 LE (e.g. FNV-1a of the model spec "tl16+field")
//  12  4n  coefficients, f32 LE
//  12+4n 4 CRC-32 (IEEE) of bytes 0..12+4n, u32 LE

pub const BLOB_MAGIC: [u8; 4] = *b"MCCF";
pub const BLOB_VERSION: u16 = 1;
pub const BLOB_HEADER_LEN: usize = 12;

/// Blob size for `n` coefficients.
pub const fn blob_len(n: usize) -> usize {
    BLOB_HEADER_LEN + 4 * n + 4
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BlobError {
    BufferTooSmall,
    Truncated,
    BadMagic,
    BadCrc,
    WrongVersion(u16),
    WrongCount { expected: u16, found: u16 },
    ModelMismatch { expected: u32, found: u32 },
    NonFinite { index: u16 },
}

/// Id of the second blob in the coefficient store: the fluxgate calibration
/// (`FLUX_CAL_LEN` values), written right after the model's blob. A store without it (an
/// older firmware's) loads as "no calibration".
pub fn flux_blob_id() -> u32 {
    model_hash(TermKind::FluxCal.name().as_bytes())
}

/// Id of the third blob: the scalar's delay τ (s, one value), after the fluxgate
/// calibration's. A store without it (an older firmware's) loads as τ = 0.
pub fn lag_blob_id() -> u32 {
    model_hash(TermKind::Lag.name().as_bytes())
}

/// Id of the fourth blob: the fluxgate's temperature drift ([`FLUX_TEMP_LEN`] values),
/// after the delay's. A store without it (an older firmware's) loads as no correction.
pub fn flux_temp_blob_id() -> u32 {
    model_hash(TermKind::FluxTemp.name().as_bytes())
}

/// FNV-1a 32-bit: a stable model id from the model's spec string.
pub fn model_hash(spec: &[u8]) -> u32 {
    spec.iter().fold(0x811C_9DC5u32, |h, &b| {
        (h ^ b as u32).wrapping_mul(0x0100_0193)
    })
}

pub fn encode_blob(model_hash: u32, coef: &[f32], out: &mut [u8]) -> Result<usize, BlobError> {
    let n = coef.len();
    if n > u16::MAX as usize {
        return Err(BlobError::WrongCount {
            expected: u16::MAX,
            found: u16::MAX,
        });
    }
    let len = blob_len(n);
    let out = out.get_mut(..len).ok_or(BlobError::BufferTooSmall)?;
    out[0..4].copy_from_slice(&BLOB_MAGIC);
    out[4..6].copy_from_slice(&BLOB_VERSION.to_le_bytes());
    out[6..8].copy_from_slice(&(n as u16).to_le_bytes());
    out[8..12].copy_from_slice(&model_hash.to_le_bytes());
    for (i, c) in coef.iter().enumerate() {
        out[12 + 4 * i..16 + 4 * i].copy_from_slice(&c.to_le_bytes());
    }
    let crc = crc32(&out[..len - 4]);
    out[len - 4..].copy_from_slice(&crc.to_le_bytes());
    Ok(len)
}

/// Decodes a blob into `coef_out` (its length is the expected count) after checking
/// magic, CRC, version, model hash, count and finiteness; `coef_out` is unchanged on error.
pub fn decode_blob(data: &[u8], model_hash: u32, coef_out: &mut [f32]) -> Result<(), BlobError> {
    if data.len() < BLOB_HEADER_LEN + 4 {
        return Err(BlobError::Truncated);
    }
    if data[0..4] != BLOB_MAGIC {
        return Err(BlobError::BadMagic);
    }
    let n = u16::from_le_bytes([data[6], data[7]]);
    let len = blob_len(n as usize);
    if data.len() < len {
        return Err(BlobError::Truncated);
    }
    let stored = u32::from_le_bytes([data[len - 4], data[len - 3], data[len - 2], data[len - 1]]);
    if crc32(&data[..len - 4]) != stored {
        return Err(BlobError::BadCrc);
    }
    let version = u16::from_le_bytes([data[4], data[5]]);
    if version != BLOB_VERSION {
        return Err(BlobError::WrongVersion(version));
    }
    let found = u32::from_le_bytes([data[8], data[9], data[10], data[11]]);
    if found != model_hash {
        return Err(BlobError::ModelMismatch {
            expected: model_hash,
            found,
        });
    }
    if n as usize != coef_out.len() {
        return Err(BlobError::WrongCount {
            expected: coef_out.len().min(u16::MAX as usize) as u16,
            found: n,
        });
    }
    let coef = |i: usize| {
        let o = 12 + 4 * i;
        f32::from_le_bytes([data[o], data[o + 1], data[o + 2], data[o + 3]])
    };
    // Validate everything before writing, so `coef_out` is untouched on any error.
    if let Some(i) = (0..n as usize).find(|&i| !coef(i).is_finite()) {
        return Err(BlobError::NonFinite { index: i as u16 });
    }
    for (i, c) in coef_out.iter_mut().enumerate() {
        *c = coef(i);
    }
    Ok(())
}
