//! Model discovery sees what the filter absorbs (issue 20). A scalar lag shifts the
//! anomaly along the track, which the anomaly states take: the filter's innovations show
//! little of it while the output is wrong. The band-passed measurement regressed directly
//! and a refit of the whole model see it. Against the simulators' truth:
//! - the independent simulator's `lag_s32` (τ 0.166 s): `lag` named on evidence beyond the
//!   innovations, and adding it cuts the error ≥ 5×; its `clean_s33`: nothing named that
//!   raises the error;
//! - ours, broad physics: lags of 0.1 and 0.25 s named and taken out ≥ 5×; a clean flight
//!   names nothing, and says "explains the data" only within the stated factor;
//! - coefficients of another aircraft applied: `recalibrate` named.

use magcomp::calibration::{compensate_trace, EstimatorSettings, Method};
use magcomp::diagnose::{diagnose, DiagnoseOptions, Diagnosis, EXPLAINED_FACTOR, RECALIBRATE};
use magcomp::io::trace::Trace;
use magcomp::model::spec::ModelSpec;
use magcomp::sim::{parse_hidden, simulate, SimConfig};

#[path = "common/independent.rs"]
mod independent_sim;
use independent_sim::independent;

mod common;
use common::diagnosis::{error_nt, named};

const BASE: &str = "tl16+field+fluxcal";

fn diagnosed(trace: &Trace) -> Diagnosis {
    diagnose(
        trace,
        &ModelSpec::parse(BASE).unwrap(),
        &DiagnoseOptions::default(),
    )
    .expect("diagnose")
}

/// "Explains the data" is said exactly when the NIS and every band are within the factor.
fn assert_verdict_honest(d: &Diagnosis) {
    let v = d.verdict();
    if named(d).is_none() {
        assert_eq!(
            v.contains("explains the data"),
            d.nis <= EXPLAINED_FACTOR && d.band_excess_max <= EXPLAINED_FACTOR,
            "{v}"
        );
        if !d.within_expectation() {
            assert!(v.starts_with("unexplained:"), "{v}");
        }
    }
}

/// A named term must not raise the error against truth.
fn assert_named_helps(trace: &Trace, d: &Diagnosis, case: &str) -> Option<(f64, f64)> {
    let term = named(d)?;
    let (before, after) = (
        error_nt(trace, BASE),
        error_nt(trace, &format!("{BASE}+{term}")),
    );
    println!("{case}: {term} named, error {before:.4} → {after:.4} nT");
    assert!(after <= before, "{case}: {term} raised the error");
    Some((before, after))
}

#[test]
fn independent_lag_flight_names_lag_beyond_the_innovations() {
    let Some(lag) = independent("lag_s32") else {
        eprintln!("skipped: ../shared/reference-data/independent-sim not present");
        return;
    };
    let d = diagnosed(&lag);
    print!("{}", d.table());
    assert_eq!(named(&d), Some("lag"), "{}", d.verdict());
    let c = &d.candidates[0];
    // The innovations alone hold 13 % of it held out: below the 15 % bar.
    assert!(c.heldout_explained_fraction.unwrap() < 0.15);
    assert!(c.evidence.iter().any(|e| e == "band" || e == "refit"));
    assert!(c.band_heldout_fraction.unwrap() > 0.3, "{c:?}");
    let (before, after) = assert_named_helps(&lag, &d, "lag_s32").unwrap();
    assert!(before >= 5.0 * after || after <= 0.15, "{before} → {after}");
    assert!(d.verdict().starts_with("suggestion:"));

    let clean = independent("clean_s33").expect("clean_s33 beside lag_s32");
    let d = diagnosed(&clean);
    print!("{}", d.table());
    assert_verdict_honest(&d);
    assert_named_helps(&clean, &d, "clean_s33");
}

#[test]
fn own_broad_lag_flights_name_lag_and_clean_ones_nothing() {
    for (seed, tau) in [(2u64, 0.1), (3, 0.25)] {
        let mut cfg = SimConfig::broad(seed);
        cfg.hidden = vec![parse_hidden(&format!("lag:{tau}")).unwrap()];
        cfg.decoys = vec!["cur_pump".into(), "temp_bay".into()];
        let trace = simulate(&cfg).expect("simulate");
        let d = diagnosed(&trace);
        assert_eq!(
            named(&d),
            Some("lag"),
            "seed {seed} τ {tau}: {}",
            d.verdict()
        );
        let (before, after) =
            assert_named_helps(&trace, &d, &format!("seed {seed} τ {tau}")).unwrap();
        assert!(before >= 5.0 * after, "seed {seed}: {before} → {after}");
    }
    let mut cfg = SimConfig::broad(2);
    cfg.decoys = vec!["cur_pump".into(), "temp_bay".into()];
    let trace = simulate(&cfg).expect("simulate");
    let d = diagnosed(&trace);
    println!("clean seed 2: {}", d.verdict());
    assert_eq!(named(&d), None, "{}", d.verdict());
    assert_verdict_honest(&d);
}

#[test]
fn another_aircraft_s_coefficients_are_reported_for_recalibration() {
    use magcomp::calibration::compensated_trace;
    let a = simulate(&SimConfig::broad(1)).expect("simulate");
    let b = simulate(&SimConfig::broad(2)).expect("simulate");
    let est = EstimatorSettings {
        method: Method::Kf,
        ..EstimatorSettings::default()
    };
    let (_, cal) = compensate_trace(&a, &est, None, false).expect("calibrate a");
    let file = cal.coefficients.expect("coefficients");
    let (flight_b, applied) = compensate_trace(&b, &est, Some(&file), false).expect("apply to b");
    let left = compensated_trace(&b, &flight_b, &applied).expect("compensated trace");
    let d = diagnose(
        &left,
        &ModelSpec::parse("field").unwrap(),
        &DiagnoseOptions::default(),
    )
    .expect("diagnose");
    print!("{}", d.table());
    assert_eq!(named(&d), Some(RECALIBRATE), "{}", d.verdict());
    assert!(d.verdict().starts_with("recalibrate:"));
    let c = &d.candidates[0];
    assert!(c.band_heldout_fraction.unwrap() > 0.9, "{c:?}");
}
