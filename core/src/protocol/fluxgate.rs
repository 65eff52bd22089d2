//! Fluxgate frames: a 24-bit SPI ADC (TI ADS131M03-style) and a serial ASCII alternative.
//!
//! SPI frame (ADS131M03, 24-bit word length, output CRC enabled, CCITT CRC type), 15 bytes,
//! MSB first:
//! ```text
//! word 0  STATUS[15:0] 0x00     LOCK F_RESYNC REG_MAP CRC_ERR CRC_TYPE RESET WLENGTH.. DRDY[2:0]
//! word 1  CH0[23:0]             two's complement
//! word 2  CH1[23:0]
//! word 3  CH2[23:0]
//! word 4  CRC[15:0] 0x00        CRC-16/CCITT (0x1021, init 0xFFFF) over bytes 0..12
//! ```
//! The ADC's CRC covers the status word and the data words including the padding bytes.

use super::common::{crc16_ccitt, hex_val, parse_decimal, xor_checksum};

pub const SPI_FRAME_LEN: usize = 15;
/// Full-scale code magnitude of a 24-bit converter.
pub const ADC_FULL_SCALE: i32 = 1 << 23;
/// Status bit: the ADC reset since the last read.
pub const STATUS_RESET: u16 = 1 << 9;
/// Status bits: data ready per channel.
pub const STATUS_DRDY_MASK: u16 = 0b111;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FluxError {
    /// Frame or line does not have the expected length / number of fields.
    BadLength,
    /// SPI frame CRC mismatch.
    Crc { received: u16, computed: u16 },
    /// ASCII `*hh` mismatch or malformed.
    Checksum,
    /// A channel at the converter's rail: the field is beyond the range, value unusable.
    Saturated { channel: u8 },
    /// ASCII number not parseable.
    BadNumber,
    /// ASCII value beyond ±[`MAX_ASCII_NT`].
    OutOfRange,
    /// The ADC did not flag all channels ready (stale conversion).
    NotReady,
    /// ASCII line too long.
    Overlong,
    /// The UART flagged an overrun, framing or noise error while the line was received
    /// ([`super::uart_errors::LineErrors`]).
    Uart,
}

/// Raw ADC conversion.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AdcFrame {
    pub status: u16,
    pub counts: [i32; 3],
}

fn i24(b: &[u8]) -> i32 {
    // Sign-extend a big-endian 24-bit two's complement value.
    (((b[0] as i32) << 24) | ((b[1] as i32) << 16) | ((b[2] as i32) << 8)) >> 8
}

/// Decodes one 15-byte ADS131M03 frame.
pub fn decode_spi_frame(frame: &[u8]) -> Result<AdcFrame, FluxError> {
    if frame.len() != SPI_FRAME_LEN {
        return Err(FluxError::BadLength);
    }
    let computed = crc16_ccitt(&frame[..12]);
    let received = u16::from_be_bytes([frame[12], frame[13]]);
    if computed != received {
        return Err(FluxError::Crc { received, computed });
    }
    let status = u16::from_be_bytes([frame[0], frame[1]]);
    if status & STATUS_DRDY_MASK != STATUS_DRDY_MASK {
        return Err(FluxError::NotReady);
    }
    let mut counts = [0i32; 3];
    for (i, c) in counts.iter_mut().enumerate() {
        *c = i24(&frame[3 + 3 * i..6 + 3 * i]);
        // The ADC clips at 0x7FFFFF / 0x800000.
        if *c == ADC_FULL_SCALE - 1 || *c == -ADC_FULL_SCALE {
            return Err(FluxError::Saturated { channel: i as u8 });
        }
    }
    Ok(AdcFrame { status, counts })
}

/// Builds a frame (simulator, tests): counts are clamped to 24 bits.
pub fn encode_spi_frame(status: u16, counts: [i32; 3]) -> [u8; SPI_FRAME_LEN] {
    let mut f = [0u8; SPI_FRAME_LEN];
    f[..2].copy_from_slice(&status.to_be_bytes());
    for (i, &c) in counts.iter().enumerate() {
        let c = c.clamp(-ADC_FULL_SCALE, ADC_FULL_SCALE - 1);
        f[3 + 3 * i..6 + 3 * i].copy_from_slice(&c.to_be_bytes()[1..]);
    }
    let crc = crc16_ccitt(&f[..12]);
    f[12..14].copy_from_slice(&crc.to_be_bytes());
    f
}

