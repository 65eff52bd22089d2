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

#[test]
#[ignore = "prints default magnitudes over seeds"]
fn magnitudes_over_seeds() {
    for seed in 1..=6 {
        let out = simulate_detailed(&SimConfig {
            seed,
            ..SimConfig::default()
        })
        .unwrap();
        let tr = &out.trace;
        let seg = tr.text_col("segment").unwrap();
        let ti = tr.col("truth_interference").unwrap();
        let cal: Vec<usize> = (0..tr.len())
            .filter(|&i| seg[i].starts_with("cal_"))
            .collect();
        let ptp = |v: &mut dyn Iterator<Item = f64>| {
            let v: Vec<f64> = v.collect();
            v.iter().cloned().fold(f64::MIN, f64::max) - v.iter().cloned().fold(f64::MAX, f64::min)
        };
        let p_int = ptp(&mut cal.iter().map(|&i| ti[i]));
        let p_eddy = ptp(&mut cal
            .iter()
            .filter(|&&i| !seg[i].ends_with("_level"))
            .map(|&i| {
                let b = out.truth.b_body_nt[i];
                (b / b.norm()).dot(&(out.truth.m_s * out.truth.db_body_nt_s[i]))
            }));
        let an = tr.col("truth_anomaly").unwrap();
        let g: Vec<f64> = an.windows(2).map(|w| (w[1] - w[0]) / 6.0).collect();
        let gr = (g.iter().map(|x| x * x).sum::<f64>() / g.len() as f64).sqrt();
        println!("seed {seed}: interference p-p {p_int:.1} nT, eddy p-p {p_eddy:.2} nT, anomaly p-p {:.2} nT, grad rms {gr:.4} nT/m, |K| {:.1}", ptp(&mut an.iter().cloned()), out.truth.k_nt.norm());
    }
}

#[test]
#[ignore = "prints anomaly magnitudes for survey presets"]
fn survey_anomaly_magnitudes() {
    for (preset, alt) in [
        (GeologyPreset::Strong, 150.0),
        (GeologyPreset::Strong, 300.0),
        (GeologyPreset::Moderate, 300.0),
        (GeologyPreset::Moderate, 1000.0),
    ] {
        for seed in 1..=3 {
            let cfg = SimConfig {
                seed,
                flight: FlightKind::Survey,
                survey_lines: 3,
                line_length_m: 5000.0,
                survey_altitude_m: alt,
                geology: Geology::preset(preset),
                ..SimConfig::default()
            };
            let tr = simulate(&cfg).unwrap();
            let an = tr.col("truth_anomaly").unwrap();
            let g: Vec<f64> = an.windows(2).map(|w| (w[1] - w[0]) / 6.0).collect();
            let gr = (g.iter().map(|x| x * x).sum::<f64>() / g.len() as f64).sqrt();
            let gm = g.iter().map(|x| x.abs()).fold(0.0, f64::max);
            let p = an.iter().cloned().fold(f64::MIN, f64::max)
                - an.iter().cloned().fold(f64::MAX, f64::min);
            println!("{preset:?} {alt} m seed {seed}: anomaly p-p {p:.1} nT, grad rms {gr:.3} max {gm:.3} nT/m");
        }
    }
}
