//! Several effects at once and the fluxgate's temperature (issue 12 items 4 and 5).
//! `diagnose --iterate` adds the best significant term until nothing is significant; with
//! two and three hidden effects every one must be found, in any order, no decoy channel
//! may enter the model, and the final error must be within 1.5× the clean floor (the same
//! seed's flight without the effects, under `tl16+field`). `fluxtemp:CH` is tested on the
//! fluxgate's modulus, so it must be named among temperature decoys that share its trend.
//! Run in release: `cargo test --release -p magcomp --test diagnose_iterate`.
//!
//! The clean floor of a seed is computed once and shared by the tests that compare with it
//! (`common::memo`).

use magcomp::diagnose::{diagnose, iterate, DiagnoseOptions, Iteration};
use magcomp::estimate::corrections::run_kf;
use magcomp::estimate::kf::KfOptions;
use magcomp::flight::Flight;
use magcomp::io::trace::Trace;
use magcomp::model::spec::ModelSpec;
use magcomp::sim::{parse_hidden, simulate, SimConfig};

mod common;
use common::memo::Memo;

/// Decoys: a current and temperatures drawn like the fluxgate's (ground → cruise over
/// minutes plus a heater cycle), so they share its kind of trend.
const DECOYS: [&str; 3] = ["cur_fan", "temp_cabin", "temp_oat"];
/// Bias drift of a poorly compensated fluxgate (2–8 nT/°C per axis): at the 0.2–0.8 nT/°C
/// of a good one the effect on this aircraft is ~0.001 nT (see the last test).
const FLUXTEMP: &str = "fluxtemp:temp_flux:8";

fn flight(hidden: &[&str], seed: u64) -> Trace {
    let cfg = SimConfig {
        seed,
        decoys: DECOYS.iter().map(|s| s.to_string()).collect(),
        hidden: hidden
            .iter()
            .map(|h| parse_hidden(h).expect("hidden spec"))
            .collect(),
        ..SimConfig::default()
    };
    simulate(&cfg).expect("simulate")
}

/// Error against truth of `model` on `trace` (the delay-aware comparison with `lag`).
fn error_nt(trace: &Trace, model: &str) -> f64 {
    let spec = ModelSpec::parse(model).expect("spec");
    let f = Flight::from_trace(trace, &spec.channels(), &spec.relative_channels()).expect("flight");
    let run = run_kf(&f, &KfOptions::new(spec)).expect("kf");
    magcomp::estimate::corrections::error_against_truth_nt(trace, &f, &run).expect("truth")
}

fn clean_floor_nt(seed: u64) -> f64 {
    static FLOORS: Memo<u64, f64> = Memo::new();
    FLOORS.get(seed, || error_nt(&flight(&[], seed), "tl16+field"))
}

/// The terms the path added, in order.
fn added(it: &Iteration) -> Vec<String> {
    it.steps.iter().filter_map(|s| s.added.clone()).collect()
}

/// Iterates on a flight with `hidden` and checks the bar; returns (first, final error, floor).
fn check_path(hidden: &[&str], expected: &[&str], seed: u64) -> (f64, f64, f64) {
    let trace = flight(hidden, seed);
    let it = iterate(
        &trace,
        &ModelSpec::parse("tl16+field").expect("spec"),
        &DiagnoseOptions::default(),
        5,
    )
    .expect("iterate");
    let table = it.table();
    eprintln!("seed {seed}, hidden {hidden:?}:\n{table}");
    let terms = added(&it);
    for e in expected {
        assert!(
            terms.iter().any(|t| t == e),
            "seed {seed}: {e} not found\n{table}"
        );
    }
    for t in &terms {
        assert!(
            !DECOYS.iter().any(|d| t.ends_with(&format!(":{d}"))),
            "seed {seed}: decoy term {t} added\n{table}"
        );
    }
    assert!(
        it.stopped.starts_with("no candidate is significant"),
        "seed {seed}: {}\n{table}",
        it.stopped
    );
    // One step per added term, each with the model it names and an error against truth.
    assert_eq!(it.steps.len(), terms.len() + 1);
    let mut model = ModelSpec::parse("tl16+field").expect("spec");
    for st in &it.steps {
        assert_eq!(st.diagnosis.model, model.text());
        assert!(st.error_rms_nt.is_some_and(f64::is_finite));
        if let Some(t) = &st.added {
            model = model.with(t).expect("spec");
        }
    }
    let first = it.steps[0].error_rms_nt.expect("truth");
    let last = it.steps.last().and_then(|s| s.error_rms_nt).expect("truth");
    let floor = clean_floor_nt(seed);
    eprintln!(
        "seed {seed}: error {first:.4} → {last:.4} nT, clean floor {floor:.4} ({:.2}×)",
        last / floor
    );
    assert!(
        first > 10.0 * floor,
        "seed {seed}: the effects should matter ({first:.4} vs floor {floor:.4})"
    );
    assert!(
        last <= 1.5 * floor,
        "seed {seed}: final error {last:.4} nT > 1.5 × clean floor {floor:.4}\n{table}"
    );
    (first, last, floor)
}

