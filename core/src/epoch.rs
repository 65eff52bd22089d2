//! Epoch assembly: aligned samples → epochs with the direction cosines `e`, their derivative
//! `ė`, along-track step, height change and auxiliary channels, all at the scalar sample's
//! instant (model.md §5: a centred derivative delays the epoch, it must not skew it).

use crate::flags::Flags;
use crate::model::B_STAR_NT;
use crate::units::{MagCounts, COUNTS_PER_NT};

/// Number of auxiliary channels an epoch carries (currents, voltages, rpm, base station...).
pub const MAX_AUX: usize = 8;

/// One scalar-magnetometer sample with everything else interpolated or held to its instant.
/// Produced from a trace row on the host, or by the sensor aligner on the board.
/// Missing values are NaN (f32/f64) or `None`, never zero.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AlignedSample {
    /// Sample time (s): GPS seconds or seconds since start.
    pub t_s: f64,
    /// Absolute scalar reading, exact; `None` when the sample is missing or invalid.
    pub mag: Option<MagCounts>,
    /// Fluxgate vector in the body frame (x forward, y starboard, z down), nT.
    pub flux_nt: [f32; 3],
    /// WGS-84 position of the scalar sensor (deg); NaN when unknown.
    pub lat_deg: f64,
    pub lon_deg: f64,
    /// Height of the scalar sensor (m); NaN when unknown.
    pub alt_m: f32,
    /// Ground speed (m/s) from GPS/INS; NaN → derived from position differences.
    pub ground_speed_mps: f32,
    /// INS attitude roll, pitch, yaw (deg); NaN when the aircraft has no INS.
    pub attitude_deg: [f32; 3],
    /// Auxiliary channels in the order the model was told (NaN when missing).
    pub aux: [f32; MAX_AUX],
    /// Flags set upstream (stale fluxgate, no GPS fix, parser errors).
    pub flags: Flags,
    /// Core-field model value (IGRF) at the sample (nT), NaN if unknown. Its change since
    /// the first sample is removed from the scalar before the filter sees it, as survey
    /// processing always does: the main-field gradient is not the anomaly.
    pub igrf_nt: f64,
    /// External (diurnal) field from a base station, relative to its first value (nT);
    /// NaN if none. Used to tie revisited points across time, not subtracted.
    pub base_nt: f32,
}

impl AlignedSample {
    pub const fn empty(t_s: f64) -> Self {
        Self {
            t_s,
            mag: None,
            flux_nt: [f32::NAN; 3],
            lat_deg: f64::NAN,
            lon_deg: f64::NAN,
            alt_m: f32::NAN,
            ground_speed_mps: f32::NAN,
            attitude_deg: [f32::NAN; 3],
            aux: [f32::NAN; MAX_AUX],
            flags: Flags::empty(),
            igrf_nt: f64::NAN,
            base_nt: f32::NAN,
        }
    }
}

/// `a − b` in nT, the same value as [`MagCounts::diff_nt`] without soft-float f64 on the M4
/// in the usual case: below 2^24 counts (1677 nT) the difference converts to f32 exactly and
/// one correctly rounded f32 division gives the correctly rounded quotient, which the f64
/// path also gives (its f64 quotient cannot fall on an f32 rounding midpoint).
pub(crate) fn diff_nt(a: MagCounts, b: MagCounts) -> f32 {
    let d = a.0 - b.0;
    if d.unsigned_abs() < 1 << 24 {
        (d as i32) as f32 / COUNTS_PER_NT as f32
    } else {
        a.diff_nt(b)
    }
}

