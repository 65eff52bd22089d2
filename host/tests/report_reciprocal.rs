//! Issue 20 item 6: the report's evidence section plots reciprocal passes over the same
//! ground. On a calibration + two survey lines flown back and forth 10 m apart over strong
//! geology, a hidden scalar lag shows as the shift that best aligns the two passes
//! (τ = shift / 2V), a clean flight's shift is near zero (to the ground geometry's ±0.05 s), the plotted values are the
//! report's numbers, and the page renders in headless Chromium. Run in release.
use magcomp::diagnose::{diagnose, DiagnoseOptions};
use magcomp::flight::Flight;
use magcomp::model::spec::ModelSpec;
use magcomp::report::flight_report::build_report;
use magcomp::report::reciprocal::{reciprocal_pairs, ReciprocalPair};
use magcomp::sim::{simulate, SimConfig};
use std::path::{Path, PathBuf};

mod common;
use common::diagnosis::reciprocal_flights;
use common::{chromium, CHROMIUM};

const MODEL: &str = "tl16+field";

fn config(lag_s: Option<f64>) -> SimConfig {
    reciprocal_flights(lag_s, 2)
}

/// The value of attribute `name` in the opening tag that starts at `tag`.
fn attr<'a>(tag: &'a str, name: &str) -> &'a str {
    let end = tag.find('>').expect("tag end");
    let key = format!(" {name}=\"");
    let at = tag[..end].find(&key).unwrap_or_else(|| panic!("no {name}")) + key.len();
    &tag[at..at + tag[at..].find('"').expect("quote")]
}

fn numbers(s: &str) -> Vec<f64> {
    s.split(',').map(|v| v.parse().expect("number")).collect()
}

/// The `<svg>` of plot `id` in `html`, up to its end.
fn svg<'a>(html: &'a str, id: &str) -> &'a str {
    let at = html
        .find(&format!("data-plot=\"{id}\""))
        .unwrap_or_else(|| panic!("plot {id} missing"));
    let start = html[..at].rfind("<svg").expect("svg");
    &html[start..start + html[start..].find("</svg>").expect("end")]
}

/// The series `name`'s (x, y) as written on its path.
fn series(svg: &str, name: &str) -> (Vec<f64>, Vec<f64>) {
    let at = svg
        .find(&format!("data-name=\"{name}\""))
        .unwrap_or_else(|| panic!("series {name} missing"));
    let tag = &svg[svg[..at].rfind('<').expect("tag")..];
    (numbers(attr(tag, "data-x")), numbers(attr(tag, "data-y")))
}

fn close(a: &[f64], b: &[f64], what: &str) {
    let (a, b): (Vec<f64>, Vec<f64>) = a
        .iter()
        .zip(b)
        .filter(|(x, y)| x.is_finite() || y.is_finite())
        .map(|(x, y)| (*x, *y))
        .unzip();
    assert!(!a.is_empty(), "{what}: nothing plotted");
    for (x, y) in a.iter().zip(&b) {
        assert!((x - y).abs() < 1.1e-3, "{what}: plotted {x} vs data {y}");
    }
}

/// The page for `cfg`, the pairs the library finds on the same compensation, and the html.
fn page_and_pairs(cfg: &SimConfig) -> (String, Vec<ReciprocalPair>) {
    let trace = simulate(cfg).expect("simulate");
    let spec = ModelSpec::parse(MODEL).expect("spec");
    let d = diagnose(&trace, &spec, &DiagnoseOptions::default()).expect("diagnose");
    let flight =
        Flight::from_trace(&trace, &spec.channels(), &spec.relative_channels()).expect("flight");
    let pairs = reciprocal_pairs(&flight, &d.run.compensated_nt).expect("a reciprocal pair");
    let page = build_report(&trace, &[spec], Some(&d), &Default::default()).expect("report");
    (page.to_html(), pairs)
}

/// The first (longest) pair's plots hold the pair's numbers; returns its τ (s).
fn plotted_tau_s(html: &str, p: &ReciprocalPair) -> f64 {
    let over = svg(html, "reciprocal-0-0");
    let (x, a) = series(over, "compensated, first");
    let (_, b) = series(over, "compensated, second");
    close(&x, &p.x_m, "ground");
    close(&a, &p.comp_a_nt, "first pass");
    close(&b, &p.comp_b_nt, "second pass");
    let diff = svg(html, "reciprocal-diff-0-0");
    let (_, d) = series(diff, "compensated");
    let a_minus_b: Vec<f64> = a.iter().zip(&b).map(|(p, q)| p - q).collect();
    close(&d, &a_minus_b, "difference = first − second as plotted");
    let num = |k: &str| -> f64 { attr(over, k).parse().expect(k) };
    let (shift_m, tau_s, v) = (
        num("data-shift-m"),
        num("data-tau-s"),
        num("data-speed-mps"),
    );
    assert!((shift_m - p.shift_m.expect("shift")).abs() < 1e-3);
    assert!((tau_s - shift_m / (2.0 * v)).abs() < 1e-3, "τ = shift / 2V");
    assert!((num("data-rms-comp-nt") - p.rms_comp_nt).abs() < 1e-3);
    // The chart's stated figures are in the text above it.
    assert!(
        html.contains(&format!("{:+.3} s at", p.tau_s.unwrap())),
        "τ stated"
    );
    println!(
        "pair {:.0}°/{:.0}°: {:.0} m shared, rms {:.2} → {:.3} nT, mean {:+.3} nT, shift {shift_m:+.2} m, V {v:.1} m/s, τ {tau_s:+.4} s",
        p.heading_a_deg,
        p.heading_b_deg,
        p.x_m.last().unwrap() - p.x_m[0],
        p.rms_raw_nt,
        p.rms_comp_nt,
        p.mean_comp_nt
    );
    tau_s
}

