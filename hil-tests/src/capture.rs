//! Synthetic flights as raw captures: timestamped byte lines per sensor port, in the raw
//! capture text format `<t_us> <port> <hex bytes>` (one line per sensor line).
//!
//! Stand-in until `magcomp simulate` writes raw captures: a straight, weaving flight line
//! over a small anomaly, with a permanent-field interference, a fluxgate that sees the
//! Earth field rotated into the body frame, and a 1 Hz GPS (GGA, RMC, VTG with checksums).
//! Everything comes from a seeded PRNG, so a seed names a capture.

use crate::prng::Prng;
use magcomp_core::protocol::capture as cap_fmt;
use std::io::{self, BufRead, Write};

/// Sensor input ports of the board.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Port {
    Scalar,
    Flux,
    Gps,
}

impl Port {
    pub const ALL: [Port; 3] = [Port::Scalar, Port::Flux, Port::Gps];
    pub fn name(self) -> &'static str {
        match self {
            Port::Scalar => "scalar",
            Port::Flux => "flux",
            Port::Gps => "gps",
        }
    }
    pub fn from_name(s: &str) -> Option<Port> {
        Port::ALL.into_iter().find(|p| p.name() == s)
    }
    fn to_core(self) -> cap_fmt::Port {
        match self {
            Port::Scalar => cap_fmt::Port::Scalar,
            Port::Flux => cap_fmt::Port::Flux,
            Port::Gps => cap_fmt::Port::Gps,
        }
    }
    fn from_core(p: cap_fmt::Port) -> Option<Port> {
        match p {
            cap_fmt::Port::Scalar => Some(Port::Scalar),
            cap_fmt::Port::Flux => Some(Port::Flux),
            cap_fmt::Port::Gps => Some(Port::Gps),
            _ => None,
        }
    }
}

/// One chunk of bytes arriving on a port at `t_us` (microseconds from the capture start).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Chunk {
    pub t_us: u64,
    pub port: Port,
    pub bytes: Vec<u8>,
}

/// What the generator should do.
#[derive(Clone, Debug)]
pub struct FlightSpec {
    pub seed: u64,
    pub duration_s: f64,
    pub scalar_hz: f64,
    pub flux_hz: f64,
    pub gps_hz: f64,
    /// No fluxgate frames in [start, end) seconds.
    pub flux_dropout_s: Option<(f64, f64)>,
    /// GPS without fix (GGA quality 0, RMC status V) in [start, end) seconds.
    pub gps_outage_s: Option<(f64, f64)>,
    /// Fraction of payload bytes replaced by random bytes (line terminators are kept so the
    /// sample count stays known; a corrupted terminator would merge two samples).
    pub corrupt_fraction: f64,
    /// Scalar magnetometers: 1 writes single-field lines (`$ <nT>,0999`), 2–3 a
    /// multi-channel counter line (`M,<nT>,<nT>[,<nT>]`), each sensor with its own
    /// interference and 2 m further along the fuselage (docs/firmware.md).
    pub sensors: usize,
    /// Channel `.0` of the counter line sends an empty field (a dead sensor) in [start, end) s.
    pub dead_channel_s: Option<(usize, f64, f64)>,
    /// Scalar lines (by sample number) sent without their terminator, so each runs into
    /// the next: a lost line end, which must still give one record per sample.
    pub lost_line_ends: Vec<usize>,
}

impl FlightSpec {
    pub fn new(seed: u64, duration_s: f64) -> Self {
        Self {
            seed,
            duration_s,
            scalar_hz: 10.0,
            flux_hz: 10.0,
            gps_hz: 1.0,
            flux_dropout_s: None,
            gps_outage_s: None,
            corrupt_fraction: 0.0,
            sensors: 1,
            dead_channel_s: None,
            lost_line_ends: Vec::new(),
        }
    }
}

/// A capture plus what the generator knows about it.
#[derive(Clone, Debug, Default)]
pub struct Capture {
    /// Time-ordered chunks (ties keep generation order).
    pub chunks: Vec<Chunk>,
    /// Capture time (s) of every scalar line, in order: sample `seq` ↔ `scalar_t_s[seq]`.
    pub scalar_t_s: Vec<f64>,
    /// Payload bytes corrupted.
    pub corrupted_bytes: usize,
    /// Payload bytes in total.
    pub payload_bytes: usize,
}

