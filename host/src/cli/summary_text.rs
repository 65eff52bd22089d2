//! How the commands print a summary: the text on stdout, the warnings on stderr, and the
//! warnings a `--json` document carries. Shared by `calibrate`, `compensate`, `diagnose`,
//! `report` and the several-sensor commands.

use crate::calibration::summary::Summary;

/// `v`'s `warnings` with, first, those printed on stderr as they were found (glitches,
/// impossible positions: `flight::position::warn_once`), so `--json` tells what stderr
/// tells.
pub fn with_printed_warnings(mut v: serde_json::Value) -> serde_json::Value {
    let printed = crate::flight::position::printed_warnings();
    if let Some(w) = v.get_mut("warnings").and_then(|w| w.as_array_mut()) {
        let mut all: Vec<serde_json::Value> = printed
            .into_iter()
            .map(serde_json::Value::from)
            .filter(|p| !w.contains(p))
            .collect();
        all.append(w);
        *w = all;
    }
    v
}

/// Warnings go to stderr always, whatever else is printed.
pub fn print_warnings(s: &Summary) {
    for w in &s.warnings {
        crate::errln!("warning: {w}");
    }
}

pub fn print_summary(s: &Summary) {
    crate::outln!(
        "model {} ({}), {} samples",
        s.model,
        s.method.name(),
        s.samples
    );
    if let Some(live) = &s.live {
        crate::outln!("  {}", live.text());
        crate::outln!(
            "  the figures below are over the records shown converged; the predicted error is that of the coefficients held at the end"
        );
    }
    crate::outln!(
        "  compensated rms in the manoeuvre band: {:.4} nT",
        s.compensated_band_rms_nt
    );
    if let Some(ir) = s.improvement_ratio {
        crate::outln!("  improvement ratio:          {ir:.2}");
    }
    if let Some(f) = s.fom_nt {
        crate::outln!("  figure of merit (FOM):      {f:.3} nT");
    }
    if let Some(a) = s.aircraft_fom_nt {
        crate::outln!("  aircraft-only FOM:          {a:.3} nT (compensated − KF anomaly)");
    }
    if let Some(t) = &s.fom_table {
        crate::outln!("{}", crate::calibration::fom::format_table(t));
    }
    if let Some(p) = s.predicted_error_nt {
        crate::outln!(
            "  predicted error:            {p:.4} nT rms (the coefficients' covariance, the flight's own jackknife and what the model leaves unexplained)"
        );
    }
    if let Some([lo, hi]) = s.predicted_error_range_nt {
        crate::outln!(
            "  this flight's error:        {lo:.4}–{hi:.4} nT (90 %: its error lies in few directions, so one flight may fall well below or above the rms figure)"
        );
    }
    if let Some(h) = s.unfollowed_high_frequency_nt.filter(|h| *h >= 0.001) {
        crate::outln!(
            "  high-frequency residual:    {h:.4} nT rms beyond the scalar's noise (the output's quietest minutes): interference the model does not follow, counted in the predicted error"
        );
    }
    if let Some(p) = s.predicted_band_rms_nt {
        crate::outln!(
            "  predicted band rms:         {p:.4} nT (what a flight like the calibration should show in the manoeuvre band after compensation)"
        );
    }
    if let Some(c) = &s.cross_check {
        crate::outln!(
            "  cross-check (jackknife):    Kalman filter {:.4} nT, TL18-OLS {:.4} nT, disagreement {:.4} nT: {} used",
            c.kalman_filter_jackknife_nt,
            c.tolles_lawson_jackknife_nt,
            c.disagreement_nt,
            match c.chosen {
                crate::estimate::jackknife::Estimator::KalmanFilter => "Kalman filter",
                crate::estimate::jackknife::Estimator::TollesLawsonOls => "TL18-OLS",
            }
        );
    }
    if let Some(e) = s.error_rms_nt {
        let live = if s.live.is_some() {
            " (records shown converged, each convergence's level removed)"
        } else {
            ""
        };
        crate::outln!("  error vs truth:             {e:.4} nT rms{live}");
    }
    if let Some(o) = s.oracle_floor_nt {
        crate::outln!("  oracle floor of the model:  {o:.4} nT rms (filter regressors only)");
    }
    if let Some(r) = &s.rate_crossover {
        crate::outln!(
            "  rate at {} crossovers:      differences {:.3} → {:.3} nT rms, p = {:.1e}, {}",
            r.fit.crossings,
            r.fit.rms_before_nt,
            r.fit.rms_after_nt,
            r.fit.p_value,
            if r.applied {
                "applied"
            } else {
                "not significant, not applied"
            }
        );
        for (l, (v, e)) in r
            .labels
            .iter()
            .zip(r.fit.coefficients.iter().zip(&r.fit.sigmas))
        {
            crate::outln!("    {l:<10} {v:>9.4} ± {e:.4} s");
        }
    }
}

/// A streamed run's summary as text on stdout.
pub fn print_stream_text(s: &crate::stream::StreamSummary) {
    crate::outln!(
        "model {} ({}), {} samples (streamed)",
        s.model,
        s.method.name(),
        s.samples
    );
    if let Some(p) = s.predicted_error_nt {
        crate::outln!(
            "  predicted error (filter):   {p:.4} nT rms (how well the calibration determined it)"
        );
    }
    if let Some(e) = s.error_rms_nt {
        crate::outln!("  error vs truth:             {e:.4} nT rms");
    }
    crate::outln!(
        "  not computed when streamed: {} (--stream never computes them)",
        s.not_computed.join(", ")
    );
}
