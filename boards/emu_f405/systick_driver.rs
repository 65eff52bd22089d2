// Copied from shared/docs/qemu/systick_driver.rs (proven on QEMU 10 netduinoplus2).
//! Minimal embassy-time driver on the Cortex-M SysTick (for QEMU, where the STM32 TIMx
//! used by embassy-stm32's time driver is missing (L4x5) or only partly emulated (F405)).
//! SysTick interrupts every 1 ms; now() interpolates with the current value register,
//! giving µs resolution for tick-hz-1_000_000.
use core::cell::{Cell, RefCell};
use core::task::Waker;
use cortex_m::peripheral::{SCB, SYST, syst::SystClkSource};
use cortex_m_rt::exception;
use critical_section::Mutex;
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;

struct SysTickDriver {
    base_us: Mutex<Cell<u64>>, // time at last reload
    reload: Mutex<Cell<u32>>,  // SysTick reload value (cycles per ms - 1)
    cyc_per_us: Mutex<Cell<u32>>,
    queue: Mutex<RefCell<Queue>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: SysTickDriver = SysTickDriver {
    base_us: Mutex::new(Cell::new(0)),
    reload: Mutex::new(Cell::new(0)),
    cyc_per_us: Mutex::new(Cell::new(1)),
    queue: Mutex::new(RefCell::new(Queue::new())),
});

/// `core_hz`: the frequency the SysTick really counts at (QEMU: the board's sysclk).
pub fn init(mut syst: SYST, core_hz: u32) {
    critical_section::with(|cs| {
        let reload = core_hz / 1000 - 1;
        DRIVER.reload.borrow(cs).set(reload);
        DRIVER
            .cyc_per_us
            .borrow(cs)
            .set((core_hz / 1_000_000).max(1));
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(reload);
        syst.clear_current();
        syst.enable_interrupt();
        syst.enable_counter();
    });
}

fn now_cs(cs: critical_section::CriticalSection) -> u64 {
    let reload = DRIVER.reload.borrow(cs).get();
    if reload == 0 {
        return 0;
    }
    let base = DRIVER.base_us.borrow(cs).get();
    let cpu = DRIVER.cyc_per_us.borrow(cs).get();
    let mut cvr = SYST::get_current();
    let mut extra = 0u64;
    if SCB::is_pendst_pending() {
        // wrapped but ISR not run yet: re-read, count one more period
        cvr = SYST::get_current();
        extra = 1000;
    }
    base + extra + ((reload - cvr) / cpu) as u64
}

impl Driver for SysTickDriver {
    fn now(&self) -> u64 {
        critical_section::with(now_cs)
    }
    fn schedule_wake(&self, at: u64, waker: &Waker) {
        critical_section::with(|cs| {
            let mut q = self.queue.borrow(cs).borrow_mut();
            q.schedule_wake(at, waker);
            // the 1 ms SysTick ISR polls the queue; nothing else to arm
        });
    }
}

#[exception]
fn SysTick() {
    critical_section::with(|cs| {
        let b = DRIVER.base_us.borrow(cs);
        b.set(b.get() + 1000);
        let now = b.get();
        let mut q = DRIVER.queue.borrow(cs).borrow_mut();
        let _next = q.next_expiration(now);
        super::watchdog_model_tick((now / 1000) as u32);
    });
}
