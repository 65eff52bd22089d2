//! Reciprocal passes on the evidence page (issue 20 item 6): two straight legs flown over
//! the same ground in opposite directions, drawn against one ground coordinate. A scalar
//! lag τ reads the anomaly V·τ behind the aircraft on each pass, so the two overlays are
//! shifted by 2·V·τ and their difference looks like the anomaly's derivative; a heading
//! error is a constant offset between them.

use super::qc_sheet::{detrended, range_of, same_ground_rows, SAME_GROUND_M};
use super::{Plot, Section, Series, PALETTE};
use crate::estimate::crossover::straight_course;
use crate::flight::Flight;

/// Shortest straight leg considered (s).
const MIN_LEG_S: f64 = 30.0;
/// Least ground the two passes must share for a plot and a shift (m).
const MIN_OVERLAP_M: f64 = 500.0;
/// Largest along-track shift searched (m): τ up to ~1 s at 100 m/s.
const MAX_SHIFT_M: f64 = 200.0;
/// Pairs drawn per model (the longest overlaps).
const MAX_PAIRS: usize = 3;
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
}

/// Why a flight has no pair to show, or its pairs.
pub fn reciprocal_pairs(
    flight: &Flight,
    compensated_nt: &[f64],
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
    found.truncate(MAX_PAIRS);
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

fn mean(v: &[f64]) -> f64 {
    let f: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    f.iter().sum::<f64>() / f.len().max(1) as f64
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
    let span_s = |rows: &[usize]| (flight.t_s[rows[0]], flight.t_s[rows[rows.len() - 1]]);
    ReciprocalPair {
        heading_a_deg: o.heading_a_deg,
        heading_b_deg: o.heading_b_deg,
        t_a_s: span_s(on_a),
        t_b_s: span_s(on_b),
        rms_raw_nt: rms(&diff_raw_nt),
        rms_comp_nt: rms(&diff_comp_nt),
        mean_comp_nt: mean(&diff_comp_nt),
        speed_mps,
        tau_s: shift_m.map(|s| s / (2.0 * speed_mps)),
        shift_m,
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

fn signed(v: Option<f64>, digits: usize) -> String {
    v.map_or("–".into(), |x| format!("{x:+.digits$}"))
}

/// The evidence section's reciprocal-pass part for the model titled `title` (`i`-th).
pub(super) fn reciprocal_part(
    mut s: Section,
    flight: &Flight,
    compensated_nt: &[f64],
    i: usize,
    title: &str,
) -> Section {
    let pairs = match reciprocal_pairs(flight, compensated_nt) {
        Ok(p) => p,
        Err(why) => return s.paragraph(&format!("Reciprocal passes: none to plot ({why}).")),
    };
    s = s.paragraph(
        "Reciprocal passes: two straight legs over the same ground in opposite directions, \
         against the distance along the first leg's course. A scalar lag τ reads the \
         anomaly V·τ behind the aircraft on each pass: the two compensated lines are \
         shifted by 2·V·τ (the second pass read at x − shift matches the first) and their \
         difference has the shape of the anomaly's slope. A heading error is a constant \
         offset: the mean difference. The uncompensated passes are drawn faded, moved as a \
         whole to the compensated level.",
    );
    for (k, p) in pairs.iter().enumerate() {
        s = pair_plots(s, p, i, k, title);
    }
    s
}

fn pair_plots(mut s: Section, p: &ReciprocalPair, i: usize, k: usize, title: &str) -> Section {
    let name = format!(
        "{:03.0}° (t {:.0}–{:.0} s) and {:03.0}° (t {:.0}–{:.0} s)",
        p.heading_a_deg, p.t_a_s.0, p.t_a_s.1, p.heading_b_deg, p.t_b_s.0, p.t_b_s.1
    );
    let span_m = p.x_m.last().unwrap_or(&0.0) - p.x_m.first().unwrap_or(&0.0);
    s = s.paragraph(&format!(
        "Pair {}: {name}, {:.1} km of shared ground (within {SAME_GROUND_M:.0} m). \
         Difference rms {:.2} → {:.3} nT (uncompensated → compensated), mean {:+.3} nT \
         (the heading error). Best-aligning shift {} m: τ = shift / (2·V) = {} s at \
         V = {:.1} m/s.",
        k + 1,
        span_m / 1000.0,
        p.rms_raw_nt,
        p.rms_comp_nt,
        p.mean_comp_nt,
        signed(p.shift_m, 1),
        signed(p.tau_s, 3),
        p.speed_mps
    ));
    // The raw passes carry the aircraft's heading effect (tens to hundreds of nT): moved
    // as a whole to the compensated level so both fit one axis.
    let level = mean(&[mean(&p.comp_a_nt), mean(&p.comp_b_nt)])
        - mean(&[mean(&p.raw_a_nt), mean(&p.raw_b_nt)]);
    let moved = |v: &[f64]| -> Vec<f64> { v.iter().map(|x| x + level).collect() };
    let data = |plot: Plot| {
        plot.data("heading-a-deg", &format!("{:.1}", p.heading_a_deg))
            .data("heading-b-deg", &format!("{:.1}", p.heading_b_deg))
            .data("rms-raw-nt", &format!("{:.4}", p.rms_raw_nt))
            .data("rms-comp-nt", &format!("{:.4}", p.rms_comp_nt))
            .data("speed-mps", &format!("{:.3}", p.speed_mps))
            .data(
                "shift-m",
                &p.shift_m.map_or("NaN".into(), |v| format!("{v:.3}")),
            )
            .data(
                "tau-s",
                &p.tau_s.map_or("NaN".into(), |v| format!("{v:.4}")),
            )
    };
    let overlay = Plot::new(
        &format!("reciprocal-{i}-{k}"),
        &format!("Reciprocal passes {name} — {title}"),
    )
    .x_label("ground along the first pass's course (m)")
    .y_label("field, core and diurnal removed (nT)")
    .series(
        Series::line("uncompensated, first", &p.x_m, &moved(&p.raw_a_nt))
            .color("#9ecae1")
            .width_px(1.0),
    )
    .series(
        Series::line("uncompensated, second", &p.x_m, &moved(&p.raw_b_nt))
            .color("#fcbba1")
            .width_px(1.0),
    )
    .series(
        Series::line("compensated, first", &p.x_m, &p.comp_a_nt)
            .color(PALETTE[0])
            .width_px(1.5)
            .with_values(),
    )
    .series(
        Series::line("compensated, second", &p.x_m, &p.comp_b_nt)
            .color(PALETTE[1])
            .width_px(1.5)
            .dash("5 3")
            .with_values(),
    );
    s = s.plot(data(overlay));
    let mut diff = Plot::new(
        &format!("reciprocal-diff-{i}-{k}"),
        &format!("First minus second pass — {title}"),
    )
    .x_label("ground along the first pass's course (m)")
    .y_label("difference (nT)")
    .series(
        Series::line(
            "uncompensated (may run off the axis)",
            &p.x_m,
            &p.diff_raw_nt,
        )
        .color("#c7c7c7")
        .width_px(1.0),
    )
    .series(
        Series::line("compensated", &p.x_m, &p.diff_comp_nt)
            .color(PALETTE[2])
            .width_px(1.5)
            .with_values(),
    );
    // The uncompensated difference can be far larger: the axis holds the compensated one
    // and 0, and the uncompensated only when it is within 3× of that.
    let comp = range_of(&p.diff_comp_nt);
    let both = range_of(&[p.diff_comp_nt.as_slice(), &p.diff_raw_nt].concat());
    if let (Some((lo, hi)), Some((blo, bhi))) = (comp, both) {
        let (lo, hi) = if bhi - blo <= 3.0 * (hi - lo) {
            (blo, bhi)
        } else {
            (lo, hi)
        };
        diff = diff.y_range(lo.min(0.0), hi.max(0.0));
    }
    s.plot(data(diff))
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
}
