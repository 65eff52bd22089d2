//! Inputs that cannot be compensated: refused with a clear error, or warned about with the
//! figures that would pretend (FOM, improvement ratio, predicted error) withheld.

use crate::flight::Flight;
use anyhow::{bail, Result};

/// Shortest flight a calibration is attempted on (s and samples): the manoeuvre band's
/// lowest frequency is 0.1 Hz, so less than a minute holds a handful of its cycles.
pub const MIN_DURATION_S: f64 = 60.0;
pub const MIN_SAMPLES: usize = 100;

/// The least manoeuvre-band RMS of the fluxgate's direction cosines (largest axis) that
/// determines anything: about 0.45° of attitude. The simulated calibration pattern (5–8°
/// manoeuvres) gives 0.031, a straight survey line in turbulence 0.0043 (`tests/qc.rs`).
pub const MIN_EXCITATION: f64 = 0.008;

/// Earth's field is 22,000–67,000 nT; a fluxgate modulus below this is no field reading.
const MIN_FLUX_MODULUS_NT: f64 = 1_000.0;

/// What the checks found.
#[derive(Clone, Debug, Default)]
pub struct InputCheck {
    pub warnings: Vec<String>,
    /// Why FOM, improvement ratio and predicted error are withheld (None: they stand).
    pub withheld: Option<String>,
    /// First samples after time gaps (`gaps::time_breaks`).
    pub breaks: Vec<usize>,
    /// Manoeuvre-band RMS of the direction cosines (largest axis).
    pub excitation: f64,
}

impl InputCheck {
    fn withhold(&mut self, why: String) {
        self.warnings.push(format!(
            "{why}: improvement ratio, FOM and predicted error are withheld (null)"
        ));
        if self.withheld.is_none() {
            self.withheld = Some(why);
        }
    }
}

fn spread(v: impl Iterator<Item = f64>) -> (usize, f64) {
    let (mut n, mut lo, mut hi) = (0usize, f64::MAX, f64::MIN);
    for x in v.filter(|x| x.is_finite()) {
        n += 1;
        lo = lo.min(x);
        hi = hi.max(x);
    }
    (n, if n > 0 { hi - lo } else { f64::NAN })
}

/// Checks a flight before compensation. `calibrating`: the coefficients are to be
/// estimated from it (no coefficient file), which needs more than applying them.
pub fn check(flight: &Flight, calibrating: bool) -> Result<InputCheck> {
    let mut out = InputCheck {
        breaks: crate::qc::gaps::time_breaks(&flight.t_s),
        ..Default::default()
    };
    let (n_mag, mag_spread) = spread(flight.mag_nt.iter().copied());
    if n_mag == 0 {
        bail!(
            "the scalar column `mag` has no value on any of the {} rows (all missing or NaN): nothing to compensate",
            flight.len()
        );
    }
    if mag_spread == 0.0 && n_mag > 1 {
        bail!(
            "the scalar column `mag` is constant ({} nT on all {n_mag} finite rows): a stuck or placeholder magnetometer cannot be compensated",
            flight.mag_nt.iter().find(|v| v.is_finite()).unwrap_or(&f64::NAN)
        );
    }
    let modulus: Vec<f64> = flight
        .samples
        .iter()
        .map(|s| {
            let b = s.flux_nt.map(f64::from);
            (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt()
        })
        .collect();
    let n_field = modulus
        .iter()
        .filter(|m| m.is_finite() && **m >= MIN_FLUX_MODULUS_NT)
        .count();
    if n_field == 0 {
        bail!(
            "the fluxgate (flux_x, flux_y, flux_z) reads less than {MIN_FLUX_MODULUS_NT} nT or nothing on every row (all zero or missing): the direction of the field is unknown, nothing can be compensated"
        );
    }
    if n_field < flight.len() / 2 {
        out.warnings.push(format!(
            "the fluxgate reads less than {MIN_FLUX_MODULUS_NT} nT or nothing on {} of {} rows",
            flight.len() - n_field,
            flight.len()
        ));
    }
    let flux_constant =
        (0..3).all(|k| spread(flight.samples.iter().map(|s| s.flux_nt[k] as f64)).1 == 0.0);
    // The data's duration: samples × spacing (600 samples at 10 Hz are 60 s).
    let duration_s = flight.len() as f64 / flight.sample_rate_hz;
    let short = duration_s < MIN_DURATION_S || flight.len() < MIN_SAMPLES;
    if calibrating && flux_constant {
        bail!("the fluxgate reads the same vector on every row: the aircraft never changed attitude (or the fluxgate is stuck), so no coefficient can be estimated");
    }
    if calibrating && short {
        bail!(
            "the flight is too short to calibrate: {duration_s:.1} s and {} samples (at least {MIN_DURATION_S} s and {MIN_SAMPLES} samples are needed for the manoeuvre band)",
            flight.len()
        );
    }
    if let Some(w) = crate::qc::gaps::gaps_warning(&flight.t_s, &out.breaks) {
        out.warnings.push(w);
    }
    if flux_constant {
        out.withhold("the fluxgate reads the same vector on every row".into());
    } else if short {
        out.withhold(format!(
            "the flight is only {duration_s:.1} s / {} samples long (less than {MIN_DURATION_S} s or {MIN_SAMPLES} samples)",
            flight.len()
        ));
    } else {
        out.excitation = excitation(flight);
        if calibrating && (out.excitation.is_nan() || out.excitation < MIN_EXCITATION) {
            out.withhold(format!(
                "no manoeuvres: the fluxgate direction varies by {:.4} rms in the manoeuvre band (at least {MIN_EXCITATION} is needed, about 0.45° of attitude), so the flight cannot tell the interference's coefficients apart",
                out.excitation
            ));
        }
    }
    Ok(out)
}

/// Manoeuvre-band RMS of the fluxgate's direction cosines, largest of the three axes.
pub fn excitation(flight: &Flight) -> f64 {
    (0..3)
        .map(|k| {
            let e: Vec<f64> = flight
                .samples
                .iter()
                .map(|s| {
                    let b = s.flux_nt.map(f64::from);
                    b[k] / (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt()
                })
                .collect();
            crate::qc::figures::band_rms_nt(flight, &e)
        })
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max)
}