fn nmea(body: &str) -> Vec<u8> {
    let cs = body.bytes().fold(0u8, |a, b| a ^ b);
    format!("${body}*{cs:02X}\r\n").into_bytes()
}

fn hhmmss(t_s: f64) -> String {
    let t = t_s.rem_euclid(86_400.0);
    let h = (t / 3600.0).floor();
    let m = ((t - h * 3600.0) / 60.0).floor();
    let s = t - h * 3600.0 - m * 60.0;
    format!("{:02}{:02}{:05.2}", h as u32, m as u32, s)
}

fn lat_field(lat: f64) -> String {
    let a = lat.abs();
    let d = a.floor();
    format!(
        "{:02}{:07.4},{}",
        d as u32,
        (a - d) * 60.0,
        if lat >= 0.0 { 'N' } else { 'S' }
    )
}

fn lon_field(lon: f64) -> String {
    let a = lon.abs();
    let d = a.floor();
    format!(
        "{:03}{:07.4},{}",
        d as u32,
        (a - d) * 60.0,
        if lon >= 0.0 { 'E' } else { 'W' }
    )
}

/// Body-frame fluxgate vector for an Earth field `ned` and attitude (rad).
fn to_body(ned: [f64; 3], roll: f64, pitch: f64, yaw: f64) -> [f64; 3] {
    let (sr, cr) = roll.sin_cos();
    let (sp, cp) = pitch.sin_cos();
    let (sy, cy) = yaw.sin_cos();
    // rows of the NED→body rotation (transpose of body→NED, ZYX order)
    let r = [
        [cp * cy, cp * sy, -sp],
        [sr * sp * cy - cr * sy, sr * sp * sy + cr * cy, sr * cp],
        [cr * sp * cy + sr * sy, cr * sp * sy - sr * cy, cr * cp],
    ];
    let mut b = [0.0; 3];
    for i in 0..3 {
        b[i] = r[i][0] * ned[0] + r[i][1] * ned[1] + r[i][2] * ned[2];
    }
    b
}

/// GPS time of day at the capture start (12:00:00 UTC).
pub const GPS_T0_S: f64 = 43_200.0;

/// The synthetic field: |F| 52,000 nT, inclination 70°, declination −14°, in NED (nT).
fn earth_ned_nt() -> [f64; 3] {
    let (incl, decl) = (70f64.to_radians(), (-14f64).to_radians());
    [
        EARTH_F_NT * incl.cos() * decl.cos(),
        EARTH_F_NT * incl.cos() * decl.sin(),
        EARTH_F_NT * incl.sin(),
    ]
}

const EARTH_F_NT: f64 = 52_000.0;

const SPEED_MPS: f64 = 60.0;

/// The aircraft at `t` s: (yaw, roll, pitch) in rad and the distance flown (m). A weaving
/// east-bound line: heading 90° ± 20°, small pitch and roll oscillations.
fn state(t: f64) -> (f64, f64, f64, f64) {
    let yaw = (90.0 + 20.0 * (std::f64::consts::TAU * t / 15.0).sin()).to_radians();
    let roll = (8.0 * (std::f64::consts::TAU * t / 7.0).sin()).to_radians();
    let pitch = (3.0 * (std::f64::consts::TAU * t / 5.0).sin()).to_radians();
    (yaw, roll, pitch, SPEED_MPS * t)
}

fn in_window(w: Option<(f64, f64)>, t: f64) -> bool {
    w.is_some_and(|(a, b)| t >= a && t < b)
}

/// The capture of `spec`'s flight: each stream with its own phase, so lines of different
/// ports never coincide; then the line ends lost and the bytes corrupted as asked.
pub fn synthetic_flight(spec: &FlightSpec) -> Capture {
    let mut rng = Prng::new(spec.seed);
    let (mut chunks, scalar_t_s) = scalar_chunks(spec, &mut rng);
    chunks.extend(flux_chunks(spec, &mut rng));
    chunks.extend(gps_chunks(spec));
    chunks.sort_by_key(|c| c.t_us);
    let mut cap = Capture {
        chunks,
        scalar_t_s,
        corrupted_bytes: 0,
        payload_bytes: 0,
    };
    damage(&mut cap, spec, &mut rng);
    cap
}

