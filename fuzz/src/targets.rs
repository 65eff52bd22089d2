//! One function per fuzz target: decode the input and assert what must hold for any
//! input (a panic here, or in the decoder, is a finding).

use magcomp::board::replay::{replay_capture_any, ReplayOptions};
use magcomp::io::trace::{read_trace_from, ColumnMap};
use magcomp::model::spec::ModelSpec;
use magcomp_core::acquisition::AcqRecord;
use magcomp_core::protocol::capture::{decode_line, encode_line, MAX_CHUNK, MAX_LINE};
use magcomp_core::protocol::command::{
    blob_len, decode_blob, encode_blob, encode_command, parse_command, Command, CommandReader,
    MAX_COEF_ABS,
};
use magcomp_core::protocol::fluxgate::{
    decode_spi_frame, encode_spi_frame, FluxAsciiReader, ADC_FULL_SCALE, MAX_ASCII_NT,
    SPI_FRAME_LEN,
};
use magcomp_core::protocol::multi_record::{
    decode_multi_record, encode_multi_record, MAX_MULTI_RECORD_LEN,
};
use magcomp_core::protocol::multi_scalar::ScalarLine;
use magcomp_core::protocol::nmea::{NmeaReader, Sentence};
use magcomp_core::protocol::raw::{decode_raw, encode_raw, MAX_RAW_LEN};
use magcomp_core::protocol::record::{decode_record, encode_record, Record, MAX_RECORD_LEN};
use magcomp_core::protocol::scalar::{ScalarConfig, ScalarReader, MAX_FIELD_NT, MIN_FIELD_NT};
use magcomp_core::{Flags, MagCounts};
use std::sync::OnceLock;

pub type Target = fn(&[u8]);

/// Every target: name, function, which seed files feed it.
pub const TARGETS: &[(&str, Target, Seeds)] = &[
    ("nmea", nmea, Seeds::Gps),
    ("scalar", scalar, Seeds::Scalar),
    ("scalar_line", scalar_line, Seeds::Scalar),
    ("flux_ascii", flux_ascii, Seeds::Flux),
    ("flux_spi", flux_spi, Seeds::Spi),
    ("command", command, Seeds::Command),
    ("blob", blob, Seeds::Blob),
    ("record", record, Seeds::Record),
    ("multi_record", multi_record, Seeds::Record),
    ("raw", raw, Seeds::Record),
    ("capture", capture, Seeds::Capture),
    ("acquisition", acquisition, Seeds::Capture),
    ("trace", trace, Seeds::Trace),
];

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Seeds {
    Gps,
    Scalar,
    Flux,
    Spi,
    Command,
    Blob,
    Record,
    Capture,
    Trace,
}

fn in_range(v: Option<f64>, lo: f64, hi: f64) -> bool {
    v.is_none_or(|v| v.is_finite() && (lo..=hi).contains(&v))
}

/// Byte stream through the board's reader: every `$` gives exactly one result, the
/// counters add up, and every decoded value is finite and within its field's range.
fn nmea(data: &[u8]) {
    let mut rd = NmeaReader::new();
    let mut results = 0usize;
    for &b in data {
        let Some(r) = rd.push(b) else { continue };
        results += 1;
        let Ok(s) = r else { continue };
        let (time, lat, lon) = match &s {
            Sentence::Gga(g) => {
                assert!(in_range(g.alt_msl_m, -2000.0, 100_000.0), "{s:?}");
                (g.time, g.lat_deg, g.lon_deg)
            }
            Sentence::Rmc(r) => {
                assert!(in_range(r.speed_mps, 0.0, 1e5) && in_range(r.track_deg, 0.0, 360.0));
                (r.time, r.lat_deg, r.lon_deg)
            }
            Sentence::Gll(g) => (g.time, g.lat_deg, g.lon_deg),
            Sentence::Gns(g) => {
                assert!(in_range(g.alt_msl_m, -2000.0, 100_000.0), "{s:?}");
                assert!(g.modes.as_bytes().iter().all(u8::is_ascii_uppercase));
                (g.time, g.lat_deg, g.lon_deg)
            }
            Sentence::Vtg(v) => {
                assert!(in_range(v.speed_mps, 0.0, 1e5) && in_range(v.track_deg, 0.0, 360.0));
                (None, None, None)
            }
            Sentence::Gst(g) => (g.time, None, None),
            Sentence::Unsupported { .. } => (None, None, None),
        };
        assert!(
            in_range(time.map(|t| t.seconds_of_day_s), 0.0, 86_401.0),
            "{s:?}"
        );
        assert!(
            in_range(lat, -90.0, 90.0) && in_range(lon, -180.0, 180.0),
            "{s:?}"
        );
        if let Some(f) = s.fix() {
            assert!(s.is_position() && f.lat_deg.abs() <= 90.0 && f.lon_deg.abs() <= 180.0);
        }
    }
    let dollars = data.iter().filter(|&&b| b == b'$').count();
    assert_eq!(
        results + rd.in_sentence() as usize,
        dollars,
        "one result per '$'"
    );
    let st = rd.stats;
    assert_eq!((st.ok + st.unsupported + st.errors()) as usize, results);
}

