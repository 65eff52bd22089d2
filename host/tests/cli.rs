//! The `magcomp` command as a user runs it: simulate → calibrate → compensate, the JSON
//! contract, rows in = rows out, and clear errors on bad input.

mod common;

use common::cli::{bin, data_rows, run_err, run_ok, run_ok_with_stderr, simulate, tmp};
use std::path::Path;

#[test]
fn simulate_calibrate_compensate_json_contract() {
    let d = tmp("contract");
    let trace = simulate(&d, &[]);
    let rows_in = data_rows(&trace);
    let coeffs = d.join("coeffs.json");
    run_ok(bin().args(["calibrate"]).arg(&trace).arg("-o").arg(&coeffs));
    let cf: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&coeffs).unwrap()).unwrap();
    let list = cf["coefficients"].as_array().unwrap();
    assert_eq!(list.len(), 16, "tl16 has 16 coefficients");
    for c in list {
        assert!(c["value"].as_f64().unwrap().is_finite());
        let s = c["sigma"].as_f64().unwrap();
        assert!(s > 0.0 && s < 100.0, "1σ {s}");
    }
    let predicted = cf["predicted_error_nt"]
        .as_f64()
        .expect("predicted_error_nt");
    assert!(predicted > 0.0 && predicted < 0.2, "predicted {predicted}");
    // The covariance travels too (what `--coeffs` predicts a new flight's error with); its
    // diagonal is the 1σ column.
    let covariance = cf["covariance"].as_array().expect("covariance");
    assert_eq!(covariance.len(), 16);
    for (i, row) in covariance.iter().enumerate() {
        let s = list[i]["sigma"].as_f64().unwrap();
        let var = row[i].as_f64().unwrap();
        assert!(
            (var.sqrt() - s).abs() <= 1e-6 * s,
            "diagonal {i}: {var} vs σ {s}"
        );
    }
    for method in ["kf", "tl"] {
        let out = d.join(format!("out-{method}.csv"));
        let stdout = run_ok(
            bin()
                .args(["compensate"])
                .arg(&trace)
                .args(["--method", method, "--json", "--out"])
                .arg(&out),
        );
        let j: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
        // "residual" is the diagnosis's one-step innovation; the compensated signal's rms in
        // the manoeuvre band has its own key, and a summary with the old key still reads.
        assert!(j.get("residual_rms_nt").is_none(), "{j}");
        let band_rms = j["compensated_band_rms_nt"].as_f64().unwrap();
        let old = stdout.replace("\"compensated_band_rms_nt\"", "\"residual_rms_nt\"");
        let s: magcomp::calibration::summary::Summary = serde_json::from_str(old.trim()).unwrap();
        assert_eq!(s.compensated_band_rms_nt, band_rms);
        assert_eq!(s.samples, rows_in);
        for key in [
            "model",
            "method",
            "samples",
            "compensated_band_rms_nt",
            "improvement_ratio",
            "fom_nt",
            "error_rms_nt",
        ] {
            assert!(!j[key].is_null(), "{method}: missing {key} in {j}");
        }
        assert_eq!(j["samples"].as_u64().unwrap() as usize, rows_in);
        assert_eq!(data_rows(&out), rows_in, "rows in = rows out");
        let header = std::fs::read_to_string(&out)
            .unwrap()
            .lines()
            .find(|l| !l.starts_with('#'))
            .unwrap()
            .to_string();
        assert!(header.starts_with("t,mag,interference,compensated"));
        if method == "kf" {
            // Then `igrf` and the carried input columns (docs/trace-format.md).
            assert!(
                header.starts_with("t,mag,interference,compensated,anomaly,innovation,flags,igrf"),
                "{header}"
            );
            // The filter's own figure for the calibration: the estimation error beyond the
            // model floor should be of its size.
            let predicted = j["predicted_error_nt"]
                .as_f64()
                .expect("predicted_error_nt");
            let (err, floor) = (
                j["error_rms_nt"].as_f64().unwrap(),
                j["oracle_floor_nt"].as_f64().unwrap(),
            );
            let excess = (err * err - floor * floor).max(0.0).sqrt();
            println!("kf: predicted {predicted:.4} nT, error beyond the floor {excess:.4} nT");
            assert!(
                (0.3..=4.0).contains(&(excess / predicted)),
                "predicted {predicted} vs {excess}"
            );
        }
        let err = j["error_rms_nt"].as_f64().unwrap();
        println!("{method}: error {err:.4} nT, FOM {}", j["fom_nt"]);
        assert!(err < 0.2, "{method} error {err}");
    }
    // Apply the calibration's coefficients to the same flight in survey mode.
    let out = d.join("applied.csv");
    let stdout = run_ok(
        bin()
            .args(["compensate"])
            .arg(&trace)
            .arg("--coeffs")
            .arg(&coeffs)
            .args(["--json", "--out"])
            .arg(&out),
    );
    let j: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert!(j["error_rms_nt"].as_f64().unwrap() < 0.05, "{j}");
    // The file's covariance over the same flight's attitudes gives the calibration's figure.
    let applied = j["predicted_error_nt"]
        .as_f64()
        .expect("predicted_error_nt");
    assert!(
        (applied - predicted).abs() <= 1e-6 * predicted,
        "{applied} vs {predicted}"
    );
}

