//! `magcomp replay` against the firmware's wiring of the same core: the board parses in its
//! UART tasks (one reader per port, unsupported NMEA sentences dropped) and feeds the results
//! to `magcomp_core::acquisition`, started in place from a `const` placeholder with the
//! board's constants (`src/board_config.rs`, as hil-tests includes it); `magcomp replay`
//! feeds bytes to an `Acquisition::new`. Same capture → bit-identical records, including
//! under corruption and faults, and after an in-place restart.

// `rustfmt::skip`: the firmware formats its files with its own settings; `cargo fmt -p
// magcomp` must not rewrite them.
#[path = "../../src/board_config.rs"]
#[allow(dead_code)]
#[rustfmt::skip]
mod fw_config;

use fw_config::BoardAcquisition;
use magcomp::board::capture::{trace_to_capture, CaptureOptions};
use magcomp::board::replay::{replay_capture, ReplayOptions};
use magcomp::model::spec::ModelSpec;
use magcomp::sim::{simulate, SimConfig};
use magcomp_core::acquisition::AcqRecord;
use magcomp_core::model::Model;
use magcomp_core::protocol::capture::{decode_line, Port, MAX_CHUNK};
use magcomp_core::protocol::record::Record;

/// The board's acquisition as `fw.rs` makes it: a `const` placeholder started in place.
fn board_acquisition() -> Box<BoardAcquisition> {
    let mut acq = Box::new(BoardAcquisition::placeholder(Model {
        field: false,
        terms: &[],
    }));
    fw_config::start(&mut acq).unwrap();
    acq
}

/// The firmware's tasks in capture order (as `fw.rs` wires them: the board's port parsers
/// from `src/board_config.rs`), into `acq`.
fn firmware(cap: &[u8], acq: &mut BoardAcquisition) -> Vec<Record> {
    let mut scalar = fw_config::ScalarPort::new();
    let mut flux = fw_config::FluxAsciiPort::new();
    let mut gps = fw_config::GpsPort::new();
    let mut out = Vec::new();
    let mut buf = [0u8; MAX_CHUNK];
    for l in cap.split(|&b| b == b'\n') {
        let Ok(Some(c)) = decode_line(l, &mut buf) else {
            continue;
        };
        for &b in &buf[..c.len] {
            let ev = match c.port {
                Port::Scalar => scalar.push(b),
                Port::Flux => flux.push(b),
                Port::Gps => gps.push(b),
                Port::Cmd | Port::Out => None,
            };
            // single-sensor captures here: every record is a `$MCREC`
            let one = |r| match r {
                AcqRecord::One(r) => r,
                AcqRecord::Multi(r) => panic!("record {}: a counter line", r.seq),
            };
            out.extend(ev.and_then(|ev| ev.apply(acq)).map(one));
            while let Some(ev) = scalar.owed() {
                out.extend(ev.apply(acq).map(one));
            }
        }
    }
    while let Some(r) = acq.flush() {
        out.push(r);
    }
    out
}

/// `magcomp replay` of `cap` at the board's rates.
fn host_replay(cap: &[u8]) -> Vec<Record> {
    let mut ro = ReplayOptions::new(ModelSpec::parse("tl16+field").unwrap());
    ro.rate_hz = Some(fw_config::SCALAR_HZ);
    ro.flux_rate_hz = Some(fw_config::FLUX_HZ);
    ro.gps_rate_hz = Some(fw_config::GPS_HZ);
    let mut rep = Vec::new();
    replay_capture(cap, &ro, |r| {
        rep.push(*r);
        Ok(())
    })
    .unwrap();
    rep
}

fn assert_identical(fw: &[Record], rep: &[Record]) {
    assert_eq!(rep.len(), fw.len());
    for (a, b) in fw.iter().zip(rep) {
        assert_eq!(a.seq, b.seq);
        assert_eq!(a.t_s.to_bits(), b.t_s.to_bits(), "seq {}", a.seq);
        assert_eq!(a.mag, b.mag);
        assert_eq!(a.compensated, b.compensated, "seq {}", a.seq);
        assert_eq!(a.interference_nt.to_bits(), b.interference_nt.to_bits());
        assert_eq!(a.anomaly_nt.to_bits(), b.anomaly_nt.to_bits());
        assert_eq!(a.innovation_nt.to_bits(), b.innovation_nt.to_bits());
        assert_eq!(a.flags, b.flags, "seq {}", a.seq);
    }
}

