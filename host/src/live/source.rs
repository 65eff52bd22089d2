//! Follows the board's output port for the live page: a serial device or file, `-`
//! (stdin), or `tcp:HOST:PORT`. The bytes are cut into lines and classified exactly as
//! `magcomp monitor` does ([`LineSplitter`], [`Monitor`](crate::board::monitor::Monitor)
//! inside [`Feed`]). A read error or a lost connection (cable pulled, board power-cycled)
//! is reported and the port reopened every second until it answers again; a recorded file
//! can be played at its records' own pace.

use super::feed::{Feed, Message};
use crate::board::monitor::{save_row, write_save_header, LineSplitter};
use std::io::{Read, Write};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// Pause before reopening a port that failed: an unplugged adapter takes a moment to reappear.
pub const REOPEN_PERIOD: Duration = Duration::from_secs(1);
/// Poll period at the end of a file a logger is still writing (as `monitor --follow`).
const FOLLOW_POLL: Duration = Duration::from_millis(200);
/// A pause longer than this between records of a paced file is not waited out.
const MAX_PACE_GAP_S: f64 = 10.0;

/// What to read and how.
#[derive(Clone, Debug)]
pub struct Input {
    /// Path, `-`, or `tcp:HOST:PORT`.
    pub name: String,
    /// At the end of a regular file, wait for more (a logger still writing it).
    pub follow: bool,
    /// Play the records at the pace of their time stamps (a recorded stream).
    pub realtime: bool,
    /// `stty` settings applied to a device before every (re)open (e.g. `115200 raw -echo`):
    /// a USB adapter pulled and put back comes back with the kernel's defaults.
    pub stty: Option<String>,
}

enum Port {
    Stdin(std::io::Stdin),
    File(std::fs::File, bool),
    Tcp(std::net::TcpStream),
}

impl Port {
    fn open(input: &Input) -> std::io::Result<Port> {
        let name = input.name.as_str();
        if name == "-" {
            return Ok(Port::Stdin(std::io::stdin()));
        }
        if let Some(addr) = name.strip_prefix("tcp:") {
            return std::net::TcpStream::connect(addr).map(Port::Tcp);
        }
        let f = std::fs::File::open(name)?;
        let regular = f.metadata()?.is_file();
        if let (Some(settings), false) = (&input.stty, regular) {
            set_line(name, settings)?;
        }
        Ok(Port::File(f, regular))
    }
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        match self {
            Port::Stdin(s) => s.read(buf),
            Port::File(f, _) => f.read(buf),
            Port::Tcp(t) => t.read(buf),
        }
    }
}

/// Holds records back to their time stamps' pace.
#[derive(Default)]
struct Pacer {
    base: Option<(Instant, f64)>,
    last_t_s: f64,
}

impl Pacer {
    fn wait(&mut self, t_s: f64) {
        if !t_s.is_finite() {
            return;
        }
        let rebase = match self.base {
            None => true,
            // A restart (time going back) or a long silence starts the clock again.
            Some(_) => t_s < self.last_t_s || t_s - self.last_t_s > MAX_PACE_GAP_S,
        };
        if rebase {
            self.base = Some((Instant::now(), t_s));
        }
        self.last_t_s = t_s;
        if let Some((start, t0)) = self.base {
            let due = start + Duration::from_secs_f64((t_s - t0).max(0.0));
            let now = Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
        }
    }
}

/// The page is told (as a link message: it shows in the events) that saving stopped.
fn save_failed(e: &std::io::Error) -> Message {
    Message::Link {
        up: true,
        text: format!("saving the records failed ({e}); no longer saving"),
    }
}

fn unix_ms() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64() * 1e3)
}

