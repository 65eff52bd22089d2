//! Reciprocal passes (issue 20 items 1 and 6): two straight legs flown over the same ground
//! in opposite directions. A scalar lag τ reads the anomaly V·τ behind the aircraft on
//! each pass, so the two passes are shifted against each other by 2·V·τ along the track;
//! the shift that best lines them up gives τ = shift / (2·V). A heading error is a
//! constant offset between them instead. The anomaly states of the filter cannot hide
//! such a shift (they follow whatever each pass reads), so this is a witness for `lag`
//! that the innovations lack (`diagnose/evidence.rs`), and the report draws the pairs
//! (`report/reciprocal.rs`).
//!
//! **Uncertainty of τ** ([`reciprocal_lag`]). Each pair's shift has its own 1σ
//! ([`shift_sd_m`]: the misfit over the anomaly's slope). The ground adds what no misfit
//! shows: two lines 10 m apart at 300 m over strong geology, with neither lag nor
//! compensation error (`mag − true interference`, seeds 1–6), align at 4.1 m rms per pair
//! ([`PAIR_GROUND_SD_M`]) and 2.5 m rms for a flight's mean of four
//! ([`GROUND_SHIFT_SD_M`]): an anomaly striking obliquely across two lines reads as a
//! shift, about a quarter of their separation here, and the pairs of a flight fly the
//! same lines, so it does not average away. τ is the pairs' weighted mean, σ_τ theirs
//! (widened when they scatter more than they state) with that floor: 0.021 s at 60 m/s.

use super::crossover::straight_course;
use crate::flight::Flight;
use crate::signal::stats::finite_mean;
use serde::Serialize;

/// Within this distance (m) two passes are over the same ground.
pub const SAME_GROUND_M: f64 = 200.0;

/// Every `every`-th row of `p.0..p.1` within SAME_GROUND_M of the track over rows
/// `q.0..q.1` (`ne` from [`Flight::local_ne_m`]; q thinned to ≤ 2000 points).
pub fn same_ground_rows(
    ne: &[[f64; 2]],
    p: (usize, usize),
    q: (usize, usize),
    every: usize,
) -> Vec<usize> {
    let step = ((q.1 - q.0) / 2000).max(1);
    let track: Vec<[f64; 2]> = (q.0..q.1).step_by(step).map(|i| ne[i]).collect();
    (p.0..p.1)
        .step_by(every.max(1))
        .filter(|&i| {
            track
                .iter()
                .any(|t| (t[0] - ne[i][0]).hypot(t[1] - ne[i][1]) < SAME_GROUND_M)
        })
        .collect()
}

/// `x` minus its least-squares line over the finite samples.
pub fn detrended(t: &[f64], x: &[f64]) -> Vec<f64> {
    let pts: Vec<(f64, f64)> = t
        .iter()
        .zip(x)
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .map(|(a, b)| (*a, *b))
        .collect();
    let n = pts.len().max(1) as f64;
    let (mt, mx) = pts
        .iter()
        .fold((0.0, 0.0), |(a, b), p| (a + p.0 / n, b + p.1 / n));
    let sxx: f64 = pts.iter().map(|p| (p.0 - mt).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mt) * (p.1 - mx)).sum();
    let slope = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    t.iter()
        .zip(x)
        .map(|(a, b)| b - mx - slope * (a - mt))
        .collect()
}

/// Shortest straight leg considered (s).
const MIN_LEG_S: f64 = 30.0;
/// Least ground the two passes must share for a plot and a shift (m).
const MIN_OVERLAP_M: f64 = 500.0;
/// Largest along-track shift searched (m): τ up to ~1 s at 100 m/s.
const MAX_SHIFT_M: f64 = 200.0;
/// A gap in a pass's samples wider than this (m) is not interpolated across.
const MAX_GAP_M: f64 = 30.0;