/// Where a body axis comes from: sensor channel and sign.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AxisMap {
    pub sensor_channel: u8,
    pub negate: bool,
}

/// Per-channel scale and offset, then sensor → body (x forward, y starboard, z down).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FluxgateCal {
    pub nt_per_lsb: [f32; 3],
    pub offset_nt: [f32; 3],
    /// Body axis i = ±(sensor channel `axis_map[i]`).
    pub axis_map: [AxisMap; 3],
}

impl FluxgateCal {
    /// ±`full_scale_nt` over the ADC's ±2^23 codes, identity axes.
    pub fn full_scale(full_scale_nt: f32) -> Self {
        let lsb = full_scale_nt / ADC_FULL_SCALE as f32;
        Self {
            nt_per_lsb: [lsb; 3],
            offset_nt: [0.0; 3],
            axis_map: [0, 1, 2].map(|c| AxisMap {
                sensor_channel: c,
                negate: false,
            }),
        }
    }

    /// Sensor-frame values (nT) → body frame.
    pub fn to_body(&self, sensor_nt: [f32; 3]) -> [f32; 3] {
        self.axis_map.map(|m| {
            let v = sensor_nt[(m.sensor_channel % 3) as usize];
            if m.negate {
                -v
            } else {
                v
            }
        })
    }

    /// ADC counts → body-frame nT.
    pub fn scale(&self, counts: [i32; 3]) -> [f32; 3] {
        let mut s = [0f32; 3];
        for i in 0..3 {
            // f64 so 24-bit counts times the scale lose nothing before the final rounding.
            s[i] = (counts[i] as f64 * self.nt_per_lsb[i] as f64 - self.offset_nt[i] as f64) as f32;
        }
        self.to_body(s)
    }
}

/// The fluxgate's scalar calibration (the `fluxcal` effect), applied to body-frame vectors:
/// `B = M·B_F + b`. Fitted on a calibration flight by `magcomp calibrate --model …+fluxcal`
/// and sent to the board with `SETFLUX` (or compiled in, `src/board_config.rs`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FluxCalibration {
    pub matrix: [[f32; 3]; 3],
    pub bias_nt: [f32; 3],
}

impl FluxCalibration {
    pub const IDENTITY: Self = Self {
        matrix: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        bias_nt: [0.0; 3],
    };

    pub fn apply(&self, b: [f32; 3]) -> [f32; 3] {
        let m = &self.matrix;
        let mut out = [0f32; 3];
        for i in 0..3 {
            out[i] = m[i][0] * b[0] + m[i][1] * b[1] + m[i][2] * b[2] + self.bias_nt[i];
        }
        out
    }

    /// 12 values: the matrix row by row, then the bias (nT).
    pub fn to_array(&self) -> [f32; 12] {
        let (m, b) = (&self.matrix, &self.bias_nt);
        [
            m[0][0], m[0][1], m[0][2], m[1][0], m[1][1], m[1][2], m[2][0], m[2][1], m[2][2], b[0],
            b[1], b[2],
        ]
    }

    /// From 12 values; `None` unless it is a plausible correction of a working fluxgate
    /// (diagonal 0.5–2, off-diagonal within ±0.5, bias within ±100 000 nT).
    pub fn from_array(v: &[f32; 12]) -> Option<Self> {
        let plausible = v.iter().all(|x| x.is_finite())
            && (0..3).all(|i| {
                (0..3).all(|j| {
                    let m = v[3 * i + j];
                    if i == j {
                        (0.5..=2.0).contains(&m)
                    } else {
                        libm::fabsf(m) <= 0.5
                    }
                })
            })
            && v[9..].iter().all(|b| libm::fabsf(*b) <= 100_000.0);
        plausible.then(|| Self {
            matrix: [[v[0], v[1], v[2]], [v[3], v[4], v[5]], [v[6], v[7], v[8]]],
            bias_nt: [v[9], v[10], v[11]],
        })
    }

