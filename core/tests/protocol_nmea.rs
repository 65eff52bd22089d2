//! NMEA reader: exact field decoding, typed errors, fuzzing.

mod common;
use common::Rng;

use magcomp_core::protocol::nmea::*;

fn with_cs(body: &str) -> String {
    let x = body.bytes().fold(0u8, |a, b| a ^ b);
    format!("${body}*{x:02X}\r\n")
}

fn feed(r: &mut NmeaReader, s: &[u8]) -> Vec<Result<Sentence, NmeaError>> {
    s.iter().filter_map(|&b| r.push(b)).collect()
}

#[test]
fn gga_exact_fields() {
    let s = with_cs("GNGGA,171926.25,4404.14063,N,12118.85478,W,1,12,0.91,1147.2,M,-21.3,M,,");
    let mut r = NmeaReader::new();
    let out = feed(&mut r, s.as_bytes());
    assert_eq!(out.len(), 1);
    let Ok(Sentence::Gga(g)) = out[0] else {
        panic!("{:?}", out[0])
    };
    assert_eq!(
        g.time.unwrap().seconds_of_day_s,
        17.0 * 3600.0 + 19.0 * 60.0 + 26.25
    );
    // 44 + 4.14063/60 exactly: compare against the exact rational to 1e-12.
    assert!((g.lat_deg.unwrap() - (44.0 + 414063.0 / 6_000_000.0)).abs() < 1e-12);
    assert!((g.lon_deg.unwrap() + (121.0 + 1885478.0 / 6_000_000.0)).abs() < 1e-12);
    assert_eq!(g.fix_quality, Some(1));
    assert_eq!(g.satellites, Some(12));
    assert_eq!(g.hdop, Some(0.91));
    assert_eq!(g.alt_msl_m, Some(1147.2));
    assert_eq!(g.geoid_sep_m, Some(-21.3));
    assert_eq!(r.stats.ok, 1);
}

#[test]
fn high_precision_coordinates_do_not_drift() {
    // 10 decimal digits of minutes (RTK receivers send 7-8).
    let s = with_cs("GPGGA,000000,8959.9999999999,S,17959.9999999999,E,4,10,0.5,0.0,M,,M,,");
    let Ok(Sentence::Gga(g)) = parse_sentence(s.as_bytes()) else {
        panic!()
    };
    let lat = -(89.0 + 59.9999999999 / 60.0);
    assert!((g.lat_deg.unwrap() - lat).abs() < 1e-12);
    assert!(g.lat_deg.unwrap() > -90.0);
}

#[test]
fn rmc_vtg_gst() {
    let s = with_cs("GPRMC,235959.999,A,3751.65,S,14507.36,E,10.5,54.7,191194,020.3,E,D");
    let Ok(Sentence::Rmc(m)) = parse_sentence(s.as_bytes()) else {
        panic!()
    };
    assert!(m.valid);
    assert_eq!(m.time.unwrap().seconds_of_day_s, 86399.999);
    assert!((m.speed_mps.unwrap() - 10.5 * 1852.0 / 3600.0).abs() < 1e-12);
    assert_eq!(m.track_deg, Some(54.7));
    assert_eq!(
        m.date,
        Some(Date {
            year: 1994,
            month: 11,
            day: 19
        })
    );
    assert_eq!(m.mode, Some(b'D'));
    let s = with_cs("GNVTG,54.7,T,34.4,M,,N,36.0,K,A");
    let Ok(Sentence::Vtg(v)) = parse_sentence(s.as_bytes()) else {
        panic!()
    };
    assert_eq!(v.track_deg, Some(54.7));
    assert!((v.speed_mps.unwrap() - 10.0).abs() < 1e-12);
    assert_eq!(v.mode, Some(b'A'));
    let s = with_cs("GNGST,223745.00,228650,2.5,2.4,126,0.98,1.0,3.1");
    let Ok(Sentence::Gst(g)) = parse_sentence(s.as_bytes()) else {
        panic!()
    };
    assert_eq!(g.sigma_lat_m, Some(0.98));
    assert_eq!(g.sigma_alt_m, Some(3.1));
    // Empty fields → None.
    let s = with_cs("GPRMC,,V,,,,,,,,,,N");
    let Ok(Sentence::Rmc(m)) = parse_sentence(s.as_bytes()) else {
        panic!()
    };
    assert!(!m.valid && m.time.is_none() && m.lat_deg.is_none() && m.speed_mps.is_none());
}

