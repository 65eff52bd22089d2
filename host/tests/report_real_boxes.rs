//! `magcomp report` on real data, opened in headless Chromium: the two calibration boxes of
//! SGL 2020 flight 1002 (`../shared/reference-data/sgl2020-flt1002-cal/`, as
//! `real_boxes.rs` reads them: no labels, no positions, 10 Hz rows, t = i/10, the anomaly
//! modelled in time at 60 m/s). The Kalman filter's page and Tolles–Lawson's must render
//! every plot with no page error and show the FOM table of the manoeuvres detected from the
//! fluxgate. Skips, saying so, where the shared data or Chromium are absent.

mod common;

use common::cli::{bin, run_ok_with_stderr, tmp};
use common::{chromium_logged, CHROMIUM};
use std::path::{Path, PathBuf};

const FS_HZ: f64 = 10.0;

/// The boxes as a positionless CSV (`t,mag,flux_x,flux_y,flux_z` of `mag_4_uc`, `flux_d`).
fn boxes_csv(dir: &Path) -> Option<PathBuf> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/reference-data/sgl2020-flt1002-cal/flt1002_line1002.02.csv");
    let Ok(text) = std::fs::read_to_string(&path) else {
        eprintln!(
            "SKIPPED: {} is absent (shared reference data)",
            path.display()
        );
        return None;
    };
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next()?.split(',').collect();
    let col = |name: &str| header.iter().position(|c| *c == name).expect(name);
    let cols = [
        col("mag_4_uc"),
        col("flux_d_x"),
        col("flux_d_y"),
        col("flux_d_z"),
    ];
    let mut out = String::from("t,mag,flux_x,flux_y,flux_z\n");
    for (i, l) in lines.enumerate() {
        let v: Vec<&str> = l.split(',').collect();
        out.push_str(&format!("{}", i as f64 / FS_HZ));
        for &j in &cols {
            out.push(',');
            out.push_str(v[j]);
        }
        out.push('\n');
    }
    let csv = dir.join("boxes.csv");
    std::fs::write(&csv, out).expect("write boxes.csv");
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
        // Two boxes of four headings (`qc` finds these 8 legs), each with its manoeuvres:
        // one Σ row per heading.
        let headings = html.matches("<td>Σ</td>").count();
        assert_eq!(headings, 8, "{method}: headings in the FOM table");
        assert!(n >= headings, "{method}: {n} manoeuvres");
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
