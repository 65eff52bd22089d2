use magcomp::estimate::corrections::run_kf;
use magcomp::estimate::kf::KfOptions;
use magcomp::estimate::tl;
use magcomp::flight::Flight;
use magcomp::model::spec::ModelSpec;
use magcomp::qc::figures::*;
use magcomp::qc::truth::*;
use magcomp::sim::anomaly::Geology;
use magcomp::sim::{simulate, GeologyPreset, SimConfig};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let low = args.get(1).map(|s| s == "low").unwrap_or(false);
    let seed: u64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1);
    let mut cfg = SimConfig {
        seed,
        ..Default::default()
    };
    if std::env::var("CLEAN").is_ok() {
        cfg.geology = Geology::preset(GeologyPreset::None);
        cfg.diurnal_nt = 0.0;
    }
    if std::env::var("NOGEO").is_ok() {
        cfg.geology = Geology::preset(GeologyPreset::None);
    }
    if std::env::var("NODIURNAL").is_ok() {
        cfg.diurnal_nt = 0.0;
    }
    if std::env::var("NOFLUXNOISE").is_ok() {
        cfg.flux_noise_nt = 0.0;
    }
    let envf = |k: &str| std::env::var(k).ok().and_then(|v| v.parse::<f64>().ok());
    if low {
        cfg.cal_altitude_m = envf("ALT").unwrap_or(300.0);
        cfg.altitude_swing_m = envf("SWING").unwrap_or(100.0);
        cfg.geology = Geology::preset(match std::env::var("GEO").as_deref() {
            Ok("moderate") => GeologyPreset::Moderate,
            Ok("quiet") => GeologyPreset::Quiet,
            _ => GeologyPreset::Strong,
        });
    }
    if let Some(v) = envf("GPSV") {
        cfg.gps_sigma_v_m = v;
    }
    if let Some(v) = envf("GPSH") {
        cfg.gps_sigma_h_m = v;
    }
    if let Some(v) = envf("YAW") {
        cfg.yaw_amp_deg = v;
    }
    if let Some(v) = envf("PITCH") {
        cfg.pitch_amp_deg = v;
    }
    if let Some(v) = envf("WIND") {
        cfg.wind_mps = v;
    }
    if let Some(v) = envf("TURB") {
        cfg.turbulence_deg = v;
    }
    if let Some(v) = envf("MANCYC") {
        cfg.manoeuvre_cycles = v as _;
    }
    if let Some(v) = envf("LEVEL") {
        cfg.level_s = v;
    }
    if let Some(v) = envf("NOISE") {
        cfg.scalar_noise_nt = v;
    }
    let t0 = std::time::Instant::now();
    let mut trace = simulate(&cfg)?;
    if std::env::var("SUBBASE").is_ok() {
        let b = trace.col("base").unwrap().to_vec();
        let m: Vec<f64> = trace
            .col("mag")
            .unwrap()
            .iter()
            .zip(&b)
            .map(|(a, c)| a - c)
            .collect();
        trace.set_col("mag", m);
    }
    println!("simulated {} rows in {:.2?}", trace.len(), t0.elapsed());
    if std::env::var("SUBANOM").is_ok() {
        let ta = trace.col("truth_anomaly").unwrap().to_vec();
        let m: Vec<f64> = trace
            .col("mag")
            .unwrap()
            .iter()
            .zip(&ta)
            .map(|(a, b)| a - b)
            .collect();
        trace.set_col("mag", m);
    }
    let spec = ModelSpec::parse(args.get(3).map(|s| s.as_str()).unwrap_or("tl16+field"))?;
    let flight = Flight::from_trace(&trace, &spec.channels(), &spec.relative_channels())?;
    println!(
        "tie point {:?}, fs {}",
        flight.tie_point, flight.sample_rate_hz
    );
    let truth = flight.truth_interference_nt.clone().unwrap();
    let mut opts = KfOptions::new(spec.clone());
    if std::env::var("NOTIE").is_ok() {
        opts.tie_points = false;
    }
    if let Some(s) = args.get(4).filter(|s| *s != "-") {
        opts.sigma1 = Some(s.parse()?);
    }
    if let Some(v) = envf("S2R") {
        opts.sigma2_ratio = v;
    }
    if let Some(v) = envf("S1X") {
        opts.sigma1_scale = v;
    }
    if let Some(v) = envf("PRIOR") {
        opts.prior_scale = v;
    }
    if let Ok(v) = std::env::var("CANDS") {
        opts.sigma1_candidates = v.split(',').filter_map(|x| x.parse().ok()).collect();
    }
    if std::env::var("NOPROF").is_ok() {
        opts.field_profiles = false;
    }
    if let Some(v) = envf("GATE") {
        opts.gate_sigma = v;
    }
    if let Some(v) = envf("TURNR") {
        opts.turn_noise_scale = v;
    }
    if let Some(v) = envf("H0R") {
        opts.h0_reanchor_m = v;
    }
    if let Some(v) = envf("HW") {
        opts.half_width = Some(v as usize);
    }
    if let Some(s) = args.get(5) {
        opts.noise_nt = Some(s.parse()?);
    }
    let t0 = std::time::Instant::now();
    let run = run_kf(&flight, &opts)?;
    println!(
        "kf in {:.2?}: sigma1 {:.2e} noise {:.4}",
        t0.elapsed(),
        run.sigma1,
        run.noise_nt
    );
    println!(
        "tie rejected: {}",
        run.flags
            .iter()
            .filter(|f| **f & magcomp_core::Flags::TIE_REJECTED != 0)
            .count()
    );
    println!(
        "tie flags: {}",
        run.flags
            .iter()
            .filter(|f| **f & magcomp_core::Flags::TIE_POINT != 0)
            .count()
    );
    let err = error_rms_nt(&run.interference_nt, &truth, None);
    let nll: f64 = run
        .innovation_nt
        .iter()
        .zip(&run.innovation_var_nt2)
        .filter(|(v, s)| v.is_finite() && s.is_finite() && **s > 0.0)
        .map(|(v, s)| s.ln() + v * v / s)
        .sum::<f64>()
        / run.innovation_nt.len() as f64;
    println!("NLL per sample {nll:.4}");
    let oracle = oracle_floor_nt(&run.regressors, &truth).unwrap();
    println!(
        "predicted error {:.4} (actual/predicted {:.2}, actual-vs-oracle excess {:.4})",
        run.predicted_error_nt.unwrap_or(f64::NAN),
        err / run.predicted_error_nt.unwrap_or(f64::NAN),
        (err * err - oracle * oracle).max(0.0).sqrt()
    );
    let fom_kf = fom(&flight, &run.compensated_nt).map(|f| f.0);
    println!(
        "KF post: error {err:.4} oracle {oracle:.4} ratio {:.2} fom {fom_kf:?} IR {:?}",
        err / oracle,
        improvement_ratio(&flight, &run.compensated_nt)
    );
    if std::env::var("SEGS").is_ok() {
        let d: Vec<f64> = run
            .interference_nt
            .iter()
            .zip(&truth)
            .map(|(a, b)| a - b)
            .collect();
        let m = d.iter().sum::<f64>() / d.len() as f64;
        let mut acc: std::collections::BTreeMap<String, (f64, usize)> = Default::default();
        for (i, lab) in flight.segments.as_ref().unwrap().iter().enumerate() {
            let key = lab.rsplit('_').next().unwrap_or(lab).to_string();
            let e = acc.entry(key).or_default();
            e.0 += (d[i] - m).powi(2);
            e.1 += 1;
        }
        for (k, (s2, n)) in acc {
            println!(
                "  seg {k:>10}: rms {:.4} ({n} rows)",
                (s2 / n as f64).sqrt()
            );
        }
    }
    opts.realtime = true;
    let rt = run_kf(&flight, &opts)?;
    let last_man = flight
        .segments
        .as_ref()
        .unwrap()
        .iter()
        .rposition(|s| is_manoeuvre(s))
        .unwrap();
    let rows: Vec<usize> = (last_man..flight.len()).collect();
    println!(
        "KF realtime after last manoeuvre: {:.4} ({} rows); whole {:.4}",
        error_rms_nt(&rt.interference_nt, &truth, Some(&rows)),
        rows.len(),
        error_rms_nt(&rt.interference_nt, &truth, None)
    );
    let flux: Vec<[f64; 3]> = flight
        .samples
        .iter()
        .map(|s| {
            [
                s.flux_nt[0] as f64,
                s.flux_nt[1] as f64,
                s.flux_nt[2] as f64,
            ]
        })
        .collect();
    let tcfg = tl::TlConfig {
        fs_hz: flight.sample_rate_hz,
        ..Default::default()
    };
    let f = tl::fit(&flux, &flight.mag_nt, &tcfg, None)?;
    let ti = tl::interference(&f, &flux);
    let comp_tl: Vec<f64> = flight.mag_nt.iter().zip(&ti).map(|(m, i)| m - i).collect();
    println!(
        "TL18: error {:.4} fom {:?}",
        error_rms_nt(&ti, &truth, None),
        fom(&flight, &comp_tl).map(|f| f.0)
    );
    let rf = magcomp::estimate::reference_kf::run_reference(
        &flight,
        &spec,
        run.sigma1,
        run.sigma1 * opts.sigma2_ratio,
        run.noise_nt,
    )?;
    println!(
        "f64 reference realtime: after last manoeuvre {:.4}, final-coeff diff vs f32 {:?}",
        error_rms_nt(&rf.interference_nt, &truth, Some(&rows)),
        rf.coefficients
            .iter()
            .zip(&run.coefficients)
            .map(|(a, b)| ((a - b) * 1000.0).round() / 1000.0)
            .collect::<Vec<_>>()
    );
    {
        let ri: Vec<f64> = run
            .regressors
            .iter()
            .map(|r| {
                r.iter()
                    .zip(&rf.coefficients)
                    .map(|(a, c)| *a as f64 * c)
                    .sum()
            })
            .collect();
        println!(
            "f64 reference post-flight (final coeffs applied): {:.4}",
            error_rms_nt(&ri, &truth, None)
        );
    }
    {
        let igrf = trace.col("igrf").unwrap();
        let ta = trace.col("truth_anomaly").unwrap();
        let td = trace.col("truth_diurnal").unwrap();
        let y: Vec<f64> = (0..flight.len())
            .map(|i| flight.mag_nt[i] - igrf[i] - ta[i] - td[i])
            .collect();
        // LS of y on regressors -> fitted interference
        let p = run.regressors[0].len() + 1;
        let a = nalgebra::DMatrix::from_fn(y.len(), p, |r, c| {
            if c == 0 {
                1.0
            } else {
                run.regressors[r][c - 1] as f64
            }
        });
        let yv = nalgebra::DVector::from_vec(y.clone());
        let x = a.clone().svd(true, true).solve(&yv, 1e-12).unwrap();
        let fit = &a * &x;
        let est: Vec<f64> = (0..y.len()).map(|i| fit[i] - x[0]).collect();
        println!(
            "noise-limited LS floor (anomaly known): {:.4}",
            error_rms_nt(&est, &truth, None)
        );
    }
    if std::env::var("DECOMP").is_ok() {
        let p = run.regressors[0].len() + 1;
        let a = nalgebra::DMatrix::from_fn(truth.len(), p, |r, c| {
            if c == 0 {
                1.0
            } else {
                run.regressors[r][c - 1] as f64
            }
        });
        let yv = nalgebra::DVector::from_vec(truth.clone());
        let x = a.clone().svd(true, true).solve(&yv, 1e-12).unwrap();
        let mut parts: Vec<(f64, String)> = Vec::new();
        for j in 1..p {
            let d = run.coefficients[j - 1] - x[j];
            let col: Vec<f64> = (0..truth.len()).map(|r| a[(r, j)] * d).collect();
            let m = col.iter().sum::<f64>() / col.len() as f64;
            let rms = (col.iter().map(|v| (v - m).powi(2)).sum::<f64>() / col.len() as f64).sqrt();
            parts.push((
                rms,
                format!(
                    "{} kf {:.4} oracle {:.4} sigma {:.4}",
                    run.coefficient_names[j - 1].0,
                    run.coefficients[j - 1],
                    x[j],
                    run.coefficient_sigmas[j - 1]
                ),
            ));
        }
        parts.sort_by(|a, b| b.0.total_cmp(&a.0));
        for (r, n) in parts.iter().take(8) {
            println!("  decomp {r:.4} nT: {n}");
        }
    }
    {
        use magcomp_core::spectrum::{estimate_sigma1, Sigma1Config};
        let sd = flight.along_track_m();
        let ta = trace.col("truth_anomaly").unwrap();
        let zk: Vec<f64> = flight
            .mag_nt
            .iter()
            .zip(&run.interference_nt)
            .map(|(m, i)| m - i)
            .collect();
        for (lo, hi, bin) in [
            (200.0, 500.0, 50.0),
            (500.0, 1000.0, 50.0),
            (1000.0, 2000.0, 100.0),
            (1000.0, 8000.0, 100.0),
            (2000.0, 8000.0, 100.0),
        ] {
            let c = Sigma1Config {
                bin_m: bin,
                min_wavelength_m: lo,
                max_wavelength_m: hi,
            };
            let mut scr = vec![0.0; 3 * (sd.last().unwrap() / bin) as usize + 6];
            let a = estimate_sigma1(&sd, ta, &c, &mut scr).map(|e| e.sigma1);
            let b = estimate_sigma1(&sd, &zk, &c, &mut scr).map(|e| e.sigma1);
            println!(
                "sigma1 band {lo}-{hi}: truth anomaly {:.2e} residual {:.2e}",
                a.unwrap_or(f64::NAN),
                b.unwrap_or(f64::NAN)
            );
        }
    }
    println!("truth interference rms {:.3}", rms_demeaned(&truth));
    Ok(())
}
