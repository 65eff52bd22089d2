//! The fluxgate's delay line (`lag` on the board): a scalar sample at t is paired with the
//! fluxgate at t − τ; one record per scalar line whatever τ; `FLUX_STALE` until the line
//! reaches back τ.

#[path = "common/acq_run.rs"]
mod acq_run;
use acq_run::run;

use magcomp_core::acquisition::{compensator_config, AcqConfig, Acquisition};
use magcomp_core::model::Model;
use magcomp_core::protocol::aligner::{Aligner, AlignerConfig};
use magcomp_core::protocol::capture::Port;
use magcomp_core::protocol::lag_line::{LagError, LagLine, MAX_LAG_S};
use magcomp_core::protocol::record::Record;
use magcomp_core::{Compensator, Flags, MagCounts};

const RATE_HZ: f64 = 10.0;

type Acq<'a> = Acquisition<'a, 32, 16>;

fn acq<'a>(flux_hz: f64) -> Acq<'a> {
    acq_at(RATE_HZ, flux_hz)
}

fn acq_at<'a>(scalar_hz: f64, flux_hz: f64) -> Acq<'a> {
    let comp = Compensator::new(Model::paper(), compensator_config(scalar_hz as f32, 16)).unwrap();
    Acquisition::new(AcqConfig::new(scalar_hz, flux_hz, 1.0), comp).unwrap()
}

/// Field vector of a manoeuvring aircraft, body frame (nT), at `t_s` (the phase turns at
/// 3 rad/s: 0.3 per epoch at 10 Hz; per frame at 1 kHz, a rotation the fluxgate's
/// continuity check takes for one).
fn flux_at(t_s: f64) -> [f64; 3] {
    let a = t_s * 3.0;
    [
        20_000.0 + 3000.0 * a.sin(),
        1000.0 * (0.7 * a).cos(),
        45_000.0 - 1000.0 * a.sin(),
    ]
}

/// `n` epochs at `rate_hz` of fluxgate then scalar; the fluxgate shows epoch `k − delay`,
/// none inside `gap`.
fn stream(rate_hz: f64, n: usize, delay: i64, gap: Option<(usize, usize)>) -> Vec<(Port, Vec<u8>)> {
    let mut chunks = Vec::new();
    for k in 0..n {
        if !gap.is_some_and(|(a, b)| (a..b).contains(&k)) {
            let f = flux_at((k as i64 - delay) as f64 / rate_hz);
            let line = format!("{:.3},{:.3},{:.3}\r\n", f[0], f[1], f[2]);
            chunks.push((Port::Flux, line.into_bytes()));
        }
        let m = 536_200_000 + (k as i64 * 37) % 5000;
        let line = format!("{}.{:04}\r\n", m / 10_000, m % 10_000);
        chunks.push((Port::Scalar, line.into_bytes()));
    }
    chunks
}

fn coefficients() -> [f32; 16] {
    core::array::from_fn(|i| (i as f32 - 7.5) * 2.0)
}

fn stale(recs: &[Record]) -> Vec<usize> {
    recs.iter()
        .enumerate()
        .filter(|(_, r)| r.flags.contains(Flags::FLUX_STALE))
        .map(|(i, _)| i)
        .collect()
}

