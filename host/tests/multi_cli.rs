//! `--sensors` on the command line (issue 19 items 1–2): one sensor is exactly today's run;
//! several give one coefficient file holding every sensor, and `compensate` writes each
//! sensor's compensated field and interference and the named gradients, in CSV and XYZ.

mod common;

use common::cli::{bin, csv_column, run_err, run_ok_with_stderr};
use magcomp::cli::multi::{read_multi, MultiFile};
use magcomp::io::trace::{read_trace, write_trace, ColumnMap, Trace};
use magcomp::sim::multi::{simulate_multi, STINGER_WINGTIPS_CABIN_M};
use magcomp::sim::SimConfig;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

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

/// The simulated flight of seed 2 (a 3000 m cloverleaf; `max_duration_s` as given) with
/// the first `sensors` of stinger, wingtips and cabin, written as `<tag>.csv`.
fn simulated(tag: &str, sensors: usize, max_duration_s: Option<f64>) -> (Trace, PathBuf) {
    let cfg = SimConfig {
        seed: 2,
        max_duration_s,
        ..Default::default()
    };
    let trace = simulate_multi(&cfg, &STINGER_WINGTIPS_CABIN_M[..sensors]).unwrap();
    let input = tmp(&format!("{tag}.csv"));
    write_trace(&input, &trace).unwrap();
    (trace, input)
}

/// Three simulated sensors: calibrate writes one file with every sensor; compensate
/// applies it and writes per-sensor columns and the wingtip gradient, CSV and XYZ alike.
#[test]
fn several_sensors_calibrate_and_compensate() {
    let (trace, input) = simulated("sim3", 3, None);
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
    let input = simulated("grad-only", 2, Some(60.0)).1;
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

/// The three-sensor flight of [`several_sensors_calibrate_and_compensate`] (seed 2,
/// stinger and wingtips), its file and its all-Tolles–Lawson file (`calibrate --sensors
/// mag_1,mag_2,mag_3 --method tl`), made once for the `--sensor-method` tests.
fn three_and_all_tl() -> &'static (Trace, PathBuf, PathBuf) {
    static MADE: OnceLock<(Trace, PathBuf, PathBuf)> = OnceLock::new();
    MADE.get_or_init(|| {
        let (trace, input) = simulated("sm3", 3, None);
        let all_tl = tmp("sm3-all-tl.json");
        magcomp(&[
            "calibrate",
            s(&input),
            "--sensors",
            "mag_1,mag_2,mag_3",
            "--method",
            "tl",
            "-o",
            s(&all_tl),
        ]);
        (trace, input, all_tl)
    })
}

/// `calibrate --sensors mag_1,mag_2,mag_3 --sensor-method METHODS -o <tag>.json`: the
/// file, as read, and the command's stderr.
fn calibrate_with(methods: &str, tag: &str) -> (PathBuf, MultiFile, String) {
    let (_, input, _) = three_and_all_tl();
    let out = tmp(&format!("{tag}.json"));
    let mut cmd = bin();
    cmd.args(["calibrate", s(input), "--sensors", "mag_1,mag_2,mag_3"])
        .args(["--sensor-method", methods, "-o", s(&out)]);
    let (_, err) = run_ok_with_stderr(&mut cmd);
    eprintln!("{err}");
    let (m, _) = read_multi(&out).unwrap();
    (out, m, err)
}

/// A several-sensor file's entry `k` (0-based): its name, `joint`, its embedded file's
/// text as written (every digit) and that file's method.
fn entry(m: &MultiFile, k: usize) -> (String, bool, String, String) {
    let e = &m.sensors[k];
    let text = e.coefficients.get().to_string();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let method = v["method"].as_str().unwrap().to_string();
    (e.name.clone(), e.joint, text, method)
}