    pub fn is_identity(&self) -> bool {
        *self == Self::IDENTITY
    }
}

/// Longest ASCII fluxgate line.
pub const MAX_FLUX_LINE: usize = 64;
/// Largest accepted ASCII component (nT).
pub const MAX_ASCII_NT: f64 = 200_000.0;

/// Largest accepted ASCII temperature magnitude (°C): beyond it the field is garbage.
pub const MAX_ASCII_DEGC: f64 = 200.0;

/// Parses `X,Y,Z` in nT (sensor frame) with an optional `*hh` XOR checksum over `X,Y,Z`.
pub fn parse_ascii_line(line: &[u8]) -> Result<[f32; 3], FluxError> {
    parse_ascii_frame(line).map(|(v, _)| v)
}

/// Parses `X,Y,Z[,T]` (nT, sensor frame; T the sensor's temperature in °C) with an
/// optional `*hh` XOR checksum over everything before it. T is NaN on a 3-field line.
pub fn parse_ascii_frame(line: &[u8]) -> Result<([f32; 3], f32), FluxError> {
    let mut line = line;
    while let [rest @ .., b'\r' | b'\n' | b' '] = line {
        line = rest;
    }
    let body = match line.iter().position(|&b| b == b'*') {
        Some(p) => {
            let (body, cs) = (&line[..p], &line[p + 1..]);
            let want = match cs {
                [h, l] => match (hex_val(*h), hex_val(*l)) {
                    (Some(h), Some(l)) => (h << 4) | l,
                    _ => return Err(FluxError::Checksum),
                },
                _ => return Err(FluxError::Checksum),
            };
            if xor_checksum(body) != want {
                return Err(FluxError::Checksum);
            }
            body
        }
        None => line,
    };
    let mut out = [0f32; 3];
    let mut temp_degc = f32::NAN;
    let mut n = 0;
    for f in body.split(|&b| b == b',') {
        if n == 4 {
            return Err(FluxError::BadLength);
        }
        let d = parse_decimal(f).map_err(|_| FluxError::BadNumber)?;
        let v = d.to_f64();
        let limit = if n == 3 { MAX_ASCII_DEGC } else { MAX_ASCII_NT };
        if v.abs() > limit {
            return Err(FluxError::OutOfRange);
        }
        if n == 3 {
            temp_degc = v as f32;
        } else {
            out[n] = v as f32;
        }
        n += 1;
    }
    if n < 3 {
        return Err(FluxError::BadLength);
    }
    Ok((out, temp_degc))
}

/// Number of `SETFTEMP`/`GETFTEMP` values: T_ref, b×3, s×3.
pub const FLUX_TEMP_LEN: usize = 7;

/// The fluxgate's temperature drift (`fluxtemp:CH`), the host's formula in f32:
/// `B = B_F + (T − T_ref)·(b + s∘B_F)` on the body-frame vector before `fluxcal`'s
/// calibration (the host corrects the raw fluxgate first, then calibrates).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FluxTempCal {
    pub t_ref_degc: f32,
    pub bias_nt_per_degc: [f32; 3],
    pub scale_per_degc: [f32; 3],
}

impl FluxTempCal {
    /// No correction (all zero): the vector passes unchanged, whatever the temperature.
    pub const NONE: Self = Self {
        t_ref_degc: 0.0,
        bias_nt_per_degc: [0.0; 3],
        scale_per_degc: [0.0; 3],
    };

    pub fn is_none(&self) -> bool {
        self.bias_nt_per_degc == [0.0; 3] && self.scale_per_degc == [0.0; 3]
    }

