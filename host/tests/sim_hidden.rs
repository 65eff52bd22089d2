//! Hidden effects: each contributes what it says, only inside its window; decoys do nothing;
//! lag shifts the scalar in time; fluxcal leaves the scalar alone.

use magcomp::io::trace::Trace;
use magcomp::sim::*;

fn base_cfg() -> SimConfig {
    SimConfig {
        flight: FlightKind::Survey,
        geology: Geology::preset(GeologyPreset::Strong),
        survey_lines: 3,
        line_length_m: 4000.0,
        ..SimConfig::default()
    }
}

fn with(specs: &[&str], decoys: &[&str]) -> Trace {
    let cfg = SimConfig {
        hidden: specs.iter().map(|s| parse_hidden(s).unwrap()).collect(),
        decoys: decoys.iter().map(|s| s.to_string()).collect(),
        ..base_cfg()
    };
    simulate(&cfg).unwrap()
}

fn std_dev(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
}

fn inside(tr: &Trace, col: &str, w: (f64, f64)) -> (Vec<f64>, Vec<f64>) {
    let t = tr.col("t").unwrap();
    let c = tr.col(col).unwrap_or_else(|| panic!("missing {col}"));
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for i in 0..t.len() {
        if t[i] >= w.0 && t[i] < w.1 {
            a.push(c[i]);
        } else {
            b.push(c[i]);
        }
    }
    (a, b)
}

#[test]
fn scaled_effects_windowed_and_additive() {
    let w = (200.0, 700.0);
    let specs = [
        "current:cur_pump@200:700",
        "current_rate:cur_flap@200:700",
        "induced_high@200:700",
        "diurnal@200:700",
        "periodic:rpm_l@200:700",
        "rate",
    ];
    let plain = with(&[], &[]);
    let tr = with(&specs, &["cur_decoy", "volt_bus"]);
    for (col, lo, hi) in [
        ("truth_hidden_current_cur_pump", 1.0, 5.0),
        ("truth_hidden_current_rate_cur_flap", 1.0, 5.0),
        ("truth_hidden_induced_high", 1.0, 5.0),
        ("truth_hidden_diurnal", 1.0, 5.0),
        ("truth_hidden_periodic_rpm_l", 0.5, 2.5),
    ] {
        let (a, b) = inside(&tr, col, w);
        let sd = std_dev(&a);
        assert!((lo..hi).contains(&sd), "{col}: std {sd} in window");
        assert!(b.iter().all(|&x| x == 0.0), "{col}: nonzero outside window");
    }
    // `rate` is physical (not scaled): visible low over strong sources.
    let r = std_dev(tr.col("truth_hidden_rate").unwrap());
    assert!((0.05..10.0).contains(&r), "rate std {r}");
    // Auxiliary channels: currents within 0–20 A, rpm 2000–2400.
    for ch in ["cur_pump", "cur_flap", "cur_decoy", "volt_bus"] {
        let c = tr.col(ch).unwrap();
        assert!(c.iter().all(|&x| (-0.01..=20.0).contains(&x)), "{ch}");
        assert!(std_dev(c) > 1.0, "{ch} is flat");
    }
    let rpm = tr.col("rpm_l").unwrap();
    assert!(rpm.iter().all(|&x| (1950.0..2450.0).contains(&x)));
    assert!(tr.col("truth_hidden_cur_decoy").is_none());
    // Everything else is unchanged (independent random streams), so the differences are
    // exactly the hidden contributions; decoys add nothing.
    let (ti, ti0) = (
        tr.col("truth_interference").unwrap(),
        plain.col("truth_interference").unwrap(),
    );
    let (mag, mag0) = (tr.col("mag").unwrap(), plain.col("mag").unwrap());
    let (di, di0) = (
        tr.col("truth_diurnal").unwrap(),
        plain.col("truth_diurnal").unwrap(),
    );
    let aircraft = [
        "truth_hidden_current_cur_pump",
        "truth_hidden_current_rate_cur_flap",
        "truth_hidden_induced_high",
        "truth_hidden_periodic_rpm_l",
        "truth_hidden_rate",
    ];
    let hd = tr.col("truth_hidden_diurnal").unwrap();
    let base = tr.col("base").unwrap();
    let base0 = plain.col("base").unwrap();
    for i in 0..tr.len() {
        let sum: f64 = aircraft.iter().map(|c| tr.col(c).unwrap()[i]).sum();
        assert!((ti[i] - ti0[i] - sum).abs() < 2e-3, "row {i} interference");
        assert!((di[i] - di0[i] - hd[i]).abs() < 1e-6, "row {i} diurnal");
        assert!((mag[i] - mag0[i] - sum - hd[i]).abs() < 2e-3, "row {i} mag");
        // The base station records the micropulsations too.
        assert!((base[i] - base0[i] - hd[i]).abs() < 1e-3, "row {i} base");
    }
}

