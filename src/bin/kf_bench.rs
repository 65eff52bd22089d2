//! Target benchmark: guest instructions per filter step, counted in QEMU by the TCG plugin
//! `hil-tests/qemu/regioncount.c` between pairs of marker functions (scripts/bench-target.sh).
//! Built like the emulated firmware (profile `fw`: opt-level "s", fat LTO, thumbv7em-none-eabihf).
//!
//! Regions (each measured over `STEPS` calls after a warm-up):
//! - `comp21` / `comp27`: one `Compensator::push` (epoch building, regressors, UD time update,
//!   Bierman measurement update, output) for tl16+field (21 states) and tl16+field+rate (27);
//! - `tu21`/`mu21`, `tu27`/`mu27`: the UD filter's time update (5 field states) and scalar
//!   measurement update alone;
//! - `kf21` / `kf27`: a plain covariance Kalman step (same structure: 5 dynamic states,
//!   scalar measurement) written here, because the core exposes none;
//! - `sample21`: the board's whole per-sample path: scalar + fluxgate line parsing, the
//!   aligner, `Compensator::push` and the record encoding;
//! - `empty`: the markers alone (overhead to subtract).
#![no_std]
#![no_main]

#[path = "../pipeline.rs"]
#[allow(dead_code)]
mod pipeline;
#[path = "../timebase.rs"]
#[allow(dead_code)]
mod timebase;

// the interrupt vector table (cortex-m-rt is built with its `device` feature)
use embassy_stm32 as _;

use core::hint::black_box;
use cortex_m_rt::entry;
use cortex_m_semihosting::debug;
use magcomp_core::epoch::AlignedSample;
use magcomp_core::filter::UdFilter;
use magcomp_core::filter::ud::{MAX_DYNAMIC, MAX_NOISE};
use magcomp_core::model::{Eddy, Induced, Model, Permanent, Rate, Term};
use magcomp_core::protocol::fluxgate::FluxAsciiReader;
use magcomp_core::protocol::record::{MAX_RECORD_LEN, encode_record};
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

/// Plain covariance Kalman filter with the same structure as the compensator's: `m`
/// dynamic states (block `Φ`) followed by constant states, one scalar measurement.
struct PlainKf<const N: usize> {
    n: usize,
    x: [f32; N],
    p: [[f32; N]; N],
}

// index loops read like the matrix algebra they implement
#[allow(clippy::needless_range_loop)]
impl<const N: usize> PlainKf<N> {
    fn new(n: usize) -> Self {
        let mut p = [[0f32; N]; N];
        for (i, row) in p.iter_mut().enumerate().take(n) {
            row[i] = 1.0;
        }
        Self { n, x: [0.0; N], p }
    }

    /// `P ← ΦPΦᵀ + Q` with Φ = identity except the leading m×m block (only the m rows/columns
    /// it touches are recomputed), then the scalar update `K = Ph/(hᵀPh + r)`, `P ← P − K hᵀP`.
    fn step(
        &mut self,
        m: usize,
        phi: &[[f32; MAX_DYNAMIC]; MAX_DYNAMIC],
        q: f32,
        h: &[f32],
        z: f32,
        r: f32,
    ) {
        let n = self.n;
        let mut xm = [0f32; MAX_DYNAMIC];
        for i in 0..m {
            xm[i] = (0..m).map(|k| phi[i][k] * self.x[k]).sum();
        }
        self.x[..m].copy_from_slice(&xm[..m]);
        // rows 0..m: Φ·P
        let mut rows = [[0f32; N]; MAX_DYNAMIC];
        for i in 0..m {
            for j in 0..n {
                rows[i][j] = (0..m).map(|k| phi[i][k] * self.p[k][j]).sum();
            }
        }
        // (ΦP)Φᵀ for the m×m block, ΦP for the coupling, then symmetric copy
        for i in 0..m {
            for j in 0..m {
                self.p[i][j] = (0..m).map(|k| rows[i][k] * phi[j][k]).sum::<f32>()
                    + if i == j { q } else { 0.0 };
            }
            for j in m..n {
                self.p[i][j] = rows[i][j];
                self.p[j][i] = rows[i][j];
            }
        }
        let mut ph = [0f32; N];
        for i in 0..n {
            ph[i] = (0..n).map(|j| self.p[i][j] * h[j]).sum();
        }
        let s: f32 = (0..n).map(|i| h[i] * ph[i]).sum::<f32>() + r;
        // also rejects NaN
        if s.partial_cmp(&0.0) != Some(core::cmp::Ordering::Greater) {
            return;
        }
        let innov = z - (0..n).map(|i| h[i] * self.x[i]).sum::<f32>();
        for i in 0..n {
            let k = ph[i] / s;
            self.x[i] += k * innov;
            for j in i..n {
                let v = self.p[i][j] - k * ph[j];
                self.p[i][j] = v;
                self.p[j][i] = v;
            }
        }
    }
}

