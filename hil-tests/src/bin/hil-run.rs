//! `hil-run CAPTURE [--speed X] [--out FILE]`: runs the firmware on the emulated board (or a
//! real one, `MAGCOMP_HIL_TARGET=serial`, see docs/firmware.md), streams a raw capture into
//! its sensor ports and prints the board's output port live on stdout, e.g.
//! `hil-run flight.cap | magcomp monitor -`. Ends with `FLUSH` so every sample has its record.

use hil_tests::board::{self, Board};
use hil_tests::capture::Capture;
use std::io::Write;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

fn main() {
    if let Err(e) = run() {
        eprintln!("hil-run: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<(), String> {
    let mut args = std::env::args().skip(1);
    let (mut cap_path, mut speed, mut out) = (None, 1.0f64, None);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--speed" => {
                speed = args
                    .next()
                    .and_then(|v| v.parse().ok())
                    .filter(|v: &f64| *v > 0.0)
                    .ok_or("--speed X (> 0)")?
            }
            "--out" => out = Some(args.next().ok_or("--out FILE")?),
            "-h" | "--help" => {
                println!("usage: hil-run CAPTURE [--speed X] [--out FILE]");
                return Ok(());
            }
            _ => cap_path = Some(a),
        }
    }
    let cap_path = cap_path.ok_or("usage: hil-run CAPTURE [--speed X] [--out FILE]")?;
    let file = std::fs::File::open(&cap_path).map_err(|e| format!("{cap_path}: {e}"))?;
    let cap = Capture::read_raw(std::io::BufReader::new(file)).map_err(|e| e.to_string())?;
    if let Some(why) = board::skip_reason() {
        return Err(why);
    }
    let mut b = Board::start("run")?;
    // print the output port as it arrives; the protocol lines go through unchanged
    let log = b.line_log();
    let done = Arc::new(AtomicBool::new(false));
    let printer = {
        let done = done.clone();
        std::thread::spawn(move || {
            let mut shown = 0;
            let mut stdout = std::io::stdout();
            loop {
                let finished = done.load(Ordering::Relaxed);
                let new: Vec<String> = log.lock().map(|l| l[shown..].to_vec()).unwrap_or_default();
                shown += new.len();
                for l in new.iter().filter(|l| !l.starts_with("$MCSYN")) {
                    if writeln!(stdout, "{l}").is_err() {
                        return;
                    }
                }
                let _ = stdout.flush();
                if finished {
                    return;
                }
                std::thread::sleep(Duration::from_millis(50));
            }
        })
    };
    b.stream(&cap, speed)?;
    b.flush()?;
    done.store(true, Ordering::Relaxed);
    let _ = printer.join();
    let (recs, bad) = b.records();
    if let Some(p) = out {
        let f = std::fs::File::create(&p).map_err(|e| format!("{p}: {e}"))?;
        hil_tests::write_csv(std::io::BufWriter::new(f), &recs).map_err(|e| e.to_string())?;
    }
    eprintln!(
        "hil-run: {} scalar samples in, {} records out, {} undecodable lines; logs in {}",
        cap.scalar_t_s.len(),
        recs.len(),
        bad.len(),
        b.dir.display()
    );
    Ok(())
}
