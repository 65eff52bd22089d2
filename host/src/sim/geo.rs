//! Main (core) geomagnetic field and the local flat-earth frame.
//!
//! The default main field is a tilted centred dipole with the IGRF-2020 degree-1 Gauss
//! coefficients on a spherical Earth (radius 6371.2 km, latitude taken as geocentric).
//! It gets the field strength, inclination and the ~0.02 nT/m regional gradient of a real
//! core field to within a few percent, which is all a compensator test needs; it is not
//! an IGRF replacement.

use nalgebra::Vector3;

/// IGRF reference radius (m).
pub const EARTH_RADIUS_M: f64 = 6_371_200.0;
/// IGRF-2020 degree-1 coefficients (nT): g10, g11, h11.
pub const IGRF2020_G10_NT: f64 = -29_404.8;
pub const IGRF2020_G11_NT: f64 = -1_450.9;
pub const IGRF2020_H11_NT: f64 = 4_652.5;

/// How the main field is produced.
#[derive(Clone, Debug, PartialEq)]
pub enum EarthField {
    /// Tilted centred dipole (IGRF-2020 degree 1), evaluated at every sample.
    Dipole,
    /// A uniform field given by total intensity, inclination and declination.
    Fixed {
        f_nt: f64,
        inc_deg: f64,
        dec_deg: f64,
    },
}

impl EarthField {
    /// Main field at geographic position (deg, deg, m above the reference sphere),
    /// in that point's own north-east-down frame (what an INS-referenced sensor sees).
    pub fn field_ned_nt(&self, lat_deg: f64, lon_deg: f64, alt_m: f64) -> Vector3<f64> {
        match *self {
            EarthField::Fixed {
                f_nt,
                inc_deg,
                dec_deg,
            } => {
                let (i, d) = (inc_deg.to_radians(), dec_deg.to_radians());
                Vector3::new(
                    f_nt * i.cos() * d.cos(),
                    f_nt * i.cos() * d.sin(),
                    f_nt * i.sin(),
                )
            }
            EarthField::Dipole => dipole_ned_nt(lat_deg, lon_deg, alt_m),
        }
    }
}

/// Centred dipole: B = (a/r)^3 [3 (g·r̂) r̂ − g], g = (g11, h11, g10) in Earth-fixed axes,
/// which is −∇ of the degree-1 potential a (a/r)^2 (g10 P10 + (g11 cos φ + h11 sin φ) P11).
fn dipole_ned_nt(lat_deg: f64, lon_deg: f64, alt_m: f64) -> Vector3<f64> {
    let (lat, lon) = (lat_deg.to_radians(), lon_deg.to_radians());
    let (sl, cl, so, co) = (lat.sin(), lat.cos(), lon.sin(), lon.cos());
    let r_hat = Vector3::new(cl * co, cl * so, sl);
    let r = EARTH_RADIUS_M + alt_m;
    let g = Vector3::new(IGRF2020_G11_NT, IGRF2020_H11_NT, IGRF2020_G10_NT);
    let scale = (EARTH_RADIUS_M / r).powi(3);
    let b = (r_hat * (3.0 * g.dot(&r_hat)) - g) * scale;
    let north = Vector3::new(-sl * co, -sl * so, cl);
    let east = Vector3::new(-so, co, 0.0);
    Vector3::new(b.dot(&north), b.dot(&east), -b.dot(&r_hat))
}

/// Local flat-earth frame: north/east metres from the start point, down = −altitude.
/// Equirectangular mapping; over a survey block (tens of km) its distortion is far below
/// the GPS error.
#[derive(Clone, Copy, Debug)]
pub struct LocalFrame {
    pub lat0_deg: f64,
    pub lon0_deg: f64,
}

impl LocalFrame {
    pub fn to_geo(&self, north_m: f64, east_m: f64) -> (f64, f64) {
        let lat = self.lat0_deg + (north_m / EARTH_RADIUS_M).to_degrees();
        let lon = self.lon0_deg
            + (east_m / (EARTH_RADIUS_M * self.lat0_deg.to_radians().cos())).to_degrees();
        (lat, lon)
    }
    pub fn to_local(&self, lat_deg: f64, lon_deg: f64) -> (f64, f64) {
        let n = (lat_deg - self.lat0_deg).to_radians() * EARTH_RADIUS_M;
        let e = (lon_deg - self.lon0_deg).to_radians()
            * EARTH_RADIUS_M
            * self.lat0_deg.to_radians().cos();
        (n, e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dipole_is_realistic_at_ottawa() {
        let b = EarthField::Dipole.field_ned_nt(45.3, -75.7, 3000.0);
        let f = b.norm();
        let inc = (b.z / (b.x * b.x + b.y * b.y).sqrt()).atan().to_degrees();
        // Real IGRF there: F ≈ 53 500 nT, I ≈ 68°; a dipole is within ~10 %.
        assert!((47_000.0..60_000.0).contains(&f), "F = {f}");
        assert!((62.0..78.0).contains(&inc), "I = {inc}");
    }

    #[test]
    fn local_frame_round_trip() {
        let fr = LocalFrame {
            lat0_deg: 45.3,
            lon0_deg: -75.7,
        };
        let (lat, lon) = fr.to_geo(1234.5, -987.6);
        let (n, e) = fr.to_local(lat, lon);
        assert!((n - 1234.5).abs() < 1e-6 && (e + 987.6).abs() < 1e-6);
    }
}
