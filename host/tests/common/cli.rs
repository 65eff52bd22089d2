//! Running the `magcomp` command from a test: the binary, a scratch directory, and
//! success/failure with its output.

use std::path::{Path, PathBuf};
use std::process::Command;

pub fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_magcomp"))
}

pub fn tmp(name: &str) -> Scratch {
    Scratch(
        tempfile::Builder::new()
            .prefix(&format!("magcomp-cli-{name}-"))
            .tempdir()
            .unwrap(),
    )
}
/// A scratch directory removed when dropped (at the end of the test, passed or failed);
/// it reads as the directory's path.
pub struct Scratch(tempfile::TempDir);

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        self.0.path()
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        self.0.path()
    }
}

impl AsRef<std::ffi::OsStr> for Scratch {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.0.path().as_os_str()
    }
}

/// Runs a command that must succeed; its stdout and stderr.
pub fn run_ok_with_stderr(cmd: &mut Command) -> (String, String) {
    let out = cmd.output().expect("run magcomp");
    assert!(
        out.status.success(),
        "magcomp failed: {}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (
        String::from_utf8(out.stdout).unwrap(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

pub fn run_ok(cmd: &mut Command) -> String {
    run_ok_with_stderr(cmd).0
}

pub fn run_err(cmd: &mut Command) -> String {
    let out = cmd.output().expect("run magcomp");
    assert!(!out.status.success(), "magcomp should have failed");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

pub fn simulate(dir: &Path, extra: &[&str]) -> PathBuf {
    let p = dir.join("flight.csv");
    let mut c = bin();
    c.args(["simulate", "--seed", "3", "-o"])
        .arg(&p)
        .args(extra);
    run_ok(&mut c);
    p
}

pub fn data_rows(p: &Path) -> usize {
    std::fs::read_to_string(p)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .count()
        - 1
}

/// A named column's cells of a CSV with `#` comments.
fn column_cells(path: &Path, name: &str) -> Vec<String> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let j = lines
        .next()
        .unwrap()
        .split(',')
        .position(|c| c == name)
        .unwrap_or_else(|| panic!("no {name} in {}", path.display()));
    lines
        .map(|l| l.split(',').nth(j).unwrap().to_string())
        .collect()
}

/// A named numeric column of a CSV with `#` comments.
pub fn csv_column(path: &Path, name: &str) -> Vec<f64> {
    column_cells(path, name)
        .iter()
        .map(|c| c.parse().unwrap_or(f64::NAN))
        .collect()
}

/// The `flags` column (hex, `0x…`) of a `compensate` output CSV, one per row.
pub fn flags_column(path: &Path) -> Vec<u16> {
    column_cells(path, "flags")
        .iter()
        .map(|c| u16::from_str_radix(c.trim_start_matches("0x"), 16).unwrap())
        .collect()
}
