//! What the hil test binaries share: running a flight on the board, command replies,
//! the stream's speed. Each binary uses a part of it.
#![allow(dead_code)]

use hil_tests::Record;
use hil_tests::board::{self, Board};
use hil_tests::capture::Capture;
use hil_tests::replay::replay;
use magcomp_core::protocol::command::check_reply;
use magcomp_core::protocol::scalar::{ScalarConfig, parse_scalar_line};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// The core's scalar parser on one captured line (terminator stripped).
pub fn scalar_line(
    b: &[u8],
) -> Result<magcomp_core::protocol::scalar::ScalarFrame, magcomp_core::protocol::scalar::ScalarError>
{
    let end = b
        .iter()
        .position(|&c| c == b'\r' || c == b'\n')
        .unwrap_or(b.len());
    parse_scalar_line(&b[..end], &ScalarConfig::default())
}

/// Sends a command and returns its reply, whose CRC must check.
pub fn reply(b: &mut Board, body: &str) -> String {
    let r = b.command(body).unwrap_or_else(|e| panic!("{body}: {e}"));
    assert!(check_reply(r.as_bytes()).is_some(), "reply CRC: {r}");
    r
}

/// The values of a reply `$MCACK,<CMD>,v1,v2…*HHHH`.
pub fn reply_values(r: &str) -> Vec<f32> {
    r.split('*')
        .next()
        .unwrap_or_default()
        .split(',')
        .skip(2)
        .map(|v| v.parse().unwrap_or_else(|_| panic!("value {v:?} in {r}")))
        .collect()
}

