//! The Kalman filter against band-passed least-squares Tolles–Lawson (TL18-OLS) on clean
//! calibration flights (issue 10, item 4).
//!
//! An independent simulator found the KF at 1.0–3.0× the error of TL18-OLS on clean
//! 3000 m calibrations. This test flies ≥ 10 seeds of the simulator's broad physics
//! profile (`SimConfig::broad`: heading order, geology strength, aircraft, fluxgate and
//! navigation errors drawn per seed) and prints, per seed, the error against truth of
//! - the KF with the default model (`tl16+field+fluxcal`: the fluxgate calibrated against
//!   the scalar first) and with the paper's model alone (`tl16+field`),
//! - TL18-OLS (λ = 0, `TlConfig::ols`) and MagNav's ridge TL18 (λ = 0.001),
//! - the oracle floor (least squares of the truth on the default model's regressors).
//!
//! What holds today is asserted; the issue's target is a separate test.

use magcomp::estimate::corrections::run_kf;
use magcomp::estimate::fluxcal::flight_flux;
use magcomp::estimate::kf::KfOptions;
use magcomp::estimate::tl;
use magcomp::flight::Flight;
use magcomp::model::spec::{ModelSpec, DEFAULT_MODEL};
use magcomp::qc::figures::manoeuvre_band;
use magcomp::qc::truth::{error_rms_nt, oracle_floor_nt};
use magcomp::sim::{simulate, GeologyPreset, SimConfig};

const PAPER_MODEL: &str = "tl16+field";

/// Seeds of the clean 3000 m cases (≥ 10, issue 10).
const SEEDS: [u64; 10] = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10];

#[derive(Clone, Debug)]
struct Row {
    seed: u64,
    headings: String,
    /// Peak-to-peak of the true anomaly along the flight (nT).
    anomaly_pp_nt: f64,
    kf: f64,
    kf_paper: f64,
    /// RMS angle (mrad) by which the default model's fluxgate calibration turned the
    /// direction cosines (0 when it was not applied).
    fluxcal_mrad: f64,
    ols: f64,
    ridge: f64,
    oracle: f64,
}

fn flight(trace: &magcomp::io::trace::Trace, model: &str) -> Flight {
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
    let fp = flight(&trace, PAPER_MODEL);
    let run_p =
        run_kf(&fp, &KfOptions::new(ModelSpec::parse(PAPER_MODEL).unwrap())).expect("kf paper");
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
        kf_paper: error_rms_nt(&run_p.interference_nt, &truth, None),
        fluxcal_mrad: run
            .fluxgate_fit
            .as_ref()
            .map_or(0.0, |f| 1e3 * f.direction_change_rad),
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
        "KF paper",
        "TL-OLS",
        "TL-ridge",
        "oracle",
        "KF/OLS",
        "fluxcal"
    );
    for r in &rows {
        println!(
            "{:>4} {:>15} {:>8.1} {:>8.4} {:>10.4} {:>8.4} {:>8.4} {:>8.4} {:>7.2} {:>9.4}",
            r.seed,
            r.headings,
            r.anomaly_pp_nt,
            r.kf,
            r.kf_paper,
            r.ols,
            r.ridge,
            r.oracle,
            r.kf / r.ols,
            r.fluxcal_mrad
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

/// The 3000 m table, flown once for the two tests that read it.
fn high_table() -> Vec<Row> {
    static TABLE: std::sync::OnceLock<Vec<Row>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| table(high_cases())).clone()
}

/// Issue 10's bar: KF ≤ max(1.1 × TL18-OLS, TL18-OLS + 0.005 nT).
fn meets_target(kf: f64, ols: f64) -> bool {
    kf <= (1.1 * ols).max(ols + 0.005)
}

/// What holds today on the broad profile at 3000 m.
#[test]
fn clean_calibrations_kf_and_tl18_ols_against_truth() {
    let rows = high_table();
    for r in &rows {
        // TL18-OLS on a clean high calibration: 0.027–0.050 nT, 0.13 nT where 18 nT of
        // anomaly leaks into its band (seed 2).
        assert!(r.ols < 0.2, "seed {}: TL18-OLS {:.4} nT", r.seed, r.ols);
        assert!(r.oracle <= r.ols, "seed {}: oracle above OLS", r.seed);
        // The KF (default model): 0.009–0.021 nT, 1.2–2.4× the oracle floor of its own
        // regressors; the paper's model alone: 0.010–0.056 nT.
        assert!(r.kf < 0.04, "seed {}: KF {:.4} nT", r.seed, r.kf);
        assert!(
            r.kf < 3.5 * r.oracle,
            "seed {}: KF {:.4} vs oracle {:.4}",
            r.seed,
            r.kf,
            r.oracle
        );
        assert!(
            r.kf_paper < 0.08,
            "seed {}: KF paper {:.4} nT",
            r.seed,
            r.kf_paper
        );
        // The fluxgate in the aircraft's field is turned by milliradians: the calibration is
        // applied on every calibration pattern.
        assert!(
            r.fluxcal_mrad > 0.5,
            "seed {}: fluxcal {:.2} mrad",
            r.seed,
            r.fluxcal_mrad
        );
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
/// Measured (nT; KF = the default model `tl16+field+fluxcal`, KF paper = `tl16+field`,
/// fluxcal = rms direction change of the fitted fluxgate calibration, mrad):
///
/// ```text
/// seed        headings  anom pp       KF   KF paper   TL-OLS TL-ridge   oracle  KF/OLS   fluxcal
///    1 135/225/315/045      5.8   0.0121     0.0184   0.0284   0.1678   0.0100    0.43   11.1869
///    2 270/090/000/180     18.0   0.0153     0.0245   0.1302   0.0799   0.0094    0.12    6.7532
///    3 090/000/270/180      4.0   0.0191     0.0183   0.0302   0.1450   0.0098    0.63    4.3122
///    4 225/315/045/135     10.4   0.0109     0.0102   0.0316   0.0640   0.0045    0.34    5.0179
///    5 000/180/090/270     23.5   0.0213     0.0188   0.0273   0.1050   0.0118    0.78    2.7029
///    6 180/270/090/000      3.2   0.0092     0.0139   0.0289   0.0557   0.0045    0.32    3.7165
///    7 090/270/180/000     18.8   0.0115     0.0212   0.0328   0.1158   0.0056    0.35    7.1438
///    8 000/180/270/090      3.2   0.0159     0.0160   0.0308   0.0624   0.0124    0.51    3.6226
///    9 000/180/270/090      4.6   0.0113     0.0151   0.0287   0.2103   0.0083    0.40    8.0743
///   10 315/045/135/225      2.1   0.0205     0.0555   0.0497   0.0956   0.0112    0.41   12.3751
///  101 045/315/225/135      2.5   0.0146     0.0483   0.0491   0.0869   0.0060    0.30    8.7278
/// ```
///
/// The paper's model alone failed seed 10 (1.12×) and was level on 101 (0.98×): weak
/// anomalies on the diagonal headings, where the fluxgate's direction cosines, turned by
/// the aircraft's field at the fluxgate (4–12 mrad), biased the induced coefficients.
/// Calibrating the fluxgate against the scalar first removes that bias: 0.12–0.78×.
#[test]
fn kf_meets_tl18_ols_on_every_clean_seed() {
    let rows = high_table();
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
