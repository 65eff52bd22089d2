//! The embassy tasks and their channels.

use core::fmt::Write as _;
use core::sync::atomic::{AtomicU32, Ordering};

use embassy_executor::Spawner;
use embassy_futures::select::{Either, select};
use embassy_stm32::usart::{BufferedUartRx, BufferedUartTx};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_time::Timer;
use embedded_io_async::{Read, Write};
use magcomp_core::epoch::AlignedSample;

#[cfg(feature = "board-emu")]
use defmt_semihosting as _;
#[cfg(feature = "board-acq")]
use {defmt_rtt as _, panic_probe as _};

use crate::aligner::{Aligner, AlignerConfig, Event, Port};
use crate::board;
use crate::pipeline::{N_COEF, Pipeline};
use crate::wire::{self, CmdError, Command, LineBuf, LineEvent, Mode};

/// Nominal sensor rates (Hz) of the reference installation. The scalar rate sets the
/// time base; the fluxgate and GPS rates only set the staleness limits.
pub const SCALAR_RATE_HZ: f64 = 10.0;
pub const FLUX_RATE_HZ: f64 = 10.0;
pub const GPS_RATE_HZ: f64 = 1.0;

type Mutex = CriticalSectionRawMutex;
static EVENTS: Channel<Mutex, Event, 32> = Channel::new();
static SAMPLES: Channel<Mutex, (u32, AlignedSample), 8> = Channel::new();
static COMMANDS: Channel<Mutex, Command, 4> = Channel::new();
static OUT: Channel<Mutex, wire::Line, 8> = Channel::new();

/// Counters shown by `STATUS` (parser errors are kept by the aligner, in event order).
static PARSE_ERRORS: [AtomicU32; 3] = [AtomicU32::new(0), AtomicU32::new(0), AtomicU32::new(0)];
static UART_ERRORS: AtomicU32 = AtomicU32::new(0);
static CMD_ERRORS: AtomicU32 = AtomicU32::new(0);

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let b = board::init();
    defmt::info!(
        "magcomp firmware on {}, scalar rate {} Hz",
        board::NAME,
        SCALAR_RATE_HZ
    );

    let mut banner = wire::Line::new();
    let _ = write!(
        banner,
        "$MCBOOT,{},{}",
        board::NAME,
        env!("CARGO_PKG_VERSION")
    );
    wire::finish_sentence(&mut banner);
    OUT.send(banner).await;

    spawner.spawn(watchdog_task(b.watchdog).unwrap());
    spawner.spawn(output_task(b.out_tx).unwrap());
    spawner.spawn(command_task(b.out_rx).unwrap());
    spawner.spawn(filter_task(b.store).unwrap());
    spawner.spawn(aligner_task().unwrap());
    spawner.spawn(line_task(b.scalar, Port::Scalar).unwrap());
    spawner.spawn(line_task(b.gps, Port::Gps).unwrap());
    #[cfg(any(feature = "board-emu", feature = "flux-uart"))]
    spawner.spawn(line_task(b.flux, Port::Flux).unwrap());
    #[cfg(all(feature = "board-acq", not(feature = "flux-uart")))]
    spawner.spawn(flux_spi_task(b.flux).unwrap());
}

/// One ASCII sensor port: bytes → lines → parsed frames → `EVENTS`.
#[embassy_executor::task(pool_size = 3)]
async fn line_task(mut rx: BufferedUartRx<'static>, port: Port) {
    let mut lines = LineBuf::new();
    let mut buf = [0u8; 64];
    loop {
        let n = match rx.read(&mut buf).await {
            Ok(n) => n,
            Err(_) => {
                // overrun/framing/noise: the bytes are lost, the line parser will resync
                UART_ERRORS.fetch_add(1, Ordering::Relaxed);
                continue;
            }
        };
        for &byte in &buf[..n] {
            let ev = match lines.push(byte) {
                LineEvent::Pending => continue,
                LineEvent::Line(len) => parse_line(port, lines.line(len)),
                LineEvent::Overflow => match port {
                    Port::Scalar => Event::Scalar(Err(wire::ParseError::Overflow)),
                    Port::Flux => Event::Flux(Err(wire::ParseError::Overflow)),
                    Port::Gps => Event::Gps(Err(wire::ParseError::Overflow)),
                },
            };
            EVENTS.send(ev).await;
        }
    }
}