#[test]
fn lag_shifts_the_scalar_by_its_delay() {
    let plain = with(&[], &[]);
    let tr = with(&["lag:0.1"], &[]);
    let (m, m0) = (tr.col("mag").unwrap(), plain.col("mag").unwrap());
    let lag = tr.col("truth_hidden_lag").unwrap();
    let n = m.len();
    // At 10 Hz a 0.1 s lag is one sample: mag[k] = mag0[k-1] up to the white noise.
    let d_shift: Vec<f64> = (1..n).map(|k| m[k] - m0[k - 1]).collect();
    let d_same: Vec<f64> = (1..n).map(|k| m[k] - m0[k]).collect();
    let s_shift = std_dev(&d_shift);
    assert!(s_shift < 0.02, "shifted residual {s_shift}");
    assert!(std_dev(&d_same) > 20.0 * s_shift);
    // The contribution column is exactly that change (noise-free).
    for k in 1..n {
        assert!((m[k] - m0[k] - lag[k]).abs() < 1e-6);
    }
    // Windowed: zero outside.
    let tw = with(&["lag:0.1@300:400"], &[]);
    let (a, b) = inside(&tw, "truth_hidden_lag", (300.0, 400.0));
    assert!(b.iter().all(|&x| x == 0.0));
    assert!(std_dev(&a) > 0.1);
}

#[test]
fn fluxcal_changes_the_fluxgate_only() {
    let plain = with(&[], &[]);
    let tr = with(&["fluxcal@100:600"], &[]);
    assert_eq!(tr.col("mag"), plain.col("mag"));
    assert_eq!(
        tr.col("truth_interference"),
        plain.col("truth_interference")
    );
    let t = tr.col("t").unwrap();
    let (fx, fx0) = (tr.col("flux_x").unwrap(), plain.col("flux_x").unwrap());
    for i in 0..t.len() {
        let d = (fx[i] - fx0[i]).abs();
        if (100.0..600.0).contains(&t[i]) {
            assert!(d > 100.0, "fluxgate unchanged at t={}", t[i]);
        } else {
            assert!(d == 0.0);
        }
    }
    let (a, b) = inside(&tr, "truth_hidden_fluxcal", (100.0, 600.0));
    assert!(b.iter().all(|&x| x == 0.0));
    let rms = (a.iter().map(|x| x * x).sum::<f64>() / a.len() as f64).sqrt();
    // A few hundred nT of bias in 50 000 nT tilts e by ~0.3–0.5°: a few tenths of a nT of
    // Tolles–Lawson error with K ~ 50 nT.
    assert!((0.02..3.0).contains(&rms), "fluxcal rms {rms}");
}

/// The fluxgate drifts by `d·β` (d = temperature − its first value, β per axis within
/// K/4…K nT/°C) and nothing else changes; a decoy named like a temperature is one.
#[test]
fn fluxtemp_drifts_the_fluxgate_with_its_temperature_only() {
    let clean = with(&[], &[]);
    let ft = with(&["fluxtemp:temp_flux:2"], &["temp_cabin"]);
    assert_eq!(clean.col("mag").unwrap(), ft.col("mag").unwrap());
    let beta: Vec<f64> =
        serde_json::from_str(ft.meta("truth_fluxtemp_bias_nt_per_degc").unwrap()).unwrap();
    assert!(
        beta.iter().all(|b| (0.5..=2.0).contains(&b.abs())),
        "{beta:?}"
    );
    let temp = ft.col("temp_flux").unwrap();
    let span = temp.iter().copied().fold(f64::MIN, f64::max)
        - temp.iter().copied().fold(f64::MAX, f64::min);
    assert!((5.0..60.0).contains(&span), "temperature span {span} °C");
    for (ax, name) in ["flux_x", "flux_y", "flux_z"].iter().enumerate() {
        let (a, b) = (clean.col(name).unwrap(), ft.col(name).unwrap());
        // Recorded temperature carries 0.01 °C noise; its first sample is T(0) ± 0.01.
        let worst = (0..a.len())
            .map(|k| (b[k] - a[k] - beta[ax] * (temp[k] - temp[0])).abs())
            .fold(0.0, f64::max);
        assert!(worst < 0.1 * beta[ax].abs(), "{name}: {worst}");
    }
    let cabin = ft.col("temp_cabin").unwrap();
    assert!(cabin.iter().all(|t| (-40.0..60.0).contains(t)));
    assert!(std_dev(ft.col("truth_hidden_fluxtemp_temp_flux").unwrap()) > 0.0);
}
