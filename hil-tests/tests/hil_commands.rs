//! Hardware-in-the-loop tests of the command port: commands, coefficients, the store, the
//! watchdog and crash records, on the emulated board (or a real one, see `board.rs`).
//! Each test SKIPs (passes with a message) when qemu-system-arm is missing, unless
//! `MAGCOMP_REQUIRE_QEMU=1`. The flights are `hil`.

mod common;

use common::{
    assert_one_record_per_sample, banners, coefficients_read_back, collect_records, reply,
    reply_values, run_flight, send_hook, speed, start, start_with_hooks,
};
use hil_tests::board::{self, Board, sentence};
use hil_tests::board_config::{FLUXMOD, N_COEF};
use hil_tests::capture::{FlightSpec, synthetic_flight};
use hil_tests::replay::replay;
use magcomp_core::Flags;
use magcomp_core::protocol::command::{CommandError, Reply, check_reply, parse_reply};
use std::io::Write;
use std::time::{Duration, Instant};

#[test]
fn malformed_commands_rejected_valid_ones_applied() {
    let name = "commands";
    let Some(mut b) = start(name) else {
        return;
    };
    let mut rejected = 0;
    let mut expect_err = |b: &mut Board, bytes: &[u8], reason: &str| {
        let mut r = b.command_raw(bytes).unwrap();
        // a line damaged on the way gets a transport error instead (see `Board::command_line`):
        // the board counted that one too; send it again
        for _ in 0..hil_tests::board::MAX_RESENDS {
            match parse_reply(r.as_bytes()) {
                Some(Reply::Refused(e)) if e.is_transport() && e.text() != reason => {
                    rejected += 1;
                    r = b.command_raw(bytes).unwrap();
                }
                _ => break,
            }
        }
        assert!(
            r.starts_with("$MCERR,") && r.contains(&format!(",{reason}*")),
            "{:?} → {r}, want {reason}",
            String::from_utf8_lossy(bytes)
        );
        assert!(check_reply(r.as_bytes()).is_some(), "reply CRC: {r}");
        rejected += 1;
    };
    let mut bad_cs = sentence("MCCMD,STATUS");
    let k = bad_cs.len() - 3;
    bad_cs[k] = if bad_cs[k] == b'0' { b'1' } else { b'0' };
    expect_err(&mut b, &bad_cs, "CHECKSUM");
    expect_err(&mut b, b"$MCCMD,STATUS\r\n", "CHECKSUM");
    expect_err(&mut b, b"$MCCMD,STATUS*FFFF\r\n", "CHECKSUM");
    expect_err(&mut b, &sentence("MCCMD,SELFDESTRUCT"), "UNKNOWN");
    expect_err(&mut b, &sentence("MCXYZ,STATUS"), "FRAMING");
    expect_err(&mut b, b"garbage \x01\x02\xff\r\n", "FRAMING");
    expect_err(&mut b, &sentence("MCCMD,SETCOEF,99,1.0"), "INDEX");
    expect_err(&mut b, &sentence("MCCMD,GETCOEF,17"), "INDEX");
    expect_err(&mut b, &sentence("MCCMD,SETCOEF,1,1E9"), "VALUE");
    expect_err(&mut b, &sentence("MCCMD,SETCOEF,1,NaN"), "BADARG");
    expect_err(&mut b, &sentence("MCCMD,MODE,TURBO"), "BADARG");
    expect_err(&mut b, &sentence("MCCMD,SETCOEF,1"), "BADARG");
    expect_err(&mut b, &sentence("MCCMD,GETCOEF,x"), "BADARG");
    expect_err(&mut b, &sentence("MCCMD,STATUS,extra"), "BADARG");
    expect_err(&mut b, &sentence("MCCMD,SETFLUX,12,1.0"), "INDEX");
    expect_err(&mut b, &sentence("MCCMD,GETFLUX,12"), "INDEX");
    // an implausible calibration (diagonal 3) is refused, the old one kept
    expect_err(&mut b, &sentence("MCCMD,SETFLUX,0,3.0"), "VALUE");
    let mut long = vec![b'A'; 300];
    long.extend_from_slice(b"\r\n");
    expect_err(&mut b, &long, "OVERLONG");

    let ack = |b: &mut Board, body: &str| {
        let r = b.command(body).unwrap();
        assert!(r.starts_with("$MCACK"), "{body} → {r}");
        assert!(check_reply(r.as_bytes()).is_some(), "reply CRC: {r}");
        r
    };
    let coef = |r: &str| -> f64 {
        r.split(['*', ','])
            .nth(3)
            .and_then(|v| v.parse().ok())
            .unwrap_or(f64::NAN)
    };
    assert!(ack(&mut b, "MCCMD,STATUS").starts_with("$MCACK,STATUS,CAL,0,"));
    let all = ack(&mut b, "MCCMD,GETCOEF");
    assert_eq!(
        all.split(',').count(),
        2 + N_COEF,
        "GETCOEF returns the board's 17 coefficients: {all}"
    );
    assert!(ack(&mut b, "MCCMD,SETCOEF,0,5.25").starts_with("$MCACK,SETCOEF,0,"));
    assert_eq!(coef(&ack(&mut b, "MCCMD,GETCOEF,0")), 5.25);
    // staged, not flown: one SETCOEF does not switch the board to a half-sent set
    let s = ack(&mut b, "MCCMD,STATUS");
    assert!(s.starts_with("$MCACK,STATUS,CAL,"), "{s}");
    // the fluxgate calibration (`fluxcal`): identity until set, 12 values
    let flux = ack(&mut b, "MCCMD,GETFLUX");
    assert_eq!(
        flux.split(',').count(),
        2 + 12,
        "GETFLUX returns 12 values: {flux}"
    );
    assert_eq!(coef(&ack(&mut b, "MCCMD,GETFLUX,0")), 1.0);
    assert!(ack(&mut b, "MCCMD,SETFLUX,0,1.0065").starts_with("$MCACK,SETFLUX,0,"));
    assert!(ack(&mut b, "MCCMD,SETFLUX,9,-312.5").starts_with("$MCACK,SETFLUX,9,"));
    ack(&mut b, "MCCMD,SAVE");
    ack(&mut b, "MCCMD,SETCOEF,0,0");
    ack(&mut b, "MCCMD,SETFLUX,9,0");
    assert_eq!(coef(&ack(&mut b, "MCCMD,GETCOEF,0")), 0.0);
    // RESET re-initialises the filter and reloads the stored blobs (checked: CRC, version,
    // model), coefficients and fluxgate calibration alike
    assert!(ack(&mut b, "MCCMD,RESET").starts_with("$MCACK,RESET,0"));
    let g = ack(&mut b, "MCCMD,GETCOEF,0");
    assert_eq!(coef(&g), 5.25, "store round trip: {g}");
    let f0 = coef(&ack(&mut b, "MCCMD,GETFLUX,0"));
    let f9 = coef(&ack(&mut b, "MCCMD,GETFLUX,9"));
    assert!(
        (f0 - 1.0065).abs() < 1e-6 && f9 == -312.5,
        "fluxgate store round trip: {f0} {f9}"
    );
    assert!(ack(&mut b, "MCCMD,MODE,SURVEY").starts_with("$MCACK,MODE,SURVEY"));

    // records flow while commands are handled, and carry the mode
    let cap = synthetic_flight(&FlightSpec::new(7, 3.0));
    b.stream(&cap, speed()).unwrap();
    b.flush().unwrap();
    let (recs, bad) = b.records();
    assert!(bad.is_empty());
    assert_eq!(recs.len(), cap.scalar_t_s.len());
    hil_tests::check_contiguous(&recs).unwrap();
    assert!(
        recs.iter().all(|r| r.flags.contains(Flags::SURVEY_MODE)),
        "survey mode not flagged"
    );
    let s = ack(&mut b, "MCCMD,STATUS");
    assert!(s.starts_with("$MCACK,STATUS,SURVEY,"), "{s}");
    let cmd_errors: u32 = s
        .split(['*', ','])
        .nth(8)
        .and_then(|v| v.parse().ok())
        .unwrap_or(u32::MAX);
    assert_eq!(
        cmd_errors as usize,
        rejected + b.resends(),
        "command error counter ({} resends): {s}",
        b.resends()
    );
}

