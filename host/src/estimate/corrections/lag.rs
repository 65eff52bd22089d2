//! `lag`: the scalar sensor's time tag lags the fluxgate/GPS by τ. Survey processing
//! treats that as what it is, a delay: estimate τ and re-align the scalar channel, rather
//! than the first-order Taylor term `−τ·dB/dt` (which leaves (ωτ)²-sized residuals).
//!
//! **Estimate.** For a trial τ the scalar is read at `t + τ` (fractional delay, below) and
//! fitted by least squares on the model's own regressors at `t`, in the innovation domain
//! of the anomaly-field filter (`diagnose::innovations`: the field states take the geology
//! and the diurnal drift; the scalar's innovations are refiltered per τ, the regressors'
//! once). The residual variance is smallest at the true τ. A grid over ±[`MAX_LAG_S`] in
//! 20 ms steps, then Brent's method, finds the minimum; the 1σ comes from the curvature
//! there (`var τ = 2·RSS/(n_eff·RSS'')`, `n_eff` from the residual's lag-1 correlation).
//!
//! **Band.** The scalar, its core-field change and the regressors pass the same zero-phase
//! band-pass (0.005 Hz up to `0.06 / Δ`, Δ the centred derivative's half-span: 0.6 Hz at
//! 10 Hz, 1.2 Hz at 1 kHz) and are decimated to ~10 Hz for the search. Two biases made τ
//! ≥ 0.2 s come out 10–36 ms off with the full band, because a shift of the interference
//! is, to first order, `δ·dI/dt`, which the eddy terms absorb (`d(e_i e_j)/dt·|B|` lies in
//! the span of `e_i ė_j·|B|`), leaving a flat-bottomed objective that any small
//! τ-dependent misfit moves: (1) reading white noise between samples smooths it (the
//! interpolator attenuates near Nyquist), so the residual is smaller at half-sample shifts:
//! τ = 0.2 s (2 samples at 10 Hz) came out at 0.236 s; (2) `ė` from a ±Δ difference has
//! the gain `sin ωΔ/ωΔ` (93 % at 1 Hz, 10 Hz data), a misfit that grows with frequency like
//! the shift's own signature. With the band: τ within 0–5 ms at 10 Hz and 1 ms at 1 kHz
//! (τ = 0.05/0.2/0.5 s, tests/lag_delay.rs), the error 0.79–1.33× the clean floor. A
//! 0.1–0.9 Hz band tried first kept the noise bias out but the derivative's gain error in.
//! Decimating makes the 1 kHz search as cheap as the 10 Hz one (3.5 s instead of 350 s).
//!
//! **Re-align.** `mag(t) ← mag(t + τ)` by a Kaiser-windowed sinc (±16 taps, β = 8). Why not
//! cubic: a Catmull–Rom cubic loses ~1 % of the amplitude at 0.1·fs (a 1 Hz manoeuvre at
//! 10 Hz) at half-sample offsets, i.e. ~0.1 nT of a 10 nT manoeuvre, twenty times the
//! clean flight's error; the windowed sinc is flat to < 1e-4 below 0.3·fs, is exact at
//! integer shifts (no smoothing of the scalar noise when τ is a whole number of samples),
//! and costs 33 multiply-adds a sample. Samples whose kernel would reach past the ends of
//! the flight or a missing reading become missing (the filter flags them `MAG_MISSING`).
//! The samples are taken as uniformly spaced at the flight's median rate.

use crate::estimate::innovations::{filter_columns, FieldSettings, Geometry};
use crate::estimate::kf::HOST_WINDOW;
use crate::flight::Flight;
use crate::model::corrections::ScalarLag;
use crate::model::spec::ModelSpec;
use anyhow::{bail, Context, Result};
use magcomp_core::compensator::CompensatorConfig;
use magcomp_core::epoch::EpochBuilder;
use magcomp_core::model::Term;
use magcomp_core::MagCounts;
use nalgebra::DMatrix;

