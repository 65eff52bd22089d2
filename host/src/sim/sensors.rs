//! The sensors and their errors: scalar white noise; the fluxgate's own aircraft field,
//! bias, scale, misalignment, noise (and the `fluxcal` / `fluxtemp` hidden effects); INS
//! attitude errors; GPS position and velocity errors.

use super::aircraft::Aircraft;
use super::config::SimConfig;
use super::effects::Effects;
use super::geo::LocalFrame;
use super::signals::gauss_markov;
use super::trajectory::Clock;
use super::world::{
    json_mat, json_vec, random_sign, small_rotation, tl_scalar, unit_and_rate, Inst, World,
};
use super::{rng_for, stream_of};
use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// The scalar magnetometer's readings: the clean scalar plus white noise.
pub(super) fn scalar_readings(cfg: &SimConfig, mag_clean: &[f64]) -> Vec<f64> {
    let mut rn = rng_for(cfg.seed, 6);
    mag_clean
        .iter()
        .map(|m| m + cfg.scalar_noise_nt * rn.sample::<f64, _>(StandardNormal))
        .collect()
}

/// The fluxgate's errors: reading = scale·rot·(B + K_F + L_F·B + M_F·dB/dt) + bias, and the
/// wrong calibration (`fluxcal`) it has inside that hidden effect's window.
struct FluxgateErrors {
    kf: Vector3<f64>,
    lf: Matrix3<f64>,
    mf: Matrix3<f64>,
    bias: Vector3<f64>,
    scale: Matrix3<f64>,
    rot: Matrix3<f64>,
    bad_bias: Vector3<f64>,
    bad_scale: Matrix3<f64>,
    bad_rot: Matrix3<f64>,
}

impl FluxgateErrors {
    fn draw(cfg: &SimConfig, aircraft: &Aircraft) -> Self {
        let ifs = cfg.interference_scale;
        let mut rf = rng_for(cfg.seed, 5);
        let kf = Vector3::from_fn(|_, _| rf.sample::<f64, _>(StandardNormal) * 8.0) * ifs;
        let lf = Matrix3::from_fn(|_, _| rf.sample::<f64, _>(StandardNormal) * 5e-5) * ifs;
        let flux_bias = Vector3::from_fn(|_, _| rf.sample::<f64, _>(StandardNormal) * 30.0);
        let flux_scale = Matrix3::from_diagonal(&Vector3::from_fn(|_, _| {
            1.0 + rf.sample::<f64, _>(StandardNormal) * 1e-3
        }));
        let flux_rot = small_rotation(0.07f64.to_radians(), &mut rf);
        // Broad: the aircraft's eddy field reaches the fluxgate too, and its errors are one
        // scale/cross-coupling matrix (rotation = identity) and a 10–50 nT bias.
        let (kf, lf, mf, bias, scale, rot) = match &aircraft.broad {
            Some((_, fg)) => (
                fg.aircraft.k_nt,
                fg.aircraft.l,
                fg.aircraft.m_s,
                fg.bias_nt,
                fg.matrix,
                Matrix3::identity(),
            ),
            None => (kf, lf, Matrix3::zeros(), flux_bias, flux_scale, flux_rot),
        };
        let mut rfc = rng_for(cfg.seed, stream_of("fluxcal"));
        let bad_bias = Vector3::from_fn(|_, _| random_sign(&mut rfc) * rfc.gen_range(200.0..500.0));
        let bad_scale = Matrix3::from_diagonal(&Vector3::from_fn(|_, _| {
            1.0 + random_sign(&mut rfc) * rfc.gen_range(0.005..0.01)
        }));
        let bad_rot = Rotation3::from_euler_angles(
            random_sign(&mut rfc) * rfc.gen_range(0.3f64..0.5).to_radians(),
            random_sign(&mut rfc) * rfc.gen_range(0.3f64..0.5).to_radians(),
            random_sign(&mut rfc) * rfc.gen_range(0.3f64..0.5).to_radians(),
        )
        .into_inner();
        FluxgateErrors {
            kf,
            lf,
            mf,
            bias,
            scale,
            rot,
            bad_bias,
            bad_scale,
            bad_rot,
        }
    }

    /// `truth_flux_*` (and `truth_fluxcal_*` with that hidden effect).
    fn meta(&self, broad: bool, fluxcal: bool, meta: &mut Vec<(String, String)>) {
        meta.push(("truth_flux_K_nt".into(), json_vec(&self.kf)));
        meta.push(("truth_flux_L".into(), json_mat(&self.lf)));
        if broad {
            meta.push(("truth_flux_M_s".into(), json_mat(&self.mf)));
        }
        meta.push(("truth_flux_bias_nt".into(), json_vec(&self.bias)));
        meta.push((
            "truth_flux_matrix".into(),
            json_mat(&(self.scale * self.rot)),
        ));
        if fluxcal {
            meta.push(("truth_fluxcal_bias_nt".into(), json_vec(&self.bad_bias)));
            meta.push((
                "truth_fluxcal_matrix".into(),
                json_mat(&(self.bad_scale * self.bad_rot)),
            ));
        }
    }
}

/// The fluxgate's three axes, and what `fluxcal` and `fluxtemp` do to a TL compensation.
pub(super) struct FluxgateTrack {
    pub(super) flux: [Vec<f64>; 3],
    pub(super) fluxcal_col: Vec<f64>,
    pub(super) fluxtemp_col: Vec<f64>,
}

