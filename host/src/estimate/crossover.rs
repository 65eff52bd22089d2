//! Crossovers: places a flight passes twice on different headings, e.g. survey lines and
//! their tie lines. The anomaly there is the same on both passes, so the difference of the
//! two compensated values holds only what the compensation got wrong plus the diurnal
//! variation (removed with the base station) and noise.
//!
//! This is what the `rate` term needs (model.md §4, and the paper: "needs crossover points
//! of survey lines to estimate"). Eddy currents driven by flying through gradients add
//! `eᵀNe·d|B|/dt`; along a straight line `e` is nearly constant, so on one pass that term is
//! `c·d|B|/dt` — the anomaly read `c·V` metres late, which no filter tells from the anomaly
//! itself. At a crossing the two passes read it with different `c` and different
//! `d|B|/dt`, and the difference pins N down. The fit here uses the rate term's five
//! regressors `e_i·e_j·d|B|/dt` plus the isotropic `d|B|/dt`, with one intercept per
//! pair of headings (a heading-dependent level error of the compensation).

use crate::flight::Flight;
use crate::signal::stats::chi2_sf;
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

/// Names of the crossover rate coefficients (s): the `rate` term's five, then isotropic.
pub const RATE_LABELS: [&str; 6] = [
    "e1*e1*dB", "e2*e2*dB", "e1*e2*dB", "e1*e3*dB", "e2*e3*dB", "dB",
];

/// Fewest crossings the rate fit accepts (6 coefficients + intercepts + a margin).
pub const MIN_CROSSINGS: usize = 16;

/// One crossing: the two passes, each as a sample index and the fraction to the next.
#[derive(Clone, Copy, Debug)]
pub struct Crossing {
    pub a: (usize, f64),
    pub b: (usize, f64),
    pub course_a_rad: f64,
    pub course_b_rad: f64,
    /// The straight passes the two belong to (numbered along the flight).
    pub pass_a: usize,
    pub pass_b: usize,
}

/// The crossing's two courses as an unordered pair of 45° sectors: crossings of the same
/// pair of headings share one level error of the compensation.
fn heading_pair(c: &Crossing) -> (i64, i64) {
    let sector = |r: f64| {
        ((r.rem_euclid(std::f64::consts::TAU) / std::f64::consts::FRAC_PI_4).round() as i64) % 8
    };
    let (a, b) = (sector(c.course_a_rad), sector(c.course_b_rad));
    (a.min(b), a.max(b))
}

/// `values` less the mean of the values that share their key.
fn demeaned_by_key(values: &[f64], keys: &[(i64, i64)]) -> Vec<f64> {
    let mut means: std::collections::HashMap<(i64, i64), (f64, usize)> = Default::default();
    for (v, k) in values.iter().zip(keys) {
        let m = means.entry(*k).or_default();
        m.0 += v;
        m.1 += 1;
    }
    values
        .iter()
        .zip(keys)
        .map(|(v, k)| v - means[k].0 / means[k].1 as f64)
        .collect()
}

/// Most grid cells one track segment may span on an axis (64 × 50 m = 3.2 km).
const MAX_SEGMENT_CELLS: f64 = 64.0;

