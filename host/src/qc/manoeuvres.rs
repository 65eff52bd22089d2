//! The calibration pattern found without labels: the straight legs and their headings,
//! and within each leg the manoeuvre segments (oscillations of a few degrees at
//! 0.05–0.5 Hz).
//!
//! Headings come from the track (positions), else the INS yaw, else the fluxgate: the
//! field's direction in the fluxgate frame turns about the aircraft's vertical as the
//! heading changes, so over a pattern the directions lie on a cone whose axis is the
//! vertical (the direction of least variance); the azimuth about it is the heading up to
//! a constant, reported relative to the first leg. Manoeuvres are classified roll, pitch
//! or yaw from the INS attitude. Without INS they are numbered in their order on the leg
//! (`m1`, `m2`, …): one field vector gives only two of the three rotation angles, and a
//! roll while flying along the field's horizontal direction moves it exactly as a yaw.

use crate::flight::Flight;
use crate::signal::stats::moving_mean;
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;

/// Band of the manoeuvres (Hz): periods of 2–10 s (a lower edge of 0.05 Hz lets the roll
/// into a turn ring 10 s ahead of it and hide the end of a yaw manoeuvre).
pub const MANOEUVRE_BAND_HZ: (f64, f64) = (0.1, 0.5);
/// A manoeuvre's amplitude must exceed this (deg; ~5° manoeuvres, <1° turbulence).
pub const MIN_AMPLITUDE_DEG: f64 = 1.5;
/// Heading window (s) over which a leg is straight, and the change allowed over it (deg).
const LEG_WINDOW_S: f64 = 20.0;
const LEG_MAX_TURN_DEG: f64 = 15.0;
/// A leg is extended while the heading stays this close to its median (deg): a turn
/// reaches it within ~4 s, a ±5° yaw manoeuvre keeps within it.
const LEG_EXTEND_DEG: f64 = 8.0;
/// A manoeuvre oscillates: at least this many zero crossings of its band-passed angle
/// (two cycles); the roll into a turn is one pulse.
const MIN_ZERO_CROSSINGS: usize = 4;
/// Shortest leg (s) and shortest manoeuvre (s).
const MIN_LEG_S: f64 = 40.0;
const MIN_MANOEUVRE_S: f64 = 6.0;
/// Envelope window (s) and the largest pause inside one manoeuvre (s).
const ENVELOPE_S: f64 = 5.0;
const MAX_PAUSE_S: f64 = 3.0;

/// One detected manoeuvre: rows `start..end`.
#[derive(Clone, Debug, Serialize)]
pub struct Manoeuvre {
    /// `roll`, `pitch`, `yaw` (with INS attitude), else `m1`, `m2`, … in order on the leg.
    pub kind: String,
    /// `cal_h045_roll` (absolute heading) or `cal_r090_m2` (heading relative to the first leg).
    pub label: String,
    pub start: usize,
    pub end: usize,
    pub t_start: f64,
    pub t_end: f64,
    /// Peak amplitude of the manoeuvre angle (deg; without INS: of the field direction).
    pub amplitude_deg: f64,
}

/// One straight leg with its manoeuvres.
#[derive(Clone, Debug, Serialize)]
pub struct Leg {
    /// Heading (deg, 0–360): true course, INS yaw, or relative to the first leg.
    pub heading_deg: f64,
    /// `h045` or `r090`.
    pub tag: String,
    pub start: usize,
    pub end: usize,
    pub manoeuvres: Vec<Manoeuvre>,
}

/// The calibration pattern found in a flight.
#[derive(Clone, Debug, Serialize)]
pub struct Pattern {
    /// Where the headings came from: `track`, `yaw` or `fluxgate` (relative headings).
    pub heading_source: String,
    /// Where the manoeuvre angles came from: `attitude` or `fluxgate`.
    pub manoeuvre_source: String,
    pub legs: Vec<Leg>,
}

