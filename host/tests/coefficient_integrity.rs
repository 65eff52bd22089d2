//! Issue 21 item 3: `calibrate` seals its coefficient file with a SHA-256 over the
//! canonical content; a value changed afterwards (two induced coefficients swapped, the
//! sign of `permanent.e3` flipped) is refused by `compensate` and `upload`, while
//! reordering the entries is not a change. A file without a checksum (written before it
//! existed) loads with a note. Covariance, noise, sample rate and σ1 are validated on load
//! with messages in words. A fluxgate calibration outside physical bounds is refused by
//! `upload`.

mod common;

use common::cli::{bin, run_err, run_ok, run_ok_with_stderr, simulate, tmp};
use serde_json::Value;
use std::path::Path;

/// (what, how the file is edited, what the error must say).
type Case = (&'static str, Box<dyn Fn(&mut Value)>, &'static str);

fn json(p: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

fn write(p: &Path, v: &Value) {
    std::fs::write(p, serde_json::to_string_pretty(v).unwrap()).unwrap();
}

fn index_of(v: &Value, name: &str) -> usize {
    v["coefficients"]
        .as_array()
        .unwrap()
        .iter()
        .position(|c| c["name"] == name)
        .unwrap_or_else(|| panic!("{name} in {v}"))
}

/// A calibrated simulated flight, its sealed coefficient file, and a scratch file the
/// checks write their edited copies to.
struct Fixture {
    d: common::cli::Scratch,
    trace: std::path::PathBuf,
    edited: std::path::PathBuf,
    sealed: Value,
}

impl Fixture {
    fn compensate(&self, c: &Path) -> std::process::Output {
        bin()
            .arg("compensate")
            .arg(&self.trace)
            .arg("--coeffs")
            .arg(c)
            .arg("--out")
            .arg(self.d.join("o.csv"))
            .output()
            .unwrap()
    }
}

#[test]
fn changed_values_are_refused_and_implausible_ones_named() {
    let d = tmp("integrity");
    let trace = simulate(&d, &["--max-duration-s", "300"]);
    let coeffs = d.join("c.json");
    run_ok(bin().arg("calibrate").arg(&trace).arg("-o").arg(&coeffs));
    let sealed = json(&coeffs);
    let sum = sealed["checksum"]
        .as_str()
        .expect("calibrate writes a checksum");
    assert_eq!(sum.len(), 64, "SHA-256 hex: {sum}");
    let f = Fixture {
        edited: d.join("edited.json"),
        d,
        trace,
        sealed,
    };
    let ok = f.compensate(&coeffs);
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    assert!(
        !String::from_utf8_lossy(&ok.stderr).contains("checksum"),
        "a sealed file loads without a note"
    );
    changed_values_are_refused(&f);
    let old = unsealed_loads_with_a_note(&f);
    implausible_values_are_named(&f, &old);
    unphysical_fluxgate_calibrations_are_not_uploaded(&f, &old);
    std::fs::remove_dir_all(&f.d).ok();
}

/// A value changed after `calibrate` is refused by `compensate` and `upload`; reordered
/// entries are not a change.
fn changed_values_are_refused(f: &Fixture) {
    let (edited, sealed) = (&f.edited, &f.sealed);
    let compensate = |c: &Path| f.compensate(c);
    const CHANGED: &str = "does not match its checksum";
    let expect_refused = |v: &Value, what: &str| {
        write(edited, v);
        let out = compensate(edited);
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && e.contains(CHANGED), "{what}: {e}");
        let e = run_err(bin().arg("upload").arg(edited));
        assert!(e.contains(CHANGED), "upload, {what}: {e}");
    };
    // Two induced coefficients' values swapped.
    let mut v = sealed.clone();
    let induced: Vec<usize> = (0..v["coefficients"].as_array().unwrap().len())
        .filter(|&i| {
            v["coefficients"][i]["name"]
                .as_str()
                .unwrap()
                .starts_with("induced.")
        })
        .collect();
    let (a, b) = (induced[0], induced[1]);
    let (va, vb) = (
        v["coefficients"][a]["value"].clone(),
        v["coefficients"][b]["value"].clone(),
    );
    v["coefficients"][a]["value"] = vb;
    v["coefficients"][b]["value"] = va;
    expect_refused(&v, "induced swapped");
    // The sign of permanent.e3 flipped.
    let mut v = sealed.clone();
    let i = index_of(&v, "permanent.e3");
    let x = v["coefficients"][i]["value"].as_f64().unwrap();
    v["coefficients"][i]["value"] = (-x).into();
    expect_refused(&v, "permanent.e3 negated");
    // The fluxgate calibration's bias changed.
    let mut v = sealed.clone();
    v["fluxgate_calibration"]["bias_nt"][2] = 500.0.into();
    expect_refused(&v, "fluxgate bias");

    // Reordered entries, another layout, provenance stripped: the same content.
    let mut v = sealed.clone();
    v["coefficients"].as_array_mut().unwrap().reverse();
    v.as_object_mut().unwrap().remove("provenance");
    std::fs::write(edited, serde_json::to_string(&v).unwrap()).unwrap();
    let out = compensate(edited);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Without its checksum a file loads with a note (stderr and `--json`); returns it.
fn unsealed_loads_with_a_note(f: &Fixture) -> Value {
    let (d, trace, edited, sealed) = (&f.d, &f.trace, &f.edited, &f.sealed);
    // No checksum: loads, with a note; then each implausible value is named in words.
    let mut old = sealed.clone();
    old.as_object_mut().unwrap().remove("checksum");
    write(edited, &old);
    let (_, e) = run_ok_with_stderr(
        bin()
            .arg("compensate")
            .arg(trace)
            .arg("--coeffs")
            .arg(edited)
            .arg("--out")
            .arg(d.join("o.csv")),
    );
    assert!(e.contains("note:") && e.contains("no checksum"), "{e}");
    // …and in `--json`, where a pipeline reads it, not only on stderr.
    let (json, _) = run_ok_with_stderr(
        bin()
            .arg("compensate")
            .arg(trace)
            .arg("--coeffs")
            .arg(edited)
            .arg("--json")
            .arg("--out")
            .arg(d.join("o.csv")),
    );
    let j: Value = serde_json::from_str(&json).expect("--json output");
    let warnings = j["warnings"].as_array().expect("warnings");
    assert!(
        warnings
            .iter()
            .any(|w| w.as_str().is_some_and(|w| w.contains("no checksum"))),
        "{warnings:?}"
    );
    old
}

/// Each implausible value of an unsealed file is refused, named in words.
fn implausible_values_are_named(f: &Fixture, old: &Value) {
    let edited = &f.edited;
    let compensate = |c: &Path| f.compensate(c);
    let k = old["coefficients"].as_array().unwrap().len();
    let cases: Vec<Case> = vec![
        (
            "negated covariance",
            Box::new(|v: &mut Value| {
                for row in v["covariance"].as_array_mut().unwrap() {
                    for x in row.as_array_mut().unwrap() {
                        *x = (-x.as_f64().unwrap()).into();
                    }
                }
            }),
            "the covariance is not positive semi-definite",
        ),
        (
            "asymmetric covariance",
            Box::new(move |v: &mut Value| {
                let x = v["covariance"][0][k - 1].as_f64().unwrap();
                v["covariance"][0][k - 1] = (x + 1.0 + 10.0 * x.abs()).into();
            }),
            "the covariance is not symmetric",
        ),
        (
            "noise 0",
            Box::new(|v: &mut Value| v["noise_nt"] = 0.0.into()),
            "the scalar noise is 0 nT: it must be a positive number",
        ),
        (
            "noise -1",
            Box::new(|v: &mut Value| v["noise_nt"] = (-1.0).into()),
            "the scalar noise is -1 nT: it must be a positive number",
        ),
        (
            "sample rate 0",
            Box::new(|v: &mut Value| v["sample_rate_hz"] = 0.0.into()),
            "the sample rate is 0 Hz: it must be a positive number",
        ),
        (
            "sigma1 0",
            Box::new(|v: &mut Value| v["sigma1"] = 0.0.into()),
            "σ1 (the anomaly's along-track roughness, sigma1) is 0",
        ),
    ];
    for (what, edit, said) in cases {
        let mut v = old.clone();
        edit(&mut v);
        write(edited, &v);
        let out = compensate(edited);
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{what}: accepted");
        assert!(e.contains(said), "{what}: {e}");
        assert!(!e.contains("Bad"), "{what}: no enum names: {e}");
        eprintln!(
            "{what}: {}",
            e.lines().find(|l| l.contains(said)).unwrap_or("")
        );
    }
}

/// A fluxgate calibration only bad data gives, or a left-handed one, is refused by
/// `upload`, checksum or not.
fn unphysical_fluxgate_calibrations_are_not_uploaded(f: &Fixture, old: &Value) {
    let edited = &f.edited;
    // A fluxgate calibration only bad data gives (one zero row: −38,736 nT, z scale
    // 1.75) or a left-handed one is refused by `upload`, checksum or not.
    let bad_fluxcal: [Case; 3] = [
        (
            "bias",
            Box::new(|v: &mut Value| v["fluxgate_calibration"]["bias_nt"][2] = (-38736.0).into()),
            "z bias is -38736 nT",
        ),
        (
            "scale",
            Box::new(|v: &mut Value| v["fluxgate_calibration"]["matrix"][2][2] = 1.75.into()),
            "z scale is 1.7500",
        ),
        (
            "left-handed",
            Box::new(|v: &mut Value| {
                let m = &mut v["fluxgate_calibration"]["matrix"];
                let x = m[0][0].as_f64().unwrap();
                m[0][0] = (-x).into();
            }),
            "left-handed frame",
        ),
    ];
    for (what, edit, said) in bad_fluxcal {
        let mut v = old.clone();
        edit(&mut v);
        write(edited, &v);
        let e = run_err(bin().arg("upload").arg(edited));
        assert!(
            e.contains(said) && e.contains("not uploaded"),
            "{what}: {e}"
        );
    }
}
