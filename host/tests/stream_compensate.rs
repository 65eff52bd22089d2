//! Streaming `compensate --coeffs` (host/src/stream) against the in-memory path on the
//! same simulated survey: the output files must be identical line for line (frames in =
//! frames out), with a scalar glitch, a bad fluxgate row, a bad latitude, a time gap, a run of missing
//! positions, an extra numeric and text column, the core field from the file or computed
//! from a date, KF and Tolles–Lawson, and a `--time` selection; and through the command,
//! glitches that meet (a row both a scalar and a fluxgate glitch, adjacent fluxgate
//! glitches, the first and last row), with the same warnings.
use magcomp::calibration::coefficients::{CoefficientFile, Method};
use magcomp::calibration::summary::{summarise, write_output_csv, Summary};
use magcomp::calibration::{compensate_trace, EstimatorSettings};
use magcomp::cli::args::TraceInput;
use magcomp::flight::input::take_rows;
use magcomp::io::trace::{write_trace, Trace};
use magcomp::sim::{simulate, FlightKind, SimConfig};
use magcomp::stream::StreamInput;
use std::path::{Path, PathBuf};

mod common;

fn est(method: Method) -> EstimatorSettings {
    EstimatorSettings {
        // The default model: its fluxgate calibration is applied row by row when streamed.
        model: magcomp::model::spec::DEFAULT_MODEL.into(),
        method,
        // Fixed σ1: the calibration here only has to produce coefficients, quickly.
        sigma1: Some(3e-7),
        ..Default::default()
    }
}

/// A folder under `target/tmp` (cargo's `CARGO_TARGET_TMPDIR`): the same name each run,
/// so runs overwrite, not accumulate.
fn dir(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("magcomp-stream-{name}"));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn coefficients(method: Method) -> CoefficientFile {
    let cal = simulate(&SimConfig {
        // The same aircraft as the survey (the seed draws its coefficients).
        seed: 8,
        ..SimConfig::default()
    })
    .unwrap();
    let (_, comp) = compensate_trace(&cal, &est(method), None, false).unwrap();
    comp.coefficients.unwrap()
}

/// The aircraft's survey: 10 Hz, two lines, 300 s (3,000 rows), no fault.
fn clean_survey() -> Trace {
    simulate(&SimConfig {
        seed: 8,
        flight: FlightKind::Survey,
        survey_lines: 2,
        max_duration_s: Some(300.0),
        ..SimConfig::default()
    })
    .unwrap()
}

/// A 10 Hz survey with the faults a real file has.
fn survey(with_igrf: bool) -> Trace {
    let t = clean_survey();
    let n = t.len();
    // A 3 s time gap (rows 1200..1230 dropped).
    let rows: Vec<usize> = (0..n).filter(|i| !(1200..1230).contains(i)).collect();
    let mut t = take_rows(&t, &rows);
    let n = t.len();
    let set = |t: &mut Trace, name: &str, f: &dyn Fn(usize, f64) -> f64| {
        let mut v = t.col(name).unwrap().to_vec();
        for (i, x) in v.iter_mut().enumerate() {
            *x = f(i, *x);
        }
        t.set_col(name, v);
    };
    set(&mut t, "mag", &|i, x| if i == 650 { x + 4000.0 } else { x });
    // A bad fluxgate row (issue 21 item 2): taken out and bridged in the stream as in memory.
    set(&mut t, "flux_z", &|i, x| if i == 2100 { 0.0 } else { x });
    set(&mut t, "lat", &|i, x| match i {
        900 => 95.0,
        1500..=1540 => f64::NAN,
        _ => x,
    });
    set(&mut t, "lon", &|i, x| {
        if (1500..=1540).contains(&i) {
            f64::NAN
        } else {
            x
        }
    });
    t.set_col(
        "cur_extra",
        (0..n).map(|i| (i % 17) as f64 * 0.25).collect(),
    );
    t.set_col(
        "line",
        (0..n)
            .map(|i| if i < 1800 { 1001.0 } else { 1002.0 })
            .collect(),
    );
    t.set_text_col(
        "note",
        (0..n)
            .map(|i| {
                if i % 500 == 0 {
                    format!("mark, {i}")
                } else {
                    String::new()
                }
            })
            .collect(),
    );
    if !with_igrf {
        t.numeric.retain(|(n, _)| n != "igrf");
    }
    t
}

