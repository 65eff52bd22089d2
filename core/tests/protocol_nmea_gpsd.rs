//! Conformance of the NMEA reader against gpsd's regression decodes
//! (`data/reference/nmea/NAME.log` + `NAME.log.chk`).

use magcomp_core::protocol::nmea::{parse_sentence, NmeaError, NmeaReader, Sentence};
use std::path::PathBuf;

fn data_dir() -> Option<PathBuf> {
    // In the repository (gpsd's logs, BSD-2-Clause: data/reference/nmea/NOTICE).
    let d = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../data/reference/nmea");
    d.is_dir().then_some(d)
}

/// One decoded sentence with the quantities gpsd reports.
#[derive(Debug, Clone, Copy)]
struct Decoded {
    kind: &'static str,
    tod_s: Option<f64>,
    lat: Option<f64>,
    lon: Option<f64>,
    alt: Option<f64>,
    speed: Option<f64>,
    track: Option<f64>,
    /// GGA quality > 0 / RMC status A.
    fix: Option<bool>,
}

fn decode(s: &Sentence, cycle_tod: Option<f64>) -> Option<Decoded> {
    match s {
        Sentence::Gga(g) => Some(Decoded {
            kind: "GGA",
            tod_s: g.time.map(|t| t.seconds_of_day_s),
            // gpsd ignores the position of a GGA with quality 0.
            lat: g.lat_deg.filter(|_| g.fix_quality.unwrap_or(0) > 0),
            lon: g.lon_deg.filter(|_| g.fix_quality.unwrap_or(0) > 0),
            alt: g.alt_msl_m.filter(|_| g.fix_quality.unwrap_or(0) > 0),
            speed: None,
            track: None,
            fix: g.fix_quality.map(|q| q > 0),
        }),
        Sentence::Rmc(r) => Some(Decoded {
            kind: "RMC",
            tod_s: r.time.map(|t| t.seconds_of_day_s),
            lat: r.lat_deg.filter(|_| r.valid),
            lon: r.lon_deg.filter(|_| r.valid),
            alt: None,
            speed: r.speed_mps.filter(|_| r.valid),
            track: r.track_deg.filter(|_| r.valid),
            fix: Some(r.valid),
        }),
        Sentence::Gll(g) => Some(Decoded {
            kind: "GLL",
            tod_s: g.time.map(|t| t.seconds_of_day_s),
            lat: g.lat_deg.filter(|_| g.has_fix()),
            lon: g.lon_deg.filter(|_| g.has_fix()),
            alt: None,
            speed: None,
            track: None,
            fix: Some(g.has_fix()),
        }),
        Sentence::Gns(g) => Some(Decoded {
            kind: "GNS",
            tod_s: g.time.map(|t| t.seconds_of_day_s),
            lat: g.lat_deg.filter(|_| g.has_fix()),
            lon: g.lon_deg.filter(|_| g.has_fix()),
            alt: g.alt_msl_m.filter(|_| g.has_fix()),
            speed: None,
            track: None,
            fix: Some(g.has_fix()),
        }),
        Sentence::Vtg(v) => Some(Decoded {
            kind: "VTG",
            tod_s: cycle_tod,
            lat: None,
            lon: None,
            alt: None,
            speed: v.speed_mps,
            track: v.track_deg,
            fix: None,
        }),
        _ => None,
    }
}

fn tod_of(time: &str) -> Option<f64> {
    let t = time.split('T').nth(1)?.trim_end_matches('Z');
    let mut p = t.split(':');
    let h: f64 = p.next()?.parse().ok()?;
    let m: f64 = p.next()?.parse().ok()?;
    let s: f64 = p.next()?.parse().ok()?;
    Some(h * 3600.0 + m * 60.0 + s)
}

