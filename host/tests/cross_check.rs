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
use magcomp::sim::{parse_hidden, simulate, Geology, GeologyPreset, SimConfig};

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

/// The flight's error lies in its 90 % range (`qc::error_range`).
fn within_range(s: &Summary) -> bool {
    let e = s.error_rms_nt.expect("truth");
    s.predicted_error_range_nt
        .is_some_and(|[lo, hi]| lo <= e && e <= hi)
}

/// Issue 17 item 4's floor: one flight's error is spread over few directions (1.5–3.5),
/// so an honest rms figure cannot hold every flight within [1/3, 2] of itself; the 90 %
/// range beside it must hold nine flights in ten. 24 flights: 300 m over strong geology
/// (broad physics and the default aircraft, seeds 1–8 each) and clean 3000 m broad
/// flights (seeds 1–8). Measured (this commit): 23 of 24 in their range (the one out is
/// the default aircraft's 300 m seed 6, actual/predicted 2.27), actual/predicted
/// 0.32–2.27, mean of its square 1.05 (1.07 before the figure counted the output's
/// unfollowed high frequency, `qc::high_frequency`: 0 on 22 of these flights, 0.008 nT on
/// broad seed 1 at both heights); before it, on 52 flights (seeds 1–16 of each, four with a
/// lag) 49 in range (out: 300 m seeds 6 and 10 at 2.27 and 2.24, 3000 m seed 10 at 1.67
/// against a range up to 1.63 ×), mean square 1.26.
#[test]
fn one_flights_error_lies_in_its_predicted_range_on_nine_flights_in_ten() {
    let strong = |cfg: SimConfig| SimConfig {
        cal_altitude_m: 300.0,
        geology: Geology::preset(GeologyPreset::Strong),
        ..cfg
    };
    let mut flights = Vec::new();
    for seed in 1u64..=8 {
        flights.push(SimConfig {
            anomaly_pp_nt: None,
            ..strong(SimConfig::broad(seed))
        });
        flights.push(SimConfig {
            altitude_swing_m: 100.0,
            ..strong(SimConfig {
                seed,
                ..SimConfig::default()
            })
        });
        flights.push(SimConfig::broad(seed));
    }
    let (mut inside, mut square) = (0, 0.0);
    for cfg in &flights {
        let d = run(&simulate(cfg).expect("simulate"), &default_settings());
        let [lo, hi] = d.predicted_error_range_nt.expect("range");
        let p = d.predicted_error_nt.unwrap();
        assert!(lo < p && p < hi, "{lo} {p} {hi}");
        println!(
            "seed {} at {} m: {:.4} nT, predicted {p:.4} ({:.2}), range {lo:.4}–{hi:.4}, \
             high-frequency {:.4}",
            cfg.seed,
            cfg.cal_altitude_m,
            d.error_rms_nt.unwrap(),
            ratio(&d),
            d.unfollowed_high_frequency_nt.unwrap_or(f64::NAN)
        );
        inside += usize::from(within_range(&d));
        square += ratio(&d).powi(2);
    }
    let mean_square = square / flights.len() as f64;
    println!(
        "{inside} of {} in range, mean ratio² {mean_square:.2}",
        flights.len()
    );
    // 90 % expected: 21.6 of 24, binomial σ 1.5.
    assert!(inside >= 20, "{inside} of {}", flights.len());
    // The figure is an rms: the squared ratio averages to 1 when it is honest.
    assert!((0.6..=1.6).contains(&mean_square), "{mean_square:.2}");
}

