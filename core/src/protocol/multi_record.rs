//! Multi-sensor output record: one line per counter-line sample (`multi_scalar`) when the
//! board reads 2–3 scalar magnetometers, carrying every channel's compensation and the
//! differences between the channels.
//!
//! ```text
//! $MCMREC,<seq>,<t_s>,<n>,{<mag_nt>,<interf_nt>,<comp_nt>,<sigma_nt>,<flags>}×n,{<diff_nt>}×n(n−1)/2*<CRC16>\r\n
//! ```
//! Per channel as in `$MCREC` (`record.rs`): the absolute reading and the compensated value
//! printed exactly from counts (empty when missing), the interference and its stated 1σ
//! (empty when unknown), 4 hex digits of flags. Then the pair differences of the
//! compensated fields in nT, exact from counts, in the order (0,1), (0,2), (1,2) (channel
//! `j` minus channel `i`), empty when either is missing. The board knows nothing of the
//! sensors' positions: the host, which does (the installation's geometry), divides by the
//! separation for the gradient in nT/m. Same number formatting and CRC-16/CCITT-FALSE
//! checksum as `$MCREC`; a different sentence name so a single-sensor decoder never takes
//! one for its own.

use super::common::{fields, finish_crc, parse_float_field, Cursor};
use super::multi_scalar::MAX_CHANNELS;
use super::record::{check_crc_line, counts_field, flags_field, parse_seq, RecordError};
use crate::flags::Flags;
use crate::units::MagCounts;

/// Buffer large enough for any multi record (every value at its longest: ~350 bytes).
pub const MAX_MULTI_RECORD_LEN: usize = 384;
/// Channel pairs, in record order.
pub const PAIRS: [(usize, usize); 3] = [(0, 1), (0, 2), (1, 2)];

/// One channel of a multi record.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChannelRecord {
    pub mag: Option<MagCounts>,
    pub interference_nt: f32,
    pub compensated: Option<MagCounts>,
    pub sigma_nt: f32,
    pub flags: Flags,
}

impl ChannelRecord {
    /// A channel with no reading and no output (a sensor not yet seen): flagged missing.
    pub const MISSING: ChannelRecord = ChannelRecord {
        mag: None,
        interference_nt: f32::NAN,
        compensated: None,
        sigma_nt: f32::NAN,
        flags: Flags(Flags::MAG_MISSING),
    };
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MultiRecord {
    pub seq: u32,
    pub t_s: f64,
    /// Channels carried (2–3); `ch` beyond them is [`ChannelRecord::MISSING`].
    pub channels: u8,
    pub ch: [ChannelRecord; MAX_CHANNELS],
    /// Compensated `ch[j] − ch[i]` for the pairs of [`PAIRS`] within `channels`, exact.
    pub diff: [Option<MagCounts>; 3],
}

/// Pairs carried with `n` channels: 1 for 2, 3 for 3.
pub const fn pair_count(n: usize) -> usize {
    n * n.saturating_sub(1) / 2
}

impl MultiRecord {
    /// A record of `channels` channels, their pair differences formed from `ch`.
    pub fn new(seq: u32, t_s: f64, channels: u8, ch: [ChannelRecord; MAX_CHANNELS]) -> Self {
        Self {
            seq,
            t_s,
            channels,
            ch,
            diff: Self::differences(channels, &ch),
        }
    }

