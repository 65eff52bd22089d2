//! The estimator on real data: the two calibration boxes of SGL 2020 flight 1002 (a Cessna
//! Caravan of the MagNav challenge, `data/reference/sgl2020-flt1002-cal/`). The
//! file has no time, position or attitude: rows are 10 Hz samples, box 1 is rows 0–6499,
//! box 2 the rest. The figures are the 0.1–0.9 Hz band-passed standard deviation of the
//! compensated scalar on box 2 with coefficients from box 1 (a transfer), against classic
//! Tolles–Lawson fitted the same way: MagNav's ridge TL18 and plain least squares (no ridge).
//! Skips, saying so, where the shared data are absent.

use magcomp::calibration::{compensate_trace, EstimatorSettings, Method};
use magcomp::estimate::tl;
use magcomp::io::trace::Trace;
use magcomp::model::spec::DEFAULT_MODEL;
use magcomp_core::Flags;

#[path = "common/real_boxes.rs"]
mod real_boxes_data;
use real_boxes_data::{band_std_nt, boxes, Boxes, BOX1_ROWS, FS_HZ, SPEED_MPS};

/// Rows `range` as a positionless trace of scalar `mag` and fluxgate `flux`.
fn trace(b: &Boxes, range: std::ops::Range<usize>, mag: &str, flux: &str) -> Trace {
    b.trace(range, mag, flux)
}

fn est(method: Method, model: &str) -> EstimatorSettings {
    EstimatorSettings {
        model: model.into(),
        method,
        speed_mps: Some(SPEED_MPS),
        ..Default::default()
    }
}

/// Box 2's band-passed residual with `method`/`model` calibrated on box 1.
fn transfer_nt(b: &Boxes, mag: &str, flux: &str, method: Method, model: &str) -> f64 {
    transfer(b, mag, flux, method, model).0
}

/// Box 2's band-passed residual and the band rms box 1's calibration predicted for a
/// flight like it (`predicted_band_rms_nt`, carried with the coefficients).
fn transfer(b: &Boxes, mag: &str, flux: &str, method: Method, model: &str) -> (f64, Option<f64>) {
    let applied = applied_to_box2(b, mag, flux, method, model);
    (
        band_std_nt(&applied.compensated_nt),
        applied.coefficients.and_then(|c| c.predicted_band_rms_nt),
    )
}

/// Box 2 compensated with `method`/`model` calibrated on box 1.
fn applied_to_box2(
    b: &Boxes,
    mag: &str,
    flux: &str,
    method: Method,
    model: &str,
) -> magcomp::calibration::result::Compensation {
    let e = est(method, model);
    let (_, cal) = compensate_trace(&trace(b, 0..BOX1_ROWS, mag, flux), &e, None, false).unwrap();
    let file = cal.coefficients.unwrap();
    let box2 = trace(b, BOX1_ROWS..b.rows.len(), mag, flux);
    compensate_trace(&box2, &e, Some(&file), false).unwrap().1
}

/// Plain band-passed least-squares TL18 (λ = 0), box 1 → box 2.
fn tl18_ols_transfer_nt(b: &Boxes, mag: &str, flux: &str) -> f64 {
    let t1 = trace(b, 0..BOX1_ROWS, mag, flux);
    let t2 = trace(b, BOX1_ROWS..b.rows.len(), mag, flux);
    let flux_of = |t: &Trace| -> Vec<[f64; 3]> {
        let (x, y, z) = (
            t.col("flux_x").unwrap(),
            t.col("flux_y").unwrap(),
            t.col("flux_z").unwrap(),
        );
        (0..x.len()).map(|i| [x[i], y[i], z[i]]).collect()
    };
    let mut cfg = tl::TlConfig::for_rate(FS_HZ);
    cfg.pass_hz = Some((0.1, 0.9));
    cfg.lambda = 0.0;
    let fit = tl::fit(&flux_of(&t1), t1.col("mag").unwrap(), &cfg, None).unwrap();
    band_std_nt(&tl::compensate(&fit, &flux_of(&t2), t2.col("mag").unwrap()).unwrap())
}