/// `SETLAG` over the command port (issue 12 item 1, the board side of `lag`): `GETLAG`
/// returns it, out-of-range values are refused, `SAVE` + `RESET` reload it; a flight
/// streamed with τ = 0.3 s gives one record per scalar sample, the first 3 (τ at 10 Hz)
/// `FLUX_STALE` while the delay line fills, and equals the host run of the board's code
/// with the same τ (and not the undelayed one).
#[test]
fn lag_set_over_the_command_port_delays_the_fluxgate_without_losing_a_record() {
    let name = "lag";
    let Some(mut b) = start(name) else {
        return;
    };
    let value = |r: &str| -> f64 {
        r.split(['*', ','])
            .nth(2)
            .and_then(|v| v.parse().ok())
            .unwrap_or(f64::NAN)
    };
    assert_eq!(value(&reply(&mut b, "MCCMD,GETLAG")), 0.0, "τ = 0 at boot");
    for bad in ["0.6", "-0.1", "x"] {
        let r = reply(&mut b, &format!("MCCMD,SETLAG,{bad}"));
        assert!(r.starts_with("$MCERR,"), "SETLAG,{bad} → {r}");
    }
    let r = reply(&mut b, "MCCMD,SETLAG,0.3");
    assert!(r.starts_with("$MCACK,SETLAG,"), "{r}");
    assert!((value(&reply(&mut b, "MCCMD,GETLAG")) - 0.3).abs() < 1e-7);
    let cap = synthetic_flight(&FlightSpec::new(0x1A6, 8.0));
    b.stream(&cap, speed()).unwrap();
    b.flush().unwrap();
    let (recs, bad) = b.records();
    assert!(bad.is_empty(), "{bad:?}");
    let n = cap.scalar_t_s.len();
    assert_eq!(
        recs.len(),
        n,
        "{name}: frames in {n}, records out {}",
        recs.len()
    );
    hil_tests::check_contiguous(&recs).unwrap();
    let stale: Vec<u32> = recs
        .iter()
        .filter(|r| r.flags.contains(Flags::FLUX_STALE))
        .map(|r| r.seq)
        .collect();
    assert_eq!(stale, [0, 1, 2], "{name}: FLUX_STALE records");
    let lagged = hil_tests::replay::replay_lagged(&cap, 0.3);
    hil_tests::compare_records(&recs, &lagged, 1e-3)
        .unwrap_or_else(|e| panic!("{name}: board vs replay with τ = 0.3 s: {e}"));
    assert!(
        hil_tests::compare_records(&recs, &replay(&cap), 1e-3).is_err(),
        "{name}: the delay changed nothing"
    );
    // `magcomp replay --lag-s 0.3` (when MAGCOMP_BIN is set) gives the board's records too
    let cap_path = b.dir.join("capture.txt");
    cap.write_raw(std::io::BufWriter::new(
        std::fs::File::create(&cap_path).unwrap(),
    ))
    .unwrap();
    let out = b.dir.join("replay.txt");
    if let Some(host) = hil_tests::host_replay_with(&cap_path, &out, &["--lag-s", "0.3"]) {
        let host = host.unwrap_or_else(|e| panic!("{name}: magcomp replay: {e}"));
        hil_tests::compare_records(&recs, &host, 1e-3)
            .unwrap_or_else(|e| panic!("{name}: board vs magcomp replay --lag-s 0.3: {e}"));
        eprintln!("{name}: = `magcomp replay --lag-s 0.3` within 1e-3 nT");
    }
    eprintln!(
        "{name}: SETLAG 0.3 s: {n} frames in, {} records out, = host replay with τ",
        recs.len()
    );
    // stored with the coefficients: SAVE, change it, RESET reloads the stored τ
    assert!(reply(&mut b, "MCCMD,SAVE").starts_with("$MCACK,SAVE"));
    assert!(reply(&mut b, "MCCMD,SETLAG,0").starts_with("$MCACK,SETLAG,"));
    assert_eq!(value(&reply(&mut b, "MCCMD,GETLAG")), 0.0);
    assert!(reply(&mut b, "MCCMD,RESET").starts_with("$MCACK,RESET,"));
    let stored = value(&reply(&mut b, "MCCMD,GETLAG"));
    assert!((stored - 0.3).abs() < 1e-7, "τ after RESET: {stored}");
}

