//! Several magnetometers at once on the real SGL 2020 flight-1002 calibration boxes
//! (issue 19 item 3): the cabin scalars mag_3, mag_4, mag_5 with fluxgates B, C, D,
//! calibrated together (one anomaly) against each alone and against TL18-OLS per sensor,
//! box 1 → box 2 and box 2 → box 1, by the band-passed (0.1–0.9 Hz) std of the
//! compensated scalar on the other box. Skips, saying so, where the data are absent.

use magcomp::calibration::{EstimatorSettings, Method};
use magcomp::estimate::tl;
use magcomp::io::trace::Trace;
use magcomp::model::spec::DEFAULT_MODEL;
use magcomp::multi::{apply_each, calibrate_joint, parse_sensors};

#[path = "common/real_boxes.rs"]
mod real_boxes_data;
use real_boxes_data::{band_std_nt, boxes, Boxes, BOX1_ROWS, FS_HZ, SPEED_MPS};

const SENSORS: &str = "mag_3:flux_b,mag_4:flux_c,mag_5:flux_d";

/// As the command line builds them without `--method`: the default, whose per-sensor
/// calibrations take the sensor's fluxgate as a witness where it decisively helps.
fn est(model: &str) -> EstimatorSettings {
    EstimatorSettings {
        model: model.into(),
        method: Method::Kf,
        speed_mps: Some(SPEED_MPS),
        cross_check: true,
        ..Default::default()
    }
}

/// Every column of rows `range`, with `t` = row / 10 Hz.
fn box_trace(b: &Boxes, range: std::ops::Range<usize>) -> Trace {
    let mut numeric = vec![(
        "t".to_string(),
        range.clone().map(|i| i as f64 / FS_HZ).collect(),
    )];
    for c in &b.columns {
        numeric.push((c.clone(), b.column(c, range.clone())));
    }
    Trace {
        numeric,
        ..Default::default()
    }
}

fn tl18_ols(
    b: &Boxes,
    cal: std::ops::Range<usize>,
    app: std::ops::Range<usize>,
    mag: &str,
    flux: &str,
) -> f64 {
    let flux_of = |r: std::ops::Range<usize>| -> Vec<[f64; 3]> {
        let (x, y, z) = (
            b.column(&format!("{flux}_x"), r.clone()),
            b.column(&format!("{flux}_y"), r.clone()),
            b.column(&format!("{flux}_z"), r),
        );
        (0..x.len()).map(|i| [x[i], y[i], z[i]]).collect()
    };
    let mut cfg = tl::TlConfig::for_rate(FS_HZ);
    cfg.pass_hz = Some((0.1, 0.9));
    cfg.lambda = 0.0;
    let fit = tl::fit(&flux_of(cal.clone()), &b.column(mag, cal), &cfg, None).unwrap();
    band_std_nt(&tl::compensate(&fit, &flux_of(app.clone()), &b.column(mag, app)).unwrap())
}

struct Row {
    name: String,
    joint: f64,
    kept: f64,
    joint_kept: bool,
    alone: f64,
    ols: f64,
}

/// Per sensor the band std on the other box: joint, the kept result, alone, TL18-OLS.
fn transfer(
    b: &Boxes,
    model: &str,
    cal: std::ops::Range<usize>,
    app: std::ops::Range<usize>,
) -> Vec<Row> {
    let t_cal = box_trace(b, cal.clone());
    let t_app = box_trace(b, app.clone());
    let sensors = parse_sensors(SENSORS, &t_cal).unwrap();
    let joint = calibrate_joint(&t_cal, &est(model), &sensors).unwrap();
    let files = |f: &dyn Fn(
        &magcomp::multi::SensorResult,
    ) -> magcomp::calibration::result::Compensation|
     -> Vec<_> {
        joint
            .sensors
            .iter()
            .map(|s| f(s).coefficients.unwrap())
            .collect()
    };
    let j = apply_each(&t_app, &est(model), &sensors, &files(&|s| s.joint.clone())).unwrap();
    let a = apply_each(&t_app, &est(model), &sensors, &files(&|s| s.alone.clone())).unwrap();
    sensors
        .iter()
        .enumerate()
        .map(|(k, s)| {
            let flux = SENSORS
                .split(',')
                .nth(k)
                .unwrap()
                .split(':')
                .nth(1)
                .unwrap();
            let (jn, al) = (
                band_std_nt(&j[k].1.compensated_nt),
                band_std_nt(&a[k].1.compensated_nt),
            );
            let kept = joint.sensors[k].joint_chosen;
            Row {
                name: s.name.clone(),
                joint: jn,
                kept: if kept { jn } else { al },
                joint_kept: kept,
                alone: al,
                ols: tl18_ols(b, cal.clone(), app.clone(), &s.scalar_column, flux),
            }
        })
        .collect()
}