/// `(a − b) as f32` for f64 times without soft-float f64 on the M4 where both are positive
/// with the same exponent (all but the pairs across a power of two): the difference is
/// then the integer `d` of their bit patterns times the exponent's unit `2^k`, which the
/// f64 subtraction returns exactly, and the conversion rounds once to f32. Here `|d|` is
/// rounded to 24 bits by the FPU's u32 conversion (from its top 31 bits and a sticky bit
/// for the rest when it is longer: the same rounding) and scaled exactly by `2^k` (kept in
/// f32's normal range). Anything else takes the f64 path.
pub(crate) fn diff_f32(a: f64, b: f64) -> f32 {
    let (ia, ib) = (a.to_bits(), b.to_bits());
    // sign and exponent: equal, positive, 2^k and |d|·2^k (|d| < 2^52) normal f32
    let e = (ia >> 52) as u32;
    if e != (ib >> 52) as u32 || !(1075 - 126..=1075 + 60).contains(&e) {
        return (a - b) as f32;
    }
    let d = ia as i64 - ib as i64;
    let u = d.unsigned_abs();
    let v = if u >> 31 == 0 {
        u as u32 as f32
    } else {
        let s = 33 - u.leading_zeros(); // u >> s has 31 bits
        let sticky = u32::from(u & ((1 << s) - 1) != 0);
        ((u >> s) as u32 | sticky) as f32 * f32::from_bits((127 + s) << 23)
    };
    let v = if d < 0 { -v } else { v };
    v * f32::from_bits((e + 127 - 1075) << 23)
}

/// `counts / (COUNTS_PER_NT · B*)` as f32.
const FIELD_RATIO_PER_COUNT: f64 = 1.0 / (COUNTS_PER_NT as f64 * B_STAR_NT);

/// `(m as f64 · FIELD_RATIO_PER_COUNT) as f32` — the f64 product rounded to 53 bits, then to
/// 24 — by integers, exactly (no soft-float multiply and conversions on the M4), for counts
/// in [2^21, 2^32) (210 to 429 000 nT); anything else takes the f64 path.
pub(crate) fn field_ratio(m: i64) -> f32 {
    const BITS: u64 = FIELD_RATIO_PER_COUNT.to_bits();
    const MANT: u64 = (BITS & ((1 << 52) - 1)) | (1 << 52);
    const EXP: i32 = (BITS >> 52) as i32 - 1075;
    /// `x / 2^s` rounded to nearest, ties to even (1 ≤ s < 64).
    fn shift_round(x: u64, s: u32) -> u64 {
        let (q, rem, half) = (x >> s, x & ((1 << s) - 1), 1u64 << (s - 1));
        q + u64::from(rem > half || (rem == half && q & 1 == 1))
    }
    if !(1 << 21..1 << 32).contains(&m) {
        return (m as f64 * FIELD_RATIO_PER_COUNT) as f32;
    }
    // the exact product m·MANT in [2^73, 2^85), as hi·2^32 + lo
    let a = (m as u64) * (MANT & 0xffff_ffff);
    let hi = (m as u64) * (MANT >> 32) + (a >> 32);
    let lo = a & 0xffff_ffff;
    // rounded to 53 bits: the low r bits dropped, 21 ≤ r ≤ 32, so all from `lo`
    let r = 64 - hi.leading_zeros() - 21;
    let q = (hi << (32 - r)) | (lo >> r);
    let (rem, half) = (lo & ((1 << r) - 1), 1 << (r - 1));
    let t53 = q + u64::from(rem > half || (rem == half && q & 1 == 1));
    // then to 24 bits (t53 ≤ 2^53, so t24 ≤ 2^24: exact in f32), scaled by a power of two
    let t24 = shift_round(t53, 29);
    t24 as u32 as f32 * f32::from_bits(((r as i32 + 29 + EXP + 127) as u32) << 23)
}

/// Mean Earth radius for the local flat-Earth conversion of position steps (m): the one
/// the host's flight positions and captures use too.
pub const EARTH_RADIUS_M: f64 = 6_371_000.0;
/// Re-reference when the field drifts this far from the reference, keeping f32 resolution
/// below 1e-4 nT at any value the filter sees (f32 ULP at 4096 nT is ~0.0005 nT).
const REREFERENCE_LIMIT_NT: f32 = 2000.0;