#[test]
fn bad_input_gives_clear_errors() {
    let d = tmp("bad");
    let trace = simulate(&d, &["--max-duration-s", "60"]);
    let text = std::fs::read_to_string(&trace).unwrap();
    let out = d.join("o.csv");
    // A missing required column, named in the error.
    let no_flux = d.join("noflux.csv");
    let mut lines: Vec<String> = Vec::new();
    let mut idx = None;
    for l in text.lines() {
        if l.starts_with('#') {
            lines.push(l.into());
            continue;
        }
        let f: Vec<&str> = l.split(',').collect();
        let i = *idx.get_or_insert_with(|| f.iter().position(|c| *c == "flux_y").unwrap());
        lines.push(
            f.iter()
                .enumerate()
                .filter(|(k, _)| *k != i)
                .map(|(_, v)| *v)
                .collect::<Vec<_>>()
                .join(","),
        );
    }
    std::fs::write(&no_flux, lines.join("\n")).unwrap();
    let e = run_err(bin().arg("compensate").arg(&no_flux).arg("--out").arg(&out));
    assert!(e.contains("flux_y"), "{e}");
    // An unparsable number, with line and column.
    let bad_num = d.join("badnum.csv");
    let mut ls: Vec<String> = text.lines().map(String::from).collect();
    let first_data = ls.iter().position(|l| !l.starts_with('#')).unwrap() + 5;
    let mut f: Vec<String> = ls[first_data].split(',').map(String::from).collect();
    f[1] = "53x12.1".into();
    ls[first_data] = f.join(",");
    std::fs::write(&bad_num, ls.join("\n")).unwrap();
    let e = run_err(bin().arg("compensate").arg(&bad_num).arg("--out").arg(&out));
    assert!(
        e.contains("53x12.1") && e.contains(&format!(":{}", first_data + 1)),
        "{e}"
    );
    // Time going backwards.
    let back = d.join("back.csv");
    let mut ls: Vec<String> = text.lines().map(String::from).collect();
    let mut f: Vec<String> = ls[first_data].split(',').map(String::from).collect();
    f[0] = "0".into();
    ls[first_data] = f.join(",");
    std::fs::write(&back, ls.join("\n")).unwrap();
    let e = run_err(bin().arg("compensate").arg(&back).arg("--out").arg(&out));
    assert!(e.contains("increasing"), "{e}");
    // Unknown model term.
    let e = run_err(
        bin()
            .arg("compensate")
            .arg(&trace)
            .args(["--model", "tl16+wobble", "--out"])
            .arg(&out),
    );
    assert!(e.contains("wobble"), "{e}");
}

