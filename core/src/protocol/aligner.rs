//! Sensor aligner: asynchronous scalar, fluxgate and GPS frames → one
//! [`AlignedSample`] per scalar frame.
//!
//! Timestamps are the caller's (the board's µs clock at frame arrival, or the capture's
//! `t_us` in replay), so live and replayed runs give identical samples.
//! - Fluxgate: linear interpolation between the two frames bracketing the scalar time
//!   when both are already in (a caller that wants bracketing every time delays its scalar
//!   by one fluxgate period); otherwise the nearest frame is held. `FLUX_STALE` when the
//!   held frame, or the gap being interpolated across, exceeds `flux_stale_us`.
//! - Delay (`lag`, the board's side): with a [`LagLine`] and τ set, the fluxgate is taken at
//!   `t − τ` from the line instead (same interpolation; `FLUX_STALE` until the line reaches
//!   back that far). GPS is not delayed (module `lag_line` says why).
//! - GPS: position/height/speed from the latest valid GGA/RMC/GLL/GNS/VTG, held or (optionally)
//!   extrapolated along track; `NO_GPS` with no fix or a fix older than `gps_stale_us`.
//! - `PARSE_ERROR` when any parser error was reported since the previous scalar sample.

use super::lag_line::LagLine;
use super::nmea::Sentence;
use super::scalar::{ScalarError, ScalarFrame};
use crate::epoch::AlignedSample;
use crate::flags::Flags;
use crate::units::MagCounts;

const FLUX_HISTORY: usize = 4;
/// Samples whose held-frame age sets what is normal (see `AlignerConfig::flux_period_us`).
pub const AGE_HISTORY: usize = 16;
/// Mean Earth radius (m): along-track extrapolation over a few seconds only.
const EARTH_RADIUS_M: f64 = 6_371_008.8;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AlignerConfig {
    pub flux_stale_us: u64,
    pub gps_stale_us: u64,
    /// Extrapolate position with speed and track to the scalar time.
    pub extrapolate_gps: bool,
    /// Nominal fluxgate frame period (0 = unknown). A sample whose fluxgate frame is held
    /// ¾ period longer than the median of the last [`AGE_HISTORY`] samples' (the frame
    /// after it was lost), or interpolated between frames more than 1.5 periods apart, is
    /// flagged `DERIVATIVE_DEGRADED`: its value is a period old or a straight line across
    /// the lost frame, and the centred derivative of its neighbours spans it (0.36 nT of
    /// error on them at 0.1 % corrupted bytes). A fixed age limit cannot tell: at equal
    /// rates the normal age is the sensors' constant phase, anywhere in 0–1 period.
    pub flux_period_us: u64,
}

impl Default for AlignerConfig {
    fn default() -> Self {
        Self {
            // A few periods of a 100 Hz+ fluxgate / a 1–10 Hz receiver.
            flux_stale_us: 50_000,
            gps_stale_us: 2_000_000,
            extrapolate_gps: true,
            flux_period_us: 0,
        }
    }
}

/// A GPS fix as the aligner keeps it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpsFix {
    pub t_us: u64,
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// Height above mean sea level (m); NaN if unknown.
    pub alt_m: f32,
    /// NaN if unknown.
    pub speed_mps: f32,
    /// NaN if unknown.
    pub track_deg: f32,
}

#[derive(Clone, Debug)]
pub struct Aligner {
    pub cfg: AlignerConfig,
    /// Ages (µs) of the held fluxgate frame at the last samples.
    ages: [u64; AGE_HISTORY],
    n_ages: usize,
    flux: [(u64, [f32; 3]); FLUX_HISTORY],
    n_flux: usize,
    gps: Option<GpsFix>,
    gps_valid: bool,
    parse_error: bool,
    /// Delay of the fluxgate behind the scalar (µs) when paired through a delay line.
    lag_us: u64,
    /// Scalar samples emitted.
    pub samples: u32,
    /// Time of the last scalar sample (µs): a scalar earlier than it is a restart.
    last_scalar_us: Option<u64>,
}

impl Aligner {
    pub const fn new(cfg: AlignerConfig) -> Self {
        Self {
            cfg,
            ages: [0; AGE_HISTORY],
            n_ages: 0,
            flux: [(0, [0.0; 3]); FLUX_HISTORY],
            n_flux: 0,
            gps: None,
            gps_valid: false,
            parse_error: false,
            lag_us: 0,
            samples: 0,
            last_scalar_us: None,
        }
    }

