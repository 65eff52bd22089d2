//! Hardware-in-the-loop tests of the coefficient store's flash behaviour: `SAVE` and
//! `FACTORY,ERASE` while the sensors stream (the CPU stalls for each sector erase: the
//! emulated store stalls the worst case, 500 ms, see `board_shape::SECTOR_ERASE_MAX_US`),
//! and the store of earlier firmware (the real board's sectors 10–11) loaded after an
//! upgrade and retired by `FACTORY,ERASE`. Each test SKIPs (passes with a message) when
//! qemu-system-arm is missing, unless `MAGCOMP_REQUIRE_QEMU=1`.

mod common;

use common::{
    assert_one_record_per_sample, collect_records, reply, reply_values, send_hook, speed, start,
    start_with_hooks,
};
use hil_tests::board::{self, Board, MAX_RESENDS, sentence};
use hil_tests::capture::{FlightSpec, synthetic_flight};
use magcomp_core::protocol::command::{Reply, parse_reply};
use std::io::Write;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// The emulated store's stall per sector erase (`board_shape::SECTOR_ERASE_MAX_US`).
const ERASE_S: f64 = 0.5;

/// Sends `body` on the command port from a thread other than the streaming one and waits
/// for its reply in the shared line log; a reply saying the line arrived damaged (see
/// `Board::command_line`), or none in 5 s (a lost line end merged it with the next), gets
/// it resent. Returns the reply and the seconds it took.
fn command_while_streaming(
    cmd: &Mutex<Box<dyn Write + Send>>,
    lines: &Mutex<Vec<String>>,
    body: &str,
) -> (String, f64) {
    let is_reply = |l: &str| l.starts_with("$MCACK") || l.starts_with("$MCERR");
    for _ in 0..=MAX_RESENDS {
        let from = lines.lock().map(|l| l.len()).unwrap_or(0);
        let t0 = Instant::now();
        assert!(cmd.lock().unwrap().write_all(&sentence(body)).is_ok());
        let end = t0 + Duration::from_secs(5);
        let r = loop {
            let found = lines
                .lock()
                .ok()
                .and_then(|l| l.iter().skip(from).find(|l| is_reply(l)).cloned());
            if found.is_some() || Instant::now() > end {
                break found;
            }
            std::thread::sleep(Duration::from_millis(5));
        };
        let dt = t0.elapsed().as_secs_f64();
        match r.as_deref().map(|r| (r, parse_reply(r.as_bytes()))) {
            Some((r, Some(Reply::Refused(e)))) if e.is_transport() => {
                eprintln!("note: {body} arrived damaged ({r}), resent");
            }
            Some((r, _)) => return (r.to_string(), dt),
            None => eprintln!("note: {body}: no reply in 5 s, resent"),
        }
    }
    panic!("{body}: no clean reply after {MAX_RESENDS} resends");
}

/// Issue 23 item 5: `SAVE` no longer freezes acquisition for a 128 KiB erase. Idle, one
/// `SAVE` takes at least the emulated erase (0.5 s). Then, while scalar, fluxgate and GPS
/// stream at their real rates (not paced by the board's `$MCSYN`, so their bytes keep
/// coming during each stall), four `SAVE`, a `FACTORY,ERASE` (two erases: the longest
/// stall, 1 s) and one more `SAVE`: every scalar sample still yields exactly one record,
/// contiguous, and the board never resets (one boot banner: the watchdog stayed fed).
#[test]
fn save_while_sensors_stream_keeps_every_record_and_the_watchdog_fed() {
    let name = "savestream";
    let Some(mut b) = start(name) else {
        return;
    };
    let t0 = Instant::now();
    assert!(reply(&mut b, "MCCMD,SAVE").starts_with("$MCACK,SAVE"));
    let idle_save = t0.elapsed().as_secs_f64();
    if board::emulated() {
        assert!(
            idle_save >= ERASE_S,
            "{name}: SAVE took {idle_save:.3} s, the emulated erase is {ERASE_S} s"
        );
    }
    let cap = synthetic_flight(&FlightSpec::new(0x5A7E_0016, 12.0));
    let (cmd, lines) = (b.command_writer(), b.line_log());
    let plan = [
        (1.5, "MCCMD,SAVE"),
        (3.0, "MCCMD,SAVE"),
        (4.5, "MCCMD,SAVE"),
        (6.0, "MCCMD,SAVE"),
        (7.5, "MCCMD,FACTORY,ERASE"),
        (9.5, "MCCMD,SAVE"),
    ];
    let sender = std::thread::spawn({
        let (cmd, lines) = (Arc::clone(&cmd), Arc::clone(&lines));
        move || {
            let start = Instant::now();
            let mut out = Vec::new();
            for (at, body) in plan {
                let due = start + Duration::from_secs_f64(at / speed());
                if let Some(d) = due.checked_duration_since(Instant::now()) {
                    std::thread::sleep(d);
                }
                out.push((body, command_while_streaming(&cmd, &lines, body)));
            }
            out
        }
    });
    b.stream_unpaced(&cap, speed())
        .unwrap_or_else(|e| panic!("{name}: stream: {e}"));
    let replies = sender.join().expect("command thread");
    let n = cap.scalar_t_s.len();
    let (recs, _) = collect_records(&mut b, name, n);
    for (body, (r, dt)) in &replies {
        let what = body.trim_start_matches("MCCMD,");
        let want = format!("$MCACK,{}", what.split(',').next().unwrap_or(what));
        assert!(r.starts_with(&want), "{name}: {body} → {r}");
        if board::emulated() {
            let erases = if what.starts_with("FACTORY") {
                2.0
            } else {
                1.0
            };
            assert!(
                *dt >= erases * ERASE_S,
                "{name}: {body} answered in {dt:.3} s: no {erases} × {ERASE_S} s stall"
            );
        }
    }
    assert_one_record_per_sample(name, &b, &cap, &recs);
    let s = reply(&mut b, "MCCMD,STATUS");
    assert!(s.starts_with("$MCACK,STATUS,CAL,"), "{name}: {s}");
    let took: Vec<String> = replies
        .iter()
        .map(|(body, (_, dt))| format!("{} {dt:.2} s", body.trim_start_matches("MCCMD,")))
        .collect();
    eprintln!(
        "{name}: idle SAVE {idle_save:.2} s; streaming: {}; {n} samples in, {} records out, one boot",
        took.join(", "),
        recs.len()
    );
}

