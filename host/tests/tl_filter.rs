//! Butterworth band-pass design and zero-phase filtering, checked with numbers.

use magcomp::signal::bandpass::{butterworth_bandpass, filtfilt, filtfilt_with_pad};
use std::f64::consts::PI;

/// Digital centre of the band: where the prewarped analogue centre √(w1·w2) maps to.
fn centre_hz(lo_hz: f64, hi_hz: f64, fs_hz: f64) -> f64 {
    let t = ((PI * lo_hz / fs_hz).tan() * (PI * hi_hz / fs_hz).tan()).sqrt();
    fs_hz / PI * t.atan()
}

#[test]
fn magnav_bandpass_response() {
    let (fs, lo, hi) = (10.0, 0.1, 0.9);
    let sos = butterworth_bandpass(4, lo, hi, fs).unwrap();
    assert_eq!(
        sos.sections.len(),
        4,
        "4-pole prototype → 8th-order band-pass"
    );
    let mag = |f: f64| sos.response(f, fs).norm();
    let inv_sqrt2 = 0.5f64.sqrt();
    println!(
        "|H| at 0.1 Hz {:.12}, 0.9 Hz {:.12}, centre {:.12}",
        mag(lo),
        mag(hi),
        mag(centre_hz(lo, hi, fs))
    );
    // −3 dB exactly at the (prewarped) edges, unity at the centre.
    assert!((mag(lo) - inv_sqrt2).abs() < 1e-9);
    assert!((mag(hi) - inv_sqrt2).abs() < 1e-9);
    assert!((mag(centre_hz(lo, hi, fs)) - 1.0).abs() < 1e-9);
    // Maximally flat: within 1 % over most of the band.
    for k in 0..=40 {
        let f = 0.2 + 0.4 * k as f64 / 40.0;
        assert!((mag(f) - 1.0).abs() < 0.01, "|H({f})| = {}", mag(f));
    }
    // Steep stop bands: 4th-order roll-off on each side.
    println!(
        "|H| stop band: 0.01 Hz {:.2e}, 0.03 Hz {:.2e}, 3 Hz {:.2e}, 4.9 Hz {:.2e}, DC {:.1e}, Nyquist {:.1e}",
        mag(0.01),
        mag(0.03),
        mag(3.0),
        mag(4.9),
        mag(0.0),
        mag(5.0)
    );
    assert!(mag(0.01) < 2e-4);
    assert!(mag(0.03) < 1e-2);
    assert!(mag(3.0) < 5e-3);
    assert!(mag(4.9) < 1e-5);
    assert!(mag(0.0) < 1e-12 && mag(5.0) < 1e-12);
    // Monotone outside the pass band.
    let mut prev = 0.0;
    for k in 1..=100 {
        let f = 0.1 * k as f64 / 100.0;
        assert!(mag(f) > prev);
        prev = mag(f);
    }
}

#[test]
fn generic_rates_and_bands() {
    for (fs, lo, hi, poles) in [
        (1000.0, 1.0, 100.0, 4),
        (1000.0, 0.1, 0.9, 4), // MagNav's band at 1 kHz: poles within 1e-3 of z = 1
        (1.0, 0.01, 0.2, 3),
        (100.0, 2.0, 30.0, 6),
    ] {
        let sos = butterworth_bandpass(poles, lo, hi, fs).unwrap();
        let m = |f: f64| sos.response(f, fs).norm();
        assert!(
            (m(lo) - 0.5f64.sqrt()).abs() < 1e-9,
            "fs {fs}: |H(lo)| = {}",
            m(lo)
        );
        assert!(
            (m(hi) - 0.5f64.sqrt()).abs() < 1e-9,
            "fs {fs}: |H(hi)| = {}",
            m(hi)
        );
        assert!((m(centre_hz(lo, hi, fs)) - 1.0).abs() < 1e-9);
        // Zero-phase filtering of a large offset plus an in-band tone stays clean at every
        // rate: the tone comes through with gain |H|², the offset does not leak.
        let f0 = centre_hz(lo, hi, fs);
        let n = (60.0 * fs / lo).round() as usize;
        let x: Vec<f64> = (0..n)
            .map(|i| 50_000.0 + (2.0 * PI * f0 * i as f64 / fs).sin())
            .collect();
        let y = filtfilt(&sos, &x).unwrap();
        let err = (n / 3..2 * n / 3)
            .map(|i| (y[i] - (2.0 * PI * f0 * i as f64 / fs).sin()).abs())
            .fold(0.0, f64::max);
        println!("fs {fs} Hz, {lo}–{hi} Hz: max error in the middle {err:.2e}");
        assert!(err < 1e-6, "fs {fs}: {err}");
    }
}

