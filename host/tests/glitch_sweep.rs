//! Bad scalar samples, alone, in pairs, triples and steps, and as 1 % random garbage, at
//! 10 Hz and 1 kHz: every one is found and flagged `MAG_MISSING` (no good one is), and the
//! calibration's error against the simulator's truth stays within 1.5 × the clean flight's,
//! for the default method and for TL18-OLS. The detector's own sweep over spacing,
//! amplitude and count is `signal::despike`'s unit test.

use magcomp::calibration::{compensate_trace, EstimatorSettings, Method};
use magcomp::flight::Flight;
use magcomp::io::trace::Trace;
use magcomp::qc::truth::error_rms_nt;
use magcomp::sim::{simulate, SimConfig};

mod common;
use magcomp_core::Flags;

fn settings(method: Option<Method>) -> EstimatorSettings {
    match method {
        None => EstimatorSettings {
            cross_check: true,
            ..Default::default()
        },
        Some(m) => EstimatorSettings {
            method: m,
            tl_ridge: Some(0.0),
            ..Default::default()
        },
    }
}

/// Error (nT rms against truth) and the rows flagged `MAG_MISSING`.
fn calibrated(trace: &Trace, method: Option<Method>) -> (f64, Vec<usize>) {
    let (flight, comp): (Flight, _) =
        compensate_trace(trace, &settings(method), None, false).unwrap();
    let truth = flight.truth_interference_nt.as_ref().unwrap();
    let missing = comp
        .flags
        .map(|f| {
            (0..f.len())
                .filter(|&i| f[i] & Flags::MAG_MISSING != 0)
                .collect()
        })
        .unwrap_or_default();
    (error_rms_nt(&comp.interference_nt, truth, None), missing)
}

/// A deterministic pseudo-random sequence in [0, 1) (no dependency for one test).
fn uniform(seed: &mut u64) -> f64 {
    *seed = seed
        .wrapping_mul(6_364_136_223_846_793_005)
        .wrapping_add(1_442_695_040_888_963_407);
    (*seed >> 11) as f64 / (1u64 << 53) as f64
}

/// Rows `at` of `trace`'s scalar moved by `by` nT each.
fn corrupted(trace: &Trace, at: &[usize], by: &[f64]) -> Trace {
    let mut t = trace.clone();
    let mut mag = t.col("mag").unwrap().to_vec();
    for (&i, &d) in at.iter().zip(by) {
        mag[i] += d;
    }
    t.set_col("mag", mag);
    t
}

fn sweep(trace: &Trace, label: &str) {
    let n = trace.len();
    let clean = [
        calibrated(trace, None).0,
        calibrated(trace, Some(Method::Tl)).0,
    ];
    let mut seed = 7;
    let garbage: Vec<usize> = (0..n).filter(|_| uniform(&mut seed) < 0.01).collect();
    let garbage_by: Vec<f64> = garbage
        .iter()
        .map(|_| {
            let v = 2e5 * uniform(&mut seed) - 1e5;
            // what is within the floor is no glitch a detector can see, nor one that matters
            if v.abs() < 100.0 {
                1e3
            } else {
                v
            }
        })
        .collect();
    let mid = n / 2;
    let cases: Vec<(&str, Vec<usize>, Vec<f64>)> = vec![
        ("pair 2 rows apart", vec![mid, mid + 2], vec![1e5, 1e5]),
        ("triple", vec![mid, mid + 1, mid + 3], vec![5e3, -5e3, 5e3]),
        (
            "5-sample +50 nT step",
            (mid..mid + 5).collect(),
            vec![50.0; 5],
        ),
        ("first sample", vec![0, 1], vec![4e3, 4e3]),
        ("1 % random garbage", garbage, garbage_by),
    ];
    for (name, at, by) in cases {
        let bad = corrupted(trace, &at, &by);
        for (k, method) in [None, Some(Method::Tl)].into_iter().enumerate() {
            let (err, missing) = calibrated(&bad, method);
            eprintln!(
                "{label} {name} ({:?}): {err:.4} nT against {:.4} clean ({:.2}×), {} of {} \
                 flagged",
                method.unwrap_or(Method::Kf),
                clean[k],
                err / clean[k],
                missing.len(),
                at.len()
            );
            assert_eq!(
                missing, at,
                "{label} {name}: the flagged rows are the bad ones"
            );
            assert!(
                err <= 1.5 * clean[k],
                "{label} {name}: {err:.4} against {:.4} nT",
                clean[k]
            );
        }
    }
}

#[test]
fn glitches_anywhere_cost_a_10_hz_calibration_little() {
    let trace = simulate(&SimConfig {
        seed: 3,
        ..SimConfig::default()
    })
    .unwrap();
    sweep(&trace, "10 Hz");
}

#[test]
fn glitches_anywhere_cost_a_1_khz_calibration_little() {
    let trace = simulate(&common::short_1khz_calibration()).unwrap();
    sweep(&trace, "1 kHz");
}
