//! Streaming `compensate --coeffs` (host/src/stream) against the in-memory path on the
//! same simulated survey: the output files must be identical line for line (frames in =
//! frames out), with a scalar glitch, a bad fluxgate row, a bad latitude, a time gap, a run of missing
//! positions, an extra numeric and text column, the core field from the file or computed
//! from a date, KF and Tolles–Lawson, and a `--time` selection.
use magcomp::calibration::coefficients::{CoefficientFile, Method};
use magcomp::calibration::summary::{summarise, write_output_csv, Summary};
use magcomp::calibration::{compensate_trace, EstimatorSettings};
use magcomp::cli::args::TraceInput;
use magcomp::flight::input::take_rows;
use magcomp::io::trace::{write_trace, Trace};
use magcomp::sim::{simulate, FlightKind, SimConfig};
use magcomp::stream::StreamInput;
use std::path::{Path, PathBuf};

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

/// A 10 Hz survey with the faults a real file has.
fn survey(with_igrf: bool) -> Trace {
    let t = simulate(&SimConfig {
        seed: 8,
        flight: FlightKind::Survey,
        survey_lines: 2,
        max_duration_s: Some(300.0),
        ..SimConfig::default()
    })
    .unwrap();
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
