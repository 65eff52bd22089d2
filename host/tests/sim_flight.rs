//! Flight geometry of the simulator: cloverleaf through one centre, manoeuvres within spec,
//! survey lines on heading and spacing, altitude swing, determinism, sample count.

use magcomp::sim::*;
use std::collections::BTreeSet;

fn local(tr: &magcomp::io::trace::Trace, fr: &LocalFrame) -> Vec<(f64, f64)> {
    let (lat, lon) = (tr.col("lat").unwrap(), tr.col("lon").unwrap());
    lat.iter()
        .zip(lon)
        .map(|(&a, &b)| fr.to_local(a, b))
        .collect()
}

fn indices(seg: &[String], name: &str) -> Vec<usize> {
    (0..seg.len()).filter(|&i| seg[i] == name).collect()
}

fn zero_crossings(v: &[f64]) -> usize {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    v.windows(2)
        .filter(|w| (w[0] - m).signum() != (w[1] - m).signum())
        .count()
}

#[test]
fn cloverleaf_geometry_and_manoeuvres() {
    let cfg = SimConfig::default();
    let out = simulate_detailed(&cfg).unwrap();
    let tr = &out.trace;
    let seg = tr.text_col("segment").unwrap();
    // Sample count = duration × rate.
    let dur: f64 = tr.meta("duration_s").unwrap().parse().unwrap();
    assert_eq!(tr.len(), (dur * 10.0).round() as usize);
    assert_eq!(tr.meta("sample_rate_hz"), Some("10"));
    // Segments: 12 manoeuvres + 4 level parts + turns.
    let names: BTreeSet<&str> = seg.iter().map(|s| s.as_str()).collect();
    let man: Vec<&&str> = names
        .iter()
        .filter(|s| s.ends_with("_roll") || s.ends_with("_pitch") || s.ends_with("_yaw"))
        .collect();
    assert_eq!(man.len(), 12, "{names:?}");
    for h in ["045", "135", "225", "315"] {
        for m in ["roll", "pitch", "yaw", "level"] {
            assert!(names.contains(format!("cal_h{h}_{m}").as_str()), "{h} {m}");
        }
    }
    assert!(names.contains("turn"));
    assert_eq!(names.len(), 17);
    // Every leg passes the centre: true track within 5 cm cross-track, GPS within 6 m.
    let fr = LocalFrame {
        lat0_deg: tr.meta("cal_centre_lat").unwrap().parse().unwrap(),
        lon0_deg: tr.meta("cal_centre_lon").unwrap().parse().unwrap(),
    };
    let gps = local(tr, &fr);
    let yaw = tr.col("yaw").unwrap();
    for h in ["045", "135", "225", "315"] {
        let idx = indices(seg, &format!("cal_h{h}_level"));
        let d_true = idx
            .iter()
            .map(|&i| out.truth.pos_ned_m[i].xy().norm())
            .fold(f64::MAX, f64::min);
        let d_gps = idx
            .iter()
            .map(|&i| (gps[i].0.powi(2) + gps[i].1.powi(2)).sqrt())
            .fold(f64::MAX, f64::min);
        // Samples are 6 m apart at 10 Hz: the nearest is ≤ 3 m away along track, while
        // the cross-track miss of the true line is only the integration error.
        let want_c = h.parse::<f64>().unwrap().to_radians();
        let cross = idx
            .iter()
            .map(|&i| {
                let p = out.truth.pos_ned_m[i];
                (p.x * want_c.sin() - p.y * want_c.cos()).abs()
            })
            .fold(0.0, f64::max);
        assert!(cross < 0.05, "h{h}: cross-track {cross} m");
        assert!(d_true < 3.1, "h{h}: true miss {d_true} m");
        assert!(d_gps < 6.0, "h{h}: GPS miss {d_gps} m");
        // Heading on the level part ≈ leg heading (± crab from 5 m/s wind).
        let mean_yaw = idx.iter().map(|&i| yaw[i]).sum::<f64>() / idx.len() as f64;
        let want: f64 = h.parse().unwrap();
        assert!((mean_yaw - want).abs() < 6.0, "h{h}: yaw {mean_yaw}");
    }
    // Manoeuvre amplitudes (half peak-to-peak) and periods.
    let (roll, pitch) = (tr.col("roll").unwrap(), tr.col("pitch").unwrap());
    for h in ["045", "135", "225", "315"] {
        for (m, col, lo, hi) in [
            ("roll", roll, 5.0, 10.0),
            ("pitch", pitch, 4.0, 7.0),
            ("yaw", yaw, 4.0, 7.0),
        ] {
            let v: Vec<f64> = indices(seg, &format!("cal_h{h}_{m}"))
                .iter()
                .map(|&i| col[i])
                .collect();
            let amp = (v.iter().cloned().fold(f64::MIN, f64::max)
                - v.iter().cloned().fold(f64::MAX, f64::min))
                / 2.0;
            assert!((lo..hi).contains(&amp), "h{h} {m}: amplitude {amp}");
            let period = 2.0 * v.len() as f64 * 0.1 / zero_crossings(&v) as f64;
            assert!((4.0..8.0).contains(&period), "h{h} {m}: period {period}");
        }
    }
    // Turns are banked (coordinated): a 3 °/s turn at 60 m/s needs ~18° of bank.
    let max_bank = roll.iter().map(|r| r.abs()).fold(0.0, f64::max);
    assert!((15.0..22.0).contains(&max_bank), "bank {max_bank}");
}

