//! Scalar glitches: a sample no magnetometer can produce next to its neighbours (a
//! corrupted line, a dropout reading) is taken as missing before anything is estimated.
//! The board's filter gates such samples itself, but post-flight a single +1e5 nT value
//! also enters the along-track spectrum (σ1), the local-roughness profile and Tolles–
//! Lawson's band-passed least squares, and one of them took a clean calibration's error
//! from 0.007 to 0.21 nT. One rule, for the whole flight in memory ([`glitches`]) and for
//! the stream (`stream::stats::Despiker`): [`judge`].

/// Below this a departure from the neighbours' line is never a glitch (nT): no real field
/// moves a sample this far from quiet neighbours.
const FLOOR_NT: f64 = 20.0;
/// A departure beyond this many times the neighbours' own median departure from their line
/// is a glitch: a manoeuvre's curvature shows in the neighbours as much as in the sample
/// (a 300 nT, 0.5 Hz swing departs 124 nT at its peak where its neighbours depart ~75).
const SCATTER_FACTOR: f64 = 6.0;

/// Neighbours a side: ±0.5 s, 5–15 samples. Wide enough that a 5-sample step or a cluster
/// of glitches is outnumbered by good neighbours at 10 Hz.
pub fn half_window(sample_rate_hz: f64) -> usize {
    ((0.5 * sample_rate_hz).round() as usize).clamp(5, 15)
}

/// Rows after a fluxgate glitch its bridge looks through for a good vector: one despiker
/// window, the longest run of glitches it can find. Further on the last good vector is
/// held: the stream then bridges in a bounded queue (unbounded, a fluxgate dead after a
/// glitch held back the rest of the flight), and a line drawn across a longer dropout is
/// no better than the vector held.
pub fn bridge_reach(sample_rate_hz: f64) -> usize {
    2 * half_window(sample_rate_hz) + 1
}

/// Is `window[centre]` a glitch? `window` is consecutive samples around it (NaN = none).
/// It is judged against a robust line through its neighbours (Theil–Sen: the median of
/// the pairwise slopes, then the median intercept) and their median departure from it:
/// glitches among the neighbours (a pair, a triple, a short step) move neither while good
/// neighbours are the majority. The former rule (50 nT + 10 × the neighbours' max − min)
/// let each of two +1e5 nT samples two rows apart widen the other's limit past it: a
/// calibration 6× worse, TL 156 nT off, no warning.
pub fn judge(window: &[f64], centre: usize, scratch: &mut Vec<f64>) -> bool {
    let v = window[centre];
    if !v.is_finite() {
        return false;
    }
    let good = |j: usize| j != centre && window[j].is_finite();
    let n = window.len();
    // A quick no: with the finite values within `range`, every pairwise slope is within
    // ±range, the line's value at the centre within range·(n − 1) of them, and so the
    // departure within range·n, which below half the floor can never pass it (the test
    // below, exact, cost 435 slopes and three medians a sample at 1 kHz).
    let (lo, hi) = window
        .iter()
        .filter(|w| w.is_finite())
        .fold((v, v), |(lo, hi), &w| (lo.min(w), hi.max(w)));
    if (hi - lo) * n as f64 <= 0.5 * FLOOR_NT {
        return false;
    }
    scratch.clear();
    for j in (0..n).filter(|&j| good(j)) {
        for k in (j + 1..n).filter(|&k| good(k)) {
            scratch.push((window[k] - window[j]) / (k - j) as f64);
        }
    }
    if scratch.len() < 3 {
        return false;
    }
    let slope = median_of(scratch);
    let at = |j: usize| window[j] - slope * (j as f64 - centre as f64);
    scratch.clear();
    scratch.extend((0..n).filter(|&j| good(j)).map(at));
    let predicted = median_of(scratch);
    scratch.clear();
    scratch.extend(
        (0..n)
            .filter(|&j| good(j))
            .map(|j| (at(j) - predicted).abs()),
    );
    let scatter = median_of(scratch);
    (v - predicted).abs() > FLOOR_NT + SCATTER_FACTOR * scatter
}

fn median_of(values: &mut [f64]) -> f64 {
    let mid = values.len() / 2;
    *values.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1
}

/// A bound on [`judge`]'s departure for a full window (`2·half + 1` finite values, the
/// centre in the middle): at most `range ×` this, `range` the window's max − min. More than
/// half the pairwise slopes join samples `d` or more apart and are within ±range/d, so
/// their median is; the line then moves at most range·half/d from the values.
fn departure_factor(half: usize) -> f64 {
    let good: Vec<usize> = (0..=2 * half).filter(|&j| j != half).collect();
    let pairs = good.len() * good.len().saturating_sub(1) / 2;
    let apart = |d: usize| {
        (0..good.len())
            .map(|a| good[a + 1..].iter().filter(|&&k| k - good[a] >= d).count())
            .sum::<usize>()
    };
    let d = (1..=2 * half).rfind(|&d| apart(d) > pairs / 2).unwrap_or(1);
    1.0 + half as f64 / d as f64
}

