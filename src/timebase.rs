//! The board's sample time base and alignment rule, pure (no embassy) so the host replay
//! and hil-tests run exactly the same code on a capture.
//!
//! - Every scalar line is one sample, `seq` = 0, 1, 2, … (a line the parser rejects is a
//!   sample with `mag = None`, flagged `MAG_MISSING | PARSE_ERROR`).
//! - Virtual clock: sample `k` is at `T_k = k · P` (P = 1/scalar rate). Fluxgate and GPS
//!   frames are stamped `T_k` of the next sample, so the core's aligner pairs each sample with
//!   the latest frames received before it, and their ages are whole sample periods. Nothing
//!   depends on when bytes happened to arrive, only on their order: the host replay of the
//!   same capture (same byte order) gives identical samples.
//! - Output time: `t = k / rate` until the first sample with a valid GPS fix; from then on
//!   `t = t_fix + (T_k − T_fix) + (k − k_anchor) / rate`, anchored once to the GGA time of
//!   that fix, so records carry GPS time of day and stay evenly spaced through outages.

use magcomp_core::Flags;
use magcomp_core::epoch::AlignedSample;
use magcomp_core::protocol::aligner::{Aligner, AlignerConfig};
use magcomp_core::protocol::fluxgate::FluxError;
use magcomp_core::protocol::nmea::{Gga, NmeaError, Sentence};
use magcomp_core::protocol::scalar::{ScalarError, ScalarFrame};

/// Nominal sensor rates (Hz).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rates {
    pub scalar_hz: f64,
    pub flux_hz: f64,
    pub gps_hz: f64,
}

/// Sensor ports, also the index of the per-port error counters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Port {
    Scalar = 0,
    Flux = 1,
    Gps = 2,
}

pub struct SampleAligner {
    aligner: Aligner,
    rate_hz: f64,
    period_us: u64,
    /// GGA time of day (s) of the latest valid fix and the virtual time it was stamped with.
    last_fix: Option<(f64, u64)>,
    /// `(t at k_anchor, k_anchor)`.
    anchor: Option<(f64, u32)>,
    seq: u32,
    /// Parser errors per port (`Port as usize`), in arrival order.
    pub errors: [u32; 3],
}

impl SampleAligner {
    pub fn new(r: Rates) -> Self {
        let period_us = (1e6 / r.scalar_hz) as u64;
        // stale after 2.5 periods of the sensor: one missed frame is tolerated, two are not
        let cfg = AlignerConfig {
            flux_stale_us: (2.5e6 / r.flux_hz) as u64,
            gps_stale_us: (2.5e6 / r.gps_hz) as u64,
            // position held, not extrapolated: the board's virtual clock carries no sub-sample timing
            extrapolate_gps: false,
        };
        Self {
            aligner: Aligner::new(cfg),
            rate_hz: r.scalar_hz,
            period_us,
            last_fix: None,
            anchor: None,
            seq: 0,
            errors: [0; 3],
        }
    }

    /// Virtual time of the next scalar sample.
    fn now_us(&self) -> u64 {
        u64::from(self.seq) * self.period_us
    }

    fn error(&mut self, p: Port) {
        self.errors[p as usize] = self.errors[p as usize].saturating_add(1);
        self.aligner.note_parse_error();
    }

    /// A fluxgate frame already in the body frame (nT), or its parse error.
    pub fn flux(&mut self, r: Result<[f32; 3], FluxError>) {
        match r {
            Ok(v) => self.aligner.push_flux(self.now_us(), v),
            Err(_) => self.error(Port::Flux),
        }
    }

    /// A decoded NMEA sentence, or its parse error. Unsupported sentences are not errors.
    pub fn nmea(&mut self, r: Result<Sentence, NmeaError>) {
        match r {
            Ok(s) => {
                let now = self.now_us();
                if let Sentence::Gga(Gga {
                    fix_quality: Some(1..),
                    time: Some(t),
                    lat_deg: Some(_),
                    lon_deg: Some(_),
                    ..
                }) = &s
                {
                    self.last_fix = Some((t.seconds_of_day_s, now));
                }
                self.aligner.push_nmea(now, &s);
            }
            Err(_) => self.error(Port::Gps),
        }
    }

    /// A scalar line's result → `(seq, sample)`: exactly one sample per line.
    pub fn scalar(&mut self, r: Result<ScalarFrame, ScalarError>) -> (u32, AlignedSample) {
        let k = self.seq;
        let t_us = self.now_us();
        if r.is_err() {
            self.errors[Port::Scalar as usize] =
                self.errors[Port::Scalar as usize].saturating_add(1);
        }
        let mut s = self.aligner.push_scalar_result(t_us, r);
        if let (None, false, Some((tod, at_us))) =
            (self.anchor, s.flags.contains(Flags::NO_GPS), self.last_fix)
        {
            self.anchor = Some((tod + (t_us - at_us) as f64 * 1e-6, k));
        }
        s.t_s = match self.anchor {
            Some((t0, k0)) => t0 + f64::from(k.wrapping_sub(k0)) / self.rate_hz,
            None => f64::from(k) / self.rate_hz,
        };
        self.seq = self.seq.wrapping_add(1);
        (k, s)
    }
}
