//! σ1 recovered from a field generated with a known σ1 (exact discrete third-order
//! integrated white noise in distance), within the scatter of a median of periodogram
//! ordinates.

use magcomp_core::spectrum::{estimate_sigma1, Sigma1Config};

struct Rng(u64);
impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn gauss(&mut self) -> f64 {
        let (u, v) = (self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
    }
}

fn field(sigma1: f64, ds: f64, n: usize, seed: u64) -> (Vec<f64>, Vec<f64>) {
    let mut rng = Rng(seed);
    let (mut b, mut g, mut c) = (0.0f64, 0.0f64, 0.0f64);
    let mut s = Vec::with_capacity(n);
    let mut z = Vec::with_capacity(n);
    // Exact discretisation via the UD factors of Q3 (see core::filter::field).
    let d = ds;
    let dq = [d.powi(5) / 720.0, d.powi(3) / 12.0, d];
    for i in 0..n {
        s.push(i as f64 * ds);
        z.push(b);
        let w = [
            rng.gauss() * (sigma1 * sigma1 * dq[0]).sqrt(),
            rng.gauss() * (sigma1 * sigma1 * dq[1]).sqrt(),
            rng.gauss() * (sigma1 * sigma1 * dq[2]).sqrt(),
        ];
        let nb = b + d * g + 0.5 * d * d * c + w[0] + 0.5 * d * w[1] + d * d / 6.0 * w[2];
        let ng = g + d * c + w[1] + 0.5 * d * w[2];
        let nc = c + w[2];
        b = nb;
        g = ng;
        c = nc;
    }
    (s, z)
}

#[test]
fn recovers_sigma1_of_a_model_field() {
    let mut ratios = vec![];
    for (seed, sigma1) in [(1u64, 1e-6), (2, 1e-7), (3, 1.5e-5), (4, 1e-6)] {
        let (s, mut z) = field(sigma1, 6.0, 20_000, seed);
        // plus white sensor noise that must not matter at 1–8 km
        let mut rng = Rng(seed + 100);
        for v in z.iter_mut() {
            *v += 0.01 * rng.gauss();
        }
        let mut a = vec![0.0; 6000];
        let est = estimate_sigma1(&s, &z, &Sigma1Config::default(), &mut a).unwrap();
        let r = est.sigma1 / sigma1;
        println!(
            "sigma1 {sigma1:.1e}: estimate {:.3e} (ratio {r:.2}, {} ordinates over {:.0} m)",
            est.sigma1, est.ordinates, est.length_m
        );
        ratios.push(r);
    }
    for r in ratios {
        assert!((0.6..1.6).contains(&r), "ratio {r}");
    }
}

#[test]
fn too_short_or_bad_input_gives_none() {
    let (s, z) = field(1e-6, 6.0, 1000, 7); // 6 km < 2 × 8 km
    let mut a = vec![0.0; 6000];
    assert!(estimate_sigma1(&s, &z, &Sigma1Config::default(), &mut a).is_none());
    let (s, z) = field(1e-6, 6.0, 20_000, 7);
    let mut small = vec![0.0; 10];
    assert!(estimate_sigma1(&s, &z, &Sigma1Config::default(), &mut small).is_none());
    let nan = vec![f64::NAN; 20_000];
    assert!(estimate_sigma1(&s, &nan, &Sigma1Config::default(), &mut a).is_none());
}

#[test]
fn a_bad_distance_costs_no_more_than_the_samples() {
    use magcomp_core::spectrum::{sigma1_scratch_len, MAX_BINS_PER_SAMPLE, MAX_ORDINATES};
    let cfg = Sigma1Config::default();
    let (mut s, z) = field(1e-6, 6.0, 20_000, 7);
    let clean_len = sigma1_scratch_len(&s, &z, &cfg);
    assert_eq!(
        clean_len,
        3 * (119_994 / 100 + 1),
        "3 × bins of a 120 km track"
    );
    // One sample 1e11 m along (a latitude of 1e6°) and all after it: no grid of a
    // billion bins, no estimate from a grid the samples cannot fill.
    for v in &mut s[15_000..] {
        *v += 1e11;
    }
    assert_eq!(sigma1_scratch_len(&s, &z, &cfg), 0);
    let mut a = vec![0.0; 3 * MAX_BINS_PER_SAMPLE * s.len()];
    assert!(estimate_sigma1(&s, &z, &cfg, &mut a).is_none());
    // A long track: the evaluated ordinates stay at MAX_ORDINATES however long it is
    // (strided over the band), and the estimate still holds.
    let (s, z) = field(1e-6, 50.0, 400_000, 9); // 20,000 km, 175,000 ordinates in band
    let mut a = vec![0.0; sigma1_scratch_len(&s, &z, &cfg)];
    let est = estimate_sigma1(&s, &z, &cfg, &mut a).unwrap();
    assert!(est.ordinates <= MAX_ORDINATES, "{}", est.ordinates);
    assert!(est.ordinates >= MAX_ORDINATES / 2, "{}", est.ordinates);
    let r = est.sigma1 / 1e-6;
    assert!((0.7..1.4).contains(&r), "ratio {r}");
}
