//! Raw sample line: what post-flight calibration needs, one per scalar sample as the
//! aligner made it, so one flight's output log is enough to calibrate after landing
//! (`RAW,ON`; off by default: it more than doubles the port's load).
//!
//! ```text
//! $MCRAW,<k>,<t_s>,<mag_nt>,<flux_x_nt>,<flux_y_nt>,<flux_z_nt>,<lat_deg>,<lon_deg>,<alt_m>,<speed_mps>,<flags>*<CRC16>\r\n
//! ```
//! `k` is the sample's number since (re)start; the `$MCREC` of the same sample follows
//! `half_width` samples later (the centred derivative), with its own `seq`. The fluxgate is
//! in the body frame with the board's fluxgate corrections applied (`SETFLUX`,
//! `SETFTEMP`) and the scalar is delayed by `SETLAG`, exactly what the filter was given:
//! coefficients calibrated on this log are for the board as it was set. `mag` exact from
//! its counts; flux, altitude and speed 4 decimals, latitude/longitude 8 (≈ 1 mm); NaN →
//! empty field; framing and CRC as `$MCREC` ([`super::record`]).

use super::common::{fields, finish_crc, parse_float_field, BufferFull, Cursor};
use super::record::{check_crc_line, counts_field, flags_field, parse_seq, RecordError};
use crate::epoch::AlignedSample;
use crate::flags::Flags;
use crate::units::MagCounts;

/// Buffer large enough for any raw line.
pub const MAX_RAW_LEN: usize = 224;

/// Data fields after `MCRAW`.
const FIELDS: usize = 11;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RawSample {
    /// Sample number since (re)start (wraps).
    pub k: u32,
    pub t_s: f64,
    /// Absolute scalar reading (exact); `None` when missing.
    pub mag: Option<MagCounts>,
    pub flux_nt: [f32; 3],
    pub lat_deg: f64,
    pub lon_deg: f64,
    pub alt_m: f32,
    pub ground_speed_mps: f32,
    pub flags: Flags,
}

impl RawSample {
    /// Sample `k` as the aligner made it.
    pub fn of(k: u32, s: &AlignedSample) -> Self {
        Self {
            k,
            t_s: s.t_s,
            mag: s.mag,
            flux_nt: s.flux_nt,
            lat_deg: s.lat_deg,
            lon_deg: s.lon_deg,
            alt_m: s.alt_m,
            ground_speed_mps: s.ground_speed_mps,
            flags: s.flags,
        }
    }
}

/// Writes one raw line with `\r\n`; returns the length.
pub fn encode_raw(r: &RawSample, out: &mut [u8]) -> Result<usize, RecordError> {
    let mut c = Cursor::new(out);
    let res = (|| {
        c.bytes(b"$MCRAW,")?;
        c.u64(u64::from(r.k))?;
        c.byte(b',')?;
        c.float(r.t_s, 6)?;
        c.byte(b',')?;
        if let Some(m) = r.mag {
            c.fixed(m.0, 4)?;
        }
        encode_motion(&mut c, r)?;
        c.byte(b',')?;
        c.hex_u16(r.flags.0)?;
        finish_crc(&mut c)
    })();
    res.map_err(|_| RecordError::BufferFull)?;
    Ok(c.pos())
}

/// `,<flux_x>,<flux_y>,<flux_z>,<lat>,<lon>,<alt>,<speed>` of a raw line (`$MCRAW`,
/// `$MCMRAW`): flux, height and speed 4 decimals, latitude/longitude 8.
pub(crate) fn encode_motion(c: &mut Cursor, r: &RawSample) -> Result<(), BufferFull> {
    for v in r.flux_nt {
        c.byte(b',')?;
        c.float(f64::from(v), 4)?;
    }
    for (v, scale) in [(r.lat_deg, 8), (r.lon_deg, 8)] {
        c.byte(b',')?;
        c.float(v, scale)?;
    }
    for v in [r.alt_m, r.ground_speed_mps] {
        c.byte(b',')?;
        c.float(f64::from(v), 4)?;
    }
    Ok(())
}