/// Reads `input` until it ends for good (stdin or a file without `follow` at its end),
/// sending every record and every change of the link to `send`. Never returns on a port
/// that fails: it is reopened.
/// With `save`, every record is also written as `monitor --save` writes it (header first,
/// flushed per record so the file is as current as the page); a write failure is reported
/// on the page and ends the saving, not the view.
pub fn follow(input: &Input, save: Option<Box<dyn Write + Send>>, mut send: impl FnMut(Message)) {
    let mut feed = Feed::new();
    let source = if input.name == "-" {
        "stdin"
    } else {
        &input.name
    };
    let mut save = save.and_then(|mut w| match write_save_header(&mut w, source) {
        Ok(()) => Some(w),
        Err(e) => {
            send(save_failed(&e));
            None
        }
    });
    let mut lines = LineSplitter::default();
    let mut pacer = Pacer::default();
    let mut buf = [0u8; 4096];
    let mut link_down: Option<String> = None;
    loop {
        let mut port = match Port::open(input) {
            Ok(p) => p,
            Err(e) => {
                let text = format!("cannot open {}: {e}; retrying", input.name);
                if link_down.as_deref() != Some(text.as_str()) {
                    send(Message::Link {
                        up: false,
                        text: text.clone(),
                    });
                    link_down = Some(text);
                }
                std::thread::sleep(REOPEN_PERIOD);
                continue;
            }
        };
        send(Message::Link {
            up: true,
            text: format!("reading {}", input.name),
        });
        let why = loop {
            match port.read(&mut buf) {
                Ok(0) => match &port {
                    Port::File(_, true) if input.follow => std::thread::sleep(FOLLOW_POLL),
                    Port::File(_, true) | Port::Stdin(_) => {
                        flush_rest(
                            &mut feed, &mut lines, &mut pacer, input, &mut save, &mut send,
                        );
                        send(Message::Link {
                            up: false,
                            text: format!("end of {}", input.name),
                        });
                        return;
                    }
                    // A device or socket at its end: the other side went away.
                    _ => break "closed".to_string(),
                },
                Ok(n) => {
                    let _ = lines.push(&buf[..n], |l| {
                        handle(&mut feed, l, &mut pacer, input, &mut save, &mut send);
                        Ok::<(), ()>(())
                    });
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => break e.to_string(),
            }
        };
        // The half line before the break does not continue in what the port sends next.
        lines.clear();
        send(Message::Link {
            up: false,
            text: format!("{} lost ({why}); reopening", input.name),
        });
        // A failure to reopen is then reported once, not every second.
        link_down = None;
        std::thread::sleep(REOPEN_PERIOD);
    }
}

fn handle(
    feed: &mut Feed,
    line: &[u8],
    pacer: &mut Pacer,
    input: &Input,
    save: &mut Option<Box<dyn Write + Send>>,
    send: &mut impl FnMut(Message),
) {
    if let Some(mut m) = feed.push_line(line, Instant::now(), unix_ms()) {
        // `--save` writes single-sensor records (`monitor --save`'s columns have no channels).
        let last = feed
            .monitor()
            .stats()
            .last
            .as_ref()
            .filter(|_| m.channels.is_empty());
        if let (Some(w), Some(r)) = (save.as_mut(), last) {
            if let Err(e) = writeln!(w, "{}", save_row(r)).and_then(|()| w.flush()) {
                send(save_failed(&e));
                *save = None;
            }
        }
        if input.realtime {
            pacer.wait(m.t_s);
            // Stamped when it leaves, so the page's latency excludes the pacing.
            m.sent_unix_ms = unix_ms();
        }
        send(Message::Record(Box::new(m)));
        if let Some(mut f) = feed.take_fom() {
            f.sent_unix_ms = unix_ms();
            send(Message::Fom(Box::new(f)));
        }
    }
}

fn flush_rest(
    feed: &mut Feed,
    lines: &mut LineSplitter,
    pacer: &mut Pacer,
    input: &Input,
    save: &mut Option<Box<dyn Write + Send>>,
    send: &mut impl FnMut(Message),
) {
    let _ = lines.finish(|l| {
        handle(feed, l, pacer, input, save, send);
        Ok::<(), ()>(())
    });
}

/// `stty -F DEVICE SETTINGS…`: the system's own tool sets the line (no termios code here).
fn set_line(device: &str, settings: &str) -> std::io::Result<()> {
    let out = std::process::Command::new("stty")
        .arg("-F")
        .arg(device)
        .args(settings.split_whitespace())
        .output()?;
    if out.status.success() {
        Ok(())
    } else {
        Err(std::io::Error::other(format!(
            "stty {settings}: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        )))
    }
}
