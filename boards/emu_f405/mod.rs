//! Emulated board: QEMU `netduinoplus2` (STM32F405RG, the real board's chip), run by hil-tests.
//!
//! Same chip and HAL as the acquisition board, with the QEMU patch of embassy-stm32
//! (`--cfg embassy_qemu`, see docs/firmware.md). Differences from the real board:
//! - clocks: QEMU's RCC is not emulated, so the HSI default is kept (no PLL) and time comes
//!   from a SysTick driver (QEMU's TIM2 lacks compare interrupts);
//! - fluxgate on its UART alternative (QEMU has no SPI ADC);
//! - coefficients in a RAM store with the same blob format (QEMU does not emulate the
//!   flash controller): they survive a soft restart of the tasks, not a QEMU restart; a
//!   write stalls the tasks for a sector erase's worst case, as the real CPU stalls;
//! - logs over semihosting (QEMU stdout) instead of RTT;
//! - the IWDG is a model in the SysTick interrupt (QEMU has none), see [`Watchdog`].
//!
//! QEMU `-serial` order: 0 USART1 (unused), 1 USART2 = output/command, 2 USART3 = scalar,
//! 3 UART4 = fluxgate, 4 UART5 = GPS.

mod systick_driver;

use core::sync::atomic::{AtomicU32, Ordering};
use embassy_stm32::usart::{self, BufferedUart, BufferedUartRx};
use embassy_stm32::{bind_interrupts, peripherals};
use static_cell::ConstStaticCell;

use crate::board_shape::{BAUD_FLUX, BAUD_GPS, BAUD_OUT, BAUD_SCALAR, Board, StoreError};
use crate::store;

pub const NAME: &str = "emu-f405";

/// SysTick counts at QEMU's netduinoplus2 system clock.
const QEMU_SYSCLK_HZ: u32 = 168_000_000;

use crate::uart_stats::Port;
crate::uart_error_counter!(OutErrors, USART2, USART2, Port::Out);
crate::uart_error_counter!(ScalarErrors, USART3, USART3, Port::Scalar);
crate::uart_error_counter!(FluxErrors, UART4, UART4, Port::Flux);
crate::uart_error_counter!(GpsErrors, UART5, UART5, Port::Gps);

// each UART's error counter runs before the HAL's handler (src/uart_stats.rs); QEMU's
// model never sets the error flags, so here they stay 0
bind_interrupts!(struct Irqs {
    USART2 => OutErrors, usart::BufferedInterruptHandler<peripherals::USART2>;
    USART3 => ScalarErrors, usart::BufferedInterruptHandler<peripherals::USART3>;
    UART4 => FluxErrors, usart::BufferedInterruptHandler<peripherals::UART4>;
    UART5 => GpsErrors, usart::BufferedInterruptHandler<peripherals::UART5>;
});

/// A model of the IWDG (QEMU emulates none): the SysTick interrupt resets the board when
/// it has not been fed for `crate::WATCHDOG_TIMEOUT_US`, as the IWDG's own counter would,
/// even while a task spins. It records the cause in the crash record (QEMU sets no RCC flag).
pub struct Watchdog;

/// Deadline in ms of SysTick time; 0 = not unleashed.
static WDG_DEADLINE_MS: AtomicU32 = AtomicU32::new(0);

impl crate::board_shape::Watchdog for Watchdog {
    fn unleash(&mut self) {
        self.feed();
    }
    fn feed(&mut self) {
        let now = embassy_time::Instant::now().as_millis() as u32;
        let d = now.wrapping_add(crate::WATCHDOG_TIMEOUT_US / 1000).max(1);
        WDG_DEADLINE_MS.store(d, Ordering::Relaxed);
    }
}

/// Called from the SysTick interrupt every ms.
fn watchdog_model_tick(now_ms: u32) {
    let d = WDG_DEADLINE_MS.load(Ordering::Relaxed);
    if d != 0 && now_ms.wrapping_sub(d) < u32::MAX / 2 {
        crate::health::record_emulated_watchdog();
        cortex_m::peripheral::SCB::sys_reset();
    }
}

/// Fluxgate port: the serial ASCII alternative.
pub type FluxPort = BufferedUartRx<'static>;

