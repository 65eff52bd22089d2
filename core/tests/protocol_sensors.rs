//! Scalar magnetometer lines and fluxgate frames.

mod common;
use common::Rng;

use magcomp_core::protocol::fluxgate::*;
use magcomp_core::protocol::scalar::*;
use magcomp_core::MagCounts;

fn cfg() -> ScalarConfig {
    ScalarConfig::default()
}

#[test]
fn scalar_exact_digits() {
    let f = parse_scalar_line(b"53620.4401\r\n", &cfg()).unwrap();
    assert_eq!(f.mag, MagCounts(536_204_401));
    assert_eq!(f.quality, None);
    assert_eq!(
        parse_scalar_line(b"53620.440", &cfg()).unwrap().mag,
        MagCounts(536_204_400)
    );
    assert_eq!(
        parse_scalar_line(b"99999.9999", &cfg()).unwrap().mag,
        MagCounts(999_999_999)
    );
    let g = parse_scalar_line(b"$ 53620.441,0999", &cfg()).unwrap();
    assert_eq!(g.mag, MagCounts(536_204_410));
    assert_eq!(g.quality, Some(999));
    let q = parse_scalar_line(b"53620.4401,Q=97", &cfg()).unwrap();
    assert_eq!((q.mag, q.quality), (MagCounts(536_204_401), Some(97)));
    // Every 4-decimal value in a range maps exactly (no float path).
    for c in (100_000_000i64..1_000_000_000).step_by(7_919_993) {
        let s = format!("{}.{:04}", c / 10_000, c % 10_000);
        assert_eq!(parse_field_nt(s.as_bytes()).unwrap(), MagCounts(c), "{s}");
    }
}

#[test]
fn larmor_conversion_exact() {
    let f_hz = "187594.863120657"; // 53620.4401 nT × 3.49857 Hz/nT, exact
    let r = parse_scalar_line(format!("F,{f_hz}").as_bytes(), &cfg()).unwrap();
    assert_eq!(r.mag, MagCounts(536_204_401));
    // Rounding to the nearest 1e-4 nT: f = (c + 0.4) counts worth of Hz rounds down,
    // (c + 0.6) rounds up. Computed with exact integers.
    for (extra_tenths, want) in [(4i128, 536_204_401i64), (6, 536_204_402)] {
        // f(Hz) × 1e14 = (c·10 + extra) × 3498570000 × 1e-5 ... use 1e-14 Hz resolution.
        let num = (536_204_401i128 * 10 + extra_tenths) * 3_498_570_000; // Hz × 1e14
        let s = format!(
            "{}.{:014}",
            num / 100_000_000_000_000,
            num % 100_000_000_000_000
        );
        // 18 significant digits max: trim trailing zeros.
        let s = s.trim_end_matches('0');
        let got = larmor_to_counts(s.as_bytes(), CS133_HZ_PER_NT_NANO);
        assert_eq!(got, Ok(MagCounts(want)), "{s}");
    }
    assert_eq!(
        larmor_to_counts(b"174928.5", 0),
        Err(ScalarError::NoLarmorRatio)
    );
}

#[test]
fn scalar_typed_errors() {
    use ScalarError::*;
    let p = |s: &str| parse_scalar_line(s.as_bytes(), &cfg()).map(|f| f.mag);
    assert_eq!(p("."), Err(NoDigits));
    assert_eq!(p("53620.44011"), Err(TooManyDigits));
    assert_eq!(p("9999.9999"), Err(OutOfRange));
    assert_eq!(p("100000.0001"), Err(OutOfRange));
    assert_eq!(p("-53620.1"), Err(OutOfRange));
    assert_eq!(p("53620.1,Q=101"), Err(BadStatus));
    assert_eq!(p("$ 53620.441,099"), Err(BadStatus));
    assert_eq!(p("53620.4x"), Err(BadCharacter));
    assert_eq!(p("99999999999999999999"), Err(TooManyDigits));
}

