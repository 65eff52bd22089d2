//! Liveness: per-task heartbeats for the watchdog, the reset cause, and the crash record a
//! panic leaves in no-init RAM for the next boot to report.

use core::fmt::Write as _;
use core::future::Future;
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

/// The tasks the watchdog watches (the watchdog task itself is covered by the IWDG: if it
/// does not run, nothing feeds it).
#[derive(Clone, Copy, defmt::Format)]
pub enum Task {
    Scalar,
    Flux,
    Gps,
    Acq,
    Command,
    Output,
}
const N_TASKS: usize = 6;

struct Beat {
    /// The task is waiting for its input: a silent sensor is not a stalled task.
    waiting: AtomicBool,
    /// Units of work done (incremented each time the task comes back to wait).
    done: AtomicU32,
}

static BEATS: [Beat; N_TASKS] = [const {
    Beat {
        waiting: AtomicBool::new(false),
        done: AtomicU32::new(0),
    }
}; N_TASKS];

/// Awaits a task's input. Coming back here means the previous unit of work is done; while
/// here the task is idle, not stalled. Everything between two `idle` calls (parsing,
/// sending into a full channel, writing the UART) is work that must finish.
pub async fn idle<F: Future>(t: Task, input: F) -> F::Output {
    let b = &BEATS[t as usize];
    b.done.fetch_add(1, Ordering::Relaxed);
    b.waiting.store(true, Ordering::Relaxed);
    let r = input.await;
    b.waiting.store(false, Ordering::Relaxed);
    r
}

/// What the watchdog task saw at its previous check.
pub struct Progress {
    seen: [u32; N_TASKS],
}

impl Progress {
    pub const fn new() -> Self {
        Self {
            seen: [u32::MAX; N_TASKS],
        }
    }

    /// `Ok` when every task is idle or has finished work since the previous check; else
    /// the first task that is busy and has not.
    pub fn check(&mut self) -> Result<(), Task> {
        const ALL: [Task; N_TASKS] = [
            Task::Scalar,
            Task::Flux,
            Task::Gps,
            Task::Acq,
            Task::Command,
            Task::Output,
        ];
        let mut stalled = None;
        for t in ALL {
            let b = &BEATS[t as usize];
            let done = b.done.load(Ordering::Relaxed);
            let ok = b.waiting.load(Ordering::Relaxed) || done != self.seen[t as usize];
            self.seen[t as usize] = done;
            if !ok && stalled.is_none() {
                stalled = Some(t);
            }
        }
        stalled.map_or(Ok(()), Err)
    }
}

/// Why the board last reset: RCC CSR flags, most specific first, or the crash record.
#[derive(Clone, Copy, PartialEq, Eq, defmt::Format)]
pub enum ResetCause {
    /// Independent watchdog (a stalled task or a hard fault).
    Iwdg,
    Wwdg,
    LowPower,
    /// Software reset: a panic (see the crash record), `board::exit`.
    Software,
    /// Power on / brown-out.
    PowerOn,
    /// The NRST pin (reset button, debugger).
    Pin,
    /// No flag set (the emulator's RCC keeps none).
    Unknown,
}

impl ResetCause {
    pub fn word(self) -> &'static [u8] {
        match self {
            ResetCause::Iwdg => b"IWDG",
            ResetCause::Wwdg => b"WWDG",
            ResetCause::LowPower => b"LPWR",
            ResetCause::Software => b"SW",
            ResetCause::PowerOn => b"POR",
            ResetCause::Pin => b"PIN",
            ResetCause::Unknown => b"NONE",
        }
    }
}

/// The crash record in `.uninit` (NOLOAD: the start-up code neither zeroes nor copies it,
/// so a software or watchdog reset keeps it; power-on leaves garbage, hence magic + check).
#[repr(C)]
#[derive(Clone, Copy)]
struct Crash {
    magic: u32,
    /// [`CAUSE_PANIC`] or [`CAUSE_EMU_WATCHDOG`].
    cause: u32,
    line: u32,
    file_len: u32,
    file: [u8; FILE_LEN],
    check: u32,
}
const FILE_LEN: usize = 40;
const MAGIC: u32 = 0x4D43_5253; // "MCRS"
const CAUSE_PANIC: u32 = 1;
/// The emulated board's IWDG model fired (QEMU has no IWDG and keeps no RCC flags).
const CAUSE_EMU_WATCHDOG: u32 = 2;

