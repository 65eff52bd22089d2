//! Feeding an acquisition a captured stream, shared by the `acquisition_*` tests.

use magcomp_core::acquisition::Acquisition;
use magcomp_core::protocol::capture::Port;
use magcomp_core::protocol::record::Record;

/// Every chunk in order (a 15-byte fluxgate chunk without a line end is an SPI frame,
/// anything else goes through the port's byte parser), then the held records flushed:
/// all the records the stream gives.
pub fn run<const N: usize, const W: usize>(
    a: &mut Acquisition<'_, N, W>,
    chunks: &[(Port, Vec<u8>)],
) -> Vec<Record> {
    let mut out = Vec::new();
    for (p, bytes) in chunks {
        if *p == Port::Flux && bytes.len() == 15 && !bytes.ends_with(b"\n") {
            a.push_flux_frame(bytes);
        } else {
            a.push_bytes(*p, bytes, |r| out.push(r));
        }
    }
    while let Some(r) = a.flush() {
        out.push(r);
    }
    out
}