#[derive(Default, Debug)]
struct Tally {
    tpv: usize,
    tpv_timed: usize,
    matched: usize,
    /// TPVs with mode 1 (no fix) where our latest GGA/RMC of that second also says no fix.
    no_fix_agreed: usize,
    pos: usize,
    alt: usize,
    speed: usize,
    track: usize,
    /// TPVs with a position, timed or not (gpsd reports a position without time when it
    /// has no date yet, e.g. a log that starts with GLL before the first RMC).
    fixes: usize,
    /// Of those, equal to the position of our latest fix sentence before the TPV: with
    /// every sentence we decode, and with GGA/RMC alone (the reader before GLL/GNS).
    fixes_ours: usize,
    fixes_gga_rmc: usize,
    disagreements: Vec<String>,
    explained: Vec<String>,
    /// gpsd reported a value none of our sentences of that second carried.
    gpsd_only: Vec<String>,
}

fn latest(
    hist: &[Decoded],
    tod: f64,
    pick: impl Fn(&Decoded) -> Option<f64>,
) -> Option<(&Decoded, f64)> {
    hist.iter()
        .rev()
        .take(40)
        .filter(|d| d.tod_s.is_some_and(|t| (t - tod).abs() < 1e-6))
        .find_map(|d| pick(d).map(|v| (d, v)))
}

fn check_log(dir: &std::path::Path, name: &str) -> Tally {
    let log = std::fs::read(dir.join(name)).unwrap();
    stream_log(name, &log);
    check_checksums(name, &log);
    tpv_agreement(dir, name)
}

/// Streams the raw log byte by byte: no panic; every `$` yields exactly one result.
fn stream_log(name: &str, log: &[u8]) {
    let mut rd = NmeaReader::new();
    let mut results = 0usize;
    for &b in log {
        if rd.push(b).is_some() {
            results += 1;
        }
    }
    let dollars = log.iter().filter(|&&b| b == b'$').count();
    assert_eq!(
        results + rd.in_sentence() as usize,
        dollars,
        "{name}: every sentence start accounted for"
    );
    let st = rd.stats;
    assert_eq!(
        (st.ok + st.unsupported + st.errors()) as usize,
        results,
        "{name}: counters add up"
    );
}

/// Verifies every line's checksum independently: a bad one is rejected as a checksum error.
fn check_checksums(name: &str, log: &[u8]) {
    let text = String::from_utf8_lossy(log);
    let mut bad_cs = 0;
    for line in text.lines() {
        let line = line.trim_end_matches(['\r', '\n']);
        if !line.starts_with('$') {
            continue;
        }
        let Some(star) = line.rfind('*') else {
            assert!(
                parse_sentence(line.as_bytes()).is_err(),
                "{name}: no checksum accepted: {line}"
            );
            continue;
        };
        let want = line[1..star].bytes().fold(0u8, |a, b| a ^ b);
        let got = u8::from_str_radix(&line[star + 1..], 16).ok();
        if got != Some(want) && line.len() - star == 3 {
            bad_cs += 1;
            assert!(
                matches!(
                    parse_sentence(line.as_bytes()),
                    Err(NmeaError::Checksum { .. })
                ),
                "{name}: bad checksum accepted: {line}"
            );
        } else if got != Some(want) {
            assert!(parse_sentence(line.as_bytes()).is_err(), "{name}: {line}");
        }
    }
    if bad_cs > 0 {
        println!("  {name}: {bad_cs} sentences with bad checksums rejected");
    }
}

