//! The board's records state their own bound (`$MCREC` `sigma_nt`, issue 17 item 1): a record
//! shown converged carries a finite 1σ on its interference, a `NOT_CONVERGED` one none, and
//! the bound holds against the simulator's truth on the board's own path (capture →
//! `replay`, cold, calibrating in flight with the board's adapted scalar noise).
//!
//! What the bound covers: the interference's variation about the last minute's mean (its
//! level is the anomaly's, levelled by tie lines; docs/model.md §5a). So the error is taken
//! inside each run of ≥ 30 s of records shown good, less its 60 s running mean.
//! Run in release: `cargo test --release -p magcomp --test replay_bound -- --nocapture`.

#[path = "common/cabin_current.rs"]
mod cabin_current;
#[path = "common/independent.rs"]
mod independent_sim;

use cabin_current::flown_with_cabin_current;
use magcomp::board::capture::{trace_to_capture, CaptureOptions};
use magcomp::board::replay::{replay_capture, ReplayOptions};
use magcomp::io::trace::Trace;
use magcomp::model::spec::ModelSpec;
use magcomp::signal::bandpass::bandpass;
use magcomp::sim::{simulate, SimConfig};
use magcomp_core::protocol::record::Record;
use magcomp_core::Flags;

/// Records shown good: converged and not degraded.
fn shown_good(r: &Record) -> bool {
    !r.flags.contains(Flags::NOT_CONVERGED) && !r.flags.degraded()
}

/// The board's records (`witness`: its two filters, the paper model's and beside it the
/// fluxgate as a witness; else the paper filter alone).
fn board_records(trace: &Trace, witness: bool) -> Vec<Record> {
    let cap = trace_to_capture(trace, &CaptureOptions::default()).unwrap();
    let mut opts = ReplayOptions::new(ModelSpec::parse("tl16+field").unwrap());
    if witness {
        opts.witness = Some(ModelSpec::parse("tl16+field+fluxmod").unwrap());
    }
    let mut recs = Vec::new();
    replay_capture(&cap[..], &opts, |r| {
        recs.push(*r);
        Ok(())
    })
    .unwrap();
    assert_eq!(recs.len(), trace.len(), "one record per scalar sample");
    recs
}

/// Every converged record states a finite positive bound; every `NOT_CONVERGED` one none.
fn assert_bound_present_iff_converged(recs: &[Record], name: &str) {
    for r in recs {
        let converged = !r.flags.contains(Flags::NOT_CONVERGED);
        let stated = r.sigma_nt.is_finite() && r.sigma_nt > 0.0;
        assert_eq!(
            converged, stated,
            "{name}: record {} flags {:04X} sigma {}",
            r.seq, r.flags.0, r.sigma_nt
        );
    }
}

/// How the records shown good hold their bound: over each run of ≥ 30 s of them, the
/// interference error in the compensation band (0.1–0.9 Hz, filtered inside the run) and
/// less its 60 s running mean.
#[derive(Debug, Default)]
struct Holding {
    records: usize,
    /// rms error in the band (nT).
    band_error_nt: f64,
    /// rms error / rms bound, and the share beyond 3σ, in the band.
    band_ratio: f64,
    band_beyond_3s: f64,
    /// The same about the 60 s running mean.
    minute_ratio: f64,
    minute_beyond_3s: f64,
}

fn bound_against_truth(recs: &[Record], truth: &[f64], rate_hz: f64) -> Holding {
    let min_run = (30.0 * rate_hz) as usize;
    let half = (30.0 * rate_hz) as usize;
    let (mut band, mut minute, mut sig2) = ((0.0, 0usize), (0.0, 0usize), 0.0);
    let mut n = 0;
    let mut i = 0;
    while i < recs.len() {
        let j = (i..recs.len())
            .find(|&k| !shown_good(&recs[k]))
            .unwrap_or(recs.len());
        if j - i >= min_run {
            let d: Vec<f64> = (i..j)
                .map(|k| recs[k].interference_nt as f64 - truth[k])
                .collect();
            let in_band = bandpass(&d, 4, 0.1, 0.9, rate_hz).unwrap();
            for (k, dk) in d.iter().enumerate() {
                let (lo, hi) = (k.saturating_sub(half), (k + half + 1).min(d.len()));
                let about_minute = dk - d[lo..hi].iter().sum::<f64>() / (hi - lo) as f64;
                let s = recs[i + k].sigma_nt as f64;
                for (e, acc) in [(in_band[k], &mut band), (about_minute, &mut minute)] {
                    acc.0 += e * e;
                    acc.1 += usize::from(e.abs() > 3.0 * s);
                }
                sig2 += s * s;
                n += 1;
            }
        }
        i = j.max(i + 1);
    }
    let share = |c: usize| c as f64 / n.max(1) as f64;
    Holding {
        records: n,
        band_error_nt: (band.0 / n.max(1) as f64).sqrt(),
        band_ratio: (band.0 / sig2).sqrt(),
        band_beyond_3s: share(band.1),
        minute_ratio: (minute.0 / sig2).sqrt(),
        minute_beyond_3s: share(minute.1),
    }
}

