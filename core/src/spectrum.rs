//! σ1 of the field model from data (model.md §3): the model's along-track spectral
//! density is `S(k) = σ1²/k⁶`. The series is binned on a uniform distance grid and
//! third-differenced, which turns `σ1²/k⁶` into a flat spectrum of level σ1² at long
//! wavelengths — so no window leakage from the steep red spectrum can bias the fit —
//! then σ1² is the median periodogram level over the 1–8 km wavelengths (median, not
//! mean, so a few bins holding residual interference do not dominate).

/// Settings of the estimator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sigma1Config {
    /// Distance bin (m).
    pub bin_m: f64,
    pub min_wavelength_m: f64,
    pub max_wavelength_m: f64,
}

impl Default for Sigma1Config {
    fn default() -> Self {
        Self {
            bin_m: 100.0,
            min_wavelength_m: 1000.0,
            max_wavelength_m: 8000.0,
        }
    }
}

/// Result of the estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sigma1Estimate {
    /// σ1 (nT/m^2.5).
    pub sigma1: f64,
    /// Number of periodogram ordinates used.
    pub ordinates: usize,
    /// Track length used (m).
    pub length_m: f64,
}

/// At most this many distance bins per sample: a grid the samples cannot fill is
/// interpolation, not data (a position jump, or a track sampled far coarser than the
/// bin), and sizing it by the distance would let one bad coordinate cost gigabytes.
pub const MAX_BINS_PER_SAMPLE: usize = 4;
/// At most this many periodogram ordinates are evaluated (evenly strided over the band
/// when it holds more): the median is settled long before, and the cost stays linear in
/// the number of samples (≤ `MAX_ORDINATES × MAX_BINS_PER_SAMPLE` operations per sample).
/// A 650 km survey line set has ~570 ordinates, so real flights are unaffected.
pub const MAX_ORDINATES: usize = 1024;

/// Distance bins of the grid for this track, `None` when it cannot be estimated.
fn grid_bins(s_m: &[f64], n: usize, cfg: &Sigma1Config) -> Option<usize> {
    if n < 8 || !(cfg.bin_m > 0.0) {
        return None;
    }
    let length = s_m[n - 1] - s_m[0];
    if !(length >= 2.0 * cfg.max_wavelength_m) {
        return None;
    }
    let bins = length / cfg.bin_m + 1.0;
    (bins <= (MAX_BINS_PER_SAMPLE * n) as f64).then_some(bins as usize)
}

/// The scratch [`estimate_sigma1`] needs for this track: at most
/// `3 × MAX_BINS_PER_SAMPLE × samples`, whatever the coordinates (0 when the track
/// cannot be estimated).
pub fn sigma1_scratch_len(s_m: &[f64], z_nt: &[f64], cfg: &Sigma1Config) -> usize {
    grid_bins(s_m, s_m.len().min(z_nt.len()), cfg).map_or(0, |nb| 3 * nb)
}

