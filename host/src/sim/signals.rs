//! Smooth time signals with analytic derivatives: diurnal variation, current-like
//! auxiliary channels, engine rpm. Everything is C¹ so dB/dt stays physical.

use rand::Rng;
use std::f64::consts::PI;

/// Σ a_i sin(2π t / P_i + φ_i).
#[derive(Clone, Debug, Default)]
pub struct SineSum {
    pub terms: Vec<(f64, f64, f64)>, // (amplitude, period_s, phase_rad)
}

impl SineSum {
    /// `n` terms with periods log-uniform in [p_min, p_max], amplitudes scaled so that
    /// the sum's rms is `rms`.
    pub fn random<R: Rng>(n: usize, p_min_s: f64, p_max_s: f64, rms: f64, rng: &mut R) -> Self {
        let mut terms: Vec<(f64, f64, f64)> = (0..n)
            .map(|_| {
                let p = (rng.gen_range(p_min_s.ln()..=p_max_s.ln())).exp();
                (rng.gen_range(0.5..1.0), p, rng.gen_range(0.0..2.0 * PI))
            })
            .collect();
        let ss: f64 = terms.iter().map(|t| t.0 * t.0 / 2.0).sum();
        let k = if ss > 0.0 { rms / ss.sqrt() } else { 0.0 };
        for t in &mut terms {
            t.0 *= k;
        }
        SineSum { terms }
    }
    pub fn value(&self, t: f64) -> f64 {
        self.terms
            .iter()
            .map(|&(a, p, ph)| a * (2.0 * PI * t / p + ph).sin())
            .sum()
    }
    pub fn deriv(&self, t: f64) -> f64 {
        self.terms
            .iter()
            .map(|&(a, p, ph)| a * 2.0 * PI / p * (2.0 * PI * t / p + ph).cos())
            .sum()
    }
    /// ∫_0^t value.
    pub fn integral(&self, t: f64) -> f64 {
        self.terms
            .iter()
            .map(|&(a, p, ph)| {
                let w = 2.0 * PI / p;
                a / w * (ph.cos() - (w * t + ph).cos())
            })
            .sum()
    }
}

/// Catmull-Rom interpolated random walk on a regular knot grid (C¹, analytic derivative).
#[derive(Clone, Debug, Default)]
pub struct SmoothWalk {
    pub knot_s: f64,
    pub y: Vec<f64>,
}

impl SmoothWalk {
    pub fn random<R: Rng>(duration_s: f64, knot_s: f64, step_sigma: f64, rng: &mut R) -> Self {
        let n = (duration_s / knot_s).ceil() as usize + 4;
        let mut y = Vec::with_capacity(n);
        let mut v = 0.0;
        for _ in 0..n {
            y.push(v);
            let w: f64 = rng.sample(rand_distr::StandardNormal);
            v += step_sigma * w;
        }
        // Start near zero: the walk is a variation, not an offset.
        let y0 = y[1];
        y.iter_mut().for_each(|v| *v -= y0);
        SmoothWalk { knot_s, y }
    }
    /// (value, derivative) at t (knot 1 is t = 0).
    pub fn eval(&self, t: f64) -> (f64, f64) {
        if self.y.len() < 4 {
            return (0.0, 0.0);
        }
        let x = t / self.knot_s + 1.0;
        let i = (x.floor().max(1.0) as usize).min(self.y.len() - 3);
        let u = x - i as f64;
        let (p0, p1, p2, p3) = (self.y[i - 1], self.y[i], self.y[i + 1], self.y[i + 2]);
        let (m1, m2) = ((p2 - p0) / 2.0, (p3 - p1) / 2.0);
        let (u2, u3) = (u * u, u * u * u);
        let v = (2.0 * u3 - 3.0 * u2 + 1.0) * p1
            + (u3 - 2.0 * u2 + u) * m1
            + (-2.0 * u3 + 3.0 * u2) * p2
            + (u3 - u2) * m2;
        let d = (6.0 * u2 - 6.0 * u) * p1
            + (3.0 * u2 - 4.0 * u + 1.0) * m1
            + (-6.0 * u2 + 6.0 * u) * p2
            + (3.0 * u2 - 2.0 * u) * m2;
        (v, d / self.knot_s)
    }
}

/// Raised-cosine step from 0 to 1 over [0, ramp]: (value, derivative).
pub fn smooth_step(tau: f64, ramp_s: f64) -> (f64, f64) {
    if tau <= 0.0 {
        (0.0, 0.0)
    } else if tau >= ramp_s {
        (1.0, 0.0)
    } else {
        let a = PI * tau / ramp_s;
        ((1.0 - a.cos()) / 2.0, PI / (2.0 * ramp_s) * a.sin())
    }
}

/// A load current: switched on/off with ramps, a level per "on" period, slow drift and
/// faster load fluctuation. 0–20 A. Value and analytic derivative.
#[derive(Clone, Debug, Default)]
pub struct CurrentWave {
    /// (on time, off time, level A)
    pub periods: Vec<(f64, f64, f64)>,
    pub ramp_s: f64,
    pub drift: SineSum,
    pub fluct: SineSum,
}