impl Pattern {
    pub fn manoeuvres(&self) -> impl Iterator<Item = &Manoeuvre> {
        self.legs.iter().flat_map(|l| l.manoeuvres.iter())
    }
}

fn unwrap_deg(v: &mut [f64]) {
    let mut prev: Option<f64> = None;
    let mut offset = 0.0;
    for x in v.iter_mut() {
        if !x.is_finite() {
            continue;
        }
        let raw = *x;
        if let Some(p) = prev {
            let d = raw + offset - p;
            offset -= 360.0 * (d / 360.0).round();
        }
        *x = raw + offset;
        prev = Some(*x);
    }
}

fn fill_forward(v: &mut [f64]) {
    let first = v.iter().copied().find(|x| x.is_finite()).unwrap_or(0.0);
    let mut last = first;
    for x in v.iter_mut() {
        if x.is_finite() {
            last = *x;
        } else {
            *x = last;
        }
    }
}

/// The fluxgate-frame axis the field turns about (the aircraft's vertical, pointing along
/// the field's vertical component) and two horizontal axes completing a right-handed
/// frame; None when the flight does not turn enough to show it.
pub(super) fn cone_frame(flight: &Flight) -> Option<[Vector3<f64>; 3]> {
    let u: Vec<Vector3<f64>> = flight
        .samples
        .iter()
        .map(|s| Vector3::from(s.flux_nt.map(f64::from)))
        .filter(|b| b.norm().is_finite() && b.norm() > 1.0)
        .map(|b| b.normalize())
        .collect();
    if u.len() < 10 {
        return None;
    }
    let mean = u.iter().sum::<Vector3<f64>>() / u.len() as f64;
    let cov = u
        .iter()
        .map(|x| (x - mean) * (x - mean).transpose())
        .sum::<Matrix3<f64>>()
        / u.len() as f64;
    let eig = cov.symmetric_eigen();
    let mut idx = [0, 1, 2];
    idx.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    // A circle of directions: two large, similar variances (≥ 30° of heading change).
    if eig.eigenvalues[idx[1]] < 0.01 {
        return None;
    }
    let mut a: Vector3<f64> = eig.eigenvectors.column(idx[0]).into();
    if a.dot(&mean) < 0.0 {
        a = -a;
    }
    let k = (0..3)
        .min_by(|&i, &j| a[i].abs().total_cmp(&a[j].abs()))
        .unwrap_or(0);
    let h1 = a.cross(&Vector3::ith(k, 1.0)).normalize();
    let h2 = a.cross(&h1);
    Some([a, h1, h2])
}

/// Heading (deg, unwrapped) per sample and its source.
fn heading_deg(flight: &Flight) -> Option<(Vec<f64>, &'static str)> {
    let n = flight.len();
    let fs = flight.sample_rate_hz;
    if flight.has_position() {
        let ne = flight.local_ne_m();
        let k = ((2.0 * fs).round() as usize).max(1);
        let mut h: Vec<f64> = (0..n)
            .map(|i| {
                let (a, b) = (i.saturating_sub(k), (i + k).min(n - 1));
                let (dn, de) = (ne[b][0] - ne[a][0], ne[b][1] - ne[a][1]);
                if dn.hypot(de) > 1.0 {
                    de.atan2(dn).to_degrees()
                } else {
                    f64::NAN
                }
            })
            .collect();
        if h.iter().filter(|v| v.is_finite()).count() > n / 2 {
            unwrap_deg(&mut h);
            fill_forward(&mut h);
            return Some((h, "track"));
        }
    }
    let yaw: Vec<f64> = flight
        .samples
        .iter()
        .map(|s| s.attitude_deg[2] as f64)
        .collect();
    if yaw.iter().filter(|v| v.is_finite()).count() > n * 9 / 10 {
        let mut h = yaw;
        unwrap_deg(&mut h);
        fill_forward(&mut h);
        return Some((h, "yaw"));
    }
    let [_, h1, h2] = cone_frame(flight)?;
    let mut h: Vec<f64> = flight
        .samples
        .iter()
        .map(|s| {
            let b = Vector3::from(s.flux_nt.map(f64::from));
            // The field's body azimuth turns against the heading.
            -b.dot(&h2).atan2(b.dot(&h1)).to_degrees()
        })
        .collect();
    unwrap_deg(&mut h);
    fill_forward(&mut h);
    Some((h, "fluxgate"))
}

