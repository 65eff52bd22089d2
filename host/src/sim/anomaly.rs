//! Geological anomaly: buried point dipoles (a uniformly magnetised sphere has exactly the
//! field of a dipole outside it), so the field is harmonic in the air by construction —
//! nothing here is drawn from the compensator's stochastic anomaly model.

use nalgebra::{Matrix3, Vector3};
use rand::Rng;
use rand_distr::{Distribution, UnitSphere};

/// μ0/4π in nT·m³/(A·m²): B[nT] = 100 · (3(m·r̂)r̂ − m)/r³ with m in A·m², r in m.
pub const MU0_4PI_NT_M3_PER_AM2: f64 = 100.0;

/// Geology presets: what lies under the flight.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GeologyPreset {
    /// Deep crystalline basement under thick sediments: gradients of ~0.001–0.01 nT/m
    /// at calibration altitude (3 km).
    Quiet,
    /// Basement at a few hundred metres to a few kilometres.
    Moderate,
    /// Shallow, strongly magnetic rocks (ore bodies, mafic intrusions): hundreds
    /// of nT and 0.1–several nT/m at 150–400 m survey altitude.
    Strong,
    /// No anomaly at all.
    None,
}

/// Parameters of the buried source population.
#[derive(Clone, Debug, PartialEq)]
pub struct Geology {
    pub preset: GeologyPreset,
    /// Source density per km² of the area flown (plus a margin).
    pub sources_per_km2: f64,
    /// Depth of the dipole centres below ground (m).
    pub depth_min_m: f64,
    pub depth_max_m: f64,
    /// Induced moment magnitudes (A·m²), drawn log-uniformly.
    pub moment_min_am2: f64,
    pub moment_max_am2: f64,
    /// Koenigsberger ratio: remanent / induced moment, remanent direction random.
    pub remanence_q: f64,
}

impl Geology {
    pub fn preset(p: GeologyPreset) -> Self {
        let (density, dmin, dmax, mmin, mmax, q) = match p {
            GeologyPreset::Quiet => (0.08, 2000.0, 6000.0, 2e9, 2e10, 0.2),
            GeologyPreset::Moderate => (0.2, 500.0, 3000.0, 5e7, 1e9, 0.3),
            GeologyPreset::Strong => (1.5, 150.0, 1200.0, 3e7, 5e8, 0.5),
            GeologyPreset::None => (0.0, 1000.0, 1000.0, 1.0, 1.0, 0.0),
        };
        Geology {
            preset: p,
            sources_per_km2: density,
            depth_min_m: dmin,
            depth_max_m: dmax,
            moment_min_am2: mmin,
            moment_max_am2: mmax,
            remanence_q: q,
        }
    }

    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.sources_per_km2.is_finite() && (0.0..=50.0).contains(&self.sources_per_km2),
            "source density must be within 0–50 per km²"
        );
        anyhow::ensure!(
            self.depth_min_m > 0.0
                && self.depth_max_m >= self.depth_min_m
                && self.depth_max_m <= 100_000.0,
            "source depths must be within (0, 100 km] with min ≤ max"
        );
        anyhow::ensure!(
            self.moment_min_am2 > 0.0
                && self.moment_max_am2 >= self.moment_min_am2
                && self.moment_max_am2 <= 1e16,
            "source moments must be within (0, 1e16] A·m² with min ≤ max"
        );
        anyhow::ensure!(
            (0.0..=20.0).contains(&self.remanence_q),
            "remanence Q must be within 0–20"
        );
        Ok(())
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct Dipole {
    /// Position in the local frame (north, east, down from sea level), m.
    pub pos_ned_m: Vector3<f64>,
    /// Magnetic moment (A·m²) in north-east-down axes.
    pub moment_am2: Vector3<f64>,
}

/// A set of buried dipoles.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Anomaly {
    pub sources: Vec<Dipole>,
}

impl Anomaly {
    /// Draws sources over the rectangle [n0,n1]×[e0,e1] (m) below ground at `ground_m`
    /// (height above sea level). Induced magnetisation is along `earth_dir`.
    pub fn generate<R: Rng>(
        geo: &Geology,
        area_ne_m: ([f64; 2], [f64; 2]),
        ground_m: f64,
        earth_dir: Vector3<f64>,
        rng: &mut R,
    ) -> Self {
        if geo.preset == GeologyPreset::None || geo.sources_per_km2 <= 0.0 {
            return Anomaly::default();
        }
        let ([n0, n1], [e0, e1]) = area_ne_m;
        let area_km2 = (n1 - n0).abs() * (e1 - e0).abs() / 1e6;
        // Cap keeps a 1 kHz hour-long flight tractable; beyond it the density is moot.
        let count = ((geo.sources_per_km2 * area_km2).round() as usize).clamp(1, 3000);
        let dir = earth_dir.normalize();
        let (lmin, lmax) = (geo.moment_min_am2.ln(), geo.moment_max_am2.ln());
        let sources = (0..count)
            .map(|_| {
                let n = rng.gen_range(n0.min(n1)..=n0.max(n1));
                let e = rng.gen_range(e0.min(e1)..=e0.max(e1));
                let depth = rng.gen_range(geo.depth_min_m..=geo.depth_max_m);
                let m_ind = (rng.gen_range(lmin..=lmax)).exp();
                let rem: [f64; 3] = UnitSphere.sample(rng);
                let moment =
                    dir * m_ind + Vector3::from(rem) * (m_ind * geo.remanence_q * rng.gen::<f64>());
                Dipole {
                    pos_ned_m: Vector3::new(n, e, depth - ground_m),
                    moment_am2: moment,
                }
            })
            .collect();
        Anomaly { sources }
    }

    /// Anomaly field vector (nT, NED) at `p` (local frame, m).
    pub fn field_ned_nt(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.field_and_gradient(p).0
    }

    /// Field (nT) and its exact spatial gradient tensor G_ij = ∂B_i/∂x_j (nT/m); G is
    /// symmetric and traceless for every source (curl- and divergence-free).
    pub fn field_and_gradient(&self, p: &Vector3<f64>) -> (Vector3<f64>, Matrix3<f64>) {
        // Plain arrays: this is the simulator's hot loop (sources × knots).
        let k = MU0_4PI_NT_M3_PER_AM2;
        let mut b = [0.0f64; 3];
        let mut g = [[0.0f64; 3]; 3];
        for s in &self.sources {
            let r = [
                p.x - s.pos_ned_m.x,
                p.y - s.pos_ned_m.y,
                p.z - s.pos_ned_m.z,
            ];
            let m = [s.moment_am2.x, s.moment_am2.y, s.moment_am2.z];
            let r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
            let inv_r = 1.0 / r2.sqrt();
            let inv_r3 = inv_r * inv_r * inv_r;
            let inv_r5 = inv_r3 / r2;
            let mr = m[0] * r[0] + m[1] * r[1] + m[2] * r[2];
            let c1 = 3.0 * k * inv_r5;
            let c2 = 15.0 * k * mr * inv_r5 / r2;
            for i in 0..3 {
                b[i] += k * inv_r3 * (3.0 * mr * r[i] / r2 - m[i]);
                for j in 0..3 {
                    let delta = if i == j { mr } else { 0.0 };
                    g[i][j] += c1 * (delta + m[i] * r[j] + r[i] * m[j]) - c2 * r[i] * r[j];
                }
            }
        }
        (
            Vector3::new(b[0], b[1], b[2]),
            Matrix3::from_fn(|i, j| g[i][j]),
        )
    }
}