fn wrap_pi(a: f64) -> f64 {
    (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
}

/// Per sample of `ne` (the flight's [`Flight::local_ne_m`]): the course over ±2 s (rad from
/// north, NaN without positions) and whether the track is straight there (the course holds
/// to 3° over ±4 s, with no time gap).
pub fn straight_course(flight: &Flight, ne: &[[f64; 2]]) -> (Vec<f64>, Vec<bool>) {
    let n = flight.len();
    let t = &flight.t_s;
    let k = ((2.0 * flight.sample_rate_hz).round() as usize).max(1);
    let course_between =
        |i: usize, j: usize| -> f64 { (ne[j][1] - ne[i][1]).atan2(ne[j][0] - ne[i][0]) };
    // Course over ±k samples, and whether it holds over the wider ±2k.
    let mut course = vec![f64::NAN; n];
    let mut straight = vec![false; n];
    for i in 2 * k..n.saturating_sub(2 * k) {
        if !(ne[i - 2 * k][0].is_finite() && ne[i + 2 * k][0].is_finite()) {
            continue;
        }
        let c = course_between(i - k, i + k);
        let c1 = course_between(i - 2 * k, i);
        let c2 = course_between(i, i + 2 * k);
        course[i] = c;
        straight[i] = wrap_pi(c1 - c2).abs() < 3f64.to_radians()
            && (t[i + 2 * k] - t[i - 2 * k]) < 4.0 * k as f64 / flight.sample_rate_hz + 1.0;
    }
    (course, straight)
}

/// Crossings of straight, level parts of the track (course steady to 3° over ±4 s) whose
/// courses differ by 30–150° and that are at least 60 s apart.
pub fn find_crossings(flight: &Flight) -> Vec<Crossing> {
    let n = flight.len();
    let ne = flight.local_ne_m();
    let t = &flight.t_s;
    let (course, straight) = straight_course(flight, &ne);
    // A pass: a run of straight samples.
    let mut pass = vec![0usize; n];
    let mut id = 0;
    for i in 1..n {
        if straight[i] && !straight[i - 1] {
            id += 1;
        }
        pass[i] = id;
    }
    // Segments (i, i+1) of straight track into a 50 m grid.
    let cell = 50.0;
    let mut grid: std::collections::HashMap<(i64, i64), Vec<usize>> = Default::default();
    // Segments of ~0.1 s: at 1 kHz a 50 m cell would otherwise hold ~800 segments per pass
    // and the pair search would grow with their square.
    let step = ((flight.sample_rate_hz / 10.0).round() as usize).max(1);
    let end = |i: usize| (i + step).min(n - 1);
    for i in (0..n.saturating_sub(1)).step_by(step) {
        if !(straight[i] && straight[end(i)]) {
            continue;
        }
        let (p, q) = (ne[i], ne[end(i)]);
        let lo = [p[0].min(q[0]), p[1].min(q[1])];
        let hi = [p[0].max(q[0]), p[1].max(q[1])];
        // A ~0.1 s segment spans a cell or two; one spanning more is a bad position, and
        // the cell loop below must not be sized by it.
        if (0..2).any(|k| !(0.0..=MAX_SEGMENT_CELLS).contains(&((hi[k] - lo[k]) / cell))) {
            continue;
        }
        for cx in (lo[0] / cell).floor() as i64..=(hi[0] / cell).floor() as i64 {
            for cy in (lo[1] / cell).floor() as i64..=(hi[1] / cell).floor() as i64 {
                grid.entry((cx, cy)).or_default().push(i);
            }
        }
    }
    let mut seen = std::collections::HashSet::new();
    let mut out = Vec::new();
    for segs in grid.values() {
        for (x, &i) in segs.iter().enumerate() {
            for &j in &segs[x + 1..] {
                let (i, j) = if i < j { (i, j) } else { (j, i) };
                if t[j] - t[i] < 60.0 || !seen.insert((i, j)) {
                    continue;
                }
                let dc = wrap_pi(course[i] - course[j]).abs();
                if !(30f64.to_radians()..=150f64.to_radians()).contains(&dc) {
                    continue;
                }
                // p + s·r = q + u·w, s, u ∈ [0, 1).
                let (p, q) = (ne[i], ne[j]);
                let r = [ne[end(i)][0] - p[0], ne[end(i)][1] - p[1]];
                let w = [ne[end(j)][0] - q[0], ne[end(j)][1] - q[1]];
                let den = r[0] * w[1] - r[1] * w[0];
                if den.abs() < 1e-9 {
                    continue;
                }
                let d = [q[0] - p[0], q[1] - p[1]];
                let s = (d[0] * w[1] - d[1] * w[0]) / den;
                let u = (d[0] * r[1] - d[1] * r[0]) / den;
                if (0.0..1.0).contains(&s) && (0.0..1.0).contains(&u) {
                    // Back to a sample and the fraction to the next one.
                    let at_sample = |k: usize, f: f64| {
                        let x = f * (end(k) - k) as f64;
                        let whole = (x.floor() as usize).min(end(k) - k - 1);
                        (k + whole, x - whole as f64)
                    };
                    out.push(Crossing {
                        a: at_sample(i, s),
                        b: at_sample(j, u),
                        course_a_rad: course[i],
                        course_b_rad: course[j],
                        pass_a: pass[i],
                        pass_b: pass[j],
                    });
                }
            }
        }
    }
    out.sort_by_key(|c| (c.a.0, c.b.0));
    out
}

/// Per crossing: the time of the later pass and the difference of `value_nt` between the
/// passes with its heading pair's mean removed (what levelling would leave).
pub fn levelled_differences(
    flight: &Flight,
    value_nt: &[f64],
    crossings: &[Crossing],
) -> Vec<(f64, f64)> {
    let usable: Vec<(&Crossing, f64)> = crossings
        .iter()
        .map(|c| (c, at(value_nt, c.a) - at(value_nt, c.b)))
        .filter(|(_, d)| d.is_finite())
        .collect();
    let d: Vec<f64> = usable.iter().map(|u| u.1).collect();
    let keys: Vec<(i64, i64)> = usable.iter().map(|u| heading_pair(u.0)).collect();
    usable
        .iter()
        .zip(demeaned_by_key(&d, &keys))
        .map(|((c, _), v)| (flight.t_s[c.b.0], v))
        .collect()
}

fn at(v: &[f64], (i, f): (usize, f64)) -> f64 {
    v[i] * (1.0 - f) + v[i + 1] * f
}

/// Per sample: the six crossover rate regressors `[e1², e2², e1e2, e1e3, e2e3, 1]·d|B|/dt`
/// with `e` from the fluxgate and `d|B|/dt` a centred difference of the scalar over ±0.2 s.
pub fn rate_regressors(flight: &Flight) -> Vec<[f64; 6]> {
    let n = flight.len();
    let h = ((0.2 * flight.sample_rate_hz).round() as usize).max(1);
    (0..n)
        .map(|i| {
            let (lo, hi) = (i.saturating_sub(h), (i + h).min(n - 1));
            let dt = flight.t_s[hi] - flight.t_s[lo];
            let bdot = if dt > 0.0 {
                (flight.mag_nt[hi] - flight.mag_nt[lo]) / dt
            } else {
                f64::NAN
            };
            let f = flight.samples[i].flux_nt.map(|v| v as f64);
            let m = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
            let e = [f[0] / m, f[1] / m, f[2] / m];
            [
                e[0] * e[0] * bdot,
                e[1] * e[1] * bdot,
                e[0] * e[1] * bdot,
                e[0] * e[2] * bdot,
                e[1] * e[2] * bdot,
                bdot,
            ]
        })
        .collect()
}

/// The rate coefficients fitted to the crossover differences.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RateFit {
    /// Seconds, in [`RATE_LABELS`] order.
    pub coefficients: [f64; 6],
    pub sigmas: [f64; 6],
    pub crossings: usize,
    /// Rms of the crossover differences after the intercepts only, and after the fit (nT).
    pub rms_before_nt: f64,
    pub rms_after_nt: f64,
    /// Nested F-test of the rate coefficients against the intercepts-only fit.
    pub f_statistic: f64,
    pub p_value: f64,
    pub added_parameters: usize,
}

