//! MagNav.jl conformance checks for classic Tolles–Lawson (data/reference/README.md).
//! Skips, with a printed message, where the reference data is absent.

use magcomp::estimate::tl::{self, TlConfig, TlTerms};
use magcomp::signal::bandpass;
use std::path::PathBuf;

fn ref_dir() -> Option<PathBuf> {
    let d = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../data/reference/magnav-tl");
    if d.join("raw_1000x6.csv").is_file() {
        Some(d)
    } else {
        eprintln!(
            "SKIP: MagNav reference data not found at {} — conformance check not run",
            d.display()
        );
        None
    }
}

/// Numeric rows of a CSV; a non-numeric first line is taken as the header.
fn read_csv(dir: &std::path::Path, name: &str) -> Vec<Vec<f64>> {
    let text = std::fs::read_to_string(dir.join(name)).unwrap();
    let mut rows = Vec::new();
    for (k, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let parsed: Result<Vec<f64>, _> = line.split(',').map(|v| v.trim().parse()).collect();
        match parsed {
            Ok(r) => rows.push(r),
            Err(_) if k == 0 => {}
            Err(e) => panic!("{name}:{}: {e}", k + 1),
        }
    }
    rows
}

struct Ref {
    flux: Vec<[f64; 3]>,
    mag_uc: Vec<f64>,
    mag_c: Vec<f64>,
    a: Vec<Vec<f64>>,
    a_f: Vec<Vec<f64>>,
    mag_f: Vec<f64>,
    coef: Vec<f64>,
}

fn load(dir: &std::path::Path) -> Ref {
    let raw = read_csv(dir, "raw_1000x6.csv");
    assert_eq!(raw.len(), 1000);
    Ref {
        flux: raw.iter().map(|r| [r[0], r[1], r[2]]).collect(),
        mag_uc: raw.iter().map(|r| r[3]).collect(),
        mag_c: raw.iter().map(|r| r[4]).collect(),
        a: read_csv(dir, "A_a_1000x18.csv"),
        a_f: read_csv(dir, "A_a_f_t_960x18.csv"),
        mag_f: read_csv(dir, "mag_1_uc_f_t_960.csv")
            .into_iter()
            .map(|r| r[0])
            .collect(),
        coef: read_csv(dir, "TL_a_1_18.csv")
            .into_iter()
            .flatten()
            .collect(),
    }
}

fn rms(x: impl Iterator<Item = f64> + Clone) -> f64 {
    let n = x.clone().count() as f64;
    (x.map(|v| v * v).sum::<f64>() / n).sqrt()
}

fn std(x: &[f64]) -> f64 {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    (x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
}

/// Zero-phase gain that maps the raw (trimmed, Hann-windowed) channels onto the
/// reference's filtered ones, from the cross-spectrum pooled over the 18 columns and the
/// scalar, at the FFT bin nearest each frequency (±1 bin).
fn implied_response(r: &Ref, freqs_hz: &[f64]) -> Vec<(f64, f64)> {
    use rustfft::{num_complex::Complex, FftPlanner};
    let n = 960;
    let fft = FftPlanner::<f64>::new().plan_fft_forward(n);
    let hann =
        |i: usize| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / (n - 1) as f64).cos();
    let mut pairs: Vec<(Vec<f64>, Vec<f64>)> = (0..18)
        .map(|j| {
            (
                r.a[20..980].iter().map(|row| row[j]).collect(),
                r.a_f.iter().map(|row| row[j]).collect(),
            )
        })
        .collect();
    pairs.push((r.mag_uc[20..980].to_vec(), r.mag_f.clone()));
    let mut sxy = vec![Complex::new(0.0, 0.0); n];
    let mut sxx = vec![0.0; n];
    for (x, y) in pairs {
        let mx = x.iter().sum::<f64>() / n as f64;
        let norm = x.iter().map(|v| (v - mx).powi(2)).sum::<f64>();
        let mut xc: Vec<Complex<f64>> = (0..n)
            .map(|i| Complex::new((x[i] - mx) * hann(i), 0.0))
            .collect();
        let mut yc: Vec<Complex<f64>> = (0..n).map(|i| Complex::new(y[i] * hann(i), 0.0)).collect();
        fft.process(&mut xc);
        fft.process(&mut yc);
        for k in 0..n {
            sxy[k] += yc[k] * xc[k].conj() / norm;
            sxx[k] += xc[k].norm_sqr() / norm;
        }
    }
    freqs_hz
        .iter()
        .map(|&f| {
            let k = (f / 10.0 * n as f64).round() as usize;
            let (num, den) = (k - 1..=k + 1).fold((Complex::new(0.0, 0.0), 0.0), |(a, b), j| {
                (a + sxy[j], b + sxx[j])
            });
            (f, (num / den).re)
        })
        .collect()
}

