//! Filter-step cost on the host: UD square-root (time + measurement update) for 21 and
//! 21 + 6 states, the plain covariance form for comparison, and whole-compensator replay
//! throughput.

use criterion::{black_box, criterion_group, criterion_main, Criterion, Throughput};
use magcomp::estimate::kf::HostCompensator;
use magcomp::flight::Flight;
use magcomp::model::spec::{with_model, ModelSpec};
use magcomp::sim::{simulate, SimConfig};
use magcomp_core::filter::covariance::CovFilter;
use magcomp_core::filter::field::FieldProcess;
use magcomp_core::filter::ud::{UdFilter, MAX_DYNAMIC, MAX_NOISE};
use magcomp_core::CompensatorConfig;

fn noise_inputs(
    ds: f32,
) -> (
    [[f32; MAX_DYNAMIC]; MAX_DYNAMIC],
    [[f32; MAX_DYNAMIC]; MAX_NOISE],
    [f32; MAX_NOISE],
) {
    let f = FieldProcess::new(1e-6, 1e-7, 1000.0, 100.0);
    let mut phi = [[0.0; MAX_DYNAMIC]; MAX_DYNAMIC];
    let mut g = [[0.0; MAX_DYNAMIC]; MAX_NOISE];
    let mut dq = [0.0; MAX_NOISE];
    f.discretise(ds, 0, &mut phi, &mut g, &mut dq);
    (phi, g, dq)
}

fn regressor<const N: usize>(n: usize, k: usize) -> [f32; N] {
    let mut h = [0.0f32; N];
    h[0] = 1.0;
    h[3] = 0.3;
    for (i, v) in h.iter_mut().enumerate().take(n).skip(5) {
        *v = ((i * 7 + k) % 13) as f32 / 13.0 - 0.5;
    }
    h
}

fn bench_steps<const N: usize>(c: &mut Criterion, n: usize, label: &str) {
    let (phi, g, dq) = noise_inputs(6.0);
    let mut grp = c.benchmark_group(format!("filter_step_{label}"));
    let mut ud = UdFilter::<N>::new(n, &[0.0; N], &[1.0; N]).unwrap();
    let h = regressor::<N>(n, 1);
    grp.bench_function("ud_time_update", |b| {
        b.iter(|| ud.time_update(5, black_box(&phi), black_box(&g), black_box(&dq)))
    });
    let mut ud = UdFilter::<N>::new(n, &[0.0; N], &[1.0; N]).unwrap();
    let mut k = 0usize;
    grp.bench_function("ud_measurement_update", |b| {
        b.iter(|| {
            k += 1;
            ud.update(black_box(&h), black_box((k % 7) as f32 * 0.01), 1e-4)
        })
    });
    let mut ud = UdFilter::<N>::new(n, &[0.0; N], &[1.0; N]).unwrap();
    grp.bench_function("ud_full_step", |b| {
        b.iter(|| {
            ud.time_update(5, &phi, &g, &dq);
            ud.update(black_box(&h), 0.01, 1e-4)
        })
    });
    let mut cov = CovFilter::<N>::new(n, &[1.0; N]).unwrap();
    grp.bench_function("covariance_full_step", |b| {
        b.iter(|| {
            cov.time_update(5, &phi, &g, &dq);
            cov.update(black_box(&h), 0.01, 1e-4)
        })
    });
    grp.finish();
}

fn filter_steps(c: &mut Criterion) {
    bench_steps::<21>(c, 21, "21_states");
    bench_steps::<27>(c, 27, "27_states");
}

fn replay(c: &mut Criterion) {
    let trace = simulate(&SimConfig::default()).unwrap();
    let spec = ModelSpec::parse("tl16+field").unwrap();
    let flight = Flight::from_trace(&trace, &[], &[]).unwrap();
    let mut grp = c.benchmark_group("replay");
    grp.throughput(Throughput::Elements(flight.len() as u64));
    grp.sample_size(20);
    grp.bench_function("compensator_tl16_field_10hz_flight", |b| {
        b.iter(|| {
            with_model(&spec, |model| {
                let mut comp =
                    HostCompensator::new(model, CompensatorConfig::for_rate(10.0)).unwrap();
                let mut acc = 0.0f32;
                for s in &flight.samples {
                    if let Some(o) = comp.push(s) {
                        acc += o.interference_nt;
                    }
                }
                while let Some(o) = comp.flush() {
                    acc += o.interference_nt;
                }
                black_box(acc)
            })
        })
    });
    grp.finish();
}

criterion_group!(benches, filter_steps, replay);
criterion_main!(benches);
