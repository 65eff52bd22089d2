//! The default post-flight calibration checks itself on the flight's own evidence (issue
//! 17, items 4 and 5): each method's delete-a-group jackknife is its predicted error, the
//! method with the lower one is used, and a scalar delay the model was not told of is
//! found and re-aligned. Against the simulators' truth:
//! - ours, broad physics, clean 3000 m cloverleaves: the filter stays the choice,
//!   actual/predicted within [0.5, 2], no worse than TL18-OLS;
//! - ours with an unmodelled lag: found, and the error falls to the clean flights' level;
//! - the independent simulator's `clean_s33` (the filter's anomaly states took per-heading
//!   interference: 0.106 nT against TL18-OLS's 0.032) and `lag_s32`.

use magcomp::calibration::summary::{summarise, Summary};
use magcomp::calibration::{compensate_trace, EstimatorSettings, Method};
use magcomp::estimate::jackknife::Estimator;
use magcomp::io::trace::Trace;
use magcomp::sim::{parse_hidden, simulate, SimConfig};

#[path = "common/independent.rs"]
mod independent_sim;
use independent_sim::independent;

/// What `compensate` runs by default (no `--method`).
fn default_settings() -> EstimatorSettings {
    EstimatorSettings {
        cross_check: true,
        ..EstimatorSettings::default()
    }
}

fn tl_ols() -> EstimatorSettings {
    EstimatorSettings {
        method: Method::Tl,
        tl_ridge: Some(0.0),
        ..EstimatorSettings::default()
    }
}

fn run(trace: &Trace, est: &EstimatorSettings) -> Summary {
    let (flight, comp) = compensate_trace(trace, est, None, false).expect("calibrate");
    summarise(&flight, &comp)
}

fn ratio(s: &Summary) -> f64 {
    s.error_rms_nt.expect("truth") / s.predicted_error_nt.expect("predicted")
}

#[test]
fn on_clean_broad_flights_the_filter_is_kept_and_its_figure_is_honest() {
    // Seed 2 is where the held-out figure alone would pick TL18-OLS (0.025 nT held out
    // against the filter's 0.032; true error 0.130 against 0.015): the cloverleaf flies
    // over the same ground again and least squares fits the recurring anomaly. Its
    // jackknives (0.047 against 0.026 nT) are beyond their resolution and decide.
    for seed in [1u64, 2, 4, 6, 9] {
        let trace = simulate(&SimConfig::broad(seed)).expect("simulate");
        let d = run(&trace, &default_settings());
        let tl = run(&trace, &tl_ols());
        let check = d.cross_check.clone().expect("cross-check");
        let e = d.error_rms_nt.unwrap();
        println!(
            "seed {seed}: {e:.4} nT, predicted {:.4}, TL18-OLS {:.4}, {check:?}",
            d.predicted_error_nt.unwrap(),
            tl.error_rms_nt.unwrap()
        );
        assert_eq!(check.chosen, Estimator::KalmanFilter, "seed {seed}");
        assert!(
            (0.5..=2.0).contains(&ratio(&d)),
            "seed {seed}: {:.2}",
            ratio(&d)
        );
        assert!(e <= tl.error_rms_nt.unwrap(), "seed {seed}");
    }
}

#[test]
fn an_unmodelled_scalar_lag_is_found_and_taken_out() {
    let mut cfg = SimConfig::broad(18);
    cfg.hidden = vec![parse_hidden("lag:0.3").expect("spec")];
    let trace = simulate(&cfg).expect("simulate");
    let d = run(&trace, &default_settings());
    let forced = run(
        &trace,
        &EstimatorSettings {
            method: Method::Kf,
            ..EstimatorSettings::default()
        },
    );
    println!(
        "lag 0.3 s: default {:.4} nT (predicted {:.4}), --method kf {:.4}",
        d.error_rms_nt.unwrap(),
        d.predicted_error_nt.unwrap(),
        forced.error_rms_nt.unwrap()
    );
    assert!(d.model.contains("lag"), "{}", d.model);
    assert!(d.warnings.iter().any(|w| w.contains("lags the fluxgate")));
    // Unmodelled, the delay costs ~2 nT; found, the flight is as good as a clean one.
    assert!(forced.error_rms_nt.unwrap() > 1.0);
    assert!(d.error_rms_nt.unwrap() < 0.05);
    assert!((0.5..=2.0).contains(&ratio(&d)), "{:.2}", ratio(&d));
}

#[test]
fn independent_simulator_flights_no_worse_than_tl18_ols_and_honestly_predicted() {
    let Some(clean) = independent("clean_s33") else {
        eprintln!("skipped: ../shared/reference-data/independent-sim not present");
        return;
    };
    let d = run(&clean, &default_settings());
    let tl = run(&clean, &tl_ols());
    let (e, t) = (d.error_rms_nt.unwrap(), tl.error_rms_nt.unwrap());
    println!(
        "clean_s33: default {e:.4} nT, TL18-OLS {t:.4}, {:?}",
        d.cross_check
    );
    assert!(e <= (1.1 * t).max(t + 0.005), "{e} vs {t}");
    assert!((0.5..=2.0).contains(&ratio(&d)), "{:.2}", ratio(&d));

    let lag = independent("lag_s32").expect("lag_s32 beside clean_s33");
    let d = run(&lag, &default_settings());
    let tl = run(&lag, &tl_ols());
    let (e, t) = (d.error_rms_nt.unwrap(), tl.error_rms_nt.unwrap());
    println!(
        "lag_s32: default {e:.4} nT, TL18-OLS {t:.4}, model {}",
        d.model
    );
    assert!(d.model.contains("lag"));
    assert!(e < 0.2 * t, "{e} vs {t}");
    assert!((0.5..=2.0).contains(&ratio(&d)), "{:.2}", ratio(&d));
}
