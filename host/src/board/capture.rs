//! A flight (simulated, or any trace the host reads: `magcomp capture`) written as a raw
//! capture: the bytes the sensors would have sent, timestamped per port
//! (`docs/protocols.md` §7), for `magcomp replay` and the HIL harness.
//!
//! Per scalar sample `k` at trace time `t_k` (board clock `T = start + t_k`):
//! - fluxgate at `T`: an ASCII line `X,Y,Z*hh` (nT, 3 decimals, XOR checksum) or a 15-byte
//!   ADS131M03 SPI frame (±100 000 nT over ±2^23 codes, identity axes);
//! - GPS at its own epochs (5 or 10 Hz from `t = 0`, positions interpolated between
//!   samples), starting 100 µs after the epoch: `$GNGGA`, `$GNRMC`, `$GNVTG`, each chunk
//!   timed at the receiver's baud rate;
//!   none when the trace has no `lat`/`lon`/`alt` (a real calibration box);
//! - scalar at `T + P/2`: the field with 4 decimals, exactly the trace's value rounded to
//!   1e-4 nT (the same rounding `Flight` applies), `53620.4401\r\n`.
//!
//! So the fluxgate and GPS of an epoch precede its scalar line, as on the board (at 10 Hz
//! and 115 200 Bd the three sentences take ~19 ms of the 50 ms before the scalar).
//! Chunks are sorted by time; equal times keep flux → GPS → scalar order.
//!
//! Faults: a fluxgate dropout window (no frames), a GPS outage window (the receiver keeps
//! talking but reports no fix: GGA quality 0, RMC `V`, VTG mode `N`), and a seeded fraction
//! of corrupted bytes. Corruption keeps line framing (CR/LF are never corrupted and no byte
//! becomes one) so every scalar line stays one sample: a realistic UART bit error that
//! merges two lines would lose a sample on any receiver, and the HIL test counts samples.

use crate::flight::col;
use crate::io::trace::Trace;
use anyhow::{bail, ensure, Context, Result};
use magcomp_core::acquisition::FLUX_FULL_SCALE_NT;
use magcomp_core::epoch::EARTH_RADIUS_M;
use magcomp_core::protocol::capture::{encode_header, encode_line, Port, MAX_CHUNK, MAX_LINE};
use magcomp_core::protocol::common::xor_checksum;
use magcomp_core::protocol::fluxgate::{encode_spi_frame, ADC_FULL_SCALE};
use magcomp_core::MagCounts;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::io::Write;
use std::path::Path;

const KNOT_MPS: f64 = 1852.0 / 3600.0;
/// ADS131M03 status word with all three DRDY bits set.
const SPI_STATUS: u16 = 0x0007;
/// Delay of the first GPS byte after its epoch (µs).
const GPS_DELAY_US: u64 = 100;

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FluxFormat {
    /// Serial ASCII lines `X,Y,Z*hh`.
    #[default]
    Ascii,
    /// 15-byte ADS131M03 SPI frames (one capture line each).
    Spi,
}

impl FluxFormat {
    pub fn name(self) -> &'static str {
        match self {
            FluxFormat::Ascii => "ascii",
            FluxFormat::Spi => "spi",
        }
    }
    pub fn parse(s: &str) -> Option<Self> {
        match s.trim() {
            "ascii" => Some(FluxFormat::Ascii),
            "spi" => Some(FluxFormat::Spi),
            _ => None,
        }
    }
}