/// Everything the model terms need at one scalar-sample instant.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Epoch {
    pub t_s: f64,
    /// Absolute scalar reading (exact), `None` if missing.
    pub mag: Option<MagCounts>,
    /// The exact reference subtracted from `mag` to form `dmag_nt`.
    pub reference: MagCounts,
    /// `mag − reference` (nT), NaN if missing.
    pub dmag_nt: f32,
    /// Time derivative of the scalar reading (nT/s), centred.
    pub dmag_dt_nt_per_s: f32,
    /// `|B| / 50 000 nT`: induced and eddy regressors are multiplied by it so one set of
    /// coefficients holds in another field strength (model.md §2).
    pub field_ratio: f32,
    /// Fluxgate modulus minus the scalar reading (nT), NaN when either is missing. The
    /// Earth's field cancels; what is left is the aircraft's field at the fluxgate (and the
    /// fluxgate's own errors) against that at the scalar sensor (`fluxmod` term).
    pub flux_excess_nt: f32,
    /// Direction cosines of the field in the body frame, from the fluxgate.
    pub e: [f32; 3],
    /// Their time derivative (1/s), centred on this instant.
    pub e_dot_per_s: [f32; 3],
    /// Field direction predicted from INS attitude and the main-field direction (NaN if
    /// unavailable): lets a model see fluxgate calibration errors.
    pub e_ref: [f32; 3],
    /// Time since the previous epoch (s) and along-track distance covered (m).
    pub dt_s: f32,
    pub ds_m: f32,
    pub speed_mps: f32,
    /// The ground speed the GNSS/INS reported for this sample (m/s; NaN when none): unlike
    /// `speed_mps` never derived from held positions, so it can tell a parked aircraft.
    pub reported_speed_mps: f32,
    /// Height above the reference height `h0` (m).
    pub dh_m: f32,
    /// Local horizontal position relative to the first fix (m).
    pub north_m: f32,
    pub east_m: f32,
    pub aux: [f32; MAX_AUX],
    /// Centred time derivative of each aux channel (unit/s).
    pub aux_dot: [f32; MAX_AUX],
    /// Fractional cycles of `∫ aux/60 dt` (an rpm channel's rotation phase, in [0, 1)).
    pub aux_cycles: [f32; MAX_AUX],
    /// Base-station external field (nT, relative), NaN if none.
    pub base_nt: f32,
    pub flags: Flags,
    /// The fluxgate behind this epoch's direction or its derivative was held across a lost
    /// frame or stale: the regressors may be off by the field's change over the gap, so
    /// the filter predicts with them but does not learn from them. (A one-sided
    /// derivative at a flight's ends is flagged `DERIVATIVE_DEGRADED` but not suspect.)
    pub regressors_suspect: bool,
}

/// What `push` needs of the previous sample.
#[derive(Clone, Copy)]
struct Prev {
    t_s: f64,
    north_m: f64,
    east_m: f64,
    north_f32: f32,
    east_f32: f32,
    aux: [f32; MAX_AUX],
}

/// The last fix's local position per coordinate, keyed by the coordinate's bits: the board
/// holds a GNSS fix (1–10 Hz) across the scalar samples in between, and an unchanged
/// coordinate gives the same metres (f64 is soft-float on the M4, ~150 instructions a
/// coordinate with the f32 conversion).
#[derive(Clone, Copy, Debug)]
struct LocalPosition {
    lat_bits: u64,
    north_m: f64,
    north_f32: f32,
    lon_bits: u64,
    east_m: f64,
    east_f32: f32,
}

impl LocalPosition {
    /// Matches no finite coordinate.
    const NONE: Self = Self {
        lat_bits: u64::MAX,
        north_m: 0.0,
        north_f32: 0.0,
        lon_bits: u64::MAX,
        east_m: 0.0,
        east_f32: 0.0,
    };
}

#[derive(Clone, Copy, Debug)]
struct Slot {
    s: AlignedSample,
    e: [f32; 3],
    e_valid: bool,
    flux_norm_nt: f32,
    dt_s: f32,
    ds_m: f32,
    north_m: f64,
    east_m: f64,
    /// `north_m`, `east_m` and the aux channels' cycles as the epoch carries them (f32).
    north_f32: f32,
    east_f32: f32,
    aux_cycles: [f32; MAX_AUX],
    /// The aux channels that are finite (bit k: channel k).
    aux_finite: u8,
}