/// `SETFTEMP` over the command port (issue 12 item 5, the board side of `fluxtemp`): none at
/// boot, 7 values set one at a time and read back exactly, absurd or non-finite ones
/// refused (the value kept), `SAVE` + `RESET` reload them.
#[test]
fn fluxtemp_set_over_the_command_port_is_stored() {
    let name = "fluxtemp";
    let Some(mut b) = start(name) else {
        return;
    };
    assert_eq!(
        reply_values(&reply(&mut b, "MCCMD,GETFTEMP")),
        [0.0; 7],
        "none at boot"
    );
    let want: [f32; 7] = [21.5, 0.41, -0.2, 0.8, 1e-5, -2e-5, 3e-6];
    for (i, v) in want.iter().enumerate() {
        let r = reply(&mut b, &format!("MCCMD,SETFTEMP,{i},{v:e}"));
        assert!(r.starts_with("$MCACK,SETFTEMP,"), "{i}: {r}");
    }
    for bad in ["0,250", "2,5000", "5,0.5", "1,x", "7,0"] {
        let r = reply(&mut b, &format!("MCCMD,SETFTEMP,{bad}"));
        assert!(r.starts_with("$MCERR,"), "SETFTEMP,{bad} → {r}");
    }
    assert_eq!(reply_values(&reply(&mut b, "MCCMD,GETFTEMP")), want);
    assert!(reply(&mut b, "MCCMD,SAVE").starts_with("$MCACK,SAVE"));
    for i in 0..7 {
        reply(&mut b, &format!("MCCMD,SETFTEMP,{i},0"));
    }
    assert_eq!(reply_values(&reply(&mut b, "MCCMD,GETFTEMP")), [0.0; 7]);
    assert!(reply(&mut b, "MCCMD,RESET").starts_with("$MCACK,RESET,"));
    assert_eq!(
        reply_values(&reply(&mut b, "MCCMD,GETFTEMP")),
        want,
        "after RESET"
    );
    eprintln!("{name}: SETFTEMP × 7 read back exactly, 5 bad values refused, SAVE + RESET reloads");
}

