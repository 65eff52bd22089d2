//! `magcomp upload` as a verified exchange, against a fake board on the other end of a
//! unix socket: the core's `CommandReader` parses the bytes it receives, SET/GET act on an
//! in-memory state held like the firmware holds it (coefficients scaled by σ_prior, so a
//! read-back can be 1 ulp off), replies formatted as `src/fw.rs` `handle_command` formats
//! them, and faults injected on the bytes received (a byte lost, a terminator lost, a
//! refused value, silence).

mod common;

use common::cli::{bin, tmp};
use magcomp::board::link::{upload, within_2_ulp, BoardLink, ExchangeOptions, LineSource};
use magcomp::board::upload::upload_commands;
use magcomp::calibration::coefficients::{Coefficient, CoefficientFile, Method};
use magcomp::estimate::fluxcal::FluxgateCalibration;
use magcomp::model::spec::ModelSpec;
use magcomp_core::protocol::command::{
    encode_ack, encode_ack_indexed, encode_error, Command, CommandError, CommandReader,
    FLUX_CAL_LEN, FLUX_TEMP_LEN,
};
use magcomp_core::protocol::common::Cursor;
use magcomp_core::protocol::fluxgate::{FluxCalibration, FluxTempCal};
use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

const N_COEF: usize = 16;

#[derive(Clone, Copy, Debug)]
enum Fault {
    None,
    /// One byte (the 11th) of every n-th line received is lost.
    DropByteEvery(usize),
    /// The k-th line received (1-based) loses its `\r\n`; with `damaged`, also a byte.
    DropTerminatorOf {
        k: usize,
        damaged: bool,
    },
    /// `SETFLUX,index` is refused with VALUE (as an implausible calibration would be).
    RefuseFlux(u16),
    /// Reads everything, answers nothing.
    Silent,
    /// `SETFLUX,index` is acknowledged with the value sent but 0.5 more is stored.
    StoreFluxOff(u16),
}

/// What the board holds: coefficients as the filter's scaled state x = c / σ.
#[derive(Clone, Debug, PartialEq)]
struct BoardState {
    x: [f32; N_COEF],
    flux: [f32; FLUX_CAL_LEN],
    lag_s: f32,
    ftemp: [f32; FLUX_TEMP_LEN],
}

fn sigma(i: usize) -> f32 {
    0.37 + 0.113 * i as f32
}

impl BoardState {
    fn new() -> Self {
        Self {
            x: [0.0; N_COEF],
            flux: FluxCalibration::IDENTITY.to_array(),
            lag_s: 0.0,
            ftemp: [0.0; FLUX_TEMP_LEN],
        }
    }
    fn coef(&self, i: usize) -> f32 {
        self.x[i] * sigma(i)
    }
}

#[derive(Debug)]
struct FakeReport {
    ram: BoardState,
    saved: Option<BoardState>,
    saves: usize,
    /// `MODE,SURVEY` received after the last `SAVE` (the set is flown only then).
    survey_after_save: bool,
    lines_received: usize,
    damaged: usize,
}

fn ack_values(name: &[u8], values: &[f32]) -> Vec<u8> {
    let texts: Vec<Vec<u8>> = values
        .iter()
        .map(|&v| {
            let mut b = [0u8; 32];
            let mut c = Cursor::new(&mut b);
            c.sci(v.into()).unwrap();
            c.written().to_vec()
        })
        .collect();
    let args: Vec<&[u8]> = texts.iter().map(|t| t.as_slice()).collect();
    let mut out = [0u8; 512];
    let n = encode_ack(name, &args, &mut out).unwrap();
    out[..n].to_vec()
}

fn indexed(name: &[u8], i: u16, v: f32) -> Vec<u8> {
    let mut out = [0u8; 96];
    let n = encode_ack_indexed(name, i, v, &mut out).unwrap();
    out[..n].to_vec()
}

fn error(e: CommandError) -> Vec<u8> {
    let mut out = [0u8; 64];
    let n = encode_error(e, &mut out).unwrap();
    out[..n].to_vec()
}

