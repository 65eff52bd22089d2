//! Renders a sample report in headless Chromium (when installed): screenshot for a person
//! to look at, and the DOM to check every plot is there. Skips with a message otherwise.
use magcomp::report::*;
use std::path::{Path, PathBuf};

mod common;
use common::{chromium, CHROMIUM};

fn sample_report() -> HtmlReport {
    // One hour at 10 Hz: slow diurnal-like drift, manoeuvre wiggles, a spike, a gap.
    let n = 36_000;
    let t_s: Vec<f64> = (0..n).map(|i| i as f64 * 0.1).collect();
    let mut raw_nt: Vec<f64> = t_s
        .iter()
        .map(|t| {
            52_000.0 + 15.0 * (t / 900.0).sin() + 8.0 * (t * 0.6).sin() * (1.0 + (t / 300.0).sin())
        })
        .collect();
    raw_nt[21_000] += 60.0;
    for v in &mut raw_nt[30_000..30_300] {
        *v = f64::NAN;
    }
    let comp_nt: Vec<f64> = t_s
        .iter()
        .zip(&raw_nt)
        .map(|(t, r)| r - 8.0 * (t * 0.6).sin() * (1.0 + (t / 300.0).sin()) + 0.5)
        .collect();
    let f_hz: Vec<f64> = (1..400).map(|i| i as f64 * 0.0125).collect();
    let psd_raw: Vec<f64> = f_hz
        .iter()
        .map(|f| 1.0 / (f * f + 0.01) + if (f - 0.6).abs() < 0.02 { 50.0 } else { 0.0 })
        .collect();
    let psd_comp: Vec<f64> = f_hz
        .iter()
        .map(|f| 1.0 / (f * f + 0.01) * 0.05 + 1e-3)
        .collect();
    let ts = Plot::new("time-series", "Scalar magnetometer, Flt 1003 (simulated)")
        .x_label("time since start (s)")
        .y_label("total field (nT)")
        .line("uncompensated", &t_s, &raw_nt)
        .series(
            Series::line("compensated", &t_s, &comp_nt)
                .color("#111111")
                .width_px(1.0),
        )
        .window(2000.0, 2200.0, "fluxgate dropout")
        .segment(0.0, 600.0, "cal_h000")
        .segment(600.0, 1200.0, "cal_h090")
        .segment(1200.0, 1800.0, "cal_h180")
        .segment(1800.0, 2400.0, "cal_h270")
        .segment(2400.0, 3600.0, "line_1010");
    let psd = Plot::new("psd", "Power spectral density")
        .log_log()
        .x_label("frequency (Hz)")
        .y_label("PSD (nT²/Hz)")
        .line("uncompensated", &f_hz, &psd_raw)
        .series(Series::line("compensated", &f_hz, &psd_comp).dash("6 3"));
    let fom = Plot::new("fom", "Figure of merit per manoeuvre (±1σ)")
        .y_label("FOM (nT)")
        .bars(
            &[
                "roll h000",
                "pitch h000",
                "yaw h000",
                "roll h090",
                "pitch h090",
                "yaw h090",
            ],
            &[1.8, 0.9, 1.2, 2.1, 1.1, 0.7],
            Some(&[0.2, 0.1, 0.3, 0.25, 0.15, 0.1]),
        );
    let coef = Plot::new("coefficients", "Tolles–Lawson coefficients")
        .y_label("value (nT)")
        .bars(
            &["p1", "p2", "p3", "i11", "i12", "i13", "i22", "i23", "i33"],
            &[12.0, -4.5, 30.2, 0.4, -0.1, 0.2, -0.3, 0.05, 0.6],
            Some(&[0.5, 0.4, 0.8, 0.05, 0.02, 0.04, 0.05, 0.01, 0.07]),
        )
        .bar_color("#2ca02c");
    HtmlReport::new("magcomp report <sample>")
        .paragraph("Sample report rendered by the test suite: the layout a geophysicist will see.")
        .section(
            Section::new("Summary")
                .paragraph("Compensation removed the manoeuvre noise; residual standard deviation below 1 nT.")
                .table(
                    &["quantity", "before (nT)", "after (nT)"],
                    &[
                        vec!["std dev".into(), "8.31".into(), "0.72".into()],
                        vec!["FOM".into(), "41.2".into(), "3.9".into()],
                    ],
                ),
        )
        .section(Section::new("Time series").plot(ts))
        .section(Section::new("Spectrum").plot_sized(psd, 700, 420))
        .section(Section::new("Calibration").plot(fom).plot(coef))
}

#[test]
fn sample_report_renders_in_headless_chromium() {
    let report = sample_report();
    let html = report.to_html();
    assert!(
        html.len() < 400_000,
        "a 1 h trace report stays small: {} bytes",
        html.len()
    );
    if !Path::new(CHROMIUM).exists() {
        println!("SKIP sample_report_renders_in_headless_chromium: {CHROMIUM} not installed (apt-get install chromium)");
        return;
    }
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("report-browser");
    let profile = dir.join(format!("profile-{}", std::process::id()));
    std::fs::create_dir_all(&profile).unwrap();
    let page = dir.join("sample-report.html");
    report.write(&page).unwrap();
    let url = format!("file://{}", page.display());

    let shot = dir.join("sample-report.png");
    let _ = std::fs::remove_file(&shot);
    let out = chromium(
        &[
            format!("--screenshot={}", shot.display()),
            "--window-size=1200,2000".into(),
            url.clone(),
        ],
        &profile,
    )
    .expect("chromium --screenshot timed out");
    assert!(
        out.status.success(),
        "chromium --screenshot failed: {:?}",
        out.status
    );
    let png = std::fs::read(&shot).expect("no screenshot written");
    assert!(
        png.starts_with(b"\x89PNG") && png.len() > 20_000,
        "screenshot looks empty ({} bytes)",
        png.len()
    );
    println!("screenshot: {}", shot.display());

    let out =
        chromium(&["--dump-dom".into(), url], &profile).expect("chromium --dump-dom timed out");
    assert!(
        out.status.success(),
        "chromium --dump-dom failed: {:?}",
        out.status
    );
    let dom = String::from_utf8_lossy(&out.stdout);
    for id in report.plot_ids() {
        assert!(
            dom.contains(&format!("data-plot=\"{id}\"")),
            "plot '{id}' missing from the rendered DOM"
        );
    }
    assert_eq!(
        dom.matches("class=\"plot\"").count(),
        report.plot_ids().len()
    );
    assert!(dom.contains("magcomp report &lt;sample&gt;"));
    let _ = std::fs::remove_dir_all(&profile);
}
