//! `magcomp capture TRACE -o OUT.cap`: any trace the host reads (a recorded real flight
//! included) written as a board capture (`board::capture`, the writer `simulate --capture`
//! uses), so it replays through the firmware's acquisition path (`replay`, the HIL rig).

use super::args::TraceInput;
use crate::board::capture::{
    parse_time_of_day, with_dead_reckoned_track, write_capture_file, CaptureOptions, FluxFormat,
};
use crate::io::output::refuse_overwriting;
use anyhow::{Context, Result};
use std::path::PathBuf;

/// Turn a trace into a raw sensor capture: scalar lines, fluxgate frames and NMEA as the
/// sensors would have sent them (docs/protocols.md §7, §10b).
#[derive(clap::Args, Clone, Debug)]
pub struct CaptureCmdArgs {
    #[command(flatten)]
    pub input: TraceInput,
    /// The capture to write (`# magcomp-capture v1`).
    #[arg(
        short = 'o',
        long = "out",
        visible_alias = "output",
        value_name = "OUT.cap"
    )]
    pub out: PathBuf,
    /// Fluxgate format: serial ASCII lines or ADS131M03 SPI frames.
    #[arg(long, value_enum, default_value = "ascii", value_name = "FORMAT")]
    pub flux: FluxFormat,
    /// GPS epoch rate (Hz): GGA + RMC + VTG per epoch. A trace without lat/lon/alt gets
    /// no GPS bytes at all (the board flags NO_GPS; survey mode does not need it).
    #[arg(long, default_value_t = 5.0, value_name = "HZ")]
    pub gps_hz: f64,
    /// UTC time of day at the trace's first sample, `HH:MM:SS` (the NMEA time).
    #[arg(long, default_value = "12:00:00", value_name = "HH:MM:SS")]
    pub start: String,
    /// For a trace without positions: give it a dead-reckoned track at this ground speed
    /// (due north from 45°N 75°W at 1000 m), so the board sees the speed the host's own
    /// `--speed-mps` assumes (the anomaly model moves with distance flown; without a speed
    /// the board holds it still). The positions are invented, and the command says so.
    #[arg(long, value_name = "M_PER_S")]
    pub speed_mps: Option<f64>,
}

pub fn run(a: &CaptureCmdArgs) -> Result<()> {
    refuse_overwriting(&[&a.input.trace], &[&a.out])?;
    let mut trace = a.input.read()?;
    let dead_reckoned = match a.speed_mps {
        Some(v) => with_dead_reckoned_track(&mut trace, v, (45.0, -75.0), 1000.0)?,
        None => false,
    };
    let mut o = CaptureOptions {
        flux_format: a.flux,
        gps_rate_hz: a.gps_hz,
        start_tod_s: parse_time_of_day(&a.start)?,
        source: format!("magcomp capture {}", a.input.trace.display()),
        ..CaptureOptions::default()
    };
    if let Some(d) = &a.input.date {
        o.date = rmc_date(d).with_context(|| format!("--date {d}"))?;
    }
    let s = write_capture_file(&trace, &o, &a.out)?;
    crate::errln!(
        "wrote {}: {} scalar lines at {} Hz, {} fluxgate frames, {} NMEA sentences{} ({} bytes)",
        a.out.display(),
        s.scalar_lines,
        s.scalar_hz,
        s.flux_frames,
        s.gps_sentences,
        match (s.gps_sentences, dead_reckoned) {
            (0, _) => " (no positions in the trace)",
            (_, true) => " (positions dead-reckoned at --speed-mps: the trace has none)",
            _ => "",
        },
        s.total_bytes
    );
    Ok(())
}

/// `YYYY-MM-DD` → the RMC date `(day, month, year)`.
fn rmc_date(d: &str) -> Result<(u8, u8, u16)> {
    let p: Vec<&str> = d.trim().split('-').collect();
    anyhow::ensure!(p.len() == 3, "not YYYY-MM-DD");
    Ok((p[2].parse()?, p[1].parse()?, p[0].parse()?))
}