/// Parses a line written by [`encode_raw`].
pub fn decode_raw(line: &[u8]) -> Result<RawSample, RecordError> {
    let payload = check_crc_line(line, b"MCRAW,")?;
    let mut f = [&b""[..]; FIELDS];
    let mut n = 0;
    for x in fields(payload).skip(1) {
        if n == FIELDS {
            return Err(RecordError::FieldCount);
        }
        f[n] = x;
        n += 1;
    }
    if n != FIELDS {
        return Err(RecordError::FieldCount);
    }
    let k = parse_seq(f[0]).ok_or(RecordError::BadField(0))?;
    let flags = flags_field(f[10], 10)?;
    let t_s = parse_float_field(f[1]).map_err(|_| RecordError::BadField(1))?;
    decode_motion(&f, 3, k, t_s, counts_field(f[2], 2)?, flags)
}

/// The sample whose motion fields ([`encode_motion`]) start at field `o` of `f`: fluxgate
/// (3), latitude, longitude, height, ground speed; `k`, `t_s`, `mag` and `flags` as read
/// before them.
pub(crate) fn decode_motion(
    f: &[&[u8]],
    o: usize,
    k: u32,
    t_s: f64,
    mag: Option<MagCounts>,
    flags: Flags,
) -> Result<RawSample, RecordError> {
    let fl = |i: usize| parse_float_field(f[i]).map_err(|_| RecordError::BadField(i as u8));
    Ok(RawSample {
        k,
        t_s,
        mag,
        flux_nt: [fl(o)? as f32, fl(o + 1)? as f32, fl(o + 2)? as f32],
        lat_deg: fl(o + 3)?,
        lon_deg: fl(o + 4)?,
        alt_m: fl(o + 5)? as f32,
        ground_speed_mps: fl(o + 6)? as f32,
        flags,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> RawSample {
        RawSample {
            k: 4_294_967_295,
            t_s: 43_210.123_456,
            mag: Some(MagCounts(543_219_876)),
            flux_nt: [-18_123.5, 4_321.5, 47_001.25],
            lat_deg: -45.123_456_78,
            lon_deg: 170.987_654_32,
            alt_m: 562.25,
            ground_speed_mps: 61.5,
            flags: Flags(0x0104),
        }
    }

    #[test]
    fn a_raw_line_reads_back_exactly_what_was_written() {
        let mut buf = [0u8; MAX_RAW_LEN];
        let n = encode_raw(&sample(), &mut buf).unwrap();
        let back = decode_raw(&buf[..n]).unwrap();
        assert_eq!(back.k, sample().k);
        assert_eq!(back.mag, sample().mag);
        assert_eq!(back.flags, sample().flags);
        assert!((back.t_s - sample().t_s).abs() < 1e-9);
        assert!((back.lat_deg - sample().lat_deg).abs() < 1e-9);
        assert!((back.lon_deg - sample().lon_deg).abs() < 1e-9);
        for (a, b) in back.flux_nt.iter().zip(sample().flux_nt) {
            assert!((a - b).abs() < 1e-3, "{a} {b}");
        }
        assert_eq!(back.alt_m, 562.25);
        assert_eq!(back.ground_speed_mps, 61.5);
    }

    #[test]
    fn missing_values_are_empty_fields_and_read_back_missing() {
        let r = RawSample {
            mag: None,
            lat_deg: f64::NAN,
            lon_deg: f64::NAN,
            alt_m: f32::NAN,
            ground_speed_mps: f32::NAN,
            ..sample()
        };
        let mut buf = [0u8; MAX_RAW_LEN];
        let n = encode_raw(&r, &mut buf).unwrap();
        let back = decode_raw(&buf[..n]).unwrap();
        assert_eq!(back.mag, None);
        assert!(back.lat_deg.is_nan() && back.lon_deg.is_nan());
        assert!(back.alt_m.is_nan() && back.ground_speed_mps.is_nan());
    }

    #[test]
    fn a_changed_byte_or_a_record_line_is_refused() {
        let mut buf = [0u8; MAX_RAW_LEN];
        let n = encode_raw(&sample(), &mut buf).unwrap();
        let mut bad = buf;
        bad[12] ^= 0x01;
        assert!(matches!(
            decode_raw(&bad[..n]),
            Err(RecordError::Crc { .. } | RecordError::Framing)
        ));
        assert_eq!(
            decode_raw(b"$MCREC,1,2.0,,,,,,,0000*0000\r\n"),
            Err(RecordError::Framing)
        );
    }
}