/// Configuration of the epoch builder.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EpochConfig {
    /// Half-width of the centred derivative in samples (≥ 1); the epoch for sample k is
    /// emitted when sample k + half_width arrives.
    pub half_width: usize,
    /// Main-field direction in NED (unit vector), for `e_ref`; `None` if unknown.
    pub earth_dir_ned: Option<[f32; 3]>,
    /// Reference height `h0` (m); `None` → the first valid height.
    pub h0_m: Option<f32>,
}

impl EpochConfig {
    /// A derivative spanning about ±0.05 s, so ė has comparable noise at 10 Hz and 1 kHz.
    pub fn for_rate(sample_rate_hz: f32) -> Self {
        let hw = libm::roundf(0.05 * sample_rate_hz.max(1.0)) as usize;
        Self {
            half_width: hw.max(1),
            earth_dir_ned: None,
            h0_m: None,
        }
    }
}

/// Turns aligned samples into epochs, one per sample, delayed by `half_width` samples.
/// `W` is the ring capacity and must be ≥ 2·half_width + 1.
#[derive(Clone, Debug)]
pub struct EpochBuilder<const W: usize> {
    cfg: EpochConfig,
    ring: [Option<Slot>; W],
    /// Index (sample number) of the next sample to push and the next epoch to emit.
    pushed: u64,
    emitted: u64,
    reference: Option<MagCounts>,
    h0_m: Option<f32>,
    /// First fix and its metres per degree north and east: `(lat0, lon0, k_north, k_east)`.
    origin: Option<(f64, f64, f64, f64)>,
    position: LocalPosition,
    last_e: Option<[f32; 3]>,
    last_cycles: [f64; MAX_AUX],
    /// Aux channels integrated since the start (bit k: channel k); the others' cycles are
    /// still exactly 0.
    integrated: u8,
    igrf0_nt: Option<f64>,
}

impl<const W: usize> EpochBuilder<W> {
    /// `None` when the window does not fit the ring.
    pub fn new(cfg: EpochConfig) -> Option<Self> {
        if cfg.half_width == 0 || 2 * cfg.half_width + 1 > W {
            return None;
        }
        Some(Self {
            cfg,
            ring: [None; W],
            pushed: 0,
            emitted: 0,
            reference: None,
            h0_m: cfg.h0_m,
            origin: None,
            position: LocalPosition::NONE,
            last_e: None,
            last_cycles: [0.0; MAX_AUX],
            integrated: 0,
            igrf0_nt: None,
        })
    }

    pub fn config(&self) -> &EpochConfig {
        &self.cfg
    }

    /// Current reference height `h0` (m), once known.
    pub fn h0_m(&self) -> Option<f32> {
        self.h0_m
    }

    /// Moves the reference height by `delta_m` for every epoch emitted from now on (the
    /// compensator re-anchors `h0` near the flown height and re-expresses `B_h` exactly).
    pub fn shift_h0(&mut self, delta_m: f32) {
        if let Some(h0) = self.h0_m.as_mut() {
            *h0 += delta_m;
        }
    }

    /// Number of samples pushed but not yet emitted.
    pub fn pending(&self) -> usize {
        (self.pushed - self.emitted) as usize
    }

    fn slot(&self, k: u64) -> Option<&Slot> {
        self.ring[(k % W as u64) as usize].as_ref()
    }

    /// Local (north, east) metres of a position relative to the first fix; `None` before it.
    pub fn local_position(&self, lat_deg: f64, lon_deg: f64) -> Option<(f32, f32)> {
        let (lat0, lon0, k_north, k_east) = self.origin?;
        Some((
            ((lat_deg - lat0) * k_north) as f32,
            ((lon_deg - lon0) * k_east) as f32,
        ))
    }

