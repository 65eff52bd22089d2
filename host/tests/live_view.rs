//! `magcomp monitor --web`: the live chart-recorder page, in headless Chromium (skipped with
//! a message when it is not installed) and at the websocket.
//!
//! The browser test plays a recorded 10 Hz stream at its own pace (`--realtime`): a boot
//! banner, a calibration converging, garbage lines and a record with a broken CRC, three
//! lost records, a degraded record, a board reset (banner, sequence and clock start again).
//! Chromium is driven over its DevTools protocol and the page's hidden `#plotted` element
//! (what its charts hold, read back from uPlot) is polled in real time. Checked: the
//! plotted values equal the stream's (the 4th difference against this file's own), live
//! updates arrive at 10 Hz, the browser reports no console error or exception, each alarm
//! is on the banner within 1 s of being sent, and the page follows the stream through the
//! garbage and the reset to its last record.
//!
//! The socket test pulls the "cable" (a TCP source closes mid-stream) and checks the server
//! says so, reconnects, and goes on with the records.
//!
//! With `$MCRAW` lines (a simulated calibration pattern and a survey line through `replay
//! --raw --records`): every record's height and GPS state equal its raw line's, and one FOM
//! table arrives, after the pattern's end and the quiet time, with the figures the host's
//! own report path gives for the same lines (computed here through the library). The same
//! lines flown twice give a second table over the second pattern's rows, which the page
//! shows (with its number and time) beside the heights. Without raw lines the page says
//! `RAW,ON` is needed.

use magcomp_core::protocol::common::crc16_ccitt;
use magcomp_core::protocol::raw::decode_raw;
use magcomp_core::protocol::record::{decode_record, encode_record, Record, MAX_RECORD_LEN};
use magcomp_core::{Flags, MagCounts};
use serde_json::{json, Value};
use std::io::Write;
use std::net::{TcpListener, TcpStream};
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

mod common;
use common::CHROMIUM;
#[path = "common/live_page.rs"]
mod live_page;
use live_page::{numbers, read_until, start_server, ws_connect, Page};

fn sentence(body: &str) -> String {
    format!("${body}*{:04X}\r\n", crc16_ccitt(body.as_bytes()))
}

fn record_line(r: &Record) -> String {
    let mut b = [0u8; MAX_RECORD_LEN];
    let n = encode_record(r, &mut b).unwrap();
    String::from_utf8(b[..n].to_vec()).unwrap()
}

/// A record of a smooth field with a few counts of deterministic noise.
fn rec(seq: u32, t_s: f64, flags: u16) -> Record {
    let k = f64::from(seq);
    let noise = ((seq.wrapping_mul(2_654_435_761) >> 20) % 601) as i64 - 300; // ±0.03 nT
    let mag = MagCounts(515_000_000 + (20_000.0 * (0.05 * k).sin()) as i64 + noise);
    let interf = (12.5 + 3.0 * (0.3 * k).sin()) as f32;
    Record {
        seq,
        t_s,
        mag: Some(mag),
        interference_nt: interf,
        compensated: Record::compensate(Some(mag), interf),
        anomaly_nt: 0.5,
        innovation_nt: 0.01,
        sigma_nt: 0.25,
        flags: Flags(flags),
    }
}

/// Seq of the injected events in the first boot.
const LOST: std::ops::Range<u32> = 30..33;
const DEGRADED_AT: u32 = 40;
const CONVERGED_AT: u32 = 15;
const FIRST_BOOT: u32 = 55;
const SECOND_BOOT: u32 = 40;

/// The scripted stream: 10 Hz, ~9 s.
fn stream() -> String {
    let mut s = sentence("MCBOOT,emu-f405,0.1.0,RST=POR");
    for seq in 0..FIRST_BOOT {
        if LOST.contains(&seq) {
            continue;
        }
        let mut flags = 0;
        if seq < CONVERGED_AT {
            flags |= Flags::NOT_CONVERGED;
        }
        if seq == DEGRADED_AT {
            flags |= Flags::FLUX_STALE;
        }
        let line = record_line(&rec(seq, 1000.0 + f64::from(seq) * 0.1, flags));
        if seq == 20 {
            // A garbage line and a copy of the record with one digit changed (CRC fails).
            s.push_str("\u{1}\u{7f}noise ~~~ $MC\r\n");
            s.push_str(&line.replacen(",20,", ",21,", 1));
        }
        s.push_str(&line);
    }
    // The board resets: banner, then its sequence and clock start again.
    s.push_str(&sentence("MCBOOT,emu-f405,0.1.0,RST=PIN"));
    for seq in 0..SECOND_BOOT {
        s.push_str(&record_line(&rec(seq, 5.0 + f64::from(seq) * 0.1, 0)));
    }
    s
}