/// Compares each TPV gpsd wrote with what our sentences of the same moment gave.
fn tpv_agreement(dir: &std::path::Path, name: &str) -> Tally {
    let chk = std::fs::read_to_string(dir.join(format!("{name}.chk"))).unwrap();
    let mut hist: Vec<Decoded> = Vec::new();
    let mut cycle_tod = None;
    let mut t = Tally::default();
    let mut last_kind = String::new();
    let mut last_pos: Option<(f64, f64)> = None;
    let mut last_pos_gga_rmc: Option<(f64, f64)> = None;
    for line in chk.lines() {
        if line.starts_with('$') {
            last_kind = line.get(3..6).unwrap_or("").to_string();
            if let Ok(s) = parse_sentence(line.as_bytes()) {
                if let Some(f) = s.fix() {
                    last_pos = Some((f.lat_deg, f.lon_deg));
                    if matches!(s, Sentence::Gga(_) | Sentence::Rmc(_)) {
                        last_pos_gga_rmc = last_pos;
                    }
                }
                if let Some(d) = decode(&s, cycle_tod) {
                    if d.kind != "VTG" {
                        cycle_tod = d.tod_s.or(cycle_tod);
                    }
                    hist.push(d);
                }
            }
            continue;
        }
        if !line.starts_with('{') {
            continue;
        }
        let Ok(v) = serde_json::from_str::<serde_json::Value>(line) else {
            continue;
        };
        if v["class"] != "TPV" {
            continue;
        }
        t.tpv += 1;
        if let (Some(lat), Some(lon)) = (v["lat"].as_f64(), v["lon"].as_f64()) {
            t.fixes += 1;
            let same = |p: Option<(f64, f64)>| {
                p.is_some_and(|(a, b)| (a - lat).abs() <= 1e-6 && (b - lon).abs() <= 1e-6)
            };
            t.fixes_ours += same(last_pos) as usize;
            t.fixes_gga_rmc += same(last_pos_gga_rmc) as usize;
            if !same(last_pos) {
                t.disagreements.push(format!(
                    "{name}: TPV position {lat},{lon} is not our latest fix {last_pos:?}"
                ));
            }
        }
        let Some(tod) = v["time"].as_str().and_then(tod_of) else {
            continue;
        };
        t.tpv_timed += 1;
        let any = compare_values(name, tod, &v, &hist, &mut t);
        compare_fix_state(name, tod, &v, &hist, &last_kind, any, &mut t);
    }
    t
}

/// A timed TPV's position, height, speed and track against our latest values of that
/// second; true when we had any of them.
fn compare_values(
    name: &str,
    tod: f64,
    v: &serde_json::Value,
    hist: &[Decoded],
    t: &mut Tally,
) -> bool {
    let mut any = false;
    let mut ok = true;
    let mut gpsd_only = Vec::new();
    let mut cmp =
        |what: &str, gpsd: Option<f64>, ours: Option<(&Decoded, f64)>, tol: f64, n: &mut usize| {
            if let (Some(g), None) = (gpsd, ours) {
                gpsd_only.push(format!("{name} {tod}: {what} gpsd {g}, none from us"));
            }
            if let (Some(g), Some((d, o))) = (gpsd, ours) {
                any = true;
                if (g - o).abs() <= tol {
                    *n += 1;
                } else {
                    ok = false;
                    t.disagreements.push(format!(
                        "{name} {tod}: {what} gpsd {g} ours {o} ({})",
                        d.kind
                    ));
                }
            }
        };
    cmp(
        "lat",
        v["lat"].as_f64(),
        latest(hist, tod, |d| d.lat),
        1e-6,
        &mut t.pos,
    );
    cmp(
        "lon",
        v["lon"].as_f64(),
        latest(hist, tod, |d| d.lon),
        1e-6,
        &mut 0,
    );
    let galt = v["altMSL"].as_f64().or(v["alt"].as_f64());
    cmp("alt", galt, latest(hist, tod, |d| d.alt), 1e-3, &mut t.alt);
    // gpsd prints speed with 3 decimals.
    cmp(
        "speed",
        v["speed"].as_f64(),
        latest(hist, tod, |d| d.speed),
        6e-4,
        &mut t.speed,
    );
    cmp(
        "track",
        v["track"].as_f64(),
        latest(hist, tod, |d| d.track),
        1e-4,
        &mut t.track,
    );
    if any && ok {
        t.matched += 1;
    }
    t.gpsd_only.extend(gpsd_only);
    any
}