/// The reply `src/fw.rs` `handle_command` gives.
fn handle(cmd: Command, s: &mut BoardState, r: &mut FakeReport, fault: Fault) -> Vec<u8> {
    match cmd {
        Command::SetCoef { index, value } => {
            s.x[usize::from(index)] = value / sigma(usize::from(index));
            indexed(b"SETCOEF", index, value)
        }
        Command::GetCoef(Some(i)) => indexed(b"GETCOEF", i, s.coef(usize::from(i))),
        Command::GetCoef(None) => ack_values(
            b"GETCOEF",
            &(0..N_COEF).map(|i| s.coef(i)).collect::<Vec<_>>(),
        ),
        Command::SetFlux { index, value } => {
            let mut v = s.flux;
            v[usize::from(index)] = value;
            match (fault, FluxCalibration::from_array(&v)) {
                (Fault::RefuseFlux(i), _) if i == index => error(CommandError::ValueOutOfBounds),
                (Fault::StoreFluxOff(i), Some(_)) if i == index => {
                    s.flux[usize::from(index)] = value + 0.5;
                    indexed(b"SETFLUX", index, value)
                }
                (_, Some(_)) => {
                    s.flux = v;
                    indexed(b"SETFLUX", index, value)
                }
                (_, None) => error(CommandError::ValueOutOfBounds),
            }
        }
        Command::GetFlux(Some(i)) => indexed(b"GETFLUX", i, s.flux[usize::from(i)]),
        Command::GetFlux(None) => ack_values(b"GETFLUX", &s.flux),
        Command::SetFluxTemp { index, value } => {
            let mut v = s.ftemp;
            v[usize::from(index)] = value;
            match FluxTempCal::from_array(&v) {
                Some(_) => {
                    s.ftemp = v;
                    indexed(b"SETFTEMP", index, value)
                }
                None => error(CommandError::ValueOutOfBounds),
            }
        }
        Command::GetFluxTemp(Some(i)) => indexed(b"GETFTEMP", i, s.ftemp[usize::from(i)]),
        Command::GetFluxTemp(None) => ack_values(b"GETFTEMP", &s.ftemp),
        Command::SetLag(v) => {
            s.lag_s = v;
            ack_values(b"SETLAG", &[v])
        }
        Command::GetLag => ack_values(b"GETLAG", &[s.lag_s]),
        Command::Save => {
            r.saved = Some(s.clone());
            r.saves += 1;
            r.survey_after_save = false;
            ack_values(b"SAVE", &[])
        }
        Command::Mode(magcomp_core::protocol::command::Mode::Survey) => {
            r.survey_after_save = r.saves > 0;
            let mut out = [0u8; 64];
            let n = encode_ack(b"MODE", &[b"SURVEY"], &mut out).unwrap();
            out[..n].to_vec()
        }
        other => panic!("upload does not send {other:?}"),
    }
}

/// Runs the fake board on `port` until the other side shuts the stream down.
fn fake_board(mut port: UnixStream, fault: Fault) -> JoinHandle<FakeReport> {
    std::thread::spawn(move || {
        let mut state = BoardState::new();
        let mut r = FakeReport {
            ram: state.clone(),
            saved: None,
            saves: 0,
            survey_after_save: false,
            lines_received: 0,
            damaged: 0,
        };
        let mut reader = CommandReader::new(N_COEF);
        let mut pending = Vec::new();
        let mut buf = [0u8; 256];
        let mut replies = 0usize;
        // a boot line first: not a reply, skipped
        let _ = port.write_all(b"$MCBOOT,fake\r\n");
        loop {
            let n = match port.read(&mut buf) {
                Ok(0) | Err(_) => break,
                Ok(n) => n,
            };
            for &b in &buf[..n] {
                pending.push(b);
                if b != b'\n' {
                    continue;
                }
                let mut line = std::mem::take(&mut pending);
                if line.iter().any(|b| !b.is_ascii_whitespace()) {
                    r.lines_received += 1;
                    let k = r.lines_received;
                    match fault {
                        Fault::DropByteEvery(every) if k.is_multiple_of(every) => {
                            line.remove(10);
                            r.damaged += 1;
                        }
                        Fault::DropTerminatorOf { k: at, damaged } if at == k => {
                            line.truncate(line.len() - 2);
                            if damaged {
                                line.remove(10);
                                r.damaged += 1;
                            }
                        }
                        _ => {}
                    }
                }
                for &c in &line {
                    let Some(res) = reader.push(c) else { continue };
                    if matches!(fault, Fault::Silent) {
                        continue;
                    }
                    let reply = match res {
                        Ok(cmd) => handle(cmd, &mut state, &mut r, fault),
                        Err(e) => error(e),
                    };
                    replies += 1;
                    // records and sync lines between replies: not replies, skipped
                    if replies.is_multiple_of(3) {
                        let _ = port.write_all(b"$MCREC,17,1.5,2.5,NaN*0000\r\n$MCSYN,4,4,1\r\n");
                    }
                    if port.write_all(&reply).is_err() {
                        break;
                    }
                }
            }
        }
        r.ram = state;
        r
    })
}

