//! A verified command exchange with the board: every command line is sent, its reply read
//! (`$MCACK` / `$MCERR`, parsed by the core's `parse_reply`), a damaged line resent, a
//! verdict reported — so `magcomp upload` never stores (`SAVE`) a partly old coefficient
//! set because a byte was lost on the serial line.
//!
//! The board can lose a command byte (noise; also embassy-stm32's BufferedUart clears TC
//! with a read-modify-write of the USART SR that can clear an RXNE arriving in between):
//! it then answers `$MCERR,2,CHECKSUM` (or FRAMING/OVERLONG) and does not apply the line,
//! or — if the terminator was lost — does not answer until the next line ends.

use anyhow::{anyhow, bail, Context, Result};
use magcomp_core::protocol::command::{encode_command, parse_reply, Command, Mode, Reply};
use std::io::{BufRead, BufReader, Read, Write};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

/// Lines from the board, read by a thread so that a reply can be awaited with a timeout
/// on any byte stream (a tty, a socket).
pub struct LineSource {
    rx: Receiver<Vec<u8>>,
}

/// Longest board line kept (bytes). The board's replies and records are under 200 bytes;
/// a longer run without a line end is noise (a babbling port, the wrong baud rate) and is
/// dropped up to its end, so it can neither grow memory without bound nor end the link.
pub const MAX_BOARD_LINE_BYTES: usize = 4096;

impl LineSource {
    /// Reads `r` on a thread until end of stream or an error; lines without `\r\n`, lines
    /// longer than [`MAX_BOARD_LINE_BYTES`] dropped.
    pub fn spawn<R: Read + Send + 'static>(r: R) -> Self {
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let mut r = BufReader::new(r);
            let mut line = Vec::new();
            loop {
                line.clear();
                match (&mut r)
                    .take(MAX_BOARD_LINE_BYTES as u64 + 1)
                    .read_until(b'\n', &mut line)
                {
                    Ok(0) | Err(_) => break,
                    Ok(_) if line.len() > MAX_BOARD_LINE_BYTES && line.last() != Some(&b'\n') => {
                        // The rest of the overlong run, up to its line end.
                        if r.skip_until(b'\n').is_err() {
                            break;
                        }
                    }
                    Ok(_) => {
                        while let [rest @ .., b'\r' | b'\n'] = line.as_slice() {
                            line.truncate(rest.len());
                        }
                        if tx.send(line.clone()).is_err() {
                            break;
                        }
                    }
                }
            }
        });
        Self { rx }
    }

    /// The next line before `deadline`; `Ok(None)` at the deadline, an error when the
    /// board's side of the stream closed.
    fn next_before(&self, deadline: Instant) -> Result<Option<Vec<u8>>> {
        let wait = deadline.saturating_duration_since(Instant::now());
        match self.rx.recv_timeout(wait) {
            Ok(l) => Ok(Some(l)),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => bail!("the board's port closed"),
        }
    }
}

/// Retry policy of the exchange.
#[derive(Clone, Copy, Debug)]
pub struct ExchangeOptions {
    /// How long to wait for a command's reply (`SAVE`: 5× this, a flash write).
    pub reply_timeout: Duration,
    /// Resends of one line (after a transport error or a timeout) before giving up.
    pub max_resends: u32,
}

impl Default for ExchangeOptions {
    fn default() -> Self {
        Self {
            reply_timeout: Duration::from_secs(2),
            max_resends: 3,
        }
    }
}

/// What an exchange did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ExchangeStats {
    /// Distinct command lines (resends not counted).
    pub lines_sent: usize,
    pub acknowledged: usize,
    /// Transmissions after the first, for either reason below.
    pub resends: usize,
    /// Replies saying the line arrived damaged (FRAMING, CHECKSUM, OVERLONG).
    pub transport_errors: usize,
    /// Lines with no reply within the timeout.
    pub timeouts: usize,
}

