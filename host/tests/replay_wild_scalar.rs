//! Issue 21 item 4: on the board path no wild scalar value leaves unflagged, from the first
//! sample on. A scalar line has no checksum, so a corrupted digit is another number; the
//! filter judges a reading against its prediction once it has a level (`MAG_SUSPECT`
//! beyond 5σ of the predicted innovation spread, in warm-up too), and the reading's own
//! recent past judges it where the filter cannot (the first reading, before the first
//! update, suspect regressors).

#[path = "common/board_replay.rs"]
#[allow(dead_code)] // shared with the other board-replay tests
mod board_replay;

use board_replay::board_flight;
use magcomp::board::capture::{trace_to_capture, CaptureOptions};
use magcomp::board::replay::{replay_capture, ReplayOptions};
use magcomp::estimate::corrections::run_kf;
use magcomp::estimate::kf::KfOptions;
use magcomp::io::trace::Trace;
use magcomp::model::spec::ModelSpec;
use magcomp::sim::{simulate, SimConfig};
use magcomp_core::protocol::record::Record;
use magcomp_core::Flags;
use rand::{Rng, SeedableRng};

fn spec() -> ModelSpec {
    ModelSpec::parse("tl16+field").unwrap()
}

fn opts() -> ReplayOptions {
    ReplayOptions::new(spec())
}

/// A simulated calibration (take-off, pattern) as in `replay_sim.rs`.
fn flight_trace() -> Trace {
    let cfg = SimConfig {
        max_duration_s: Some(150.0),
        seed: 7,
        ..SimConfig::default()
    };
    simulate(&cfg).unwrap()
}

/// The board's code over a capture: one record per scalar line.
fn replay(cap: &[u8], o: &ReplayOptions) -> Vec<Record> {
    let mut recs = Vec::new();
    replay_capture(cap, o, |r| {
        recs.push(*r);
        Ok(())
    })
    .unwrap();
    recs
}

/// Post-flight coefficients with the board's settings (survey-mode cases).
fn board_coefficients(trace: &Trace) -> Vec<f32> {
    let mut ko = KfOptions::new(spec());
    ko.sigma1 = Some(1.0e-6);
    ko.noise_nt = Some(0.02);
    ko.tie_points = false;
    ko.freeze_on_survey = false;
    let post = run_kf(&board_flight(trace, &spec()), &ko).unwrap();
    post.coefficients.iter().map(|v| *v as f32).collect()
}

/// Replaces `fraction` of the hex digits of every capture line's payload by random hex
/// digits (as a noisy link or a flipped bit in storage would), keeping each line's `0D0A`
/// end so that every scalar sample still has its line: the records pair one to one.
fn corrupt_hex_digits(cap: &[u8], fraction: f64, seed: u64) -> Vec<u8> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::with_capacity(cap.len());
    for line in std::str::from_utf8(cap).unwrap().lines() {
        let mut parts = line.splitn(3, ' ');
        let (Some(t), Some(port), Some(hex)) = (parts.next(), parts.next(), parts.next()) else {
            out.extend_from_slice(line.as_bytes());
            out.push(b'\n');
            continue;
        };
        let keep_end = hex.len().saturating_sub(4);
        let payload: String = hex
            .char_indices()
            .map(|(i, c)| {
                if i < keep_end && rng.gen_bool(fraction) {
                    b"0123456789ABCDEF"[rng.gen_range(0..16)] as char
                } else {
                    c
                }
            })
            .collect();
        out.extend_from_slice(format!("{t} {port} {payload}\n").as_bytes());
    }
    out
}

/// The board's scalar noise (1σ, nT): the records carry no spread of their own, so a
/// reading changed by more than 5 × this is wild.
const SCALAR_NOISE_NT: f64 = 0.02;

/// Records of the corrupted capture shown good (neither degraded nor `NOT_CONVERGED`)
/// whose scalar differs from the clean capture's by more than 5σ: (count, the largest such
/// difference in nT, how many scalars were changed by more than 5σ at all).
fn unflagged_wild(clean: &[Record], bad: &[Record]) -> (usize, f64, usize) {
    assert_eq!(clean.len(), bad.len(), "one record per scalar line");
    let (mut unflagged, mut worst, mut wild) = (0, 0f64, 0);
    for (c, b) in clean.iter().zip(bad) {
        assert_eq!(c.seq, b.seq);
        let (Some(mc), Some(mb)) = (c.mag, b.mag) else {
            continue;
        };
        let off_nt = (mc.to_nt_f64() - mb.to_nt_f64()).abs();
        if off_nt <= 5.0 * SCALAR_NOISE_NT {
            continue;
        }
        wild += 1;
        if !b.flags.degraded() {
            eprintln!(
                "  seq {} off {off_nt:.4} nT, flags {:#06x}",
                b.seq, b.flags.0
            );
            if !b.flags.contains(Flags::NOT_CONVERGED) {
                unflagged += 1;
                worst = worst.max(off_nt);
            }
        }
    }
    (unflagged, worst, wild)
}

