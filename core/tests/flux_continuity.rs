//! The board's causal check on the fluxgate modulus and vector
//! (`continuity::FluxContinuity`, used by `Acquisition::flux_result_temp`): no false
//! positive on a real flight's three fluxgates (SGL 2020 flight 1002, line 1002.02, 10 Hz,
//! 12 901 frames with calibration manoeuvres) nor on MagNav.jl's test flight (1000
//! frames), a corrupted frame caught alone (also one that keeps the modulus: an axis near 0
//! read as 0, a sign flip, swapped axes, a 5° rotation), and on the board path the frame
//! held as unusable (`FLUX_STALE`, counted in `flux_suspect`), never fed to the regressors.

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

/// The frames judged suspect, how many were judged (not `Unverified`), and the largest
/// departure of each check (modulus, vector) as a fraction of its limit.
fn margins(ts: &[f64], vs: &[[f32; 3]]) -> (Vec<usize>, usize, [f32; 2]) {
    let mut c = FluxContinuity::new();
    let (mut s, mut judged, mut worst) = (Vec::new(), 0, [0.0f32; 2]);
    for i in 0..vs.len() {
        let (verdict, m) = c.judge_with_margins(ts[i], vs[i]);
        match verdict {
            Continuity::Suspect => s.push(i),
            Continuity::Consistent => judged += 1,
            Continuity::Unverified => continue,
        }
        worst = [worst[0].max(m[0]), worst[1].max(m[1])];
    }
    let n = judged + s.len();
    (s, n, worst)
}