/// The board's records of `trace` hold their bound against `truth` (the interference);
/// returns how many were the witness filter's.
fn check_flight(name: &str, trace: &Trace, truth: &[f64]) -> usize {
    let recs = board_records(trace, true);
    let h = holding(name, &recs, trace, truth);
    if h.records > 0 {
        assert!(
            h.band_ratio <= 2.0 && h.band_beyond_3s <= 0.05,
            "{name}: {h:?}"
        );
        // About the minute's mean (turns, the level moving between headings) it holds too,
        // less tightly: 0.51–1.10 measured, up to 6.9 % beyond 3σ (cloverleaf).
        assert!(
            h.minute_ratio <= 2.0 && h.minute_beyond_3s <= 0.10,
            "{name}: {h:?}"
        );
    }
    recs.iter()
        .filter(|r| r.flags.contains(Flags::WITNESS))
        .count()
}

/// How `recs` hold their bound against `truth`, said on stderr.
fn holding(name: &str, recs: &[Record], trace: &Trace, truth: &[f64]) -> Holding {
    assert_bound_present_iff_converged(recs, name);
    let converged = recs
        .iter()
        .filter(|r| !r.flags.contains(Flags::NOT_CONVERGED))
        .count();
    let witnessed = recs
        .iter()
        .filter(|r| r.flags.contains(Flags::WITNESS))
        .count();
    eprintln!(
        "{name}: {converged} of {} records converged, {witnessed} the witness filter's",
        recs.len()
    );
    let t = trace.col("t").unwrap();
    let rate_hz = 1.0 / (t[1] - t[0]);
    let h = bound_against_truth(recs, truth, rate_hz);
    eprintln!(
        "{name}: {} records shown good in runs ≥ 30 s; band: error {:.3} nT, error/bound \
         {:.2}, beyond 3σ {:.1} %; about the minute's mean: {:.2}, {:.1} %",
        h.records,
        h.band_error_nt,
        h.band_ratio,
        h.band_beyond_3s * 100.0,
        h.minute_ratio,
        h.minute_beyond_3s * 100.0
    );
    h
}

/// The simulator's own fluxgates see the Earth, the aircraft and their own errors, nothing
/// the paper model misses: the witness has nothing to add, and its records must never be
/// shown (measured: none on every flight).
fn check_unwitnessed(name: &str, trace: &Trace, truth_col: &str) {
    let truth = trace.col(truth_col).unwrap().to_vec();
    let witnessed = check_flight(name, trace, &truth);
    assert_eq!(
        witnessed, 0,
        "{name}: the witness filter's records were shown"
    );
}

#[test]
fn cloverleaf_with_exit_leg_records_hold_their_bound() {
    let trace = simulate(&SimConfig::calibration_with_exit(7)).unwrap();
    check_unwitnessed(
        "cloverleaf + exit leg, seed 7",
        &trace,
        "truth_interference",
    );
}

#[test]
fn broad_flights_records_hold_their_bound() {
    // Broad physics: noisy fluxgates that read the aircraft, a slow external variation,
    // headings off the cardinal directions, sensor errors the model does not know.
    // Each followed by the exit leg of `calibration_with_exit`: the board converges a minute
    // after the pattern, so a pattern alone leaves no run of converged records to judge.
    for seed in 1..=4 {
        let exit = SimConfig::calibration_with_exit(seed);
        let cfg = SimConfig {
            flight: exit.flight,
            survey_altitude_m: exit.survey_altitude_m,
            survey_lines: exit.survey_lines,
            line_length_m: exit.line_length_m,
            survey_offset_m: exit.survey_offset_m,
            ..SimConfig::broad(seed)
        };
        let trace = simulate(&cfg).unwrap();
        check_unwitnessed(&format!("broad seed {seed}"), &trace, "truth_interference");
    }
}

#[test]
fn independent_flights_records_hold_their_bound() {
    // The independent simulator's flights, where the shared data are present.
    match independent_sim::independent("clean_s33") {
        Some(trace) => check_unwitnessed("clean_s33", &trace, "truth_interference"),
        None => eprintln!("clean_s33: shared data absent, not checked"),
    }
    // A scalar lag neither model has: the witnessed filter's extra regressor takes a little
    // of it, and 4 isolated records (0.4 s) of 11,476 were shown from it once its noise was
    // re-weighted by the variance factor (`follow_variance_factor`); 52 records converge
    // either way, none in a run of 30 s. Whatever is shown must hold its bound (checked by
    // `check_flight`).
    match independent_sim::independent("lag_s32") {
        Some(trace) => {
            let truth = trace.col("truth_interference").unwrap().to_vec();
            let witnessed = check_flight("lag_s32", &trace, &truth);
            assert!(
                witnessed * 100 <= trace.len(),
                "lag_s32: {witnessed} witness records"
            );
        }
        None => eprintln!("lag_s32: shared data absent, not checked"),
    }
}

