//! `magcomp report` on real data, opened in headless Chromium: the two calibration boxes of
//! SGL 2020 flight 1002 (`data/reference/sgl2020-flt1002-cal/`, as
//! `real_boxes.rs` reads them: no labels, no positions, 10 Hz rows, t = i/10, the anomaly
//! modelled in time at 60 m/s). The Kalman filter's page and Tolles–Lawson's must render
//! every plot with no page error and show the FOM table of the manoeuvres detected from the
//! fluxgate. Skips, saying so, where the shared data or Chromium are absent.

mod common;
#[path = "common/real_boxes.rs"]
mod real_boxes_data;

use common::cli::{bin, run_ok_with_stderr, tmp};
use common::{chromium_logged, CHROMIUM};
use std::path::{Path, PathBuf};

/// The boxes as a positionless CSV (`t,mag,flux_x,flux_y,flux_z` of `mag_4_uc`, `flux_d`).
fn boxes_csv(dir: &Path) -> Option<PathBuf> {
    let b = real_boxes_data::boxes()?;
    let csv = dir.join("boxes.csv");
    magcomp::io::trace::write_trace(&csv, &b.trace(0..b.len(), "mag_4_uc", "flux_d"))
        .expect("write boxes.csv");
    Some(csv)
}

/// `N manoeuvres (` in the FOM section's paragraph.
fn manoeuvres_in(html: &str) -> usize {
    let at = html
        .find(" manoeuvres (")
        .expect("no FOM table paragraph on the page");
    let start = html[..at]
        .rfind(|c: char| !c.is_ascii_digit())
        .map_or(0, |k| k + 1);
    html[start..at].parse().expect("manoeuvre count")
}

