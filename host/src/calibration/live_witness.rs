//! `compensate --realtime` with the fluxgate as a witness, as the board flies it
//! (`magcomp_core::compensator::witness`): the model's filter and beside it the same model
//! with `fluxmod`, both causal over the same samples, each record the shown filter's by the
//! board's own rule ([`WitnessChoice`]). Without it the host's real-time view of a flight
//! whose fluxgate sees the aircraft was not what the board shows (the real SGL boxes'
//! `mag_3` with `flux_b`, box 2 band std on the board: 4.6 nT from the paper filter alone,
//! 2.1 with the pair; `compensate --realtime`: 5.2 alone, 3.3 with the pair).

use super::result::Compensation;
use super::{kf, EstimatorSettings};
use crate::flight::Flight;
use crate::io::trace::Trace;
use crate::model::spec::ModelSpec;
use anyhow::{ensure, Result};
use magcomp_core::compensator::witness::{Shown, WitnessChoice};
use magcomp_core::compensator::Output;
use magcomp_core::model::TermKind;
use magcomp_core::Flags;

/// The witnessed form of `model_text` when the pair runs: the default estimator (not a
/// method asked for by name, as post-flight considers the witness only then), calibrating
/// in flight (`calibrating_live`: real time without coefficients), a model with induced
/// terms and no `fluxmod` yet (the board's rule).
pub(super) fn witnessed_model(
    est: &EstimatorSettings,
    model_text: &str,
    calibrating_live: bool,
) -> Option<String> {
    if !(calibrating_live && est.cross_check && est.live_witness) {
        return None;
    }
    let spec = ModelSpec::parse(model_text).ok()?;
    if spec.has(TermKind::FluxMod) || !spec.has(TermKind::Induced) {
        return None;
    }
    Some(spec.with(TermKind::FluxMod.name()).ok()?.text())
}

/// Both filters in real time on `trace`, merged record by record. A witness that cannot be
/// run (a flight it cannot be fitted on) leaves the model's filter alone, saying so.
pub(super) fn run_pair(
    trace: &Trace,
    est: &EstimatorSettings,
    model_text: &str,
    witnessed_text: &str,
) -> Result<(Flight, Compensation)> {
    let (paper, witnessed) = std::thread::scope(|s| {
        let w = s.spawn(|| kf::run_kf_method(trace, est, None, true, witnessed_text));
        let p = kf::run_kf_method(trace, est, None, true, model_text);
        (p, w.join().expect("the witnessed filter's run panicked"))
    });
    let (flight, mut paper) = paper?;
    let witness = match witnessed {
        Ok((_, w)) => w,
        Err(e) => {
            paper.warnings.push(format!(
                "the fluxgate witness ({witnessed_text}) could not run beside the filter: {e:#}"
            ));
            return Ok((flight, paper));
        }
    };
    let merged = merge(&flight, paper, witness)?;
    Ok((flight, merged))
}

/// Each record the shown filter's, at the level carried across switches; the coefficients
/// (and model) of the filter shown at the end, as the board's `GETCOEF` reads them.
fn merge(flight: &Flight, mut paper: Compensation, witness: Compensation) -> Result<Compensation> {
    let n = flight.len();
    ensure!(
        paper.interference_nt.len() == n && witness.interference_nt.len() == n,
        "internal: the witnessed filter gave {} records for {n} samples",
        witness.interference_nt.len()
    );
    let mut choice = WitnessChoice::for_rate(flight.sample_rate_hz);
    let mut shown_witness = 0usize;
    // A trace without positions (the anomaly modelled in time at an assumed speed) flags
    // every record NO_GPS: no outage the choice should hold through, as it does on the
    // board's records while its GPS is lost.
    let all_flags = |c: &Compensation| {
        c.flags
            .as_ref()
            .map_or(0, |f| f.iter().fold(u16::MAX, |a, b| a & b))
    };
    let throughout = all_flags(&paper) & all_flags(&witness) & Flags::NO_GPS;
    for i in 0..n {
        let (mut p, mut w) = (record(&paper, i), record(&witness, i));
        p.flags.0 &= !throughout;
        w.flags.0 &= !throughout;
        if (p.flags.0 | w.flags.0) & Flags::SURVEY_MODE != 0 {
            choice.freeze();
        }
        let o = choice.show(p, w);
        let witnessed = o.flags.contains(Flags::WITNESS);
        let (from, shown) = if witnessed {
            (&witness, w)
        } else {
            (&paper, p)
        };
        // The level carried across switches (f32, as the core holds it).
        let carried = o.interference_nt - shown.interference_nt;
        if witnessed || carried != 0.0 {
            let interference = from.interference_nt[i] + f64::from(carried);
            if witnessed {
                shown_witness += 1;
                copy_at(&mut paper.anomaly_nt, &witness.anomaly_nt, i);
                copy_at(&mut paper.innovation_nt, &witness.innovation_nt, i);
            }
            // The carried level leaves the anomaly: their sum stays the field.
            if let Some(a) = paper.anomaly_nt.as_mut().and_then(|a| a.get_mut(i)) {
                *a -= f64::from(carried);
            }
            paper.interference_nt[i] = interference;
            paper.compensated_nt[i] = flight.mag_nt[i] - interference;
        }
        if let Some(f) = paper.flags.as_mut() {
            f[i] = o.flags.0 | throughout;
        }
        if let Some(s) = paper.interference_sigma_nt.as_mut() {
            s[i] = f64::from(o.interference_sigma_nt);
        }
    }
    if shown_witness > 0 {
        // Said only when it changed what is shown: otherwise the records are the model's.
        paper.warnings.push(format!(
            "the fluxgate witness ran beside the filter, as on the board ({}): its records \
             (flag WITNESS) shown for {shown_witness} of {n} samples, {} switches{}",
            witness.model,
            choice.switches(),
            if choice.shown() == Shown::Witness {
                "; the coefficients are the witnessed filter's"
            } else {
                ""
            }
        ));
    }
    if choice.shown() == Shown::Witness {
        paper.model = witness.model;
        paper.coefficients = witness.coefficients;
        paper.regressors = witness.regressors;
    }
    Ok(paper)
}

/// The filter's record of sample `i` as the core gave it (the interference in f32).
fn record(c: &Compensation, i: usize) -> Output {
    let col = |v: &Option<Vec<f64>>| v.as_ref().map_or(f32::NAN, |v| v[i] as f32);
    Output {
        t_s: 0.0,
        mag: None,
        interference_nt: c.interference_nt[i] as f32,
        compensated: None,
        anomaly_nt: col(&c.anomaly_nt),
        innovation_nt: col(&c.innovation_nt),
        innovation_var_nt2: f32::NAN,
        interference_sigma_nt: col(&c.interference_sigma_nt),
        flags: Flags(c.flags.as_ref().map_or(0, |f| f[i])),
    }
}

/// `into[i] = from[i]` where both columns exist.
fn copy_at(into: &mut Option<Vec<f64>>, from: &Option<Vec<f64>>, i: usize) {
    if let (Some(v), Some(f)) = (into.as_mut(), from.as_ref()) {
        v[i] = f[i];
    }
}