fn parse_line(port: Port, line: &[u8]) -> Event {
    match port {
        Port::Scalar => Event::Scalar(wire::parse_scalar(line)),
        Port::Flux => Event::Flux(wire::parse_flux(line)),
        Port::Gps => Event::Gps(wire::parse_nmea(line)),
    }
}

/// Fluxgate 24-bit ADC on SPI: on each data-ready edge read 3 × 24-bit big-endian
/// two's-complement channels (x forward, y starboard, z down).
#[cfg(all(feature = "board-acq", not(feature = "flux-uart")))]
#[embassy_executor::task]
async fn flux_spi_task(mut f: board::FluxPort) {
    /// ±100 000 nT full scale over ±2^23 counts.
    const NT_PER_LSB: f32 = 100_000.0 / 8_388_608.0;
    loop {
        f.drdy.wait_for_falling_edge().await;
        let mut frame = [0u8; 9];
        f.cs.set_low();
        let r = f.spi.blocking_transfer_in_place(&mut frame);
        f.cs.set_high();
        let ev = match r {
            Ok(()) => {
                let ch = |i: usize| {
                    let raw =
                        i32::from_be_bytes([frame[3 * i], frame[3 * i + 1], frame[3 * i + 2], 0])
                            >> 8;
                    raw as f32 * NT_PER_LSB
                };
                Event::Flux(Ok([ch(0), ch(1), ch(2)]))
            }
            Err(_) => Event::Flux(Err(wire::ParseError::Syntax)),
        };
        EVENTS.send(ev).await;
    }
}

/// Frames in arrival order → one aligned sample per scalar line.
#[embassy_executor::task]
async fn aligner_task() {
    let mut aligner = Aligner::new(AlignerConfig::for_rates(
        SCALAR_RATE_HZ,
        FLUX_RATE_HZ,
        GPS_RATE_HZ,
    ));
    loop {
        let ev = EVENTS.receive().await;
        let sample = aligner.push(ev);
        for (c, n) in PARSE_ERRORS.iter().zip(aligner.errors) {
            c.store(n, Ordering::Relaxed);
        }
        if let Some(s) = sample {
            SAMPLES.send(s).await;
        }
    }
}

/// The compensator at the scalar rate, plus the commands that touch its state.
#[embassy_executor::task]
async fn filter_task(mut store: board::CoefStore) {
    let Ok(mut pipe) = Pipeline::new(SCALAR_RATE_HZ as f32) else {
        defmt::error!("compensator init failed");
        board::exit(false)
    };
    // survey-ready: take the stored coefficients if the blob is valid
    if load_coefficients(&mut store, &mut pipe).is_ok() {
        defmt::info!("coefficients loaded from store");
    }
    let mut line = wire::Line::new();
    loop {
        match select(SAMPLES.receive(), COMMANDS.receive()).await {
            Either::First((_sample_seq, s)) => {
                if let Some(r) = pipe.push(&s) {
                    send_record(&r, &mut line).await;
                }
            }
            Either::Second(cmd) => handle_command(cmd, &mut pipe, &mut store, &mut line).await,
        }
    }
}

async fn send_record(r: &wire::Record, line: &mut wire::Line) {
    if wire::encode_record(r, line) {
        OUT.send(core::mem::take(line)).await;
    } else {
        defmt::error!("record {} does not fit a line", r.seq);
    }
}

fn load_coefficients(store: &mut board::CoefStore, pipe: &mut Pipeline) -> Result<(), CmdError> {
    let mut blob = [0u8; crate::COEF_BLOB_MAX];
    store.read(&mut blob).map_err(|_| CmdError::Storage)?;
    let mut c = [0f32; N_COEF];
    wire::decode_blob(&blob, &mut c).map_err(|_| CmdError::Storage)?;
    if pipe.set_coefficients(&c) {
        Ok(())
    } else {
        Err(CmdError::Bounds)
    }
}

