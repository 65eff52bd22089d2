//! The world along a flight: the environment field track (Hermite between exact knots),
//! the fixed random parts (diurnal, aircraft coefficients), the hidden vector effects,
//! and small numeric helpers of `simulate_detailed`.

use super::*;

/// Environment field (main + anomaly) along the path, stored at knots with its exact
/// time derivative and Hermite-interpolated between them. At ≤ 20 Hz every sample is a
/// knot; above, knots are every 50 ms, where the cubic's error is < 1e-6 nT (the field
/// varies over hundreds of metres = seconds of flight); a take-off's every 10 ms (its
/// taxi passes steel 5–35 m away: ~1e-6 nT).
pub(super) struct FieldTrack {
    pub(super) t: Vec<f64>,
    pub(super) be: Vec<Vector3<f64>>,
    pub(super) dbe: Vec<Vector3<f64>>,
    pub(super) ba: Vec<Vector3<f64>>,
    pub(super) dba: Vec<Vector3<f64>>,
    pub(super) dt_knot: f64,
}

pub(super) fn hermite(
    t: f64,
    t0: f64,
    t1: f64,
    f: [&Vector3<f64>; 4],
) -> (Vector3<f64>, Vector3<f64>) {
    let h = t1 - t0;
    if h <= 0.0 {
        return (*f[0], *f[1]);
    }
    let u = ((t - t0) / h).clamp(0.0, 1.0);
    let (u2, u3) = (u * u, u * u * u);
    let v = f[0] * (2.0 * u3 - 3.0 * u2 + 1.0)
        + f[1] * (h * (u3 - 2.0 * u2 + u))
        + f[2] * (-2.0 * u3 + 3.0 * u2)
        + f[3] * (h * (u3 - u2));
    let d = f[0] * ((6.0 * u2 - 6.0 * u) / h)
        + f[1] * (3.0 * u2 - 4.0 * u + 1.0)
        + f[2] * ((-6.0 * u2 + 6.0 * u) / h)
        + f[3] * (3.0 * u2 - 2.0 * u);
    (v, d)
}

impl FieldTrack {
    /// (main field, its rate, anomaly, its rate) at t.
    pub(super) fn at(&self, t: f64) -> [Vector3<f64>; 4] {
        let n = self.t.len();
        let i = if n < 2 {
            0
        } else {
            (((t - self.t[0]) / self.dt_knot).floor().max(0.0) as usize).min(n - 2)
        };
        if n < 2 {
            return [self.be[0], self.dbe[0], self.ba[0], self.dba[0]];
        }
        let (t0, t1) = (self.t[i], self.t[i + 1]);
        let (be, dbe) = hermite(
            t,
            t0,
            t1,
            [&self.be[i], &self.dbe[i], &self.be[i + 1], &self.dbe[i + 1]],
        );
        let (ba, dba) = hermite(
            t,
            t0,
            t1,
            [&self.ba[i], &self.dba[i], &self.ba[i + 1], &self.dba[i + 1]],
        );
        [be, dbe, ba, dba]
    }
}

/// The fast external variation of the `diurnal` hidden effect, and its window.
pub(super) type Micropulsations = (SineSum, Option<(f64, f64)>);

/// The diurnal variation (slow sinusoids of 10 min – 3 h + a smooth random walk) and the
/// `diurnal` hidden effect's micropulsations, if it is asked for.
pub(super) fn diurnal_draws(
    cfg: &SimConfig,
    dur: f64,
) -> ((SineSum, SmoothWalk), Option<Micropulsations>) {
    let mut rd = rng_for(cfg.seed, 3);
    let diurnal = (
        SineSum::random(3, 600.0, 10_800.0, cfg.diurnal_nt * 0.8, &mut rd),
        SmoothWalk::random(dur + 10.0, 120.0, cfg.diurnal_nt * 0.15, &mut rd),
    );
    let micro = cfg
        .hidden
        .iter()
        .find(|h| h.kind == HiddenKind::Diurnal)
        .map(|h| {
            let mut r = rng_for(cfg.seed, stream_of(&h.name()));
            (
                SineSum::random(7, 20.0, 300.0, cfg.hidden_std_nt, &mut r),
                h.window_s,
            )
        });
    (diurnal, micro)
}

