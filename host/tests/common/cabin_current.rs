//! The simulated cabin current both real-time witness tests fly: a 10 nT load current near
//! the scalar that the fluxgate sees 3 × as strongly, its channel not recorded, so only the
//! fluxgate's modulus witnesses it (`fluxmod`).

use magcomp::io::trace::Trace;
use magcomp::sim::{parse_hidden, simulate, SimConfig};

/// `cfg` flown with the cabin current and `more` hidden effects: the trace, and the truth
/// a compensator must find (the aircraft's interference plus the current's field).
pub fn flown_with_cabin_current(mut cfg: SimConfig, more: &[&str]) -> (Trace, Vec<f64>) {
    cfg.hidden = std::iter::once("current:cabin")
        .chain(more.iter().copied())
        .map(|h| parse_hidden(h).unwrap())
        .collect();
    cfg.hidden_std_nt = 10.0;
    cfg.hidden_at_fluxgate = 3.0;
    let trace = simulate(&cfg).unwrap();
    let truth = (trace.col("truth_interference").unwrap().iter())
        .zip(trace.col("truth_hidden_current_cabin").unwrap())
        .map(|(a, b)| a + b)
        .collect();
    (trace, truth)
}