/// Every non-empty line is one result; a sample is within the Earth-field range.
fn scalar(data: &[u8]) {
    let mut rd = ScalarReader::new(ScalarConfig::default());
    let mut n = 0u32;
    for &b in data {
        if let Some(r) = rd.push(b) {
            n += 1;
            if let Ok(f) = r {
                let nt = f.mag.0 / 10_000;
                assert!((MIN_FIELD_NT..=MAX_FIELD_NT).contains(&nt), "{f:?}");
            }
        }
    }
    assert_eq!(rd.stats.ok + rd.stats.errors + rd.stats.overlong, n);
}

/// Single fields and counter lines (`M,…`): every non-empty line is one result; a
/// counter line carries 2–3 channels, each reading within the Earth-field range.
fn scalar_line(data: &[u8]) {
    let mut rd = ScalarReader::new(ScalarConfig::default());
    let mut n = 0u32;
    let in_range = |m: MagCounts| (MIN_FIELD_NT..=MAX_FIELD_NT).contains(&(m.0 / 10_000));
    for &b in data {
        match rd.push_line(b) {
            None => continue,
            Some(ScalarLine::Single(Ok(f))) => assert!(in_range(f.mag), "{f:?}"),
            Some(ScalarLine::Single(Err(_))) => {}
            Some(ScalarLine::Multi(f)) => {
                assert!((2..=3).contains(&f.channels), "{f:?}");
                assert!(f.ch.iter().filter_map(|c| c.mag()).all(in_range), "{f:?}");
                assert!(f.ch[usize::from(f.channels)..]
                    .iter()
                    .all(|c| c.mag().is_none()));
            }
        }
        n += 1;
    }
    assert_eq!(rd.stats.ok + rd.stats.errors + rd.stats.overlong, n);
}

/// Multi-sensor records (`$MCMREC`): decoding is idempotent after one canonicalisation,
/// as for `$MCREC`.
fn multi_record(data: &[u8]) {
    let mut out = [0u8; MAX_MULTI_RECORD_LEN];
    for line in data.split(|&b| b == b'\n') {
        let Ok(r) = decode_multi_record(line) else {
            continue;
        };
        let Ok(n) = encode_multi_record(&r, &mut out) else {
            continue; // values too long for a record line: refused, fine
        };
        let r2 = decode_multi_record(&out[..n]).expect("an encoded multi record decodes");
        let n2 = encode_multi_record(&r2, &mut out).unwrap();
        let mut again = [0u8; MAX_MULTI_RECORD_LEN];
        let n3 =
            encode_multi_record(&decode_multi_record(&out[..n2]).unwrap(), &mut again).unwrap();
        assert_eq!(&out[..n2], &again[..n3], "{r:?}");
    }
}

fn flux_ascii(data: &[u8]) {
    let mut rd = FluxAsciiReader::new();
    let mut n = 0u32;
    for &b in data {
        if let Some(r) = rd.push_frame(b) {
            n += 1;
            if let Ok((v, t)) = r {
                assert!(v
                    .iter()
                    .all(|x| x.is_finite() && x.abs() as f64 <= MAX_ASCII_NT));
                // The optional 4th field: NaN when absent, else finite within ±200 °C.
                assert!(t.is_nan() || t.abs() <= 200.0, "{t}");
            }
        }
    }
    assert_eq!(rd.stats.ok + rd.stats.errors, n);
}

