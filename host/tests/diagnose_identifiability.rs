//! Identifiability first, verdicts held out (issue 12, items 2 and 3): a candidate the
//! flight cannot determine is listed as untestable, not ranked; a candidate's share is
//! judged on manoeuvres it was not fitted on.
//! Run in release: `cargo test --release -p magcomp --test diagnose_identifiability -- --nocapture`.

use magcomp::diagnose::{diagnose, DiagnoseOptions, Diagnosis};
use magcomp::io::trace::Trace;
use magcomp::model::spec::ModelSpec;
use magcomp::sim::{parse_hidden, simulate, FlightKind, Geology, GeologyPreset, SimConfig};
use magcomp_core::model::catalog::{ChannelUse, CATALOG};

const DECOYS: [&str; 2] = ["cur_fan", "cur_avionics"];

fn diag(trace: &Trace) -> Diagnosis {
    let d = diagnose(
        trace,
        &ModelSpec::parse("tl16+field").expect("spec"),
        &DiagnoseOptions::default(),
    )
    .expect("diagnose");
    eprintln!("{}", d.table());
    d
}

/// Terms driven by attitude alone (catalogue terms without a channel, but `field`).
fn attitude_driven(term: &str) -> bool {
    CATALOG
        .iter()
        .any(|t| t.name == term && matches!(t.channel, ChannelUse::None))
}

/// A calibration pattern has no crossovers, so `rate` cannot be tested there: it is listed
/// untestable (it was ranked first and significant on a lagged flight, issue 12), and the
/// lag is named.
#[test]
fn lag_is_named_and_rate_untestable_on_a_pattern_without_crossovers() {
    let cfg = SimConfig {
        seed: 2,
        decoys: DECOYS.iter().map(|s| s.to_string()).collect(),
        hidden: vec![parse_hidden("lag:0.2").expect("spec")],
        ..SimConfig::default()
    };
    let d = diag(&simulate(&cfg).expect("simulate"));
    let first = d.candidates.first().expect("a candidate");
    assert_eq!(first.term, "lag", "{}", d.table());
    assert!(first.significant, "{}", d.table());
    let h = first.heldout_explained_fraction.expect("held out");
    assert!(h > 0.5, "lag explains {h} of held-out residual");
    assert!(
        d.untestable
            .iter()
            .any(|u| u.term == "rate" && u.reason.contains("crossovers")),
        "{}",
        d.table()
    );
    assert!(d.candidates.iter().all(|c| c.term != "rate"));
}

/// A straight survey line over strong geology at 200 m, no manoeuvres (turbulence only):
/// the attitude-driven candidates cannot be determined and nothing attitude-driven is
/// recommended.
#[test]
fn a_straight_line_over_geology_recommends_nothing_attitude_driven() {
    let cfg = SimConfig {
        seed: 4,
        flight: FlightKind::Survey,
        survey_lines: 1,
        line_length_m: 40_000.0,
        survey_altitude_m: 200.0,
        altitude_swing_m: 150.0,
        geology: Geology::preset(GeologyPreset::Strong),
        decoys: DECOYS.iter().map(|s| s.to_string()).collect(),
        ..SimConfig::default()
    };
    let d = diag(&simulate(&cfg).expect("simulate"));
    for c in d.candidates.iter().filter(|c| c.significant) {
        assert!(
            !attitude_driven(&c.term),
            "{} recommended on a straight line:\n{}",
            c.term,
            d.table()
        );
    }
    let untestable: Vec<&str> = d.untestable.iter().map(|u| u.term.as_str()).collect();
    for t in ["induced_high", "rate"] {
        assert!(
            untestable.contains(&t),
            "{t} not untestable: {untestable:?}"
        );
    }
    let json = d.to_json();
    assert!(json.contains("\"untestable\""), "{json}");
}
