//! The diagnosis on awkward input: more auxiliary channels than an epoch carries, missing
//! samples, too-short traces, a model that already holds the effect. Errors, not panics.
use magcomp::diagnose::{diagnose, DiagnoseOptions};
use magcomp::model::spec::ModelSpec;
use magcomp::sim::{parse_hidden, simulate, SimConfig};

fn opts() -> DiagnoseOptions {
    DiagnoseOptions::default()
}

#[test]
fn many_channels_are_tested_in_batches() {
    // 11 decoys + the pump: more than MAX_AUX (8) channels per epoch.
    let cfg = SimConfig {
        seed: 7,
        hidden: vec![parse_hidden("current:cur_pump").expect("hidden")],
        decoys: (0..11).map(|i| format!("cur_d{i}")).collect(),
        ..SimConfig::default()
    };
    let trace = simulate(&cfg).expect("simulate");
    let d = diagnose(
        &trace,
        &ModelSpec::parse("tl16+field").expect("spec"),
        &opts(),
    )
    .expect("diagnose");
    assert_eq!(d.candidates[0].term, "current:cur_pump", "{}", d.table());
    assert_eq!(
        d.candidates
            .iter()
            .filter(|c| c.term.starts_with("current:"))
            .count(),
        12
    );
    assert_eq!(
        d.candidates.iter().filter(|c| c.significant).count(),
        1,
        "{}",
        d.table()
    );
}

#[test]
fn missing_samples_and_a_term_already_in_the_model() {
    let cfg = SimConfig {
        seed: 8,
        hidden: vec![parse_hidden("current:cur_pump").expect("hidden")],
        decoys: vec!["cur_fan".into()],
        ..SimConfig::default()
    };
    let mut trace = simulate(&cfg).expect("simulate");
    let mut mag = trace.col("mag").expect("mag").to_vec();
    for v in mag.iter_mut().skip(2000).take(50) {
        *v = f64::NAN;
    }
    trace.set_col("mag", mag);
    let mut fan = trace.col("cur_fan").expect("fan").to_vec();
    for v in fan.iter_mut().skip(3000).take(30) {
        *v = f64::NAN;
    }
    trace.set_col("cur_fan", fan);
    let d = diagnose(
        &trace,
        &ModelSpec::parse("tl16+field").expect("spec"),
        &opts(),
    )
    .expect("diagnose");
    assert_eq!(d.candidates[0].term, "current:cur_pump");
    assert!(d.residual_rms_nt.is_finite());
    // With the pump in the model, it is no longer a candidate and nothing is significant.
    let spec = ModelSpec::parse("tl16+field+current:cur_pump").expect("spec");
    let d = diagnose(&trace, &spec, &opts()).expect("diagnose");
    assert!(d.candidates.iter().all(|c| c.term != "current:cur_pump"));
    assert!(d.candidates.iter().all(|c| !c.significant), "{}", d.table());
    assert!(d.residual_rms_nt < 0.05, "{}", d.table());
}

#[test]
fn short_or_broken_traces_give_errors_not_panics() {
    let cfg = SimConfig {
        seed: 9,
        max_duration_s: Some(5.0),
        ..SimConfig::default()
    };
    let trace = simulate(&cfg).expect("simulate");
    let spec = ModelSpec::parse("tl16+field").expect("spec");
    let e = diagnose(&trace, &spec, &opts()).unwrap_err().to_string();
    assert!(e.contains("too few") || e.contains("samples"), "{e}");
    let mut t = simulate(&SimConfig {
        seed: 9,
        max_duration_s: Some(60.0),
        ..SimConfig::default()
    })
    .expect("sim");
    t.numeric.retain(|(n, _)| n != "flux_y");
    let e = format!("{:#}", diagnose(&t, &spec, &opts()).unwrap_err());
    assert!(e.contains("flux_y"), "{e}");
    let mut t = simulate(&SimConfig {
        seed: 9,
        max_duration_s: Some(60.0),
        ..SimConfig::default()
    })
    .expect("sim");
    let n = t.len();
    t.set_col("mag", vec![f64::NAN; n]);
    assert!(diagnose(&t, &spec, &opts()).is_err());
}