/// KF calibrated on box 1 → box 2 against both TL18s, for the two cabin magnetometers.
/// Measured: TL18-ridge 3.47 / 4.30 nT, TL18-OLS 2.91 / 3.93 nT; KF `tl16+field` 3.34 /
/// 4.54; KF `tl16+fluxmod+field` 2.99 / 3.21 (mag_4 / mag_3). Since the calibration stopped
/// loosening the anomaly by a roughness measured on the model's error
/// (`FieldProcessStage::applies`) mag_3's paper model alone moved 4.36 → 4.54 nT (it lacks
/// what the fluxgate sees: the model error is largest there) and its `fluxmod` model 3.39 →
/// 3.21; mag_4 3.36 → 3.34 and 3.00 → 2.99.
#[test]
fn kf_transfer_between_real_boxes_beats_tolles_lawson() {
    let Some(b) = boxes() else { return };
    for mag in ["mag_4_uc", "mag_3_uc"] {
        let ridge = transfer_nt(&b, mag, "flux_d", Method::Tl, "tl16+field");
        let ols = tl18_ols_transfer_nt(&b, mag, "flux_d");
        let paper = transfer_nt(&b, mag, "flux_d", Method::Kf, "tl16+field");
        let (default, predicted) = transfer(&b, mag, "flux_d", Method::Kf, DEFAULT_MODEL);
        let fluxmod = transfer_nt(&b, mag, "flux_d", Method::Kf, "tl16+fluxmod+field");
        let predicted = predicted.expect("predicted error");
        eprintln!(
            "{mag}: box 1 → box 2 band std: TL18 ridge {ridge:.3}, TL18 OLS {ols:.3}, \
             KF tl16+field {paper:.3}, KF default {default:.3} (predicted {predicted:.3}), \
             KF tl16+fluxmod+field {fluxmod:.3} nT"
        );
        // The default model is level with MagNav's TL18 on these boxes (mag_3: 1.055 ×).
        assert!(
            default <= 1.06 * ridge,
            "{mag}: KF default {default:.3} vs ridge TL18 {ridge:.3}"
        );
        // Box 1's calibration predicts box 2's band rms: its own band rms with the band
        // part of its jackknife (the coefficient covariance alone said 0.85–1.3 nT).
        assert!(
            (0.5 * default..=2.0 * default).contains(&predicted),
            "{mag}: predicted {predicted:.3} vs transfer {default:.3}"
        );
        // The fluxgate's own modulus carries the aircraft's field at the fluxgate: with it
        // the filter beats MagNav's TL18 and is level with or better than plain OLS.
        assert!(
            fluxmod < ridge,
            "{mag}: KF+fluxmod {fluxmod:.3} ≥ ridge TL18 {ridge:.3}"
        );
        assert!(
            fluxmod <= 1.05 * ols,
            "{mag}: KF+fluxmod {fluxmod:.3} vs OLS TL18 {ols:.3}"
        );
        // The paper's 16 terms alone cannot span it (TL18's extra column is |B_F|): level
        // with the ridge TL18, not better (mag_3: 1.055 ×).
        assert!(
            paper <= 1.06 * ridge,
            "{mag}: KF {paper:.3} vs ridge TL18 {ridge:.3}"
        );
        assert!(
            paper
                < 0.15
                    * band_std_nt(&trace(&b, BOX1_ROWS..b.rows.len(), mag, "flux_d").numeric[1].1)
        );
    }
}

/// On a clean real box the filter's noise comes from the data: innovations are consistent
/// with it and (almost) nothing is refused by the gate (was 69 % with the sensor's 0.02 nT).
#[test]
fn real_box_innovations_are_not_rejected() {
    let Some(b) = boxes() else { return };
    let e = est(Method::Kf, "tl16+fluxmod+field");
    let (_, comp) = compensate_trace(
        &trace(&b, 0..BOX1_ROWS, "mag_4_uc", "flux_d"),
        &e,
        None,
        false,
    )
    .unwrap();
    let flags = comp.flags.unwrap();
    let rejected = flags
        .iter()
        .filter(|&&f| f & Flags::INNOVATION_REJECTED != 0)
        .count() as f64
        / flags.len() as f64;
    let noise = comp.coefficients.unwrap().noise_nt.unwrap();
    eprintln!(
        "box 1: {:.2} % rejected, noise {noise:.3} nT",
        100.0 * rejected
    );
    assert!(rejected < 0.05, "{:.1} % rejected", 100.0 * rejected);
    assert!(
        noise > 0.5,
        "the real model error is nT-sized, got {noise} nT"
    );
}

/// Real time from an unknown start: the output is exactly the raw signal (interference 0)
/// while `NOT_CONVERGED` (a half-learnt estimate put ~9 000 nT into the first 30 s). The
/// flag clears only once every heading's manoeuvres are flown, near the box's end (when and
/// how well: `real_boxes_realtime.rs`); from then on the compensated signal must vary less
/// than the raw one.
#[test]
fn real_time_on_a_real_box_starts_sane() {
    let Some(b) = boxes() else { return };
    let t = trace(&b, 0..BOX1_ROWS, "mag_4_uc", "flux_d");
    let raw = t.col("mag").unwrap().to_vec();
    let (_, comp) = compensate_trace(&t, &est(Method::Kf, "tl16+field"), None, true).unwrap();
    let flags = comp.flags.unwrap();
    let mut not_converged = 0;
    for i in 0..flags.len() {
        if flags[i] & Flags::NOT_CONVERGED != 0 {
            not_converged += 1;
            assert_eq!(comp.interference_nt[i], 0.0, "row {i}");
            assert_eq!(comp.compensated_nt[i], raw[i], "row {i}");
        }
    }
    let clears = flags.iter().position(|f| f & Flags::NOT_CONVERGED == 0);
    eprintln!(
        "box 1 real time: NOT_CONVERGED on {not_converged} of {} records, clears at {:?} s",
        flags.len(),
        clears.map(|c| c as f64 / FS_HZ)
    );
    assert!(not_converged > BOX1_ROWS / 2);
    if let Some(c) = clears {
        assert!(band_std_nt(&comp.compensated_nt[c..]) < 0.5 * band_std_nt(&raw[c..]));
    }
}