/// One reciprocal pair, on a common ground grid. Fields are environment-corrected (the
/// core field's change and a recorded diurnal removed), as the QC sheet's heading error.
#[derive(Clone, Debug)]
pub struct ReciprocalPair {
    /// Course of the first (earlier) and the second pass (degrees from north).
    pub heading_a_deg: f64,
    pub heading_b_deg: f64,
    /// Time span of each pass's part over the shared ground (s).
    pub t_a_s: (f64, f64),
    pub t_b_s: (f64, f64),
    /// Ground coordinate: distance along the first pass's course (m).
    pub x_m: Vec<f64>,
    pub comp_a_nt: Vec<f64>,
    pub comp_b_nt: Vec<f64>,
    pub raw_a_nt: Vec<f64>,
    pub raw_b_nt: Vec<f64>,
    /// First pass minus second at each grid point.
    pub diff_comp_nt: Vec<f64>,
    pub diff_raw_nt: Vec<f64>,
    pub rms_raw_nt: f64,
    pub rms_comp_nt: f64,
    /// Mean compensated difference: the heading error over this ground.
    pub mean_comp_nt: f64,
    /// Mean ground speed of the two passes (m/s).
    pub speed_mps: f64,
    /// Shift s (m) for which the second pass, read at x − s, best matches the first (peak
    /// of their correlation, detrended); a lag τ gives s = 2·V·τ. None when flat.
    pub shift_m: Option<f64>,
    /// τ = s / (2·V) (s).
    pub tau_s: Option<f64>,
    /// 1σ of the shift from this pair's own misfit (m, [`shift_sd_m`]): how sharply the
    /// anomaly fixes it. Not the ground's share, which every pair of the flight has too.
    pub shift_sd_m: Option<f64>,
}

/// Why a flight has no pair, or its pairs: those with the `max_pairs` longest shared
/// grounds, longest first.
pub fn reciprocal_pairs(
    flight: &Flight,
    compensated_nt: &[f64],
    max_pairs: usize,
) -> Result<Vec<ReciprocalPair>, String> {
    if !flight.has_position() {
        return Err("no positions".into());
    }
    let ne = flight.local_ne_m();
    let (course, straight) = straight_course(flight, &ne);
    let legs = straight_legs(flight, &course, &straight);
    let raw = flight.environment_corrected_nt(&flight.mag_nt);
    let comp = flight.environment_corrected_nt(compensated_nt);
    // Candidates by their shared ground (cheap), then the full pair for the longest few.
    let mut found = Vec::new();
    for (x, a) in legs.iter().enumerate() {
        for b in &legs[x + 1..] {
            let d = (b.2 - a.2).rem_euclid(360.0);
            if (d - 180.0).abs() < 20.0 && near_somewhere(&ne, a, b) {
                if let Some(o) = overlap(flight, &ne, a, b) {
                    found.push(o);
                }
            }
        }
    }
    if found.is_empty() {
        return Err(format!(
            "no two straight legs of ≥ {MIN_LEG_S:.0} s in opposite directions share \
             {MIN_OVERLAP_M:.0} m of ground (within {SAME_GROUND_M:.0} m)"
        ));
    }
    found.sort_by(|p, q| (q.hi_m - q.lo_m).total_cmp(&(p.hi_m - p.lo_m)));
    found.truncate(max_pairs);
    Ok(found.iter().map(|o| pair(flight, o, &raw, &comp)).collect())
}

/// Two legs' shared ground: the rows of each over it, their ground coordinate along the
/// first leg's course, and the common extent.
struct Overlap {
    heading_a_deg: f64,
    heading_b_deg: f64,
    on_a: Vec<usize>,
    on_b: Vec<usize>,
    xa: Vec<f64>,
    xb: Vec<f64>,
    lo_m: f64,
    hi_m: f64,
}

type LegRows = (usize, usize, f64);

/// Whether the legs come within SAME_GROUND_M anywhere (each thinned to ~200 points, with
/// the thinning's spacing as margin): most opposite legs of a survey are not neighbours.
fn near_somewhere(ne: &[[f64; 2]], a: &LegRows, b: &LegRows) -> bool {
    let thin = |l: &LegRows| -> Vec<[f64; 2]> {
        let step = ((l.1 - l.0) / 200).max(1);
        (l.0..l.1).step_by(step).map(|i| ne[i]).collect()
    };
    let (ta, tb) = (thin(a), thin(b));
    let spacing = |t: &[[f64; 2]]| {
        t.windows(2)
            .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
            .fold(0.0, f64::max)
    };
    let reach = SAME_GROUND_M + spacing(&ta) + spacing(&tb);
    ta.iter()
        .any(|p| tb.iter().any(|q| (p[0] - q[0]).hypot(p[1] - q[1]) < reach))
}