#[test]
fn a_real_flight_has_no_suspect_frame() {
    for prefix in ["flux_b_", "flux_c_", "flux_d_"] {
        let (ts, vs) = read_flux(SGL, prefix);
        assert_eq!(vs.len(), 12_901);
        let (s, judged, worst) = margins(&ts, &vs);
        assert!(s.is_empty(), "{prefix}: {} suspect: {s:?}", s.len());
        assert_eq!(judged, 12_900);
        // Measured 0.38/0.46 (b), 0.36/0.49 (c), 0.37/0.48 (d): a margin of 2.
        assert!(worst.iter().all(|w| *w < 0.6), "{prefix}: {worst:?}");
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
    // What the modulus cannot see and the vector does: an axis read as 0 where it was near
    // 0 already. At row 6435 (level flight) flux_b_z is −439.9 nT of a 53 800 nT field;
    // zeroing it moves the modulus by 1.8 nT, the vector by 440 nT.
    let mut bad = vs.clone();
    bad[6435][2] = 0.0;
    assert_eq!(suspects(&ts, &bad), [6435]);
    // Its limit: at row 9876, in a manoeuvre (recent departures ~80 nT, the frames moving
    // ~250 nT each: limit ~1300 nT), the 856 nT of a zeroed z pass.
    let mut bad = vs.clone();
    bad[9876][2] = 0.0;
    assert_eq!(suspects(&ts, &bad), []);
}

/// The first frames, before any departure sets a spread, are judged by physical bounds
/// alone: the step from the only frame by the body rate (0.6 rad/s: 3200 nT at 10 Hz), the
/// first departure from the line by the angular acceleration (2 rad/s²: 1100 nT, plus the
/// last frames' motion). An axis read as 0 or sign-flipped in the second frame (8730 nT on
/// flux_b) passed the 100 × floor (~12 000 nT) this frame had before; now it is caught, and
/// so is every corruption of the third frame. A 5° rotation of the second frame (2522 nT,
/// 27°/s) is a rotation the body could have made: taken, and the frame after it suspect.
#[test]
fn the_first_frames_are_judged_by_physical_bounds() {
    let (ts, vs) = read_flux(SGL, "flux_b_");
    let first = |row: usize, f: Corrupt| {
        let mut bad = vs[..40].to_vec();
        bad[row] = f(bad[row]);
        suspects(&ts[..40], &bad)
    };
    for (what, f) in corruptions() {
        assert_eq!(first(2, f), [2], "third frame, {what}");
        if what != "rotated 5°" {
            assert_eq!(first(1, f), [1], "second frame, {what}");
        }
    }
    assert_eq!(first(1, |v| rotate_x(v, 5.0)), [2]);
}

/// A corruption of one frame.
type Corrupt = fn([f32; 3]) -> [f32; 3];

/// The corruptions of one frame the sweep tries: each axis read as 0, the smallest axis's
/// sign flipped, x and y swapped, the frame rotated 5° about its body x axis.
fn corruptions() -> [(&'static str, Corrupt); 6] {
    [
        ("x = 0", |v| [0.0, v[1], v[2]]),
        ("y = 0", |v| [v[0], 0.0, v[2]]),
        ("z = 0", |v| [v[0], v[1], 0.0]),
        ("smallest axis sign flipped", |v| {
            let k = (0..3)
                .min_by(|&a, &b| v[a].abs().total_cmp(&v[b].abs()))
                .unwrap_or(0);
            let mut w = v;
            w[k] = -w[k];
            w
        }),
        ("x, y swapped", |v| [v[1], v[0], v[2]]),
        ("rotated 5°", |v| rotate_x(v, 5.0)),
    ]
}

/// `v` rotated by `deg` about the x axis.
fn rotate_x(v: [f32; 3], deg: f64) -> [f32; 3] {
    let (s, c) = deg.to_radians().sin_cos();
    let (y, z) = (f64::from(v[1]), f64::from(v[2]));
    [v[0], (c * y - s * z) as f32, (s * y + c * z) as f32]
}

/// Every 10th row of flux_b corrupted in turn (one at a time, each corruption of
/// [`corruptions`]): how many are caught alone, missed (with the largest vector change
/// missed), or otherwise (the frame taken and the next ones suspect, or more than it
/// suspect). `cargo test --release -p magcomp-core --test flux_continuity -- --ignored
/// --nocapture sweep`; another trace with `MAGCOMP_FLUX_CSV` (and `MAGCOMP_FLUX_PREFIX`,
/// `MAGCOMP_SWEEP_STEP` for every n-th row), as for `suspects_in_a_given_trace`.
#[test]
#[ignore]
fn sweep_corrupted_rows() {
    let (ts, vs) = match std::env::var("MAGCOMP_FLUX_CSV") {
        Ok(path) => {
            let prefix = std::env::var("MAGCOMP_FLUX_PREFIX").unwrap_or_else(|_| "flux_".into());
            read_flux(&path, &prefix)
        }
        Err(_) => read_flux(SGL, "flux_b_"),
    };
    let step: usize = std::env::var("MAGCOMP_SWEEP_STEP")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(10);
    let norm = |a: [f32; 3], b: [f32; 3]| {
        (0..3)
            .map(|k| (f64::from(a[k]) - f64::from(b[k])).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    for (what, f) in corruptions() {
        let (mut caught, mut other, mut tried, mut unchanged) = (0, 0, 0, 0);
        let mut missed: Vec<f64> = Vec::new();
        for row in (1..vs.len()).step_by(step) {
            let mut bad = vs.clone();
            bad[row] = f(bad[row]);
            if norm(bad[row], vs[row]) < 1.0 {
                // x = y or an axis already ~0: nothing changed.
                unchanged += 1;
                continue;
            }
            let s = suspects(&ts, &bad);
            tried += 1;
            if s == [row] {
                caught += 1;
            } else if s.is_empty() {
                missed.push(norm(bad[row], vs[row]));
            } else {
                other += 1;
            }
        }
        let worst = missed.iter().fold(0.0f64, |a, d| a.max(*d));
        println!(
            "{what}: {tried} rows, {caught} caught alone, {} missed (vector change ≤ {worst:.0} nT), {other} other, {unchanged} unchanged",
            missed.len()
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
    let (s, judged, worst) = margins(&ts, &vs);
    println!(
        "{path} {prefix}: {} frames, {judged} judged, {} suspect: {s:?}; largest departure / limit: modulus {:.2}, vector {:.2}",
        vs.len(),
        s.len(),
        worst[0],
        worst[1]
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

// The vector check on synthetic flights: the field of the Earth (52 000 nT, inclination
// 65°) seen in the body frame of an aircraft with the given heading and roll.

/// The body-frame field at heading `yaw` and roll `roll` (rad), with 0.3 nT of alternating
/// noise on each axis (frame `i`).
fn body_field(i: usize, yaw: f64, roll: f64) -> [f32; 3] {
    let (si, ci) = 65f64.to_radians().sin_cos();
    let b = [52_000.0 * ci, 0.0, 52_000.0 * si];
    // Into the body: undo the heading (about z), then the roll (about x).
    let (sy, cy) = yaw.sin_cos();
    let h = [cy * b[0] + sy * b[1], -sy * b[0] + cy * b[1], b[2]];
    let (sr, cr) = roll.sin_cos();
    let v = [h[0], cr * h[1] + sr * h[2], -sr * h[1] + cr * h[2]];
    let noise = if i.is_multiple_of(2) { 0.3 } else { -0.3 };
    v.map(|x| (x + noise) as f32)
}

/// Level flight at 10 Hz, heading drifting 0.2°/s from 89.6° so that body x reads
/// ~±100–700 nT: the axis near 0 a modulus check cannot see.
fn level(i: usize) -> [f32; 3] {
    body_field(i, (89.6 + 0.02 * i as f64).to_radians(), 0.0)
}

fn judge_level_then(bad: [f32; 3]) -> [Continuity; 21] {
    let mut c = FluxContinuity::new();
    for i in 0..100 {
        c.judge(i as f64 * 0.1, level(i));
    }
    core::array::from_fn(|k| {
        let v = if k == 0 { bad } else { level(100 + k) };
        c.judge((100 + k) as f64 * 0.1, v)
    })
}

#[test]
fn errors_that_keep_the_modulus_are_caught_alone() {
    let v = level(100);
    let modulus = |v: [f32; 3]| (v.iter().map(|x| f64::from(*x).powi(2)).sum::<f64>()).sqrt();
    assert!(v[0].abs() < 700.0, "{v:?}");
    // Two axes of similar size: heading −43.8° (x 15 860, y 15 210 nT).
    let near_45 = body_field(100, (-43.8f64).to_radians(), 0.0);
    assert!((near_45[0] - near_45[1]).abs() < 700.0, "{near_45:?}");
    for (what, bad) in [
        ("axis near 0 read as 0", [0.0, v[1], v[2]]),
        ("small axis sign flipped", [-v[0], v[1], v[2]]),
        ("rotated 5°", {
            let (s, c) = 5f64.to_radians().sin_cos();
            let (y, z) = (f64::from(v[1]), f64::from(v[2]));
            [v[0], (c * y - s * z) as f32, (s * y + c * z) as f32]
        }),
    ] {
        // The modulus moves by less than its own floor (20 nT).
        assert!((modulus(bad) - modulus(v)).abs() < 5.0, "{what}");
        let verdicts = judge_level_then(bad);
        assert_eq!(verdicts[0], Continuity::Suspect, "{what}");
        assert!(
            verdicts[1..].iter().all(|v| *v == Continuity::Consistent),
            "{what}: {verdicts:?}"
        );
    }
    // x and y swapped, on a flight at heading −43.8°.
    let mut c = FluxContinuity::new();
    let at_45 = |i: usize| body_field(i, (-43.8f64).to_radians(), 0.0);
    for i in 0..100 {
        assert_ne!(c.judge(i as f64 * 0.1, at_45(i)), Continuity::Suspect);
    }
    assert_eq!(
        c.judge(10.0, [near_45[1], near_45[0], near_45[2]]),
        Continuity::Suspect
    );
    for i in 101..120 {
        assert_eq!(c.judge(i as f64 * 0.1, at_45(i)), Continuity::Consistent);
    }
}

#[test]
fn a_real_step_in_one_axis_is_taken_after_three_frames() {
    // An offset of 800 nT on y from frame 100 on (a moved fluxgate, a changed
    // calibration): the modulus moves by ~350 nT, the vector by 800 nT.
    let mut c = FluxContinuity::new();
    for i in 0..100 {
        c.judge(i as f64 * 0.1, level(i));
    }
    let verdicts: [Continuity; 20] = core::array::from_fn(|k| {
        let mut v = level(100 + k);
        v[1] += 800.0;
        c.judge((100 + k) as f64 * 0.1, v)
    });
    assert_eq!(&verdicts[..3], &[Continuity::Suspect; 3]);
    assert!(
        verdicts[3..].iter().all(|v| *v == Continuity::Consistent),
        "{verdicts:?}"
    );
}

/// Smooth, fast rotation: a ±25° roll at 0.2 Hz and a turn at up to 10°/s, both eased in
/// over 5 s (peak roll acceleration 0.69 rad/s², above the check's 0.2 rad/s² onset
/// allowance: its median follows), at 10 and 100 Hz: nothing flagged.
#[test]
fn smooth_fast_rotation_is_not_flagged() {
    for rate_hz in [10.0, 100.0] {
        let mut c = FluxContinuity::new();
        let n = (120.0 * rate_hz) as usize;
        let (mut suspect, mut worst) = (Vec::new(), 0.0f32);
        for i in 0..n {
            let t = i as f64 / rate_hz;
            // Eases 0 → 1 over t = 10…15 s with zero first and second derivatives at
            // both ends.
            let ease = |t: f64| {
                let x = ((t - 10.0) / 5.0).clamp(0.0, 1.0);
                x * x * x * (10.0 - 15.0 * x + 6.0 * x * x)
            };
            let roll = 25f64.to_radians() * ease(t) * (2.0 * core::f64::consts::PI * 0.2 * t).sin();
            // Heading: ∫ 10°/s × ease dt.
            let x = ((t - 10.0) / 5.0).clamp(0.0, 1.0);
            let yaw = 10f64.to_radians()
                * (5.0 * x.powi(4) * (2.5 - 3.0 * x + x * x) + (t - 15.0).max(0.0));
            let (verdict, m) = c.judge_with_margins(t, body_field(i, yaw, roll));
            if verdict == Continuity::Suspect {
                suspect.push(i);
            }
            worst = worst.max(m[1]);
        }
        assert!(suspect.is_empty(), "{rate_hz} Hz: {suspect:?}");
        assert!(worst < 0.7, "{rate_hz} Hz: vector {worst}");
    }
}