/// Largest |τ| searched (s).
pub const MAX_LAG_S: f64 = 1.0;
/// Grid step of the coarse search (s): well below the period of the fastest manoeuvre
/// band content (1.1 s), so the grid cannot step over the minimum's basin.
const GRID_STEP_S: f64 = 0.02;
/// Lower edge of the band kept for the estimate (Hz): every manoeuvre and turn.
const ESTIMATE_LOW_HZ: f64 = 0.005;
/// Upper edge × the centred derivative's half-span (Hz·s): where `ė` (a ±Δ difference)
/// still has 97.6 % of the true rate's gain (module notes). 0.6 Hz at 10 Hz (Δ = 0.1 s).
const ESTIMATE_HIGH_HZ_S: f64 = 0.06;
/// Rate the band-limited columns are decimated to for the search (Hz).
const SEARCH_RATE_HZ: f64 = 10.0;
/// Half-length of the windowed-sinc kernel (samples).
const HALF_TAPS: usize = 16;
const KAISER_BETA: f64 = 8.0;

/// Smallest delay the default calibration re-aligns for (s). The estimator reads 6–9 ms
/// (2–4σ) on simulated flights without any lag (broad seeds 1, 2, 10), a bias of the
/// search, not a delay; at 10 Hz 30 ms is a third of a sample.
pub const MIN_DETECTED_LAG_S: f64 = 0.03;

/// Significance (in σ) a detected delay needs as well.
pub const DETECTED_LAG_SIGMA: f64 = 4.0;

/// The default calibration's check for a delay the model was not told of: τ when the flight
/// shows one beyond [`MIN_DETECTED_LAG_S`] and [`DETECTED_LAG_SIGMA`]σ. Unmodelled, it
/// hides in the anomaly states and in the eddy terms, where neither method's error figure
/// sees it (simulated τ = 0.3–0.5 s: 1.8–6.7 nT actual against 0.3–1.1 nT predicted).
pub fn detect(flight: &Flight, spec: &ModelSpec) -> Option<ScalarLag> {
    let l = estimate(flight, spec).ok()?;
    let significant = l.lag_s.abs() >= MIN_DETECTED_LAG_S
        && l.sigma_s.is_finite()
        && l.lag_s.abs() >= DETECTED_LAG_SIGMA * l.sigma_s;
    significant.then_some(l)
}

/// Modified Bessel function I0 (power series; converges fast for the β used here).
fn bessel_i0(x: f64) -> f64 {
    let q = x * x / 4.0;
    let (mut sum, mut term) = (1.0, 1.0);
    for k in 1..50 {
        term *= q / (k * k) as f64;
        sum += term;
        if term < 1e-17 * sum {
            break;
        }
    }
    sum
}

/// Kernel weight at offset `x` samples from the interpolation point.
fn kernel(x: f64) -> f64 {
    let h = HALF_TAPS as f64;
    if x.abs() >= h {
        return 0.0;
    }
    let sinc = if x.abs() < 1e-12 {
        1.0
    } else {
        let px = std::f64::consts::PI * x;
        px.sin() / px
    };
    let r = x / h;
    sinc * bessel_i0(KAISER_BETA * (1.0 - r * r).sqrt()) / bessel_i0(KAISER_BETA)
}

/// `y` read at fractional index `pos`; NaN when the kernel's support leaves `y` or holds a
/// missing value.
pub fn value_at(y: &[f64], pos: f64) -> f64 {
    Taps::default().value_at(y, pos)
}

/// The kernel's weights for one fractional offset, kept while the offset repeats: reading
/// a whole series at one shift computes them once per binade of the index instead of once
/// a sample (33 sines and 66 Bessel series). `pos − ⌊pos⌋` is exact and `j − pos` is the
/// rounding of the same real as `(j − i₀) − frac`, so the weights, their order of
/// summation and every value read are bit-identical to computing them afresh.
#[derive(Default)]
struct Taps {
    frac_bits: Option<u64>,
    weights: [f64; 2 * HALF_TAPS],
    sum: f64,
}