fn overlap(flight: &Flight, ne: &[[f64; 2]], a: &LegRows, b: &LegRows) -> Option<Overlap> {
    // ≤ ~20 samples/s: a 1 kHz trace would make the proximity search slow for nothing.
    let every = (flight.sample_rate_hz / 20.0).floor().max(1.0) as usize;
    let on_a = same_ground_rows(ne, (a.0, a.1), (b.0, b.1), every);
    let on_b = same_ground_rows(ne, (b.0, b.1), (a.0, a.1), every);
    let first = *on_a.first()?;
    on_b.first()?;
    let dir = a.2.to_radians();
    let origin = ne[first];
    let along = |i: usize| (ne[i][0] - origin[0]) * dir.cos() + (ne[i][1] - origin[1]) * dir.sin();
    let xa: Vec<f64> = on_a.iter().map(|&i| along(i)).collect();
    let xb: Vec<f64> = on_b.iter().map(|&i| along(i)).collect();
    let extent = |x: &[f64]| {
        x.iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
                (l.min(*v), h.max(*v))
            })
    };
    let ((la, ha), (lb, hb)) = (extent(&xa), extent(&xb));
    let (lo_m, hi_m) = (la.max(lb), ha.min(hb));
    if (hi_m - lo_m).is_nan() || hi_m - lo_m < MIN_OVERLAP_M {
        return None;
    }
    Some(Overlap {
        heading_a_deg: a.2,
        heading_b_deg: b.2,
        on_a,
        on_b,
        xa,
        xb,
        lo_m,
        hi_m,
    })
}

/// Straight runs of at least MIN_LEG_S: (first row, last row + 1, mean course in degrees).
fn straight_legs(flight: &Flight, course: &[f64], straight: &[bool]) -> Vec<LegRows> {
    let min_rows = (MIN_LEG_S * flight.sample_rate_hz) as usize;
    let mut out = Vec::new();
    let mut i = 0;
    while i < straight.len() {
        if !straight[i] {
            i += 1;
            continue;
        }
        let a = i;
        while i < straight.len() && straight[i] {
            i += 1;
        }
        if i - a >= min_rows {
            // Circular mean: a leg flown due north straddles ±180° in atan2.
            let (s, c) = course[a..i]
                .iter()
                .filter(|v| v.is_finite())
                .fold((0.0, 0.0), |(s, c), v| (s + v.sin(), c + v.cos()));
            out.push((a, i, s.atan2(c).to_degrees().rem_euclid(360.0)));
        }
    }
    out
}

/// `ys` at `xs` (any order) read at each grid point by linear interpolation; NaN outside
/// the samples or across a gap wider than MAX_GAP_M.
fn on_grid(xs: &[f64], ys: &[f64], grid: &[f64]) -> Vec<f64> {
    let mut pts: Vec<(f64, f64)> = xs
        .iter()
        .zip(ys)
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .map(|(x, y)| (*x, *y))
        .collect();
    pts.sort_by(|p, q| p.0.total_cmp(&q.0));
    grid.iter()
        .map(|&g| {
            let k = pts.partition_point(|p| p.0 < g);
            if k == 0 || k == pts.len() {
                return f64::NAN;
            }
            let (p, q) = (pts[k - 1], pts[k]);
            if q.0 - p.0 > MAX_GAP_M {
                return f64::NAN;
            }
            let w = if q.0 > p.0 {
                (g - p.0) / (q.0 - p.0)
            } else {
                0.0
            };
            p.1 + w * (q.1 - p.1)
        })
        .collect()
}

fn rms(v: &[f64]) -> f64 {
    let f: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    (f.iter().map(|x| x * x).sum::<f64>() / f.len().max(1) as f64).sqrt()
}