/// τ = `delay` periods through the line gives, record for record, what the acquisition
/// without a delay gives when the fluxgate itself arrives `delay` periods late:
/// bit-identical interference (survey mode: coefficients × regressors of e, ė) once the
/// derivative window is past the first τ; those first `delay` records are FLUX_STALE, none
/// is lost.
fn whole_sample_delay_equals_a_fluxgate_sent_late(rate_hz: f64, delay: usize, n: usize) {
    let lag_s = (delay as f64 / rate_hz) as f32;
    let mut line = LagLine::new();
    let mut a = acq_at(rate_hz, rate_hz);
    a.attach_lag_line(&mut line);
    a.set_lag_s(lag_s).unwrap();
    assert_eq!(a.lag_s(), lag_s);
    a.set_coefficients(&coefficients()).unwrap();
    let lagged = run(&mut a, &stream(rate_hz, n, 0, None));
    let mut b = acq_at(rate_hz, rate_hz);
    b.set_coefficients(&coefficients()).unwrap();
    let late = run(&mut b, &stream(rate_hz, n, delay as i64, None));
    // Without the delay, the same stream is another pairing altogether.
    let mut c = acq_at(rate_hz, rate_hz);
    c.set_coefficients(&coefficients()).unwrap();
    let plain = run(&mut c, &stream(rate_hz, n, 0, None));
    assert_eq!((lagged.len(), late.len()), (n, n));
    assert_eq!(a.counters().records as usize, n);
    assert_eq!(stale(&lagged), (0..delay).collect::<Vec<_>>());
    assert!(stale(&late).is_empty());
    let half = compensator_config(rate_hz as f32, 16).epoch.half_width;
    let mut worst_plain = 0f32;
    for k in delay + half + 1..n {
        assert_eq!(
            lagged[k].interference_nt.to_bits(),
            late[k].interference_nt.to_bits(),
            "{rate_hz} Hz, record {k}: {} vs {}",
            lagged[k].interference_nt,
            late[k].interference_nt
        );
        // The pairing's flags (the field states' gate saw different first records).
        let pairing = |r: &Record| r.flags.0 & (Flags::FLUX_STALE | Flags::DERIVATIVE_DEGRADED);
        assert_eq!(pairing(&lagged[k]), pairing(&late[k]), "record {k}");
        worst_plain = worst_plain.max((plain[k].interference_nt - late[k].interference_nt).abs());
    }
    assert!(
        worst_plain > 1.0,
        "undelayed differs by {worst_plain} nT only"
    );
}

#[test]
fn a_whole_sample_delay_equals_a_fluxgate_sent_late() {
    whole_sample_delay_equals_a_fluxgate_sent_late(RATE_HZ, 3, 200);
}

/// The line's design point: 0.5 s at a 1 kHz fluxgate (500 frames back), and its limit,
/// 0.51 s (510 frames).
#[test]
fn half_a_second_at_1_khz_is_held_by_the_line() {
    whole_sample_delay_equals_a_fluxgate_sent_late(1000.0, 500, 1500);
    whole_sample_delay_equals_a_fluxgate_sent_late(1000.0, 510, 1200);
}

/// Sub-sample τ: linear interpolation between the frames that bracket t − τ; a fluxgate
/// gap shows τ later and is stale where the held frame is older than the limit.
#[test]
fn sub_sample_delay_interpolates_and_gaps_are_flagged_late() {
    let cfg = AlignerConfig {
        flux_stale_us: 250_000,
        gps_stale_us: 2_500_000,
        extrapolate_gps: false,
        flux_period_us: 100_000,
    };
    let mut al = Aligner::new(cfg);
    al.set_lag_us(250_000);
    let mut line = LagLine::new();
    // Frames every 100 ms from t = 0 to 2.0 s, value = t in ms on every axis.
    for j in 0..=20u64 {
        let t = 100_000 * j;
        assert!(al.push_flux(t, [t as f32 / 1e3; 3]));
        line.push(t, [t as f32 / 1e3; 3]);
    }
    let m = Some(MagCounts(536_200_000));
    // Before the line reaches back τ: stale, whatever the distance.
    let s = al.push_scalar_delayed(200_000, m, Some(&line));
    assert!(s.flags.contains(Flags::FLUX_STALE));
    // t − τ = 1.05 s: halfway between the 1.0 and 1.1 s frames.
    let s = al.push_scalar_delayed(1_300_000, m, Some(&line));
    assert_eq!(s.flux_nt, [1050.0; 3]);
    assert!(!s.flags.contains(Flags::FLUX_STALE));
    // Fluxgate stopped at 2.0 s: at t = 2.2 s the delayed time 1.95 s is still bracketed.
    let s = al.push_scalar_delayed(2_200_000, m, Some(&line));
    assert_eq!(s.flux_nt, [1950.0; 3]);
    assert!(!s.flags.contains(Flags::FLUX_STALE));
    // t = 2.45 s → 2.2 s: held 0.2 s (within 2.5 periods); t = 2.6 s → 2.35 s: stale.
    let s = al.push_scalar_delayed(2_450_000, m, Some(&line));
    assert!(!s.flags.contains(Flags::FLUX_STALE));
    let s = al.push_scalar_delayed(2_600_000, m, Some(&line));
    assert!(s.flags.contains(Flags::FLUX_STALE));
    assert_eq!(s.flux_nt, [2000.0; 3]);
}