impl RateFit {
    /// The interference the coefficients add at every sample (nT).
    pub fn correction_nt(&self, regressors: &[[f64; 6]]) -> Vec<f64> {
        rate_correction_nt(regressors, &self.coefficients)
    }
}

/// The interference rate coefficients ([`RATE_LABELS`] order, s) add at every sample (nT;
/// 0 where a regressor is not finite).
pub fn rate_correction_nt(regressors: &[[f64; 6]], coefficients: &[f64; 6]) -> Vec<f64> {
    regressors
        .iter()
        .map(|r| {
            let v: f64 = r.iter().zip(coefficients).map(|(a, c)| a * c).sum();
            if v.is_finite() {
                v
            } else {
                0.0
            }
        })
        .collect()
}

/// Least squares with an SVD cut-off, returning the solution, residual sum of squares,
/// rank and the pseudo-inverse's diagonal (for the 1σ).
fn lstsq(a: &DMatrix<f64>, y: &DVector<f64>) -> Option<(DVector<f64>, f64, usize, Vec<f64>)> {
    // Column scaling so the cut-off is relative to each column's size.
    let norms: Vec<f64> = (0..a.ncols())
        .map(|c| a.column(c).norm().max(1e-300))
        .collect();
    let mut s = a.clone();
    for (c, nrm) in norms.iter().enumerate() {
        s.column_mut(c).scale_mut(1.0 / nrm);
    }
    let svd = s.clone().svd(true, true);
    let smax = svd.singular_values.max();
    let tol = smax * 1e-6;
    let rank = svd.singular_values.iter().filter(|&&v| v > tol).count();
    let x = svd.solve(y, tol).ok()?;
    let r = y - &s * &x;
    let v_t = svd.v_t.as_ref()?;
    let diag: Vec<f64> = (0..a.ncols())
        .map(|c| {
            let mut d = 0.0;
            for (k, sv) in svd.singular_values.iter().enumerate() {
                if *sv > tol {
                    d += (v_t[(k, c)] / sv).powi(2);
                }
            }
            d / norms[c].powi(2)
        })
        .collect();
    let x = DVector::from_iterator(a.ncols(), x.iter().zip(&norms).map(|(v, n)| v / n));
    Some((x, r.norm_squared(), rank, diag))
}

