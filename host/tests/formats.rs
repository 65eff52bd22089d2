//! File formats as survey users have them (issue 11 item 3): a MagNav.jl HDF5 flight file
//! read through the CLI gives exactly what the same flight as CSV gives; Geosoft XYZ
//! output reads back to the CSV output's values; bad HDF5 files are clear errors.
#[cfg(feature = "hdf5")]
use hdf5_metno as h5;
use magcomp::io::trace::{read_trace, ColumnMap, Trace};
mod common;
use common::cli::{bin, tmp};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Mutex;

/// Held while an HDF5 file is open for writing and while a child is spawned: a child
/// forked by another test thread meanwhile would inherit the open file and its lock
/// (HDF5 locks files with flock), so the file would stay locked while that child runs.
static FORK_GUARD: Mutex<()> = Mutex::new(());

fn guard() -> std::sync::MutexGuard<'static, ()> {
    FORK_GUARD.lock().unwrap_or_else(|e| e.into_inner())
}

fn run(cmd: &mut Command) -> (bool, String, String) {
    let child = {
        let _g = guard();
        cmd.stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("run magcomp")
    };
    let out = child.wait_with_output().expect("run magcomp");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn run_ok(cmd: &mut Command) -> String {
    let (ok, o, e) = run(cmd);
    assert!(ok, "magcomp failed:\n{o}\n{e}");
    o
}

/// A short simulated survey (two 2 km lines) as CSV, and the trace.
fn simulated(dir: &Path) -> (PathBuf, Trace) {
    let csv = dir.join("sim.csv");
    run_ok(
        bin()
            .args(["simulate", "--flight", "survey", "--lines", "2"])
            .args(["--line-length-m", "2000", "--seed", "4", "-o"])
            .arg(&csv),
    );
    let t = read_trace(&csv, &ColumnMap::new()).unwrap();
    (csv, t)
}

#[cfg(feature = "hdf5")]
/// MagNav's names for the canonical columns (`--map magnav` maps them back).
fn magnav_name(canonical: &str) -> String {
    match canonical {
        "t" => "tt".into(),
        "mag" => "mag_1_uc".into(),
        "alt" => "utm_z".into(),
        "roll" | "pitch" | "yaw" => format!("ins_{canonical}"),
        c if c.starts_with("flux_") => format!("flux_a_{}", &c[5..]),
        c => c.into(),
    }
}

#[cfg(feature = "hdf5")]
/// Writes `trace` as a MagNav-layout HDF5 file: one root dataset per channel (fluxgate
/// chunked and gzip-compressed, as h5py/HDF5.jl may write them), `N` and `dt` scalars,
/// a 3×3×N `Cnb`, an integer `flight` channel and the text `segment` as strings.
/// `edit` may change a dataset before it is written (None drops it).
fn write_magnav_h5(path: &Path, trace: &Trace, edit: impl Fn(&str, Vec<f64>) -> Option<Vec<f64>>) {
    let _g = guard();
    let f = h5::File::create(path).unwrap();
    let n = trace.len();
    for (name, v) in &trace.numeric {
        let hname = magnav_name(name);
        let Some(v) = edit(&hname, v.clone()) else {
            continue;
        };
        if hname.starts_with("flux_") {
            f.new_dataset_builder()
                .chunk(256)
                .deflate(4)
                .with_data(&v)
                .create(hname.as_str())
                .unwrap();
        } else {
            f.new_dataset_builder()
                .with_data(&v)
                .create(hname.as_str())
                .unwrap();
        }
    }
    let flight: Vec<i32> = vec![1003; n];
    f.new_dataset_builder()
        .with_data(&flight)
        .create("flight")
        .unwrap();
    let seg: Vec<h5::types::VarLenUnicode> = trace
        .text_col("segment")
        .unwrap()
        .iter()
        .map(|s| s.parse().unwrap())
        .collect();
    f.new_dataset_builder()
        .with_data(&seg)
        .create("segment")
        .unwrap();
    f.new_dataset::<u64>()
        .create("N")
        .unwrap()
        .write_scalar(&(n as u64))
        .unwrap();
    f.new_dataset::<f64>()
        .create("dt")
        .unwrap()
        .write_scalar(&0.1)
        .unwrap();
    let cnb = vec![0.0f64; 9 * n];
    f.new_dataset::<f64>()
        .shape([3, 3, n])
        .create("Cnb")
        .unwrap()
        .write_raw(&cnb)
        .unwrap();
    f.close().unwrap();
}

#[cfg(feature = "hdf5")]
/// The columns of a `compensate` output file as text, by name.
fn columns(path: &Path) -> Vec<(String, Vec<String>)> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let names: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    let mut cols: Vec<(String, Vec<String>)> = names.into_iter().map(|n| (n, vec![])).collect();
    for l in lines {
        for (k, f) in l.split(',').enumerate() {
            cols[k].1.push(f.to_string());
        }
    }
    cols
}