#[test]
fn scalar_fuzz_resync() {
    let mut rng = Rng(12345);
    let mut r = ScalarReader::new(cfg());
    let (mut lines, mut results, mut good_sent, mut good_back) = (0u64, 0u64, 0u64, 0u64);
    let mut n = 0u64;
    let mut pending = false;
    while n < 1_200_000 {
        let junk: Vec<u8> = (0..rng.next() % 80)
            .map(|_| match rng.next() % 6 {
                0 => b'\n',
                1 => b'.',
                _ => b'0' + (rng.next() % 75) as u8,
            })
            .collect();
        let good = format!(
            "\n{}.{:04}\r\n",
            20_000 + rng.next() % 60_000,
            rng.next() % 10_000
        );
        good_sent += 1;
        for chunk in [&junk[..], good.as_bytes()] {
            for &b in chunk {
                n += 1;
                if b == b'\n' || b == b'\r' {
                    lines += pending as u64;
                    pending = false;
                } else {
                    pending = true;
                }
                match r.push(b) {
                    Some(Ok(_)) => {
                        results += 1;
                        if std::ptr::eq(chunk, good.as_bytes()) {
                            good_back += 1;
                        }
                    }
                    Some(Err(_)) => results += 1,
                    None => {}
                }
            }
        }
    }
    assert_eq!(results, lines, "one result per non-empty line");
    assert_eq!(
        (r.stats.ok + r.stats.errors + r.stats.overlong) as u64,
        results
    );
    assert_eq!(
        good_back, good_sent,
        "every clean line after a newline decodes"
    );
}

#[test]
fn spi_frame_roundtrip_crc_and_saturation() {
    let f = encode_spi_frame(0x0507, [1, -1, 4_194_304]);
    // CRC over the first 12 bytes, independently recomputed bitwise.
    let mut crc: u16 = 0xFFFF;
    for &b in &f[..12] {
        crc ^= (b as u16) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
    }
    assert_eq!(u16::from_be_bytes([f[12], f[13]]), crc);
    let a = decode_spi_frame(&f).unwrap();
    assert_eq!(a.counts, [1, -1, 4_194_304]);
    assert_eq!(a.status, 0x0507);
    // Any single bit flip is caught.
    for i in 0..14 {
        for bit in 0..8 {
            let mut g = f;
            g[i] ^= 1 << bit;
            assert!(decode_spi_frame(&g).is_err(), "byte {i} bit {bit}");
        }
    }
    assert_eq!(decode_spi_frame(&f[..14]), Err(FluxError::BadLength));
    let s = encode_spi_frame(0x0007, [0, 8_388_607, 0]);
    assert_eq!(
        decode_spi_frame(&s),
        Err(FluxError::Saturated { channel: 1 })
    );
    let s = encode_spi_frame(0x0007, [-8_388_608, 0, 0]);
    assert_eq!(
        decode_spi_frame(&s),
        Err(FluxError::Saturated { channel: 0 })
    );
    let s = encode_spi_frame(0x0003, [0, 0, 0]);
    assert_eq!(decode_spi_frame(&s), Err(FluxError::NotReady));
}

#[test]
fn scaling_and_axis_map() {
    let mut cal = FluxgateCal::full_scale(100_000.0);
    // Half scale is 50 000 nT exactly (power-of-two scale).
    assert_eq!(
        cal.scale([4_194_304, -4_194_304, 0]),
        [50_000.0, -50_000.0, 0.0]
    );
    // Sensor mounted with x aft, y up, z starboard → body x = -s0, y = s2, z = -s1.
    cal.axis_map = [
        AxisMap {
            sensor_channel: 0,
            negate: true,
        },
        AxisMap {
            sensor_channel: 2,
            negate: false,
        },
        AxisMap {
            sensor_channel: 1,
            negate: true,
        },
    ];
    let lsb = 100_000.0 / 8_388_608.0;
    let b = cal.scale([1000, 2000, 3000]);
    assert_eq!(
        b,
        [
            -(1000.0 * lsb) as f32,
            (3000.0 * lsb) as f32,
            -(2000.0 * lsb) as f32
        ]
    );
}

#[test]
fn ascii_fluxgate() {
    assert_eq!(
        parse_ascii_line(b"12345.6,-2345.25,40000\r\n"),
        Ok([12345.6, -2345.25, 40000.0])
    );
    let body = "1.5,2.5,-3.5";
    let x = body.bytes().fold(0u8, |a, b| a ^ b);
    assert_eq!(
        parse_ascii_line(format!("{body}*{x:02X}").as_bytes()),
        Ok([1.5, 2.5, -3.5])
    );
    assert_eq!(
        parse_ascii_line(format!("{body}*{:02X}", x ^ 1).as_bytes()),
        Err(FluxError::Checksum)
    );
    assert_eq!(parse_ascii_line(b"1,2"), Err(FluxError::BadLength));
    // A 4th field is the sensor's temperature (°C, `fluxtemp`); a 5th is too many.
    assert_eq!(parse_ascii_line(b"1,2,3,4"), Ok([1.0, 2.0, 3.0]));
    assert_eq!(parse_ascii_line(b"1,2,3,4,5"), Err(FluxError::BadLength));
    assert_eq!(parse_ascii_line(b"1,x,3"), Err(FluxError::BadNumber));
    assert_eq!(parse_ascii_line(b"1,2,300000"), Err(FluxError::OutOfRange));
    let mut r = FluxAsciiReader::new();
    let out: Vec<_> = b"garbage\n1,2,3\r\n"
        .iter()
        .filter_map(|&b| r.push(b))
        .collect();
    assert_eq!(out, vec![Err(FluxError::BadNumber), Ok([1.0, 2.0, 3.0])]);
}