/// The ground-to-board path: `magcomp calibrate --model tl16+field+fluxcal` on a flight with a
/// miscalibrated fluxgate, `magcomp upload` turns the JSON into command lines, the board
/// acknowledges every one, holds exactly the file's values (f32) and keeps them over
/// `RESET`. Needs `MAGCOMP_BIN`.
#[test]
fn coefficients_from_magcomp_calibrate_uploaded() {
    let name = "upload";
    let Ok(bin) = std::env::var("MAGCOMP_BIN") else {
        eprintln!("SKIP: {name}: set MAGCOMP_BIN=path/to/magcomp to calibrate and upload");
        return;
    };
    if let Some(why) = board::skip_reason() {
        eprintln!("{why}");
        return;
    }
    let dir = std::env::temp_dir().join(format!("magcomp-hil-{}-upload", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (trace, coeffs) = (dir.join("cal.csv"), dir.join("coeffs.json"));
    let run = |args: &[&std::ffi::OsStr]| {
        let out = std::process::Command::new(&bin)
            .args(args)
            .output()
            .expect("run magcomp");
        assert!(
            out.status.success(),
            "magcomp {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).unwrap()
    };
    run(&[
        "simulate".as_ref(),
        "--seed".as_ref(),
        "3".as_ref(),
        "--hidden".as_ref(),
        "fluxcal".as_ref(),
        "-o".as_ref(),
        trace.as_os_str(),
    ]);
    run(&[
        "calibrate".as_ref(),
        "--model".as_ref(),
        "tl16+field+fluxcal".as_ref(),
        trace.as_os_str(),
        "-o".as_ref(),
        coeffs.as_os_str(),
    ]);
    let lines = run(&["upload".as_ref(), coeffs.as_os_str()]);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&coeffs).unwrap()).unwrap();
    let want_coef: Vec<f32> = json["coefficients"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["value"].as_f64().unwrap() as f32)
        .collect();
    let cal = &json["fluxgate_calibration"];
    let mut want_flux: Vec<f32> = Vec::new();
    for i in 0..3 {
        for j in 0..3 {
            want_flux.push(cal["matrix"][i][j].as_f64().unwrap() as f32);
        }
    }
    for i in 0..3 {
        want_flux.push(cal["bias_nt"][i].as_f64().unwrap() as f32);
    }
    assert_eq!(want_coef.len(), 16);
    assert!(
        want_flux[9..].iter().any(|b| b.abs() > 100.0),
        "a fluxgate bias was fitted"
    );

    // its own directory: `Board::start` clears the board's, and this one holds the files
    let mut b = Board::start(&format!("{name}-board")).unwrap_or_else(|e| panic!("{name}: {e}"));
    let sent = lines.lines().count();
    assert_eq!(
        sent,
        17 + 12 + 1 + 7 + 1,
        "SETCOEF × 17 (the paper set's 16, then `fluxmod` 0: the board's vector), SETFLUX × \
         12, SETLAG (0: no `lag`), SETFTEMP × 7 (0: no `fluxtemp`), SAVE"
    );
    // `magcomp upload --to PORT` itself, on the board's command port served as a socket
    // (as ser2net/socat serve a real one): every line acknowledged, SAVE, read-back
    let sock = b.dir.join("command.sock");
    let server = b.serve_command_port(&sock).unwrap();
    let out = std::process::Command::new(&bin)
        .args(["upload".as_ref(), coeffs.as_os_str(), "--to".as_ref()])
        .arg(&sock)
        .output()
        .expect("run magcomp upload");
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "magcomp upload --to: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        said.contains(&format!("{sent} acknowledged")) && said.contains("read-back OK"),
        "{said}"
    );
    server.join().unwrap();
    eprintln!("{name}: {}", said.trim());
    let check = |b: &mut Board, when: &str| {
        let c = reply_values(&b.command("MCCMD,GETCOEF").unwrap());
        // the board's vector: the paper model's 16, then `fluxmod`, 0 for a paper set
        assert_eq!(c.get(FLUXMOD), Some(&0.0), "{when}: fluxmod in {c:?}");
        let c = &c[..FLUXMOD];
        let f = reply_values(&b.command("MCCMD,GETFLUX").unwrap());
        assert!(
            coefficients_read_back(c, &want_coef),
            "{when}: coefficients {c:?} ≠ {want_coef:?}"
        );
        assert_eq!(f, want_flux, "{when}: fluxgate calibration");
        assert_eq!(
            reply_values(&b.command("MCCMD,GETLAG").unwrap()),
            [0.0],
            "{when}: τ"
        );
        assert_eq!(
            reply_values(&b.command("MCCMD,GETFTEMP").unwrap()),
            [0.0; 7],
            "{when}: fluxgate temperature correction"
        );
    };
    check(&mut b, "after upload");
    assert!(
        b.command("MCCMD,RESET")
            .unwrap()
            .starts_with("$MCACK,RESET")
    );
    check(&mut b, "after RESET (flash)");
    eprintln!(
        "{name}: {sent} lines acknowledged; the board holds the file's 16 coefficients and fluxgate calibration, also after RESET"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Commands back to back, each sent the moment the previous reply arrives (when the board is
/// ending a transmission: the window in which embassy's BufferedUart can lose a received
/// byte, see `Board::command_line`): every SETCOEF takes effect exactly once, a damaged line
/// is answered with a transport error and resent, and the board's command-error counter
/// equals the resends.
#[test]
fn commands_back_to_back_all_take_effect() {
    let name = "backtoback";
    let Some(mut b) = start(name) else {
        return;
    };
    let n_rounds = 40;
    let mut want = [0f32; N_COEF];
    for round in 0..n_rounds {
        for (i, w) in want.iter_mut().enumerate() {
            // distinct, exactly representable values
            *w = (round * N_COEF + i) as f32 * 0.25 - 100.0;
            let r = b
                .command(&format!("MCCMD,SETCOEF,{i},{w}"))
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(r.starts_with(&format!("$MCACK,SETCOEF,{i},")), "{r}");
        }
        let got = reply_values(&reply(&mut b, "MCCMD,GETCOEF"));
        assert!(
            coefficients_read_back(&got, &want),
            "{name}: round {round}: {got:?} ≠ {want:?}"
        );
    }
    let s = b.command("MCCMD,STATUS").unwrap();
    let cmd_errors: usize = s
        .split(['*', ','])
        .nth(8)
        .and_then(|v| v.parse().ok())
        .unwrap_or(usize::MAX);
    assert_eq!(cmd_errors, b.resends(), "command errors = resends: {s}");
    eprintln!(
        "{name}: {} commands back to back, all applied; {} arrived damaged and were resent",
        n_rounds * (N_COEF + 1) + 1,
        b.resends()
    );
}

/// The output port keeps going through command bursts while records stream: 40 `STATUS`
/// in one write, then `FLUSH`/`RESET` in one write, then `FLUSH`/`RESET` at ~120 Hz.
/// Guards the write path against embassy-stm32 0.6's `BufferedUartTx::write` returning
/// `Pending` without a waker when its ring is short of room (docs/firmware.md, output
/// port): on silicon that stopped the port for good. QEMU's UART transmits instantly, so
/// here the ring never fills and this checks the burst's bookkeeping, not the stall itself.
#[test]
fn command_burst_keeps_records_flowing() {
    let name = "burst";
    let cap = synthetic_flight(&FlightSpec::new(0x5EED_0023, 8.0));
    let Some(mut b) = start(name) else {
        return;
    };
    let cmd = b.command_writer();
    let sent = std::thread::spawn(move || {
        let send = |bytes: &[u8]| {
            cmd.lock()
                .map(|mut c| c.write_all(bytes).is_ok())
                .unwrap_or(false)
        };
        let mut lines = 0;
        std::thread::sleep(Duration::from_millis(1500));
        let burst: Vec<u8> = (0..40).flat_map(|_| sentence("MCCMD,STATUS")).collect();
        assert!(send(&burst));
        lines += 40;
        std::thread::sleep(Duration::from_millis(1500));
        let mixed: Vec<u8> = (0..10)
            .flat_map(|i| {
                sentence(if i % 2 == 0 {
                    "MCCMD,FLUSH"
                } else {
                    "MCCMD,RESET"
                })
            })
            .collect();
        assert!(send(&mixed));
        lines += 10;
        std::thread::sleep(Duration::from_millis(1000));
        for i in 0..30 {
            assert!(send(&sentence(if i % 3 == 2 {
                "MCCMD,RESET"
            } else {
                "MCCMD,FLUSH"
            })));
            lines += 1;
            std::thread::sleep(Duration::from_millis(8));
        }
        lines
    });
    b.stream(&cap, speed())
        .unwrap_or_else(|e| panic!("{name}: stream: {e}"));
    let lines = sent.join().expect("command thread");
    let n = cap.scalar_t_s.len();
    let (recs, out) = collect_records(&mut b, name, n);
    assert_one_record_per_sample(name, &b, &cap, &recs);
    let replies = b
        .output()
        .iter()
        .filter(|l| l.starts_with("$MCACK") || l.starts_with("$MCERR"))
        .count();
    let output = b.output();
    let acks = |what: &str| {
        output
            .iter()
            .filter(|l| l.starts_with(&format!("$MCACK,{what}")))
            .count()
    };
    // a command byte can be lost as the board ends a line (see `Board::command_line`): a
    // line merged with the next gets one reply for two; nearly all must be answered
    assert!(
        replies >= lines * 9 / 10,
        "{name}: {replies} replies to {lines} command lines (output in {})",
        out.display()
    );
    let s = reply(&mut b, "MCCMD,STATUS");
    assert!(s.starts_with("$MCACK,STATUS,"), "{s}");
    eprintln!(
        "{name}: {n} samples in, {} records out through {lines} burst commands \
         ({} STATUS, {} FLUSH, {} RESET acknowledged, {replies} replies)",
        recs.len(),
        acks("STATUS"),
        acks("FLUSH"),
        acks("RESET")
    );
}

/// A task that stops making progress (the emulated build's hidden `!STALL`: the output task
/// waits forever on an await that never completes, as a lost wake-up would) resets the
/// board within the watchdog's 3.5 s, and the next boot says `RST=IWDG`. QEMU has no IWDG: the
/// emulated board's model of it (SysTick, boards/emu_f405) resets the machine.
#[test]
fn stalled_task_resets_the_board_and_the_next_boot_says_why() {
    let name = "stall";
    let Some(mut b) = start_with_hooks(name) else {
        return;
    };
    let first = banners(&b).remove(0);
    assert!(first.contains(",RST="), "{name}: no reset cause: {first}");
    assert!(!first.contains("PANIC="), "{name}: {first}");
    reply(&mut b, "MCCMD,STATUS");
    // the watchdog must still be fed while nothing happens (idle tasks are not stalled)
    std::thread::sleep(Duration::from_secs(5));
    assert_eq!(banners(&b).len(), 1, "{name}: reset while idle");
    reply(&mut b, "MCCMD,STATUS");
    send_hook(&mut b, b"!STALL\r\n");
    let t0 = Instant::now();
    // a line for the output task to stall on (its reply never comes)
    b.send_command_bytes(&sentence("MCCMD,STATUS")).unwrap();
    let second = b.wait_line_from_banner(1, Duration::from_secs(20));
    let dt = t0.elapsed().as_secs_f64();
    let second = second.unwrap_or_else(|| panic!("{name}: no reset 20 s after the stall"));
    assert!(second.contains(",RST=IWDG"), "{name}: {second}");
    // 3.5 s watchdog + at most one 0.5 s check. Not before 2.9 s of wall time; the upper bound
    // is loose because the emulated clock counts SysTick interrupts, which QEMU delivers late
    // on a loaded host (measured 4.9–6.5 s on 2 shared cores)
    assert!(
        (2.9..=15.0).contains(&dt),
        "{name}: reset {dt:.1} s after the stall (watchdog 3.5 s, checked every 0.5 s)"
    );
    // the board works again after the reset
    let s = reply(&mut b, "MCCMD,STATUS");
    assert!(s.starts_with("$MCACK,STATUS,"), "{s}");
    eprintln!("{name}: stalled output task reset the board after {dt:.1} s: {second}");
}

/// A panic (the emulated build's hidden `!PANIC`) leaves its location in no-init RAM; the
/// next boot reports it in `$MCBOOT` (`PANIC=file:line`, `RST=SW`) once.
#[test]
fn panic_leaves_a_record_the_next_boot_reports() {
    let name = "panic";
    let Some(mut b) = start_with_hooks(name) else {
        return;
    };
    reply(&mut b, "MCCMD,STATUS");
    send_hook(&mut b, b"!PANIC\r\n");
    let second = b
        .wait_line_from_banner(1, Duration::from_secs(20))
        .unwrap_or_else(|| panic!("{name}: no reboot after the panic"));
    assert!(second.contains(",RST=SW,PANIC="), "{name}: {second}");
    assert!(second.contains("fw.rs:"), "{name}: {second}");
    assert!(check_reply(second.as_bytes()).is_some(), "CRC: {second}");
    let s = reply(&mut b, "MCCMD,STATUS");
    assert!(s.starts_with("$MCACK,STATUS,"), "{s}");
    // reported once: a reset now (the stall) does not repeat it
    send_hook(&mut b, b"!STALL\r\n");
    b.send_command_bytes(&sentence("MCCMD,STATUS")).unwrap();
    let third = b
        .wait_line_from_banner(2, Duration::from_secs(20))
        .unwrap_or_else(|| panic!("{name}: no reset after the stall"));
    assert!(!third.contains("PANIC="), "{name}: {third}");
    eprintln!("{name}: {second} then {third}");
}

/// `STATUS` carries the UART error counters by kind (overrun, framing, noise) and by port
/// (scalar, fluxgate, GPS, output/command), and `err_uart` is their total. QEMU's UART model
/// never raises an error flag, so on the emulator they must all read 0 after a flight; on a
/// real board (`MAGCOMP_HIL_TARGET=serial`) clean wiring must read 0 too.
#[test]
fn status_reports_uart_errors_by_kind_and_port() {
    let name = "uarterr";
    let cap = synthetic_flight(&FlightSpec::new(0x5EED_0007, 4.0));
    let Some((mut b, recs)) = run_flight(name, &cap) else {
        return;
    };
    assert_one_record_per_sample(name, &b, &cap, &recs);
    let s = reply(&mut b, "MCCMD,STATUS");
    let f: Vec<&str> = s.split('*').next().unwrap_or_default().split(',').collect();
    assert_eq!(f.len(), 2 + 1 + 6 + 7 + 1, "{name}: STATUS fields: {s}");
    let n: Vec<u64> = f[3..].iter().map(|v| v.parse().unwrap()).collect();
    let (uart, kinds, ports) = (n[4], &n[6..9], &n[9..13]);
    assert_eq!(
        uart,
        kinds.iter().sum::<u64>(),
        "{name}: err_uart = kinds: {s}"
    );
    assert_eq!(
        uart,
        ports.iter().sum::<u64>(),
        "{name}: err_uart = ports: {s}"
    );
    assert_eq!(uart, 0, "{name}: UART errors on clean input: {s}");
    // The last field: fluxgate frames refused as suspect, none from a working fluxgate.
    assert_eq!(n[13], 0, "{name}: flux_suspect on clean input: {s}");
    eprintln!("{name}: {s}");
}

/// `FACTORY,ERASE` erases the store and returns to the boot defaults (calibrate mode, no
/// coefficients, identity fluxgate calibration, τ = 0, no temperature drift), so a later
/// `RESET` or boot finds nothing; `FACTORY` without its argument is refused.
#[test]
fn factory_reset_erases_the_store() {
    let name = "factory";
    let Some(mut b) = start(name) else {
        return;
    };
    let ok = |r: &str, what: &str| assert!(r.starts_with(what), "{name}: {r}");
    ok(&reply(&mut b, "MCCMD,SETCOEF,3,1.5"), "$MCACK,SETCOEF,3,");
    ok(&reply(&mut b, "MCCMD,SETLAG,0.3"), "$MCACK,SETLAG,");
    ok(&reply(&mut b, "MCCMD,SETFLUX,9,12.5"), "$MCACK,SETFLUX,9,");
    ok(&reply(&mut b, "MCCMD,SAVE"), "$MCACK,SAVE");
    ok(&reply(&mut b, "MCCMD,RESET"), "$MCACK,RESET,");
    ok(&reply(&mut b, "MCCMD,STATUS"), "$MCACK,STATUS,SURVEY,");
    assert_eq!(reply_values(&reply(&mut b, "MCCMD,GETLAG")), [0.3]);
    let r = b.command_raw(&sentence("MCCMD,FACTORY")).unwrap();
    assert_eq!(
        parse_reply(r.as_bytes()),
        Some(Reply::Refused(CommandError::BadArgument)),
        "{name}: {r}"
    );
    ok(&reply(&mut b, "MCCMD,FACTORY,ERASE"), "$MCACK,FACTORY,");
    let check_defaults = |b: &mut Board, when: &str| {
        let s = reply(b, "MCCMD,STATUS");
        assert!(s.starts_with("$MCACK,STATUS,CAL,"), "{name} {when}: {s}");
        assert_eq!(reply_values(&reply(b, "MCCMD,GETLAG")), [0.0], "{when}");
        assert!(
            reply_values(&reply(b, "MCCMD,GETCOEF"))
                .iter()
                .all(|&v| v == 0.0),
            "{name} {when}: coefficients left"
        );
        let flux = reply_values(&reply(b, "MCCMD,GETFLUX"));
        let identity = [1., 0., 0., 0., 1., 0., 0., 0., 1., 0., 0., 0.];
        assert_eq!(flux, identity, "{name} {when}: fluxgate calibration");
    };
    check_defaults(&mut b, "after FACTORY");
    // the store is empty: a RESET reloads nothing
    ok(&reply(&mut b, "MCCMD,RESET"), "$MCACK,RESET,");
    check_defaults(&mut b, "after FACTORY + RESET");
    eprintln!("{name}: store erased, defaults back, also after RESET");
}

/// A `SAVE` cut at any point (the emulated build's hidden `!CUT<n>`: the image being
/// written stops after `n` bytes, as a power cut leaves flash) keeps the previous set: the
/// store writes the other of its two images, with the next sequence number, and reads it
/// back (`$MCERR,8,STORAGE` when it does not read back), and a reload takes the newest
/// valid image, never a mix. Completed saves alternate images and the newest wins.
#[test]
fn save_cut_at_any_point_keeps_the_old_set() {
    let name = "cut";
    let Some(mut b) = start_with_hooks(name) else {
        return;
    };
    let lag = |b: &mut Board| reply_values(&reply(b, "MCCMD,GETLAG"))[0];
    let set_and_save = |b: &mut Board, tau: f32| {
        let r = reply(b, &format!("MCCMD,SETLAG,{tau}"));
        assert!(r.starts_with("$MCACK,SETLAG,"), "{r}");
        reply(b, "MCCMD,SAVE")
    };
    let reload = |b: &mut Board| {
        let r = reply(b, "MCCMD,RESET");
        assert!(r.starts_with("$MCACK,RESET,"), "{r}");
    };
    reply(&mut b, "MCCMD,SETCOEF,3,1.5");
    assert!(set_and_save(&mut b, 0.1).starts_with("$MCACK,SAVE"));
    reload(&mut b);
    assert_eq!(lag(&mut b), 0.1);
    // image: 8-byte header, the blobs (the first four 212 bytes, then sensors 1 and 2),
    // CRC-32 last: cut before, inside the first blobs and the later sensors', at the end
    let len = hil_tests::store::IMAGE_LEN;
    let cuts = [
        0usize,
        1,
        7,
        8,
        100,
        219,
        220,
        223,
        300,
        len - 5,
        len - 4,
        len - 1,
    ];
    for (round, cut) in cuts.into_iter().enumerate() {
        send_hook(&mut b, format!("!CUT{cut}\r\n").as_bytes());
        let r = set_and_save(&mut b, 0.2);
        assert!(r.starts_with("$MCERR,8,STORAGE"), "{name}: cut {cut}: {r}");
        reload(&mut b);
        assert_eq!(
            lag(&mut b),
            0.1,
            "{name}: cut at {cut} (round {round}): old set lost"
        );
        let s = reply(&mut b, "MCCMD,STATUS");
        assert!(s.starts_with("$MCACK,STATUS,SURVEY,"), "{name}: {s}");
    }
    // complete saves alternate the images; the newest is loaded, and a cut now spares it
    for tau in [0.2f32, 0.3, 0.4] {
        assert!(set_and_save(&mut b, tau).starts_with("$MCACK,SAVE"));
        reload(&mut b);
        assert_eq!(lag(&mut b), tau);
    }
    send_hook(&mut b, b"!CUT100\r\n");
    assert!(set_and_save(&mut b, 0.5).starts_with("$MCERR,8,STORAGE"));
    reload(&mut b);
    assert_eq!(lag(&mut b), 0.4, "{name}: the newest complete set");
    eprintln!(
        "{name}: {} cut saves of a {len}-byte image kept the previous set; complete saves \
         alternate images",
        cuts.len() + 1
    );
}

/// The board runs the paper model with the fluxgate's witness beside it (docs/firmware.md,
/// "Fluxgate witness"): a set of the board's 17 values with `fluxmod` ≠ 0 flies the
/// witnessed filter, whose records are shown (flag `WITNESS`) and whose set `GETCOEF` reads
/// back; the same set with `fluxmod` 0 is the paper filter's, its records without the flag.
#[test]
fn a_set_with_fluxmod_flies_the_witnessed_filter_and_one_without_the_paper_filter() {
    let name = "witness";
    let Some(mut b) = start(name) else {
        return;
    };
    // exactly representable; `fluxmod`'s (index 16) 0.5
    let mut want: Vec<f32> = (0..N_COEF).map(|i| (i as f32 - 8.0) * 0.125).collect();
    want[FLUXMOD] = 0.5;
    let fly = |b: &mut Board, set: &[f32], from: usize| {
        for (i, v) in set.iter().enumerate() {
            let r = reply(b, &format!("MCCMD,SETCOEF,{i},{v}"));
            assert!(
                r.starts_with(&format!("$MCACK,SETCOEF,{i},")),
                "{name}: {r}"
            );
        }
        assert!(reply(b, "MCCMD,MODE,SURVEY").starts_with("$MCACK,MODE,SURVEY"));
        let got = reply_values(&reply(b, "MCCMD,GETCOEF"));
        assert!(
            coefficients_read_back(&got, set),
            "{name}: GETCOEF {got:?} ≠ {set:?}"
        );
        let cap = synthetic_flight(&FlightSpec::new(0x3171_7E55, 3.0));
        b.stream(&cap, speed())
            .unwrap_or_else(|e| panic!("{name}: stream: {e}"));
        let (recs, _) = collect_records(b, name, from + cap.scalar_t_s.len());
        assert_eq!(recs.len(), from + cap.scalar_t_s.len(), "{name}: records");
        recs[from..]
            .iter()
            .map(|r| {
                assert!(r.flags.contains(Flags::SURVEY_MODE), "{name}: {r:?}");
                r.flags.contains(Flags::WITNESS)
            })
            .collect::<Vec<bool>>()
    };
    let witnessed = fly(&mut b, &want, 0);
    assert!(
        witnessed.iter().all(|&w| w),
        "{name}: a set with fluxmod: every record the witnessed filter's"
    );
    want[FLUXMOD] = 0.0;
    let paper = fly(&mut b, &want, witnessed.len());
    assert!(
        paper.iter().all(|&w| !w),
        "{name}: fluxmod 0: every record the paper filter's"
    );
    eprintln!(
        "{name}: {} records of the witnessed set flagged WITNESS, {} of the paper set not; \
         GETCOEF read each set back",
        witnessed.len(),
        paper.len()
    );
}
