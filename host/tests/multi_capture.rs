//! A counter of three magnetometers on the scalar port (`M,<nT>,<nT>,<nT>`), replayed as
//! the board runs it: `replay -o` writes every channel's columns (issue 19; it refused
//! them), each value the `$MCMREC` line's exactly, and with `--raw` the log (`$MCMRAW`)
//! reads as a several-sensor trace whose every sensor calibrates as the one-sensor log of
//! the same samples does.

mod common;
use common::cli::{bin, csv_column, run_ok, simulate, tmp};
use magcomp_core::protocol::multi_record::decode_multi_record;
use magcomp_core::Flags;

/// Sensor 2 reads 1.5 nT above sensor 1, sensor 3 0.75 nT below; sensor 2 sends nothing on
/// samples 100–119.
const OFFSETS_NT: [f64; 3] = [0.0, 1.5, -0.75];

fn counter_capture(single: &str) -> String {
    let mut k = 0usize;
    let mut out = String::new();
    for line in single.lines() {
        let mut parts = line.splitn(3, ' ');
        let (t, port, hex) = (parts.next(), parts.next(), parts.next());
        let (Some(t), Some("scalar"), Some(hex)) = (t, port, hex) else {
            out.push_str(line);
            out.push('\n');
            continue;
        };
        let bytes: Vec<u8> = (0..hex.len() / 2)
            .map(|i| u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).unwrap())
            .collect();
        let text = String::from_utf8(bytes).unwrap();
        let v: f64 = text.trim().parse().unwrap();
        let fields: Vec<String> = OFFSETS_NT
            .iter()
            .enumerate()
            .map(|(c, o)| {
                if c == 1 && (100..120).contains(&k) {
                    String::new()
                } else {
                    format!("{:.4}", v + o)
                }
            })
            .collect();
        let line = format!("M,{}\r\n", fields.join(","));
        let hex: String = line.bytes().map(|b| format!("{b:02X}")).collect();
        out.push_str(&format!("{t} scalar {hex}\n"));
        k += 1;
    }
    out
}

#[test]
fn a_three_sensor_capture_replays_to_csv_and_its_raw_log_calibrates_each_sensor() {
    let d = tmp("multi-capture");
    let cap1 = d.join("flight.cap");
    simulate(&d, &["--capture", cap1.to_str().unwrap()]);
    let cap3 = d.join("three.cap");
    std::fs::write(
        &cap3,
        counter_capture(&std::fs::read_to_string(&cap1).unwrap()),
    )
    .unwrap();
    let (log, csv) = (d.join("three.txt"), d.join("three.csv"));
    run_ok(
        bin()
            .arg("replay")
            .arg(&cap3)
            .args(["--raw", "--records"])
            .arg(&log)
            .arg("-o")
            .arg(&csv),
    );
    let text = std::fs::read_to_string(&log).unwrap();
    let recs: Vec<_> = text
        .lines()
        .filter(|l| l.starts_with("$MCMREC,"))
        .map(|l| decode_multi_record(l.as_bytes()).unwrap())
        .collect();
    let raw = text.lines().filter(|l| l.starts_with("$MCMRAW,")).count();
    assert!(recs.len() > 1000, "{} records", recs.len());
    assert!(!text.contains("$MCRAW,"), "channel 1 alone");

    // The CSV: the records' values, exactly, every channel and pair.
    let csv_text = std::fs::read_to_string(&csv).unwrap();
    let mut rows = csv_text.lines();
    let header: Vec<&str> = rows.next().unwrap().split(',').collect();
    assert_eq!(header.len(), 2 + 3 * 5 + 3, "{header:?}");
    assert_eq!(&header[..4], ["seq", "t", "mag_1", "interference_mag_1"]);
    assert_eq!(header[19], "difference_mag_2_mag_3");
    let rows: Vec<Vec<&str>> = rows.map(|r| r.split(',').collect()).collect();
    assert_eq!(rows.len(), recs.len());
    let text_of = |m: Option<magcomp_core::MagCounts>| {
        m.map_or(String::new(), |m| format!("{:.4}", m.to_nt_f64()))
    };
    let mut dead = 0;
    for (row, r) in rows.iter().zip(&recs) {
        assert_eq!(row[0], r.seq.to_string());
        for c in 0..3 {
            let at = 2 + 5 * c;
            assert_eq!(row[at], text_of(r.ch[c].mag), "seq {} mag_{}", r.seq, c + 1);
            assert_eq!(row[at + 2], text_of(r.ch[c].compensated), "seq {}", r.seq);
            assert_eq!(row[at + 4], r.ch[c].flags.0.to_string(), "seq {}", r.seq);
        }
        for k in 0..3 {
            assert_eq!(row[17 + k], text_of(r.diff[k]), "seq {} pair {k}", r.seq);
        }
        if row[2 + 5].is_empty() {
            dead += 1;
            assert!(Flags(row[2 + 5 + 4].parse().unwrap()).contains(Flags::MAG_MISSING));
        }
        // 2 − 1 is the offset wherever both read (the same interference on both).
        if let (Some(a), Some(b)) = (r.ch[0].mag, r.ch[1].mag) {
            assert_eq!(b.0 - a.0, 15_000, "seq {}", r.seq);
        }
    }
    assert_eq!(dead, 20, "sensor 2 dead for 20 samples");

    // The raw log: one line per sample, read as mag_1 … mag_3, each sensor calibrating.
    let flight = d.join("flight.csv");
    let samples = csv_column(&flight, "mag");
    assert_eq!(raw, samples.len(), "one $MCMRAW line per sample");
    let joint = d.join("joint.json");
    run_ok(
        bin()
            .arg("calibrate")
            .arg(&log)
            .args(["--sensors", "mag_1,mag_2,mag_3", "-o"])
            .arg(&joint),
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&joint).unwrap()).unwrap();
    let sensors = v["sensors"].as_array().unwrap();
    assert_eq!(sensors.len(), 3);
    // The one-sensor log of the same samples, calibrated as today.
    let log1 = d.join("one.txt");
    run_ok(
        bin()
            .arg("replay")
            .arg(&cap1)
            .args(["--raw", "--records"])
            .arg(&log1),
    );
    let one = run_ok(
        bin()
            .arg("calibrate")
            .arg(&log1)
            .arg("--json")
            .arg("-o")
            .arg(d.join("one.json")),
    );
    let one: serde_json::Value = serde_json::from_str(&one).unwrap();
    let p1 = one["predicted_error_nt"].as_f64().unwrap();
    for s in sensors {
        let p = s["alone_predicted_error_nt"].as_f64().unwrap();
        println!(
            "{}: alone predicted error {p:.4} nT (one-sensor log {p1:.4})",
            s["name"]
        );
        assert!(p <= 1.5 * p1 && p < 0.05, "{}: {p} against {p1}", s["name"]);
    }
}