fn in_memory(
    input: &TraceInput,
    est: &EstimatorSettings,
    c: &CoefficientFile,
    out: &Path,
) -> Summary {
    let trace = input.read().unwrap();
    let (flight, comp) = compensate_trace(&trace, est, Some(c), false).unwrap();
    let carried = magcomp::flight::input::carried_columns(&trace);
    write_output_csv(out, &flight, &comp, &carried).unwrap();
    summarise(&flight, &comp)
}

fn compare(a: &Path, b: &Path) -> usize {
    let a = std::fs::read_to_string(a).unwrap();
    let b = std::fs::read_to_string(b).unwrap();
    let (la, lb): (Vec<&str>, Vec<&str>) = (a.lines().collect(), b.lines().collect());
    assert_eq!(la.len(), lb.len(), "lines in memory vs streamed");
    for (i, (x, y)) in la.iter().zip(&lb).enumerate() {
        assert_eq!(x, y, "line {}", i + 1);
    }
    la.len()
}

fn check(
    name: &str,
    method: Method,
    with_igrf: bool,
    time: Option<&str>,
    lines: Option<&str>,
    xyz: bool,
) {
    let d = dir(name);
    let coeffs = coefficients(method);
    let trace = survey(with_igrf);
    let path = if xyz {
        let p = d.join("survey.xyz");
        write_xyz(&p, &trace);
        p
    } else {
        let p = d.join("survey.csv");
        write_trace(&p, &trace).unwrap();
        p
    };
    let mut input = TraceInput::new(&path);
    input.time = time.map(String::from);
    input.lines = lines.map(String::from);
    if !with_igrf {
        input.date = Some("2024-06-01".into());
    }
    let est = est(method);
    let mem = in_memory(&input, &est, &coeffs, &d.join("mem.csv"));
    let n_mem = mem.samples;
    let streamed = StreamInput {
        trace: &input.trace,
        map: input.map.as_deref(),
        lines: input.lines.as_deref(),
        time: input.time.as_deref(),
        date: input.date.as_deref(),
    };
    let s =
        magcomp::stream::compensate(&streamed, &est, &coeffs, &d.join("stream.csv"), true).unwrap();
    assert_eq!(s.samples, n_mem, "samples in memory vs streamed");
    let out_lines = compare(&d.join("mem.csv"), &d.join("stream.csv"));
    // Frames in = frames out: the header, two comment lines, one row per selected sample.
    assert_eq!(out_lines, n_mem + 3);
    if time.is_none() && lines.is_none() {
        assert_eq!(n_mem, trace.len());
    }
    let e = s.error_rms_nt.unwrap();
    // The figures a streamed run computes are the in-memory ones (running sums).
    let close = |a: Option<f64>, b: Option<f64>| match (a, b) {
        (Some(a), Some(b)) => (a - b).abs() <= 1e-9 * a.abs().max(1e-3),
        (a, b) => a.is_none() && b.is_none(),
    };
    assert!(
        close(s.error_rms_nt, mem.error_rms_nt),
        "{:?} {:?}",
        s.error_rms_nt,
        mem.error_rms_nt
    );
    assert!(
        close(s.predicted_error_nt, mem.predicted_error_nt),
        "{:?} {:?}",
        s.predicted_error_nt,
        mem.predicted_error_nt
    );
    if method == Method::Kf {
        assert!(s.predicted_error_nt.is_some());
    }
    eprintln!(
        "{name}: {n_mem} rows identical; streamed error vs truth {e:.4} nT, warnings {:?}",
        s.warnings
    );
    // The gap is in line 1001 and before t = 250 s.
    if lines.is_none() {
        assert!(
            s.warnings.iter().any(|w| w.contains("1 time gap")),
            "{:?}",
            s.warnings
        );
    }
    // The survey error stays what a calibration transferred to a survey gives.
    assert!(e < if method == Method::Kf { 0.03 } else { 0.1 }, "{e}");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn streamed_kf_survey_equals_in_memory() {
    check("kf", Method::Kf, true, None, None, false);
}

#[test]
fn streamed_kf_survey_with_computed_core_field_and_time_selection_equals_in_memory() {
    check("kf-igrf", Method::Kf, false, Some("20:250"), None, false);
}

#[test]
fn streamed_tl_survey_equals_in_memory() {
    check("tl", Method::Tl, true, None, None, false);
}

#[test]
fn streamed_line_selection_equals_in_memory() {
    // Line 1002 only: rows 1800.. (after the gap), the line column carried to the output.
    check("kf-lines", Method::Kf, true, None, Some("1002"), false);
}

/// Geosoft-style XYZ of the numeric columns: `/` header, `Line` separators, `*` missing.
fn write_xyz(path: &Path, t: &Trace) {
    use std::fmt::Write as _;
    let mut out = String::from("/ simulated survey\n/ ");
    let names: Vec<&str> = t.numeric.iter().map(|(n, _)| n.as_str()).collect();
    out.push_str(&names.join(" "));
    out.push('\n');
    let line = t.col("line").unwrap();
    for i in 0..t.len() {
        if i == 0 || line[i] != line[i - 1] {
            writeln!(out, "Line {}", line[i]).unwrap();
        }
        let row: Vec<String> = t
            .numeric
            .iter()
            .map(|(_, v)| {
                if v[i].is_finite() {
                    v[i].to_string()
                } else {
                    "*".into()
                }
            })
            .collect();
        writeln!(out, "{}", row.join(" ")).unwrap();
    }
    std::fs::write(path, out).unwrap();
}

#[test]
fn streamed_xyz_survey_equals_in_memory() {
    check("kf-xyz", Method::Kf, true, None, None, true);
}

#[test]
fn what_cannot_stream_says_why() {
    let mut c = coefficients(Method::Kf);
    let e = est(Method::Kf);
    assert!(c.fluxgate_calibration.is_some());
    assert!(magcomp::stream::unstreamable(Some(&c), &e, false).is_none());
    assert!(magcomp::stream::unstreamable(None, &e, false)
        .unwrap()
        .contains("calibrating"));
    assert!(magcomp::stream::unstreamable(Some(&c), &e, true)
        .unwrap()
        .contains("realtime"));
    c.model = "tl16+field+lag".into();
    assert!(magcomp::stream::unstreamable(Some(&c), &e, false)
        .unwrap()
        .contains("lag"));
}

/// Issue 21: the glitches where the stream's fluxgate bridge could part from memory's, in
/// one simulated survey (10 Hz, 3,000 rows; `flux_z` = 0 is a fluxgate glitch, +4000 nT a
/// scalar one): a fluxgate glitch in the first and in the last row; a row that is both a
/// scalar and a fluxgate glitch (400); two adjacent fluxgate glitches (700, 701); a
/// fluxgate glitch whose next finite row is another (1000, 1001 without a fluxgate,
/// 1002); a fluxgate glitch followed by a scalar glitch (1600, 1601); a fluxgate glitch
/// followed by more rows without a fluxgate than its bridge reaches (2200, 2201..2220).
/// Returns the trace, the scalar glitches and the fluxgate glitches.
fn coincident_glitches() -> (Trace, Vec<usize>, Vec<usize>) {
    let mut t = clean_survey();
    let n = t.len();
    let scalar = vec![400, 1601];
    let flux = vec![0, 400, 700, 701, 1000, 1002, 1600, 2200, n - 1];
    let missing = |i: usize| i == 1001 || (2201..=2220).contains(&i);
    let mut set = |name: &str, f: &dyn Fn(usize, f64) -> f64| {
        let v = t.col(name).unwrap().iter().enumerate();
        let v = v.map(|(i, x)| f(i, *x)).collect();
        t.set_col(name, v);
    };
    set("mag", &|i, x| {
        if scalar.contains(&i) {
            x + 4000.0
        } else {
            x
        }
    });
    for axis in ["flux_x", "flux_y", "flux_z"] {
        set(axis, &|i, x| if missing(i) { f64::NAN } else { x });
    }
    set("flux_z", &|i, x| if flux.contains(&i) { 0.0 } else { x });
    (t, scalar, flux)
}

/// The count a glitch warning on stderr gives (`FILE: N what`), 0 without one, and the
/// lines it lists.
fn warned(stderr: &str, what: &str) -> (usize, Vec<String>) {
    let Some(at) = stderr.find(what) else {
        return (0, Vec::new());
    };
    let count = stderr[..at].rsplit(": ").next().unwrap().trim();
    let listed = stderr[at..]
        .lines()
        .skip(1)
        .take_while(|l| l.starts_with("  line "))
        .map(|l| l.split(':').next().unwrap().trim().to_string())
        .collect();
    (count.parse().unwrap(), listed)
}

/// The data rows of two `compensate` outputs that differ, each with the largest
/// difference of its numeric cells (a NaN against a number counts as infinite).
fn differing_rows(a: &str, b: &str) -> Vec<(usize, f64)> {
    let rows = |s: &str| -> Vec<String> {
        let data = s.lines().filter(|l| !l.starts_with('#')).skip(1);
        data.map(String::from).collect()
    };
    let (ra, rb) = (rows(a), rows(b));
    assert_eq!(ra.len(), rb.len(), "rows in memory vs streamed");
    let cell = |c: &str| c.parse::<f64>().unwrap_or(f64::NAN);
    let gap = |x: f64, y: f64| match (x.is_nan(), y.is_nan()) {
        (true, true) => 0.0,
        (false, false) => (x - y).abs(),
        _ => f64::INFINITY,
    };
    let mut out = Vec::new();
    for (i, (x, y)) in ra.iter().zip(&rb).enumerate() {
        if x != y {
            let cells = x.split(',').zip(y.split(','));
            let d = cells
                .map(|(p, q)| gap(cell(p), cell(q)))
                .fold(0.0, f64::max);
            out.push((i, d));
        }
    }
    out
}

/// Every case of [`coincident_glitches`], for the Kalman filter and Tolles–Lawson:
/// `compensate --stream never` and `--stream always` write the same file line for line,
/// every row in a row out, and warn of the same scalar and fluxgate glitches (all of
/// them).
#[test]
fn coincident_and_adjacent_glitches_stream_as_in_memory() {
    use common::cli::{bin, run_ok_with_stderr, tmp};
    let d = tmp("glitch-coincidence");
    let (trace, scalar, flux) = coincident_glitches();
    let input = d.join("survey.csv");
    write_trace(&input, &trace).unwrap();
    let mut failures = Vec::new();
    for method in [Method::Kf, Method::Tl] {
        let coeffs = d.join(format!("{}.json", method.name()));
        let text = magcomp::calibration::coefficients::to_sealed_json(&coefficients(method));
        std::fs::write(&coeffs, text.unwrap()).unwrap();
        let mut runs = Vec::new();
        for mode in ["never", "always"] {
            let out = d.join(format!("{}-{mode}.csv", method.name()));
            let mut cmd = bin();
            cmd.arg("compensate")
                .arg(&input)
                .arg("--coeffs")
                .arg(&coeffs);
            cmd.args(["--stream", mode, "-o"]).arg(&out);
            let (_, err) = run_ok_with_stderr(&mut cmd);
            assert!(!err.contains("not streamed"), "{mode}: {err}");
            runs.push((std::fs::read_to_string(&out).unwrap(), err));
        }
        let [(mem, mem_err), (streamed, str_err)] = <[_; 2]>::try_from(runs).unwrap();
        let rows_out = streamed.lines().filter(|l| !l.starts_with('#')).count() - 1;
        assert_eq!(rows_out, trace.len(), "{method:?}: rows in, rows out");
        for (what, expected) in [("scalar glitch", &scalar), ("fluxgate sample", &flux)] {
            let (m, s) = (warned(&mem_err, what), warned(&str_err, what));
            eprintln!("{method:?} {what}: in memory {m:?}, streamed {s:?}");
            if m != s || m.0 != expected.len() {
                failures.push(format!(
                    "{method:?} {what}: {m:?} in memory, {s:?} streamed"
                ));
            }
        }
        let differ = differing_rows(&mem, &streamed);
        // The rows a bridge moved, not the filter's state carried on by 1e-4 nT.
        let big: Vec<_> = differ.iter().filter(|(_, d)| *d >= 1e-3).collect();
        eprintln!(
            "{method:?}: {rows_out} rows, {} differ; by ≥ 1e-3 (data row, largest |Δ|): {big:?}",
            differ.len()
        );
        if !differ.is_empty() {
            failures.push(format!("{method:?}: {} rows differ: {big:?}", differ.len()));
        }
    }
    assert!(failures.is_empty(), "streamed ≠ in memory: {failures:#?}");
}
