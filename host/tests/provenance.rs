//! Issue 22 item 3: coefficient files record where they came from (source file and its
//! SHA-256, column map, sensor, window, flight date, model, magcomp version); applying
//! them to another sensor or more than 90 days after the calibration flight warns on
//! stderr, in `--json` and on the report page; a file written before provenance existed
//! still loads, without those warnings.

mod common;

use common::cli::{bin, run_ok, run_ok_with_stderr, simulate, tmp};
use magcomp::io::trace::{read_trace, write_trace, ColumnMap};
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};

const CAL_DATE: &str = "2020-06-20";

/// A simulated flight calibrated (TL: the quick fit; provenance is the same for both
/// methods) with the calibration date given: (trace, coefficient file).
fn calibrated(dir: &Path) -> (PathBuf, PathBuf) {
    let trace = simulate(dir, &[]);
    let coeffs = dir.join("coeffs.json");
    run_ok(
        bin()
            .arg("calibrate")
            .arg(&trace)
            .args(["--method", "tl", "--date", CAL_DATE, "-o"])
            .arg(&coeffs),
    );
    (trace, coeffs)
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// `compensate --json` of `trace` with `coeffs` and `extra` arguments: (summary, stderr).
fn compensate(
    trace: &Path,
    coeffs: &Path,
    extra: &[&str],
    out: &Path,
) -> (serde_json::Value, String) {
    let (o, e) = run_ok_with_stderr(
        bin()
            .arg("compensate")
            .arg(trace)
            .arg("--coeffs")
            .arg(coeffs)
            .args(extra)
            .args(["--json", "-o"])
            .arg(out),
    );
    (serde_json::from_str(o.trim()).unwrap(), e)
}

fn warned(summary: &serde_json::Value, stderr: &str, what: &str) -> bool {
    let in_json = summary["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .any(|w| w.as_str().unwrap().contains(what));
    let on_stderr = stderr
        .lines()
        .any(|l| l.starts_with("warning: ") && l.contains(what));
    assert_eq!(in_json, on_stderr, "{what}: --json and stderr disagree");
    in_json
}

const OTHER_SENSOR: &str = "coefficients belong to one sensor";
const STALE: &str = "days from the calibration flight";

#[test]
fn the_file_records_its_provenance() {
    let d = tmp("prov-record");
    let (trace, coeffs) = calibrated(&d);
    let p = &json(&coeffs)["provenance"];
    let hash: String = Sha256::digest(std::fs::read(&trace).unwrap())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    assert_eq!(p["source_file"], trace.display().to_string(), "{p}");
    assert_eq!(p["source_sha256"], hash, "{p}");
    assert_eq!(p["sensor"], "mag", "{p}");
    assert_eq!(p["flight_date"], CAL_DATE, "{p}");
    assert_eq!(p["model"], json(&coeffs)["model"], "{p}");
    assert_eq!(p["magcomp_version"], env!("CARGO_PKG_VERSION"), "{p}");
    let t = read_trace(&trace, &ColumnMap::new()).unwrap();
    let tt = t.col("t").unwrap();
    assert_eq!(p["t_first_s"].as_f64(), Some(tt[0]));
    assert_eq!(p["t_last_s"].as_f64(), Some(*tt.last().unwrap()));
    assert!(p.get("column_map").is_none(), "no --map given: {p}");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn same_sensor_within_90_days_is_quiet() {
    let d = tmp("prov-quiet");
    let (trace, coeffs) = calibrated(&d);
    let (s, e) = compensate(&trace, &coeffs, &["--date", "2020-09-17"], &d.join("o.csv"));
    assert!(
        !warned(&s, &e, OTHER_SENSOR) && !warned(&s, &e, STALE),
        "{s}"
    );
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn long_after_the_calibration_warns() {
    let d = tmp("prov-stale");
    let (trace, coeffs) = calibrated(&d);
    let (s, e) = compensate(&trace, &coeffs, &["--date", "2021-06-20"], &d.join("o.csv"));
    assert!(warned(&s, &e, STALE), "{s}\n{e}");
    assert!(warned(&s, &e, "(2021-06-20) is 365 days"), "{e}");
    assert!(!warned(&s, &e, OTHER_SENSOR));
    // Streamed too (the date from --date: a streamed run reads no columns ahead).
    let args = ["--date", "2021-06-20", "--stream", "always"];
    let (s, e) = compensate(&trace, &coeffs, &args, &d.join("s.csv"));
    assert!(warned(&s, &e, STALE), "{s}\n{e}");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn another_sensor_warns_on_stderr_json_and_the_report_page() {
    let d = tmp("prov-sensor");
    let (trace, coeffs) = calibrated(&d);
    // The same flight with its scalar under another column name: another sensor.
    let mut t = read_trace(&trace, &ColumnMap::new()).unwrap();
    for (n, _) in t.numeric.iter_mut() {
        if n == "mag" {
            *n = "mag_4_uc".into();
        }
    }
    let other = d.join("other.csv");
    write_trace(&other, &t).unwrap();
    let args = ["--map", "mag=mag_4_uc", "--date", CAL_DATE];
    let (s, e) = compensate(&other, &coeffs, &args, &d.join("o.csv"));
    assert!(warned(&s, &e, OTHER_SENSOR), "{s}\n{e}");
    assert!(warned(&s, &e, "this flight's scalar is 'mag_4_uc'"), "{e}");
    assert!(!warned(&s, &e, STALE));

    let page = d.join("report");
    run_ok(
        bin()
            .arg("report")
            .arg(&other)
            .args(args)
            .arg("--coeffs")
            .arg(&coeffs)
            .arg("-o")
            .arg(&page),
    );
    let html = std::fs::read_to_string(page.join("index.html")).unwrap();
    assert!(html.contains(OTHER_SENSOR), "the page does not warn");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn a_file_without_provenance_still_loads_and_applies() {
    let d = tmp("prov-old");
    let (trace, coeffs) = calibrated(&d);
    let mut v = json(&coeffs);
    v.as_object_mut().unwrap().remove("provenance").unwrap();
    let old = d.join("old.json");
    std::fs::write(&old, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    let c = magcomp::calibration::coefficients::read_coefficients(&old).unwrap();
    assert!(c.provenance.is_none());
    // Nothing to compare with: applied without provenance warnings, even a year on.
    let (s, e) = compensate(&trace, &old, &["--date", "2021-06-20"], &d.join("o.csv"));
    assert!(
        !warned(&s, &e, OTHER_SENSOR) && !warned(&s, &e, STALE),
        "{s}"
    );
    std::fs::remove_dir_all(&d).ok();
}
