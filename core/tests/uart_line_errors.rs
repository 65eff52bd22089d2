//! A UART error on the scalar port, as the board's sensor task handles it (`fw::forward`):
//! the port's error count grew on a chunk, so the lines completed from that chunk and the
//! one left open at its end are rejected (`ScalarError::Uart`). Each still gives exactly
//! one record, flagged `PARSE_ERROR`, its value not fused; the clean lines around them are
//! as without the error.

use magcomp_core::acquisition::{compensator_config, AcqConfig, AcqRecord, Acquisition};
use magcomp_core::model::Model;
use magcomp_core::protocol::multi_scalar::ScalarLine;
use magcomp_core::protocol::record::Record;
use magcomp_core::protocol::scalar::{ScalarConfig, ScalarError, ScalarReader};
use magcomp_core::protocol::uart_errors::LineErrors;
use magcomp_core::{Compensator, Flags};

type Acq<'a> = Acquisition<'a, 32, 16>;

fn acq<'a>() -> Acq<'a> {
    let comp = Compensator::new(Model::paper(), compensator_config(10.0, 16)).unwrap();
    Acquisition::new(AcqConfig::new(10.0, 10.0, 1.0), comp).unwrap()
}

/// 40 scalar lines at 10 Hz (a slow ramp), sent in chunks of `chunk` bytes; `errors[c]` is
/// the port's UART error count after chunk `c` (0 when not listed). Every record, in order.
fn flown(chunk: usize, errors: &[(usize, u32)]) -> Vec<Record> {
    let text: String = (0..40)
        .map(|k| format!("{:.4}\r\n", 53_000.0 + 0.25 * k as f64))
        .collect();
    let mut a = acq();
    let mut reader = ScalarReader::new(ScalarConfig::default());
    let mut uart = LineErrors::new(0);
    let mut count = 0;
    let mut out = Vec::new();
    let mut keep = |r: Option<AcqRecord>| {
        if let Some(AcqRecord::One(r)) = r {
            out.push(r);
        }
    };
    for (c, bytes) in text.as_bytes().chunks(chunk).enumerate() {
        if let Some(&(_, n)) = errors.iter().find(|(at, _)| *at == c) {
            count = n;
        }
        uart.after_read(count);
        for &b in bytes {
            if let Some(line) = reader.push_line(b) {
                let line = if uart.line_done() {
                    ScalarLine::Single(Err(ScalarError::Uart))
                } else {
                    line
                };
                keep(a.scalar_line(line));
            }
        }
    }
    while let Some(r) = a.flush_any() {
        keep(Some(r));
    }
    out
}

fn rejected(recs: &[Record]) -> Vec<usize> {
    (0..recs.len())
        .filter(|&k| recs[k].flags.contains(Flags::PARSE_ERROR))
        .collect()
}

#[test]
fn the_lines_of_a_chunk_with_a_uart_error_are_rejected_each_with_its_record() {
    // 12-byte lines ("53000.0000\r\n") read 20 bytes at a time: chunk 5 (bytes 100–119)
    // completes lines 8 (bytes 96–107) and 9 (108–119); line 10, the next to complete,
    // is rejected too: the tracker cannot tell that the chunk ended on a line end.
    let clean = flown(20, &[]);
    assert_eq!(clean.len(), 40);
    assert!(rejected(&clean).is_empty());
    let bad = flown(20, &[(5, 1)]);
    assert_eq!(bad.len(), 40, "one record per line");
    assert_eq!(rejected(&bad), [8, 9, 10]);
    for k in [8, 9, 10] {
        assert!(bad[k].flags.contains(Flags::MAG_MISSING), "record {k}");
    }
    // The line times and the records of the other lines are the clean run's.
    for k in 0..40 {
        assert_eq!(bad[k].seq, clean[k].seq);
        assert_eq!(bad[k].t_s.to_bits(), clean[k].t_s.to_bits());
    }
    let same = |a: &Record, b: &Record| {
        (a.mag, a.compensated, a.flags, a.interference_nt.to_bits())
            == (b.mag, b.compensated, b.flags, b.interference_nt.to_bits())
    };
    assert!((0..8).all(|k| same(&bad[k], &clean[k])));
    // A count that grows again on a later chunk rejects that chunk's lines too.
    let twice = flown(20, &[(5, 1), (12, 3)]);
    assert_eq!(rejected(&twice), [8, 9, 10, 20, 21]);
}
