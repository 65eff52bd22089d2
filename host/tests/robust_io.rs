//! Files, devices and bounded cost (issue 21 items 5 and 6) and one convention across the
//! commands (issue 22 item 5), each case run through the `magcomp` binary as a user would.

mod common;

use common::cli::{bin, run_err, run_ok, run_ok_with_stderr, simulate, tmp};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// A calibration flight (seed 3), its coefficients and its capture, made once.
struct Fixture {
    flight: PathBuf,
    coeffs: PathBuf,
    capture: PathBuf,
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        // Shared by every test of this binary, so not a scratch dropped with one of them:
        // under `target/tmp` (cargo's `CARGO_TARGET_TMPDIR`), overwritten by the next run.
        let d = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("robust-io-fixture");
        std::fs::create_dir_all(&d).unwrap();
        let capture = d.join("flight.cap");
        let flight = simulate(&d, &["--capture", capture.to_str().unwrap()]);
        let coeffs = d.join("coeffs.json");
        run_ok(
            bin()
                .args(["calibrate"])
                .arg(&flight)
                .arg("-o")
                .arg(&coeffs),
        );
        Fixture {
            flight,
            coeffs,
            capture,
        }
    })
}

/// The binary without anyhow's backtrace, so an error's length is its message's.
fn quiet() -> Command {
    let mut c = bin();
    c.env("RUST_BACKTRACE", "0").env("RUST_LIB_BACKTRACE", "0");
    c
}

fn compensate_to(out: &Path) -> Command {
    let f = fixture();
    let mut c = bin();
    c.arg("compensate")
        .arg(&f.flight)
        .arg("--coeffs")
        .arg(&f.coeffs)
        .arg("-o")
        .arg(out);
    c
}

fn leftovers(d: &Path) -> Vec<String> {
    std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect()
}

// ---- 21.5: files and devices ----

#[cfg(unix)]
#[test]
fn out_to_a_device_writes_through_it_and_never_replaces_it() {
    use std::os::unix::fs::FileTypeExt;
    let null = Path::new("/dev/null");
    run_ok(&mut compensate_to(null));
    assert!(std::fs::metadata(null)
        .unwrap()
        .file_type()
        .is_char_device());
    // As root a rename would have put a regular file at /dev/null; now nothing is
    // created beside it either.
    assert!(leftovers(Path::new("/dev"))
        .iter()
        .all(|n| !n.contains("null")));
}

#[cfg(unix)]
#[test]
fn out_to_a_fifo_writes_through_it() {
    use std::io::Read;
    use std::os::unix::fs::FileTypeExt;
    let d = tmp("fifo");
    let fifo = d.join("out.fifo");
    let _ = std::fs::remove_file(&fifo);
    assert!(Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap()
        .success());
    let reader = {
        let fifo = fifo.clone();
        std::thread::spawn(move || {
            let mut s = String::new();
            std::fs::File::open(&fifo)
                .unwrap()
                .read_to_string(&mut s)
                .unwrap();
            s
        })
    };
    let mut child = compensate_to(&fifo)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t0.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            panic!("compensate -o FIFO hung");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(status.success());
    let text = reader.join().unwrap();
    let rows = text.lines().filter(|l| !l.starts_with('#')).count();
    assert_eq!(rows, 7084 + 1, "header and every row through the FIFO");
    assert!(std::fs::metadata(&fifo).unwrap().file_type().is_fifo());
}

#[cfg(unix)]
#[test]
fn out_through_a_symlink_writes_its_target_and_keeps_the_link() {
    let d = tmp("symlink");
    let (link, target) = (d.join("link.csv"), d.join("target.csv"));
    let _ = std::fs::remove_file(&link);
    std::fs::write(&target, "old\n").unwrap();
    std::os::unix::fs::symlink("target.csv", &link).unwrap();
    run_ok(&mut compensate_to(&link));
    assert!(std::fs::symlink_metadata(&link)
        .unwrap()
        .file_type()
        .is_symlink());
    let text = std::fs::read_to_string(&target).unwrap();
    assert!(text.contains("compensated"), "the target holds the output");
    assert!(leftovers(&d).is_empty());
}

#[test]
fn an_unusable_out_is_refused_before_the_work() {
    let d = tmp("unusable-out");
    // The input would fail when read (`/dev/zero`): the -o error comes first, at once.
    for (out, says) in [
        (d.join("no-such-dir").join("out.csv"), "does not exist"),
        (d.to_path_buf(), "is a directory"),
    ] {
        let t0 = Instant::now();
        let e = run_err(
            bin()
                .args(["compensate", "/dev/zero", "-o"])
                .arg(&out)
                .arg("--coeffs")
                .arg(&fixture().coeffs),
        );
        assert!(e.contains(says), "{e}");
        assert!(t0.elapsed() < Duration::from_secs(5));
    }
    let e = run_err(
        bin()
            .args(["calibrate", "/dev/zero", "-o"])
            .arg(d.join("x/c.json")),
    );
    assert!(e.contains("does not exist"), "{e}");
}

