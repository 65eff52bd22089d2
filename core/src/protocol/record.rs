//! Output record: one line per scalar sample on the output port.
//!
//! ```text
//! $MCREC,<seq>,<t_s>,<mag_nt>,<interf_nt>,<comp_nt>,<anom_nt>,<innov_nt>,<sigma_nt>,<flags>*<CRC16>\r\n
//! ```
//! `sigma_nt` is the record's own stated 1σ bound on its interference, so an operator (or a
//! logger) can judge a record without the host; empty while `NOT_CONVERGED`. Streams from
//! firmware before it (8 data fields) still decode, with the bound unknown (NaN).
//! `t_s` 6 decimals; nT values 4 decimals; `mag` and `comp` printed exactly from their
//! integer counts; other values rounded from f32/f64. NaN → empty field; ±inf → `INF`/`-INF`;
//! values too large for 4 fixed decimals → `<9 digits>E<exp>`. `flags` is 4 hex digits.
//! The checksum is CRC-16/CCITT-FALSE (4 hex digits) over the bytes between `$` and `*`:
//! unlike NMEA's XOR it catches swapped and doubled characters, which matter for a data
//! logger recording the stream as is.

use super::common::{
    crc16_ccitt, fields, finish_crc, parse_decimal, parse_float_field, parse_hex_u32, Cursor,
};
use crate::flags::Flags;
use crate::units::MagCounts;

/// Buffer large enough for any record.
pub const MAX_RECORD_LEN: usize = 192;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Record {
    pub seq: u32,
    pub t_s: f64,
    /// Absolute scalar reading (exact); `None` when missing.
    pub mag: Option<MagCounts>,
    pub interference_nt: f32,
    /// `mag − round(interference)` in counts, exact; `None` when either is missing.
    pub compensated: Option<MagCounts>,
    pub anomaly_nt: f32,
    pub innovation_nt: f32,
    /// The record's stated 1σ bound on `interference_nt`
    /// ([`crate::compensator::Output::interference_sigma_nt`]); NaN when unknown.
    pub sigma_nt: f32,
    pub flags: Flags,
}

impl Record {
    /// Forms the compensated value exactly from the absolute reading and the interference.
    pub fn compensate(mag: Option<MagCounts>, interference_nt: f32) -> Option<MagCounts> {
        let m = mag?;
        interference_nt
            .is_finite()
            .then(|| m.minus_nt(interference_nt))
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RecordError {
    /// Output buffer too small.
    BufferFull,
    /// Not `$MCREC,...*hhhh`.
    Framing,
    Crc {
        received: u16,
        computed: u16,
    },
    /// Not 9 data fields (or the 8 of a stream written before `sigma_nt`).
    FieldCount,
    /// Field `n` (0 = seq) unparseable.
    BadField(u8),
}

fn opt_counts(c: &mut Cursor, m: Option<MagCounts>) -> Result<(), super::common::BufferFull> {
    match m {
        Some(m) => c.fixed(m.0, 4),
        None => Ok(()),
    }
}

/// Writes one record with `\r\n`; returns the length.
pub fn encode_record(r: &Record, out: &mut [u8]) -> Result<usize, RecordError> {
    let mut c = Cursor::new(out);
    let res = (|| {
        c.bytes(b"$MCREC,")?;
        c.u64(r.seq as u64)?;
        c.byte(b',')?;
        c.float(r.t_s, 6)?;
        c.byte(b',')?;
        opt_counts(&mut c, r.mag)?;
        c.byte(b',')?;
        c.float(r.interference_nt as f64, 4)?;
        c.byte(b',')?;
        opt_counts(&mut c, r.compensated)?;
        c.byte(b',')?;
        c.float(r.anomaly_nt as f64, 4)?;
        c.byte(b',')?;
        c.float(r.innovation_nt as f64, 4)?;
        c.byte(b',')?;
        c.float(r.sigma_nt as f64, 4)?;
        c.byte(b',')?;
        c.hex_u16(r.flags.0)?;
        finish_crc(&mut c)
    })();
    res.map_err(|_| RecordError::BufferFull)?;
    Ok(c.pos())
}

/// Checks framing and CRC of a `$TYPE,...*HHHH` line; returns the payload after `$`.
pub(crate) fn check_crc_line<'a>(line: &'a [u8], prefix: &[u8]) -> Result<&'a [u8], RecordError> {
    let mut line = line;
    while let [rest @ .., b'\r' | b'\n'] = line {
        line = rest;
    }
    let body = line.strip_prefix(b"$").ok_or(RecordError::Framing)?;
    if !body.starts_with(prefix) {
        return Err(RecordError::Framing);
    }
    let star = body
        .iter()
        .rposition(|&b| b == b'*')
        .ok_or(RecordError::Framing)?;
    let cs = &body[star + 1..];
    if cs.len() != 4 {
        return Err(RecordError::Framing);
    }
    let received = parse_hex_u32(cs).ok_or(RecordError::Framing)? as u16;
    let computed = crc16_ccitt(&body[..star]);
    if received != computed {
        return Err(RecordError::Crc { received, computed });
    }
    Ok(&body[..star])
}

