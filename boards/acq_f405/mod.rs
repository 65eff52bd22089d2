//! The acquisition board: STM32F405RG (LQFP64), 8 MHz HSE crystal, 168 MHz sysclk.
//! Pin and peripheral map (see boards/README.md):
//!
//! | function                 | peripheral  | pins                         | notes                     |
//! |--------------------------|-------------|------------------------------|---------------------------|
//! | output / command port    | USART1      | PA9 TX, PA10 RX              | 921 600 Bd (APB2, 84 MHz) |
//! | scalar magnetometer      | USART2      | PA2 TX, PA3 RX               | 115 200 Bd                |
//! | fluxgate ADC (24-bit)    | SPI1        | PA5 SCK, PA6 MISO, PA7 MOSI  | feature `flux-spi`, mode 1 |
//! | fluxgate chip select     | GPIO        | PA4                          | active low                |
//! | fluxgate DRDY            | EXTI1       | PB1                          | falling edge              |
//! | fluxgate UART (default)  | USART3      | PB10 TX, PB11 RX             | 115 200 Bd                |
//! | GPS NMEA                 | UART4       | PA0 TX, PA1 RX               | 115 200 Bd                |
//! | GPS PPS (optional)       | EXTI0       | PB0                          | reserved, not used yet    |
//! | SWD + RTT (defmt)        | SWD         | PA13 SWDIO, PA14 SWCLK       | probe-rs                  |
//! | HSE crystal              | OSC         | PH0, PH1                     | 8 MHz                     |
//! | coefficients             | FLASH       | sectors 1–2, 0x0800_4000     | 2 × 16 KiB, two images, no code (memory.x) |
//! | earlier firmware's store | FLASH       | sectors 10–11, 0x080C_0000   | read if 1–2 hold none, retired by FACTORY |
//! | watchdog                 | IWDG        | LSI 32 kHz                   | 3.5 s, fed on progress    |

use embassy_stm32::rcc::*;
use embassy_stm32::time::Hertz;
use embassy_stm32::usart::{self, BufferedUart};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, flash, peripherals};
use static_cell::ConstStaticCell;

#[cfg(not(feature = "flux-spi"))]
use crate::board_shape::BAUD_FLUX;
use crate::board_shape::{BAUD_GPS, BAUD_OUT, BAUD_SCALAR, Board, StoreError};
use crate::store;

pub const NAME: &str = "acq-f405";

use crate::uart_stats::Port;
crate::uart_error_counter!(OutErrors, USART1, USART1, Port::Out);
crate::uart_error_counter!(ScalarErrors, USART2, USART2, Port::Scalar);
crate::uart_error_counter!(GpsErrors, UART4, UART4, Port::Gps);
#[cfg(not(feature = "flux-spi"))]
crate::uart_error_counter!(FluxErrors, USART3, USART3, Port::Flux);

// each UART's error counter runs before the HAL's handler (src/uart_stats.rs)
#[cfg(feature = "flux-spi")]
bind_interrupts!(struct Irqs {
    USART1 => OutErrors, usart::BufferedInterruptHandler<peripherals::USART1>;
    USART2 => ScalarErrors, usart::BufferedInterruptHandler<peripherals::USART2>;
    UART4 => GpsErrors, usart::BufferedInterruptHandler<peripherals::UART4>;
    EXTI1 => embassy_stm32::exti::InterruptHandler<embassy_stm32::interrupt::typelevel::EXTI1>;
});
#[cfg(not(feature = "flux-spi"))]
bind_interrupts!(struct Irqs {
    USART1 => OutErrors, usart::BufferedInterruptHandler<peripherals::USART1>;
    USART2 => ScalarErrors, usart::BufferedInterruptHandler<peripherals::USART2>;
    USART3 => FluxErrors, usart::BufferedInterruptHandler<peripherals::USART3>;
    UART4 => GpsErrors, usart::BufferedInterruptHandler<peripherals::UART4>;
});

