use magcomp::flight::Flight;
use magcomp::metrics::*;
use magcomp::model_spec::ModelSpec;
use magcomp::pipeline::{run_kf, KfOptions};
use magcomp::sim::anomaly::Geology;
use magcomp::sim::{simulate, GeologyPreset, SimConfig};
use magcomp::tl;

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
    if low {
        cfg.cal_altitude_m = 300.0;
        cfg.altitude_swing_m = 100.0;
        cfg.geology = Geology::preset(GeologyPreset::Strong);
    }
    let t0 = std::time::Instant::now();
    let trace = simulate(&cfg)?;
    println!("simulated {} rows in {:.2?}", trace.len(), t0.elapsed());
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
    if let Some(s) = args.get(4) {
        opts.sigma1 = Some(s.parse()?);
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
        "tie flags: {}",
        run.flags
            .iter()
            .filter(|f| **f & magcomp_core::Flags::TIE_POINT != 0)
            .count()
    );
    let err = error_rms_nt(&run.interference_nt, &truth, None);
    let oracle = oracle_floor_nt(&run.regressors, &truth).unwrap();
    let fom_kf = fom(&flight, &run.compensated_nt).map(|f| f.0);
    println!(
        "KF post: error {err:.4} oracle {oracle:.4} ratio {:.2} fom {fom_kf:?} IR {:?}",
        err / oracle,
        improvement_ratio(&flight, &run.compensated_nt)
    );
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
    let rf = magcomp::reference_kf::run_reference(
        &flight,
        &spec,
        run.sigma1,
        run.sigma1 / 10.0,
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
    println!("truth interference rms {:.3}", rms_demeaned(&truth));
    Ok(())
}