/// Measured (seed: error before → after, clean floor): 1: 1.88 → 0.0055 (0.0044, 1.26×);
/// 2: 1.62 → 0.0092 (0.0093, 0.99×).
#[test]
fn two_effects_pump_current_and_lag_are_both_found() {
    for seed in [1, 2] {
        check_path(
            &["current:cur_pump", "lag:0.05"],
            &["current:cur_pump", "lag"],
            seed,
        );
    }
}

/// Measured (2026-11-27): 1: 1.84 → 0.0056 (1.28×); 2: 1.62 → 0.0080 (0.86×).
#[test]
fn three_effects_pump_current_lag_and_fluxgate_temperature_are_all_found() {
    for seed in [1, 2] {
        check_path(
            &["current:cur_pump", "lag:0.05", FLUXTEMP],
            &["current:cur_pump", "lag", "fluxtemp:temp_flux"],
            seed,
        );
    }
}

/// Seeds 3–6 (measured, error with the effects → after the path, clean floor): two effects
/// 2.11 → 0.0071 (0.0068), 1.71 → 0.0064 (0.0069), 2.03 → 0.0056 (0.0055), 1.97 → 0.0081
/// (0.0094) nT; three 1.04–1.09× the floor. Seed 4 named `current_rate:cur_pump` (the
/// lagged current's first-order form) before `lag` until the ranking counted `lag` as the
/// one parameter it adds (τ), not its detector's rank (error then 0.0608 nT).
#[test]
fn several_effects_on_more_seeds() {
    for seed in [3, 4, 5, 6] {
        check_path(
            &["current:cur_pump", "lag:0.05"],
            &["current:cur_pump", "lag"],
            seed,
        );
        check_path(
            &["current:cur_pump", "lag:0.05", FLUXTEMP],
            &["current:cur_pump", "lag", "fluxtemp:temp_flux"],
            seed,
        );
    }
}

/// The fluxgate's temperature drift, named through the fluxgate's modulus among
/// temperature decoys. Measured (error without → with, clean floor): seed 1 0.0148 →
/// 0.0049 (0.0044), seed 2 0.0278 → 0.0084 (0.0093), seed 3 0.0343 → 0.0071 (0.0068).
#[test]
fn fluxgate_temperature_is_named_among_temperature_decoys_and_removes_the_error() {
    for seed in [1, 2, 3] {
        let trace = flight(&[FLUXTEMP], seed);
        let d = diagnose(
            &trace,
            &ModelSpec::parse("tl16+field").expect("spec"),
            &DiagnoseOptions::default(),
        )
        .expect("diagnose");
        let table = d.table();
        let first = &d.candidates[0];
        assert_eq!(first.term, "fluxtemp:temp_flux", "seed {seed}\n{table}");
        assert!(first.significant, "seed {seed}\n{table}");
        // Every other candidate, the decoys' fluxtemp included, is not significant.
        for c in &d.candidates[1..] {
            assert!(
                !c.significant,
                "seed {seed}: {} significant\n{table}",
                c.term
            );
        }
        for dec in ["temp_cabin", "temp_oat"] {
            let c = d
                .candidates
                .iter()
                .find(|c| c.term == format!("fluxtemp:{dec}"))
                .expect("decoy temperature tested");
            assert!(!c.material, "seed {seed}: {dec}\n{table}");
        }
        // Only temperature-named channels are fluxtemp candidates.
        assert!(!d.candidates.iter().any(|c| c.term == "fluxtemp:cur_fan"));
        let floor = clean_floor_nt(seed);
        let before = error_nt(&trace, "tl16+field");
        let after = error_nt(&trace, "tl16+field+fluxtemp:temp_flux");
        eprintln!("seed {seed}: error {before:.4} → {after:.4} nT, clean floor {floor:.4}");
        assert!(
            before > 2.0 * floor,
            "seed {seed}: the drift should matter: {before:.4} vs floor {floor:.4}"
        );
        assert!(
            after <= 1.5 * floor,
            "seed {seed}: {after:.4} nT > 1.5 × clean floor {floor:.4}"
        );
    }
}

