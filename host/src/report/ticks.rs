//! Axis tick selection: 1-2-5 "nice" steps on linear axes, decades (plus 2 and 5 when
//! the range is short) on log axes.

/// Ticks at a 1, 2 or 5 × 10^k step covering [lo, hi] with at most about `max_ticks`
/// ticks, all inside the range. Empty for a non-finite or empty range.
pub fn nice_ticks(lo: f64, hi: f64, max_ticks: usize) -> Vec<f64> {
    if !(lo.is_finite() && hi.is_finite()) || hi < lo {
        return Vec::new();
    }
    if hi == lo {
        return vec![lo];
    }
    let step = nice_step(lo, hi, max_ticks);
    if !(step.is_finite() && step > 0.0) {
        return Vec::new();
    }
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    if last.saturating_sub(first) > 1000 {
        return Vec::new(); // only possible with degenerate float ranges
    }
    // Multiples of an integer index, not repeated addition, so 0.1 + 0.2 drift never shows.
    (first..=last).map(|k| clean(k as f64 * step)).collect()
}

/// The step [`nice_ticks`] uses.
fn nice_step(lo: f64, hi: f64, max_ticks: usize) -> f64 {
    let raw = (hi - lo) / max_ticks.max(2) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let norm = raw / mag;
    let m = if norm <= 1.0 {
        1.0
    } else if norm <= 2.0 {
        2.0
    } else if norm <= 5.0 {
        5.0
    } else {
        10.0
    };
    m * mag
}

/// Rounds away float noise (0.30000000000000004 -> 0.3) by a decimal round trip.
fn clean(v: f64) -> f64 {
    if v == 0.0 {
        return 0.0; // also turns -0 into 0
    }
    format!("{v:.12e}").parse().unwrap_or(v)
}

/// Major ticks of a log axis over [lo, hi] (both > 0): the decades inside the range; when
/// fewer than three decades fall inside, also 2 and 5 × 10^k; when there are more than
/// ~10 decades, every n-th decade.
pub fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    if !(lo > 0.0 && hi >= lo && hi.is_finite()) {
        return Vec::new();
    }
    let k0 = lo.log10().floor() as i32 - 1;
    let k1 = hi.log10().ceil() as i32 + 1;
    let inside = |v: f64| v >= lo * (1.0 - 1e-12) && v <= hi * (1.0 + 1e-12);
    let decades: Vec<i32> = (k0..=k1).filter(|&k| inside(pow10(1, k))).collect();
    if decades.len() >= 3 {
        let every = decades.len().div_ceil(10);
        return decades
            .iter()
            .filter(|&&k| k.rem_euclid(every as i32) == 0)
            .map(|&k| pow10(1, k))
            .collect();
    }
    (k0..=k1)
        .flat_map(|k| [1, 2, 5].map(|m| pow10(m, k)))
        .filter(|&v| inside(v))
        .collect()
}

/// Minor ticks of a log axis: 2..9 × 10^k inside [lo, hi] that are not majors; empty when
/// the range spans more than 6 decades (they would merge into a grey band).
pub fn log_minor_ticks(lo: f64, hi: f64) -> Vec<f64> {
    if !(lo > 0.0 && hi > lo && hi.is_finite()) || hi / lo > 1e6 {
        return Vec::new();
    }
    let majors = log_ticks(lo, hi);
    let k0 = lo.log10().floor() as i32;
    let k1 = hi.log10().ceil() as i32;
    (k0..=k1)
        .flat_map(|k| (2..=9).map(move |m| pow10(m, k)))
        .filter(|&v| v >= lo && v <= hi && !majors.contains(&v))
        .collect()
}

/// m × 10^k as the f64 nearest the decimal value (so 0.1 is 0.1, not 0.1000000001).
fn pow10(m: i32, k: i32) -> f64 {
    format!("{m}e{k}").parse().unwrap_or(f64::NAN)
}

/// Tick label text. `step` is the tick spacing (linear axes) or None for log axes, where
/// 10^k outside 0.001..10000 is written `1e-5`, `2e6`, and plain decimals inside.
pub fn format_tick(v: f64, step: Option<f64>) -> String {
    if v == 0.0 {
        return "0".into();
    }
    match step {
        Some(step) => {
            let decimals = if step > 0.0 && step.is_finite() {
                (-(step.log10().floor())).max(0.0) as usize
            } else {
                0
            };
            let s = format!("{v:.decimals$}");
            if s.trim_start_matches('-')
                .chars()
                .all(|c| c == '0' || c == '.')
            {
                "0".into()
            } else {
                s
            }
        }
        None => {
            let a = v.abs();
            if (1e-3..1e4).contains(&a) {
                format!("{}", clean(v))
            } else {
                let k = a.log10().floor() as i32;
                let m = (v / 10f64.powi(k)).round();
                format!("{m}e{k}")
            }
        }
    }
}