/// Seed 3 is the hardest of seeds 1–6 for the shift (measured with `measure_seeds`): the
/// ground itself sets it: `mag − true interference` aligns at −2.9 m (τ −0.025 s) on the
/// clean flight, with perfect positions too; most likely the two lines being 10 m apart
/// (the simulator's least spacing) under an anomaly striking obliquely across them. The same
/// seed with and without the lag has the same geometry, so their difference is the lag's.
#[test]
fn a_hidden_lag_shifts_the_reciprocal_passes_by_two_v_tau() {
    let lag_s = 0.2;
    let (html, pairs) = page_and_pairs(&config(Some(lag_s)));
    let tau_s = plotted_tau_s(&html, &pairs[0]);
    assert!(
        (tau_s - lag_s).abs() <= 0.05,
        "τ {tau_s:.4} s from the shift, hidden lag {lag_s} s"
    );
    // The clean flight aligns near zero (seeds 1–6: |τ| ≤ 0.041 s, |shift| ≤ 4.9 m).
    let (clean_html, clean_pairs) = page_and_pairs(&config(None));
    let clean_tau_s = plotted_tau_s(&clean_html, &clean_pairs[0]);
    assert!(
        clean_tau_s.abs() <= 0.05,
        "τ {clean_tau_s:.4} s on a clean flight"
    );
    // Seeds 1–6: the difference is 0.178–0.199 s for 0.2 s, 0.089–0.099 s for 0.1 s.
    assert!(
        (tau_s - clean_tau_s - lag_s).abs() <= 0.025,
        "lag flight {tau_s:.4} s − clean {clean_tau_s:.4} s vs {lag_s} s"
    );
    in_chromium(&html);
}

/// The reciprocal plots are drawn in a browser and keep their figures.
fn in_chromium(html: &str) {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("report-reciprocal");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("dir");
    let path = dir.join("index.html");
    std::fs::write(&path, html).expect("write");
    if !Path::new(CHROMIUM).exists() {
        println!("SKIP chromium part: {CHROMIUM} not installed (apt-get install chromium)");
        return;
    }
    let profile = dir.join(format!("profile-{}", std::process::id()));
    std::fs::create_dir_all(&profile).expect("profile");
    let url = format!("file://{}", path.display());
    let out = chromium(&["--dump-dom".into(), url], &profile).expect("dump-dom timed out");
    assert!(out.status.success());
    let dom = String::from_utf8_lossy(&out.stdout);
    let over = svg(&dom, "reciprocal-0-0");
    assert_eq!(
        attr(over, "data-tau-s"),
        attr(svg(html, "reciprocal-0-0"), "data-tau-s")
    );
    assert!(over.contains("class=\"series\""), "no line drawn");
    svg(&dom, "reciprocal-diff-0-0");
    let _ = std::fs::remove_dir_all(&profile);
}

/// The figures the tests state: τ per seed 1–6 with no lag, 0.1 s and 0.2 s, from the
/// compensated passes and from `mag − true interference` (the lag taken out with it: what
/// the ground geometry alone gives). `--ignored --nocapture`.
#[test]
#[ignore]
fn measure_seeds() {
    for lag in [None, Some(0.1), Some(0.2)] {
        for seed in 1..=6 {
            let cfg = SimConfig {
                seed,
                ..config(lag)
            };
            let trace = simulate(&cfg).expect("simulate");
            let spec = ModelSpec::parse(MODEL).expect("spec");
            let d = diagnose(&trace, &spec, &DiagnoseOptions::default()).expect("diagnose");
            let flight = Flight::from_trace(&trace, &spec.channels(), &spec.relative_channels())
                .expect("flight");
            let p = &reciprocal_pairs(&flight, &d.run.compensated_nt).expect("pair")[0];
            let ti = flight.truth_interference_nt.clone().expect("truth");
            let clean: Vec<f64> = flight.mag_nt.iter().zip(&ti).map(|(m, t)| m - t).collect();
            let q = &reciprocal_pairs(&flight, &clean).expect("pair")[0];
            println!(
                "lag {lag:?} seed {seed}: comp τ {:+.4} s (rms {:.3} nT), mag − true interference τ {:+.4} s",
                p.tau_s.unwrap_or(f64::NAN),
                p.rms_comp_nt,
                q.tau_s.unwrap_or(f64::NAN)
            );
        }
    }
}
