//! Several magnetometers at once on simulated flights (issue 19 item 4): a stinger and
//! two wingtips (8 m out, 6 m ahead), each its own permanent/induced/eddy set, the anomaly
//! evaluated at each sensor (so the true gradient is physical). Per sensor the error of the
//! interference against the truth (nT rms, mean removed), joint against alone, the joint
//! predicted error against the actual, and the gradient of the wingtip pair against the
//! true one (nT/m, mean removed: each sensor's level is unobservable).

use magcomp::calibration::EstimatorSettings;
use magcomp::multi::{calibrate_joint, parse_sensors, separation_m};
use magcomp::qc::figures::rms_demeaned;
use magcomp::sim::multi::{simulate_multi, STINGER_WINGTIPS_CABIN_M};
use magcomp::sim::{Geology, GeologyPreset, SimConfig};

struct Case {
    label: &'static str,
    cfg: SimConfig,
}

fn cases() -> Vec<Case> {
    vec![
        Case {
            label: "3000 m",
            cfg: SimConfig {
                seed: 1,
                ..Default::default()
            },
        },
        Case {
            label: "300 m strong geology",
            cfg: SimConfig {
                seed: 1,
                cal_altitude_m: 300.0,
                altitude_swing_m: 100.0,
                geology: Geology::preset(GeologyPreset::Strong),
                ..Default::default()
            },
        },
    ]
}

struct Row {
    name: String,
    alone: f64,
    joint: f64,
    joint_predicted: f64,
    chosen: f64,
    chosen_predicted: f64,
    joint_chosen: bool,
    /// The kept figure's 90 % range (`qc::error_range`).
    range: Option<[f64; 2]>,
    /// The kept figure says it is a lower bound (the sensor's lever arm, `multi::lever`).
    lower_bound: bool,
    /// The lever arm's signal in the band (nT) and the noise the calibration allowed for.
    lever: Option<(f64, f64)>,
}

/// Per sensor the errors, and the wingtip pair's gradient error and true rms (nT/m).
fn run(cfg: &SimConfig, sensors: usize) -> (Vec<Row>, f64, f64) {
    run_at(cfg, &STINGER_WINGTIPS_CABIN_M[..sensors])
}

fn run_at(cfg: &SimConfig, offsets: &[[f64; 3]]) -> (Vec<Row>, f64, f64) {
    let sensors = offsets.len();
    let trace = simulate_multi(cfg, offsets).unwrap();
    let names: Vec<String> = (1..=sensors).map(|k| format!("mag_{k}")).collect();
    let specs = parse_sensors(&names.join(","), &trace).unwrap();
    let r = calibrate_joint(&trace, &EstimatorSettings::default(), &specs).unwrap();
    let per: Vec<Row> = r
        .sensors
        .iter()
        .map(|s| Row {
            name: s.spec.name.clone(),
            alone: s.truth_error_alone_nt.unwrap(),
            joint: s.truth_error_joint_nt.unwrap(),
            joint_predicted: s.predicted_error_nt.unwrap(),
            chosen: s.chosen_truth_error_nt().unwrap(),
            chosen_predicted: s.chosen_predicted_nt().unwrap(),
            joint_chosen: s.joint_chosen,
            range: s
                .chosen()
                .coefficients
                .as_ref()
                .and_then(|c| c.predicted_error_range_nt),
            lower_bound: s.chosen_predicted_is_lower_bound(),
            lever: s.lever_arm.map(|l| (l.signal_band_nt, l.noise_nt)),
        })
        .collect();
    // The wingtips: mag_2 and mag_3.
    let (a, b) = (&r.sensors[1], &r.sensors[2]);
    let sep = separation_m(&a.spec, &b.spec).unwrap();
    let ta = trace.col("truth_anomaly_mag_2").unwrap();
    let tb = trace.col("truth_anomaly_mag_3").unwrap();
    let (ca, cb) = (&a.chosen().compensated_nt, &b.chosen().compensated_nt);
    let d: Vec<f64> = (0..ta.len())
        .map(|i| (cb[i] - ca[i]) / sep - (tb[i] - ta[i]) / sep)
        .collect();
    let truth: Vec<f64> = (0..ta.len()).map(|i| (tb[i] - ta[i]) / sep).collect();
    (per, rms_demeaned(&d), rms_demeaned(&truth))
}

