//! The source layout the command layer depends on (issue 11 item 7), checked by reading
//! the sources: `src/cli/` (one file per subcommand) is the only place with clap, nothing
//! outside it imports it, and the two former import cycles stay broken.

use std::path::{Path, PathBuf};

/// Every `.rs` file under `dir`, recursively.
fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).expect("read_dir") {
        let p = e.expect("entry").path();
        if p.is_dir() {
            out.extend(rust_files(&p));
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
    out.sort();
    out
}

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// The file's code without comment lines (a doc comment may name a module freely).
fn code(path: &Path) -> String {
    std::fs::read_to_string(path)
        .expect("read")
        .lines()
        .filter(|l| !l.trim_start().starts_with("//"))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Processing files: everything but the command layer and the binary's entry point.
fn processing_files() -> Vec<PathBuf> {
    let cli = src().join("cli");
    rust_files(&src())
        .into_iter()
        .filter(|p| !p.starts_with(&cli) && !p.ends_with("main.rs") && !p.ends_with("lib.rs"))
        .collect()
}

/// Files under `src/<module>` (a directory) or `src/<module>.rs`.
fn module_files(module: &str) -> Vec<PathBuf> {
    let dir = src().join(module);
    if dir.is_dir() {
        rust_files(&dir)
    } else {
        vec![src().join(format!("{module}.rs"))]
    }
}

fn offenders(files: &[PathBuf], needles: &[&str]) -> Vec<String> {
    files
        .iter()
        .filter(|p| {
            let c = code(p);
            needles.iter().any(|n| c.contains(n))
        })
        .map(|p| p.strip_prefix(src()).unwrap_or(p).display().to_string())
        .collect()
}

#[test]
fn processing_neither_imports_the_command_layer_nor_uses_clap() {
    let files = processing_files();
    // The check must see the processing modules, or it passes on nothing.
    assert!(files.len() > 40, "{} processing files", files.len());
    for must in [
        "calibration/mod.rs",
        "calibration/coefficients.rs",
        "diagnose/mod.rs",
    ] {
        assert!(files.iter().any(|p| p.ends_with(must)), "{must} not seen");
    }
    let bad = offenders(&files, &["crate::cli", "magcomp::cli", "super::cli"]);
    assert!(
        bad.is_empty(),
        "processing imports the command layer: {bad:?}"
    );
    let bad = offenders(&files, &["clap::", "#[arg(", "#[command("]);
    assert!(bad.is_empty(), "clap outside src/cli: {bad:?}");
}

#[test]
fn every_subcommand_has_its_file_in_cli() {
    for sub in [
        "simulate",
        "calibrate",
        "compensate",
        "nmea",
        "diagnose",
        "report",
        "replay",
        "monitor",
        "upload",
        "demo",
        "args",
    ] {
        assert!(
            src().join("cli").join(format!("{sub}.rs")).is_file(),
            "{sub}"
        );
    }
    // main.rs parses and dispatches only: no processing module is called from it.
    let main = code(&src().join("main.rs"));
    assert!(main.contains("Cli::parse()"), "main.rs does not parse");
    let calls: Vec<&str> = main
        .lines()
        .filter(|l| l.contains("magcomp::") && !l.contains("magcomp::cli"))
        .collect();
    assert!(
        calls.is_empty(),
        "main.rs reaches past the command layer: {calls:?}"
    );
}

#[test]
fn diagnose_and_report_do_not_import_each_other_both_ways() {
    let report_uses_diagnose = !offenders(&module_files("report"), &["crate::diagnose"]).is_empty();
    let diagnose_uses_report = offenders(&module_files("diagnose"), &["crate::report"]);
    // The report is built from diagnoses: that direction is the one kept.
    assert!(
        report_uses_diagnose,
        "the check no longer sees report → diagnose"
    );
    assert!(
        diagnose_uses_report.is_empty(),
        "diagnose imports report: {diagnose_uses_report:?}"
    );
}

#[test]
fn flight_does_not_import_fluxgate() {
    assert!(!offenders(&module_files("estimate/fluxcal"), &["crate::flight"]).is_empty());
    let bad = offenders(
        &module_files("flight"),
        &["crate::estimate::fluxcal", "fluxcal::"],
    );
    assert!(bad.is_empty(), "flight imports fluxgate: {bad:?}");
}

#[test]
fn command_layer_and_the_split_modules_stay_under_1000_lines() {
    let mut files = rust_files(&src().join("cli"));
    files.extend(module_files("calibration"));
    files.extend(module_files("estimate/kf"));
    files.extend(["calibration/coefficients.rs", "main.rs"].map(|f| src().join(f)));
    for p in files {
        let n = std::fs::read_to_string(&p).expect("read").lines().count();
        assert!(n <= 1000, "{}: {n} lines", p.display());
    }
}
