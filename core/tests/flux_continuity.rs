//! The board's causal check on the fluxgate modulus (`continuity::FluxContinuity`, used by
//! `Acquisition::flux_result_temp`): no false positive on a real flight's three fluxgates
//! (SGL 2020 flight 1002, line 1002.02, 10 Hz, 12 901 frames with calibration manoeuvres)
//! nor on MagNav.jl's test flight (1000 frames),
//! a corrupted frame caught alone, and on the board path the frame held as unusable
//! (`FLUX_STALE`, counted in `flux_suspect`), never fed to the regressors.

#[path = "common/acq_run.rs"]
mod acq_run;
use acq_run::run;

use magcomp_core::acquisition::{compensator_config, AcqConfig, Acquisition};
use magcomp_core::continuity::{Continuity, FluxContinuity};
use magcomp_core::model::Model;
use magcomp_core::protocol::capture::Port;
use magcomp_core::{Compensator, Flags};

const SGL: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../data/reference/sgl2020-flt1002-cal/flt1002_line1002.02.csv"
);

/// The `<prefix>x/y/z` columns of a trace CSV (`#` lines skipped), and `t` if it has one.
fn read_flux(path: &str, prefix: &str) -> (Vec<f64>, Vec<[f32; 3]>) {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name);
    let axes: Vec<usize> = ["x", "y", "z"]
        .iter()
        .map(|a| col(&format!("{prefix}{a}")).unwrap_or_else(|| panic!("no {prefix}{a}")))
        .collect();
    let t_col = col("t");
    let (mut ts, mut vs) = (Vec::new(), Vec::new());
    for (i, l) in lines.enumerate() {
        let f: Vec<&str> = l.split(',').collect();
        ts.push(t_col.map_or(i as f64 * 0.1, |c| f[c].parse().unwrap()));
        vs.push(core::array::from_fn(|k| f[axes[k]].parse().unwrap()));
    }
    (ts, vs)
}

/// Indices of the frames judged suspect.
fn suspects(ts: &[f64], vs: &[[f32; 3]]) -> Vec<usize> {
    let mut c = FluxContinuity::new();
    (0..vs.len())
        .filter(|&i| c.judge(ts[i], vs[i]) == Continuity::Suspect)
        .collect()
}

#[test]
fn a_real_flight_has_no_suspect_frame() {
    for prefix in ["flux_b_", "flux_c_", "flux_d_"] {
        let (ts, vs) = read_flux(SGL, prefix);
        assert_eq!(vs.len(), 12_901);
        let s = suspects(&ts, &vs);
        assert!(s.is_empty(), "{prefix}: {} suspect: {s:?}", s.len());
    }
}

const MAGNAV: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../data/reference/magnav-tl/raw_1000x6.csv"
);

/// MagNav.jl's test flight (flux_a, 10 Hz, 1000 frames).
#[test]
fn magnav_test_flight_has_no_suspect_frame() {
    let (ts, vs) = read_flux(MAGNAV, "flux_a_");
    assert_eq!(vs.len(), 1000);
    assert_eq!(suspects(&ts, &vs), []);
}

#[test]
fn a_corrupted_frame_in_a_real_flight_is_caught_alone() {
    let (ts, vs) = read_flux(SGL, "flux_b_");
    // Spread through the line, calibration manoeuvres included.
    for row in [100, 2_345, 6_000, 9_500, 12_800] {
        for (what, f) in [
            (
                "z = 0",
                (|v: [f32; 3]| [v[0], v[1], 0.0]) as fn([f32; 3]) -> [f32; 3],
            ),
            ("x = 0", |v| [0.0, v[1], v[2]]),
            ("z + 5000", |v| [v[0], v[1], v[2] + 5000.0]),
            ("y − 2000", |v| [v[0], v[1] - 2000.0, v[2]]),
        ] {
            let mut bad = vs.clone();
            bad[row] = f(bad[row]);
            assert_eq!(suspects(&ts, &bad), [row], "row {row}, {what}");
        }
    }
    // What the modulus cannot see: an axis read as 0 where it was near 0 already. At row
    // 9876 flux_b_z is −855.9 nT of a 53 783 nT field; zeroing it moves the modulus by
    // 6.8 nT, inside the floor (the direction moves by 0.016 rad).
    let mut bad = vs.clone();
    bad[9876][2] = 0.0;
    assert_eq!(suspects(&ts, &bad), []);
}

