//! The aircraft's own field: the Tolles–Lawson coefficients K, L, M the scalar sees
//! (Cessna Caravan-like, or the `broad` profile's draws, which also give the fluxgate's).

use super::config::SimConfig;
use super::physics::{self, BroadFluxgate, FieldLaw, Physics};
use super::rng_for;
use super::world::random_sign;
use nalgebra::{Matrix3, Vector3};
use rand::Rng;
use rand_distr::StandardNormal;

pub(super) struct Aircraft {
    /// Permanent (nT), induced (1) and eddy (s) coefficients at the scalar sensor.
    pub(super) k: Vector3<f64>,
    pub(super) l: Matrix3<f64>,
    pub(super) m: Matrix3<f64>,
    /// `broad` physics: the scalar's field law and the fluxgate drawn with it.
    pub(super) broad: Option<(FieldLaw, BroadFluxgate)>,
}

/// Permanent K: ~10–60 nT per axis; induced L: a few 1e-4 (×50 000 nT → tens of nT); eddy
/// M: ~1e-4 s (×~1e4 nT/s in a 5° manoeuvre → ~1 nT). All × `interference_scale`.
pub(super) fn draw_aircraft(cfg: &SimConfig) -> Aircraft {
    let seed = cfg.seed;
    let mut ra = rng_for(seed, 4);
    let ifs = cfg.interference_scale;
    let k = Vector3::from_fn(|_, _| random_sign(&mut ra) * ra.gen_range(10.0..60.0)) * ifs;
    let l = Matrix3::from_fn(|i, j| {
        let w = if i == j { 4e-4 } else { 2e-4 };
        ra.sample::<f64, _>(StandardNormal) * w
    }) * ifs;
    let m = Matrix3::from_fn(|_, _| ra.sample::<f64, _>(StandardNormal) * 6e-5) * ifs;
    let broad = (cfg.physics == Physics::Broad).then(|| {
        let law = physics::broad_aircraft(seed, ifs);
        (law, physics::broad_fluxgate(seed, &law, ifs))
    });
    let (k, l, m) = match &broad {
        Some((law, _)) => (law.k_nt, law.l, law.m_s),
        None => (k, l, m),
    };
    Aircraft { k, l, m, broad }
}
