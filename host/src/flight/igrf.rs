//! The core (main) field of the Earth from IGRF-14: the value the `igrf` trace column
//! carries, computed from position, height and date when a file does not have it.
//!
//! Why hand-written: the `igrf` crate (0.2) carries IGRF-13 only (valid to 2025) and
//! calls itself "not well tested"; `world_magnetic_model` is the WMM, not the IGRF;
//! `ferromagnetic` 0.0.1-alpha.5 has IGRF-14 but, on the 3,000 worldwide points of
//! `tests/igrf.rs`, panics on the 74 dated after 2029.0 and is more than 10 nT from
//! ppigrf on 474 of the rest (all dated 2022 or later, up to 269 nT); this code is within
//! 0.32 nT of it everywhere. The synthesis is ~80 lines of textbook spherical harmonics
//! (Schmidt semi-normalised Legendre functions, as in the IAGA reference code).
//!
//! Coefficients: `host/data/igrf14.shc`, the IGRF-14 model of IAGA Working Group V-MOD
//! (Alken et al. 2025, doi:10.5281/zenodo.14012302), 1900–2030 in 5-year epochs, degree
//! 13 from 2000; the 2030 column is the 2025 model plus 5 years of its predicted secular
//! variation, so linear interpolation between columns is the official time dependence.
//! The file is the one shipped in the PyPI package `ppigrf` 2.1.0 (MIT, K. M. Laundal),
//! whose `ppigrf.igrf` is also the reference the tests compare with
//! (`host/tests/data/igrf14_reference.csv`).

use anyhow::{bail, Context, Result};
use std::sync::OnceLock;

/// The model's name as reported to the user.
pub const MODEL_NAME: &str = "IGRF-14";

/// Reference radius of the IGRF expansion (km).
const REF_RADIUS_KM: f64 = 6371.2;
/// WGS-84 semi-major axis (km) and flattening: geodetic positions (GNSS) to geocentric.
/// The difference between geodetic and geocentric latitude (up to 0.19°) moves the
/// field by tens of nT, so the conversion is needed at the 1 nT level.
const WGS84_A_KM: f64 = 6378.137;
const WGS84_F: f64 = 1.0 / 298.257_223_563;
/// Latitudes beyond this (deg) are taken at it: at a geographic pole sinθ = 0 and the
/// east component (a limit along the meridian `lon`) would be lost, 16,500 nT of it at
/// worst; 1e-7° is 1 cm, a few µnT of field. ppigrf and the IAGA code take the same limit.
const POLE_LAT_DEG: f64 = 90.0 - 1e-7;

const SHC: &str = include_str!("../../data/igrf14.shc");

/// Gauss coefficients at every epoch of the table.
pub struct Igrf {
    /// Maximum degree.
    n_max: usize,
    /// Epochs (decimal years), increasing.
    epochs: Vec<f64>,
    /// Per epoch: g[n][m], h[n][m] (nT), n ≤ n_max.
    g: Vec<Vec<Vec<f64>>>,
    h: Vec<Vec<Vec<f64>>>,
}

/// The field at one point: geodetic north, east, down components and the total (nT).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MainField {
    pub north_nt: f64,
    pub east_nt: f64,
    pub down_nt: f64,
    pub total_nt: f64,
}

