//! Shared helpers for the text and binary protocols: checksums, exact decimal parsing and
//! formatting, hex. Written here (not with `core::fmt`/`crc`) because they are a few dozen
//! lines, exact, and add no dependency or float-formatting code to the firmware image.

/// NMEA 0183 checksum: XOR of every byte between `$` and `*`.
pub fn xor_checksum(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0u8, |a, &b| a ^ b)
}

/// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no xorout): the CRC the
/// TI ADS131M0x ADCs append, reused for the output records. Check value "123456789" → 0x29B1.
pub fn crc16_ccitt(bytes: &[u8]) -> u16 {
    crc16_ccitt_update(0xFFFF, bytes)
}

/// Continues a CRC-16/CCITT-FALSE over more bytes (bitwise: small, and fast enough for
/// a few hundred bytes per sample).
pub fn crc16_ccitt_update(mut crc: u16, bytes: &[u8]) -> u16 {
    for &b in bytes {
        crc ^= (b as u16) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// CRC-32 (IEEE 802.3, reflected poly 0xEDB88320, init/xorout 0xFFFFFFFF) for the flash
/// blob. Check value "123456789" → 0xCBF43926.
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &b in bytes {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

pub(crate) fn hex_val(b: u8) -> Option<u8> {
    match b {
        b'0'..=b'9' => Some(b - b'0'),
        b'A'..=b'F' => Some(b - b'A' + 10),
        b'a'..=b'f' => Some(b - b'a' + 10),
        _ => None,
    }
}

pub(crate) const HEX_UPPER: &[u8; 16] = b"0123456789ABCDEF";

/// Parses exactly `s.len()` hex digits (up to 8) into a u32.
pub fn parse_hex_u32(s: &[u8]) -> Option<u32> {
    if s.is_empty() || s.len() > 8 {
        return None;
    }
    let mut v = 0u32;
    for &b in s {
        v = (v << 4) | hex_val(b)? as u32;
    }
    Some(v)
}

/// A decimal number exactly as written: `mantissa × 10^-scale`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Decimal {
    pub mantissa: i64,
    /// Number of digits after the decimal point.
    pub scale: u8,
    /// Digits before the decimal point (without sign or leading zeros removed).
    pub int_digits: u8,
}

/// Why a decimal field could not be read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DecimalError {
    /// Empty, or a sign/point with no digit.
    NoDigits,
    /// More than 18 significant digits: would not fit exactly in i64.
    TooManyDigits,
    /// A byte that is not a digit, sign or single point.
    BadCharacter,
}

pub(crate) const POW10: [i64; 19] = [
    1,
    10,
    100,
    1_000,
    10_000,
    100_000,
    1_000_000,
    10_000_000,
    100_000_000,
    1_000_000_000,
    10_000_000_000,
    100_000_000_000,
    1_000_000_000_000,
    10_000_000_000_000,
    100_000_000_000_000,
    1_000_000_000_000_000,
    10_000_000_000_000_000,
    100_000_000_000_000_000,
    1_000_000_000_000_000_000,
];

const POW10_F64: [f64; 19] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18,
];

/// Parses `[+-]digits[.digits]` exactly (no exponent, no float on the way).
pub fn parse_decimal(s: &[u8]) -> Result<Decimal, DecimalError> {
    let (neg, body) = match s.first() {
        Some(b'-') => (true, &s[1..]),
        Some(b'+') => (false, &s[1..]),
        _ => (false, s),
    };
    let mut mant: i64 = 0;
    let mut digits = 0u32;
    let mut sig = 0u32;
    let mut scale = 0u8;
    let mut int_digits = 0u8;
    let mut seen_point = false;
    for &b in body {
        match b {
            b'0'..=b'9' => {
                digits += 1;
                if sig > 0 || b != b'0' {
                    sig += 1;
                }
                if sig > 18 {
                    return Err(DecimalError::TooManyDigits);
                }
                mant = mant * 10 + (b - b'0') as i64;
                if seen_point {
                    scale += 1;
                } else {
                    int_digits = int_digits.saturating_add(1);
                }
                // Leading zeros after the point still add scale: cap so POW10 stays in range.
                if scale > 18 {
                    return Err(DecimalError::TooManyDigits);
                }
            }
            b'.' if !seen_point => seen_point = true,
            _ => return Err(DecimalError::BadCharacter),
        }
    }
    if digits == 0 {
        return Err(DecimalError::NoDigits);
    }
    Ok(Decimal {
        mantissa: if neg { -mant } else { mant },
        scale,
        int_digits,
    })
}