/// Measured (this commit), nT rms against truth (README, docs/model.md §7):
/// 3000 m, stinger + wingtips: alone 0.0043 / 0.0063 / 0.0054, joint 0.0029 / 0.0066 /
/// 0.0047; the joint is kept for the stinger only (its predicted error is below the alone
/// one's there); 300 m strong geology: joint 6.7 / 2.6 / 2.5 against alone 0.024 /
/// 0.17 / 0.12: the sensors' anomaly differences hold more than the joint model describes,
/// its predicted error says so (8–15 nT) and every sensor keeps its alone calibration.
/// The alone figures there are 0.42 / 2.41 / 1.83 × off: the stinger's on the
/// conservative side of a single sensor at 300 m (covariance and jackknife summed), the
/// wingtips' optimistic because their lever arm (`multi::lever`) is signal their model
/// lacks: 0.052 nT in the band from the flight's gradient and their motion, 4.6 × the
/// 0.011 nT noise they allowed for (3000 m: 0.001 nT, 0.09 ×), so their figure says it is
/// a lower bound.
/// Since the joint figure is held to its move from the alone one
/// (`multi::choice::no_better_than_its_move`), the stinger's joint predicted error at
/// 3000 m is 0.0059 nT (0.0042 before; actual 0.0029, 0.50 ×).
/// Asserted: the kept result ≤ 1.05 × alone + 0.002 nT per sensor; the joint's actual ≤
/// 2 × its predicted (never optimistic); the kept result's actual within its 90 % range
/// (`qc::error_range`; issue 17 item 4), above it only where the figure says it is a lower
/// bound, which it says for the wingtips at 300 m and for no sensor at 3000 m; the
/// wingtip gradient (16 m) within 0.002 nT/m at 3000 m and 0.05 nT/m at 300 m.
#[test]
fn joint_against_alone_on_simulated_stinger_and_wingtips() {
    let results: Vec<_> = cases().into_iter().map(|c| (run(&c.cfg, 3), c)).collect();
    for ((per, grad_err, grad_rms), c) in &results {
        for r in per {
            eprintln!(
                "{} {}: alone {:.4}, joint {:.4} nT (predicted {:.4}); kept: {} {:.4} \
                 (predicted {:.4}{}, actual/predicted {:.2}, range {:?}); lever arm {:?}",
                c.label,
                r.name,
                r.alone,
                r.joint,
                r.joint_predicted,
                if r.joint_chosen { "joint" } else { "alone" },
                r.chosen,
                r.chosen_predicted,
                if r.lower_bound { ", a lower bound" } else { "" },
                r.chosen / r.chosen_predicted,
                r.range,
                r.lever
            );
        }
        eprintln!(
            "{} wingtip gradient (16 m): error {grad_err:.5} nT/m, true gradient rms {grad_rms:.5} nT/m",
            c.label
        );
    }
    for ((per, grad_err, _), c) in &results {
        let high = c.label.starts_with("3000");
        for r in per {
            assert!(
                r.chosen <= 1.05 * r.alone + 0.002,
                "{} {}: kept {:.4} vs alone {:.4}",
                c.label,
                r.name,
                r.chosen,
                r.alone
            );
            assert!(
                r.joint <= 2.0 * r.joint_predicted,
                "{} {}: joint {:.4} vs its predicted {:.4}",
                c.label,
                r.name,
                r.joint,
                r.joint_predicted
            );
            let [lo, hi] = r.range.expect("range");
            assert!(
                lo <= r.chosen && (r.chosen <= hi || r.lower_bound),
                "{} {}: actual {:.4}, predicted {:.4} in {lo:.4}–{hi:.4} (lower bound: {})",
                c.label,
                r.name,
                r.chosen,
                r.chosen_predicted,
                r.lower_bound
            );
            // The stinger sits at the trajectory's point; the wingtips 10 m from it.
            let off_centre = r.name != "mag_1";
            assert_eq!(
                r.lower_bound,
                off_centre && !high,
                "{} {}: lever arm {:?}",
                c.label,
                r.name,
                r.lever
            );
        }
        let limit = if high { 0.002 } else { 0.05 };
        assert!(
            *grad_err < limit,
            "{}: gradient error {grad_err:.4} nT/m",
            c.label
        );
    }
}