impl Igrf {
    /// The embedded IGRF-14 table (parsed once).
    pub fn igrf14() -> &'static Igrf {
        static MODEL: OnceLock<Igrf> = OnceLock::new();
        MODEL.get_or_init(|| Igrf::parse(SHC).expect("the embedded IGRF-14 table parses"))
    }

    /// Parses a `.shc` table (`#` comments; a parameter line `n_min n_max n_times ...`;
    /// the epochs; then `n m values...`, m < 0 for the h coefficients).
    pub fn parse(text: &str) -> Result<Self> {
        let mut lines = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim_start().starts_with('#') && !l.trim().is_empty());
        let (_, params) = lines.next().context("shc: no parameter line")?;
        let p: Vec<usize> = params
            .split_whitespace()
            .take(3)
            .map(|v| v.parse().context("shc: bad parameter line"))
            .collect::<Result<_>>()?;
        let (n_max, n_times) = (p[1], p[2]);
        let (_, epochs) = lines.next().context("shc: no epoch line")?;
        let epochs: Vec<f64> = epochs
            .split_whitespace()
            .map(|v| v.parse().context("shc: bad epoch"))
            .collect::<Result<_>>()?;
        if epochs.len() != n_times || epochs.windows(2).any(|w| w[1] <= w[0]) {
            bail!(
                "shc: {} epochs, expected {n_times} increasing",
                epochs.len()
            );
        }
        let zero = vec![vec![vec![0.0; n_max + 1]; n_max + 1]; n_times];
        let (mut g, mut h) = (zero.clone(), zero);
        for (i, line) in lines {
            let v: Vec<f64> = line
                .split_whitespace()
                .map(|x| x.parse().with_context(|| format!("shc line {}", i + 1)))
                .collect::<Result<_>>()?;
            if v.len() != n_times + 2 {
                bail!(
                    "shc line {}: {} values, expected {}",
                    i + 1,
                    v.len(),
                    n_times + 2
                );
            }
            let (n, m) = (v[0] as usize, v[1] as i64);
            if n == 0 || n > n_max || m.unsigned_abs() as usize > n {
                bail!("shc line {}: degree/order ({n}, {m}) out of range", i + 1);
            }
            let target = if m < 0 { &mut h } else { &mut g };
            for (k, c) in v[2..].iter().enumerate() {
                target[k][n][m.unsigned_abs() as usize] = *c;
            }
        }
        Ok(Igrf {
            n_max,
            epochs,
            g,
            h,
        })
    }

    /// First and last epoch the model is defined for (decimal years).
    pub fn valid_years(&self) -> (f64, f64) {
        (
            self.epochs[0],
            *self.epochs.last().unwrap_or(&self.epochs[0]),
        )
    }

    /// Gauss coefficients at a decimal year: linear between the table's epochs.
    pub fn coefficients_at(&self, year: f64) -> Result<Coefficients> {
        let (first, last) = self.valid_years();
        if !(first..=last).contains(&year) {
            bail!("{MODEL_NAME} is defined for {first}–{last}; the date is {year:.3}");
        }
        let k = self
            .epochs
            .windows(2)
            .position(|w| year <= w[1])
            .unwrap_or(self.epochs.len() - 2);
        let w = (year - self.epochs[k]) / (self.epochs[k + 1] - self.epochs[k]);
        let lerp = |a: &Vec<Vec<f64>>, b: &Vec<Vec<f64>>| -> Vec<Vec<f64>> {
            a.iter()
                .zip(b)
                .map(|(ra, rb)| ra.iter().zip(rb).map(|(x, y)| x + w * (y - x)).collect())
                .collect()
        };
        Ok(Coefficients {
            n_max: self.n_max,
            g: lerp(&self.g[k], &self.g[k + 1]),
            h: lerp(&self.h[k], &self.h[k + 1]),
        })
    }
}

/// The Gauss coefficients of one date.
#[derive(Clone, Debug)]
pub struct Coefficients {
    n_max: usize,
    g: Vec<Vec<f64>>,
    h: Vec<Vec<f64>>,
}

impl Coefficients {
    /// The field at a WGS-84 geodetic position (height above the ellipsoid).
    pub fn field(&self, lat_deg: f64, lon_deg: f64, height_m: f64) -> MainField {
        let lat_deg = lat_deg.clamp(-POLE_LAT_DEG, POLE_LAT_DEG);
        // Geodetic → geocentric through Earth-centred Cartesian coordinates.
        let e2 = WGS84_F * (2.0 - WGS84_F);
        let (sin_lat, cos_lat) = lat_deg.to_radians().sin_cos();
        let h_km = height_m / 1000.0;
        let n_km = WGS84_A_KM / (1.0 - e2 * sin_lat * sin_lat).sqrt();
        let rho = (n_km + h_km) * cos_lat;
        let z = (n_km * (1.0 - e2) + h_km) * sin_lat;
        let r = rho.hypot(z);
        // Geocentric colatitude θ.
        let (sin_th, cos_th) = (rho / r, z / r);
        let phi = lon_deg.to_radians();

        // Schmidt semi-normalised P_n^m(cos θ) and dP/dθ by the standard recursions.
        let nm = self.n_max;
        let mut p = vec![vec![0.0; nm + 1]; nm + 1];
        let mut dp = vec![vec![0.0; nm + 1]; nm + 1];
        p[0][0] = 1.0;
        for n in 1..=nm {
            for m in 0..=n {
                if n == m {
                    // Diagonal: P_n^n = sqrt(1 − 1/2n)·sinθ·P_{n−1}^{n−1} (×√2 at n = 1).
                    let k = if n == 1 {
                        1.0
                    } else {
                        (1.0 - 1.0 / (2.0 * n as f64)).sqrt()
                    };
                    p[n][n] = k * sin_th * p[n - 1][n - 1];
                    dp[n][n] = k * (cos_th * p[n - 1][n - 1] + sin_th * dp[n - 1][n - 1]);
                } else {
                    let nf = n as f64;
                    let mf = m as f64;
                    let a = (2.0 * nf - 1.0) / (nf * nf - mf * mf).sqrt();
                    let b = if n >= 2 {
                        (((nf - 1.0) * (nf - 1.0) - mf * mf) / (nf * nf - mf * mf)).sqrt()
                    } else {
                        0.0
                    };
                    let p2 = if n >= 2 { p[n - 2][m] } else { 0.0 };
                    let dp2 = if n >= 2 { dp[n - 2][m] } else { 0.0 };
                    p[n][m] = a * cos_th * p[n - 1][m] - b * p2;
                    dp[n][m] = a * (cos_th * dp[n - 1][m] - sin_th * p[n - 1][m]) - b * dp2;
                }
            }
        }
        let (mut br, mut bth, mut bph) = (0.0, 0.0, 0.0);
        let ratio = REF_RADIUS_KM / r;
        let mut rn = ratio * ratio; // (a/r)^(n+2) for n = 0
        for n in 1..=nm {
            rn *= ratio;
            let nf = n as f64;
            for m in 0..=n {
                let (sm, cm) = (m as f64 * phi).sin_cos();
                let gh = self.g[n][m] * cm + self.h[n][m] * sm;
                br += (nf + 1.0) * rn * gh * p[n][m];
                bth -= rn * gh * dp[n][m];
                if sin_th > 1e-10 {
                    bph +=
                        rn * m as f64 * (self.g[n][m] * sm - self.h[n][m] * cm) * p[n][m] / sin_th;
                }
            }
        }
        // Geocentric (r, θ, φ) → geodetic north/east/down: rotate by δ = φ_gd − φ_gc.
        let lat_gc = z.atan2(rho);
        let (sd, cd) = (lat_deg.to_radians() - lat_gc).sin_cos();
        let north = -bth * cd - br * sd;
        let down = bth * sd - br * cd;
        MainField {
            north_nt: north,
            east_nt: bph,
            down_nt: down,
            total_nt: (north * north + bph * bph + down * down).sqrt(),
        }
    }
}

