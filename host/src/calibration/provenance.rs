//! Where a coefficient file came from (`provenance` in the file): the source file and its
//! SHA-256, the column map and sensor, the window, the flight date, the model and the
//! magcomp version; and the warnings when coefficients are applied to another sensor or
//! long after their calibration. Files written before it existed have none and still load.

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::path::Path;

/// Coefficients applied to a flight further than this from their calibration flight
/// (days) are warned about: an installation changes (a new harness, a moved sensor, a
/// magnetised part) over months.
pub const STALE_AFTER_DAYS: f64 = 90.0;

/// The calibration flight a coefficient file was estimated from.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, Default)]
pub struct Provenance {
    /// The trace file's name as given to `calibrate`.
    pub source_file: String,
    /// SHA-256 of the trace file's bytes (hex).
    pub source_sha256: String,
    /// The `--map` given, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub column_map: Option<String>,
    /// The file's column read as the scalar (`mag`, or the one `--map mag=…` names): the
    /// sensor, and with it the installation, the coefficients belong to.
    pub sensor: String,
    /// `--lines` and `--time` as given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lines: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_window: Option<String>,
    /// First and last `t` (s) of the rows calibrated on.
    pub t_first_s: f64,
    pub t_last_s: f64,
    /// `YYYY-MM-DD` of the flight's first dated row, when the trace or `--date` has one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flight_date: Option<String>,
    pub model: String,
    /// The `magcomp` that wrote the file.
    pub magcomp_version: String,
    /// The calibration flight's fluxgate through its calibration, to check an applied
    /// flight's fluxgate against (`fluxgate_check`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fluxgate: Option<super::fluxgate_check::FluxgateRecord>,
}

/// The running magcomp's version, as files record it.
pub fn magcomp_version() -> String {
    env!("CARGO_PKG_VERSION").to_string()
}

/// SHA-256 of a file's bytes, hex.
pub fn sha256_file(path: &Path) -> Result<String> {
    let mut f = std::fs::File::open(path).with_context(|| format!("hashing {}", path.display()))?;
    let mut h = Sha256::new();
    std::io::copy(&mut f, &mut h).with_context(|| format!("hashing {}", path.display()))?;
    Ok(h.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

/// `YYYY-MM-DD` of a decimal year as `flight::igrf::decimal_year` makes it (day start).
pub fn date_of_decimal_year(y: f64) -> Option<String> {
    if !y.is_finite() {
        return None;
    }
    let year = y.floor() as i32;
    let leap = (year % 4 == 0 && year % 100 != 0) || year % 400 == 0;
    let days = if leap { 366.0 } else { 365.0 };
    let mut doy = ((y - year as f64) * days + 1e-6).floor() as u32 + 1;
    for month in 1..=12u32 {
        for day in (1..=31).rev() {
            if crate::flight::igrf::day_of_year(year, month, day).is_some() {
                if doy <= day {
                    return Some(format!("{year:04}-{month:02}-{doy:02}"));
                }
                doy -= day;
                break;
            }
        }
    }
    None
}

/// Days between two `YYYY-MM-DD` dates.
fn days_between(a: &str, b: &str) -> Option<f64> {
    // Days since 1970-01-01 (the proleptic Gregorian count of H. Hinnant's `days_from_civil`).
    let day = |d: &str| -> Option<i64> {
        let mut it = d.trim().splitn(3, '-');
        let y: i64 = it.next()?.parse().ok()?;
        let m: i64 = it.next()?.parse().ok()?;
        let dd: i64 = it.next()?.get(..2)?.parse().ok()?;
        let y = if m <= 2 { y - 1 } else { y };
        let era = y.div_euclid(400);
        let yoe = y - era * 400;
        let doy = (153 * (m + if m > 2 { -3 } else { 9 }) + 2) / 5 + dd - 1;
        let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
        Some(era * 146_097 + doe - 719_468)
    };
    Some((day(a)? - day(b)?).abs() as f64)
}

/// The warnings for applying coefficients of `p` to a flight whose scalar is the file
/// column `sensor`, flown on `date` (when known).
pub fn warnings(p: &Provenance, sensor: &str, date: Option<&str>) -> Vec<String> {
    let mut out = Vec::new();
    if p.sensor != sensor {
        out.push(format!(
            "the coefficients were calibrated for scalar column '{}' ({}), this flight's scalar \
             is '{sensor}': coefficients belong to one sensor in one aircraft; calibrate this \
             installation",
            p.sensor, p.source_file
        ));
    }
    if let (Some(cal), Some(here)) = (p.flight_date.as_deref(), date) {
        if let Some(days) = days_between(cal, here).filter(|d| *d > STALE_AFTER_DAYS) {
            out.push(format!(
                "this flight ({here}) is {days:.0} days from the calibration flight ({cal}), \
                 more than {STALE_AFTER_DAYS:.0}: the installation may have changed; fly a new \
                 calibration"
            ));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_round_trip_through_decimal_years() {
        for d in [
            "2020-01-01",
            "2020-02-29",
            "2020-12-31",
            "2021-06-20",
            "2021-03-01",
        ] {
            let (y, doy) = crate::flight::igrf::parse_date(d).unwrap();
            let dy = crate::flight::igrf::decimal_year(y, doy, 0.0);
            assert_eq!(date_of_decimal_year(dy).as_deref(), Some(d));
        }
        assert_eq!(days_between("2020-06-20", "2020-09-28"), Some(100.0));
        assert_eq!(days_between("2021-03-01", "2020-02-28"), Some(367.0));
        assert_eq!(days_between("1970-01-01", "1970-01-01"), Some(0.0));
    }
}
