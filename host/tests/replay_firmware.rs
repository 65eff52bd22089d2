//! `magcomp replay` (via `core::acquisition`) against the firmware's own host-testable
//! stages (`src/timebase.rs`, `src/pipeline.rs`, as hil-tests includes them): the same
//! capture must give bit-identical records, including under corruption and faults.

// `rustfmt::skip`: the firmware formats its files with its own settings; `cargo fmt -p
// magcomp` must not rewrite them.
#[path = "../../src/pipeline.rs"]
#[allow(dead_code)]
#[rustfmt::skip]
mod fw_pipeline;
#[path = "../../src/timebase.rs"]
#[allow(dead_code)]
#[rustfmt::skip]
mod fw_timebase;

use magcomp::capture_sim::{trace_to_capture, CaptureOptions};
use magcomp::model_spec::ModelSpec;
use magcomp::replay::{replay_capture, ReplayOptions};
use magcomp::sim::{simulate, SimConfig};
use magcomp_core::protocol::capture::{decode_line, Port, MAX_CHUNK};
use magcomp_core::protocol::fluxgate::{FluxAsciiReader, FluxgateCal};
use magcomp_core::protocol::nmea::{NmeaReader, Sentence};
use magcomp_core::protocol::record::Record;
use magcomp_core::protocol::scalar::{ScalarConfig, ScalarReader};

/// The firmware's tasks in capture order (as `fw.rs` wires them).
fn firmware(cap: &[u8], rates: fw_timebase::Rates) -> Vec<Record> {
    let mut scalar = ScalarReader::new(ScalarConfig::default());
    let mut flux = FluxAsciiReader::new();
    let mut gps = NmeaReader::new();
    let cal = FluxgateCal::full_scale(100_000.0);
    let mut al = fw_timebase::SampleAligner::new(rates);
    let mut filter = fw_pipeline::Filter::new(rates.scalar_hz as f32).unwrap();
    let mut out = Vec::new();
    let mut buf = [0u8; MAX_CHUNK];
    for l in cap.split(|&b| b == b'\n') {
        let Ok(Some(c)) = decode_line(l, &mut buf) else {
            continue;
        };
        for &b in &buf[..c.len] {
            match c.port {
                Port::Scalar => {
                    if let Some(r) = scalar.push(b) {
                        let (_, s) = al.scalar(r);
                        out.extend(filter.push(&s));
                    }
                }
                Port::Flux => {
                    if let Some(r) = flux.push(b) {
                        al.flux(r.map(|v| cal.to_body(v)));
                    }
                }
                Port::Gps => match gps.push(b) {
                    Some(Ok(Sentence::Unsupported { .. })) | None => {}
                    Some(r) => al.nmea(r),
                },
                Port::Cmd | Port::Out => {}
            }
        }
    }
    while let Some(r) = filter.flush() {
        out.push(r);
    }
    out
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
    // The reference firmware's constants (fw.rs RATES): GPS staleness from 1 Hz.
    let rates = fw_timebase::Rates {
        scalar_hz: 10.0,
        flux_hz: 10.0,
        gps_hz: 1.0,
    };
    let fw = firmware(&cap, rates);
    let mut ro = ReplayOptions::new(ModelSpec::parse("tl16+field").unwrap());
    ro.rate_hz = Some(rates.scalar_hz);
    ro.flux_rate_hz = Some(rates.flux_hz);
    ro.gps_rate_hz = Some(rates.gps_hz);
    let mut rep = Vec::new();
    replay_capture(&cap[..], &ro, |r| {
        rep.push(*r);
        Ok(())
    })
    .unwrap();
    assert_eq!(fw.len(), trace.len());
    assert_eq!(rep.len(), fw.len());
    for (a, b) in fw.iter().zip(&rep) {
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
