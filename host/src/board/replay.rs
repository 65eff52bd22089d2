//! `magcomp replay CAPTURE`: a raw sensor capture through `magcomp_core::acquisition`, the
//! code the firmware runs, in capture-line order; writes the records the board would send.
//!
//! Same as the board: readers, time base (virtual clock from the scalar line count, GPS
//! time of day anchor), staleness limits of 2.5 sensor periods, the derivative window of a
//! 16-sample ring, `CompensatorConfig::for_rate` defaults. Only the order of the chunks
//! matters, not their timestamps (the board's records do not depend on UART jitter either).
//! Rates come from `--rate`/`--flux-rate`/`--gps-rate`, else from the capture's
//! `# scalar_hz:` / `# flux_hz:` / `# gps_hz:` comments, else the board's 10/10/1 Hz.
//! The fluxgate's temperature drift (`fluxtemp`, `SETFTEMP`) is corrected per fluxgate line
//! with the line's 4th field, as on the board.
//! The scalar's delay τ (`lag`, the board's `SETLAG`) goes through the board's delay line:
//! each scalar sample is paired with the fluxgate at t − τ.

use crate::board::capture::FluxFormat;
use crate::io::bounded::read_line_bounded;
use crate::model::spec::{with_models, ModelSpec};
use anyhow::{bail, Context, Result};
use magcomp_core::acquisition::{
    compensator_config, AcqConfig, AcqCounters, AcqRecord, Acquisition,
};
use magcomp_core::protocol::capture::{decode_line, Port, MAX_CHUNK};
use magcomp_core::protocol::fluxgate::{FluxCalibration, FluxTempCal};
use magcomp_core::protocol::lag_line::{LagLine, LAG_FRAMES, MAX_LAG_S};
use magcomp_core::protocol::multi_raw::RawLine;
use magcomp_core::protocol::record::Record;
use magcomp_core::{Compensator, Flags, MagCounts};
use std::fmt;
use std::io::BufRead;
use std::path::Path;

/// State capacity of the host replay (any model the host can build).
pub const REPLAY_STATES: usize = 64;
/// Derivative ring of the board (`WINDOW` in the firmware): same half-width clamp.
pub const REPLAY_WINDOW: usize = 16;
/// The board's nominal rates when neither the flags nor the capture say otherwise.
pub const BOARD_RATES_HZ: (f64, f64, f64) = (10.0, 10.0, 1.0);

/// Columns of the records CSV.
pub const CSV_HEADER: &str = "seq,t,mag,interference,compensated,anomaly,innovation,sigma,flags";

/// Everything the replay needs besides the bytes.
#[derive(Clone, Debug)]
pub struct ReplayOptions {
    pub model: ModelSpec,
    pub coefficients: Option<Vec<f32>>,
    pub rate_hz: Option<f64>,
    pub flux_rate_hz: Option<f64>,
    pub gps_rate_hz: Option<f64>,
    pub flux: Option<FluxFormat>,
    /// The fluxgate calibration (`fluxcal`) the board applies (`SETFLUX`).
    pub flux_calibration: Option<FluxCalibration>,
    /// The scalar's delay τ (s) the board applies (`SETLAG`): the fluxgate is delayed.
    pub lag_s: Option<f32>,
    /// The fluxgate's temperature drift the board corrects (`fluxtemp`, `SETFTEMP`), with
    /// the temperature of each fluxgate line (4th field).
    pub flux_temp: Option<FluxTempCal>,
    /// `RAW,ON`: each scalar sample also as a `$MCRAW` line ([`replay_capture_raw`]).
    pub raw: bool,
    /// The model with the fluxgate as a witness, run beside `model` as a board built with
    /// it does (`Acquisition::attach_witness`).
    pub witness: Option<ModelSpec>,
}

impl ReplayOptions {
    pub fn new(model: ModelSpec) -> Self {
        Self {
            model,
            coefficients: None,
            rate_hz: None,
            flux_rate_hz: None,
            gps_rate_hz: None,
            flux: None,
            flux_calibration: None,
            lag_s: None,
            flux_temp: None,
            raw: false,
            witness: None,
        }
    }
}