impl Taps {
    fn value_at(&mut self, y: &[f64], pos: f64) -> f64 {
        let i0 = pos.floor();
        let frac = pos - i0;
        let i0 = i0 as i64;
        if frac.abs() < 1e-12 {
            return if i0 >= 0 && (i0 as usize) < y.len() {
                y[i0 as usize]
            } else {
                f64::NAN
            };
        }
        let h = HALF_TAPS as i64;
        let (a, b) = (i0 - h + 1, i0 + h);
        if a < 0 || b >= y.len() as i64 {
            return f64::NAN;
        }
        if self.frac_bits != Some(frac.to_bits()) {
            let mut w = 0.0;
            for (m, slot) in (1 - h..=h).zip(self.weights.iter_mut()) {
                *slot = kernel(m as f64 - frac);
                w += *slot;
            }
            self.frac_bits = Some(frac.to_bits());
            self.sum = w;
        }
        let mut s = 0.0;
        for (k, v) in self.weights.iter().zip(&y[a as usize..=b as usize]) {
            s += k * v;
        }
        // Normalised by the weights' sum: a constant passes exactly.
        s / self.sum
    }
}

/// `y` advanced by `shift` samples: `out[k] = y(k + shift)`.
pub fn shifted(y: &[f64], shift: f64) -> Vec<f64> {
    let mut taps = Taps::default();
    (0..y.len())
        .map(|k| taps.value_at(y, k as f64 + shift))
        .collect()
}

/// The flight with its scalar re-aligned: `mag(t) ← mag(t + τ)`.
pub fn realign(flight: &Flight, lag_s: f64) -> Flight {
    let m0 = crate::flight::first_reading_nt(flight);
    // Relative to the first reading: the kernel's sums then run on tens of nT, not 50 000.
    let rel: Vec<f64> = flight.mag_nt.iter().map(|v| v - m0).collect();
    let out = shifted(&rel, lag_s * flight.sample_rate_hz);
    let mut f = flight.clone();
    for ((m, s), v) in f.mag_nt.iter_mut().zip(&mut f.samples).zip(out) {
        *m = v + m0;
        s.mag = MagCounts::from_nt_f64(*m);
    }
    f
}

/// The regressors of the model's terms at every sample (columns), built with the core's
/// epoch builder exactly as the filter builds them.
fn model_regressors(flight: &Flight, spec: &ModelSpec) -> Result<(Vec<Vec<f64>>, Geometry)> {
    let terms = spec.build_terms();
    let k: usize = terms.iter().map(|t| t.len()).sum();
    let mut ecfg = CompensatorConfig::for_rate(flight.sample_rate_hz as f32).epoch;
    ecfg.earth_dir_ned = flight.earth_dir_ned;
    let mut builder = EpochBuilder::<HOST_WINDOW>::new(ecfg)
        .context("the derivative window does not fit at this sample rate")?;
    let mut cols = vec![Vec::with_capacity(flight.len()); k];
    let mut buf = [0.0f32; magcomp_core::model::MAX_TERM_STATES];
    let mut geometry = Geometry {
        ds_m: Vec::with_capacity(flight.len()),
        dh_m: Vec::with_capacity(flight.len()),
    };
    let mut push = |ep: &magcomp_core::epoch::Epoch| {
        geometry.ds_m.push(ep.ds_m as f64);
        geometry.dh_m.push(ep.dh_m as f64);
        let mut c = 0;
        for t in &terms {
            let l = t.len();
            t.regressors(ep, &mut buf[..l]);
            for v in &buf[..l] {
                cols[c].push(*v as f64);
                c += 1;
            }
        }
    };
    for s in &flight.samples {
        if let Some(ep) = builder.push(s) {
            push(&ep);
        }
    }
    while let Some(ep) = builder.flush() {
        push(&ep);
    }
    if cols.iter().any(|c| c.len() != flight.len()) || geometry.ds_m.len() != flight.len() {
        bail!("internal: regressors do not cover the flight");
    }
    Ok((cols, geometry))
}