#[test]
fn upload_refuses_a_regular_file_unless_told_and_then_replaces_it_whole() {
    let d = tmp("upload-file");
    let victim = d.join("trace.csv");
    let before = "t,mag\n".to_string() + &"0.1,50000.0\n".repeat(1000);
    std::fs::write(&victim, &before).unwrap();
    let coeffs = &fixture().coeffs;
    for extra in [&[][..], &["--no-verify"][..]] {
        let e = run_err(
            bin()
                .arg("upload")
                .arg(coeffs)
                .arg("--to")
                .arg(&victim)
                .args(extra),
        );
        assert!(e.contains("regular file") && e.contains("--to-file"), "{e}");
        assert!(!e.contains("or --no-verify"), "{e}");
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), before);
    }
    run_ok(
        bin()
            .arg("upload")
            .arg(coeffs)
            .arg("--to")
            .arg(&victim)
            .arg("--to-file"),
    );
    let after = std::fs::read_to_string(&victim).unwrap();
    let stdout = run_ok(bin().arg("upload").arg(coeffs).args(["--to", "-"]));
    assert_eq!(after, stdout, "exactly the lines, nothing of the old file");
}

#[test]
fn monitor_save_appends() {
    let d = tmp("monitor-append");
    let records = d.join("records.txt");
    let f = fixture();
    run_ok(
        bin()
            .arg("replay")
            .arg(&f.capture)
            .arg("--records")
            .arg(&records),
    );
    let save = d.join("live.csv");
    let _ = std::fs::remove_file(&save);
    let monitor = || {
        run_ok(
            bin()
                .arg("monitor")
                .arg(&records)
                .arg("--quiet")
                .arg("--save")
                .arg(&save),
        );
        std::fs::read_to_string(&save).unwrap()
    };
    let first = monitor();
    let second = monitor();
    let rows = |s: &str| s.lines().filter(|l| !l.starts_with('#')).count();
    assert_eq!(rows(&first), 7084 + 1);
    assert!(second.starts_with(&first), "the first session is kept");
    assert_eq!(
        rows(&second),
        2 * 7084 + 1,
        "one header, both sessions' rows"
    );
}

#[cfg(unix)]
#[test]
fn an_interrupted_run_leaves_no_temporary_file() {
    let d = tmp("sigint");
    // A 1 kHz flight: long enough to be caught while its output is being written.
    let big = d.join("big.csv");
    run_ok(
        bin()
            .args(["simulate", "--seed", "3", "--rate-hz", "1000", "-o"])
            .arg(&big),
    );
    for signal in ["-INT", "-TERM"] {
        let out = d.join("out.csv");
        let mut child = bin()
            .arg("compensate")
            .arg(&big)
            .arg("--coeffs")
            .arg(&fixture().coeffs)
            .args(["--stream", "always", "-o"])
            .arg(&out)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let t0 = Instant::now();
        while leftovers(&d).is_empty() {
            assert!(
                child.try_wait().unwrap().is_none(),
                "finished before caught"
            );
            assert!(t0.elapsed() < Duration::from_secs(120));
            std::thread::sleep(Duration::from_millis(5));
        }
        Command::new("kill")
            .arg(signal)
            .arg(child.id().to_string())
            .status()
            .unwrap();
        let status = child.wait().unwrap();
        assert_eq!(status.code(), Some(130), "{signal}");
        assert!(leftovers(&d).is_empty(), "{signal}: {:?}", leftovers(&d));
        assert!(!out.exists());
    }
}

#[test]
fn replay_refuses_what_is_not_a_capture() {
    let d = tmp("not-a-capture");
    let random = d.join("random.bin");
    let mut x = 0x2545_f491_4f6c_dd1du64;
    let bytes: Vec<u8> = (0..100_000)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x as u8
        })
        .collect();
    std::fs::write(&random, bytes).unwrap();
    let empty = d.join("empty.cap");
    std::fs::write(&empty, "").unwrap();
    let cases: [(&Path, &str); 5] = [
        (&random, "not a"),
        (Path::new("/bin/ls"), "not a"),
        (&fixture().flight, "not a magcomp capture"),
        (&empty, "empty"),
        (Path::new("/dev/zero"), "longer than 4096 bytes"),
    ];
    for (input, says) in cases {
        let out = d.join("out.csv");
        let e = run_err(quiet().arg("replay").arg(input).arg("-o").arg(&out));
        assert!(e.contains(says), "{}: {e}", input.display());
        assert!(
            e.len() < 600,
            "{}: a short excerpt only: {e}",
            input.display()
        );
        assert!(!out.exists());
    }
}