/// 15-byte frames: decode(encode(frame)) == frame, and the encoding carries the input's
/// status and data words (bytes 2 and 14 are the 24-bit words' padding, and the CRC
/// covers byte 2, so those may differ).
fn flux_spi(data: &[u8]) {
    for chunk in data.chunks(SPI_FRAME_LEN) {
        if let Ok(f) = decode_spi_frame(chunk) {
            assert!(f
                .counts
                .iter()
                .all(|c| (-ADC_FULL_SCALE..ADC_FULL_SCALE).contains(c)));
            let e = encode_spi_frame(f.status, f.counts);
            assert_eq!(decode_spi_frame(&e), Ok(f));
            assert_eq!((&e[..2], &e[3..12]), (&chunk[..2], &chunk[3..12]), "{f:?}");
        }
    }
}

/// Command lines: a parsed command is within bounds and decode(encode(cmd)) == cmd.
fn command(data: &[u8]) {
    const N_COEF: usize = 21;
    let mut rd = CommandReader::new(N_COEF);
    let mut out = [0u8; 128];
    for &b in data {
        let Some(Ok(c)) = rd.push(b) else { continue };
        if let Command::SetCoef { index, value } | Command::SetFlux { index, value } = c {
            assert!(value.is_finite() && value.abs() < MAX_COEF_ABS && (index as usize) < N_COEF);
        }
        if let Command::SetFluxTemp { index, value } = c {
            assert!(value.is_finite() && usize::from(index) < 7);
        }
        if let Command::SetSensorCoef {
            sensor,
            index,
            value,
        } = c
        {
            assert!(value.is_finite() && value.abs() < MAX_COEF_ABS && (index as usize) < N_COEF);
            assert!((1..3).contains(&sensor), "{c:?}");
        }
        if let Command::SetLag(v) = c {
            assert!(
                (0.0..=magcomp_core::protocol::lag_line::MAX_LAG_S).contains(&v),
                "{v}"
            );
        }
        let n = encode_command(&c, &mut out).expect("a parsed command encodes");
        assert_eq!(parse_command(&out[..n], N_COEF), Ok(c), "round trip");
    }
    for line in data.split(|&b| b == b'\n') {
        if let Ok(c) = parse_command(line, N_COEF) {
            let n = encode_command(&c, &mut out).expect("encodes");
            assert_eq!(parse_command(&out[..n], N_COEF), Ok(c));
        }
    }
}

/// Flash blob: a blob that decodes re-encodes to the same bytes.
fn blob(data: &[u8]) {
    let hash = u32::from_le_bytes([data.get(8).copied().unwrap_or(0), 0, 0, 0]) | 0x5A5A_0000;
    for n in [16usize, 12, 7, 1] {
        let mut coef = vec![0f32; n];
        for h in [
            hash,
            magcomp_core::protocol::command::flux_blob_id(),
            magcomp_core::protocol::command::lag_blob_id(),
            magcomp_core::protocol::command::flux_temp_blob_id(),
        ] {
            if decode_blob(data, h, &mut coef).is_ok() {
                assert!(coef.iter().all(|c| c.is_finite()), "{coef:?}");
                let mut out = vec![0u8; blob_len(n)];
                let len = encode_blob(h, &coef, &mut out).unwrap();
                assert_eq!(&out[..len], &data[..len]);
            }
        }
    }
}

/// Output records: decoding is idempotent after one canonicalisation
/// (decode ∘ encode ∘ decode == decode on what decode produced).
fn record(data: &[u8]) {
    let mut out = [0u8; MAX_RECORD_LEN];
    for line in data.split(|&b| b == b'\n') {
        // An empty field is NaN, as the encoder writes it: no finiteness to assert here
        // (the acquisition target asserts it on what the board emits).
        let Ok(r) = decode_record(line) else { continue };
        let Ok(n) = encode_record(&r, &mut out) else {
            continue; // values too long for a record line (e.g. 1e300): refused, fine
        };
        let r2 = decode_record(&out[..n]).expect("an encoded record decodes");
        let n2 = encode_record(&r2, &mut out).unwrap();
        let r3 = decode_record(&out[..n2]).unwrap();
        assert_eq!(bits(&r2), bits(&r3), "{r:?}");
    }
}

