//! `magcomp nmea`: decode a GPS receiver log with the board's NMEA reader.

use anyhow::{Context, Result};
use std::path::PathBuf;

#[derive(clap::Args, Clone, Debug)]
pub struct NmeaArgs {
    /// NMEA log file (`-` for stdin).
    pub file: PathBuf,
}

pub fn run(a: &NmeaArgs) -> Result<()> {
    let stdout = std::io::stdout();
    let out = std::io::BufWriter::new(stdout.lock());
    let stats = if a.file.as_os_str() == "-" {
        crate::board::nmea::decode_log(std::io::stdin().lock(), out)?
    } else {
        let f = std::fs::File::open(&a.file)
            .with_context(|| format!("opening {}", a.file.display()))?;
        crate::board::nmea::decode_log(std::io::BufReader::new(f), out)?
    };
    crate::errln!(
        "nmea: {} lines, {} sentences decoded, {} of types not decoded, {} rejected ({} by checksum)",
        stats.lines, stats.decoded, stats.unsupported, stats.errors, stats.checksum_errors
    );
    Ok(())
}