/// Issue 17 item 4 on clean 3000 m calibrations, the default estimator: actual/predicted
/// within [0.5, 2] on nine flights in ten, over the broad physics and over the default
/// aircraft (each seed its own aircraft, fluxgate and heading order), seeds 1–16 each.
/// Measured (this commit): 31 of 32 inside (the default aircraft's seed 7 at 0.47, its
/// figure pessimistic), 0.47–1.67, mean square 1.10 (broad 1.18, default 1.02).
#[test]
fn clean_flights_are_honestly_predicted_nine_in_ten() {
    let mut flights = Vec::new();
    for seed in 1u64..=16 {
        flights.push(("broad", SimConfig::broad(seed)));
        flights.push((
            "default",
            SimConfig {
                seed,
                ..SimConfig::default()
            },
        ));
    }
    let (mut inside, mut square) = (0, 0.0);
    for (label, cfg) in &flights {
        let d = run(&simulate(cfg).expect("simulate"), &default_settings());
        let r = ratio(&d);
        println!(
            "seed {} ({label}): {:.4} nT, predicted {:.4} ({r:.2})",
            cfg.seed,
            d.error_rms_nt.unwrap(),
            d.predicted_error_nt.unwrap()
        );
        inside += usize::from((0.5..=2.0).contains(&r));
        square += r * r;
    }
    let mean_square = square / flights.len() as f64;
    println!(
        "{inside} of {} within [0.5, 2], mean ratio² {mean_square:.2}",
        flights.len()
    );
    // Nine in ten of 32: 28.8.
    assert!(inside >= 29, "{inside} of {}", flights.len());
    assert!((0.6..=1.6).contains(&mean_square), "{mean_square:.2}");
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
        "clean_s33: default {e:.4} nT, TL18-OLS {t:.4}, range {:?}, {:?}",
        d.predicted_error_range_nt, d.cross_check
    );
    assert!(within_range(&d), "{:?}", d.predicted_error_range_nt);
    assert!(e <= (1.1 * t).max(t + 0.005), "{e} vs {t}");
    assert!((0.5..=2.0).contains(&ratio(&d)), "{:.2}", ratio(&d));

    let lag = independent("lag_s32").expect("lag_s32 beside clean_s33");
    let d = run(&lag, &default_settings());
    let tl = run(&lag, &tl_ols());
    let (e, t) = (d.error_rms_nt.unwrap(), tl.error_rms_nt.unwrap());
    println!(
        "lag_s32: default {e:.4} nT, TL18-OLS {t:.4}, model {}, range {:?}",
        d.model, d.predicted_error_range_nt
    );
    // Most of its error is high-frequency interference the re-alignment cannot undo at
    // 10 Hz (0.066 nT above 1 Hz of 0.083): before the figure counted the output's
    // high-frequency content beyond its quietest minutes (`qc::high_frequency`, 0.058 nT
    // here) it lay out of its range (0.012–0.074). Since TL18-OLS is fitted on the
    // re-aligned scalar too, it is the choice here (0.0857 nT, the filter 0.0831), its
    // range 0.060–0.091 (the high end allows all the output's high frequency to be
    // interference: with the part found alone, 0.060–0.076 missed it).
    assert!(d.warnings.iter().any(|w| w.contains("lags the fluxgate")));
    assert!(within_range(&d), "{:?}", d.predicted_error_range_nt);
    let high_frequency = d.unfollowed_high_frequency_nt.unwrap();
    assert!((0.03..0.08).contains(&high_frequency), "{high_frequency}");
    assert!(
        d.warnings.iter().any(|w| w.contains("at high frequency")),
        "{:?}",
        d.warnings
    );
    assert!(e < 0.2 * t, "{e} vs {t}");
    assert!((0.5..=2.0).contains(&ratio(&d)), "{:.2}", ratio(&d));
}

/// `clean_s33` with its scalar delayed by 0.25 s (the noise-free field the truth columns
/// give, shifted by a cubic interpolation the product does not use): the delay is found
/// and TL18-OLS is fitted on the re-aligned scalar beside the filter, so the flight's own
/// evidence still chooses. Before, a found delay kept the filter unchecked: 0.108 nT
/// against the truth, outside its range (0.018–0.101), where TL18-OLS on the re-aligned
/// scalar is 0.043. Measured (this commit): 0.0427 nT, predicted 0.028, range 0.014–0.051.
#[test]
fn a_delayed_flight_is_still_checked_against_tl18_ols() {
    let Some(mut trace) = independent("clean_s33") else {
        eprintln!("skipped: ../shared/reference-data/independent-sim not present");
        return;
    };
    let col = |t: &Trace, name: &str| t.col(name).expect(name).to_vec();
    let (interference, anomaly, igrf) = (
        col(&trace, "truth_interference"),
        col(&trace, "truth_anomaly"),
        col(&trace, "igrf"),
    );
    let field: Vec<f64> = (0..interference.len())
        .map(|k| interference[k] + anomaly[k] + igrf[k])
        .collect();
    let delay_samples = 2.5;
    let delayed = |k: usize| -> f64 {
        let x = k as f64 - delay_samples;
        let i = (x.floor() as usize).clamp(1, field.len() - 3);
        let f = x - i as f64;
        let p = &field[i - 1..=i + 2];
        p[1] + 0.5
            * f
            * (p[2] - p[0]
                + f * (2.0 * p[0] - 5.0 * p[1] + 4.0 * p[2] - p[3]
                    + f * (3.0 * (p[1] - p[2]) + p[3] - p[0])))
    };
    let effect: Vec<f64> = (0..field.len())
        .map(|k| if k >= 3 { delayed(k) - field[k] } else { 0.0 })
        .collect();
    let shifted = |name: &str| -> Vec<f64> {
        col(&trace, name)
            .iter()
            .zip(&effect)
            .map(|(v, e)| v + e)
            .collect()
    };
    let (mag, truth) = (shifted("mag"), shifted("truth_interference"));
    trace.set_col("mag", mag);
    trace.set_col("truth_interference", truth);
    let d = run(&trace, &default_settings());
    let chosen = d.cross_check.as_ref().map(|c| c.chosen);
    println!(
        "clean_s33 delayed 0.25 s: {:.4} nT, predicted {:.4}, range {:?}, chosen {chosen:?}",
        d.error_rms_nt.unwrap(),
        d.predicted_error_nt.unwrap(),
        d.predicted_error_range_nt
    );
    assert!(d
        .warnings
        .iter()
        .any(|w| w.contains("lags the fluxgate by 25")));
    assert_eq!(chosen, Some(Estimator::TollesLawsonOls));
    assert!(d.error_rms_nt.unwrap() < 0.06);
    assert!(within_range(&d), "{:?}", d.predicted_error_range_nt);
}