fn uart_config(baud: u32) -> usart::Config {
    let mut c = usart::Config::default();
    c.baudrate = baud;
    // QEMU never raises IDLE: hand bytes to the reader as soon as one is there
    c.eager_reads = Some(1);
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

pub fn init() -> Board {
    let mut config = embassy_stm32::Config::default();
    // LSI is not emulated: leave the low-speed clocks off
    config.rcc.ls = embassy_stm32::rcc::LsConfig::off();
    let p = embassy_stm32::init(config);
    let core = cortex_m::Peripherals::take();
    if let Some(core) = core {
        systick_driver::init(core.SYST, QEMU_SYSCLK_HZ);
    }

    let (tx, rx) = buffers!(512, 256);
    let out = BufferedUart::new(p.USART2, p.PA3, p.PA2, tx, rx, Irqs, uart_config(BAUD_OUT));
    let (tx, rx) = buffers!(8, 512);
    let cfg = uart_config(BAUD_SCALAR);
    let scalar = BufferedUart::new(p.USART3, p.PB11, p.PB10, tx, rx, Irqs, cfg);
    let (tx, rx) = buffers!(8, 512);
    let flux = BufferedUart::new(p.UART4, p.PA1, p.PA0, tx, rx, Irqs, uart_config(BAUD_FLUX));
    let (tx, rx) = buffers!(8, 1024);
    let gps = BufferedUart::new(p.UART5, p.PD2, p.PC12, tx, rx, Irqs, uart_config(BAUD_GPS));
    // a UART that cannot be configured is a firmware bug, not an input condition
    let (out_tx, out_rx) = defmt::unwrap!(out.map_err(|_| ())).split();
    let (_, scalar) = defmt::unwrap!(scalar.map_err(|_| ())).split();
    let (_, flux) = defmt::unwrap!(flux.map_err(|_| ())).split();
    let (_, gps) = defmt::unwrap!(gps.map_err(|_| ())).split();

    let watchdog = Watchdog;
    Board {
        scalar,
        flux,
        gps,
        out_tx,
        out_rx,
        watchdog,
        store: CoefStore::new(),
    }
}

/// Coefficient store: RAM stand-in for the two flash sectors (same images, same checks)
/// and for the earlier firmware's two. `!CUT<n>` (fw::test_hook) makes the next write stop
/// after `n` bytes of the erased image, as a power cut during `SAVE` would leave it;
/// `!OLDSTORE` / `!OLDLEGACY` move the store to the old sectors as an upgrade finds it.
pub struct CoefStore {
    mem: [store::Image; store::N_IMAGES],
    /// In a static, not in the struct: `init` builds the `Board` on the main task's stack,
    /// and 760 more bytes there would raise the start-up stack peak the hil runs measure.
    old: &'static mut [store::Image; store::N_OLD_IMAGES],
}

impl CoefStore {
    fn new() -> Self {
        // erased flash reads as 0xFF: start the same way
        static OLD: ConstStaticCell<[store::Image; store::N_OLD_IMAGES]> =
            ConstStaticCell::new([store::ERASED; store::N_OLD_IMAGES]);
        Self {
            mem: [store::ERASED; store::N_IMAGES],
            old: OLD.take(),
        }
    }

    /// Applies a pending `!OLDSTORE` / `!OLDLEGACY`.
    fn upgrade(&mut self) {
        use crate::fw::test_hook::Upgrade;
        let Some(u) = crate::fw::test_hook::take_upgrade() else {
            return;
        };
        // in place (`fill`, `copy_from_slice`): no image-sized temporaries on the stack
        self.old.iter_mut().for_each(|img| img.fill(0xFF));
        match u {
            Upgrade::TwoImages => self.old.copy_from_slice(&self.mem),
            Upgrade::OneImage => {
                let seqs = core::array::from_fn(|i| store::sequence(&self.mem[i]));
                if let Some(i) = store::newest(seqs) {
                    let n = store::IMAGE_LEN - 8;
                    self.old[1][..n].copy_from_slice(&self.mem[i][8..]);
                }
            }
        }
        // the new firmware's sectors held the earlier firmware's code: not erased, no image
        self.mem.iter_mut().for_each(|img| img.fill(0x00));
    }

    /// The CPU stalls while the real board erases a sector (one flash bank): here the
    /// tasks stall as long, spinning on the SysTick clock, while interrupts still run (so
    /// the UARTs keep receiving, as DMA would on the real board; see docs/firmware.md).
    fn erase_stall() {
        let end = embassy_time::Instant::now()
            + embassy_time::Duration::from_micros(crate::board_shape::SECTOR_ERASE_MAX_US.into());
        while embassy_time::Instant::now() < end {
            core::hint::spin_loop();
        }
    }
}

impl crate::board_shape::CoefStore for CoefStore {
    fn read(&mut self, image: usize, img: &mut store::Image) -> Result<(), StoreError> {
        self.upgrade();
        img.copy_from_slice(self.mem.get(image).ok_or(StoreError)?);
        Ok(())
    }
    fn write(&mut self, image: usize, img: &store::Image) -> Result<(), StoreError> {
        self.upgrade();
        let dst = self.mem.get_mut(image).ok_or(StoreError)?;
        let n = crate::fw::test_hook::take_cut().unwrap_or(store::IMAGE_LEN);
        *dst = store::ERASED;
        Self::erase_stall();
        let n = n.min(store::IMAGE_LEN);
        dst[..n].copy_from_slice(&img[..n]);
        Ok(())
    }
    fn read_old(&mut self, image: usize, img: &mut store::Image) -> Result<(), StoreError> {
        self.upgrade();
        img.copy_from_slice(self.old.get(image).ok_or(StoreError)?);
        Ok(())
    }
    fn retire_old(&mut self) -> Result<(), StoreError> {
        self.upgrade();
        // as flash programming does it: the first word to 0, no erase
        for img in self.old.iter_mut() {
            if img[..4] != [0; 4] && img[..4] != [0xFF; 4] {
                img[..4].fill(0);
            }
        }
        Ok(())
    }
}

/// Ends the QEMU run with a status (semihosting SYS_EXIT).
pub fn exit(ok: bool) -> ! {
    cortex_m_semihosting::debug::exit(if ok {
        cortex_m_semihosting::debug::EXIT_SUCCESS
    } else {
        cortex_m_semihosting::debug::EXIT_FAILURE
    });
    loop {
        cortex_m::asm::wfi();
    }
}
