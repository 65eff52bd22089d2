//! A board's output log read as a trace: its `$MCRAW` lines (`RAW,ON` on the board,
//! `replay --raw` on the host; `magcomp_core::protocol::raw`) hold what post-flight
//! calibration needs, one row per scalar sample. Records, replies and boot lines are
//! skipped; a raw line whose checksum or fields fail is counted and said, never read.

use super::{Trace, TraceError};
use magcomp_core::protocol::raw::{decode_raw, RawSample};
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

/// Whether `path` is a board output log: its first non-blank line starts with `$MC`.
pub fn is_board_log(path: &Path) -> bool {
    let Ok(f) = std::fs::File::open(path) else {
        return false;
    };
    let mut head = Vec::new();
    if f.take(4096).read_to_end(&mut head).is_err() {
        return false;
    }
    head.split(|&b| b == b'\n')
        .map(|l| l.trim_ascii())
        .find(|l| !l.is_empty())
        .is_some_and(|l| l.starts_with(b"$MC"))
}

/// The columns of a board log's trace, in order.
pub const COLUMNS: [&str; 9] = [
    "t",
    "mag",
    "flux_x",
    "flux_y",
    "flux_z",
    "lat",
    "lon",
    "alt",
    "ground_speed",
];

/// Reads the `$MCRAW` lines of a board log as a trace (`t`, `mag`, `flux_x/y/z`, `lat`,
/// `lon`, `alt`, `ground_speed`; a missing value is NaN).
pub fn read_board_log(path: &Path) -> Result<Trace, TraceError> {
    let file = path.display().to_string();
    let f = std::fs::File::open(path).map_err(|source| TraceError::Io {
        file: file.clone(),
        source,
    })?;
    let mut cols: Vec<Vec<f64>> = vec![Vec::new(); COLUMNS.len()];
    let (mut bad, mut first_bad) = (0u64, None);
    let mut reader = BufReader::new(f);
    let mut line = Vec::new();
    let mut lineno = 0u64;
    loop {
        line.clear();
        let n = reader
            .read_until(b'\n', &mut line)
            .map_err(|source| TraceError::Io {
                file: file.clone(),
                source,
            })?;
        if n == 0 {
            break;
        }
        lineno += 1;
        if !line.starts_with(b"$MCRAW,") {
            continue;
        }
        let Ok(r) = decode_raw(&line) else {
            bad += 1;
            first_bad.get_or_insert(lineno);
            continue;
        };
        for (c, v) in cols.iter_mut().zip(raw_row(&r)) {
            c.push(v);
        }
    }
    if cols[0].is_empty() {
        return Err(TraceError::BoardLog {
            file,
            msg: "a board output log without $MCRAW lines: the board sent records only. \
                  `RAW,ON` on the board (or `magcomp replay --raw`) writes what calibration \
                  needs"
                .into(),
        });
    }
    let mut trace = raw_trace(cols);
    if bad > 0 {
        eprintln!(
            "warning: {file}: {bad} $MCRAW line(s) failed their checksum or fields and were \
             not read (the first at line {})",
            first_bad.unwrap_or(0)
        );
        trace
            .meta
            .push(("board_log_bad_lines".into(), bad.to_string()));
    }
    Ok(trace)
}

/// One raw line as a row of [`COLUMNS`] (a missing value is NaN).
pub fn raw_row(r: &RawSample) -> [f64; 9] {
    [
        r.t_s,
        r.mag.map_or(f64::NAN, |m| m.to_nt_f64()),
        f64::from(r.flux_nt[0]),
        f64::from(r.flux_nt[1]),
        f64::from(r.flux_nt[2]),
        r.lat_deg,
        r.lon_deg,
        f64::from(r.alt_m),
        f64::from(r.ground_speed_mps),
    ]
}

/// The trace of raw lines' rows, one column per [`COLUMNS`] entry: what a board log reads
/// as, and what the live view builds from the lines it holds.
pub fn raw_trace(cols: Vec<Vec<f64>>) -> Trace {
    let mut trace = Trace {
        meta: vec![("source".into(), "board output log ($MCRAW lines)".into())],
        ..Trace::default()
    };
    for (name, values) in COLUMNS.iter().zip(cols) {
        trace.numeric.push((name.to_string(), values));
    }
    trace
}
