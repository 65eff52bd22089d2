//! Raw capture format: timestamped sensor bytes per port, one chunk per line.
//!
//! ```text
//! # magcomp-capture v1
//! 1000000 gps 24475047474...0D0A
//! 1000250 scalar 35333632302E343430310D0A
//! ```
//! `<t_us> <port> <hex bytes>\n`: decimal microseconds of the board clock when the first
//! byte arrived, a port name (`scalar`, `flux`, `gps`, `cmd`, `out`), and the bytes as
//! upper-case hex (lower case accepted), at most [`MAX_CHUNK`] bytes per line. Lines
//! starting with `#` are comments; the first line should be the version header. A text
//! format so flights can be grepped, diffed and cut with line tools.

use super::common::{hex_val, Cursor};

pub const HEADER: &[u8] = b"# magcomp-capture v1";
/// Largest chunk per line (longer writes are split by the encoder's caller).
pub const MAX_CHUNK: usize = 256;
/// Line buffer large enough for any line.
pub const MAX_LINE: usize = 20 + 1 + 6 + 1 + 2 * MAX_CHUNK + 1;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Port {
    Scalar,
    Flux,
    Gps,
    Cmd,
    Out,
}

impl Port {
    pub const ALL: [Port; 5] = [Port::Scalar, Port::Flux, Port::Gps, Port::Cmd, Port::Out];
    pub fn name(self) -> &'static str {
        match self {
            Port::Scalar => "scalar",
            Port::Flux => "flux",
            Port::Gps => "gps",
            Port::Cmd => "cmd",
            Port::Out => "out",
        }
    }
    pub fn from_name(s: &[u8]) -> Option<Port> {
        Port::ALL.into_iter().find(|p| p.name().as_bytes() == s)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CaptureLine {
    pub t_us: u64,
    pub port: Port,
    /// Number of bytes written into the caller's buffer.
    pub len: usize,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CaptureError {
    /// A `# magcomp-capture vN` header with N ≠ 1.
    UnsupportedVersion,
    BadTime,
    UnknownPort,
    /// Odd number of hex digits or a non-hex character.
    BadHex,
    /// More bytes than the caller's buffer holds.
    BufferFull,
    /// Not three space-separated fields.
    BadLine,
}

/// `# magcomp-capture v1\n`
pub fn encode_header(out: &mut [u8]) -> Option<usize> {
    let mut c = Cursor::new(out);
    c.bytes(HEADER).ok()?;
    c.byte(b'\n').ok()?;
    Some(c.pos())
}

/// One line with its `\n`; `None` if `out` is too small.
pub fn encode_line(t_us: u64, port: Port, data: &[u8], out: &mut [u8]) -> Option<usize> {
    let mut c = Cursor::new(out);
    c.u64(t_us).ok()?;
    c.byte(b' ').ok()?;
    c.bytes(port.name().as_bytes()).ok()?;
    c.byte(b' ').ok()?;
    for &b in data {
        c.hex_u8(b).ok()?;
    }
    c.byte(b'\n').ok()?;
    Some(c.pos())
}

/// Decodes one line into `data_out`. `Ok(None)` for blank lines, comments and the header.
pub fn decode_line(line: &[u8], data_out: &mut [u8]) -> Result<Option<CaptureLine>, CaptureError> {
    let mut line = line;
    while let [rest @ .., b'\r' | b'\n' | b' ' | b'\t'] = line {
        line = rest;
    }
    if line.is_empty() {
        return Ok(None);
    }
    if line[0] == b'#' {
        if let Some(v) = line.strip_prefix(b"# magcomp-capture ") {
            if v != b"v1" {
                return Err(CaptureError::UnsupportedVersion);
            }
        }
        return Ok(None);
    }
    let mut it = line.split(|&b| b == b' ').filter(|f| !f.is_empty());
    let (t, p, h) = match (it.next(), it.next(), it.next(), it.next()) {
        (Some(t), Some(p), h, None) => (t, p, h.unwrap_or(b"")),
        _ => return Err(CaptureError::BadLine),
    };
    if t.is_empty() || !t.iter().all(u8::is_ascii_digit) {
        return Err(CaptureError::BadTime);
    }
    let t_us = t
        .iter()
        .try_fold(0u64, |a, &d| {
            a.checked_mul(10)?.checked_add((d - b'0') as u64)
        })
        .ok_or(CaptureError::BadTime)?;
    let port = Port::from_name(p).ok_or(CaptureError::UnknownPort)?;
    if h.len() % 2 != 0 {
        return Err(CaptureError::BadHex);
    }
    let n = h.len() / 2;
    let out = data_out.get_mut(..n).ok_or(CaptureError::BufferFull)?;
    for (i, o) in out.iter_mut().enumerate() {
        let hi = hex_val(h[2 * i]).ok_or(CaptureError::BadHex)?;
        let lo = hex_val(h[2 * i + 1]).ok_or(CaptureError::BadHex)?;
        *o = (hi << 4) | lo;
    }
    Ok(Some(CaptureLine { t_us, port, len: n }))
}