/// f32 values within 2 ulp of the larger: a coefficient is held scaled on the board
/// (x = c / σ_prior, read back as x · σ_prior), which can move it by one ulp.
pub fn within_2_ulp(a: f32, b: f32) -> bool {
    let m = a.abs().max(b.abs());
    if !m.is_finite() {
        return a == b;
    }
    let ulp = f32::from_bits(m.to_bits() + 1) - m;
    (a - b).abs() <= 2.0 * ulp
}

/// Whether the board holds `got` for the `sent` value: a coefficient within 2 ulp, any
/// other value exactly.
fn held_as_sent(sent: f32, got: f32, coefficient: bool) -> bool {
    if coefficient {
        within_2_ulp(sent, got)
    } else {
        sent == got
    }
}

/// The command line as sent (XOR checksum, `\r\n`).
pub fn command_line(cmd: &Command) -> Result<String> {
    let mut buf = [0u8; 128];
    let n = encode_command(cmd, &mut buf).ok_or_else(|| anyhow!("{cmd:?}: line too long"))?;
    Ok(String::from_utf8_lossy(&buf[..n]).into_owned())
}

fn fields(ack: &[u8]) -> Vec<&str> {
    std::str::from_utf8(ack)
        .map(|s| s.split(',').collect())
        .unwrap_or_default()
}

fn value(s: &str) -> Option<f32> {
    s.parse::<f32>().ok()
}

/// What the ACK of `cmd` looks like: its command word and the numbers it echoes (index;
/// sensor and index for sensors 1–2).
fn ack_key(cmd: &Command) -> (&'static str, Vec<u16>) {
    let (word, index) = match *cmd {
        Command::SetSensorCoef { sensor, index, .. } => {
            return ("SETCOEF", vec![sensor.into(), index])
        }
        Command::GetSensorCoef {
            sensor,
            index: Some(i),
        } => return ("GETCOEF", vec![sensor.into(), i]),
        Command::GetSensorCoef { sensor, .. } => return ("GETCOEF", vec![sensor.into()]),
        Command::SetCoef { index, .. } => ("SETCOEF", Some(index)),
        Command::SetFlux { index, .. } => ("SETFLUX", Some(index)),
        Command::SetFluxTemp { index, .. } => ("SETFTEMP", Some(index)),
        Command::SetLag(_) => ("SETLAG", None),
        Command::GetCoef(i) => ("GETCOEF", i),
        Command::GetFlux(i) => ("GETFLUX", i),
        Command::GetFluxTemp(i) => ("GETFTEMP", i),
        Command::GetLag => ("GETLAG", None),
        Command::Save => ("SAVE", None),
        Command::Reset => ("RESET", None),
        Command::Flush => ("FLUSH", None),
        Command::FactoryReset => ("FACTORY", None),
        Command::Raw(_) => ("RAW", None),
        Command::Status => ("STATUS", None),
        Command::Mode(_) => ("MODE", None),
    };
    (word, index.into_iter().collect())
}

/// The value a SET command carries, and whether the board may hold it within 2 ulp
/// rather than exactly (a coefficient).
pub fn set_value(cmd: &Command) -> Option<(f32, bool)> {
    match *cmd {
        Command::SetCoef { value, .. } | Command::SetSensorCoef { value, .. } => {
            Some((value, true))
        }
        Command::SetFlux { value, .. } | Command::SetFluxTemp { value, .. } => Some((value, false)),
        Command::SetLag(v) => Some((v, false)),
        _ => None,
    }
}

/// The GET that reads back what a SET stored.
pub fn read_back_of(cmd: &Command) -> Option<Command> {
    match *cmd {
        Command::SetCoef { index, .. } => Some(Command::GetCoef(Some(index))),
        Command::SetSensorCoef { sensor, index, .. } => Some(Command::GetSensorCoef {
            sensor,
            index: Some(index),
        }),
        Command::SetFlux { index, .. } => Some(Command::GetFlux(Some(index))),
        Command::SetFluxTemp { index, .. } => Some(Command::GetFluxTemp(Some(index))),
        Command::SetLag(_) => Some(Command::GetLag),
        _ => None,
    }
}