    /// Adds a sample; returns the epoch of the sample `half_width` back, if any.
    pub fn push(&mut self, s: &AlignedSample) -> Option<Epoch> {
        // Only the previous sample's time, position and aux values are needed: a `Slot` is
        // ~250 bytes, copying it whole cost more than the arithmetic below.
        let prev = if self.pushed > 0 {
            self.slot(self.pushed - 1).map(|p| Prev {
                t_s: p.s.t_s,
                north_m: p.north_m,
                east_m: p.east_m,
                north_f32: p.north_f32,
                east_f32: p.east_f32,
                aux: p.s.aux,
            })
        } else {
            None
        };
        let flux = s.flux_nt;
        let norm = libm::sqrtf(flux[0] * flux[0] + flux[1] * flux[1] + flux[2] * flux[2]);
        let (e, e_valid) = if norm.is_finite() && norm > 1.0 {
            let e = [flux[0] / norm, flux[1] / norm, flux[2] / norm];
            self.last_e = Some(e);
            (e, true)
        } else {
            (self.last_e.unwrap_or([1.0, 0.0, 0.0]), false)
        };
        // Local position (f64: lat/lon need it), origin at the first fix. The metres per
        // degree are formed once: f64 is soft-float on the M4 (~100 instructions a multiply).
        let (north_m, east_m, north_f32, east_f32) =
            if s.lat_deg.is_finite() && s.lon_deg.is_finite() {
                let (lat0, lon0, k_north, k_east) = *self.origin.get_or_insert_with(|| {
                    let k_north = EARTH_RADIUS_M * (core::f64::consts::PI / 180.0);
                    let coslat0 = libm::cos(s.lat_deg.to_radians());
                    (s.lat_deg, s.lon_deg, k_north, k_north * coslat0)
                });
                let c = &mut self.position;
                if s.lat_deg.to_bits() != c.lat_bits {
                    c.lat_bits = s.lat_deg.to_bits();
                    c.north_m = (s.lat_deg - lat0) * k_north;
                    c.north_f32 = c.north_m as f32;
                }
                if s.lon_deg.to_bits() != c.lon_bits {
                    c.lon_bits = s.lon_deg.to_bits();
                    c.east_m = (s.lon_deg - lon0) * k_east;
                    c.east_f32 = c.east_m as f32;
                }
                (c.north_m, c.east_m, c.north_f32, c.east_f32)
            } else {
                prev.map(|p| (p.north_m, p.east_m, p.north_f32, p.east_f32))
                    .unwrap_or((0.0, 0.0, 0.0, 0.0))
            };
        let (dt_s, ds_m) = match prev {
            Some(p) => {
                let dt = diff_f32(s.t_s, p.t_s);
                let dt = if dt.is_finite() && dt > 0.0 { dt } else { 0.0 };
                let ds = if s.ground_speed_mps.is_finite() {
                    s.ground_speed_mps.abs() * dt
                } else {
                    let dn = north_m - p.north_m;
                    let de = east_m - p.east_m;
                    libm::sqrt(dn * dn + de * de) as f32
                };
                (dt, if ds.is_finite() { ds } else { 0.0 })
            }
            None => (0.0, 0.0),
        };
        // Rotation phase by the trapezoid rule: the rectangle rule drifts by up to ~15° per
        // sample at 10 Hz when the rpm changes.
        let mut aux_finite = 0u8;
        for (k, a) in s.aux.iter().enumerate() {
            aux_finite |= u8::from(a.is_finite()) << k;
        }
        let mut cycles = self.last_cycles;
        for (k, (c, a)) in cycles.iter_mut().zip(s.aux.iter()).enumerate() {
            if aux_finite & (1 << k) != 0 {
                let prev_a = prev
                    .as_ref()
                    .map(|p| p.aux[k])
                    .filter(|v| v.is_finite())
                    .unwrap_or(*a);
                *c += 0.5 * (*a as f64 + prev_a as f64) / 60.0 * dt_s as f64;
                *c -= libm::floor(*c);
                self.integrated |= 1 << k;
            }
        }
        self.last_cycles = cycles;
        // channels never integrated hold exactly 0: no soft-float conversion for them
        let mut aux_cycles = [0.0f32; MAX_AUX];
        if self.integrated != 0 {
            for (k, (o, v)) in aux_cycles.iter_mut().zip(cycles.iter()).enumerate() {
                if self.integrated & (1 << k) != 0 {
                    *o = *v as f32;
                }
            }
        }
        if self.h0_m.is_none() && s.alt_m.is_finite() {
            self.h0_m = Some(s.alt_m);
        }
        let idx = (self.pushed % W as u64) as usize;
        self.ring[idx] = Some(Slot {
            s: *s,
            e,
            e_valid,
            flux_norm_nt: if e_valid { norm } else { f32::NAN },
            dt_s,
            ds_m,
            north_m,
            east_m,
            north_f32,
            east_f32,
            aux_cycles,
            aux_finite,
        });
        self.pushed += 1;
        if self.pushed - self.emitted > self.cfg.half_width as u64 {
            self.emit()
        } else {
            None
        }
    }