/// The manoeuvre angles (deg) per sample: roll, pitch, yaw from the INS, else the field
/// direction's azimuth (scaled to an arc) and elevation about the cone axis.
fn manoeuvre_angles(flight: &Flight) -> Option<(Vec<Vec<f64>>, &'static str)> {
    let n = flight.len();
    let att_ok = flight
        .samples
        .iter()
        .filter(|s| s.attitude_deg.iter().all(|v| v.is_finite()))
        .count()
        > n * 9 / 10;
    if att_ok {
        let mut out: Vec<Vec<f64>> = (0..3)
            .map(|k| {
                flight
                    .samples
                    .iter()
                    .map(|s| s.attitude_deg[k] as f64)
                    .collect()
            })
            .collect();
        unwrap_deg(&mut out[2]);
        return Some((out, "attitude"));
    }
    let [a, h1, h2] = cone_frame(flight)?;
    let mut az = Vec::with_capacity(n);
    let mut el = Vec::with_capacity(n);
    for s in &flight.samples {
        let b = Vector3::from(s.flux_nt.map(f64::from));
        let u = b / b.norm();
        let horiz = u.dot(&h1).hypot(u.dot(&h2));
        az.push(u.dot(&h2).atan2(u.dot(&h1)).to_degrees() * horiz);
        el.push(u.dot(&a).clamp(-1.0, 1.0).asin().to_degrees());
    }
    unwrap_deg(&mut az);
    Some((vec![az, el], "fluxgate"))
}