async fn handle_command(
    cmd: Command,
    pipe: &mut Pipeline,
    store: &mut board::CoefStore,
    line: &mut wire::Line,
) {
    line.clear();
    let r: Result<(), CmdError> = (|| {
        match cmd {
            Command::Ping => {
                let _ = write!(line, "$MCACK,PING");
            }
            Command::Status => {
                let mode = match pipe.mode() {
                    Mode::Calibrate => "CAL",
                    Mode::Survey => "SURVEY",
                };
                let e = |i: usize| PARSE_ERRORS[i].load(Ordering::Relaxed);
                let _ = write!(
                    line,
                    "$MCACK,STATUS,{mode},{},{},{},{},{},{}",
                    pipe.records(),
                    e(0),
                    e(1),
                    e(2),
                    UART_ERRORS.load(Ordering::Relaxed),
                    CMD_ERRORS.load(Ordering::Relaxed)
                );
            }
            Command::Mode(m) => {
                pipe.set_mode(m);
                let _ = write!(
                    line,
                    "$MCACK,MODE,{}",
                    if m == Mode::Survey { "SURVEY" } else { "CAL" }
                );
            }
            Command::GetCoef { index } => {
                let v = pipe
                    .coefficients()
                    .get(usize::from(index))
                    .copied()
                    .ok_or(CmdError::Bounds)?;
                let _ = write!(line, "$MCACK,GETC,{index},{v:e}");
            }
            Command::SetCoef { index, value } => {
                let mut c = [0f32; N_COEF];
                let cur = pipe.coefficients();
                let n = cur.len().min(N_COEF);
                c[..n].copy_from_slice(&cur[..n]);
                *c.get_mut(usize::from(index)).ok_or(CmdError::Bounds)? = value;
                if !pipe.set_coefficients(&c) {
                    return Err(CmdError::Bounds);
                }
                let _ = write!(line, "$MCACK,SETC,{index},{value:e}");
            }
            Command::Save => {
                let mut blob = [0u8; crate::COEF_BLOB_MAX];
                let n =
                    wire::encode_blob(pipe.coefficients(), &mut blob).ok_or(CmdError::Storage)?;
                store.write(&blob[..n]).map_err(|_| CmdError::Storage)?;
                let _ = write!(line, "$MCACK,SAVE,{n}");
            }
            Command::Load => {
                load_coefficients(store, pipe)?;
                let _ = write!(line, "$MCACK,LOAD");
            }
            Command::Flush => {
                // handled below: records must go out before the ACK
                let _ = write!(line, "$MCACK,FLUSH");
            }
        }
        Ok(())
    })();
    if cmd == Command::Flush {
        let mut rec = wire::Line::new();
        while let Some(r) = pipe.flush() {
            send_record(&r, &mut rec).await;
        }
        line.clear();
        let _ = write!(line, "$MCACK,FLUSH,{}", pipe.records());
    }
    if let Err(e) = r {
        CMD_ERRORS.fetch_add(1, Ordering::Relaxed);
        line.clear();
        let _ = write!(line, "$MCERR,{}", e.word());
    }
    wire::finish_sentence(line);
    OUT.send(core::mem::take(line)).await;
}

/// Commands arrive on the output port's RX line; malformed ones are answered here.
#[embassy_executor::task]
async fn command_task(mut rx: BufferedUartRx<'static>) {
    let mut lines = LineBuf::new();
    let mut buf = [0u8; 32];
    loop {
        let Ok(n) = rx.read(&mut buf).await else {
            UART_ERRORS.fetch_add(1, Ordering::Relaxed);
            continue;
        };
        for &byte in &buf[..n] {
            let r = match lines.push(byte) {
                LineEvent::Pending => continue,
                LineEvent::Line(len) => wire::parse_command(lines.line(len), N_COEF),
                LineEvent::Overflow => Err(CmdError::Overflow),
            };
            match r {
                Ok(cmd) => COMMANDS.send(cmd).await,
                Err(e) => {
                    CMD_ERRORS.fetch_add(1, Ordering::Relaxed);
                    let mut line = wire::Line::new();
                    let _ = write!(line, "$MCERR,{}", e.word());
                    wire::finish_sentence(&mut line);
                    OUT.send(line).await;
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
        if tx.write_all(line.as_bytes()).await.is_err() {
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
