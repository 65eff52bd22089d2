//! `magcomp nmea FILE`: decode an NMEA log with the board's own reader
//! (`magcomp_core::protocol::nmea`) and print one JSON object per decoded or rejected line.

use anyhow::{Context, Result};
use magcomp_core::protocol::nmea::{parse_sentence, NmeaError, Sentence};
use serde_json::{Map, Value};
use std::io::{BufRead, Write};

/// What [`decode_log`] saw.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct NmeaLogStats {
    /// Lines read (including blank and `#` comment lines).
    pub lines: u64,
    /// GGA/RMC/GLL/GNS/VTG/GST decoded.
    pub decoded: u64,
    /// Valid checksum, sentence type not decoded.
    pub unsupported: u64,
    /// Lines rejected (bad checksum, no checksum, bad field...).
    pub errors: u64,
    /// Of which checksum mismatches.
    pub checksum_errors: u64,
}

fn error_text(e: &NmeaError) -> String {
    match e {
        NmeaError::Checksum { received, computed } => {
            format!("checksum: received {received:02X}, computed {computed:02X}")
        }
        NmeaError::MissingChecksum => "missing checksum".into(),
        NmeaError::Overlong => "overlong sentence".into(),
        NmeaError::Interrupted => "interrupted sentence".into(),
        NmeaError::BadCharacter => "non-printable character".into(),
        NmeaError::BadAddress => "bad address field".into(),
        NmeaError::MissingField(f) => format!("missing field: {f:?}"),
        NmeaError::InvalidField(f) => format!("invalid field: {f:?}"),
    }
}

fn put(m: &mut Map<String, Value>, k: &str, v: Option<f64>) {
    if let Some(v) = v.filter(|v| v.is_finite()) {
        m.insert(k.into(), Value::from(v));
    }
}

/// An f32 as the f64 of its shortest decimal: HDOP 0.8 is printed `0.8`, not the f32's
/// exact binary value `0.800000011920929`.
fn f32_decimal(v: f32) -> f64 {
    v.to_string().parse().unwrap_or(f64::from(v))
}

/// JSON object for a decoded sentence (`None` for unsupported types).
pub fn sentence_json(line: u64, s: &Sentence) -> Option<Value> {
    let mut m = Map::new();
    m.insert("line".into(), line.into());
    m.insert("sentence".into(), s.kind().into());
    match s {
        Sentence::Gga(g) => {
            put(&mut m, "time_s", g.time.map(|t| t.seconds_of_day_s));
            put(&mut m, "lat_deg", g.lat_deg);
            put(&mut m, "lon_deg", g.lon_deg);
            put(&mut m, "alt_msl_m", g.alt_msl_m);
            put(&mut m, "geoid_sep_m", g.geoid_sep_m);
            if let Some(q) = g.fix_quality {
                m.insert("fix".into(), q.into());
            }
            if let Some(n) = g.satellites {
                m.insert("sats".into(), n.into());
            }
            put(&mut m, "hdop", g.hdop.map(f32_decimal));
        }
        Sentence::Rmc(r) => {
            put(&mut m, "time_s", r.time.map(|t| t.seconds_of_day_s));
            put(&mut m, "lat_deg", r.lat_deg);
            put(&mut m, "lon_deg", r.lon_deg);
            put(&mut m, "speed_mps", r.speed_mps);
            put(&mut m, "track_deg", r.track_deg);
            m.insert("status".into(), if r.valid { "A" } else { "V" }.into());
            if let Some(d) = r.date {
                m.insert(
                    "date".into(),
                    format!("{:04}-{:02}-{:02}", d.year, d.month, d.day).into(),
                );
            }
            if let Some(c) = r.mode {
                m.insert("mode".into(), (c as char).to_string().into());
            }
        }
        Sentence::Gll(g) => {
            put(&mut m, "time_s", g.time.map(|t| t.seconds_of_day_s));
            put(&mut m, "lat_deg", g.lat_deg);
            put(&mut m, "lon_deg", g.lon_deg);
            m.insert("status".into(), if g.valid { "A" } else { "V" }.into());
            if let Some(c) = g.mode {
                m.insert("mode".into(), (c as char).to_string().into());
            }
        }
        Sentence::Gns(g) => {
            put(&mut m, "time_s", g.time.map(|t| t.seconds_of_day_s));
            put(&mut m, "lat_deg", g.lat_deg);
            put(&mut m, "lon_deg", g.lon_deg);
            put(&mut m, "alt_msl_m", g.alt_msl_m);
            put(&mut m, "geoid_sep_m", g.geoid_sep_m);
            m.insert(
                "mode".into(),
                String::from_utf8_lossy(g.modes.as_bytes())
                    .into_owned()
                    .into(),
            );
            if let Some(n) = g.satellites {
                m.insert("sats".into(), n.into());
            }
            put(&mut m, "hdop", g.hdop.map(f32_decimal));
            if let Some(c) = g.nav_status {
                m.insert("nav_status".into(), (c as char).to_string().into());
            }
        }
        Sentence::Vtg(v) => {
            put(&mut m, "speed_mps", v.speed_mps);
            put(&mut m, "track_deg", v.track_deg);
            if let Some(c) = v.mode {
                m.insert("mode".into(), (c as char).to_string().into());
            }
        }
        Sentence::Gst(g) => {
            put(&mut m, "time_s", g.time.map(|t| t.seconds_of_day_s));
            put(&mut m, "rms_m", g.rms_m);
            put(&mut m, "sigma_lat_m", g.sigma_lat_m);
            put(&mut m, "sigma_lon_m", g.sigma_lon_m);
            put(&mut m, "sigma_alt_m", g.sigma_alt_m);
        }
        Sentence::Unsupported { .. } => return None,
    }
    if s.is_position() {
        // One yes/no for every position sentence: GGA quality > 0, RMC/GLL status A,
        // GNS with a constellation in use (GLL/GNS mode N is no fix).
        m.insert("has_fix".into(), s.fix().is_some().into());
    }
    Some(Value::Object(m))
}

