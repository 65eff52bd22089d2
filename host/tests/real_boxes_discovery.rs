//! Model discovery on real data (issue 12, item 6): `diagnose --iterate` on box 1 of SGL
//! 2020 flight 1002 (`data/reference/sgl2020-flt1002-cal/`, see real_boxes.rs for
//! the file) must end with a model whose box 1 → box 2 band-passed (0.1–0.9 Hz) residual is
//! lower than `tl16+field`'s, and every term it adds must improve box 2, which it never saw.
//! Skips, saying so, where the shared data are absent.
//! Run in release: `cargo test --release -p magcomp --test real_boxes_discovery -- --nocapture`.

use magcomp::calibration::{compensate_trace, EstimatorSettings, Method};
use magcomp::diagnose::{iterate, DiagnoseOptions};
use magcomp::io::trace::Trace;
use magcomp::model::spec::ModelSpec;

#[path = "common/real_boxes.rs"]
mod real_boxes_data;
use real_boxes_data::{band_std_nt, boxes, Boxes, BOX1_ROWS, SPEED_MPS};

/// Rows `range` as a trace of scalar `mag` and fluxgate `flux_d`, with the assumed ground
/// speed as `vn` (the diagnosis runs the filter, which needs the along-track distance).
fn trace(b: &Boxes, range: std::ops::Range<usize>, mag: &str) -> Trace {
    let n = range.len();
    let mut t = b.trace(range, mag, "flux_d");
    t.numeric.push(("vn".into(), vec![SPEED_MPS; n]));
    t.numeric.push(("ve".into(), vec![0.0; n]));
    t
}

/// Box 2's band-passed residual with `model` calibrated (KF) on box 1.
fn transfer_nt(b: &Boxes, mag: &str, model: &str) -> f64 {
    let e = EstimatorSettings {
        model: model.into(),
        method: Method::Kf,
        speed_mps: Some(SPEED_MPS),
        ..Default::default()
    };
    let (_, cal) = compensate_trace(&trace(b, 0..BOX1_ROWS, mag), &e, None, false).unwrap();
    let file = cal.coefficients.unwrap();
    let box2 = trace(b, BOX1_ROWS..b.rows.len(), mag);
    let (_, applied) = compensate_trace(&box2, &e, Some(&file), false).unwrap();
    band_std_nt(&applied.compensated_nt)
}

/// Measured: mag_4 (mag_3) `tl16+field` 3.360 (4.357) nT on box 2. The path adds `fluxmod`
/// (the fluxgate's own view of the aircraft: its calibrated modulus misfits by ~9× what the
/// scalar leaves unexplained; 25 % (56 %) of box 1's residual, 24 % (55 %) held out), which
/// takes box 2 to 2.999 (3.390) nT, and stops. Before candidates were fitted against their
/// priors, `induced_high` was added instead (68 % in-sample with its coefficients at
/// ~22,000 nT against a 50 nT prior) and box 2 got worse (3.428, 4.478 nT).
#[test]
fn iterate_on_box_1_improves_box_2_at_every_step() {
    let Some(b) = boxes() else { return };
    let mut failures = Vec::new();
    for mag in ["mag_4_uc", "mag_3_uc"] {
        let start = ModelSpec::parse("tl16+field").unwrap();
        let it = iterate(
            &trace(&b, 0..BOX1_ROWS, mag),
            &start,
            &DiagnoseOptions::default(),
            5,
        )
        .unwrap();
        eprintln!("{mag}:\n{}", it.table());
        let models: Vec<String> = it.models().unwrap().iter().map(|m| m.text()).collect();
        let box2: Vec<f64> = models.iter().map(|m| transfer_nt(&b, mag, m)).collect();
        for (m, r) in models.iter().zip(&box2) {
            eprintln!("{mag}: {m}: box 1 → box 2 band std {r:.3} nT");
        }
        if models.len() < 2 {
            failures.push(format!("{mag}: nothing added"));
        }
        for k in 1..box2.len() {
            if box2[k] >= box2[k - 1] {
                failures.push(format!(
                    "{mag}: {} → {} makes box 2 worse: {:.3} → {:.3} nT",
                    models[k - 1],
                    models[k],
                    box2[k - 1],
                    box2[k]
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
