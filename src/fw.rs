//! The embassy tasks and their channels.

use core::sync::atomic::{AtomicU32, Ordering};

use embassy_executor::Spawner;
use embassy_futures::select::{Either, select};
use embassy_stm32::usart::{BufferedUartRx, BufferedUartTx};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_time::Timer;
use embedded_io_async::{Read, Write};
use magcomp_core::protocol::command::{
    Command, CommandError, CommandReader, FLUX_CAL_LEN, FLUX_TEMP_LEN, Mode, blob_len, decode_blob,
    encode_ack_coef, encode_ack_indexed, encode_blob, encode_error, flux_blob_id,
    flux_temp_blob_id, lag_blob_id,
};
use magcomp_core::protocol::common::{BufferFull, Cursor, crc16_ccitt};
use magcomp_core::protocol::fluxgate::{FluxCalibration, FluxTempCal};
use magcomp_core::protocol::lag_line::LagLine;
use magcomp_core::protocol::record::{Record, encode_record};

#[cfg(feature = "board-emu")]
use defmt_semihosting as _;
#[cfg(feature = "board-acq")]
use {defmt_rtt as _, panic_probe as _};

use crate::board;
use crate::board_config::{self as bc, BoardAcquisition, Event, N_COEF, model_id};
use magcomp_core::model::Model;
use static_cell::ConstStaticCell;

/// A line for the output port (records < 192 bytes; GETCOEF of all 16 coefficients < 320).
pub struct Line {
    buf: [u8; 320],
    len: usize,
}

