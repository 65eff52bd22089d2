//! Byte-level mutations of a seed (libFuzzer's usual set, plus checksum repair so a
//! mutated sentence or record still reaches the field decoders behind its checksum).

use magcomp_core::protocol::common::{crc16_ccitt, xor_checksum};
use rand::rngs::SmallRng;
use rand::Rng;

/// Bytes every text protocol here gives meaning to.
const DICT: &[&[u8]] = &[
    b"$",
    b"*",
    b",",
    b".",
    b"-",
    b"+",
    b"\r\n",
    b"\n",
    b"\r",
    b" ",
    b"0",
    b"9",
    b"e",
    b"E",
    b"nan",
    b"inf",
    b"1e300",
    b"-0",
    b"99999999999999999999",
    b"A",
    b"V",
    b"N",
    b"#",
    b"GPGGA",
    b"GNRMC",
    b"GNGLL",
    b"GNGNS",
    b"MCREC",
    b"MCCMD",
    b"SETCOEF",
    b"SETFLUX",
    b"scalar ",
    b"flux ",
    b"gps ",
    b"cmd ",
    b"\xff",
    b"\0",
    b"# magcomp-capture v2",
    b"t,mag,flux_x",
];

/// Largest mutated input (keeps one execution in the tens of microseconds).
pub const MAX_LEN: usize = 8192;

/// A random window of `seed` (whole seeds can be 100 KB logs), starting at a line start.
pub fn window<'a>(rng: &mut SmallRng, seed: &'a [u8], max: usize) -> &'a [u8] {
    if seed.len() <= max {
        return seed;
    }
    let mut a = rng.gen_range(0..seed.len() - max);
    // Prefer to start on a line: framing is where decoders differ.
    if let Some(nl) = seed[a..].iter().take(200).position(|&b| b == b'\n') {
        a += nl + 1;
    }
    let n = rng.gen_range(1..=max.min(seed.len() - a));
    &seed[a..a + n]
}

/// Applies 1–8 random mutations to `v` in place.
pub fn mutate(rng: &mut SmallRng, v: &mut Vec<u8>, other: &[u8]) {
    for _ in 0..rng.gen_range(1..=8) {
        let len = v.len();
        match rng.gen_range(0..11) {
            0 if len > 0 => {
                let i = rng.gen_range(0..len);
                v[i] ^= 1 << rng.gen_range(0..8);
            }
            1 if len > 0 => {
                let i = rng.gen_range(0..len);
                v[i] = rng.gen();
            }
            2 => {
                let i = rng.gen_range(0..=len);
                let d = DICT[rng.gen_range(0..DICT.len())];
                v.splice(i..i, d.iter().copied());
            }
            3 if len > 0 => {
                let a = rng.gen_range(0..len);
                let b = (a + rng.gen_range(1..=16)).min(len);
                v.drain(a..b);
            }
            4 if len > 0 => {
                // Duplicate a range (repeated lines, doubled bytes).
                let a = rng.gen_range(0..len);
                let b = (a + rng.gen_range(1..=64)).min(len);
                let chunk = v[a..b].to_vec();
                v.splice(b..b, chunk);
            }
            5 if !other.is_empty() => {
                // Splice a piece of another seed.
                let a = rng.gen_range(0..other.len());
                let b = (a + rng.gen_range(1..=128)).min(other.len());
                let i = rng.gen_range(0..=len);
                v.splice(i..i, other[a..b].iter().copied());
            }
            6 if len > 0 => v.truncate(rng.gen_range(0..len)),
            7 if len > 0 => {
                // Replace a digit run by an extreme number.
                let i = rng.gen_range(0..len);
                if let Some(s) = v[i..].iter().position(u8::is_ascii_digit) {
                    let s = i + s;
                    let e = s + v[s..].iter().take_while(|b| b.is_ascii_digit()).count();
                    let rep: &[u8] = match rng.gen_range(0..5) {
                        0 => b"0",
                        1 => b"4294967296",
                        2 => b"18446744073709551616",
                        3 => b"000000000000000000000001",
                        _ => b"9",
                    };
                    v.splice(s..e, rep.iter().copied());
                }
            }
            8 if len > 1 => {
                let i = rng.gen_range(0..len - 1);
                v.swap(i, i + 1);
            }
            _ => {
                let i = rng.gen_range(0..=len);
                v.insert(i, rng.gen());
            }
        }
    }
    v.truncate(MAX_LEN);
}

/// Recomputes the checksum of every `$…*hh` (NMEA XOR) or `$…*hhhh` (CRC-16) line.
pub fn fix_checksums(v: &mut [u8]) {
    let mut start = 0;
    while start < v.len() {
        let end = v[start..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(v.len(), |e| start + e);
        let line = &v[start..end];
        if let (Some(d), Some(s)) = (
            line.iter().position(|&b| b == b'$'),
            line.iter().rposition(|&b| b == b'*'),
        ) {
            if d < s {
                let tail = line[s + 1..]
                    .iter()
                    .take_while(|b| b.is_ascii_hexdigit())
                    .count();
                let body = &line[d + 1..s];
                let hex = match tail {
                    2 => format!("{:02X}", xor_checksum(body)),
                    4 => format!("{:04X}", crc16_ccitt(body)),
                    _ => String::new(),
                };
                let at = start + s + 1;
                v[at..at + hex.len()].copy_from_slice(hex.as_bytes());
            }
        }
        start = end + 1;
    }
}