#[allow(clippy::needless_range_loop)]
fn bench_kf<const N: usize>(n: usize, b: extern "C" fn(), e: extern "C" fn()) {
    let mut kf = PlainKf::<N>::new(n);
    let mut phi = [[0f32; MAX_DYNAMIC]; MAX_DYNAMIC];
    for i in 0..5 {
        phi[i][i] = 1.0;
        if i + 1 < 5 {
            phi[i][i + 1] = 0.06;
        }
    }
    let mut h = [0f32; N];
    for k in 0..WARMUP + STEPS {
        for (i, v) in h.iter_mut().enumerate().take(n) {
            *v = libm::sinf(0.37 * (i as f32 + 1.0) + 0.1 * k as f32);
        }
        let z = libm::sinf(0.05 * k as f32);
        if k >= WARMUP {
            b();
        }
        kf.step(5, black_box(&phi), 1e-6, black_box(&h[..n]), z, 4e-4);
        if k >= WARMUP {
            e();
        }
    }
    black_box(&kf.x);
}

/// The board's per-sample work from bytes to an encoded record.
fn bench_sample() {
    use timebase::{Rates, SampleAligner};
    let Ok(mut filter) = pipeline::Filter::new(10.0) else {
        fail()
    };
    let mut al = SampleAligner::new(Rates {
        scalar_hz: 10.0,
        flux_hz: 10.0,
        gps_hz: 1.0,
    });
    let mut scalar = ScalarReader::new(ScalarConfig::default());
    let mut flux = FluxAsciiReader::new();
    let mut out = [0u8; MAX_RECORD_LEN];
    for k in 0..WARMUP + STEPS {
        let s = sample(k);
        // the lines as the sensors send them (formatting is not part of the measured path)
        let mut sl = [0u8; 24];
        let sl = fmt_line(&mut sl, |w| {
            let m = s.mag.map_or(0, |m| m.0);
            core::fmt::write(
                w,
                format_args!("$ {}.{:04},0999\r\n", m / 10_000, m % 10_000),
            )
        });
        let mut fl = [0u8; 48];
        let fl = fmt_line(&mut fl, |w| {
            let f = s.flux_nt.map(|v| v as i32);
            core::fmt::write(w, format_args!("{}.25,{}.5,{}.75\r\n", f[0], f[1], f[2]))
        });
        if k >= WARMUP {
            bench_sample21_begin();
        }
        for &b in fl {
            if let Some(r) = flux.push(b) {
                al.flux(r);
            }
        }
        for &b in sl {
            if let Some(r) = scalar.push(b) {
                let (_, smp) = al.scalar(r);
                if let Some(rec) = filter.push(&smp) {
                    black_box(encode_record(&rec, &mut out).ok());
                }
            }
        }
        if k >= WARMUP {
            bench_sample21_end();
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
    bench_sample();
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}
