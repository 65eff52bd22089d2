//! The records of the input corrections: what a calibration did to the scalar and the
//! fluxgate before the filter (estimated by `estimate::corrections`, stored in the
//! coefficient file, sent to the board). Plain data here, below the filter, so the filter's
//! options and results can carry them without importing their estimators.

use serde::{Deserialize, Serialize};

/// What was done to the flight before the filter (estimated, or given from a coefficient
/// file).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Preprocessing {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scalar_lag: Option<ScalarLag>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fluxgate_temperature: Option<FluxgateTemperature>,
}

/// The estimated delay of the scalar behind the fluxgate/GPS.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScalarLag {
    /// τ (s): the scalar reports at t what it measured at t − τ.
    pub lag_s: f64,
    /// 1σ of τ from the curvature of the objective (s).
    pub sigma_s: f64,
}

/// The temperature correction of the fluxgate.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FluxgateTemperature {
    /// The temperature channel (trace column).
    pub channel: String,
    /// `T_ref`: the flight's mean temperature (channel units, °C).
    pub reference_degc: f64,
    /// `b` (nT/°C per axis) and its 1σ.
    pub bias_nt_per_degc: [f64; 3],
    pub bias_sigma_nt_per_degc: [f64; 3],
    /// `s` (1/°C per axis) and its 1σ.
    pub scale_per_degc: [f64; 3],
    pub scale_sigma_per_degc: [f64; 3],
}

impl FluxgateTemperature {
    /// Corrected fluxgate vector at temperature `t_degc` (NaN if the temperature is missing:
    /// the sample is then flagged, not silently left uncorrected).
    pub fn apply(&self, b: [f64; 3], t_degc: f64) -> [f64; 3] {
        let d = t_degc - self.reference_degc;
        if !d.is_finite() {
            return [f64::NAN; 3];
        }
        std::array::from_fn(|i| {
            b[i] + d * (self.bias_nt_per_degc[i] + self.scale_per_degc[i] * b[i])
        })
    }
}