/// The error model of a crossover difference: the position error of each pass times the
/// gradient there, plus the compensation's own error. Position errors of GNSS wander with a
/// correlation time of about a minute, so crossings that share a pass share its error
/// (projected on their own gradients): a tie line flown in 30 s carries one position error
/// to every line it crosses. Treating the crossings as independent made clean surveys
/// look significant (p = 1e-6 with ties every 500 m). The position error's size relative
/// to the compensation's is chosen by likelihood from `POSITION_SIGMAS_M`.
const POSITION_CORRELATION_S: f64 = 60.0;
const POSITION_SIGMAS_M: [f64; 6] = [0.05, 0.1, 0.2, 0.5, 1.0, 2.0];
const COMPENSATION_SIGMA_NT: f64 = 0.03;
/// Prior 1σ of each element of N (s): directions the crossings' headings leave
/// unobserved stay near zero instead of taking any value along the null space.
const N_PRIOR_SIGMA_S: f64 = 0.05;

/// One crossover difference ready for the fit.
struct Row {
    d_nt: f64,
    /// Regressor differences in N space.
    x: [f64; 6],
    headings: (i64, i64),
    /// Horizontal gradient at the crossing (nT/m, north/east).
    grad: [f64; 2],
    passes: [(usize, f64); 2],
}

/// Covariance of the differences (nT²) for a position error of `sigma_pos_m` per pass.
fn covariance(rows: &[Row], sigma_pos_m: f64) -> DMatrix<f64> {
    let n = rows.len();
    DMatrix::from_fn(n, n, |k, l| {
        let (rk, rl) = (&rows[k], &rows[l]);
        let g = rk.grad[0] * rl.grad[0] + rk.grad[1] * rl.grad[1];
        let mut c = 0.0;
        for (sk, (pk, tk)) in [1.0, -1.0].iter().zip(rk.passes) {
            for (sl, (pl, tl)) in [1.0, -1.0].iter().zip(rl.passes) {
                if pk == pl {
                    c += sk * sl * (-(tk - tl).abs() / POSITION_CORRELATION_S).exp();
                }
            }
        }
        let diag = if k == l {
            COMPENSATION_SIGMA_NT.powi(2)
        } else {
            0.0
        };
        sigma_pos_m * sigma_pos_m * g * c + diag
    })
}

/// `L⁻¹·M` for the Cholesky factor of `cov`, and `ln det cov`.
fn whiten(cov: DMatrix<f64>, m: &DMatrix<f64>) -> Option<(DMatrix<f64>, f64)> {
    let ch = cov.cholesky()?;
    let l = ch.l();
    let logdet = 2.0 * l.diagonal().iter().map(|v| v.ln()).sum::<f64>();
    let w = l.solve_lower_triangular(m)?;
    Some((w, logdet))
}

