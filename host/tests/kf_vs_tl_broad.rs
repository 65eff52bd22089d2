//! The Kalman filter against band-passed least-squares Tolles–Lawson (TL18-OLS) on clean
//! calibration flights (issue 10, item 4).
//!
//! An independent simulator found the KF at 1.0–3.0× the error of TL18-OLS on clean
//! 3000 m calibrations. This test flies ≥ 10 seeds of the simulator's broad physics
//! profile (`SimConfig::broad`: heading order, geology strength, aircraft, fluxgate and
//! navigation errors drawn per seed) and prints, per seed, the error against truth of
//! - the KF with the default model (`tl16+field`) and with `tl16+fluxmod+field`,
//! - TL18-OLS (λ = 0, `TlConfig::ols`) and MagNav's ridge TL18 (λ = 0.001),
//! - the oracle floor (least squares of the truth on the default model's regressors).
//!
//! What holds today is asserted; the issue's target is a separate test.

use magcomp::flight::Flight;
use magcomp::fluxgate::flight_flux;
use magcomp::metrics::{error_rms_nt, manoeuvre_band, oracle_floor_nt};
use magcomp::model_spec::{ModelSpec, DEFAULT_MODEL};
use magcomp::pipeline::{run_kf, KfOptions};
use magcomp::sim::{simulate, GeologyPreset, SimConfig};
use magcomp::tl;

const FLUXMOD_MODEL: &str = "tl16+fluxmod+field";

/// Seeds of the clean 3000 m cases (≥ 10, issue 10).
const SEEDS: [u64; 10] = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10];

#[derive(Clone, Debug)]
struct Row {
    seed: u64,
    headings: String,
    /// Peak-to-peak of the true anomaly along the flight (nT).
    anomaly_pp_nt: f64,
    kf: f64,
    kf_fluxmod: f64,
    /// The `fluxmod` coefficient the KF estimated (nT/nT).
    c_fluxmod: f64,
    ols: f64,
    ridge: f64,
    oracle: f64,
}

fn flight(trace: &magcomp::trace::Trace, model: &str) -> Flight {
    let spec = ModelSpec::parse(model).unwrap();
    Flight::from_trace(trace, &spec.channels(), &spec.relative_channels()).expect("flight")
}

/// TL18 error against truth with ridge λ (0 = OLS), fitted and applied on the flight.
fn tl_error(f: &Flight, truth: &[f64], lambda: f64) -> f64 {
    let mut cfg = tl::TlConfig::ols(f.sample_rate_hz);
    cfg.lambda = lambda;
    cfg.pass_hz = Some(manoeuvre_band(f.sample_rate_hz));
    let fx = flight_flux(f);
    let fit = tl::fit(&fx, &f.mag_nt, &cfg, None).expect("tl fit");
    error_rms_nt(&tl::interference(&fit, &fx), truth, None)
}

fn measure(cfg: &SimConfig) -> Row {
    let trace = simulate(cfg).expect("simulate");
    let anomaly = trace.col("truth_anomaly").expect("truth anomaly");
    let anomaly_pp_nt = anomaly.iter().copied().fold(f64::MIN, f64::max)
        - anomaly.iter().copied().fold(f64::MAX, f64::min);
    let f = flight(&trace, DEFAULT_MODEL);
    let truth = f.truth_interference_nt.clone().expect("truth");
    let run = run_kf(
        &f,
        &KfOptions::new(ModelSpec::parse(DEFAULT_MODEL).unwrap()),
    )
    .expect("kf");
    let ff = flight(&trace, FLUXMOD_MODEL);
    let run_f = run_kf(
        &ff,
        &KfOptions::new(ModelSpec::parse(FLUXMOD_MODEL).unwrap()),
    )
    .expect("kf fluxmod");
    Row {
        seed: cfg.seed,
        headings: cfg
            .cal_headings_deg
            .iter()
            .map(|h| format!("{h:03.0}"))
            .collect::<Vec<_>>()
            .join("/"),
        anomaly_pp_nt,
        kf: error_rms_nt(&run.interference_nt, &truth, None),
        kf_fluxmod: error_rms_nt(&run_f.interference_nt, &truth, None),
        c_fluxmod: run_f
            .coefficient_names
            .iter()
            .position(|n| n.0.starts_with("fluxmod"))
            .map_or(f64::NAN, |k| run_f.coefficients[k]),
        ols: tl_error(&f, &truth, 0.0),
        ridge: tl_error(&f, &truth, tl::TlConfig::default().lambda),
        oracle: oracle_floor_nt(&run.regressors, &truth).expect("oracle"),
    }
}

