//! `monitor`: a generated `$MCREC` stream with gaps, corruption, replies and noise.

mod common;
use magcomp::board::monitor::{monitor_stream, Display, SAVE_HEADER};
use magcomp::cli::monitor::{run as run_monitor, MonitorArgs};
use magcomp_core::protocol::record::{encode_record, Record, MAX_RECORD_LEN};
use magcomp_core::{Flags, MagCounts};

const N: u32 = 1000;

fn rec(seq: u32) -> Record {
    let mag = MagCounts(536_204_401 + seq as i64 * 13);
    let interf = 12.3456 + seq as f32 * 0.001;
    let mut flags = Flags::empty();
    if (300..320).contains(&seq) {
        flags.set(Flags::FLUX_STALE);
    }
    if seq % 100 == 7 {
        flags.set(Flags::NO_GPS);
    }
    Record {
        seq,
        t_s: 43_200.0 + seq as f64 * 0.1,
        mag: Some(mag),
        interference_nt: interf,
        compensated: Record::compensate(Some(mag), interf),
        anomaly_nt: -3.21,
        innovation_nt: 0.0123,
        sigma_nt: 0.25,
        flags,
    }
}

fn line(r: &Record) -> Vec<u8> {
    let mut b = [0u8; MAX_RECORD_LEN];
    let n = encode_record(r, &mut b).unwrap();
    b[..n].to_vec()
}

struct Expect {
    records: u64,
    crc: u64,
    malformed: u64,
    missing: u64,
    saved_seqs: Vec<u32>,
}

/// Records 0..N except two gaps; every 50th record (not in a gap) has one byte changed
/// (CRC error), record 500 loses its `$` (malformed), plus replies, boot text, a truncated
/// record and an overlong line.
fn stream() -> (Vec<u8>, Expect) {
    let mut out = Vec::new();
    let mut e = Expect {
        records: 0,
        crc: 0,
        malformed: 0,
        missing: 0,
        saved_seqs: Vec::new(),
    };
    out.extend_from_slice(b"magcomp fw boot\r\n");
    for seq in 0..N {
        if (100..=104).contains(&seq) || seq == 700 {
            e.missing += 1;
            continue;
        }
        let mut l = line(&rec(seq));
        if seq == 500 {
            l.remove(0);
            e.malformed += 1;
        } else if seq % 50 == 25 {
            // A digit of the time field changed: CRC catches it.
            let p = l.iter().position(|&b| b == b'.').unwrap() - 1;
            l[p] = if l[p] == b'9' { b'8' } else { l[p] + 1 };
            e.crc += 1;
        } else {
            e.records += 1;
            e.saved_seqs.push(seq);
        }
        out.extend_from_slice(&l);
        if seq == 200 {
            out.extend_from_slice(b"$MCACK,MODE,SURVEY*041F\r\n");
        }
        if seq == 201 {
            // Truncated record (the logger was unplugged mid-line, then resumed).
            out.extend_from_slice(b"$MCREC,9999,43200.0000\r\n");
            e.malformed += 1;
        }
        if seq == 202 {
            out.extend_from_slice(&[b'x'; 2000]);
            out.extend_from_slice(b"\r\n");
        }
    }
    (out, e)
}

#[test]
fn counts_gaps_and_saved_rows_are_exact() {
    let (bytes, e) = stream();
    let mut out = Vec::new();
    let mut save = Vec::new();
    let st = monitor_stream(
        &bytes[..],
        "test",
        Display::Summary(10.0),
        false,
        &mut out,
        Some(&mut save),
    )
    .unwrap();
    assert_eq!(st.records, e.records);
    assert_eq!(st.crc_errors, e.crc);
    assert_eq!(st.parse_errors, e.malformed);
    assert_eq!(st.replies, 1);
    assert_eq!(st.other_lines, 2); // boot text, overlong line
                                   // Corrupted records are not "missing": the gap logic sees their seq absent too, so the
                                   // missing count is every seq never decoded.
    let never = e.missing + e.crc + e.malformed - 1; // the truncated line is not a seq
    assert_eq!(st.missing, never);
    assert!(st.gaps.contains(&(100, 104)));
    assert!(st.gaps.contains(&(700, 700)));
    assert!(st.gaps.contains(&(25, 25)));
    assert_eq!(st.restarts, 0);
    assert_eq!(st.last.unwrap().seq, N - 1);
    // Flags counted per decoded record: 20 FLUX_STALE (300–319, none corrupted: 325 is
    // outside), NO_GPS on every x07 except gaps.
    assert_eq!(st.flag_counts[0], 20);
    assert_eq!(st.flag_counts[1], 10);

    // Saved: metadata, header, one row per decoded record, values as sent.
    let text = String::from_utf8(save).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("# source: magcomp monitor"));
    assert_eq!(lines.next(), Some("# input: test"));
    assert_eq!(lines.next(), Some(SAVE_HEADER));
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len() as u64, e.records);
    let seqs: Vec<u32> = rows
        .iter()
        .map(|r| r.rsplit(',').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(seqs, e.saved_seqs);
    let r310: Vec<&str> = rows
        .iter()
        .find(|r| r.ends_with(",310"))
        .unwrap()
        .split(',')
        .collect();
    assert_eq!(r310[0], "43231.000000");
    assert_eq!(r310[1], "53620.8431"); // 536204401 + 310·13 counts
    assert_eq!(r310[2], "12.6556");
    assert_eq!(r310[3], "53608.1875"); // − round(12.6556 × 1e4) counts
    assert_eq!(r310[6], "0.2500"); // the record's stated bound
    assert_eq!(r310[7], "1"); // FLUX_STALE

    // Summary lines: one per 10 s of record time over ~100 s, then the final one.
    let printed = String::from_utf8(out).unwrap();
    let n_summaries = printed
        .lines()
        .filter(|l| l.starts_with("records "))
        .count();
    assert!((9..=10).contains(&n_summaries), "{printed}");
    let last = printed.lines().last().unwrap();
    assert!(
        last.starts_with(&format!("end of stream: records {}", e.records)),
        "{last}"
    );
    assert_eq!(e.records, 973);
    // Received-record rate over the last 100 records: 925 and 975 were lost, so
    // 99 intervals in 10.1 s.
    assert!(last.contains("rate 9.80 Hz"), "{last}");
    assert!(last.contains(&format!("missing {never}")), "{last}");
}