impl CurrentWave {
    pub fn random<R: Rng>(duration_s: f64, rng: &mut R) -> Self {
        let ramp_s = rng.gen_range(0.5..2.0);
        let mut periods = Vec::new();
        let mut t = -rng.gen_range(0.0..100.0);
        while t < duration_s + 10.0 {
            let on = t + rng.gen_range(15.0..150.0);
            let off = on + rng.gen_range(20.0..120.0);
            periods.push((on, off, rng.gen_range(6.0..13.0)));
            t = off + ramp_s;
        }
        CurrentWave {
            periods,
            ramp_s,
            drift: SineSum::random(2, 60.0, 600.0, 0.8, rng),
            fluct: SineSum::random(3, 2.0, 20.0, 1.0, rng),
        }
    }
    pub fn eval(&self, t: f64) -> (f64, f64) {
        let mut v = 0.0;
        let mut d = 0.0;
        let extra = self.drift.value(t) + self.fluct.value(t);
        let extra_d = self.drift.deriv(t) + self.fluct.deriv(t);
        for &(on, off, level) in &self.periods {
            if t < on || t > off + self.ramp_s {
                continue;
            }
            let (a, ad) = smooth_step(t - on, self.ramp_s);
            let (b, bd) = smooth_step(t - off, self.ramp_s);
            let env = a - b;
            let env_d = ad - bd;
            v += env * (level + extra);
            d += env_d * (level + extra) + env * extra_d;
        }
        (v, d)
    }
}

/// Engine/propeller speed (rpm) and the shaft phase ∫ rpm/60 dt (cycles), closed form.
#[derive(Clone, Debug, Default)]
pub struct RpmWave {
    pub mean_rpm: f64,
    pub var: SineSum,
}

impl RpmWave {
    pub fn random<R: Rng>(rng: &mut R) -> Self {
        RpmWave {
            mean_rpm: rng.gen_range(2150.0..2250.0),
            var: SineSum::random(3, 60.0, 900.0, 60.0, rng),
        }
    }
    pub fn rpm(&self, t: f64) -> f64 {
        self.mean_rpm + self.var.value(t)
    }
    pub fn cycles(&self, t: f64) -> f64 {
        (self.mean_rpm * t + self.var.integral(t)) / 60.0
    }
}

/// A sensor temperature over a flight (°C): from the ground's towards the cruise level's
/// with a time constant of minutes (cabin heating or cooling, a stinger cooling at
/// altitude), plus a slow heater/ventilation cycle. Value and analytic derivative.
#[derive(Clone, Debug, Default)]
pub struct TempWave {
    pub start_degc: f64,
    pub change_degc: f64,
    pub tau_s: f64,
    pub cycle: SineSum,
}

impl TempWave {
    pub fn random<R: Rng>(rng: &mut R) -> Self {
        let sign = if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
        TempWave {
            start_degc: rng.gen_range(10.0..25.0),
            change_degc: sign * rng.gen_range(10.0..25.0),
            tau_s: rng.gen_range(150.0..600.0),
            cycle: SineSum::random(2, 100.0, 500.0, rng.gen_range(1.0..3.0), rng),
        }
    }
    pub fn eval(&self, t: f64) -> (f64, f64) {
        let x = (-t.max(0.0) / self.tau_s).exp();
        (
            self.start_degc + self.change_degc * (1.0 - x) + self.cycle.value(t),
            self.change_degc * x / self.tau_s + self.cycle.deriv(t),
        )
    }
}

/// First-order Gauss–Markov sequence with stationary σ and correlation time τ.
pub fn gauss_markov<R: Rng>(n: usize, dt_s: f64, sigma: f64, tau_s: f64, rng: &mut R) -> Vec<f64> {
    let a = (-dt_s / tau_s).exp();
    let q = sigma * (1.0 - a * a).sqrt();
    let mut x = sigma * rng.sample::<f64, _>(rand_distr::StandardNormal);
    (0..n)
        .map(|_| {
            let v = x;
            x = a * x + q * rng.sample::<f64, _>(rand_distr::StandardNormal);
            v
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn check_deriv(f: impl Fn(f64) -> (f64, f64), t0: f64, t1: f64) {
        let h = 1e-4;
        let mut t = t0;
        while t < t1 {
            let num = (f(t + h).0 - f(t - h).0) / (2.0 * h);
            let (_, d) = f(t);
            assert!(
                (num - d).abs() < 1e-5 * (1.0 + d.abs()),
                "t={t} {num} vs {d}"
            );
            t += 0.37;
        }
    }

    #[test]
    fn analytic_derivatives_match() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let w = SmoothWalk::random(500.0, 30.0, 1.0, &mut rng);
        check_deriv(|t| w.eval(t), 0.1, 480.0);
        let c = CurrentWave::random(500.0, &mut rng);
        check_deriv(|t| c.eval(t), 0.1, 480.0);
        let s = SineSum::random(4, 10.0, 100.0, 2.0, &mut rng);
        check_deriv(|t| (s.value(t), s.deriv(t)), 0.1, 480.0);
        check_deriv(|t| (s.integral(t), s.value(t)), 0.1, 480.0);
        let tw = TempWave::random(&mut rng);
        check_deriv(|t| tw.eval(t), 0.1, 480.0);
        let max_i = (0..5000)
            .map(|k| c.eval(k as f64 * 0.1).0)
            .fold(f64::MIN, f64::max);
        assert!(max_i <= 20.0 && max_i > 3.0, "{max_i}");
    }
}