/// Brent's minimiser on [a, b] (golden section with parabolic steps). Hand-written: 40
/// lines against a solver crate's dependency tree for one 1-D minimisation.
fn brent(f: &mut dyn FnMut(f64) -> f64, mut a: f64, mut b: f64, tol: f64) -> (f64, f64) {
    const G: f64 = 0.381_966_011_250_105;
    let mut x = a + G * (b - a);
    let (mut w, mut v) = (x, x);
    let mut fx = f(x);
    let (mut fw, mut fv) = (fx, fx);
    let (mut d, mut e): (f64, f64) = (0.0, 0.0);
    for _ in 0..100 {
        let m = 0.5 * (a + b);
        let tol1 = tol + 1e-12 * x.abs();
        if (x - m).abs() <= 2.0 * tol1 - 0.5 * (b - a) {
            break;
        }
        let mut golden = true;
        if e.abs() > tol1 {
            let r = (x - w) * (fx - fv);
            let mut q = (x - v) * (fx - fw);
            let mut p = (x - v) * q - (x - w) * r;
            q = 2.0 * (q - r);
            if q > 0.0 {
                p = -p;
            }
            q = q.abs();
            if p.abs() < (0.5 * q * e).abs() && p > q * (a - x) && p < q * (b - x) {
                e = d;
                d = p / q;
                golden = false;
            }
        }
        if golden {
            e = if x < m { b - x } else { a - x };
            d = G * e;
        }
        let u = if d.abs() >= tol1 {
            x + d
        } else {
            x + tol1.copysign(d)
        };
        let fu = f(u);
        if fu <= fx {
            if u < x {
                b = x;
            } else {
                a = x;
            }
            (v, fv, w, fw, x, fx) = (w, fw, x, fx, u, fu);
        } else {
            if u < x {
                a = u;
            } else {
                b = u;
            }
            if fu <= fw || w == x {
                (v, fv, w, fw) = (w, fw, u, fu);
            } else if fu <= fv || v == x || v == w {
                (v, fv) = (u, fu);
            }
        }
    }
    (x, fx)
}

/// Estimates τ on `flight` under `spec` (see the module notes).
pub fn estimate(flight: &Flight, spec: &ModelSpec) -> Result<ScalarLag> {
    let fs = flight.sample_rate_hz;
    let n = flight.len();
    let max_shift = (MAX_LAG_S * fs).ceil() as usize + HALF_TAPS + 1;
    if n < 2 * max_shift + (120.0 * fs) as usize {
        bail!(
            "the flight is too short to estimate the scalar lag: {:.0} s, need ≥ {:.0} s",
            n as f64 / fs,
            2.0 * max_shift as f64 / fs + 120.0
        );
    }
    let (cols, geometry) = model_regressors(flight, spec)?;
    if cols.is_empty() {
        bail!("the model has no regressors to estimate the scalar lag against");
    }
    let band = BandLimited::of(flight, &cols)?;
    let near_bad = near_missing(&band.bad, max_shift);
    let search = LagSearch::new(flight, spec, band, geometry, near_bad)?;
    let (tau, f_min) = search.minimise();
    Ok(ScalarLag {
        lag_s: tau,
        sigma_s: search.sigma_s(tau, f_min),
    })
}

/// The scalar relative to its first value, its core-field change and the regressors,
/// each through the same zero-phase band-pass: it commutes with the shift and with
/// constant coefficients (module notes, **Band**).
struct BandLimited {
    cols: Vec<Vec<f64>>,
    mag_rel: Vec<f64>,
    igrf_rel: Vec<f64>,
    /// Samples without a scalar reading or with a regressor missing.
    bad: Vec<bool>,
}

