//! Sensor aligner, and a no-panic fuzz of every slice decoder.

mod common;
use common::Rng;

use magcomp_core::protocol::aligner::*;
use magcomp_core::protocol::nmea::{parse_sentence, Sentence};
use magcomp_core::protocol::scalar::ScalarError;
use magcomp_core::{Flags, MagCounts};

fn with_cs(body: &str) -> Vec<u8> {
    let x = body.bytes().fold(0u8, |a, b| a ^ b);
    format!("${body}*{x:02X}\r\n").into_bytes()
}

fn gga() -> Sentence {
    parse_sentence(&with_cs(
        "GNGGA,171926.00,4500.00000,N,00700.00000,E,1,12,0.91,1000.0,M,47.0,M,,",
    ))
    .unwrap()
}
fn rmc(speed_kn: &str, track: &str) -> Sentence {
    parse_sentence(&with_cs(&format!(
        "GNRMC,171926.00,A,4500.00000,N,00700.00000,E,{speed_kn},{track},180315,,,A"
    )))
    .unwrap()
}

#[test]
fn flux_interpolation_and_staleness() {
    let mut a = Aligner::new(AlignerConfig::default());
    // No fluxgate yet: NaN and stale, no GPS.
    let s = a.push_scalar(1_000, Some(MagCounts(536_204_401)));
    assert!(s.flux_nt[0].is_nan());
    assert!(s.flags.contains(Flags::FLUX_STALE) && s.flags.contains(Flags::NO_GPS));
    assert_eq!(s.mag, Some(MagCounts(536_204_401)));
    a.push_flux(10_000, [100.0, 200.0, 300.0]);
    a.push_flux(20_000, [200.0, 400.0, 600.0]);
    a.push_flux(30_000, [300.0, 600.0, 900.0]);
    // Between two frames: linear interpolation.
    let s = a.push_scalar(12_500, Some(MagCounts(1)));
    assert_eq!(s.flux_nt, [125.0, 250.0, 375.0]);
    assert!(!s.flags.contains(Flags::FLUX_STALE));
    assert_eq!(s.t_s, 0.0125);
    // After the last frame: held; stale beyond 50 ms.
    let s = a.push_scalar(79_000, Some(MagCounts(1)));
    assert_eq!(s.flux_nt, [300.0, 600.0, 900.0]);
    assert!(!s.flags.contains(Flags::FLUX_STALE));
    let s = a.push_scalar(80_001, Some(MagCounts(1)));
    assert!(s.flags.contains(Flags::FLUX_STALE));
    // Interpolating across a gap larger than the limit is flagged.
    a.push_flux(200_000, [0.0; 3]);
    let s = a.push_scalar(100_000, Some(MagCounts(1)));
    assert!(s.flags.contains(Flags::FLUX_STALE));
}

#[test]
fn gps_hold_extrapolate_stale() {
    let mut a = Aligner::new(AlignerConfig::default());
    a.push_flux(0, [1.0; 3]);
    a.push_nmea(0, &gga());
    // 1 knot due north.
    a.push_nmea(0, &rmc("1.0", "0.0"));
    let s = a.push_scalar(0, Some(MagCounts(1)));
    assert_eq!((s.lat_deg, s.lon_deg, s.alt_m), (45.0, 7.0, 1000.0));
    assert!((s.ground_speed_mps - 0.514_444).abs() < 1e-5);
    assert!(!s.flags.contains(Flags::NO_GPS));
    // 1 s later: moved 0.514 m north.
    let s = a.push_scalar(1_000_000, Some(MagCounts(1)));
    let dn_m = (s.lat_deg - 45.0).to_radians() * 6_371_008.8;
    assert!((dn_m - 0.514_444).abs() < 1e-4, "{dn_m}");
    assert_eq!(s.lon_deg, 7.0);
    assert!(!s.flags.contains(Flags::NO_GPS));
    // Beyond 2 s: held/extrapolated but flagged.
    let s = a.push_scalar(2_000_001, Some(MagCounts(1)));
    assert!(s.flags.contains(Flags::NO_GPS));
    // Fix lost (RMC V): flagged immediately.
    a.push_nmea(2_100_000, &rmc("1.0", "0.0"));
    let v = parse_sentence(&with_cs("GNRMC,171928.00,V,,,,,,,180315,,,N")).unwrap();
    a.push_nmea(2_200_000, &v);
    let s = a.push_scalar(2_200_000, Some(MagCounts(1)));
    assert!(s.flags.contains(Flags::NO_GPS));
}

