//! The anomaly-process stage: post-flight, besides the paper's stationary process, the
//! processes whose σ1 varies along the track with the local roughness of the anomaly
//! ([`FIELD_PROFILES`]) at [`FIELD_PROFILE_SCALES`] of σ1²; the one under which the data are
//! most likely (innovation likelihood of the calibration pass) wins.

use super::super::tuning::innovation_nll;
use super::super::{field_profile, interference_of, parallel, KfOptions};
use super::super::{FIELD_PROFILES, FIELD_PROFILE_SCALES};
use super::filter_pass::{self, CalibrationPass, PassSetup};
use crate::flight::Flight;
use anyhow::Result;
use magcomp_core::compensator::CompensatorConfig;

/// The anomaly process the stage chose.
#[derive(Clone, Debug)]
pub(crate) struct FieldProcessStage {
    /// Per-sample multiplier of the field's process-noise variance (None = stationary at
    /// the spectral σ1, the paper's model).
    pub profile: Option<Vec<f64>>,
    /// "stationary" or the profile and σ1² scale chosen.
    pub label: String,
    /// The family chosen (0 the stationary, k the k-th profile); None when the stage did
    /// not run.
    pub family: Option<usize>,
}

impl FieldProcessStage {
    /// The paper's stationary process, unchosen.
    pub fn stationary() -> Self {
        Self {
            profile: None,
            label: String::from("stationary"),
            family: None,
        }
    }

    /// Whether the choice runs: only when σ1 itself is estimated (a σ1 the user gives is
    /// taken as the model) and the run calibrates; in the calibration a user is given
    /// (`KfOptions::jackknife`), only where the model follows the signal to the scalar's own
    /// noise (`model_error`: the noise stage found error beyond it). The runs made for
    /// other ends (diagnosis, a first pass for `fluxcal`) keep the likelihood's choice: a
    /// diagnosis compares models on the innovations they leave.
    ///
    /// The roughness is measured on the scalar less the interference estimate, which is
    /// the anomaly only where the model follows the interference. Where it leaves an error
    /// (a real aircraft's: 0.5–4 nT on the SGL boxes, largest in the manoeuvres) that
    /// residual is rough where the aircraft manoeuvres, not where the geology is, and the
    /// likelihood then chose a field loosened exactly where the coefficients are learnt,
    /// which took interference: box 1 → 2 band std `mag_5` 0.77 nT (TL18-OLS 0.66), `mag_3`
    /// 1.73; 0.66 and 1.57 under the stationary process. Over a strong shallow anomaly at
    /// 300 m, where the model holds and the roughness is the geology's, the profile is what
    /// keeps the coefficients clean (broad seeds 1–3: 0.032 / 0.066 / 0.093 nT with it, 0.24
    /// / 0.10 / 0.42 without); the flight's held-out band figure, tried as the judge, chose
    /// the stationary process there (it carries the geology's band signal).
    pub fn applies(opts: &KfOptions, model_error: bool) -> bool {
        opts.field_profiles
            && opts.model.field
            && opts.sigma1.is_none()
            && opts.coefficients.is_none()
            && !(model_error && opts.jackknife)
    }

    /// The stationary process (the paper's) and the [`FIELD_PROFILES`], each at the
    /// [`FIELD_PROFILE_SCALES`] of the spectral σ1², run as calibration passes; the one
    /// with the least innovation NLL wins. The scales are bounded (¼–1 × σ1²): an
    /// unbounded likelihood search for σ1 runs away when the data hold an effect the model
    /// lacks (model.md §3). `stationary` is the calibration pass at `cfg` with `held` held
    /// under the stationary process at 1 × σ1².
    ///
    /// `family`: only that process (0 the stationary, k the k-th profile) at its scales,
    /// beside the stationary at 1 × σ1² (a second run on the calibrated fluxgate: the first
    /// run's choice of family, its scale chosen again).
    pub fn choose(
        flight: &Flight,
        opts: &KfOptions,
        (cfg, held): (CompensatorConfig, &[Vec<f32>]),
        stationary: &CalibrationPass,
        family: Option<usize>,
    ) -> Result<Self> {
        let interference = interference_of(&stationary.regressors, &stationary.coefficients);
        let mut best = (innovation_nll(&stationary.outputs), None, 0);
        let ones = vec![1.0; flight.len()];
        let local: Vec<Vec<f64>> = FIELD_PROFILES
            .iter()
            .map(|&p| field_profile(flight, &interference, cfg.noise_nt as f64, p))
            .collect();
        let trials: Vec<(usize, f64)> = (0..=local.len())
            .flat_map(|k| FIELD_PROFILE_SCALES.iter().map(move |&m| (k, m)))
            // The stationary process at 1 × σ1² is the pass given.
            .filter(|&(k, m)| !(k == 0 && m == 1.0))
            .filter(|&(k, _)| family.is_none_or(|f| f == k))
            .collect();
        let profile = |k: usize, m: f64| -> Vec<f64> {
            let p = if k == 0 { &ones } else { &local[k - 1] };
            p.iter().map(|v| v * m).collect()
        };
        // Independent passes (on the cores); the choice runs in their order.
        let nlls = parallel::map(&trials, |&(k, m)| {
            let p = profile(k, m);
            let setup = PassSetup {
                field_profile: Some(&p),
                ..PassSetup::held(cfg, held)
            };
            let outs = filter_pass::run(flight, opts, &setup, None, false)?.outputs;
            Ok::<_, anyhow::Error>(innovation_nll(&outs))
        });
        for (&(k, m), nll) in trials.iter().zip(nlls) {
            let nll = nll?;
            if nll < best.0 {
                best = (nll, Some((k, m)), k);
            }
        }
        let Some((k, m)) = best.1 else {
            return Ok(Self {
                family: Some(0),
                ..Self::stationary()
            });
        };
        let label = match k {
            0 => format!("stationary, {m} × σ1²"),
            _ => {
                let (step, half, median) = FIELD_PROFILES[k - 1];
                format!(
                    "local roughness (step {step}, ±{half} samples at 10 Hz, {}), {m} × σ1²",
                    if median { "median" } else { "mean" }
                )
            }
        };
        Ok(Self {
            profile: Some(profile(k, m)),
            label,
            family: Some(best.2),
        })
    }
}