/// How to turn a trace into sensor bytes.
#[derive(Clone, Debug, PartialEq)]
pub struct CaptureOptions {
    pub flux_format: FluxFormat,
    /// GPS epoch rate (Hz), 1–20.
    pub gps_rate_hz: f64,
    /// GPS baud rate: spacing of the sentences' timestamps.
    pub gps_baud: u32,
    /// UTC time of day at trace `t = 0` (s); wraps at midnight.
    pub start_tod_s: f64,
    /// RMC date `(day, month, year)`.
    pub date: (u8, u8, u16),
    /// Board clock at trace `t = 0` (µs).
    pub start_us: u64,
    /// Trace-time window `[start, end)` (s) without fluxgate frames.
    pub flux_dropout_s: Option<(f64, f64)>,
    /// Trace-time window `[start, end)` (s) in which the receiver reports no fix.
    pub gps_outage_s: Option<(f64, f64)>,
    /// Fraction of bytes replaced by random bytes (0 ≤ f ≤ 0.5), all ports.
    pub corrupt_fraction: f64,
    /// Corrupt only this port's bytes (None: every port). The scalar port is the one
    /// without a checksum, so its corruption reaches the filter as wrong values.
    pub corrupt_port: Option<Port>,
    /// The trace column written as the fluxgate line's 4th field, the sensor's
    /// temperature (°C, `X,Y,Z,T*hh`). None: the simulator's `fluxtemp:CH` channel when
    /// the trace has one (`truth_hidden_fluxtemp_CH`), else 3 fields. ASCII only.
    pub flux_temp_channel: Option<String>,
    pub seed: u64,
    /// What made the capture, for its `# source:` comment.
    pub source: String,
}

impl Default for CaptureOptions {
    fn default() -> Self {
        Self {
            flux_format: FluxFormat::Ascii,
            gps_rate_hz: 5.0,
            gps_baud: 115_200,
            start_tod_s: 12.0 * 3600.0,
            date: (21, 11, 2026),
            start_us: 1_000_000,
            flux_dropout_s: None,
            gps_outage_s: None,
            corrupt_fraction: 0.0,
            corrupt_port: None,
            flux_temp_channel: None,
            seed: 1,
            source: "magcomp simulate".into(),
        }
    }
}

impl CaptureOptions {
    pub fn validate(&self) -> Result<()> {
        ensure!(
            self.gps_rate_hz.is_finite() && (1.0..=20.0).contains(&self.gps_rate_hz),
            "GPS rate {} Hz is outside 1–20 Hz",
            self.gps_rate_hz
        );
        ensure!(
            (1200..=4_000_000).contains(&self.gps_baud),
            "GPS baud {}",
            self.gps_baud
        );
        ensure!(
            self.start_tod_s.is_finite() && (0.0..86_400.0).contains(&self.start_tod_s),
            "start time of day {} s is outside 0–86400",
            self.start_tod_s
        );
        ensure!(
            self.corrupt_fraction.is_finite() && (0.0..=0.5).contains(&self.corrupt_fraction),
            "corrupt fraction {} is outside 0–0.5",
            self.corrupt_fraction
        );
        for (w, what) in [
            (self.flux_dropout_s, "fluxgate dropout"),
            (self.gps_outage_s, "GPS outage"),
        ] {
            if let Some((a, b)) = w {
                ensure!(
                    a.is_finite() && b.is_finite() && a < b,
                    "{what} window {a}:{b} is empty or not finite"
                );
            }
        }
        Ok(())
    }
}

/// What a capture contains (also written as `# key: value` comments in its header).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CaptureSummary {
    pub scalar_hz: f64,
    pub flux_hz: f64,
    pub gps_hz: f64,
    pub scalar_lines: usize,
    pub flux_frames: usize,
    pub gps_sentences: usize,
    pub corrupted_bytes: usize,
    pub total_bytes: usize,
}

fn within(w: Option<(f64, f64)>, t: f64) -> bool {
    w.is_some_and(|(a, b)| t >= a && t < b)
}

/// `$<body>*hh\r\n`
fn nmea(body: &str) -> Vec<u8> {
    format!("${body}*{:02X}\r\n", xor_checksum(body.as_bytes())).into_bytes()
}

/// `hhmmss.ss` (centiseconds, wrapped at midnight).
fn hms(tod_s: f64) -> String {
    let cs = (tod_s * 100.0).round() as u64 % 8_640_000;
    let s = cs / 100;
    format!(
        "{:02}{:02}{:02}.{:02}",
        s / 3600,
        s / 60 % 60,
        s % 60,
        cs % 100
    )
}