/// What a replay read and produced.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReplayStats {
    /// The term coefficients the filter holds at the end, physical units, model order
    /// (what the board's `GETCOEF` would read then).
    pub final_coefficients: Vec<f32>,
    pub records: u64,
    pub counters: AcqCounters,
    /// Capture data lines read, and those that could not be decoded (skipped).
    pub capture_lines: u64,
    pub bad_capture_lines: u64,
    pub scalar_hz: f64,
    pub flux_hz: f64,
    pub gps_hz: f64,
    pub flux_format: Option<FluxFormat>,
    pub first_t_s: Option<f64>,
    pub last_t_s: Option<f64>,
    /// Capture lines dropped because they repeat the previous line of their port (same
    /// time stamp, same bytes): a logger never receives one chunk twice.
    pub duplicate_lines: u64,
    /// Capture lines dropped because their time stamp is earlier than one already read on
    /// the same port (bytes of one port arrive in order; e.g. a capture concatenated twice).
    pub time_reversals: u64,
    /// File line of the first of each, for the warning.
    pub first_duplicate_line: Option<u64>,
    pub first_reversal_line: Option<u64>,
}

impl ReplayStats {
    /// What was dropped, for a warning (`None` when nothing was).
    pub fn dropped_warning(&self) -> Option<String> {
        let mut parts = Vec::new();
        if let Some(l) = self.first_duplicate_line {
            parts.push(format!(
                "{} duplicated line(s) (first at line {l})",
                self.duplicate_lines
            ));
        }
        if let Some(l) = self.first_reversal_line {
            parts.push(format!(
                "{} line(s) earlier than their port's previous line (first at line {l})",
                self.time_reversals
            ));
        }
        (!parts.is_empty()).then(|| {
            format!(
                "dropped {}; the next record after each is flagged PARSE_ERROR",
                parts.join(" and ")
            )
        })
    }
}

impl fmt::Display for ReplayStats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let c = &self.counters;
        write!(
            f,
            "{} records from {} scalar lines (rates {}/{}/{} Hz, fluxgate {}); errors: scalar {}, flux {}, gps {}; \
             flux frames suspect {}; flagged: flux stale {}, no GPS {}, mag missing {}, parse error {}; {} bad capture lines; \
             dropped: {} duplicated lines, {} lines back in time",
            self.records,
            c.scalar_lines,
            self.scalar_hz,
            self.flux_hz,
            self.gps_hz,
            self.flux_format.map_or("?", |x| x.name()),
            c.scalar_errors,
            c.flux_errors,
            c.gps_errors,
            c.flux_suspect,
            c.flux_stale,
            c.no_gps,
            c.mag_missing,
            c.parse_error,
            self.bad_capture_lines,
            self.duplicate_lines,
            self.time_reversals
        )
    }
}

/// The longest capture line read: a chunk of `MAX_CHUNK` bytes in hex, its time and port
/// fit in well under this.
pub const MAX_CAPTURE_LINE: usize = 4096;

/// A coefficient file's text, refused past `MAX_COEFFICIENT_FILE_BYTES`.
fn read_coefficient_text(path: &Path) -> Result<String> {
    crate::io::bounded::read_to_string_bounded(
        path,
        crate::io::bounded::MAX_COEFFICIENT_FILE_BYTES,
        "coefficient file",
    )
}

/// Reads coefficients: a `calibrate` JSON file or plain numbers.
pub fn read_coefficients(path: &Path) -> Result<Vec<f32>> {
    read_coefficients_for(path, None)
}

