//! Positions no aircraft can have: out of range, not finite, or a jump no aircraft can
//! fly. Such a position is treated as missing for its sample, which is flagged `NO_GPS`
//! (the core's flag for "no usable fix: position held"), so that nothing downstream —
//! the along-track distance, the σ1 spectrum, crossovers, the tie point — ever sizes a
//! grid or a loop by a bad coordinate. The sample itself is kept (one output row per
//! input row).

use crate::io::trace::RowOrigin;
use magcomp_core::epoch::EARTH_RADIUS_M;
use magcomp_core::{AlignedSample, Flags};

/// Fastest ground speed accepted between consecutive fixes (m/s): above any survey or
/// calibration aircraft (a jet at Mach 1 flies ~340 m/s).
pub const MAX_SPEED_MPS: f64 = 400.0;
/// GNSS noise allowance (m) on top of speed × time, so that fix scatter between two close
/// samples is never a "jump".
const JUMP_SLACK_M: f64 = 50.0;
/// Heights accepted (m): below the Dead Sea shore's −430 m with margin, above any aircraft.
pub const ALT_RANGE_M: (f64, f64) = (-1000.0, 100_000.0);
/// Consecutive refused fixes that agree with each other after which the track is taken to
/// have really moved (e.g. a receiver that re-acquired with a new datum) and they are
/// accepted again: a bad value is one or a few samples, a real step is permanent.
const REANCHOR_FIXES: usize = 5;

/// Why a sample's position was not used.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PositionFault {
    /// |lat| > 90° or not finite while lon is given (value).
    Lat(f64),
    /// |lon| > 180° or not finite while lat is given.
    Lon(f64),
    /// Height outside [`ALT_RANGE_M`] (only the height is dropped).
    Alt(f64),
    /// The fix implies this speed (m/s) from the last accepted one.
    Jump { speed_mps: f64 },
}

impl std::fmt::Display for PositionFault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Lat(v) => write!(f, "lat = {v} is not a latitude (|lat| ≤ 90°)"),
            Self::Lon(v) => write!(f, "lon = {v} is not a longitude (|lon| ≤ 180°)"),
            Self::Alt(v) => write!(
                f,
                "alt = {v} m is outside {} … {} m",
                ALT_RANGE_M.0, ALT_RANGE_M.1
            ),
            Self::Jump { speed_mps } => write!(
                f,
                "the position jumps at {speed_mps:.0} m/s from the previous fix (> {MAX_SPEED_MPS} m/s)"
            ),
        }
    }
}

/// Great-circle-free distance (m) between two fixes: flat earth at their mean latitude,
/// longitude difference wrapped so that crossing ±180° is not a jump.
pub fn flat_distance_m(a: (f64, f64), b: (f64, f64)) -> f64 {
    let dlon = (b.1 - a.1 + 540.0).rem_euclid(360.0) - 180.0;
    let dn = (b.0 - a.0).to_radians() * EARTH_RADIUS_M;
    let de = dlon.to_radians() * EARTH_RADIUS_M * (0.5 * (a.0 + b.0)).to_radians().cos();
    dn.hypot(de)
}

/// Checks every sample's position in place (one pass, constant memory besides the
/// result): a position out of range or jumping is set to NaN and the sample flagged
/// `NO_GPS`; a height out of range is set to NaN and flagged likewise; a sample without a
/// position is flagged `NO_GPS` too. Returns the refused values by row.
pub fn check_positions(samples: &mut [AlignedSample]) -> Vec<(usize, PositionFault)> {
    let mut checker = PositionChecker::default();
    let mut faults = Vec::new();
    for (i, s) in samples.iter_mut().enumerate() {
        checker.check(s, |f| faults.push((i, f)));
    }
    faults
}

/// [`check_positions`] one sample at a time (the streaming `compensate` checks each row
/// as it is read): the last accepted fix and the run of refused jumps that agree with
/// each other.
#[derive(Clone, Debug, Default)]
pub struct PositionChecker {
    last: Option<(f64, f64, f64)>,
    run: (usize, Option<(f64, f64, f64)>),
}

impl PositionChecker {
    /// Checks `s` in place; `fault` is called for each refused value (a height and a
    /// position may both be refused).
    pub fn check(&mut self, s: &mut AlignedSample, mut fault: impl FnMut(PositionFault)) {
        let plausible = |from: (f64, f64, f64), to: (f64, f64, f64)| -> (bool, f64) {
            let dt = (to.0 - from.0).abs();
            let d = flat_distance_m((from.1, from.2), (to.1, to.2));
            (
                d <= MAX_SPEED_MPS * dt + JUMP_SLACK_M,
                if dt > 0.0 { d / dt } else { f64::INFINITY },
            )
        };
        let alt = f64::from(s.alt_m);
        if !alt.is_nan() && !(ALT_RANGE_M.0..=ALT_RANGE_M.1).contains(&alt) {
            fault(PositionFault::Alt(alt));
            s.alt_m = f32::NAN;
            s.flags.set(Flags::NO_GPS);
        }
        let (lat, lon) = (s.lat_deg, s.lon_deg);
        if lat.is_nan() && lon.is_nan() {
            s.flags.set(Flags::NO_GPS);
            return;
        }
        let bad = if !(-90.0..=90.0).contains(&lat) {
            Some(PositionFault::Lat(lat))
        } else if !(-180.0..=180.0).contains(&lon) {
            Some(PositionFault::Lon(lon))
        } else {
            None
        };
        let bad = bad.or_else(|| {
            let here = (s.t_s, lat, lon);
            let (ok, speed_mps) = self.last.map_or((true, 0.0), |l| plausible(l, here));
            if ok {
                self.last = Some(here);
                self.run = (0, None);
                return None;
            }
            // A refused fix: part of a consistent run (the track really moved)?
            self.run = match self.run.1 {
                Some(prev) if plausible(prev, here).0 => (self.run.0 + 1, Some(here)),
                _ => (1, Some(here)),
            };
            if self.run.0 >= REANCHOR_FIXES {
                self.last = Some(here);
                self.run = (0, None);
                return None;
            }
            Some(PositionFault::Jump { speed_mps })
        });
        if let Some(f) = bad {
            fault(f);
            s.lat_deg = f64::NAN;
            s.lon_deg = f64::NAN;
            s.flags.set(Flags::NO_GPS);
        }
    }
}