/// The IWDG (LSI), fed by the watchdog task only while every task makes progress.
pub struct Watchdog(IndependentWatchdog<'static, peripherals::IWDG>);

impl crate::board_shape::Watchdog for Watchdog {
    fn unleash(&mut self) {
        self.0.unleash();
    }
    fn feed(&mut self) {
        self.0.pet();
    }
}

/// Fluxgate port: the 24-bit SPI ADC with its data-ready line.
#[cfg(feature = "flux-spi")]
pub struct FluxPort {
    pub spi: embassy_stm32::spi::Spi<
        'static,
        embassy_stm32::mode::Blocking,
        embassy_stm32::spi::mode::Master,
    >,
    pub cs: embassy_stm32::gpio::Output<'static>,
    pub drdy: embassy_stm32::exti::ExtiInput<'static, embassy_stm32::mode::Async>,
}
/// Fluxgate port: the serial ASCII alternative.
#[cfg(not(feature = "flux-spi"))]
pub type FluxPort = usart::BufferedUartRx<'static>;

fn uart_config(baud: u32) -> usart::Config {
    let mut c = usart::Config::default();
    c.baudrate = baud;
    c
}

macro_rules! buffers {
    ($tx:literal, $rx:literal) => {{
        // const-initialised (in .bss): no array built on the stack and copied
        static TX: ConstStaticCell<[u8; $tx]> = ConstStaticCell::new([0; $tx]);
        static RX: ConstStaticCell<[u8; $rx]> = ConstStaticCell::new([0; $rx]);
        (TX.take(), RX.take())
    }};
}

fn clocks() -> embassy_stm32::Config {
    let mut config = embassy_stm32::Config::default();
    // 8 MHz HSE / 4 × 168 / 2 = 168 MHz sysclk, /7 = 48 MHz for USB; APB1 42 MHz, APB2 84 MHz
    config.rcc.hse = Some(Hse {
        freq: Hertz(8_000_000),
        mode: HseMode::Oscillator,
    });
    config.rcc.pll_src = PllSource::HSE;
    config.rcc.pll = Some(Pll {
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL168,
        divp: Some(PllPDiv::DIV2),
        divq: Some(PllQDiv::DIV7),
        divr: None,
    });
    config.rcc.sys = Sysclk::PLL1_P;
    config.rcc.ahb_pre = AHBPrescaler::DIV1;
    config.rcc.apb1_pre = APBPrescaler::DIV4;
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config
}

pub fn init() -> Board {
    let p = embassy_stm32::init(clocks());

    let (tx, rx) = buffers!(512, 256);
    let out = BufferedUart::new(p.USART1, p.PA10, p.PA9, tx, rx, Irqs, uart_config(BAUD_OUT));
    let (tx, rx) = buffers!(8, 512);
    let scalar = BufferedUart::new(
        p.USART2,
        p.PA3,
        p.PA2,
        tx,
        rx,
        Irqs,
        uart_config(BAUD_SCALAR),
    );
    let (tx, rx) = buffers!(8, 1024);
    let gps = BufferedUart::new(p.UART4, p.PA1, p.PA0, tx, rx, Irqs, uart_config(BAUD_GPS));
    // a UART that cannot be configured is a firmware bug, not an input condition
    let (out_tx, out_rx) = defmt::unwrap!(out.map_err(|_| ())).split();
    let (_, scalar) = defmt::unwrap!(scalar.map_err(|_| ())).split();
    let (_, gps) = defmt::unwrap!(gps.map_err(|_| ())).split();

    #[cfg(feature = "flux-spi")]
    let flux = {
        use embassy_stm32::gpio::{Level, Output, Pull, Speed};
        let mut cfg = embassy_stm32::spi::Config::default();
        cfg.frequency = Hertz(1_000_000);
        cfg.mode = embassy_stm32::spi::MODE_1;
        FluxPort {
            spi: embassy_stm32::spi::Spi::new_blocking(p.SPI1, p.PA5, p.PA7, p.PA6, cfg),
            cs: Output::new(p.PA4, Level::High, Speed::VeryHigh),
            drdy: embassy_stm32::exti::ExtiInput::new(p.PB1, p.EXTI1, Pull::Up, Irqs),
        }
    };
    #[cfg(not(feature = "flux-spi"))]
    let flux = {
        let (tx, rx) = buffers!(8, 512);
        let cfg = uart_config(BAUD_FLUX);
        let f = BufferedUart::new(p.USART3, p.PB11, p.PB10, tx, rx, Irqs, cfg);
        defmt::unwrap!(f.map_err(|_| ())).split().1
    };

    let watchdog = Watchdog(IndependentWatchdog::new(p.IWDG, crate::WATCHDOG_TIMEOUT_US));
    let store = CoefStore {
        flash: flash::Flash::new_blocking(p.FLASH),
    };
    Board {
        scalar,
        flux,
        gps,
        out_tx,
        out_rx,
        watchdog,
        store,
    }
}

/// The store's two images: flash sectors 1 and 2 (16 KiB each; memory.x keeps code out of
/// sectors 1–3), as offsets from the flash base.
const IMAGE_SECTORS: [u32; store::N_IMAGES] = [0x0000_4000, 0x0000_8000];
const SECTOR_SIZE: u32 = 16 * 1024;
/// The earlier firmware's images: sectors 10 and 11 (128 KiB, outside memory.x's program
/// area). Its image 1 is sector 11, where the single-image store before it kept its blobs.
const OLD_SECTORS: [u32; store::N_OLD_IMAGES] = [0x000C_0000, 0x000E_0000];

const _: () = assert!(store::IMAGE_LEN as u32 <= SECTOR_SIZE);

/// Coefficient store: two flash sectors, one image each.
pub struct CoefStore {
    flash: flash::Flash<'static, flash::Blocking>,
}

impl CoefStore {
    fn sector(image: usize) -> Result<u32, StoreError> {
        IMAGE_SECTORS.get(image).copied().ok_or(StoreError)
    }

    /// Erases one sector at x32 parallelism. embassy-stm32 0.6 sets PSIZE for programming
    /// only and erases with whatever the control register holds: x8 after reset and after
    /// its own writes, 400 ms typ / 800 ms max for 16 KiB instead of x32's 250 / 500
    /// (DS8626; x32 needs 2.7–3.6 V, the board runs at 3.3 V). The register only takes a
    /// write unlocked, so unlock it here (the driver then finds it unlocked, keeps PSIZE and
    /// locks it again after the erase).
    fn erase_x32(&mut self, at: u32) -> Result<(), StoreError> {
        use embassy_stm32::pac::{FLASH, flash::vals::Psize};
        if FLASH.cr().read().lock() {
            // RM0090 3.5.1: the two keys in a row; a wrong one locks the register until reset
            FLASH.keyr().write_value(0x4567_0123);
            FLASH.keyr().write_value(0xCDEF_89AB);
        }
        FLASH.cr().modify(|w| w.set_psize(Psize::PSIZE32));
        self.flash
            .blocking_erase(at, at + SECTOR_SIZE)
            .map_err(|_| StoreError)
    }
}

impl crate::board_shape::CoefStore for CoefStore {
    fn read(&mut self, image: usize, img: &mut store::Image) -> Result<(), StoreError> {
        self.flash
            .blocking_read(Self::sector(image)?, img)
            .map_err(|_| StoreError)
    }
    /// Erases the image's 16 KiB sector (250 ms typ, 500 ms max: the CPU stalls, the
    /// watchdog timeout allows it) and writes it; the other image is not touched.
    fn write(&mut self, image: usize, img: &store::Image) -> Result<(), StoreError> {
        let at = Self::sector(image)?;
        // flash programming needs a multiple of the 4-byte write size
        let mut buf = [0xFFu8; store::IMAGE_LEN.div_ceil(4) * 4];
        buf[..store::IMAGE_LEN].copy_from_slice(img);
        self.erase_x32(at)?;
        self.flash.blocking_write(at, &buf).map_err(|_| StoreError)
    }
    fn read_old(&mut self, image: usize, img: &mut store::Image) -> Result<(), StoreError> {
        let at = OLD_SECTORS.get(image).ok_or(StoreError)?;
        self.flash.blocking_read(*at, img).map_err(|_| StoreError)
    }
    /// Programs the first word of each old image to 0 (its magic, or the single-image
    /// store's first blob's): programming only clears bits, so no 128 KiB erase (1–2 s).
    /// Erased or already retired words are left alone.
    fn retire_old(&mut self) -> Result<(), StoreError> {
        for at in OLD_SECTORS {
            let mut word = [0u8; 4];
            self.flash
                .blocking_read(at, &mut word)
                .map_err(|_| StoreError)?;
            if word != [0; 4] && word != [0xFF; 4] {
                self.flash
                    .blocking_write(at, &[0; 4])
                    .map_err(|_| StoreError)?;
            }
        }
        Ok(())
    }
}

/// The real board has nowhere to exit to: reset.
pub fn exit(_ok: bool) -> ! {
    cortex_m::peripheral::SCB::sys_reset()
}