/// Finds the calibration pattern; None when the flight has no heading source or no
/// straight leg with manoeuvres.
pub fn detect(flight: &Flight) -> Option<Pattern> {
    let n = flight.len();
    let fs = flight.sample_rate_hz;
    if n < 10 || fs.is_nan() || fs <= 2.0 * MANOEUVRE_BAND_HZ.1 {
        return None;
    }
    let (heading, heading_source) = heading_deg(flight)?;
    let (angles, manoeuvre_source) = manoeuvre_angles(flight)?;
    let samples_of = |s: f64| ((s * fs).round() as usize).max(1);

    // Straight legs: the smoothed heading changes little over a window.
    let smooth = moving_mean(&heading, samples_of(LEG_WINDOW_S));
    let half = samples_of(LEG_WINDOW_S / 2.0);
    let straight: Vec<bool> = (0..n)
        .map(|i| {
            let (a, b) = (i.saturating_sub(half), (i + half).min(n - 1));
            (smooth[b] - smooth[a]).abs() < LEG_MAX_TURN_DEG
        })
        .collect();
    // The smoothing window shortens each leg by up to half of it at either end: extend
    // it while the heading stays within the allowed change of the leg's median.
    let legs_rows: Vec<(usize, usize)> = runs(&straight, samples_of(MIN_LEG_S))
        .into_iter()
        .map(|(mut a, mut b)| {
            let mut h: Vec<f64> = heading[a..b].to_vec();
            h.sort_by(|x, y| x.total_cmp(y));
            let med = h[h.len() / 2];
            let reach = samples_of(LEG_WINDOW_S);
            let near = |i: usize| (heading[i] - med).abs() < LEG_EXTEND_DEG;
            let (a0, b0) = (a.saturating_sub(reach), (b + reach).min(n));
            while a > a0 && near(a - 1) {
                a -= 1;
            }
            while b < b0 && near(b) {
                b += 1;
            }
            (a, b)
        })
        .collect();

    // Manoeuvre envelopes: band-passed angles, √2 × moving RMS ≈ the amplitude.
    let breaks = crate::qc::gaps::time_breaks(&flight.t_s);
    let (lo, hi) = (MANOEUVRE_BAND_HZ.0, MANOEUVRE_BAND_HZ.1.min(0.4 * fs));
    let band: Vec<Vec<f64>> = angles
        .iter()
        .map(|x| {
            let mut x = x.clone();
            fill_forward(&mut x);
            let gaps = crate::signal::bandpass::Gaps {
                breaks: &breaks,
                max_fill: crate::qc::gaps::MAX_FILL_SAMPLES,
                min_len: 64,
            };
            crate::signal::bandpass::bandpass_gaps(&x, 4, lo, hi, fs, &gaps)
                .unwrap_or_else(|_| vec![f64::NAN; n])
        })
        .collect();
    let env: Vec<Vec<f64>> = band
        .iter()
        .map(|bp| {
            let sq: Vec<f64> = bp
                .iter()
                .map(|v| if v.is_finite() { v * v } else { 0.0 })
                .collect();
            moving_mean(&sq, samples_of(ENVELOPE_S))
                .into_iter()
                .map(|m| (2.0 * m).sqrt())
                .collect()
        })
        .collect();
    // Per sample: the dominant axis when any is above the threshold.
    let dominant: Vec<Option<usize>> = (0..n)
        .map(|i| {
            let (k, v) = (0..env.len())
                .map(|k| (k, env[k][i]))
                .max_by(|a, b| a.1.total_cmp(&b.1))?;
            (v > MIN_AMPLITUDE_DEG).then_some(k)
        })
        .collect();

    // Without INS, each leg's window is split into its pitch, roll and yaw sets by the
    // body rate the fluxgate sees (`sets`); a leg that does not show them keeps `m1`, `m2`, ….
    let rates = (manoeuvre_source == "fluxgate")
        .then(|| cone_frame(flight))
        .flatten()
        .map(|frame| super::sets::fluxgate_rates(flight, &frame, (lo, hi)));
    let mut legs = Vec::new();
    let mut first_heading: Option<f64> = None;
    for (li, &(a, b)) in legs_rows.iter().enumerate() {
        // The sets may reach past the leg's ends: a roll swings the fluxgate's heading
        // beyond LEG_EXTEND_DEG, so look up to one leg window further while the smoothed
        // heading stays on the leg and before the neighbouring legs.
        let prev_end = if li > 0 { legs_rows[li - 1].1 } else { 0 };
        let next_start = legs_rows.get(li + 1).map_or(n, |l| l.0);
        let (sa, sb) = set_window(
            &smooth,
            (a, b),
            samples_of(LEG_WINDOW_S),
            (prev_end, next_start),
        );
        let segs: Vec<(String, usize, usize, f64)> = match rates
            .as_ref()
            .and_then(|r| super::sets::split_leg(r, sa, sb))
        {
            Some(parts) => parts
                .into_iter()
                // The amplitude of the field direction, as for the numbered manoeuvres.
                .map(|(k, s, e)| {
                    let amp = (s..e).flat_map(|r| env.iter().map(move |x| x[r]));
                    (k.to_string(), s, e, amp.fold(0.0, f64::max))
                })
                .collect(),
            None => axis_segments(&dominant, &band, &env, (a, b), fs, manoeuvre_source),
        };
        if segs.is_empty() {
            continue;
        }
        legs.push(make_leg(
            flight,
            &smooth,
            heading_source,
            &mut first_heading,
            (a, b),
            segs,
        ));
    }
    (!legs.is_empty()).then(|| Pattern {
        heading_source: heading_source.into(),
        manoeuvre_source: manoeuvre_source.into(),
        legs,
    })
}

