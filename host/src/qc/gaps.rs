//! Time gaps: a stretch without samples longer than [`GAP_FACTOR`] sample spacings. No
//! filter, derivative or band-pass may bridge one.

/// A time step longer than this many median sample spacings is a gap.
pub const GAP_FACTOR: f64 = 10.0;

/// Isolated missing samples up to this run length are interpolated for band-passing
/// (and left out of every statistic); longer runs split the signal like a time gap.
pub const MAX_FILL_SAMPLES: usize = 10;

/// Indices of the first sample after each time gap (`t[i] − t[i−1] > GAP_FACTOR ×` the
/// median spacing).
pub fn time_breaks(t_s: &[f64]) -> Vec<usize> {
    let mut dts: Vec<f64> = t_s
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| d.is_finite() && *d > 0.0)
        .collect();
    if dts.is_empty() {
        return Vec::new();
    }
    dts.sort_by(|a, b| a.total_cmp(b));
    let limit = GAP_FACTOR * dts[dts.len() / 2];
    (1..t_s.len())
        .filter(|&i| t_s[i] - t_s[i - 1] > limit)
        .collect()
}

/// The warning for the gaps of a flight, naming the first ones; None without gaps.
pub fn gaps_warning(t_s: &[f64], breaks: &[usize]) -> Option<String> {
    if breaks.is_empty() {
        return None;
    }
    let shown: Vec<String> = breaks
        .iter()
        .take(3)
        .map(|&i| {
            format!(
                "{:.1} s at t = {} (data row {})",
                t_s[i] - t_s[i - 1],
                t_s[i - 1],
                i + 1
            )
        })
        .collect();
    Some(format!(
        "{} time gap(s) longer than {GAP_FACTOR} sample spacings ({}{}): the samples on either side are flagged DERIVATIVE_DEGRADED, Tolles–Lawson and the band-pass are not run across them",
        breaks.len(),
        shown.join(", "),
        if breaks.len() > 3 { ", …" } else { "" }
    ))
}

/// Rows next to a gap (the last before and the first after): their derivatives span it.
pub fn gap_neighbours(breaks: &[usize]) -> Vec<usize> {
    breaks.iter().flat_map(|&i| [i - 1, i]).collect()
}

/// The row ranges between time gaps, covering `0..n`.
pub fn stretches(n: usize, breaks: &[usize]) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::with_capacity(breaks.len() + 1);
    let mut start = 0;
    for &b in breaks.iter().filter(|&&b| b > 0 && b < n) {
        out.push(start..b);
        start = b;
    }
    out.push(start..n);
    out
}