/// As [`read_coefficients`]; a JSON file must also be a Kalman-filter calibration of
/// `model` (Tolles–Lawson coefficients follow other conventions than the board's filter).
pub fn read_coefficients_for(path: &Path, model: Option<&ModelSpec>) -> Result<Vec<f32>> {
    let text = read_coefficient_text(path)?;
    let ctx = || format!("coefficients in {}", path.display());
    if let (Some(spec), Ok(v)) = (model, serde_json::from_str::<serde_json::Value>(&text)) {
        if let Some(m) = v.get("method").and_then(|m| m.as_str()) {
            if m != "kf" {
                bail!(
                    "{}: method '{m}' coefficients cannot be loaded into the board's filter; calibrate with the Kalman filter",
                    path.display()
                );
            }
        }
        if let Some(m) = v.get("model").and_then(|m| m.as_str()) {
            let theirs = ModelSpec::parse(m).with_context(ctx)?;
            if theirs.text() != spec.text() {
                bail!(
                    "{} was calibrated for model '{}', the replay runs '{}' (use --model {})",
                    path.display(),
                    theirs.text(),
                    spec.text(),
                    theirs.text()
                );
            }
        }
        if let Some(arr) = v.get("coefficients").and_then(|a| a.as_array()) {
            return named_coefficients(arr, spec).with_context(ctx);
        }
    }
    parse_coefficients(&text).with_context(ctx)
}

/// A `calibrate` file's coefficients matched to `spec`'s by name, in the model's order.
fn named_coefficients(arr: &[serde_json::Value], spec: &ModelSpec) -> Result<Vec<f32>> {
    let entries = arr
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let name = c
                .get("name")
                .and_then(|n| n.as_str())
                .with_context(|| format!("coefficient {} has no \"name\"", i + 1))?;
            let value = c
                .get("value")
                .and_then(|v| v.as_f64())
                .with_context(|| format!("coefficient '{name}' has no numeric \"value\""))?;
            Ok((name, value))
        })
        .collect::<Result<Vec<_>>>()?;
    let names: Vec<String> = spec
        .coefficient_names()
        .into_iter()
        .map(|(n, _)| n)
        .collect();
    let order = crate::calibration::coefficients::order_by_name(
        entries.iter().map(|e| e.0),
        &names,
        "coefficient",
    )?;
    board_range(order.iter().map(|&i| entries[i].1).collect())
}

/// The values as the board holds them (f32), refused when one is not finite or |v| ≥ 1e6.
fn board_range(vals: Vec<f64>) -> Result<Vec<f32>> {
    if vals.iter().any(|v| !v.is_finite() || v.abs() >= 1e6) {
        bail!("a coefficient is not finite or |v| ≥ 1e6");
    }
    Ok(vals.iter().map(|v| *v as f32).collect())
}

/// The fluxgate calibration of a `calibrate --model …+fluxcal` JSON file, if it has one,
/// as the board holds it (f32, checked plausible like `SETFLUX`).
pub fn read_flux_calibration(path: &Path) -> Result<Option<FluxCalibration>> {
    let Some(cal) =
        read_member::<crate::estimate::fluxcal::FluxgateCalibration>(path, "fluxgate_calibration")?
    else {
        return Ok(None);
    };
    cal.to_board().map(Some).with_context(|| {
        format!(
            "fluxgate_calibration in {} is not a plausible one (diagonal 0.5–2, off-diagonal ±0.5, bias ±100 000 nT)",
            path.display()
        )
    })
}

/// The fluxgate temperature correction of a `calibrate --model …+fluxtemp:CH` JSON file,
/// if it has one, as the board holds it (f32, checked plausible like `SETFTEMP`).
pub fn read_flux_temperature(path: &Path) -> Result<Option<FluxTempCal>> {
    let Some(c) = read_member::<crate::model::corrections::FluxgateTemperature>(
        path,
        "fluxgate_temperature",
    )?
    else {
        return Ok(None);
    };
    board_flux_temperature(&c)
        .map(Some)
        .with_context(|| format!("fluxgate_temperature in {}", path.display()))
}

/// The host's temperature correction as the board's 7 values (`SETFTEMP`).
pub fn board_flux_temperature(
    c: &crate::model::corrections::FluxgateTemperature,
) -> Result<FluxTempCal> {
    let (b, s) = (&c.bias_nt_per_degc, &c.scale_per_degc);
    let v = [c.reference_degc, b[0], b[1], b[2], s[0], s[1], s[2]].map(|x| x as f32);
    FluxTempCal::from_array(&v).with_context(|| {
        format!("the fluxgate temperature correction {v:?} is not a plausible one (|T_ref| ≤ 200 °C, |b| ≤ 1000 nT/°C, |s| ≤ 0.01/°C)")
    })
}