    /// Emits the next pending epoch with a one-sided derivative (end of stream).
    pub fn flush(&mut self) -> Option<Epoch> {
        if self.emitted < self.pushed {
            self.emit()
        } else {
            None
        }
    }

    fn emit(&mut self) -> Option<Epoch> {
        let k = self.emitted;
        let hw = self.cfg.half_width as u64;
        let lo = k.saturating_sub(hw);
        let hi = (k + hw).min(self.pushed - 1);
        self.emitted += 1;
        // By reference: three `Slot` copies per epoch were a large part of its cost.
        let ring = &self.ring;
        let at = |k: u64| ring[(k % W as u64) as usize].as_ref();
        let c = at(k)?;
        let a = at(lo)?;
        let b = at(hi)?;
        let mut flags = c.s.flags;
        // Ends of the derivative (and the sample itself) interpolated across a lost
        // fluxgate frame (the aligner flags such a sample) or held past the staleness limit.
        let held = Flags::DERIVATIVE_DEGRADED | Flags::FLUX_STALE;
        let ends_suspect = (a.s.flags.0 | b.s.flags.0) & held != 0 || !a.e_valid || !b.e_valid;
        let regressors_suspect = ends_suspect || c.s.flags.0 & held != 0 || !c.e_valid;
        // A one-sided derivative at the ends, or one across a held frame.
        if lo + hw != k || hi != k + hw || ends_suspect {
            flags.set(Flags::DERIVATIVE_DEGRADED);
        }
        if !c.e_valid {
            flags.set(Flags::FLUX_STALE);
        }
        let span_s = diff_f32(b.s.t_s, a.s.t_s);
        let inv_span = if span_s > 0.0 { 1.0 / span_s } else { 0.0 };
        let mut e_dot = [0.0f32; 3];
        for (i, v) in e_dot.iter_mut().enumerate() {
            *v = (b.e[i] - a.e[i]) * inv_span;
        }
        // NaN wherever either end is not finite (the difference is not then either)
        let mut aux_dot = [f32::NAN; MAX_AUX];
        let both = a.aux_finite & b.aux_finite;
        if both != 0 {
            for (i, v) in aux_dot.iter_mut().enumerate() {
                let d = (b.s.aux[i] - a.s.aux[i]) * inv_span;
                *v = if d.is_finite() { d } else { f32::NAN };
            }
        }
        // Exact reference handling: differences of integer counts, never of f32 values.
        let core_delta_nt = if c.s.igrf_nt.is_finite() {
            let i0 = *self.igrf0_nt.get_or_insert(c.s.igrf_nt);
            (c.s.igrf_nt - i0) as f32
        } else {
            0.0
        };
        let mut dmag_nt = f32::NAN;
        if let Some(m) = c.s.mag {
            let r = *self.reference.get_or_insert(m);
            let d = diff_nt(m, r) - core_delta_nt;
            if d.abs() > REREFERENCE_LIMIT_NT {
                // New exact reference such that the residual core delta stays continuous.
                let r = m.minus_nt(core_delta_nt);
                self.reference = Some(r);
                dmag_nt = m.diff_nt(r) - core_delta_nt;
            } else {
                dmag_nt = d;
            }
        } else {
            flags.set(Flags::MAG_MISSING);
        }
        let reference = self.reference.unwrap_or_default();
        let dmag_dt = match (a.s.mag, b.s.mag) {
            (Some(ma), Some(mb)) if span_s > 0.0 => diff_nt(mb, ma) * inv_span,
            _ => 0.0,
        };
        // Without a scalar value the last reference stands in for |B| (within the
        // re-referencing limit of it), not B*: at 1.0 the induced and eddy regressors of a
        // missing sample were 6 % off at 53 000 nT, and its interference 0.1 nT off on a
        // simulated calibration (1 % missing samples tripled the flight's error figure).
        let field_counts = c.s.mag.or(self.reference).map(|m| m.0);
        let field_ratio = match field_counts {
            // one f64 multiply instead of two divisions (counts → nT → ratio), its value
            // formed by integers on the usual path (`field_ratio`)
            Some(m) => field_ratio(m),
            None => 1.0,
        };
        // f32 is enough here: the fluxgate's own noise (0.1–2 nT) dwarfs the 0.004 nT ULP.
        let flux_excess_nt = if c.s.mag.is_some() {
            c.flux_norm_nt - field_ratio * B_STAR_NT as f32
        } else {
            f32::NAN
        };
        let dh_m = match (self.h0_m, c.s.alt_m.is_finite()) {
            (Some(h0), true) => c.s.alt_m - h0,
            _ => 0.0,
        };
        let speed = if c.dt_s > 0.0 { c.ds_m / c.dt_s } else { 0.0 };
        Some(Epoch {
            t_s: c.s.t_s,
            mag: c.s.mag,
            reference,
            dmag_nt,
            dmag_dt_nt_per_s: dmag_dt,
            field_ratio,
            flux_excess_nt,
            e: c.e,
            e_dot_per_s: e_dot,
            e_ref: self.e_ref(&c.s.attitude_deg),
            dt_s: c.dt_s,
            ds_m: c.ds_m,
            speed_mps: speed,
            reported_speed_mps: c.s.ground_speed_mps,
            dh_m,
            north_m: c.north_f32,
            east_m: c.east_f32,
            aux: c.s.aux,
            aux_dot,
            aux_cycles: c.aux_cycles,
            base_nt: c.s.base_nt,
            flags,
            regressors_suspect,
        })
    }