/// `compensate` the three-sensor flight with `coeffs` (its sensors from the file): every
/// row in a row out, each sensor's compensated column finite; the output CSV, and each
/// sensor's interference error against the simulated truth (nT rms, mean removed).
fn compensated(coeffs: &Path, tag: &str) -> (PathBuf, [f64; 3]) {
    let (trace, input, _) = three_and_all_tl();
    let out = tmp(&format!("{tag}-out.csv"));
    magcomp(&["compensate", s(input), "--coeffs", s(coeffs), "-o", s(&out)]);
    let errors = [1, 2, 3].map(|k| {
        let comp = csv_column(&out, &format!("compensated_mag_{k}"));
        assert_eq!(comp.len(), trace.len(), "{tag}: mag_{k}: rows in, rows out");
        assert!(comp.iter().all(|v| v.is_finite()), "{tag}: mag_{k}");
        let interference = csv_column(&out, &format!("interference_mag_{k}"));
        let truth = trace.col(&format!("truth_interference_mag_{k}")).unwrap();
        magcomp::qc::truth::error_rms_nt(&interference, truth, None)
    });
    eprintln!("{tag}: error against truth mag_1..3 {errors:.4?} nT");
    (out, errors)
}

/// `--sensor-method mag_2=tl,mag_3=kf`: mag_2 is calibrated alone by Tolles–Lawson, its
/// set character for character the one `--method tl` writes for it; mag_1 (the default:
/// cross-checked) and mag_3 (`kf`: not) by the joint filter, whose σ1 the file carries.
/// The file compensates the flight, mag_2's output equal to the all-Tolles–Lawson file's.
#[test]
fn sensor_method_mixes_tolles_lawson_and_the_joint_filter() {
    let (_, _, all_tl) = three_and_all_tl();
    let (mix, v, err) = calibrate_with("mag_2=tl,mag_3=kf", "sm-mix");
    let (tl, _) = read_multi(all_tl).unwrap();
    let names: Vec<String> = (0..3).map(|k| entry(&v, k).0).collect();
    assert_eq!(names, ["mag_1", "mag_2", "mag_3"], "the --sensors order");
    let (_, joint_2, set_2, method_2) = entry(&v, 1);
    assert_eq!((joint_2, method_2.as_str()), (false, "tl"));
    assert_eq!(set_2, entry(&tl, 1).2, "mag_2: the set --method tl writes");
    for k in [0, 2] {
        let (name, _, _, method) = entry(&v, k);
        assert_eq!(method, "kf", "{name}");
    }
    // The check against TL18-OLS is recorded in the set it kept, as in a one-sensor file:
    // mag_1 was checked (the default), mag_3 (`kf`) and mag_2 (`tl`) were not.
    let checked = |k: usize| {
        let set: serde_json::Value = serde_json::from_str(&entry(&v, k).2).unwrap();
        !set["cross_check"].is_null()
    };
    assert_eq!(
        [0, 1, 2].map(checked),
        [true, false, false],
        "cross_check records"
    );
    assert!(v.sigma1.is_some(), "the joint run's σ1");
    for (name, method) in [("mag_1", "kf"), ("mag_2", "tl"), ("mag_3", "kf")] {
        let line = err
            .lines()
            .find(|l| l.trim_start().starts_with(&format!("{name} (")))
            .unwrap_or_else(|| panic!("no summary line for {name}: {err}"));
        assert!(line.contains(&format!("method {method}")), "{line}");
        assert_eq!(
            line.contains("(--sensor-method)"),
            name != "mag_1",
            "{line}"
        );
    }
    let (mix_out, mix_err) = compensated(&mix, "sm-mix");
    let (tl_out, tl_err) = compensated(all_tl, "sm-all-tl");
    let c = |p: &Path| csv_column(p, "compensated_mag_2");
    assert_eq!(
        c(&mix_out),
        c(&tl_out),
        "mag_2 compensated as by the all-TL file"
    );
    assert_eq!(mix_err[1], tl_err[1]);
}

