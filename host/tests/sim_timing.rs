//! Timing of long simulations; run with `cargo test --release --test sim_timing -- --ignored --nocapture`.

use magcomp::sim::*;
use std::time::Instant;

#[test]
#[ignore = "timing only, run in release"]
fn timing_long_flights() {
    // 1 h at 10 Hz: a calibration + 14 survey lines of 10 km (≈ 60 min).
    let cfg = SimConfig {
        flight: FlightKind::CalibrationSurvey,
        survey_lines: 14,
        geology: Geology::preset(GeologyPreset::Moderate),
        max_duration_s: Some(3600.0),
        ..SimConfig::default()
    };
    let t0 = Instant::now();
    let tr = simulate(&cfg).unwrap();
    println!("1 h at 10 Hz: {} samples in {:?}", tr.len(), t0.elapsed());
    let cfg = SimConfig {
        sample_rate_hz: 1000.0,
        flight: FlightKind::CalibrationSurvey,
        survey_lines: 3,
        max_duration_s: Some(1200.0),
        ..SimConfig::default()
    };
    let t0 = Instant::now();
    let tr = simulate(&cfg).unwrap();
    println!(
        "20 min at 1 kHz: {} samples in {:?}",
        tr.len(),
        t0.elapsed()
    );
}
