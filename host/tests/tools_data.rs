//! Tools that never lose data: an output that is an input is refused before anything is
//! read or written; a write that fails (here: the file-size limit, as a full disk would)
//! leaves the previous file intact, no temporary file, and a non-zero exit naming the
//! output; coefficient files are read by name; a BOM on a trace header is read through.

mod common;

use common::cli::{bin, data_rows, run_err, run_ok, simulate, tmp};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// `magcomp ARGS` with writes limited to `kib` KiB (bash's `ulimit -f`), SIGXFSZ ignored
/// so that a write past the limit fails with EFBIG, as one on a full disk fails with
/// ENOSPC, instead of killing the process.
fn run_limited(kib: u64, args: &[&std::ffi::OsStr]) -> Output {
    Command::new("bash")
        .arg("-c")
        .arg(format!("trap '' XFSZ; ulimit -f {kib}; exec \"$0\" \"$@\""))
        .arg(env!("CARGO_BIN_EXE_magcomp"))
        .args(args)
        .output()
        .expect("run bash")
}

fn temporaries(d: &Path) -> Vec<String> {
    std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect()
}

#[test]
fn an_output_that_is_an_input_is_refused_before_anything_is_written() {
    let d = tmp("same-path");
    let trace = simulate(&d, &["--max-duration-s", "60"]);
    let before = std::fs::read(&trace).unwrap();
    let link = d.join("link.csv");
    let _ = std::fs::remove_file(&link);
    std::os::unix::fs::symlink(&trace, &link).unwrap();
    let spelled = d.join(".").join("flight.csv");
    for out in [&trace, &spelled, &link] {
        let e = run_err(bin().arg("compensate").arg(&trace).arg("--out").arg(out));
        assert!(e.contains("refusing to overwrite"), "{e}");
        let e = run_err(bin().arg("calibrate").arg(&trace).arg("-o").arg(out));
        assert!(e.contains("refusing to overwrite"), "{e}");
        assert_eq!(std::fs::read(&trace).unwrap(), before, "input untouched");
    }
    // The coefficient file of compensate is an input too, and so is replay's capture.
    let coeffs = d.join("c.json");
    run_ok(bin().arg("calibrate").arg(&trace).arg("-o").arg(&coeffs));
    let e = run_err(
        bin()
            .arg("compensate")
            .arg(&trace)
            .arg("--coeffs")
            .arg(&coeffs)
            .arg("--out")
            .arg(&coeffs),
    );
    assert!(e.contains("refusing to overwrite"), "{e}");
    let cap = d.join("cap.cap");
    run_ok(
        bin()
            .args(["simulate", "--max-duration-s", "30", "-o"])
            .arg(d.join("s.csv"))
            .arg("--capture")
            .arg(&cap),
    );
    let cap_before = std::fs::read(&cap).unwrap();
    let e = run_err(bin().arg("replay").arg(&cap).arg("-o").arg(&cap));
    assert!(e.contains("refusing to overwrite"), "{e}");
    let e = run_err(
        bin()
            .arg("replay")
            .arg(&cap)
            .arg("-o")
            .arg(d.join("r.csv"))
            .arg("--records")
            .arg(d.join(".").join("r.csv")),
    );
    assert!(e.contains("same file"), "{e}");
    assert_eq!(std::fs::read(&cap).unwrap(), cap_before);
    // simulate's trace and capture must differ; upload must not write over its input.
    let e = run_err(
        bin()
            .args(["simulate", "--max-duration-s", "10", "-o"])
            .arg(d.join("x.csv"))
            .arg("--capture")
            .arg(d.join("x.csv")),
    );
    assert!(e.contains("same file"), "{e}");
    let coeffs_before = std::fs::read(&coeffs).unwrap();
    let e = run_err(bin().arg("upload").arg(&coeffs).arg("--to").arg(&coeffs));
    assert!(e.contains("refusing to overwrite"), "{e}");
    assert_eq!(std::fs::read(&coeffs).unwrap(), coeffs_before);
}

#[test]
fn a_failed_write_leaves_the_previous_file_and_no_temporary() {
    let d = tmp("fsize");
    let cap = d.join("f.cap");
    let trace = simulate(
        &d,
        &[
            "--max-duration-s",
            "120",
            "--capture",
            cap.to_str().unwrap(),
        ],
    );
    let previous = b"previous content\n";
    let os = |p: &PathBuf| p.as_os_str().to_owned();
    let cases: Vec<(&str, Vec<std::ffi::OsString>, PathBuf)> = vec![
        (
            "compensate",
            vec![
                "compensate".into(),
                os(&trace),
                "--out".into(),
                os(&d.join("out.csv")),
            ],
            d.join("out.csv"),
        ),
        (
            "calibrate",
            vec![
                "calibrate".into(),
                os(&trace),
                "-o".into(),
                os(&d.join("k.json")),
            ],
            d.join("k.json"),
        ),
        (
            "simulate",
            vec!["simulate".into(), "-o".into(), os(&d.join("sim.csv"))],
            d.join("sim.csv"),
        ),
        (
            "replay",
            vec![
                "replay".into(),
                os(&cap),
                "-o".into(),
                os(&d.join("rec.csv")),
            ],
            d.join("rec.csv"),
        ),
        (
            "report",
            vec![
                "report".into(),
                os(&trace),
                "--model".into(),
                "tl16+field".into(),
                "-o".into(),
                os(&d.to_path_buf()),
            ],
            d.join("index.html"),
        ),
    ];
    for (name, args, out) in cases {
        std::fs::write(&out, previous).unwrap();
        let argv: Vec<&std::ffi::OsStr> = args.iter().map(|a| a.as_os_str()).collect();
        // Below each output's size: the coefficient file ~6 KB, the replay's records
        // ~80 KB, the others 100s of KB.
        let limit = match name {
            "calibrate" => 1,
            "replay" => 16,
            _ => 64,
        };
        let r = run_limited(limit, &argv);
        let stderr = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success(), "{name} must fail: {stderr}");
        assert!(
            stderr.contains(&*out.file_name().unwrap().to_string_lossy()),
            "{name}: the message names the output: {stderr}"
        );
        assert_eq!(
            std::fs::read(&out).unwrap(),
            previous,
            "{name}: nothing truncated under the final name"
        );
        assert!(temporaries(&d).is_empty(), "{name}: {:?}", temporaries(&d));
    }
    // The same commands without the limit replace the file.
    run_ok(
        bin()
            .arg("compensate")
            .arg(&trace)
            .arg("--out")
            .arg(d.join("out.csv")),
    );
    assert_eq!(data_rows(&d.join("out.csv")), data_rows(&trace));
}

