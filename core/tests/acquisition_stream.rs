//! `Acquisition`: sensor bytes in, one record per scalar line out, flagged when degraded.

#[path = "common/acq_run.rs"]
mod acq_run;
use acq_run::run;

use magcomp_core::acquisition::{compensator_config, AcqConfig, Acquisition};
use magcomp_core::model::Model;
use magcomp_core::protocol::capture::Port;
use magcomp_core::protocol::common::xor_checksum;
use magcomp_core::protocol::fluxgate::encode_spi_frame;
use magcomp_core::protocol::record::Record;
use magcomp_core::{Compensator, Flags};

const RATE_HZ: f64 = 10.0;
const GPS_HZ: f64 = 5.0;
const TOD0_S: f64 = 45_000.0;

type Acq = Acquisition<'static, 32, 16>;

fn acq() -> Acq {
    let comp = Compensator::new(Model::paper(), compensator_config(RATE_HZ as f32, 16)).unwrap();
    Acquisition::new(AcqConfig::new(RATE_HZ, RATE_HZ, GPS_HZ), comp).unwrap()
}

fn nmea(body: &str) -> Vec<u8> {
    format!("${body}*{:02X}\r\n", xor_checksum(body.as_bytes())).into_bytes()
}

fn hms(tod: f64) -> String {
    let cs = (tod * 100.0).round() as u64;
    let s = cs / 100;
    format!(
        "{:02}{:02}{:02}.{:02}",
        s / 3600,
        s / 60 % 60,
        s % 60,
        cs % 100
    )
}

fn gps_sentences(tod: f64, fix: bool) -> Vec<u8> {
    let mut v = Vec::new();
    if fix {
        v.extend(nmea(&format!(
            "GPGGA,{},4518.00000,N,07542.00000,W,1,12,0.8,3000.0,M,-34.0,M,,",
            hms(tod)
        )));
        v.extend(nmea(&format!(
            "GPRMC,{},A,4518.00000,N,07542.00000,W,116.630,45.00,211126,,,A",
            hms(tod)
        )));
    } else {
        v.extend(nmea(&format!("GPGGA,{},,,,,0,00,99.9,,,,,,", hms(tod))));
        v.extend(nmea(&format!("GPRMC,{},V,,,,,,,211126,,,N", hms(tod))));
    }
    v
}

/// Field vector of a slowly rolling aircraft, body frame (nT).
fn flux_at(k: usize) -> [f64; 3] {
    let a = k as f64 * 0.05;
    [
        20_000.0 + 3000.0 * a.sin(),
        1000.0 * a.cos(),
        45_000.0 - 1000.0 * a.sin(),
    ]
}

struct Stream {
    chunks: Vec<(Port, Vec<u8>)>,
    mags: Vec<i64>,
}

/// `n` epochs: fluxgate (ASCII or SPI) and GPS before the scalar of the same epoch.
fn stream(
    n: usize,
    spi: bool,
    flux_gap: Option<(usize, usize)>,
    gps_gap: Option<(usize, usize)>,
) -> Stream {
    stream_from(n, spi, flux_gap, gps_gap, gps_sentences)
}

/// [`stream`] with another receiver's sentences (`receiver(tod, fix)`).
fn stream_from(
    n: usize,
    spi: bool,
    flux_gap: Option<(usize, usize)>,
    gps_gap: Option<(usize, usize)>,
    receiver: fn(f64, bool) -> Vec<u8>,
) -> Stream {
    let mut chunks = Vec::new();
    let mut mags = Vec::new();
    let lsb = 100_000.0 / (1u32 << 23) as f64;
    let gps_every = (RATE_HZ / GPS_HZ) as usize;
    for k in 0..n {
        let inside = |g: Option<(usize, usize)>| g.is_some_and(|(a, b)| (a..b).contains(&k));
        if !inside(flux_gap) {
            let f = flux_at(k);
            if spi {
                let c = f.map(|v| (v / lsb).round() as i32);
                chunks.push((Port::Flux, encode_spi_frame(0x0007, c).to_vec()));
            } else {
                let line = format!("{:.3},{:.3},{:.3}\r\n", f[0], f[1], f[2]);
                chunks.push((Port::Flux, line.into_bytes()));
            }
        }
        if k % gps_every == 0 {
            let tod = TOD0_S + k as f64 / RATE_HZ;
            chunks.push((Port::Gps, receiver(tod, !inside(gps_gap))));
        }
        let m = 536_200_000 + (k as i64 * 37) % 5000;
        mags.push(m);
        let line = format!("{}.{:04}\r\n", m / 10_000, m % 10_000);
        chunks.push((Port::Scalar, line.into_bytes()));
    }
    Stream { chunks, mags }
}