#[test]
fn real_boxes_report_renders_in_headless_chromium() {
    let dir = tmp("report-real-boxes");
    let Some(csv) = boxes_csv(&dir) else { return };
    for method in ["kf", "tl"] {
        let out = dir.join(method);
        let (_, stderr) = run_ok_with_stderr(
            bin()
                .arg("report")
                .arg(&csv)
                .args(["--method", method, "--speed-mps", "60", "-o"])
                .arg(&out),
        );
        let page = out.join("index.html");
        let html = std::fs::read_to_string(&page).expect("page");
        let ids: Vec<&str> = html
            .match_indices("data-plot=\"")
            .map(|(k, m)| {
                let rest = &html[k + m.len()..];
                &rest[..rest.find('"').expect("id end")]
            })
            .collect();
        let n = manoeuvres_in(&html);
        println!("{method}: plots {ids:?}, {n} manoeuvres detected");
        for want in ["overlay-0", "fom", "coefficients"] {
            assert!(ids.contains(&want), "{method}: no plot '{want}'");
        }
        // Two boxes of four headings (`qc` finds these 8 legs), one Σ row per heading.
        let headings = html.matches("<td>Σ</td>").count();
        assert_eq!(headings, 8, "{method}: headings in the FOM table");
        // Each heading's pitch, roll and yaw sets (`qc::sets`): 24 on the two boxes.
        assert_eq!(n, 3 * headings, "{method}: {n} manoeuvres");
        assert!(html.contains("FOM table"), "{method}: no FOM table");
        assert!(
            !html.contains("<script"),
            "the page is meant to run no script"
        );

        if !Path::new(CHROMIUM).exists() {
            println!("SKIP the browser part: {CHROMIUM} not installed (apt-get install chromium)");
            continue;
        }
        let profile = dir.join(format!("profile-{method}"));
        std::fs::create_dir_all(&profile).expect("profile");
        let url = format!("file://{}", page.display());
        let run = chromium_logged(&["--dump-dom".into(), url], &profile)
            .expect("chromium --dump-dom timed out");
        assert!(run.status.success(), "chromium failed: {:?}", run.status);
        let dom = String::from_utf8_lossy(&run.stdout);
        let log = String::from_utf8_lossy(&run.stderr);
        let page_errors: Vec<&str> = log
            .lines()
            .filter(|l| l.contains(":CONSOLE") || l.contains("Uncaught"))
            .collect();
        assert!(page_errors.is_empty(), "{method}: {page_errors:?}");
        assert_eq!(
            dom.matches("class=\"plot\"").count(),
            ids.len(),
            "{method}: rendered SVG plots"
        );
        for id in &ids {
            assert!(
                dom.contains(&format!("data-plot=\"{id}\"")),
                "{method}: {id}"
            );
        }
        assert!(
            dom.contains("FOM table"),
            "{method}: FOM table not rendered"
        );
        if !stderr.is_empty() {
            println!("{method} stderr: {stderr}");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The number after `key` on the page (e.g. `; IR ` → 18.48).
fn number_after(html: &str, key: &str) -> f64 {
    let at = html
        .find(key)
        .unwrap_or_else(|| panic!("no '{key}' on the page"))
        + key.len();
    let s: String = html[at..]
        .chars()
        .take_while(|c| c.is_ascii_digit() || *c == '.' || *c == '-')
        .collect();
    s.parse()
        .unwrap_or_else(|_| panic!("'{key}' is followed by '{s}'"))
}

/// The QC sheet on each real box, as a survey company would sign it: box 1 calibrated (the
/// page without --coeffs), box 2 with box 1's coefficients (`--coeffs`). Each page carries
/// the file, sensor and window; a FOM table of 12 manoeuvres (4 headings × pitch, roll, yaw)
/// detected without labels, the compensated FOM below the uncompensated; the IR the CLI
/// prints (`calibrate`/`compensate --json`, one definition); the coefficients' calibrated σ
/// (the file's, not the filter's prior); the heading error, the scaled overlays and the
/// 4th-difference panel. Box 2's page is opened in headless Chromium.
#[test]
fn real_box_qc_sheets_carry_twelve_manoeuvres_and_the_clis_ir() {
    let dir = tmp("report-qc-sheet");
    let Some(b) = real_boxes_data::boxes() else {
        return;
    };
    let (box1, box2) = (dir.join("box1.csv"), dir.join("box2.csv"));
    let split = real_boxes_data::BOX1_ROWS;
    for (path, rows) in [(&box1, 0..split), (&box2, split..b.len())] {
        magcomp::io::trace::write_trace(path, &b.trace(rows, "mag_4_uc", "flux_d")).unwrap();
    }
    let coeffs = dir.join("kf.json");
    let json = |args: &[&std::ffi::OsStr]| -> serde_json::Value {
        serde_json::from_str(&common::cli::run_ok(bin().args(args))).expect("--json")
    };
    let cal = json(&[
        "calibrate".as_ref(),
        box1.as_os_str(),
        "--method".as_ref(),
        "kf".as_ref(),
        "--speed-mps".as_ref(),
        "60".as_ref(),
        "--json".as_ref(),
        "-o".as_ref(),
        coeffs.as_os_str(),
    ]);
    let applied = json(&[
        "compensate".as_ref(),
        box2.as_os_str(),
        "--coeffs".as_ref(),
        coeffs.as_os_str(),
        "--json".as_ref(),
        "-o".as_ref(),
        dir.join("box2-comp.csv").as_os_str(),
    ]);
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&coeffs).unwrap()).unwrap();
    let pages = [
        (
            "box 1",
            dir.join("r1"),
            vec!["--speed-mps", "60"],
            &box1,
            &cal,
            "t 0.0–649.9 s",
        ),
        (
            "box 2",
            dir.join("r2"),
            vec![
                "--coeffs",
                coeffs.to_str().unwrap(),
                "--d4-limit-nt",
                "0.02",
            ],
            &box2,
            &applied,
            "t 650.0–1290.0 s",
        ),
    ];
    for (what, out, extra, csv, cli, window) in &pages {
        run_ok_with_stderr(bin().arg("report").arg(csv).args(extra).arg("-o").arg(out));
        let html = std::fs::read_to_string(out.join("index.html")).unwrap();
        let name = csv.file_name().unwrap().to_str().unwrap();
        let title = &html[html.find("<h1>").unwrap()..html.find("</h1>").unwrap()];
        assert!(
            title.contains(name) && title.contains("mag") && title.contains(window),
            "{what}: title {title}"
        );
        assert_eq!(manoeuvres_in(&html), 12, "{what}");
        let (headings, kinds) = (
            html.matches("<td>Σ</td>").count(),
            ["pitch", "roll", "yaw"].map(|k| html.matches(&format!("<td>{k}</td>")).count()),
        );
        assert_eq!((headings, kinds), (4, [4, 4, 4]), "{what}: FOM rows");
        let uncompensated = number_after(&html, "Uncompensated ");
        let fom = number_after(&html, "nT, FOM ");
        let ir_page = number_after(&html, "; IR ");
        let ir_cli = cli["improvement_ratio"].as_f64().unwrap();
        println!(
            "{what}: FOM {fom} nT of {uncompensated} uncompensated, IR page {ir_page} / CLI {ir_cli:.4}"
        );
        assert!(
            fom < uncompensated / 5.0,
            "{what}: FOM {fom} vs {uncompensated}"
        );
        assert!(
            (ir_page - ir_cli).abs() < 0.006,
            "{what}: IR {ir_page} vs {ir_cli}"
        );
        assert_eq!(
            cli["fom_table"]["improvement_ratio"].as_f64(),
            Some(ir_cli),
            "{what}: the FOM table's IR is the summary's"
        );
        for id in ["qc-detrended", "qc-bandpassed", "qc-fourth-difference"] {
            assert!(
                html.contains(&format!("data-plot=\"{id}\"")),
                "{what}: {id}"
            );
        }
        for text in ["/ 16", "Reciprocal passes", "magcomp version", "SHA-256"] {
            assert!(html.contains(text), "{what}: no '{text}'");
        }
        // The file's calibrated σ, not the filter's ±200 nT prior.
        let c0 = &file["coefficients"][0];
        let sigma = format!(
            "{:.4} ± {:.4}",
            c0["value"].as_f64().unwrap(),
            c0["sigma"].as_f64().unwrap()
        );
        assert!(html.contains(&sigma), "{what}: no '{sigma}'");
        assert!(!html.contains("± 200.0000"), "{what}: prior σ shown");
    }
    let r2 = std::fs::read_to_string(pages[1].1.join("index.html")).unwrap();
    assert!(
        r2.contains("coefficients: file"),
        "box 2: no coefficient provenance"
    );
    assert!(
        r2.contains("within ±0.02 nT (%)"),
        "box 2: --d4-limit-nt not applied"
    );
    if Path::new(CHROMIUM).exists() {
        let profile = dir.join("profile");
        std::fs::create_dir_all(&profile).unwrap();
        let url = format!("file://{}", pages[1].1.join("index.html").display());
        let run = chromium_logged(&["--dump-dom".into(), url], &profile).expect("chromium");
        let dom = String::from_utf8_lossy(&run.stdout);
        assert!(run.status.success() && dom.contains("data-plot=\"qc-fourth-difference\""));
        assert_eq!(dom.matches("<td>yaw</td>").count(), 4);
    } else {
        println!("SKIP the browser part: {CHROMIUM} not installed");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