/// Fits the crossover rate coefficients at `crossings` ([`find_crossings`]) to the
/// compensated scalar, levelled first (core-field change and, when recorded, the base
/// station's diurnal variation removed). `None` with fewer than [`MIN_CROSSINGS`] usable
/// crossings.
///
/// Fitted as the symmetric N itself (`[N11, N22, N33, N12, N13, N23]`, regressors
/// `e_i·e_j·d|B|/dt` with the off-diagonals twice), with a weak prior on each element, and
/// reported in the `rate` term's coordinates ([`RATE_LABELS`]: e3² eliminated).
pub fn fit_rate(
    flight: &Flight,
    crossings: &[Crossing],
    compensated_nt: &[f64],
    regressors: &[[f64; 6]],
) -> Option<RateFit> {
    let rows = crossing_rows(flight, crossings, compensated_nt, regressors);
    let mut groups: Vec<(i64, i64)> = rows.iter().map(|r| r.headings).collect();
    groups.sort();
    groups.dedup();
    let n = rows.len();
    let ng = groups.len();
    if n < MIN_CROSSINGS.max(ng + 6 + 4) {
        return None;
    }
    let raw = design_matrix(&rows, &groups);
    let w = whiten_at_likeliest_position_sigma(&rows, &raw, ng)?;
    let y = DVector::from_iterator(n, w.column(ng + 6).iter().copied());
    let a1 = w.columns(0, ng + 6).into_owned();
    let test = FTest::of(&w.columns(0, ng).into_owned(), &a1, &y)?;
    let (x, diag) = estimate_with_prior(&a1, &y, test.s2)?;
    let nm: [f64; 6] = std::array::from_fn(|k| x[ng + k]);
    let nv: [f64; 6] = std::array::from_fn(|k| test.s2 * diag[ng + k]);
    let (coefficients, sigmas) = rate_coordinates(&nm, &nv);
    // Rms of the raw differences (readable, unlike the whitened ones): about the heading
    // pairs' means before, about the fitted intercepts and N after.
    let d: Vec<f64> = rows.iter().map(|r| r.d_nt).collect();
    let keys: Vec<(i64, i64)> = rows.iter().map(|r| r.headings).collect();
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    let rms_before_nt = rms(&demeaned_by_key(&d, &keys));
    let residual: Vec<f64> = (0..n)
        .map(|r| rows[r].d_nt - (0..ng + 6).map(|c| raw[(r, c)] * x[c]).sum::<f64>())
        .collect();
    let rms_after_nt = rms(&residual);
    Some(RateFit {
        coefficients,
        sigmas,
        crossings: n,
        rms_before_nt,
        rms_after_nt,
        f_statistic: test.f,
        p_value: test.p,
        added_parameters: test.q,
    })
}

/// Per sample, the N-space regressors from the rate-term ones (e3² = 1 − e1² − e2²).
fn n_space(r: &[f64; 6]) -> [f64; 6] {
    let bdot = r[5];
    [
        r[0],
        r[1],
        bdot - r[0] - r[1],
        2.0 * r[2],
        2.0 * r[3],
        2.0 * r[4],
    ]
}

/// One row per crossing where the levelled difference, the regressor differences and the
/// horizontal gradient are all finite.
fn crossing_rows(
    flight: &Flight,
    crossings: &[Crossing],
    compensated_nt: &[f64],
    regressors: &[[f64; 6]],
) -> Vec<Row> {
    let value_nt = flight.environment_corrected_nt(compensated_nt);
    let speed = |i: usize| -> f64 {
        let s = flight.samples[i].ground_speed_mps as f64;
        if s.is_finite() && s > 1.0 {
            s
        } else {
            60.0
        }
    };
    let mut rows: Vec<Row> = Vec::new();
    for c in crossings {
        let d = at(&value_nt, c.a) - at(&value_nt, c.b);
        let interp = |(i, f): (usize, f64)| -> [f64; 6] {
            let (p, q) = (n_space(&regressors[i]), n_space(&regressors[i + 1]));
            std::array::from_fn(|k| p[k] * (1.0 - f) + q[k] * f)
        };
        let (ra, rb) = (interp(c.a), interp(c.b));
        let x: [f64; 6] = std::array::from_fn(|k| ra[k] - rb[k]);
        // Horizontal gradient from the along-track derivatives of the two passes.
        let ga = regressors[c.a.0][5] / speed(c.a.0);
        let gb = regressors[c.b.0][5] / speed(c.b.0);
        let (ua, ub) = (
            [c.course_a_rad.cos(), c.course_a_rad.sin()],
            [c.course_b_rad.cos(), c.course_b_rad.sin()],
        );
        let det = ua[0] * ub[1] - ua[1] * ub[0];
        let grad = [
            (ga * ub[1] - gb * ua[1]) / det,
            (ua[0] * gb - ub[0] * ga) / det,
        ];
        if d.is_finite() && x.iter().all(|v| v.is_finite()) && grad.iter().all(|v| v.is_finite()) {
            rows.push(Row {
                d_nt: d,
                x,
                headings: heading_pair(c),
                grad,
                passes: [(c.pass_a, flight.t_s[c.a.0]), (c.pass_b, flight.t_s[c.b.0])],
            });
        }
    }
    rows
}