fn count(recs: &[Record], bit: u16) -> usize {
    recs.iter().filter(|r| r.flags.contains(bit)).count()
}

fn assert_contiguous(recs: &[Record]) {
    for (i, r) in recs.iter().enumerate() {
        assert_eq!(r.seq as usize, i, "sequence");
    }
}

#[test]
fn clean_stream_one_record_per_line_exact_mag_gps_time() {
    let s = stream(300, false, None, None);
    let mut a = acq();
    let recs = run(&mut a, &s.chunks);
    assert_eq!(recs.len(), 300);
    assert_contiguous(&recs);
    for (r, m) in recs.iter().zip(&s.mags) {
        assert_eq!(r.mag.map(|c| c.0), Some(*m));
    }
    // Anchored to the first GGA: the first sample is at its time of day, then 0.1 s steps.
    assert!((recs[0].t_s - TOD0_S).abs() < 1e-9, "{}", recs[0].t_s);
    assert!((recs[299].t_s - (TOD0_S + 29.9)).abs() < 1e-6);
    assert_eq!(count(&recs, Flags::FLUX_STALE), 0);
    assert_eq!(count(&recs, Flags::NO_GPS), 0);
    assert_eq!(count(&recs, Flags::PARSE_ERROR), 0);
    let c = a.counters();
    assert_eq!((c.scalar_lines, c.records, c.errors()), (300, 300, 0));
    assert_eq!(c.flux_frames, 300);
    assert_eq!(c.gps_sentences, 300); // 150 epochs × GGA + RMC
                                      // The filter ran: finite interference and exact compensated = mag − round(interf).
    let r = &recs[200];
    assert!(r.interference_nt.is_finite());
    let want = r.mag.unwrap().minus_nt(r.interference_nt);
    assert_eq!(r.compensated, Some(want));
}

#[test]
fn spi_frames_feed_the_same_samples_as_ascii_lines() {
    let mut a = acq();
    let ascii = run(&mut a, &stream(200, false, None, None).chunks);
    let mut b = acq();
    let spi = run(&mut b, &stream(200, true, None, None).chunks);
    assert_eq!(ascii.len(), 200);
    assert_eq!(spi.len(), 200);
    assert_eq!(b.counters().flux_frames, 200);
    assert_eq!(b.flux_stats().ok, 200);
    assert_eq!(b.counters().errors(), 0);
    for (x, y) in ascii.iter().zip(&spi) {
        assert_eq!(x.flags, y.flags);
        assert_eq!(x.mag, y.mag);
        assert!(y.interference_nt.is_finite());
    }
    // A frame with a bad CRC is a counted fluxgate error and flags the next record.
    let mut f = encode_spi_frame(0x0007, [1, 2, 3]);
    f[4] ^= 1;
    b.push_flux_frame(&f);
    assert_eq!(b.counters().flux_errors, 1);
}

#[test]
fn chunking_does_not_change_records() {
    let s = stream(120, false, None, None);
    let whole = run(&mut acq(), &s.chunks);
    // Same bytes in the same order, one byte per chunk.
    let bytes: Vec<(Port, Vec<u8>)> = s
        .chunks
        .iter()
        .flat_map(|(p, b)| b.iter().map(move |x| (*p, vec![*x])))
        .collect();
    let split = run(&mut acq(), &bytes);
    assert_eq!(whole.len(), split.len());
    for (a, b) in whole.iter().zip(&split) {
        assert_eq!(a.seq, b.seq);
        assert_eq!(a.t_s.to_bits(), b.t_s.to_bits());
        assert_eq!(a.compensated, b.compensated);
        assert_eq!(a.flags, b.flags);
    }
}

#[test]
fn fluxgate_dropout_is_flagged_stale_and_no_sample_is_lost() {
    let s = stream(300, false, Some((100, 150)), None);
    let recs = run(&mut acq(), &s.chunks);
    assert_eq!(recs.len(), 300);
    assert_contiguous(&recs);
    let stale: Vec<usize> = recs
        .iter()
        .enumerate()
        .filter(|(_, r)| r.flags.contains(Flags::FLUX_STALE))
        .map(|(i, _)| i)
        .collect();
    // Stale once the held frame (sample 99's) is older than 2.5 periods: samples 102…149.
    assert_eq!(stale.first(), Some(&102));
    assert_eq!(stale.last(), Some(&149));
    assert_eq!(stale.len(), 48);
    assert!(recs[100..150].iter().all(|r| r.mag.is_some()));
}

