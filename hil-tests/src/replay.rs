//! Reference replay of a capture on the host with the board's own code: the core's parsers,
//! the firmware's time base (`timebase.rs`) and filter stage (`pipeline.rs`), fed in capture
//! byte order. Until `magcomp replay` exists this is what the board's records are held to;
//! `magcomp replay` must give the same records (the same rules, see docs/firmware.md).

use crate::capture::{Capture, Port};
use crate::pipeline::Filter;
use crate::timebase::{Rates, SampleAligner};
use magcomp_core::protocol::fluxgate::{FluxAsciiReader, FluxgateCal};
use magcomp_core::protocol::nmea::{NmeaReader, Sentence};
use magcomp_core::protocol::record::Record;
use magcomp_core::protocol::scalar::{ScalarConfig, ScalarReader};

/// The firmware's constants (src/fw.rs `RATES`, `FLUX_FULL_SCALE_NT`).
pub const BOARD_RATES: Rates = Rates {
    scalar_hz: 10.0,
    flux_hz: 10.0,
    gps_hz: 1.0,
};
pub const FLUX_FULL_SCALE_NT: f32 = 100_000.0;

/// Every record the board should emit for `cap`, flushed at the end of the stream.
pub fn replay(cap: &Capture, rates: Rates) -> Vec<Record> {
    let mut scalar = ScalarReader::new(ScalarConfig::default());
    let mut flux = FluxAsciiReader::new();
    let mut gps = NmeaReader::new();
    let cal = FluxgateCal::full_scale(FLUX_FULL_SCALE_NT);
    let mut al = SampleAligner::new(rates);
    let mut filter = match Filter::new(rates.scalar_hz as f32) {
        Ok(f) => f,
        Err(e) => panic!("compensator init: {e:?}"),
    };
    let mut out = Vec::new();
    for c in &cap.chunks {
        for &b in &c.bytes {
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
            }
        }
    }
    while let Some(r) = filter.flush() {
        out.push(r);
    }
    out
}
