//! hil-tests: runs the magcomp firmware on a board (QEMU's STM32F405 by default, a real
//! acquisition board with `MAGCOMP_HIL_TARGET=serial`), streams sensor captures into its
//! ports at the sensors' rates and checks every output record. See docs/firmware.md.

pub mod board;
pub mod capture;
pub mod prng;

/// The firmware's constants (model, capacities, rates), source-for-source (pure, no
/// embassy): the reference replay runs the board's `magcomp_core::acquisition` with them.
#[path = "../../src/board_config.rs"]
pub mod board_config;
pub mod replay;
/// The board's coefficient store layout (pure: the tests check its images on the host).
/// Its `Result<_, ()>` is the firmware's ("no valid set: calibrate"), public here only
/// because this crate is a library.
#[path = "../../src/store.rs"]
#[allow(clippy::result_unit_err)]
pub mod store;

pub use magcomp_core::protocol::record::{Record, decode_record};
use std::io::{self, BufRead, Write};

/// CSV header of decoded records (the same columns `magcomp replay` is to write).
pub const CSV_HEADER: &str =
    "seq,t_s,mag_nt,interference_nt,compensated_nt,anomaly_nt,innovation_nt,sigma_nt,flags";

fn counts(c: Option<magcomp_core::MagCounts>) -> String {
    c.map(|c| {
        let sign = if c.0 < 0 { "-" } else { "" };
        let a = c.0.unsigned_abs();
        format!("{sign}{}.{:04}", a / 10_000, a % 10_000)
    })
    .unwrap_or_default()
}

fn num(v: f32) -> String {
    if v.is_finite() {
        format!("{v:.4}")
    } else {
        String::new()
    }
}

/// Writes records as CSV (empty cell = missing).
pub fn write_csv<W: Write>(mut w: W, recs: &[Record]) -> io::Result<()> {
    writeln!(w, "{CSV_HEADER}")?;
    for r in recs {
        writeln!(
            w,
            "{},{:.6},{},{},{},{},{},{},{}",
            r.seq,
            r.t_s,
            counts(r.mag),
            num(r.interference_nt),
            counts(r.compensated),
            num(r.anomaly_nt),
            num(r.innovation_nt),
            num(r.sigma_nt),
            r.flags.0
        )?;
    }
    Ok(())
}

/// Reads records written by `write_csv` (or by `magcomp replay` in the same columns).
pub fn read_csv<R: BufRead>(r: R) -> io::Result<Vec<Record>> {
    let bad = |n: usize| io::Error::new(io::ErrorKind::InvalidData, format!("csv line {n}"));
    let mut out = Vec::new();
    for (n, line) in r.lines().enumerate() {
        let line = line?;
        if n == 0 || line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 9 {
            return Err(bad(n));
        }
        let opt_c = |s: &str| -> io::Result<Option<magcomp_core::MagCounts>> {
            if s.is_empty() {
                Ok(None)
            } else {
                let v: f64 = s.parse().map_err(|_| bad(n))?;
                magcomp_core::MagCounts::from_nt_f64(v)
                    .map(Some)
                    .ok_or_else(|| bad(n))
            }
        };
        let opt_f = |s: &str| -> io::Result<f32> {
            if s.is_empty() {
                Ok(f32::NAN)
            } else {
                s.parse().map_err(|_| bad(n))
            }
        };
        out.push(Record {
            seq: f[0].parse().map_err(|_| bad(n))?,
            t_s: f[1].parse().map_err(|_| bad(n))?,
            mag: opt_c(f[2])?,
            interference_nt: opt_f(f[3])?,
            compensated: opt_c(f[4])?,
            anomaly_nt: opt_f(f[5])?,
            innovation_nt: opt_f(f[6])?,
            sigma_nt: opt_f(f[7])?,
            flags: magcomp_core::Flags(f[8].parse().map_err(|_| bad(n))?),
        });
    }
    Ok(out)
}

/// Record-by-record comparison (board vs host replay): same count, sequence, flags and
/// time, values within `tol_nt` (missing must match missing).
pub fn compare_records(board: &[Record], replay: &[Record], tol_nt: f64) -> Result<(), String> {
    if board.len() != replay.len() {
        return Err(format!(
            "{} board records vs {} replay records",
            board.len(),
            replay.len()
        ));
    }
    let close = |a: f64, b: f64| (a.is_nan() && b.is_nan()) || (a - b).abs() <= tol_nt;
    let c = |x: Option<magcomp_core::MagCounts>| x.map_or(f64::NAN, |v| v.to_nt_f64());
    for (a, b) in board.iter().zip(replay) {
        let ok = a.seq == b.seq
            && a.flags == b.flags
            && (a.t_s - b.t_s).abs() < 1e-6
            && close(c(a.mag), c(b.mag))
            && close(a.interference_nt.into(), b.interference_nt.into())
            && close(c(a.compensated), c(b.compensated))
            && close(a.anomaly_nt.into(), b.anomaly_nt.into())
            && close(a.innovation_nt.into(), b.innovation_nt.into())
            && close(a.sigma_nt.into(), b.sigma_nt.into());
        if !ok {
            return Err(format!(
                "record {} differs:\n board  {a:?}\n replay {b:?}",
                a.seq
            ));
        }
    }
    Ok(())
}

/// Sequence numbers 0, 1, 2, … without gap or repeat.
pub fn check_contiguous(recs: &[Record]) -> Result<(), String> {
    for (i, r) in recs.iter().enumerate() {
        if r.seq as usize != i {
            return Err(format!("record #{i} has seq {}", r.seq));
        }
    }
    Ok(())
}

/// Runs the host replay of a capture when `MAGCOMP_BIN` names a `magcomp` executable:
/// `magcomp replay CAPTURE --records OUT` writes the records as the board sends them
/// (`$MCREC` lines), decoded here with the core's decoder. `None` when not configured.
pub fn host_replay(
    capture_path: &std::path::Path,
    out: &std::path::Path,
) -> Option<Result<Vec<Record>, String>> {
    host_replay_with(capture_path, out, &[])
}

/// As [`host_replay`] with extra `magcomp replay` arguments (e.g. `--lag-s 0.3`).
pub fn host_replay_with(
    capture_path: &std::path::Path,
    out: &std::path::Path,
    extra: &[&str],
) -> Option<Result<Vec<Record>, String>> {
    let exe = std::env::var("MAGCOMP_BIN").ok()?;
    let run = || -> Result<Vec<Record>, String> {
        let st = std::process::Command::new(&exe)
            .arg("replay")
            .arg(capture_path)
            .arg("--records")
            .arg(out)
            .args(extra)
            .status()
            .map_err(|e| format!("{exe}: {e}"))?;
        if !st.success() {
            return Err(format!("{exe} replay failed ({st})"));
        }
        let text = std::fs::read_to_string(out).map_err(|e| e.to_string())?;
        text.lines()
            .filter(|l| l.starts_with("$MCREC"))
            .map(|l| decode_record(l.as_bytes()).map_err(|e| format!("{l}: {e:?}")))
            .collect()
    };
    Some(run())
}