impl BandLimited {
    fn of(flight: &Flight, cols: &[Vec<f64>]) -> Result<Self> {
        let fs = flight.sample_rate_hz;
        let n = flight.len();
        let half_span_s = CompensatorConfig::for_rate(fs as f32).epoch.half_width as f64 / fs;
        let band = (
            ESTIMATE_LOW_HZ,
            (ESTIMATE_HIGH_HZ_S / half_span_s).min(0.2 * fs.min(SEARCH_RATE_HZ)),
        );
        let gaps = crate::signal::bandpass::Gaps {
            breaks: &[],
            max_fill: n,
            min_len: 0,
        };
        let lp =
            |x: &[f64]| crate::signal::bandpass::bandpass_gaps(x, 4, band.0, band.1, fs, &gaps);
        let cols: Vec<Vec<f64>> = cols.iter().map(|c| lp(c)).collect::<Result<_>>()?;
        // The scalar relative to its first value, and the core-field change (at the true
        // instants: only the scalar is shifted).
        let m0 = crate::flight::first_reading_nt(flight);
        let mag_rel: Vec<f64> = flight.mag_nt.iter().map(|v| v - m0).collect();
        let y0 = crate::flight::scalar_relative_nt(flight);
        let igrf_rel: Vec<f64> = mag_rel
            .iter()
            .zip(&y0)
            .map(|(m, y)| {
                let d = m - y;
                if d.is_finite() {
                    d
                } else {
                    0.0
                }
            })
            .collect();
        let mag_rel = lp(&mag_rel)?;
        let igrf_rel = lp(&igrf_rel)?;
        let bad: Vec<bool> = (0..n)
            .map(|i| !y0[i].is_finite() || cols.iter().any(|c| !c[i].is_finite()))
            .collect();
        Ok(Self {
            cols,
            mag_rel,
            igrf_rel,
            bad,
        })
    }
}

/// One missing-sample pattern for every trial τ (the ends and whatever is within the
/// largest shift of a missing reading), so the regressors' innovations are computed once.
fn near_missing(bad: &[bool], max_shift: usize) -> Vec<bool> {
    let n = bad.len();
    let mut near_bad = vec![false; n];
    let mut last_bad: Option<usize> = None;
    for i in 0..n {
        if bad[i] {
            last_bad = Some(i);
        }
        near_bad[i] =
            i < max_shift || i + max_shift >= n || last_bad.is_some_and(|b| i - b <= max_shift);
    }
    let mut next_bad: Option<usize> = None;
    for i in (0..n).rev() {
        if bad[i] {
            next_bad = Some(i);
        }
        near_bad[i] |= next_bad.is_some_and(|b| b - i <= max_shift);
    }
    near_bad
}

/// The scalar read at t + τ on the search's (decimated) samples, less the core field's
/// change; missing where the shift could reach a missing reading.
struct ShiftedScalar {
    fs: f64,
    /// The full-rate index of each search sample.
    at: Vec<usize>,
    near_bad: Vec<bool>,
    mag_rel: Vec<f64>,
    igrf_rel: Vec<f64>,
}

impl ShiftedScalar {
    fn at(&self, tau: f64) -> Vec<f64> {
        let mut taps = Taps::default();
        self.at
            .iter()
            .map(|&k| {
                if self.near_bad[k] {
                    f64::NAN
                } else {
                    taps.value_at(&self.mag_rel, k as f64 + tau * self.fs) - self.igrf_rel[k]
                }
            })
            .collect()
    }
}

/// The regressors' innovations on the usable search samples, as the orthonormal basis
/// (the SVD's U, its non-negligible columns) the scalar is projected off.
struct RegressorBasis {
    rows: Vec<usize>,
    keep: Vec<usize>,
    u: DMatrix<f64>,
}

