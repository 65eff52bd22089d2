//! The result of calibrating or compensating a flight with either method, per sample. A
//! record of its own so that the checks of it (`applied`, `fom`) and the figures reported
//! from it (`summary`) import it without importing the code that computes it.

use super::coefficients::{CoefficientFile, Method};

/// Per-sample result of either method.
#[derive(Clone, Debug, Default)]
pub struct Compensation {
    pub model: String,
    pub method: Option<Method>,
    pub interference_nt: Vec<f64>,
    pub compensated_nt: Vec<f64>,
    pub anomaly_nt: Option<Vec<f64>>,
    pub innovation_nt: Option<Vec<f64>>,
    pub flags: Option<Vec<u16>>,
    /// Real time: each record's stated 1σ bound on its interference (nT; empty while not
    /// converged); the `interference_sigma` column.
    pub interference_sigma_nt: Option<Vec<f64>>,
    pub coefficients: CoefficientFileOpt,
    pub regressors: Vec<Vec<f32>>,
    /// What the user must know about this result (printed on stderr, `warnings` in JSON).
    pub warnings: Vec<String>,
    /// Calibration: the method's jackknife error (nT rms; `crate::estimate::jackknife`).
    pub jackknife_nt: Option<f64>,
    /// The same in the manoeuvre band: what a band-passed figure on another flight sees.
    pub band_jackknife_nt: Option<f64>,
    /// Calibration: the method's blocked cross-validation in the manoeuvre band
    /// (`crate::estimate::jackknife::holdout_band_nt`).
    pub holdout_band_nt: Option<f64>,
    /// Kalman filter calibration: how far its jackknife refits moved over what its own
    /// covariances allow (`crate::estimate::kf::KfJackknife::inflation`; ≈ 1 when its model
    /// holds).
    pub refit_inflation: Option<f64>,
    /// Why the figures that would pretend (IR, FOM, predicted error) are withheld
    /// (`qc::inputs`); None when they stand.
    pub withheld: Option<String>,
}

pub type CoefficientFileOpt = Option<CoefficientFile>;

impl Compensation {
    /// A real-time run (the board's view, `--realtime`): it carries each record's stated
    /// bound, which only the live filter states.
    pub fn is_live(&self) -> bool {
        self.interference_sigma_nt.is_some()
    }
}