#[test]
fn invalid_designs_are_errors() {
    assert!(
        butterworth_bandpass(4, 0.1, 5.0, 10.0).is_err(),
        "high edge at Nyquist"
    );
    assert!(
        butterworth_bandpass(4, 0.9, 0.1, 10.0).is_err(),
        "edges swapped"
    );
    assert!(
        butterworth_bandpass(4, 0.0, 0.9, 10.0).is_err(),
        "zero low edge"
    );
    assert!(butterworth_bandpass(0, 0.1, 0.9, 10.0).is_err(), "no poles");
    assert!(
        butterworth_bandpass(4, 0.1, 0.9, f64::NAN).is_err(),
        "NaN rate"
    );
    let sos = butterworth_bandpass(4, 0.1, 0.9, 10.0).unwrap();
    let e = filtfilt(&sos, &[1.0; 24]).unwrap_err().to_string();
    assert!(e.contains("more than 24 samples"), "{e}");
    assert!(filtfilt(&sos, &[1.0; 25]).is_ok());
}

#[test]
fn filtfilt_is_zero_phase_with_squared_gain() {
    let (fs, n) = (10.0, 4000);
    let sos = butterworth_bandpass(4, 0.1, 0.9, fs).unwrap();
    for f in [0.15, 0.4, 0.8, 1.2] {
        let x: Vec<f64> = (0..n)
            .map(|i| (2.0 * PI * f * i as f64 / fs).sin())
            .collect();
        let y = filtfilt(&sos, &x).unwrap();
        let g2 = sos.response(f, fs).norm_sqr();
        // Away from the ends (the slowest pole, radius 0.98, has decayed to ~1e-9 after
        // 1000 samples) the output is |H|²·input: no delay, no phase.
        let err = (1000..n - 1000)
            .map(|i| (y[i] - g2 * x[i]).abs())
            .fold(0.0, f64::max);
        println!("{f} Hz: |H|² = {g2:.6}, max |y − |H|²x| = {err:.2e}");
        assert!(err < 1e-7, "{f} Hz: {err}");
    }
    // A symmetric pulse stays symmetric about the same sample.
    let mut x = vec![0.0; 4001];
    for (i, v) in x.iter_mut().enumerate() {
        *v = (-((i as f64 - 2000.0) / 8.0).powi(2)).exp();
    }
    let y = filtfilt(&sos, &x).unwrap();
    let asym = (1..300)
        .map(|k| (y[2000 + k] - y[2000 - k]).abs())
        .fold(0.0, f64::max);
    let peak = (0..4001).max_by(|&a, &b| y[a].total_cmp(&y[b])).unwrap();
    println!("pulse: peak at {peak}, max asymmetry {asym:.2e}");
    assert_eq!(peak, 2000);
    assert!(asym < 1e-10);
}

#[test]
fn filtfilt_has_no_startup_transient_on_offsets() {
    // Steady-state initial conditions: a large constant (≈ Earth's field) gives ~0 output,
    // not a ringing start-up. Without them the start would ring at ~|x| level.
    let sos = butterworth_bandpass(4, 0.1, 0.9, 10.0).unwrap();
    let x = vec![50_000.0; 500];
    let y = filtfilt(&sos, &x).unwrap();
    let worst = y.iter().map(|v| v.abs()).fold(0.0, f64::max);
    println!("constant 50 000 nT → max |y| = {worst:.2e} nT");
    assert!(worst < 1e-6);
    // Longer padding (scipy's 27) changes only the ends.
    let z: Vec<f64> = (0..3000)
        .map(|i| (i as f64 * 0.31).sin() + 1e-3 * i as f64)
        .collect();
    let a = filtfilt(&sos, &z).unwrap();
    let b = filtfilt_with_pad(&sos, &z, 27).unwrap();
    let ends = (a[0] - b[0]).abs();
    let mid = (1000..2000)
        .map(|i| (a[i] - b[i]).abs())
        .fold(0.0, f64::max);
    println!("pad 24 vs 27: |Δ| first sample {ends:.2e}, middle max {mid:.2e}");
    assert!(ends > 1e-6, "padding should matter at the ends");
    assert!(mid < 1e-7, "{mid}");
}

#[test]
fn noise_gain_matches_filtered_white_noise() {
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    let sos = butterworth_bandpass(4, 0.1, 0.9, 10.0).unwrap();
    let g = sos.filtfilt_noise_gain();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let x: Vec<f64> = (0..200_000)
        .map(|_| StandardNormal.sample(&mut rng))
        .collect();
    let y = filtfilt(&sos, &x).unwrap();
    let var = y.iter().map(|v| v * v).sum::<f64>() / y.len() as f64;
    println!("filtfilt white-noise power gain: computed {g:.4}, measured {var:.4}");
    // The band is 0.8 of 5 Hz wide: the gain is a bit under 0.16.
    assert!((0.12..0.16).contains(&g));
    assert!((var / g - 1.0).abs() < 0.03);
    // The same band at 1 kHz passes 100× less of the (wider) white-noise band.
    let g_khz = butterworth_bandpass(4, 0.1, 0.9, 1000.0)
        .unwrap()
        .filtfilt_noise_gain();
    println!("same band at 1 kHz: {g_khz:.4e}");
    assert!((g_khz / (g / 100.0) - 1.0).abs() < 0.01);
}
