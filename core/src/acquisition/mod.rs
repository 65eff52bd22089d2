//! Acquisition: sensor bytes in, output records out. The one path from the scalar,
//! fluxgate and GPS ports to `$MCREC` records, shared by the firmware and `magcomp replay`
//! so that both emit the same records for the same bytes in the same order.
//!
//! ```text
//! scalar bytes ─ ScalarReader ─┐
//! flux bytes/SPI frames ─ Flux ─┼─ time base + Aligner ─ Compensator ─ Record (seq, t, …)
//! GPS bytes ─ NmeaReader ───────┘
//! ```
//!
//! Time base (the firmware's rule, `docs/protocols.md` §10): only the *order* of frames
//! matters, never when their bytes arrived, so jitter on the UARTs cannot change a record.
//! - Every scalar line is one sample `k` = 0, 1, 2, … (a rejected line is a sample with
//!   `mag = None`, flagged `MAG_MISSING | PARSE_ERROR`): nothing is dropped.
//! - Virtual clock: sample `k` is at `T_k = k · P` (P = 1 / scalar rate, whole µs). A
//!   fluxgate or GPS frame is stamped `T_k` of the next scalar sample, so each sample is
//!   paired with the latest frames received before it and their ages are whole periods.
//!   Staleness limits are 2.5 nominal periods of each sensor (one missed frame tolerated).
//! - Output time: `t = k / rate` until the first sample with a valid fix; from then on
//!   `t = t_fix + (T_k − T_fix) + (k − k_anchor) / rate`, anchored once to the time of
//!   day of a GGA, GLL or GNS fix, so records carry GPS time and stay evenly spaced through outages.
//! - Records are delayed by the compensator's derivative half-width; [`Acquisition::flush`]
//!   emits the held ones at the end of a stream.
//!
//! Several magnetometers (`protocol::multi_scalar`): a counter line carrying 2–3 fields
//! runs one [`Compensator`] per channel, each with its own coefficients and field states,
//! all on the one sample (same time base, fluxgate and GPS), and yields one
//! [`MultiRecord`] per line. The channel count is learnt from the lines: single-field lines
//! take exactly the single-sensor path above (same records, byte for byte); the first
//! counter line switches to multi records until the next start, a later one with more
//! channels adds them. A channel added mid-stream has no output for the samples its
//! compensator has not seen: those records carry it as missing.

mod config;
mod output;
mod witness;

pub use config::{
    compensator_config, AcqConfig, AcqError, BOARD_NOISE_FLOOR_NT, FLUX_FULL_SCALE_NT, MAX_RATE_HZ,
};
use output::{inc, COUNTERS_ZERO};
pub use output::{AcqCounters, AcqRecord};

use crate::compensator::witness::WitnessChoice;
use crate::compensator::{Compensator, CompensatorConfig, CompensatorError};
use crate::continuity::{Continuity, FluxContinuity, StuckAxis};
use crate::epoch::AlignedSample;
use crate::flags::Flags;
use crate::model::Model;
use crate::protocol::aligner::{Aligner, AlignerConfig};
use crate::protocol::capture::Port;
use crate::protocol::fluxgate::AxisMap;
use crate::protocol::fluxgate::{
    decode_spi_frame, FluxAsciiReader, FluxCalibration, FluxError, FluxStats, FluxTempCal,
    FluxgateCal,
};
use crate::protocol::lag_line::{check_lag, LagError, LagLine};
use crate::protocol::multi_raw::{MultiRawSample, RawLine};
use crate::protocol::multi_record::{ChannelRecord, MultiRecord};
use crate::protocol::multi_scalar::{Channel, MultiFrame, ScalarLine, MAX_CHANNELS};
use crate::protocol::nmea::{Fix, NmeaError, NmeaReader, NmeaStats, Sentence};
use crate::protocol::raw::RawSample;
use crate::protocol::record::Record;
use crate::protocol::scalar::{
    ScalarConfig, ScalarError, ScalarFrame, ScalarReader, ScalarStats, CS133_HZ_PER_NT_NANO,
};
use crate::units::MagCounts;

/// Oldest scalar value a fluxgate frame is held against (µs): the field moves at most a few
/// nT in a second, far inside the check's 20 % of it.
const SCALAR_REFERENCE_MAX_AGE_US: u64 = 1_000_000;