/// `[intercepts per heading pair | N regressors | differences]`, a row per crossing.
fn design_matrix(rows: &[Row], groups: &[(i64, i64)]) -> DMatrix<f64> {
    let ng = groups.len();
    let group_col = |r: usize, g: usize| f64::from(u8::from(rows[r].headings == groups[g]));
    DMatrix::from_fn(rows.len(), ng + 7, |r, c| {
        if c < ng {
            group_col(r, c)
        } else if c < ng + 6 {
            rows[r].x[c - ng]
        } else {
            rows[r].d_nt
        }
    })
}

/// The design whitened at the position error's size the profile likelihood prefers (scale
/// profiled out) among [`POSITION_SIGMAS_M`].
fn whiten_at_likeliest_position_sigma(
    rows: &[Row],
    raw: &DMatrix<f64>,
    ng: usize,
) -> Option<DMatrix<f64>> {
    let n = rows.len();
    let mut best: Option<(f64, DMatrix<f64>)> = None;
    for sp in POSITION_SIGMAS_M {
        let Some((w, logdet)) = whiten(covariance(rows, sp), raw) else {
            continue;
        };
        let a1 = w.columns(0, ng + 6).into_owned();
        let y = DVector::from_iterator(n, w.column(ng + 6).iter().copied());
        let Some((_, rss, _, _)) = lstsq(&a1, &y) else {
            continue;
        };
        let nll = n as f64 * (rss / n as f64).ln() + logdet;
        if best.as_ref().is_none_or(|b| nll < b.0) {
            best = Some((nll, w));
        }
    }
    best.map(|(_, w)| w)
}

/// The F test of the intercepts-only fit (`a0`) against the one with N (`a1`).
struct FTest {
    /// Residual variance of the fit with N (whitened units).
    s2: f64,
    f: f64,
    p: f64,
    /// Parameters N adds (rank difference).
    q: usize,
}

impl FTest {
    fn of(a0: &DMatrix<f64>, a1: &DMatrix<f64>, y: &DVector<f64>) -> Option<Self> {
        let n = y.len();
        let (_, rss0, rank0, _) = lstsq(a0, y)?;
        let (_, rss1, rank1, _) = lstsq(a1, y)?;
        let q = rank1.saturating_sub(rank0);
        let dof = n.saturating_sub(rank1).max(1);
        let s2 = rss1 / dof as f64;
        let f = if q > 0 && rss1 > 0.0 {
            ((rss0 - rss1).max(0.0) / q as f64) / s2
        } else {
            0.0
        };
        let p = if q > 0 {
            chi2_sf(f * q as f64, q as f64)
        } else {
            1.0
        };
        Some(Self { s2, f, p, q })
    }
}

/// The estimate: the same whitened problem with the prior rows (in units of the fitted
/// residual scale, so the prior's weight does not depend on the assumed σ's). The
/// solution and the diagonal of its unscaled covariance.
fn estimate_with_prior(
    a1: &DMatrix<f64>,
    y: &DVector<f64>,
    s2: f64,
) -> Option<(DVector<f64>, Vec<f64>)> {
    let n = y.len();
    let ng = a1.ncols() - 6;
    let lam = s2.sqrt() / N_PRIOR_SIGMA_S;
    let a2 = DMatrix::from_fn(n + 6, ng + 6, |r, c| {
        if r < n {
            a1[(r, c)]
        } else if c == ng + (r - n) {
            lam
        } else {
            0.0
        }
    });
    let y2 = DVector::from_iterator(n + 6, y.iter().copied().chain(std::iter::repeat_n(0.0, 6)));
    let (x, _, _, diag) = lstsq(&a2, &y2)?;
    Some((x, diag))
}

/// N-space estimate and variances → rate-term coefficients and 1σ:
/// e1²(N11−N33) + e2²(N22−N33) + e1e2·2N12 + … + N33.
fn rate_coordinates(nm: &[f64; 6], nv: &[f64; 6]) -> ([f64; 6], [f64; 6]) {
    let coefficients = [
        nm[0] - nm[2],
        nm[1] - nm[2],
        2.0 * nm[3],
        2.0 * nm[4],
        2.0 * nm[5],
        nm[2],
    ];
    let sigmas = [
        (nv[0] + nv[2]).sqrt(),
        (nv[1] + nv[2]).sqrt(),
        2.0 * nv[3].sqrt(),
        2.0 * nv[4].sqrt(),
        2.0 * nv[5].sqrt(),
        nv[2].sqrt(),
    ];
    (coefficients, sigmas)
}