/// Every 10th row of flux_b corrupted in turn (one at a time): how many are caught alone,
/// and the modulus change of those missed. `cargo test --release -p magcomp-core --test
/// flux_continuity -- --ignored --nocapture sweep`.
#[test]
#[ignore]
fn sweep_corrupted_rows() {
    let (ts, vs) = read_flux(SGL, "flux_b_");
    let modulus = |v: [f32; 3]| (v.iter().map(|x| f64::from(*x).powi(2)).sum::<f64>()).sqrt();
    for axis in 0..3 {
        let (mut caught, mut other, mut tried) = (0, 0, 0);
        let mut missed_dm: Vec<f64> = Vec::new();
        for row in (1..vs.len()).step_by(10) {
            let mut bad = vs.clone();
            bad[row][axis] = 0.0;
            let s = suspects(&ts, &bad);
            tried += 1;
            if s == [row] {
                caught += 1;
            } else if s.is_empty() {
                missed_dm.push(modulus(vs[row]) - modulus(bad[row]));
            } else {
                other += 1;
            }
        }
        let worst = missed_dm.iter().fold(0.0f64, |a, d| a.max(d.abs()));
        println!(
            "axis {axis} = 0: {tried} rows, {caught} caught alone, {} missed (|Δ|B|| ≤ {worst:.1} nT), {other} other",
            missed_dm.len()
        );
    }
}

/// A trace of one's own (e.g. `magcomp simulate -o sim.csv`): `MAGCOMP_FLUX_CSV=sim.csv
/// [MAGCOMP_FLUX_PREFIX=flux_] cargo test -p magcomp-core --test flux_continuity -- --ignored
/// --nocapture`.
#[test]
#[ignore]
fn suspects_in_a_given_trace() {
    let path = std::env::var("MAGCOMP_FLUX_CSV").expect("MAGCOMP_FLUX_CSV");
    let prefix = std::env::var("MAGCOMP_FLUX_PREFIX").unwrap_or_else(|_| "flux_".into());
    let (ts, vs) = read_flux(&path, &prefix);
    let s = suspects(&ts, &vs);
    println!(
        "{path} {prefix}: {} frames, {} suspect: {s:?}",
        vs.len(),
        s.len()
    );
}

/// On the board path: the frame with an axis read as 0 is counted, held as unusable, and
/// only the record that would have used it is `FLUX_STALE`; the rest are as without it.
#[test]
fn the_board_holds_a_suspect_frame_as_unusable() {
    const RATE_HZ: f64 = 10.0;
    let acq = || {
        let comp =
            Compensator::new(Model::paper(), compensator_config(RATE_HZ as f32, 16)).unwrap();
        Acquisition::<32, 16>::new(AcqConfig::new(RATE_HZ, RATE_HZ, 1.0), comp).unwrap()
    };
    let (_, vs) = read_flux(SGL, "flux_b_");
    let n = 300;
    let bad_k = 150;
    let stream = |corrupt: bool| {
        let mut chunks = Vec::new();
        for (k, v) in vs.iter().take(n).enumerate() {
            let z = if corrupt && k == bad_k { 0.0 } else { v[2] };
            let line = format!("{:.3},{:.3},{:.3}\r\n", v[0], v[1], z);
            chunks.push((Port::Flux, line.into_bytes()));
            let m = 536_200_000 + (k as i64 * 37) % 5000;
            let line = format!("{}.{:04}\r\n", m / 10_000, m % 10_000);
            chunks.push((Port::Scalar, line.into_bytes()));
        }
        chunks
    };
    let mut clean = acq();
    let good = run(&mut clean, &stream(false));
    assert_eq!(clean.counters().flux_suspect, 0);
    assert!(good.iter().all(|r| !r.flags.contains(Flags::FLUX_STALE)));

    let mut a = acq();
    let recs = run(&mut a, &stream(true));
    let c = a.counters();
    assert_eq!(
        (c.flux_suspect, c.flux_frames, c.flux_errors),
        (1, n as u32, 0)
    );
    assert_eq!(recs.len(), n);
    let stale: Vec<usize> = (0..n)
        .filter(|&k| recs[k].flags.contains(Flags::FLUX_STALE))
        .collect();
    assert_eq!(stale, [bad_k]);
    assert!(!recs[bad_k].flags.contains(Flags::PARSE_ERROR));
    // Before its derivative window (half width 8), the records are the clean run's, bit
    // for bit; within it they are DERIVATIVE_DEGRADED, as around any stale frame.
    let first_diff = (0..n)
        .find(|&k| format!("{:?}", recs[k]) != format!("{:?}", good[k]))
        .unwrap();
    assert!(first_diff >= bad_k - 8, "{first_diff}");
    for (k, r) in recs.iter().enumerate().take(bad_k).skip(first_diff) {
        assert!(r.flags.contains(Flags::DERIVATIVE_DEGRADED), "record {k}");
    }
    assert!(recs.iter().all(|r| r.interference_nt.is_finite()));
}