fn file() -> CoefficientFile {
    let names = ModelSpec::parse("tl16+field+fluxcal")
        .unwrap()
        .coefficient_names();
    let coefficients = names
        .iter()
        .enumerate()
        .map(|(i, (n, _))| Coefficient {
            name: n.clone(),
            unit: "nT".into(),
            value: (i as f64 - 7.3) * 8.39,
            sigma: 0.1,
        })
        .collect();
    CoefficientFile {
        fluxgate_calibration: Some(FluxgateCalibration {
            matrix: [
                [1.006, 0.002, -0.001],
                [0.002, 0.993, 0.0015],
                [-0.001, 0.0015, 1.004],
            ],
            bias_nt: [320.5, -250.25, 410.0],
        }),
        ..CoefficientFile::new("tl16+field+fluxcal", Method::Kf, 10.0, coefficients)
    }
}

/// What the file puts on the board: coefficients, fluxcal, τ, fluxtemp.
fn want() -> (
    [f32; N_COEF],
    [f32; FLUX_CAL_LEN],
    f32,
    [f32; FLUX_TEMP_LEN],
) {
    let mut c = [0.0; N_COEF];
    let mut f = [0.0; FLUX_CAL_LEN];
    let mut lag = f32::NAN;
    let mut t = [f32::NAN; FLUX_TEMP_LEN];
    for cmd in upload_commands(&file(), "tl16+field", true).unwrap() {
        match cmd {
            Command::SetCoef { index, value } => c[usize::from(index)] = value,
            Command::SetFlux { index, value } => f[usize::from(index)] = value,
            Command::SetFluxTemp { index, value } => t[usize::from(index)] = value,
            Command::SetLag(v) => lag = v,
            _ => {}
        }
    }
    (c, f, lag, t)
}

/// The board holds what the file says: coefficients within 2 ulp (scaled state), the rest
/// exactly; the number of coefficients that came back not bit-exact.
fn assert_holds_the_file(s: &BoardState) -> usize {
    let (c, f, lag, t) = want();
    for (i, &want) in c.iter().enumerate() {
        assert!(
            within_2_ulp(s.coef(i), want),
            "coef {i}: {} vs {want}",
            s.coef(i)
        );
    }
    assert_eq!(s.flux, f);
    assert_eq!(s.lag_s, lag);
    assert_eq!(s.ftemp, t);
    (0..N_COEF).filter(|&i| s.coef(i) != c[i]).count()
}

struct Run {
    result: anyhow::Result<magcomp::board::link::UploadSummary>,
    board: FakeReport,
    elapsed: Duration,
}