#[test]
fn nan_and_gaps_are_flagged_not_dropped() {
    let d = tmp("nan");
    let trace = simulate(&d, &["--max-duration-s", "120"]);
    let text = std::fs::read_to_string(&trace).unwrap();
    let mut ls: Vec<String> = text.lines().map(String::from).collect();
    let header_i = ls.iter().position(|l| !l.starts_with('#')).unwrap();
    let header: Vec<String> = ls[header_i].split(',').map(String::from).collect();
    let mag_i = header.iter().position(|c| c == "mag").unwrap();
    let fx_i = header.iter().position(|c| c == "flux_x").unwrap();
    // NaN magnetometer on 10 rows, empty fluxgate on 10 others.
    for k in 0..10 {
        let r = header_i + 200 + k;
        let mut f: Vec<String> = ls[r].split(',').map(String::from).collect();
        f[mag_i] = "nan".into();
        ls[r] = f.join(",");
        let r = header_i + 400 + k;
        let mut f: Vec<String> = ls[r].split(',').map(String::from).collect();
        f[fx_i] = String::new();
        ls[r] = f.join(",");
    }
    let p = d.join("holes.csv");
    std::fs::write(&p, ls.join("\n")).unwrap();
    let out = d.join("o.csv");
    run_ok(
        bin()
            .arg("compensate")
            .arg(&p)
            .args(["--realtime", "--out"])
            .arg(&out),
    );
    let rows: Vec<Vec<String>> = std::fs::read_to_string(&out)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .skip(1)
        .map(|l| l.split(',').map(String::from).collect())
        .collect();
    assert_eq!(
        rows.len(),
        ls.len() - header_i - 1,
        "every row has an output"
    );
    let flag = |r: usize| u16::from_str_radix(rows[r][6].trim_start_matches("0x"), 16).unwrap();
    for k in 0..10 {
        assert!(
            flag(199 + k) & magcomp_core::Flags::MAG_MISSING != 0,
            "row {}",
            199 + k
        );
        assert!(
            rows[199 + k][3].is_empty(),
            "no compensated value without mag"
        );
        assert!(flag(399 + k) & magcomp_core::Flags::FLUX_STALE != 0);
        assert!(
            !rows[399 + k][3].is_empty(),
            "held direction still compensates"
        );
    }
    // The compensated values stay finite around the holes.
    for r in rows.iter().skip(450).take(100) {
        let v: f64 = r[3].parse().unwrap();
        assert!(v.is_finite());
    }
}

#[test]
fn public_xyz_survey_data_with_a_column_map() {
    let xyz = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/reference-data/Flt1003_sample.xyz");
    if !xyz.exists() {
        eprintln!("SKIP: {} absent", xyz.display());
        return;
    }
    let d = tmp("xyz");
    // Coefficients from a simulated calibration, applied to the real survey rows.
    let trace = simulate(&d, &["--max-duration-s", "600"]);
    let coeffs = d.join("c.json");
    run_ok(bin().arg("calibrate").arg(&trace).arg("-o").arg(&coeffs));
    let out = d.join("xyz-out.csv");
    let stdout = run_ok(
        bin()
            .arg("compensate")
            .arg(&xyz)
            .args([
                "--map",
                "t=TIME,mag=UNCOMPMAG4,flux_x=FLUXB_X,flux_y=FLUXB_Y,flux_z=FLUXB_Z,lat=LAT,lon=LONG,alt=MSL-Z",
                "--coeffs",
            ])
            .arg(&coeffs)
            .args(["--json", "--out"])
            .arg(&out),
    );
    let j: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(j["samples"], 9);
    assert_eq!(data_rows(&out), 9);
    // A wrong map names the missing file column.
    let e = run_err(
        bin()
            .arg("compensate")
            .arg(&xyz)
            .args(["--map", "mag=NOPE", "--out"])
            .arg(&out),
    );
    assert!(e.contains("NOPE"), "{e}");
}

/// `calibrate --model MODEL` on the trace, then `compensate --coeffs` with the file it
/// wrote: the coefficient file as JSON and the applied run's error against truth (nT).
fn calibrate_then_apply(dir: &Path, trace: &Path, model: &str) -> (serde_json::Value, f64) {
    let coeffs = dir.join(format!("{model}.json"));
    run_ok(
        bin()
            .args(["calibrate", "--model", model])
            .arg(trace)
            .arg("-o")
            .arg(&coeffs),
    );
    let file = serde_json::from_str(&std::fs::read_to_string(&coeffs).unwrap()).unwrap();
    let stdout = run_ok(
        bin()
            .args(["compensate"])
            .arg(trace)
            .arg("--coeffs")
            .arg(&coeffs)
            .args(["--json", "--out"])
            .arg(dir.join("applied.csv")),
    );
    let j: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    (file, j["error_rms_nt"].as_f64().unwrap())
}