/// A board flashed with earlier firmware keeps its store where that firmware wrote it (the
/// real board's sectors 10–11; the emulated build's hidden `!OLDSTORE` / `!OLDLEGACY` put
/// it there and leave the current images' sectors holding no image, as the old code in
/// them does). Boot (`RESET` here) loads the newest valid old image, or the single-image
/// store's blobs; the next `SAVE` writes the current images, which win from then on;
/// `FACTORY,ERASE` retires the old store too, so nothing older comes back.
#[test]
fn store_of_earlier_firmware_loads_after_upgrade_and_factory_reset_retires_it() {
    let name = "upgrade";
    let Some(mut b) = start_with_hooks(name) else {
        return;
    };
    let ok = |r: String, what: &str| assert!(r.starts_with(what), "{name}: {r}");
    let lag = |b: &mut Board| reply_values(&reply(b, "MCCMD,GETLAG"))[0];
    let mode = |b: &mut Board| {
        let s = reply(b, "MCCMD,STATUS");
        s.split(',').nth(2).unwrap_or_default().to_string()
    };
    let reset = |b: &mut Board| ok(reply(b, "MCCMD,RESET"), "$MCACK,RESET,");
    let save_lag = |b: &mut Board, tau: f32| {
        ok(reply(b, &format!("MCCMD,SETLAG,{tau}")), "$MCACK,SETLAG,");
        ok(reply(b, "MCCMD,SAVE"), "$MCACK,SAVE");
    };
    ok(reply(&mut b, "MCCMD,SETCOEF,3,1.5"), "$MCACK,SETCOEF,3,");
    // two images, the newer τ = 0.2
    save_lag(&mut b, 0.3);
    save_lag(&mut b, 0.2);

    // from the two-image firmware: its newest image loads
    send_hook(&mut b, b"!OLDSTORE\r\n");
    reset(&mut b);
    assert_eq!(lag(&mut b), 0.2, "{name}: old store's newest image");
    assert_eq!(mode(&mut b), "SURVEY", "{name}: old coefficients loaded");
    // the next SAVE writes the current images: they win over the old store
    save_lag(&mut b, 0.4);
    reset(&mut b);
    assert_eq!(lag(&mut b), 0.4, "{name}: the new image after SAVE");
    // FACTORY,ERASE: the old store does not come back
    ok(reply(&mut b, "MCCMD,FACTORY,ERASE"), "$MCACK,FACTORY,");
    reset(&mut b);
    assert_eq!(lag(&mut b), 0.0, "{name}: after FACTORY + RESET");
    assert_eq!(mode(&mut b), "CAL", "{name}: after FACTORY + RESET");

    // from the single-image firmware: its blobs alone at the start of old image 1
    ok(reply(&mut b, "MCCMD,SETCOEF,3,1.5"), "$MCACK,SETCOEF,3,");
    save_lag(&mut b, 0.25);
    send_hook(&mut b, b"!OLDLEGACY\r\n");
    reset(&mut b);
    assert_eq!(lag(&mut b), 0.25, "{name}: single-image store");
    assert_eq!(mode(&mut b), "SURVEY", "{name}: single-image coefficients");
    ok(reply(&mut b, "MCCMD,FACTORY,ERASE"), "$MCACK,FACTORY,");
    reset(&mut b);
    assert_eq!(
        lag(&mut b),
        0.0,
        "{name}: after FACTORY + RESET (single image)"
    );
    assert_eq!(
        mode(&mut b),
        "CAL",
        "{name}: after FACTORY + RESET (single image)"
    );
    eprintln!(
        "{name}: old two-image store (newest τ 0.2) and single-image store (τ 0.25) loaded \
         after the upgrade; SAVE then wins; FACTORY,ERASE retired both, nothing came back"
    );
}
