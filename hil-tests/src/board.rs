//! A running board: the firmware in QEMU (default) or a real acquisition board on serial
//! ports. Both look the same to a test: three sensor inputs, one output/command port.
//!
//! Emulated (default): `qemu-system-arm -M netduinoplus2` with unix-socket chardevs for
//! USART2 (output/command), USART3 (scalar), UART4 (fluxgate), UART5 (GPS). The ELF is
//! `MAGCOMP_FW_ELF` or built by `scripts/build-emu.sh`.
//!
//! Real board (`MAGCOMP_HIL_TARGET=serial`): the firmware built with `--features hil-sync` (its default serial fluxgate),
//! flashed on an erased chip and reset with probe-rs before every test, and four serial devices:
//! `MAGCOMP_HIL_OUT` (output/command, 921600 Bd), `MAGCOMP_HIL_SCALAR`, `MAGCOMP_HIL_FLUX`,
//! `MAGCOMP_HIL_GPS` (115200 Bd), set raw with `stty`. `MAGCOMP_FW_ELF` names the ELF.

use crate::capture::{Capture, Port};
use magcomp_core::protocol::command::{Reply, parse_reply};
use magcomp_core::protocol::common::xor_checksum;
use magcomp_core::protocol::fluxgate::FluxAsciiReader;
use magcomp_core::protocol::nmea::{NmeaReader, Sentence};
use magcomp_core::protocol::record::{Record, decode_record};
use magcomp_core::protocol::scalar::{ScalarConfig, ScalarReader};
use std::collections::HashMap;
use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::thread;
use std::time::{Duration, Instant};

pub type Result<T> = std::result::Result<T, String>;

/// Repository root (hil-tests is one level below it).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_default()
}

/// The board is the emulated one (QEMU), not a real board on serial ports.
pub fn emulated() -> bool {
    std::env::var("MAGCOMP_HIL_TARGET")
        .map(|v| v != "serial")
        .unwrap_or(true)
}

