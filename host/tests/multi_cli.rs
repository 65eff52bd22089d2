//! `--sensors` on the command line (issue 19 items 1–2): one sensor is exactly today's run;
//! several give one coefficient file holding every sensor, and `compensate` writes each
//! sensor's compensated field and interference and the named gradients, in CSV and XYZ.

use magcomp::io::trace::{read_trace, write_trace, ColumnMap};
use magcomp::sim::multi::{simulate_multi, STINGER_WINGTIPS_CABIN_M};
use magcomp::sim::SimConfig;
use std::path::{Path, PathBuf};
use std::process::Command;

fn magcomp(args: &[&str]) {
    let out = Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "magcomp {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A file in this test binary's scratch folder under `target/tmp` (cargo's
/// `CARGO_TARGET_TMPDIR`): the same names each run, so runs overwrite, not accumulate.
fn tmp(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("magcomp-multi-cli");
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `--sensors mag_4:flux_d` writes byte for byte what `--map mag=mag_4_uc,flux_x=flux_d_x,…`
/// writes today, calibrating and applying.
#[test]
fn one_sensor_is_todays_run() {
    let file = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../data/reference/sgl2020-flt1002-cal/flt1002_line1002.02.csv");
    if !file.exists() {
        eprintln!(
            "SKIPPED: {} is absent (shared reference data)",
            file.display()
        );
        return;
    }
    let common = ["--rate-hz", "10", "--speed-mps", "60", "--time", "0:649.95"];
    let map = "mag=mag_4_uc,flux_x=flux_d_x,flux_y=flux_d_y,flux_z=flux_d_z";
    let (a, b) = (tmp("one_sensors.csv"), tmp("one_map.csv"));
    let (ca, cb) = (tmp("one_sensors.json"), tmp("one_map.json"));
    let f = s(&file);
    magcomp(
        &[
            &["compensate", f, "--sensors", "mag_4:flux_d", "-o", s(&a)][..],
            &common,
        ]
        .concat(),
    );
    magcomp(&[&["compensate", f, "--map", map, "-o", s(&b)][..], &common].concat());
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    magcomp(
        &[
            &["calibrate", f, "--sensors", "mag_4:flux_d", "-o", s(&ca)][..],
            &common,
        ]
        .concat(),
    );
    magcomp(&[&["calibrate", f, "--map", map, "-o", s(&cb)][..], &common].concat());
    let strip = |p: &Path| {
        let mut v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap();
        // The provenance names the map given, which differs by design.
        v.as_object_mut().unwrap().remove("provenance");
        v
    };
    assert_eq!(strip(&ca), strip(&cb));
}

/// Three simulated sensors: calibrate writes one file with every sensor; compensate
/// applies it and writes per-sensor columns and the wingtip gradient, CSV and XYZ alike.
#[test]
fn several_sensors_calibrate_and_compensate() {
    let cfg = SimConfig {
        seed: 2,
        ..Default::default()
    };
    let trace = simulate_multi(&cfg, &STINGER_WINGTIPS_CABIN_M[..3]).unwrap();
    let input = tmp("sim3.csv");
    write_trace(&input, &trace).unwrap();
    let coeffs = tmp("sim3.json");
    let sensors = "mag_1,mag_2,mag_3";
    magcomp(&[
        "calibrate",
        s(&input),
        "--sensors",
        sensors,
        "-o",
        s(&coeffs),
    ]);
    let text = std::fs::read_to_string(&coeffs).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(v["format"], "magcomp-multi-coefficients-1");
    assert_eq!(v["sensors"].as_array().unwrap().len(), 3);
    for ext in ["csv", "xyz"] {
        let out = tmp(&format!("sim3_out.{ext}"));
        magcomp(&[
            "compensate",
            s(&input),
            "--sensors",
            sensors,
            "--gradients",
            "mag_2-mag_3",
            "--coeffs",
            s(&coeffs),
            "-o",
            s(&out),
        ]);
        let o = read_trace(&out, &ColumnMap::new()).unwrap();
        for c in [
            "compensated_mag_1",
            "interference_mag_2",
            "compensated_mag_3",
            "gradient_mag_2_mag_3",
        ] {
            let col = o.col(c).unwrap_or_else(|| panic!("{ext}: no {c}"));
            assert!(col.iter().all(|v| v.is_finite()), "{ext}: {c}");
        }
        // The gradient against the truth (16 m, mean removed).
        let g = o.col("gradient_mag_2_mag_3").unwrap();
        let (ta, tb) = (
            trace.col("truth_anomaly_mag_2").unwrap(),
            trace.col("truth_anomaly_mag_3").unwrap(),
        );
        let d: Vec<f64> = (0..g.len())
            .map(|i| g[i] - (tb[i] - ta[i]) / 16.0)
            .collect();
        let err = magcomp::qc::figures::rms_demeaned(&d);
        eprintln!("{ext}: gradient error {err:.5} nT/m");
        assert!(err < 0.005, "{ext}: gradient error {err}");
    }
}

/// `--gradients` without `--sensors` is refused by `compensate` as by `calibrate`: it was
/// silently ignored, so a user asking for a gradient got none and no word why.
#[test]
fn gradients_without_sensors_are_refused_by_both_commands() {
    let cfg = SimConfig {
        seed: 2,
        max_duration_s: Some(60.0),
        ..Default::default()
    };
    let trace = simulate_multi(&cfg, &STINGER_WINGTIPS_CABIN_M[..2]).unwrap();
    let input = tmp("grad-only.csv");
    write_trace(&input, &trace).unwrap();
    for cmd in ["calibrate", "compensate"] {
        let out = Command::new(env!("CARGO_BIN_EXE_magcomp"))
            .args([cmd, s(&input), "--gradients", "mag_1-mag_2", "-o"])
            .arg(tmp(&format!("grad-only-{cmd}.out")))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{cmd} accepted --gradients alone");
        assert!(err.contains("--gradients needs --sensors"), "{cmd}: {err}");
    }
}
