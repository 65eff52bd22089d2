//! Reference replay of a capture on the host with the board's own code, wired as the
//! firmware's tasks wire it (`src/fw.rs`): the core's readers per port (unsupported NMEA
//! sentences dropped, as the GPS task does) feeding `magcomp_core::acquisition` with the
//! board's constants (`src/board_config.rs`), in capture byte order. `magcomp replay` feeds
//! bytes to the same `Acquisition` and must give the same records (`host/tests/replay_firmware.rs`).

use crate::board_config::{self, BoardAcquisition};
use crate::capture::{Capture, Port};
use magcomp_core::model::Model;
use magcomp_core::protocol::fluxgate::{FluxAsciiReader, FluxgateCal};
use magcomp_core::protocol::nmea::{NmeaReader, Sentence};
use magcomp_core::protocol::record::Record;
use magcomp_core::protocol::scalar::{ScalarConfig, ScalarReader};

pub use magcomp_core::acquisition::FLUX_FULL_SCALE_NT;

/// Every record the board should emit for `cap`, flushed at the end of the stream.
pub fn replay(cap: &Capture) -> Vec<Record> {
    let mut scalar = ScalarReader::new(ScalarConfig::default());
    let mut flux = FluxAsciiReader::new();
    let mut gps = NmeaReader::new();
    let cal = FluxgateCal::full_scale(FLUX_FULL_SCALE_NT);
    let mut acq = Box::new(BoardAcquisition::placeholder(Model {
        field: false,
        terms: &[],
    }));
    if let Err(e) = board_config::start(&mut acq) {
        panic!("acquisition init: {e:?}");
    }
    let mut out = Vec::new();
    for c in &cap.chunks {
        for &b in &c.bytes {
            match c.port {
                Port::Scalar => {
                    if let Some(r) = scalar.push(b) {
                        out.extend(acq.scalar_result(r));
                    }
                }
                Port::Flux => {
                    if let Some(r) = flux.push(b) {
                        acq.flux_result(r.map(|v| cal.to_body(v)));
                    }
                }
                Port::Gps => match gps.push(b) {
                    Some(Ok(Sentence::Unsupported { .. })) | None => {}
                    Some(r) => acq.nmea_result(r),
                },
            }
        }
    }
    while let Some(r) = acq.flush() {
        out.push(r);
    }
    out
}