fn qemu_available() -> bool {
    Command::new("qemu-system-arm")
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// `Ok(None)` means "skip this test": QEMU is absent and `MAGCOMP_REQUIRE_QEMU` is not 1.
pub fn skip_reason() -> Option<String> {
    if !emulated() || qemu_available() {
        return None;
    }
    if std::env::var("MAGCOMP_REQUIRE_QEMU").as_deref() == Ok("1") {
        panic!(
            "MAGCOMP_REQUIRE_QEMU=1 but qemu-system-arm is not installed (scripts/install-qemu.sh)"
        );
    }
    Some("SKIP: qemu-system-arm not found (run scripts/install-qemu.sh, or set MAGCOMP_HIL_TARGET=serial for a real board)".into())
}

/// Builds (once per process) and returns the firmware ELF for the chosen target.
pub fn firmware_elf() -> Result<PathBuf> {
    static ELF: OnceLock<std::result::Result<PathBuf, String>> = OnceLock::new();
    ELF.get_or_init(|| {
        if let Ok(p) = std::env::var("MAGCOMP_FW_ELF") {
            // relative paths are taken from the repository root (tests run in hil-tests/)
            let p = PathBuf::from(p);
            return Ok(if p.is_relative() && !p.exists() {
                repo_root().join(p)
            } else {
                p
            });
        }
        let root = repo_root();
        let out = if emulated() {
            Command::new("bash")
                .arg(root.join("scripts/build-emu.sh"))
                .current_dir(&root)
                .stderr(Stdio::inherit())
                .output()
        } else {
            Command::new("cargo")
                .args([
                    "build",
                    "--profile",
                    "fw",
                    "--target",
                    "thumbv7em-none-eabihf",
                    "-p",
                    "magcomp-firmware",
                    "--features",
                    "hil-sync",
                ])
                .current_dir(&root)
                .stderr(Stdio::inherit())
                .output()
        }
        .map_err(|e| format!("firmware build: {e}"))?;
        if !out.status.success() {
            return Err(format!("firmware build failed ({})", out.status));
        }
        if emulated() {
            let s = String::from_utf8_lossy(&out.stdout);
            s.lines()
                .last()
                .map(PathBuf::from)
                .ok_or_else(|| "build-emu.sh printed no path".to_string())
        } else {
            Ok(root.join("target/thumbv7em-none-eabihf/fw/magcomp-firmware"))
        }
    })
    .clone()
}

/// `$<body>*HH\r\n` with the NMEA XOR checksum (how an operator types a command).
pub fn sentence(body: &str) -> Vec<u8> {
    format!("${body}*{:02X}\r\n", xor_checksum(body.as_bytes())).into_bytes()
}

/// Frames the board will take from the bytes sent so far, per port (scalar, flux, GPS):
/// the core's readers on the same bytes, as the firmware's port tasks run them.
struct FrameCounter {
    scalar: ScalarReader,
    flux: FluxAsciiReader,
    gps: NmeaReader,
    n: [u64; 3],
}

impl Default for FrameCounter {
    fn default() -> Self {
        Self {
            scalar: ScalarReader::new(ScalarConfig::default()),
            flux: FluxAsciiReader::new(),
            gps: NmeaReader::new(),
            n: [0; 3],
        }
    }
}

impl FrameCounter {
    fn feed(&mut self, port: Port, bytes: &[u8]) {
        for &b in bytes {
            match port {
                Port::Scalar => {
                    self.n[0] += u64::from(self.scalar.push_line(b).is_some());
                    // a line that ran into the next: the board takes one event per sample
                    while self.scalar.owed_line().is_some() {
                        self.n[0] += 1;
                    }
                }
                Port::Flux => self.n[1] += u64::from(self.flux.push(b).is_some()),
                // the firmware does not forward valid-but-unused sentences
                Port::Gps => match self.gps.push(b) {
                    None | Some(Ok(Sentence::Unsupported { .. })) => {}
                    Some(_) => self.n[2] += 1,
                },
            }
        }
    }
}

/// A sensor input of the board and how to know the board has taken what was written.
struct Input {
    file: std::fs::File,
    /// FIFO into QEMU (drained when QEMU has read every byte into the UART) or a tty
    /// (drained when the adapter has sent every byte).
    fifo: bool,
}

impl Input {
    /// Waits until the written bytes left our side. QEMU's UART takes one byte at a time
    /// and, when the host stalls, interleaves pending bytes of different ports: waiting here
    /// before writing another port keeps the capture's byte order on the board.
    fn drain(&self, timeout: Duration) -> Result<()> {
        if !self.fifo {
            return rustix::termios::tcdrain(&self.file).map_err(|e| format!("tcdrain: {e}"));
        }
        let end = Instant::now() + timeout;
        while rustix::io::ioctl_fionread(&self.file).map_err(|e| format!("FIONREAD: {e}"))? > 0 {
            if Instant::now() > end {
                return Err("the board stopped reading a sensor port".into());
            }
            thread::sleep(Duration::from_micros(200));
        }
        Ok(())
    }
}

/// Resends of one command line that arrived damaged.
pub const MAX_RESENDS: usize = 3;

pub struct Board {
    child: Option<Child>,
    inputs: HashMap<Port, Input>,
    /// The output port's write side (commands); shared with [`Board::serve_command_port`].
    cmd: Arc<Mutex<Box<dyn Write + Send>>>,
    lines: Arc<Mutex<Vec<String>>>,
    /// Working directory of this run (sockets, QEMU logs, CSVs).
    pub dir: PathBuf,
    /// The firmware acknowledges frames (`$MCSYN`, feature `hil-sync`).
    sync: bool,
    /// Output lines already searched for `$MCSYN`.
    syn_from: usize,
    /// Commands resent because the board received them damaged (see [`Board::command_line`]).
    resends: usize,
    pub started: Instant,
}

fn spawn_reader(mut r: Box<dyn Read + Send>, lines: Arc<Mutex<Vec<String>>>) {
    thread::spawn(move || {
        let mut buf = [0u8; 4096];
        let mut cur = Vec::new();
        loop {
            let n = match r.read(&mut buf) {
                Ok(0) | Err(_) => break,
                Ok(n) => n,
            };
            for &b in &buf[..n] {
                if b == b'\n' {
                    let s = String::from_utf8_lossy(&cur)
                        .trim_end_matches('\r')
                        .to_string();
                    cur.clear();
                    if let Ok(mut l) = lines.lock() {
                        l.push(s);
                    }
                } else {
                    cur.push(b);
                }
            }
        }
    });
}

fn connect(path: &Path, deadline: Instant) -> Result<UnixStream> {
    loop {
        match UnixStream::connect(path) {
            Ok(s) => return Ok(s),
            Err(e) if Instant::now() > deadline => {
                return Err(format!("connect {}: {e}", path.display()));
            }
            Err(_) => thread::sleep(Duration::from_millis(20)),
        }
    }
}

impl Board {
    /// Starts the board for test `name` and waits for its boot banner.
    pub fn start(name: &str) -> Result<Board> {
        let dir = std::env::temp_dir().join(format!("magcomp-hil-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
        let elf = firmware_elf()?;
        let mut b = if emulated() {
            Self::start_qemu(&elf, dir)?
        } else {
            Self::start_serial(&elf, dir)?
        };
        let banner = b.wait_line(|l| l.starts_with("$MCBOOT"), Duration::from_secs(20));
        b.sync = banner.as_deref().is_some_and(|l| l.contains(",SYNC*"));
        if banner.is_none() {
            let qemu = std::fs::read_to_string(b.dir.join("qemu-stderr.txt")).unwrap_or_default();
            return Err(format!(
                "no $MCBOOT banner from the firmware ({}) {}",
                b.dir.display(),
                qemu.trim()
            ));
        }
        Ok(b)
    }

    fn start_qemu(elf: &Path, dir: PathBuf) -> Result<Board> {
        // -serial order on netduinoplus2: USART1, USART2, USART3, UART4, UART5
        let roles = ["", "out", "scalar", "flux", "gps"];
        let mut cmd = Command::new("qemu-system-arm");
        cmd.args([
            "-M",
            "netduinoplus2",
            "-display",
            "none",
            "-monitor",
            "none",
            "-semihosting-config",
            "enable=on,target=native",
            "-kernel",
        ]);
        cmd.arg(elf);
        for (i, role) in roles.iter().enumerate() {
            if role.is_empty() {
                cmd.args(["-serial", "null"]);
            } else if *role == "out" {
                // wait=on: the machine starts only once the harness is connected, so the
                // boot banner cannot be sent into an unconnected socket and lost
                let p = dir.join("out.sock");
                cmd.arg("-chardev").arg(format!(
                    "socket,id=s{i},path={},server=on,wait=on",
                    p.display()
                ));
                cmd.args(["-serial", &format!("chardev:s{i}")]);
            } else {
                // sensor inputs: FIFOs, whose fill level tells when QEMU has taken the bytes
                let p = dir.join(role);
                for ext in ["in", "out"] {
                    let f = p.with_extension(ext);
                    let ok = Command::new("mkfifo")
                        .arg(&f)
                        .status()
                        .is_ok_and(|s| s.success());
                    if !ok {
                        return Err(format!("mkfifo {}", f.display()));
                    }
                }
                cmd.arg("-chardev")
                    .arg(format!("pipe,id=s{i},path={}", p.display()));
                cmd.args(["-serial", &format!("chardev:s{i}")]);
            }
        }
        // extra QEMU arguments, e.g. a TCG plugin: `-plugin target/qemu-plugins/libstackmin.so`
        if let Ok(extra) = std::env::var("MAGCOMP_HIL_QEMU_ARGS") {
            cmd.args(extra.split_whitespace());
        }
        let log = |n: &str| {
            std::fs::File::create(dir.join(n))
                .map(Stdio::from)
                .map_err(|e| e.to_string())
        };
        // stdout carries the defmt frames (semihosting): decode with `defmt-print -e ELF < defmt.bin`
        let child = cmd
            .stdout(log("defmt.bin")?)
            .stderr(log("qemu-stderr.txt")?)
            .spawn()
            .map_err(|e| format!("qemu: {e}"))?;
        let deadline = Instant::now() + Duration::from_secs(10);
        let out = connect(&dir.join("out.sock"), deadline)?;
        let mut inputs = HashMap::new();
        for p in Port::ALL {
            // read+write, so opening a FIFO never blocks (QEMU holds both ends open as well)
            let open = |ext: &str| {
                std::fs::OpenOptions::new()
                    .read(true)
                    .write(true)
                    .open(dir.join(p.name()).with_extension(ext))
                    .map_err(|e| format!("{} FIFO: {e}", p.name()))
            };
            let file = open("in")?;
            // the firmware never transmits on a sensor port; its .out end needs no reader
            inputs.insert(p, Input { file, fifo: true });
        }
        let lines = Arc::new(Mutex::new(Vec::new()));
        spawn_reader(
            Box::new(out.try_clone().map_err(|e| e.to_string())?),
            lines.clone(),
        );
        Ok(Board {
            child: Some(child),
            inputs,
            cmd: Arc::new(Mutex::new(Box::new(out))),
            lines,
            dir,
            sync: false,
            syn_from: 0,
            resends: 0,
            started: Instant::now(),
        })
    }

    fn start_serial(elf: &Path, dir: PathBuf) -> Result<Board> {
        let dev =
            |v: &str| std::env::var(v).map_err(|_| format!("{v} is not set (serial device path)"));
        let open = |path: &str, baud: &str| -> Result<std::fs::File> {
            let ok = Command::new("stty")
                .args(["-F", path, baud, "raw", "-echo"])
                .status()
                .is_ok_and(|s| s.success());
            if !ok {
                return Err(format!("stty {path}"));
            }
            std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .open(path)
                .map_err(|e| format!("{path}: {e}"))
        };
        // the rates the firmware was built with (`MAGCOMP_BAUD_*`, docs/firmware.md)
        let baud = |v: &str, default: &str| std::env::var(v).unwrap_or_else(|_| default.into());
        let out = open(
            &dev("MAGCOMP_HIL_OUT")?,
            &baud("MAGCOMP_BAUD_OUT", "921600"),
        )?;
        let mut inputs = HashMap::new();
        for (p, var, rate) in [
            (Port::Scalar, "MAGCOMP_HIL_SCALAR", "MAGCOMP_BAUD_SCALAR"),
            (Port::Flux, "MAGCOMP_HIL_FLUX", "MAGCOMP_BAUD_FLUX"),
            (Port::Gps, "MAGCOMP_HIL_GPS", "MAGCOMP_BAUD_GPS"),
        ] {
            let file = open(&dev(var)?, &baud(rate, "115200"))?;
            inputs.insert(p, Input { file, fifo: false });
        }
        let lines = Arc::new(Mutex::new(Vec::new()));
        spawn_reader(
            Box::new(out.try_clone().map_err(|e| e.to_string())?),
            lines.clone(),
        );
        // a fresh firmware state for every test: erase the whole chip (the coefficient
        // store another test saved goes too), flash and reset over SWD
        let chip = std::env::var("MAGCOMP_HIL_CHIP").unwrap_or_else(|_| "STM32F405RGTx".into());
        let st = Command::new("probe-rs")
            .args(["erase", "--chip", &chip])
            .status();
        if !st.is_ok_and(|s| s.success()) {
            return Err("probe-rs erase failed".into());
        }
        let st = Command::new("probe-rs")
            .args(["download", "--chip", &chip])
            .arg(elf)
            .status();
        if !st.is_ok_and(|s| s.success()) {
            return Err("probe-rs download failed".into());
        }
        let st = Command::new("probe-rs")
            .args(["reset", "--chip", &chip])
            .status();
        if !st.is_ok_and(|s| s.success()) {
            return Err("probe-rs reset failed".into());
        }
        Ok(Board {
            child: None,
            inputs,
            cmd: Arc::new(Mutex::new(Box::new(out))),
            lines,
            dir,
            sync: false,
            syn_from: 0,
            resends: 0,
            started: Instant::now(),
        })
    }

    /// The shared log of output lines (for a live view from another thread).
    pub fn line_log(&self) -> Arc<Mutex<Vec<String>>> {
        self.lines.clone()
    }

    /// All output lines so far.
    pub fn output(&self) -> Vec<String> {
        self.lines.lock().map(|l| l.clone()).unwrap_or_default()
    }

    fn n_lines(&self) -> usize {
        self.lines.lock().map(|l| l.len()).unwrap_or(0)
    }

    /// Waits for an output line matching `pred` (searching from the start).
    pub fn wait_line(&self, pred: impl Fn(&str) -> bool, timeout: Duration) -> Option<String> {
        self.wait_line_from(0, pred, timeout)
    }

    /// Waits for the boot banner after `n` earlier ones (a reset).
    pub fn wait_line_from_banner(&self, n: usize, timeout: Duration) -> Option<String> {
        let end = Instant::now() + timeout;
        loop {
            if let Some(l) = self
                .output()
                .into_iter()
                .filter(|l| l.starts_with("$MCBOOT"))
                .nth(n)
            {
                return Some(l);
            }
            if Instant::now() > end {
                return None;
            }
            thread::sleep(Duration::from_millis(10));
        }
    }

    fn wait_line_from(
        &self,
        from: usize,
        pred: impl Fn(&str) -> bool,
        timeout: Duration,
    ) -> Option<String> {
        let end = Instant::now() + timeout;
        loop {
            if let Ok(l) = self.lines.lock()
                && let Some(s) = l.iter().skip(from).find(|s| pred(s))
            {
                return Some(s.clone());
            }
            if Instant::now() > end {
                return None;
            }
            thread::sleep(Duration::from_millis(10));
        }
    }

    /// Streams a capture into the sensor ports at its own timing divided by `speed`
    /// (1.0 = the sensors' real rates; QEMU's UARTs have no baud timing, so pacing is ours).
    /// One thread writes all ports in capture order and lets each chunk drain before the
    /// next: the board sees the capture's byte order, which is what the replay reproduces.
    pub fn stream(&mut self, cap: &Capture, speed: f64) -> Result<()> {
        let t0 = Instant::now();
        let mut expect = FrameCounter::default();
        for c in &cap.chunks {
            let due = t0 + Duration::from_secs_f64(c.t_us as f64 * 1e-6 / speed);
            if let Some(d) = due.checked_duration_since(Instant::now()) {
                thread::sleep(d);
            }
            let w = self.inputs.get_mut(&c.port).ok_or("port missing")?;
            w.file
                .write_all(&c.bytes)
                .map_err(|e| format!("write {}: {e}", c.port.name()))?;
            w.drain(Duration::from_secs(10))?;
            expect.feed(c.port, &c.bytes);
            if self.sync {
                self.wait_frames(expect.n, Duration::from_secs(10))?;
            }
        }
        Ok(())
    }

    /// As [`Board::stream`], but at the capture's own pace whatever the board does: no
    /// waiting for `$MCSYN`, so while the board stalls (a flash erase) the sensors' bytes
    /// keep coming and pile up in its receive buffers, as a real sensor's would. The order
    /// across ports is then the board's to keep: records may differ from the replay's
    /// values, not in number.
    pub fn stream_unpaced(&mut self, cap: &Capture, speed: f64) -> Result<()> {
        let sync = std::mem::replace(&mut self.sync, false);
        let r = self.stream(cap, speed);
        self.sync = sync;
        r
    }

    /// Waits until the board acknowledged at least `n` frames per port (`$MCSYN`).
    fn wait_frames(&mut self, n: [u64; 3], timeout: Duration) -> Result<()> {
        let end = Instant::now() + timeout;
        if n == [0; 3] {
            // nothing the board could acknowledge yet (e.g. a chunk with no line end)
            return Ok(());
        }
        loop {
            if let Ok(l) = self.lines.lock() {
                for line in &l[self.syn_from..] {
                    if let Some(body) = line.strip_prefix("$MCSYN,") {
                        let got: Vec<u64> = body
                            .split(['*', ','])
                            .take(3)
                            .filter_map(|v| v.parse().ok())
                            .collect();
                        if got.len() == 3 && (0..3).all(|i| got[i] >= n[i]) {
                            return Ok(());
                        }
                    }
                }
                self.syn_from = l.len();
            }
            if Instant::now() > end {
                return Err(format!(
                    "the board did not take frame {n:?} (last seen in {})",
                    self.dir.display()
                ));
            }
            thread::sleep(Duration::from_micros(300));
        }
    }

    /// The command port's write side, for another thread to send on while this one streams.
    pub fn command_writer(&self) -> Arc<Mutex<Box<dyn Write + Send>>> {
        self.cmd.clone()
    }

    /// Sends raw bytes on the command port.
    pub fn send_command_bytes(&mut self, b: &[u8]) -> Result<()> {
        let mut cmd = self.cmd.lock().map_err(|_| "command port lock poisoned")?;
        cmd.write_all(b).map_err(|e| e.to_string())
    }

    /// Sends `$<body>*HH` and returns its reply (see [`Board::command_line`]).
    pub fn command(&mut self, body: &str) -> Result<String> {
        self.command_line(&sentence(body))
    }

    /// Sends a well-formed command line and returns its `$MCACK`/`$MCERR` reply. A reply that
    /// says the line arrived damaged (`FRAMING`, `CHECKSUM`, `OVERLONG`: not executed) gets
    /// it resent, at most [`MAX_RESENDS`] times. Why a line can arrive damaged on a board
    /// with a perfect link: embassy-stm32 0.6's BufferedUart clears TC with a read-modify-write
    /// of SR, which also clears an RXNE set between its read and its write, so a command byte
    /// arriving as the board ends a transmission is lost (QEMU widens that window; on silicon
    /// it is a few cycles). `magcomp upload` resends the same way.
    pub fn command_line(&mut self, bytes: &[u8]) -> Result<String> {
        for _ in 0..=MAX_RESENDS {
            let r = self.command_raw(bytes)?;
            match parse_reply(r.as_bytes()) {
                Some(Reply::Refused(e)) if e.is_transport() => {
                    self.resends += 1;
                    eprintln!(
                        "note: {:?} arrived damaged ({r}), resent",
                        String::from_utf8_lossy(bytes).trim_end()
                    );
                }
                _ => return Ok(r),
            }
        }
        Err(format!(
            "{:?} still damaged after {MAX_RESENDS} resends",
            String::from_utf8_lossy(bytes)
        ))
    }

    /// Commands resent so far because they arrived damaged: each one is also an `$MCERR`
    /// the board counted.
    pub fn resends(&self) -> usize {
        self.resends
    }

    /// Serves the board's command port on a unix socket at `path`, as ser2net or socat do
    /// for a real port, to one client (e.g. `magcomp upload --to PATH`): its bytes go to the
    /// board, the board's output lines from the moment it connects go to it. The thread ends
    /// when the client disconnects.
    pub fn serve_command_port(&self, path: &Path) -> Result<thread::JoinHandle<()>> {
        let listener = UnixListener::bind(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let (cmd, lines) = (self.cmd.clone(), self.lines.clone());
        Ok(thread::spawn(move || {
            let Ok((client, _)) = listener.accept() else {
                return;
            };
            let mut from = lines.lock().map(|l| l.len()).unwrap_or(0);
            let done = Arc::new(AtomicBool::new(false));
            if let Ok(mut rx) = client.try_clone() {
                let done = done.clone();
                thread::spawn(move || {
                    let mut buf = [0u8; 256];
                    while let Ok(n @ 1..) = rx.read(&mut buf) {
                        let Ok(mut c) = cmd.lock() else { break };
                        if c.write_all(&buf[..n]).is_err() {
                            break;
                        }
                    }
                    done.store(true, Ordering::Relaxed);
                });
            }
            let mut tx = client;
            while !done.load(Ordering::Relaxed) {
                let new: Vec<String> = match lines.lock() {
                    Ok(l) => l[from..].to_vec(),
                    Err(_) => break,
                };
                from += new.len();
                for l in new {
                    if tx.write_all(format!("{l}\r\n").as_bytes()).is_err() {
                        return;
                    }
                }
                thread::sleep(Duration::from_millis(2));
            }
        }))
    }

    /// Sends raw bytes and returns the next reply line (no resend: for lines meant to be
    /// malformed).
    pub fn command_raw(&mut self, bytes: &[u8]) -> Result<String> {
        let from = self.n_lines();
        self.send_command_bytes(bytes)?;
        self.wait_line_from(
            from,
            |l| l.starts_with("$MCACK") || l.starts_with("$MCERR"),
            Duration::from_secs(10),
        )
        .ok_or_else(|| format!("no reply to {:?}", String::from_utf8_lossy(bytes)))
    }

    /// Waits until `n` records (`$MCREC` or `$MCMREC`) arrived (or `timeout`); returns the
    /// count seen.
    pub fn wait_records(&self, n: usize, timeout: Duration) -> usize {
        let end = Instant::now() + timeout;
        loop {
            let got = self.output().iter().filter(|l| is_record_line(l)).count();
            if got >= n || Instant::now() > end {
                return got;
            }
            thread::sleep(Duration::from_millis(20));
        }
    }

    /// Waits until no record has arrived for `quiet` (at most `timeout`): the samples in
    /// flight have gone through the pipeline.
    pub fn settle(&self, quiet: Duration, timeout: Duration) -> usize {
        let end = Instant::now() + timeout;
        let mut last = usize::MAX;
        let mut since = Instant::now();
        loop {
            let n = self.output().iter().filter(|l| is_record_line(l)).count();
            if n != last {
                last = n;
                since = Instant::now();
            } else if since.elapsed() >= quiet || Instant::now() > end {
                return n;
            }
            thread::sleep(Duration::from_millis(20));
        }
    }

    /// Ends the stream: the firmware emits the records it holds for the centred derivative.
    /// The command travels on another port than the samples, so the pipeline settles first.
    pub fn flush(&mut self) -> Result<String> {
        self.settle(Duration::from_millis(300), Duration::from_secs(10));
        let r = self.command("MCCMD,FLUSH")?;
        if r.starts_with("$MCACK,FLUSH") {
            Ok(r)
        } else {
            Err(format!("FLUSH rejected: {r}"))
        }
    }

    /// The decoded records, in arrival order, and the output lines that failed to decode.
    pub fn records(&self) -> (Vec<Record>, Vec<String>) {
        let mut recs = Vec::new();
        let mut bad = Vec::new();
        for l in self.output() {
            if l.starts_with("$MCREC") {
                match decode_record(l.as_bytes()) {
                    Ok(r) => recs.push(r),
                    Err(_) => bad.push(l),
                }
            }
        }
        (recs, bad)
    }

    /// Whether QEMU is still running (a crash or a semihosting exit ends it).
    pub fn alive(&mut self) -> bool {
        match &mut self.child {
            Some(c) => matches!(c.try_wait(), Ok(None)),
            None => true,
        }
    }

    /// Saves the raw output next to the run's logs.
    pub fn save_output(&self) -> PathBuf {
        let p = self.dir.join("output.txt");
        let _ = std::fs::write(&p, self.output().join("\n"));
        p
    }
}

impl Drop for Board {
    fn drop(&mut self) {
        if let Some(c) = &mut self.child {
            let _ = c.kill();
            let _ = c.wait();
        }
        // A passing run's logs and CSVs are not needed; a failing one keeps them for the
        // post-mortem (its path is in the failure message). `MAGCOMP_HIL_KEEP=1` keeps every
        // run's, with its whole output port in output.txt: comparing two firmware builds'
        // records line by line (scripts/hil-records-diff.sh).
        if std::env::var("MAGCOMP_HIL_KEEP").as_deref() == Ok("1") {
            self.save_output();
        } else if !std::thread::panicking() {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

/// An output record line: a single sensor's `$MCREC` or a counter line's `$MCMREC`.
pub fn is_record_line(l: &str) -> bool {
    l.starts_with("$MCREC") || l.starts_with("$MCMREC")
}
