//! Target benchmark: guest instructions per filter step, counted in QEMU by the TCG plugin
//! `hil-tests/qemu/regioncount.c` between pairs of marker functions (scripts/bench-target.sh).
//! Built like the emulated firmware (profile `fw`: opt-level "s", fat LTO, thumbv7em-none-eabihf).
//!
//! Regions (each measured over `STEPS` calls after a warm-up):
//! - `comp21` / `comp27`: one `Compensator::push` (epoch building, regressors, UD time update,
//!   Bierman measurement update, output) for tl16+field (21 states) and tl16+field+rate (27);
//! - `tu21`/`mu21`, `tu27`/`mu27`: the UD filter's time update (5 field states) and scalar
//!   measurement update alone;
//! - `kf21` / `kf27`: one step (time + measurement update) of the core's plain covariance
//!   filter `CovFilter`, the yardstick: same structure (5 dynamic states, scalar measurement);
//! - `sample21`: the board's whole per-sample path: scalar + fluxgate line parsing, the
//!   aligner, `Compensator::push` and the record encoding;
//! - `sample3`: the same with three magnetometers on a counter line (`M,…`): one line, three
//!   `Compensator::push`, one `$MCMREC`;
//! - `epoch`: `EpochBuilder::push` alone (the part of `Compensator::push` before the filter);
//! - `empty`: the markers alone (overhead to subtract).
#![no_std]
#![no_main]

#[path = "../board_config.rs"]
#[allow(dead_code)]
mod board_config;

// the interrupt vector table (cortex-m-rt is built with its `device` feature)
use embassy_stm32 as _;

use core::fmt::Write as _;
use core::hint::black_box;
use cortex_m_rt::entry;
use cortex_m_semihosting::debug;
use magcomp_core::epoch::{AlignedSample, EpochBuilder};
use magcomp_core::filter::UdFilter;
use magcomp_core::filter::covariance::CovFilter;
use magcomp_core::filter::ud::{MAX_DYNAMIC, MAX_NOISE};
use magcomp_core::model::{Eddy, Induced, Model, Permanent, Rate, Term};
use magcomp_core::protocol::fluxgate::FluxAsciiReader;
use magcomp_core::protocol::multi_record::MAX_MULTI_RECORD_LEN;
use magcomp_core::protocol::scalar::{ScalarConfig, ScalarReader};
use magcomp_core::{Compensator, CompensatorConfig, MagCounts};

const STEPS: u32 = 200;
const WARMUP: u32 = 20;

/// Marker pairs: `#[unsafe(no_mangle)]` so the bench script finds them by name; different
/// nop counts so the linker cannot fold them into one function.
macro_rules! markers {
    ($($b:ident $e:ident $n:literal),* $(,)?) => {$(
        #[unsafe(no_mangle)]
        #[inline(never)]
        pub extern "C" fn $b() {
            for _ in 0..$n { cortex_m::asm::nop(); }
        }
        #[unsafe(no_mangle)]
        #[inline(never)]
        pub extern "C" fn $e() {
            for _ in 0..$n + 1 { cortex_m::asm::nop(); }
            cortex_m::asm::nop();
        }
    )*};
}
markers!(
    bench_empty_begin bench_empty_end 1,
    bench_comp21_begin bench_comp21_end 3,
    bench_comp27_begin bench_comp27_end 5,
    bench_tu21_begin bench_tu21_end 7,
    bench_mu21_begin bench_mu21_end 9,
    bench_tu27_begin bench_tu27_end 11,
    bench_mu27_begin bench_mu27_end 13,
    bench_kf21_begin bench_kf21_end 15,
    bench_kf27_begin bench_kf27_end 17,
    bench_sample21_begin bench_sample21_end 19,
    bench_epoch_begin bench_epoch_end 21,
    bench_sample3_begin bench_sample3_end 23,
);

/// A deterministic manoeuvring sample `k` at 10 Hz.
fn sample(k: u32) -> AlignedSample {
    let t = k as f32 * 0.1;
    let yaw = 1.57 + 0.35 * libm::sinf(t * 0.42);
    let roll = 0.14 * libm::sinf(t * 0.9);
    let (bn, be, bd) = (17_200.0f32, -4_300.0f32, 48_900.0f32);
    let (sy, cy) = libm::sincosf(yaw);
    let (sr, cr) = libm::sincosf(roll);
    let x = cy * bn + sy * be;
    let y0 = -sy * bn + cy * be;
    let flux = [x, cr * y0 + sr * bd, -sr * y0 + cr * bd];
    let mut s = AlignedSample::empty(43_200.0 + f64::from(k) * 0.1);
    s.mag = Some(MagCounts(520_000_000 + ((k * 7919) % 20_000) as i64));
    s.flux_nt = flux;
    s.lat_deg = 45.5;
    s.lon_deg = -73.5 + f64::from(k) * 0.1 * 60.0 / 78_000.0;
    s.alt_m = 300.0;
    s.ground_speed_mps = 60.0;
    s
}