#[test]
fn streamed_xyz_output_is_xyz_and_reads_back() {
    let d = tmp("streamed-xyz");
    let (xyz, csv) = (d.join("out.xyz"), d.join("out.csv"));
    for out in [&xyz, &csv] {
        run_ok(compensate_to(out).args(["--stream", "always"]));
    }
    let text = std::fs::read_to_string(&xyz).unwrap();
    assert!(text.starts_with("/ "), "{}", &text[..80]);
    assert!(!text.contains(','), "no CSV under the .xyz name");
    let map = magcomp::io::trace::ColumnMap::new();
    let a = magcomp::io::trace::read_trace(&xyz, &map).unwrap();
    let b = magcomp::io::trace::read_trace(&csv, &map).unwrap();
    assert_eq!(a.len(), 7084);
    for c in ["t", "mag", "interference", "compensated"] {
        assert_eq!(a.col(c), b.col(c), "{c}");
    }
}

// ---- 21.6: bounded cost ----

#[test]
fn endless_input_ends_in_a_clear_error() {
    let d = tmp("dev-zero");
    let coeffs = &fixture().coeffs;
    for stream in ["never", "always"] {
        let e = run_err(
            bin()
                .args(["compensate", "/dev/zero", "--stream", stream, "--coeffs"])
                .arg(coeffs)
                .arg("-o")
                .arg(d.join("z.csv")),
        );
        assert!(e.contains("longer than 1 MiB"), "{stream}: {e}");
    }
    let e = run_err(bin().args(["nmea", "/dev/zero"]));
    assert!(e.contains("longer than 4096 bytes"), "{e}");
}

#[test]
fn a_huge_coefficient_file_is_refused_unread_and_not_echoed() {
    let d = tmp("huge-coeffs");
    let huge = d.join("huge.json");
    // 8 MB of one bad token: neither read whole nor quoted whole.
    std::fs::write(&huge, "x".repeat(8 << 20)).unwrap();
    let words = d.join("words.txt");
    std::fs::write(&words, "1, 2, ".to_string() + &"y".repeat(1 << 20)).unwrap();
    let f = fixture();
    for coeffs in [&huge, &words] {
        let e = run_err(
            quiet()
                .arg("replay")
                .arg(&f.capture)
                .arg("--coeffs")
                .arg(coeffs)
                .arg("-o")
                .arg(d.join("r.csv")),
        );
        assert!(
            e.len() < 600,
            "{}: {} bytes of error",
            coeffs.display(),
            e.len()
        );
    }
    let e = run_err(
        quiet()
            .arg("compensate")
            .arg(&f.flight)
            .arg("--coeffs")
            .arg(&huge)
            .arg("-o")
            .arg(d.join("c.csv")),
    );
    assert!(e.contains("larger than 4 MiB"), "{e}");
    assert!(e.len() < 600, "{e}");
}

#[test]
fn the_streamed_median_is_bounded_with_its_stated_error() {
    use magcomp::stream::stats::{StreamMedian, EXACT_DISTINCT, MEDIAN_RELATIVE_ERROR};
    // Full-precision third differences: a distinct value every row.
    let mut m = StreamMedian::default();
    let mut all = Vec::new();
    let mut x = 0x9e37_79b9_7f4a_7c15u64;
    for _ in 0..1_000_000 {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        // |d3| of a few-pT-noise scalar: half-normal-like, 1e-4 … 1 nT.
        let v = (x >> 11) as f64 / (1u64 << 53) as f64;
        let v = 0.02 * v * v / (1.0 - v + 1e-9).min(1.0);
        m.push(v);
        all.push(v);
    }
    assert!(!m.is_exact());
    assert!(m.distinct() <= 30_000, "{} buckets", m.distinct());
    all.sort_by(f64::total_cmp);
    let exact = all[all.len() / 2];
    let got = m.median().unwrap();
    assert!(
        ((got - exact) / exact).abs() <= MEDIAN_RELATIVE_ERROR,
        "{got} vs {exact}"
    );
    // Few distinct values (a 1e-4 nT scalar, time steps): exact, as in memory.
    let mut e = StreamMedian::default();
    for i in 0..200_000u32 {
        e.push(f64::from(i % 5_000) * 1e-4);
    }
    assert!(e.is_exact() && e.distinct() <= EXACT_DISTINCT);
    assert_eq!(e.median(), Some(2_500.0 * 1e-4));
}