    /// Forgets the held-frame ages that set what is normal: lost-frame detection restarts
    /// after [`AGE_HISTORY`]` / 2` samples, as on a fresh board.
    pub fn forget_frame_ages(&mut self) {
        self.n_ages = 0;
    }

    /// A fluxgate vector (body frame, nT) received at `t_us`; false when refused (not
    /// finite: a parse error on the next sample).
    pub fn push_flux(&mut self, t_us: u64, flux_nt: [f32; 3]) -> bool {
        if !flux_nt.iter().all(|v| v.is_finite()) {
            self.parse_error = true;
            return false;
        }
        if self.n_flux > 0 && t_us < self.flux[self.n_flux - 1].0 {
            // Clock went backwards (restart, new replay): forget the history, the frame
            // ages learnt from it included.
            self.n_flux = 0;
            self.n_ages = 0;
        }
        if self.n_flux == FLUX_HISTORY {
            self.flux.copy_within(1.., 0);
            self.n_flux -= 1;
        }
        self.flux[self.n_flux] = (t_us, flux_nt);
        self.n_flux += 1;
        true
    }

    /// A fluxgate frame received at `t_us` whose value cannot be used (a temperature
    /// correction without a temperature): kept as NaN, so a sample that holds or
    /// interpolates it is `FLUX_STALE`, without a parse error.
    pub fn push_flux_unusable(&mut self, t_us: u64) {
        if self.push_flux(t_us, [0.0; 3]) {
            self.flux[self.n_flux - 1].1 = [f32::NAN; 3];
        }
    }

    /// Any parser error on any port: flags the next sample.
    pub fn note_parse_error(&mut self) {
        self.parse_error = true;
    }

    /// A decoded NMEA sentence received at `t_us`.
    pub fn push_nmea(&mut self, t_us: u64, s: &Sentence) {
        match s {
            Sentence::Gga(g) => {
                let q = g.fix_quality.unwrap_or(0);
                match (q, g.lat_deg, g.lon_deg) {
                    (1.., Some(lat), Some(lon)) => {
                        let prev = self.gps;
                        self.gps = Some(GpsFix {
                            t_us,
                            lat_deg: lat,
                            lon_deg: lon,
                            alt_m: g.alt_msl_m.map_or(f32::NAN, |a| a as f32),
                            speed_mps: prev.map_or(f32::NAN, |p| p.speed_mps),
                            track_deg: prev.map_or(f32::NAN, |p| p.track_deg),
                        });
                        self.gps_valid = true;
                    }
                    _ => self.gps_valid = false,
                }
            }
            Sentence::Rmc(r) => match (r.valid, r.lat_deg, r.lon_deg) {
                (true, Some(lat), Some(lon)) => {
                    let prev = self.gps;
                    self.gps = Some(GpsFix {
                        t_us,
                        lat_deg: lat,
                        lon_deg: lon,
                        alt_m: prev.map_or(f32::NAN, |p| p.alt_m),
                        speed_mps: r.speed_mps.map_or(f32::NAN, |v| v as f32),
                        track_deg: r.track_deg.map_or(f32::NAN, |v| v as f32),
                    });
                    self.gps_valid = true;
                }
                _ => self.gps_valid = false,
            },
            // GLL and GNS carry no speed or track (GLL no height either): those are
            // held from the previous fix, as RMC holds the height.
            Sentence::Gll(_) | Sentence::Gns(_) => match s.fix() {
                Some(f) => {
                    let prev = self.gps;
                    self.gps = Some(GpsFix {
                        t_us,
                        lat_deg: f.lat_deg,
                        lon_deg: f.lon_deg,
                        alt_m: f
                            .alt_msl_m
                            .map_or(prev.map_or(f32::NAN, |p| p.alt_m), |a| a as f32),
                        speed_mps: prev.map_or(f32::NAN, |p| p.speed_mps),
                        track_deg: prev.map_or(f32::NAN, |p| p.track_deg),
                    });
                    self.gps_valid = true;
                }
                None => self.gps_valid = false,
            },
            Sentence::Vtg(v) => {
                if v.mode == Some(b'N') {
                    return;
                }
                if let Some(g) = &mut self.gps {
                    if let Some(s) = v.speed_mps {
                        g.speed_mps = s as f32;
                    }
                    if let Some(t) = v.track_deg {
                        g.track_deg = t as f32;
                    }
                }
            }
            _ => {}
        }
    }

