//! What an acquisition gives out: one record per scalar line (a sensor's `$MCREC` or a
//! counter line's `$MCMREC`), and the frame, error and flag counters.

use crate::protocol::multi_record::MultiRecord;
use crate::protocol::record::{encode_record, Record, RecordError};

/// One output line: a single sensor's `$MCREC` or a counter line's `$MCMREC`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum AcqRecord {
    One(Record),
    Multi(MultiRecord),
}

impl AcqRecord {
    pub fn seq(&self) -> u32 {
        match self {
            AcqRecord::One(r) => r.seq,
            AcqRecord::Multi(r) => r.seq,
        }
    }
    /// Writes the record's line with `\r\n`; returns the length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, RecordError> {
        match self {
            AcqRecord::One(r) => encode_record(r, out),
            AcqRecord::Multi(r) => crate::protocol::multi_record::encode_multi_record(r, out),
        }
    }
}

/// Frame, error and flag counters (saturating).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AcqCounters {
    /// Scalar lines seen (= samples = records once flushed) and those rejected.
    pub scalar_lines: u32,
    pub scalar_errors: u32,
    /// Fluxgate frames accepted / rejected (ASCII lines or SPI frames).
    pub flux_frames: u32,
    pub flux_errors: u32,
    /// Fluxgate frames accepted by the parser but whose modulus departs from the recent
    /// frames' ([`crate::continuity::FluxContinuity`]): counted in `flux_frames`, held as
    /// unusable (samples using them are `FLUX_STALE`).
    pub flux_suspect: u32,
    /// NMEA sentences accepted (including unsupported types) / rejected.
    pub gps_sentences: u32,
    pub gps_errors: u32,
    /// Records emitted.
    pub records: u32,
    /// Records carrying each degradation flag.
    pub flux_stale: u32,
    pub no_gps: u32,
    pub mag_missing: u32,
    pub parse_error: u32,
}

impl AcqCounters {
    /// Parser errors on all ports.
    pub fn errors(&self) -> u32 {
        self.scalar_errors
            .saturating_add(self.flux_errors)
            .saturating_add(self.gps_errors)
    }
}

pub(super) const COUNTERS_ZERO: AcqCounters = AcqCounters {
    scalar_lines: 0,
    scalar_errors: 0,
    flux_frames: 0,
    flux_errors: 0,
    flux_suspect: 0,
    gps_sentences: 0,
    gps_errors: 0,
    records: 0,
    flux_stale: 0,
    no_gps: 0,
    mag_missing: 0,
    parse_error: 0,
};

pub(super) fn inc(c: &mut u32) {
    *c = c.saturating_add(1);
}