#[test]
fn check1_design_matrix_matches_magnav() {
    let Some(dir) = ref_dir() else { return };
    let r = load(&dir);
    let a = tl::design_matrix(&r.flux, &TlTerms::Tl18, tl::BT_SCALE_NT);
    assert_eq!(a.shape(), (1000, 18));
    let mut worst = 0.0f64;
    for j in 0..18 {
        // Relative to the column's scale, so near-zero entries don't blow the ratio up.
        let scale = rms(r.a.iter().map(|row| row[j]));
        for i in 0..1000 {
            worst = worst.max((a[(i, j)] - r.a[i][j]).abs() / scale);
        }
    }
    println!("check 1: design matrix max |A - A_a| / rms(column) = {worst:.3e}");
    assert!(
        worst < 1e-12,
        "design matrix differs from MagNav: {worst:e}"
    );
}

#[test]
fn check2_ridge_on_reference_filtered_arrays() {
    let Some(dir) = ref_dir() else { return };
    let r = load(&dir);
    let a = nalgebra::DMatrix::from_fn(960, 18, |i, j| r.a_f[i][j]);
    let sol = tl::ridge(&a, &r.mag_f, 0.001).unwrap();
    let num: f64 = sol
        .coefficients
        .iter()
        .zip(&r.coef)
        .map(|(c, e)| (c - e).powi(2))
        .sum();
    let den: f64 = r.coef.iter().map(|e| e * e).sum();
    let rel = (num / den).sqrt();
    let worst_elem = sol
        .coefficients
        .iter()
        .zip(&r.coef)
        .map(|(c, e)| ((c - e) / e).abs())
        .fold(0.0, f64::max);
    println!(
        "check 2: ridge ‖c - TL_a_1‖/‖TL_a_1‖ = {rel:.3e}, worst element relative {worst_elem:.3e}, cond(AᵀA+λI) = {:.3e}",
        sol.cond_normal
    );
    assert!(rel < 1e-9, "ridge differs from MagNav: {rel:e}");
}

