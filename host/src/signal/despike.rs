//! Scalar glitches: a sample no magnetometer can produce next to its neighbours (a
//! corrupted line, a dropout reading) is taken as missing before anything is estimated.
//! The board's filter gates such samples itself, but post-flight a single +1e5 nT value
//! also enters the along-track spectrum (σ1), the local-roughness profile and Tolles–
//! Lawson's band-passed least squares, and one of them took a clean calibration's error
//! from 0.007 to 0.21 nT.

/// A sample is a glitch when it leaves the median of its neighbours by more than
/// `FLOOR_NT` plus `SPREAD_FACTOR` × their spread (max − min). A real signal, however
/// strong its manoeuvres, stays within its neighbours' spread; the floor keeps a quiet
/// stretch's noise from counting.
const FLOOR_NT: f64 = 50.0;
const SPREAD_FACTOR: f64 = 10.0;

/// Rows of `mag_nt` that are glitches. The neighbourhood is ±0.3 s (3–15 samples a side).
pub fn glitches(mag_nt: &[f64], sample_rate_hz: f64) -> Vec<usize> {
    let half = ((0.3 * sample_rate_hz).round() as usize).clamp(3, 15);
    let n = mag_nt.len();
    let mut out = Vec::new();
    let mut neighbours = Vec::with_capacity(2 * half);
    for i in 0..n {
        let v = mag_nt[i];
        if !v.is_finite() {
            continue;
        }
        neighbours.clear();
        neighbours.extend(
            (i.saturating_sub(half)..(i + half + 1).min(n))
                .filter(|&j| j != i)
                .map(|j| mag_nt[j])
                .filter(|x| x.is_finite()),
        );
        if neighbours.len() < 3 {
            continue;
        }
        neighbours.sort_by(|a, b| a.total_cmp(b));
        let median = neighbours[neighbours.len() / 2];
        let spread = neighbours[neighbours.len() - 1] - neighbours[0];
        if (v - median).abs() > FLOOR_NT + SPREAD_FACTOR * spread {
            out.push(i);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::glitches;

    #[test]
    fn finds_spikes_and_leaves_strong_manoeuvres_alone() {
        let fs = 10.0;
        // a 300 nT, 0.5 Hz manoeuvre (stronger than any real aircraft's) plus noise
        let mut mag: Vec<f64> = (0..2000)
            .map(|i| {
                let t = i as f64 / fs;
                52_000.0
                    + 300.0 * (std::f64::consts::PI * t).sin()
                    + 0.01 * ((i * 7919) % 13) as f64
            })
            .collect();
        assert!(glitches(&mag, fs).is_empty());
        mag[65] += 4000.0;
        mag[900] += 100.0;
        mag[1500] -= 1e5;
        assert_eq!(glitches(&mag, fs), vec![65, 1500]);
        // a quiet stretch: 100 nT is caught
        let mut quiet = vec![52_000.0; 200];
        quiet[100] += 100.0;
        assert_eq!(glitches(&quiet, fs), vec![100]);
    }
}