/// Sensor bytes → records. `N`, `W`: the compensator's state and derivative-ring capacity.
pub struct Acquisition<'a, const N: usize, const W: usize> {
    cfg: AcqConfig,
    scalar: ScalarReader,
    flux: FluxAsciiReader,
    flux_spi: FluxStats,
    nmea: NmeaReader,
    aligner: Aligner,
    /// The fluxgate modulus judged against its recent past, frame by frame.
    flux_check: FluxContinuity,
    /// The raw frames' axes, each judged for a value that never changes.
    flux_stuck: StuckAxis,
    comp: Compensator<'a, N, W>,
    /// Channels 1 and 2 of a counter line (`comp` is channel 0).
    extra: [Compensator<'a, N, W>; MAX_CHANNELS - 1],
    /// Channels seen on counter lines (1: single-sensor records).
    channels: u8,
    /// While single fields arrive, `extra[0]` may run this model beside `comp`: the paper
    /// model with the fluxgate as a witness (`witness.rs`), and which of the two is shown.
    witness: Option<(Model<'a>, WitnessChoice)>,
    /// The fluxgate's delay line (`lag`), when the caller gave one (8 KiB: the board keeps
    /// it in its own zero-initialised static).
    lag_line: Option<&'a mut LagLine>,
    /// τ (s) as set, 0 = none.
    lag_s: f32,
    period_us: u64,
    /// Next scalar sample index.
    k: u32,
    /// Next record sequence number.
    seq: u32,
    /// GGA time of day (s) of the latest valid fix and the virtual time it was stamped with.
    last_fix: Option<(f64, u64)>,
    /// `(t at k_anchor, k_anchor)`.
    anchor: Option<(f64, u32)>,
    counters: AcqCounters,
    /// The latest scalar value (nT) and its virtual time, that fluxgate frames are held
    /// against ([`flux_disagrees_with_scalar`](crate::continuity::flux_disagrees_with_scalar)).
    last_scalar: Option<(u64, f32)>,
    /// `RAW,ON`: each scalar sample is also kept as a raw line ([`take_raw`](Self::take_raw)).
    raw_output: bool,
    last_raw: Option<RawLine>,
}

impl<'a, const N: usize, const W: usize> Acquisition<'a, N, W> {
    /// `comp` is built by the caller (the board from its static model, the host from a
    /// model spec), normally with [`compensator_config`].
    pub fn new(cfg: AcqConfig, comp: Compensator<'a, N, W>) -> Result<Self, AcqError> {
        if !cfg.valid() {
            return Err(AcqError::BadRate);
        }
        let more = || Compensator::new(*comp.model(), *comp.config());
        let extra = [
            more().map_err(AcqError::Compensator)?,
            more().map_err(AcqError::Compensator)?,
        ];
        Ok(Self {
            cfg,
            scalar: ScalarReader::new(cfg.scalar),
            flux: FluxAsciiReader::new(),
            flux_spi: FluxStats::default(),
            nmea: NmeaReader::new(),
            aligner: Aligner::new(cfg.aligner_config()),
            flux_check: FluxContinuity::new(),
            flux_stuck: StuckAxis::new(),
            comp,
            extra,
            channels: 1,
            witness: None,
            lag_line: None,
            lag_s: 0.0,
            period_us: cfg.period_us().max(1),
            k: 0,
            seq: 0,
            last_fix: None,
            anchor: None,
            counters: AcqCounters::default(),
            last_scalar: None,
            raw_output: false,
            last_raw: None,
        })
    }

    /// An acquisition with a [`Compensator::placeholder`], usable in a `static`
    /// initialiser (`const`), so a board never builds the ~N² filter on its stack: call
    /// [`reset_in_place`](Self::reset_in_place) before use.
    pub const fn placeholder(model: Model<'a>) -> Self {
        const AXES: [AxisMap; 3] = [
            AxisMap {
                sensor_channel: 0,
                negate: false,
            },
            AxisMap {
                sensor_channel: 1,
                negate: false,
            },
            AxisMap {
                sensor_channel: 2,
                negate: false,
            },
        ];
        let cfg = AcqConfig {
            scalar_hz: 1.0,
            flux_hz: 1.0,
            gps_hz: 1.0,
            scalar: ScalarConfig {
                larmor_hz_per_nt_nano: CS133_HZ_PER_NT_NANO,
            },
            flux_cal: FluxgateCal {
                nt_per_lsb: [0.0; 3],
                offset_nt: [0.0; 3],
                axis_map: AXES,
            },
            flux_scalar_cal: FluxCalibration::IDENTITY,
            flux_temp_cal: FluxTempCal::NONE,
        };
        let aligner = AlignerConfig {
            flux_stale_us: 0,
            gps_stale_us: 0,
            extrapolate_gps: false,
            flux_period_us: 0,
        };
        Self {
            cfg,
            scalar: ScalarReader::new(cfg.scalar),
            flux: FluxAsciiReader::new(),
            flux_spi: FluxStats { ok: 0, errors: 0 },
            nmea: NmeaReader::new(),
            aligner: Aligner::new(aligner),
            flux_check: FluxContinuity::new(),
            flux_stuck: StuckAxis::new(),
            comp: Compensator::placeholder(model),
            extra: [
                Compensator::placeholder(model),
                Compensator::placeholder(model),
            ],
            channels: 1,
            witness: None,
            lag_line: None,
            lag_s: 0.0,
            period_us: 1,
            k: 0,
            seq: 0,
            last_fix: None,
            anchor: None,
            counters: COUNTERS_ZERO,
            last_scalar: None,
            raw_output: false,
            last_raw: None,
        }
    }

    /// (Re)starts in place: parsers, time base, counters, sequence numbers and the
    /// compensator (via [`Compensator::reset_in_place`]), as [`new`](Self::new) would
    /// build them. On error nothing is changed.
    pub fn reset_in_place(
        &mut self,
        cfg: AcqConfig,
        model: Model<'a>,
        comp: CompensatorConfig,
    ) -> Result<(), AcqError> {
        if !cfg.valid() {
            return Err(AcqError::BadRate);
        }
        self.comp
            .reset_in_place(model, comp)
            .map_err(AcqError::Compensator)?;
        for c in &mut self.extra {
            c.reset_in_place(model, comp)
                .map_err(AcqError::Compensator)?;
        }
        self.channels = 1;
        self.witness = None;
        self.cfg = cfg;
        self.scalar = ScalarReader::new(cfg.scalar);
        self.flux = FluxAsciiReader::new();
        self.flux_spi = FluxStats::default();
        self.nmea = NmeaReader::new();
        self.aligner = Aligner::new(cfg.aligner_config());
        self.flux_check = FluxContinuity::new();
        self.flux_stuck.restart();
        self.last_scalar = None;
        // A fresh start has no delay until one is set (the board reloads its stored τ).
        self.lag_s = 0.0;
        if let Some(l) = self.lag_line.as_deref_mut() {
            l.clear();
        }
        self.period_us = cfg.period_us().max(1);
        self.k = 0;
        self.seq = 0;
        self.last_raw = None;
        self.last_fix = None;
        self.anchor = None;
        self.counters = AcqCounters::default();
        Ok(())
    }

    /// Restarts the compensator alone, in place (priors, derivative window, calibrate
    /// mode), the aligner's lost-frame reference and the fluxgate continuity check with it,
    /// so a restarted filter learns from what a fresh board would (the old run's frame
    /// phase flagged the first four samples of a replay restarted in place, which then did
    /// not update; its last fluxgate frames made the first one suspect); the time base,
    /// counters and sequence numbers continue. Call [`flush`](Self::flush) first so no
    /// sample loses its record. On error the compensator is unchanged.
    pub fn reset_compensator(
        &mut self,
        model: Model<'a>,
        comp: CompensatorConfig,
    ) -> Result<(), CompensatorError> {
        self.comp.reset_in_place(model, comp)?;
        for c in &mut self.extra {
            c.reset_in_place(model, comp)?;
        }
        self.restart_witness()?;
        self.aligner.forget_frame_ages();
        // A fresh start for the fluxgate's continuity check too: the frames before the
        // restart need not continue into the ones after it.
        self.flux_check.restart();
        self.flux_stuck.restart();
        Ok(())
    }

    pub fn config(&self) -> &AcqConfig {
        &self.cfg
    }
    pub fn counters(&self) -> AcqCounters {
        self.counters
    }
    pub fn scalar_stats(&self) -> ScalarStats {
        self.scalar.stats
    }
    pub fn nmea_stats(&self) -> NmeaStats {
        self.nmea.stats
    }
    /// ASCII and SPI fluxgate frames together.
    pub fn flux_stats(&self) -> FluxStats {
        FluxStats {
            ok: self.flux.stats.ok.saturating_add(self.flux_spi.ok),
            errors: self.flux.stats.errors.saturating_add(self.flux_spi.errors),
        }
    }
    /// Scalar samples taken so far (records emitted + records still held).
    pub fn samples(&self) -> u32 {
        self.k
    }
    /// Sequence number of the next record.
    pub fn next_seq(&self) -> u32 {
        self.seq
    }

    pub fn compensator(&self) -> &Compensator<'a, N, W> {
        &self.comp
    }
    pub fn compensator_mut(&mut self) -> &mut Compensator<'a, N, W> {
        &mut self.comp
    }
    /// Swaps in a fresh compensator (filter reset); sequence numbers and the time base
    /// continue. Call [`flush`](Self::flush) first so no sample loses its record.
    pub fn replace_compensator(&mut self, comp: Compensator<'a, N, W>) -> Compensator<'a, N, W> {
        core::mem::replace(&mut self.comp, comp)
    }
    /// Every channel's compensator.
    pub fn set_survey_mode(&mut self, on: bool) {
        self.comp.set_survey_mode(on);
        for c in &mut self.extra {
            c.set_survey_mode(on);
        }
        self.witness_survey_mode(on);
    }
    /// Channels seen on counter lines since the start (1: single-sensor records).
    pub fn channels(&self) -> u8 {
        self.channels
    }
    /// Channel `sensor`'s compensator (0 = the single sensor's), `None` beyond
    /// [`MAX_CHANNELS`] and for channel 1 while the witness runs in its compensator.
    pub fn sensor(&self, sensor: usize) -> Option<&Compensator<'a, N, W>> {
        match sensor {
            0 => Some(&self.comp),
            1 if self.witness.is_some() => None,
            s => self.extra.get(s - 1),
        }
    }
    /// Channel `sensor`'s compensator to change: taking channel 1's stops the witness.
    pub fn sensor_mut(&mut self, sensor: usize) -> Option<&mut Compensator<'a, N, W>> {
        match sensor {
            0 => Some(&mut self.comp),
            s => {
                if s == 1 {
                    self.detach_witness();
                }
                self.extra.get_mut(s - 1)
            }
        }
    }
    pub fn is_survey_mode(&self) -> bool {
        self.comp.is_survey_mode()
    }
    /// Loads coefficients (physical units, model order) and switches to survey mode.
    /// With a witness attached, a set of the witnessed model's length goes to its filter,
    /// and the records shown are that filter's from then on.
    pub fn set_coefficients(&mut self, c: &[f32]) -> Result<(), CompensatorError> {
        if let Some(r) = self.set_witness_coefficients(c) {
            return r;
        }
        self.comp.set_coefficients(c)
    }

    /// Gives the acquisition a delay line for the fluxgate (needed for a τ > 0); it starts
    /// empty, so the first τ of records are `FLUX_STALE`.
    pub fn attach_lag_line(&mut self, line: &'a mut LagLine) {
        line.clear();
        self.lag_line = Some(line);
    }

    /// The scalar's delay τ (s, `lag`, `SETLAG`): from the next sample on, each scalar
    /// sample at t is paired with the fluxgate at t − τ. Refused (nothing changed) when
    /// outside [0, `MAX_LAG_S`], longer than the line at the nominal fluxgate rate, or > 0
    /// without a line. A τ set mid-flight applies at once; the line already holds the past.
    pub fn set_lag_s(&mut self, lag_s: f32) -> Result<(), LagError> {
        check_lag(lag_s, self.cfg.flux_hz)?;
        if lag_s > 0.0 && self.lag_line.is_none() {
            return Err(LagError::NoLine);
        }
        self.lag_s = lag_s;
        self.aligner
            .set_lag_us(libm::round(f64::from(lag_s) * 1e6) as u64);
        Ok(())
    }

    /// τ (s) as set.
    pub fn lag_s(&self) -> f32 {
        self.lag_s
    }

    /// The fluxgate's scalar calibration (`fluxcal`) applied to every frame.
    pub fn flux_calibration(&self) -> FluxCalibration {
        self.cfg.flux_scalar_cal
    }

    /// Applies a fluxgate calibration to every frame from now on.
    pub fn set_flux_calibration(&mut self, cal: FluxCalibration) {
        self.cfg.flux_scalar_cal = cal;
        // The modulus moves with the calibration: not a glitch.
        self.flux_check.restart();
    }
    /// The shown filter's coefficients (the witnessed model's when its records are shown).
    pub fn coefficients(&self, out: &mut [f32]) -> usize {
        self.shown_compensator().coefficients(out)
    }

    /// Virtual time of the next scalar sample.
    fn now_us(&self) -> u64 {
        u64::from(self.k).saturating_mul(self.period_us)
    }

    /// One byte from the scalar port; a line end yields the sample's record (or the record
    /// of the sample `half_width` back, which is what the compensator has ready).
    pub fn push_scalar_byte(&mut self, b: u8) -> Option<Record> {
        let r = self.scalar.push(b)?;
        self.scalar_result(r)
    }

    /// A scalar line's result from a reader the caller runs itself (the board parses in
    /// its UART task): exactly one sample per line, rejected lines included.
    pub fn scalar_result(&mut self, r: Result<ScalarFrame, ScalarError>) -> Option<Record> {
        let line_error = r.is_err();
        let s = self.next_sample(r.ok().map(|f| f.mag), line_error);
        let out = self.comp.push(&s);
        let witnessed = self.witness.is_some().then(|| self.extra[0].push(&s));
        let out = self.shown_output(out?, witnessed.flatten());
        Some(self.record(out))
    }

    /// The next sample `k` on the time base, paired with the fluxgate and GPS; a rejected
    /// line (`line_error`) is counted and flagged `PARSE_ERROR`.
    fn next_sample(&mut self, mag: Option<MagCounts>, line_error: bool) -> AlignedSample {
        let k = self.k;
        let t_us = self.now_us();
        inc(&mut self.counters.scalar_lines);
        if line_error {
            inc(&mut self.counters.scalar_errors);
            self.aligner.note_parse_error();
        }
        if let Some(m) = mag {
            self.last_scalar = Some((t_us, m.to_nt_f64() as f32));
        }
        let mut s = self
            .aligner
            .push_scalar_delayed(t_us, mag, self.lag_line.as_deref());
        if let (None, false, Some((tod_s, at_us))) =
            (self.anchor, s.flags.contains(Flags::NO_GPS), self.last_fix)
        {
            self.anchor = Some((tod_s + t_us.saturating_sub(at_us) as f64 * 1e-6, k));
        }
        s.t_s = match self.anchor {
            Some((t0, k0)) => t0 + f64::from(k.wrapping_sub(k0)) / self.cfg.scalar_hz,
            None => f64::from(k) / self.cfg.scalar_hz,
        };
        if self.raw_output {
            self.last_raw = Some(RawLine::One(RawSample::of(k, &s)));
        }
        self.k = self.k.wrapping_add(1);
        s
    }

    /// One byte from the scalar port, single-field or counter lines
    /// ([`scalar_line`](Self::scalar_line)). After each byte the caller takes the lines a
    /// merged line still owes ([`owed_scalar_line`](Self::owed_scalar_line)).
    pub fn push_scalar_line_byte(&mut self, b: u8) -> Option<AcqRecord> {
        let l = self.scalar.push_line(b)?;
        self.scalar_line(l)
    }

    /// A further sample of the last scalar line, when it ran into the next (a lost
    /// terminator, `ScalarReader`): pass it to [`scalar_line`](Self::scalar_line) like a
    /// line, until None, so every sample keeps its record and its time. The board's UART
    /// task does the same with its own reader.
    pub fn owed_scalar_line(&mut self) -> Option<ScalarLine> {
        self.scalar.owed_line()
    }

    /// A scalar port line (single field or counter line) from a reader the caller runs:
    /// exactly one sample, and one record once the compensators hold it no longer.
    /// Single-field lines while no counter line has been seen are [`scalar_result`](Self::scalar_result)'s.
    pub fn scalar_line(&mut self, l: ScalarLine) -> Option<AcqRecord> {
        let f = match l {
            ScalarLine::Single(r) if self.channels == 1 => {
                return self.scalar_result(r).map(AcqRecord::One);
            }
            ScalarLine::Multi(f) => {
                self.channels = self.channels.max(f.channels);
                self.detach_witness();
                f
            }
            // a counter that has sent counter lines: a single field is its channel 0,
            // an unreadable line every channel read wrong
            ScalarLine::Single(r) => {
                let mut f = MultiFrame {
                    channels: self.channels,
                    ch: [Channel::Missing; MAX_CHANNELS],
                };
                match r {
                    Ok(s) => f.ch[0] = Channel::Field(s.mag),
                    Err(e) => f.ch = [Channel::Invalid(e); MAX_CHANNELS],
                }
                f
            }
        };
        self.multi_result(&f)
    }

    /// A counter line: the one sample for every channel, each through its compensator.
    fn multi_result(&mut self, f: &MultiFrame) -> Option<AcqRecord> {
        let invalid = |c: &Channel| matches!(c, Channel::Invalid(_));
        let s = self.next_sample(f.ch[0].mag(), false);
        if f.ch.iter().any(invalid) {
            inc(&mut self.counters.scalar_errors);
        }
        let n = usize::from(self.channels);
        // the aligner flagged channel 0's reading; each channel gets its own
        let channel_sample = |c: &Channel| {
            let mut si = s;
            si.mag = c.mag();
            si.flags.0 &= !(Flags::MAG_MISSING);
            if si.mag.is_none() {
                si.flags.set(Flags::MAG_MISSING);
            }
            if invalid(c) {
                si.flags.set(Flags::PARSE_ERROR);
            }
            si
        };
        // `RAW,ON`: every channel's reading as its compensator is given it (`$MCMRAW`)
        if let (true, Some(RawLine::One(shared))) = (n > 1, self.last_raw) {
            let mut raw = MultiRawSample {
                shared,
                channels: self.channels,
                mag: [None; MAX_CHANNELS],
                flags: [Flags(Flags::MAG_MISSING); MAX_CHANNELS],
            };
            for (i, c) in f.ch.iter().enumerate().take(n) {
                let si = channel_sample(c);
                (raw.mag[i], raw.flags[i]) = (si.mag, si.flags);
            }
            (raw.shared.mag, raw.shared.flags) = (raw.mag[0], raw.flags[0]);
            self.last_raw = Some(RawLine::Multi(raw));
        }
        let out0 = self.comp.push(&channel_sample(&f.ch[0]));
        let mut outs = [None; MAX_CHANNELS - 1];
        for (i, o) in outs.iter_mut().enumerate().take(n - 1) {
            *o = self.extra[i].push(&channel_sample(&f.ch[i + 1]));
        }
        Some(AcqRecord::Multi(self.multi_record(out0?, outs)))
    }

    /// `RAW,ON` / `RAW,OFF`: keep each scalar sample as a raw line for the output port
    /// (`protocol::raw`), so the flight's log is enough to calibrate after landing.
    pub fn set_raw_output(&mut self, on: bool) {
        self.raw_output = on;
        self.last_raw = None;
    }
    pub fn raw_output(&self) -> bool {
        self.raw_output
    }

    /// The raw line of the latest scalar sample, once (None with `RAW,OFF`): `$MCRAW`, or
    /// `$MCMRAW` with every channel when the counter sends 2–3.
    pub fn take_raw(&mut self) -> Option<RawLine> {
        self.last_raw.take()
    }

    /// The fluxgate's temperature correction (`fluxtemp`) applied to every frame.
    pub fn flux_temp_calibration(&self) -> FluxTempCal {
        self.cfg.flux_temp_cal
    }

    /// Applies a temperature correction to every frame from now on ([`FluxTempCal::NONE`]
    /// clears it). With one set, a frame without a temperature is `FLUX_STALE`.
    pub fn set_flux_temp_calibration(&mut self, cal: FluxTempCal) {
        self.cfg.flux_temp_cal = cal;
        self.flux_check.restart();
    }

    /// One byte from the fluxgate's serial ASCII port (sensor frame, nT; `X,Y,Z[,T]`).
    pub fn push_flux_byte(&mut self, b: u8) {
        if let Some(r) = self.flux.push_frame(b) {
            let cal = self.cfg.flux_cal;
            match r {
                Ok((v, t)) => self.flux_result_temp(Ok(cal.to_body(v)), t),
                Err(e) => self.flux_result(Err(e)),
            }
        }
    }

    /// One complete SPI frame from the fluxgate ADC (15 bytes, see `fluxgate`).
    pub fn push_flux_frame(&mut self, frame: &[u8]) {
        let r = decode_spi_frame(frame).map(|a| self.cfg.flux_cal.scale(a.counts));
        let c = if r.is_ok() {
            &mut self.flux_spi.ok
        } else {
            &mut self.flux_spi.errors
        };
        inc(c);
        self.flux_result(r);
    }

    /// A fluxgate vector already decoded and in the body frame (nT), or its error; no
    /// temperature (an SPI frame).
    pub fn flux_result(&mut self, r: Result<[f32; 3], FluxError>) {
        self.flux_result_temp(r, f32::NAN);
    }

    /// As [`flux_result`](Self::flux_result), with the sensor's temperature (°C, NaN if
    /// none). The temperature correction is applied here, per frame with its own T, so the
    /// aligner and the delay line hold and interpolate corrected vectors.
    pub fn flux_result_temp(&mut self, r: Result<[f32; 3], FluxError>, temp_degc: f32) {
        match r {
            Ok(raw) => {
                inc(&mut self.counters.flux_frames);
                // The frame's time on the board's clock, for every check and store below.
                let now = self.now_us();
                // Judged raw: a correction that mixes the axes or follows the temperature
                // would move a dead channel.
                let stuck = raw.iter().all(|x| x.is_finite())
                    && self.flux_stuck.judge(now as f64 * 1e-6, raw);
                let v = self.cfg.flux_temp_cal.apply(raw, temp_degc);
                if !v[0].is_finite() {
                    // A correction is set and this frame has no temperature: the frame
                    // counts (timing, lost-frame checks) but samples using it are FLUX_STALE.
                    self.aligner.push_flux_unusable(now);
                    if let Some(l) = self.lag_line.as_deref_mut() {
                        l.push(now, v);
                    }
                    return;
                }
                let v = if self.cfg.flux_scalar_cal.is_identity() {
                    v
                } else {
                    self.cfg.flux_scalar_cal.apply(v)
                };
                if v.iter().all(|x| x.is_finite())
                    && (self.flux_check.judge(now as f64 * 1e-6, v) == Continuity::Suspect
                        || stuck
                        || self.flux_disagrees_with_scalar(now, v))
                {
                    // Parsed but read wrong (an axis 0, a corrupted digit, a dead axis from
                    // power-up): as a frame without its temperature, it counts for timing,
                    // samples using it are FLUX_STALE.
                    inc(&mut self.counters.flux_suspect);
                    self.aligner.push_flux_unusable(now);
                    if let Some(l) = self.lag_line.as_deref_mut() {
                        l.push(now, [f32::NAN; 3]);
                    }
                    return;
                }
                if self.aligner.push_flux(now, v) {
                    if let Some(l) = self.lag_line.as_deref_mut() {
                        l.push(now, v);
                    }
                }
            }
            Err(_) => {
                inc(&mut self.counters.flux_errors);
                self.aligner.note_parse_error();
            }
        }
    }

    /// The frame `flux_nt` at `now_us` against the latest scalar value, when that is at
    /// most [`SCALAR_REFERENCE_MAX_AGE_US`] old (a silent scalar judges nothing).
    fn flux_disagrees_with_scalar(&self, now_us: u64, flux_nt: [f32; 3]) -> bool {
        self.last_scalar.is_some_and(|(t_us, scalar_nt)| {
            now_us.saturating_sub(t_us) <= SCALAR_REFERENCE_MAX_AGE_US
                && crate::continuity::flux_disagrees_with_scalar(flux_nt, scalar_nt)
        })
    }

    /// One byte from the GPS port.
    pub fn push_gps_byte(&mut self, b: u8) {
        if let Some(r) = self.nmea.push(b) {
            self.nmea_result(r);
        }
    }

    /// A sentence from an NMEA reader the caller runs itself, or its error. Unsupported
    /// sentence types are counted as sentences, not errors.
    pub fn nmea_result(&mut self, r: Result<Sentence, NmeaError>) {
        match r {
            Ok(s) => {
                inc(&mut self.counters.gps_sentences);
                let now = self.now_us();
                // GGA, GLL and GNS fixes set the time anchor (a GLL- or GNS-only
                // receiver still gives GPS time); RMC does not, as before.
                if !matches!(s, Sentence::Rmc(_)) {
                    if let Some(Fix { time: Some(t), .. }) = s.fix() {
                        self.last_fix = Some((t.seconds_of_day_s, now));
                    }
                }
                self.aligner.push_nmea(now, &s);
            }
            Err(_) => {
                inc(&mut self.counters.gps_errors);
                self.aligner.note_parse_error();
            }
        }
    }

    /// Dispatches a byte by port (`cmd`/`out` bytes are not sensor data: ignored).
    /// SPI fluxgate frames go through [`push_flux_frame`](Self::push_flux_frame).
    pub fn push_byte(&mut self, port: Port, b: u8) -> Option<Record> {
        match port {
            Port::Scalar => return self.push_scalar_byte(b),
            Port::Flux => self.push_flux_byte(b),
            Port::Gps => self.push_gps_byte(b),
            Port::Cmd | Port::Out => {}
        }
        None
    }

    /// A chunk of bytes from one port (a capture line); every record goes to `sink`, those
    /// of a line's further samples ([`owed_scalar_line`](Self::owed_scalar_line)) included.
    pub fn push_bytes(&mut self, port: Port, bytes: &[u8], mut sink: impl FnMut(Record)) {
        for &b in bytes {
            if let Some(r) = self.push_byte(port, b) {
                sink(r);
            }
            while let Some(ScalarLine::Single(r)) = self.owed_scalar_line() {
                if let Some(rec) = self.scalar_result(r) {
                    sink(rec);
                }
            }
        }
    }

    /// End of stream: the records still held for the centred derivative, one per call.
    /// A scalar line left unterminated is not a sample (its end never arrived).
    pub fn flush(&mut self) -> Option<Record> {
        let out = self.comp.flush();
        let witnessed = self.witness.is_some().then(|| self.extra[0].flush());
        let out = self.shown_output(out?, witnessed.flatten());
        Some(self.record(out))
    }

    /// [`flush`](Self::flush) for either kind of record: with counter lines, every channel's
    /// held samples together.
    pub fn flush_any(&mut self) -> Option<AcqRecord> {
        if self.channels == 1 {
            return self.flush().map(AcqRecord::One);
        }
        let out0 = self.comp.flush();
        let mut outs = [None; MAX_CHANNELS - 1];
        let n = usize::from(self.channels);
        for (i, o) in outs.iter_mut().enumerate().take(n - 1) {
            *o = self.extra[i].flush();
        }
        Some(AcqRecord::Multi(self.multi_record(out0?, outs)))
    }

    /// [`push_byte`](Self::push_byte) reading counter lines too.
    pub fn push_byte_any(&mut self, port: Port, b: u8) -> Option<AcqRecord> {
        match port {
            Port::Scalar => self.push_scalar_line_byte(b),
            _ => self.push_byte(port, b).map(AcqRecord::One),
        }
    }

    fn multi_record(
        &mut self,
        out0: crate::compensator::Output,
        outs: [Option<crate::compensator::Output>; MAX_CHANNELS - 1],
    ) -> MultiRecord {
        let one = |o: &crate::compensator::Output| ChannelRecord {
            mag: o.mag,
            interference_nt: o.interference_nt,
            compensated: o.compensated,
            sigma_nt: o.interference_sigma_nt,
            flags: o.flags,
        };
        let mut ch = [ChannelRecord::MISSING; MAX_CHANNELS];
        ch[0] = one(&out0);
        let mut flags = out0.flags;
        for (c, o) in ch[1..].iter_mut().zip(&outs) {
            if let Some(o) = o {
                *c = one(o);
            }
            flags = flags.union(c.flags);
        }
        // the counters count records, each flag when any channel carries it
        let seq = self.count_record(flags);
        MultiRecord::new(seq, out0.t_s, self.channels, ch)
    }

    /// The next sequence number, the record and its flags counted.
    fn count_record(&mut self, flags: Flags) -> u32 {
        let seq = self.seq;
        self.seq = self.seq.wrapping_add(1);
        let c = &mut self.counters;
        inc(&mut c.records);
        for (bit, n) in [
            (Flags::FLUX_STALE, &mut c.flux_stale),
            (Flags::NO_GPS, &mut c.no_gps),
            (Flags::MAG_MISSING, &mut c.mag_missing),
            (Flags::PARSE_ERROR, &mut c.parse_error),
        ] {
            if flags.contains(bit) {
                inc(n);
            }
        }
        seq
    }

    fn record(&mut self, o: crate::compensator::Output) -> Record {
        let seq = self.count_record(o.flags);
        Record {
            seq,
            t_s: o.t_s,
            mag: o.mag,
            interference_nt: o.interference_nt,
            compensated: o.compensated,
            anomaly_nt: o.anomaly_nt,
            innovation_nt: o.innovation_nt,
            sigma_nt: o.interference_sigma_nt,
            flags: o.flags,
        }
    }
}