static PAPER_RATE: [&dyn Term; 4] = [&Permanent, &Induced, &Eddy, &Rate];

fn bench_comp<const N: usize>(model: Model<'static>, begin: extern "C" fn(), end: extern "C" fn()) {
    let Ok(mut c) = Compensator::<'static, N, 16>::new(model, CompensatorConfig::for_rate(10.0))
    else {
        fail()
    };
    for k in 0..WARMUP {
        black_box(c.push(&sample(k)));
    }
    for k in WARMUP..WARMUP + STEPS {
        let s = sample(k);
        begin();
        black_box(c.push(black_box(&s)));
        end();
    }
}

/// The epoch builder alone: the non-filter part of `Compensator::push`.
fn bench_epoch() {
    let cfg = CompensatorConfig::for_rate(10.0);
    let Some(mut b) = EpochBuilder::<16>::new(cfg.epoch) else {
        fail()
    };
    for k in 0..WARMUP {
        black_box(b.push(&sample(k)));
    }
    for k in WARMUP..WARMUP + STEPS {
        let s = sample(k);
        bench_epoch_begin();
        black_box(b.push(black_box(&s)));
        bench_epoch_end();
    }
}

#[allow(clippy::needless_range_loop)]
fn bench_ud<const N: usize>(
    n: usize,
    tb: extern "C" fn(),
    te: extern "C" fn(),
    mb: extern "C" fn(),
    me: extern "C" fn(),
) {
    let Some(mut f) = UdFilter::<N>::new(n, &[0.0; N], &[1.0; N]) else {
        fail()
    };
    // field block: integrator chain along track, as the field process discretises it
    let m = 5;
    let mut phi = [[0f32; MAX_DYNAMIC]; MAX_DYNAMIC];
    let mut g = [[0f32; MAX_DYNAMIC]; MAX_NOISE];
    for i in 0..m {
        phi[i][i] = 1.0;
        if i + 1 < m {
            phi[i][i + 1] = 0.06;
        }
        g[i][i] = 1.0;
    }
    let dq = [1e-6f32; 5];
    let mut h = [0f32; N];
    for k in 0..WARMUP + STEPS {
        for (i, v) in h.iter_mut().enumerate().take(n) {
            *v = libm::sinf(0.37 * (i as f32 + 1.0) + 0.1 * k as f32);
        }
        let z = libm::sinf(0.05 * k as f32);
        let measure = k >= WARMUP;
        if measure {
            tb();
        }
        f.time_update(m, black_box(&phi), &g, &dq);
        if measure {
            te();
            mb();
        }
        black_box(f.update(black_box(&h[..n]), z, 4e-4));
        if measure {
            me();
        }
    }
}

/// The core's plain covariance filter (`filter::covariance::CovFilter`, the yardstick) on
/// the same problem as `bench_ud`: one step = time update + scalar measurement update.
#[allow(clippy::needless_range_loop)]
fn bench_kf<const N: usize>(n: usize, b: extern "C" fn(), e: extern "C" fn()) {
    let Some(mut f) = CovFilter::<N>::new(n, &[1.0; N]) else {
        fail()
    };
    let m = 5;
    let mut phi = [[0f32; MAX_DYNAMIC]; MAX_DYNAMIC];
    let mut g = [[0f32; MAX_DYNAMIC]; MAX_NOISE];
    for i in 0..m {
        phi[i][i] = 1.0;
        if i + 1 < m {
            phi[i][i + 1] = 0.06;
        }
        g[i][i] = 1.0;
    }
    let dq = [1e-6f32; 5];
    let mut h = [0f32; N];
    for k in 0..WARMUP + STEPS {
        for (i, v) in h.iter_mut().enumerate().take(n) {
            *v = libm::sinf(0.37 * (i as f32 + 1.0) + 0.1 * k as f32);
        }
        let z = libm::sinf(0.05 * k as f32);
        if k >= WARMUP {
            b();
        }
        f.time_update(m, black_box(&phi), &g, &dq);
        black_box(f.update(black_box(&h[..n]), z, 4e-4));
        if k >= WARMUP {
            e();
        }
    }
    black_box(f.state());
}

