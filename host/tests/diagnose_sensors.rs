//! Discovery across sensors (issue 19 item 5): a current that disturbs one cabin sensor,
//! among decoy channels, is named for that sensor and not for the others, using each
//! sensor's difference with the others' compensated fields (where the anomaly cancels)
//! as evidence; adding it to that sensor's model makes its error against truth fall.
//!
//! The simulator puts hidden effects on its first sensor, the one at the trajectory's
//! point: here that is the cabin sensor, with the stinger 9 m behind it and a wingtip.
//! Run in release: `cargo test --release -p magcomp --test diagnose_sensors -- --nocapture`.

use magcomp::calibration::{compensate_trace, EstimatorSettings, Method};
use magcomp::diagnose::sensors::diagnose_sensors;
use magcomp::diagnose::DiagnoseOptions;
use magcomp::model::spec::ModelSpec;
use magcomp::multi::sensors::{parse_sensors, sensor_trace};
use magcomp::qc::truth::error_rms_nt;
use magcomp::sim::multi::simulate_multi;
use magcomp::sim::{parse_hidden, SimConfig};

/// Cabin (the simulated point, carrying the current), stinger 9 m aft, a wingtip.
const CABIN_STINGER_WINGTIP_M: [[f64; 3]; 3] =
    [[0.0, 0.0, 0.0], [-9.0, 0.0, -0.5], [-3.0, -8.0, -1.0]];

const MODEL: &str = "tl16+field";

#[test]
fn a_cabin_current_is_named_for_its_sensor_only_and_adding_it_helps_there() {
    let cfg = SimConfig {
        seed: 5,
        hidden: vec![parse_hidden("current:cur_heater").expect("spec")],
        decoys: vec!["cur_pump".into(), "cur_radio".into()],
        ..SimConfig::default()
    };
    let trace = simulate_multi(&cfg, &CABIN_STINGER_WINGTIP_M).expect("simulate");
    let sensors = parse_sensors("mag_1,mag_2,mag_3", &trace).expect("sensors");
    let est = EstimatorSettings {
        method: Method::Kf,
        model: MODEL.into(),
        ..EstimatorSettings::default()
    };
    let model = ModelSpec::parse(MODEL).expect("model");
    let findings = diagnose_sensors(&trace, &sensors, &model, &DiagnoseOptions::default(), &est)
        .expect("diagnose");
    for f in &findings {
        println!("{}: named {:?}", f.sensor, f.named);
        for (other, d) in &f.against {
            let shown: Vec<String> = d
                .candidates
                .iter()
                .filter(|c| c.term.starts_with("current"))
                .map(|c| {
                    format!(
                        "{} sig {} ref {:.2} evidence {:?}",
                        c.term,
                        c.significant,
                        c.reference_heldout_fraction.unwrap_or(f64::NAN),
                        c.evidence
                    )
                })
                .collect();
            println!("  against {other}: {shown:?}");
        }
    }
    let named = |s: &str| {
        findings
            .iter()
            .find(|f| f.sensor == s)
            .map(|f| f.named.clone())
            .unwrap()
    };
    assert!(
        named("mag_1").iter().any(|t| t == "current:cur_heater"),
        "the cabin sensor's current is not named: {:?}",
        named("mag_1")
    );
    for s in ["mag_2", "mag_3"] {
        assert!(
            !named(s).iter().any(|t| t.starts_with("current")),
            "{s} is given a current it does not see: {:?}",
            named(s)
        );
    }
    assert!(
        !named("mag_1")
            .iter()
            .any(|t| t.contains("cur_pump") || t.contains("cur_radio")),
        "a decoy is named: {:?}",
        named("mag_1")
    );
    // Adding it where it was named: the cabin sensor's error against truth falls.
    let cabin = sensor_trace(&trace, &sensors[0]);
    let error = |model: &str| {
        let e = EstimatorSettings {
            model: model.into(),
            ..est.clone()
        };
        let (flight, comp) = compensate_trace(&cabin, &e, None, false).expect("calibrate");
        let truth = flight.truth_interference_nt.as_deref().expect("truth");
        error_rms_nt(&comp.interference_nt, truth, None)
    };
    let (before, after) = (error(MODEL), error(&format!("{MODEL}+current:cur_heater")));
    println!("mag_1: error {before:.4} nT → {after:.4} nT with the current");
    assert!(
        after < 0.5 * before,
        "adding the current: {before:.4} → {after:.4} nT"
    );
}

/// The command line, two sensors: `diagnose --sensors mag_1,mag_2 --json` names the
/// current for the cabin sensor and nothing for the stinger.
#[test]
fn diagnose_sensors_on_the_command_line() {
    let cfg = SimConfig {
        seed: 5,
        hidden: vec![parse_hidden("current:cur_heater").expect("spec")],
        decoys: vec!["cur_pump".into()],
        ..SimConfig::default()
    };
    let trace = simulate_multi(&cfg, &CABIN_STINGER_WINGTIP_M[..2]).expect("simulate");
    let scratch = tempfile::tempdir().unwrap();
    let input = scratch.path().join("two.csv");
    magcomp::io::trace::write_trace(&input, &trace).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .arg("diagnose")
        .arg(&input)
        .args(["--sensors", "mag_1,mag_2", "--model", MODEL, "--json"])
        .output()
        .expect("run magcomp");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("one JSON value");
    let named = |i: usize| -> Vec<String> {
        v[i]["named"]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| t.as_str().unwrap().to_string())
            .collect()
    };
    assert_eq!(v[0]["sensor"], "mag_1");
    assert_eq!(named(0), vec!["current:cur_heater".to_string()]);
    assert!(named(1).is_empty(), "mag_2: {:?}", named(1));
    assert!(v[1]["against"][0]["diagnosis"]["candidates"].is_array());
}
