//! The UD filter against a dense f64 covariance Kalman filter on the same problem.
#![allow(clippy::needless_range_loop)] // dense reference matrices indexed in lockstep

use magcomp_core::filter::field::{FieldProcess, FIELD_STATES};
use magcomp_core::filter::ud::{UdFilter, MAX_DYNAMIC, MAX_NOISE};

/// Small deterministic generator (xorshift) so the test needs no crates.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }
}

struct DenseKf {
    x: Vec<f64>,
    p: Vec<Vec<f64>>,
}

impl DenseKf {
    fn update(&mut self, h: &[f64], z: f64, r: f64) -> (f64, f64) {
        let n = self.x.len();
        let ph: Vec<f64> = (0..n)
            .map(|i| (0..n).map(|j| self.p[i][j] * h[j]).sum())
            .collect();
        let s: f64 = (0..n).map(|i| h[i] * ph[i]).sum::<f64>() + r;
        let nu = z - (0..n).map(|i| h[i] * self.x[i]).sum::<f64>();
        for i in 0..n {
            self.x[i] += ph[i] / s * nu;
        }
        for i in 0..n {
            for j in 0..n {
                self.p[i][j] -= ph[i] * ph[j] / s;
            }
        }
        (nu, s)
    }
    fn predict(&mut self, phi: &[Vec<f64>], q: &[Vec<f64>]) {
        let n = self.x.len();
        let x = self.x.clone();
        for i in 0..n {
            self.x[i] = (0..n).map(|k| phi[i][k] * x[k]).sum();
        }
        let mut fp = vec![vec![0.0; n]; n];
        for i in 0..n {
            for j in 0..n {
                fp[i][j] = (0..n).map(|k| phi[i][k] * self.p[k][j]).sum();
            }
        }
        for i in 0..n {
            for j in 0..n {
                self.p[i][j] = (0..n).map(|k| fp[i][k] * phi[j][k]).sum::<f64>() + q[i][j];
            }
        }
    }
}

const N: usize = 23;
const CLONE_AT: usize = 500;
const STEPS: usize = 3000;