/// The manoeuvres of leg rows `a..b`: runs of one dominant axis (across pauses shorter
/// than MAX_PAUSE_S) that oscillate; named by the axis with INS attitude, else `m1`, `m2`, ….
fn axis_segments(
    dominant: &[Option<usize>],
    band: &[Vec<f64>],
    env: &[Vec<f64>],
    (a, b): (usize, usize),
    fs: f64,
    manoeuvre_source: &str,
) -> Vec<(String, usize, usize, f64)> {
    let samples_of = |s: f64| ((s * fs).round() as usize).max(1);
    let mut segs = Vec::new();
    let mut i = a;
    while i < b {
        let Some(k) = dominant[i] else {
            i += 1;
            continue;
        };
        let start = i;
        let mut end = i + 1;
        let mut j = i + 1;
        while j < b && j - end <= samples_of(MAX_PAUSE_S) {
            match dominant[j] {
                Some(kk) if kk == k => end = j + 1,
                Some(_) => break,
                None => {}
            }
            j += 1;
        }
        let crossings = band[k][start..end]
            .windows(2)
            .filter(|w| w[0] * w[1] < 0.0)
            .count();
        if end - start >= samples_of(MIN_MANOEUVRE_S) && crossings >= MIN_ZERO_CROSSINGS {
            let amp = (start..end).map(|r| env[k][r]).fold(0.0, f64::max);
            let kind = if manoeuvre_source == "attitude" {
                ["roll", "pitch", "yaw"][k].to_string()
            } else {
                format!("m{}", segs.len() + 1)
            };
            segs.push((kind, start, end, amp));
        }
        i = end;
    }
    segs
}

/// Rows `a..b` widened by up to `reach` on each side, within `bounds`, while the smoothed
/// heading stays within LEG_MAX_TURN_DEG of its median over the leg.
fn set_window(
    smooth: &[f64],
    (a, b): (usize, usize),
    reach: usize,
    bounds: (usize, usize),
) -> (usize, usize) {
    let mut h: Vec<f64> = smooth[a..b].to_vec();
    h.sort_by(|x, y| x.total_cmp(y));
    let med = h[h.len() / 2];
    let near = |i: usize| (smooth[i] - med).abs() < LEG_MAX_TURN_DEG;
    let (mut sa, mut sb) = (a, b);
    while sa > a.saturating_sub(reach).max(bounds.0) && near(sa - 1) {
        sa -= 1;
    }
    while sb < (b + reach).min(bounds.1) && near(sb) {
        sb += 1;
    }
    (sa, sb)
}

/// A leg of rows `a..b` with its manoeuvres `(kind, start, end, amplitude)`, its heading the
/// mean of the smoothed heading (relative to the first leg's for the fluxgate's).
fn make_leg(
    flight: &Flight,
    smooth: &[f64],
    heading_source: &str,
    first_heading: &mut Option<f64>,
    (a, b): (usize, usize),
    segs: Vec<(String, usize, usize, f64)>,
) -> Leg {
    let mean_heading = smooth[a..b].iter().sum::<f64>() / (b - a) as f64;
    let (heading_deg, tag) = if heading_source == "fluxgate" {
        let h0 = *first_heading.get_or_insert(mean_heading);
        let r = (mean_heading - h0).rem_euclid(360.0);
        (r, format!("r{:03}", r.round() as i64 % 360))
    } else {
        let h = mean_heading.rem_euclid(360.0);
        (h, format!("h{:03}", h.round() as i64 % 360))
    };
    let manoeuvres = segs
        .into_iter()
        .map(|(kind, s, e, amp)| Manoeuvre {
            label: format!("cal_{tag}_{kind}"),
            kind,
            start: s,
            end: e,
            t_start: flight.t_s[s],
            t_end: flight.t_s[e - 1],
            amplitude_deg: amp,
        })
        .collect();
    Leg {
        heading_deg,
        tag,
        start: a,
        end: b,
        manoeuvres,
    }
}

/// Runs of `true` at least `min_len` long: (first, last + 1).
fn runs(mask: &[bool], min_len: usize) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < mask.len() {
        if mask[i] {
            let s = i;
            while i < mask.len() && mask[i] {
                i += 1;
            }
            if i - s >= min_len {
                out.push((s, i));
            }
        } else {
            i += 1;
        }
    }
    out
}
