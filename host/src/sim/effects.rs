//! The hidden effects (`--hidden`) made real for one flight: their auxiliary channels and
//! truth metadata, the vector effects scaled to their target size, and the noise-free
//! scalar with each effect's incremental contribution (and the sensor's lag).

use super::config::SimConfig;
use super::hidden::{FluxTempDrift, HiddenEffect, HiddenKind};
use super::signals::{CurrentWave, RpmWave};
use super::takeoff;
use super::world::{
    decoy_channels, json_mat, json_vec, random_dir, random_sign, std_dev, Inst, VecEffect, World,
};
use super::{rng_for, stream_of};
use nalgebra::{Matrix3, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use std::f64::consts::TAU;

/// The hidden effects of a flight, drawn.
pub(super) struct Effects {
    /// Auxiliary channels: the effects' recorded currents, rpm, temperatures, the decoys.
    pub(super) aux: Vec<(String, Vec<f64>)>,
    /// `truth_*` metadata of the effects, in the order drawn.
    pub(super) meta: Vec<(String, String)>,
    /// The vector effects: (index in `cfg.hidden`, law, scale).
    pub(super) vector: Vec<(usize, VecEffect, f64)>,
    /// The scalar's lag: (index in `cfg.hidden`, lag s).
    pub(super) lag: Option<(usize, f64)>,
    /// The fluxgate calibration change (index in `cfg.hidden`).
    pub(super) fluxcal: Option<usize>,
    /// The fluxgate's temperature drift (index in `cfg.hidden`, drift).
    pub(super) fluxtemp: Option<(usize, FluxTempDrift)>,
}

/// What the scalar sees, noise-free, at every sample.
pub(super) struct ScalarTrack {
    pub(super) mag_clean: Vec<f64>,
    /// Per vector effect: its incremental contribution to the scalar (nT).
    pub(super) hidden_cols: Vec<Vec<f64>>,
    /// What the lag changes in the scalar (nT).
    pub(super) lag_col: Vec<f64>,
}

impl Effects {
    /// Draws every hidden effect from its own stream, then the decoy channels.
    pub(super) fn draw(cfg: &SimConfig, world: &World, times: &[f64], dur: f64) -> Self {
        let mut fx = Effects {
            aux: Vec::new(),
            meta: Vec::new(),
            vector: Vec::new(),
            lag: None,
            fluxcal: None,
            fluxtemp: None,
        };
        for (hi, h) in cfg.hidden.iter().enumerate() {
            let mut r = rng_for(cfg.seed, stream_of(&h.name()));
            if let Some(e) = fx.draw_one(hi, h, world, times, dur, &mut r) {
                fx.vector.push((hi, e, 1.0));
            }
        }
        fx.aux.extend(decoy_channels(cfg, dur, times));
        fx
    }

    /// Draws hidden effect `hi`: a vector effect is returned, the input-side ones (lag,
    /// fluxgate calibration and temperature) are kept in `self`.
    fn draw_one(
        &mut self,
        hi: usize,
        h: &HiddenEffect,
        world: &World,
        times: &[f64],
        dur: f64,
        r: &mut ChaCha8Rng,
    ) -> Option<VecEffect> {
        match &h.kind {
            HiddenKind::Current { channel } | HiddenKind::CurrentRate { channel } => {
                let wave = CurrentWave::random(dur, r);
                self.aux.push((
                    channel.clone(),
                    times.iter().map(|&t| wave.eval(t).0).collect(),
                ));
                Some(VecEffect::Current {
                    dir: random_dir(r),
                    wave,
                    rate: matches!(h.kind, HiddenKind::CurrentRate { .. }),
                })
            }
            HiddenKind::Periodic { channel } => {
                let rpm = RpmWave::random(r);
                self.aux
                    .push((channel.clone(), times.iter().map(|&t| rpm.rpm(t)).collect()));
                Some(VecEffect::Periodic {
                    dir: random_dir(r),
                    rpm,
                    phase: [r.gen_range(0.0..TAU), r.gen_range(0.0..TAU)],
                    h2: r.gen_range(0.2..0.5),
                })
            }
            HiddenKind::Rate => Some(self.rate_effect(r)),
            HiddenKind::InducedHigh => {
                let c: [f64; 10] = std::array::from_fn(|_| r.sample::<f64, _>(StandardNormal));
                Some(VecEffect::InducedHigh { c })
            }
            HiddenKind::Lag { lag_s } => {
                self.lag = Some((hi, *lag_s));
                None
            }
            HiddenKind::FluxCal => {
                self.fluxcal = Some(hi);
                None
            }
            HiddenKind::FluxTemp {
                channel,
                max_nt_per_degc,
            } => {
                self.draw_fluxtemp(hi, channel, *max_nt_per_degc, times, r);
                None
            }
            HiddenKind::Diurnal => None,
            HiddenKind::Engine { channel } => Some(takeoff::engine_effect(
                world,
                channel.as_deref(),
                times,
                &mut self.aux,
                &mut self.meta,
                r,
            )),
        }
    }

    /// N (s): not scaled to a target std, 0.01–0.03 s on the diagonal, so the term is ~1 nT
    /// only where d|B|/dt is tens of nT/s (low over strong sources). This is a deliberately
    /// exaggerated *extra* eddy path: the airframe's own eddy response to flying through
    /// gradients is already in every flight through `M·dB/dt` (db_body includes the anomaly
    /// gradient · velocity), and M is only ~6e-5–1e-4 s, i.e. ~0.001 nT here. Even at this
    /// size `rate` is not observable on a calibration pattern alone, only at the crossovers
    /// of a survey with tie lines (tests/diagnose_effects.rs).
    fn rate_effect(&mut self, r: &mut ChaCha8Rng) -> VecEffect {
        let mut nm = Matrix3::from_fn(|_, _| r.sample::<f64, _>(StandardNormal) * 0.008);
        nm = (nm + nm.transpose()) / 2.0;
        for i in 0..3 {
            nm[(i, i)] = random_sign(r) * r.gen_range(0.01..0.03);
        }
        self.meta.push(("truth_N_s".into(), json_mat(&nm)));
        VecEffect::Rate { n: nm }
    }

    /// The fluxgate's temperature drift; the temperature is recorded with 0.01 °C noise,
    /// the drift follows the true temperature.
    fn draw_fluxtemp(
        &mut self,
        hi: usize,
        channel: &str,
        max_nt_per_degc: f64,
        times: &[f64],
        r: &mut ChaCha8Rng,
    ) {
        let drift = FluxTempDrift::random(max_nt_per_degc, r);
        self.aux.push((
            channel.to_string(),
            times
                .iter()
                .map(|&t| drift.temp.eval(t).0 + 0.01 * r.sample::<f64, _>(StandardNormal))
                .collect(),
        ));
        self.meta.push((
            "truth_fluxtemp_bias_nt_per_degc".into(),
            json_vec(&drift.bias_nt_per_degc),
        ));
        self.fluxtemp = Some((hi, drift));
    }

    /// Scales each vector effect (except the physical `rate` and `engine`) to the target
    /// std inside its window, measured on its projection on the field direction (what the
    /// scalar sees), and records the scaled coefficients of the channel effects.
    pub(super) fn scale_to_target(&mut self, cfg: &SimConfig, times: &[f64], insts: &[Inst]) {
        for (hi, eff, scale) in self.vector.iter_mut() {
            let h = &cfg.hidden[*hi];
            let target = match eff {
                VecEffect::Rate { .. } | VecEffect::Engine(_) => continue,
                VecEffect::Periodic { .. } => cfg.hidden_std_nt / 2.0,
                _ => cfg.hidden_std_nt,
            };
            let proj: Vec<f64> = times
                .iter()
                .zip(insts)
                .filter(|(&t, _)| h.active(t))
                .map(|(&t, i)| {
                    let tot = i.b_body + i.delta_b;
                    eff.field(t, i).dot(&tot) / tot.norm()
                })
                .collect();
            let sd = std_dev(proj.iter().copied());
            *scale = if sd > 1e-12 { target / sd } else { 0.0 };
            match eff {
                VecEffect::Current { dir, rate, .. } => {
                    let key = if *rate { "nt_per_a_per_s" } else { "nt_per_a" };
                    self.meta.push((
                        format!("truth_c_{}_{key}", h.name()),
                        json_vec(&(*dir * *scale)),
                    ));
                }
                VecEffect::Periodic { dir, .. } => {
                    self.meta.push((
                        format!("truth_c_{}_nt", h.name()),
                        json_vec(&(*dir * *scale)),
                    ));
                }
                _ => {}
            }
        }
    }

    /// The hidden vector effects' field at an instant (body axes, nT), as scaled: what a
    /// fluxgate beside the same sources sees of them (`SimConfig::hidden_at_fluxgate`).
    pub(super) fn hidden_field(&self, cfg: &SimConfig, t: f64, i: &Inst) -> Vector3<f64> {
        self.vector
            .iter()
            .filter(|(hi, ..)| cfg.hidden[*hi].active(t))
            .map(|(_, eff, scale)| eff.field(t, i) * *scale)
            .sum()
    }

    /// Noise-free scalar at an instant, with per-effect incremental contributions.
    fn scalar_at(&self, cfg: &SimConfig, t: f64, i: &Inst, contrib: &mut [f64]) -> f64 {
        let mut tot = i.b_body + i.delta_b;
        let mut prev = tot.norm();
        for (slot, (hi, eff, scale)) in self.vector.iter().enumerate() {
            if !cfg.hidden[*hi].active(t) {
                contrib[slot] = 0.0;
                continue;
            }
            tot += eff.field(t, i) * *scale;
            let now = tot.norm();
            contrib[slot] = now - prev;
            prev = now;
        }
        prev
    }

    /// The noise-free scalar, interference and hidden contributions at every sample.
    pub(super) fn scalar_track(
        &self,
        cfg: &SimConfig,
        world: &World,
        times: &[f64],
        insts: &[Inst],
    ) -> ScalarTrack {
        let n = times.len();
        let mut mag_clean = vec![0.0; n];
        let mut hidden_cols: Vec<Vec<f64>> = vec![vec![0.0; n]; self.vector.len()];
        let mut lag_col = vec![0.0; n];
        let mut contrib = vec![0.0; self.vector.len()];
        let mut scratch = vec![0.0; self.vector.len()];
        for (kk, (&t, i)) in times.iter().zip(insts).enumerate() {
            let s_now = self.scalar_at(cfg, t, i, &mut contrib);
            for (col, c) in hidden_cols.iter_mut().zip(&contrib) {
                col[kk] = *c;
            }
            let mut s = s_now;
            if let Some((hi, lag_s)) = self.lag {
                if cfg.hidden[hi].active(t) {
                    // The sensor reports at t what it measured at t − τ (clamped at the start).
                    let tl = (t - lag_s).max(0.0);
                    let il = world.inst(tl);
                    s = self.scalar_at(cfg, tl, &il, &mut scratch);
                    lag_col[kk] = s - s_now;
                }
            }
            mag_clean[kk] = s;
        }
        ScalarTrack {
            mag_clean,
            hidden_cols,
            lag_col,
        }
    }
}
