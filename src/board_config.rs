//! What the board runs, as constants (pure, no embassy, so hil-tests, the host tests and
//! the benchmark include this file too): the model, the filter capacities, the sensor rates,
//! and how each sensor port's bytes become events for the acquisition. The bytes → records
//! path itself is `magcomp_core::acquisition`, the same code as `magcomp replay`.

use magcomp_core::acquisition::{
    AcqConfig, AcqError, AcqRecord, Acquisition, FLUX_FULL_SCALE_NT, compensator_config,
};
use magcomp_core::compensator::CompensatorError;
use magcomp_core::model::Model;
use magcomp_core::protocol::command::{MAX_SENSORS, model_hash};
use magcomp_core::protocol::fluxgate::{FluxAsciiReader, FluxError, FluxgateCal};
use magcomp_core::protocol::multi_scalar::ScalarLine;
use magcomp_core::protocol::nmea::{NmeaError, NmeaReader, Sentence};
use magcomp_core::protocol::scalar::{ScalarConfig, ScalarError, ScalarReader};

/// The coefficient vector of the board (GETCOEF/SETCOEF indices, staged sets, the store's
/// blobs): the witnessed model's order, the paper model's 16 terms then `fluxmod`. The board
/// runs the paper model (16 TL coefficients + 5 field states) with this one beside it as the
/// fluxgate's witness (docs/firmware.md, "Fluxgate witness"); a paper set is this vector with
/// `fluxmod` 0.
pub const MODEL_SPEC: &[u8] = b"tl16+field+fluxmod";
/// The paper model's spec: the model id of the sets earlier firmware stored.
pub const PAPER_SPEC: &[u8] = b"tl16+field";
/// Whether the fluxgate's frames carry its temperature: the serial fluxgate's do
/// (`X,Y,Z,T*hh`); the SPI ADC (`flux-spi`) has no temperature channel, so a temperature
/// calibration (`SETFTEMP`) would turn every record `FLUX_STALE` there and is refused.
pub const FLUX_HAS_TEMPERATURE: bool = !cfg!(feature = "flux-spi");

/// Coefficients of `MODEL_SPEC` (the index bound of GETCOEF/SETCOEF).
pub const N_COEF: usize = 17;
/// Coefficients of the paper model: the vector's first ones.
pub const N_PAPER: usize = 16;
/// Index of `fluxmod`'s coefficient in the vector: 0 in a paper set.
pub const FLUXMOD: usize = N_PAPER;

/// The model of the board's main filter (and of sensors 1–2 on a counter line).
pub fn board_model() -> Model<'static> {
    Model::paper()
}

/// The model run beside it while single fields arrive (`Acquisition::attach_witness`).
pub fn witness_model() -> Model<'static> {
    Model::paper_with_fluxgate_witness()
}

/// State capacity and derivative-window capacity of the on-board filter. 24 holds the paper
/// model (21) plus two tie-point clones, or the witnessed model (22) plus two; RAM scales
/// with its square.
pub const STATE_CAPACITY: usize = 24;
pub const WINDOW: usize = 16;

/// Nominal sensor rates of the reference installation (Hz). The scalar rate sets the time
/// base; the fluxgate and GPS rates set the staleness limits (2.5 periods).
pub const SCALAR_HZ: f64 = 10.0;
pub const FLUX_HZ: f64 = 10.0;
pub const GPS_HZ: f64 = 1.0;

pub type BoardAcquisition = Acquisition<'static, STATE_CAPACITY, WINDOW>;

/// One sensor's set in the board's order ([`MODEL_SPEC`]).
pub type CoefSet = [f32; N_COEF];

/// `SETCOEF` values waiting for `MODE,SURVEY`, per sensor (channel of a counter line).
pub type Staged = [Option<CoefSet>; MAX_SENSORS];

/// No set staged.
pub const NONE_STAGED: Staged = [None; MAX_SENSORS];

