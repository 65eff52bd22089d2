//! Multi-channel counter line: one line per sample carrying 2–3 scalar magnetometers'
//! fields, as airborne counters with several sensor channels send them.
//!
//! ```text
//! M,<field_0_nt>,<field_1_nt>[,<field_2_nt>]
//! M,53620.4401,53621.1187,53619.9043
//! M,53620.4401,,53619.9043          channel 1 sent nothing (dead sensor): missing
//! M,53620.4401,5362X.1,53619.9043   channel 1 unreadable: missing, parse error
//! ```
//! Each field is in nT with 1–4 decimals, read exactly into counts like a single field
//! ([`parse_field_nt`]); an empty field is a channel with no reading, a field that does
//! not parse is a channel read wrong: either way only that channel is flagged, never the
//! line. The number of fields is the counter's channel count (2 or 3); a line with fewer or
//! more is rejected whole (every channel of that sample then has no reading). Single-field
//! lines keep every format of [`super::scalar`].

use super::scalar::{parse_field_nt, parse_scalar_line, ScalarConfig, ScalarError, ScalarFrame};
use crate::units::MagCounts;

/// Most channels a counter line carries (the board's compensators).
pub const MAX_CHANNELS: usize = 3;

/// One channel's reading on a counter line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channel {
    Field(MagCounts),
    /// Empty field: the counter had no reading from this sensor.
    Missing,
    /// The field did not parse.
    Invalid(ScalarError),
}

impl Channel {
    pub fn mag(self) -> Option<MagCounts> {
        match self {
            Channel::Field(m) => Some(m),
            _ => None,
        }
    }
}

/// One counter line: `channels` (2–3) readings, the rest [`Channel::Missing`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MultiFrame {
    pub channels: u8,
    pub ch: [Channel; MAX_CHANNELS],
}

/// A scalar port line: a single field (any format of `scalar.rs`) or a counter line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScalarLine {
    Single(Result<ScalarFrame, ScalarError>),
    Multi(MultiFrame),
}

/// Parses a counter line's fields after `M,` (terminator stripped).
pub fn parse_multi_fields(rest: &[u8]) -> Result<MultiFrame, ScalarError> {
    let mut f = MultiFrame {
        channels: 0,
        ch: [Channel::Missing; MAX_CHANNELS],
    };
    for field in rest.split(|&b| b == b',') {
        let slot =
            f.ch.get_mut(usize::from(f.channels))
                .ok_or(ScalarError::ChannelCount)?;
        *slot = if field.is_empty() {
            Channel::Missing
        } else {
            parse_field_nt(field).map_or_else(Channel::Invalid, Channel::Field)
        };
        f.channels += 1;
    }
    if f.channels < 2 {
        return Err(ScalarError::ChannelCount);
    }
    Ok(f)
}

/// Parses any scalar port line: `M,…` as a counter line, anything else as a single field.
/// A malformed counter line is a single line's error (the sample then has no reading).
pub fn parse_scalar_any(line: &[u8], cfg: &ScalarConfig) -> ScalarLine {
    let mut line = line;
    while let [rest @ .., b'\r' | b'\n' | b' '] = line {
        line = rest;
    }
    match line {
        [b'M', b',', rest @ ..] => match parse_multi_fields(rest) {
            Ok(f) => ScalarLine::Multi(f),
            Err(e) => ScalarLine::Single(Err(e)),
        },
        _ => ScalarLine::Single(parse_scalar_line(line, cfg)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn any(s: &str) -> ScalarLine {
        parse_scalar_any(s.as_bytes(), &ScalarConfig::default())
    }

    #[test]
    fn three_channels_exact() {
        let ScalarLine::Multi(f) = any("M,53620.4401,53621.1187,53619.9043\r\n") else {
            panic!()
        };
        assert_eq!(f.channels, 3);
        assert_eq!(f.ch[0], Channel::Field(MagCounts(536_204_401)));
        assert_eq!(f.ch[1], Channel::Field(MagCounts(536_211_187)));
        assert_eq!(f.ch[2], Channel::Field(MagCounts(536_199_043)));
    }

    #[test]
    fn dead_and_unreadable_channels_keep_the_line() {
        let ScalarLine::Multi(f) = any("M,53620.4401,,5362X.1") else {
            panic!()
        };
        assert_eq!(f.channels, 3);
        assert_eq!(f.ch[0].mag(), Some(MagCounts(536_204_401)));
        assert_eq!(f.ch[1], Channel::Missing);
        assert_eq!(f.ch[2], Channel::Invalid(ScalarError::BadCharacter));
        let ScalarLine::Multi(f) = any("M,,") else {
            panic!()
        };
        assert_eq!(
            (f.channels, f.ch[0], f.ch[1]),
            (2, Channel::Missing, Channel::Missing)
        );
        // out of range and too many decimals are the channel's, not the line's
        let ScalarLine::Multi(f) = any("M,5.0,53620.12345") else {
            panic!()
        };
        assert_eq!(f.ch[0], Channel::Invalid(ScalarError::OutOfRange));
        assert_eq!(f.ch[1], Channel::Invalid(ScalarError::TooManyDigits));
    }

    #[test]
    fn channel_count_outside_2_to_3_rejects_the_line() {
        for s in ["M,53620.4", "M,", "M,1,2,3,4", "M,53620.4,53620.4,53620.4,"] {
            assert_eq!(
                any(s),
                ScalarLine::Single(Err(ScalarError::ChannelCount)),
                "{s}"
            );
        }
    }

    #[test]
    fn single_formats_unchanged() {
        for s in [
            "53620.4401",
            "$ 53620.441,0999",
            "53620.4401,Q=97",
            "F,187594.863120657",
            "M",
        ] {
            assert_eq!(
                any(s),
                ScalarLine::Single(parse_scalar_line(s.as_bytes(), &ScalarConfig::default())),
                "{s}"
            );
        }
    }
}