/// The scalar's delay τ (s) of a `calibrate --model …+lag` JSON file, if it has one.
pub fn read_scalar_lag(path: &Path) -> Result<Option<f64>> {
    let lag = read_member::<crate::model::corrections::ScalarLag>(path, "scalar_lag")?;
    Ok(lag.map(|l| l.lag_s))
}

/// Member `key` of a `calibrate` JSON file, if the file is JSON and has it (not null);
/// a member that is there but malformed is an error naming it.
fn read_member<T: serde::de::DeserializeOwned>(path: &Path, key: &str) -> Result<Option<T>> {
    let text = read_coefficient_text(path)?;
    let Ok(v) = serde_json::from_str::<serde_json::Value>(&text) else {
        return Ok(None);
    };
    let Some(m) = v.get(key).filter(|m| !m.is_null()) else {
        return Ok(None);
    };
    serde_json::from_value(m.clone())
        .map(Some)
        .with_context(|| format!("{key} in {}", path.display()))
}

pub fn parse_coefficients(text: &str) -> Result<Vec<f32>> {
    let vals: Vec<f64> = if text.trim_start().starts_with('{') || text.trim_start().starts_with('[')
    {
        let v: serde_json::Value = serde_json::from_str(text).context("not valid JSON")?;
        let list = v.get("coefficients").unwrap_or(&v);
        let Some(arr) = list.as_array() else {
            bail!("no \"coefficients\" array");
        };
        arr.iter()
            .map(|c| {
                c.get("value")
                    .unwrap_or(c)
                    .as_f64()
                    .context("a coefficient is not a number")
            })
            .collect::<Result<_>>()?
    } else {
        text.split(|c: char| c == ',' || c.is_whitespace())
            .filter(|s| !s.is_empty())
            .map(|s| {
                s.parse::<f64>().with_context(|| {
                    format!("'{}' is not a number", crate::io::bounded::excerpt(s))
                })
            })
            .collect::<Result<_>>()?
    };
    board_range(vals)
}

/// `# key: value` metadata from the capture's leading comments.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CaptureMeta {
    pub scalar_hz: Option<f64>,
    pub flux_hz: Option<f64>,
    pub gps_hz: Option<f64>,
    pub flux_format: Option<FluxFormat>,
}

impl CaptureMeta {
    fn take(&mut self, line: &str) {
        let Some((k, v)) = line.trim_start_matches('#').split_once(':') else {
            return;
        };
        let num = v.trim().parse::<f64>().ok();
        match k.trim() {
            "scalar_hz" => self.scalar_hz = num,
            "flux_hz" => self.flux_hz = num,
            "gps_hz" => self.gps_hz = num,
            "flux_format" => self.flux_format = FluxFormat::parse(v),
            _ => {}
        }
    }
}

/// The acquisition chain a replay runs: the board's, with the host's state budget.
type ReplayAcquisition<'a> = Acquisition<'a, REPLAY_STATES, REPLAY_WINDOW>;

/// Replays a capture from `input`; every record goes to `sink` in order: the header (rates,
/// format) is read, the board's acquisition chain built and loaded (delay, coefficients),
/// then every capture line fed to it.
pub fn replay_capture<R: BufRead>(
    input: R,
    opts: &ReplayOptions,
    sink: impl FnMut(&Record) -> Result<()>,
) -> Result<ReplayStats> {
    replay_capture_raw(input, opts, sink, |_| Ok(()))
}

/// [`replay_capture`], with each `$MCRAW` sample (`opts.raw`) going to `raw_sink` as the
/// board sends it: before the record the same byte completed. A capture of a
/// multi-channel counter (`$MCMREC` records) is an error here: see [`replay_capture_any`].
pub fn replay_capture_raw<R: BufRead>(
    input: R,
    opts: &ReplayOptions,
    mut sink: impl FnMut(&Record) -> Result<()>,
    raw_sink: impl FnMut(&RawLine) -> Result<()>,
) -> Result<ReplayStats> {
    replay_capture_any(
        input,
        opts,
        |r| {
            match r {
            AcqRecord::One(r) => sink(r),
            AcqRecord::Multi(r) => bail!(
                "record {}: the capture's scalar port carries counter lines of {} magnetometers (multi-sensor records); replay them with --records",
                r.seq,
                r.channels
            ),
        }
        },
        raw_sink,
    )
}

