//! Helpers shared by the host's integration tests.
#![allow(dead_code)] // each test binary uses the part it needs

pub mod cli;
pub mod diagnosis;
pub mod memo;

use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Debian's Chromium (`apt-get install chromium`); tests skip with a message without it.
pub const CHROMIUM: &str = "/usr/bin/chromium";

/// Runs headless Chromium with the flags this machine needs (no network, no sandbox as
/// root, a fresh profile), killing it after 90 s; `None` if it could not start or timed out.
pub fn chromium(args: &[String], profile: &Path) -> Option<Output> {
    run_chromium(args, profile, false)
}

/// As [`chromium`], with the browser's log (console messages, page errors) on `stderr`.
pub fn chromium_logged(args: &[String], profile: &Path) -> Option<Output> {
    run_chromium(args, profile, true)
}

/// Headless Chromium with this machine's flags (as [`chromium`]) and a fresh profile, not
/// started: for a test that drives it itself (e.g. over `--remote-debugging-port`).
pub fn chromium_command(profile: &Path) -> Command {
    let mut cmd = Command::new(CHROMIUM);
    cmd.args([
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--hide-scrollbars",
    ]);
    cmd.arg(format!("--user-data-dir={}", profile.display()));
    cmd
}

fn run_chromium(args: &[String], profile: &Path, log: bool) -> Option<Output> {
    let mut cmd = chromium_command(profile);
    if log {
        cmd.args(["--enable-logging=stderr", "--v=0"]);
    }
    cmd.args(args);
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(if log { Stdio::piped() } else { Stdio::null() })
        .spawn()
        .ok()?;
    let err_reader = child.stderr.take().map(|mut e| {
        std::thread::spawn(move || {
            let mut buf = Vec::new();
            std::io::Read::read_to_end(&mut e, &mut buf).ok();
            buf
        })
    });
    // Read stdout on a thread so a large DOM cannot fill the pipe and stall the browser.
    let mut stdout = child.stdout.take()?;
    let reader = std::thread::spawn(move || {
        let mut buf = Vec::new();
        std::io::Read::read_to_end(&mut stdout, &mut buf).ok();
        buf
    });
    let start = Instant::now();
    loop {
        match child.try_wait() {
            Ok(Some(status)) => {
                return Some(Output {
                    status,
                    stdout: reader.join().unwrap_or_default(),
                    stderr: err_reader
                        .map(|r| r.join().unwrap_or_default())
                        .unwrap_or_default(),
                })
            }
            Ok(None) if start.elapsed() < Duration::from_secs(90) => {
                std::thread::sleep(Duration::from_millis(100))
            }
            _ => {
                let _ = child.kill();
                let _ = child.wait();
                return None;
            }
        }
    }
}

/// A simulated 1 kHz calibration (seed 3) short enough to calibrate whole in memory: one
/// cycle per manoeuvre, 4 s periods, 2 s levels, brisk turns.
pub fn short_1khz_calibration() -> magcomp::sim::SimConfig {
    magcomp::sim::SimConfig {
        seed: 3,
        sample_rate_hz: 1000.0,
        manoeuvre_cycles: 1,
        level_s: 2.0,
        manoeuvre_period_s: 4.0,
        turn_rate_deg_s: 10.0,
        ..magcomp::sim::SimConfig::default()
    }
}
