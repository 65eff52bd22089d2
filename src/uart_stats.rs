//! UART receive errors counted per port and kind. embassy-stm32 0.6's buffered UART reads
//! the error flags in its interrupt, logs them and drops them (its `read` never returns an
//! error), so each board binds a counter *before* the HAL's handler on every UART
//! interrupt ([`uart_error_counter!`]): it reads SR (a read alone clears nothing on the
//! F4's USART v1; the HAL's SR-then-DR read that follows clears the flags as before).
//!
//! A sensor task also compares its port's total after each read, so the scalar lines and
//! fluxgate frames an error may have touched are rejected and their records flagged
//! (`fw::forward`, `magcomp_core::protocol::uart_errors`).
//!
//! Not counted: a byte dropped because the driver's RX ring is full (the HAL drops it
//! silently and exposes no flag); on the F4 that also shows up as an overrun soon after.

use core::sync::atomic::{AtomicU32, Ordering};

/// The board's UART roles (index into the counters).
#[derive(Clone, Copy)]
pub enum Port {
    Scalar = 0,
    // no UART on the SPI-fluxgate flight build
    #[allow(dead_code)]
    Flux = 1,
    Gps = 2,
    /// The output/command port (its RX carries commands).
    Out = 3,
}
const N_PORTS: usize = 4;

/// Error kinds, from SR: overrun (a byte arrived before the last was read), framing (no
/// stop bit: wrong baud rate, a break, a wiring fault), noise (and parity, unused at 8N1).
const N_KINDS: usize = 3;

static ERRORS: [[AtomicU32; N_KINDS]; N_PORTS] =
    [const { [const { AtomicU32::new(0) }; N_KINDS] }; N_PORTS];

/// Counts the error flags of one SR read (called from the UART's interrupt).
pub fn count(port: Port, overrun: bool, framing: bool, noise: bool) {
    for (k, set) in [overrun, framing, noise].into_iter().enumerate() {
        if set {
            ERRORS[port as usize][k].fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// Totals per kind over all ports: `[overrun, framing, noise]`.
pub fn by_kind() -> [u32; N_KINDS] {
    let mut t = [0u32; N_KINDS];
    for p in &ERRORS {
        for (t, e) in t.iter_mut().zip(p) {
            *t = t.wrapping_add(e.load(Ordering::Relaxed));
        }
    }
    t
}

/// Totals per port: `[scalar, flux, gps, out]`.
pub fn by_port() -> [u32; N_PORTS] {
    let mut t = [0u32; N_PORTS];
    for (t, p) in t.iter_mut().zip(&ERRORS) {
        *t = total(p);
    }
    t
}

/// One port's errors of every kind (wrapping): what its task compares after each read to
/// tell the lines an error may have touched (`magcomp_core::protocol::uart_errors`).
pub fn port_total(port: Port) -> u32 {
    total(&ERRORS[port as usize])
}

fn total(kinds: &[AtomicU32; N_KINDS]) -> u32 {
    kinds
        .iter()
        .fold(0u32, |a, e| a.wrapping_add(e.load(Ordering::Relaxed)))
}

/// Defines an interrupt handler type `$name` that counts `$pac`'s error flags for `$port`;
/// list it before the HAL's handler in `bind_interrupts!`.
#[macro_export]
macro_rules! uart_error_counter {
    ($name:ident, $irq:ident, $pac:ident, $port:expr) => {
        pub struct $name;
        impl embassy_stm32::interrupt::typelevel::Handler<embassy_stm32::interrupt::typelevel::$irq>
            for $name
        {
            unsafe fn on_interrupt() {
                let sr = embassy_stm32::pac::$pac.sr().read();
                $crate::uart_stats::count($port, sr.ore(), sr.fe(), sr.ne() || sr.pe());
            }
        }
    };
}