/// The same 300 m strong-geology flight with the three sensors 1 m apart (a boom pair
/// beside the stinger): the anomaly is nearly common and the joint estimate gains.
/// Measured (this commit): printed; README. Asserted: joint ≤ 1.05 × alone + 0.002 nT on
/// every sensor and < alone on two of three; the gradient (2 m) within 0.05 nT/m.
#[test]
fn joint_gains_where_the_sensors_are_close() {
    let cfg = &cases()[1].cfg;
    let (per, grad_err, grad_rms) = run_at(cfg, &[[0.0; 3], [0.0, -1.0, 0.0], [0.0, 1.0, 0.0]]);
    let mut better = 0;
    for r in &per {
        eprintln!(
            "300 m, 1 m apart, {}: alone {:.4}, joint {:.4} nT (predicted {:.4}, {}); kept {:.4}",
            r.name,
            r.alone,
            r.joint,
            r.joint_predicted,
            if r.joint_chosen {
                "joint kept"
            } else {
                "alone kept"
            },
            r.chosen
        );
        assert!(
            r.joint <= 1.05 * r.alone + 0.002,
            "{}: {:.4} vs {:.4}",
            r.name,
            r.joint,
            r.alone
        );
        better += usize::from(r.joint < r.alone);
    }
    eprintln!("gradient (2 m): error {grad_err:.4} nT/m, true rms {grad_rms:.4} nT/m");
    assert!(better >= 2, "joint better on {better} of 3");
    assert!(grad_err < 0.05);
}

/// Why the wingtips' alone figures are optimistic at 300 m over strong geology: their
/// lever arm. The same wingtip sensors (the same aircraft draws, interference and noise)
/// given the stinger's anomaly instead of their own, i.e. flown at the trajectory's point,
/// are calibrated alone. Measured (seed 1): 0.168 / 0.116 nT against truth with their own
/// anomaly (2.41 / 1.83 × predicted), 0.057 / 0.029 with the stinger's (1.21 / 0.61 ×).
/// Asserted: the lever arm costs each wingtip more than its whole predicted error, and
/// without it both are within [0.5, 2] × their predicted error.
#[test]
fn the_wingtips_lever_arm_is_what_their_figure_misses() {
    use magcomp::calibration::{compensate_trace, Method};
    use magcomp::multi::sensor_trace;
    let cfg = &cases()[1].cfg;
    let trace = simulate_multi(cfg, &STINGER_WINGTIPS_CABIN_M[..3]).unwrap();
    let specs = parse_sensors("mag_1,mag_2,mag_3", &trace).unwrap();
    let est = EstimatorSettings {
        method: Method::Kf,
        ..EstimatorSettings::default()
    };
    let stinger = trace.col("truth_anomaly_mag_1").unwrap().to_vec();
    for s in &specs[1..] {
        let own = sensor_trace(&trace, s);
        // The scalar with the stinger's anomaly in place of its own.
        let mut centred = own.clone();
        let (mag, anomaly) = (own.col("mag").unwrap(), own.col("truth_anomaly").unwrap());
        let moved: Vec<f64> = (0..mag.len())
            .map(|i| mag[i] - anomaly[i] + stinger[i])
            .collect();
        centred.set_col("mag", moved);
        centred.set_col("truth_anomaly", stinger.clone());
        let figures = |t: &magcomp::io::trace::Trace| {
            let (f, c) = compensate_trace(t, &est, None, false).unwrap();
            let truth = f.truth_interference_nt.unwrap();
            let e = magcomp::qc::truth::error_rms_nt(&c.interference_nt, &truth, None);
            (e, c.coefficients.unwrap().predicted_error_nt.unwrap())
        };
        let ((e_own, p_own), (e_c, p_c)) = (figures(&own), figures(&centred));
        eprintln!(
            "{}: own anomaly {e_own:.4} nT (predicted {p_own:.4}, {:.2}×), the stinger's \
             {e_c:.4} (predicted {p_c:.4}, {:.2}×)",
            s.name,
            e_own / p_own,
            e_c / p_c
        );
        assert!(e_own - e_c > p_own, "{}", s.name);
        assert!((0.5..=2.0).contains(&(e_c / p_c)), "{}", s.name);
    }
}