#[test]
fn deterministic_per_seed() {
    let cfg = SimConfig {
        max_duration_s: Some(120.0),
        ..SimConfig::default()
    };
    let a = simulate(&cfg).unwrap();
    let b = simulate(&cfg).unwrap();
    assert_eq!(a, b);
    let c = simulate(&SimConfig { seed: 2, ..cfg }).unwrap();
    assert_ne!(a.col("mag"), c.col("mag"));
    assert_ne!(a.meta("truth_K_nt"), c.meta("truth_K_nt"));
}

#[test]
fn survey_lines_heading_spacing_and_swing() {
    let cfg = SimConfig {
        flight: FlightKind::Survey,
        survey_lines: 4,
        line_length_m: 3000.0,
        line_spacing_m: 150.0,
        line_heading_deg: 0.0,
        survey_altitude_m: 400.0,
        altitude_swing_m: 100.0,
        ..SimConfig::default()
    };
    let out = simulate_detailed(&cfg).unwrap();
    let tr = &out.trace;
    let seg = tr.text_col("segment").unwrap();
    let (vn, ve) = (tr.col("vn").unwrap(), tr.col("ve").unwrap());
    let mut east = Vec::new();
    for k in 0..4 {
        let idx = indices(seg, &format!("line_{}", 1001 + k));
        assert!(!idx.is_empty(), "line {k} missing");
        let want = if k % 2 == 0 { 0.0 } else { 180.0 };
        for &i in &idx {
            let c = ve[i].atan2(vn[i]).to_degrees().rem_euclid(360.0);
            let d = (c - want + 180.0).rem_euclid(360.0) - 180.0;
            assert!(d.abs() < 0.5, "line {k}: course {c}");
        }
        let e = idx.iter().map(|&i| out.truth.pos_ned_m[i].y).sum::<f64>() / idx.len() as f64;
        east.push(e);
        // Line length ≈ 3000 m.
        let len = idx.len() as f64 * 0.1 * 60.0;
        assert!((len - 3000.0).abs() < 10.0, "line length {len}");
    }
    for w in east.windows(2) {
        assert!((w[1] - w[0] - 150.0).abs() < 0.5, "spacing {}", w[1] - w[0]);
    }
    assert!(indices(seg, "line_1005").is_empty());
    // Altitude swing: ±100 m around 400 m, climb ≤ 5 m/s.
    let h: Vec<f64> = out.truth.pos_ned_m.iter().map(|p| -p.z).collect();
    let amp = (h.iter().cloned().fold(f64::MIN, f64::max)
        - h.iter().cloned().fold(f64::MAX, f64::min))
        / 2.0;
    assert!((85.0..=100.5).contains(&amp), "swing {amp}");
    let vd = tr.col("vd").unwrap();
    assert!(vd.iter().all(|v| v.abs() < 5.5));
}

#[test]
fn combined_flight_and_rate() {
    let cfg = SimConfig {
        flight: FlightKind::CalibrationSurvey,
        survey_lines: 2,
        line_length_m: 2000.0,
        sample_rate_hz: 20.0,
        ..SimConfig::default()
    };
    let tr = simulate(&cfg).unwrap();
    let seg = tr.text_col("segment").unwrap();
    assert!(seg.iter().any(|s| s == "cal_h315_yaw"));
    assert!(seg.iter().any(|s| s == "line_1002"));
    let alt = tr.col("alt").unwrap();
    let line: Vec<f64> = (0..tr.len())
        .filter(|&i| seg[i] == "line_1001")
        .map(|i| alt[i])
        .collect();
    let mean = line.iter().sum::<f64>() / line.len() as f64;
    assert!((mean - 300.0).abs() < 5.0, "survey altitude {mean}");
    let t = tr.col("t").unwrap();
    assert!((t[1] - t[0] - 0.05).abs() < 1e-12);
    // The 2700 m descent peaks at 6 m/s (spiralling over the cloverleaf if needed), and
    // does not make the transit absurdly long.
    let vd = tr.col("vd").unwrap();
    let max_vd = (0..tr.len())
        .filter(|&i| !seg[i].starts_with("cal_"))
        .map(|i| vd[i].abs())
        .fold(0.0, f64::max);
    assert!((5.0..6.5).contains(&max_vd), "descent rate {max_vd}");
    let dur: f64 = tr.meta("duration_s").unwrap().parse().unwrap();
    assert!(dur < 2400.0, "combined flight lasts {dur} s");
}

#[test]
fn geometry_variants_are_flyable() {
    let variants = [
        SimConfig {
            cal_headings_deg: vec![0.0, 90.0, 180.0, 270.0],
            ..SimConfig::default()
        },
        SimConfig {
            cal_headings_deg: vec![30.0, 210.0],
            turn_rate_deg_s: 1.5,
            speed_mps: 90.0,
            ..SimConfig::default()
        },
        SimConfig {
            flight: FlightKind::Survey,
            line_spacing_m: 100.0,
            line_heading_deg: 45.0,
            survey_lines: 6,
            ..SimConfig::default()
        },
        SimConfig {
            flight: FlightKind::CalibrationSurvey,
            survey_offset_m: [-3000.0, -500.0],
            cal_altitude_m: 1000.0,
            survey_altitude_m: 1200.0,
            line_spacing_m: 300.0,
            speed_mps: 40.0,
            ..SimConfig::default()
        },
    ];
    for cfg in variants {
        let out = simulate_detailed(&SimConfig {
            max_duration_s: Some(30.0),
            ..cfg.clone()
        })
        .unwrap_or_else(|e| panic!("{e:#} for {cfg:?}"));
        let plan = &out.truth.plan;
        // Pieces are contiguous in time.
        for w in plan.pieces.windows(2) {
            assert!((w[0].t0_s + w[0].dur_s - w[1].t0_s).abs() < 1e-9);
        }
        assert_eq!(out.trace.len(), 30 * 10);
    }
}
