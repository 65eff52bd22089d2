//! Fluxgate sanity (issue 21 item 2): one fluxgate row inconsistent with its neighbours or
//! with the scalar — a `flux_z` of 0, a file cut inside its last number (48954.7 → 48) —
//! is flagged `MAG_MISSING` and not learnt from: the calibration's error against the
//! simulator's truth and its fluxgate calibration stay those of the clean flight, and so
//! does the error its coefficients leave on a survey. Coefficients applied to a fluxgate
//! that changed since calibration (an axis negated, a +500 nT bias, two axes swapped) warn;
//! a calibration on a left-handed (swapped) frame warns.

use magcomp::calibration::coefficients::CoefficientFile;
use magcomp::calibration::fluxgate_check;
use magcomp::calibration::provenance::Provenance;
use magcomp::calibration::{compensate_trace, EstimatorSettings};
use magcomp::io::trace::Trace;
use magcomp::qc::truth::error_rms_nt;
use magcomp::sim::FlightKind;
use magcomp::sim::{simulate, SimConfig};
use magcomp_core::Flags;

/// Error (nT rms against truth), rows flagged `MAG_MISSING`, largest |fluxgate bias| (nT)
/// and largest |scale − 1|.
/// With the coefficient file as `calibrate` writes it (the fluxgate record in its
/// provenance).
fn calibrated_file(trace: &Trace) -> (f64, Vec<usize>, f64, f64, CoefficientFile) {
    let (flight, comp) =
        compensate_trace(trace, &EstimatorSettings::default(), None, false).expect("calibration");
    let mut file = comp.coefficients.clone().unwrap();
    file.provenance = Some(Provenance {
        fluxgate: Some(fluxgate_check::record(
            &flight,
            &file.fluxgate_calibration.unwrap(),
            &comp.interference_nt,
        )),
        ..Default::default()
    });
    let truth = flight.truth_interference_nt.as_ref().unwrap();
    let missing = comp
        .flags
        .as_ref()
        .map(|f| {
            (0..f.len())
                .filter(|&i| f[i] & Flags::MAG_MISSING != 0)
                .collect()
        })
        .unwrap_or_default();
    let cal = comp
        .coefficients
        .as_ref()
        .and_then(|c| c.fluxgate_calibration)
        .expect("the default model calibrates the fluxgate");
    let bias = cal.bias_nt.iter().fold(0.0f64, |m, b| m.max(b.abs()));
    let scale = (0..3).fold(0.0f64, |m, i| m.max((cal.matrix[i][i] - 1.0).abs()));
    (
        error_rms_nt(&comp.interference_nt, truth, None),
        missing,
        bias,
        scale,
        file,
    )
}

/// Error (nT rms against truth) of `file` applied to `survey`, and the run's warnings.
fn applied(survey: &Trace, file: &CoefficientFile) -> (f64, Vec<String>) {
    let (flight, comp) =
        compensate_trace(survey, &EstimatorSettings::default(), Some(file), false).unwrap();
    let truth = flight.truth_interference_nt.as_ref().unwrap();
    (
        error_rms_nt(&comp.interference_nt, truth, None),
        comp.warnings,
    )
}

fn survey() -> Trace {
    simulate(&SimConfig {
        seed: 3,
        flight: FlightKind::Survey,
        survey_lines: 2,
        ..SimConfig::default()
    })
    .unwrap()
}

fn edited(trace: &Trace, f: impl Fn(&mut [Vec<f64>; 3])) -> Trace {
    let mut t = trace.clone();
    let mut v = ["flux_x", "flux_y", "flux_z"].map(|c| t.col(c).unwrap().to_vec());
    f(&mut v);
    for (c, col) in ["flux_x", "flux_y", "flux_z"].into_iter().zip(v) {
        t.set_col(c, col);
    }
    t
}

const FLUXGATE_CHANGED: [&str; 2] = [
    "the fluxgate disagrees with the one the coefficients were calibrated with",
    "the fluxgate's main-field direction is",
];

fn with_flux(trace: &Trace, col: &str, row: usize, value: f64) -> Trace {
    let mut t = trace.clone();
    let mut v = t.col(col).unwrap().to_vec();
    v[row] = value;
    t.set_col(col, v);
    t
}