/// `calibrate`'s JSON with its coefficient entries rewritten by `f`.
fn edited(coeffs: &Path, out: &Path, f: impl Fn(&mut Vec<serde_json::Value>)) {
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(coeffs).unwrap()).unwrap();
    f(v["coefficients"].as_array_mut().unwrap());
    std::fs::write(out, serde_json::to_string_pretty(&v).unwrap()).unwrap();
}

#[test]
fn coefficient_files_are_read_by_name() {
    let d = tmp("by-name");
    let trace = simulate(&d, &["--max-duration-s", "300"]);
    let coeffs = d.join("c.json");
    run_ok(bin().arg("calibrate").arg(&trace).arg("-o").arg(&coeffs));
    let compensate = |c: &Path, out: &str| {
        let json = run_ok(
            bin()
                .arg("compensate")
                .arg(&trace)
                .arg("--coeffs")
                .arg(c)
                .arg("--json")
                .arg("--out")
                .arg(d.join(out)),
        );
        (json, std::fs::read(d.join(out)).unwrap())
    };
    let want = compensate(&coeffs, "a.csv");
    let swapped = d.join("swapped.json");
    edited(&coeffs, &swapped, |c| c.swap(0, 5));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&swapped).unwrap()).unwrap();
    assert_ne!(
        v["coefficients"][0]["name"], "permanent.e1",
        "the file is reordered"
    );
    let got = compensate(&swapped, "b.csv");
    assert_eq!(got.1, want.1, "same output rows");
    assert_eq!(got.0, want.0, "same summary");
    // upload sends the same lines.
    let up = |c: &Path| run_ok(bin().arg("upload").arg(c));
    assert_eq!(up(&swapped), up(&coeffs));
    // The default model calibrates the fluxgate: its 12 values go with SETFLUX.
    let lines = up(&coeffs);
    // The board's vector: the file's 16, then `fluxmod` 0 (its witness filter's term).
    assert_eq!(lines.lines().filter(|l| l.contains("SETCOEF")).count(), 17);
    assert_eq!(
        lines
            .lines()
            .filter(|l| l.starts_with("$MCCMD,SETCOEF,16,0*"))
            .count(),
        1
    );
    assert_eq!(lines.lines().filter(|l| l.contains("SETFLUX")).count(), 12);
    // No `lag` in the model: SETLAG 0, so a τ left by an earlier upload does not stay.
    assert_eq!(
        lines
            .lines()
            .filter(|l| l.starts_with("$MCCMD,SETLAG,0"))
            .count(),
        1
    );
    // No `fluxtemp`: 7 SETFTEMP zeros clear an earlier upload's correction.
    assert_eq!(
        lines
            .lines()
            .filter(|l| l.starts_with("$MCCMD,SETFTEMP,")
                && l.split('*').next().is_some_and(|b| b.ends_with(",0")))
            .count(),
        7
    );
    assert_eq!(
        lines.lines().count(),
        38,
        "17 SETCOEF, 12 SETFLUX, SETLAG, 7 SETFTEMP and SAVE"
    );
    // An unknown or a missing name is an error naming it; so is a short file for upload.
    let bad = d.join("bad.json");
    edited(&coeffs, &bad, |c| c[3]["name"] = "induced.wobble".into());
    let e = run_err(
        bin()
            .arg("compensate")
            .arg(&trace)
            .arg("--coeffs")
            .arg(&bad)
            .arg("--out")
            .arg(d.join("x.csv")),
    );
    assert!(e.contains("unknown coefficient 'induced.wobble'"), "{e}");
    edited(&coeffs, &bad, |c| c.truncate(10));
    let e = run_err(
        bin()
            .arg("compensate")
            .arg(&trace)
            .arg("--coeffs")
            .arg(&bad)
            .arg("--out")
            .arg(d.join("x.csv")),
    );
    assert!(e.contains("is missing (10 of 16 given)"), "{e}");
    let out = bin().arg("upload").arg(&bad).output().unwrap();
    assert!(!out.status.success());
    assert!(out.stdout.is_empty(), "nothing sent");
    assert!(String::from_utf8_lossy(&out.stderr).contains("is missing (10 of 16 given)"));
}

#[test]
fn a_bom_on_the_trace_header_is_read_through() {
    let d = tmp("bom");
    let trace = simulate(&d, &["--max-duration-s", "120"]);
    let mut bom = b"\xEF\xBB\xBF".to_vec();
    bom.extend_from_slice(&std::fs::read(&trace).unwrap());
    let with_bom = d.join("bom.csv");
    std::fs::write(&with_bom, bom).unwrap();
    let run = |t: &Path, out: &str| {
        run_ok(bin().arg("compensate").arg(t).arg("--out").arg(d.join(out)));
        std::fs::read(d.join(out)).unwrap()
    };
    assert_eq!(run(&with_bom, "b.csv"), run(&trace, "a.csv"));
}