    /// Body-frame field direction from INS attitude: `e = R_nbᵀ·e_ned` (ZYX Euler angles).
    fn e_ref(&self, att_deg: &[f32; 3]) -> [f32; 3] {
        let Some(en) = self.cfg.earth_dir_ned else {
            return [f32::NAN; 3];
        };
        if !att_deg.iter().all(|a| a.is_finite()) {
            return [f32::NAN; 3];
        }
        let (sr, cr) = libm::sincosf(att_deg[0].to_radians());
        let (sp, cp) = libm::sincosf(att_deg[1].to_radians());
        let (sy, cy) = libm::sincosf(att_deg[2].to_radians());
        // Rows of R_bn (NED → body).
        let r = [
            [cp * cy, cp * sy, -sp],
            [sr * sp * cy - cr * sy, sr * sp * sy + cr * cy, sr * cp],
            [cr * sp * cy + sr * sy, cr * sp * sy - sr * cy, cr * cp],
        ];
        let mut e = [0.0f32; 3];
        for (i, row) in r.iter().enumerate() {
            e[i] = row[0] * en[0] + row[1] * en[1] + row[2] * en[2];
        }
        e
    }
}

/// In-place (re)initialisation, so a board can keep the builder in a `static` and restart
/// it without building a second ring on the stack.
impl<const W: usize> EpochBuilder<W> {
    /// An empty builder (half-width 1), usable in a `static` initialiser; call
    /// [`reset`](Self::reset) with the real configuration before use.
    pub const fn empty() -> Self {
        Self {
            cfg: EpochConfig {
                half_width: 1,
                earth_dir_ned: None,
                h0_m: None,
            },
            ring: [None; W],
            pushed: 0,
            emitted: 0,
            reference: None,
            h0_m: None,
            origin: None,
            position: LocalPosition::NONE,
            last_e: None,
            last_cycles: [0.0; MAX_AUX],
            integrated: 0,
            igrf0_nt: None,
        }
    }