#[test]
fn typed_errors() {
    use NmeaError::*;
    let bad = |b: &str| parse_sentence(with_cs(b).as_bytes());
    assert_eq!(
        bad("GPGGA,120000,9100.0,N,00000.0,E,1,5,1,0,M,0,M,,"),
        Err(InvalidField(Field::Latitude))
    );
    assert_eq!(
        bad("GPGGA,120000,4560.0,N,00000.0,E,1,5,1,0,M,0,M,,"),
        Err(InvalidField(Field::Latitude))
    );
    assert_eq!(
        bad("GPGGA,120000,4500.0,N,18100.0,E,1,5,1,0,M,0,M,,"),
        Err(InvalidField(Field::Longitude))
    );
    assert_eq!(
        bad("GPGGA,120000,4500.0,X,00000.0,E,1,5,1,0,M,0,M,,"),
        Err(InvalidField(Field::Latitude))
    );
    assert_eq!(
        bad("GPGGA,126000,4500.0,N,00000.0,E,1,5,1,0,M,0,M,,"),
        Err(InvalidField(Field::Time))
    );
    assert_eq!(
        bad("GPRMC,120000,A,4500.0,N,00000.0,E,1.0,400,010120,,,A"),
        Err(InvalidField(Field::Track))
    );
    assert_eq!(
        bad("GPRMC,120000,A,4500.0,N,00000.0,E,1.0,40,320120,,,A"),
        Err(InvalidField(Field::Date))
    );
    assert!(matches!(bad("GPGGA,120000"), Err(MissingField(_))));
    assert_eq!(
        parse_sentence(b"$GPGGA,120000,,,,,0,,,,,,,,"),
        Err(MissingChecksum)
    );
    assert!(matches!(
        parse_sentence(b"$GPGGA,120000,,,,,0,,,,,,,,*00"),
        Err(Checksum { .. })
    ));
    // Other sentence types are counted as unsupported, not errors.
    assert!(matches!(
        bad("GPGSV,1,1,00"),
        Ok(Sentence::Unsupported { .. })
    ));
    assert!(matches!(
        bad("PGLOR,4,PWR"),
        Ok(Sentence::Unsupported { .. })
    ));
}

#[test]
fn every_single_byte_corruption_is_rejected() {
    let good = with_cs("GNRMC,171926.00,A,4404.14063,N,12118.85478,W,0.117,,180315,,,A");
    let bytes = good.trim_end().as_bytes();
    let mut rejected = 0;
    for i in 1..bytes.len() {
        for flip in [1u8, 2, 4, 0x10, 0x20] {
            let mut b = bytes.to_vec();
            b[i] ^= flip;
            // Corrupting the terminator positions or `$` changes framing; all must fail.
            assert!(
                parse_sentence(&b).is_err(),
                "accepted corrupted byte {i}: {:?}",
                String::from_utf8_lossy(&b)
            );
            rejected += 1;
        }
    }
    assert_eq!(rejected, (bytes.len() - 1) * 5);
}

#[test]
fn framing_lf_only_overlong_interrupted_garbage() {
    let mut r = NmeaReader::new();
    let a = with_cs("GPVTG,0.00,T,,,0.00,N,0.00,K,A").replace("\r\n", "\n");
    let long = format!("${}\r\n", "A".repeat(200));
    let input = format!("junk{a}$GPGGA,12{a}{long}{a}");
    let out = feed(&mut r, input.as_bytes());
    let kinds: Vec<_> = out
        .iter()
        .map(|o| o.as_ref().map(|s| s.kind()).map_err(|e| *e))
        .collect();
    assert_eq!(
        kinds,
        vec![
            Ok("VTG"),
            Err(NmeaError::Interrupted),
            Ok("VTG"),
            Err(NmeaError::Overlong),
            Ok("VTG")
        ]
    );
    assert_eq!(r.stats.garbage_bytes, 4);
    assert_eq!(r.stats.ok, 3);
    assert_eq!(r.stats.errors(), 2);
}