#[test]
fn replay_equals_the_firmware_bit_for_bit() {
    let trace = simulate(&SimConfig {
        max_duration_s: Some(120.0),
        seed: 11,
        ..SimConfig::default()
    })
    .unwrap();
    let o = CaptureOptions {
        corrupt_fraction: 0.01,
        flux_dropout_s: Some((30.0, 34.0)),
        gps_outage_s: Some((60.0, 70.0)),
        ..CaptureOptions::default()
    };
    let cap = trace_to_capture(&trace, &o).unwrap();
    let mut acq = board_acquisition();
    let fw = firmware(&cap, &mut acq);
    let rep = host_replay(&cap);
    assert_eq!(fw.len(), trace.len());
    assert_identical(&fw, &rep);
    // the STATUS counters the board reports
    let n = acq.counters();
    assert_eq!(n.records as usize, fw.len());
    assert!(
        n.scalar_errors > 0 && n.flux_errors > 0 && n.gps_errors > 0,
        "{n:?}"
    );

    // restarted in place after a whole flight (the board's RESET path, then a fresh
    // start): the same records again, no trace of the first run
    fw_config::start(&mut acq).unwrap();
    assert_identical(&firmware(&cap, &mut acq), &rep);
    // the filter alone restarted in place = a fresh compensator (sequence numbers go on)
    fw_config::start(&mut acq).unwrap();
    let half = firmware(&cap[..cap.len() / 2], &mut acq);
    fw_config::restart_filter(&mut acq).unwrap();
    let mut fresh = board_acquisition();
    let a = firmware(&cap, &mut acq);
    let b = firmware(&cap, &mut fresh);
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x.seq, y.seq + half.len() as u32);
        assert_eq!(x.interference_nt.to_bits(), y.interference_nt.to_bits());
        assert_eq!(x.anomaly_nt.to_bits(), y.anomaly_nt.to_bits());
        // The restart forgets the aligner's lost-frame reference too: the half run's frame
        // phase used to flag records 1–4 DERIVATIVE_DEGRADED, and flagged samples no longer
        // update the filter, so flags and values are identical throughout.
        assert_eq!(x.flags.0, y.flags.0, "record {} of {}", y.seq, b.len());
    }
}

/// `cap` with the scalar port's line ends removed from the scalar lines numbered `lost`,
/// so each runs into the next (a lost terminator).
fn without_line_ends(cap: &[u8], lost: &[usize]) -> Vec<u8> {
    use magcomp_core::protocol::capture::encode_line;
    let mut out = Vec::new();
    let (mut buf, mut line) = ([0u8; MAX_CHUNK], [0u8; 1024]);
    let mut k = 0;
    for l in cap.split(|&b| b == b'\n').filter(|l| !l.is_empty()) {
        match decode_line(l, &mut buf) {
            Ok(Some(c)) if c.port == Port::Scalar => {
                let mut data = buf[..c.len].to_vec();
                if lost.contains(&k) {
                    data.retain(|b| !matches!(b, b'\r' | b'\n'));
                }
                k += 1;
                let n = encode_line(c.t_us, c.port, &data, &mut line).unwrap();
                out.extend_from_slice(&line[..n]);
            }
            _ => {
                out.extend_from_slice(l);
                out.push(b'\n');
            }
        }
    }
    out
}

/// A scalar line whose terminator is lost runs into the next (issue 21): on the board and
/// in `magcomp replay` alike each sample keeps one record, the merged ones flagged, and
/// every later record keeps its time (read as one line, every later time was one period
/// late and the flight one record short).
#[test]
fn a_lost_scalar_line_end_keeps_every_record_and_time() {
    let trace = simulate(&SimConfig {
        max_duration_s: Some(60.0),
        seed: 12,
        ..SimConfig::default()
    })
    .unwrap();
    let cap = trace_to_capture(&trace, &CaptureOptions::default()).unwrap();
    let lost = [100, 250, 251, 400];
    let merged = without_line_ends(&cap, &lost);
    let clean = firmware(&cap, &mut board_acquisition());
    let fw = firmware(&merged, &mut board_acquisition());
    assert_eq!(clean.len(), trace.len());
    assert_eq!(fw.len(), trace.len());
    let rep = host_replay(&merged);
    assert_identical(&fw, &rep);
    let missing: Vec<usize> = (fw.iter().enumerate())
        .filter(|(_, r)| r.mag.is_none())
        .map(|(k, _)| k)
        .collect();
    assert_eq!(missing, [100, 101, 250, 251, 252, 400, 401]);
    for (k, (a, b)) in fw.iter().zip(&clean).enumerate() {
        assert_eq!(a.t_s.to_bits(), b.t_s.to_bits(), "record {k}");
    }
}