#[test]
fn parse_errors_flag_next_sample_only_and_one_sample_per_scalar() {
    let mut a = Aligner::new(AlignerConfig::default());
    a.note_parse_error();
    let s = a.push_scalar(0, Some(MagCounts(1)));
    assert!(s.flags.contains(Flags::PARSE_ERROR));
    let s = a.push_scalar(100, Some(MagCounts(1)));
    assert!(!s.flags.contains(Flags::PARSE_ERROR));
    let s = a.push_scalar_result(200, Err(ScalarError::OutOfRange));
    assert!(s.flags.contains(Flags::PARSE_ERROR) && s.flags.contains(Flags::MAG_MISSING));
    assert_eq!(s.mag, None);
    assert_eq!(a.samples, 3);
}

#[test]
fn slice_decoders_never_panic() {
    use magcomp_core::protocol::*;
    let mut rng = Rng(7);
    let alphabet = b"$*,.-+0123456789ABCDEFEMCRECMDQF= \r\n#gpsflux";
    let mut data = [0u8; 512];
    let mut coef = [0f32; 21];
    let mut total = 0usize;
    while total < 1_000_000 {
        let n = (rng.next() % 160) as usize;
        let v: Vec<u8> = (0..n)
            .map(|_| {
                let r = rng.next();
                // One byte in three fully random, the rest from the protocols' alphabet.
                match r % 3 {
                    0 => (r >> 8) as u8,
                    _ => alphabet[(r >> 8) as usize % alphabet.len()],
                }
            })
            .collect();
        total += n;
        let _ = nmea::parse_sentence(&v);
        let _ = scalar::parse_scalar_line(&v, &Default::default());
        let _ = fluxgate::parse_ascii_line(&v);
        let _ = fluxgate::decode_spi_frame(&v);
        let _ = record::decode_record(&v);
        let _ = command::parse_command(&v, 21);
        let _ = command::decode_blob(&v, 0, &mut coef);
        let _ = capture::decode_line(&v, &mut data);
        let _ = common::parse_float_field(&v);
    }
}

#[test]
fn line_readers_fuzz_account_for_every_line() {
    use magcomp_core::protocol::{
        command::CommandReader, fluxgate::FluxAsciiReader, scalar::ScalarReader,
    };
    let mut rng = Rng(99);
    let mut s = ScalarReader::new(Default::default());
    let mut f = FluxAsciiReader::new();
    let mut c = CommandReader::new(21);
    let alphabet = b"$*,.-0123456789EFQ=MCMDSAVE\r\n";
    let (mut lines, mut rs, mut rf, mut rc) = (0u64, 0u64, 0u64, 0u64);
    let mut pending = false;
    for i in 0..1_200_000u64 {
        let r = rng.next();
        let b = match r % 4 {
            0 => (r >> 8) as u8,
            _ => alphabet[(r >> 8) as usize % alphabet.len()],
        };
        // Inject long runs without a newline now and then to exercise the overlong paths.
        let b = if i % 50_000 < 300 && (b == b'\n' || b == b'\r') {
            b'7'
        } else {
            b
        };
        if b == b'\n' || b == b'\r' {
            lines += pending as u64;
            pending = false;
        } else {
            pending = true;
        }
        rs += s.push(b).is_some() as u64;
        rf += f.push(b).is_some() as u64;
        rc += c.push(b).is_some() as u64;
    }
    assert_eq!((rs, rf, rc), (lines, lines, lines));
    assert_eq!(
        (s.stats.ok + s.stats.errors + s.stats.overlong) as u64,
        lines
    );
    assert_eq!((f.stats.ok + f.stats.errors) as u64, lines);
    assert_eq!((c.ok + c.errors) as u64, lines);
    assert!(s.stats.overlong > 0);
}

#[test]
fn state_sizes_fit_the_board() {
    use core::mem::size_of;
    use magcomp_core::protocol::*;
    let sizes = [
        ("NmeaReader", size_of::<nmea::NmeaReader>()),
        ("ScalarReader", size_of::<scalar::ScalarReader>()),
        ("FluxAsciiReader", size_of::<fluxgate::FluxAsciiReader>()),
        ("CommandReader", size_of::<command::CommandReader>()),
        ("Aligner", size_of::<Aligner>()),
        ("Sentence", size_of::<nmea::Sentence>()),
    ];
    for (n, s) in sizes {
        println!("{n}: {s} bytes");
    }
    let total: usize = sizes.iter().map(|s| s.1).sum();
    assert!(total < 1024, "protocol state {total} bytes");
}