/// Decodes every line of `input`; blank and `#` lines are skipped silently.
pub fn decode_log(mut input: impl BufRead, mut out: impl Write) -> Result<NmeaLogStats> {
    let mut st = NmeaLogStats::default();
    let mut buf = Vec::new();
    loop {
        buf.clear();
        // NMEA sentences are ≤ 82 characters: a longer "line" (`/dev/zero`) is not a log.
        if crate::io::bounded::read_line_bounded(&mut input, &mut buf, 4096)
            .with_context(|| format!("line {}", st.lines + 1))?
            == 0
        {
            break;
        }
        st.lines += 1;
        let line = buf.trim_ascii();
        if line.is_empty() || line[0] == b'#' {
            continue;
        }
        match parse_sentence(line) {
            Ok(s) => match sentence_json(st.lines, &s) {
                Some(v) => {
                    st.decoded += 1;
                    writeln!(out, "{v}")?;
                }
                None => st.unsupported += 1,
            },
            Err(e) => {
                st.errors += 1;
                if matches!(e, NmeaError::Checksum { .. }) {
                    st.checksum_errors += 1;
                }
                let v = serde_json::json!({"line": st.lines, "error": error_text(&e)});
                writeln!(out, "{v}")?;
            }
        }
    }
    Ok(st)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decodes_and_rejects() {
        let input = "# header\n\
$GNGGA,171926.00,4404.14063,N,12118.85478,W,1,12,0.91,1147.2,M,-21.3,M,,*44\r\n\
$GNRMC,171926.00,A,4404.14063,N,12118.85478,W,0.117,,180315,,,A*76\r\n\
$GNVTG,,T,,M,0.117,N,0.216,K,A*3F\r\n\
$GNGGA,171926.00,4404.14063,N,12118.85478,W,1,12,0.91,1147.2,M,-21.3,M,,*45\r\n\
$GPGSV,4,4,13,32,76,331,31*48\r\n\
garbage\n";
        let mut out = Vec::new();
        let st = decode_log(input.as_bytes(), &mut out).unwrap();
        assert_eq!(
            st,
            NmeaLogStats {
                lines: 7,
                decoded: 3,
                unsupported: 1,
                errors: 2,
                checksum_errors: 1
            }
        );
        let v: Vec<Value> = String::from_utf8(out)
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(v.len(), 5);
        assert_eq!(v[0]["line"], 2);
        assert_eq!(v[0]["sentence"], "GGA");
        assert_eq!(v[0]["time_s"], 62366.0);
        assert!((v[0]["lat_deg"].as_f64().unwrap() - 44.069_010_5).abs() < 1e-9);
        assert!((v[0]["lon_deg"].as_f64().unwrap() + 121.314_246_333).abs() < 1e-9);
        assert_eq!(v[0]["alt_msl_m"], 1147.2);
        assert_eq!(v[0]["fix"], 1);
        assert!(v[0].get("speed_mps").is_none());
        assert!((v[1]["speed_mps"].as_f64().unwrap() - 0.117 * 1852.0 / 3600.0).abs() < 1e-12);
        assert!(v[1].get("track_deg").is_none());
        assert_eq!(v[2]["sentence"], "VTG");
        assert_eq!(v[3]["line"], 5);
        assert!(v[3]["error"].as_str().unwrap().starts_with("checksum"));
        assert_eq!(v[4]["line"], 7);
    }

    #[test]
    fn gll_and_gns_fixes_are_shown() {
        let input = "$GNGLL,4404.14066,N,12118.85481,W,171925.00,A,A*66\r\n\
$GPGLL,,,,,171926.00,V,N*40\r\n\
$GNGNS,171927.00,4404.14066,N,12118.85481,W,AAN,14,0.9,1147.2,-21.3,,,S*6A\r\n\
$GNGNS,171928.00,,,,,NNN,00,,,,,,V*4D\r\n";
        let mut out = Vec::new();
        let st = decode_log(input.as_bytes(), &mut out).unwrap();
        assert_eq!(
            (st.decoded, st.errors),
            (4, 0),
            "{}",
            String::from_utf8_lossy(&out)
        );
        let v: Vec<Value> = String::from_utf8(out)
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(v[0]["sentence"], "GLL");
        assert_eq!(v[0]["time_s"], 62365.0);
        assert!((v[0]["lat_deg"].as_f64().unwrap() - 44.069_011).abs() < 1e-9);
        assert_eq!(
            (&v[0]["status"], &v[0]["has_fix"]),
            (&"A".into(), &true.into())
        );
        assert_eq!(
            (&v[1]["status"], &v[1]["has_fix"]),
            (&"V".into(), &false.into())
        );
        assert_eq!(v[2]["sentence"], "GNS");
        assert_eq!(v[2]["mode"], "AAN");
        assert_eq!(
            (&v[2]["alt_msl_m"], &v[2]["sats"]),
            (&1147.2.into(), &14.into())
        );
        assert_eq!(v[2]["has_fix"], true);
        assert_eq!(
            (&v[3]["mode"], &v[3]["has_fix"]),
            (&"NNN".into(), &false.into())
        );
    }
}