#[test]
fn ud_matches_dense_covariance_with_field_dynamics_and_clone() {
    let n = 1 + FIELD_STATES + 16; // one clone, field, 16 constants
    let m = 1 + FIELD_STATES;
    let mut ud = UdFilter::<N>::new(n, &[0.0; N], &[1.0; N]).unwrap();
    let mut dense = DenseKf {
        x: vec![0.0; n],
        p: (0..n)
            .map(|i| (0..n).map(|j| if i == j { 1.0 } else { 0.0 }).collect())
            .collect(),
    };
    let field = FieldProcess::new(1e-6, 1e-7, 1000.0, 100.0);
    let mut rng = Rng(0x9E3779B97F4A7C15);
    let truth: Vec<f64> = (0..n).map(|_| rng.next()).collect();
    let mut max_dx = 0.0f64;
    let mut max_dp = 0.0f64;
    let mut max_dnu = 0.0f64;
    let mut max_ds = 0.0f64;
    for step in 0..STEPS {
        // time update with ds ≈ 6 m
        let ds = 6.0 + rng.next();
        let mut phi = [[0.0f32; MAX_DYNAMIC]; MAX_DYNAMIC];
        let mut g = [[0.0f32; MAX_DYNAMIC]; MAX_NOISE];
        let mut dq = [0.0f32; MAX_NOISE];
        field.discretise(ds as f32, 1, &mut phi, &mut g, &mut dq);
        ud.time_update(m, &phi, &g, &dq);
        let mut phid = vec![vec![0.0; n]; n];
        let mut qd = vec![vec![0.0; n]; n];
        for i in 0..n {
            phid[i][i] = 1.0;
        }
        for i in 0..m {
            for j in 0..m {
                phid[i][j] = phi[i][j] as f64;
            }
        }
        for i in 0..m {
            for j in 0..m {
                qd[i][j] = (0..FIELD_STATES)
                    .map(|k| g[k][i] as f64 * g[k][j] as f64 * dq[k] as f64)
                    .sum();
            }
        }
        dense.predict(&phid, &qd);
        if step == CLONE_AT {
            // clone B_h (index 1) into slot 0 in both
            ud.clone_state(0, 1);
            dense.x[0] = dense.x[1];
            for j in 0..n {
                dense.p[0][j] = dense.p[1][j];
                dense.p[j][0] = dense.p[j][1];
            }
            dense.p[0][0] = dense.p[1][1];
        }
        let mut h = [0.0f32; N];
        h[1] = 1.0;
        h[4] = rng.next() as f32 * 0.5;
        for v in h.iter_mut().take(n).skip(m) {
            *v = rng.next() as f32;
        }
        if step > CLONE_AT && step % 400 == 0 {
            h = [0.0; N];
            h[1] = 1.0;
            h[0] = -1.0;
        }
        let hd: Vec<f64> = h[..n].iter().map(|v| *v as f64).collect();
        let z = (0..n).map(|i| hd[i] * truth[i]).sum::<f64>() + 1e-3 * rng.next();
        let r = 1e-6;
        let inn = ud.update(&h, z as f32, r as f32).unwrap();
        let (nu, s) = dense.update(&hd, z, r);
        max_dnu = max_dnu.max((inn.value as f64 - nu).abs());
        // S is a tiny difference of O(1) terms late in the run; compare it against the
        // size of the prior projection, which is what f32 resolves.
        let hh: f64 = hd.iter().map(|v| v * v).sum();
        max_ds = max_ds.max((inn.variance as f64 - s).abs() / (s + 1e-6 * hh));
        assert!(ud.is_healthy(), "UD factors unhealthy at step {step}");
    }
    for i in 0..n {
        max_dx = max_dx.max((ud.state()[i] as f64 - dense.x[i]).abs());
        for j in 0..n {
            let pij = ud.covariance(i, j) as f64;
            let scale = (dense.p[i][i] * dense.p[j][j]).sqrt().max(1e-12);
            max_dp = max_dp.max((pij - dense.p[i][j]).abs() / scale);
        }
    }
    println!("max |dx| = {max_dx:.3e}, max rel dP = {max_dp:.3e}, max |dnu| = {max_dnu:.3e}, max rel dS = {max_ds:.3e}");
    assert!(max_ds < 0.05, "innovation variance mismatch {max_ds}");
    assert!(max_dx < 1e-3, "state mismatch {max_dx}");
    assert!(max_dp < 1e-2, "covariance mismatch {max_dp}");
    assert!(max_dnu < 1e-3, "innovation mismatch {max_dnu}");
}

#[test]
fn harsh_conditioning_stays_positive_definite() {
    // r = 1e-8 and P0 = 1e4 made the covariance form diverge in f32 (model.md §5).
    let n = 21;
    let mut ud = UdFilter::<N>::new(n, &[0.0; N], &[100.0; N]).unwrap();
    let mut rng = Rng(12345);
    for _ in 0..20_000 {
        let mut h = [0.0f32; N];
        for v in h.iter_mut().take(n) {
            *v = rng.next() as f32;
        }
        ud.update(&h, rng.next() as f32, 1e-8).unwrap();
        assert!(ud.is_healthy());
    }
    for i in 0..n {
        assert!(ud.variance(i) > 0.0);
    }
}

#[test]
fn bad_inputs_leave_the_filter_untouched() {
    let mut ud = UdFilter::<N>::new(3, &[0.0; N], &[1.0; N]).unwrap();
    let h = [1.0f32; N];
    assert!(ud.update(&h, f32::NAN, 1.0).is_none());
    assert!(ud.update(&h, 1.0, 0.0).is_none());
    let mut hn = h;
    hn[1] = f32::INFINITY;
    assert!(ud.update(&hn, 1.0, 1.0).is_none());
    assert_eq!(ud.state(), &[0.0, 0.0, 0.0]);
    assert!(UdFilter::<N>::new(N + 1, &[0.0; N], &[1.0; N]).is_none());
}