/// Raw sample lines (`$MCRAW`): decoding is idempotent after one canonicalisation, as
/// for records.
fn raw(data: &[u8]) {
    let mut out = [0u8; MAX_RAW_LEN];
    for line in data.split(|&b| b == b'\n') {
        let Ok(r) = decode_raw(line) else { continue };
        let Ok(n) = encode_raw(&r, &mut out) else {
            continue; // values too long for a raw line: refused, fine
        };
        let r2 = decode_raw(&out[..n]).expect("an encoded raw line decodes");
        let n2 = encode_raw(&r2, &mut out).unwrap();
        assert_eq!(decode_raw(&out[..n2]).map(|r| r.k), Ok(r2.k), "{r:?}");
        let mut again = [0u8; MAX_RAW_LEN];
        let n3 = encode_raw(&decode_raw(&out[..n2]).unwrap(), &mut again).unwrap();
        assert_eq!(&out[..n2], &again[..n3], "{r:?}");
    }
}

fn bits(r: &Record) -> (u32, u64, Option<i64>, u32, Option<i64>, u32, u32, u16) {
    (
        r.seq,
        r.t_s.to_bits(),
        r.mag.map(|m| m.0),
        r.interference_nt.to_bits(),
        r.compensated.map(|m| m.0),
        r.anomaly_nt.to_bits(),
        r.innovation_nt.to_bits(),
        r.flags.0,
    )
}

/// Capture lines: decode(encode(line)) == line.
fn capture(data: &[u8]) {
    let mut buf = [0u8; MAX_CHUNK];
    let mut buf2 = [0u8; MAX_CHUNK];
    let mut out = [0u8; MAX_LINE + 2];
    for line in data.split(|&b| b == b'\n') {
        let Ok(Some(c)) = decode_line(line, &mut buf) else {
            continue;
        };
        assert!(c.len <= MAX_CHUNK);
        let n = encode_line(c.t_us, c.port, &buf[..c.len], &mut out).expect("encodes");
        let c2 = decode_line(&out[..n], &mut buf2).unwrap().unwrap();
        assert_eq!(
            (c2.t_us, c2.port, &buf2[..c2.len]),
            (c.t_us, c.port, &buf[..c.len])
        );
    }
}

fn model() -> &'static ModelSpec {
    static M: OnceLock<ModelSpec> = OnceLock::new();
    M.get_or_init(|| ModelSpec::parse("tl16+field").unwrap())
}

/// A capture through `magcomp replay`'s path (the board's acquisition): one record per
/// scalar line, contiguous sequence numbers, finite time, and a value that is not finite
/// only on a flagged record.
fn acquisition(data: &[u8]) {
    let mut opts = ReplayOptions::new(model().clone());
    // Half the inputs through the fluxgate's delay line (τ 0.01–0.51 s from the first byte).
    if let Some(&b) = data.first().filter(|b| *b & 1 == 1) {
        opts.lag_s = Some(f32::from(b % 52) * 0.01);
    }
    let mut recs = Vec::new();
    let Ok(st) = replay_capture_any(
        data,
        &opts,
        |r| {
            recs.push(*r);
            Ok(())
        },
        |_| Ok(()),
    ) else {
        return; // refused with an error (e.g. unsupported version): fine
    };
    assert_eq!(recs.len() as u64, st.records);
    assert_eq!(
        st.records, st.counters.scalar_lines as u64,
        "one record per scalar line"
    );
    for (i, rec) in recs.iter().enumerate() {
        assert_eq!(rec.seq() as usize, i);
        match rec {
            AcqRecord::One(r) => {
                assert!(r.t_s.is_finite(), "{r:?}");
                let finite = r.interference_nt.is_finite() && r.innovation_nt.is_finite();
                assert!(finite || r.flags.0 != 0 || r.mag.is_none(), "{r:?}");
                if r.mag.is_none() {
                    assert!(r.compensated.is_none(), "{r:?}");
                }
            }
            AcqRecord::Multi(r) => {
                assert!(r.t_s.is_finite(), "{r:?}");
                for c in &r.ch[..usize::from(r.channels)] {
                    assert!(c.interference_nt.is_finite() || c.flags.0 != 0, "{r:?}");
                    if c.mag.is_none() {
                        assert!(c.compensated.is_none(), "{r:?}");
                        assert!(c.flags.contains(Flags::MAG_MISSING), "{r:?}");
                    }
                }
            }
        }
    }
}

/// The trace reader: an accepted trace is rectangular and its time strictly increasing.
fn trace(data: &[u8]) {
    let Ok(t) = read_trace_from(data, "fuzz", &ColumnMap::new()) else {
        return;
    };
    assert!(t.is_rectangular());
    if let Some(time) = t.col("t") {
        assert!(time.windows(2).all(|w| w[1] > w[0]), "time not increasing");
    }
}