impl Decimal {
    /// Correctly rounded f64 for mantissas below 2^53 (one division of two exact values).
    pub fn to_f64(self) -> f64 {
        self.mantissa as f64 / POW10_F64[self.scale as usize]
    }
    /// The value rescaled to `scale` decimals, rounding half away from zero; `None` on
    /// overflow.
    pub fn rescale(self, scale: u8) -> Option<i64> {
        if scale >= self.scale {
            let p = *POW10.get((scale - self.scale) as usize)?;
            self.mantissa.checked_mul(p)
        } else {
            let p = POW10[(self.scale - scale) as usize];
            let q = self.mantissa / p;
            let r = self.mantissa % p;
            Some(if 2 * r.abs() >= p {
                q + self.mantissa.signum()
            } else {
                q
            })
        }
    }
}

/// Parses an unsigned integer of at most 9 digits.
pub(crate) fn parse_u32(s: &[u8]) -> Option<u32> {
    if s.is_empty() || s.len() > 9 {
        return None;
    }
    let mut v = 0u32;
    for &b in s {
        if !b.is_ascii_digit() {
            return None;
        }
        v = v * 10 + (b - b'0') as u32;
    }
    Some(v)
}

/// A bounded writer into a caller buffer; every write reports overflow instead of panicking.
pub struct Cursor<'a> {
    buf: &'a mut [u8],
    pos: usize,
}

/// The caller's buffer was too small.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BufferFull;