#[test]
fn fuzz_random_bytes_and_mutated_sentences() {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let mut r = NmeaReader::new();
    let mut results = 0u64;
    let mut dollars = 0u64;
    let good = [
        with_cs("GNGGA,171926.00,4404.14063,N,12118.85478,W,1,12,0.91,1147.2,M,-21.3,M,,"),
        with_cs("GNRMC,171926.00,A,4404.14063,N,12118.85478,W,0.117,,180315,,,A"),
        with_cs("GNVTG,,T,,M,0.117,N,0.216,K,A"),
        with_cs("GNGST,223745.00,228650,2.5,2.4,126,0.98,1.0,3.1"),
    ];
    let mut n_bytes = 0u64;
    let mut clean_ok = 0u64;
    while n_bytes < 1_500_000 {
        let mode = rng.next() % 4;
        let chunk: Vec<u8> = match mode {
            // Pure noise, biased towards NMEA-ish characters.
            0 => (0..rng.next() % 200)
                .map(|_| {
                    let v = rng.next();
                    match v % 8 {
                        0 => b'$',
                        1 => b',',
                        2 => b'\n',
                        3 => b'*',
                        _ => (v >> 8) as u8,
                    }
                })
                .collect(),
            // A valid sentence.
            1 => {
                clean_ok += 1;
                good[(rng.next() % 4) as usize].as_bytes().to_vec()
            }
            // A mutated sentence.
            _ => {
                let mut s = good[(rng.next() % 4) as usize].as_bytes().to_vec();
                let i = (rng.next() as usize) % s.len();
                s[i] = rng.next() as u8;
                s
            }
        };
        // Starting a clean sentence mid-garbage would be interrupted: count what the reader
        // must produce from the bytes themselves.
        for &b in &chunk {
            dollars += (b == b'$') as u64;
            if r.push(b).is_some() {
                results += 1;
            }
        }
        n_bytes += chunk.len() as u64;
    }
    assert_eq!(
        results + r.in_sentence() as u64,
        dollars,
        "one result per `$`"
    );
    let st = r.stats;
    assert_eq!((st.ok + st.unsupported + st.errors()) as u64, results);
    assert!(
        st.ok as u64 > clean_ok / 4,
        "valid sentences still decoded: {st:?}"
    );
    assert!(st.checksum_errors > 0 && st.garbage_bytes > 0 && st.interrupted > 0);
    println!("{n_bytes} bytes: {st:?}");
}

#[test]
fn gll_fields_status_and_mode() {
    // NMEA 2.3+: time, status and mode after the position.
    let s = with_cs("GNGLL,4404.14066,N,12118.85481,W,171925.00,A,D");
    let Ok(Sentence::Gll(g)) = parse_sentence(s.as_bytes()) else {
        panic!()
    };
    assert_eq!(g.talker, Talker(*b"GN"));
    assert!((g.lat_deg.unwrap() - (44.0 + 414_066.0 / 6_000_000.0)).abs() < 1e-12);
    assert!((g.lon_deg.unwrap() + (121.0 + 1_885_481.0 / 6_000_000.0)).abs() < 1e-12);
    assert_eq!(g.time.unwrap().seconds_of_day_s, 62_365.0);
    assert!(g.valid && g.mode == Some(b'D') && g.has_fix());
    let f = Sentence::Gll(g).fix().unwrap();
    assert_eq!(
        (f.lat_deg, f.lon_deg, f.alt_msl_m),
        (g.lat_deg.unwrap(), g.lon_deg.unwrap(), None)
    );
    // Status V, or status A with mode N: decoded, no fix.
    for body in [
        "GPGLL,4404.14066,N,12118.85481,W,171925.00,V,A",
        "GPGLL,4404.14066,N,12118.85481,W,171925.00,A,N",
        "GPGLL,,,,,171925.00,V,N",
    ] {
        let s = parse_sentence(with_cs(body).as_bytes()).unwrap();
        assert_eq!(s.kind(), "GLL", "{body}");
        assert!(s.is_position() && s.fix().is_none(), "{body}");
    }
    // NMEA 1.x: ends after the longitude; no status means no fix is claimed.
    let Ok(Sentence::Gll(g)) = parse_sentence(with_cs("GPGLL,4916.45,N,12311.12,W").as_bytes())
    else {
        panic!()
    };
    assert!(g.lat_deg.is_some() && g.time.is_none() && !g.valid && !g.has_fix());
    use NmeaError::*;
    let bad = |b: &str| parse_sentence(with_cs(b).as_bytes());
    assert_eq!(
        bad("GPGLL,4404.1,N,12118.8,W,171925.00,X,A"),
        Err(InvalidField(Field::Status))
    );
    assert_eq!(
        bad("GPGLL,4404.1,N,12118.8,W,171925.00,A,AD"),
        Err(InvalidField(Field::Mode))
    );
    assert_eq!(bad("GPGLL,4404.1,N"), Err(MissingField(Field::Longitude)));
    assert_eq!(
        bad("GPGLL,4404.1,N,12118.8,W,251925.00,A,A"),
        Err(InvalidField(Field::Time))
    );
}

