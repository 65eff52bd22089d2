//! Least-squares experiment: how much does each extra nuisance regressor cost?
use magcomp::flight::Flight;
use magcomp::metrics::*;
use magcomp::model_spec::ModelSpec;
use magcomp::pipeline::{run_kf, KfOptions};
use magcomp::sim::anomaly::Geology;
use magcomp::sim::{simulate, GeologyPreset, SimConfig};
use nalgebra::{DMatrix, DVector};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let seed: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(1);
    let mut cfg = SimConfig {
        seed,
        ..Default::default()
    };
    if std::env::var("NOGEO").is_ok() {
        cfg.geology = Geology::preset(GeologyPreset::None);
    }
    if std::env::var("NODIURNAL").is_ok() {
        cfg.diurnal_nt = 0.0;
    }
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
    let spec = ModelSpec::parse("tl16+field")?;
    let flight = Flight::from_trace(&trace, &spec.channels(), &spec.relative_channels())?;
    let truth = flight.truth_interference_nt.clone().unwrap();
    let opts = KfOptions::new(spec.clone());
    let run = run_kf(&flight, &opts)?;
    let n = flight.len();
    let i0 = flight.samples[0].igrf_nt;
    let h0 = flight.samples[0].alt_m as f64;
    let t0 = flight.t_s[0];
    let tn = flight.t_s[n - 1] - t0;
    let anom = flight.truth_anomaly_nt.clone().unwrap_or(vec![0.0; n]);
    let subanom = std::env::var("SUBANOM").is_ok();
    let y: Vec<f64> = (0..n)
        .map(|i| {
            flight.mag_nt[i]
                - (flight.samples[i].igrf_nt - i0)
                - if subanom { anom[i] } else { 0.0 }
        })
        .collect();
    let ts: Vec<f64> = flight.t_s.iter().map(|t| (t - t0) / tn).collect();
    let hs: Vec<f64> = flight.samples.iter().map(|s| s.alt_m as f64 - h0).collect();
    let kinds: Vec<&str> = args
        .get(2)
        .map(|s| s.split(',').collect())
        .unwrap_or_default();
    let p0 = run.regressors[0].len();
    let rows: Vec<usize> = (0..n)
        .filter(|&i| y[i].is_finite() && run.regressors[i].iter().all(|v| v.is_finite()))
        .collect();
    let mut extra: Vec<Box<dyn Fn(usize) -> f64>> = vec![Box::new(|_| 1.0)];
    for k in &kinds {
        match *k {
            "t1" => extra.push(Box::new({
                let ts = ts.clone();
                move |i| ts[i]
            })),
            "t2" => extra.push(Box::new({
                let ts = ts.clone();
                move |i| ts[i].powi(2)
            })),
            "t3" => extra.push(Box::new({
                let ts = ts.clone();
                move |i| ts[i].powi(3)
            })),
            "h" => extra.push(Box::new({
                let hs = hs.clone();
                move |i| hs[i]
            })),
            k if k.starts_with("xy") => {
                let d: i32 = k[2..].parse()?;
                let lat0 = flight.samples[0].lat_deg;
                let lon0 = flight.samples[0].lon_deg;
                let ne: Vec<(f64, f64)> = flight
                    .samples
                    .iter()
                    .map(|s| {
                        (
                            (s.lat_deg - lat0) * 111.2,
                            (s.lon_deg - lon0) * 111.2 * lat0.to_radians().cos(),
                        )
                    })
                    .collect();
                let sc = ne
                    .iter()
                    .fold(0.0f64, |m, (a, b)| m.max(a.abs()).max(b.abs()));
                for tot in 1..=d {
                    for a in 0..=tot {
                        let ne = ne.clone();
                        extra.push(Box::new(move |i| {
                            (ne[i].0 / sc).powi(a) * (ne[i].1 / sc).powi(tot - a)
                        }));
                    }
                }
            }
            k if k.starts_with("tp") => {
                let d: i32 = k[2..].parse()?;
                for e in 1..=d {
                    let ts = ts.clone();
                    extra.push(Box::new(move |i| (2.0 * ts[i] - 1.0).powi(e)));
                }
            }
            "" => {}
            _ => anyhow::bail!("unknown {k}"),
        }
    }
    let p = p0 + extra.len();
    let a = DMatrix::from_fn(rows.len(), p, |r, c| {
        let i = rows[r];
        if c < p0 {
            run.regressors[i][c] as f64
        } else {
            extra[c - p0](i)
        }
    });
    let yv = DVector::from_iterator(rows.len(), rows.iter().map(|&i| y[i]));
    let x = a.clone().svd(true, true).solve(&yv, 1e-12).unwrap();
    let interf: Vec<f64> = (0..n)
        .map(|i| (0..p0).map(|c| run.regressors[i][c] as f64 * x[c]).sum())
        .collect();
    println!(
        "seed {seed} extras {kinds:?}: LS error {:.4}, KF {:.4}, oracle {:.4}",
        error_rms_nt(&interf, &truth, None),
        error_rms_nt(&run.interference_nt, &truth, None),
        oracle_floor_nt(&run.regressors, &truth).unwrap()
    );
    let s1: f64 = std::env::var("S1")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(run.sigma1);
    let rf = magcomp::reference_kf::run_reference(
        &flight,
        &spec,
        s1,
        s1 * opts.sigma2_ratio,
        run.noise_nt,
    )?;
    let interf: Vec<f64> = (0..n)
        .map(|i| {
            (0..p0)
                .map(|c| run.regressors[i][c] as f64 * rf.coefficients[c])
                .sum()
        })
        .collect();
    println!(
        "reference f64 KF sigma1 {s1:.1e}: error {:.4}",
        error_rms_nt(&interf, &truth, None)
    );
    let mut o = opts.clone();
    o.sigma1 = Some(s1);
    o.tie_points = false;
    o.field_profiles = false;
    o.freeze_on_survey = false;
    o.gate_sigma = 0.0;
    let run2 = run_kf(&flight, &o)?;
    println!(
        "f32 KF same settings: error {:.4}",
        error_rms_nt(&run2.interference_nt, &truth, None)
    );
    Ok(())
}