/// The fluxgate's readings; its error draws go to `effects.meta`.
pub(super) fn fluxgate_readings(
    cfg: &SimConfig,
    aircraft: &Aircraft,
    effects: &mut Effects,
    times: &[f64],
    insts: &[Inst],
) -> FluxgateTrack {
    let fe = FluxgateErrors::draw(cfg, aircraft);
    fe.meta(
        aircraft.broad.is_some(),
        effects.fluxcal.is_some(),
        &mut effects.meta,
    );
    let (k, l, m) = (&aircraft.k, &aircraft.l, &aircraft.m);
    let n = times.len();
    let mut rfn = rng_for(cfg.seed, 7);
    let mut flux = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
    let mut fluxcal_col = vec![0.0; n];
    let mut fluxtemp_col = vec![0.0; n];
    for (kk, (&t, i)) in times.iter().zip(insts).enumerate() {
        let bad = effects.fluxcal.is_some_and(|hi| cfg.hidden[hi].active(t));
        let (sc, rot, bias) = if bad {
            (&fe.bad_scale, &fe.bad_rot, &fe.bad_bias)
        } else {
            (&fe.scale, &fe.rot, &fe.bias)
        };
        let a = sc * rot;
        let hidden = if cfg.hidden_at_fluxgate > 0.0 {
            effects.hidden_field(cfg, t, i) * cfg.hidden_at_fluxgate
        } else {
            Vector3::zeros()
        };
        let f_static =
            a * (i.b_body + fe.kf + fe.lf * i.b_body + fe.mf * i.db_body + hidden) + bias;
        // (mf·d²B/dt² left out of the rate: the fluxcal truth column is a first-order figure.)
        let f_static_dot = a * (i.db_body + fe.lf * i.db_body);
        let f_clean = match &effects.fluxtemp {
            Some((hi, drift)) if cfg.hidden[*hi].active(t) => {
                let (f, f_dot) = drift.apply(t, &f_static, &f_static_dot);
                // What the drift alone does to a TL compensation (against the static
                // fluxgate, which the clean flight has too).
                let (em, emd) = unit_and_rate(&f, &f_dot);
                let (es, esd) = unit_and_rate(&f_static, &f_static_dot);
                let b = i.b_body.norm();
                let bd = i.b_body.dot(&i.db_body) / b;
                fluxtemp_col[kk] =
                    tl_scalar(k, l, m, b, bd, &em, &emd) - tl_scalar(k, l, m, b, bd, &es, &esd);
                f
            }
            _ => f_static,
        };
        for (ax, col) in flux.iter_mut().enumerate() {
            col[kk] = f_clean[ax] + cfg.flux_noise_nt * rfn.sample::<f64, _>(StandardNormal);
        }
        if bad {
            let (em, emd) = unit_and_rate(&f_static, &f_static_dot);
            let (et, etd) = unit_and_rate(&i.b_body, &i.db_body);
            let b = i.b_body.norm();
            let bd = et.dot(&i.db_body);
            fluxcal_col[kk] =
                tl_scalar(k, l, m, b, bd, &em, &emd) - tl_scalar(k, l, m, b, bd, &et, &etd);
        }
    }
    FluxgateTrack {
        flux,
        fluxcal_col,
        fluxtemp_col,
    }
}

/// INS attitude errors (deg) per axis: correlated drift (τ = 100 s) + 30 % white noise.
pub(super) fn ins_errors(cfg: &SimConfig, clock: &Clock) -> Vec<Vec<f64>> {
    let mut ri = rng_for(cfg.seed, 8);
    let ins_sd = cfg.ins_noise_deg;
    (0..3)
        .map(|_| {
            let gm = gauss_markov(clock.n, clock.dt, ins_sd, 100.0, &mut ri);
            gm.into_iter()
                .map(|x| x + ins_sd * 0.3 * ri.sample::<f64, _>(StandardNormal))
                .collect()
        })
        .collect()
}

/// The GPS receiver's columns: `lat`, `lon`, `alt`, `vn`, `ve`, `vd`, with a Gauss–Markov
/// position error + white noise and velocity noise.
pub(super) fn gps_readings(
    cfg: &SimConfig,
    frame: &LocalFrame,
    world: &World,
    clock: &Clock,
    pos_ned: &[Vector3<f64>],
) -> [(&'static str, Vec<f64>); 6] {
    let n = clock.n;
    let dt = clock.dt;
    let mut rg = rng_for(cfg.seed, 9);
    let gps_n = gauss_markov(n, dt, cfg.gps_sigma_h_m, cfg.gps_tau_s, &mut rg);
    let gps_e = gauss_markov(n, dt, cfg.gps_sigma_h_m, cfg.gps_tau_s, &mut rg);
    let gps_u = gauss_markov(n, dt, cfg.gps_sigma_v_m, cfg.gps_tau_s, &mut rg);
    let mut lat = Vec::with_capacity(n);
    let mut lon = Vec::with_capacity(n);
    let mut alt = Vec::with_capacity(n);
    let (mut vn, mut ve, mut vd) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    for kk in 0..n {
        let p = &pos_ned[kk];
        let white = |r: &mut ChaCha8Rng, s: f64| s * r.sample::<f64, _>(StandardNormal);
        let (la, lo) = frame.to_geo(
            p.x + gps_n[kk] + white(&mut rg, 0.1),
            p.y + gps_e[kk] + white(&mut rg, 0.1),
        );
        lat.push(la);
        lon.push(lo);
        alt.push(-p.z + gps_u[kk] + white(&mut rg, 0.2));
        let v = world.plan.velocity(clock.times[kk]);
        vn[kk] = v[0] + white(&mut rg, 0.03);
        ve[kk] = v[1] + white(&mut rg, 0.03);
        vd[kk] = -v[2] + white(&mut rg, 0.05);
    }
    [
        ("lat", lat),
        ("lon", lon),
        ("alt", alt),
        ("vn", vn),
        ("ve", ve),
        ("vd", vd),
    ]
}