    /// A fix from another source (INS, simulator).
    pub fn push_gps(&mut self, fix: GpsFix) {
        self.gps = Some(fix);
        self.gps_valid = true;
    }

    /// The fluxgate at `t_us` from the aligner's own history: (value, stale, interpolated
    /// across a lost frame, age of the held frame when one is held).
    fn flux_at(&self, t_us: u64) -> ([f32; 3], bool, bool, Option<u64>) {
        let h = &self.flux[..self.n_flux];
        interpolate(h.len(), |i| h[i], t_us, &self.cfg, false)
    }

    /// The fluxgate at `t_us − τ` from the delay line (`lag_line`); `FLUX_STALE` until
    /// the line reaches back that far (start, or a line restarted by a clock reset).
    fn flux_delayed(&self, line: &LagLine, t_us: u64) -> ([f32; 3], bool, bool, Option<u64>) {
        let oldest = || match line.is_empty() {
            true => [f32::NAN; 3],
            false => line.get(0).1,
        };
        match t_us.checked_sub(self.lag_us) {
            Some(t) => interpolate(line.len(), |i| line.get(i), t, &self.cfg, true),
            None => (oldest(), true, false, None),
        }
    }

    /// Whether a frame held `age_us` is one whose successor was lost: older by three
    /// quarters of a period than the youngest age of the last [`AGE_HISTORY`] samples (at
    /// least 8), which is the ports' phase as long as one of them had a fresh frame. Every
    /// age enters the history, lost ones too, so the reference follows the phase whatever
    /// came before (a sensor restart, a resumed replay) and cannot ratchet: two aligners
    /// that saw different pasts agree again after 16 samples. The median was used first:
    /// with 1 % of the fluxgate's bytes corrupted 28 % of its frames are lost, runs of held
    /// frames pushed the median up, and 65 held frames went unflagged (one 5.1 nT off).
    fn held_across_loss(&mut self, age_us: u64) -> bool {
        let period = self.cfg.flux_period_us;
        if period == 0 {
            return false;
        }
        let lost = self.n_ages >= AGE_HISTORY / 2 && {
            let youngest = self.ages[..self.n_ages]
                .iter()
                .copied()
                .min()
                .unwrap_or(age_us);
            // Saturating: a time jump of any size must not overflow (no panic on any input).
            age_us.saturating_mul(4)
                > youngest
                    .saturating_mul(4)
                    .saturating_add(period.saturating_mul(3))
        };
        // Rotate: the newest age replaces the oldest once the history is full.
        if self.n_ages < AGE_HISTORY {
            self.n_ages += 1;
        } else {
            self.ages.rotate_left(1);
        }
        self.ages[self.n_ages - 1] = age_us;
        lost
    }

    /// A scalar sample at `t_us` (`None`: missing/invalid) → its aligned sample.
    pub fn push_scalar(&mut self, t_us: u64, mag: Option<MagCounts>) -> AlignedSample {
        self.push_scalar_delayed(t_us, mag, None)
    }

    /// The delay applied to the fluxgate (µs): with a delay line, a scalar sample at t is
    /// paired with the fluxgate at t − τ (`lag_line`). 0 = none.
    pub fn set_lag_us(&mut self, lag_us: u64) {
        self.lag_us = lag_us;
    }

    pub fn lag_us(&self) -> u64 {
        self.lag_us
    }

