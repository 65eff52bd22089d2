//! `compensate --sensors` and streaming (issue 19): several magnetometers are compensated
//! in memory, so `--stream always` is refused with the reason (it was silently ignored and
//! the whole flight read), and an input `--stream auto` would stream (≥ 256 MiB) is said
//! to be read whole.

use magcomp::cli::compensate::{several_sensors_unstreamed, StreamMode};
use magcomp::io::trace::{read_trace, write_trace, ColumnMap};
use magcomp::sim::multi::{simulate_multi, STINGER_WINGTIPS_CABIN_M};
use magcomp::sim::SimConfig;
use magcomp::stream::AUTO_STREAM_BYTES;
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

#[test]
fn stream_always_is_refused_with_the_reason_and_nothing_is_written() {
    let cfg = SimConfig {
        seed: 5,
        ..Default::default()
    };
    let trace = simulate_multi(&cfg, &STINGER_WINGTIPS_CABIN_M[..2]).unwrap();
    let input = tmp("sim2.csv");
    write_trace(&input, &trace).unwrap();
    let coeffs = tmp("sim2.json");
    let o = magcomp(&[
        "calibrate",
        s(&input),
        "--sensors",
        "mag_1,mag_2",
        "-o",
        s(&coeffs),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // With --sensors, and with the several-sensor file alone (it names its sensors).
    let with_sensors = ["--sensors", "mag_1,mag_2"];
    for extra in [&with_sensors[..], &[]] {
        let out = tmp("refused.csv");
        let _ = std::fs::remove_file(&out);
        let mut args = vec!["compensate", s(&input), "--coeffs", s(&coeffs)];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--stream", "always", "-o", s(&out)]);
        let o = magcomp(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{extra:?}: {err}");
        assert!(
            err.contains("--stream always: this run cannot be streamed")
                && err.contains("several magnetometers"),
            "{extra:?}: {err}"
        );
        assert!(!out.exists(), "{extra:?}: an output was written");
        // `never` and `auto` (a small file) run it in memory, every row out.
        for mode in ["never", "auto"] {
            let mut args = vec!["compensate", s(&input), "--coeffs", s(&coeffs)];
            args.extend_from_slice(extra);
            args.extend_from_slice(&["--stream", mode, "-o", s(&out)]);
            let o = magcomp(&args);
            let err = String::from_utf8_lossy(&o.stderr);
            assert!(o.status.success(), "{extra:?} {mode}: {err}");
            assert!(!err.contains("not streamed"), "{mode}: {err}");
            let t = read_trace(&out, &ColumnMap::new()).unwrap();
            assert_eq!(t.len(), trace.len(), "{mode}");
            assert!(t.col("compensated_mag_2").is_some(), "{mode}");
        }
    }
}

/// The decision by size: `auto` notes from 256 MiB (the one-sensor streaming threshold),
/// not below; `never` never; `always` refuses at any size.
#[test]
fn a_large_input_read_whole_is_said_so() {
    let p = Path::new("big.csv");
    assert_eq!(AUTO_STREAM_BYTES, 268_435_456);
    let at = several_sensors_unstreamed(StreamMode::Auto, AUTO_STREAM_BYTES, p).unwrap();
    let note = at.expect("a note at 256 MiB");
    assert!(
        note.starts_with("note: big.csv is read into memory") && note.contains("not streamed"),
        "{note}"
    );
    let below = several_sensors_unstreamed(StreamMode::Auto, AUTO_STREAM_BYTES - 1, p).unwrap();
    assert_eq!(below, None);
    let never = several_sensors_unstreamed(StreamMode::Never, 10 * AUTO_STREAM_BYTES, p);
    assert_eq!(never.unwrap(), None);
    for size in [0, AUTO_STREAM_BYTES] {
        let e = several_sensors_unstreamed(StreamMode::Always, size, p).unwrap_err();
        assert!(format!("{e}").contains("cannot be streamed"), "{e}");
    }
}