/// At a good fluxgate's 0.2–0.8 nT/°C the drift is plain on the modulus (F in the
/// thousands) but moves the compensation by less than the 0.01 nT materiality bar: nothing
/// is recommended, and the error is the clean flight's. Seed 2 is the one where a decoy
/// temperature had fitted the modulus to within 2× its noise with a 12 nT/°C z drift.
#[test]
fn a_good_fluxgates_temperature_drift_is_seen_but_not_recommended() {
    for seed in [1, 2] {
        let trace = flight(&["fluxtemp:temp_flux"], seed);
        let d = diagnose(
            &trace,
            &ModelSpec::parse("tl16+field").expect("spec"),
            &DiagnoseOptions::default(),
        )
        .expect("diagnose");
        let table = d.table();
        assert!(
            d.candidates.iter().all(|c| !c.significant),
            "seed {seed}\n{table}"
        );
        let c = d
            .candidates
            .iter()
            .find(|c| c.term == "fluxtemp:temp_flux")
            .expect("tested");
        assert!(c.p_value < 1e-6 && !c.material, "seed {seed}\n{table}");
        let (before, floor) = (error_nt(&trace, "tl16+field"), clean_floor_nt(seed));
        assert!(
            before <= 1.1 * floor,
            "seed {seed}: {before:.4} vs {floor:.4}"
        );
    }
}

/// `--max-steps` bounds the path and says so; the JSON is an array of steps, each a
/// diagnosis object with `step`, `error_rms_nt` and `added`, the last with `stopped`.
#[test]
fn the_path_is_bounded_and_its_json_is_an_array_of_steps() {
    let trace = flight(&["current:cur_pump", "lag:0.05"], 1);
    let it = iterate(
        &trace,
        &ModelSpec::parse("tl16+field").expect("spec"),
        &DiagnoseOptions::default(),
        1,
    )
    .expect("iterate");
    assert_eq!(it.steps.len(), 2, "{}", it.table());
    assert_eq!(it.steps[0].added.as_deref(), Some("current:cur_pump"));
    assert!(it.stopped.contains("--max-steps"), "{}", it.stopped);
    assert!(it.stopped.contains("lag"), "{}", it.stopped);
    let v: serde_json::Value = serde_json::from_str(&it.to_json()).expect("json");
    let steps = v.as_array().expect("array");
    assert_eq!(steps.len(), 2);
    for (i, s) in steps.iter().enumerate() {
        assert_eq!(s["step"], i);
        for k in [
            "model",
            "residual_rms_nt",
            "error_rms_nt",
            "candidates",
            "nis",
        ] {
            assert!(!s[k].is_null(), "step {i} lacks {k}");
        }
    }
    assert_eq!(steps[0]["added"], "current:cur_pump");
    assert_eq!(steps[1]["model"], "tl16+field+current:cur_pump");
    assert!(steps[1]["added"].is_null() && steps[1]["stopped"].is_string());
    assert!(
        steps[1]["error_rms_nt"].as_f64().expect("f64")
            < steps[0]["error_rms_nt"].as_f64().expect("f64") / 10.0
    );
}
