//! Epoch assembly: aligned samples → epochs with the direction cosines `e`, their derivative
//! `ė`, along-track step, height change and auxiliary channels, all at the scalar sample's
//! instant (model.md §5: a centred derivative delays the epoch, it must not skew it).

use crate::flags::Flags;
use crate::units::MagCounts;

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
        }
    }
}