/// Random parts of the world that are fixed for a flight.
pub(super) struct World {
    pub(super) plan: Plan,
    pub(super) field: FieldTrack,
    pub(super) e0: Vector3<f64>,
    pub(super) diurnal: (SineSum, SmoothWalk),
    pub(super) micro: Option<Micropulsations>,
    pub(super) k: Vector3<f64>,
    pub(super) l: Matrix3<f64>,
    pub(super) m: Matrix3<f64>,
}

/// Everything at one instant that does not depend on hidden-effect scaling.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Inst {
    pub(super) be: Vector3<f64>,
    pub(super) ba: Vector3<f64>,
    pub(super) d_nt: f64,
    pub(super) d_micro_nt: f64,
    pub(super) att: [f64; 3],
    pub(super) b_body: Vector3<f64>,
    pub(super) db_body: Vector3<f64>,
    pub(super) delta_b: Vector3<f64>,
}

impl World {
    pub(super) fn diurnal_at(&self, t: f64) -> (f64, f64, f64, f64) {
        let (w, wd) = self.diurnal.1.eval(t);
        let d = self.diurnal.0.value(t) + w;
        let dd = self.diurnal.0.deriv(t) + wd;
        let (mut m, mut md) = (0.0, 0.0);
        if let Some((s, win)) = &self.micro {
            if win.is_none_or(|(a, b)| t >= a && t < b) {
                m = s.value(t);
                md = s.deriv(t);
            }
        }
        (d, dd, m, md)
    }

    pub(super) fn inst(&self, t: f64) -> Inst {
        let [be, dbe, ba, dba] = self.field.at(t);
        let (d, dd, m, md) = self.diurnal_at(t);
        let b_ned = be + ba + self.e0 * (d + m);
        let db_ned = dbe + dba + self.e0 * (dd + md);
        let s = self.plan.state(t);
        let c = dcm_ned_to_body(s.roll_rad, s.pitch_rad, s.yaw_rad);
        // Attitude is analytic, so a ±1 ms central difference of the DCM is accurate to
        // ~1e-7 relative.
        let h = 1e-3;
        let (sp, sm) = (self.plan.state(t + h), self.plan.state(t - h));
        let c_dot = (dcm_ned_to_body(sp.roll_rad, sp.pitch_rad, sp.yaw_rad)
            - dcm_ned_to_body(sm.roll_rad, sm.pitch_rad, sm.yaw_rad))
            / (2.0 * h);
        let b_body = c * b_ned;
        let db_body = c_dot * b_ned + c * db_ned;
        let delta_b = self.k + self.l * b_body + self.m * db_body;
        Inst {
            be,
            ba,
            d_nt: d,
            d_micro_nt: m,
            att: [s.roll_rad, s.pitch_rad, s.yaw_rad],
            b_body,
            db_body,
            delta_b,
        }
    }
}

/// A hidden vector effect before scaling: direction/law fixed, amplitude set later.
pub(super) enum VecEffect {
    Current {
        dir: Vector3<f64>,
        wave: CurrentWave,
        rate: bool,
    },
    Rate {
        n: Matrix3<f64>,
    },
    InducedHigh {
        c: [f64; 10],
    },
    Periodic {
        dir: Vector3<f64>,
        rpm: RpmWave,
        phase: [f64; 2],
        h2: f64,
    },
    /// The take-off's engine start (physical size, not scaled).
    Engine(takeoff::EngineStart),
}

impl VecEffect {
    pub(super) fn engine(&self) -> Option<takeoff::EngineStart> {
        match self {
            VecEffect::Engine(e) => Some(e.clone()),
            _ => None,
        }
    }

    /// Unscaled field (nT, body axes) at one instant.
    pub(super) fn field(&self, t: f64, i: &Inst) -> Vector3<f64> {
        match self {
            VecEffect::Current { dir, wave, rate } => {
                let (v, d) = wave.eval(t);
                dir * if *rate { d } else { v }
            }
            VecEffect::Rate { n } => {
                let b = i.b_body.norm();
                let e = i.b_body / b;
                let bdot = e.dot(&i.db_body);
                // N·e·d|B|/dt projects on the sensor direction as eᵀNe·d|B|/dt.
                n * e * bdot
            }
            VecEffect::InducedHigh { c } => {
                let b = i.b_body.norm();
                let e = i.b_body / b;
                let mono = [
                    e.x * e.x * e.x,
                    e.y * e.y * e.y,
                    e.z * e.z * e.z,
                    e.x * e.x * e.y,
                    e.x * e.x * e.z,
                    e.y * e.y * e.x,
                    e.y * e.y * e.z,
                    e.z * e.z * e.x,
                    e.z * e.z * e.y,
                    e.x * e.y * e.z,
                ];
                let f: f64 = mono.iter().zip(c).map(|(a, b)| a * b).sum();
                e * (f * b / magcomp_core::model::B_STAR_NT)
            }
            VecEffect::Periodic {
                dir,
                rpm,
                phase,
                h2,
            } => {
                let a = TAU * rpm.cycles(t);
                dir * ((a + phase[0]).cos() + h2 * (2.0 * a + phase[1]).cos())
            }
            VecEffect::Engine(e) => e.field(t),
        }
    }
}

