//! magcomp acquisition-board firmware.
//!
//! Tasks (one per box, joined by embassy-sync channels, no heap):
//!
//! ```text
//! scalar UART ─► line_task(Scalar) ─┐
//! flux SPI/UART ► flux task ────────┼─► EVENTS ─► aligner_task ─► SAMPLES ─► filter_task ─► OUT ─► output_task ─► output UART
//! GPS UART ───► line_task(Gps) ─────┘   (arrival order)                         ▲   │
//! output UART RX ─► command_task ──────────────────────────► COMMANDS ──────────┘   └ replies, records
//! watchdog_task: feeds the IWDG only while every task makes progress (health.rs)
//! ```
//!
//! Every scalar line becomes exactly one record; the channels apply back-pressure instead of
//! dropping (a full output port slows the filter, the UART ring buffers absorb the sensors).
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!(
        "magcomp-firmware runs on the board: cargo fw-build / cargo fw-run (see docs/firmware.md)"
    );
}

#[cfg(target_os = "none")]
mod board_config;

#[cfg(all(target_os = "none", feature = "board-acq", feature = "board-emu"))]
compile_error!(
    "choose one board: --no-default-features --features board-emu for the emulated board"
);

#[cfg(all(target_os = "none", feature = "board-acq", not(feature = "board-emu")))]
#[path = "../boards/acq_f405/mod.rs"]
mod board;
#[cfg(all(target_os = "none", feature = "board-emu", not(feature = "board-acq")))]
#[path = "../boards/emu_f405/mod.rs"]
mod board;

#[cfg(target_os = "none")]
mod board_shape;
#[cfg(target_os = "none")]
mod fw;
#[cfg(target_os = "none")]
mod health;
#[cfg(target_os = "none")]
mod store;
#[cfg(target_os = "none")]
mod uart_stats;

/// Watchdog timeout (µs): long enough for a flash sector erase on the real board (1–2 s).
#[cfg(target_os = "none")]
pub const WATCHDOG_TIMEOUT_US: u32 = 4_000_000;