/// The pair drawn on a common grid, and its best-aligning shift.
fn pair(flight: &Flight, o: &Overlap, raw: &[f64], comp: &[f64]) -> ReciprocalPair {
    let (on_a, on_b, xa, xb) = (&o.on_a, &o.on_b, &o.xa, &o.xb);
    let (lo, hi) = (o.lo_m, o.hi_m);
    let speed = |rows: &[usize], x: &[f64]| {
        let (i, j) = (rows[0], rows[rows.len() - 1]);
        (x[x.len() - 1] - x[0]).abs() / (flight.t_s[j] - flight.t_s[i])
    };
    let speed_mps = 0.5 * (speed(on_a, xa) + speed(on_b, xb));
    // The drawn grid: ≤ ~600 points, so the values can ride on the SVG.
    let step_m = ((hi - lo) / 600.0).max(5.0);
    let grid: Vec<f64> = (0..=((hi - lo) / step_m) as usize)
        .map(|k| lo + k as f64 * step_m)
        .collect();
    let take = |rows: &[usize], v: &[f64]| -> Vec<f64> { rows.iter().map(|&i| v[i]).collect() };
    let comp_a_nt = on_grid(xa, &take(on_a, comp), &grid);
    let comp_b_nt = on_grid(xb, &take(on_b, comp), &grid);
    let raw_a_nt = on_grid(xa, &take(on_a, raw), &grid);
    let raw_b_nt = on_grid(xb, &take(on_b, raw), &grid);
    let minus =
        |p: &[f64], q: &[f64]| -> Vec<f64> { p.iter().zip(q).map(|(x, y)| x - y).collect() };
    let diff_comp_nt = minus(&comp_a_nt, &comp_b_nt);
    let diff_raw_nt = minus(&raw_a_nt, &raw_b_nt);
    // The shift on a 1 m grid: a lag of 0.1 s at 60 m/s is 12 m.
    let fine: Vec<f64> = (0..=(hi - lo) as usize).map(|k| lo + k as f64).collect();
    let fa = on_grid(xa, &take(on_a, comp), &fine);
    let fb = on_grid(xb, &take(on_b, comp), &fine);
    let shift_m = best_shift_m(&fine, &fa, &fb);
    let spacing_m = speed_mps / flight.sample_rate_hz;
    let shift_sd_m = shift_m.and_then(|sh| shift_sd_m(&fine, &fa, &fb, sh, spacing_m));
    let span_s = |rows: &[usize]| (flight.t_s[rows[0]], flight.t_s[rows[rows.len() - 1]]);
    ReciprocalPair {
        heading_a_deg: o.heading_a_deg,
        heading_b_deg: o.heading_b_deg,
        t_a_s: span_s(on_a),
        t_b_s: span_s(on_b),
        rms_raw_nt: rms(&diff_raw_nt),
        rms_comp_nt: rms(&diff_comp_nt),
        mean_comp_nt: finite_mean(&diff_comp_nt),
        speed_mps,
        tau_s: shift_m.map(|s| s / (2.0 * speed_mps)),
        shift_m,
        shift_sd_m,
        x_m: grid,
        comp_a_nt,
        comp_b_nt,
        raw_a_nt,
        raw_b_nt,
        diff_comp_nt,
        diff_raw_nt,
    }
}

/// The shift s (m, on the 1 m grid `x`, refined by a parabola through the peak) that
/// maximises the correlation of `a(x)` with `b(x − s)`, both detrended so a heading error
/// or a diurnal drift does not pull it. None when either pass is flat or the peak is at
/// the search's edge.
pub fn best_shift_m(x: &[f64], a: &[f64], b: &[f64]) -> Option<f64> {
    let (a, b) = (detrended(x, a), detrended(x, b));
    let n = x.len() as i64;
    let max = (MAX_SHIFT_M as i64).min(n / 4);
    let corr = |s: i64| -> f64 {
        let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
        for k in 0.max(s)..n.min(n + s) {
            let (p, q) = (a[k as usize], b[(k - s) as usize]);
            if p.is_finite() && q.is_finite() {
                sab += p * q;
                saa += p * p;
                sbb += q * q;
            }
        }
        if saa > 0.0 && sbb > 0.0 {
            sab / (saa * sbb).sqrt()
        } else {
            f64::NAN
        }
    };
    let c: Vec<f64> = (-max..=max).map(corr).collect();
    let (k, &peak) = c
        .iter()
        .enumerate()
        .filter(|(_, v)| v.is_finite())
        .max_by(|p, q| p.1.total_cmp(q.1))?;
    if k == 0 || k + 1 == c.len() || peak < 0.5 {
        return None;
    }
    let (l, r) = (c[k - 1], c[k + 1]);
    let den = l - 2.0 * peak + r;
    let frac = if den < 0.0 { 0.5 * (l - r) / den } else { 0.0 };
    Some((k as i64 - max) as f64 + frac)
}