#[test]
fn errors_say_it_in_words_not_enum_names() {
    let e = run_err(
        bin()
            .arg("compensate")
            .arg(&fixture().flight)
            .arg("--noise-nt=-1")
            .arg("-o")
            .arg(tmp("words").join("x.csv")),
    );
    assert!(
        !e.contains("BadConfig") && !e.contains("BadCoefficients"),
        "{e}"
    );
    assert!(e.contains("not a finite positive number"), "{e}");
}

#[test]
fn json_warnings_carry_the_glitch_and_position_warnings() {
    let d = tmp("json-warnings");
    let f = fixture();
    // Two rows spoiled: a +1e5 nT glitch and a latitude of 95°.
    let text = std::fs::read_to_string(&f.flight).unwrap();
    let mut data = 0;
    let spoiled: Vec<String> = text
        .lines()
        .map(|l| {
            if l.starts_with('#') || l.starts_with("t,") {
                return l.to_string();
            }
            data += 1;
            let mut v: Vec<String> = l.split(',').map(String::from).collect();
            if data == 3000 {
                v[1] = format!("{}", v[1].parse::<f64>().unwrap() + 1e5);
            }
            if data == 4000 {
                v[5] = "95.0".into();
            }
            v.join(",")
        })
        .collect();
    let bad = d.join("bad.csv");
    std::fs::write(&bad, spoiled.join("\n") + "\n").unwrap();
    for stream in ["never", "always"] {
        let (out, err) = run_ok_with_stderr(
            bin()
                .arg("compensate")
                .arg(&bad)
                .arg("--coeffs")
                .arg(&f.coeffs)
                .args(["--json", "--stream", stream, "-o"])
                .arg(d.join("out.csv")),
        );
        let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
        let w: Vec<&str> = v["warnings"]
            .as_array()
            .unwrap()
            .iter()
            .map(|w| w.as_str().unwrap())
            .collect();
        assert!(err.contains("glitch"), "{err}");
        assert!(w.iter().any(|w| w.contains("glitch")), "{stream}: {w:?}");
        assert!(w.iter().any(|w| w.contains("lat")), "{stream}: {w:?}");
        for line in err.lines().filter_map(|l| l.strip_prefix("warning: ")) {
            assert!(w.iter().any(|w| w.starts_with(line)), "{stream}: {line}");
        }
    }
}

// ---- 22.5: one convention everywhere ----

#[test]
fn replay_and_upload_take_the_model_from_the_coefficient_file() {
    let f = fixture();
    let d = tmp("model-from-file");
    let (_, err) = run_ok_with_stderr(
        bin()
            .arg("replay")
            .arg(&f.capture)
            .arg("--coeffs")
            .arg(&f.coeffs)
            .arg("-o")
            .arg(d.join("r.csv")),
    );
    assert!(err.contains("7084 records"), "{err}");
    let lines = run_ok(bin().arg("upload").arg(&f.coeffs).args(["--to", "-"]));
    assert!(
        lines.contains("SETCOEF") && lines.contains("SETFLUX"),
        "{lines}"
    );
}

/// The fixture's flight without time, position or velocity columns.
fn bare_flight(d: &Path) -> PathBuf {
    let text = std::fs::read_to_string(&fixture().flight).unwrap();
    let mut keep: Vec<usize> = Vec::new();
    let mut out = String::new();
    for l in text.lines().filter(|l| !l.starts_with('#')) {
        let f: Vec<&str> = l.split(',').collect();
        if keep.is_empty() {
            keep = (0..f.len())
                .filter(|&i| !["t", "lat", "lon", "vn", "ve", "vd"].contains(&f[i]))
                .collect();
        }
        out += &keep.iter().map(|&i| f[i]).collect::<Vec<_>>().join(",");
        out.push('\n');
    }
    let p = d.join("bare.csv");
    std::fs::write(&p, out).unwrap();
    p
}

