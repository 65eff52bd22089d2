//! Peak memory (RSS) of `compensate --coeffs`, streamed and in memory, on long synthetic
//! surveys: a simulated 10 Hz survey (seed 8, 4 lines, 11,603 rows) repeated with its
//! time shifted until the wanted row count, with coefficients calibrated on the same
//! aircraft's cloverleaf. A measurement, not a timed test: run it with
//! `scripts/stream_rss.sh` (or `cargo bench -p magcomp --bench stream_rss`).
//!
//! `STREAM_RSS_SENSORS=N` (2–4, issue 19): the same for N magnetometers — a simulated
//! N-sensor survey (seed 5) and the several-sensor file `calibrate --sensors` makes on
//! the N-sensor cloverleaf, applied by `compensate --coeffs` (one filter per sensor).
//!
//! Env: `STREAM_RSS_ROWS` (default `1000000,10000000`), `STREAM_RSS_IN_MEMORY_MAX`
//! (default 1000000: the in-memory run takes ~1 KB/row), `STREAM_RSS_DIR` (default
//! `$TMPDIR/magcomp-stream-rss`; ~360 bytes of disk per row). Needs GNU `/usr/bin/time`.
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::process::Command;

fn magcomp(args: &[&str], dir: &Path) {
    let st = Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("running magcomp");
    assert!(
        st.status.success(),
        "magcomp {args:?}: {}",
        String::from_utf8_lossy(&st.stderr)
    );
}

/// The base survey's rows repeated, `t` (first column) shifted by the span each time.
fn write_survey(base: &Path, out: &Path, rows: usize) {
    let text = std::fs::read_to_string(base).unwrap();
    let mut head = Vec::new();
    let mut data: Vec<(f64, &str)> = Vec::new();
    for line in text.lines() {
        if data.is_empty()
            && (line.starts_with('#') || head.iter().all(|l: &&str| l.starts_with('#')))
        {
            head.push(line);
            continue;
        }
        let (t, rest) = line.split_once(',').unwrap();
        data.push((t.parse().unwrap(), rest));
    }
    let span = data[data.len() - 1].0 - data[0].0 + (data[1].0 - data[0].0);
    let mut w = BufWriter::with_capacity(1 << 20, std::fs::File::create(out).unwrap());
    for l in &head {
        writeln!(w, "{l}").unwrap();
    }
    let mut k = 0;
    'rep: for rep in 0.. {
        for (t, rest) in &data {
            if k == rows {
                break 'rep;
            }
            writeln!(w, "{:.4},{rest}", t + rep as f64 * span).unwrap();
            k += 1;
        }
    }
    w.flush().unwrap();
}

/// (peak RSS in KiB, wall clock) of one `compensate` run.
fn measure(dir: &Path, input: &str, out: &str, mode: &str) -> (u64, String) {
    let o = Command::new("/usr/bin/time")
        .arg("-v")
        .arg(env!("CARGO_BIN_EXE_magcomp"))
        .args([
            "compensate",
            input,
            "--coeffs",
            "coeffs.json",
            "-o",
            out,
            "--stream",
            mode,
        ])
        .current_dir(dir)
        .output()
        .expect("/usr/bin/time (GNU time) is needed");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "compensate --stream {mode}: {err}");
    let field = |key: &str| {
        err.lines()
            .find(|l| l.contains(key))
            .and_then(|l| l.rsplit(' ').next())
            .unwrap_or("")
            .to_string()
    };
    (
        field("Maximum resident set size").parse().unwrap_or(0),
        field("Elapsed (wall clock)"),
    )
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return; // `cargo test --benches` asks for a list: nothing to run there
    }
    let rows: Vec<usize> = std::env::var("STREAM_RSS_ROWS")
        .unwrap_or_else(|_| "1000000,10000000".into())
        .split(',')
        .map(|s| s.trim().parse().expect("STREAM_RSS_ROWS: row counts"))
        .collect();
    let in_memory_max: usize = std::env::var("STREAM_RSS_IN_MEMORY_MAX")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1_000_000);
    let sensors: usize = std::env::var("STREAM_RSS_SENSORS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1);
    let dir = std::env::var("STREAM_RSS_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|_| {
            let name = match sensors {
                1 => "magcomp-stream-rss".to_string(),
                n => format!("magcomp-stream-rss-{n}-sensors"),
            };
            std::env::temp_dir().join(name)
        });
    std::fs::create_dir_all(&dir).unwrap();
    // One sensor: seed 8, as before; several: `--sensors N` (seed 5), calibrated jointly.
    let n_text = sensors.to_string();
    let names: Vec<String> = (1..=sensors).map(|k| format!("mag_{k}")).collect();
    let names = names.join(",");
    let (seed, several): (&str, &[&str]) = match sensors {
        1 => ("8", &[]),
        _ => ("5", &["--sensors", &n_text]),
    };
    if !dir.join("coeffs.json").exists() {
        let mut sim = vec!["simulate", "--flight", "calibration", "--seed", seed];
        sim.extend_from_slice(several);
        sim.extend_from_slice(&["-o", "cal.csv"]);
        magcomp(&sim, &dir);
        let mut cal = vec!["calibrate", "cal.csv", "--sigma1", "3e-7"];
        if sensors > 1 {
            cal.extend_from_slice(&["--sensors", &names]);
        }
        cal.extend_from_slice(&["-o", "coeffs.json"]);
        magcomp(&cal, &dir);
    }
    if !dir.join("base.csv").exists() {
        let mut sim = vec![
            "simulate", "--flight", "survey", "--seed", seed, "--lines", "4",
        ];
        sim.extend_from_slice(several);
        sim.extend_from_slice(&["-o", "base.csv"]);
        magcomp(&sim, &dir);
    }
    for n in rows {
        let name = format!("survey_{n}.csv");
        if !dir.join(&name).exists() {
            write_survey(&dir.join("base.csv"), &dir.join(&name), n);
        }
        let mib = std::fs::metadata(dir.join(&name)).unwrap().len() >> 20;
        let (kb, wall) = measure(&dir, &name, "out_stream.csv", "always");
        println!(
            "{n} rows ({mib} MiB file): streamed peak RSS {} MiB ({} B/row), wall {wall}",
            kb >> 10,
            kb * 1024 / n as u64
        );
        if n <= in_memory_max {
            let (kb, wall) = measure(&dir, &name, "out_mem.csv", "never");
            let same = std::fs::read(dir.join("out_stream.csv")).unwrap()
                == std::fs::read(dir.join("out_mem.csv")).unwrap();
            println!(
                "{n} rows: in memory peak RSS {} MiB ({} B/row), wall {wall}; outputs {}",
                kb >> 10,
                kb * 1024 / n as u64,
                if same { "identical" } else { "DIFFER" }
            );
            std::fs::remove_file(dir.join("out_mem.csv")).ok();
        }
        std::fs::remove_file(dir.join("out_stream.csv")).ok();
    }
}