/// Half the span the anomaly's slope is read over in [`shift_sd_m`] (m): a third of the
/// shortest wavelength at 300 m (~600 m), where the difference still has 83 % of the gain.
const SLOPE_HALF_SPAN_M: f64 = 50.0;

/// 1σ of the shift `s` that aligns `b(x − s)` with `a(x)` (both on the 1 m grid `x`,
/// detrended): linearised least squares, var s = σ_e² / (N_eff · mean a′²), with e the
/// misfit left at `s` and a′ the first pass's slope, read every `spacing_m` (the samples'
/// spacing: the grid between them is interpolation), N_eff from e's lag-1 correlation
/// there. A flat anomaly (a calibration leg over quiet ground: 1.7 nT over 4 km) or a large misfit
/// leaves the shift loose. None when too few points remain.
pub fn shift_sd_m(x: &[f64], a: &[f64], b: &[f64], s: f64, spacing_m: f64) -> Option<f64> {
    let (a, b) = (detrended(x, a), detrended(x, b));
    let step = (spacing_m.round() as usize).max(1);
    // The slope over ±SLOPE_HALF_SPAN_M: over a sample spacing the sensor's noise would
    // pass for slope where the anomaly is smooth (0.014 nT over 12 m is as steep as a
    // 1.7 nT anomaly over 4 km).
    let half = (SLOPE_HALF_SPAN_M as usize).max(step);
    let k_s = s.round() as i64;
    let n = a.len() as i64;
    let (mut e, mut slope2) = (Vec::new(), 0.0);
    for k in (step as i64..n - step as i64).step_by(step) {
        let j = k - k_s;
        if j < 0 || j >= n {
            continue;
        }
        let (ku, ju) = (k as usize, j as usize);
        let (lo, hi) = (ku.saturating_sub(half), (ku + half).min(a.len() - 1));
        let slope = (a[hi] - a[lo]) / (hi - lo) as f64;
        let d = a[ku] - b[ju];
        if slope.is_finite() && d.is_finite() {
            e.push(d);
            slope2 += slope * slope;
        }
    }
    if e.len() < 10 || slope2 <= 0.0 {
        return None;
    }
    let m = e.len() as f64;
    let mean_e = e.iter().sum::<f64>() / m;
    let var_e = e.iter().map(|v| (v - mean_e).powi(2)).sum::<f64>() / m;
    let cov1 = e
        .windows(2)
        .map(|w| (w[0] - mean_e) * (w[1] - mean_e))
        .sum::<f64>()
        / (m - 1.0);
    let rho = if var_e > 0.0 {
        (cov1 / var_e).clamp(0.0, 0.99)
    } else {
        0.0
    };
    let n_eff = (m * (1.0 - rho) / (1.0 + rho)).max(1.0);
    Some((var_e / (n_eff * slope2 / m)).sqrt())
}

/// The ground's share of one pair's shift (m, 1σ): the shift two passes 10 m apart at
/// 300 m over strong geology read with neither lag nor compensation error (`mag − true
/// interference`, 24 pairs of seeds 1–6: rms 4.1 m, at most 14.8 m).
pub const PAIR_GROUND_SD_M: f64 = 4.1;
/// The ground's share of a flight's mean shift (m, 1σ): the pairs of one flight fly the
/// same lines, so their ground errors do not average away (the 4-pair means of seeds 1–6:
/// rms 2.5 m, at most 5.4 m). The floor of σ_τ, with the sampling's.
pub const GROUND_SHIFT_SD_M: f64 = 2.5;
/// A pair counts when its own shift is fixed to this (m, 1σ): a lag of 0.3 s at 60 m/s
/// is 36 m. Survey lines 10 m apart at 300 m over strong geology read ±3–7 m with a lag
/// left in, the cloverleaf's legs over quiet ground (1.7 nT over 4 km) mostly ±15–90 m.
pub const MAX_PAIR_SHIFT_SD_M: f64 = 12.0;
/// A pair further than this many of its σ from the pairs' weighted median is set aside.
pub const CLIP_SIGMAS: f64 = 3.0;
/// Fewest counted pairs for a τ: one pair has no scatter to judge it by.
pub const MIN_PAIRS: usize = 2;
/// Most pairs looked at (the longest shared grounds).
pub const MAX_WITNESS_PAIRS: usize = 8;