fn run(fault: Fault, timeout: Duration) -> Run {
    let (host, board) = UnixStream::pair().unwrap();
    let fake = fake_board(board, fault);
    let lines = LineSource::spawn(host.try_clone().unwrap());
    let opts = ExchangeOptions {
        reply_timeout: timeout,
        ..ExchangeOptions::default()
    };
    let mut link = BoardLink::new(host.try_clone().unwrap(), lines, opts);
    let cmds = upload_commands(&file(), "tl16+field", true).unwrap();
    assert_eq!(cmds.len(), 16 + 12 + 1 + 7 + 1);
    let t0 = Instant::now();
    let result = upload(&mut link, &cmds);
    let elapsed = t0.elapsed();
    host.shutdown(std::net::Shutdown::Both).unwrap();
    Run {
        result,
        board: fake.join().unwrap(),
        elapsed,
    }
}

const LINES: usize = 36 + 1;
const READ_BACK: usize = 36;

#[test]
fn clean_line_every_line_acknowledged_and_read_back() {
    let r = run(Fault::None, Duration::from_secs(2));
    let s = r.result.unwrap();
    assert_eq!(s.exchange.lines_sent, LINES);
    assert_eq!(s.exchange.acknowledged, LINES);
    assert_eq!(s.exchange.resends, 0);
    assert_eq!(s.read_back_ok, READ_BACK);
    assert_eq!(s.read_back.resends, 0);
    assert_eq!(r.board.saves, 1);
    // the read-back, then MODE,SURVEY: the board flies the set only after both
    assert_eq!(r.board.lines_received, LINES + READ_BACK + 1);
    assert!(r.board.survey_after_save);
    let saved = r.board.saved.unwrap();
    let off_by_ulps = assert_holds_the_file(&saved);
    // the 2-ulp tolerance is exercised: σ-scaling moved some coefficients
    assert!(off_by_ulps > 0, "no coefficient moved by the scaling");
    println!("{off_by_ulps} of {N_COEF} coefficients read back 1–2 ulp off");
}

#[test]
fn a_lost_byte_in_every_fifth_line_is_resent() {
    let r = run(Fault::DropByteEvery(5), Duration::from_secs(2));
    let s = r.result.unwrap();
    let d = r.board.damaged;
    // every 5th of the lines received, resends included
    assert_eq!(d, r.board.lines_received / 5);
    assert_eq!(r.board.lines_received, LINES + READ_BACK + 1 + d);
    assert_eq!(s.exchange.resends + s.read_back.resends, d);
    assert_eq!(
        s.exchange.transport_errors + s.read_back.transport_errors,
        d
    );
    assert_eq!(s.exchange.timeouts + s.read_back.timeouts, 0);
    assert!(s.exchange.resends >= 7, "{:?}", s.exchange);
    assert_eq!(s.exchange.acknowledged, LINES);
    assert_eq!(s.read_back_ok, READ_BACK);
    assert_eq!(r.board.saves, 1);
    assert_holds_the_file(&r.board.saved.unwrap());
    println!(
        "{d} damaged lines, {} resends",
        s.exchange.resends + s.read_back.resends
    );
}

#[test]
fn a_lost_terminator_is_recovered_by_the_timeout() {
    // line 9 (SETCOEF,8) loses its \r\n: no reply until the host's bare \r\n ends it,
    // then it is applied and acknowledged; no resend needed.
    let r = run(
        Fault::DropTerminatorOf {
            k: 9,
            damaged: false,
        },
        Duration::from_millis(200),
    );
    let s = r.result.unwrap();
    assert_eq!(s.exchange.timeouts, 1);
    assert_eq!(s.exchange.resends, 0);
    assert_eq!(s.exchange.acknowledged, LINES);
    assert_eq!(s.read_back_ok, READ_BACK);
    assert_holds_the_file(&r.board.saved.unwrap());
    // also damaged: the \r\n makes it a CHECKSUM error, the line is resent once.
    let r = run(
        Fault::DropTerminatorOf {
            k: 9,
            damaged: true,
        },
        Duration::from_millis(200),
    );
    let s = r.result.unwrap();
    assert_eq!(s.exchange.timeouts, 1);
    assert_eq!(s.exchange.resends, 1);
    assert_eq!(r.board.lines_received, LINES + READ_BACK + 1 + 1);
    assert_eq!(s.read_back_ok, READ_BACK);
    assert_holds_the_file(&r.board.saved.unwrap());
}