/// `[d]ddmm.mmmmm,H`: 5 decimals of minutes (1.9 cm), rounded once on the integer.
fn coord(v: f64, is_lat: bool) -> String {
    let hemi = match (is_lat, v < 0.0) {
        (true, false) => 'N',
        (true, true) => 'S',
        (false, false) => 'E',
        (false, true) => 'W',
    };
    let total = (v.abs() * 60.0 * 1e5).round() as u64;
    let deg = total / 6_000_000;
    let min = total % 6_000_000;
    let w = if is_lat { 2 } else { 3 };
    format!(
        "{deg:0w$}{:02}.{:05},{hemi}",
        min / 100_000,
        min % 100_000,
        w = w
    )
}

struct GpsState {
    lat: f64,
    lon: f64,
    alt: f64,
    vn: f64,
    ve: f64,
}

fn gps_sentences(tod_s: f64, g: Option<&GpsState>, date: (u8, u8, u16)) -> Vec<Vec<u8>> {
    let t = hms(tod_s);
    let d = format!("{:02}{:02}{:02}", date.0, date.1, date.2 % 100);
    match g {
        Some(g) => {
            let speed_kn = g.vn.hypot(g.ve) / KNOT_MPS;
            let track = g.ve.atan2(g.vn).to_degrees().rem_euclid(360.0);
            let (lat, lon) = (coord(g.lat, true), coord(g.lon, false));
            vec![
                nmea(&format!(
                    "GNGGA,{t},{lat},{lon},1,12,0.8,{:.2},M,-34.00,M,,",
                    g.alt
                )),
                nmea(&format!(
                    "GNRMC,{t},A,{lat},{lon},{speed_kn:.3},{track:.2},{d},,,A"
                )),
                nmea(&format!(
                    "GNVTG,{track:.2},T,,M,{speed_kn:.3},N,{:.3},K,A",
                    speed_kn * KNOT_MPS * 3.6
                )),
            ]
        }
        None => vec![
            nmea(&format!("GNGGA,{t},,,,,0,00,99.99,,,,,,")),
            nmea(&format!("GNRMC,{t},V,,,,,,,{d},,,N")),
            nmea("GNVTG,,T,,M,,N,,K,N"),
        ],
    }
}

/// Linear interpolation of column `v` at fractional index `x`.
fn lerp(v: &[f64], x: f64) -> f64 {
    let i = (x.floor() as usize).min(v.len().saturating_sub(1));
    let j = (i + 1).min(v.len() - 1);
    let w = x - i as f64;
    v[i] + w * (v[j] - v[i])
}

/// The capture as bytes (header, `# key: value` comments, one line per chunk).
pub fn trace_to_capture(trace: &Trace, opts: &CaptureOptions) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    write_capture(trace, opts, &mut out)?;
    Ok(out)
}

/// Writes a capture file.
pub fn write_capture_file(
    trace: &Trace,
    opts: &CaptureOptions,
    path: &Path,
) -> Result<CaptureSummary> {
    crate::io::output::write_with(path, |w| write_capture(trace, opts, w))
}

/// Writes the capture of `trace` to `w`: the trace's columns are read and checked, the
/// sensors' chunks (fluxgate, scalar, GPS epochs) made and time-ordered, corrupted when
/// asked, then written after the header.
pub fn write_capture<W: Write>(
    trace: &Trace,
    opts: &CaptureOptions,
    w: &mut W,
) -> Result<CaptureSummary> {
    opts.validate()?;
    let inp = CaptureInput::read(trace, opts)?;
    let mut summary = CaptureSummary {
        scalar_hz: inp.scalar_hz,
        flux_hz: inp.scalar_hz,
        gps_hz: if inp.pos.is_some() {
            opts.gps_rate_hz
        } else {
            0.0
        },
        ..Default::default()
    };
    let mut chunks: Vec<Chunk> = Vec::with_capacity(3 * inp.t.len());
    sensor_chunks(&inp, opts, &mut chunks, &mut summary);
    gps_chunks(&inp, opts, &mut chunks, &mut summary);
    chunks.sort_by_key(|c| (c.0, c.1));
    if opts.corrupt_fraction > 0.0 {
        corrupt(&mut chunks, opts, &mut summary);
    }

    let mut line = vec![0u8; MAX_LINE];
    let hl = encode_header(&mut line).context("capture header")?;
    w.write_all(&line[..hl])?;
    write_header_comments(w, opts, inp.scalar_hz, inp.pos.is_some())?;
    for (t_us, _, port, bytes) in &chunks {
        summary.total_bytes += bytes.len();
        for part in bytes.chunks(MAX_CHUNK) {
            let l = encode_line(*t_us, *port, part, &mut line).context("capture line")?;
            w.write_all(&line[..l])?;
        }
    }
    Ok(summary)
}