    /// Re-initialises in place to exactly what [`new`](Self::new) builds from `cfg`.
    /// Returns false, leaving the builder unchanged, where `new` returns `None`.
    pub fn reset(&mut self, cfg: EpochConfig) -> bool {
        if cfg.half_width == 0 || 2 * cfg.half_width + 1 > W {
            return false;
        }
        self.cfg = cfg;
        self.ring.fill(None);
        self.pushed = 0;
        self.emitted = 0;
        self.reference = None;
        self.h0_m = cfg.h0_m;
        self.origin = None;
        self.position = LocalPosition::NONE;
        self.last_e = None;
        self.last_cycles = [0.0; MAX_AUX];
        self.integrated = 0;
        self.igrf0_nt = None;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::{diff_f32, diff_nt, field_ratio, FIELD_RATIO_PER_COUNT};
    use crate::units::MagCounts;

    #[test]
    fn integer_field_ratio_equals_the_f64_path() {
        let check = |m: i64| {
            let (x, y) = (field_ratio(m), (m as f64 * FIELD_RATIO_PER_COUNT) as f32);
            assert!(x.to_bits() == y.to_bits(), "{m}: {x:e} against {y:e}");
        };
        // every count of 49 000-51 000 nT, sampled steps elsewhere, the range's ends, and
        // the f64 fallback outside it
        for m in 490_000_000..510_000_000 {
            check(m);
        }
        let mut m = 1i64;
        while m < 1 << 40 {
            for v in [m - 1, m, m + 1, -m] {
                check(v);
            }
            m = m * 1_000_003 / 1_000_000 + 1;
        }
        for m in [
            0,
            i64::MIN,
            i64::MAX,
            (1 << 21) - 1,
            1 << 21,
            (1 << 32) - 1,
            1 << 32,
        ] {
            check(m);
        }
    }

    #[test]
    fn fast_time_difference_equals_the_f64_path() {
        let check = |a: f64, b: f64| {
            let (x, y) = (diff_f32(a, b), (a - b) as f32);
            assert!(
                x.to_bits() == y.to_bits(),
                "{a:e} - {b:e}: {x:e} against {y:e}"
            );
        };
        // sample times at 10 Hz to 2 kHz, jittered, across powers of two, and far apart
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for base in [
            0.0, 0.37, 1.0, 2.0, 1023.9, 43_200.0, 65_535.95, 1.7e9, 3.1e13,
        ] {
            for _ in 0..20_000 {
                let r = next();
                let a = base + (r % 1_000_000) as f64 * 1e-4;
                let dt = [1e-3, 5e-4, 0.1, 0.1000001, 1.0, 3.0][(r >> 32) as usize % 6];
                let b = a - dt * ((r >> 40) % 4) as f64 + ((r >> 48) % 7) as f64 * 1e-9;
                check(a, b);
                check(b, a);
                check(a, a);
            }
        }
        // random bit patterns: every exponent pair, signs, zeros, subnormals, NaN and ∞
        for _ in 0..200_000 {
            let a = f64::from_bits(next());
            let b = f64::from_bits((a.to_bits() & !0xffff_ffff) ^ (next() >> 40));
            for (x, y) in [(a, b), (b, a), (a, f64::from_bits(next()))] {
                let (u, v) = (diff_f32(x, y), (x - y) as f32);
                assert!(
                    u.to_bits() == v.to_bits() || (u.is_nan() && v.is_nan()),
                    "{x:e} {y:e}"
                );
            }
        }
        for (a, b) in [
            (f64::NAN, 1.0),
            (f64::INFINITY, 1.0),
            (0.0, 0.0),
            (-1.0, -1.5),
        ] {
            let (u, v) = (diff_f32(a, b), (a - b) as f32);
            assert!(u.to_bits() == v.to_bits() || (u.is_nan() && v.is_nan()));
        }
    }

    #[test]
    fn fast_diff_equals_the_f64_path() {
        let r = MagCounts(523_456_789);
        let check = |d: i64| {
            let m = MagCounts(r.0 + d);
            assert_eq!(diff_nt(m, r).to_bits(), m.diff_nt(r).to_bits(), "d = {d}");
        };
        for d in -(1 << 18)..(1 << 18) {
            check(d);
        }
        // the rest of the f32 range sampled, and the f64 fallback beyond it
        let mut d = 1i64 << 18;
        while d < 1 << 26 {
            for v in [d, -d, d + 1, -d - 7] {
                check(v);
            }
            d += 997;
        }
    }
}
