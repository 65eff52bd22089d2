//! TL18 fit (band-pass + ridge) on a 20-minute, 10 Hz synthetic flight (12 000 samples).

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use magcomp::estimate::tl::{self, TlConfig, TlTerms};
use nalgebra::{DVector, Rotation3, Vector3};
use std::f64::consts::PI;
use std::time::Duration;

fn flight(n: usize) -> (Vec<[f64; 3]>, Vec<f64>) {
    let b_ned = Vector3::new(20_000.0, 1_500.0, 44_700.0);
    let flux: Vec<[f64; 3]> = (0..n)
        .map(|i| {
            let t = i as f64 / 10.0;
            // Slow heading changes with roll/pitch/yaw swings in the TL band.
            let roll = 0.09 * (2.0 * PI * 0.2 * t).sin();
            let pitch = 0.06 * (2.0 * PI * 0.15 * t + 1.0).sin();
            let yaw = (2.0 * PI * t / 300.0) + 0.05 * (2.0 * PI * 0.33 * t).sin();
            let b = Rotation3::from_euler_angles(roll, pitch, yaw).transpose() * b_ned;
            [b.x, b.y, b.z]
        })
        .collect();
    let coef: Vec<f64> = (0..16).map(|k| 10.0 + 7.0 * k as f64).collect();
    let a = tl::design_matrix(&flux, &TlTerms::Tl16, tl::BT_SCALE_NT);
    let interf = a * DVector::from_vec(coef);
    let mag = (0..n)
        .map(|i| {
            let b = flux[i];
            (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt()
                + interf[i]
                + 0.01 * ((i * 7919) % 13) as f64
        })
        .collect();
    (flux, mag)
}

fn bench_tl(c: &mut Criterion) {
    let (flux, mag) = flight(12_000);
    let cfg = TlConfig::default();
    let mut g = c.benchmark_group("tl");
    g.sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    g.bench_function("tl18_fit_12000", |b| {
        b.iter(|| tl::fit(black_box(&flux), black_box(&mag), &cfg, None).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench_tl);
criterion_main!(benches);