/// [`replay_capture_raw`] for both kinds of record: `$MCREC`, and `$MCMREC` when the
/// scalar port carries multi-channel counter lines (`multi_scalar`), as the board emits
/// them.
pub fn replay_capture_any<R: BufRead>(
    input: R,
    opts: &ReplayOptions,
    sink: impl FnMut(&AcqRecord) -> Result<()>,
    raw_sink: impl FnMut(&RawLine) -> Result<()>,
) -> Result<ReplayStats> {
    let mut lines = CaptureLines {
        input,
        line: Vec::new(),
        lineno: 0,
    };
    let (meta, first_data) = read_header(&mut lines)?;
    let setup = ReplaySetup::of(opts, &meta);
    let spec = &opts.model;
    let specs: Vec<&ModelSpec> = std::iter::once(spec).chain(opts.witness.as_ref()).collect();
    with_models(&specs, |models| -> Result<ReplayStats> {
        let model = models[0];
        let comp = Compensator::<REPLAY_STATES, REPLAY_WINDOW>::new(
            model,
            compensator_config(setup.scalar_hz as f32, REPLAY_WINDOW),
        )
        .map_err(|e| crate::model::errors::cannot_build(&spec.text(), &e))?;
        // The board's delay line (a static there): 8 KiB, so on the heap here.
        let mut lag_line = Box::new(LagLine::new());
        let mut acq = Acquisition::new(setup.acq_config(opts), comp).map_err(|e| {
            anyhow::anyhow!(
                "rates {}/{}/{} Hz: {}",
                setup.scalar_hz,
                setup.flux_hz,
                setup.gps_hz,
                crate::model::errors::acquisition_error(&e)
            )
        })?;
        acq.attach_lag_line(&mut lag_line);
        if let Some(w) = models.get(1) {
            acq.attach_witness(*w)
                .map_err(|e| crate::model::errors::cannot_build(&specs[1].text(), &e))?;
        }
        load_board_state(&mut acq, opts, &setup, model.coefficient_count())?;
        acq.set_raw_output(opts.raw);
        let mut stats = ReplayStats {
            scalar_hz: setup.scalar_hz,
            flux_hz: setup.flux_hz,
            gps_hz: setup.gps_hz,
            flux_format: Some(setup.flux_format),
            ..Default::default()
        };
        let mut out = Emitter {
            sink,
            raw_sink,
            dropped: false,
        };
        feed(
            &mut acq,
            &mut lines,
            first_data,
            setup.flux_format,
            &mut stats,
            &mut out,
        )?;
        while let Some(r) = acq.flush_any() {
            out.emit(r, &mut stats)?;
        }
        stats.counters = acq.counters();
        let most = models.iter().map(|m| m.coefficient_count()).max();
        let mut held = vec![0.0f32; most.unwrap_or(0)];
        let n = acq.coefficients(&mut held);
        held.truncate(n);
        stats.final_coefficients = held;
        Ok(stats)
    })
}

/// A capture's lines, numbered from 1, each read with the board's line bound.
struct CaptureLines<R> {
    input: R,
    line: Vec<u8>,
    lineno: u64,
}

impl<R: BufRead> CaptureLines<R> {
    /// The next line, `None` at the end.
    fn next_line(&mut self) -> Result<Option<Vec<u8>>> {
        self.line.clear();
        if read_line_bounded(&mut self.input, &mut self.line, MAX_CAPTURE_LINE)
            .with_context(|| format!("line {}", self.lineno + 1))?
            == 0
        {
            return Ok(None);
        }
        self.lineno += 1;
        Ok(Some(std::mem::take(&mut self.line)))
    }
}

