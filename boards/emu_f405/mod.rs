//! Emulated board: QEMU `netduinoplus2` (STM32F405RG, the real board's chip), run by hil-tests.
//!
//! Same chip and HAL as the acquisition board, with the QEMU patch of embassy-stm32
//! (`--cfg embassy_qemu`, see docs/firmware.md). Differences from the real board:
//! - clocks: QEMU's RCC is not emulated, so the HSI default is kept (no PLL) and time comes
//!   from a SysTick driver (QEMU's TIM2 lacks compare interrupts);
//! - fluxgate on its UART alternative (QEMU has no SPI ADC);
//! - coefficients in a RAM store with the same blob format (QEMU does not emulate the
//!   flash controller): they survive a soft restart of the tasks, not a QEMU restart;
//! - logs over semihosting (QEMU stdout) instead of RTT.
//!
//! QEMU `-serial` order: 0 USART1 (unused), 1 USART2 = output/command, 2 USART3 = scalar,
//! 3 UART4 = fluxgate, 4 UART5 = GPS.

mod systick_driver;

use embassy_stm32::usart::{self, BufferedUart, BufferedUartRx, BufferedUartTx};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, peripherals};
use static_cell::StaticCell;

pub const NAME: &str = "emu-f405";

/// SysTick counts at QEMU's netduinoplus2 system clock.
const QEMU_SYSCLK_HZ: u32 = 168_000_000;

bind_interrupts!(struct Irqs {
    USART2 => usart::BufferedInterruptHandler<peripherals::USART2>;
    USART3 => usart::BufferedInterruptHandler<peripherals::USART3>;
    UART4 => usart::BufferedInterruptHandler<peripherals::UART4>;
    UART5 => usart::BufferedInterruptHandler<peripherals::UART5>;
});

pub type Watchdog = IndependentWatchdog<'static, peripherals::IWDG>;

/// Fluxgate port: the serial ASCII alternative.
pub type FluxPort = BufferedUartRx<'static>;

pub struct Board {
    pub scalar: BufferedUartRx<'static>,
    pub flux: FluxPort,
    pub gps: BufferedUartRx<'static>,
    pub out_tx: BufferedUartTx<'static>,
    pub out_rx: BufferedUartRx<'static>,
    pub watchdog: Watchdog,
    pub store: CoefStore,
}

fn uart_config(baud: u32) -> usart::Config {
    let mut c = usart::Config::default();
    c.baudrate = baud;
    // QEMU never raises IDLE: hand bytes to the reader as soon as one is there
    c.eager_reads = Some(1);
    c
}

macro_rules! buffers {
    ($tx:literal, $rx:literal) => {{
        static TX: StaticCell<[u8; $tx]> = StaticCell::new();
        static RX: StaticCell<[u8; $rx]> = StaticCell::new();
        (TX.init([0; $tx]), RX.init([0; $rx]))
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
    let out = BufferedUart::new(p.USART2, p.PA3, p.PA2, tx, rx, Irqs, uart_config(921_600));
    let (tx, rx) = buffers!(8, 512);
    let scalar = BufferedUart::new(p.USART3, p.PB11, p.PB10, tx, rx, Irqs, uart_config(115_200));
    let (tx, rx) = buffers!(8, 512);
    let flux = BufferedUart::new(p.UART4, p.PA1, p.PA0, tx, rx, Irqs, uart_config(115_200));
    let (tx, rx) = buffers!(8, 1024);
    let gps = BufferedUart::new(p.UART5, p.PD2, p.PC12, tx, rx, Irqs, uart_config(115_200));
    // a UART that cannot be configured is a firmware bug, not an input condition
    let (out_tx, out_rx) = defmt::unwrap!(out.map_err(|_| ())).split();
    let (_, scalar) = defmt::unwrap!(scalar.map_err(|_| ())).split();
    let (_, flux) = defmt::unwrap!(flux.map_err(|_| ())).split();
    let (_, gps) = defmt::unwrap!(gps.map_err(|_| ())).split();

    let watchdog = IndependentWatchdog::new(p.IWDG, crate::WATCHDOG_TIMEOUT_US);
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

/// Coefficient store: RAM stand-in for the flash sector (same blob, same CRC checks).
pub struct CoefStore {
    mem: [u8; crate::COEF_BLOB_MAX],
}

#[derive(Debug, defmt::Format)]
pub struct StoreError;

impl CoefStore {
    const fn new() -> Self {
        // erased flash reads as 0xFF: start the same way
        Self {
            mem: [0xFF; crate::COEF_BLOB_MAX],
        }
    }
    pub fn read(&mut self, buf: &mut [u8]) -> Result<(), StoreError> {
        let n = buf.len().min(self.mem.len());
        buf[..n].copy_from_slice(&self.mem[..n]);
        Ok(())
    }
    pub fn write(&mut self, data: &[u8]) -> Result<(), StoreError> {
        let dst = self.mem.get_mut(..data.len()).ok_or(StoreError)?;
        dst.copy_from_slice(data);
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

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    defmt::error!("panic: {}", defmt::Display2Format(info));
    exit(false)
}