/// One chunk of a capture: (t_us, order within equal times, port, bytes).
type Chunk = (u64, u8, Port, Vec<u8>);

/// The trace's columns a capture is made from, checked, with the rate and velocity.
struct CaptureInput<'a> {
    t: &'a [f64],
    mag: &'a [f64],
    flux: [&'a [f64]; 3],
    /// The fluxgate temperature channel, if any.
    temp: Option<&'a [f64]>,
    /// lat, lon, alt; `None` for a trace without positions (a real calibration box), which
    /// gets no GPS port at all rather than invented fixes: the board flags NO_GPS, which
    /// survey mode does not need.
    pos: Option<(&'a [f64], &'a [f64], &'a [f64])>,
    /// North and east velocity: the trace's, else from position differences.
    vn: Vec<f64>,
    ve: Vec<f64>,
    /// Median sample period (s) and the scalar rate it gives (Hz, rounded to µHz).
    period_s: f64,
    scalar_hz: f64,
    start_us: u64,
}

impl<'a> CaptureInput<'a> {
    fn read(trace: &'a Trace, opts: &CaptureOptions) -> Result<Self> {
        let t = col(trace, "t")?;
        let mag = col(trace, "mag")?;
        let flux = [
            col(trace, "flux_x")?,
            col(trace, "flux_y")?,
            col(trace, "flux_z")?,
        ];
        let temp_channel = opts.flux_temp_channel.clone().or_else(|| {
            trace.numeric.iter().find_map(|(name, _)| {
                let ch = name.strip_prefix("truth_hidden_fluxtemp_")?;
                trace.col(ch).map(|_| ch.to_string())
            })
        });
        let temp = temp_channel.as_deref().map(|c| col(trace, c)).transpose()?;
        let pos = match (trace.col("lat"), trace.col("lon"), trace.col("alt")) {
            (Some(a), Some(b), Some(c)) => Some((a, b, c)),
            _ => None,
        };
        let n = t.len();
        ensure!(n >= 2, "the trace has {n} rows; a capture needs at least 2");
        for i in 1..n {
            // Also rejects NaN times.
            if t[i].partial_cmp(&t[i - 1]) != Some(std::cmp::Ordering::Greater) {
                bail!("time is not strictly increasing at data row {}", i + 1);
            }
        }
        let mut dts: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
        dts.sort_by(|a, b| a.total_cmp(b));
        let period_s = dts[dts.len() / 2];
        // Rounded to µHz: 1/0.1 in f64 is 10.000000000000036.
        let scalar_hz = (1e6 / period_s).round() / 1e6;
        let (vn, ve) = velocity_ne(trace, t, pos);
        Ok(CaptureInput {
            t,
            mag,
            flux,
            temp,
            pos,
            vn,
            ve,
            period_s,
            scalar_hz,
            start_us: opts.start_us,
        })
    }

    /// The capture time (µs) of trace time `ts`.
    fn us(&self, ts: f64) -> u64 {
        self.start_us + ((ts - self.t[0]) * 1e6).round().max(0.0) as u64
    }
}

/// North and east velocity: the trace's `vn`/`ve`, else central differences of the
/// positions, else none.
fn velocity_ne(
    trace: &Trace,
    t: &[f64],
    pos: Option<(&[f64], &[f64], &[f64])>,
) -> (Vec<f64>, Vec<f64>) {
    let n = t.len();
    match (trace.col("vn"), trace.col("ve"), pos) {
        (Some(a), Some(b), _) => (a.to_vec(), b.to_vec()),
        (_, _, None) => (Vec::new(), Vec::new()),
        (_, _, Some((lat, lon, _))) => {
            let mut vn = vec![0.0; n];
            let mut ve = vec![0.0; n];
            for i in 0..n {
                let (a, b) = (i.saturating_sub(1), (i + 1).min(n - 1));
                let dt = t[b] - t[a];
                vn[i] = (lat[b] - lat[a]).to_radians() * EARTH_RADIUS_M / dt;
                ve[i] = (lon[b] - lon[a]).to_radians() * EARTH_RADIUS_M * lat[i].to_radians().cos()
                    / dt;
            }
            (vn, ve)
        }
    }
}

/// Per sample: the fluxgate frame (outside a dropout, when all three axes are there) and,
/// half a period later, the scalar's line (none for a missing value: the sensor sent
/// nothing).
fn sensor_chunks(
    inp: &CaptureInput<'_>,
    opts: &CaptureOptions,
    chunks: &mut Vec<Chunk>,
    summary: &mut CaptureSummary,
) {
    let t = inp.t;
    let t0 = t[0];
    let [fx, fy, fz] = inp.flux;
    let half_period_us = (inp.period_s * 0.5e6).round() as u64;
    for k in 0..t.len() {
        let tk = t[k] - t0;
        if !within(opts.flux_dropout_s, tk) {
            let f = [fx[k], fy[k], fz[k]];
            if f.iter().all(|v| v.is_finite()) {
                let temp = inp.temp.map(|c| c[k]);
                chunks.push((inp.us(t[k]), 0, Port::Flux, flux_bytes(f, temp, opts)));
                summary.flux_frames += 1;
            }
        }
        if let Some(m) = MagCounts::from_nt_f64(inp.mag[k]) {
            let a = m.0.unsigned_abs();
            let sign = if m.0 < 0 { "-" } else { "" };
            let line = format!("{sign}{}.{:04}\r\n", a / 10_000, a % 10_000);
            chunks.push((
                inp.us(t[k]) + half_period_us,
                2,
                Port::Scalar,
                line.into_bytes(),
            ));
            summary.scalar_lines += 1;
        }
    }
}

/// One fluxgate frame in the capture's format: an ASCII line `X,Y,Z[,T]*hh` or an SPI
/// frame.
fn flux_bytes(f: [f64; 3], temp: Option<f64>, opts: &CaptureOptions) -> Vec<u8> {
    match opts.flux_format {
        FluxFormat::Ascii => {
            let mut body = format!("{:.3},{:.3},{:.3}", f[0], f[1], f[2]);
            // A missing temperature is a 3-field line (T = NaN on the board).
            if let Some(t) = temp.filter(|t| t.is_finite()) {
                body.push_str(&format!(",{t:.4}"));
            }
            format!("{body}*{:02X}\r\n", xor_checksum(body.as_bytes())).into_bytes()
        }
        FluxFormat::Spi => {
            let lsb_nt = FLUX_FULL_SCALE_NT as f64 / ADC_FULL_SCALE as f64;
            encode_spi_frame(SPI_STATUS, f.map(|v| (v / lsb_nt).round() as i32)).to_vec()
        }
    }
}

/// GPS epochs on the receiver's own grid, interpolated from the samples, each epoch's
/// sentences spaced by their transmission time.
fn gps_chunks(
    inp: &CaptureInput<'_>,
    opts: &CaptureOptions,
    chunks: &mut Vec<Chunk>,
    summary: &mut CaptureSummary,
) {
    let Some((lat, lon, alt)) = inp.pos else {
        return;
    };
    let t = inp.t;
    let n = t.len();
    let t0 = t[0];
    let span_s = t[n - 1] - t0;
    let byte_us = 10.0e6 / opts.gps_baud as f64;
    let mut j = 0u64;
    loop {
        let tg = j as f64 / opts.gps_rate_hz;
        if tg > span_s + 1e-9 {
            break;
        }
        j += 1;
        // Fractional sample index of the epoch (samples may be unevenly spaced).
        let hi = t.partition_point(|&x| x - t0 <= tg).clamp(1, n - 1);
        let lo = hi - 1;
        let x = lo as f64 + ((tg - (t[lo] - t0)) / (t[hi] - t[lo])).clamp(0.0, 1.0);
        let g = GpsState {
            lat: lerp(lat, x),
            lon: lerp(lon, x),
            alt: lerp(alt, x),
            vn: lerp(&inp.vn, x),
            ve: lerp(&inp.ve, x),
        };
        let ok = !within(opts.gps_outage_s, tg)
            && [g.lat, g.lon, g.alt, g.vn, g.ve]
                .iter()
                .all(|v| v.is_finite());
        let tod = (opts.start_tod_s + tg).rem_euclid(86_400.0);
        let mut at = inp.us(t0 + tg) as f64 + GPS_DELAY_US as f64;
        for s in gps_sentences(tod, ok.then_some(&g), opts.date) {
            let len = s.len();
            chunks.push((at.round() as u64, 1, Port::Gps, s));
            at += len as f64 * byte_us;
            summary.gps_sentences += 1;
        }
    }
}

/// Corrupts `opts.corrupt_fraction` of the bytes (of one port, or all), line ends kept.
fn corrupt(chunks: &mut [Chunk], opts: &CaptureOptions, summary: &mut CaptureSummary) {
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    for (_, _, port, bytes) in chunks.iter_mut() {
        if opts.corrupt_port.is_some_and(|p| p != *port) {
            continue;
        }
        for b in bytes.iter_mut() {
            if *b == b'\r' || *b == b'\n' || !rng.gen_bool(opts.corrupt_fraction) {
                continue;
            }
            // A different byte that is not a line end.
            let v = loop {
                let v: u8 = rng.gen();
                if v != *b && v != b'\r' && v != b'\n' {
                    break v;
                }
            };
            *b = v;
            summary.corrupted_bytes += 1;
        }
    }
}

/// The `# key: value` comments after the header line: source, rates, format, and the
/// faults the capture was made with.
fn write_header_comments<W: Write>(
    w: &mut W,
    opts: &CaptureOptions,
    scalar_hz: f64,
    has_gps: bool,
) -> Result<()> {
    writeln!(w, "# source: {}", opts.source)?;
    writeln!(w, "# scalar_hz: {scalar_hz}")?;
    writeln!(w, "# flux_hz: {scalar_hz}")?;
    // Kept without positions too: replay takes its staleness limit from it.
    writeln!(w, "# gps_hz: {}", opts.gps_rate_hz)?;
    if !has_gps {
        writeln!(w, "# gps: none (the trace has no lat/lon/alt)")?;
    }
    writeln!(w, "# flux_format: {}", opts.flux_format.name())?;
    writeln!(w, "# start_tod_s: {}", opts.start_tod_s)?;
    if let Some((a, b)) = opts.flux_dropout_s {
        writeln!(w, "# flux_dropout_s: {a}:{b}")?;
    }
    if let Some((a, b)) = opts.gps_outage_s {
        writeln!(w, "# gps_outage_s: {a}:{b}")?;
    }
    if opts.corrupt_fraction > 0.0 {
        writeln!(
            w,
            "# corrupt_fraction: {} (seed {})",
            opts.corrupt_fraction, opts.seed
        )?;
    }
    Ok(())
}

/// `HH:MM:SS[.s]` → seconds of day.
pub fn parse_time_of_day(s: &str) -> Result<f64> {
    let p: Vec<&str> = s.trim().split(':').collect();
    let bad = || anyhow::anyhow!("time of day '{s}' is not HH:MM:SS");
    if p.len() != 3 {
        return Err(bad());
    }
    let h: u32 = p[0].parse().map_err(|_| bad())?;
    let m: u32 = p[1].parse().map_err(|_| bad())?;
    let sec: f64 = p[2].parse().map_err(|_| bad())?;
    ensure!(h < 24 && m < 60 && (0.0..60.0).contains(&sec), bad());
    Ok(f64::from(h * 3600 + m * 60) + sec)
}

/// A trace without positions (a real calibration box) given a dead-reckoned track: due north
/// from `start_deg` (lat, lon) at `speed_mps` and `alt_m`, as the host's `--speed-mps`
/// assumes for it. The board then sees that ground speed in the NMEA; the positions are
/// invented, which `magcomp capture` says. No change to a trace that has positions.
pub fn with_dead_reckoned_track(
    trace: &mut Trace,
    speed_mps: f64,
    start_deg: (f64, f64),
    alt_m: f64,
) -> Result<bool> {
    if trace.col("lat").is_some() && trace.col("lon").is_some() {
        return Ok(false);
    }
    ensure!(
        speed_mps.is_finite() && speed_mps > 0.0 && speed_mps < 400.0,
        "--speed-mps {speed_mps} is not an aircraft's ground speed (0–400 m/s)"
    );
    let t = trace
        .col("t")
        .context("a dead-reckoned track needs the trace's time (`t`, or --rate-hz)")?
        .to_vec();
    let t0 = t.first().copied().unwrap_or(0.0);
    let lat: Vec<f64> = t
        .iter()
        .map(|ti| start_deg.0 + ((ti - t0) * speed_mps / EARTH_RADIUS_M).to_degrees())
        .collect();
    trace.set_col("lat", lat);
    trace.set_col("lon", vec![start_deg.1; t.len()]);
    if trace.col("alt").is_none() {
        trace.set_col("alt", vec![alt_m; t.len()]);
    }
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coordinates_and_time_are_formatted_as_receivers_do() {
        assert_eq!(coord(45.3, true), "4518.00000,N");
        assert_eq!(coord(-75.7, false), "07542.00000,W");
        // 59.999999 minutes rounds up to the next degree, never "60.00000".
        assert_eq!(coord(10.999_999_99, true), "1100.00000,N");
        assert_eq!(hms(45_296.25), "123456.25");
        assert_eq!(hms(86_399.999), "000000.00");
        assert_eq!(parse_time_of_day("12:34:56").unwrap(), 45_296.0);
        assert!(parse_time_of_day("24:00:00").is_err());
    }

    #[test]
    fn sentences_parse_back_with_the_core_reader() {
        use magcomp_core::protocol::nmea::{parse_sentence, Sentence};
        let g = GpsState {
            lat: 45.123456789,
            lon: -75.987654321,
            alt: 3012.3456,
            vn: 40.0,
            ve: -30.0,
        };
        let s = gps_sentences(45_296.2, Some(&g), (21, 11, 2026));
        match parse_sentence(&s[0]).unwrap() {
            Sentence::Gga(x) => {
                assert!((x.lat_deg.unwrap() - 45.123456789).abs() < 2e-7);
                assert!((x.lon_deg.unwrap() + 75.987654321).abs() < 2e-7);
                assert_eq!(x.alt_msl_m, Some(3012.35));
                assert_eq!(x.fix_quality, Some(1));
                assert!((x.time.unwrap().seconds_of_day_s - 45_296.2).abs() < 1e-9);
            }
            o => panic!("{o:?}"),
        }
        match parse_sentence(&s[1]).unwrap() {
            Sentence::Rmc(x) => {
                assert!(x.valid);
                assert!((x.speed_mps.unwrap() - 50.0).abs() < 1e-3);
                assert!((x.track_deg.unwrap() - 323.13).abs() < 0.006);
            }
            o => panic!("{o:?}"),
        }
        match parse_sentence(&s[2]).unwrap() {
            Sentence::Vtg(x) => assert!((x.speed_mps.unwrap() - 50.0).abs() < 1e-3),
            o => panic!("{o:?}"),
        }
        for s in gps_sentences(0.0, None, (1, 1, 2026)) {
            assert!(
                parse_sentence(&s).is_ok(),
                "{}",
                String::from_utf8_lossy(&s)
            );
        }
    }
}