/// The leading comments (they carry the rates the capture was made with) up to the first
/// data line, which is returned. A file without the `# magcomp-capture` header is taken for
/// a capture only when its first data line is one.
fn read_header<R: BufRead>(lines: &mut CaptureLines<R>) -> Result<(CaptureMeta, Option<Vec<u8>>)> {
    let mut meta = CaptureMeta::default();
    let mut header = false;
    let first_data = loop {
        let Some(mut line) = lines.next_line()? else {
            break None;
        };
        // A UTF-8 byte-order mark (editors on Windows add one) is not part of the header.
        if lines.lineno == 1 && line.starts_with(b"\xEF\xBB\xBF") {
            line.drain(..3);
        }
        if line.first() == Some(&b'#') {
            if decode_line(&line, &mut []).is_err() {
                bail!("line {}: unsupported capture version", lines.lineno);
            }
            header |= line.starts_with(b"# magcomp-capture ");
            meta.take(&String::from_utf8_lossy(&line));
            continue;
        }
        if line.iter().all(u8::is_ascii_whitespace) {
            continue;
        }
        break Some(line);
    };
    // Random bytes, a program or a CSV replayed to an empty output with exit 0 before.
    if !header {
        let lineno = lines.lineno;
        let mut scratch = [0u8; MAX_CHUNK];
        match &first_data {
            None => bail!("not a magcomp capture: no `# magcomp-capture v1` header and no capture line (the file is empty)"),
            Some(l) if !matches!(decode_line(l, &mut scratch), Ok(Some(_))) => bail!(
                "not a magcomp capture: no `# magcomp-capture v1` header, and line {lineno} is not a capture line (`T_US PORT HEX`): \"{}\"",
                crate::io::bounded::excerpt(&String::from_utf8_lossy(l))
            ),
            Some(_) => {}
        }
    }
    Ok((meta, first_data))
}

/// The rates and fluxgate format a replay runs at: the options', else the capture
/// header's, else the board's.
struct ReplaySetup {
    scalar_hz: f64,
    flux_hz: f64,
    gps_hz: f64,
    flux_format: FluxFormat,
}

impl ReplaySetup {
    fn of(opts: &ReplayOptions, meta: &CaptureMeta) -> Self {
        let (d_scalar, d_flux, d_gps) = BOARD_RATES_HZ;
        ReplaySetup {
            scalar_hz: opts.rate_hz.or(meta.scalar_hz).unwrap_or(d_scalar),
            flux_hz: opts.flux_rate_hz.or(meta.flux_hz).unwrap_or(d_flux),
            gps_hz: opts.gps_rate_hz.or(meta.gps_hz).unwrap_or(d_gps),
            flux_format: opts.flux.or(meta.flux_format).unwrap_or(FluxFormat::Ascii),
        }
    }

    /// The acquisition's configuration, with the fluxgate corrections the options load.
    fn acq_config(&self, opts: &ReplayOptions) -> AcqConfig {
        let mut cfg = AcqConfig::new(self.scalar_hz, self.flux_hz, self.gps_hz);
        if let Some(c) = opts.flux_calibration {
            cfg.flux_scalar_cal = c;
        }
        if let Some(c) = opts.flux_temp {
            cfg.flux_temp_cal = c;
        }
        cfg
    }
}

/// Loads what an upload would: the scalar's delay τ and the coefficients (`n_coefficients`
/// is what the model has).
fn load_board_state(
    acq: &mut ReplayAcquisition<'_>,
    opts: &ReplayOptions,
    setup: &ReplaySetup,
    n_coefficients: usize,
) -> Result<()> {
    if let Some(l) = opts.lag_s {
        acq.set_lag_s(l).map_err(|_| {
            anyhow::anyhow!(
                "the board cannot delay the fluxgate by τ = {l} s: 0 – {MAX_LAG_S} s, at most {} frames at {} Hz",
                LAG_FRAMES - 2,
                setup.flux_hz
            )
        })?;
    }
    if let Some(c) = &opts.coefficients {
        acq.set_coefficients(c).map_err(|_| {
            anyhow::anyhow!(
                "{} coefficients do not fit model '{}' ({} coefficients)",
                c.len(),
                opts.model.text(),
                n_coefficients
            )
        })?;
    }
    Ok(())
}