#[cfg(feature = "hdf5")]
fn col<'a>(cols: &'a [(String, Vec<String>)], name: &str) -> &'a [String] {
    &cols.iter().find(|(n, _)| n == name).unwrap().1
}

#[cfg(feature = "hdf5")]
#[test]
fn a_magnav_hdf5_file_compensates_exactly_as_the_same_flight_in_csv() {
    let dir = tmp("h5");
    let (csv, trace) = simulated(&dir);
    let h5 = dir.join("Flt_sim.h5");
    write_magnav_h5(&h5, &trace, |_, v| Some(v));

    // Read back: every channel, renamed by the preset, values bit for bit.
    let back = read_trace(&h5, &ColumnMap::parse("magnav").unwrap()).unwrap();
    assert_eq!(back.len(), trace.len());
    for (name, v) in &trace.numeric {
        let b = back.col(name).unwrap_or_else(|| panic!("{name} not read"));
        assert!(
            v.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()),
            "{name} differs"
        );
    }
    assert_eq!(back.text_col("segment"), trace.text_col("segment"));
    assert_eq!(back.col("flight").unwrap()[0], 1003.0);
    assert_eq!(back.meta("dt"), Some("0.1"));
    assert!(back.meta("h5_skipped").unwrap().contains("Cnb (3×3×"));

    let (a, b) = (dir.join("from_csv.csv"), dir.join("from_h5.csv"));
    let sa = run_ok(
        bin()
            .arg("compensate")
            .arg(&csv)
            .args(["--json", "-o"])
            .arg(&a),
    );
    let sb = run_ok(
        bin()
            .arg("compensate")
            .arg(&h5)
            .args(["--map", "magnav", "--json", "-o"])
            .arg(&b),
    );
    let (ca, cb) = (columns(&a), columns(&b));
    assert_eq!(col(&ca, "t").len(), trace.len(), "frames in = frames out");
    for name in [
        "t",
        "mag",
        "interference",
        "compensated",
        "anomaly",
        "innovation",
        "flags",
    ] {
        assert_eq!(col(&ca, name), col(&cb, name), "{name}");
    }
    // The same fit: the summaries agree figure for figure.
    let (ja, jb): (serde_json::Value, serde_json::Value) = (
        serde_json::from_str(sa.trim()).unwrap(),
        serde_json::from_str(sb.trim()).unwrap(),
    );
    for k in [
        "compensated_band_rms_nt",
        "error_rms_nt",
        "predicted_error_nt",
        "samples",
    ] {
        assert_eq!(ja[k], jb[k], "{k}");
    }
    assert!(ja["error_rms_nt"].as_f64().unwrap() < 0.1, "{ja}");
    // The HDF5-only channel is carried to the output like any other.
    assert!(col(&cb, "flight").iter().all(|v| v == "1003"));
}