#[test]
fn hex_digit_corruption_leaves_no_wild_scalar_unflagged() {
    let trace = flight_trace();
    let clean_cap = trace_to_capture(&trace, &CaptureOptions::default()).unwrap();
    let mut survey = opts();
    survey.coefficients = Some(board_coefficients(&trace));
    for (mode, o) in [("calibrate", opts()), ("survey", survey)] {
        let clean = replay(&clean_cap, &o);
        for seed in [3u64, 5, 9] {
            let bad = replay(&corrupt_hex_digits(&clean_cap, 0.01, seed), &o);
            let (unflagged, worst, wild) = unflagged_wild(&clean, &bad);
            eprintln!(
                "{mode}, seed {seed}: {wild} scalars changed beyond 5σ, {unflagged} of them unflagged (largest {worst:.3} nT)"
            );
            assert!(wild > 5, "the corruption must reach the scalar");
            assert_eq!(unflagged, 0, "{mode} seed {seed}: largest {worst} nT");
        }
    }
}

/// Rows `at` of `trace`'s scalar moved by `by_nt` each.
fn with_glitches(trace: &Trace, at: &[usize], by_nt: &[f64]) -> Trace {
    let mut t = trace.clone();
    let mut mag = t.col("mag").unwrap().to_vec();
    for (&i, &d) in at.iter().zip(by_nt) {
        mag[i] += d;
    }
    t.set_col("mag", mag);
    t
}

fn suspect_seqs(recs: &[Record]) -> Vec<usize> {
    recs.iter()
        .enumerate()
        .filter(|(_, r)| r.flags.contains(Flags::MAG_SUSPECT))
        .map(|(i, _)| i)
        .collect()
}

#[test]
fn glitches_from_the_first_sample_on_are_flagged_and_a_clean_flight_is_not() {
    let trace = flight_trace();
    let mut survey = opts();
    survey.coefficients = Some(board_coefficients(&trace));
    let capture = |t: &Trace| trace_to_capture(t, &CaptureOptions::default()).unwrap();
    for (mode, o) in [("calibrate", opts()), ("survey", survey)] {
        // Clean: only the first reading, which nothing can check, is flagged.
        let clean = replay(&capture(&trace), &o);
        assert_eq!(suspect_seqs(&clean), vec![0], "{mode}: clean flight");
        // The audit's cases: +4000 nT at sample 65 (warm-up, where the gate only
        // Huber-weights), two +1e5 nT samples two rows apart in the first 100 updates, a
        // pair of +300 nT, a wild first reading, and a 5-sample +50 nT step.
        let cases: [(&str, Vec<usize>, Vec<f64>); 5] = [
            ("+4000 nT at 65", vec![65], vec![4000.0]),
            ("pair of +1e5 nT", vec![40, 42], vec![1e5, 1e5]),
            ("pair of +300 nT", vec![40, 42], vec![300.0, 300.0]),
            ("+400 nT first reading", vec![0], vec![400.0]),
            ("5-sample +50 nT step", (300..305).collect(), vec![50.0; 5]),
        ];
        for (what, at, by) in cases {
            let recs = replay(&capture(&with_glitches(&trace, &at, &by)), &o);
            assert_eq!(recs.len(), trace.len(), "one record per scalar sample");
            let suspect = suspect_seqs(&recs);
            eprintln!("{mode}, {what}: MAG_SUSPECT on {suspect:?}");
            for &i in &at {
                // Beyond the scalar's range (+1e5 nT) the parser refuses the line
                // (`MAG_MISSING`); within it the value is `MAG_SUSPECT`.
                assert!(
                    recs[i].flags.degraded(),
                    "{mode}, {what}: sample {i} unflagged"
                );
            }
            // A wild first reading gives the filter a wrong level (nothing could check it):
            // its successors disagree with it until the filter has moved (2 samples), and
            // the calibration it started leaves a few late disagreements (measured 5).
            let extra = suspect
                .iter()
                .filter(|i| !at.contains(i) && **i != 0)
                .count();
            let allowed = if at == [0] { 10 } else { 0 };
            assert!(
                extra <= allowed,
                "{mode}, {what}: {extra} good samples flagged"
            );
        }
    }
}