/// A gap in the fluxgate on the board: every scalar line still one record, the gap's
/// records stale τ later than without the delay.
#[test]
fn a_fluxgate_gap_is_flagged_shifted_by_the_delay_and_nothing_is_lost() {
    let n = 120;
    let mut line = LagLine::new();
    let mut a = acq(RATE_HZ);
    a.attach_lag_line(&mut line);
    a.set_lag_s(0.5).unwrap();
    let lagged = run(&mut a, &stream(RATE_HZ, n, 0, Some((50, 60))));
    let mut b = acq(RATE_HZ);
    let plain = run(&mut b, &stream(RATE_HZ, n, 0, Some((50, 60))));
    assert_eq!((lagged.len(), plain.len()), (n, n));
    for (k, r) in lagged.iter().enumerate() {
        assert_eq!(r.seq as usize, k);
    }
    let (sl, sp) = (stale(&lagged), stale(&plain));
    // Start: 5 records before the line reaches back 0.5 s.
    assert_eq!(&sl[..5], &[0, 1, 2, 3, 4]);
    let shifted: Vec<usize> = sp.iter().map(|k| k + 5).collect();
    assert_eq!(
        &sl[5..],
        &shifted[..],
        "stale with τ {sl:?}, without {sp:?}"
    );
    assert!(!sp.is_empty());
}

#[test]
fn delays_beyond_the_line_or_without_one_are_refused() {
    let mut line = LagLine::new();
    let mut a = acq(1000.0);
    // No line: only τ = 0.
    assert_eq!(a.set_lag_s(0.2), Err(LagError::NoLine));
    assert_eq!(a.set_lag_s(0.0), Ok(()));
    a.attach_lag_line(&mut line);
    // 0.5 s at 1 kHz is the line's design point.
    assert_eq!(a.set_lag_s(MAX_LAG_S), Ok(()));
    for bad in [0.52, -0.1, f32::NAN, f32::INFINITY] {
        assert_eq!(a.set_lag_s(bad), Err(LagError::OutOfRange), "{bad}");
    }
    assert_eq!(a.lag_s(), MAX_LAG_S, "a refused τ changes nothing");
    let mut fast_line = LagLine::new();
    let mut fast = acq(2000.0);
    fast.attach_lag_line(&mut fast_line);
    assert_eq!(fast.set_lag_s(0.5), Err(LagError::BeyondLine));
    assert_eq!(fast.set_lag_s(0.25), Ok(()));
}

mod no_panic {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(300))]

        /// Any order of frames and samples, stamps anywhere in u64 (backwards, huge jumps),
        /// any τ the aligner is given: no panic, and a sample is either paired with a finite
        /// fluxgate value or flagged FLUX_STALE.
        #[test]
        fn delayed_pairing_is_total(
            ops in proptest::collection::vec((any::<bool>(), any::<u64>(), -1.0e5f32..1.0e5), 1..300),
            lag_us in prop_oneof![Just(0u64), 1u64..600_000, Just(u64::MAX)],
            period_us in prop_oneof![Just(0u64), 1u64..1_000_000, Just(u64::MAX)],
        ) {
            let mut al = Aligner::new(AlignerConfig {
                flux_stale_us: 250_000,
                gps_stale_us: 2_500_000,
                extrapolate_gps: false,
                flux_period_us: period_us,
            });
            al.set_lag_us(lag_us);
            let mut line = LagLine::new();
            for (is_flux, t, v) in ops {
                if is_flux {
                    if al.push_flux(t, [v, -v, v]) {
                        line.push(t, [v, -v, v]);
                    }
                } else {
                    let s = al.push_scalar_delayed(t, Some(MagCounts(1)), Some(&line));
                    prop_assert!(
                        s.flux_nt.iter().all(|x| x.is_finite()) || s.flags.contains(Flags::FLUX_STALE)
                    );
                }
            }
        }
    }
}
