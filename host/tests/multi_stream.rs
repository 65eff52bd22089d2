//! `compensate --sensors` and streaming (issue 19): several magnetometers with a
//! several-sensor `--coeffs` file stream for real — one read of the file per pass, one
//! stage per sensor (the filter, or Tolles–Lawson for a Tolles–Lawson set, any mix) — and
//! write what the in-memory run writes, value for value (the standard of
//! `stream_compensate.rs`: the files identical line for line). What still
//! needs the whole flight (the joint calibration without `--coeffs`, `--realtime`, a set
//! the one-sensor stream refuses) is refused by `--stream always` with the reason, and an
//! input `--stream auto` would stream (≥ 256 MiB) is said to be read whole.

use magcomp::calibration::coefficients::Method;
use magcomp::calibration::EstimatorSettings;
use magcomp::cli::compensate::{stream_decision, StreamMode};
use magcomp::cli::multi::{read_multi, MultiFile};
use magcomp::io::trace::{read_trace, write_trace, ColumnMap, Trace};
use magcomp::sim::multi::{simulate_multi, STINGER_WINGTIPS_CABIN_M};
use magcomp::sim::{FlightKind, SimConfig};
use magcomp::stream::several::several_unstreamable;
use magcomp::stream::AUTO_STREAM_BYTES;
use magcomp_core::Flags;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn magcomp(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .args(args)
        .output()
        .unwrap()
}

fn tmp(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("magcomp-multi-stream");
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn ok(o: &Output, what: &str) -> String {
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "{what}: {err}");
    err
}

/// Three sensors' calibration flight and its several-sensor file (`calibrate --sensors`),
/// made once for every test here.
fn calibrated() -> (PathBuf, PathBuf) {
    static MADE: std::sync::OnceLock<(PathBuf, PathBuf)> = std::sync::OnceLock::new();
    MADE.get_or_init(|| calibrate("cal")).clone()
}

fn calibrate(tag: &str) -> (PathBuf, PathBuf) {
    let cfg = SimConfig {
        seed: 5,
        ..Default::default()
    };
    let trace = simulate_multi(&cfg, &STINGER_WINGTIPS_CABIN_M[..3]).unwrap();
    let input = tmp(&format!("{tag}-cal.csv"));
    write_trace(&input, &trace).unwrap();
    let coeffs = tmp(&format!("{tag}-cal.json"));
    let o = magcomp(&[
        "calibrate",
        s(&input),
        "--sensors",
        "mag_1,mag_2,mag_3",
        "-o",
        s(&coeffs),
    ]);
    ok(&o, "calibrate --sensors");
    (input, coeffs)
}

/// A survey of the same aircraft with the faults a real file has: a scalar glitch on
/// one sensor, a bad fluxgate row (the shared fluxgate), a 3 s time gap, a bad latitude.
fn survey() -> Trace {
    let cfg = SimConfig {
        seed: 5,
        flight: FlightKind::Survey,
        survey_lines: 2,
        max_duration_s: Some(300.0),
        ..Default::default()
    };
    let t = simulate_multi(&cfg, &STINGER_WINGTIPS_CABIN_M[..3]).unwrap();
    let rows: Vec<usize> = (0..t.len()).filter(|i| !(1200..1230).contains(i)).collect();
    let mut t = magcomp::flight::input::take_rows(&t, &rows);
    let mut set = |name: &str, row: usize, f: &dyn Fn(f64) -> f64| {
        let mut v = t.col(name).unwrap().to_vec();
        v[row] = f(v[row]);
        t.set_col(name, v);
    };
    set("mag_2", 650, &|x| x + 4000.0);
    set("flux_z", 2100, &|_| 0.0);
    set("lat", 900, &|_| 95.0);
    t
}

fn lines(p: &Path) -> Vec<String> {
    std::fs::read_to_string(p)
        .unwrap()
        .lines()
        .map(String::from)
        .collect()
}