/// Whether `ack` answers `cmd`: `None` if it is another command's (a late reply of an
/// earlier line), else the value it carries (SETs: checked against the one sent).
fn answers(cmd: &Command, ack: &[u8]) -> Result<Option<Option<f32>>> {
    let f = fields(ack);
    let (word, index) = ack_key(cmd);
    if f.first() != Some(&word) {
        return Ok(None);
    }
    if let Command::Mode(m) = cmd {
        // `$MCACK,MODE,SURVEY`: a word, not a number.
        let want = match m {
            Mode::Survey => "SURVEY",
            Mode::Cal => "CAL",
        };
        return Ok((f.get(1) == Some(&want)).then_some(None));
    }
    let echoed = f
        .iter()
        .skip(1)
        .take(index.len())
        .map(|s| s.parse::<u16>().ok());
    if !echoed.eq(index.iter().map(|&i| Some(i))) {
        return Ok(None);
    }
    let rest = &f[1 + index.len()..];
    let got = match rest {
        [] => None,
        [v] => Some(value(v).ok_or_else(|| {
            anyhow!(
                "the board's reply '{}' has no number",
                String::from_utf8_lossy(ack)
            )
        })?),
        // `GETCOEF` without index and the like: not something this exchange asks.
        _ => return Ok(None),
    };
    if let (Some((sent, coef)), Some(echo)) = (set_value(cmd), got) {
        if !held_as_sent(sent, echo, coef) {
            bail!(
                "the board acknowledged {} with value {echo:e}, {sent:e} was sent",
                String::from_utf8_lossy(ack)
            );
        }
    }
    Ok(Some(got))
}

/// One end of the command port: a writer and the board's lines.
pub struct BoardLink<W: Write> {
    out: W,
    lines: LineSource,
    pub opts: ExchangeOptions,
    pub stats: ExchangeStats,
}

enum Outcome {
    Answered(Option<f32>),
    Resend,
}

impl<W: Write> BoardLink<W> {
    pub fn new(out: W, lines: LineSource, opts: ExchangeOptions) -> Self {
        Self {
            out,
            lines,
            opts,
            stats: ExchangeStats::default(),
        }
    }

    fn send(&mut self, bytes: &[u8]) -> Result<()> {
        self.out
            .write_all(bytes)
            .and_then(|()| self.out.flush())
            .context("writing to the board's port")
    }

    /// Reads until `cmd`'s reply or `deadline`; on the timeout, ends a partial line and
    /// drains its answer.
    fn await_reply(&mut self, cmd: &Command, line: &str, deadline: Instant) -> Result<Outcome> {
        while let Some(l) = self.lines.next_before(deadline)? {
            match parse_reply(&l) {
                // records, sync and boot lines, noise, a reply damaged on its way back
                None => {}
                Some(Reply::Ack(ack)) => {
                    if let Some(v) = answers(cmd, ack)? {
                        return Ok(Outcome::Answered(v));
                    }
                }
                Some(Reply::Refused(e)) if e.is_transport() => {
                    self.stats.transport_errors += 1;
                    return Ok(Outcome::Resend);
                }
                Some(Reply::Refused(e)) => bail!(
                    "the board refused '{}': $MCERR {},{}",
                    line.trim_end(),
                    e.code(),
                    e.text()
                ),
                Some(Reply::BoardError(b)) => bail!(
                    "the board answered '{}' with $MCERR,{}",
                    line.trim_end(),
                    String::from_utf8_lossy(b)
                ),
            }
        }
        self.stats.timeouts += 1;
        // End a line whose terminator was lost (the board answers it), then give the
        // answer a moment: the ACK of `cmd` itself means it was applied after all.
        self.send(b"\r\n")?;
        let drain = Instant::now() + self.opts.reply_timeout / 4;
        while let Some(l) = self.lines.next_before(drain)? {
            if let Some(Reply::Ack(ack)) = parse_reply(&l) {
                if let Some(v) = answers(cmd, ack)? {
                    return Ok(Outcome::Answered(v));
                }
            }
        }
        Ok(Outcome::Resend)
    }