/// Two sensors Tolles–Lawson, one left for the Kalman filter: it is calibrated alone as
/// `calibrate` calibrates one sensor (its set equal to `calibrate --sensors mag_2`'s but
/// for the provenance, which the several-sensor file does not carry), `joint` false and
/// no shared σ1; the Tolles–Lawson sets are the all-Tolles–Lawson file's.
#[test]
fn one_sensor_left_for_the_kalman_filter_is_calibrated_alone() {
    let (_, input, all_tl) = three_and_all_tl();
    let (mix, v, err) = calibrate_with("mag_1=tl,mag_3=tl", "sm-one-kf");
    let (tl, _) = read_multi(all_tl).unwrap();
    assert_eq!(v.sigma1, None, "no joint run, no shared σ1");
    for k in [0, 2] {
        let (name, joint, set, method) = entry(&v, k);
        assert_eq!((joint, method.as_str()), (false, "tl"), "{name}");
        assert_eq!(set, entry(&tl, k).2, "{name}: the set --method tl writes");
    }
    let one = tmp("sm-one-mag_2.json");
    magcomp(&["calibrate", s(input), "--sensors", "mag_2", "-o", s(&one)]);
    let mut own: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&one).unwrap()).unwrap();
    own.as_object_mut().unwrap().remove("provenance");
    let (name, joint, set, method) = entry(&v, 1);
    assert_eq!((name.as_str(), joint), ("mag_2", false));
    let set: serde_json::Value = serde_json::from_str(&set).unwrap();
    assert_eq!(set, own, "mag_2: the one-sensor calibration's set");
    eprintln!("mag_2 alone, method {method}");
    assert!(err.contains("the one Kalman-filter sensor"), "{err}");
    compensated(&mix, "sm-one-kf");
}

/// `--sensor-method` refused, each with its reason and no file written: a sensor not in
/// `--sensors`, a method other than tl/kf, a sensor named twice, an entry without `=`,
/// one sensor only, no `--sensors`; `compensate` does not take it.
#[test]
fn sensor_method_refusals_name_the_problem() {
    let input = simulated("sm-refuse", 2, Some(60.0)).1;
    let out = tmp("sm-refuse.json");
    let _ = std::fs::remove_file(&out);
    let cases: [(&str, Option<&str>, &str, &[&str]); 6] = [
        (
            "calibrate",
            Some("mag_1,mag_2"),
            "mag_3=tl",
            &["mag_3", "not among --sensors", "mag_1, mag_2"],
        ),
        (
            "calibrate",
            Some("mag_1,mag_2"),
            "mag_1=ols",
            &["'mag_1=ols'", "unknown method 'ols'", "tl", "kf"],
        ),
        (
            "calibrate",
            Some("mag_1,mag_2"),
            "mag_1=tl,mag_1=kf",
            &["names mag_1 twice"],
        ),
        (
            "calibrate",
            Some("mag_1,mag_2"),
            "mag_1",
            &["'mag_1'", "SENSOR=METHOD"],
        ),
        (
            "calibrate",
            Some("mag_1"),
            "mag_1=tl",
            &["two sensors or more"],
        ),
        (
            "calibrate",
            None,
            "mag_1=tl",
            &["--sensor-method needs --sensors"],
        ),
    ];
    for (cmd, sensors, methods, expect) in cases {
        let mut c = bin();
        c.args([cmd, s(&input), "--sensor-method", methods, "-o", s(&out)]);
        if let Some(list) = sensors {
            c.args(["--sensors", list]);
        }
        let err = run_err(&mut c);
        for e in expect {
            assert!(err.contains(e), "{sensors:?} {methods}: no '{e}' in: {err}");
        }
        assert!(!out.exists(), "{methods}: a file was written");
    }
    let mut c = bin();
    c.args(["compensate", s(&input), "--sensors", "mag_1,mag_2"])
        .args(["--sensor-method", "mag_1=tl", "-o", s(&out)]);
    let err = run_err(&mut c);
    assert!(err.contains("--sensor-method"), "{err}");
    assert!(!out.exists());
}