/// The delay search: the residual of the shifted scalar after the fit on the regressors,
/// as a function of τ.
struct LagSearch {
    scalar: ShiftedScalar,
    geometry: Geometry,
    settings: FieldSettings,
    basis: RegressorBasis,
}

impl LagSearch {
    fn new(
        flight: &Flight,
        spec: &ModelSpec,
        band: BandLimited,
        geometry: Geometry,
        near_bad: Vec<bool>,
    ) -> Result<Self> {
        let fs = flight.sample_rate_hz;
        // Decimated to ~10 Hz (the columns hold nothing above 2 Hz): the search's cost no
        // longer grows with the sample rate. The scalar is still read at full-rate positions.
        let dec = ((fs / SEARCH_RATE_HZ).floor() as usize).max(1);
        let at: Vec<usize> = (0..flight.len()).step_by(dec).collect();
        let cols: Vec<Vec<f64>> = band
            .cols
            .iter()
            .map(|c| at.iter().map(|&k| c[k]).collect())
            .collect();
        let geometry = Geometry {
            ds_m: at
                .iter()
                .map(|&k| geometry.ds_m[k.saturating_sub(dec - 1)..=k].iter().sum())
                .collect(),
            dh_m: at.iter().map(|&k| geometry.dh_m[k]).collect(),
        };
        let scalar = ShiftedScalar {
            fs,
            at,
            near_bad,
            mag_rel: band.mag_rel,
            igrf_rel: band.igrf_rel,
        };
        let settings = field_settings(flight, spec);
        let basis = regressor_basis(&scalar, &cols, &geometry, settings)?;
        Ok(Self {
            scalar,
            geometry,
            settings,
            basis,
        })
    }

    /// Residual of the scalar read at t + τ (its whitened innovations) after the least-
    /// squares fit on the regressors' (orthogonal projection: no normal-equation
    /// cancellation).
    fn residual(&self, tau: f64) -> Vec<f64> {
        let yt = self.scalar.at(tau);
        let inn_y = filter_columns(&self.geometry, &[&yt], self.settings);
        let z: Vec<f64> = self.basis.rows.iter().map(|&k| inn_y.cols[0][k]).collect();
        let mut r = z.clone();
        for &j in &self.basis.keep {
            let col = self.basis.u.column(j);
            let c: f64 = col.iter().zip(&z).map(|(a, b)| a * b).sum();
            for (rk, uk) in r.iter_mut().zip(col.iter()) {
                *rk -= c * uk;
            }
        }
        r
    }

    fn objective(&self, tau: f64) -> f64 {
        self.residual(tau).iter().map(|v| v * v).sum::<f64>() / self.basis.rows.len() as f64
    }

    /// τ and the objective there: the grid's best, refined by Brent's method.
    fn minimise(&self) -> (f64, f64) {
        let steps = (MAX_LAG_S / GRID_STEP_S).round() as i64;
        let (mut best_tau, mut best) = (0.0, f64::INFINITY);
        for k in -steps..=steps {
            let tau = k as f64 * GRID_STEP_S;
            let v = self.objective(tau);
            if v < best {
                (best_tau, best) = (tau, v);
            }
        }
        brent(
            &mut |t| self.objective(t),
            best_tau - GRID_STEP_S,
            best_tau + GRID_STEP_S,
            1e-6,
        )
    }

    /// 1σ of τ from the objective's curvature at its minimum.
    fn sigma_s(&self, tau: f64, f_min: f64) -> f64 {
        let h = 0.002;
        let curvature = (self.objective(tau + h) - 2.0 * f_min + self.objective(tau - h)) / (h * h);
        // Effective sample count of the (not quite white) residual from its lag-1
        // correlation.
        let rho = crate::signal::stats::lag1_autocorr(&self.residual(tau)).clamp(0.0, 0.99);
        let n_eff = self.basis.rows.len() as f64 * (1.0 - rho) / (1.0 + rho);
        if curvature > 0.0 {
            (2.0 * f_min / (n_eff * curvature)).sqrt()
        } else {
            f64::INFINITY
        }
    }
}