/// A checksummed stream refuses lines without a checksum from its first valid one on: a
/// corrupted byte that became a line end cuts `15847.677,-14708.960,46768.073*00` into
/// `15847.677,-14708.960,4676` (parses, Z wrong by 42,092 nT) and `.073*00` (refused).
#[test]
fn a_checksummed_fluxgate_stream_refuses_a_frame_cut_short() {
    let mut r = FluxAsciiReader::new();
    let out: Vec<_> = b"1,2,3\r\n15896.450,-14842.334,46708.926*0E\r\n15847.677,-14708.960,4676\n.073*00\r\n15798.902,-14573.949,46826.278*09\r\n"
        .iter()
        .filter_map(|&b| r.push(b))
        .collect();
    assert_eq!(
        out,
        vec![
            Ok([1.0, 2.0, 3.0]),
            Ok([15896.45, -14842.334, 46708.926]),
            Err(FluxError::Checksum),
            Err(FluxError::Checksum),
            Ok([15798.902, -14573.949, 46826.278]),
        ]
    );
    assert_eq!((r.stats.ok, r.stats.errors), (3, 2));
}

/// Every line the reader yields for `text`, with the lines merged lines owe.
fn lines_of(text: &str) -> Vec<Result<MagCounts, ScalarError>> {
    use magcomp_core::protocol::multi_scalar::ScalarLine;
    let mut r = ScalarReader::new(cfg());
    let mut out = Vec::new();
    let mut take = |l: ScalarLine| {
        out.push(match l {
            ScalarLine::Single(r) => r.map(|f| f.mag),
            ScalarLine::Multi(f) => f.ch[0].mag().ok_or(ScalarError::BadCharacter),
        })
    };
    for &b in text.as_bytes() {
        if let Some(l) = r.push_line(b) {
            take(l);
        }
        while let Some(l) = r.owed_line() {
            take(l);
        }
    }
    out
}

#[test]
fn a_line_run_into_the_next_counts_its_samples() {
    let m = |s: &str| Ok(MagCounts::from_nt_f64(s.parse().unwrap()).unwrap());
    let bad = |e| Err(e);
    // plain fields, one terminator lost, then two in a row
    let got = lines_of("53620.4401\n53620.4402\n53620.440353620.4404\n53620.4405\n");
    assert_eq!(got.len(), 5);
    assert_eq!(got[3], bad(ScalarError::Merged));
    assert_eq!(got[4], m("53620.4405"));
    let got = lines_of("53620.4401\n53620.440253620.440353620.4404\n53620.4405\n");
    assert_eq!(got.len(), 5);
    assert_eq!(&got[2..4], &[bad(ScalarError::Merged); 2]);
    // Geometrics lines, with CR LF: both lost
    let got = lines_of("$ 53620.441,0999\r\n$ 53620.442,0999$ 53620.443,0999\r\n");
    assert_eq!(got.len(), 3);
    assert!(got[1].is_err() && got[2] == bad(ScalarError::Merged));
    // counter lines whose channel 1 is dead on one of them: shorter, still two samples
    let got = lines_of(
        "M,53620.4401,53621.1187,53619.9043\nM,53620.4402,,53619.9044M,53620.4403,53621.1189,53619.9045\n",
    );
    assert_eq!(got.len(), 3);
    assert_eq!(got[2], bad(ScalarError::Merged));
    // a corrupted digit or a lost byte keeps one sample; so does junk before any good line
    assert_eq!(lines_of("53620.4401\n536#0.4402\n").len(), 2);
    assert_eq!(lines_of("53620.4401\n53620.442\n536200.44022\n").len(), 3);
    assert_eq!(lines_of("53620.440353620.4404\n53620.4405\n").len(), 2);
    // a stuck stream without terminators is at most MAX_MERGED_SAMPLES
    let long = "53620.4401\n".to_string() + &"9".repeat(500) + "\n";
    assert_eq!(lines_of(&long).len(), 1 + MAX_MERGED_SAMPLES as usize);
}
