//! Identifiability (issue 12, item 2): before a candidate is ranked, can this flight
//! determine it at all? A term whose regressors do not vary in the manoeuvre band beyond
//! what the model's own terms already span is fitted to whatever else the residual holds:
//! on a real straight line, geology (`induced_high` "explained" 83–98 %).
//!
//! The measure is the one the filter uses to hold unexcited combinations
//! (`estimate/excitation.rs`): how far a prior-1σ change of the candidate's best-excited coefficient
//! combination moves the manoeuvre-band (0.1–0.9 Hz) interference, after projecting out
//! every combination of the model's own terms (nT rms over the flight). Columns are built
//! from the INS attitude's field direction (`e_ref`), so only the variation attitude drives
//! counts, not the field direction's swing over geology. Below
//! [`crate::estimate::excitation::EXCITATION_FLOOR_NT`] the candidate is untestable here. Channel
//! terms (a current, a temperature) vary with their channel, not only with attitude: their
//! band runs from the manoeuvre band's lower edge up to 0.4·fs.

use crate::qc::figures::manoeuvre_band;
use nalgebra::{DMatrix, SymmetricEigen};

/// Columns band-passed (4 poles, zero phase), missing values as 0, every `stride`-th row
/// kept (the band ends ≤ 0.4·fs; ~20 rows a second are plenty for a Gram matrix).
fn banded(cols: &[&[f64]], band: (f64, f64), fs_hz: f64) -> Option<Vec<Vec<f64>>> {
    let stride = ((fs_hz / (5.0 * band.1)).floor() as usize).max(1);
    cols.iter()
        .map(|c| {
            let clean: Vec<f64> = c
                .iter()
                .map(|v| if v.is_finite() { *v } else { 0.0 })
                .collect();
            crate::signal::bandpass::bandpass(&clean, 4, band.0, band.1, fs_hz)
                .ok()
                .map(|bp| bp.into_iter().step_by(stride).collect())
        })
        .collect()
}

/// Excitation (nT) of the candidate's best-determined combination beyond the span of
/// `base`: √(largest eigenvalue of the Schur complement of the prior-scaled Gram matrix).
/// `channel_term`: the wider band (module notes). None when the columns cannot be filtered.
pub(crate) fn candidate_excitation_nt(
    base: &[&[f64]],
    cand: &[&[f64]],
    prior_sigma: &[f64],
    fs_hz: f64,
    channel_term: bool,
) -> Option<f64> {
    let (lo, hi) = manoeuvre_band(fs_hz);
    let band = if channel_term {
        (lo, 0.4 * fs_hz)
    } else {
        (lo, hi)
    };
    let b = banded(base, band, fs_hz)?;
    let mut c = banded(cand, band, fs_hz)?;
    for (col, s) in c.iter_mut().zip(prior_sigma) {
        col.iter_mut().for_each(|v| *v *= s);
    }
    let n = c.first().map_or(0, |v| v.len());
    if n < 16 {
        return None;
    }
    let all: Vec<&Vec<f64>> = b.iter().chain(c.iter()).collect();
    let k = all.len();
    let g = DMatrix::from_fn(k, k, |i, j| {
        all[i].iter().zip(all[j]).map(|(x, y)| x * y).sum::<f64>() / n as f64
    });
    let nb = b.len();
    let gcc = g.view((nb, nb), (k - nb, k - nb)).into_owned();
    let schur = if nb == 0 {
        gcc
    } else {
        // Pseudo-inverse of the base block by its eigenvectors: the model's own terms are
        // often nearly collinear in the band (that is what the filter holds at the prior).
        let gbb = g.view((0, 0), (nb, nb)).into_owned();
        let gbc = g.view((0, nb), (nb, k - nb)).into_owned();
        let eig = SymmetricEigen::new(gbb);
        let top = eig.eigenvalues.max().max(0.0);
        let mut proj = DMatrix::<f64>::zeros(k - nb, k - nb);
        for (e, &mu) in eig.eigenvalues.iter().enumerate() {
            if mu > 1e-12 * top && mu > 0.0 {
                let v = eig.eigenvectors.column(e);
                let w = gbc.transpose() * v;
                proj += &w * w.transpose() / mu;
            }
        }
        gcc - proj
    };
    let eig = SymmetricEigen::new(schur);
    Some(eig.eigenvalues.max().max(0.0).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::TAU;

    /// A candidate that is the model's own column scaled has no excitation of its own; an
    /// independent manoeuvre-band sinusoid of amplitude A at prior 1 has A/√2.
    #[test]
    fn excitation_beyond_the_model_span() {
        let fs = 10.0;
        let t: Vec<f64> = (0..6000).map(|k| k as f64 / fs).collect();
        let base: Vec<f64> = t.iter().map(|t| (TAU * 0.3 * t).sin()).collect();
        let same: Vec<f64> = base.iter().map(|v| 3.0 * v).collect();
        let other: Vec<f64> = t.iter().map(|t| 0.5 * (TAU * 0.47 * t).cos()).collect();
        let e_same = candidate_excitation_nt(&[&base], &[&same], &[1.0], fs, false).unwrap();
        let e_other = candidate_excitation_nt(&[&base], &[&other], &[1.0], fs, false).unwrap();
        assert!(e_same < 1e-6, "{e_same}");
        assert!(
            (e_other - 0.5 / 2f64.sqrt()).abs() < 0.02,
            "{e_other} vs {}",
            0.5 / 2f64.sqrt()
        );
        // Below the band (a 100 s period) nothing counts.
        let slow: Vec<f64> = t.iter().map(|t| (TAU * 0.01 * t).sin()).collect();
        let e_slow = candidate_excitation_nt(&[&base], &[&slow], &[1.0], fs, false).unwrap();
        assert!(e_slow < 0.02, "{e_slow}");
    }
}