    /// The pair differences of the channels' compensated fields (exact, saturating).
    pub fn differences(channels: u8, ch: &[ChannelRecord; MAX_CHANNELS]) -> [Option<MagCounts>; 3] {
        let mut d = [None; 3];
        for (k, &(i, j)) in PAIRS.iter().enumerate().take(pair_count(channels.into())) {
            if let (Some(a), Some(b)) = (ch[i].compensated, ch[j].compensated) {
                d[k] = Some(MagCounts(b.0.saturating_sub(a.0)));
            }
        }
        d
    }
}

fn opt_counts(c: &mut Cursor, m: Option<MagCounts>) -> Result<(), super::common::BufferFull> {
    match m {
        Some(m) => c.fixed(m.0, 4),
        None => Ok(()),
    }
}

/// Writes one multi record with `\r\n`; returns the length.
pub fn encode_multi_record(r: &MultiRecord, out: &mut [u8]) -> Result<usize, RecordError> {
    let n = usize::from(r.channels).clamp(2, MAX_CHANNELS);
    let mut c = Cursor::new(out);
    let res = (|| {
        c.bytes(b"$MCMREC,")?;
        c.u64(r.seq.into())?;
        c.byte(b',')?;
        c.float(r.t_s, 6)?;
        c.byte(b',')?;
        c.u64(n as u64)?;
        for ch in &r.ch[..n] {
            c.byte(b',')?;
            opt_counts(&mut c, ch.mag)?;
            c.byte(b',')?;
            c.float(ch.interference_nt.into(), 4)?;
            c.byte(b',')?;
            opt_counts(&mut c, ch.compensated)?;
            c.byte(b',')?;
            c.float(ch.sigma_nt.into(), 4)?;
            c.byte(b',')?;
            c.hex_u16(ch.flags.0)?;
        }
        for d in &r.diff[..pair_count(n)] {
            c.byte(b',')?;
            opt_counts(&mut c, *d)?;
        }
        finish_crc(&mut c)
    })();
    res.map_err(|_| RecordError::BufferFull)?;
    Ok(c.pos())
}

/// A several-channel line's fields after its sentence name (`<seq/k>,<t_s>,<n>,…`), checked
/// against its CRC: at most `M`, how many there are, and the channel count `n` (2 or 3).
pub(crate) fn channel_fields<'a, const M: usize>(
    line: &'a [u8],
    name: &[u8],
) -> Result<([&'a [u8]; M], usize, usize), RecordError> {
    let payload = check_crc_line(line, name)?;
    let mut f = [&b""[..]; M];
    let mut len = 0;
    for x in fields(payload).skip(1) {
        *f.get_mut(len).ok_or(RecordError::FieldCount)? = x;
        len += 1;
    }
    let n = match f[2] {
        b"2" => 2,
        b"3" => 3,
        _ => return Err(RecordError::BadField(2)),
    };
    Ok((f, len, n))
}

/// Parses a line written by [`encode_multi_record`].
pub fn decode_multi_record(line: &[u8]) -> Result<MultiRecord, RecordError> {
    let (f, len, n) = channel_fields::<{ 3 + 5 * MAX_CHANNELS + 3 }>(line, b"MCMREC,")?;
    if len != 3 + 5 * n + pair_count(n) {
        return Err(RecordError::FieldCount);
    }
    let fl = |i: usize| {
        parse_float_field(f[i])
            .map(|v| v as f32)
            .map_err(|_| RecordError::BadField(i as u8))
    };
    let mut r = MultiRecord {
        seq: parse_seq(f[0]).ok_or(RecordError::BadField(0))?,
        t_s: parse_float_field(f[1]).map_err(|_| RecordError::BadField(1))?,
        channels: n as u8,
        ch: [ChannelRecord::MISSING; MAX_CHANNELS],
        diff: [None; 3],
    };
    for (k, ch) in r.ch[..n].iter_mut().enumerate() {
        let at = 3 + 5 * k;
        *ch = ChannelRecord {
            mag: counts_field(f[at], at as u8)?,
            interference_nt: fl(at + 1)?,
            compensated: counts_field(f[at + 2], (at + 2) as u8)?,
            sigma_nt: fl(at + 3)?,
            flags: flags_field(f[at + 4], (at + 4) as u8)?,
        };
    }
    for (k, d) in r.diff[..pair_count(n)].iter_mut().enumerate() {
        let at = 3 + 5 * n + k;
        *d = counts_field(f[at], at as u8)?;
    }
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ch(mag: i64, interf: f32, flags: u16) -> ChannelRecord {
        let mag = Some(MagCounts(mag));
        ChannelRecord {
            mag,
            interference_nt: interf,
            compensated: crate::protocol::record::Record::compensate(mag, interf),
            sigma_nt: 0.125,
            flags: Flags(flags),
        }
    }

    #[test]
    fn three_channels_round_trip_with_exact_differences() {
        let c = [
            ch(536_204_401, 12.5, 0x0100),
            ch(536_211_187, -3.25, 0x0100),
            ChannelRecord::MISSING,
        ];
        let r = MultiRecord::new(42, 12.3, 3, c);
        // (53621.1187 + 3.25) − (53620.4401 − 12.5) = 16.4286 nT; pairs with channel 2 empty
        assert_eq!(r.diff, [Some(MagCounts(164_286)), None, None]);
        let mut buf = [0u8; MAX_MULTI_RECORD_LEN];
        let n = encode_multi_record(&r, &mut buf).unwrap();
        let line = core::str::from_utf8(&buf[..n]).unwrap();
        assert!(
            line.starts_with(
                "$MCMREC,42,12.300000,3,53620.4401,12.5000,53607.9401,0.1250,0100,\
                 53621.1187,-3.2500,53624.3687,0.1250,0100,,,,,0008,16.4286,,*"
            ),
            "{line}"
        );
        let back = decode_multi_record(&buf[..n]).unwrap();
        assert_eq!(back.diff, r.diff);
        assert_eq!(back.ch[..2], r.ch[..2]);
        assert_eq!(back.ch[2].flags, Flags(Flags::MAG_MISSING));
        // a single-sensor decoder refuses it, and a flipped byte fails the CRC
        assert!(crate::protocol::record::decode_record(&buf[..n]).is_err());
        buf[20] ^= 1;
        assert!(decode_multi_record(&buf[..n]).is_err());
    }

    #[test]
    fn two_channels_carry_one_pair() {
        let c = [
            ch(536_204_401, 0.0, 0),
            ch(536_204_400, 0.0, 0),
            ChannelRecord::MISSING,
        ];
        let r = MultiRecord::new(0, 0.0, 2, c);
        let mut buf = [0u8; MAX_MULTI_RECORD_LEN];
        let n = encode_multi_record(&r, &mut buf).unwrap();
        let line = core::str::from_utf8(&buf[..n]).unwrap();
        assert!(line.contains(",0000,-0.0001*"), "{line}");
        assert_eq!(
            decode_multi_record(&buf[..n]).unwrap().diff[0],
            Some(MagCounts(-1))
        );
    }

    #[test]
    fn longest_values_fit_the_buffer() {
        let big = ChannelRecord {
            mag: Some(MagCounts(-999_999_999_999_999_999)),
            interference_nt: -f32::MAX,
            compensated: Some(MagCounts(i64::MIN)),
            sigma_nt: -f32::MAX,
            flags: Flags(0xFFFF),
        };
        let r = MultiRecord {
            seq: u32::MAX,
            t_s: -f64::MAX,
            channels: 3,
            ch: [big; 3],
            diff: [Some(MagCounts(i64::MIN)); 3],
        };
        let mut buf = [0u8; MAX_MULTI_RECORD_LEN];
        let n = encode_multi_record(&r, &mut buf).unwrap();
        assert!(n < MAX_MULTI_RECORD_LEN, "{n}");
    }
}