/// Every case on its own thread (the flights are independent; CI has 2 cores).
fn table(cfgs: Vec<SimConfig>) -> Vec<Row> {
    let rows: Vec<Row> = std::thread::scope(|s| {
        let hs: Vec<_> = cfgs.iter().map(|c| s.spawn(move || measure(c))).collect();
        hs.into_iter().map(|h| h.join().expect("case")).collect()
    });
    println!(
        "{:>4} {:>15} {:>8} {:>8} {:>10} {:>8} {:>8} {:>8} {:>7} {:>9}",
        "seed",
        "headings",
        "anom pp",
        "KF",
        "KF+fluxmod",
        "TL-OLS",
        "TL-ridge",
        "oracle",
        "KF/OLS",
        "c_fluxmod"
    );
    for r in &rows {
        println!(
            "{:>4} {:>15} {:>8.1} {:>8.4} {:>10.4} {:>8.4} {:>8.4} {:>8.4} {:>7.2} {:>9.4}",
            r.seed,
            r.headings,
            r.anomaly_pp_nt,
            r.kf,
            r.kf_fluxmod,
            r.ols,
            r.ridge,
            r.oracle,
            r.kf / r.ols,
            r.c_fluxmod
        );
    }
    rows
}

/// The broad seeds, and the independent simulator's worst case as far as the issue
/// describes it: headings flown 045, 315, 225, 135 over a weak anomaly (2.5 nT).
fn high_cases() -> Vec<SimConfig> {
    let mut c: Vec<SimConfig> = SEEDS.iter().map(|&s| SimConfig::broad(s)).collect();
    c.push(SimConfig {
        cal_headings_deg: vec![45.0, 315.0, 225.0, 135.0],
        anomaly_pp_nt: Some(2.5),
        ..SimConfig::broad(101)
    });
    c
}

/// Issue 10's bar: KF ≤ max(1.1 × TL18-OLS, TL18-OLS + 0.005 nT).
fn meets_target(kf: f64, ols: f64) -> bool {
    kf <= (1.1 * ols).max(ols + 0.005)
}

/// What holds today on the broad profile at 3000 m.
#[test]
fn clean_calibrations_kf_and_tl18_ols_against_truth() {
    let rows = table(high_cases());
    for r in &rows {
        // TL18-OLS on a clean high calibration: 0.027–0.050 nT, 0.13 nT where 18 nT of
        // anomaly leaks into its band (seed 2).
        assert!(r.ols < 0.2, "seed {}: TL18-OLS {:.4} nT", r.seed, r.ols);
        assert!(r.oracle <= r.ols, "seed {}: oracle above OLS", r.seed);
        // The KF: 0.010–0.056 nT, 1.4–3.1× the oracle floor (measured on this profile).
        for (what, e) in [("KF", r.kf), ("KF+fluxmod", r.kf_fluxmod)] {
            assert!(e < 0.08, "seed {}: {what} {e:.4} nT", r.seed);
            assert!(
                e < 3.5 * r.oracle,
                "seed {}: {what} {e:.4} vs oracle {:.4}",
                r.seed,
                r.oracle
            );
        }
    }
    // The profile varies what it claims to: heading order and geology strength.
    let mut orders: Vec<&str> = rows.iter().map(|r| r.headings.as_str()).collect();
    orders.sort();
    orders.dedup();
    assert!(orders.len() >= 4, "heading orders {orders:?}");
    let (lo, hi) = rows.iter().fold((f64::MAX, f64::MIN), |(a, b), r| {
        (a.min(r.anomaly_pp_nt), b.max(r.anomaly_pp_nt))
    });
    assert!(
        lo < 6.0 && hi > 15.0,
        "anomaly peak-to-peak {lo:.1}–{hi:.1} nT"
    );
}