#[cfg(feature = "hdf5")]
#[test]
fn bad_hdf5_files_are_clear_errors() {
    let dir = tmp("badh5");
    let (_, trace) = simulated(&dir);
    let fails = |path: &Path, map: &str| -> String {
        let (ok, _, e) = run(bin()
            .arg("calibrate")
            .arg(path)
            .args(["--map", map, "--method", "tl", "-o"])
            .arg(dir.join("c.json")));
        assert!(!ok, "{} accepted", path.display());
        // The library's own diagnostic stack is not dumped on the user.
        assert!(!e.contains("HDF5-DIAG"), "{e}");
        e
    };

    let missing = dir.join("missing.h5");
    write_magnav_h5(&missing, &trace, |n, v| (n != "flux_a_z").then_some(v));
    let e = fails(&missing, "magnav");
    assert!(e.contains("'flux_z'") && e.contains("flux_y"), "{e}");

    let short = dir.join("short.h5");
    write_magnav_h5(&short, &trace, |n, mut v| {
        if n == "lat" {
            v.truncate(v.len() - 3);
        }
        Some(v)
    });
    let e = fails(&short, "magnav");
    assert!(
        e.contains("different lengths") && e.contains(&format!("'lat' has {}", trace.len() - 3)),
        "{e}"
    );

    let not = dir.join("not.h5");
    std::fs::write(&not, "t,mag\n1,2\n").unwrap();
    let e = fails(&not, "magnav");
    assert!(e.contains("not an HDF5 file"), "{e}");

    let unsorted = dir.join("unsorted.h5");
    write_magnav_h5(&unsorted, &trace, |n, mut v| {
        if n == "tt" {
            v.swap(10, 11);
        }
        Some(v)
    });
    let e = fails(&unsorted, "magnav");
    assert!(
        e.contains("row 12") && e.contains("strictly increasing"),
        "{e}"
    );

    // Without the map, the missing-column error points at the preset.
    let plain = dir.join("plain.h5");
    write_magnav_h5(&plain, &trace, |_, v| Some(v));
    let e = fails(&plain, "lat=lat");
    assert!(e.contains("--map magnav"), "{e}");
}

#[test]
fn xyz_output_reads_back_to_the_csv_output() {
    let dir = tmp("xyz");
    // A flight with a line column, so the XYZ has `Line` sections.
    let (csv, trace) = simulated(&dir);
    let mut with_line = trace.clone();
    let seg = trace.text_col("segment").unwrap().to_vec();
    let line: Vec<f64> = seg
        .iter()
        .map(|s| match s.strip_prefix("line_") {
            Some(n) => n.parse::<f64>().unwrap() + 0.01,
            None => 9001.01,
        })
        .collect();
    with_line.set_col("LINE", line.clone());
    let lined = dir.join("lined.csv");
    magcomp::io::trace::write_trace(&lined, &with_line).unwrap();

    let (oc, ox) = (dir.join("out.csv"), dir.join("out.xyz"));
    for o in [&oc, &ox] {
        run_ok(
            bin()
                .arg("compensate")
                .arg(&lined)
                .args(["--method", "kf", "-o"])
                .arg(o),
        );
    }
    let text = std::fs::read_to_string(&ox).unwrap();
    // One `Line` line per run of one line value.
    let runs = 1 + line.windows(2).filter(|w| w[0] != w[1]).count();
    assert_eq!(
        text.lines().filter(|l| l.starts_with("Line ")).count(),
        runs
    );
    assert!(text.starts_with("/ model: "), "{}", &text[..80]);

    let (c, x) = (
        read_trace(&oc, &ColumnMap::new()).unwrap(),
        read_trace(&ox, &ColumnMap::new()).unwrap(),
    );
    assert_eq!(x.len(), trace.len(), "frames in = frames out");
    assert_eq!(x.meta("model"), c.meta("model"));
    for (name, v) in &c.numeric {
        let w = x
            .col(name)
            .unwrap_or_else(|| panic!("{name} missing in XYZ"));
        for (i, (a, b)) in v.iter().zip(w).enumerate() {
            assert!(
                a == b || (a.is_nan() && b.is_nan()),
                "{name} row {i}: {a} vs {b}"
            );
        }
    }
    // Flags: hexadecimal in CSV, the same bits as a decimal channel in XYZ.
    let fc = c.text_col("flags").unwrap();
    let fx = x.col("flags").unwrap();
    for (a, b) in fc.iter().zip(fx) {
        assert_eq!(u32::from_str_radix(&a[2..], 16).unwrap() as f64, *b);
    }
    assert_eq!(x.text_col("segment"), c.text_col("segment"));

    // The simulator's trace itself, as XYZ, reads back equal to its CSV.
    let sx = dir.join("sim.xyz");
    run_ok(
        bin()
            .args(["simulate", "--flight", "survey", "--lines", "2"])
            .args(["--line-length-m", "2000", "--seed", "4", "-o"])
            .arg(&sx),
    );
    let back = read_trace(&sx, &ColumnMap::new()).unwrap();
    let orig = read_trace(&csv, &ColumnMap::new()).unwrap();
    assert_eq!(back.numeric, orig.numeric);
    assert_eq!(back.text, orig.text);
}