#[test]
fn one_bad_fluxgate_row_is_flagged_and_not_learnt_from() {
    let trace = simulate(&SimConfig {
        seed: 3,
        ..SimConfig::default()
    })
    .unwrap();
    let n = trace.len();
    let (clean, clean_missing, clean_bias, clean_scale, clean_file) = calibrated_file(&trace);
    let survey = survey();
    let (clean_survey, _) = applied(&survey, &clean_file);
    eprintln!(
        "clean: {clean:.4} nT, bias ≤ {clean_bias:.1} nT, |scale − 1| ≤ {clean_scale:.4}, {} flagged",
        clean_missing.len()
    );
    assert!(
        clean_missing.is_empty(),
        "a clean flight has no bad fluxgate rows: {clean_missing:?}"
    );
    let last_z = trace.col("flux_z").unwrap()[n - 1];
    // "48954.7" cut to "48": the first two digits, sign kept.
    let digits = (last_z.abs().log10().floor() as i32) - 1;
    let cut = (last_z / 10f64.powi(digits)).trunc();
    let cases = [
        (
            "flux_z = 0 mid-flight",
            with_flux(&trace, "flux_z", n / 2, 0.0),
            n / 2,
        ),
        (
            "last line cut inside flux_z",
            with_flux(&trace, "flux_z", n - 1, cut),
            n - 1,
        ),
        (
            "flux_x = 0 at the first row",
            with_flux(&trace, "flux_x", 0, 0.0),
            0,
        ),
    ];
    for (name, bad, row) in cases {
        let (err, missing, bias, scale, file) = calibrated_file(&bad);
        let (on_survey, _) = applied(&survey, &file);
        eprintln!(
            "{name}: {err:.4} nT against {clean:.4} clean ({:.2}×), bias ≤ {bias:.1} nT, \
             |scale − 1| ≤ {scale:.4}, flagged {missing:?}; survey {on_survey:.4} nT against \
             {clean_survey:.4} ({:.2}×)",
            err / clean,
            on_survey / clean_survey
        );
        assert!(
            on_survey <= 1.5 * clean_survey,
            "{name}: survey {on_survey:.4} against {clean_survey:.4} nT"
        );
        assert_eq!(missing, vec![row], "{name}: the bad row alone is flagged");
        assert!(err <= 1.5 * clean, "{name}: {err:.4} against {clean:.4} nT");
        assert!(
            (bias - clean_bias).abs() < 50.0 && (scale - clean_scale).abs() < 1e-3,
            "{name}: the fluxgate calibration moved: bias {bias:.1} nT, scale {scale:.4}"
        );
    }
}

#[test]
fn a_fluxgate_changed_since_calibration_warns() {
    let cal = simulate(&SimConfig {
        seed: 3,
        ..SimConfig::default()
    })
    .unwrap();
    let (_, _, _, _, file) = calibrated_file(&cal);
    let rec = file.provenance.as_ref().unwrap().fluxgate.clone().unwrap();
    eprintln!("calibration record: {rec:?}");
    assert!(fluxgate_check::frame_warning(&rec).is_none(), "{rec:?}");
    let survey = survey();
    let (clean, w) = applied(&survey, &file);
    eprintln!("survey as calibrated: {clean:.4} nT, warnings {w:?}");
    let warned = |w: &[String]| {
        w.iter()
            .any(|w| FLUXGATE_CHANGED.iter().any(|f| w.contains(f)))
    };
    assert!(!warned(&w), "the same fluxgate: no warning: {w:?}");
    let cases: [(&str, Trace); 4] = [
        (
            "flux_x negated",
            edited(&survey, |v| v[0].iter_mut().for_each(|x| *x = -*x)),
        ),
        (
            "flux_z negated",
            edited(&survey, |v| v[2].iter_mut().for_each(|x| *x = -*x)),
        ),
        (
            "+500 nT on flux_z",
            edited(&survey, |v| v[2].iter_mut().for_each(|x| *x += 500.0)),
        ),
        ("x and y swapped", edited(&survey, |v| v.swap(0, 1))),
    ];
    for (name, bad) in cases {
        let (err, w) = applied(&bad, &file);
        eprintln!(
            "{name}: {err:.4} nT ({:.1}× clean), warnings {w:?}",
            err / clean
        );
        assert!(warned(&w), "{name}: no fluxgate warning: {w:?}");
    }
    // Calibrating on a left-handed (x ↔ y swapped) frame warns.
    let swapped = edited(&cal, |v| v.swap(0, 1));
    let (_, _, _, _, file) = calibrated_file(&swapped);
    let rec = file.provenance.unwrap().fluxgate.unwrap();
    let w = fluxgate_check::frame_warning(&rec);
    eprintln!("left-handed calibration: {rec:?} → {w:?}");
    assert!(
        w.as_deref()
            .is_some_and(|w| w.contains("does not turn with the INS")),
        "{w:?}"
    );
}
