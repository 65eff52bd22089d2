//! Issue 19 item 2, what the commands give for several magnetometers. `report` takes a
//! several-sensor coefficient file. A simulated stinger
//! and two wingtips are calibrated jointly; `report --coeffs joint.json` (the file brings
//! its sensors) writes each sensor's calibration page and an overview whose figures are
//! the library's for the same coefficients, whose compensation removes the interference,
//! and whose sensor differences cancel the shared anomaly; `--sensors` picks a subset, one
//! sensor is today's single report, and the page renders in headless Chromium.
//! `compensate --sensors --realtime` runs each sensor's own causal filter (the board's
//! one filter per sensor): each sensor's output is exactly the one-sensor `--realtime`
//! run's; `--json` gives one summary per sensor.

use magcomp::calibration::EstimatorSettings;
use magcomp::cli::multi::{coefficient_sets, read_multi, sensors_of_file};
use magcomp::io::trace::{read_trace, ColumnMap};
use magcomp::multi::joint::apply_each;
use magcomp::qc::figures::band_rms_nt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

mod common;
use common::{chromium, CHROMIUM};

fn magcomp(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .args(args)
        .output()
        .unwrap()
}

fn ok(args: &[&str]) -> String {
    let out = magcomp(args);
    assert!(
        out.status.success(),
        "magcomp {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn dir() -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("report-multi");
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The number in attribute `data-KEY` of the overview page.
fn data(html: &str, key: &str) -> f64 {
    let k = format!("data-{key}=\"");
    let at = html.find(&k).unwrap_or_else(|| panic!("no data-{key}")) + k.len();
    html[at..at + html[at..].find('"').unwrap()]
        .parse()
        .unwrap()
}

/// A simulated calibration with three magnetometers and its joint coefficient file, made
/// once per run (the tests share it).
fn flight_and_file() -> (PathBuf, PathBuf) {
    static MADE: OnceLock<(PathBuf, PathBuf)> = OnceLock::new();
    MADE.get_or_init(|| {
        let d = dir();
        let (trace, joint) = (d.join("three.csv"), d.join("joint.json"));
        ok(&[
            "simulate",
            "--sensors",
            "3",
            "--flight",
            "calibration",
            "--seed",
            "3",
            "-o",
            s(&trace),
        ]);
        ok(&[
            "calibrate",
            s(&trace),
            "--sensors",
            "mag_1,mag_2,mag_3",
            "-o",
            s(&joint),
        ]);
        (trace, joint)
    })
    .clone()
}

#[test]
fn a_several_sensor_file_gives_each_sensor_its_page_and_an_overview() {
    let (trace_path, joint) = flight_and_file();
    let out = dir().join("report");
    let _ = std::fs::remove_dir_all(&out);
    ok(&[
        "report",
        s(&trace_path),
        "--coeffs",
        s(&joint),
        "--gradients",
        "mag_2-mag_3",
        "-o",
        s(&out),
    ]);
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();

    // The library's figures for the same coefficients on the same flight.
    let trace = read_trace(&trace_path, &ColumnMap::default()).unwrap();
    let (m, _) = read_multi(&joint).unwrap();
    let sensors = sensors_of_file(&m, &trace, &joint).unwrap();
    assert_eq!(sensors.len(), 3);
    let est = EstimatorSettings::default();
    let (files, _) = coefficient_sets(&trace, &est, &sensors, Some(&joint)).unwrap();
    let applied = apply_each(&trace, &est, &sensors, &files).unwrap();
    for (spec, (flight, comp)) in sensors.iter().zip(&applied) {
        let page = std::fs::read_to_string(out.join(&spec.name).join("index.html"))
            .unwrap_or_else(|e| panic!("{}'s page: {e}", spec.name));
        assert!(page.contains(&format!("(sensor {})", spec.name)));
        assert!(html.contains(&format!("href=\"{}/index.html\"", spec.name)));
        let raw = band_rms_nt(flight, &flight.mag_nt);
        let compensated = band_rms_nt(flight, &comp.compensated_nt);
        let shown = data(&html, &format!("band-compensated-{}", spec.name));
        println!(
            "{}: band rms raw {raw:.3} → compensated {compensated:.4} nT (page {shown:.4})",
            spec.name
        );
        assert!((shown - compensated).abs() <= 1e-6 + 1e-6 * compensated);
        assert!((data(&html, &format!("band-raw-{}", spec.name)) - raw).abs() <= 1e-6 * raw);
        // The interference is tens of nT in the band; what is left is the anomaly's band
        // part at 3000 m (a few hundredths).
        assert!(
            compensated < raw / 20.0,
            "{}: {compensated} of {raw}",
            spec.name
        );
    }
    // The wingtips see one anomaly: their difference keeps only the gradient's part and
    // what the two compensations left, far below the raw difference.
    let (a, b) = (&applied[1], &applied[2]);
    let raw_difference: Vec<f64> = (a.0.mag_nt.iter().zip(&b.0.mag_nt))
        .map(|(x, y)| y - x)
        .collect();
    let difference = data(&html, "band-difference-mag_3-mag_2");
    let raw_band = band_rms_nt(&a.0, &raw_difference);
    println!("mag_3 − mag_2: band rms raw {raw_band:.3} → compensated {difference:.4} nT");
    assert!(difference < raw_band / 50.0 && difference < 0.02);
    in_chromium(&out.join("index.html"));
}

#[test]
fn sensors_choose_a_subset_and_one_sensor_is_todays_report() {
    let (trace, joint) = flight_and_file();
    let two = dir().join("two");
    let _ = std::fs::remove_dir_all(&two);
    ok(&[
        "report",
        s(&trace),
        "--coeffs",
        s(&joint),
        "--sensors",
        "mag_1,mag_3",
        "-o",
        s(&two),
    ]);
    assert!(two.join("mag_1/index.html").exists() && two.join("mag_3/index.html").exists());
    assert!(!two.join("mag_2").exists());
    let html = std::fs::read_to_string(two.join("index.html")).unwrap();
    assert!(html.contains("2 magnetometers: mag_1, mag_3"));

    let one = dir().join("one");
    let _ = std::fs::remove_dir_all(&one);
    ok(&["report", s(&trace), "--sensors", "mag_2", "-o", s(&one)]);
    let page = std::fs::read_to_string(one.join("index.html")).unwrap();
    assert!(!page.contains("magnetometers:") && !one.join("mag_2").exists());

    let refused = magcomp(&[
        "report",
        s(&trace),
        "--coeffs",
        s(&joint),
        "--method",
        "tl",
        "-o",
        s(&dir().join("refused")),
    ]);
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("several magnetometers"));
}

#[test]
fn compensate_takes_the_sensors_of_a_several_sensor_file() {
    let (trace, joint) = flight_and_file();
    let out = dir().join("applied.csv");
    ok(&[
        "compensate",
        s(&trace),
        "--coeffs",
        s(&joint),
        "-o",
        s(&out),
    ]);
    let table = read_trace(&out, &ColumnMap::default()).unwrap();
    for k in 1..=3 {
        let c = table
            .col(&format!("compensated_mag_{k}"))
            .unwrap_or_else(|| panic!("compensated_mag_{k}"));
        assert_eq!(c.len(), table.col("t").unwrap().len());
    }
}

#[test]
fn realtime_runs_each_sensors_own_filter_and_json_has_every_sensor() {
    let (trace, joint) = flight_and_file();
    let d = dir();
    let both = d.join("realtime.csv");
    ok(&[
        "compensate",
        s(&trace),
        "--sensors",
        "mag_2,mag_3",
        "--realtime",
        "-o",
        s(&both),
    ]);
    let both = read_trace(&both, &ColumnMap::default()).unwrap();
    for k in [2, 3] {
        let one = d.join(format!("realtime_{k}.csv"));
        ok(&[
            "compensate",
            s(&trace),
            "--sensors",
            &format!("mag_{k}"),
            "--realtime",
            "-o",
            s(&one),
        ]);
        let one = read_trace(&one, &ColumnMap::default()).unwrap();
        // Not the joint post-flight output: in real time the output is raw until the
        // sensor's own filter has converged.
        let (a, b) = (
            both.col(&format!("compensated_mag_{k}")).unwrap(),
            one.col("compensated").unwrap(),
        );
        let differing = a.iter().zip(b).filter(|(x, y)| x != y).count();
        assert!(
            a.len() == b.len() && differing == 0,
            "mag_{k}: {differing} rows differ"
        );
        // Each output says whether it is compensated yet: the first records are raw and
        // flagged NOT_CONVERGED, as the board's are.
        let flags = both.col(&format!("flags_mag_{k}")).expect("flags column");
        let not_converged = |f: f64| (f as u16) & magcomp_core::Flags::NOT_CONVERGED != 0;
        assert!(not_converged(flags[0]));
        let cleared = flags.iter().position(|f| !not_converged(*f));
        println!(
            "mag_{k}: NOT_CONVERGED clears at row {cleared:?} of {}",
            flags.len()
        );
    }
    let out = Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .args([
            "compensate",
            s(&trace),
            "--coeffs",
            s(&joint),
            "--json",
            "-o",
        ])
        .arg(d.join("json.csv"))
        .output()
        .unwrap();
    assert!(out.status.success());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON document");
    let sensors = v["sensors"].as_array().expect("sensors");
    let names: Vec<&str> = sensors
        .iter()
        .map(|e| e["sensor"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["mag_1", "mag_2", "mag_3"]);
    for e in sensors {
        let ir = e["improvement_ratio"].as_f64().expect("IR");
        println!("{}: IR {ir:.1} with the joint file", e["sensor"]);
        assert!(ir > 20.0, "{e}");
    }
}

/// The overview renders in a browser with its figures and lines.
fn in_chromium(page: &Path) {
    if !Path::new(CHROMIUM).exists() {
        println!("SKIP chromium part: {CHROMIUM} not installed (apt-get install chromium)");
        return;
    }
    let profile = dir().join(format!("profile-{}", std::process::id()));
    std::fs::create_dir_all(&profile).unwrap();
    let url = format!("file://{}", page.display());
    let out = chromium(&["--dump-dom".into(), url], &profile).expect("dump-dom timed out");
    assert!(out.status.success());
    let dom = String::from_utf8_lossy(&out.stdout);
    for id in ["sensor-fields", "sensor-differences"] {
        let at = dom
            .find(&format!("data-plot=\"{id}\""))
            .unwrap_or_else(|| panic!("{id} not rendered"));
        let svg = &dom[at..at + dom[at..].find("</svg>").unwrap()];
        assert!(svg.contains("class=\"series\""), "{id}: no line drawn");
    }
    let _ = std::fs::remove_dir_all(&profile);
}
