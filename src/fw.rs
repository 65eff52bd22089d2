//! The embassy tasks and their channels.

use core::sync::atomic::{AtomicU32, Ordering};

use embassy_executor::Spawner;
use embassy_futures::select::{Either, select};
use embassy_stm32::usart::{BufferedUartRx, BufferedUartTx};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_time::{Duration, Timer, with_timeout};
use embedded_io_async::{Read, Write};
use magcomp_core::acquisition::AcqRecord;
use magcomp_core::protocol::command::{
    Command, CommandError, CommandReader, FLUX_CAL_LEN, FLUX_TEMP_LEN, Mode, encode_ack_coef,
    encode_ack_indexed, encode_error,
};
use magcomp_core::protocol::common::{BufferFull, Cursor, crc16_ccitt};
use magcomp_core::protocol::fluxgate::{FluxCalibration, FluxTempCal};
use magcomp_core::protocol::lag_line::LagLine;
use magcomp_core::protocol::multi_raw::RawLine;
use magcomp_core::protocol::uart_errors::LineErrors;

#[cfg(feature = "board-acq")]
use defmt_rtt as _;
#[cfg(feature = "board-emu")]
use defmt_semihosting as _;

use crate::board;
use crate::board_config::{self as bc, BoardAcquisition, Event, N_COEF, SensorPort, Staged};
use crate::board_shape::{CoefStore as _, StoreError, Watchdog as _};
use crate::health::{self, Task};
use crate::store;
use crate::uart_stats;
use magcomp_core::model::Model;
use static_cell::ConstStaticCell;

/// A line for the output port (records < 192 bytes, multi records < 384 (`MAX_MULTI_RECORD_LEN`);
/// GETCOEF of all 17 coefficients < 320).
pub struct Line {
    buf: [u8; LINE_LEN],
    len: usize,
}

impl Line {
    const fn new() -> Self {
        Self {
            buf: [0; LINE_LEN],
            len: 0,
        }
    }
    fn bytes(&self) -> &[u8] {
        &self.buf[..self.len]
    }
    /// Fills the line with `f(out) -> Option<len>`; an empty line if it did not fit.
    fn fill(f: impl FnOnce(&mut [u8]) -> Option<usize>) -> Self {
        let mut l = Self::new();
        l.len = f(&mut l.buf).unwrap_or(0);
        l
    }
    /// `$<body>*CRC16\r\n` with `body` written by `f` (replies and the boot banner).
    fn sentence(f: impl FnOnce(&mut Cursor) -> Result<(), BufferFull>) -> Self {
        Self::fill(|out| {
            let mut c = Cursor::new(out);
            c.byte(b'$').ok()?;
            f(&mut c).ok()?;
            let crc = crc16_ccitt(&c.written()[1..]);
            c.byte(b'*').ok()?;
            c.hex_u16(crc).ok()?;
            c.bytes(b"\r\n").ok()?;
            Some(c.pos())
        })
    }
}

const LINE_LEN: usize = magcomp_core::protocol::multi_record::MAX_MULTI_RECORD_LEN;

type Mutex = CriticalSectionRawMutex;
static EVENTS: Channel<Mutex, Event, 16> = Channel::new();
static COMMANDS: Channel<Mutex, Command, 4> = Channel::new();
static OUT: Channel<Mutex, Line, 6> = Channel::new();