/// Sensor `sensor`'s set as `GETCOEF` and `SAVE` read it: the staged one when one waits;
/// sensor 0's is the shown filter's (the paper filter's 16 values and `fluxmod` 0, or the
/// witnessed filter's 17); sensors 1–2 run the paper model (`fluxmod` 0).
pub fn coefficients(acq: &BoardAcquisition, staged: &Staged, sensor: usize) -> CoefSet {
    if let Some(Some(c)) = staged.get(sensor) {
        return *c;
    }
    let mut c = [0f32; N_COEF];
    match sensor {
        0 => {
            acq.coefficients(&mut c);
        }
        // while the witness runs in channel 1's compensator, sensor 1 has none: 0s
        s => {
            if let Some(comp) = acq.sensor(s) {
                comp.coefficients(&mut c[..N_PAPER]);
            }
        }
    }
    c
}

/// Whether sensor `sensor` holds a set worth storing: staged, loaded (survey mode), or
/// learnt from the counter lines that feed it. A single-sensor board's idle channels do
/// not, nor does channel 1 while the witness runs in its compensator.
pub fn holds_set(acq: &BoardAcquisition, staged: &Staged, sensor: usize) -> bool {
    staged.get(sensor).is_some_and(Option::is_some)
        || acq
            .sensor(sensor)
            .is_some_and(|c| c.is_survey_mode() || usize::from(acq.channels()) > sensor)
}

/// Loads sensor `sensor`'s set (survey mode). Sensor 0: with `fluxmod` 0 it is a paper set
/// for the paper filter, else the witnessed filter's, shown from then on. Sensors 1–2 run
/// the paper model: a set with `fluxmod` ≠ 0 is refused; sensor 1's takes channel 1's
/// compensator back from the witness (an installation of several magnetometers; where the
/// witness's set was shown, sensor 0 then calibrates afresh).
pub fn load_set(
    acq: &mut BoardAcquisition,
    sensor: usize,
    c: &CoefSet,
) -> Result<(), CompensatorError> {
    let paper = c[FLUXMOD] == 0.0;
    match sensor {
        0 if paper => acq.set_coefficients(&c[..N_PAPER]),
        0 => acq.set_coefficients(c),
        _ if !paper || c.iter().any(|v| !v.is_finite()) => Err(CompensatorError::BadCoefficients),
        s => acq
            .sensor_mut(s)
            .ok_or(CompensatorError::BadConfig)?
            .set_coefficients(&c[..N_PAPER]),
    }
}

/// Model id stored in the coefficient blob.
pub fn model_id() -> u32 {
    model_hash(MODEL_SPEC)
}

/// Model id of the 16-value blobs earlier firmware (the paper model alone) stored.
pub fn paper_model_id() -> u32 {
    model_hash(PAPER_SPEC)
}

/// Rates, default scalar parser, ±100 000 nT fluxgate with identity axes, no fluxgate
/// scalar calibration until one is loaded from flash or sent with `SETFLUX` (`fluxcal`).
pub fn acq_config() -> AcqConfig {
    AcqConfig::new(SCALAR_HZ, FLUX_HZ, GPS_HZ)
}

/// Starts (or restarts) the board's acquisition in place: no filter on the stack. The
/// witness is attached here because `reset_in_place` drops it.
pub fn start(acq: &mut BoardAcquisition) -> Result<(), AcqError> {
    acq.reset_in_place(
        acq_config(),
        board_model(),
        compensator_config(SCALAR_HZ as f32, WINDOW),
    )?;
    acq.attach_witness(witness_model())
        .map_err(AcqError::Compensator)
}

/// Restarts the compensator in place (`RESET`); sequence numbers and time base continue.
/// The witness, when attached, restarts with it (`reset_compensator` keeps it).
pub fn restart_filter(acq: &mut BoardAcquisition) -> Result<(), CompensatorError> {
    acq.reset_compensator(board_model(), compensator_config(SCALAR_HZ as f32, WINDOW))
}

/// One frame (or parse failure) from a sensor port, in arrival order.
pub enum Event {
    /// A single field or a multi-channel counter line (`multi_scalar`), or its error.
    Scalar(ScalarLine),
    /// Body frame (x forward, y starboard, z down), nT; the sensor's temperature (°C, NaN
    /// when the frame has none: SPI, a 3-field ASCII line).
    Flux(Result<[f32; 3], FluxError>, f32),
    Gps(Result<Sentence, NmeaError>),
}

