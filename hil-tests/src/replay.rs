//! Reference replay of a capture on the host with the board's own code, wired as the
//! firmware's tasks wire it (`src/fw.rs`): the board's port parsers (`src/board_config.rs`,
//! the same the UART tasks use) feeding `magcomp_core::acquisition` with the
//! board's constants (`src/board_config.rs`), in capture byte order. `magcomp replay` feeds
//! bytes to the same `Acquisition` and must give the same records (`host/tests/replay_firmware.rs`).

use crate::board_config::{self, BoardAcquisition, FluxAsciiPort, GpsPort, ScalarPort};
use crate::capture::{Capture, Port};
use magcomp_core::acquisition::AcqRecord;
use magcomp_core::model::Model;
use magcomp_core::protocol::lag_line::LagLine;
use magcomp_core::protocol::record::Record;

pub use magcomp_core::acquisition::FLUX_FULL_SCALE_NT;

/// Every record the board should emit for `cap`, flushed at the end of the stream.
pub fn replay(cap: &Capture) -> Vec<Record> {
    replay_lagged(cap, 0.0)
}

/// As [`replay`], with the scalar's delay τ set (`SETLAG`) before the first byte: the
/// board's delay line is attached at boot, as `src/fw.rs` does. Single-sensor captures
/// only (a counter line's `$MCMREC` records: [`replay_any`]).
pub fn replay_lagged(cap: &Capture, lag_s: f32) -> Vec<Record> {
    replay_any_lagged(cap, lag_s)
        .into_iter()
        .map(|r| match r {
            AcqRecord::One(r) => r,
            AcqRecord::Multi(r) => panic!("record {}: a multi-sensor capture", r.seq),
        })
        .collect()
}

/// Every record, `$MCREC` or `$MCMREC`, the board should emit for `cap`.
pub fn replay_any(cap: &Capture) -> Vec<AcqRecord> {
    replay_any_lagged(cap, 0.0)
}

fn replay_any_lagged(cap: &Capture, lag_s: f32) -> Vec<AcqRecord> {
    let (mut scalar, mut flux, mut gps) = (ScalarPort::new(), FluxAsciiPort::new(), GpsPort::new());
    let mut acq = Box::new(BoardAcquisition::placeholder(Model {
        field: false,
        terms: &[],
    }));
    if let Err(e) = board_config::start(&mut acq) {
        panic!("acquisition init: {e:?}");
    }
    // The board's line is a `static`; here one per replay, leaked (8 KiB, tests only).
    acq.attach_lag_line(Box::leak(Box::new(LagLine::new())));
    if let Err(e) = acq.set_lag_s(lag_s) {
        panic!("SETLAG {lag_s}: {e:?}");
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
            // a scalar line that ran into the next: one event per further sample
            while let Some(ev) = scalar.owed() {
                out.extend(ev.apply(&mut acq));
            }
        }
    }
    while let Some(r) = acq.flush_any() {
        out.push(r);
    }
    out
}