/// Rows of `mag_nt` that are glitches.
pub fn glitches(mag_nt: &[f64], sample_rate_hz: f64) -> Vec<usize> {
    let half = half_window(sample_rate_hz);
    let n = mag_nt.len();
    let mut scratch = Vec::with_capacity(2 * half + 1);
    let factor = departure_factor(half);
    (0..n)
        .filter(|&i| {
            let (lo, hi) = (i.saturating_sub(half), (i + half + 1).min(n));
            let window = &mag_nt[lo..hi];
            // The same verdict without the 435 slopes and three medians (1 kHz) where the
            // bound cannot reach half the floor: a fluxgate modulus's noise at 1 kHz spans
            // 2–3 nT over a window, too wide for `judge`'s own quick no.
            if window.len() == 2 * half + 1 && window.iter().all(|w| w.is_finite()) {
                let (a, b) = window
                    .iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &w| {
                        (a.min(w), b.max(w))
                    });
                if (b - a) * factor <= 0.5 * FLOOR_NT {
                    return false;
                }
            }
            judge(window, i - lo, &mut scratch)
        })
        .collect()
}

/// `|B_F|`, as the fluxgate test judges it (the stream's too).
pub fn modulus_nt(b: &[f64; 3]) -> f64 {
    (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt()
}

/// Rows whose fluxgate vector is inconsistent with its neighbours or with the scalar: a
/// glitch (by [`judge`]) in the modulus `|B_F|` or in `|B_F| − mag`. Both are free of the
/// attitude (an axis swings by thousands of nT in a turn; the modulus does not), so the
/// scalar's rule applies unchanged. One `flux_z` = 0, or a line cut inside its last number
/// (48954.7 → 48), otherwise gave the fluxgate calibration a −38,736 nT bias and a survey
/// 6× worse. Rows without a finite vector are not judged (they are missing already).
pub fn flux_glitches(flux_nt: &[[f64; 3]], mag_nt: &[f64], sample_rate_hz: f64) -> Vec<usize> {
    let modulus: Vec<f64> = flux_nt.iter().map(modulus_nt).collect();
    let against_scalar: Vec<f64> = modulus.iter().zip(mag_nt).map(|(f, m)| f - m).collect();
    let mut rows = glitches(&modulus, sample_rate_hz);
    rows.extend(glitches(&against_scalar, sample_rate_hz));
    rows.sort_unstable();
    rows.dedup();
    rows
}

#[cfg(test)]
mod tests {
    use super::glitches;

    /// The quick no of `glitches` gives `judge`'s verdict on every row: noise whose range
    /// straddles the bound, a ramp, spikes of 15–60 nT, at 10 Hz and 1 kHz.
    #[test]
    fn the_quick_no_is_judge_s_verdict() {
        let mut seed = 12345u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for rate in [10.0, 1000.0] {
            let n = 6000;
            let x: Vec<f64> = (0..n)
                .map(|i| {
                    let amp = [0.5, 2.0, 4.0, 6.0, 12.0][(i / 400) % 5];
                    let spike = if i % 97 == 0 {
                        15.0 + 45.0 * (next() + 0.5)
                    } else {
                        0.0
                    };
                    0.02 * i as f64 + amp * next() + spike
                })
                .collect();
            let half = super::half_window(rate);
            let mut scratch = Vec::new();
            let exact: Vec<usize> = (0..n)
                .filter(|&i| {
                    let (lo, hi) = (i.saturating_sub(half), (i + half + 1).min(n));
                    super::judge(&x[lo..hi], i - lo, &mut scratch)
                })
                .collect();
            assert!(!exact.is_empty());
            assert_eq!(glitches(&x, rate), exact, "{rate} Hz");
        }
    }

    fn manoeuvring(n: usize, fs: f64) -> Vec<f64> {
        // a 300 nT, 0.5 Hz manoeuvre (stronger than any real aircraft's) plus noise
        (0..n)
            .map(|i| {
                let t = i as f64 / fs;
                52_000.0
                    + 300.0 * (std::f64::consts::PI * t).sin()
                    + 0.01 * ((i * 7919) % 13) as f64
            })
            .collect()
    }

    #[test]
    fn finds_spikes_and_leaves_strong_manoeuvres_alone() {
        let fs = 10.0;
        let mut mag = manoeuvring(2000, fs);
        assert_eq!(glitches(&mag, fs), Vec::<usize>::new());
        mag[65] += 4000.0;
        mag[900] += 100.0;
        mag[1500] -= 1e5;
        assert_eq!(glitches(&mag, fs), vec![65, 1500]);
        // a quiet stretch: 100 nT is caught
        let mut quiet = vec![52_000.0; 200];
        quiet[100] += 100.0;
        assert_eq!(glitches(&quiet, fs), vec![100]);
    }

    /// Pairs, triples and 5-sample steps, at every spacing inside the window, both signs,
    /// from the floor to 1e5 nT, on a quiet stretch and in a strong manoeuvre: every bad
    /// sample is found, no good one is.
    #[test]
    fn clusters_of_glitches_do_not_hide_each_other() {
        let fs = 10.0;
        for amplitude in [30.0, 500.0, 1e5, -4000.0] {
            for (count, spacing) in [(2, 1), (2, 2), (2, 4), (3, 1), (3, 2), (5, 1)] {
                let at: Vec<usize> = (0..count).map(|k| 400 + k * spacing).collect();
                let mut quiet: Vec<f64> = (0..800)
                    .map(|i| 52_000.0 + 0.02 * ((i * 7919) % 13) as f64)
                    .collect();
                for &i in &at {
                    quiet[i] += amplitude;
                }
                assert_eq!(
                    glitches(&quiet, fs),
                    at,
                    "{count} × {amplitude} nT, {spacing} apart"
                );
                // in a manoeuvre only what a real signal cannot do is required
                if amplitude.abs() >= 4000.0 {
                    let mut m = manoeuvring(800, fs);
                    for &i in &at {
                        m[i] += amplitude;
                    }
                    assert_eq!(glitches(&m, fs), at, "manoeuvre {count} × {amplitude}");
                }
            }
        }
    }
}