/// `fluxcal` end to end as a user runs it: calibrate on a flight whose fluxgate is off by
/// hundreds of nT, the coefficient file carries the fitted fluxgate calibration, and
/// applying that file with `--coeffs` uses it (error falls against the plain model's).
#[test]
fn fluxcal_calibration_travels_in_the_coefficient_file() {
    let d = tmp("fluxcal");
    let trace = simulate(&d, &["--hidden", "fluxcal"]);
    let mut errors = Vec::new();
    for model in ["tl16+field", "tl16+field+fluxcal"] {
        let (cf, error) = calibrate_then_apply(&d, &trace, model);
        let cal = &cf["fluxgate_calibration"];
        assert_eq!(cal.is_null(), model == "tl16+field", "{model}: {cal}");
        if !cal.is_null() {
            let bias = cal["bias_nt"].as_array().unwrap();
            assert!(
                bias.iter().any(|b| b.as_f64().unwrap().abs() > 100.0),
                "{cal}"
            );
        }
        errors.push(error);
    }
    println!(
        "fluxcal via --coeffs: error {:.4} → {:.4} nT",
        errors[0], errors[1]
    );
    assert!(errors[1] * 3.0 < errors[0], "{errors:?}");
}

/// `rate` on a survey with tie lines: `calibrate` stores the crossover fit in the
/// coefficient file, and `compensate --coeffs` applies it (simulate's `--tie-lines`).
#[test]
fn rate_crossover_fit_travels_in_the_coefficient_file() {
    let d = tmp("rate");
    let p = d.join("survey.csv");
    run_ok(
        bin()
            .args([
                "simulate",
                "--flight",
                "calibration+survey",
                "--seed",
                "2",
                "--cal-altitude-m",
                "300",
                "--survey-altitude-m",
                "300",
                "--cal-headings-deg",
                "0,90,180,270",
                "--geology",
                "strong",
                "--lines",
                "8",
                "--line-length-m",
                "5000",
                "--tie-lines",
                "5",
                "--survey-offset-m",
                "0,5000",
                "--gps-sigma-h-m",
                "0.3",
                "--hidden",
                "rate",
                "-o",
            ])
            .arg(&p),
    );
    let segments = std::fs::read_to_string(&p).unwrap();
    assert!(segments.contains(",tie_2005"), "tie lines are labelled");
    let mut errors = Vec::new();
    for model in ["tl16+field", "tl16+field+rate"] {
        let (cf, error) = calibrate_then_apply(&d, &p, model);
        let rc = &cf["rate_crossover"];
        assert_eq!(rc.is_null(), model == "tl16+field", "{model}: {rc}");
        if !rc.is_null() {
            assert_eq!(rc["applied"], true, "{rc}");
            assert!(rc["crossings"].as_u64().unwrap() >= 40, "{rc}");
            assert_eq!(rc["coefficients"].as_array().unwrap().len(), 6);
        }
        errors.push(error);
    }
    println!(
        "rate via --coeffs: error {:.4} → {:.4} nT",
        errors[0], errors[1]
    );
    assert!(
        errors[1] <= 0.1 && errors[1] * 3.0 < errors[0],
        "{errors:?}"
    );
}

/// `calibrate` says when the flight left the compensation undetermined, from the filter's
/// own covariance (no truth): a cloverleaf at 150 m over strong geology (predicted
/// 0.21 nT; the error against the truth is 0.12 nT) warns, the 3000 m one does not.
#[test]
fn calibrate_warns_when_the_flight_left_the_interference_undetermined() {
    let d = tmp("warn");
    let calibrate = |name: &str, extra: &[&str]| -> (String, f64) {
        let trace = d.join(format!("{name}.csv"));
        run_ok(
            bin()
                .args(["simulate", "--seed", "2", "-o"])
                .arg(&trace)
                .args(extra),
        );
        let coeffs = d.join(format!("{name}.json"));
        let (_, stderr) =
            run_ok_with_stderr(bin().arg("calibrate").arg(&trace).arg("-o").arg(&coeffs));
        let cf: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&coeffs).unwrap()).unwrap();
        (
            stderr,
            cf["predicted_error_nt"]
                .as_f64()
                .expect("predicted_error_nt"),
        )
    };
    let (low_stderr, low_predicted) = calibrate(
        "low",
        &[
            "--cal-altitude-m",
            "150",
            "--altitude-swing-m",
            "100",
            "--geology",
            "strong",
        ],
    );
    let (high_stderr, high_predicted) = calibrate("high", &[]);
    println!("predicted: 150 m strong {low_predicted:.4} nT, 3000 m {high_predicted:.4} nT");
    assert!(low_predicted > 0.1, "{low_predicted}");
    assert!(
        low_stderr.contains("warning: the predicted error of this calibration is")
            && low_stderr.contains("fly the pattern higher"),
        "{low_stderr}"
    );
    assert!(high_predicted < 0.01, "{high_predicted}");
    assert!(!high_stderr.contains("warning"), "{high_stderr}");
}