#[test]
fn a_refused_value_stops_before_save() {
    let r = run(Fault::RefuseFlux(4), Duration::from_secs(2));
    let e = format!("{:#}", r.result.unwrap_err());
    assert!(
        e.contains("stopped before SAVE") && e.contains("SETFLUX,4,") && e.contains("6,VALUE"),
        "{e}"
    );
    assert_eq!(r.board.saves, 0, "SAVE never sent");
    assert!(
        !r.board.survey_after_save,
        "a refused upload is never flown"
    );
    // 16 SETCOEF + SETFLUX 0–4, then nothing
    assert_eq!(r.board.lines_received, 16 + 5);
    assert_eq!(
        r.board.ram.flux[4], 1.0,
        "SETFLUX,4 not applied: the identity's 1 stays"
    );
}

#[test]
fn a_silent_board_is_an_error_after_the_retries_not_a_hang() {
    let timeout = Duration::from_millis(100);
    let r = run(Fault::Silent, timeout);
    let e = format!("{:#}", r.result.unwrap_err());
    assert!(
        e.contains("no acknowledgement for '$MCCMD,SETCOEF,0,") && e.contains("after 3 resends"),
        "{e}"
    );
    assert_eq!(
        r.board.lines_received, 4,
        "1 send + 3 resends of the first line"
    );
    assert_eq!(r.board.saves, 0);
    // 4 × (timeout + drain of timeout/4) = 0.5 s; generous bound against a hang
    assert!(r.elapsed < Duration::from_secs(5), "{:?}", r.elapsed);
    assert!(r.elapsed >= timeout * 4, "{:?}", r.elapsed);
}

#[test]
fn a_value_stored_wrong_fails_the_read_back() {
    let r = run(Fault::StoreFluxOff(9), Duration::from_secs(2));
    let e = format!("{:#}", r.result.unwrap_err());
    // the file's bias 320.5 nT, stored as 321
    assert!(
        e.contains("read-back differs from the file in 1 of 36 values: GETFLUX,9: board 3.21e2, file 3.205e2"),
        "{e}"
    );
    assert_eq!(r.board.saves, 1);
    // a failed read-back: the set is never switched to (no MODE,SURVEY)
    assert_eq!(r.board.lines_received, LINES + READ_BACK);
    assert!(!r.board.survey_after_save);
}

/// `magcomp upload --to SOCKET`: the exchange from the command line; exit 0 with the
/// summary, non-zero naming the refused line.
#[test]
fn cli_upload_to_a_socket() {
    let d = tmp("upload-socket");
    let coeffs = d.join("coeffs.json");
    std::fs::write(&coeffs, serde_json::to_string(&file()).unwrap()).unwrap();
    for (fault, ok) in [
        (Fault::DropByteEvery(7), true),
        (Fault::RefuseFlux(2), false),
    ] {
        let sock = d.join("board.sock");
        let _ = std::fs::remove_file(&sock);
        let listener = UnixListener::bind(&sock).unwrap();
        let board = std::thread::spawn(move || {
            let (s, _) = listener.accept().unwrap();
            fake_board(s, fault).join().unwrap()
        });
        let out = bin()
            .arg("upload")
            .arg(&coeffs)
            .arg("--to")
            .arg(&sock)
            .args(["--board-model", "tl16+field", "--reply-timeout-s", "1"])
            .output()
            .unwrap();
        let report = board.join().unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.success(), ok, "{stdout}\n{stderr}");
        if ok {
            let resends = report.damaged;
            assert!(
                stdout.contains(&format!(
                    "sent 37 lines to {}: 37 acknowledged, ",
                    sock.display()
                )) && stdout.contains("read-back OK: 36 of 36 values"),
                "{stdout}"
            );
            assert!(resends > 0);
            assert_eq!(report.saves, 1);
            assert_holds_the_file(&report.saved.unwrap());
        } else {
            assert!(
                stderr.contains("refused '$MCCMD,SETFLUX,2,") && stderr.contains("VALUE"),
                "{stderr}"
            );
            assert_eq!(report.saves, 0);
        }
    }
}
