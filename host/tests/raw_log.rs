//! What post-flight needs leaves the board (issue 23 item 6): with `RAW,ON` (here
//! `replay --raw`, the board's own acquisition code) every scalar sample also goes out as
//! a `$MCRAW` line, and the output log reads back as a trace that calibrates. Frames in =
//! rows out, the scalar exact, and the log's coefficients compensate the simulated flight
//! against its truth within the log calibration's own predicted error. A corrupted raw
//! line is refused, counted and said, never read.

mod common;
use common::cli::{bin, csv_column, run_ok, run_ok_with_stderr, simulate, tmp};

fn json_number(json: &str, key: &str) -> f64 {
    let v: serde_json::Value = serde_json::from_str(json).expect("one JSON value");
    v[key].as_f64().unwrap_or_else(|| panic!("{key} in {json}"))
}

#[test]
fn a_raw_log_calibrates_as_the_flight_itself_does() {
    let d = tmp("raw-log");
    let cap = d.join("flight.cap");
    let flight = simulate(&d, &["--capture", cap.to_str().unwrap()]);
    let log = d.join("log.txt");
    run_ok(
        bin()
            .arg("replay")
            .arg(&cap)
            .args(["--raw", "--records"])
            .arg(&log),
    );
    let text = std::fs::read_to_string(&log).unwrap();
    let raw_lines = text.lines().filter(|l| l.starts_with("$MCRAW,")).count();
    let records = text.lines().filter(|l| l.starts_with("$MCREC,")).count();
    let scalar = csv_column(&flight, "mag");
    assert_eq!(raw_lines, scalar.len(), "one raw line per scalar sample");
    assert_eq!(records, scalar.len(), "one record per scalar sample");

    // The log as a trace: every sample, the scalar exactly as the sensor sent it (the
    // capture's scalar lines carry 4 decimals).
    let trace = d.join("log.csv");
    run_ok(
        bin()
            .args(["compensate"])
            .arg(&log)
            .args(["--method", "tl", "-o"])
            .arg(&trace),
    );
    let mag = csv_column(&trace, "mag");
    assert_eq!(mag.len(), scalar.len());
    for (a, b) in mag.iter().zip(&scalar) {
        assert!((a - b).abs() <= 0.5e-4 + 1e-9, "{a} against {b}");
    }

    // Calibrated on the log, applied to the flight with its truth.
    let coeffs = d.join("log.json");
    let cal = run_ok(
        bin()
            .arg("calibrate")
            .arg(&log)
            .arg("--json")
            .arg("-o")
            .arg(&coeffs),
    );
    let predicted = json_number(&cal, "predicted_error_nt");
    let applied = run_ok(
        bin()
            .arg("compensate")
            .arg(&flight)
            .arg("--coeffs")
            .arg(&coeffs)
            .arg("--json")
            .arg("-o")
            .arg(d.join("applied.csv")),
    );
    let error = json_number(&applied, "error_rms_nt");
    let own = json_number(
        &run_ok(
            bin()
                .arg("calibrate")
                .arg(&flight)
                .arg("--json")
                .arg("-o")
                .arg(d.join("own.json")),
        ),
        "error_rms_nt",
    );
    println!("log's coefficients: {error:.4} nT against truth (predicted {predicted:.4}); the flight's own {own:.4}");
    assert!(error <= 0.05, "{error}");
    assert!(
        error <= 1.5 * predicted.max(own),
        "{error} against {predicted} / {own}"
    );

    // One raw line corrupted: refused and counted, the rest read.
    let mut bad = text.clone();
    let at = bad.find("$MCRAW,100,").expect("line 100");
    bad.replace_range(at + 12..at + 13, "9");
    let bad_log = d.join("bad.txt");
    std::fs::write(&bad_log, bad).unwrap();
    let (_, stderr) = run_ok_with_stderr(
        bin()
            .args(["compensate"])
            .arg(&bad_log)
            .args(["--method", "tl", "-o"])
            .arg(d.join("bad.csv")),
    );
    assert!(
        stderr.contains("1 $MCRAW line(s) failed their checksum"),
        "{stderr}"
    );
    assert_eq!(
        csv_column(&d.join("bad.csv"), "mag").len(),
        scalar.len() - 1
    );
}

#[test]
fn a_log_of_records_only_says_what_is_missing() {
    let d = tmp("records-only");
    let cap = d.join("flight.cap");
    simulate(&d, &["--capture", cap.to_str().unwrap()]);
    let log = d.join("log.txt");
    run_ok(bin().arg("replay").arg(&cap).arg("--records").arg(&log));
    let err = common::cli::run_err(
        bin()
            .arg("calibrate")
            .arg(&log)
            .arg("-o")
            .arg(d.join("c.json")),
    );
    assert!(
        err.contains("without $MCRAW lines") && err.contains("RAW,ON"),
        "{err}"
    );
}
