//! Sensor aligner: turns the merged, arrival-ordered stream of sensor frames into one
//! `AlignedSample` per scalar sample.
//!
//! PLACEHOLDER until the core's aligner (branch `proto`) lands; pure logic, no embassy,
//! so the host replay can run the identical rules:
//! - every scalar line is one sample (a line that fails to parse is a sample with
//!   `mag = None`, `MAG_MISSING | PARSE_ERROR`), sample `seq` counts from 0;
//! - time comes from the sample counter at the nominal rate, `t = seq / rate`, until the
//!   first GPS fix; from then on `t = t_fix + age / rate + (seq - seq_anchor) / rate`, where
//!   `t_fix` is the GGA time of the latest fix and `age` the samples since it arrived;
//! - a sample takes the latest fluxgate and GPS frames received before it; their ages are
//!   counted in scalar samples (not wall time) so the rules are reproducible off-board;
//! - stale or missing values are NaN and flagged (`FLUX_STALE`, `NO_GPS`); any parser
//!   error since the previous sample sets `PARSE_ERROR`.

use crate::wire::{Nmea, ParseError};
use magcomp_core::epoch::AlignedSample;
use magcomp_core::{Flags, MagCounts};

/// One parsed frame (or parse failure) from a sensor port, in arrival order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Event {
    Scalar(Result<MagCounts, ParseError>),
    Flux(Result<[f32; 3], ParseError>),
    Gps(Result<Nmea, ParseError>),
}

/// Sensor ports, also the index of the per-port error counters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Port {
    Scalar = 0,
    Flux = 1,
    Gps = 2,
}

#[derive(Clone, Copy, Debug)]
pub struct AlignerConfig {
    /// Nominal scalar sample rate (Hz).
    pub rate_hz: f64,
    /// A fluxgate frame older than this many scalar samples is stale.
    pub flux_stale_samples: u32,
    /// A GPS fix older than this many scalar samples is lost.
    pub gps_stale_samples: u32,
}

impl AlignerConfig {
    /// Defaults for a scalar rate, fluxgate rate and GPS rate (Hz): stale after 2.5 periods
    /// of the slower sensor, counted in scalar samples.
    pub fn for_rates(scalar_hz: f64, flux_hz: f64, gps_hz: f64) -> Self {
        let samples = |hz: f64| libm::ceil(2.5 * scalar_hz / hz.max(1e-3)).max(1.0) as u32;
        Self {
            rate_hz: scalar_hz,
            flux_stale_samples: samples(flux_hz),
            gps_stale_samples: samples(gps_hz),
        }
    }
}

#[derive(Clone, Copy, Debug)]
struct Fix {
    time_s: f64,
    lat_deg: f64,
    lon_deg: f64,
    alt_m: f32,
    quality: u8,
}

pub struct Aligner {
    cfg: AlignerConfig,
    seq: u32,
    flux: Option<[f32; 3]>,
    flux_age: u32,
    fix: Option<Fix>,
    gps_age: u32,
    speed_mps: f32,
    speed_age: u32,
    parse_error_pending: bool,
    anchor: Option<(f64, u32)>,
    /// Parser errors per port (`Port as usize`).
    pub errors: [u32; 3],
}

impl Aligner {
    pub const fn new(cfg: AlignerConfig) -> Self {
        Self {
            cfg,
            seq: 0,
            flux: None,
            flux_age: 0,
            fix: None,
            gps_age: 0,
            speed_mps: f32::NAN,
            speed_age: 0,
            parse_error_pending: false,
            anchor: None,
            errors: [0; 3],
        }
    }

    /// Samples produced so far.
    pub fn samples(&self) -> u32 {
        self.seq
    }

    fn error(&mut self, port: Port) {
        self.errors[port as usize] = self.errors[port as usize].saturating_add(1);
        self.parse_error_pending = true;
    }

    /// Feeds one event; a scalar event yields the sample `(seq, sample)`.
    pub fn push(&mut self, ev: Event) -> Option<(u32, AlignedSample)> {
        match ev {
            Event::Flux(Ok(v)) => {
                self.flux = Some(v);
                self.flux_age = 0;
                None
            }
            Event::Gps(Ok(Nmea::Gga {
                time_s,
                lat_deg,
                lon_deg,
                alt_msl_m,
                fix,
            })) => {
                self.fix = Some(Fix {
                    time_s,
                    lat_deg,
                    lon_deg,
                    alt_m: alt_msl_m,
                    quality: fix,
                });
                self.gps_age = 0;
                None
            }
            Event::Gps(Ok(
                Nmea::Rmc {
                    valid: true,
                    speed_mps,
                    ..
                }
                | Nmea::Vtg { speed_mps, .. },
            )) => {
                self.speed_mps = speed_mps;
                self.speed_age = 0;
                None
            }
            Event::Gps(Ok(_)) => None,
            Event::Flux(Err(_)) => {
                self.error(Port::Flux);
                None
            }
            Event::Gps(Err(_)) => {
                self.error(Port::Gps);
                None
            }
            Event::Scalar(r) => {
                if r.is_err() {
                    self.error(Port::Scalar);
                }
                Some(self.sample(r.ok()))
            }
        }
    }

    fn sample(&mut self, mag: Option<MagCounts>) -> (u32, AlignedSample) {
        let seq = self.seq;
        self.seq = self.seq.wrapping_add(1);
        let rate = self.cfg.rate_hz;
        let fix = self
            .fix
            .filter(|f| f.quality > 0 && self.gps_age <= self.cfg.gps_stale_samples);
        if let (None, Some(f)) = (self.anchor, fix) {
            self.anchor = Some((f.time_s + f64::from(self.gps_age) / rate, seq));
        }
        let t_s = match self.anchor {
            Some((t0, s0)) => t0 + f64::from(seq.wrapping_sub(s0)) / rate,
            None => f64::from(seq) / rate,
        };
        let mut s = AlignedSample::empty(t_s);
        s.mag = mag;
        if mag.is_none() {
            s.flags.set(Flags::MAG_MISSING);
        }
        match self.flux {
            Some(v) if self.flux_age <= self.cfg.flux_stale_samples => s.flux_nt = v,
            _ => s.flags.set(Flags::FLUX_STALE),
        }
        match fix {
            Some(f) => {
                s.lat_deg = f.lat_deg;
                s.lon_deg = f.lon_deg;
                s.alt_m = f.alt_m;
                if self.speed_age <= self.cfg.gps_stale_samples {
                    s.ground_speed_mps = self.speed_mps;
                }
            }
            None => s.flags.set(Flags::NO_GPS),
        }
        if core::mem::take(&mut self.parse_error_pending) {
            s.flags.set(Flags::PARSE_ERROR);
        }
        self.flux_age = self.flux_age.saturating_add(1);
        self.gps_age = self.gps_age.saturating_add(1);
        self.speed_age = self.speed_age.saturating_add(1);
        (seq, s)
    }
}
