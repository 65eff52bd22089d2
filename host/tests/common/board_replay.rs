//! What the board-side replay tests share (`replay_lag.rs`, `replay_fluxtemp.rs`): the
//! trace as the board sees it, the board's code run over its capture, and a coefficient
//! file for the `replay` CLI.

use magcomp::board::capture::{trace_to_capture, CaptureOptions};
use magcomp::board::replay::{replay_capture, ReplayOptions};
use magcomp::flight::Flight;
use magcomp::io::trace::Trace;
use magcomp::model::spec::ModelSpec;
use magcomp_core::protocol::record::Record;
use magcomp_core::Flags;
use std::path::{Path, PathBuf};

/// The trace as the board sees it: no core-field model (as `replay_sim.rs`).
pub fn board_flight(trace: &Trace, spec: &ModelSpec) -> Flight {
    let mut t = trace.clone();
    t.numeric.retain(|(name, _)| name != "igrf");
    Flight::from_trace(&t, &spec.channels(), &spec.relative_channels()).expect("flight")
}

/// The board's code (`replay`, model `tl16+field`) over the trace's capture in survey mode
/// with these coefficients, `configure` adding what the board was told (τ, a correction):
/// one record per scalar sample, every one in survey mode.
pub fn survey_replay(
    trace: &Trace,
    coefficients: &[f32],
    configure: impl FnOnce(&mut ReplayOptions),
) -> Vec<Record> {
    let cap = trace_to_capture(trace, &CaptureOptions::default()).expect("capture");
    let mut o = ReplayOptions::new(ModelSpec::parse("tl16+field").expect("spec"));
    o.coefficients = Some(coefficients.to_vec());
    configure(&mut o);
    let mut recs = Vec::new();
    replay_capture(cap.as_slice(), &o, |r| {
        recs.push(*r);
        Ok(())
    })
    .expect("replay");
    assert_eq!(recs.len(), trace.len(), "one record per scalar sample");
    assert!(recs.iter().all(|r| r.flags.contains(Flags::SURVEY_MODE)));
    recs
}

/// The trace's capture written to `dir/flight.cap`.
pub fn write_capture(trace: &Trace, dir: &Path) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let cap = dir.join("flight.cap");
    std::fs::write(
        &cap,
        trace_to_capture(trace, &CaptureOptions::default()).unwrap(),
    )
    .unwrap();
    cap
}

/// A 16-coefficient `kf` file of `model` at 10 Hz, with `extra` JSON members (each ending
/// in a comma) before the coefficients; returns the coefficients too.
pub fn coefficient_file(model: &str) -> (Vec<f32>, impl Fn(&str) -> String) {
    let names = ModelSpec::parse(model).unwrap().coefficient_names();
    assert_eq!(names.len(), 16, "{model}: the term adds no filter state");
    let coefficients: Vec<f32> = (0..16).map(|i| (i as f32 - 7.5) * 0.25).collect();
    let entries: Vec<String> = names
        .iter()
        .zip(&coefficients)
        .map(|((n, _), v)| format!(r#"{{"name":"{n}","unit":"nT","value":{v},"sigma":0.1}}"#))
        .collect();
    let model = model.to_string();
    let file = move |extra: &str| {
        format!(
            r#"{{"format":"magcomp-coefficients-v1","model":"{model}","method":"kf","sample_rate_hz":10,{extra}"coefficients":[{}]}}"#,
            entries.join(",")
        )
    };
    (coefficients, file)
}

/// RMS about the mean of `est − truth` (the board's interference has an arbitrary level),
/// and over how many values.
pub fn rms_about_mean(diffs: impl Iterator<Item = f64>) -> (f64, usize) {
    let d: Vec<f64> = diffs.collect();
    let m = d.iter().sum::<f64>() / d.len() as f64;
    let rms = (d.iter().map(|v| (v - m).powi(2)).sum::<f64>() / d.len() as f64).sqrt();
    (rms, d.len())
}