/// Estimates σ1 from `z_nt` (the scalar signal minus an interference estimate) against
/// cumulative along-track distance `s_m` (non-decreasing). `scratch` must hold
/// [`sigma1_scratch_len`] values; returns `None` when the track is too short (< 2 × the
/// longest wavelength), has more than [`MAX_BINS_PER_SAMPLE`] bins per sample, the
/// scratch is too small, or the data are unusable. Cost: linear in the samples.
pub fn estimate_sigma1(
    s_m: &[f64],
    z_nt: &[f64],
    cfg: &Sigma1Config,
    scratch: &mut [f64],
) -> Option<Sigma1Estimate> {
    let n = s_m.len().min(z_nt.len());
    let nb = grid_bins(s_m, n, cfg)?;
    let s0 = s_m[0];
    let length = s_m[n - 1] - s0;
    if scratch.len() < 3 * nb {
        return None;
    }
    let (zs, rest) = scratch.split_at_mut(nb);
    let (ss, rest) = rest.split_at_mut(nb);
    let counts = &mut rest[..nb];
    zs.fill(0.0);
    ss.fill(0.0);
    counts.fill(0.0);
    for i in 0..n {
        if !(s_m[i].is_finite() && z_nt[i].is_finite()) {
            continue;
        }
        let b = ((s_m[i] - s0) / cfg.bin_m) as usize;
        if b < nb {
            zs[b] += z_nt[i];
            ss[b] += s_m[i] - s0;
            counts[b] += 1.0;
        }
    }
    // Bin means at their mean positions (averaging cuts the sensor noise), compacted...
    let mut filled = 0usize;
    for b in 0..nb {
        if counts[b] > 0.0 {
            zs[filled] = zs[b] / counts[b];
            ss[filled] = ss[b] / counts[b];
            filled += 1;
        }
    }
    if filled < 8 {
        return None;
    }
    // ...then interpolated onto the exact grid: a bin mean sits where its samples were,
    // not at the bin centre, and that jitter times the gradient would swamp σ1.
    let grid = &mut counts[..nb];
    let mut a = 0usize;
    for (j, g) in grid.iter_mut().enumerate() {
        let sj = (j as f64 + 0.5) * cfg.bin_m;
        while a + 2 < filled && ss[a + 1] < sj {
            a += 1;
        }
        let (sa, sb) = (ss[a], ss[a + 1]);
        let w = if sb > sa { (sj - sa) / (sb - sa) } else { 0.0 };
        *g = zs[a] + (zs[a + 1] - zs[a]) * w;
    }
    // Third differences scaled to a third derivative (into zs, no longer needed).
    let m = nb - 3;
    let d3 = cfg.bin_m * cfg.bin_m * cfg.bin_m;
    for j in 0..m {
        zs[j] = (grid[j + 3] - 3.0 * grid[j + 2] + 3.0 * grid[j + 1] - grid[j]) / d3;
    }
    let y = &zs[..m];
    let out = &mut ss[..];
    let total = m as f64 * cfg.bin_m;
    let first = (libm::ceil(total / cfg.max_wavelength_m) as usize).max(1);
    // Not beyond the grid's Nyquist wavenumber (a bin coarser than half the shortest
    // wavelength).
    let last_h = (libm::floor(total / cfg.min_wavelength_m) as usize).min(m / 2);
    let stride = (last_h + 1)
        .saturating_sub(first)
        .div_ceil(MAX_ORDINATES)
        .max(1);
    // Periodogram ordinates at the Fourier wavenumbers in the band, corrected for the
    // difference operator and the bin averaging.
    let mut count = 0usize;
    for h in (first..=last_h).step_by(stride) {
        if count == out.len() {
            break;
        }
        let k = 2.0 * core::f64::consts::PI * h as f64 / total;
        let (mut re, mut im) = (0.0f64, 0.0f64);
        let (sd, cd) = libm::sincos(k * cfg.bin_m);
        let (mut sn, mut cs) = (0.0f64, 1.0f64);
        for v in y {
            re += v * cs;
            im -= v * sn;
            let c2 = cs * cd - sn * sd;
            sn = sn * cd + cs * sd;
            cs = c2;
        }
        let p = cfg.bin_m / m as f64 * (re * re + im * im);
        let half = 0.5 * k * cfg.bin_m;
        let gain = libm::pow(half / libm::sin(half), 8.0);
        out[count] = p * gain;
        count += 1;
    }
    if count < 3 {
        return None;
    }
    let v = &mut out[..count];
    // Insertion sort: a few hundred values at most, no allocation.
    for i in 1..v.len() {
        let mut j = i;
        while j > 0 && v[j - 1] > v[j] {
            v.swap(j - 1, j);
            j -= 1;
        }
    }
    let median = if count % 2 == 1 {
        v[count / 2]
    } else {
        0.5 * (v[count / 2 - 1] + v[count / 2])
    };
    // A periodogram ordinate is level·χ²₂/2: its median is ln 2 times its mean.
    let level = median / core::f64::consts::LN_2;
    Some(Sigma1Estimate {
        sigma1: libm::sqrt(level.max(0.0)),
        ordinates: count,
        length_m: length,
    })
}