impl Crash {
    fn checksum(&self) -> u32 {
        let words = [self.magic, self.cause, self.line, self.file_len];
        let bytes = words.iter().flat_map(|w| w.to_le_bytes()).chain(self.file);
        bytes.fold(0x811C_9DC5u32, |h, b| {
            (h ^ u32::from(b)).wrapping_mul(0x0100_0193)
        })
    }
}

#[unsafe(link_section = ".uninit.magcomp_crash")]
static mut CRASH: MaybeUninit<Crash> = MaybeUninit::uninit();

fn write_crash(c: Crash) {
    let c = Crash {
        check: c.checksum(),
        ..c
    };
    // SAFETY: CRASH is only accessed here and in `take_crash`, both with interrupts either
    // not yet running (boot) or about to reset (panic, watchdog model); a volatile write
    // so it is not elided before the reset.
    unsafe { core::ptr::write_volatile(&raw mut CRASH, MaybeUninit::new(c)) }
}

fn take_crash() -> Option<Crash> {
    // SAFETY: no-init RAM holds whatever the last run (or power-on) left: read it whole,
    // volatile, as plain integers and bytes (every bit pattern is a valid `Crash`), then
    // accept it only with the magic and a matching check. Cleared so it is reported once.
    let c = unsafe {
        let raw = core::ptr::read_volatile(&raw const CRASH);
        core::ptr::write_volatile(&raw mut CRASH, MaybeUninit::zeroed());
        raw.assume_init()
    };
    (c.magic == MAGIC && c.check == c.checksum()).then_some(c)
}

/// The emulated board's watchdog model records why it resets (QEMU sets no RCC flag).
#[cfg(feature = "board-emu")]
pub fn record_emulated_watchdog() {
    write_crash(Crash {
        magic: MAGIC,
        cause: CAUSE_EMU_WATCHDOG,
        line: 0,
        file_len: 0,
        file: [0; FILE_LEN],
        check: 0,
    });
}

/// What the boot banner reports about the previous run.
pub struct BootInfo {
    pub cause: ResetCause,
    /// `file:line` of the panic that caused the reset (ASCII, no commas).
    pub panic: Option<heapless::String<56>>,
}

/// Reads and clears the reset flags and the crash record. Call once, first thing at boot.
pub fn take_boot_info() -> BootInfo {
    let rcc = embassy_stm32::pac::RCC;
    let f = rcc.csr().read();
    rcc.csr().modify(|w| w.set_rmvf(true));
    let crash = take_crash();
    let cause = if f.wdgrstf() || crash.is_some_and(|c| c.cause == CAUSE_EMU_WATCHDOG) {
        ResetCause::Iwdg
    } else if f.wwdgrstf() {
        ResetCause::Wwdg
    } else if f.lpwrrstf() {
        ResetCause::LowPower
    } else if f.sftrstf() || crash.is_some_and(|c| c.cause == CAUSE_PANIC) {
        ResetCause::Software
    } else if f.porrstf() || f.borrstf() {
        ResetCause::PowerOn
    } else if f.padrstf() {
        ResetCause::Pin
    } else {
        ResetCause::Unknown
    };
    let panic = crash.filter(|c| c.cause == CAUSE_PANIC).map(|c| {
        let mut s = heapless::String::new();
        let n = (c.file_len as usize).min(FILE_LEN);
        for &b in &c.file[..n] {
            let _ = s.push(char::from(b));
        }
        let _ = write!(s, ":{}", c.line);
        s
    });
    BootInfo { cause, panic }
}

/// Any panic (a firmware bug: input never panics) records where it happened in no-init
/// RAM and resets; the next `$MCBOOT` reports it (`PANIC=file:line`).
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    cortex_m::interrupt::disable();
    let mut c = Crash {
        magic: MAGIC,
        cause: CAUSE_PANIC,
        line: 0,
        file_len: 0,
        file: [0; FILE_LEN],
        check: 0,
    };
    if let Some(l) = info.location() {
        c.line = l.line();
        // the path's tail (the file name matters most), banner-safe bytes only
        let f = l.file().as_bytes();
        let tail = &f[f.len().saturating_sub(FILE_LEN)..];
        for (d, &s) in c.file.iter_mut().zip(tail) {
            let ok = s.is_ascii_alphanumeric() || matches!(s, b'_' | b'.' | b'/' | b'-');
            *d = if ok { s } else { b'_' };
        }
        c.file_len = tail.len() as u32;
    }
    write_crash(c);
    defmt::error!("panic: {}", defmt::Display2Format(info));
    cortex_m::peripheral::SCB::sys_reset()
}
