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
    let refits = blocks
        .iter()
        .map(|block| {
            let mut rows = select.to_vec();
            for r in &mut rows[block.clone()] {
                *r = false;
            }
            let refit = fit(flux_nt, mag_nt, cfg, Some(&rows)).ok()?;
            Some(interference(&refit, flux_nt))
        })
        .collect::<Option<Vec<_>>>()?;
    Some(refits)
}
