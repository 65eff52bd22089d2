//! Where the model fails: time windows, frequency bands and labelled segments of the
//! residual against what the model itself predicts.

use super::{BandFailure, Failure, SegmentStat};
use crate::flight::Flight;
use crate::signal::stats::{chi2_isf, lag1_autocorr, median};

/// Label of the rows a..b: the segment, or the first and last segment it spans.
pub(crate) fn span_label(flight: &Flight, t0: f64, t1: f64) -> String {
    let runs = flight.segment_runs();
    let hit: Vec<&String> = runs
        .iter()
        .filter(|(_, a, b)| flight.t_s[*a] < t1 && flight.t_s[*b - 1] >= t0)
        .map(|(l, _, _)| l)
        .collect();
    match hit.as_slice() {
        [] => format!("t = {t0:.0}–{t1:.0} s"),
        [one] => (*one).clone(),
        [first, .., last] => format!("{first} … {last}"),
    }
}

/// Windows whose residual mean square exceeds the flight's typical (median) window level
/// by more than a χ² bound with the window's effective sample count (Bonferroni over the
/// windows), and by at least 3×; adjacent windows are merged.
pub(crate) fn time_failures(flight: &Flight, t: &[f64], e: &[f64], window_s: f64) -> Vec<Failure> {
    if t.len() < 10 {
        return Vec::new();
    }
    let (t0, t1) = (t[0], t[t.len() - 1]);
    let nw = (((t1 - t0) / window_s).floor() as usize).max(1);
    let mut ms = vec![0.0f64; nw];
    let mut cnt = vec![0usize; nw];
    for (ti, ei) in t.iter().zip(e) {
        let w = (((ti - t0) / window_s) as usize).min(nw - 1);
        ms[w] += ei * ei;
        cnt[w] += 1;
    }
    for (m, c) in ms.iter_mut().zip(&cnt) {
        *m = if *c > 0 { *m / *c as f64 } else { f64::NAN };
    }
    let typical = median(&ms);
    if typical.is_nan() || typical <= 0.0 {
        return Vec::new();
    }
    let rho = lag1_autocorr(e).clamp(0.0, 0.99);
    let per = t.len() as f64 / nw as f64;
    let n_eff = (per * (1.0 - rho) / (1.0 + rho)).max(2.0);
    let bound = (chi2_isf(0.01 / nw as f64, n_eff) / n_eff).max(3.0);
    let bad: Vec<bool> = ms.iter().map(|m| *m > typical * bound).collect();
    let mut out = Vec::new();
    let mut w = 0;
    while w < nw {
        if !bad[w] {
            w += 1;
            continue;
        }
        let start = w;
        while w < nw && bad[w] {
            w += 1;
        }
        let ws = t0 + start as f64 * window_s;
        let we = if w == nw {
            t1
        } else {
            t0 + w as f64 * window_s
        };
        let (mut s, mut c) = (0.0, 0usize);
        for (ti, ei) in t.iter().zip(e) {
            if *ti >= ws && *ti <= we {
                s += ei * ei;
                c += 1;
            }
        }
        out.push(Failure {
            t_start: ws,
            t_end: we,
            rms_nt: (s / c.max(1) as f64).sqrt(),
            label: span_label(flight, ws, we),
        });
    }
    out
}

/// Residual power spectrum (Welch, Hann, 1024-sample segments) against the model's
/// expectation (white innovations of variance S): bands where it exceeds 3× are listed.
pub fn residual_spectrum(e: &[f64], fs: f64) -> (Vec<f64>, Vec<f64>) {
    use rustfft::{num_complex::Complex, FftPlanner};
    let seg = 1024.min(e.len().next_power_of_two() / 2).max(16);
    if e.len() < seg {
        return (Vec::new(), Vec::new());
    }
    let win: Vec<f64> = (0..seg)
        .map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / seg as f64).cos())
        .collect();
    let wss: f64 = win.iter().map(|w| w * w).sum();
    let fft = FftPlanner::new().plan_fft_forward(seg);
    let mut acc = vec![0.0f64; seg / 2 + 1];
    let mut count = 0usize;
    let mut start = 0;
    while start + seg <= e.len() {
        let x = &e[start..start + seg];
        let mean = x.iter().sum::<f64>() / seg as f64;
        let mut buf: Vec<Complex<f64>> = x
            .iter()
            .zip(&win)
            .map(|(v, w)| Complex::new((v - mean) * w, 0.0))
            .collect();
        fft.process(&mut buf);
        for (a, c) in acc.iter_mut().zip(&buf) {
            *a += c.norm_sqr();
        }
        count += 1;
        start += seg / 2;
    }
    let f: Vec<f64> = (0..acc.len()).map(|i| i as f64 * fs / seg as f64).collect();
    // One-sided density (nT²/Hz).
    let p: Vec<f64> = acc
        .iter()
        .enumerate()
        .map(|(i, a)| {
            let one_sided = if i == 0 || i == seg / 2 { 1.0 } else { 2.0 };
            one_sided * a / (count as f64 * wss * fs)
        })
        .collect();
    (f, p)
}

/// Every octave band's residual power over the model's predicted power (from 0.01 Hz).
pub(crate) fn band_failures(e: &[f64], sd: &[f64], fs: f64) -> Vec<BandFailure> {
    let (f, p) = residual_spectrum(e, fs);
    if f.len() < 8 {
        return Vec::new();
    }
    let mean_var = sd.iter().map(|s| s * s).sum::<f64>() / sd.len() as f64;
    let level = 2.0 * mean_var / fs;
    // Octave bands from 0.01 Hz to Nyquist.
    let mut out = Vec::new();
    let mut lo = 0.01f64;
    while lo < fs / 2.0 {
        let hi = (lo * 2.0).min(fs / 2.0);
        let sel: Vec<f64> = f
            .iter()
            .zip(&p)
            .filter(|(fi, _)| **fi >= lo && **fi < hi)
            .map(|(_, pi)| *pi)
            .collect();
        if !sel.is_empty() {
            let excess = sel.iter().sum::<f64>() / sel.len() as f64 / level;
            out.push(BandFailure {
                f_lo_hz: lo,
                f_hi_hz: hi,
                excess,
            });
        }
        lo = hi;
    }
    out
}

pub(crate) fn segment_stats(
    flight: &Flight,
    rows: &[usize],
    e: &[f64],
    nis_k: &[f64],
) -> Vec<SegmentStat> {
    let mut out = Vec::new();
    for (label, a, b) in flight.segment_runs() {
        let lo = rows.partition_point(|&k| k < a);
        let hi = rows.partition_point(|&k| k < b);
        if hi <= lo {
            continue;
        }
        let r = &e[lo..hi];
        out.push(SegmentStat {
            label,
            t_start: flight.t_s[a],
            t_end: flight.t_s[b - 1],
            rms_nt: (r.iter().map(|x| x * x).sum::<f64>() / r.len() as f64).sqrt(),
            nis: nis_k[lo..hi].iter().sum::<f64>() / (hi - lo) as f64,
        });
    }
    out
}
