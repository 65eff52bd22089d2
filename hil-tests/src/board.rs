//! A running board: the firmware in QEMU (default) or a real acquisition board on serial
//! ports. Both look the same to a test: three sensor inputs, one output/command port.
//!
//! Emulated (default): `qemu-system-arm -M netduinoplus2` with unix-socket chardevs for
//! USART2 (output/command), USART3 (scalar), UART4 (fluxgate), UART5 (GPS). The ELF is
//! `MAGCOMP_FW_ELF` or built by `scripts/build-emu.sh`.
//!
//! Real board (`MAGCOMP_HIL_TARGET=serial`): the firmware built with `--features flux-uart`,
//! flashed and reset with probe-rs before every test, and four serial devices:
//! `MAGCOMP_HIL_OUT` (output/command, 921600 Bd), `MAGCOMP_HIL_SCALAR`, `MAGCOMP_HIL_FLUX`,
//! `MAGCOMP_HIL_GPS` (115200 Bd), set raw with `stty`. `MAGCOMP_FW_ELF` names the ELF.

use crate::capture::{Capture, Port};
use magcomp_core::protocol::common::xor_checksum;
use magcomp_core::protocol::record::{decode_record, Record};
use std::collections::HashMap;
use std::io::{Read, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
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

fn emulated() -> bool {
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
            return Ok(PathBuf::from(p));
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
                    "flux-uart",
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

pub struct Board {
    child: Option<Child>,
    inputs: HashMap<Port, Box<dyn Write + Send>>,
    cmd: Box<dyn Write + Send>,
    lines: Arc<Mutex<Vec<String>>>,
    /// Working directory of this run (sockets, QEMU logs, CSVs).
    pub dir: PathBuf,
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
                return Err(format!("connect {}: {e}", path.display()))
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
        let b = if emulated() {
            Self::start_qemu(&elf, dir)?
        } else {
            Self::start_serial(&elf, dir)?
        };
        b.wait_line(|l| l.starts_with("$MCBOOT"), Duration::from_secs(20))
            .ok_or("no $MCBOOT banner from the firmware")?;
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
            } else {
                let p = dir.join(format!("{role}.sock"));
                cmd.arg("-chardev").arg(format!(
                    "socket,id=s{i},path={},server=on,wait=off",
                    p.display()
                ));
                cmd.args(["-serial", &format!("chardev:s{i}")]);
            }
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
        let mut inputs: HashMap<Port, Box<dyn Write + Send>> = HashMap::new();
        for p in Port::ALL {
            inputs.insert(
                p,
                Box::new(connect(&dir.join(format!("{}.sock", p.name())), deadline)?),
            );
        }
        let lines = Arc::new(Mutex::new(Vec::new()));
        spawn_reader(
            Box::new(out.try_clone().map_err(|e| e.to_string())?),
            lines.clone(),
        );
        Ok(Board {
            child: Some(child),
            inputs,
            cmd: Box::new(out),
            lines,
            dir,
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
        let out = open(&dev("MAGCOMP_HIL_OUT")?, "921600")?;
        let mut inputs: HashMap<Port, Box<dyn Write + Send>> = HashMap::new();
        inputs.insert(
            Port::Scalar,
            Box::new(open(&dev("MAGCOMP_HIL_SCALAR")?, "115200")?),
        );
        inputs.insert(
            Port::Flux,
            Box::new(open(&dev("MAGCOMP_HIL_FLUX")?, "115200")?),
        );
        inputs.insert(
            Port::Gps,
            Box::new(open(&dev("MAGCOMP_HIL_GPS")?, "115200")?),
        );
        let lines = Arc::new(Mutex::new(Vec::new()));
        spawn_reader(
            Box::new(out.try_clone().map_err(|e| e.to_string())?),
            lines.clone(),
        );
        // a fresh firmware state for every test: flash (idempotent) and reset over SWD
        let chip = std::env::var("MAGCOMP_HIL_CHIP").unwrap_or_else(|_| "STM32F405RGTx".into());
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
            cmd: Box::new(out),
            lines,
            dir,
            started: Instant::now(),
        })
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

    fn wait_line_from(
        &self,
        from: usize,
        pred: impl Fn(&str) -> bool,
        timeout: Duration,
    ) -> Option<String> {
        let end = Instant::now() + timeout;
        loop {
            if let Ok(l) = self.lines.lock() {
                if let Some(s) = l.iter().skip(from).find(|s| pred(s)) {
                    return Some(s.clone());
                }
            }
            if Instant::now() > end {
                return None;
            }
            thread::sleep(Duration::from_millis(10));
        }
    }

    /// Streams a capture into the sensor ports at its own timing divided by `speed`
    /// (1.0 = the sensors' real rates; QEMU's UARTs have no baud timing, so pacing is ours).
    /// One thread writes all ports in capture order, which keeps the byte order of the capture.
    pub fn stream(&mut self, cap: &Capture, speed: f64) -> Result<()> {
        let t0 = Instant::now();
        for c in &cap.chunks {
            let due = t0 + Duration::from_secs_f64(c.t_us as f64 * 1e-6 / speed);
            if let Some(d) = due.checked_duration_since(Instant::now()) {
                thread::sleep(d);
            }
            let w = self.inputs.get_mut(&c.port).ok_or("port missing")?;
            w.write_all(&c.bytes)
                .map_err(|e| format!("write {}: {e}", c.port.name()))?;
        }
        Ok(())
    }

    /// Sends raw bytes on the command port.
    pub fn send_command_bytes(&mut self, b: &[u8]) -> Result<()> {
        self.cmd.write_all(b).map_err(|e| e.to_string())
    }

    /// Sends `$<body>*HH` and returns the next `$MCACK`/`$MCERR` reply line.
    pub fn command(&mut self, body: &str) -> Result<String> {
        self.command_raw(&sentence(body))
    }

    /// Sends raw bytes and returns the next reply line.
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

    /// Waits until `n` records arrived (or `timeout`); returns the count seen.
    pub fn wait_records(&self, n: usize, timeout: Duration) -> usize {
        let end = Instant::now() + timeout;
        loop {
            let got = self
                .output()
                .iter()
                .filter(|l| l.starts_with("$MCREC"))
                .count();
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
            let n = self
                .output()
                .iter()
                .filter(|l| l.starts_with("$MCREC"))
                .count();
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
    }
}