impl Line {
    const fn new() -> Self {
        Self {
            buf: [0; 320],
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

type Mutex = CriticalSectionRawMutex;
static EVENTS: Channel<Mutex, Event, 16> = Channel::new();
static COMMANDS: Channel<Mutex, Command, 4> = Channel::new();
static OUT: Channel<Mutex, Line, 6> = Channel::new();

/// Counters shown by `STATUS` besides the acquisition's own (records, parser errors per
/// port): UART errors (overrun/framing/noise) and rejected commands.
static UART_ERRORS: AtomicU32 = AtomicU32::new(0);
static CMD_ERRORS: AtomicU32 = AtomicU32::new(0);

#[embassy_executor::main]
async fn main(spawner: Spawner) {
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
        // tells the harness that frames are acknowledged (`$MCSYN`)
        if cfg!(feature = "hil-sync") {
            c.bytes(b",SYNC")?;
        }
        Ok(())
    }))
    .await;

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
    #[cfg(any(feature = "board-emu", feature = "flux-uart"))]
    spawner.spawn(flux_uart_task(b.flux).unwrap());
    #[cfg(all(feature = "board-acq", not(feature = "flux-uart")))]
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

/// A sensor UART's bytes through its port parser into the event channel, forever.
async fn forward(mut rx: BufferedUartRx<'static>, mut parse: impl FnMut(u8) -> Option<Event>) -> ! {
    let mut buf = [0u8; 64];
    loop {
        let n = read_some(&mut rx, &mut buf).await;
        for &b in &buf[..n] {
            if let Some(ev) = parse(b) {
                EVENTS.send(ev).await;
            }
        }
    }
}

#[embassy_executor::task]
async fn scalar_task(rx: BufferedUartRx<'static>) {
    let mut port = bc::ScalarPort::new();
    forward(rx, |b| port.push(b)).await
}

#[embassy_executor::task]
async fn gps_task(rx: BufferedUartRx<'static>) {
    let mut port = bc::GpsPort::new();
    forward(rx, |b| port.push(b)).await
}

/// Fluxgate on its serial ASCII alternative (sensor frame → body frame by the board's axes).
#[cfg(any(feature = "board-emu", feature = "flux-uart"))]
#[embassy_executor::task]
async fn flux_uart_task(rx: BufferedUartRx<'static>) {
    let mut port = bc::FluxAsciiPort::new();
    forward(rx, |b| port.push(b)).await
}

/// Fluxgate ADC (ADS131M03) on SPI: on each data-ready edge read one 15-byte frame
/// (status, 3 × 24-bit channels, CRC-16) and scale it to the body frame.
#[cfg(all(feature = "board-acq", not(feature = "flux-uart")))]
#[embassy_executor::task]
async fn flux_spi_task(mut f: board::FluxPort) {
    use magcomp_core::acquisition::FLUX_FULL_SCALE_NT;
    use magcomp_core::protocol::fluxgate::{
        FluxError, FluxgateCal, SPI_FRAME_LEN, decode_spi_frame,
    };
    let cal = FluxgateCal::full_scale(FLUX_FULL_SCALE_NT);
    loop {
        f.drdy.wait_for_falling_edge().await;
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
    loop {
        let ev = match select(EVENTS.receive(), COMMANDS.receive()).await {
            Either::First(ev) => ev,
            Either::Second(cmd) => {
                handle_command(cmd, acq, &mut store).await;
                continue;
            }
        };
        #[cfg(feature = "hil-sync")]
        let port = match ev {
            Event::Scalar(_) => 0,
            Event::Flux(..) => 1,
            Event::Gps(_) => 2,
        };
        if let Some(r) = ev.apply(acq) {
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

async fn send_record(r: &Record) {
    let line = Line::fill(|out| encode_record(r, out).ok());
    if line.len == 0 {
        // cannot happen (MAX_RECORD_LEN < 320): a bug, logged, the record still counted
        defmt::error!("record {} did not encode", r.seq);
    }
    OUT.send(line).await;
}

/// The store holds the model's blob, then the fluxgate calibration's, then the scalar
/// delay's, then the fluxgate temperature drift's; a store written before `fluxcal` /
/// `SETLAG` / `SETFTEMP` existed loads as "no fluxgate calibration" / τ = 0 / no drift.
fn load_coefficients(store: &mut board::CoefStore, acq: &mut BoardAcquisition) -> Result<(), ()> {
    let mut blob = [0u8; crate::COEF_BLOB_MAX];
    store.read(&mut blob).map_err(|_| ())?;
    let mut c = [0f32; N_COEF];
    decode_blob(&blob, model_id(), &mut c).map_err(|_| ())?;
    acq.set_coefficients(&c).map_err(|_| ())?;
    let mut f = [0f32; FLUX_CAL_LEN];
    let flux = decode_blob(&blob[blob_len(N_COEF)..], flux_blob_id(), &mut f)
        .ok()
        .and_then(|()| FluxCalibration::from_array(&f));
    acq.set_flux_calibration(flux.unwrap_or(FluxCalibration::IDENTITY));
    let mut lag = [0f32; 1];
    let at = blob_len(N_COEF) + blob_len(FLUX_CAL_LEN);
    let stored = decode_blob(&blob[at..], lag_blob_id(), &mut lag).is_ok();
    if !(stored && acq.set_lag_s(lag[0]).is_ok()) {
        let _ = acq.set_lag_s(0.0);
    }
    let mut ft = [0f32; FLUX_TEMP_LEN];
    let at = at + blob_len(1);
    let temp = decode_blob(&blob[at..], flux_temp_blob_id(), &mut ft)
        .ok()
        .and_then(|()| FluxTempCal::from_array(&ft));
    acq.set_flux_temp_calibration(temp.unwrap_or(FluxTempCal::NONE));
    Ok(())
}

fn save_coefficients(store: &mut board::CoefStore, acq: &BoardAcquisition) -> bool {
    let mut blob = [0u8; crate::COEF_BLOB_MAX];
    let Ok(n) = encode_blob(model_id(), &coefficients(acq), &mut blob) else {
        return false;
    };
    let flux = acq.flux_calibration().to_array();
    let Ok(m) = encode_blob(flux_blob_id(), &flux, &mut blob[n..]) else {
        return false;
    };
    let Ok(l) = encode_blob(lag_blob_id(), &[acq.lag_s()], &mut blob[n + m..]) else {
        return false;
    };
    let ft = acq.flux_temp_calibration().to_array();
    let Ok(t) = encode_blob(flux_temp_blob_id(), &ft, &mut blob[n + m + l..]) else {
        return false;
    };
    store.write(&blob[..n + m + l + t]).is_ok()
}

fn mode(acq: &BoardAcquisition) -> Mode {
    if acq.is_survey_mode() {
        Mode::Survey
    } else {
        Mode::Cal
    }
}

fn coefficients(acq: &BoardAcquisition) -> [f32; N_COEF] {
    let mut c = [0f32; N_COEF];
    acq.coefficients(&mut c);
    c
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

async fn handle_command(cmd: Command, acq: &mut BoardAcquisition, store: &mut board::CoefStore) {
    let reply = match cmd {
        Command::Mode(m) => {
            acq.set_survey_mode(m == Mode::Survey);
            Line::sentence(|c| {
                c.bytes(b"MCACK,MODE,")?;
                c.bytes(mode_word(m))
            })
        }
        Command::Status => Line::sentence(|c| {
            c.bytes(b"MCACK,STATUS,")?;
            let n = acq.counters();
            c.bytes(mode_word(mode(acq)))?;
            for v in [n.records, n.scalar_errors, n.flux_errors, n.gps_errors] {
                c.byte(b',')?;
                c.u64(v.into())?;
            }
            c.byte(b',')?;
            c.u64(UART_ERRORS.load(Ordering::Relaxed).into())?;
            c.byte(b',')?;
            c.u64(CMD_ERRORS.load(Ordering::Relaxed).into())
        }),
        Command::GetCoef(Some(i)) => {
            let v = coefficients(acq)
                .get(usize::from(i))
                .copied()
                .unwrap_or(f32::NAN);
            Line::fill(|out| encode_ack_coef(i, v, out))
        }
        Command::GetCoef(None) => ack_values(b"GETCOEF", &coefficients(acq)),
        Command::SetCoef { index, value } => {
            let mut c = coefficients(acq);
            if let Some(slot) = c.get_mut(usize::from(index)) {
                *slot = value;
            }
            match acq.set_coefficients(&c) {
                Ok(()) => Line::fill(|out| encode_ack_indexed(b"SETCOEF", index, value, out)),
                Err(_) => refused(CommandError::ValueOutOfBounds),
            }
        }
        Command::GetFlux(Some(i)) => {
            let v = acq.flux_calibration().to_array()[usize::from(i) % FLUX_CAL_LEN];
            Line::fill(|out| encode_ack_indexed(b"GETFLUX", i, v, out))
        }
        Command::GetFlux(None) => ack_values(b"GETFLUX", &acq.flux_calibration().to_array()),
        Command::SetFlux { index, value } => {
            let mut v = acq.flux_calibration().to_array();
            v[usize::from(index) % FLUX_CAL_LEN] = value;
            // One value at a time: a half-sent calibration must still be a plausible one.
            match FluxCalibration::from_array(&v) {
                Some(cal) => {
                    acq.set_flux_calibration(cal);
                    Line::fill(|out| encode_ack_indexed(b"SETFLUX", index, value, out))
                }
                None => refused(CommandError::ValueOutOfBounds),
            }
        }
        Command::GetLag => ack_values(b"GETLAG", &[acq.lag_s()]),
        Command::GetFluxTemp(Some(i)) => {
            let v = acq.flux_temp_calibration().to_array()[usize::from(i) % FLUX_TEMP_LEN];
            Line::fill(|out| encode_ack_indexed(b"GETFTEMP", i, v, out))
        }
        Command::GetFluxTemp(None) => {
            ack_values(b"GETFTEMP", &acq.flux_temp_calibration().to_array())
        }
        Command::SetFluxTemp { index, value } => {
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
        Command::SetLag(v) => match acq.set_lag_s(v) {
            Ok(()) => ack_values(b"SETLAG", &[v]),
            Err(_) => refused(CommandError::ValueOutOfBounds),
        },
        Command::Save => {
            if save_coefficients(store, acq) {
                Line::sentence(|c| c.bytes(b"MCACK,SAVE"))
            } else {
                // flash failure is not a command error: say so in the ACK's place
                Line::sentence(|c| c.bytes(b"MCERR,8,STORAGE"))
            }
        }
        Command::Reset | Command::Flush => {
            // every sample keeps its record: emit the held ones before anything else
            while let Some(r) = acq.flush() {
                send_record(&r).await;
            }
            if cmd == Command::Reset {
                // in place: no second filter on the stack
                if bc::restart_filter(acq).is_err() {
                    defmt::error!("compensator re-init failed");
                    board::exit(false)
                }
                let _ = load_coefficients(store, acq);
            }
            let name: &[u8] = if cmd == Command::Reset {
                b"RESET"
            } else {
                b"FLUSH"
            };
            Line::sentence(|c| {
                c.bytes(b"MCACK,")?;
                c.bytes(name)?;
                c.byte(b',')?;
                c.u64(acq.next_seq().into())
            })
        }
    };
    OUT.send(reply).await;
}

/// Commands arrive on the output port's RX line; malformed ones are answered here.
#[embassy_executor::task]
async fn command_task(mut rx: BufferedUartRx<'static>) {
    let mut reader = CommandReader::new(N_COEF);
    let mut buf = [0u8; 32];
    loop {
        let n = read_some(&mut rx, &mut buf).await;
        for &b in &buf[..n] {
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

/// The single writer of the output port: records and replies, in channel order.
#[embassy_executor::task]
async fn output_task(mut tx: BufferedUartTx<'static>) {
    loop {
        let line = OUT.receive().await;
        if tx.write_all(line.bytes()).await.is_err() {
            UART_ERRORS.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// Pets the IWDG while the executor keeps running: a task stuck in a loop (or a hard
/// fault) stops the petting and the board resets.
#[embassy_executor::task]
async fn watchdog_task(mut wdg: board::Watchdog) {
    wdg.unleash();
    loop {
        wdg.pet();
        Timer::after_millis(500).await;
    }
}
