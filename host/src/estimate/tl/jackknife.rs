//! Tolles–Lawson's jackknife ([`crate::estimate::jackknife`]): the fit again without each stretch of
//! the selected rows, each refit's interference over the whole flight.

use super::{fit, interference, TlConfig};
use std::ops::Range;

/// The interference each refit gives over the whole flight (`crate::estimate::jackknife`): a fit on
/// `select` without each block of `span`; None when `span` is too short to cut into blocks
/// or a refit fails.
pub fn jackknife_refits(
    flux_nt: &[[f64; 3]],
    mag_nt: &[f64],
    cfg: &TlConfig,
    select: &[bool],
    span: &Range<usize>,
) -> Option<Vec<Vec<f64>>> {
    let blocks = crate::estimate::jackknife::blocks(span, cfg.fs_hz)?;
    let refit = |block: &Range<usize>| {
        let mut rows = select.to_vec();
        for r in &mut rows[block.clone()] {
            *r = false;
        }
        let refit = fit(flux_nt, mag_nt, cfg, Some(&rows)).ok()?;
        Some(interference(&refit, flux_nt))
    };
    // The refits are independent and each re-filters the whole flight: they were most of
    // `calibrate --method tl`'s time, so they share the cores. Each refit is computed
    // exactly as before, so the result does not depend on the thread count.
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(blocks.len())
        .max(1);
    let chunk = blocks.len().div_ceil(threads);
    let refits: Vec<Option<Vec<f64>>> = std::thread::scope(|s| {
        let handles: Vec<_> = blocks
            .chunks(chunk)
            .map(|part| s.spawn(move || part.iter().map(refit).collect::<Vec<_>>()))
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().expect("a jackknife refit panicked"))
            .collect()
    });
    refits.into_iter().collect()
}