/// `compensate INPUT --coeffs COEFFS EXTRA` in memory (`--stream never`) and streamed
/// (`always`), output files named by `tag`: both must succeed, stream as asked and write
/// the same file line for line. The streamed output and its stderr.
fn in_memory_and_streamed(
    input: &Path,
    coeffs: &Path,
    extra: &[&str],
    tag: &str,
) -> (PathBuf, String) {
    let mut runs = Vec::new();
    for mode in ["never", "always"] {
        let out = tmp(&format!("{tag}-{mode}.csv"));
        let _ = std::fs::remove_file(&out);
        let mut args = vec!["compensate", s(input), "--coeffs", s(coeffs)];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--stream", mode, "-o", s(&out)]);
        let err = ok(&magcomp(&args), &format!("{tag} {mode}"));
        assert!(!err.contains("not streamed"), "{tag} {mode}: {err}");
        runs.push((out, err));
    }
    let streamed = runs.pop().unwrap();
    let (mem, str_lines) = (lines(&runs[0].0), lines(&streamed.0));
    assert_eq!(mem.len(), str_lines.len(), "{tag}: lines");
    for (i, (a, b)) in mem.iter().zip(&str_lines).enumerate() {
        assert_eq!(a, b, "{tag}: line {}", i + 1);
    }
    streamed
}

/// The faulty survey compensated with `coeffs`, streamed, `--json`: the summary's
/// per-sensor entries and the survey's row count.
fn streamed_json(coeffs: &Path, tag: &str) -> (Vec<serde_json::Value>, usize) {
    let trace = survey();
    let input = tmp(&format!("survey3-{tag}.csv"));
    write_trace(&input, &trace).unwrap();
    let out = tmp(&format!("{tag}.csv"));
    let args = [
        "compensate",
        s(&input),
        "--coeffs",
        s(coeffs),
        "--stream",
        "always",
    ];
    let mut args = args.to_vec();
    args.extend_from_slice(&["--json", "-o", s(&out)]);
    let o = magcomp(&args);
    ok(&o, &format!("{tag}: --stream always --json"));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let sensors = v["sensors"].as_array().unwrap().clone();
    assert_eq!(sensors.len(), 3, "{v}");
    (sensors, trace.len())
}

/// `--stream always` and `--stream never` on one simulated three-sensor survey: the same
/// file, line for line (every value as the in-memory run writes it, no tolerance: the
/// same filter on the same numbers), every row in a row out; the same for the
/// several-sensor file alone (it names its sensors) and with `--gradients`.
#[test]
fn streamed_several_sensors_equal_in_memory_line_for_line() {
    let (_, coeffs) = calibrated();
    let trace = survey();
    let input = tmp("survey3.csv");
    write_trace(&input, &trace).unwrap();
    // Without the file's core field: computed from positions and --date, in a --time
    // selection.
    let mut no_igrf = trace.clone();
    no_igrf.numeric.retain(|(n, _)| n != "igrf");
    let input_no_igrf = tmp("survey3-no-igrf.csv");
    write_trace(&input_no_igrf, &no_igrf).unwrap();
    let with_sensors: &[&str] = &[
        "--sensors",
        "mag_1,mag_2,mag_3",
        "--gradients",
        "mag_1-mag_2,mag_2-mag_3",
    ];
    let selected: &[&str] = &["--date", "2024-06-01", "--time", "20:250"];
    let cases = [
        (&input, with_sensors, trace.len()),
        (&input, &[][..], trace.len()),
        (&input_no_igrf, selected, 0),
    ];
    for (k, (input, extra, rows)) in cases.into_iter().enumerate() {
        let (out, err) = in_memory_and_streamed(input, &coeffs, extra, &format!("out-{k}"));
        if k < 2 {
            // The glitch and the bad fluxgate row are said, naming their sensor.
            assert!(err.contains("(mag_2): 1 scalar glitch"), "{err}");
            assert!(err.contains("(mag_3): 1 fluxgate sample"), "{err}");
            assert!(err.contains("warning: mag_1: 1 time gap"), "{err}");
        }
        let t = read_trace(&out, &ColumnMap::new()).unwrap();
        if rows > 0 {
            assert_eq!(t.len(), rows, "{extra:?}: rows in, rows out");
        } else {
            let t_s = trace.col("t").unwrap();
            let kept = t_s.iter().filter(|t| (20.0..=250.0).contains(*t)).count();
            assert_eq!(t.len(), kept, "--time 20:250: rows in, rows out");
        }
        for c in ["compensated_mag_1", "flags_mag_3", "lat", "alt"] {
            assert!(t.col(c).is_some(), "{extra:?}: no {c}");
        }
        if k == 0 {
            assert!(t.col("gradient_mag_2_mag_3").is_some());
        }
        eprintln!(
            "{extra:?}: {} rows, {} columns identical",
            t.len(),
            t.numeric.len()
        );
    }
}

