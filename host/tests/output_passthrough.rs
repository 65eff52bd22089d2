//! Issue 22 item 4: `compensate`'s output carries the input. Every input column, mapped
//! (`lat`, `lon`, the fluxgate, …) and unmapped (a UTM column, a text label), goes
//! through row for row to CSV and XYZ; the input `mag`, which the output replaces, is
//! renamed `in_mag`, not dropped. Frames in = frames out, so t, lat, lon and the
//! compensated field are in one file: gridding needs no join.

mod common;

use common::cli::{bin, run_ok, simulate, tmp};
use magcomp::io::trace::{read_trace, write_trace, ColumnMap, Trace};
use std::path::Path;

/// The simulated flight under the names a survey file might use, with an unmapped numeric
/// and text column added: (the input as written, the `--map` that reads it).
fn survey_file(dir: &Path) -> (Trace, &'static str) {
    let sim = read_trace(&simulate(dir, &[]), &ColumnMap::new()).unwrap();
    let mut t = sim.clone();
    for (n, _) in t.numeric.iter_mut() {
        match n.as_str() {
            "mag" => *n = "MAG_TAIL".into(),
            "lat" => *n = "LAT".into(),
            "lon" => *n = "LONG".into(),
            _ => {}
        }
    }
    let n = t.len();
    let utm: Vec<f64> = (0..n).map(|i| 500_000.0 + 0.25 * i as f64).collect();
    t.numeric.push(("UTM_X".into(), utm));
    t.text.push((
        "crew_note".into(),
        (0..n).map(|i| format!("n{}", i % 7)).collect(),
    ));
    write_trace(&dir.join("survey.csv"), &t).unwrap();
    (t, "mag=MAG_TAIL,lat=LAT,lon=LONG")
}

fn compensate(dir: &Path, map: &str, out: &str) -> Trace {
    let o = dir.join(out);
    run_ok(
        bin()
            .arg("compensate")
            .arg(dir.join("survey.csv"))
            .args(["--map", map, "--method", "tl", "-o"])
            .arg(&o),
    );
    read_trace(&o, &ColumnMap::new()).unwrap()
}

fn check(input: &Trace, out: &Trace, what: &str) {
    assert_eq!(out.len(), input.len(), "{what}: frames in = frames out");
    // Gridding-ready: time, position and the compensated field in the one file.
    for c in ["t", "lat", "lon", "compensated"] {
        assert!(out.col(c).is_some(), "{what}: no {c}");
    }
    let same = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .all(|(x, y)| x == y || (x.is_nan() && y.is_nan()))
    };
    assert!(
        same(out.col("t").unwrap(), input.col("t").unwrap()),
        "{what}: t"
    );
    // Mapped columns under their canonical names, the replaced `mag` as `in_mag`, the
    // unmapped ones under their own: every value as read.
    for (o, i) in [
        ("lat", "LAT"),
        ("lon", "LONG"),
        ("alt", "alt"),
        ("flux_x", "flux_x"),
        ("in_mag", "MAG_TAIL"),
        ("UTM_X", "UTM_X"),
    ] {
        let a = out
            .col(o)
            .unwrap_or_else(|| panic!("{what}: {o} not carried"));
        assert!(
            same(a, input.col(i).unwrap()),
            "{what}: {o} differs from {i}"
        );
    }
}

#[test]
fn csv_output_carries_every_input_column_and_renames_the_replaced_mag() {
    let d = tmp("passthrough-csv");
    let (input, map) = survey_file(&d);
    let out = compensate(&d, map, "out.csv");
    check(&input, &out, "CSV");
    assert_eq!(out.text_col("crew_note"), input.text_col("crew_note"));
    // The output's own `mag` is the scalar as the filter used it, beside the input's.
    let (m, im) = (out.col("mag").unwrap(), out.col("in_mag").unwrap());
    assert!(m.iter().zip(im).all(|(a, b)| (a - b).abs() <= 5e-5));
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn xyz_output_carries_every_input_column() {
    let d = tmp("passthrough-xyz");
    let (input, map) = survey_file(&d);
    let out = compensate(&d, map, "out.xyz");
    check(&input, &out, "XYZ");
    std::fs::remove_dir_all(&d).ok();
}