/// Measured (this commit), band std nT on the other box (README table): the joint
/// estimate does not gain on these boxes. Default model, box 1 → 2 / 2 → 1, joint against
/// alone: mag_3 4.33 / 4.79 against 4.05 / 4.80, mag_4 5.82 / 16.6 against 3.31 / 3.10,
/// mag_5 0.93 / 0.80 against 0.77 / 0.71 (TL18-OLS 4.41 / 4.87, 1.40 / 1.68, 0.66 / 0.73).
/// The per-sensor choice by predicted error keeps alone except on mag_3.
/// With `tl16+fluxmod+field` the kept results are 0.36–0.66 × TL18-OLS on mag_3 and mag_4
/// (the aim of ≤ 0.7 ×) and 1.06–1.15 × on mag_5, where the aim is not met.
/// The default now takes the fluxgate as a witness where it decisively helps
/// (`calibration::fluxgate_witness`: mag_3 with flux_b, mag_4 with flux_c), so it keeps
/// alone-with-`fluxmod` there: 1.73 / 2.21 and 0.87 / 1.11 nT. And it checks each sensor's
/// kept set against TL18-OLS as the one-sensor default does (2026-11-27, default model /
/// `tl16+fluxmod+field`): mag_3 1.566 / 2.162 and 1.591 / 2.264, mag_4 0.874 / 1.089 both,
/// mag_5 0.655 / 0.725 (TL18-OLS kept box 2 → 1; the filter's was 0.694) and 0.656 / 0.725
/// (TL18-OLS both ways; the filter's 0.663 / 0.742 were 1.01 / 1.02 × TL18-OLS).
/// Asserted (both models): kept ≤ 0.7 × TL18-OLS on mag_3 and mag_4, ≤ TL18-OLS on mag_5
/// (issue 17 item 5; 0.5 % for rounding: without the check it was 1.01 / 1.02 ×),
/// both ways; every model: kept ≤ 1.3 × alone.
#[test]
fn joint_calibration_on_the_real_boxes_against_alone_and_tl18_ols() {
    let Some(b) = boxes() else { return };
    let n = b.len();
    let mut failures = Vec::new();
    for model in [DEFAULT_MODEL, "tl16+fluxmod+field"] {
        for (label, cal, app) in [
            ("box 1 → box 2", 0..BOX1_ROWS, BOX1_ROWS..n),
            ("box 2 → box 1", BOX1_ROWS..n, 0..BOX1_ROWS),
        ] {
            for r in transfer(&b, model, cal, app) {
                eprintln!(
                    "{model} {label} {}: joint {:.3}, alone {:.3}, kept {} {:.3}, TL18-OLS {:.3} nT \
                     (kept/OLS {:.2}, joint/alone {:.2})",
                    r.name,
                    r.joint,
                    r.alone,
                    if r.joint_kept { "joint" } else { "alone" },
                    r.kept,
                    r.ols,
                    r.kept / r.ols,
                    r.joint / r.alone
                );
                let ratio = if r.name == "mag_5" { 1.005 } else { 0.7 };
                if r.kept > ratio * r.ols {
                    failures.push(format!(
                        "{model} {label} {}: kept {:.3} vs TL18-OLS {:.3}",
                        r.name, r.kept, r.ols
                    ));
                }
                if r.kept > 1.3 * r.alone {
                    failures.push(format!(
                        "{model} {label} {}: kept {:.3} vs alone {:.3}",
                        r.name, r.kept, r.alone
                    ));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
