//! `replay` checks what a capture's lines say about time: duplicated lines and lines
//! back in time are dropped, counted and flagged, so a damaged capture yields the same
//! records as the clean one (never more records than scalar samples); a UTF-8 BOM on the
//! header is read through, never a silent fall-back to the board's default rates.

use magcomp::board::capture::{trace_to_capture, CaptureOptions};
use magcomp::board::replay::{replay_capture, ReplayOptions, ReplayStats};
use magcomp::model::spec::ModelSpec;
use magcomp::sim::{simulate, SimConfig};
use magcomp_core::protocol::record::Record;
use magcomp_core::Flags;

/// 120 s at 10 Hz: 1,200 scalar samples, as in the issue.
fn capture() -> (Vec<u8>, usize) {
    let cfg = SimConfig {
        max_duration_s: Some(120.0),
        seed: 5,
        ..SimConfig::default()
    };
    let trace = simulate(&cfg).unwrap();
    (
        trace_to_capture(&trace, &CaptureOptions::default()).unwrap(),
        trace.len(),
    )
}

fn replay(cap: &[u8]) -> (Vec<Record>, ReplayStats) {
    let mut recs = Vec::new();
    let opts = ReplayOptions::new(ModelSpec::parse("tl16+field").unwrap());
    let stats = replay_capture(cap, &opts, |r| {
        recs.push(*r);
        Ok(())
    })
    .unwrap();
    (recs, stats)
}

/// Records equal in everything but the PARSE_ERROR flag the drop adds.
fn assert_same_records(got: &[Record], want: &[Record]) {
    assert_eq!(got.len(), want.len());
    for (g, w) in got.iter().zip(want) {
        let mut g = *g;
        g.flags.0 &= !Flags::PARSE_ERROR | (w.flags.0 & Flags::PARSE_ERROR);
        // No innovation (NaN: the first reading, judged by continuity alone) equals none,
        // and so does no bound (NaN while NOT_CONVERGED).
        let mut w = *w;
        for (a, b) in [
            (&mut g.innovation_nt, &mut w.innovation_nt),
            (&mut g.sigma_nt, &mut w.sigma_nt),
        ] {
            if a.is_nan() && b.is_nan() {
                (*a, *b) = (0.0, 0.0);
            }
        }
        assert_eq!(g, w);
    }
}

fn lines(cap: &[u8]) -> Vec<&[u8]> {
    cap.split_inclusive(|&b| b == b'\n').collect()
}

#[test]
fn duplicated_scalar_lines_give_one_record_per_sample() {
    let (clean, samples) = capture();
    let (want, clean_stats) = replay(&clean);
    assert_eq!(want.len(), samples);
    assert_eq!(
        (clean_stats.duplicate_lines, clean_stats.time_reversals),
        (0, 0)
    );
    assert!(clean_stats.dropped_warning().is_none());
    // Every scalar line written twice (a logger that repeats its writes).
    let mut dup = Vec::new();
    let mut scalar_lines = 0u64;
    for l in lines(&clean) {
        dup.extend_from_slice(l);
        if l.split(|&b| b == b' ').nth(1) == Some(b"scalar") {
            dup.extend_from_slice(l);
            scalar_lines += 1;
        }
    }
    let (got, stats) = replay(&dup);
    assert_eq!(stats.duplicate_lines, scalar_lines);
    assert_eq!(got.len(), samples, "{stats}");
    assert_same_records(&got, &want);
    let flagged = got
        .iter()
        .filter(|r| r.flags.contains(Flags::PARSE_ERROR))
        .count();
    assert!(flagged as f64 > 0.9 * samples as f64, "{flagged} flagged");
    let w = stats.dropped_warning().unwrap();
    assert!(
        w.contains(&format!("{scalar_lines} duplicated line(s)")),
        "{w}"
    );
    assert!(stats
        .to_string()
        .contains(&format!("dropped: {scalar_lines} duplicated lines")));
}

#[test]
fn a_capture_concatenated_twice_is_read_once() {
    let (clean, samples) = capture();
    let (want, _) = replay(&clean);
    let data_lines = lines(&clean).iter().filter(|l| l[0] != b'#').count() as u64;
    let mut twice = clean.clone();
    twice.extend_from_slice(&clean);
    let (got, stats) = replay(&twice);
    // The second copy's header is a comment; every one of its data lines goes back in
    // time, except each port's last, which repeats the first copy's last (a duplicate).
    let ports: std::collections::BTreeSet<&[u8]> = lines(&clean)
        .iter()
        .filter(|l| l[0] != b'#')
        .filter_map(|l| l.split(|&b| b == b' ').nth(1))
        .collect();
    let ports = ports.len() as u64;
    assert_eq!(ports, 3, "scalar, flux, gps");
    assert_eq!(stats.duplicate_lines, ports, "{stats}");
    assert_eq!(stats.time_reversals, data_lines - ports, "{stats}");
    assert_eq!(got.len(), samples);
    assert_same_records(&got, &want);
    let header_lines = lines(&clean).len() as u64 - data_lines;
    assert_eq!(
        stats.first_reversal_line,
        Some(lines(&clean).len() as u64 + header_lines + 1)
    );
}

#[test]
fn a_bom_on_the_header_keeps_the_capture_rates() {
    let (clean, _) = capture();
    let (want, clean_stats) = replay(&clean);
    // The capture's GPS rate (5 Hz) differs from the board default (1 Hz): a header
    // that is not read shows here.
    assert_eq!(clean_stats.gps_hz, 5.0);
    let mut bom = b"\xEF\xBB\xBF".to_vec();
    bom.extend_from_slice(&clean);
    let (got, stats) = replay(&bom);
    assert_eq!(stats, clean_stats);
    assert_same_records(&got, &want);
}
