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

/// A several-sensor board's log (`$MCMRAW`, 3 channels): read as a trace with `mag_1` …
/// `mag_3` in place of `mag`, each channel exactly as written (a missing reading NaN), a
/// `$MCRAW` line before the counter's first counter line read as channel 1's, and a
/// damaged line counted, never read.
#[test]
fn a_several_sensor_log_reads_every_channel_exactly() {
    use magcomp::io::trace::board_log::read_board_log;
    use magcomp_core::protocol::multi_raw::{MultiRawSample, RawLine, MAX_MULTI_RAW_LEN};
    use magcomp_core::protocol::raw::RawSample;
    use magcomp_core::{Flags, MagCounts};
    let d = tmp("multi-raw-log");
    let shared = |k: u32| RawSample {
        k,
        t_s: 100.0 + 0.1 * f64::from(k),
        mag: None,
        flux_nt: [20_000.0, -3_000.0, 45_000.5],
        lat_deg: -45.5,
        lon_deg: 170.25,
        alt_m: 500.0,
        ground_speed_mps: 60.0,
        flags: Flags(0),
    };
    let counts = |k: u32, c: i64| MagCounts(530_000_000 + 1_234 * i64::from(k) + 77_777 * c);
    let mut text = String::from("$MCBOOT,whatever\r\n");
    let mut buf = [0u8; MAX_MULTI_RAW_LEN];
    let one = RawLine::One(RawSample {
        mag: Some(counts(0, 0)),
        ..shared(0)
    });
    let n = one.encode(&mut buf).unwrap();
    text.push_str(std::str::from_utf8(&buf[..n]).unwrap());
    for k in 1..40u32 {
        let mut mag = [Some(counts(k, 0)), Some(counts(k, 1)), Some(counts(k, 2))];
        if (10..15).contains(&k) {
            mag[1] = None;
        }
        let r = RawLine::Multi(MultiRawSample {
            shared: shared(k),
            channels: 3,
            mag,
            flags: mag.map(|m| Flags(if m.is_none() { Flags::MAG_MISSING } else { 0 })),
        });
        let n = r.encode(&mut buf).unwrap();
        let mut line = std::str::from_utf8(&buf[..n]).unwrap().to_string();
        if k == 20 {
            line = line.replacen(",5300", ",5301", 1); // damaged: its checksum fails
        }
        text.push_str(&line);
    }
    let log = d.join("multi.txt");
    std::fs::write(&log, text).unwrap();
    let t = read_board_log(&log).unwrap();
    assert!(t.col("mag").is_none(), "mag gives way to mag_1 … mag_3");
    let rows: Vec<u32> = (0..40).filter(|&k| k != 20).collect();
    assert_eq!(t.col("t").unwrap().len(), rows.len());
    for c in 0..3 {
        let col = t.col(&format!("mag_{}", c + 1)).unwrap();
        for (v, &k) in col.iter().zip(&rows) {
            let want = match (k, c) {
                (0, 0) => counts(0, 0).to_nt_f64(),
                (0, _) => f64::NAN,
                (10..15, 1) => f64::NAN,
                _ => counts(k, c as i64).to_nt_f64(),
            };
            assert!(
                v.to_bits() == want.to_bits() || (v.is_nan() && want.is_nan()),
                "k {k} mag_{}: {v} against {want}",
                c + 1
            );
        }
    }
    assert_eq!(t.meta("board_log_bad_lines"), Some("1"));
    let names: Vec<&str> = t.numeric.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(&names[..5], &["t", "mag_1", "mag_2", "mag_3", "flux_x"]);
}
