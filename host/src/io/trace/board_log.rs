//! A board's output log read as a trace: its `$MCRAW` lines (`RAW,ON` on the board,
//! `replay --raw` on the host; `magcomp_core::protocol::raw`) hold what post-flight
//! calibration needs, one row per scalar sample; a board reading 2–3 magnetometers on a
//! counter line writes `$MCMRAW` (`protocol::multi_raw`), read as a several-sensor trace
//! (`mag_1` … `mag_n`). Records, replies and boot lines are skipped; a raw line whose
//! checksum or fields fail is counted and said, never read.

use super::{Trace, TraceError};
use magcomp_core::protocol::multi_raw::decode_multi_raw;
use magcomp_core::protocol::multi_scalar::MAX_CHANNELS;
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
/// `lon`, `alt`, `ground_speed`; a missing value is NaN). With `$MCMRAW` lines (2–3
/// channels) `mag` is replaced by `mag_1` … `mag_n`, each channel's reading exactly; a
/// `$MCRAW` line among them (before the counter's first counter line) is channel 1's.
pub fn read_board_log(path: &Path) -> Result<Trace, TraceError> {
    let file = path.display().to_string();
    let f = std::fs::File::open(path).map_err(|source| TraceError::Io {
        file: file.clone(),
        source,
    })?;
    let mut cols: Vec<Vec<f64>> = vec![Vec::new(); COLUMNS.len()];
    // Per row every channel's reading, and the most channels a `$MCMRAW` line carried.
    let mut channels: Vec<[f64; MAX_CHANNELS]> = Vec::new();
    let mut most = 0usize;
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
        let decoded = if line.starts_with(b"$MCRAW,") {
            decode_raw(&line).map(|r| (r, [r.mag, None, None], 1))
        } else if line.starts_with(b"$MCMRAW,") {
            decode_multi_raw(&line).map(|r| (r.shared, r.mag, usize::from(r.channels)))
        } else {
            continue;
        };
        let Ok((r, mags, n)) = decoded else {
            bad += 1;
            first_bad.get_or_insert(lineno);
            continue;
        };
        for (c, v) in cols.iter_mut().zip(raw_row(&r)) {
            c.push(v);
        }
        channels.push(mags.map(|m| m.map_or(f64::NAN, |m| m.to_nt_f64())));
        most = most.max(n);
    }
    if cols[0].is_empty() {
        return Err(TraceError::BoardLog {
            file,
            msg: "a board output log without $MCRAW lines (nor $MCMRAW): the board sent records only. \
                  `RAW,ON` on the board (or `magcomp replay --raw`) writes what calibration \
                  needs"
                .into(),
        });
    }
    let mut trace = raw_trace(cols);
    if most > 1 {
        // `mag` (channel 1's) gives way to every channel's column, in its place.
        let at = trace
            .numeric
            .iter()
            .position(|(n, _)| n == "mag")
            .unwrap_or(1);
        trace.numeric.remove(at);
        for ch in (0..most).rev() {
            let v = channels.iter().map(|c| c[ch]).collect();
            trace.numeric.insert(at, (format!("mag_{}", ch + 1), v));
        }
        trace.meta[0].1 = "board output log ($MCMRAW lines)".into();
    }
    if bad > 0 {
        crate::errln!(
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
