//! Layout and path helpers of the plot builder: legend wrapping, axis ranges, label
//! widths, SVG path data and min/max decimation.
use super::{Series, CHAR_W, FONT_PX};
use std::fmt::Write;
/// Legend placement: (series index, row, x) with wrapping across the plot width.
pub(super) fn legend_layout(
    names: &[(usize, &Series)],
    left: f64,
    right: f64,
) -> Vec<(usize, usize, f64)> {
    let mut row = 0;
    let mut x = left;
    let mut out = Vec::new();
    for (i, s) in names {
        let item_w = 27.0 + text_w(&s.name, FONT_PX) + 16.0;
        if x + item_w > right && x > left {
            row += 1;
            x = left;
        }
        out.push((*i, row, x));
        x += item_w;
    }
    out
}

/// Avoids a zero or inverted span (constant data) and non-positive log ranges.
pub(super) fn widen((lo, hi): (f64, f64), log: bool) -> (f64, f64) {
    if lo.is_nan() || hi.is_nan() {
        return if log { (1.0, 10.0) } else { (0.0, 1.0) };
    }
    // Keeps hi - lo finite, so pixel scaling never divides by infinity.
    const LIM: f64 = f64::MAX / 4.0;
    let (lo, hi) = (lo.clamp(-LIM, LIM), hi.clamp(-LIM, LIM));
    let (mut lo, mut hi) = if lo <= hi { (lo, hi) } else { (hi, lo) };
    if log {
        if lo.is_nan() || lo <= 0.0 {
            lo = if hi > 0.0 { hi / 10.0 } else { 1.0 };
        }
        if hi.is_nan() || hi <= lo {
            hi = lo * 10.0;
        }
        if hi == lo {
            lo /= 3.0;
            hi *= 3.0;
        }
    } else if hi == lo {
        let d = if lo == 0.0 { 1.0 } else { lo.abs() * 0.01 };
        lo -= d;
        hi += d;
    }
    (lo, hi)
}

pub(super) fn tick_step(ticks: &[f64]) -> f64 {
    match ticks {
        [a, b, ..] => b - a,
        [a] => a.abs().max(1.0),
        [] => 1.0,
    }
}

pub(super) fn text_w(s: &str, font_px: f64) -> f64 {
    s.chars().count() as f64 * font_px * CHAR_W
}

/// Keeps ids usable inside `url(#...)`.
pub(super) fn sanitize_id(id: &str) -> String {
    id.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// SVG path data; NaN points split the path into sub-paths (gaps for missing data).
pub(super) fn path_data(x: &[f64], y: &[f64]) -> String {
    let mut d = String::with_capacity(x.len() * 12);
    let mut pen_down = false;
    let mut run = 0;
    for (&x, &y) in x.iter().zip(y) {
        if !(x.is_finite() && y.is_finite()) {
            if run == 1 {
                d.push_str("l0 0"); // a lone sample still shows as a dot (round caps)
            }
            pen_down = false;
            run = 0;
            continue;
        }
        let _ = write!(d, "{}{x:.1} {y:.1}", if pen_down { "L" } else { "M" });
        pen_down = true;
        run += 1;
    }
    if run == 1 {
        d.push_str("l0 0");
    }
    d
}

/// Min/max decimation: per bucket `floor((x - origin) / width)` of consecutive samples,
/// keeps the sample with the lowest and the one with the highest y, in their original
/// order, so every spike and dip survives. NaN in x or y is a gap: it flushes the
/// bucket and is kept as one (NaN, NaN) separator.
pub(super) fn minmax_by_bucket(
    x: &[f64],
    y: &[f64],
    origin: f64,
    width: f64,
) -> (Vec<f64>, Vec<f64>) {
    let mut ox = Vec::new();
    let mut oy = Vec::new();
    let mut cur: Option<(i64, usize, usize)> = None; // (bucket, argmin, argmax)
    let flush = |cur: &mut Option<(i64, usize, usize)>, ox: &mut Vec<f64>, oy: &mut Vec<f64>| {
        if let Some((_, imin, imax)) = cur.take() {
            let (a, b) = if imin <= imax {
                (imin, imax)
            } else {
                (imax, imin)
            };
            ox.push(x[a]);
            oy.push(y[a]);
            if b != a {
                ox.push(x[b]);
                oy.push(y[b]);
            }
        }
    };
    for i in 0..x.len().min(y.len()) {
        if !(x[i].is_finite() && y[i].is_finite()) {
            flush(&mut cur, &mut ox, &mut oy);
            if ox.last().is_some_and(|v: &f64| !v.is_nan()) {
                ox.push(f64::NAN);
                oy.push(f64::NAN);
            }
            continue;
        }
        let b = ((x[i] - origin) / width).floor() as i64;
        match &mut cur {
            Some((cb, imin, imax)) if *cb == b => {
                if y[i] < y[*imin] {
                    *imin = i;
                }
                if y[i] > y[*imax] {
                    *imax = i;
                }
            }
            _ => {
                flush(&mut cur, &mut ox, &mut oy);
                cur = Some((b, i, i));
            }
        }
    }
    flush(&mut cur, &mut ox, &mut oy);
    (ox, oy)
}

/// Min/max decimation of a series into `buckets` equal x intervals over its finite x
/// extent (see the plot: done per pixel column there). Output keeps, per bucket, the
/// lowest and highest sample in original order; missing values (NaN) stay as gaps.
pub fn downsample_minmax(x: &[f64], y: &[f64], buckets: usize) -> (Vec<f64>, Vec<f64>) {
    let (lo, hi) = x
        .iter()
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    if lo >= hi || buckets == 0 {
        return minmax_by_bucket(x, y, 0.0, f64::INFINITY);
    }
    // Slightly wider than the span so the last sample lands in the last bucket.
    let width = (hi - lo) / buckets as f64 * (1.0 + 1e-12);
    minmax_by_bucket(x, y, lo, width)
}