    /// The corrected vector; NaN (the sample is then `FLUX_STALE`) when a correction is set
    /// and the temperature is missing, so it is never silently left uncorrected.
    pub fn apply(&self, b: [f32; 3], t_degc: f32) -> [f32; 3] {
        if self.is_none() {
            return b;
        }
        let d = t_degc - self.t_ref_degc;
        if !d.is_finite() {
            return [f32::NAN; 3];
        }
        [0, 1, 2].map(|i| b[i] + d * (self.bias_nt_per_degc[i] + self.scale_per_degc[i] * b[i]))
    }

    /// 7 values: T_ref (°C), b (nT/°C) ×3, s (1/°C) ×3.
    pub fn to_array(&self) -> [f32; FLUX_TEMP_LEN] {
        let (b, s) = (&self.bias_nt_per_degc, &self.scale_per_degc);
        [self.t_ref_degc, b[0], b[1], b[2], s[0], s[1], s[2]]
    }

    /// From 7 values; `None` unless plausible for a working fluxgate: T_ref within
    /// ±[`MAX_ASCII_DEGC`], |b| ≤ 1 000 nT/°C, |s| ≤ 0.01/°C (1 %/°C; real drifts are
    /// ~1 nT/°C and ~10 ppm/°C).
    pub fn from_array(v: &[f32; FLUX_TEMP_LEN]) -> Option<Self> {
        let plausible = v.iter().all(|x| x.is_finite())
            && libm::fabsf(v[0]) <= MAX_ASCII_DEGC as f32
            && v[1..4].iter().all(|b| libm::fabsf(*b) <= 1_000.0)
            && v[4..].iter().all(|s| libm::fabsf(*s) <= 0.01);
        plausible.then(|| Self {
            t_ref_degc: v[0],
            bias_nt_per_degc: [v[1], v[2], v[3]],
            scale_per_degc: [v[4], v[5], v[6]],
        })
    }
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FluxStats {
    pub ok: u32,
    pub errors: u32,
}

/// Byte-at-a-time reader for the ASCII fluxgate port.
#[derive(Clone, Debug)]
pub struct FluxAsciiReader {
    buf: [u8; MAX_FLUX_LINE],
    len: usize,
    overlong: bool,
    /// A line with a valid `*hh` was seen: from then on a line without one is refused. A
    /// corrupted byte that turns into a line end cuts a frame short, and the cut frame
    /// (`X,Y,Z` with Z's last digits gone) parses; on a 1 % corrupted capture one such
    /// frame put a 6 nT eddy error on an unflagged record.
    checksummed: bool,
    pub stats: FluxStats,
}

impl Default for FluxAsciiReader {
    fn default() -> Self {
        Self::new()
    }
}

impl FluxAsciiReader {
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_FLUX_LINE],
            len: 0,
            overlong: false,
            checksummed: false,
            stats: FluxStats { ok: 0, errors: 0 },
        }
    }

    /// Feeds a byte; a non-empty line yields one result (sensor-frame nT).
    pub fn push(&mut self, b: u8) -> Option<Result<[f32; 3], FluxError>> {
        self.push_frame(b).map(|r| r.map(|(v, _)| v))
    }

    /// As [`push`](Self::push), with the line's temperature (°C, NaN on a 3-field line).
    pub fn push_frame(&mut self, b: u8) -> Option<Result<([f32; 3], f32), FluxError>> {
        if b == b'\r' || b == b'\n' {
            if self.len == 0 && !self.overlong {
                return None;
            }
            let line = &self.buf[..self.len];
            let has_checksum = line.contains(&b'*');
            let r = if self.overlong {
                Err(FluxError::Overlong)
            } else if self.checksummed && !has_checksum {
                Err(FluxError::Checksum)
            } else {
                parse_ascii_frame(line)
            };
            if r.is_ok() && has_checksum {
                self.checksummed = true;
            }
            self.len = 0;
            self.overlong = false;
            if r.is_ok() {
                self.stats.ok = self.stats.ok.saturating_add(1);
            } else {
                self.stats.errors = self.stats.errors.saturating_add(1);
            }
            return Some(r);
        }
        if self.len == MAX_FLUX_LINE {
            self.overlong = true;
        } else {
            self.buf[self.len] = b;
            self.len += 1;
        }
        None
    }
}