/// τ from a flight's reciprocal passes.
#[derive(Clone, Debug, Serialize)]
pub struct ReciprocalLag {
    /// Weighted mean of the counted pairs' τ (s): positive when the scalar reads the
    /// anomaly behind the aircraft (the scalar lags the positions).
    pub tau_s: f64,
    /// Its 1σ (s): the pairs' (their spread when it exceeds what each states), at least
    /// the floor.
    pub sigma_s: f64,
    /// The floor alone (s): the ground's and the sampling's (module notes).
    pub floor_s: f64,
    /// Each counted pair's τ (s).
    pub pair_tau_s: Vec<f64>,
    /// Pairs found but not counted: their own shift too loose (or none).
    pub loose_pairs: usize,
    /// Mean ground speed over the counted pairs (m/s).
    pub speed_mps: f64,
}

/// The pairs (τ, σ, V) within [`CLIP_SIGMAS`] of their own σ of the pairs' weighted
/// median, when at least [`MIN_PAIRS`] are: a pair that reads the manoeuvres' compensation
/// error rather than the ground (a calibration leg over quiet ground with a lag left in: shifts of
/// −128 to +193 m beside the survey lines' 8–26 m) does not measure the same τ.
fn consistent(pairs: Vec<(f64, f64, f64)>) -> Vec<(f64, f64, f64)> {
    let mut by_tau = pairs.clone();
    by_tau.sort_by(|p, q| p.0.total_cmp(&q.0));
    let total: f64 = by_tau.iter().map(|p| 1.0 / (p.1 * p.1)).sum();
    let mut acc = 0.0;
    let Some(median) = by_tau.iter().find_map(|p| {
        acc += 1.0 / (p.1 * p.1);
        (acc >= 0.5 * total).then_some(p.0)
    }) else {
        return pairs;
    };
    let kept: Vec<(f64, f64, f64)> = pairs
        .iter()
        .copied()
        .filter(|p| (p.0 - median).abs() <= CLIP_SIGMAS * p.1)
        .collect();
    if kept.len() >= MIN_PAIRS {
        kept
    } else {
        pairs
    }
}