/// Speed factor of the stream (1.0 = real time). `MAGCOMP_HIL_SPEED` can raise it for a
/// quick local run; CI keeps the sensors' real rates.
pub fn speed() -> f64 {
    std::env::var("MAGCOMP_HIL_SPEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .filter(|&v: &f64| v > 0.0)
        .unwrap_or(1.0)
}

/// Starts the board, streams the capture, flushes, and returns the board and its records.
/// Also writes the capture (raw format) and the decoded records (CSV) to the run directory,
/// and compares with the host replay when `MAGCOMP_BIN` names a `magcomp` with `replay`.
pub fn run_flight(name: &str, cap: &Capture) -> Option<(Board, Vec<Record>)> {
    run_flight_at(name, cap, speed())
}

/// As [`run_flight`], streamed `speed` times faster than the capture's own timing.
pub fn run_flight_at(name: &str, cap: &Capture, speed: f64) -> Option<(Board, Vec<Record>)> {
    if let Some(why) = board::skip_reason() {
        eprintln!("{why}");
        return None;
    }
    let t0 = Instant::now();
    let mut b = Board::start(name).unwrap_or_else(|e| panic!("{name}: board start: {e}"));
    b.stream(cap, speed)
        .unwrap_or_else(|e| panic!("{name}: stream: {e}"));
    let n = cap.scalar_t_s.len();
    let (recs, _) = collect_records(&mut b, name, n);
    let cap_path = b.dir.join("capture.txt");
    cap.write_raw(std::io::BufWriter::new(
        std::fs::File::create(&cap_path).unwrap(),
    ))
    .unwrap();
    let csv = b.dir.join("board.csv");
    hil_tests::write_csv(
        std::io::BufWriter::new(std::fs::File::create(&csv).unwrap()),
        &recs,
    )
    .unwrap();
    // values: the board's records equal the host run of the same code on the same bytes
    let reference = replay(cap);
    hil_tests::write_csv(
        std::io::BufWriter::new(std::fs::File::create(b.dir.join("reference.csv")).unwrap()),
        &reference,
    )
    .unwrap();
    hil_tests::compare_records(&recs, &reference, 1e-3)
        .unwrap_or_else(|e| panic!("{name}: board vs reference replay: {e}"));
    if let Some(host) = hil_tests::host_replay(&cap_path, &b.dir.join("replay.txt")) {
        let host = host.unwrap_or_else(|e| panic!("{name}: magcomp replay: {e}"));
        hil_tests::compare_records(&recs, &host, 1e-3)
            .unwrap_or_else(|e| panic!("{name}: board vs magcomp replay: {e}"));
        eprintln!(
            "{name}: {} records equal to `magcomp replay` within 1e-3 nT",
            recs.len()
        );
    }
    eprintln!(
        "{name}: {} samples in, {} records out, {:.1} s wall, logs in {}",
        n,
        recs.len(),
        t0.elapsed().as_secs_f64(),
        b.dir.display()
    );
    Some((b, recs))
}

/// The records of a flight of `n` scalar samples once streamed: all but the few samples the
/// centred derivative holds should be out promptly, then `FLUSH` sends those; the output
/// is saved in the board's log folder (the path returned), and every record line must
/// decode.
pub fn collect_records(b: &mut Board, name: &str, n: usize) -> (Vec<Record>, PathBuf) {
    b.wait_records(n.saturating_sub(8), Duration::from_secs(10));
    b.flush().unwrap_or_else(|e| panic!("{name}: {e}"));
    let (recs, bad) = b.records();
    let out = b.save_output();
    assert!(
        bad.is_empty(),
        "{name}: undecodable record lines (see {}): {:?}",
        out.display(),
        &bad[..bad.len().min(3)]
    );
    (recs, out)
}

pub fn assert_one_record_per_sample(name: &str, b: &Board, cap: &Capture, recs: &[Record]) {
    assert_eq!(
        recs.len(),
        cap.scalar_t_s.len(),
        "{name}: records out != scalar samples in (output in {})",
        b.dir.display()
    );
    hil_tests::check_contiguous(recs).unwrap_or_else(|e| panic!("{name}: {e}"));
    let boots = b
        .output()
        .iter()
        .filter(|l| l.starts_with("$MCBOOT"))
        .count();
    assert_eq!(
        boots, 1,
        "{name}: the firmware restarted ({boots} boot banners)"
    );
}

/// The board holds a coefficient as the filter's scaled state c/σ: it reads back within
/// an ulp of f32 of the value sent.
pub fn coefficients_read_back(got: &[f32], want: &[f32]) -> bool {
    got.len() == want.len()
        && got
            .iter()
            .zip(want)
            .all(|(g, w)| (g - w).abs() <= f32::EPSILON * w.abs().max(f32::MIN_POSITIVE))
}

/// Sends a hidden test-hook line (emulated build). Not right after a reply: a byte arriving
/// as the board ends a transmission can be lost (`Board::command_line`), and a hook line has
/// no reply to say so, so it waits until the port has been quiet.
pub fn send_hook(b: &mut Board, line: &[u8]) {
    std::thread::sleep(Duration::from_millis(200));
    b.send_command_bytes(line).unwrap();
}

/// Starts the board for test `name` (emulated, or the real one with
/// `MAGCOMP_HIL_TARGET=serial`); `None` (SKIP, the reason on stderr) where neither can run.
/// A board that cannot start is a failure, not a skip.
pub fn start(name: &str) -> Option<Board> {
    if let Some(why) = board::skip_reason() {
        eprintln!("{why}");
        return None;
    }
    Some(Board::start(name).unwrap_or_else(|e| panic!("{name}: {e}")))
}

/// Starts the emulated board for a test that uses its hidden hooks (`!STALL`, `!PANIC`,
/// `!CUT<n>`); `None` (SKIP) without QEMU or on a real board, whose image has no hooks.
pub fn start_with_hooks(name: &str) -> Option<Board> {
    if let Some(why) = board::skip_reason() {
        eprintln!("{why}");
        return None;
    }
    if !board::emulated() {
        eprintln!("SKIP: {name} uses the emulated build's hidden test hooks");
        return None;
    }
    start(name)
}

/// Boot banners so far.
pub fn banners(b: &Board) -> Vec<String> {
    b.output()
        .into_iter()
        .filter(|l| l.starts_with("$MCBOOT"))
        .collect()
}