/// One warning for the refused positions, naming the file and lines (at most
/// `MAX_LISTED` of them, then a count); `None` when there are none.
pub fn faults_warning(
    faults: &[(usize, PositionFault)],
    origin: Option<&RowOrigin>,
) -> Option<String> {
    const MAX_LISTED: usize = 5;
    if faults.is_empty() {
        return None;
    }
    let file = origin.map_or("trace".to_string(), |o| o.file.clone());
    let at = |row: usize| match origin.and_then(|o| o.line(row)) {
        Some(l) => format!("line {l}"),
        None => format!("data row {}", row + 1),
    };
    let mut msg = format!(
        "{file}: {} unusable position(s), treated as missing (samples flagged NO_GPS):",
        faults.len()
    );
    for (row, f) in faults.iter().take(MAX_LISTED) {
        msg.push_str(&format!("\n  {}: {f}", at(*row)));
    }
    if faults.len() > MAX_LISTED {
        msg.push_str(&format!("\n  … and {} more", faults.len() - MAX_LISTED));
    }
    Some(msg)
}

/// Prints `msg` as a warning once per process: a flight is rebuilt from the same trace
/// by several stages (diagnose builds one per candidate model).
pub fn warn_once(msg: &str) {
    use std::collections::HashSet;
    use std::sync::Mutex;
    static SEEN: Mutex<Option<HashSet<String>>> = Mutex::new(None);
    let mut seen = SEEN.lock().unwrap_or_else(|e| e.into_inner());
    if seen
        .get_or_insert_with(HashSet::new)
        .insert(msg.to_string())
    {
        crate::errln!("warning: {msg}");
        PRINTED
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(msg.to_string());
    }
}

/// Every warning [`warn_once`] printed, in order.
static PRINTED: std::sync::Mutex<Vec<String>> = std::sync::Mutex::new(Vec::new());

/// The warnings printed so far by [`warn_once`] (glitches, positions): `--json` carries
/// them with the summary's own, as stderr shows them.
pub fn printed_warnings() -> Vec<String> {
    PRINTED.lock().unwrap_or_else(|e| e.into_inner()).clone()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A straight track north at 60 m/s, 10 Hz.
    fn track(n: usize) -> Vec<AlignedSample> {
        (0..n)
            .map(|i| {
                let mut s = AlignedSample::empty(i as f64 * 0.1);
                s.lat_deg = 45.0 + (6.0 * i as f64 / EARTH_RADIUS_M).to_degrees();
                s.lon_deg = 7.0;
                s.alt_m = 3000.0;
                s
            })
            .collect()
    }

    #[test]
    fn bad_values_and_a_one_sample_jump_are_refused_alone() {
        let mut s = track(100);
        s[10].lat_deg = 1e6;
        s[20].lon_deg = 400.0;
        s[30].alt_m = 1e9;
        s[40].lat_deg = f64::INFINITY;
        s[50].lat_deg += 0.5; // 55 km away for one sample
        let f = check_positions(&mut s);
        let rows: Vec<usize> = f.iter().map(|x| x.0).collect();
        assert_eq!(rows, vec![10, 20, 30, 40, 50], "{f:?}");
        assert!(matches!(f[4].1, PositionFault::Jump { speed_mps } if speed_mps > 5e5));
        for (i, x) in s.iter().enumerate() {
            assert_eq!(
                x.flags.contains(Flags::NO_GPS),
                rows.contains(&i),
                "row {i}"
            );
        }
        assert!(s[10].lat_deg.is_nan() && s[30].alt_m.is_nan() && s[30].lat_deg.is_finite());
        let w = faults_warning(&f, None).unwrap();
        assert!(w.contains("data row 11: lat = 1000000"), "{w}");
    }

    #[test]
    fn a_real_step_is_accepted_after_a_few_fixes_and_the_dateline_is_no_jump() {
        let mut s = track(100);
        for x in &mut s[60..] {
            x.lat_deg += 0.1; // 11 km: a datum change, permanent
        }
        let f = check_positions(&mut s);
        let rows: Vec<usize> = f.iter().map(|x| x.0).collect();
        assert_eq!(rows, (60..60 + REANCHOR_FIXES - 1).collect::<Vec<_>>());
        let mut s = track(10);
        for (i, x) in s.iter_mut().enumerate() {
            x.lon_deg = if i < 5 { 179.9999 } else { -179.9999 };
        }
        assert!(check_positions(&mut s).is_empty());
    }
}