/// Issue 10 item 4: never worse than TL18-OLS on a clean calibration, on every seed.
///
/// Measured when written (nT; KF = tl16+field, c_fluxmod = the `fluxmod` coefficient of
/// the tl16+fluxmod+field run):
///
/// ```text
/// seed        headings  anom pp       KF KF+fluxmod   TL-OLS TL-ridge   oracle  KF/OLS c_fluxmod
///    1 135/225/315/045      5.8   0.0184     0.0184   0.0284   0.1678   0.0127    0.65    0.0000
///    2 270/090/000/180     18.0   0.0245     0.0245   0.1302   0.0799   0.0141    0.19   -0.0003
///    3 090/000/270/180      4.0   0.0183     0.0182   0.0302   0.1450   0.0102    0.60    0.0000
///    4 225/315/045/135     10.4   0.0102     0.0102   0.0316   0.0640   0.0045    0.32   -0.0002
///    5 000/180/090/270     23.5   0.0188     0.0188   0.0273   0.1050   0.0112    0.69   -0.0001
///    6 180/270/090/000      3.2   0.0139     0.0140   0.0289   0.0557   0.0048    0.48   -0.0001
///    7 090/270/180/000     18.8   0.0212     0.0212   0.0328   0.1158   0.0139    0.65   -0.0000
///    8 000/180/270/090      3.2   0.0160     0.0160   0.0308   0.0624   0.0123    0.52   -0.0001
///    9 000/180/270/090      4.6   0.0151     0.0151   0.0287   0.2103   0.0102    0.52   -0.0002
///   10 315/045/135/225      2.1   0.0555     0.0555   0.0497   0.0956   0.0292    1.12   -0.0002
///  101 045/315/225/135      2.5   0.0483     0.0483   0.0491   0.0869   0.0158    0.98   -0.0000
/// ```
///
/// Seed 10 fails (1.12×) and the issue's described case (101) is at 0.98×: both weak
/// anomalies on the diagonal headings. The deficit appeared only once the fluxgate saw
/// the aircraft's field strongly (coupling g 1.5–4): with g 0.3–1 every seed was at
/// 0.10–0.84× TL18-OLS. `fluxmod` does not help as the KF uses it (coefficient ≈ 0).
#[test]
#[ignore = "issue 10 item 4: KF 1.12× TL18-OLS on broad seed 10 (0.0555 vs 0.0497 nT); table in the doc comment"]
fn kf_meets_tl18_ols_on_every_clean_seed() {
    let rows = table(high_cases());
    let bad: Vec<u64> = rows
        .iter()
        .filter(|r| !meets_target(r.kf, r.ols))
        .map(|r| r.seed)
        .collect();
    assert!(
        bad.is_empty(),
        "KF above max(1.1×OLS, OLS+0.005 nT) on seeds {bad:?}"
    );
}

/// Low altitude (300 m over strong geology): TL18 cannot tell the anomaly from the
/// interference there, the KF must keep its advantage (≤ 0.15 nT).
#[test]
fn low_altitude_kf_keeps_its_advantage() {
    let cfgs: Vec<SimConfig> = [1u64, 2, 3]
        .iter()
        .map(|&s| SimConfig {
            cal_altitude_m: 300.0,
            geology: magcomp::sim::Geology::preset(GeologyPreset::Strong),
            anomaly_pp_nt: None,
            ..SimConfig::broad(s)
        })
        .collect();
    let rows = table(cfgs);
    for r in &rows {
        assert!(
            r.ridge > 0.5,
            "seed {}: TL18 {:.3} nT is not challenged",
            r.seed,
            r.ridge
        );
        assert!(r.kf <= 0.15, "seed {}: KF {:.4} nT at 300 m", r.seed, r.kf);
    }
}