/// A record's flags field `i`: exactly 4 hex digits.
pub(crate) fn flags_field(s: &[u8], i: u8) -> Result<Flags, RecordError> {
    match s {
        s if s.len() == 4 => parse_hex_u32(s)
            .map(|v| Flags(v as u16))
            .ok_or(RecordError::BadField(i)),
        _ => Err(RecordError::BadField(i)),
    }
}

pub(crate) fn counts_field(s: &[u8], i: u8) -> Result<Option<MagCounts>, RecordError> {
    if s.is_empty() {
        return Ok(None);
    }
    let d = parse_decimal(s).map_err(|_| RecordError::BadField(i))?;
    if d.scale > 4 {
        return Err(RecordError::BadField(i));
    }
    // At most 18 significant digits, as the decimal parser reads them: a value the
    // encoder would write back with more (e.g. `544073709551616` nT) is refused here
    // rather than decoded into a record that cannot be re-encoded decodably (fuzzer find).
    d.rescale(4)
        .filter(|v| v.unsigned_abs() < 1_000_000_000_000_000_000)
        .map(|v| Some(MagCounts(v)))
        .ok_or(RecordError::BadField(i))
}

/// A sequence number: any u32, all 10 digits of it.
pub(crate) fn parse_seq(s: &[u8]) -> Option<u32> {
    super::common::parse_u32(s).or_else(|| {
        let d = parse_decimal(s).ok()?;
        (d.scale == 0)
            .then_some(d.mantissa)
            .and_then(|m| u32::try_from(m).ok())
    })
}

/// Parses a record line written by [`encode_record`].
pub fn decode_record(line: &[u8]) -> Result<Record, RecordError> {
    let payload = check_crc_line(line, b"MCREC,")?;
    let mut f = [&b""[..]; 9];
    let mut n = 0;
    for x in fields(payload).skip(1) {
        if n == 9 {
            return Err(RecordError::FieldCount);
        }
        f[n] = x;
        n += 1;
    }
    // 8 fields: a stream from firmware before `sigma_nt`; its flags sit where sigma does now.
    let (sigma_field, flags_at) = match n {
        9 => (Some(7), 8),
        8 => (None, 7),
        _ => return Err(RecordError::FieldCount),
    };
    let fl = |i: usize| parse_float_field(f[i]).map_err(|_| RecordError::BadField(i as u8));
    let seq = parse_seq(f[0]).ok_or(RecordError::BadField(0))?;
    let flags = flags_field(f[flags_at], flags_at as u8)?;
    let sigma_nt = match sigma_field {
        Some(i) => fl(i)? as f32,
        None => f32::NAN,
    };
    Ok(Record {
        seq,
        t_s: fl(1)?,
        mag: counts_field(f[2], 2)?,
        interference_nt: fl(3)? as f32,
        compensated: counts_field(f[4], 4)?,
        anomaly_nt: fl(5)? as f32,
        innovation_nt: fl(6)? as f32,
        sigma_nt,
        flags,
    })
}