/// The board's per-sample work from bytes to an encoded record, with `channels` scalar
/// magnetometers (1: single-field lines; 2–3: a counter line), started afresh in place.
fn bench_sample(
    al: &mut board_config::BoardAcquisition,
    channels: i64,
    begin: extern "C" fn(),
    end: extern "C" fn(),
) {
    if board_config::start(al).is_err() {
        fail()
    }
    let mut scalar = ScalarReader::new(ScalarConfig::default());
    let mut flux = FluxAsciiReader::new();
    let mut out = [0u8; MAX_MULTI_RECORD_LEN];
    for k in 0..WARMUP + STEPS {
        let s = sample(k);
        // the lines as the sensors send them (formatting is not part of the measured path)
        let mut sl = [0u8; 48];
        let sl = fmt_line(&mut sl, |w| {
            let m = s.mag.map_or(0, |m| m.0);
            if channels == 1 {
                return core::fmt::write(
                    w,
                    format_args!("$ {}.{:04},0999\r\n", m / 10_000, m % 10_000),
                );
            }
            w.write_str("M")?;
            for i in 0..channels {
                // each sensor 1.2345 nT apart: its own reading, the same sample
                let m = m + 12_345 * i;
                core::fmt::write(w, format_args!(",{}.{:04}", m / 10_000, m % 10_000))?;
            }
            w.write_str("\r\n")
        });
        let mut fl = [0u8; 48];
        let fl = fmt_line(&mut fl, |w| {
            let f = s.flux_nt.map(|v| v as i32);
            core::fmt::write(w, format_args!("{}.25,{}.5,{}.75\r\n", f[0], f[1], f[2]))
        });
        if k >= WARMUP {
            begin();
        }
        for &b in fl {
            if let Some(r) = flux.push(b) {
                al.flux_result(r);
            }
        }
        for &b in sl {
            if let Some(rec) = scalar.push_line(b).and_then(|l| al.scalar_line(l)) {
                black_box(rec.encode(&mut out).ok());
            }
        }
        if k >= WARMUP {
            end();
        }
    }
}

struct Buf<'a>(&'a mut [u8], usize);
impl core::fmt::Write for Buf<'_> {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        let end = self.1 + s.len();
        self.0
            .get_mut(self.1..end)
            .ok_or(core::fmt::Error)?
            .copy_from_slice(s.as_bytes());
        self.1 = end;
        Ok(())
    }
}
fn fmt_line(buf: &mut [u8], f: impl FnOnce(&mut Buf) -> core::fmt::Result) -> &[u8] {
    let mut b = Buf(buf, 0);
    if f(&mut b).is_err() {
        fail()
    }
    let n = b.1;
    &b.0[..n]
}

fn fail() -> ! {
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    fail()
}

#[entry]
fn main() -> ! {
    for _ in 0..STEPS {
        bench_empty_begin();
        bench_empty_end();
    }
    bench_comp::<32>(Model::paper(), bench_comp21_begin, bench_comp21_end);
    bench_comp::<32>(
        Model {
            field: true,
            terms: &PAPER_RATE,
        },
        bench_comp27_begin,
        bench_comp27_end,
    );
    bench_ud::<21>(
        21,
        bench_tu21_begin,
        bench_tu21_end,
        bench_mu21_begin,
        bench_mu21_end,
    );
    bench_ud::<27>(
        27,
        bench_tu27_begin,
        bench_tu27_end,
        bench_mu27_begin,
        bench_mu27_end,
    );
    bench_kf::<21>(21, bench_kf21_begin, bench_kf21_end);
    bench_kf::<27>(27, bench_kf27_begin, bench_kf27_end);
    // one acquisition (3 compensators, ~22 KB) for both: `start` resets it in place
    static ACQ: static_cell::ConstStaticCell<board_config::BoardAcquisition> =
        static_cell::ConstStaticCell::new(board_config::BoardAcquisition::placeholder(Model {
            field: false,
            terms: &[],
        }));
    let al = ACQ.take();
    bench_sample(al, 1, bench_sample21_begin, bench_sample21_end);
    bench_sample(al, 3, bench_sample3_begin, bench_sample3_end);
    bench_epoch();
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}