#[test]
fn gns_multi_constellation_modes() {
    // GPS differential, GLONASS autonomous, Galileo not used, BeiDou autonomous; NMEA 4.1
    // navigational status S (safe).
    let s = with_cs("GNGNS,014035.00,4332.69262,S,17235.48549,E,DANA,13,0.9,2000.5,-12.3,,,S");
    let Ok(Sentence::Gns(g)) = parse_sentence(s.as_bytes()) else {
        panic!("{:?}", parse_sentence(s.as_bytes()))
    };
    assert_eq!(g.talker, Talker(*b"GN"));
    assert_eq!(
        g.time.unwrap().seconds_of_day_s,
        1.0 * 3600.0 + 40.0 * 60.0 + 35.0
    );
    assert!((g.lat_deg.unwrap() + (43.0 + 3_269_262.0 / 100_000.0 / 60.0)).abs() < 1e-12);
    assert!((g.lon_deg.unwrap() - (172.0 + 3_548_549.0 / 100_000.0 / 60.0)).abs() < 1e-12);
    assert_eq!(g.modes.as_bytes(), b"DANA");
    assert_eq!((g.satellites, g.hdop), (Some(13), Some(0.9)));
    assert_eq!((g.alt_msl_m, g.geoid_sep_m), (Some(2000.5), Some(-12.3)));
    assert_eq!(g.nav_status, Some(b'S'));
    let f = Sentence::Gns(g).fix().unwrap();
    assert_eq!(f.alt_msl_m, Some(2000.5));
    // Every talker a multi-constellation receiver uses decodes the same way.
    for talker in ["GN", "GP", "GL", "GA", "GB", "BD", "GQ", "GI"] {
        let body = format!("{talker}GNS,014035.00,4332.69262,S,17235.48549,E,A,13,0.9,2000.5,,,");
        let s = parse_sentence(with_cs(&body).as_bytes()).unwrap();
        assert!(s.fix().is_some(), "{body}");
    }
    // No fix: every constellation N, an empty mode, or navigational status V (unsafe).
    for body in [
        "GNGNS,014035.00,4332.69262,S,17235.48549,E,NN,00,,,,,",
        "GNGNS,014035.00,4332.69262,S,17235.48549,E,NNNNNN,00,,,,,",
        "GNGNS,014035.00,,,,,,00,,,,,",
        "GNGNS,014035.00,4332.69262,S,17235.48549,E,AA,13,0.9,2000.5,,,,V",
    ] {
        let s = parse_sentence(with_cs(body).as_bytes()).unwrap();
        assert_eq!(s.kind(), "GNS", "{body}");
        assert!(s.is_position() && s.fix().is_none(), "{body}");
    }
    use NmeaError::*;
    let bad = |b: &str| parse_sentence(with_cs(b).as_bytes());
    assert_eq!(
        bad("GNGNS,014035.00,4332.69,S,17235.48,E,AAAAAAAAA,13,0.9,20.5,,,"),
        Err(InvalidField(Field::Mode))
    );
    assert_eq!(
        bad("GNGNS,014035.00,4332.69,S,17235.48,E,A1,13,0.9,20.5,,,"),
        Err(InvalidField(Field::Mode))
    );
    assert_eq!(
        bad("GNGNS,014035.00,4332.69,S,17235.48,E,AA,13,0.9,200000,,,"),
        Err(InvalidField(Field::Altitude))
    );
    assert_eq!(
        bad("GNGNS,014035.00,4332.69,S,17235.48,E,AA,13,0.9,20.5,,,,X"),
        Err(InvalidField(Field::NavStatus))
    );
    assert_eq!(
        bad("GNGNS,014035.00,4332.69,S,17235.48,E,AA,13,0.9"),
        Err(MissingField(Field::Altitude))
    );
}