/// Counters shown by `STATUS` besides the acquisition's own (records, parser errors per
/// port) and the UART error flags (`uart_stats`): errors the UART driver returns (none in
/// embassy-stm32 0.6, whose buffered reads never fail; kept for a driver that does) and
/// rejected commands.
static UART_ERRORS: AtomicU32 = AtomicU32::new(0);
static CMD_ERRORS: AtomicU32 = AtomicU32::new(0);

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    // before anything can reset again: why the last run ended
    let boot = health::take_boot_info();
    let b = board::init();
    defmt::info!(
        "magcomp firmware on {}, scalar rate {} Hz",
        board::NAME,
        bc::SCALAR_HZ
    );
    OUT.send(Line::sentence(|c| {
        c.bytes(b"MCBOOT,")?;
        c.bytes(board::NAME.as_bytes())?;
        c.byte(b',')?;
        c.bytes(env!("CARGO_PKG_VERSION").as_bytes())?;
        c.bytes(b",RST=")?;
        c.bytes(boot.cause.word())?;
        if let Some(p) = &boot.panic {
            c.bytes(b",PANIC=")?;
            c.bytes(p.as_bytes())?;
        }
        // tells the harness that frames are acknowledged (`$MCSYN`)
        if cfg!(feature = "hil-sync") {
            c.bytes(b",SYNC")?;
        }
        Ok(())
    }))
    .await;
    match &boot.panic {
        Some(p) => defmt::warn!(
            "reset cause {}, after a panic at {}",
            boot.cause,
            p.as_str()
        ),
        None => defmt::info!("reset cause {}", boot.cause),
    }

    spawner.spawn(watchdog_task(b.watchdog).unwrap());
    spawner.spawn(output_task(b.out_tx).unwrap());
    spawner.spawn(command_task(b.out_rx).unwrap());
    // the acquisition (parsers' state, time base, ~7 KB compensator) lives in a static
    // initialised at compile time and started in place: the filter is never built on the
    // stack nor moved (stack peak = steady state)
    static ACQ: ConstStaticCell<BoardAcquisition> =
        ConstStaticCell::new(BoardAcquisition::placeholder(Model {
            field: false,
            terms: &[],
        }));
    let acq = ACQ.take();
    if bc::start(acq).is_err() {
        defmt::error!("compensator init failed");
        board::exit(false)
    }
    // the fluxgate's delay line for `SETLAG` (8 KiB): all zeros, so in .bss, not flash
    static LAG_LINE: ConstStaticCell<LagLine> = ConstStaticCell::new(LagLine::new());
    acq.attach_lag_line(LAG_LINE.take());
    spawner.spawn(acq_task(acq, b.store).unwrap());
    spawner.spawn(scalar_task(b.scalar).unwrap());
    spawner.spawn(gps_task(b.gps).unwrap());
    #[cfg(not(feature = "flux-spi"))]
    spawner.spawn(flux_uart_task(b.flux).unwrap());
    #[cfg(all(feature = "board-acq", feature = "flux-spi"))]
    spawner.spawn(flux_spi_task(b.flux).unwrap());
}