/// The anomaly-field filter's settings for the search: the scalar's noise (never below
/// 5 pT) and, with `field`, σ1 from the flight's spectrum.
fn field_settings(flight: &Flight, spec: &ModelSpec) -> FieldSettings {
    let noise_nt = {
        let s = crate::estimate::kf::estimate_noise_nt(&flight.mag_nt).unwrap_or(0.02);
        (s * s + 0.005f64.powi(2)).sqrt()
    };
    FieldSettings {
        sigma1: spec.field.then(|| {
            crate::estimate::kf::estimate_sigma1_for(flight, &vec![0.0; flight.len()])
                .unwrap_or(crate::estimate::kf::DEFAULT_SIGMA1)
        }),
        noise_nt,
    }
}

/// The regressors' innovations (filtered once, beside the unshifted scalar's, which sets
/// the rows: finite everywhere and an innovation variance within 10× the median).
fn regressor_basis(
    scalar: &ShiftedScalar,
    cols: &[Vec<f64>],
    geometry: &Geometry,
    settings: FieldSettings,
) -> Result<RegressorBasis> {
    let n = scalar.at.len();
    let y_zero = scalar.at(0.0);
    let mut columns: Vec<&[f64]> = vec![&y_zero];
    columns.extend(cols.iter().map(|c| c.as_slice()));
    let inn = filter_columns(geometry, &columns, settings);
    let med = crate::signal::stats::median(&inn.var_nt2);
    let rows: Vec<usize> = (0..n)
        .filter(|&k| inn.var_nt2[k] <= 10.0 * med && inn.cols.iter().all(|c| c[k].is_finite()))
        .collect();
    if rows.len() < 200 {
        bail!(
            "only {} usable samples to estimate the scalar lag",
            rows.len()
        );
    }
    let x = DMatrix::from_fn(rows.len(), cols.len(), |r, c| inn.cols[c + 1][rows[r]]);
    let svd = x.svd(true, false);
    let u = svd.u.context("internal: SVD without U")?;
    let smax = svd.singular_values.max();
    let keep: Vec<usize> = (0..svd.singular_values.len())
        .filter(|&j| svd.singular_values[j] > 1e-9 * smax)
        .collect();
    Ok(RegressorBasis { rows, keep, u })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A band-limited signal delayed by a fractional number of samples is recovered to well
    /// below what a cubic would give, and an integer shift is exact.
    #[test]
    fn windowed_sinc_reads_a_band_limited_signal_between_samples() {
        let fs = 10.0;
        let sig = |t: f64| 3.0 * (0.7 * t).sin() + 2.0 * (2.0 * 1.1 * t).cos();
        let y: Vec<f64> = (0..400).map(|k| sig(k as f64 / fs)).collect();
        let shift = 2.37;
        let out = shifted(&y, shift);
        let mut worst: f64 = 0.0;
        for (k, v) in out.iter().enumerate().take(380).skip(20) {
            worst = worst.max((v - sig((k as f64 + shift) / fs)).abs());
        }
        assert!(worst < 2e-3, "worst error {worst} nT on a 5 nT signal");
        // The kernel reaches 15 samples back and 16 ahead: the ends become missing.
        assert!(out[399].is_nan() && out[0].is_nan() && out[20].is_finite());
        let int = shifted(&y, 3.0);
        assert_eq!(int[10], y[13]);
        assert!(int[397].is_nan());
    }

    #[test]
    fn brent_finds_a_parabola_minimum() {
        let (x, fx) = brent(&mut |t| (t - 0.123).powi(2) + 1.0, -1.0, 1.0, 1e-8);
        assert!(
            (x - 0.123).abs() < 1e-6 && (fx - 1.0).abs() < 1e-10,
            "{x} {fx}"
        );
    }
}