/// The scalar port's lines (one sensor's `$ nT,quality` or a counter line `M,…`) and
/// their times (s).
fn scalar_chunks(spec: &FlightSpec, rng: &mut Prng) -> (Vec<Chunk>, Vec<f64>) {
    let ned = earth_ned_nt();
    let mut chunks = Vec::new();
    let mut scalar_t_s = Vec::new();
    let n_scalar = (spec.duration_s * spec.scalar_hz).round() as u64;
    for k in 0..n_scalar {
        let t = k as f64 / spec.scalar_hz + 0.05;
        let (yaw, roll, pitch, x_m) = state(t);
        let b = to_body(ned, roll, pitch, yaw);
        let bn = (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt();
        let anomaly = 30.0 * (-((x_m - 900.0) / 200.0).powi(2)).exp();
        let interference = (3.0 * b[0] - 2.0 * b[1] + 1.5 * b[2]) / bn + 4.0;
        let total = EARTH_F_NT + anomaly + interference + 0.01 * rng.gauss();
        let bytes = if spec.sensors <= 1 {
            format!("$ {total:.4},0999\r\n")
        } else {
            let mut line = String::from("M");
            for i in 0..spec.sensors.min(3) {
                // sensor i: 2·i m behind along the line, its own permanent field
                let d_m = 2.0 * i as f64;
                let anomaly = 30.0 * (-((x_m - d_m - 900.0) / 200.0).powi(2)).exp();
                let k = 1.0 + 0.5 * i as f64;
                let interference = k * (3.0 * b[0] - 2.0 * b[1] + 1.5 * b[2]) / bn + 4.0 * k;
                let field = EARTH_F_NT + anomaly + interference + 0.01 * rng.gauss();
                let dead = spec
                    .dead_channel_s
                    .is_some_and(|(c, a, e)| c == i && t >= a && t < e);
                line.push(',');
                if !dead {
                    line.push_str(&format!("{field:.4}"));
                }
            }
            line.push_str("\r\n");
            line
        };
        chunks.push(Chunk {
            t_us: (t * 1e6) as u64,
            port: Port::Scalar,
            bytes: bytes.into_bytes(),
        });
        scalar_t_s.push(t);
    }
    (chunks, scalar_t_s)
}

/// The fluxgate port's lines (body-frame vector, 0.5 nT noise), none in the dropout.
fn flux_chunks(spec: &FlightSpec, rng: &mut Prng) -> Vec<Chunk> {
    let ned = earth_ned_nt();
    let mut chunks = Vec::new();
    let n_flux = (spec.duration_s * spec.flux_hz).round() as u64;
    for k in 0..n_flux {
        let t = k as f64 / spec.flux_hz + 0.002;
        if in_window(spec.flux_dropout_s, t) {
            continue;
        }
        let (yaw, roll, pitch, _) = state(t);
        let b = to_body(ned, roll, pitch, yaw);
        let line = format!(
            "{:.2},{:.2},{:.2}\r\n",
            b[0] + 0.5 * rng.gauss(),
            b[1] + 0.5 * rng.gauss(),
            b[2] + 0.5 * rng.gauss()
        );
        chunks.push(Chunk {
            t_us: (t * 1e6) as u64,
            port: Port::Flux,
            bytes: line.into_bytes(),
        });
    }
    chunks
}

/// The GPS port's sentences (GGA, RMC, VTG; no fix in the outage).
fn gps_chunks(spec: &FlightSpec) -> Vec<Chunk> {
    let (lat0, lon0, alt_m) = (45.5f64, -73.5f64, 300.0f64);
    let mut chunks = Vec::new();
    let n_gps = (spec.duration_s * spec.gps_hz).round() as u64;
    for k in 0..n_gps {
        let t = k as f64 / spec.gps_hz + 0.02;
        let tod = GPS_T0_S + k as f64 / spec.gps_hz;
        let (yaw, _, _, x_m) = state(t);
        let lat = lat0;
        let lon = lon0 + x_m / (111_320.0 * lat0.to_radians().cos());
        let kn = SPEED_MPS * 3600.0 / 1852.0;
        let trk = yaw.to_degrees().rem_euclid(360.0);
        let mut lines = Vec::new();
        if in_window(spec.gps_outage_s, t) {
            lines.push(nmea(&format!(
                "GPGGA,{},,,,,0,00,99.9,,M,,M,,",
                hhmmss(tod)
            )));
            lines.push(nmea(&format!("GPRMC,{},V,,,,,,,211126,,,N", hhmmss(tod))));
        } else {
            lines.push(nmea(&format!(
                "GPGGA,{},{},{},1,10,0.9,{:.1},M,-30.0,M,,",
                hhmmss(tod),
                lat_field(lat),
                lon_field(lon),
                alt_m
            )));
            lines.push(nmea(&format!(
                "GPRMC,{},A,{},{},{:.2},{:.1},211126,,,A",
                hhmmss(tod),
                lat_field(lat),
                lon_field(lon),
                kn,
                trk
            )));
            lines.push(nmea(&format!(
                "GPVTG,{trk:.1},T,,M,{kn:.2},N,{:.2},K,A",
                kn * 1.852
            )));
        }
        for (i, l) in lines.into_iter().enumerate() {
            // consecutive sentences 5 ms apart, as a receiver sends them
            chunks.push(Chunk {
                t_us: (t * 1e6) as u64 + 5_000 * i as u64,
                port: Port::Gps,
                bytes: l,
            });
        }
    }
    chunks
}

/// Lost line ends and corrupted bytes, as `spec` asks.
fn damage(cap: &mut Capture, spec: &FlightSpec, rng: &mut Prng) {
    let scalar_lines = cap.chunks.iter_mut().filter(|c| c.port == Port::Scalar);
    for (k, c) in scalar_lines.enumerate() {
        if spec.lost_line_ends.contains(&k) {
            c.bytes.retain(|b| !matches!(b, b'\r' | b'\n'));
        }
    }
    for c in &mut cap.chunks {
        for b in c.bytes.iter_mut() {
            if *b == b'\r' || *b == b'\n' {
                continue;
            }
            cap.payload_bytes += 1;
            if spec.corrupt_fraction > 0.0 && rng.uniform() < spec.corrupt_fraction {
                let mut r = (rng.next_u64() & 0xFF) as u8;
                while r == b'\r' || r == b'\n' || r == *b {
                    r = (rng.next_u64() & 0xFF) as u8;
                }
                *b = r;
                cap.corrupted_bytes += 1;
            }
        }
    }
}

impl Capture {
    /// Lines sent on one port.
    pub fn lines(&self, port: Port) -> impl Iterator<Item = &Chunk> {
        self.chunks.iter().filter(move |c| c.port == port)
    }

    /// Writes the raw capture format of `magcomp_core::protocol::capture` (`# magcomp-capture v1`,
    /// then `<t_us> <port> <HEX>` per chunk).
    pub fn write_raw<W: Write>(&self, mut w: W) -> io::Result<()> {
        let mut buf = vec![0u8; cap_fmt::MAX_LINE + 2];
        let n = cap_fmt::encode_header(&mut buf).ok_or_else(|| io::Error::other("header"))?;
        w.write_all(&buf[..n])?;
        for c in &self.chunks {
            for part in c.bytes.chunks(cap_fmt::MAX_CHUNK) {
                let n = cap_fmt::encode_line(c.t_us, c.port.to_core(), part, &mut buf)
                    .ok_or_else(|| io::Error::other("line"))?;
                w.write_all(&buf[..n])?;
            }
        }
        Ok(())
    }

    /// Reads a raw capture (sensor ports only; `cmd`/`out` lines are skipped). Scalar sample
    /// times are the scalar chunks' times, one sample per line terminator.
    pub fn read_raw<R: BufRead>(r: R) -> io::Result<Capture> {
        let mut cap = Capture::default();
        let mut data = vec![0u8; cap_fmt::MAX_CHUNK];
        for (n, line) in r.lines().enumerate() {
            let line = line?;
            let parsed = cap_fmt::decode_line(line.as_bytes(), &mut data).map_err(|e| {
                io::Error::new(
                    io::ErrorKind::InvalidData,
                    format!("capture line {}: {e:?}", n + 1),
                )
            })?;
            let Some(cl) = parsed else { continue };
            let Some(port) = Port::from_core(cl.port) else {
                continue;
            };
            let bytes = data[..cl.len].to_vec();
            if port == Port::Scalar {
                // "\r\n" is one terminator, as in the firmware's reader
                let mut prev = 0u8;
                for &b in &bytes {
                    if (b == b'\n' && prev != b'\r') || b == b'\r' {
                        cap.scalar_t_s.push(cl.t_us as f64 * 1e-6);
                    }
                    prev = b;
                }
            }
            cap.payload_bytes += bytes.iter().filter(|&&b| b != b'\r' && b != b'\n').count();
            cap.chunks.push(Chunk {
                t_us: cl.t_us,
                port,
                bytes,
            });
        }
        Ok(cap)
    }
}