#[test]
fn rate_hz_reads_a_trace_without_time_and_diagnose_takes_the_files_speed() {
    let d = tmp("rate-hz");
    let bare = bare_flight(&d);
    let e = run_err(
        bin()
            .arg("calibrate")
            .arg(&bare)
            .args(["--speed-mps", "60", "-o"])
            .arg(d.join("c.json")),
    );
    assert!(e.contains("no numeric column 't'"), "{e}");
    let coeffs = d.join("c.json");
    run_ok(
        bin()
            .arg("calibrate")
            .arg(&bare)
            .args(["--rate-hz", "10", "--speed-mps", "60", "-o"])
            .arg(&coeffs),
    );
    let c: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&coeffs).unwrap()).unwrap();
    assert_eq!(c["assumed_speed_mps"], 60.0);
    // Evenly spaced rows at 10 Hz: the same sample rate as the flight's own t.
    assert_eq!(c["sample_rate_hz"].as_f64().map(|r| r.round()), Some(10.0));
    // diagnose --coeffs: the file's speed, no --speed-mps needed.
    let (out, _) = run_ok_with_stderr(
        bin()
            .arg("diagnose")
            .arg(&bare)
            .args(["--rate-hz", "10", "--coeffs"])
            .arg(&coeffs),
    );
    assert!(out.contains("compensation checked"), "{out}");
    // A trace with its own t: --rate-hz is refused, not silently ignored.
    let e = run_err(
        bin()
            .arg("compensate")
            .arg(&fixture().flight)
            .args(["--rate-hz", "10", "--coeffs"])
            .arg(&coeffs)
            .arg("-o")
            .arg(d.join("x.csv")),
    );
    assert!(
        e.contains("--rate-hz is for a trace without a time column"),
        "{e}"
    );
}

#[test]
fn no_debug_prints_and_numbers_at_their_precision() {
    let d = tmp("no-debug");
    let (_, err) = run_ok_with_stderr(
        bin()
            .args(["simulate", "--max-duration-s", "60", "-o"])
            .arg(d.join("f.csv"))
            .arg("--capture")
            .arg(d.join("f.cap")),
    );
    assert!(
        !err.contains("CaptureSummary") && !err.contains('{'),
        "{err}"
    );
    assert!(err.contains("scalar lines"), "{err}");
    let out = run_ok(
        bin()
            .arg("compensate")
            .arg(&fixture().flight)
            .arg("--coeffs")
            .arg(&fixture().coeffs)
            .arg("-o")
            .arg(d.join("o.csv")),
    );
    assert!(out.contains("(kf)") && !out.contains("(Kf)"), "{out}");
    // HDOP 0.8 from an f32: `0.8`, not `0.800000011920929`.
    let body = "GPGGA,123519,4807.038,N,01131.000,E,1,08,0.8,545.4,M,46.9,M,,";
    let sum = body.bytes().fold(0u8, |a, b| a ^ b);
    let log = d.join("gps.nmea");
    std::fs::write(&log, format!("${body}*{sum:02X}\r\n")).unwrap();
    let (out, err) = run_ok_with_stderr(bin().arg("nmea").arg(&log));
    assert!(
        out.contains("\"hdop\":0.8,") || out.contains("\"hdop\":0.8}"),
        "{out}"
    );
    assert!(!err.contains("NmeaLogStats"), "{err}");
    assert!(err.contains("1 sentences decoded"), "{err}");
}

#[test]
fn calibrate_help_names_only_its_own_options() {
    let help = run_ok(bin().args(["calibrate", "--help"]));
    assert!(!help.contains("--coeffs"), "{help}");
    let help = run_ok(bin().args(["compensate", "--help"]));
    assert!(help.contains("--rate-hz"));
}

/// `magcomp compensate … 2>&1 | tail -0` used to panic ("failed printing to stderr"):
/// a reader that has gone must cost the terminal text only, never the work or a panic.
#[test]
fn a_closed_pipe_costs_the_text_only() {
    let d = tmp("closed-pipe");
    let out = d.join("compensated.csv");
    let rows_in = std::fs::read_to_string(&fixture().flight)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .count();
    let mut child = quiet_to_closed_pipes(compensate_to(&out).arg("--json"));
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(0), "{status}");
    let rows_out = std::fs::read_to_string(&out)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .count();
    assert_eq!(
        rows_out, rows_in,
        "every row written though nobody read the text"
    );

    // A failing command still fails with its own status (1), not a panic's (101).
    let mut failing = quiet();
    failing
        .args(["compensate", "no-such-flight.csv", "-o"])
        .arg(d.join("x.csv"));
    let status = quiet_to_closed_pipes(&mut failing).wait().unwrap();
    assert_eq!(status.code(), Some(1), "{status}");
}

/// Spawns `cmd` with stdout and stderr into pipes whose reading ends are closed at once.
fn quiet_to_closed_pipes(cmd: &mut Command) -> std::process::Child {
    let mut child = cmd
        .env("RUST_BACKTRACE", "0")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    drop(child.stderr.take());
    child
}
