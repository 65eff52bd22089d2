//! The estimator does no harm where a flight cannot tell (issue 10 item 1) and one bad
//! sample does not ruin a calibration (issue 13 item 1): numbers against the simulator's
//! truth.

#[path = "common/cli.rs"]
#[allow(dead_code)] // each test file uses a part of the shared helpers
mod cli;
use cli::{bin, run_ok_with_stderr, simulate, tmp};
use std::path::Path;

fn summary(trace: &Path, out: &Path) -> (serde_json::Value, String) {
    let (stdout, stderr) = run_ok_with_stderr(
        bin()
            .args(["compensate", "--json", "-o"])
            .arg(out)
            .arg(trace),
    );
    (serde_json::from_str(&stdout).unwrap(), stderr)
}

/// A copy of `src` with `delta_nt` added to the scalar of data row `row`.
fn with_glitch(src: &Path, dst: &Path, row: usize, delta_nt: f64) {
    let text = std::fs::read_to_string(src).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let header = lines.iter().position(|l| !l.starts_with('#')).unwrap();
    let mag = lines[header].split(',').position(|c| c == "mag").unwrap();
    let mut cells: Vec<String> = lines[header + 1 + row]
        .split(',')
        .map(String::from)
        .collect();
    cells[mag] = (cells[mag].parse::<f64>().unwrap() + delta_nt).to_string();
    lines[header + 1 + row] = cells.join(",");
    std::fs::write(dst, lines.join("\n") + "\n").unwrap();
}

/// A straight line without manoeuvres, climbing and descending ±150 m at 200 m over strong
/// geology: the filter must not trade geology into the coefficients it cannot determine.
/// Measured: 10 of 16 combinations held, error 0.059 nT (0.41 nT when fitted; the
/// uncompensated signal's is 0.90 nT).
#[test]
fn a_straight_line_without_manoeuvres_is_warned_and_not_harmed() {
    let dir = tmp("noharm-line");
    let trace = dir.join("line.csv");
    run_ok_with_stderr(
        bin()
            .args(["simulate", "--seed", "4", "-o"])
            .arg(&trace)
            .args([
                "--flight",
                "survey",
                "--lines",
                "1",
                "--line-length-m",
                "40000",
                "--survey-altitude-m",
                "200",
                "--altitude-swing-m",
                "150",
                "--geology",
                "strong",
            ]),
    );
    let (s, stderr) = summary(&trace, &dir.join("out.csv"));
    let warnings = s["warnings"].as_array().unwrap();
    assert!(
        warnings
            .iter()
            .any(|w| w.as_str().unwrap().contains("not excited by manoeuvres")),
        "{warnings:?}"
    );
    assert!(stderr.contains("warning: "), "{stderr}");
    let error = s["error_rms_nt"].as_f64().unwrap();
    eprintln!("straight line: error {error:.4} nT");
    assert!(error < 0.15, "error {error} nT");
}

/// The clean cloverleaf holds nothing and is not warned about.
#[test]
fn a_calibration_pattern_holds_nothing() {
    let dir = tmp("noharm-cal");
    let trace = simulate(&dir, &[]);
    let (s, _) = summary(&trace, &dir.join("out.csv"));
    assert!(
        s["warnings"].as_array().unwrap().is_empty(),
        "{}",
        s["warnings"]
    );
}

/// One +4000 nT scalar value at 6.5 s, or a +1e5 nT one mid-flight: the final error changes
/// by less than 2× the clean flight's (+0.02 nT). Measured: clean 0.0068, early 0.0069, mid
/// 0.0076 nT (the early glitch had made it 1 361 nT, the mid one 0.21 nT).
#[test]
fn a_single_scalar_glitch_does_not_ruin_a_calibration() {
    let dir = tmp("noharm-glitch");
    let clean = simulate(&dir, &[]);
    let (c, _) = summary(&clean, &dir.join("clean.csv"));
    let clean_nt = c["error_rms_nt"].as_f64().unwrap();
    for (row, delta, name) in [(65, 4000.0, "early"), (3000, 1e5, "mid")] {
        let p = dir.join(format!("{name}.csv"));
        with_glitch(&clean, &p, row, delta);
        let (s, stderr) = summary(&p, &dir.join(format!("{name}-out.csv")));
        let e = s["error_rms_nt"].as_f64().unwrap();
        eprintln!("{name} glitch: {e:.4} nT (clean {clean_nt:.4})");
        assert!(
            e < 2.0 * clean_nt + 0.02,
            "{name}: {e} nT vs clean {clean_nt}"
        );
        assert!(stderr.contains("scalar glitch"), "{stderr}");
    }
}