/// Where records go: counted, the one after a dropped line flagged PARSE_ERROR, then to
/// the sink.
struct Emitter<F, G> {
    sink: F,
    raw_sink: G,
    /// Set when a line was dropped: the next record carries PARSE_ERROR.
    dropped: bool,
}

impl<F: FnMut(&AcqRecord) -> Result<()>, G: FnMut(&RawLine) -> Result<()>> Emitter<F, G> {
    fn emit(&mut self, mut r: AcqRecord, stats: &mut ReplayStats) -> Result<()> {
        let dropped = std::mem::take(&mut self.dropped);
        let t_s = match &mut r {
            AcqRecord::One(r) => {
                if dropped {
                    r.flags.set(Flags::PARSE_ERROR);
                }
                r.t_s
            }
            AcqRecord::Multi(r) => {
                if dropped {
                    r.ch.iter_mut()
                        .for_each(|c| c.flags.set(Flags::PARSE_ERROR));
                }
                r.t_s
            }
        };
        stats.records += 1;
        stats.first_t_s.get_or_insert(t_s);
        stats.last_t_s = Some(t_s);
        (self.sink)(&r)
    }
}

/// Per port: the latest time stamp read and that line's bytes.
#[derive(Default)]
struct PortHistory {
    last: [(Option<u64>, Vec<u8>); Port::ALL.len()],
}

impl PortHistory {
    /// Whether a line is new on its port: one back in time, or a repeat of the port's
    /// previous line (same time stamp, same bytes), is counted in `stats` and refused.
    fn admit(
        &mut self,
        port: Port,
        t_us: u64,
        bytes: &[u8],
        lineno: u64,
        stats: &mut ReplayStats,
    ) -> bool {
        let (last_t, last_bytes) = &mut self.last[port as usize];
        match *last_t {
            Some(t) if t_us < t => {
                stats.time_reversals += 1;
                stats.first_reversal_line.get_or_insert(lineno);
                false
            }
            Some(t) if t_us == t && last_bytes.as_slice() == bytes => {
                stats.duplicate_lines += 1;
                stats.first_duplicate_line.get_or_insert(lineno);
                false
            }
            _ => {
                *last_t = Some(t_us);
                last_bytes.clear();
                last_bytes.extend_from_slice(bytes);
                true
            }
        }
    }
}

/// Feeds every capture line from `first` on to the acquisition chain, emitting its records.
fn feed<R: BufRead, F: FnMut(&AcqRecord) -> Result<()>, G: FnMut(&RawLine) -> Result<()>>(
    acq: &mut ReplayAcquisition<'_>,
    lines: &mut CaptureLines<R>,
    first: Option<Vec<u8>>,
    flux_format: FluxFormat,
    stats: &mut ReplayStats,
    out: &mut Emitter<F, G>,
) -> Result<()> {
    let mut data = [0u8; MAX_CHUNK];
    let mut history = PortHistory::default();
    let mut pending = first;
    loop {
        let l = match pending.take() {
            Some(l) => l,
            None => match lines.next_line()? {
                Some(l) => l,
                None => break,
            },
        };
        let c = match decode_line(&l, &mut data) {
            Ok(Some(c)) => c,
            Ok(None) => continue,
            Err(_) => {
                stats.bad_capture_lines += 1;
                continue;
            }
        };
        stats.capture_lines += 1;
        let bytes = &data[..c.len];
        if !history.admit(c.port, c.t_us, bytes, lines.lineno, stats) {
            out.dropped = true;
            continue;
        }
        if c.port == Port::Flux && flux_format == FluxFormat::Spi {
            acq.push_flux_frame(bytes);
            continue;
        }
        for &b in bytes {
            let mut record = acq.push_byte_any(c.port, b);
            loop {
                if let Some(raw) = acq.take_raw() {
                    (out.raw_sink)(&raw)?;
                }
                if let Some(r) = record {
                    out.emit(r, stats)?;
                }
                // a line that ran into the next: its further samples, as the board's UART
                // task hands them on
                let Some(l) = acq.owed_scalar_line() else {
                    break;
                };
                record = acq.scalar_line(l);
            }
        }
    }
    Ok(())
}

