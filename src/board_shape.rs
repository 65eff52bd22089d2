//! The one shape every board has: what `board::init` hands the tasks, and the two services
//! a board implements its own way (the watchdog, the coefficient store). The boards differ
//! only in the types behind `board::FluxPort`, `board::Watchdog`, `board::CoefStore`.

use embassy_stm32::usart::{BufferedUartRx, BufferedUartTx};

use crate::board;
use crate::store;

/// What a board gives the firmware at boot.
pub struct Board {
    pub scalar: BufferedUartRx<'static>,
    pub flux: board::FluxPort,
    pub gps: BufferedUartRx<'static>,
    pub out_tx: BufferedUartTx<'static>,
    pub out_rx: BufferedUartRx<'static>,
    pub watchdog: board::Watchdog,
    pub store: board::CoefStore,
}

/// A watchdog that resets the board unless fed within `crate::WATCHDOG_TIMEOUT_US`.
pub trait Watchdog {
    /// Starts it (cannot be stopped).
    fn unleash(&mut self);
    fn feed(&mut self);
}

#[derive(Debug, defmt::Format)]
pub struct StoreError;

/// The coefficient store: [`store::N_IMAGES`] images of [`store::IMAGE_LEN`] bytes, each
/// erased and written on its own (layout in `store.rs`), and the [`store::N_OLD_IMAGES`]
/// the earlier firmware wrote elsewhere.
pub trait CoefStore {
    fn read(&mut self, image: usize, img: &mut store::Image) -> Result<(), StoreError>;
    /// Erases the image's sector and writes it: the CPU stalls for the erase (up to
    /// [`SECTOR_ERASE_MAX_US`]), the other image is not touched.
    fn write(&mut self, image: usize, img: &store::Image) -> Result<(), StoreError>;
    /// The earlier firmware's image `image` (the real board's sector 10 or 11).
    fn read_old(&mut self, image: usize, img: &mut store::Image) -> Result<(), StoreError>;
    /// Makes the earlier firmware's images unreadable as a store (their first word
    /// programmed to 0: no erase, no stall), so a `FACTORY,ERASE` cannot bring them back.
    fn retire_old(&mut self) -> Result<(), StoreError>;
}

/// Longest erase of one image's 16 KiB sector: STM32F405 datasheet (DS8626, "Flash memory
/// programming"), t_ERASE16KB at x32 parallelism (2.7–3.6 V): 250 ms typical, 500 ms max
/// (x8, the reset value of PSIZE: 400 / 800 ms). The emulated store stalls this long.
pub const SECTOR_ERASE_MAX_US: u32 = 500_000;

/// Baud rates per port, chosen at build time (`MAGCOMP_BAUD_OUT`, `MAGCOMP_BAUD_SCALAR`,
/// `MAGCOMP_BAUD_FLUX`, `MAGCOMP_BAUD_GPS`, decimal); what each sensor rate needs is in
/// docs/firmware.md. A value the UART cannot make fails the build, never the boot.
pub const BAUD_OUT: u32 = baud(option_env!("MAGCOMP_BAUD_OUT"), 921_600, 5_250_000);
pub const BAUD_SCALAR: u32 = baud(option_env!("MAGCOMP_BAUD_SCALAR"), 115_200, 2_625_000);
pub const BAUD_GPS: u32 = baud(option_env!("MAGCOMP_BAUD_GPS"), 115_200, 2_625_000);
#[cfg(not(feature = "flux-spi"))]
pub const BAUD_FLUX: u32 = baud(option_env!("MAGCOMP_BAUD_FLUX"), 115_200, 2_625_000);

/// `v` parsed at compile time (`const` items), or `default`. `max`: 16× oversampling of the
/// USART's bus clock (APB2 84 MHz for the output port's USART1, APB1 42 MHz for the rest).
const fn baud(v: Option<&str>, default: u32, max: u32) -> u32 {
    let Some(s) = v else { return default };
    let b = s.as_bytes();
    assert!(!b.is_empty(), "MAGCOMP_BAUD_*: empty");
    let mut n: u32 = 0;
    let mut i = 0;
    while i < b.len() {
        assert!(b[i].is_ascii_digit(), "MAGCOMP_BAUD_*: digits only");
        assert!(n < 100_000_000, "MAGCOMP_BAUD_*: too large");
        n = n * 10 + (b[i] - b'0') as u32;
        i += 1;
    }
    assert!(
        n >= 1_200 && n <= max,
        "MAGCOMP_BAUD_*: out of the UART's range"
    );
    n
}