impl<'a> Cursor<'a> {
    pub fn new(buf: &'a mut [u8]) -> Self {
        Self { buf, pos: 0 }
    }
    pub fn pos(&self) -> usize {
        self.pos
    }
    pub fn written(&self) -> &[u8] {
        &self.buf[..self.pos]
    }
    pub fn byte(&mut self, b: u8) -> Result<(), BufferFull> {
        let slot = self.buf.get_mut(self.pos).ok_or(BufferFull)?;
        *slot = b;
        self.pos += 1;
        Ok(())
    }
    pub fn bytes(&mut self, s: &[u8]) -> Result<(), BufferFull> {
        let end = self.pos.checked_add(s.len()).ok_or(BufferFull)?;
        self.buf
            .get_mut(self.pos..end)
            .ok_or(BufferFull)?
            .copy_from_slice(s);
        self.pos = end;
        Ok(())
    }
    pub fn u64(&mut self, mut v: u64) -> Result<(), BufferFull> {
        let mut tmp = [0u8; 20];
        let mut i = tmp.len();
        loop {
            i -= 1;
            tmp[i] = b'0' + (v % 10) as u8;
            v /= 10;
            if v == 0 {
                break;
            }
        }
        self.bytes(&tmp[i..])
    }
    pub fn i64(&mut self, v: i64) -> Result<(), BufferFull> {
        if v < 0 {
            self.byte(b'-')?;
        }
        self.u64(v.unsigned_abs())
    }
    /// Writes `v × 10^-scale` with exactly `scale` decimals (exact integer formatting).
    pub fn fixed(&mut self, v: i64, scale: u8) -> Result<(), BufferFull> {
        if v < 0 {
            self.byte(b'-')?;
        }
        let a = v.unsigned_abs();
        let p = POW10[scale as usize] as u64;
        self.u64(a / p)?;
        if scale > 0 {
            self.byte(b'.')?;
            let mut frac = a % p;
            let mut tmp = [b'0'; 18];
            for i in (0..scale as usize).rev() {
                tmp[i] = b'0' + (frac % 10) as u8;
                frac /= 10;
            }
            self.bytes(&tmp[..scale as usize])?;
        }
        Ok(())
    }
    /// Writes a float with `scale` decimals; values too large for that (|v|·10^scale ≥ 2e15)
    /// as 9 significant digits with an `E` exponent; NaN as nothing (an empty field);
    /// ±infinity as `INF`/`-INF`. Below 2e15 the two roundings of a decode/encode cycle
    /// (`m / 10^s`, then `· 10^s`) stay under half a unit, so the digits survive; up to
    /// 2^53 they did not (the fuzzer found t = 4294967296.1 s drifting one ULP per cycle).
    pub fn float(&mut self, v: f64, scale: u8) -> Result<(), BufferFull> {
        if v.is_nan() {
            return Ok(());
        }
        if v.is_infinite() {
            return self.bytes(if v > 0.0 { b"INF" } else { b"-INF" });
        }
        let scaled = v * POW10_F64[scale as usize];
        if libm::fabs(scaled) < 2.0e15 {
            return self.fixed(libm::round(scaled) as i64, scale);
        }
        self.sci(v)
    }
    /// Writes a finite non-zero float as 9 significant digits `<mantissa>E<exp>` (enough
    /// to round-trip an f32); zero as `0`.
    pub fn sci(&mut self, v: f64) -> Result<(), BufferFull> {
        if v == 0.0 || !v.is_finite() {
            return self.float(if v == 0.0 { 0.0 } else { v }, 0);
        }
        let a = libm::fabs(v);
        let mut e = libm::floor(libm::log10(a)) as i32 - 8;
        let mut m = libm::round(a / libm::pow(10.0, e as f64)) as i64;
        if m >= 1_000_000_000 {
            m /= 10;
            e += 1;
        }
        if v < 0.0 {
            self.byte(b'-')?;
        }
        self.i64(m)?;
        self.byte(b'E')?;
        self.i64(e as i64)
    }
    pub fn hex_u16(&mut self, v: u16) -> Result<(), BufferFull> {
        for s in [12u32, 8, 4, 0] {
            self.byte(HEX_UPPER[((v >> s) & 0xF) as usize])?;
        }
        Ok(())
    }
    pub fn hex_u8(&mut self, v: u8) -> Result<(), BufferFull> {
        self.byte(HEX_UPPER[(v >> 4) as usize])?;
        self.byte(HEX_UPPER[(v & 0xF) as usize])
    }
}

/// Parses a float written by [`Cursor::float`]: empty → NaN, `INF`, fixed decimals, or
/// `mantissaEexp`.
pub fn parse_float_field(s: &[u8]) -> Result<f64, DecimalError> {
    match s {
        b"" => return Ok(f64::NAN),
        b"INF" | b"+INF" => return Ok(f64::INFINITY),
        b"-INF" => return Ok(f64::NEG_INFINITY),
        _ => {}
    }
    if let Some(p) = s.iter().position(|&b| b == b'E' || b == b'e') {
        let m = parse_decimal(&s[..p])?;
        let e = parse_decimal(&s[p + 1..])?;
        if e.scale != 0 || e.mantissa.abs() > 400 {
            return Err(DecimalError::BadCharacter);
        }
        return Ok(m.to_f64() * libm::pow(10.0, e.mantissa as f64));
    }
    Ok(parse_decimal(s)?.to_f64())
}

/// Splits a field list on commas without allocating.
pub(crate) fn fields(s: &[u8]) -> impl Iterator<Item = &[u8]> {
    s.split(|&b| b == b',')
}

/// Ends a `$…` line: `*`, the CRC-16/CCITT-FALSE of everything after the `$` as 4 hex
/// digits, and `\r\n` (records, raw lines, replies).
pub fn finish_crc(c: &mut Cursor) -> Result<(), BufferFull> {
    let crc = crc16_ccitt(&c.written()[1..]);
    c.byte(b'*')?;
    c.hex_u16(crc)?;
    c.bytes(b"\r\n")
}

#[cfg(test)]
mod tests {
    use super::*;
    #[test]
    fn check_values() {
        assert_eq!(crc16_ccitt(b"123456789"), 0x29B1);
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }
}