#[test]
fn check3_full_pipeline_compensation() {
    let Some(dir) = ref_dir() else { return };
    let r = load(&dir);
    let cfg = TlConfig::default();

    // Filter match: our band-pass of A_a and mag_1_uc against MagNav's filtered arrays.
    let sos = bandpass::butterworth_bandpass(4, 0.1, 0.9, 10.0).unwrap();
    let mut worst_col = 0.0f64;
    for j in 0..18 {
        let col: Vec<f64> = r.a.iter().map(|row| row[j]).collect();
        let f = bandpass::filtfilt(&sos, &col).unwrap();
        let scale = rms(r.a_f.iter().map(|row| row[j]));
        let d = (0..960)
            .map(|i| (f[i + 20] - r.a_f[i][j]).abs())
            .fold(0.0, f64::max);
        worst_col = worst_col.max(d / scale);
    }
    let mf = bandpass::filtfilt(&sos, &r.mag_uc).unwrap();
    let mag_max = (0..960)
        .map(|i| (mf[i + 20] - r.mag_f[i]).abs())
        .fold(0.0, f64::max);
    let mag_rms = rms((0..960).map(|i| mf[i + 20] - r.mag_f[i]));
    println!(
        "check 3: filter match vs A_a_f_t / mag_1_uc_f_t: columns max |Δ|/rms(column) = {worst_col:.3e}; scalar max |Δ| = {mag_max:.3e} nT, rms Δ {mag_rms:.3e} nT (signal rms {:.3} nT)",
        rms(r.mag_f.iter().copied())
    );
    // Why they differ: the response the reference arrays imply (cross-spectrum of the
    // filtered against the raw arrays, all 19 channels) is a near brick wall, not a
    // 4-pole Butterworth passed twice.
    let resp = implied_response(&r, &[0.05, 0.5, 0.85, 0.96, 1.1, 1.5]);
    for (f, h) in resp {
        println!(
            "check 3: reference implied gain at {f:.2} Hz = {h:.4}; Butterworth filtfilt |H|² = {:.4}",
            sos.response(f, 10.0).norm_sqr()
        );
    }

    let fit = tl::fit(&r.flux, &r.mag_uc, &cfg, None).unwrap();
    let num: f64 = fit
        .coefficients
        .iter()
        .zip(&r.coef)
        .map(|(c, e)| (c - e).powi(2))
        .sum();
    let den: f64 = r.coef.iter().map(|e| e * e).sum();
    let comp = tl::compensate(&fit, &r.flux, &r.mag_uc).unwrap();
    let diff: Vec<f64> = comp.iter().zip(&r.mag_c).map(|(c, e)| c - e).collect();
    let sd = std(&diff);
    let max = diff.iter().map(|d| d.abs()).fold(0.0, f64::max);
    println!(
        "check 3: coefficients rel diff {:.3e}; compensated − mag_1_c: std {sd:.3e} nT, max |Δ| {max:.3e} nT ({} rows used)",
        (num / den).sqrt(),
        fit.rows_used
    );
    println!("{fit}");
    assert_eq!(fit.rows_used, 960);
    assert!(
        sd < 0.1,
        "compensated signal differs from MagNav: std {sd} nT"
    );
}

/// The Kalman filter on MagNav's positionless test vector (100 s at 10 Hz), with an assumed
/// ground speed: not worse than TL18 (the improvement ratio was 0.15 when the filter froze a
/// made-up position). Measured: KF IR 3.49, TL18 3.23; the fluxgate calibration is not
/// determined by 100 s and is left out with a warning.
#[test]
fn check4_kalman_filter_on_the_positionless_vector() {
    use magcomp::calibration::summary::summarise;
    use magcomp::calibration::{compensate_trace, EstimatorSettings, Method};
    use magcomp::flight::Flight;
    let Some(dir) = ref_dir() else { return };
    let r = load(&dir);
    let col = |k: usize| r.flux.iter().map(|f| f[k]).collect::<Vec<f64>>();
    let trace = magcomp::io::trace::Trace {
        numeric: vec![
            ("t".into(), (0..1000).map(|i| i as f64 / 10.0).collect()),
            ("mag".into(), r.mag_uc.clone()),
            ("flux_x".into(), col(0)),
            ("flux_y".into(), col(1)),
            ("flux_z".into(), col(2)),
        ],
        ..Default::default()
    };
    let ir = |method: Method| {
        let est = EstimatorSettings {
            method,
            speed_mps: Some(60.0),
            ..EstimatorSettings::default()
        };
        let (flight, comp): (Flight, _) = compensate_trace(&trace, &est, None, false).unwrap();
        (
            summarise(&flight, &comp).improvement_ratio.unwrap(),
            comp.warnings,
        )
    };
    let (kf, warnings) = ir(Method::Kf);
    let (tl, _) = ir(Method::Tl);
    println!("check 4: improvement ratio KF {kf:.3}, TL18 {tl:.3}");
    assert!(kf >= tl, "KF IR {kf:.3} below TL18's {tl:.3}");
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("fluxgate not calibrated")),
        "{warnings:?}"
    );
}
