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
/// 3000 m, stinger + wingtips: alone 0.0043 / 0.0063 / 0.0054, joint 0.0029 / 0.0065 /
/// 0.0046; the joint is kept for the stinger only (its predicted error is below the alone
/// one's there); 300 m strong geology: joint 0.053 / 2.3 / 11.8 against alone 0.024 /
/// 0.17 / 0.12: the sensors' anomaly differences (8 m out, ±1.4 m in a 10° roll over a
/// 0.16 nT/m gradient) hold more than the joint model describes, its predicted error says
/// so (9.4 / 13 / 18 nT) and every sensor keeps its alone calibration.
/// Asserted: the kept result ≤ 1.05 × alone + 0.002 nT per sensor; the joint's actual ≤
/// 2 × its predicted (never optimistic); the kept result's actual/predicted within [0.5, 2]
/// at 3000 m (at 300 m the alone calibration's own figure is 0.42–2.4 × off: asserted
/// within [0.3, 3]); the wingtip gradient (16 m) within 0.002 nT/m at 3000 m and 0.05
/// nT/m at 300 m.
#[test]
fn joint_against_alone_on_simulated_stinger_and_wingtips() {
    let results: Vec<_> = cases().into_iter().map(|c| (run(&c.cfg, 3), c)).collect();
    for ((per, grad_err, grad_rms), c) in &results {
        for r in per {
            eprintln!(
                "{} {}: alone {:.4}, joint {:.4} nT (predicted {:.4}); kept: {} {:.4} \
                 (predicted {:.4}, actual/predicted {:.2})",
                c.label,
                r.name,
                r.alone,
                r.joint,
                r.joint_predicted,
                if r.joint_chosen { "joint" } else { "alone" },
                r.chosen,
                r.chosen_predicted,
                r.chosen / r.chosen_predicted
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
            let ratio = r.chosen / r.chosen_predicted;
            let band = if high { 0.5..=2.0 } else { 0.3..=3.0 };
            assert!(
                band.contains(&ratio),
                "{} {}: actual {:.4} / predicted {:.4} = {ratio:.2}",
                c.label,
                r.name,
                r.chosen,
                r.chosen_predicted
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