impl Event {
    /// Into the acquisition: the record of a scalar line (`$MCREC`, or `$MCMREC` once
    /// counter lines arrive), nothing for the other ports.
    pub fn apply(self, acq: &mut BoardAcquisition) -> Option<AcqRecord> {
        match self {
            Event::Scalar(l) => acq.scalar_line(l),
            Event::Flux(r, temp_degc) => {
                acq.flux_result_temp(r, temp_degc);
                None
            }
            Event::Gps(r) => {
                acq.nmea_result(r);
                None
            }
        }
    }

    /// The event of a line the UART flagged an error on (`protocol::uart_errors`): a
    /// scalar line (no checksum: a digit may be wrong) or a fluxgate frame is rejected, its
    /// record flagged `PARSE_ERROR` and counted as the port's parse error; a GPS sentence
    /// keeps its own checksum's verdict.
    pub fn with_uart_error(self) -> Event {
        match self {
            Event::Scalar(_) => Event::Scalar(ScalarLine::Single(Err(ScalarError::Uart))),
            Event::Flux(_, temp_degc) => Event::Flux(Err(FluxError::Uart), temp_degc),
            gps @ Event::Gps(_) => gps,
        }
    }
}

/// A sensor port's parser, as its UART task runs it: the event a byte completes, then the
/// further events that byte owes (only the scalar port's merged lines owe any).
pub trait SensorPort {
    fn push(&mut self, b: u8) -> Option<Event>;
    fn owed(&mut self) -> Option<Event> {
        None
    }
}

impl SensorPort for ScalarPort {
    fn push(&mut self, b: u8) -> Option<Event> {
        ScalarPort::push(self, b)
    }
    fn owed(&mut self) -> Option<Event> {
        ScalarPort::owed(self)
    }
}

impl SensorPort for GpsPort {
    fn push(&mut self, b: u8) -> Option<Event> {
        GpsPort::push(self, b)
    }
}

impl SensorPort for FluxAsciiPort {
    fn push(&mut self, b: u8) -> Option<Event> {
        FluxAsciiPort::push(self, b)
    }
}

/// The scalar port's parser (one per UART task on the board).
pub struct ScalarPort(ScalarReader);

impl Default for ScalarPort {
    fn default() -> Self {
        Self::new()
    }
}

impl ScalarPort {
    pub fn new() -> Self {
        Self(ScalarReader::new(ScalarConfig::default()))
    }
    pub fn push(&mut self, b: u8) -> Option<Event> {
        self.0.push_line(b).map(Event::Scalar)
    }
    /// A further sample of the last line, when it ran into the next (a lost terminator):
    /// taken after each byte until None, so each sample keeps its record and its time.
    pub fn owed(&mut self) -> Option<Event> {
        self.0.owed_line().map(Event::Scalar)
    }
}

/// The GPS port's parser: GSV, GSA, proprietary… sentences are valid but unused and are
/// dropped here rather than take a channel slot.
pub struct GpsPort(NmeaReader);

impl Default for GpsPort {
    fn default() -> Self {
        Self::new()
    }
}

impl GpsPort {
    pub fn new() -> Self {
        Self(NmeaReader::new())
    }
    pub fn push(&mut self, b: u8) -> Option<Event> {
        match self.0.push(b)? {
            Ok(Sentence::Unsupported { .. }) => None,
            r => Some(Event::Gps(r)),
        }
    }
}

/// The fluxgate's serial ASCII alternative: sensor frame → body frame by the board's axes.
/// (The flight image's fluxgate; the SPI ADC is the `flux-spi` build, not yet flight-ready:
/// docs/firmware.md.)
#[allow(dead_code)]
pub struct FluxAsciiPort {
    reader: FluxAsciiReader,
    axes: FluxgateCal,
}

impl Default for FluxAsciiPort {
    fn default() -> Self {
        Self::new()
    }
}

#[allow(dead_code)]
impl FluxAsciiPort {
    pub fn new() -> Self {
        Self {
            reader: FluxAsciiReader::new(),
            axes: FluxgateCal::full_scale(FLUX_FULL_SCALE_NT),
        }
    }
    pub fn push(&mut self, b: u8) -> Option<Event> {
        let axes = self.axes;
        self.reader.push_frame(b).map(|r| match r {
            Ok((v, t)) => Event::Flux(Ok(axes.to_body(v)), t),
            Err(e) => Event::Flux(Err(e), f32::NAN),
        })
    }
}