/// `--tl-ridge 0` is TL18-OLS: the coefficient file records λ = 0, and on a simulated
/// calibration its error against truth differs from MagNav's ridge fit (the ridge
/// biases the badly determined directions); a negative λ is refused by name.
#[test]
fn tl_ridge_zero_is_least_squares() {
    let d = tmp("tl-ridge");
    let trace = simulate(&d, &[]);
    let mut errors = Vec::new();
    for ridge in [None, Some("0")] {
        let coeffs = d.join(format!("tl-{}.json", ridge.unwrap_or("default")));
        let mut c = bin();
        c.arg("calibrate")
            .arg(&trace)
            .args(["--method", "tl", "-o"])
            .arg(&coeffs);
        if let Some(r) = ridge {
            c.args(["--tl-ridge", r]);
        }
        run_ok(&mut c);
        let cf: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&coeffs).unwrap()).unwrap();
        let lambda = cf["tl_config"]["lambda"].as_f64().unwrap();
        assert_eq!(lambda, if ridge.is_some() { 0.0 } else { 0.001 });
        let stdout = run_ok(
            bin()
                .arg("compensate")
                .arg(&trace)
                .arg("--coeffs")
                .arg(&coeffs)
                .args(["--json", "-o"])
                .arg(d.join("out.csv")),
        );
        let j: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
        errors.push(j["error_rms_nt"].as_f64().unwrap());
    }
    println!(
        "TL18 ridge {:.4} nT, TL18-OLS {:.4} nT",
        errors[0], errors[1]
    );
    assert!(errors[1] < 0.2, "TL18-OLS error {}", errors[1]);
    assert!((errors[0] - errors[1]).abs() > 1e-4, "{errors:?}");
    let e = run_err(
        bin()
            .arg("calibrate")
            .arg(&trace)
            .args(["--method", "tl", "--tl-ridge", "-1", "-o"])
            .arg(d.join("bad.json")),
    );
    assert!(e.contains("--tl-ridge"), "{e}");
}

/// `compensate --realtime --survey-from T`: the operator's `MODE,SURVEY` at T replayed. No
/// record well before T is in survey mode and every record from T on is (the switch lands
/// on the sample the filter is at, which the centred derivative outputs a sample later);
/// without `--realtime` it is refused.
#[test]
fn realtime_switches_to_survey_mode_where_told() {
    let d = tmp("survey-from");
    let flight = simulate(&d, &[]);
    let out = d.join("rt.csv");
    run_ok(
        bin()
            .arg("compensate")
            .arg(&flight)
            .args(["--realtime", "--survey-from", "400", "-o"])
            .arg(&out),
    );
    let t = common::cli::csv_column(&out, "t");
    let text = std::fs::read_to_string(&out).unwrap();
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let j = header.iter().position(|h| *h == "flags").unwrap();
    let survey: Vec<bool> = lines
        .map(|l| {
            let f = l.split(',').nth(j).unwrap().trim_start_matches("0x");
            u16::from_str_radix(f, 16).unwrap() & magcomp_core::Flags::SURVEY_MODE != 0
        })
        .collect();
    assert_eq!(survey.len(), t.len());
    for (t, s) in t.iter().zip(&survey) {
        if *t >= 400.0 {
            assert!(s, "t {t}: not in survey mode");
        } else if *t < 399.0 {
            assert!(!s, "t {t}: in survey mode before the switch");
        }
    }
    let err = run_err(
        bin()
            .arg("compensate")
            .arg(&flight)
            .args(["--survey-from", "400", "-o"])
            .arg(d.join("post.csv")),
    );
    assert!(err.contains("--realtime"), "{err}");
}