/// The TPV's fix state (gpsd mode 1 ⇔ our sentence of that second says no fix; 2-D vs
/// 3-D comes from GSA, which we do not decode).
fn compare_fix_state(
    name: &str,
    tod: f64,
    v: &serde_json::Value,
    hist: &[Decoded],
    last_kind: &str,
    any: bool,
    t: &mut Tally,
) {
    let mode = v["mode"].as_u64().unwrap_or(0);
    // The most recent GGA/RMC, timed or not (a receiver losing its fix sends them
    // with empty time fields).
    let last_fix = hist.iter().rev().find_map(|d| d.fix.map(|f| (d, f)));
    if let Some((d, f)) = last_fix {
        if f != (mode >= 2) && last_kind == "GSA" {
            // gpsd takes the fix mode from GSA (`$GPGSA,A,1` = no fix), which we do
            // not decode: explained, not a decoding disagreement.
            t.explained.push(format!(
                "{name} {tod}: mode {mode} from GSA, our {} says fix={f}",
                d.kind
            ));
        } else if f != (mode >= 2) {
            t.disagreements.push(format!(
                "{name} {tod}: mode gpsd {mode}, ours fix={f} ({})",
                d.kind
            ));
        } else if mode == 1 && !f && !any {
            t.no_fix_agreed += 1;
        }
    }
}

#[test]
fn gpsd_conformance() {
    let Some(dir) = data_dir() else {
        println!("SKIP: data/reference/nmea not found");
        return;
    };
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.ends_with(".log"))
        .collect();
    names.sort();
    assert!(!names.is_empty());
    let mut total_dis = 0;
    let (mut fixes, mut ours, mut gga_rmc) = (0, 0, 0);
    for n in &names {
        let t = check_log(&dir, n);
        fixes += t.fixes;
        ours += t.fixes_ours;
        gga_rmc += t.fixes_gga_rmc;
        println!(
            "{n}: TPV {} (timed {}), fixes {} (ours {}, GGA/RMC alone {}), matched {} + no-fix agreed {} | pos {} alt {} speed {} track {} | disagreements {}",
            t.tpv,
            t.tpv_timed,
            t.fixes,
            t.fixes_ours,
            t.fixes_gga_rmc,
            t.matched,
            t.no_fix_agreed,
            t.pos,
            t.alt,
            t.speed,
            t.track,
            t.disagreements.len()
        );
        // Every timed TPV is accounted for: values matched, or agreed no-fix.
        if t.matched + t.no_fix_agreed != t.tpv_timed {
            println!(
                "    {} timed TPVs had nothing to compare",
                t.tpv_timed - t.matched - t.no_fix_agreed
            );
        }
        assert!(t.matched > 0, "{n}: no TPV matched");
        for d in t.disagreements.iter().take(5) {
            println!("    DISAGREE {d}");
        }
        for d in t.gpsd_only.iter().take(3) {
            println!("    gpsd-only ({} total): {d}", t.gpsd_only.len());
        }
        for d in &t.explained {
            println!("    explained: {d}");
        }
        total_dis += t.disagreements.len();
        // gpsd derives speed/track from successive positions when a cycle's sentences lack
        // them (GGA-only TPV before the RMC arrives); a position or height we failed to
        // decode would be a real miss.
        let missed: Vec<_> = t
            .gpsd_only
            .iter()
            .filter(|d| !(d.contains(": speed ") || d.contains(": track ")))
            .collect();
        assert!(
            missed.is_empty(),
            "{n}: gpsd decoded what we did not: {missed:?}"
        );
    }
    println!("positions gpsd reports: {fixes}; ours: {ours}; from GGA/RMC alone: {gga_rmc}");
    assert_eq!(ours, fixes, "every position gpsd reports is decoded");
    assert_eq!(total_dis, 0, "unexplained disagreements with gpsd");
}