#[test]
fn a_cabin_current_the_fluxgate_also_sees_is_taken_by_the_witness_within_its_bound() {
    // A load current near a cabin scalar and nearer its fluxgate (3 × the field there), its
    // channel not recorded: the paper model cannot see it, the fluxgate's modulus can
    // (`fluxmod`). The paper filter alone then breaks its bound (seeds 1 / 3: band error
    // 4.44 / 3.13 nT, error/bound 1.89 / 1.48 with 13.3 / 10.7 % beyond 3σ; about the
    // minute's mean 5.19 / 4.60; seed 2: never shown good, 208 records converged in short
    // runs). The board shows the witness, whose error is lower (2.08 / 1.63 / 1.63 nT) and
    // whose rms bound holds in the band (0.58 / 0.06 / 0.64: on seed 2 the disagreement
    // with a paper filter that never settles makes it very cautious; its own bound was
    // 2.2–8 × below its error). Not held: the tails (4.8 / 0.2 / 4.2 % beyond 3σ in the band,
    // the current's on/off ramps) and the minute scale (1.53 / 0.22 / 1.96, 26 / 1 / 31 %
    // beyond 3σ): the current's slow part hides in the anomaly states of both filters,
    // where neither bound can see it — no worse than the paper filter alone, which is what
    // is asserted there. (Before the board's covariance followed its adapted noise,
    // `follow_variance_factor`: paper alone 3.88 / 2.66 / 2.46 nT, pair 2.34 / 1.71 / 1.77.)
    for seed in 1..=3 {
        let name = format!("cabin current seen by the fluxgate, seed {seed}");
        let (recs, pair, paper) = cabin_current_flight(&name, seed, &[]);
        let witnessed = recs
            .iter()
            .filter(|r| r.flags.contains(Flags::WITNESS))
            .count();
        assert!(witnessed > 2000, "{name}: {witnessed} witness records");
        assert!(pair.band_ratio <= 2.0, "{name}: {pair:?}");
        assert!(
            pair.minute_ratio <= paper.minute_ratio.max(2.0),
            "{name}: {pair:?} against {paper:?}"
        );
        // where the paper filter alone shows nothing good, the pair's records are all there is
        assert!(
            paper.records == 0 || pair.band_error_nt <= 0.75 * paper.band_error_nt,
            "{name}: {:.2} against {:.2} nT alone",
            pair.band_error_nt,
            paper.band_error_nt
        );
    }
}

#[test]
fn the_witness_hands_back_when_its_fluxgate_steps() {
    // The cabin current above, and at 800 s the fluxgate's calibration changes (bias
    // 200–500 nT, scale 0.5–1 %, 0.3–0.5° per axis: the simulator's `fluxcal`): the
    // witness's regressor steps by hundreds of nT while it is shown. Its records then
    // carry the fluxgate's flags, the paper filter's are shown, and the level is carried
    // by the disagreement last seen with both trusted (by the jump itself, a 426 nT step
    // stayed in the output). Measured, seeds 1 / 2, band error against truth, error/bound,
    // about the minute's mean: the pair 3.26 / 2.19 nT, 0.97 / 0.09, 2.55 / 0.31 (seed 2:
    // 1,095 records shown good, the witness's before the step; after it the paper filter,
    // which never converges there, is shown `NOT_CONVERGED`); the paper filter alone 4.40 nT,
    // 1.87, 5.19 / never shown good.
    for seed in 1..=2 {
        let name = format!("cabin current, the fluxgate stepping at 800 s, seed {seed}");
        let (_, pair, paper) = cabin_current_flight(&name, seed, &["fluxcal@800:1000"]);
        assert!(pair.band_ratio <= 2.0, "{name}: {pair:?}");
        assert!(pair.records > 0, "{name}: {pair:?}");
        assert!(
            (paper.records == 0 || pair.band_error_nt <= paper.band_error_nt)
                && pair.minute_ratio <= paper.minute_ratio.max(2.0),
            "{name}: {pair:?} against {paper:?}"
        );
    }
}

/// A calibration flight with a 10 nT load current near the scalar that the fluxgate sees
/// 3 × as strongly (channel not recorded) and `more` hidden effects: the board's records,
/// how they hold their bound, and how the paper filter's alone do.
fn cabin_current_flight(name: &str, seed: u64, more: &[&str]) -> (Vec<Record>, Holding, Holding) {
    let (trace, truth) = flown_with_cabin_current(SimConfig::calibration_with_exit(seed), more);
    let paper = holding(
        &format!("{name}, paper filter alone"),
        &board_records(&trace, false),
        &trace,
        &truth,
    );
    let recs = board_records(&trace, true);
    let pair = holding(name, &recs, &trace, &truth);
    (recs, pair, paper)
}
