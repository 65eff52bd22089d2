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
