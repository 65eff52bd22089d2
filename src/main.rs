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

/// The watchdog task's check period (ms): it feeds the watchdog at most this often.
#[cfg(target_os = "none")]
pub const WATCHDOG_CHECK_MS: u32 = 500;

/// Watchdog timeout (µs). The longest the tasks can go unfed without being stalled: the CPU
/// stalled by `FACTORY,ERASE`'s two sector erases (2 × 500 ms max), plus two check periods
/// (the check due during the stall runs after it and may find the command's task still
/// sending its reply; the next one feeds): 2.0 s. The IWDG counts the LSI, 17–47 kHz
/// (DS8626) for the 32 kHz the timeout is computed with, so 3.5 s may last only 2.38 s:
/// 0.38 s of margin (checked below).
#[cfg(target_os = "none")]
pub const WATCHDOG_TIMEOUT_US: u32 = 3_500_000;

#[cfg(target_os = "none")]
const _: () = {
    let stall_us = 2 * board_shape::SECTOR_ERASE_MAX_US + 2 * WATCHDOG_CHECK_MS * 1000;
    // shortest real timeout at the LSI's 47 kHz, with 0.25 s to spare
    assert!(WATCHDOG_TIMEOUT_US / 47 * 32 >= stall_us + 250_000);
};
