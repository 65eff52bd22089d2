//! What an acquisition is set up with: the sensors' nominal rates and settings, the
//! board's compensator configuration, and why a setup is refused.

use crate::compensator::{CompensatorConfig, CompensatorError};
use crate::protocol::aligner::AlignerConfig;
use crate::protocol::fluxgate::{FluxCalibration, FluxTempCal, FluxgateCal};
use crate::protocol::scalar::ScalarConfig;

/// Fluxgate full scale of the reference board (±nT over ±2^23 ADC codes).
pub const FLUX_FULL_SCALE_NT: f32 = 100_000.0;
/// Highest accepted nominal rate of any sensor (Hz): the virtual clock counts whole µs.
pub const MAX_RATE_HZ: f64 = 100_000.0;

/// Nominal rates and sensor settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AcqConfig {
    /// Scalar sample rate: sets the time base.
    pub scalar_hz: f64,
    /// Fluxgate and GPS frame rates: set the staleness limits only.
    pub flux_hz: f64,
    pub gps_hz: f64,
    pub scalar: ScalarConfig,
    /// ADC counts (SPI) or sensor-frame nT (ASCII) → body frame.
    pub flux_cal: FluxgateCal,
    /// Body frame → calibrated body frame (`fluxcal`; identity when none).
    pub flux_scalar_cal: FluxCalibration,
    /// The fluxgate's temperature drift (`fluxtemp`, `SETFTEMP`), applied before
    /// `flux_scalar_cal` (none when all zero).
    pub flux_temp_cal: FluxTempCal,
}

impl AcqConfig {
    /// Default scalar parser and a ±100 000 nT fluxgate with identity axes.
    pub fn new(scalar_hz: f64, flux_hz: f64, gps_hz: f64) -> Self {
        Self {
            scalar_hz,
            flux_hz,
            gps_hz,
            scalar: ScalarConfig::default(),
            flux_cal: FluxgateCal::full_scale(FLUX_FULL_SCALE_NT),
            flux_scalar_cal: FluxCalibration::IDENTITY,
            flux_temp_cal: FluxTempCal::NONE,
        }
    }

    /// Stale after 2.5 periods of the sensor: one missed frame is tolerated, two are not.
    /// Position is held, not extrapolated: the virtual clock carries no sub-sample timing.
    pub fn aligner_config(&self) -> AlignerConfig {
        AlignerConfig {
            flux_stale_us: (2.5e6 / self.flux_hz) as u64,
            gps_stale_us: (2.5e6 / self.gps_hz) as u64,
            extrapolate_gps: false,
            flux_period_us: (1e6 / self.flux_hz) as u64,
        }
    }

    /// Scalar period in whole µs (the virtual clock's step), rounded so a rate measured
    /// as 9.999999999 Hz still steps 100 000 µs.
    pub fn period_us(&self) -> u64 {
        libm::round(1e6 / self.scalar_hz) as u64
    }

    pub(super) fn valid(&self) -> bool {
        [self.scalar_hz, self.flux_hz, self.gps_hz]
            .iter()
            .all(|r| r.is_finite() && *r > 0.0 && *r <= MAX_RATE_HZ)
    }
}

/// The board's scalar variance floor (nT 1σ): the sensor's noise plus what the model cannot
/// follow on a real installation (`CompensatorConfig::noise_nt`'s meaning), which the
/// innovations only show after the fact. On the real SGL boxes the model error is 0.2–0.8
/// nT (the post-flight filter tunes mag_5's to 0.39). Flown from the sensor's 0.02 nT, the
/// board fused the pattern's first manoeuvres at full weight before its adapted variance
/// rose, and locked their unmodelled part into the coefficients: box 2 compensated at
/// 1.09 / 8.05 / 11.36 nT band std (mag_5 / mag_4 / mag_3) where this floor gives 0.71 /
/// 3.55 / 4.63, post-flight 0.77 / 1.40 / 4.41. On the simulator (model error ~0.01 nT) it
/// costs the board's calibration 0.0317 → 0.0356 nT, and makes its records' bound hold
/// about the minute's mean too (error / bound 0.51–1.10 where it was 1.4–4.6).
pub const BOARD_NOISE_FLOOR_NT: f32 = 0.3;

/// Compensator settings for a rate and a derivative ring of `window` samples: the ring
/// holds `2·half_width + 1` samples, so above ~`window`/0.1 Hz the derivative spans fewer
/// than ±0.05 s rather than the filter refusing to start. Board and replay both use this.
pub fn compensator_config(scalar_hz: f32, window: usize) -> CompensatorConfig {
    let mut cfg = CompensatorConfig::for_rate(scalar_hz);
    // The board cannot tune its noise on the whole flight as the host does: it follows
    // what its innovations show,
    cfg.adaptive_noise = true;
    // from a floor of what no real installation's model follows, not the sensor's 0.02 nT.
    cfg.noise_nt = BOARD_NOISE_FLOOR_NT;
    cfg.epoch.half_width = cfg
        .epoch
        .half_width
        .min(window.saturating_sub(1) / 2)
        .max(1);
    cfg
}

/// Why an acquisition could not be set up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AcqError {
    /// A rate is not finite, ≤ 0, or above [`MAX_RATE_HZ`].
    BadRate,
    Compensator(CompensatorError),
}