/// The stream's records as the core decodes them, in order.
fn decoded(stream: &str) -> Vec<Record> {
    stream
        .lines()
        .filter_map(|l| decode_record(l.as_bytes()).ok())
        .collect()
}

/// This file's own 4th difference (1/16-normalised) per record, centred, over runs of
/// consecutive sequence numbers.
fn expected_d4(recs: &[Record]) -> Vec<Option<f64>> {
    let mut d4 = vec![None; recs.len()];
    for i in 2..recs.len().saturating_sub(2) {
        let w = &recs[i - 2..=i + 2];
        if w.windows(2).all(|p| p[1].seq == p[0].seq + 1) {
            let x: Vec<i64> = w.iter().map(|r| r.compensated.unwrap().0).collect();
            let c = x[0] - 4 * x[1] + 6 * x[2] - 4 * x[3] + x[4];
            d4[i] = Some(c as f64 / 16.0 / 1e4);
        }
    }
    d4
}

#[test]
fn page_plots_the_stream_live_through_garbage_and_a_reset() {
    if !Path::new(CHROMIUM).exists() {
        println!("SKIP: {CHROMIUM} not installed (apt-get install chromium)");
        return;
    }
    let t0 = Instant::now();
    let dir = tempfile::tempdir().unwrap();
    let text = stream();
    let file = dir.path().join("records.txt");
    std::fs::write(&file, &text).unwrap();
    let (server, url) = start_server(&["--realtime", file.to_str().unwrap()]);
    let (chrome, mut page) = Page::open(&url, &dir.path().join("profile"));

    // Poll in real time until the last record of the second boot is on the page.
    let recs = decoded(&text);
    let last_seq = recs.last().unwrap().seq;
    let mut p = Value::Null;
    while t0.elapsed() < Duration::from_secs(25) {
        p = page.plotted();
        let seqs = numbers(&p["seq"]);
        if seqs.len() == recs.len() && seqs.last() == Some(&Some(f64::from(last_seq))) {
            break;
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    let errors_dom = page.text_of("errors");
    let status = page.text_of("status");
    let alt_note = page.text_of("alt-note");
    let note_class = page.call(
        "Runtime.evaluate",
        json!({"expression": "document.getElementById('alt-note').className",
               "returnByValue": true}),
    );
    drop(chrome);
    drop(server);

    // No raw line in the stream: no height, and the page says what would bring it.
    assert!(
        numbers(&p["alt"]).iter().all(Option::is_none),
        "{}",
        p["alt"]
    );
    assert_eq!(note_class["result"]["value"], "note", "the note is hidden");
    assert!(alt_note.contains("$MCCMD,RAW,ON"), "{alt_note}");

    // Plotted values equal the stream's: every decoded record, in order, exactly.
    let seqs = numbers(&p["seq"]);
    assert_eq!(seqs.len(), recs.len(), "page holds {seqs:?}");
    let nt = |c: Option<MagCounts>| c.map(MagCounts::to_nt_f64);
    let as_sent = |v: f32| format!("{v:.4}").parse::<f64>().ok();
    let (raw, comp, interf) = (
        numbers(&p["raw"]),
        numbers(&p["comp"]),
        numbers(&p["interf"]),
    );
    for (i, r) in recs.iter().enumerate() {
        assert_eq!(seqs[i], Some(f64::from(r.seq)), "seq at {i}");
        assert_eq!(raw[i], nt(r.mag), "raw at seq {}", r.seq);
        assert_eq!(comp[i], nt(r.compensated), "compensated at seq {}", r.seq);
        assert_eq!(
            interf[i],
            as_sent(r.interference_nt),
            "interference at {}",
            r.seq
        );
    }
    let d4 = numbers(&p["d4"]);
    let want = expected_d4(&recs);
    assert_eq!(d4.len(), want.len());
    for (i, (got, want)) in d4.iter().zip(&want).enumerate() {
        match (got, want) {
            (Some(g), Some(w)) => assert!((g - w).abs() < 1e-12, "d4 at {i}: {g} vs {w}"),
            _ => assert_eq!(got, want, "d4 at {i} (seq {})", recs[i].seq),
        }
    }
    assert!(
        want.iter().flatten().count() >= 80,
        "{}",
        want.iter().flatten().count()
    );
    // The chart time keeps increasing across the reset.
    let x = numbers(&p["x"]);
    assert!(x.windows(2).all(|w| w[1] > w[0]), "{x:?}");

    // Live updates at the stream's rate (10 Hz): every record after the page connected.
    let recv: Vec<f64> = numbers(&p["recv_unix_ms"]).into_iter().flatten().collect();
    let live = p["live_updates"].as_u64().unwrap();
    let backlog = p["backlog_records"].as_u64().unwrap();
    assert_eq!(
        live + backlog,
        recs.len() as u64,
        "{live} live + {backlog} backlog"
    );
    assert!(live >= 50, "only {live} live updates");
    let span_s = (recv[recv.len() - 1] - recv[0]) / 1e3;
    let rate_hz = (recv.len() - 1) as f64 / span_s;
    println!("live updates {live} (backlog {backlog}) at {rate_hz:.2} Hz");
    assert!((rate_hz - 10.0).abs() < 1.0, "update rate {rate_hz:.2} Hz");

    // No console error or exception, from the browser's side and the page's own record.
    assert!(page.console_errors.is_empty(), "{:?}", page.console_errors);
    assert!(errors_dom.is_empty(), "{errors_dom}");

    // Each alarm reached the banner within 1 s of being sent (those sent while connected).
    let log = p["alarm_log"].as_array().unwrap();
    let first_live_ms = recv[0];
    let mut seen = Vec::new();
    for a in log {
        let (sent, shown) = (
            a["sent_unix_ms"].as_f64().unwrap(),
            a["shown_unix_ms"].as_f64().unwrap(),
        );
        if sent >= first_live_ms {
            let name = a["alarm"].as_str().unwrap().to_string();
            println!(
                "alarm {name} at seq {} after {:.0} ms",
                a["seq"],
                shown - sent
            );
            assert!(shown - sent < 1000.0, "{a}");
            seen.push(name);
        }
    }
    // The garbage comes at 2 s, near when the page connects: when it was sent before the
    // first live record arrived, it is not one of the alarms judged live above (`backlog >
    // 20`, the test before, missed a page that connected with 19 records of backlog).
    let garbage_before_live = log
        .iter()
        .any(|a| a["alarm"] == "GARBAGE" && a["sent_unix_ms"].as_f64().unwrap() < first_live_ms);
    for name in ["LOST", "DEGRADED", "BOARD", "GARBAGE"] {
        if name == "GARBAGE" && garbage_before_live {
            continue;
        }
        assert!(
            seen.iter().any(|s| s == name),
            "{name} not seen live: {log:?}"
        );
    }
    assert!(status.contains("restarts 1"), "{status}");
    assert!(status.contains("lost 3"), "{status}");
    println!("browser test took {:.1} s", t0.elapsed().as_secs_f64());
}

#[test]
fn a_pulled_cable_is_reported_and_the_port_reopened() {
    let board = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = board.local_addr().unwrap().port();
    let source = format!("tcp:127.0.0.1:{port}");
    let (server, url) = start_server(&[&source]);
    let ws_url = format!("{}ws", url.replace("http://", "ws://"));
    let mut ws = ws_connect(&ws_url);

    let send = |conn: &mut TcpStream, seqs: std::ops::Range<u32>| {
        for s in seqs {
            conn.write_all(record_line(&rec(s, f64::from(s) * 0.1, 0)).as_bytes())
                .unwrap();
        }
        // Half a record, then the cable goes: it must not glue onto the next line.
        conn.write_all(b"$MCREC,99,12.3").unwrap();
        conn.flush().unwrap();
    };
    let (mut c1, _) = board.accept().unwrap();
    send(&mut c1, 0..10);
    let first = read_until(&mut ws, |v| v["kind"] == "record" && v["seq"] == 9);
    drop(c1);
    let lost = read_until(&mut ws, |v| v["kind"] == "link" && v["up"] == false);
    assert!(
        lost.last().unwrap()["text"]
            .as_str()
            .unwrap()
            .contains("lost"),
        "{lost:?}"
    );
    // The board comes back (after a reset): the server reconnects within its 1 s period.
    let t_down = Instant::now();
    let (mut c2, _) = board.accept().unwrap();
    let reconnect_s = t_down.elapsed().as_secs_f64();
    send(&mut c2, 0..10);
    let back = read_until(&mut ws, |v| v["kind"] == "record" && v["seq"] == 9);
    drop(server);

    let records = |v: &[Value]| v.iter().filter(|m| m["kind"] == "record").count();
    assert_eq!(records(&first) + records(&lost), 10, "{first:?}");
    assert!(back.iter().any(|m| m["kind"] == "link" && m["up"] == true));
    assert_eq!(records(&back), 10, "{back:?}");
    let restart = back.iter().find(|m| m["seq"] == 0).unwrap();
    assert!(
        restart["alarms"]
            .as_array()
            .unwrap()
            .iter()
            .any(|a| a == "BOARD RESTART"),
        "{restart}"
    );
    assert!(reconnect_s < 2.5, "reconnected after {reconnect_s:.1} s");
}

#[test]
fn a_device_stty_refuses_is_reported_and_retried() {
    // /dev/null is a device but not a terminal: `stty` fails, the page is told why, and
    // the server keeps trying (as for an adapter not plugged in yet).
    let (server, url) = start_server(&["--stty", "raw -echo", "/dev/null"]);
    let mut ws = ws_connect(&format!("{}ws", url.replace("http://", "ws://")));
    let got = read_until(&mut ws, |v| v["kind"] == "link");
    drop(server);
    let link = got.last().unwrap();
    assert_eq!(link["up"], false, "{link}");
    let text = link["text"].as_str().unwrap();
    assert!(
        text.contains("cannot open /dev/null") && text.contains("stty"),
        "{text}"
    );
}

#[test]
fn several_sensors_are_drawn_with_their_gradient() {
    if !Path::new(CHROMIUM).exists() {
        println!("SKIP: {CHROMIUM} not installed (apt-get install chromium)");
        return;
    }
    // Two boards, same record times; the second's field is 1.5 nT higher (15 000 counts).
    let dir = tempfile::tempdir().unwrap();
    let n = 30;
    let mut files = Vec::new();
    let mut want = Vec::new();
    for (k, offset) in [0i64, 15_000].into_iter().enumerate() {
        let recs: Vec<Record> = (0..n)
            .map(|s| {
                let mut r = rec(s, 50.0 + f64::from(s) * 0.1, 0);
                r.mag = r.mag.map(|m| MagCounts(m.0 + offset));
                r.compensated = Record::compensate(r.mag, r.interference_nt);
                r
            })
            .collect();
        let f = dir.path().join(format!("board{k}.txt"));
        std::fs::write(&f, recs.iter().map(record_line).collect::<String>()).unwrap();
        files.push(f.to_str().unwrap().to_string());
        want.push(recs);
    }
    let (server, url) = start_server(&["--realtime", &files[0], "--also", &files[1]]);
    let (chrome, mut page) = Page::open(&url, &dir.path().join("profile"));
    let t0 = Instant::now();
    let mut p = Value::Null;
    while t0.elapsed() < Duration::from_secs(15) {
        p = page.plotted();
        let done = p["streams"]
            .as_array()
            .is_some_and(|s| s.iter().all(|s| numbers(&s["seq"]).len() == n as usize));
        // The gradient strip is drawn on the page's next redraw after both streams' last
        // record: wait for it too, or the snapshot can miss its last point under load.
        let gradient_drawn = numbers(&p["gradient"][0]).iter().flatten().count() == n as usize;
        if done && gradient_drawn {
            break;
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    let errors_dom = page.text_of("errors");
    drop(chrome);
    drop(server);

    for (k, recs) in want.iter().enumerate() {
        let comp = numbers(&p["streams"][k]["comp"]);
        let expect: Vec<Option<f64>> = recs
            .iter()
            .map(|r| r.compensated.map(MagCounts::to_nt_f64))
            .collect();
        assert_eq!(comp, expect, "stream {k}");
    }
    let g = numbers(&p["gradient"][0]);
    let g: Vec<f64> = g.into_iter().flatten().collect();
    assert_eq!(g.len(), n as usize, "{:?}", p["gradient"]);
    assert!(g.iter().all(|v| (v - 1.5).abs() < 1e-9), "{g:?}");
    assert!(page.console_errors.is_empty(), "{:?}", page.console_errors);
    assert!(errors_dom.is_empty(), "{errors_dom}");
}

/// One board reading three magnetometers (`$MCMREC`): the page draws each channel's compensated
/// field, its flags (channel 2 dead for 5 records), the pair differences, all exactly the line's.
#[test]
fn a_several_sensor_board_draws_each_channel_and_the_pair_differences() {
    use magcomp_core::protocol::multi_record::{
        encode_multi_record, ChannelRecord, MultiRecord, MAX_MULTI_RECORD_LEN,
    };
    if !Path::new(CHROMIUM).exists() {
        println!("SKIP: {CHROMIUM} not installed (apt-get install chromium)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (n, dead) = (30u32, 10..15u32);
    let recs: Vec<MultiRecord> = (0..n)
        .map(|s| {
            let ch = |c: i64| {
                let base = rec(s, 0.0, 0);
                let missing = c == 1 && dead.contains(&s);
                let mag = base
                    .mag
                    .map(|m| MagCounts(m.0 + 15_000 * c))
                    .filter(|_| !missing);
                ChannelRecord {
                    mag,
                    interference_nt: base.interference_nt,
                    compensated: Record::compensate(mag, base.interference_nt),
                    sigma_nt: 0.25,
                    flags: Flags(if missing { Flags::MAG_MISSING } else { 0 }),
                }
            };
            MultiRecord::new(s, 50.0 + f64::from(s) * 0.1, 3, [ch(0), ch(1), ch(2)])
        })
        .collect();
    let (mut b, mut text) = ([0u8; MAX_MULTI_RECORD_LEN], Vec::new());
    for r in &recs {
        let k = encode_multi_record(r, &mut b).unwrap();
        text.extend_from_slice(&b[..k]);
    }
    let f = dir.path().join("multi.txt");
    std::fs::write(&f, text).unwrap();
    let (server, url) = start_server(&["--realtime", f.to_str().unwrap()]);
    let (chrome, mut page) = Page::open(&url, &dir.path().join("profile"));
    let t0 = Instant::now();
    let mut p = Value::Null;
    while t0.elapsed() < Duration::from_secs(15) {
        p = page.plotted();
        let drawn = |v: &Value| numbers(v).len() == n as usize;
        if (0..3).all(|c| drawn(&p["channels"][c]["comp"]) && drawn(&p["diffs"][c])) {
            break;
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    let errors_dom = page.text_of("errors");
    drop((chrome, server));
    let nt = |c: Option<MagCounts>| c.map(MagCounts::to_nt_f64);
    for c in 0..3 {
        let want: Vec<Option<f64>> = recs.iter().map(|r| nt(r.ch[c].compensated)).collect();
        assert_eq!(
            numbers(&p["channels"][c]["comp"]),
            want,
            "channel {}",
            c + 1
        );
        let flags: Vec<Option<f64>> = recs
            .iter()
            .map(|r| Some(f64::from(r.ch[c].flags.0)))
            .collect();
        assert_eq!(
            numbers(&p["channels"][c]["flags"]),
            flags,
            "channel {} flags",
            c + 1
        );
    }
    for k in 0..3 {
        let want: Vec<Option<f64>> = recs.iter().map(|r| nt(r.diff[k])).collect();
        assert_eq!(numbers(&p["diffs"][k]), want, "pair {k}");
    }
    // 2 − 1 is 1.5 nT (15 000 counts) where channel 2 reads, empty where it is dead.
    let d21 = numbers(&p["diffs"][0]);
    assert_eq!(d21.iter().filter(|d| d.is_none()).count(), dead.len());
    assert!(
        d21.iter().flatten().all(|d| (d - 1.5).abs() < 1e-12),
        "{d21:?}"
    );
    assert_eq!(numbers(&p["comp"]), numbers(&p["channels"][0]["comp"]));
    let shown = p["channel_flags"].as_str().unwrap_or("");
    assert_eq!(shown, "1: ok, 2: ok, 3: ok", "the last record's flags");
    assert!(page.console_errors.is_empty(), "{:?}", page.console_errors);
    assert!(errors_dom.is_empty(), "{errors_dom}");
}

#[test]
fn web_save_writes_what_the_text_monitor_saves() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("records.txt");
    std::fs::write(&file, stream()).unwrap();
    let input = file.to_str().unwrap();
    let (web_csv, text_csv) = (dir.path().join("web.csv"), dir.path().join("text.csv"));
    let out = Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .args([
            "monitor",
            input,
            "--quiet",
            "--save",
            text_csv.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(out.status.success(), "{out:?}");
    let want = std::fs::read_to_string(&text_csv).unwrap();
    let (server, _url) = start_server(&[input, "--save", web_csv.to_str().unwrap()]);
    let start = Instant::now();
    let mut got = String::new();
    while start.elapsed() < Duration::from_secs(10) && got != want {
        std::thread::sleep(Duration::from_millis(100));
        got = std::fs::read_to_string(&web_csv).unwrap_or_default();
    }
    drop(server);
    assert_eq!(got.lines().count(), decoded(&stream()).len() + 3);
    assert_eq!(got, want);
}

/// A simulated calibration pattern and a short survey line as the board sends them with
/// `RAW,ON` (`replay --raw --records`: a `$MCRAW` line before each sample's record), the
/// board flying coefficients calibrated on the flight (survey mode: a check pattern, whose
/// compensated figures are small, not the filter learning from zero).
fn raw_stream(dir: &Path) -> std::path::PathBuf {
    use common::cli::{bin, run_ok, simulate};
    let cap = dir.join("flight.cap");
    let flight = simulate(
        dir,
        &[
            "--flight",
            "calibration+survey",
            "--lines",
            "1",
            "--line-length-m",
            "6000",
            "--capture",
            cap.to_str().unwrap(),
        ],
    );
    let coeffs = dir.join("coeffs.json");
    run_ok(bin().arg("calibrate").arg(&flight).arg("-o").arg(&coeffs));
    let log = dir.join("log.txt");
    run_ok(
        bin()
            .arg("replay")
            .arg(&cap)
            .arg("--coeffs")
            .arg(&coeffs)
            .args(["--raw", "--records"])
            .arg(&log),
    );
    log
}

/// The FOM table the host computes for the log's raw lines with `t` in `first..=last`
/// (raw-line times) and the records' compensated values: the report's own path (the board
/// log as a trace, the unlabelled detector, the FOM table), not the live view's.
fn expected_table(log: &Path, first: f64, last: f64) -> magcomp::calibration::fom::FomTable {
    use magcomp::io::trace::board_log::read_board_log;
    let mut trace = read_board_log(log).unwrap();
    let t = trace.col("t").unwrap().to_vec();
    let keep: Vec<usize> = (0..t.len())
        .filter(|&i| t[i] >= first && t[i] <= last)
        .collect();
    for (_, v) in &mut trace.numeric {
        *v = keep.iter().map(|&i| v[i]).collect();
    }
    let text = std::fs::read_to_string(log).unwrap();
    let comp: std::collections::HashMap<u64, f64> = decoded(&text)
        .iter()
        .map(|r| {
            let c = r.compensated.map_or(f64::NAN, MagCounts::to_nt_f64);
            ((r.t_s * 1e6).round() as u64, c)
        })
        .collect();
    let comp_nt: Vec<f64> = trace
        .col("t")
        .unwrap()
        .iter()
        .map(|t| comp[&((t * 1e6).round() as u64)])
        .collect();
    let flight = magcomp::flight::Flight::from_trace(&trace, &[], &[]).unwrap();
    let pattern = magcomp::qc::manoeuvres::detect(&flight).expect("a pattern");
    magcomp::calibration::fom::fom_table(&flight, &pattern, "detected", &comp_nt, None).unwrap()
}

/// The log flown twice: the same lines again, sample numbers, sequence numbers and times
/// continued (as if the pattern and the line were flown again right after).
fn flown_twice(text: &str) -> String {
    use magcomp_core::protocol::raw::{encode_raw, MAX_RAW_LEN};
    let raws = text.lines().filter(|l| l.starts_with("$MCRAW,")).count() as u32;
    let recs = decoded(text);
    let (n, dt_s) = (recs.len() as u32, recs[1].t_s - recs[0].t_s);
    let shift_s = f64::from(raws) * dt_s;
    let mut out = text.to_string();
    for l in text.lines() {
        if let Ok(mut r) = decode_raw(l.as_bytes()) {
            r.k += raws;
            r.t_s += shift_s;
            let mut b = [0u8; MAX_RAW_LEN];
            let len = encode_raw(&r, &mut b).unwrap();
            out.push_str(std::str::from_utf8(&b[..len]).unwrap());
        } else if let Ok(mut r) = decode_record(l.as_bytes()) {
            r.seq += n;
            r.t_s += shift_s;
            out.push_str(&record_line(&r));
        }
    }
    out
}

/// Height as each raw line's own digits, and its GPS state, by sample time (µs).
fn heights(text: &str) -> std::collections::HashMap<u64, (Option<f64>, bool)> {
    text.lines()
        .filter_map(|l| Some((l, decode_raw(l.as_bytes()).ok()?)))
        .map(|(l, r)| {
            let alt = l.split(',').nth(9).and_then(|a| a.parse::<f64>().ok());
            let fix = !r.flags.contains(Flags::NO_GPS);
            ((r.t_s * 1e6).round() as u64, (alt, fix))
        })
        .collect()
}

/// Every message the server sends for `log` (read at full speed) up to its end.
fn messages_of(log: &Path) -> Vec<Value> {
    let (server, url) = start_server(&[log.to_str().unwrap()]);
    let mut ws = ws_connect(&format!("{}ws", url.replace("http://", "ws://")));
    let got = read_until(&mut ws, |v| v["kind"] == "link" && v["up"] == false);
    drop(server);
    got
}

/// The latest FOM message among `got` (a page opened late gets it apart from the backlog).
fn latest_fom(got: &[Value]) -> Value {
    got.iter()
        .filter(|m| m["kind"] == "fom")
        .max_by_key(|m| m["number"].as_u64())
        .cloned()
        .unwrap_or(Value::Null)
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(1.0)
}

/// Each figure of the table the page got against the host's own.
fn assert_same_table(got: &Value, want: &magcomp::calibration::fom::FomTable) {
    let num = |v: &Value| v.as_f64().unwrap_or(f64::NAN);
    assert_eq!(got["manoeuvres"], want.manoeuvres);
    for (k, w) in [
        ("fom_nt", want.fom_nt),
        ("uncompensated_nt", want.uncompensated_nt),
        ("improvement_ratio", want.improvement_ratio),
    ] {
        assert!(close(num(&got[k]), w), "{k}: {} against {w}", got[k]);
    }
    let rows = got["rows"].as_array().unwrap();
    assert_eq!(rows.len(), want.rows.len());
    for (g, w) in rows.iter().zip(&want.rows) {
        assert_eq!(g["heading"], w.heading.as_str());
        assert!(close(num(&g["compensated_sum_nt"]), w.compensated_sum_nt));
        assert!(close(
            num(&g["uncompensated_sum_nt"]),
            w.uncompensated_sum_nt
        ));
        let cells = g["cells"].as_array().unwrap();
        assert_eq!(cells.len(), w.cells.len());
        for (gc, wc) in cells.iter().zip(&w.cells) {
            assert_eq!(gc["kind"], wc.kind.as_str());
            assert!(
                close(num(&gc["uncompensated_nt"]), wc.uncompensated_nt),
                "{gc}"
            );
            assert!(close(num(&gc["compensated_nt"]), wc.compensated_nt), "{gc}");
        }
    }
}

#[test]
fn raw_lines_give_height_gps_and_the_fom_table_after_the_pattern() {
    let dir = common::cli::tmp("live-raw");
    let log = raw_stream(&dir);
    let text = std::fs::read_to_string(&log).unwrap();
    let height = heights(&text);
    assert!(height.values().filter(|h| h.0.is_some()).count() > 10_000);

    // At the websocket: every record's height and GPS state, and one table.
    let got = messages_of(&log);
    let records: Vec<&Value> = got.iter().filter(|m| m["kind"] == "record").collect();
    let mut foms: Vec<&Value> = got.iter().filter(|m| m["kind"] == "fom").collect();
    // The stored table and its copy still in the backlog are one table.
    foms.dedup_by_key(|m| m["number"].as_u64());
    assert!(records.len() >= 1000, "{} records", records.len());
    for m in &records {
        let key = (m["t_s"].as_f64().unwrap() * 1e6).round() as u64;
        let (alt, fix) = height[&key];
        assert_eq!(m["alt_m"].as_f64(), alt, "{m}");
        assert_eq!(m["gps_fix"].as_bool(), Some(fix), "{m}");
    }
    assert_eq!(foms.len(), 1, "one pattern, one table");
    let f = foms[0];
    let (t_s, end) = (
        f["t_s"].as_f64().unwrap(),
        f["pattern_end_t_s"].as_f64().unwrap(),
    );
    // Computed once the quiet time after the last manoeuvre had passed, at the first
    // check after it (checks every 10 s of record time).
    println!("FOM table at {t_s:.1} s, last manoeuvre ended {end:.1} s");
    assert!(t_s >= end + 30.0 && t_s < end + 30.0 + 10.5, "{t_s} {end}");
    let want = expected_table(
        &log,
        f["first_t_s"].as_f64().unwrap(),
        f["last_t_s"].as_f64().unwrap(),
    );
    println!("{}", magcomp::calibration::fom::format_table(&want));
    // 4 headings × pitch and roll at least (the detector misses some yaws).
    assert!(
        want.manoeuvres >= 8 && want.rows.len() >= 4,
        "{}",
        want.manoeuvres
    );
    assert_same_table(&f["table"], &want);

    // Flown twice: a second table, over the second pattern's rows, replaces the first.
    let log2 = dir.join("twice.txt");
    let text2 = flown_twice(&text);
    std::fs::write(&log2, &text2).unwrap();
    let f2 = latest_fom(&messages_of(&log2));
    assert_eq!(f2["number"], 2, "{f2}");
    let shift_s = f2["t_s"].as_f64().unwrap() - t_s;
    assert!(shift_s > 1500.0, "second table {shift_s} s after the first");
    let first2 = f2["first_t_s"].as_f64().unwrap();
    assert!(
        first2 > end,
        "{first2}: the second pattern's rows start after the first's end"
    );
    let want2 = expected_table(&log2, first2, f2["last_t_s"].as_f64().unwrap());
    println!(
        "second: {}",
        magcomp::calibration::fom::format_table(&want2)
    );
    assert_same_table(&f2["table"], &want2);

    if !Path::new(CHROMIUM).exists() {
        println!("SKIP page part: {CHROMIUM} not installed (apt-get install chromium)");
        return;
    }
    // The page, opened after the stream flown twice has been read: its strips get the
    // backlog, its table the latest FOM message (the second pattern's).
    let height = heights(&text2);
    let (server, url) = start_server(&[log2.to_str().unwrap()]);
    std::thread::sleep(Duration::from_millis(1500));
    let (chrome, mut page) = Page::open(&url, &dir.join("profile"));
    let t0 = Instant::now();
    let mut p = Value::Null;
    while t0.elapsed() < Duration::from_secs(20) {
        p = page.plotted();
        if p["fom"]["number"] == 2 && numbers(&p["alt"]).len() >= 300 {
            break;
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    let note_class = page.call(
        "Runtime.evaluate",
        json!({"expression": "document.getElementById('alt-note').className",
               "returnByValue": true}),
    );
    let errors_dom = page.text_of("errors");
    drop(chrome);
    drop(server);
    let (x, alt) = (numbers(&p["x"]), numbers(&p["alt"]));
    assert_eq!(alt.len(), 300, "{p}");
    for (x, a) in x.iter().zip(&alt) {
        let key = (x.unwrap() * 1e6).round() as u64;
        assert_eq!(*a, height[&key].0, "height at {x:?}");
    }
    let gps = p["gps_fix"].as_array().unwrap();
    assert!(gps.iter().all(|g| g.is_boolean()), "{gps:?}");
    assert_eq!(note_class["result"]["value"], "note hidden");
    assert_same_table(&p["fom"]["table"], &want2);
    let shown = p["fom_text"].as_str().unwrap();
    for s in [
        format!(
            "pattern 2, computed at t = {:.1} s",
            f2["t_s"].as_f64().unwrap()
        ),
        format!("FOM {:.3} nT", want2.fom_nt),
        format!("IR {:.2}", want2.improvement_ratio),
        format!(
            "{:.2} / {:.3}",
            want2.rows[0].cells[0].uncompensated_nt, want2.rows[0].cells[0].compensated_nt
        ),
    ] {
        assert!(shown.contains(&s), "{s} not in {shown}");
    }
    assert!(page.console_errors.is_empty(), "{:?}", page.console_errors);
    assert!(errors_dom.is_empty(), "{errors_dom}");
}