/// A positionless trace needs an assumed speed for the filter's anomaly, never a silent
/// frozen position; TL needs none.
#[test]
fn positionless_trace_needs_an_assumed_speed_for_the_filter() {
    let Some(b) = boxes() else { return };
    let t = trace(&b, 0..2000, "mag_4_uc", "flux_d");
    let mut e = est(Method::Kf, "tl16+field");
    e.speed_mps = None;
    let err = compensate_trace(&t, &e, None, false).unwrap_err();
    assert!(format!("{err:#}").contains("--speed-mps"), "{err:#}");
    e.method = Method::Tl;
    assert!(compensate_trace(&t, &e, None, false).is_ok());
    let (_, kf) = compensate_trace(&t, &est(Method::Kf, "tl16+field"), None, false).unwrap();
    assert!(kf
        .warnings
        .iter()
        .any(|w| w.contains("assumed ground speed")));
}

/// Survey mode says when most of a flight is refused: box-1 coefficients applied to box 2
/// have 68 % of the samples refused by the gate (at the scalar's noise), and the run says
/// so, with the share and the calibration's own model error (it used to say nothing).
#[test]
fn applied_coefficients_say_when_most_samples_are_refused() {
    let Some(b) = boxes() else { return };
    let applied = applied_to_box2(&b, "mag_4_uc", "flux_d", Method::Kf, DEFAULT_MODEL);
    let flags = applied.flags.unwrap();
    let refused = flags
        .iter()
        .filter(|&&f| f & Flags::INNOVATION_REJECTED != 0)
        .count() as f64
        / flags.len() as f64;
    let warning = applied
        .warnings
        .iter()
        .find(|w| w.contains("refused by the innovation gate"));
    eprintln!(
        "box 1 → box 2: {:.1} % refused; {warning:?}",
        100.0 * refused
    );
    assert!(refused > 0.05);
    let w = warning.expect("a warning about the refused samples");
    assert!(
        w.starts_with(&format!("{:.0} % of the samples", 100.0 * refused)),
        "{w}"
    );
    assert!(w.contains("unexplained"), "{w}");
}

/// The `anomaly` column is relative to the flight's first reading throughout. The filter
/// holds its states relative to a reference that the epoch builder moves whenever the
/// scalar drifts 2 000 nT from it (f32 resolution); the raw `mag_3` swings thousands of nT
/// with the aircraft's attitude, so the column stepped ±2 000 nT 16 times over the two
/// boxes, and the aircraft-only FOM (compensated − anomaly) read 8 802 nT against a FOM of
/// 406 (the paper filter on both boxes). Measured (this commit): largest sample-to-sample
/// change 3.7 nT; aircraft-only FOM 376 nT (the default, with the witness: 203 against
/// 220, was 8 729).
#[test]
fn the_anomaly_column_does_not_step_when_the_filter_re_references() {
    let Some(b) = boxes() else { return };
    let whole = trace(&b, 0..b.rows.len(), "mag_3_uc", "flux_b");
    let e = est(Method::Kf, DEFAULT_MODEL);
    let (flight, comp) = compensate_trace(&whole, &e, None, false).unwrap();
    let anomaly = comp.anomaly_nt.as_deref().expect("the filter's anomaly");
    let raw_swing = flight
        .mag_nt
        .iter()
        .fold(f64::NEG_INFINITY, |m, v| m.max(*v))
        - flight.mag_nt.iter().fold(f64::INFINITY, |m, v| m.min(*v));
    assert!(
        raw_swing > 4000.0,
        "the boxes re-reference: {raw_swing:.0} nT"
    );
    let step = anomaly
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .fold(0.0, f64::max);
    let s = magcomp::calibration::summary::summarise(&flight, &comp);
    let (fom, aircraft) = (s.fom_nt.unwrap(), s.aircraft_fom_nt.unwrap());
    println!("largest anomaly step {step:.1} nT; FOM {fom:.1}, aircraft-only {aircraft:.1} nT");
    assert!(step < 50.0, "{step:.1} nT");
    assert!(aircraft < 1.5 * fom, "{aircraft:.1} against {fom:.1}");
}
