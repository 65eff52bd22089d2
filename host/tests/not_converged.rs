//! `NOT_CONVERGED` (calibrate mode): set while the predicted 1σ of the interference
//! estimate, `sqrt(hᵀ P h)` over the interference regressors only (or what the estimate
//! moved over the last minute), exceeds `CompensatorConfig::converged_sigma_nt` (default
//! 0.1 nT), or while a heading sector has not been flown; evaluated every 8th epoch and
//! held in between.

use magcomp::board::capture::{trace_to_capture, CaptureOptions};
use magcomp::sim::{simulate, SimConfig};
use magcomp_core::acquisition::{compensator_config, AcqConfig, Acquisition};
use magcomp_core::epoch::AlignedSample;
use magcomp_core::model::Model;
use magcomp_core::protocol::capture::{decode_line, MAX_CHUNK};
use magcomp_core::{Compensator, CompensatorConfig, Flags, MagCounts};

/// A simulated cloverleaf calibration flight through the board's acquisition path:
/// per record its `NOT_CONVERGED` flag and the σ last evaluated.
fn calibration(sigma_nt: f32) -> Vec<(bool, f32)> {
    let trace = simulate(&SimConfig::calibration_with_exit(5)).unwrap();
    let cap = trace_to_capture(&trace, &CaptureOptions::default()).unwrap();
    let mut cfg = compensator_config(10.0, 16);
    cfg.converged_sigma_nt = sigma_nt;
    let comp = Compensator::<24, 16>::new(Model::paper(), cfg).unwrap();
    let mut acq = Acquisition::new(AcqConfig::new(10.0, 10.0, 1.0), comp).unwrap();
    let mut out = Vec::new();
    let mut buf = [0u8; MAX_CHUNK];
    for l in cap.split(|&b| b == b'\n') {
        let Ok(Some(c)) = decode_line(l, &mut buf) else {
            continue;
        };
        for &b in &buf[..c.len] {
            if let Some(r) = acq.push_byte(c.port, b) {
                let s = acq.compensator().interference_sigma_nt();
                out.push((r.flags.contains(Flags::NOT_CONVERGED), s));
            }
        }
    }
    assert_eq!(out.len(), trace.len() - 1); // the last record is held for the derivative
    out
}

fn summary(r: &[(bool, f32)]) -> String {
    r.iter()
        .enumerate()
        .step_by(1000)
        .map(|(k, (f, s))| format!("{:.0} s: {s:.2} nT {}", k as f64 / 10.0, u8::from(*f)))
        .collect::<Vec<_>>()
        .join(", ")
}

#[test]
fn not_converged_while_the_pattern_is_flown_cleared_after_it_at_the_survey_requirement() {
    let thr = CompensatorConfig::for_rate(10.0).converged_sigma_nt;
    assert_eq!(thr, 0.1);
    let r = calibration(thr);
    eprintln!(
        "σ of the interference variation (0.1 nT threshold): {}",
        summary(&r)
    );
    let nc: Vec<bool> = r.iter().map(|x| x.0).collect();
    // set from the start (the priors allow tens of nT of interference) …
    assert!(nc[..100].iter().all(|&f| f));
    // … through the pattern (it ends at sample 6 985: every heading flown, the estimate
    // still moving), and cleared once it settles after it: the straight leg's last 150 s
    // (of 200) are clear. Measured with the board's 0.3 nT noise floor: first clear at
    // 690.4 s (the pattern ends at 698.5 s), last set at 863.9 s (the return turn) of 1 089.
    let first_clear = nc.iter().position(|&f| !f).unwrap();
    assert!(
        first_clear > 5000,
        "cleared at {first_clear}, before the last heading"
    );
    let last_set = nc.iter().rposition(|&f| f).unwrap();
    eprintln!(
        "first clear at sample {first_clear}, last set at {last_set} of {}",
        nc.len()
    );
    assert!(last_set < nc.len() - 1500, "last set at {last_set}");
    // evaluated every 8th epoch (record k = epoch k), held in between
    for k in 1..nc.len() {
        if nc[k] != nc[k - 1] {
            assert_eq!(k % 8, 0, "changed at {k}");
        }
    }
    // Before it first clears, a σ above the threshold always sets the flag. Once every
    // heading has been flown and it has cleared, the documented hysteresis holds (the
    // tolerance is the threshold here: the simulator's model error is below it): the flag
    // is set again only beyond twice the threshold, and never at or below it.
    for (k, (f, s)) in r.iter().enumerate().step_by(8).skip(20) {
        if k < first_clear {
            assert!(*s <= thr || *f, "epoch {k}: σ {s}");
        } else {
            assert!(*s <= 2.0 * thr || *f, "epoch {k}: σ {s} clear");
            assert!(*s > thr || !*f, "epoch {k}: σ {s} set");
        }
    }
}

#[test]
fn survey_mode_never_sets_not_converged() {
    let mut c =
        Compensator::<24, 16>::new(Model::paper(), CompensatorConfig::for_rate(10.0)).unwrap();
    c.set_coefficients(&[0.0; 16]).unwrap();
    let mut s = AlignedSample::empty(0.0);
    s.mag = Some(MagCounts(500_000_000));
    let mut n = 0;
    for k in 0..40 {
        s.t_s = f64::from(k) * 0.1;
        if let Some(o) = c.push(&s) {
            assert!(!o.flags.contains(Flags::NOT_CONVERGED));
            assert!(o.flags.contains(Flags::SURVEY_MODE));
            n += 1;
        }
    }
    assert!(n > 30);
}