/// The kept stinger's figure at 3000 m over seeds 1–6 (issue 19 item 4): the joint set is
/// kept on every seed, and before its figure was held to its move from the alone set
/// (`multi::choice::no_better_than_its_move`) it was optimistic: actual/predicted 0.69 /
/// 1.49 / 1.61 / 1.43 / 1.35 / 1.61, mean square 1.96 (seeds 1–10: 2.18, up to 2.90).
/// Measured now: 0.50 / 1.13 / 1.18 / 1.43 / 1.04 / 1.53, mean square 1.40 (seeds 1–10:
/// 1.15, every one in its 90 % range). Asserted: each in its range, mean square ≤ 1.6 (an
/// honest rms figure gives 1). The wingtips' kept figures on the same flights (each
/// wingtip its own aircraft draw): 12 of 12 within [0.5, 2] (seeds 1–10 alone: 19 of 20,
/// 0.54–2.73, mean square 1.64 / 1.71); asserted ≥ 11 of 12.
#[test]
fn the_kept_stingers_figure_is_honest_across_seeds() {
    let mut square = 0.0;
    let mut wingtips_within = 0;
    let seeds = 1u64..=6;
    for seed in seeds.clone() {
        let cfg = SimConfig {
            seed,
            ..Default::default()
        };
        let (per, _, _) = run(&cfg, 3);
        let r = &per[0];
        let ratio = r.chosen / r.chosen_predicted;
        let [lo, hi] = r.range.expect("range");
        eprintln!(
            "seed {seed} stinger: {} {:.4} nT, predicted {:.4} ({ratio:.2}), range {lo:.4}–{hi:.4}",
            if r.joint_chosen { "joint" } else { "alone" },
            r.chosen,
            r.chosen_predicted
        );
        assert!(lo <= r.chosen && r.chosen <= hi, "seed {seed}: {ratio:.2}");
        square += ratio * ratio;
        for w in &per[1..3] {
            let ratio = w.chosen / w.chosen_predicted;
            eprintln!(
                "seed {seed} {}: {} {:.4} nT, predicted {:.4} ({ratio:.2})",
                w.name,
                if w.joint_chosen { "joint" } else { "alone" },
                w.chosen,
                w.chosen_predicted
            );
            wingtips_within += usize::from((0.5..=2.0).contains(&ratio));
        }
    }
    let count = seeds.count();
    let mean_square = square / count as f64;
    eprintln!(
        "stinger mean (actual/predicted)²: {mean_square:.2}; wingtips within [0.5, 2]: \
         {wingtips_within} of {}",
        2 * count
    );
    assert!(mean_square <= 1.6, "{mean_square:.2}");
    assert!(wingtips_within + 1 >= 2 * count, "{wingtips_within}");
}