/// Decimal year of a calendar day (its start) plus `seconds` into it.
pub fn decimal_year(year: i32, day_of_year: u32, seconds: f64) -> f64 {
    let leap = (year % 4 == 0 && year % 100 != 0) || year % 400 == 0;
    let days = if leap { 366.0 } else { 365.0 };
    year as f64 + ((day_of_year as f64 - 1.0) + seconds / 86_400.0) / days
}

/// Day of the year (1-based) of a calendar date; None if the date does not exist.
pub fn day_of_year(year: i32, month: u32, day: u32) -> Option<u32> {
    let leap = (year % 4 == 0 && year % 100 != 0) || year % 400 == 0;
    let len = [
        31,
        if leap { 29 } else { 28 },
        31,
        30,
        31,
        30,
        31,
        31,
        30,
        31,
        30,
        31,
    ];
    if !(1..=12).contains(&month) || day == 0 || day > len[month as usize - 1] {
        return None;
    }
    Some(len[..month as usize - 1].iter().sum::<u32>() + day)
}

/// Parses `YYYY-MM-DD` into (year, day of year).
pub fn parse_date(text: &str) -> Result<(i32, u32)> {
    let bad = || format!("'{text}' is not a date YYYY-MM-DD");
    let mut it = text.trim().splitn(3, '-');
    let (y, m, d) = (
        it.next().with_context(bad)?,
        it.next().with_context(bad)?,
        it.next().with_context(bad)?,
    );
    let y: i32 = y.parse().ok().with_context(bad)?;
    let m: u32 = m.parse().ok().with_context(bad)?;
    let d: u32 = d.get(..2).unwrap_or(d).parse().ok().with_context(bad)?;
    let doy = day_of_year(y, m, d).with_context(bad)?;
    Ok((y, doy))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_poles_are_the_limit_along_the_meridian() {
        // ppigrf 2.1.0 at (−90°, −92.65786°), 6130.9 m, 2023-04-05: N/E/D/F.
        let c = Igrf::igrf14()
            .coefficients_at(2023.0 + 94.0 / 365.0)
            .unwrap();
        let b = c.field(-90.0, -92.657_86, 6130.9);
        for (got, want) in [
            (b.north_nt, 8009.2662),
            (b.east_nt, 14696.1932),
            (b.down_nt, -51666.3275),
            (b.total_nt, 54309.6293),
        ] {
            assert!((got - want).abs() < 0.2, "{b:?}");
        }
        let near = c.field(89.999_99, 10.0, 0.0);
        let at = c.field(90.0, 10.0, 0.0);
        assert!(
            (near.total_nt - at.total_nt).abs() < 0.01,
            "{near:?} {at:?}"
        );
        assert!((near.east_nt - at.east_nt).abs() < 0.1, "{near:?} {at:?}");
    }

    #[test]
    fn dipole_only_field_at_the_pole_is_twice_the_equator() {
        // A pure axial dipole g10: |B| at the geographic pole is 2|g10| at r = a, at the
        // equator |g10|: checks the Legendre recursion and the radial factor.
        let mut g = vec![vec![0.0; 3]; 3];
        g[1][0] = -30000.0;
        let c = Coefficients {
            n_max: 2,
            g,
            h: vec![vec![0.0; 3]; 3],
        };
        let r_eq_m = (REF_RADIUS_KM - WGS84_A_KM) * 1000.0;
        let eq = c.field(0.0, 10.0, r_eq_m);
        assert!((eq.total_nt - 30000.0).abs() < 1e-6, "{eq:?}");
        assert!((eq.north_nt - 30000.0).abs() < 1e-6, "{eq:?}");
    }

    #[test]
    fn dates() {
        assert_eq!(day_of_year(2020, 6, 29), Some(181));
        assert_eq!(day_of_year(2021, 2, 29), None);
        assert_eq!(parse_date("2020-06-29").unwrap(), (2020, 181));
        assert!(parse_date("2020-13-01").is_err());
        assert!((decimal_year(2020, 181, 43_200.0) - (2020.0 + 180.5 / 366.0)).abs() < 1e-12);
    }
}
