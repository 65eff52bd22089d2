//! One pass of the filter over the whole flight, the unit every stage is made of, and the
//! stationary calibration pass several stages start from (made once while their
//! configuration is the same).

use super::super::filter::{self, interference_mask, interference_regressors, HostCompensator};
use super::super::KfOptions;
use crate::flight::Flight;
use crate::model::spec::with_model;
use anyhow::{bail, Result};
use magcomp_core::compensator::{CompensatorConfig, Output};
use magcomp_core::epoch::Epoch;
use magcomp_core::AlignedSample;
use std::ops::Range;

/// What a pass is made with beside the user's options: the filter's configuration and
/// what the stages before it decided.
#[derive(Clone)]
pub(crate) struct PassSetup<'a> {
    pub cfg: CompensatorConfig,
    /// Coefficient combinations held at their prior (the excitation stage's).
    pub held: &'a [Vec<f32>],
    /// Per-sample multiplier of the anomaly's process-noise variance (the field process
    /// stage's; None = stationary, the paper's model).
    pub field_profile: Option<&'a [f64]>,
    /// Real time: switch to survey mode at this sample, as the operator's `MODE,SURVEY`
    /// would (`KfOptions::survey_from`; the pass whose records are output only).
    pub survey_from: Option<usize>,
    /// Samples whose scalar the filter does not learn from (the jackknife's refits).
    pub skip_updates: Option<Range<usize>>,
}

impl<'a> PassSetup<'a> {
    /// At `cfg`, nothing held, the stationary anomaly process, no switch, every update.
    pub fn plain(cfg: CompensatorConfig) -> Self {
        Self::held(cfg, &[])
    }

    /// At `cfg` with `held` held, otherwise [`Self::plain`].
    pub fn held(cfg: CompensatorConfig, held: &'a [Vec<f32>]) -> Self {
        Self {
            cfg,
            held,
            field_profile: None,
            survey_from: None,
            skip_updates: None,
        }
    }
}

/// What a pass gives: one output per sample, the interference regressors per sample
/// (when kept), the final coefficients and their covariance (k×k, row-major, physical
/// units), and whether the filter stayed healthy.
pub(crate) struct CalibrationPass {
    pub outputs: Vec<Output>,
    pub regressors: Vec<Vec<f32>>,
    pub coefficients: Vec<f64>,
    pub covariance: Vec<f64>,
    /// The filter's UD factors stayed finite with non-negative D after every sample.
    pub healthy: bool,
}

/// Filter passes made by this process (numbers the progress lines).
static PASSES: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// Real time with segment labels: where the pass freezes its coefficients (survey mode).
fn freeze_at(flight: &Flight, opts: &KfOptions, setup: &PassSetup, given: bool) -> Option<usize> {
    if opts.realtime && setup.survey_from.is_some() && !given {
        setup.survey_from
    } else if opts.realtime && opts.freeze_on_survey && !given {
        flight.segments.as_ref().and_then(|s| {
            let last = s
                .iter()
                .rposition(|l| crate::qc::figures::is_manoeuvre(l))?;
            Some(last + 1)
        })
    } else {
        None
    }
}

/// One pass of the compensator over all samples; exactly one output per sample. With
/// `coefficients` it applies them (survey mode), else it calibrates.
pub(crate) fn run(
    flight: &Flight,
    opts: &KfOptions,
    setup: &PassSetup,
    coefficients: Option<&[f64]>,
    keep_regressors: bool,
) -> Result<CalibrationPass> {
    let spec = &opts.model;
    let turn = |i: usize| -> bool {
        opts.turn_noise_scale != 1.0
            && flight
                .segments
                .as_ref()
                .is_some_and(|s| s[i].contains("turn"))
    };
    let freeze_at = freeze_at(flight, opts, setup, coefficients.is_some());
    with_model(spec, |model| {
        let mut comp = filter::build(&spec.text(), model, setup.cfg, coefficients, setup.held)?;
        let mask = interference_mask(&model);
        let k = model.coefficient_count();
        let mut outs = Vec::with_capacity(flight.len());
        let mut healthy = true;
        // Post-flight calibration makes a dozen or more passes; each says how it goes.
        let pass_no = PASSES.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        let mut progress = crate::io::progress::Progress::new(
            &format!("Kalman filter pass {pass_no}"),
            crate::io::progress::quiet_progress(false),
        );
        let mut regs = Vec::new();
        let mut buf = vec![0.0f32; k];
        let mut keep = |ep: &Epoch, comp: &HostCompensator| {
            if keep_regressors {
                interference_regressors(comp, ep, &mask, &mut buf);
                regs.push(buf.clone());
            }
        };
        for (i, s) in flight.samples.iter().enumerate() {
            if freeze_at == Some(i) {
                comp.set_survey_mode(true);
            }
            if let Some(p) = setup.field_profile {
                comp.set_field_noise_scale(p[i] as f32);
            }
            comp.set_noise_scale(if turn(i) {
                opts.turn_noise_scale as f32
            } else {
                1.0
            });
            let skipped;
            let s = match &setup.skip_updates {
                Some(r) if r.contains(&i) => {
                    // A sample without its scalar predicts and does not update.
                    skipped = AlignedSample { mag: None, ..*s };
                    &skipped
                }
                _ => s,
            };
            if let Some((ep, out)) = comp.push_epoch(s) {
                keep(&ep, &comp);
                outs.push(out);
            }
            healthy &= comp.filter().is_healthy();
            progress.tick();
        }
        progress.done();
        while let Some((ep, out)) = comp.flush_epoch() {
            keep(&ep, &comp);
            outs.push(out);
        }
        if outs.len() != flight.len() {
            bail!(
                "internal: {} outputs for {} samples",
                outs.len(),
                flight.len()
            );
        }
        let mut c = vec![0.0f32; k];
        comp.coefficients(&mut c);
        let covariance = (0..k * k)
            .map(|ij| comp.coefficient_covariance(ij / k, ij % k) as f64)
            .collect();
        healthy &= comp.filter().is_healthy();
        Ok(CalibrationPass {
            outputs: outs,
            regressors: regs,
            coefficients: c.iter().map(|v| *v as f64).collect(),
            covariance,
            healthy,
        })
    })
}

/// The calibration pass with the stationary anomaly process, no survey switch and its
/// regressors kept, at `cfg` with `held` held: what the noise check, the excitation check,
/// the anomaly-process choice and the calibration pass each start from. A pass is a
/// deterministic function of the flight, the options and these two, so a stage whose
/// configuration is the same takes the pass already made instead of making it again.
pub(crate) struct StationaryPass {
    cfg: CompensatorConfig,
    held: Vec<Vec<f32>>,
    pub pass: CalibrationPass,
}

impl StationaryPass {
    /// `made` when it was made at `cfg` with `held`, else a new pass.
    pub fn at(
        flight: &Flight,
        opts: &KfOptions,
        (cfg, held): (CompensatorConfig, &[Vec<f32>]),
        made: Option<Self>,
    ) -> Result<Self> {
        match made {
            Some(m) if m.cfg == cfg && m.held == held => Ok(m),
            _ => Ok(Self {
                cfg,
                held: held.to_vec(),
                pass: run(flight, opts, &PassSetup::held(cfg, held), None, true)?,
            }),
        }
    }
}