    /// Sends `cmd` until it is acknowledged; the value its ACK carries.
    pub fn exchange(&mut self, cmd: &Command) -> Result<Option<f32>> {
        let line = command_line(cmd)?;
        self.stats.lines_sent += 1;
        let wait = match cmd {
            Command::Save => self.opts.reply_timeout * 5,
            _ => self.opts.reply_timeout,
        };
        for attempt in 0..=self.opts.max_resends {
            if attempt > 0 {
                self.stats.resends += 1;
            }
            self.send(line.as_bytes())?;
            if let Outcome::Answered(v) = self.await_reply(cmd, &line, Instant::now() + wait)? {
                self.stats.acknowledged += 1;
                return Ok(v);
            }
        }
        bail!(
            "no acknowledgement for '{}' after {} resends ({} transport errors, {} timeouts of {:.2} s so far)",
            line.trim_end(),
            self.opts.max_resends,
            self.stats.transport_errors,
            self.stats.timeouts,
            wait.as_secs_f64()
        )
    }
}

/// What [`upload`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UploadSummary {
    /// SET and SAVE lines.
    pub exchange: ExchangeStats,
    /// Values read back and found equal (2 ulp for coefficients, exact otherwise).
    pub read_back_ok: usize,
    /// GET lines' exchange.
    pub read_back: ExchangeStats,
}