/// `12.3456` from counts, exactly; empty when missing.
pub fn counts_text(c: Option<MagCounts>) -> String {
    match c {
        Some(c) => {
            let sign = if c.0 < 0 { "-" } else { "" };
            let a = c.0.unsigned_abs();
            format!("{sign}{}.{:04}", a / 10_000, a % 10_000)
        }
        None => String::new(),
    }
}

/// 4 decimals, empty when not finite.
pub fn nt_text(v: f32) -> String {
    if v.is_finite() {
        format!("{v:.4}")
    } else {
        String::new()
    }
}

/// One CSV row (flags as a decimal integer, like the HIL harness reads them).
pub fn csv_row(r: &Record) -> String {
    format!(
        "{},{:.6},{},{},{},{},{},{},{}",
        r.seq,
        r.t_s,
        counts_text(r.mag),
        nt_text(r.interference_nt),
        counts_text(r.compensated),
        nt_text(r.anomaly_nt),
        nt_text(r.innovation_nt),
        nt_text(r.sigma_nt),
        r.flags.0
    )
}

/// `replay -o` header of records of `n` magnetometers (`$MCMREC`): `seq,t`, per channel
/// `mag_K,interference_mag_K,compensated_mag_K,sigma_mag_K,flags_mag_K`, then per pair of
/// the record (2−1, 3−1, 3−2) `difference_mag_A_mag_B` = compensated B − compensated A.
pub fn multi_csv_header(n: usize) -> String {
    use magcomp_core::protocol::multi_record::{pair_count, PAIRS};
    let mut h = String::from("seq,t");
    for k in 1..=n {
        for what in ["", "interference_", "compensated_", "sigma_", "flags_"] {
            h.push_str(&format!(",{what}mag_{k}"));
        }
    }
    for (a, b) in &PAIRS[..pair_count(n)] {
        h.push_str(&format!(",difference_mag_{}_mag_{}", a + 1, b + 1));
    }
    h
}

/// One row of [`multi_csv_header`]'s columns: the record's values exactly as its line
/// carries them (an empty field where the line's is).
pub fn multi_csv_row(r: &magcomp_core::protocol::multi_record::MultiRecord) -> String {
    use magcomp_core::protocol::multi_record::pair_count;
    let n = usize::from(r.channels).min(r.ch.len());
    let mut row = format!("{},{:.6}", r.seq, r.t_s);
    for c in &r.ch[..n] {
        row.push_str(&format!(
            ",{},{},{},{},{}",
            counts_text(c.mag),
            nt_text(c.interference_nt),
            counts_text(c.compensated),
            nt_text(c.sigma_nt),
            c.flags.0
        ));
    }
    for d in &r.diff[..pair_count(n)] {
        row.push(',');
        row.push_str(&counts_text(*d));
    }
    row
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coefficient_files() {
        assert_eq!(
            parse_coefficients("1, 2.5\n-3").unwrap(),
            vec![1.0, 2.5, -3.0]
        );
        let j = r#"{"format":"magcomp-coefficients-v1","coefficients":[{"name":"a","value":0.5},{"value":-2}]}"#;
        assert_eq!(parse_coefficients(j).unwrap(), vec![0.5, -2.0]);
        assert!(parse_coefficients("1, x").is_err());
        assert!(parse_coefficients("1e7").is_err());
        assert!(parse_coefficients("{\"c\": 1}").is_err());
    }

    #[test]
    fn meta_comments() {
        let mut m = CaptureMeta::default();
        for l in [
            "# scalar_hz: 20",
            "# gps_hz: 5",
            "# flux_format: spi",
            "# other: x",
        ] {
            m.take(l);
        }
        assert_eq!(m.scalar_hz, Some(20.0));
        assert_eq!(m.gps_hz, Some(5.0));
        assert_eq!(m.flux_hz, None);
        assert_eq!(m.flux_format, Some(FluxFormat::Spi));
    }
}
