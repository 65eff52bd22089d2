//! Reference replay of a capture on the host with the board's own code, wired as the
//! firmware's tasks wire it (`src/fw.rs`): the board's port parsers (`src/board_config.rs`,
//! the same the UART tasks use) feeding `magcomp_core::acquisition` with the
//! board's constants (`src/board_config.rs`), in capture byte order. `magcomp replay` feeds
//! bytes to the same `Acquisition` and must give the same records (`host/tests/replay_firmware.rs`).

use crate::board_config::{self, BoardAcquisition, FluxAsciiPort, GpsPort, ScalarPort};
use crate::capture::{Capture, Port};
use magcomp_core::model::Model;
use magcomp_core::protocol::record::Record;

pub use magcomp_core::acquisition::FLUX_FULL_SCALE_NT;

/// Every record the board should emit for `cap`, flushed at the end of the stream.
pub fn replay(cap: &Capture) -> Vec<Record> {
    let (mut scalar, mut flux, mut gps) = (ScalarPort::new(), FluxAsciiPort::new(), GpsPort::new());
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
            let ev = match c.port {
                Port::Scalar => scalar.push(b),
                Port::Flux => flux.push(b),
                Port::Gps => gps.push(b),
            };
            out.extend(ev.and_then(|ev| ev.apply(&mut acq)));
        }
    }
    while let Some(r) = acq.flush() {
        out.push(r);
    }
    out
}
