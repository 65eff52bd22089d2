//! Property tests: decode(encode(x)) == x for every format with an encoder (output
//! records, commands, captures, flash blobs, SPI frames), and GLL/GNS positions written
//! from exact digits decode to them.

use magcomp_core::protocol::capture::{decode_line, encode_line, Port, MAX_CHUNK, MAX_LINE};
use magcomp_core::protocol::command::{
    blob_len, decode_blob, encode_blob, encode_command, parse_command, Command, Mode,
};
use magcomp_core::protocol::common::xor_checksum;
use magcomp_core::protocol::fluxgate::{decode_spi_frame, encode_spi_frame, ADC_FULL_SCALE};
use magcomp_core::protocol::lag_line::MAX_LAG_S;
use magcomp_core::protocol::nmea::{parse_sentence, Sentence};
use magcomp_core::protocol::record::{decode_record, encode_record, Record, MAX_RECORD_LEN};
use magcomp_core::{Flags, MagCounts};
use proptest::prelude::*;

fn coef() -> impl Strategy<Value = f32> {
    (-1.0e6f32..1.0e6).prop_filter("|v| < 1e6", |v| v.abs() < 1.0e6)
}

fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        Just(Command::Mode(Mode::Survey)),
        Just(Command::Mode(Mode::Cal)),
        Just(Command::Status),
        Just(Command::Save),
        Just(Command::Reset),
        Just(Command::Flush),
        Just(Command::FactoryReset),
        proptest::option::of(0u16..21).prop_map(Command::GetCoef),
        proptest::option::of(0u16..12).prop_map(Command::GetFlux),
        (0u16..21, coef()).prop_map(|(index, value)| Command::SetCoef { index, value }),
        (0u16..12, coef()).prop_map(|(index, value)| Command::SetFlux { index, value }),
        Just(Command::GetLag),
        // τ over the whole accepted range, the bounds included.
        prop_oneof![Just(0.0f32), Just(MAX_LAG_S), 0.0f32..=MAX_LAG_S].prop_map(Command::SetLag),
        proptest::option::of(0u16..7).prop_map(Command::GetFluxTemp),
        (0u16..7, coef()).prop_map(|(index, value)| Command::SetFluxTemp { index, value }),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn command_round_trip(c in command()) {
        let mut out = [0u8; 128];
        let n = encode_command(&c, &mut out).unwrap();
        prop_assert_eq!(parse_command(&out[..n], 21), Ok(c));
    }

    /// Integers and the microsecond time exactly; the f32 values to their 4 written
    /// decimals (and f32 rounding).
    #[test]
    fn record_round_trip(
        seq in any::<u32>(),
        t_us in -1_000_000_000_000_000i64..1_000_000_000_000_000,
        mag in proptest::option::of(100_000_000i64..1_000_000_000),
        interference in -1.0e5f32..1.0e5,
        anomaly in -1.0e4f32..1.0e4,
        innovation in -1.0e4f32..1.0e4,
        flags in any::<u16>(),
    ) {
        let r = Record {
            seq,
            t_s: t_us as f64 / 1e6,
            mag: mag.map(MagCounts),
            interference_nt: interference,
            compensated: Record::compensate(mag.map(MagCounts), interference),
            anomaly_nt: anomaly,
            innovation_nt: innovation,
            sigma_nt: anomaly.abs(),
            flags: Flags(flags),
        };
        let mut out = [0u8; MAX_RECORD_LEN];
        let n = encode_record(&r, &mut out).unwrap();
        let d = decode_record(&out[..n]).unwrap();
        prop_assert_eq!((d.seq, d.mag, d.compensated, d.flags), (r.seq, r.mag, r.compensated, r.flags));
        prop_assert_eq!(d.t_s, r.t_s);
        for (a, b) in [(d.interference_nt, interference), (d.anomaly_nt, anomaly), (d.innovation_nt, innovation), (d.sigma_nt, anomaly.abs())] {
            prop_assert!((a - b).abs() <= 0.5e-4 + b.abs() * f32::EPSILON, "{} vs {}", a, b);
        }
    }

    #[test]
    fn capture_round_trip(t_us in any::<u64>(), port in 0usize..5, data in proptest::collection::vec(any::<u8>(), 0..=MAX_CHUNK)) {
        let port = Port::ALL[port];
        let mut out = [0u8; MAX_LINE + 2];
        let n = encode_line(t_us, port, &data, &mut out).unwrap();
        let mut buf = [0u8; MAX_CHUNK];
        let c = decode_line(&out[..n], &mut buf).unwrap().unwrap();
        prop_assert_eq!((c.t_us, c.port, &buf[..c.len]), (t_us, port, &data[..]));
    }

    #[test]
    fn blob_round_trip(hash in any::<u32>(), coef in proptest::collection::vec(coef(), 1..40)) {
        let mut out = vec![0u8; blob_len(coef.len())];
        let n = encode_blob(hash, &coef, &mut out).unwrap();
        let mut back = vec![0f32; coef.len()];
        decode_blob(&out[..n], hash, &mut back).unwrap();
        prop_assert_eq!(back, coef);
    }

    #[test]
    fn spi_frame_round_trip(status in any::<u16>(), counts in proptest::array::uniform3(-ADC_FULL_SCALE + 1..ADC_FULL_SCALE - 1)) {
        let status = status | 0b111; // data ready on all three channels
        let f = decode_spi_frame(&encode_spi_frame(status, counts)).unwrap();
        prop_assert_eq!((f.status, f.counts), (status, counts));
    }

    /// GLL and GNS positions from exact digits: `ddmm.mmmmm` → degrees to 1e-12.
    #[test]
    fn gll_gns_positions(lat_e5 in 0u64..=540_000_000, lon_e5 in 0u64..=1_080_000_000, south: bool, west: bool, modes in "[ADNEFMPRS]{1,6}") {
        let dm = |v: u64, w: usize| format!("{:0w$}{:02}.{:05}", v / 6_000_000, v / 100_000 % 60, v % 100_000);
        let want_lat = (lat_e5 / 6_000_000) as f64 + (lat_e5 % 6_000_000) as f64 / 6_000_000.0;
        let want_lon = (lon_e5 / 6_000_000) as f64 + (lon_e5 % 6_000_000) as f64 / 6_000_000.0;
        let (ns, ew) = (if south { "S" } else { "N" }, if west { "W" } else { "E" });
        let (lat, lon) = (dm(lat_e5, 2), dm(lon_e5, 3));
        for body in [
            format!("GNGLL,{lat},{ns},{lon},{ew},120000.00,A,A"),
            format!("GNGNS,120000.00,{lat},{ns},{lon},{ew},{modes},10,1.0,100.0,,,"),
        ] {
            let line = format!("${body}*{:02X}", xor_checksum(body.as_bytes()));
            let s = parse_sentence(line.as_bytes()).unwrap();
            let has_fix = !matches!(s, Sentence::Gns(_)) || modes.bytes().any(|c| c != b'N');
            prop_assert_eq!(s.fix().is_some(), has_fix, "{}", line);
            if let Some(f) = s.fix() {
                let sl = if south { -1.0 } else { 1.0 };
                let sw = if west { -1.0 } else { 1.0 };
                prop_assert!((f.lat_deg - sl * want_lat).abs() < 1e-12, "{}", line);
                prop_assert!((f.lon_deg - sw * want_lon).abs() < 1e-12, "{}", line);
            }
        }
    }
}