/// Reads a UART into `buf`; UART errors (overrun/framing/noise) are counted and the
/// parser resynchronises on the next line.
async fn read_some(rx: &mut BufferedUartRx<'static>, buf: &mut [u8]) -> usize {
    loop {
        match rx.read(buf).await {
            Ok(n) => return n,
            Err(_) => {
                UART_ERRORS.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

/// A sensor UART's bytes through its port parser into the event channel, forever; a
/// scalar line that ran into the next sends one event per sample it carried. A line the
/// UART flagged an error on (the port's count grew on the chunk it came in) goes as an
/// error (`Event::with_uart_error`), the samples it owes with it.
async fn forward(
    task: Task,
    uart: uart_stats::Port,
    mut rx: BufferedUartRx<'static>,
    mut port: impl SensorPort,
) -> ! {
    let mut buf = [0u8; 64];
    let mut errors = LineErrors::new(uart_stats::port_total(uart));
    let mut suspect = false;
    let checked = |ev: Event, suspect: bool| if suspect { ev.with_uart_error() } else { ev };
    loop {
        let n = health::idle(task, read_some(&mut rx, &mut buf)).await;
        errors.after_read(uart_stats::port_total(uart));
        for &b in &buf[..n] {
            if let Some(ev) = port.push(b) {
                suspect = errors.line_done();
                EVENTS.send(checked(ev, suspect)).await;
            }
            while let Some(ev) = port.owed() {
                EVENTS.send(checked(ev, suspect)).await;
            }
        }
    }
}

#[embassy_executor::task]
async fn scalar_task(rx: BufferedUartRx<'static>) {
    const TASK: Task = Task::Scalar;
    forward(TASK, uart_stats::Port::Scalar, rx, bc::ScalarPort::new()).await
}

#[embassy_executor::task]
async fn gps_task(rx: BufferedUartRx<'static>) {
    const TASK: Task = Task::Gps;
    forward(TASK, uart_stats::Port::Gps, rx, bc::GpsPort::new()).await
}

/// Fluxgate on its serial ASCII alternative (sensor frame → body frame by the board's axes).
#[cfg(not(feature = "flux-spi"))]
#[embassy_executor::task]
async fn flux_uart_task(rx: BufferedUartRx<'static>) {
    const TASK: Task = Task::Flux;
    forward(TASK, uart_stats::Port::Flux, rx, bc::FluxAsciiPort::new()).await
}

/// Fluxgate ADC (ADS131M03) on SPI: on each data-ready edge read one 15-byte frame
/// (status, 3 × 24-bit channels, CRC-16) and scale it to the body frame.
#[cfg(all(feature = "board-acq", feature = "flux-spi"))]
#[embassy_executor::task]
async fn flux_spi_task(mut f: board::FluxPort) {
    use magcomp_core::acquisition::FLUX_FULL_SCALE_NT;
    use magcomp_core::protocol::fluxgate::{
        FluxError, FluxgateCal, SPI_FRAME_LEN, decode_spi_frame,
    };
    let cal = FluxgateCal::full_scale(FLUX_FULL_SCALE_NT);
    loop {
        health::idle(Task::Flux, f.drdy.wait_for_falling_edge()).await;
        let mut frame = [0u8; SPI_FRAME_LEN];
        f.cs.set_low();
        let r = f.spi.blocking_transfer_in_place(&mut frame);
        f.cs.set_high();
        let ev = match r {
            Ok(()) => decode_spi_frame(&frame).map(|a| cal.scale(a.counts)),
            Err(_) => Err(FluxError::BadLength),
        };
        EVENTS.send(Event::Flux(ev, f32::NAN)).await;
    }
}

/// Frames in arrival order → `magcomp_core::acquisition` (time base, aligner, compensator,
/// exactly as `magcomp replay`) → one record per scalar line; plus the commands that touch
/// the filter's state.
#[embassy_executor::task]
async fn acq_task(acq: &'static mut BoardAcquisition, mut store: board::CoefStore) {
    match load_coefficients(&mut store, acq) {
        Ok(()) => defmt::info!("stored coefficients loaded: survey mode"),
        Err(()) => defmt::info!("no valid stored coefficients: calibrate mode"),
    }
    // `hil-sync`: frames taken per port (scalar, flux, GPS), acknowledged after each one
    #[cfg(feature = "hil-sync")]
    let mut taken = [0u64; 3];
    // `SETCOEF` values wait in `staged` for `MODE,SURVEY`: one value must not switch the
    // board to a half-uploaded set.
    let mut staged = bc::NONE_STAGED;
    loop {
        let ev = match health::idle(Task::Acq, select(EVENTS.receive(), COMMANDS.receive())).await {
            Either::First(ev) => ev,
            Either::Second(cmd) => {
                handle_command(cmd, acq, &mut store, &mut staged).await;
                continue;
            }
        };
        #[cfg(feature = "hil-sync")]
        let port = match ev {
            Event::Scalar(_) => 0,
            Event::Flux(..) => 1,
            Event::Gps(_) => 2,
        };
        let record = ev.apply(acq);
        // `RAW,ON`: the sample as the aligner made it, for calibration after landing
        if let Some(raw) = acq.take_raw() {
            send_raw(&raw).await;
        }
        if let Some(r) = record {
            send_record(&r).await;
        }
        #[cfg(feature = "hil-sync")]
        {
            taken[port] += 1;
            OUT.send(Line::sentence(|c| {
                c.bytes(b"MCSYN")?;
                for n in taken {
                    c.byte(b',')?;
                    c.u64(n)?;
                }
                Ok(())
            }))
            .await;
        }
    }
}

async fn send_raw(r: &RawLine) {
    let line = Line::fill(|out| r.encode(out).ok());
    if line.len == 0 {
        // cannot happen (MAX_RAW_LEN, MAX_MULTI_RAW_LEN ≤ LINE_LEN): a bug, logged
        defmt::error!("raw line {} did not encode", r.k());
    }
    OUT.send(line).await;
}

async fn send_record(r: &AcqRecord) {
    let line = Line::fill(|out| r.encode(out).ok());
    if line.len == 0 {
        // cannot happen (MAX_RECORD_LEN, MAX_MULTI_RECORD_LEN ≤ LINE_LEN): a bug, logged, the
        // record still counted
        defmt::error!("record {} did not encode", r.seq());
    }
    OUT.send(line).await;
}

/// The sequence numbers of the two images `read` reads (the current or the earlier
/// firmware's), one at a time into `buf` (an unreadable image counts as invalid): one image
/// buffer on the stack, not two.
fn image_seqs(
    buf: &mut store::Image,
    mut read: impl FnMut(usize, &mut store::Image) -> Result<(), StoreError>,
) -> [Option<u32>; store::N_IMAGES] {
    let mut seqs = [None; store::N_IMAGES];
    for (i, seq) in seqs.iter_mut().enumerate() {
        if read(i, buf).is_ok() {
            *seq = store::sequence(buf);
        }
    }
    seqs
}

/// Loads the newest valid image (layout: `store.rs`); `Err` when it holds no valid model
/// blob or there is none. With no valid image, the earlier firmware's store: its newest
/// valid image, else its single-image blobs (`store::load_legacy`), so an upgraded board
/// keeps its calibration until the next `SAVE` writes the current images.
fn load_coefficients(st: &mut board::CoefStore, acq: &mut BoardAcquisition) -> Result<(), ()> {
    let mut img = store::ERASED;
    if let Some(i) = store::newest(image_seqs(&mut img, |i, b| st.read(i, b))) {
        st.read(i, &mut img).map_err(|_| ())?;
        return store::load_image(&img, acq);
    }
    let old = store::newest(image_seqs(&mut img, |i, b| st.read_old(i, b)));
    // the single-image store was where the two-image firmware put its image 1
    st.read_old(old.unwrap_or(1), &mut img).map_err(|_| ())?;
    match old {
        Some(_) => store::load_image(&img, acq),
        None => store::load_legacy(&img, acq),
    }
}

/// Writes the other image than the newest (with the staged coefficients when a set waits
/// for `MODE,SURVEY`), then reads it back from the store itself.
fn save_coefficients(st: &mut board::CoefStore, acq: &BoardAcquisition, staged: &Staged) -> bool {
    let mut back = store::ERASED;
    let (i, seq) = store::next(image_seqs(&mut back, |i, b| st.read(i, b)));
    let mut img = store::ERASED;
    if store::seal(seq, acq, staged, &mut img).is_err() || st.write(i, &img).is_err() {
        return false;
    }
    st.read(i, &mut back).is_ok() && back == img
}

fn mode(acq: &BoardAcquisition) -> Mode {
    if acq.is_survey_mode() {
        Mode::Survey
    } else {
        Mode::Cal
    }
}

fn mode_word(m: Mode) -> &'static [u8] {
    match m {
        Mode::Survey => b"SURVEY",
        Mode::Cal => b"CAL",
    }
}

/// `$MCACK,<name>,<v0>,<v1>,…` with every value at 9 significant digits (f32 round trip).
fn ack_values(name: &[u8], values: &[f32]) -> Line {
    Line::sentence(|cur| {
        cur.bytes(b"MCACK,")?;
        cur.bytes(name)?;
        for &v in values {
            cur.byte(b',')?;
            cur.sci(v.into())?;
        }
        Ok(())
    })
}

/// A well-formed command the board refuses (its value would break the filter or the
/// fluxgate): counted with the malformed ones in STATUS.
fn refused(e: CommandError) -> Line {
    CMD_ERRORS.fetch_add(1, Ordering::Relaxed);
    Line::fill(|out| encode_error(e, out))
}

async fn handle_command(
    cmd: Command,
    acq: &mut BoardAcquisition,
    st: &mut board::CoefStore,
    staged: &mut Staged,
) {
    let reply = match cmd {
        Command::Mode(m) => set_mode(m, acq, staged),
        Command::Status => status(acq),
        Command::GetCoef(Some(i)) => {
            let v = bc::coefficients(acq, staged, 0)
                .get(usize::from(i))
                .copied()
                .unwrap_or(f32::NAN);
            Line::fill(|out| encode_ack_coef(i, v, out))
        }
        Command::GetCoef(None) => ack_values(b"GETCOEF", &bc::coefficients(acq, staged, 0)),
        Command::GetSensorCoef { sensor, index } => get_sensor_coef(sensor, index, acq, staged),
        Command::SetCoef { index, value } => stage_coefficient(0, index, value, acq, staged),
        Command::SetSensorCoef {
            sensor,
            index,
            value,
        } => stage_coefficient(sensor, index, value, acq, staged),
        Command::GetFlux(Some(i)) => {
            let v = acq.flux_calibration().to_array()[usize::from(i) % FLUX_CAL_LEN];
            Line::fill(|out| encode_ack_indexed(b"GETFLUX", i, v, out))
        }
        Command::GetFlux(None) => ack_values(b"GETFLUX", &acq.flux_calibration().to_array()),
        Command::SetFlux { index, value } => set_flux(index, value, acq),
        Command::GetLag => ack_values(b"GETLAG", &[acq.lag_s()]),
        Command::GetFluxTemp(Some(i)) => {
            let v = acq.flux_temp_calibration().to_array()[usize::from(i) % FLUX_TEMP_LEN];
            Line::fill(|out| encode_ack_indexed(b"GETFTEMP", i, v, out))
        }
        Command::GetFluxTemp(None) => {
            ack_values(b"GETFTEMP", &acq.flux_temp_calibration().to_array())
        }
        Command::SetFluxTemp { index, value } => set_flux_temp(index, value, acq),
        Command::SetLag(v) => match acq.set_lag_s(v) {
            Ok(()) => ack_values(b"SETLAG", &[v]),
            Err(_) => refused(CommandError::ValueOutOfBounds),
        },
        Command::Raw(on) => {
            acq.set_raw_output(on);
            Line::sentence(|c| {
                c.bytes(b"MCACK,RAW,")?;
                c.bytes(if on { b"ON" } else { b"OFF" })
            })
        }
        Command::Save => {
            if save_coefficients(st, acq, staged) {
                Line::sentence(|c| c.bytes(b"MCACK,SAVE"))
            } else {
                // flash failure is not a command error: say so in the ACK's place
                Line::sentence(|c| c.bytes(b"MCERR,8,STORAGE"))
            }
        }
        Command::Reset | Command::Flush | Command::FactoryReset => {
            restart(cmd, acq, st, staged).await
        }
    };
    OUT.send(reply).await;
}

/// `MODE`: the staged sets become the survey's coefficients here, all at once; a sensor
/// with none staged keeps its own (as a single sensor's `MODE,SURVEY` without a set).
/// Sensor 0's set goes to the paper filter or the witnessed one by its `fluxmod`; sensors
/// 1–2 refuse a set with `fluxmod` ≠ 0 (`board_config::load_set`).
fn set_mode(m: Mode, acq: &mut BoardAcquisition, staged: &mut Staged) -> Line {
    if m == Mode::Survey {
        for (sensor, slot) in staged.iter_mut().enumerate() {
            let Some(c) = slot.take() else {
                continue;
            };
            if bc::load_set(acq, sensor, &c).is_err() {
                defmt::error!("staged coefficients of sensor {} refused", sensor);
            }
        }
    }
    // survey: a no-op for the sensors just set (`set_coefficients` switched them)
    acq.set_survey_mode(m == Mode::Survey);
    Line::sentence(|c| {
        c.bytes(b"MCACK,MODE,")?;
        c.bytes(mode_word(m))
    })
}

/// `STATUS`: the mode and the board's counters.
fn status(acq: &BoardAcquisition) -> Line {
    Line::sentence(|c| {
        c.bytes(b"MCACK,STATUS,")?;
        let n = acq.counters();
        c.bytes(mode_word(mode(acq)))?;
        for v in [n.records, n.scalar_errors, n.flux_errors, n.gps_errors] {
            c.byte(b',')?;
            c.u64(v.into())?;
        }
        // err_uart: the flags counted in the interrupts (uart_stats) plus any error the
        // driver itself returns; then the breakdown by kind and by port
        let kinds = uart_stats::by_kind();
        let uart = kinds
            .iter()
            .fold(UART_ERRORS.load(Ordering::Relaxed), |a, &k| {
                a.wrapping_add(k)
            });
        for v in [uart, CMD_ERRORS.load(Ordering::Relaxed)]
            .into_iter()
            .chain(kinds)
            .chain(uart_stats::by_port())
        {
            c.byte(b',')?;
            c.u64(v.into())?;
        }
        // fluxgate frames refused as suspect (a step, an axis that does not move, a
        // modulus 20 % off the scalar): why records are FLUX_STALE while frames arrive
        c.byte(b',')?;
        c.u64(n.flux_suspect.into())?;
        Ok(())
    })
}

/// `GETCOEF,<sensor>,<index>|ALL` (sensors 1–2): `$MCACK,GETCOEF,<sensor>[,<index>],…`.
fn get_sensor_coef(
    sensor: u8,
    index: Option<u16>,
    acq: &BoardAcquisition,
    staged: &Staged,
) -> Line {
    let c = bc::coefficients(acq, staged, sensor.into());
    let values = match index {
        Some(i) => c
            .get(usize::from(i)..=usize::from(i))
            .unwrap_or(&[f32::NAN]),
        None => &c[..],
    };
    Line::sentence(|cur| {
        cur.bytes(b"MCACK,GETCOEF,")?;
        cur.u64(sensor.into())?;
        if let Some(i) = index {
            cur.byte(b',')?;
            cur.u64(i.into())?;
        }
        for &v in values {
            cur.byte(b',')?;
            cur.sci(v.into())?;
        }
        Ok(())
    })
}

/// `SETCOEF`: staged, not applied: `MODE,SURVEY` applies the whole set
/// (docs/protocols.md §5). Sensor 0's reply is the single sensor's
/// (`SETCOEF,<index>,<value>`), the others' name the sensor first.
fn stage_coefficient(
    sensor: u8,
    index: u16,
    value: f32,
    acq: &BoardAcquisition,
    staged: &mut Staged,
) -> Line {
    let mut c = bc::coefficients(acq, staged, sensor.into());
    match (
        c.get_mut(usize::from(index)),
        staged.get_mut(usize::from(sensor)),
    ) {
        (Some(slot), Some(set)) if value.is_finite() => {
            *slot = value;
            *set = Some(c);
            if sensor == 0 {
                return Line::fill(|out| encode_ack_indexed(b"SETCOEF", index, value, out));
            }
            Line::sentence(|cur| {
                cur.bytes(b"MCACK,SETCOEF,")?;
                for n in [sensor.into(), index] {
                    cur.u64(n.into())?;
                    cur.byte(b',')?;
                }
                cur.sci(value.into())
            })
        }
        _ => refused(CommandError::ValueOutOfBounds),
    }
}

/// `SETFLUX`: one value at a time, so a half-sent calibration must still be a plausible
/// one.
fn set_flux(index: u16, value: f32, acq: &mut BoardAcquisition) -> Line {
    let mut v = acq.flux_calibration().to_array();
    v[usize::from(index) % FLUX_CAL_LEN] = value;
    match FluxCalibration::from_array(&v) {
        Some(cal) => {
            acq.set_flux_calibration(cal);
            Line::fill(|out| encode_ack_indexed(b"SETFLUX", index, value, out))
        }
        None => refused(CommandError::ValueOutOfBounds),
    }
}

/// `SETFTEMP`: as `SETFLUX`, for the fluxgate's temperature calibration. Without a
/// temperature in the frames (the SPI ADC) only zeros (none) are taken: a set would make
/// every frame unusable (`$MCERR,9,NO_TEMPERATURE`).
fn set_flux_temp(index: u16, value: f32, acq: &mut BoardAcquisition) -> Line {
    if !bc::FLUX_HAS_TEMPERATURE && value != 0.0 {
        return Line::sentence(|c| c.bytes(b"MCERR,9,NO_TEMPERATURE"));
    }
    let mut v = acq.flux_temp_calibration().to_array();
    v[usize::from(index) % FLUX_TEMP_LEN] = value;
    match FluxTempCal::from_array(&v) {
        Some(cal) => {
            acq.set_flux_temp_calibration(cal);
            Line::fill(|out| encode_ack_indexed(b"SETFTEMP", index, value, out))
        }
        None => refused(CommandError::ValueOutOfBounds),
    }
}

/// `RESET`, `FLUSH` and `FACTORY`: the held records out first, then (not for `FLUSH`)
/// the filter restarted with the stored or, for `FACTORY`, the default coefficients.
async fn restart(
    cmd: Command,
    acq: &mut BoardAcquisition,
    st: &mut board::CoefStore,
    staged: &mut Staged,
) -> Line {
    // every sample keeps its record: emit the held ones before anything else
    while let Some(r) = acq.flush_any() {
        send_record(&r).await;
    }
    let name: &[u8] = match cmd {
        Command::Reset => b"RESET",
        Command::FactoryReset => b"FACTORY",
        _ => b"FLUSH",
    };
    let mut failed = false;
    if cmd != Command::Flush {
        *staged = bc::NONE_STAGED;
        // in place: no second filter on the stack
        if bc::restart_filter(acq).is_err() {
            defmt::error!("compensator re-init failed");
            board::exit(false)
        }
        if cmd == Command::FactoryReset {
            // the earlier firmware's images first, else boot would load them; and only if
            // they are gone, the current ones erased: a cut between the two leaves the
            // current set, never an older one. Then the boot defaults.
            failed = st.retire_old().is_err()
                || (0..store::N_IMAGES).any(|i| st.write(i, &store::ERASED).is_err());
            store::defaults(acq);
        } else {
            let _ = load_coefficients(st, acq);
        }
    }
    if failed {
        Line::sentence(|c| c.bytes(b"MCERR,8,STORAGE"))
    } else {
        Line::sentence(|c| {
            c.bytes(b"MCACK,")?;
            c.bytes(name)?;
            c.byte(b',')?;
            c.u64(acq.next_seq().into())
        })
    }
}

/// Commands arrive on the output port's RX line; malformed ones are answered here.
#[embassy_executor::task]
async fn command_task(mut rx: BufferedUartRx<'static>) {
    let mut reader = CommandReader::new(N_COEF);
    #[cfg(feature = "board-emu")]
    let mut hook = test_hook::Hook::new();
    let mut buf = [0u8; 32];
    loop {
        let n = health::idle(Task::Command, read_some(&mut rx, &mut buf)).await;
        for &b in &buf[..n] {
            #[cfg(feature = "board-emu")]
            if hook.push(b) {
                continue;
            }
            match reader.push(b) {
                None => {}
                Some(Ok(cmd)) => COMMANDS.send(cmd).await,
                Some(Err(e)) => {
                    CMD_ERRORS.fetch_add(1, Ordering::Relaxed);
                    OUT.send(Line::fill(|out| encode_error(e, out))).await;
                }
            }
        }
    }
}

/// Longest the output task waits on one `write` before polling it again. embassy-stm32
/// 0.6.0's `BufferedUartTx::write` (usart/buffered.rs) returns `Pending` *without
/// registering a waker* when the TX ring has less free room than the whole slice, so an
/// await on it alone can sleep forever once the ring is busy (a command burst, `FLUSH`
/// at a high record rate). A write takes all of the slice or none of it, so polling it
/// again is safe; 1 ms is less than the ≥ 192 bytes still queued in that case take to go
/// out at 921 600 Bd (2 ms), so the line never idles for it.
const TX_REPOLL: Duration = Duration::from_millis(1);

/// Writes one line to the output port (the ring takes it whole: lines < 320 B < 512 B).
async fn write_line(tx: &mut BufferedUartTx<'static>, mut bytes: &[u8]) {
    while !bytes.is_empty() {
        match with_timeout(TX_REPOLL, tx.write(bytes)).await {
            Ok(Ok(n)) => bytes = &bytes[n..],
            Ok(Err(_)) => {
                // cannot happen for a line shorter than the ring; counted, line dropped
                UART_ERRORS.fetch_add(1, Ordering::Relaxed);
                return;
            }
            Err(_) => {
                TX_REPOLLS.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

/// Times [`write_line`] had to poll again (the driver's missing wake-up; logged, not an error).
static TX_REPOLLS: AtomicU32 = AtomicU32::new(0);

/// The single writer of the output port: records and replies, in channel order.
#[embassy_executor::task]
async fn output_task(mut tx: BufferedUartTx<'static>) {
    loop {
        let line = health::idle(Task::Output, OUT.receive()).await;
        #[cfg(feature = "board-emu")]
        test_hook::maybe_stall().await;
        write_line(&mut tx, line.bytes()).await;
    }
}

/// Feeds the IWDG every 500 ms, but only when every task is idle or has finished work since
/// the previous check (`health::Progress`). A task stuck on an await that never completes
/// (the TX wake-up above, a full channel whose consumer died) or spinning, or a hard fault,
/// stops the feeding and the IWDG resets the board within its 3.5 s; `$MCBOOT` then says
/// `RST=IWDG`.
#[embassy_executor::task]
async fn watchdog_task(mut wdg: board::Watchdog) {
    wdg.unleash();
    let mut progress = health::Progress::new();
    let mut reported = 0;
    loop {
        Timer::after_millis(crate::WATCHDOG_CHECK_MS.into()).await;
        match progress.check() {
            Ok(()) => wdg.feed(),
            Err(t) => defmt::warn!("task {} made no progress: watchdog not fed", t),
        }
        let r = TX_REPOLLS.load(Ordering::Relaxed);
        if r != reported {
            defmt::debug!("output write polled again {} times", r);
            reported = r;
        }
    }
}

/// Emulated-board test hooks (compiled only with `board-emu`, never in the flight image): a
/// command-port line starting with `!` goes here, not to the command parser.
/// `!STALL`: the output task stops, busy, on an await that never completes (as a lost
/// wake-up would), so the watchdog must reset the board. `!PANIC`: a panic, whose record the
/// next boot must report. `!CUT<n>`: the next `SAVE` is cut after `n` bytes. `!OLDSTORE`,
/// `!OLDLEGACY`: the store as a board upgraded from earlier firmware has it ([`Upgrade`]).
#[cfg(feature = "board-emu")]
pub mod test_hook {
    use core::sync::atomic::{AtomicBool, AtomicU8, AtomicU32, Ordering};

    static STALL: AtomicBool = AtomicBool::new(false);

    pub struct Hook {
        at_line_start: bool,
        line: Option<heapless::Vec<u8, 16>>,
    }

    impl Hook {
        pub const fn new() -> Self {
            Self {
                at_line_start: true,
                line: None,
            }
        }

        /// `true` if the byte belongs to a hook line (not for the command parser).
        pub fn push(&mut self, b: u8) -> bool {
            let start = self.at_line_start;
            self.at_line_start = b == b'\n' || b == b'\r';
            if let Some(line) = &mut self.line {
                if self.at_line_start {
                    match line.as_slice() {
                        b"STALL" => STALL.store(true, Ordering::Relaxed),
                        b"PANIC" => panic!("test hook !PANIC"),
                        [b'C', b'U', b'T', n @ ..] => cut_next_save(n),
                        b"OLDSTORE" => UPGRADE.store(Upgrade::TwoImages as u8, Ordering::Relaxed),
                        b"OLDLEGACY" => UPGRADE.store(Upgrade::OneImage as u8, Ordering::Relaxed),
                        _ => {}
                    }
                    self.line = None;
                } else {
                    let _ = line.push(b);
                }
                return true;
            }
            if start && b == b'!' {
                self.line = Some(heapless::Vec::new());
                return true;
            }
            false
        }
    }

    /// `!CUT<n>`: the next store write stops after `n` bytes, as a power cut would
    /// (boards/emu_f405's store asks [`take_cut`]).
    static CUT_AT: AtomicU32 = AtomicU32::new(u32::MAX);

    fn cut_next_save(digits: &[u8]) {
        let n = digits.iter().try_fold(0u32, |n, &d| {
            d.is_ascii_digit()
                .then(|| n.saturating_mul(10).saturating_add(u32::from(d - b'0')))
        });
        if let Some(n) = n {
            CUT_AT.store(n, Ordering::Relaxed);
        }
    }

    /// Bytes the next store write may write before its cut, if one was asked for.
    pub fn take_cut() -> Option<usize> {
        let n = CUT_AT.swap(u32::MAX, Ordering::Relaxed);
        (n != u32::MAX).then_some(n as usize)
    }

    /// The store as a board flashed with earlier firmware and then upgraded has it: the
    /// current images' sectors hold that firmware's code (no image), its store is in the
    /// old sectors. boards/emu_f405's store applies it at its next access.
    #[derive(Clone, Copy, PartialEq, Eq)]
    pub enum Upgrade {
        /// From the two-image firmware: the images, as they are, in the old sectors.
        TwoImages = 1,
        /// From the single-image firmware: the newest image's blobs alone at the start of
        /// old image 1, old image 0 erased.
        OneImage = 2,
    }

    static UPGRADE: AtomicU8 = AtomicU8::new(0);

    /// The store layout the next store access must take, if one was asked for.
    pub fn take_upgrade() -> Option<Upgrade> {
        match UPGRADE.swap(0, Ordering::Relaxed) {
            1 => Some(Upgrade::TwoImages),
            2 => Some(Upgrade::OneImage),
            _ => None,
        }
    }

    pub async fn maybe_stall() {
        if STALL.load(Ordering::Relaxed) {
            core::future::pending::<()>().await;
        }
    }
}