#[test]
fn gll_and_gns_positions_reach_the_aligner_like_gga_rmc() {
    let gll = |status: &str, mode: &str| {
        parse_sentence(&with_cs(&format!(
            "GNGLL,4530.00000,N,00730.00000,E,171927.00,{status},{mode}"
        )))
        .unwrap()
    };
    let gns = |modes: &str| {
        parse_sentence(&with_cs(&format!(
            "GNGNS,171928.00,4600.00000,N,00800.00000,E,{modes},12,0.9,1500.0,47.0,,,"
        )))
        .unwrap()
    };
    let mut a = Aligner::new(AlignerConfig::default());
    a.push_flux(0, [1.0; 3]);
    a.push_nmea(0, &gga());
    a.push_nmea(0, &rmc("0.0", "0.0"));
    // GLL: the new position, the height held from the GGA (GLL has none).
    a.push_nmea(1_000_000, &gll("A", "A"));
    let s = a.push_scalar(1_000_000, Some(MagCounts(1)));
    assert_eq!((s.lat_deg, s.lon_deg, s.alt_m), (45.5, 7.5, 1000.0));
    assert!(!s.flags.contains(Flags::NO_GPS));
    // GNS: position and its own height.
    a.push_nmea(2_000_000, &gns("AN"));
    let s = a.push_scalar(2_000_000, Some(MagCounts(1)));
    assert_eq!((s.lat_deg, s.lon_deg, s.alt_m), (46.0, 8.0, 1500.0));
    assert!(!s.flags.contains(Flags::NO_GPS));
    // No fix from either: flagged at once, the last good position held.
    for no_fix in [gll("V", "A"), gll("A", "N"), gns("NN"), gns("NNNN")] {
        a.push_nmea(2_500_000, &gns("AA"));
        assert!(!a
            .push_scalar(2_500_000, Some(MagCounts(1)))
            .flags
            .contains(Flags::NO_GPS));
        a.push_nmea(2_600_000, &no_fix);
        let s = a.push_scalar(2_600_000, Some(MagCounts(1)));
        assert!(s.flags.contains(Flags::NO_GPS), "{no_fix:?}");
        assert_eq!((s.lat_deg, s.lon_deg), (46.0, 8.0));
    }
}

/// Scalar at 10 Hz, fluxgate frames at `flux_hz` arriving `phase_us` after each scalar
/// tick (mod the period), frame `lost` never arriving: the samples flagged
/// DERIVATIVE_DEGRADED.
fn lost_frame_flags(flux_hz: u64, phase_us: u64, lost: Option<u64>) -> Vec<usize> {
    let period = 1_000_000 / flux_hz;
    let mut a = Aligner::new(AlignerConfig {
        flux_stale_us: period * 5 / 2,
        gps_stale_us: 2_000_000,
        extrapolate_gps: false,
        flux_period_us: period,
    });
    let mut frame = 0u64;
    let mut flagged = Vec::new();
    for k in 1..100u64 {
        let t = k * 100_000;
        // Every frame due before this scalar tick (they arrive in time order).
        while frame * period + phase_us <= t {
            if Some(frame) != lost {
                a.push_flux(frame * period + phase_us, [frame as f32, 0.0, 40_000.0]);
            }
            frame += 1;
        }
        let s = a.push_scalar(t, Some(MagCounts(1)));
        if s.flags.contains(Flags::DERIVATIVE_DEGRADED) {
            flagged.push(k as usize);
        }
    }
    flagged
}

#[test]
fn a_sample_held_across_a_lost_fluxgate_frame_is_flagged_at_any_phase() {
    // Equal rates: the normal age of the held frame is the sensors' phase (here 2–98 ms);
    // the one lost frame makes the next sample's frame a period older, whatever the phase.
    for phase_us in [2_000, 30_000, 70_000, 98_000] {
        assert_eq!(
            lost_frame_flags(10, phase_us, None),
            Vec::<usize>::new(),
            "{phase_us}"
        );
        // Frame 40 (due at 4.0 s + phase) lost: the scalar at 4.1 s (k = 41) holds frame 39.
        assert_eq!(
            lost_frame_flags(10, phase_us, Some(40)),
            vec![41],
            "{phase_us}"
        );
    }
    // A 100 Hz fluxgate: no false flag however the ages spread over the period; a lost
    // frame just before a scalar tick is caught.
    for phase_us in [1_000, 5_000, 9_000] {
        assert_eq!(
            lost_frame_flags(100, phase_us, None),
            Vec::<usize>::new(),
            "{phase_us}"
        );
    }
    assert_eq!(lost_frame_flags(100, 5_000, Some(399)), vec![40]);
}
