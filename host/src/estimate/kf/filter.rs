//! The core filter as the host builds it, in one place: its configuration from the
//! flight's geometry and the user's options, and the compensator with its coefficients
//! (survey mode) or its held combinations. The in-memory runs (`stages`) and the streamed
//! `compensate` (`crate::stream`) both build it here, so they cannot drift apart.

use super::KfOptions;
use anyhow::{bail, Result};
use magcomp_core::compensator::{Compensator, CompensatorConfig, TiePoint};
use magcomp_core::epoch::Epoch;
use magcomp_core::model::Model;

/// Host capacity: 21 paper states + up to 41 extra coefficients + clones.
pub const HOST_STATES: usize = 64;
/// Derivative ring: ±50 samples at 1 kHz.
pub const HOST_WINDOW: usize = 128;
pub type HostCompensator<'a> = Compensator<'a, HOST_STATES, HOST_WINDOW>;

/// What the filter needs of a flight: sample rate (Hz), main-field direction, tie point.
pub(crate) type Geometry = (f64, Option<[f32; 3]>, Option<TiePoint>);

/// The filter's configuration for a flight's geometry, the user's options and the noise
/// levels the run chose (σ1, the measurement noise r, both nT-based).
pub(crate) fn config_for(
    geometry: Geometry,
    opts: &KfOptions,
    sigma1: f64,
    noise_nt: f64,
) -> CompensatorConfig {
    let mut cfg = base_config(geometry, sigma1, noise_nt, opts.sigma2_ratio);
    cfg.prior_scale = opts.prior_scale as f32;
    cfg.h0_reanchor_m = opts.h0_reanchor_m as f32;
    cfg.gate_sigma = opts.gate_sigma as f32;
    set_run_mode(&mut cfg, opts.realtime);
    if let Some(hw) = opts.half_width {
        cfg.epoch.half_width = hw.max(1);
    }
    if !opts.tie_points {
        cfg.tie_points[0] = None;
    }
    cfg
}

/// The filter for a flight's geometry at σ1 (σ2 = `sigma2_ratio` × σ1) and scalar noise,
/// everything else the core's defaults (the run mode is the caller's, [`set_run_mode`]):
/// what [`config_for`] starts from, and what a model with terms outside the catalogue runs
/// (`diagnose::custom`).
pub(crate) fn base_config(
    (sample_rate_hz, earth_dir_ned, tie_point): Geometry,
    sigma1: f64,
    noise_nt: f64,
    sigma2_ratio: f64,
) -> CompensatorConfig {
    let mut cfg = CompensatorConfig::for_rate(sample_rate_hz as f32);
    cfg.sigma1 = sigma1 as f32;
    cfg.sigma2 = (sigma1 * sigma2_ratio) as f32;
    cfg.noise_nt = noise_nt as f32;
    cfg.epoch.earth_dir_ned = earth_dir_ned;
    cfg.tie_points[0] = tie_point;
    cfg
}

/// Real time (the board, which `--realtime` reproduces) or a post-flight pass: post-flight
/// the calibration is judged at its end, so the causal divergence reset is off, and nothing
/// is learnt on the ground (`GROUND_SPEED_MPS`).
pub(crate) fn set_run_mode(cfg: &mut CompensatorConfig, realtime: bool) {
    cfg.divergence_reset = realtime;
    if !realtime {
        cfg.min_update_speed_mps = magcomp_core::compensator::GROUND_SPEED_MPS;
    }
}

/// The compensator for `model` (`model_text` names it in errors) at `cfg`: with
/// `coefficients` applied (survey mode), else calibrating with the `held` combinations
/// (prior-σ units, model order) held at their prior. Every host filter is built here.
pub(crate) fn build<'m>(
    model_text: &str,
    model: Model<'m>,
    cfg: CompensatorConfig,
    coefficients: Option<&[f64]>,
    held: &[Vec<f32>],
) -> Result<HostCompensator<'m>> {
    let mut comp = HostCompensator::new(model, cfg)
        .map_err(|e| crate::model::errors::cannot_build(model_text, &e))?;
    match coefficients {
        Some(c) => {
            let c32: Vec<f32> = c.iter().map(|v| *v as f32).collect();
            comp.set_coefficients(&c32).map_err(|e| {
                crate::model::errors::do_not_fit(model_text, c.len(), model.coefficient_count(), &e)
            })?;
        }
        None => {
            for w in held {
                if !comp.hold_coefficient_combination(w) {
                    bail!("internal: a held combination does not fit the model");
                }
            }
        }
    }
    Ok(comp)
}

/// Which of the model's coefficients are interference (not environment) ones, in order.
pub(crate) fn interference_mask(model: &Model) -> Vec<bool> {
    model
        .terms
        .iter()
        .flat_map(|t| std::iter::repeat_n(t.is_interference(), t.len()))
        .collect()
}

/// The interference terms' regressors of epoch `ep` into `buf` (the environment terms'
/// set to 0): what the interference is, coefficient by coefficient.
pub(crate) fn interference_regressors(
    comp: &HostCompensator,
    ep: &Epoch,
    mask: &[bool],
    buf: &mut [f32],
) {
    comp.term_regressors(ep, buf);
    for (v, &is) in buf.iter_mut().zip(mask) {
        if !is {
            *v = 0.0;
        }
    }
}
