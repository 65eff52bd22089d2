//! What the board runs, as constants (pure, no embassy, so hil-tests and the benchmark
//! include this file too): the model, the filter capacities and the sensor rates. The
//! bytes → records path itself is `magcomp_core::acquisition`, the same code as
//! `magcomp replay`.

use magcomp_core::acquisition::{AcqConfig, AcqError, Acquisition, compensator_config};
use magcomp_core::compensator::CompensatorError;
use magcomp_core::model::Model;
use magcomp_core::protocol::command::model_hash;

/// The model compiled into the board (the paper's: 16 TL coefficients + 5 field states).
pub const MODEL_SPEC: &[u8] = b"tl16+field";
/// Coefficients of `MODEL_SPEC` (the index bound of GETCOEF/SETCOEF).
pub const N_COEF: usize = 16;
/// State capacity and derivative-window capacity of the on-board filter. 24 holds the paper
/// model (21) plus two tie-point clones; RAM scales with its square.
pub const STATE_CAPACITY: usize = 24;
pub const WINDOW: usize = 16;

/// Nominal sensor rates of the reference installation (Hz). The scalar rate sets the time
/// base; the fluxgate and GPS rates set the staleness limits (2.5 periods).
pub const SCALAR_HZ: f64 = 10.0;
pub const FLUX_HZ: f64 = 10.0;
pub const GPS_HZ: f64 = 1.0;

pub type BoardAcquisition = Acquisition<'static, STATE_CAPACITY, WINDOW>;

/// Model id stored in the coefficient blob.
pub fn model_id() -> u32 {
    model_hash(MODEL_SPEC)
}

/// Rates, default scalar parser, ±100 000 nT fluxgate with identity axes, no fluxgate
/// scalar calibration until one is loaded from flash or sent with `SETFLUX` (`fluxcal`).
pub fn acq_config() -> AcqConfig {
    AcqConfig::new(SCALAR_HZ, FLUX_HZ, GPS_HZ)
}

/// Starts (or restarts) the board's acquisition in place: no filter on the stack.
pub fn start(acq: &mut BoardAcquisition) -> Result<(), AcqError> {
    acq.reset_in_place(
        acq_config(),
        Model::paper(),
        compensator_config(SCALAR_HZ as f32, WINDOW),
    )
}

/// Restarts the compensator in place (`RESET`); sequence numbers and time base continue.
pub fn restart_filter(acq: &mut BoardAcquisition) -> Result<(), CompensatorError> {
    acq.reset_compensator(Model::paper(), compensator_config(SCALAR_HZ as f32, WINDOW))
}