#[test]
fn restart_and_live_panel() {
    let mut bytes = Vec::new();
    for seq in (0..30).chain(0..10) {
        bytes.extend(line(&rec(seq)));
    }
    let mut out = Vec::new();
    let st = monitor_stream(
        &bytes[..],
        "dev",
        Display::Live(std::time::Duration::ZERO),
        false,
        &mut out,
        None,
    )
    .unwrap();
    assert_eq!(st.records, 40);
    assert_eq!(st.restarts, 1);
    assert_eq!(st.missing, 0);
    let panel = String::from_utf8_lossy(&out);
    // Redrawn in place (cursor home), the last state shows seq 9 and its flags in words.
    assert!(panel.contains("\x1b[H"));
    assert!(panel.contains("NO_GPS"), "{panel}");
    assert!(panel.contains("restarts/out of order 1"));
}

#[test]
fn run_monitor_reads_a_file_and_saves() {
    let (bytes, e) = stream();
    // Removed when the test ends, passed or failed.
    let scratch = common::cli::tmp("monitor");
    let dir = scratch.to_path_buf();
    std::fs::create_dir_all(&dir).unwrap();
    let input = dir.join("out.txt");
    std::fs::write(&input, &bytes).unwrap();
    let args = MonitorArgs {
        input: input.display().to_string(),
        save: Some(dir.join("trace.csv")),
        interval_s: 1.0,
        quiet: true,
        follow: false,
        web: false,
        listen: String::new(),
        realtime: false,
        stty: None,
        also: Vec::new(),
        d4_band_nt: 0.05,
        window_records: 1200,
    };
    let st = run_monitor(&args).unwrap();
    assert_eq!(st.records, e.records);
    let saved = std::fs::read_to_string(dir.join("trace.csv")).unwrap();
    assert_eq!(saved.lines().count() as u64, e.records + 3);
    assert!(run_monitor(&MonitorArgs {
        input: dir.join("nope").display().to_string(),
        ..args
    })
    .is_err());
    std::fs::remove_dir_all(&dir).ok();
}

/// Returns its parts one per read, an end-of-file in between, then an error.
struct Growing(Vec<Vec<u8>>);
impl std::io::Read for Growing {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if self.0.is_empty() {
            return Err(std::io::Error::other("unplugged"));
        }
        let p = self.0.remove(0);
        buf[..p.len()].copy_from_slice(&p);
        Ok(p.len())
    }
}

#[test]
fn follow_reads_past_the_end_of_a_growing_file() {
    let part = |a: u32, b: u32| (a..b).flat_map(|s| line(&rec(s))).collect::<Vec<u8>>();
    // A record split across the end of file is joined when the rest arrives.
    let mut p1 = part(0, 5);
    let mut tail = line(&rec(5));
    let rest = tail.split_off(20);
    p1.extend(tail);
    let mut p2 = rest;
    p2.extend(part(6, 10));
    let input = Growing(vec![p1, Vec::new(), p2]);
    let mut save = Vec::new();
    let mut out = Vec::new();
    let r = monitor_stream(
        input,
        "log",
        Display::Quiet,
        true,
        &mut out,
        Some(&mut save),
    );
    assert!(r.is_err());
    let rows = String::from_utf8(save).unwrap();
    assert_eq!(rows.lines().count(), 3 + 10);
}
