//! `lag` as a delay (issue 12, item 1): the scalar's delay behind the fluxgate/GPS is
//! estimated (sub-sample, with its 1σ) and the scalar re-aligned before the filter. The
//! error after adding `lag` must be within 1.5× the same flight's error without a lag.
//! Run in release: `cargo test --release -p magcomp --test lag_delay -- --nocapture`.

use magcomp::estimate::corrections::error_against_truth_nt;
use magcomp::estimate::corrections::run_kf;
use magcomp::estimate::kf::KfOptions;
use magcomp::flight::Flight;
use magcomp::io::trace::Trace;
use magcomp::model::spec::ModelSpec;
use magcomp::qc::truth::error_rms_nt;
use magcomp::sim::{parse_hidden, simulate, simulate_detailed, SimConfig};

fn config(seed: u64, rate_hz: f64) -> SimConfig {
    let mut cfg = SimConfig {
        seed,
        sample_rate_hz: rate_hz,
        ..SimConfig::default()
    };
    if rate_hz > 100.0 {
        // A short cloverleaf at 1 kHz: one cycle of each manoeuvre per heading.
        cfg.manoeuvre_cycles = 1;
        cfg.level_s = 10.0;
    }
    cfg
}

fn flight(seed: u64, rate_hz: f64, lag_s: Option<f64>) -> Trace {
    let mut cfg = config(seed, rate_hz);
    if let Some(l) = lag_s {
        cfg.hidden = vec![parse_hidden(&format!("lag:{l}")).expect("spec")];
    }
    simulate(&cfg).expect("simulate")
}

/// Error against truth and the run.
fn error_nt(trace: &Trace, model: &str) -> (f64, magcomp::estimate::kf::KfRun) {
    let spec = ModelSpec::parse(model).expect("spec");
    let f = Flight::from_trace(trace, &spec.channels(), &spec.relative_channels()).expect("flight");
    let run = run_kf(&f, &KfOptions::new(spec)).expect("kf");
    let e = error_against_truth_nt(trace, &f, &run).expect("truth");
    (e, run)
}

/// The simulator's lag is an exact delay of the noise-free scalar (not the first-order
/// form): with τ a whole number of samples the lagged flight's scalar is the clean one's,
/// shifted.
#[test]
fn the_simulated_lag_is_an_exact_delay_of_the_scalar() {
    let mut cfg = config(3, 10.0);
    cfg.max_duration_s = Some(300.0);
    let clean = simulate_detailed(&cfg).expect("clean");
    cfg.hidden = vec![parse_hidden("lag:0.3").expect("spec")];
    let lagged = simulate_detailed(&cfg).expect("lagged");
    let (a, b) = (&clean.truth.mag_clean_nt, &lagged.truth.mag_clean_nt);
    let worst = (3..a.len())
        .map(|k| (b[k] - a[k - 3]).abs())
        .fold(0.0, f64::max);
    assert!(
        worst < 1e-6,
        "lagged scalar differs from the delayed clean one by {worst} nT"
    );
    let moved = (3..a.len())
        .map(|k| (b[k] - a[k]).abs())
        .fold(0.0, f64::max);
    assert!(
        moved > 1.0,
        "the lag changes the scalar by {moved} nT at most"
    );
}

fn check(rate_hz: f64, seed: u64, lags: &[f64]) {
    let (clean, _) = error_nt(&flight(seed, rate_hz, None), "tl16+field");
    for &lag in lags {
        let trace = flight(seed, rate_hz, Some(lag));
        // The uncorrected error only for the message: a 1 kHz filter run is not free.
        let before = if rate_hz > 100.0 {
            f64::NAN
        } else {
            error_nt(&trace, "tl16+field").0
        };
        let (after, run) = error_nt(&trace, "tl16+field+lag");
        let l = run
            .preprocessing
            .and_then(|p| p.scalar_lag)
            .expect("lag estimated");
        eprintln!(
            "{rate_hz} Hz seed {seed} lag {lag} s: τ = {:.5} ± {:.5} s; error {before:.4} → {after:.4} nT, clean {clean:.4} nT ({:.2}×)",
            l.lag_s,
            l.sigma_s,
            after / clean
        );
        assert!(
            after <= 1.5 * clean,
            "{rate_hz} Hz seed {seed} lag {lag}: error {after:.4} nT > 1.5 × clean {clean:.4}"
        );
        assert!(
            (l.lag_s - lag).abs() < 0.002 + 5.0 * l.sigma_s,
            "{rate_hz} Hz seed {seed}: τ {:.5} ± {:.5} s, truth {lag}",
            l.lag_s,
            l.sigma_s
        );
    }
}

#[test]
fn a_short_lag_is_removed_to_the_clean_floor_at_10_hz_and_1_khz() {
    check(10.0, 1, &[0.05]);
    check(1000.0, 1, &[0.05]);
}

/// The full bar of issue 12 item 1 (the 1 kHz τ = 0.05 s case is in the test above).
/// Measured: 10 Hz seed 1 τ = 0.05/0.2/0.5 → 0.0519/0.2048/0.4997 s, error 0.82/0.79/1.13×
/// the clean 0.0044 nT; seed 2 → 0.0493/0.2000/0.4995 s, 0.96/1.01/1.01× the clean
/// 0.0093 nT; 1 kHz seed 1 τ = 0.2/0.5 → 0.1990/0.4990 s, 1.07/1.33× (τ = 0.05 s:
/// 0.0495 s, 1.01×). ~2 min in release on 2 cores. Before the band-limited search
/// (estimate/corrections/lag.rs notes) τ = 0.2 s came out at 0.2364 s (4.8× the floor).
#[test]
fn lag_full_bar() {
    for seed in [1, 2] {
        check(10.0, seed, &[0.05, 0.2, 0.5]);
    }
    check(1000.0, 1, &[0.2, 0.5]);
}

/// The coefficient file carries τ with its 1σ, and `compensate --coeffs` re-aligns the
/// scalar by it: the survey-mode run gives the calibration's compensation.
#[test]
fn the_coefficient_file_carries_the_lag_and_compensate_applies_it() {
    use magcomp::calibration::{compensate_trace, EstimatorSettings, Method};
    let trace = flight(2, 10.0, Some(0.2));
    let est = EstimatorSettings {
        model: "tl16+field+lag".into(),
        method: Method::Kf,
        ..Default::default()
    };
    let (f, cal) = compensate_trace(&trace, &est, None, false).expect("calibrate");
    let file = cal.coefficients.clone().expect("file");
    let json = serde_json::to_string(&file).expect("json");
    assert!(json.contains("\"scalar_lag\""), "{json}");
    let lag = file.scalar_lag.expect("lag");
    assert!(
        (lag.lag_s - 0.2).abs() < 0.05 && lag.sigma_s > 0.0,
        "{lag:?}"
    );
    let (_, applied) = compensate_trace(&trace, &est, Some(&file), false).expect("apply");
    // Same re-alignment, so the outputs agree to the coefficients' own difference.
    let d = error_rms_nt(&cal.compensated_nt, &applied.compensated_nt, None);
    let truth = f.truth_interference_nt.as_ref().expect("truth");
    let e_cal = error_rms_nt(&cal.interference_nt, truth, None);
    eprintln!("calibration vs applied from the file: {d:.5} nT rms apart (error {e_cal:.4} nT)");
    assert!(d < 0.003, "{d}");
    let mut no_lag = file.clone();
    no_lag.scalar_lag = None;
    let e = compensate_trace(&trace, &est, Some(&no_lag), false).unwrap_err();
    assert!(e.to_string().contains("scalar_lag"), "{e}");
}