#[test]
fn gps_outage_is_flagged_and_time_stays_evenly_spaced() {
    let s = stream(300, false, None, Some((100, 160)));
    let recs = run(&mut acq(), &s.chunks);
    assert_eq!(recs.len(), 300);
    let no_gps: Vec<usize> = recs
        .iter()
        .enumerate()
        .filter(|(_, r)| r.flags.contains(Flags::NO_GPS))
        .map(|(i, _)| i)
        .collect();
    // The receiver reports "no fix" (GGA quality 0, RMC V) at sample 100: flagged at once,
    // until the first valid fix at 160.
    assert_eq!(no_gps, (100..160).collect::<Vec<_>>());
    for w in recs.windows(2) {
        assert!((w[1].t_s - w[0].t_s - 0.1).abs() < 1e-6);
    }
}

/// A receiver that reports positions in GLL only (marine, older units).
fn gll_only(tod: f64, fix: bool) -> Vec<u8> {
    match fix {
        true => nmea(&format!(
            "GPGLL,4518.00000,N,07542.00000,W,{},A,A",
            hms(tod)
        )),
        false => nmea(&format!("GPGLL,,,,,{},V,N", hms(tod))),
    }
}

/// A multi-constellation receiver that reports GNS only (mode per constellation).
fn gns_only(tod: f64, fix: bool) -> Vec<u8> {
    match fix {
        true => nmea(&format!(
            "GNGNS,{},4518.00000,N,07542.00000,W,DAAN,14,0.8,3000.0,-34.0,,,S",
            hms(tod)
        )),
        false => nmea(&format!("GNGNS,{},,,,,NNNN,00,,,,,,V", hms(tod))),
    }
}

#[test]
fn gll_or_gns_only_receivers_give_position_time_and_outages() {
    for (name, receiver) in [
        ("GLL", gll_only as fn(f64, bool) -> Vec<u8>),
        ("GNS", gns_only),
    ] {
        let s = stream_from(300, false, None, Some((100, 160)), receiver);
        let mut a = acq();
        let recs = run(&mut a, &s.chunks);
        assert_eq!(recs.len(), 300, "{name}");
        // GPS time from the first fix, as with GGA.
        assert!(
            (recs[0].t_s - TOD0_S).abs() < 1e-9,
            "{name}: {}",
            recs[0].t_s
        );
        for w in recs.windows(2) {
            assert!((w[1].t_s - w[0].t_s - 0.1).abs() < 1e-6, "{name}");
        }
        // "No fix" (GLL V, GNS NNNN) flagged from sample 100 until the fix returns at 160.
        let no_gps: Vec<usize> = (0..300)
            .filter(|&i| recs[i].flags.contains(Flags::NO_GPS))
            .collect();
        assert_eq!(no_gps, (100..160).collect::<Vec<_>>(), "{name}");
        let c = a.counters();
        assert_eq!((c.gps_sentences, c.gps_errors), (150, 0), "{name}");
    }
}

#[test]
fn gps_silence_goes_stale_after_two_and_a_half_periods() {
    // Sentences stop altogether (antenna cable): stale after 2.5 GPS periods = 0.5 s.
    let mut s = stream(300, false, None, None);
    let mut k = 0usize;
    s.chunks.retain(|(p, _)| {
        if *p == Port::Scalar {
            k += 1;
        }
        !(*p == Port::Gps && (100..160).contains(&k))
    });
    let recs = run(&mut acq(), &s.chunks);
    assert_eq!(recs.len(), 300);
    let first = recs.iter().position(|r| r.flags.contains(Flags::NO_GPS));
    let n = count(&recs, Flags::NO_GPS);
    assert_eq!(first, Some(104));
    assert_eq!(n, 56);
}