/// τ and its uncertainty from the reciprocal passes of `compensated_nt` (the model's
/// output: the anomaly in it is where each pass read it). Err: why there is no τ (no
/// positions, fewer than [`MIN_PAIRS`] pairs whose shift is fixed to
/// [`MAX_PAIR_SHIFT_SD_M`]).
pub fn reciprocal_lag(flight: &Flight, compensated_nt: &[f64]) -> Result<ReciprocalLag, String> {
    let pairs = reciprocal_pairs(flight, compensated_nt, MAX_WITNESS_PAIRS)?;
    // (τ, shift 1σ with the ground's, V) of each pair that fixes its shift.
    let counted: Vec<(f64, f64, f64)> = pairs
        .iter()
        .filter_map(|p| Some((p.tau_s?, p.shift_sd_m?, p.speed_mps)))
        .filter(|(t, sd, v)| t.is_finite() && *sd <= MAX_PAIR_SHIFT_SD_M && *v > 0.0)
        .map(|(t, sd, v)| (t, sd.hypot(PAIR_GROUND_SD_M) / (2.0 * v), v))
        .collect();
    let counted = consistent(counted);
    let loose_pairs = pairs.len() - counted.len();
    if counted.len() < MIN_PAIRS {
        return Err(format!(
            "{} pair(s) over the same ground, {} with the shift fixed to ±{MAX_PAIR_SHIFT_SD_M:.0} m, \
             {MIN_PAIRS} needed",
            pairs.len(),
            counted.len()
        ));
    }
    let n = counted.len() as f64;
    let w: Vec<f64> = counted.iter().map(|p| 1.0 / (p.1 * p.1)).collect();
    let sw: f64 = w.iter().sum();
    let tau_s = counted.iter().zip(&w).map(|(p, w)| w * p.0).sum::<f64>() / sw;
    let speed_mps = counted.iter().map(|p| p.2).sum::<f64>() / n;
    // Pairs that scatter more than they state widen the mean's σ by √(χ²/(n−1)).
    let chi2: f64 = counted
        .iter()
        .zip(&w)
        .map(|(p, w)| w * (p.0 - tau_s).powi(2))
        .sum();
    let stat_s = (1.0 / sw).sqrt() * (chi2 / (n - 1.0)).sqrt().max(1.0);
    // The sampling: each pass's samples fall within ±V/(2·fs) of a ground point, uniformly;
    // at 10 Hz and 60 m/s (2.4 m) it is inside the ground's measured 2.5 m already.
    let sampling_m = speed_mps / flight.sample_rate_hz.max(1e-9) / 6f64.sqrt();
    let floor_s = GROUND_SHIFT_SD_M.max(sampling_m) / (2.0 * speed_mps);
    Ok(ReciprocalLag {
        tau_s,
        sigma_s: stat_s.max(floor_s),
        floor_s,
        pair_tau_s: counted.iter().map(|p| p.0).collect(),
        loose_pairs,
        speed_mps,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The first pass at x sees A(x − 12), the second A(x + 12) (a lag of 12 m each way),
    /// so the shift is +24 m; a constant offset (a heading error) does not move it.
    #[test]
    fn the_shift_is_the_bump_s_displacement() {
        let x: Vec<f64> = (0..3000).map(f64::from).collect();
        let bump = |u: f64| 40.0 * (-((u - 1500.0) / 150.0).powi(2)).exp();
        let a: Vec<f64> = x.iter().map(|&u| bump(u - 12.0)).collect();
        let b: Vec<f64> = x.iter().map(|&u| bump(u + 12.0) + 3.0).collect();
        let s = best_shift_m(&x, &a, &b).expect("shift");
        assert!((s - 24.0).abs() < 0.3, "{s}");
        let s0 = best_shift_m(&x, &a, &a).expect("shift");
        assert!(s0.abs() < 0.01, "{s0}");
        let flat = vec![1.0; x.len()];
        assert!(best_shift_m(&x, &flat, &a).is_none());
    }

    #[test]
    fn on_grid_interpolates_and_leaves_gaps() {
        let g = on_grid(&[10.0, 0.0, 100.0], &[1.0, 0.0, 5.0], &[5.0, 50.0, -1.0]);
        assert!((g[0] - 0.5).abs() < 1e-12);
        assert!(g[1].is_nan() && g[2].is_nan());
    }

    /// A sharp anomaly fixes the shift to well under a metre; the same misfit over a
    /// smooth one (a calibration leg over quiet ground) leaves it loose.
    #[test]
    fn a_smooth_anomaly_leaves_the_shift_loose() {
        let x: Vec<f64> = (0..5000).map(f64::from).collect();
        let noise = |u: f64| 0.05 * (u * 0.37).sin() + 0.05 * (u * 0.011).cos();
        let sd = |width_m: f64, peak_nt: f64| {
            let bump = |u: f64| peak_nt * (-((u - 2500.0) / width_m).powi(2)).exp();
            let a: Vec<f64> = x.iter().map(|&u| bump(u - 10.0) + noise(u)).collect();
            let b: Vec<f64> = x.iter().map(|&u| bump(u + 10.0) - noise(u)).collect();
            let s = best_shift_m(&x, &a, &b).expect("shift");
            (s, shift_sd_m(&x, &a, &b, s, 6.0).expect("sd"))
        };
        let ((s_sharp, sharp), (s_smooth, smooth)) = (sd(200.0, 40.0), sd(1500.0, 1.5));
        assert!(
            (s_sharp - 20.0).abs() < 1.0 && sharp < 0.5,
            "{s_sharp} ± {sharp}"
        );
        // The smooth pair's shift misses by more than the sharp one's σ, within its own.
        assert!(smooth > 10.0 * sharp, "{smooth} vs {sharp}");
        assert!(
            (s_smooth - 20.0).abs() < 3.0 * smooth,
            "{s_smooth} ± {smooth}"
        );
    }

    /// A pair far outside the others' consensus by its own σ is set aside.
    #[test]
    fn an_inconsistent_pair_is_set_aside() {
        let pairs = vec![
            (0.20, 0.04, 60.0),
            (0.19, 0.04, 60.0),
            (0.21, 0.05, 60.0),
            (1.5, 0.1, 60.0),
        ];
        let kept = consistent(pairs);
        assert_eq!(kept.len(), 3);
        assert!(kept.iter().all(|p| p.0 < 0.3));
    }
}