/// The decoy channels: current-like waveforms, or temperature-like ones for a name
/// containing `temp` (cabin, outside air, …), with no magnetic effect.
pub(super) fn decoy_channels(cfg: &SimConfig, dur: f64, times: &[f64]) -> Vec<(String, Vec<f64>)> {
    let mut out = Vec::new();
    for d in &cfg.decoys {
        let mut r = rng_for(cfg.seed, stream_of(&format!("decoy:{d}")));
        let v: Vec<f64> = if d.to_ascii_lowercase().contains("temp") {
            let wave = TempWave::random(&mut r);
            times
                .iter()
                .map(|&t| wave.eval(t).0 + 0.01 * r.sample::<f64, _>(StandardNormal))
                .collect()
        } else {
            let wave = CurrentWave::random(dur, &mut r);
            times.iter().map(|&t| wave.eval(t).0).collect()
        };
        out.push((d.clone(), v));
    }
    out
}

/// +1 or −1 with equal odds.
pub(super) fn random_sign(r: &mut ChaCha8Rng) -> f64 {
    if r.gen_bool(0.5) {
        1.0
    } else {
        -1.0
    }
}

pub(super) fn random_dir(rng: &mut ChaCha8Rng) -> Vector3<f64> {
    let v: [f64; 3] = UnitSphere.sample(rng);
    Vector3::from(v)
}

pub(super) fn small_rotation(sigma_rad: f64, rng: &mut ChaCha8Rng) -> Matrix3<f64> {
    let n = Normal::new(0.0, sigma_rad).unwrap_or(Normal::new(0.0, 0.0).expect("zero normal"));
    Rotation3::from_euler_angles(n.sample(rng), n.sample(rng), n.sample(rng)).into_inner()
}

pub(super) fn std_dev(v: impl Iterator<Item = f64> + Clone) -> f64 {
    let (n, s) = v.clone().fold((0usize, 0.0), |(n, s), x| (n + 1, s + x));
    if n < 2 {
        return 0.0;
    }
    let m = s / n as f64;
    (v.map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1) as f64).sqrt()
}

/// Tolles–Lawson scalar interference predicted with direction `e` (and rate `e_dot`)
/// using the true coefficients: eᵀK + |B| eᵀLe + eᵀM(d|B|/dt e + |B| ė).
pub(super) fn tl_scalar(
    k: &Vector3<f64>,
    l: &Matrix3<f64>,
    m: &Matrix3<f64>,
    b: f64,
    b_dot: f64,
    e: &Vector3<f64>,
    e_dot: &Vector3<f64>,
) -> f64 {
    e.dot(k) + b * e.dot(&(l * e)) + e.dot(&(m * (e * b_dot + e_dot * b)))
}

pub(super) fn trace_col<'a>(cols: &'a [(&str, Vec<f64>)], name: &str) -> &'a [f64] {
    cols.iter()
        .find(|(n, _)| *n == name)
        .map(|(_, v)| v.as_slice())
        .expect("column written above")
}

pub(super) fn unit_and_rate(
    v: &Vector3<f64>,
    v_dot: &Vector3<f64>,
) -> (Vector3<f64>, Vector3<f64>) {
    let n = v.norm();
    let e = v / n;
    (e, (v_dot - e * e.dot(v_dot)) / n)
}

pub(super) fn json_vec(v: &Vector3<f64>) -> String {
    format!("[{:.9e},{:.9e},{:.9e}]", v.x, v.y, v.z)
}

pub(super) fn json_mat(m: &Matrix3<f64>) -> String {
    let rows: Vec<String> = (0..3)
        .map(|i| format!("[{:.9e},{:.9e},{:.9e}]", m[(i, 0)], m[(i, 1)], m[(i, 2)]))
        .collect();
    format!("[{}]", rows.join(","))
}