struct XorShift(u64);
impl XorShift {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    /// Uniform in 0..n (modulo bias is irrelevant here).
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

#[test]
fn corrupted_bytes_give_flagged_records_and_counted_errors_never_a_lost_sample() {
    let s = stream(1000, false, None, None);
    let mut rng = XorShift(0x9E37_79B9_7F4A_7C15);
    let mut chunks = s.chunks.clone();
    let (mut total, mut hit) = (0usize, 0usize);
    for (_, bytes) in chunks.iter_mut() {
        for b in bytes.iter_mut() {
            total += 1;
            // 2 % of bytes replaced; line ends are kept (they frame the samples), and no
            // byte becomes one.
            if *b != b'\r' && *b != b'\n' && rng.below(50) == 0 {
                let mut v = (rng.next() & 0xFF) as u8;
                if v == b'\r' || v == b'\n' {
                    v = b'#';
                }
                if v != *b {
                    hit += 1;
                }
                *b = v;
            }
        }
    }
    assert!(hit as f64 / total as f64 > 0.015, "{hit}/{total}");
    let mut a = acq();
    let recs = run(&mut a, &chunks);
    assert_eq!(recs.len(), 1000);
    assert_contiguous(&recs);
    let c = a.counters();
    assert!(c.scalar_errors > 50, "{c:?}");
    assert!(c.flux_errors > 50, "{c:?}");
    assert!(c.gps_errors > 50, "{c:?}");
    // Every rejected scalar line is one record with no mag, flagged.
    assert_eq!(count(&recs, Flags::MAG_MISSING) as u32, c.scalar_errors);
    assert!(recs
        .iter()
        .filter(|r| r.mag.is_none())
        .all(|r| r.flags.contains(Flags::MAG_MISSING | Flags::PARSE_ERROR)));
    assert_eq!(c.parse_error as usize, count(&recs, Flags::PARSE_ERROR));
    assert!(c.parse_error >= c.scalar_errors);
    // Values stay finite where the scalar was read.
    assert!(recs
        .iter()
        .filter(|r| r.mag.is_some())
        .all(|r| r.interference_nt.is_finite()));
}

#[test]
fn random_bytes_never_panic_and_every_line_is_a_record() {
    let mut rng = XorShift(12345);
    for round in 0..20 {
        let mut a = acq();
        let mut out = 0usize;
        for _ in 0..20_000 {
            let x = rng.next();
            let b = (x >> 8) as u8;
            let port = match x % 3 {
                0 => Port::Scalar,
                1 => Port::Flux,
                _ => Port::Gps,
            };
            // Some rounds bias towards plausible characters to reach the deeper parsers.
            let b = if round % 2 == 0 {
                b"0123456789.,$*\r\nGPAF-"[(b as usize) % 21]
            } else {
                b
            };
            // push_bytes also hands on a merged line's further samples
            a.push_bytes(port, &[b], |_| out += 1);
            if rng.below(997) == 0 {
                let mut f = [0u8; 15];
                for v in f.iter_mut() {
                    *v = rng.next() as u8;
                }
                a.push_flux_frame(&f[..(x % 16) as usize]);
            }
        }
        while a.flush().is_some() {
            out += 1;
        }
        let c = a.counters();
        assert_eq!(out as u32, c.scalar_lines);
        assert_eq!(c.records, c.scalar_lines);
        let st = a.scalar_stats();
        assert_eq!(st.ok + st.errors + st.overlong + st.merged, c.scalar_lines);
    }
}

#[test]
fn bad_rates_are_rejected() {
    for r in [0.0, -1.0, f64::NAN, f64::INFINITY, 1e9] {
        let comp = Compensator::new(Model::paper(), compensator_config(10.0, 16)).unwrap();
        assert!(Acquisition::<'static, 32, 16>::new(AcqConfig::new(r, 10.0, 1.0), comp).is_err());
    }
}

#[test]
fn survey_mode_and_coefficients_pass_through() {
    let mut a = acq();
    let c: Vec<f32> = (0..16).map(|i| i as f32 * 0.5).collect();
    a.set_coefficients(&c).unwrap();
    assert!(a.is_survey_mode());
    let mut back = [0f32; 16];
    assert_eq!(a.coefficients(&mut back), 16);
    for (x, y) in c.iter().zip(&back) {
        assert!((x - y).abs() < 1e-5);
    }
    let recs = run(&mut a, &stream(50, false, None, None).chunks);
    assert_eq!(recs.len(), 50);
    assert!(recs.iter().all(|r| r.flags.contains(Flags::SURVEY_MODE)));
    assert!(a.set_coefficients(&c[..3]).is_err());
}

/// `fluxcal` on the board: a fluxgate whose frames are distorted by a known bias/scale
/// error, with the matching calibration set (`SETFLUX`), gives the records of the
/// undistorted fluxgate; without the calibration it does not.
#[test]
fn a_fluxgate_calibration_undoes_a_distorted_fluxgate() {
    use magcomp_core::protocol::fluxgate::FluxCalibration;
    // Distortion: raw = D·B + d; calibration: B = D⁻¹·(raw − d) (diagonal D, exact inverse).
    let scale = [1.006f64, 0.993, 1.004];
    let bias = [320.0f64, -250.0, 410.0];
    let clean = stream(300, false, None, None);
    let distorted: Vec<(Port, Vec<u8>)> = clean
        .chunks
        .iter()
        .map(|(p, bytes)| {
            if *p != Port::Flux {
                return (*p, bytes.clone());
            }
            let text = String::from_utf8(bytes.clone()).unwrap();
            let v: Vec<f64> = text.trim().split(',').map(|x| x.parse().unwrap()).collect();
            let r: Vec<f64> = (0..3).map(|i| scale[i] * v[i] + bias[i]).collect();
            (
                *p,
                format!("{:.4},{:.4},{:.4}\r\n", r[0], r[1], r[2]).into_bytes(),
            )
        })
        .collect();
    let cal = FluxCalibration::from_array(&[
        (1.0 / scale[0]) as f32,
        0.0,
        0.0,
        0.0,
        (1.0 / scale[1]) as f32,
        0.0,
        0.0,
        0.0,
        (1.0 / scale[2]) as f32,
        (-bias[0] / scale[0]) as f32,
        (-bias[1] / scale[1]) as f32,
        (-bias[2] / scale[2]) as f32,
    ])
    .expect("plausible");
    // Survey mode with fixed coefficients: the interference is a plain function of e.
    let surveying = || {
        let mut a = acq();
        let mut c = [0f32; 16];
        c[..3].copy_from_slice(&[40.0, -25.0, 12.0]);
        c[3] = 30.0;
        a.set_coefficients(&c).unwrap();
        a.set_survey_mode(true);
        a
    };
    let reference = run(&mut surveying(), &clean.chunks);
    let mut raw = surveying();
    let uncalibrated = run(&mut raw, &distorted);
    let mut fixed = surveying();
    fixed.set_flux_calibration(cal);
    assert_eq!(fixed.flux_calibration(), cal);
    let calibrated = run(&mut fixed, &distorted);
    assert_eq!(calibrated.len(), 300);
    let worst = |recs: &[Record]| {
        recs.iter()
            .zip(&reference)
            .map(|(a, b)| (a.interference_nt - b.interference_nt).abs())
            .fold(0.0f32, f32::max)
    };
    eprintln!(
        "worst interference difference to the clean fluxgate: uncalibrated {:.4} nT, calibrated {:.2e} nT",
        worst(&uncalibrated),
        worst(&calibrated)
    );
    assert!(
        worst(&calibrated) < 1e-3,
        "calibrated: {}",
        worst(&calibrated)
    );
    assert!(
        worst(&uncalibrated) > 0.05,
        "uncalibrated: {}",
        worst(&uncalibrated)
    );
    // Implausible calibrations are refused.
    let mut bad = cal.to_array();
    bad[0] = 3.0;
    assert!(FluxCalibration::from_array(&bad).is_none());
    bad[0] = f32::NAN;
    assert!(FluxCalibration::from_array(&bad).is_none());
}

/// A scalar line whose terminator was lost runs into the next: the two samples keep a
/// record each, flagged, and every later record keeps its time (read as one line, every
/// later time was one period late).
#[test]
fn a_lost_line_end_keeps_every_sample_and_its_time() {
    let clean = run(&mut acq(), &stream(300, false, None, None).chunks);
    for lost in [1usize, 2, 3] {
        let mut s = stream(300, false, None, None);
        // drop the terminators of `lost` consecutive scalar lines from sample 120 on
        let scalar_lines: Vec<usize> = (s.chunks.iter().enumerate())
            .filter(|(_, (p, _))| *p == Port::Scalar)
            .map(|(i, _)| i)
            .collect();
        let mut merged = Vec::new();
        for &i in &scalar_lines[120..120 + lost + 1] {
            merged.extend(s.chunks[i].1.iter().filter(|b| !matches!(b, b'\r' | b'\n')));
        }
        merged.extend(b"\r\n");
        s.chunks[scalar_lines[120]].1 = merged;
        for &i in scalar_lines[121..121 + lost].iter().rev() {
            s.chunks.remove(i);
        }
        let mut a = acq();
        let recs = run(&mut a, &s.chunks);
        assert_eq!(recs.len(), clean.len(), "{lost} lost");
        assert_contiguous(&recs);
        let bad: Vec<usize> = (recs.iter().enumerate())
            .filter(|(_, r)| r.flags.contains(Flags::MAG_MISSING | Flags::PARSE_ERROR))
            .map(|(k, _)| k)
            .collect();
        assert_eq!(bad, (120..=120 + lost).collect::<Vec<_>>(), "{lost} lost");
        for (k, (r, c)) in recs.iter().zip(&clean).enumerate() {
            assert_eq!(r.t_s.to_bits(), c.t_s.to_bits(), "record {k}, {lost} lost");
            if k > 120 + lost {
                assert_eq!(r.mag, c.mag, "record {k}");
            }
        }
        let st = a.scalar_stats();
        assert_eq!((st.errors, st.merged), (1, lost as u32));
    }
}