/// `--json` streamed: one entry per sensor, each streamed over every row, with its
/// figures against the simulated truth.
#[test]
fn streamed_several_sensors_json_summary() {
    let (_, coeffs) = calibrated();
    let (sensors, rows) = streamed_json(&coeffs, "json");
    for (k, e) in sensors.iter().enumerate() {
        assert_eq!(e["sensor"], format!("mag_{}", k + 1));
        assert_eq!(e["streamed"], true);
        assert_eq!(e["samples"], rows);
        let err = e["error_rms_nt"].as_f64().unwrap();
        assert!(err < 0.1, "mag_{}: {err} nT", k + 1);
    }
    // The glitch printed for mag_2 is in mag_2's warnings, not mag_1's.
    let said = |k: usize| sensors[k]["warnings"].to_string().contains("scalar glitch");
    assert!(said(1) && !said(0), "{sensors:?}");
}

/// What still needs the whole flight is refused by `--stream always`, saying why, and
/// nothing is written: the joint calibration (no `--coeffs`), `--realtime`. `never` and
/// `auto` (a small file) run it in memory.
#[test]
fn what_needs_the_whole_flight_is_refused_with_the_reason() {
    let (input, coeffs) = calibrated();
    let out = tmp("refused.csv");
    let cases: [(&[&str], &str); 2] = [
        (&["--sensors", "mag_1,mag_2"], "calibrated jointly"),
        (
            &[
                "--sensors",
                "mag_1,mag_2",
                "--coeffs",
                s(&coeffs),
                "--realtime",
            ],
            "--realtime",
        ),
    ];
    for (extra, why) in cases {
        let _ = std::fs::remove_file(&out);
        let mut args = vec!["compensate", s(&input)];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--stream", "always", "-o", s(&out)]);
        let o = magcomp(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{extra:?}: {err}");
        assert!(
            err.contains("--stream always: this run cannot be streamed") && err.contains(why),
            "{extra:?}: {err}"
        );
        assert!(!out.exists(), "{extra:?}: an output was written");
    }
    // The realtime run in memory, every row out.
    let mut args = vec!["compensate", s(&input)];
    args.extend_from_slice(cases[1].0);
    args.extend_from_slice(&["--stream", "never", "-o", s(&out)]);
    ok(&magcomp(&args), "--realtime in memory");
    let t = read_trace(&out, &ColumnMap::new()).unwrap();
    assert_eq!(
        t.len(),
        read_trace(&input, &ColumnMap::new()).unwrap().len()
    );
}

/// A set the one-sensor stream refuses is refused for several, naming the sensor; a
/// Tolles–Lawson set is not.
#[test]
fn a_set_the_one_sensor_stream_refuses_is_named() {
    let (_, coeffs) = calibrated();
    let (_, sets) = read_multi(&coeffs).unwrap();
    let est = EstimatorSettings::default();
    let named: Vec<(&str, _)> = ["mag_1", "mag_2", "mag_3"].into_iter().zip(&sets).collect();
    assert_eq!(several_unstreamable(&named, &est, false), None);
    let mut lagged = sets[1].clone();
    lagged.model = format!("{}+lag", lagged.model);
    let named = [("mag_1", &sets[0]), ("mag_2", &lagged)];
    let why = several_unstreamable(&named, &est, false).unwrap();
    assert!(why.starts_with("mag_2: ") && why.contains("lag"), "{why}");
    // A Tolles–Lawson set streams (it used to be refused: "applied in memory").
    let tl = read_multi(&tl_files().0).unwrap().1;
    assert_eq!(tl[0].method, Method::Tl);
    let named = [("mag_1", &sets[0]), ("mag_2", &tl[1])];
    assert_eq!(several_unstreamable(&named, &est, false), None);
}

/// Several-sensor files holding Tolles–Lawson sets, made once: every sensor's (`calibrate
/// --sensors mag_1,mag_2,mag_3 --method tl`, which must hold each sensor's own `calibrate
/// --sensors mag_K --method tl` set: there is no joint Tolles–Lawson), and a mix (mag_2's
/// Tolles–Lawson set put in place of the joint file's Kalman-filter one, so the other two
/// keep the three-sensor joint sets: `calibrate --sensor-method mag_2=tl` would run the
/// joint filter on mag_1 and mag_3 alone).
fn tl_files() -> (PathBuf, PathBuf) {
    static MADE: std::sync::OnceLock<(PathBuf, PathBuf)> = std::sync::OnceLock::new();
    MADE.get_or_init(|| {
        let (input, coeffs) = calibrated();
        let (kf, _) = read_multi(&coeffs).unwrap();
        let tl_set = |k: usize| {
            let one = tmp(&format!("tl-mag_{k}.json"));
            let name = format!("mag_{k}");
            let args = ["calibrate", s(&input), "--sensors", &name, "--method", "tl"];
            let mut args = args.to_vec();
            args.extend_from_slice(&["-o", s(&one)]);
            ok(&magcomp(&args), "calibrate --method tl");
            // The sealed text as written: its checksum is on these characters.
            let text = std::fs::read_to_string(&one).unwrap();
            serde_json::value::RawValue::from_string(text.trim_end().to_string()).unwrap()
        };
        let sets: Vec<_> = (1..=3).map(tl_set).collect();
        let write = |name: &str, tl: &[bool]| {
            let mut m: MultiFile = kf.clone();
            for ((e, set), &tl) in m.sensors.iter_mut().zip(&sets).zip(tl) {
                if tl {
                    e.coefficients = set.clone();
                }
            }
            let path = tmp(name);
            std::fs::write(&path, serde_json::to_string_pretty(&m).unwrap()).unwrap();
            path
        };
        let all = tmp("tl-all.json");
        let args = ["calibrate", s(&input), "--sensors", "mag_1,mag_2,mag_3"];
        let mut args = args.to_vec();
        args.extend_from_slice(&["--method", "tl", "-o", s(&all)]);
        let err = ok(&magcomp(&args), "calibrate --sensors … --method tl");
        assert!(err.contains("Tolles–Lawson"), "{err}");
        let (m, _) = read_multi(&all).unwrap();
        assert_eq!(m.sensors.len(), 3);
        assert_eq!(m.sigma1, None, "no shared σ1 without a joint filter");
        let value = |t: &str| serde_json::from_str::<serde_json::Value>(t).unwrap();
        for (e, set) in m.sensors.iter().zip(&sets) {
            assert!(!e.joint, "{}", e.name);
            let got = value(e.coefficients.get());
            assert_eq!(got["method"], "tl", "{}", e.name);
            // The same set and checksum; a one-sensor file also carries its provenance.
            let mut own = value(set.get());
            own.as_object_mut().unwrap().remove("provenance");
            assert_eq!(got, own, "{}: its own TL set", e.name);
        }
        (all, write("tl-mix.json", &[false, true, false]))
    })
    .clone()
}

/// Tolles–Lawson sets stream: `--stream always` and `--stream never` on the faulty
/// survey (glitch, bad fluxgate row, time gap, bad latitude) write the same file line
/// for line, every row in a row out, for a file of Tolles–Lawson sets only (with
/// `--gradients`) and for a mix of Tolles–Lawson and Kalman-filter sets. A
/// Tolles–Lawson sensor has no `anomaly_mag_K` column, as in memory; its flags mark the
/// rows without a usable scalar.
#[test]
fn tolles_lawson_sets_stream_equal_in_memory_line_for_line() {
    let (all, mix) = tl_files();
    let trace = survey();
    let input = tmp("survey3-tl.csv");
    write_trace(&input, &trace).unwrap();
    let with_gradients: &[&str] = &["--gradients", "mag_1-mag_2,mag_2-mag_3"];
    let cases = [(&all, with_gradients, "all"), (&mix, &[][..], "mix")];
    for (coeffs, extra, tag) in cases {
        let (out, _) = in_memory_and_streamed(&input, coeffs, extra, &format!("tl-{tag}"));
        let t = read_trace(&out, &ColumnMap::new()).unwrap();
        assert_eq!(t.len(), trace.len(), "{tag}: rows in, rows out");
        let tl = |k: usize| tag == "all" || k == 2;
        for k in 1..=3 {
            let has = |c: &str| t.col(&format!("{c}_mag_{k}")).is_some();
            assert!(has("compensated") && has("flags"), "{tag}: mag_{k}");
            assert_eq!(has("anomaly"), !tl(k), "{tag}: anomaly_mag_{k}");
        }
        // mag_2's glitch (row 650) is taken out, and flagged, by Tolles–Lawson too.
        let flags = t.col("flags_mag_2").unwrap();
        assert_ne!(flags[650] as u16 & Flags::MAG_MISSING, 0, "{tag}");
        assert!(t.col("compensated_mag_2").unwrap()[650].is_nan(), "{tag}");
        if tag == "all" {
            assert!(t.col("gradient_mag_2_mag_3").is_some());
        }
        eprintln!(
            "{tag}: {} rows, {} columns identical",
            t.len(),
            t.numeric.len()
        );
    }
}

/// `--stream always` takes a Tolles–Lawson several-sensor file (it used to refuse it):
/// each sensor streamed over every row, by its own method, with its error against the
/// simulated truth.
#[test]
fn stream_always_takes_tolles_lawson_sets() {
    let (_, mix) = tl_files();
    let (sensors, rows) = streamed_json(&mix, "tl-json");
    for (k, e) in sensors.iter().enumerate() {
        assert_eq!(e["streamed"], true, "{e}");
        assert_eq!(e["samples"], rows);
        assert_eq!(e["method"], if k == 1 { "tl" } else { "kf" }, "{e}");
        assert!(e["error_rms_nt"].as_f64().unwrap().is_finite(), "{e}");
    }
}

/// The decision by size: `auto` streams from 256 MiB (the one-sensor threshold) when it
/// can, else notes that the input is read whole; below, in memory without a note;
/// `never` never; `always` streams, or refuses at any size saying why.
#[test]
fn the_decision_by_size_and_mode() {
    let p = Path::new("big.csv");
    let per_row = "~1 KB per row per sensor";
    assert_eq!(AUTO_STREAM_BYTES, 268_435_456);
    let why = Some("several magnetometers without a several-sensor --coeffs file …");
    let decide = |mode, why, size| stream_decision(mode, why, size, p, per_row);
    let (stream, note) = decide(StreamMode::Auto, why, AUTO_STREAM_BYTES).unwrap();
    let note = note.expect("a note at 256 MiB");
    assert!(!stream);
    assert!(
        note.starts_with("note: big.csv is read into memory") && note.contains("not streamed"),
        "{note}"
    );
    assert_eq!(
        decide(StreamMode::Auto, None, AUTO_STREAM_BYTES).unwrap(),
        (true, None)
    );
    for w in [why, None] {
        let below = decide(StreamMode::Auto, w, AUTO_STREAM_BYTES - 1).unwrap();
        assert_eq!(below, (false, None));
        let never = decide(StreamMode::Never, w, 10 * AUTO_STREAM_BYTES).unwrap();
        assert_eq!(never, (false, None));
    }
    assert_eq!(decide(StreamMode::Always, None, 0).unwrap(), (true, None));
    for size in [0, AUTO_STREAM_BYTES] {
        let e = decide(StreamMode::Always, why, size).unwrap_err();
        assert!(format!("{e}").contains("cannot be streamed"), "{e}");
    }
}
