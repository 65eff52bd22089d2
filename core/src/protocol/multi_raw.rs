//! Raw sample line of a board reading 2–3 scalar magnetometers on a counter line
//! (`multi_scalar`): every channel's reading, so one flight's log calibrates each sensor
//! after landing (`RAW,ON`). A single-sensor board keeps writing `$MCRAW` ([`super::raw`]),
//! byte for byte as before.
//!
//! ```text
//! $MCMRAW,<k>,<t_s>,<n>,{<mag_nt>,<flags>}×n,<flux_x_nt>,<flux_y_nt>,<flux_z_nt>,<lat_deg>,<lon_deg>,<alt_m>,<speed_mps>*<CRC16>\r\n
//! ```
//! As `$MCRAW`, but per channel the reading as that channel's compensator was given it
//! (exact from counts, empty when missing) and its flags (`MAG_MISSING`, `PARSE_ERROR`
//! are the channel's own; the rest the sample's). The host reads a log of these lines as
//! a several-sensor trace, `mag_1` … `mag_n` (docs/trace-format.md).

use super::common::{finish_crc, parse_float_field, Cursor};
use super::multi_record::channel_fields;
use super::multi_scalar::MAX_CHANNELS;
use super::raw::{decode_motion, encode_motion, encode_raw, RawSample};
use super::record::{counts_field, flags_field, parse_seq, RecordError};
use crate::flags::Flags;
use crate::units::MagCounts;

/// Buffer large enough for any multi raw line (every value at its longest: ~270 bytes).
pub const MAX_MULTI_RAW_LEN: usize = 320;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MultiRawSample {
    /// The sample as `$MCRAW` has it (its `mag` and `flags` are channel 0's).
    pub shared: RawSample,
    /// Channels carried (2–3).
    pub channels: u8,
    pub mag: [Option<MagCounts>; MAX_CHANNELS],
    pub flags: [Flags; MAX_CHANNELS],
}

/// The raw line of one scalar sample: `$MCRAW` on a single-sensor board, `$MCMRAW` on a
/// counter line's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RawLine {
    One(RawSample),
    Multi(MultiRawSample),
}

impl RawLine {
    /// The sample's number since (re)start.
    pub fn k(&self) -> u32 {
        match self {
            RawLine::One(r) => r.k,
            RawLine::Multi(r) => r.shared.k,
        }
    }

    /// Writes the line with `\r\n`; returns the length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, RecordError> {
        match self {
            RawLine::One(r) => encode_raw(r, out),
            RawLine::Multi(r) => encode_multi_raw(r, out),
        }
    }
}

/// Writes one multi raw line with `\r\n`; returns the length.
pub fn encode_multi_raw(r: &MultiRawSample, out: &mut [u8]) -> Result<usize, RecordError> {
    let n = usize::from(r.channels).clamp(2, MAX_CHANNELS);
    let s = &r.shared;
    let mut c = Cursor::new(out);
    let res = (|| {
        c.bytes(b"$MCMRAW,")?;
        c.u64(u64::from(s.k))?;
        c.byte(b',')?;
        c.float(s.t_s, 6)?;
        c.byte(b',')?;
        c.u64(n as u64)?;
        for (m, f) in r.mag.iter().zip(&r.flags).take(n) {
            c.byte(b',')?;
            if let Some(m) = m {
                c.fixed(m.0, 4)?;
            }
            c.byte(b',')?;
            c.hex_u16(f.0)?;
        }
        encode_motion(&mut c, s)?;
        finish_crc(&mut c)
    })();
    res.map_err(|_| RecordError::BufferFull)?;
    Ok(c.pos())
}

/// Parses a line written by [`encode_multi_raw`].
pub fn decode_multi_raw(line: &[u8]) -> Result<MultiRawSample, RecordError> {
    let (f, len, n) = channel_fields::<{ 3 + 2 * MAX_CHANNELS + 7 }>(line, b"MCMRAW,")?;
    if len != 3 + 2 * n + 7 {
        return Err(RecordError::FieldCount);
    }
    let mut mag = [None; MAX_CHANNELS];
    let mut flags = [Flags(Flags::MAG_MISSING); MAX_CHANNELS];
    for ch in 0..n {
        let (m, fi) = (3 + 2 * ch, 4 + 2 * ch);
        mag[ch] = counts_field(f[m], m as u8)?;
        flags[ch] = flags_field(f[fi], fi as u8)?;
    }
    let k = parse_seq(f[0]).ok_or(RecordError::BadField(0))?;
    let t_s = parse_float_field(f[1]).map_err(|_| RecordError::BadField(1))?;
    Ok(MultiRawSample {
        shared: decode_motion(&f, 3 + 2 * n, k, t_s, mag[0], flags[0])?,
        channels: n as u8,
        mag,
        flags,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::raw::MAX_RAW_LEN;

    fn sample() -> MultiRawSample {
        let shared = RawSample {
            k: 4_294_967_295,
            t_s: 43_210.123_456,
            mag: Some(MagCounts(543_219_876)),
            flux_nt: [-18_123.5, 4_321.5, 47_001.25],
            lat_deg: -45.123_456_78,
            lon_deg: 170.987_654_32,
            alt_m: 562.25,
            ground_speed_mps: 61.5,
            flags: Flags(0x0104),
        };
        MultiRawSample {
            shared,
            channels: 3,
            mag: [
                Some(MagCounts(543_219_876)),
                None,
                Some(MagCounts(-999_999_999_999)),
            ],
            flags: [Flags(0x0104), Flags(0x0105), Flags(0x0104)],
        }
    }

    #[test]
    fn a_multi_raw_line_reads_back_every_channel_exactly() {
        let mut buf = [0u8; MAX_MULTI_RAW_LEN];
        let n = encode_multi_raw(&sample(), &mut buf).unwrap();
        assert!(n < MAX_MULTI_RAW_LEN);
        let back = decode_multi_raw(&buf[..n]).unwrap();
        assert_eq!(back.mag, sample().mag);
        assert_eq!(back.flags, sample().flags);
        assert_eq!(back.channels, 3);
        assert_eq!(back.shared.k, sample().shared.k);
        assert!((back.shared.t_s - sample().shared.t_s).abs() < 1e-9);
        assert_eq!(back.shared.alt_m, 562.25);
        // Two channels: the third is not carried.
        let two = MultiRawSample {
            channels: 2,
            ..sample()
        };
        let n = encode_multi_raw(&two, &mut buf).unwrap();
        let back = decode_multi_raw(&buf[..n]).unwrap();
        assert_eq!(back.channels, 2);
        assert_eq!(back.mag, [sample().mag[0], None, None]);
    }

    #[test]
    fn a_single_raw_line_is_mcraw_unchanged_and_the_kinds_are_not_mixed() {
        let one = RawLine::One(sample().shared);
        let mut a = [0u8; MAX_RAW_LEN];
        let mut b = [0u8; MAX_RAW_LEN];
        let n = one.encode(&mut a).unwrap();
        assert_eq!(encode_raw(&sample().shared, &mut b).unwrap(), n);
        assert_eq!(a[..n], b[..n]);
        assert!(decode_multi_raw(&a[..n]).is_err());
        let mut m = [0u8; MAX_MULTI_RAW_LEN];
        let n = RawLine::Multi(sample()).encode(&mut m).unwrap();
        assert!(super::super::raw::decode_raw(&m[..n]).is_err());
        m[20] ^= 1;
        assert!(decode_multi_raw(&m[..n]).is_err());
    }
}