    /// As [`push_scalar`](Self::push_scalar), the fluxgate taken from `line` at
    /// `t_us − τ` when a delay is set (the line is fed by the caller with every frame
    /// [`push_flux`](Self::push_flux) accepts).
    pub fn push_scalar_delayed(
        &mut self,
        t_us: u64,
        mag: Option<MagCounts>,
        line: Option<&LagLine>,
    ) -> AlignedSample {
        if self.last_scalar_us.is_some_and(|last| t_us < last) {
            // The clock went backwards on the scalar port (restart, new replay) before the
            // fluxgate showed it: its frames and ages belong to the old run.
            self.n_flux = 0;
            self.n_ages = 0;
        }
        self.last_scalar_us = Some(t_us);
        let mut s = AlignedSample::empty(t_us as f64 / 1e6);
        s.mag = mag;
        if mag.is_none() {
            s.flags.set(Flags::MAG_MISSING);
        }
        let (flux, stale, mut lost, age) = match line {
            Some(l) if self.lag_us > 0 => self.flux_delayed(l, t_us),
            _ => self.flux_at(t_us),
        };
        if let Some(age) = age {
            lost |= self.held_across_loss(age);
        }
        s.flux_nt = flux;
        if stale {
            s.flags.set(Flags::FLUX_STALE);
        }
        if lost {
            s.flags.set(Flags::DERIVATIVE_DEGRADED);
        }
        match self.gps {
            Some(g) => {
                let age_us = t_us.abs_diff(g.t_us);
                let (mut lat, mut lon) = (g.lat_deg, g.lon_deg);
                if self.cfg.extrapolate_gps && g.speed_mps.is_finite() && g.track_deg.is_finite() {
                    let dt_s = (t_us as f64 - g.t_us as f64) * 1e-6;
                    let d_m = g.speed_mps as f64 * dt_s;
                    let tr = (g.track_deg as f64).to_radians();
                    let dlat = d_m * libm::cos(tr) / EARTH_RADIUS_M;
                    let coslat = libm::cos(lat.to_radians()).max(1e-6);
                    let dlon = d_m * libm::sin(tr) / (EARTH_RADIUS_M * coslat);
                    lat += dlat.to_degrees();
                    lon += dlon.to_degrees();
                }
                s.lat_deg = lat;
                s.lon_deg = lon;
                s.alt_m = g.alt_m;
                s.ground_speed_mps = g.speed_mps;
                if !self.gps_valid || age_us > self.cfg.gps_stale_us {
                    s.flags.set(Flags::NO_GPS);
                }
            }
            None => s.flags.set(Flags::NO_GPS),
        }
        if self.parse_error {
            s.flags.set(Flags::PARSE_ERROR);
            self.parse_error = false;
        }
        self.samples = self.samples.wrapping_add(1);
        s
    }

    /// Convenience for a scalar reader result: an error still yields one (flagged) sample.
    pub fn push_scalar_result(
        &mut self,
        t_us: u64,
        r: Result<ScalarFrame, ScalarError>,
    ) -> AlignedSample {
        self.push_scalar_result_delayed(t_us, r, None)
    }

    /// As [`push_scalar_result`](Self::push_scalar_result) through a delay line.
    pub fn push_scalar_result_delayed(
        &mut self,
        t_us: u64,
        r: Result<ScalarFrame, ScalarError>,
        line: Option<&LagLine>,
    ) -> AlignedSample {
        match r {
            Ok(f) => self.push_scalar_delayed(t_us, Some(f.mag), line),
            Err(_) => {
                self.parse_error = true;
                self.push_scalar_delayed(t_us, None, line)
            }
        }
    }
}

/// The fluxgate at `t_us` from `n` frames, oldest first (`frame(i)` = stamp µs, value):
/// linear between the two frames that bracket `t_us`, else the nearest one held. Returns
/// (value, stale, interpolated across a lost frame, age of the held frame when one is
/// held). `strict`: a time before the oldest frame is stale whatever the distance (a delay
/// line not yet filled), rather than held from the first frame within the limit.
fn interpolate(
    n: usize,
    frame: impl Fn(usize) -> (u64, [f32; 3]),
    t_us: u64,
    cfg: &AlignerConfig,
    strict: bool,
) -> ([f32; 3], bool, bool, Option<u64>) {
    // First frame stamped after t (binary search: the delay line holds up to 512).
    let (mut lo, mut hi) = (0, n);
    while lo < hi {
        let mid = lo + (hi - lo) / 2;
        if frame(mid).0 > t_us {
            hi = mid;
        } else {
            lo = mid + 1;
        }
    }
    let limit = cfg.flux_stale_us;
    match lo {
        _ if n == 0 => ([f32::NAN; 3], true, false, None),
        i if i == n => {
            let (t, v) = frame(n - 1);
            (v, t_us - t > limit, false, Some(t_us - t))
        }
        0 => {
            let (t, v) = frame(0);
            (v, strict || t - t_us > limit, false, None)
        }
        i => {
            let (t0, v0) = frame(i - 1);
            let (t1, v1) = frame(i);
            let w = ((t_us - t0) as f64 / (t1 - t0) as f64) as f32;
            // A frame with zero weight does not enter (an unusable NaN frame after one
            // the delay lands on exactly would otherwise flag the sample).
            let v = if w == 0.0 {
                v0
            } else {
                [0, 1, 2].map(|k| v0[k] + w * (v1[k] - v0[k]))
            };
            let period = cfg.flux_period_us;
            let lost = period > 0 && (t1 - t0).saturating_mul(2) > period.saturating_mul(3);
            (v, t1 - t0 > limit, lost, None)
        }
    }
}
