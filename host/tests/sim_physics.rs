//! Physics checks of the flight simulator: exact modulus, dB/dt, Laplace consistency of the
//! anomaly, upward decay, sensor/noise bookkeeping, magnitudes of the defaults.

use magcomp::sim::*;
use nalgebra::{Matrix3, Vector3};

fn meta_vec(tr: &magcomp::io::trace::Trace, key: &str) -> Vector3<f64> {
    let v: Vec<f64> = serde_json::from_str(tr.meta(key).unwrap()).unwrap();
    Vector3::new(v[0], v[1], v[2])
}

fn meta_mat(tr: &magcomp::io::trace::Trace, key: &str) -> Matrix3<f64> {
    let v: Vec<Vec<f64>> = serde_json::from_str(tr.meta(key).unwrap()).unwrap();
    Matrix3::from_fn(|i, j| v[i][j])
}

fn std_dev(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
}

fn ptp(v: &[f64]) -> f64 {
    v.iter().cloned().fold(f64::MIN, f64::max) - v.iter().cloned().fold(f64::MAX, f64::min)
}

#[test]
fn dcm_matches_nalgebra_rotation() {
    let (r, p, y) = (0.3, -0.2, 2.1);
    let a = dcm_ned_to_body(r, p, y);
    let b = nalgebra::Rotation3::from_euler_angles(r, p, y)
        .matrix()
        .transpose();
    assert!((a - b).norm() < 1e-12);
    // Body x is forward: yaw 90° maps east (NED y) onto body x.
    let v = dcm_ned_to_body(0.0, 0.0, 90f64.to_radians()) * Vector3::new(0.0, 1.0, 0.0);
    assert!((v - Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-12);
}

#[test]
fn exact_modulus_and_column_bookkeeping() {
    let out = simulate_detailed(&SimConfig::default()).unwrap();
    let (tr, truth) = (&out.trace, &out.truth);
    let k = meta_vec(tr, "truth_K_nt");
    let l = meta_mat(tr, "truth_L");
    let m = meta_mat(tr, "truth_M_s");
    assert!((k - truth.k_nt).norm() < 1e-6 * k.norm());
    assert!((l - truth.l).norm() < 1e-6 * l.norm());
    assert!((m - truth.m_s).norm() < 1e-6 * m.norm());
    let ti = tr.col("truth_interference").unwrap();
    let (mag, igrf) = (tr.col("mag").unwrap(), tr.col("igrf").unwrap());
    let (an, di) = (
        tr.col("truth_anomaly").unwrap(),
        tr.col("truth_diurnal").unwrap(),
    );
    for i in (0..tr.len()).step_by(97) {
        let b = truth.b_body_nt[i];
        let db = truth.db_body_nt_s[i];
        let delta = k + l * b + m * db;
        let want = (b + delta).norm() - b.norm();
        assert!((want - ti[i]).abs() < 1e-6, "row {i}: {want} vs {}", ti[i]);
        // |B| in the body frame = main + anomaly + diurnal, all exact moduli.
        assert!((b.norm() - (igrf[i] + an[i] + di[i])).abs() < 1e-6);
    }
    // mag = igrf + anomaly + diurnal + interference + white noise (0.01 nT).
    let resid: Vec<f64> = (0..tr.len())
        .map(|i| mag[i] - igrf[i] - an[i] - di[i] - ti[i])
        .collect();
    let sd = std_dev(&resid);
    assert!((0.008..0.012).contains(&sd), "scalar noise sd {sd}");
    // The written attitude is the true one plus INS noise of a few hundredths of a degree.
    let roll = tr.col("roll").unwrap();
    let err: Vec<f64> = (0..tr.len())
        .map(|i| roll[i] - truth.att_rad[i][0].to_degrees())
        .collect();
    let e_sd = std_dev(&err);
    assert!((0.005..0.08).contains(&e_sd), "INS roll error sd {e_sd}");
}

#[test]
fn db_dt_is_exact_at_1khz() {
    // Lead-in, the whole roll manoeuvre and part of the level leg, at 1 kHz.
    let cfg = SimConfig {
        sample_rate_hz: 1000.0,
        max_duration_s: Some(35.0),
        ..SimConfig::default()
    };
    let out = simulate_detailed(&cfg).unwrap();
    let (b, db) = (&out.truth.b_body_nt, &out.truth.db_body_nt_s);
    assert_eq!(b.len(), 35_000);
    let mut worst: f64 = 0.0;
    let mut max_rate: f64 = 0.0;
    for i in 1..b.len() - 1 {
        let fd = (b[i + 1] - b[i - 1]) / 2e-3;
        max_rate = max_rate.max(db[i].norm());
        worst = worst.max((fd - db[i]).norm() / (db[i].norm() + 1.0));
    }
    // A 8° roll at 6 s gives thousands of nT/s in the body frame.
    assert!(max_rate > 3000.0, "max |dB/dt| {max_rate}");
    assert!(worst < 1e-3, "worst relative dB/dt error {worst}");
    // Above 20 Hz the environment field is Hermite-interpolated between 50 ms knots: the
    // anomaly column must still equal the exact dipole sum at the true position.
    let tr = &out.trace;
    let an = tr.col("truth_anomaly").unwrap();
    let igrf = tr.col("igrf").unwrap();
    let fr = out.truth.frame;
    let mut worst_nt: f64 = 0.0;
    for i in (0..tr.len()).step_by(37) {
        let p = out.truth.pos_ned_m[i];
        let (lat, lon) = fr.to_geo(p.x, p.y);
        let be = cfg.earth.field_ned_nt(lat, lon, -p.z);
        let exact = (be + out.truth.anomaly.field_ned_nt(&p)).norm() - be.norm();
        worst_nt = worst_nt.max((exact - an[i]).abs());
        worst_nt = worst_nt.max((be.norm() - igrf[i]).abs());
    }
    assert!(worst_nt < 1e-4, "interpolated field error {worst_nt} nT");
}

fn strong_world() -> SimOutput {
    let cfg = SimConfig {
        flight: FlightKind::Survey,
        geology: Geology::preset(GeologyPreset::Strong),
        survey_lines: 3,
        line_length_m: 3000.0,
        ..SimConfig::default()
    };
    simulate_detailed(&cfg).unwrap()
}

#[test]
fn anomaly_is_laplace_consistent() {
    let out = strong_world();
    let a = &out.truth.anomaly;
    assert!(a.sources.len() > 20);
    let h = 0.5;
    for k in 0..15 {
        let p = Vector3::new(
            -200.0 + 300.0 * k as f64,
            150.0 * (k % 4) as f64,
            -300.0 + 10.0 * k as f64,
        );
        let mut j = Matrix3::zeros();
        for c in 0..3 {
            let mut d = Vector3::zeros();
            d[c] = h;
            let col = (a.field_ned_nt(&(p + d)) - a.field_ned_nt(&(p - d))) / (2.0 * h);
            j.set_column(c, &col);
        }
        let scale = j.norm();
        let div = j.trace().abs();
        let curl = (j - j.transpose()).norm();
        assert!(scale > 1e-3, "gradient too small to test: {scale}");
        assert!(div < 1e-5 * scale, "div {div} vs |grad| {scale}");
        assert!(curl < 1e-5 * scale, "curl {curl} vs |grad| {scale}");
        let (_, g) = a.field_and_gradient(&p);
        assert!((g - j).norm() < 1e-5 * scale, "analytic gradient");
    }
}

#[test]
fn total_field_anomaly_decays_upward() {
    // One induced dipole 500 m deep: along the vertical through it the total-field anomaly
    // falls as r^-3 (the geometry is the same at every height).
    let be = EarthField::Dipole.field_ned_nt(45.3, -75.7, 0.0);
    let e = be.normalize();
    let a = Anomaly {
        sources: vec![Dipole {
            pos_ned_m: Vector3::new(0.0, 0.0, 500.0),
            moment_am2: e * 1e9,
        }],
    };
    let tmi = |h: f64| (be + a.field_ned_nt(&Vector3::new(0.0, 0.0, -h))).norm() - be.norm();
    let (t1, t2, t3) = (tmi(300.0), tmi(700.0), tmi(1500.0));
    let want12 = (800.0f64 / 1200.0).powi(3);
    let want13 = (800.0f64 / 2000.0).powi(3);
    assert!((t2 / t1 / want12 - 1.0).abs() < 0.02, "{t1} {t2}");
    assert!((t3 / t1 / want13 - 1.0).abs() < 0.02, "{t1} {t3}");
    // The full strong population: rms over a grid drops by > 3× from 300 m to 1500 m.
    let out = strong_world();
    let an = &out.truth.anomaly;
    let rms = |h: f64| {
        let mut s = 0.0;
        let mut n = 0.0;
        for i in 0..20 {
            for j in 0..20 {
                let p = Vector3::new(i as f64 * 150.0, j as f64 * 150.0, -h);
                let v = (be + an.field_ned_nt(&p)).norm() - be.norm();
                s += v * v;
                n += 1.0;
            }
        }
        (s / n).sqrt()
    };
    let (r300, r1500) = (rms(300.0), rms(1500.0));
    assert!(r1500 < r300 / 3.0, "rms {r300} at 300 m, {r1500} at 1500 m");
}

#[test]
fn default_magnitudes_are_realistic() {
    let out = simulate_detailed(&SimConfig::default()).unwrap();
    let tr = &out.trace;
    let seg = tr.text_col("segment").unwrap();
    let ti = tr.col("truth_interference").unwrap();
    let cal: Vec<f64> = (0..tr.len())
        .filter(|&i| seg[i].starts_with("cal_"))
        .map(|i| ti[i])
        .collect();
    let p = ptp(&cal);
    assert!(
        (15.0..300.0).contains(&p),
        "interference p-p over cloverleaf {p}"
    );
    // Eddy part eᵀM dB/dt during manoeuvres: a few tenths to a few nT.
    let eddy: Vec<f64> = (0..tr.len())
        .filter(|&i| seg[i].ends_with("_roll") || seg[i].ends_with("_pitch"))
        .map(|i| {
            let b = out.truth.b_body_nt[i];
            (b / b.norm()).dot(&(out.truth.m_s * out.truth.db_body_nt_s[i]))
        })
        .collect();
    let e = ptp(&eddy);
    assert!((0.2..6.0).contains(&e), "eddy p-p {e}");
    // Quiet geology at 3000 m: along-track gradient ~0.001–0.01 nT/m.
    let an = tr.col("truth_anomaly").unwrap();
    let g: Vec<f64> = an.windows(2).map(|w| (w[1] - w[0]) / 0.1 / 60.0).collect();
    let gs = std_dev(&g);
    assert!((3e-4..0.02).contains(&gs), "quiet gradient rms {gs}");
    // Strong geology at 300 m: tens–hundreds of nT, 0.05–5 nT/m.
    let s = strong_world();
    let an = s.trace.col("truth_anomaly").unwrap();
    let g: Vec<f64> = an.windows(2).map(|w| (w[1] - w[0]) / 0.1 / 60.0).collect();
    let gs = std_dev(&g);
    assert!(ptp(an) > 30.0, "strong anomaly p-p {}", ptp(an));
    assert!((0.05..5.0).contains(&gs), "strong gradient rms {gs}");
    // Fluxgate: within ~100 nT of the body-frame field (bias tens of nT + own field).
    let fx = s.trace.col("flux_x").unwrap();
    let d: Vec<f64> = (0..fx.len())
        .map(|i| fx[i] - s.truth.b_body_nt[i].x)
        .collect();
    let md = d.iter().map(|x| x.abs()).fold(0.0, f64::max);
    assert!(md < 250.0 && md > 1.0, "fluxgate error {md}");
}

#[test]
fn bad_configs_are_errors_not_panics() {
    let bad = [
        SimConfig {
            sample_rate_hz: 0.0,
            ..SimConfig::default()
        },
        SimConfig {
            speed_mps: f64::NAN,
            ..SimConfig::default()
        },
        SimConfig {
            cal_headings_deg: vec![],
            ..SimConfig::default()
        },
        SimConfig {
            altitude_swing_m: 3000.0,
            ..SimConfig::default()
        },
        SimConfig {
            decoys: vec!["mag".into()],
            ..SimConfig::default()
        },
        SimConfig {
            hidden: vec![parse_hidden("rate").unwrap(), parse_hidden("rate").unwrap()],
            ..SimConfig::default()
        },
    ];
    for c in bad {
        assert!(simulate(&c).is_err());
    }
}

#[test]
fn body_field_rebuilt_from_position_and_attitude() {
    // Without diurnal the external field is main + anomaly at the true position, rotated
    // by the true attitude; with the written (INS-noisy) attitude the interference agrees
    // to a few hundredths of a nT.
    let cfg = SimConfig {
        diurnal_nt: 0.0,
        ..SimConfig::default()
    };
    let out = simulate_detailed(&cfg).unwrap();
    let (tr, truth) = (&out.trace, &out.truth);
    let (k, l, m) = (truth.k_nt, truth.l, truth.m_s);
    let ti = tr.col("truth_interference").unwrap();
    let (r, p, y) = (
        tr.col("roll").unwrap(),
        tr.col("pitch").unwrap(),
        tr.col("yaw").unwrap(),
    );
    let mut worst_ins: f64 = 0.0;
    for i in (0..tr.len()).step_by(53) {
        let pos = truth.pos_ned_m[i];
        let (lat, lon) = truth.frame.to_geo(pos.x, pos.y);
        let b_ned = cfg.earth.field_ned_nt(lat, lon, -pos.z) + truth.anomaly.field_ned_nt(&pos);
        let [ra, pa, ya] = truth.att_rad[i];
        let b = dcm_ned_to_body(ra, pa, ya) * b_ned;
        assert!((b - truth.b_body_nt[i]).norm() < 1e-6, "row {i}");
        let bw = dcm_ned_to_body(r[i].to_radians(), p[i].to_radians(), y[i].to_radians()) * b_ned;
        let db = truth.db_body_nt_s[i];
        let ins = (bw + k + l * bw + m * db).norm() - bw.norm();
        worst_ins = worst_ins.max((ins - ti[i]).abs());
    }
    assert!(
        worst_ins < 0.2,
        "interference with INS attitude differs by {worst_ins} nT"
    );
}