/// Sends the SET lines of `cmds` each until acknowledged, then `SAVE` if it is in `cmds`
/// (only then: a refused or unanswered line stops everything before it), then reads every
/// value back and compares it with the one sent, and only then switches the board to
/// survey mode (`MODE,SURVEY`): the board stages `SETCOEF` values and applies the whole
/// set at that command, so a half-sent set is never flown.
pub fn upload<W: Write>(link: &mut BoardLink<W>, cmds: &[Command]) -> Result<UploadSummary> {
    for c in cmds.iter().filter(|c| **c != Command::Save) {
        link.exchange(c).context(
            "stopped before SAVE: the stored values are unchanged; the board keeps flying its old coefficients (the new ones are staged until MODE,SURVEY, dropped by RESET)",
        )?;
    }
    if cmds.contains(&Command::Save) {
        link.exchange(&Command::Save)
            .context("SAVE not acknowledged: the stored values may be the old ones")?;
    }
    let exchange = std::mem::take(&mut link.stats);
    let mut mismatches = Vec::new();
    let mut read_back_ok = 0;
    for c in cmds {
        let (Some(get), Some((sent, coef))) = (read_back_of(c), set_value(c)) else {
            continue;
        };
        let got = link
            .exchange(&get)
            .context("reading back")?
            .ok_or_else(|| {
                anyhow!(
                    "the board's reply to {} holds no value",
                    command_line(&get).unwrap_or_default().trim_end()
                )
            })?;
        if held_as_sent(sent, got, coef) {
            read_back_ok += 1;
        } else {
            let (word, index) = ack_key(&get);
            let index: String = index.iter().map(|i| format!(",{i}")).collect();
            mismatches.push(format!("{word}{index}: board {got:e}, file {sent:e}"));
        }
    }
    let read_back = std::mem::take(&mut link.stats);
    if !mismatches.is_empty() {
        bail!(
            "read-back differs from the file in {} of {} values: {}",
            mismatches.len(),
            mismatches.len() + read_back_ok,
            mismatches.join("; ")
        );
    }
    if cmds
        .iter()
        .any(|c| matches!(c, Command::SetCoef { .. } | Command::SetSensorCoef { .. }))
    {
        link.exchange(&Command::Mode(Mode::Survey))
            .context("MODE,SURVEY not acknowledged: the set is loaded but not flown")?;
    }
    Ok(UploadSummary {
        exchange,
        read_back_ok,
        read_back,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A megabyte without a line end is dropped, and the reply after it still arrives.
    #[test]
    fn an_overlong_run_is_dropped_and_the_next_line_kept() {
        let mut bytes = vec![b'x'; 1 << 20];
        bytes.extend_from_slice(b"\r\n$MCACK,1*00\r\nnext\n");
        let src = LineSource::spawn(std::io::Cursor::new(bytes));
        let deadline = Instant::now() + Duration::from_secs(5);
        assert_eq!(
            src.next_before(deadline).unwrap().as_deref(),
            Some(&b"$MCACK,1*00"[..])
        );
        assert_eq!(
            src.next_before(deadline).unwrap().as_deref(),
            Some(&b"next"[..])
        );
        assert!(src.next_before(deadline).is_err(), "end of stream");
    }

    #[test]
    fn two_ulp_of_f32_and_no_more() {
        // measured on QEMU: SETCOEF 11,-61.25 → GETCOEF -61.2500038 (1 ulp = 3.8e-6)
        assert!(within_2_ulp(-61.25, -61.250_004));
        let two = f32::from_bits((-61.25f32).to_bits() + 2);
        let three = f32::from_bits((-61.25f32).to_bits() + 3);
        assert!(within_2_ulp(-61.25, two));
        assert!(!within_2_ulp(-61.25, three));
        assert!(within_2_ulp(0.0, 0.0));
        assert!(!within_2_ulp(0.0, 1e-30));
        assert!(!within_2_ulp(1.0, f32::NAN));
    }

    #[test]
    fn an_ack_answers_only_its_own_line() {
        let set = Command::SetCoef {
            index: 3,
            value: -61.25,
        };
        assert_eq!(
            answers(&set, b"SETCOEF,3,-6.12500000E1").unwrap(),
            Some(Some(-61.25))
        );
        // a late ACK of another line, another command
        assert_eq!(answers(&set, b"SETCOEF,2,-6.12500000E1").unwrap(), None);
        assert_eq!(answers(&set, b"SETFLUX,3,-6.12500000E1").unwrap(), None);
        // a sensor's SETCOEF: its ACK names the sensor; sensor 0's and another sensor's are
        // other lines
        let set2 = Command::SetSensorCoef {
            sensor: 2,
            index: 3,
            value: -61.25,
        };
        assert_eq!(
            answers(&set2, b"SETCOEF,2,3,-6.12500000E1").unwrap(),
            Some(Some(-61.25))
        );
        assert_eq!(answers(&set2, b"SETCOEF,1,3,-6.12500000E1").unwrap(), None);
        assert_eq!(answers(&set, b"SETCOEF,2,3,-6.12500000E1").unwrap(), None);
        assert_eq!(answers(&set2, b"SETCOEF,3,-6.12500000E1").unwrap(), None);
        assert_eq!(
            read_back_of(&set2),
            Some(Command::GetSensorCoef {
                sensor: 2,
                index: Some(3)
            })
        );
        // the same line echoed with another value: the board holds something else
        let e = answers(&set, b"SETCOEF,3,-6.1E1").unwrap_err();
        assert!(
            e.to_string()
                .contains("with value -6.1e1, -6.125e1 was sent"),
            "{e}"
        );
        // exact for the others
        let lag = Command::SetLag(0.2);
        assert_eq!(
            answers(&lag, b"SETLAG,2.00000003E-1").unwrap(),
            Some(Some(0.2))
        );
        assert!(answers(&lag, b"SETLAG,2.00000018E-1").is_err());
        assert_eq!(answers(&Command::Save, b"SAVE").unwrap(), Some(None));
        assert_eq!(
            answers(&Command::GetCoef(Some(3)), b"GETCOEF,3,1.5").unwrap(),
            Some(Some(1.5))
        );
    }
}
