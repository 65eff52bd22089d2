//! The `magcomp report` page: for each model, measured vs modelled signal, the residual
//! with failure windows and segments, the paper's spectrum figure, per-manoeuvre FOM and
//! the coefficients with 1σ; for two or more models, the before/after comparison.

use super::qc_sheet::SheetInfo;
use super::{fmt_opt, HtmlReport, Plot, Section, Series, PALETTE};
use crate::calibration::fom::{fom_table, pattern_of, FomTable};
use crate::diagnose::{diagnose, residual_spectrum, DiagnoseOptions, Diagnosis};
use crate::flight::{scalar_relative_nt, Flight};
use crate::io::trace::Trace;
use crate::model::spec::ModelSpec;
use crate::qc::figures::{fom, improvement_ratio};
use crate::qc::truth::error_rms_nt;
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

/// The page's file name in the report directory.
pub const REPORT_PAGE: &str = "index.html";

/// Per-model results shown on the page.
struct ModelResult {
    spec: ModelSpec,
    diag: Diagnosis,
    fom_nt: Option<f64>,
    table: Option<FomTable>,
    ir: Option<f64>,
    error_nt: Option<f64>,
}

/// Error of the compensation against the simulator's truth (demeaned RMS), when present.
pub fn truth_error_nt(flight: &Flight, interference_nt: &[f64]) -> Option<f64> {
    flight
        .truth_interference_nt
        .as_ref()
        .map(|t| error_rms_nt(interference_nt, t, None))
}

/// Builds the page (diagnosing each model; `first` reuses an existing diagnosis of
/// `models[0]`) and writes `dir/index.html`. Returns the file's path.
pub fn write_report(
    trace: &Trace,
    models: &[ModelSpec],
    first: Option<&Diagnosis>,
    info: &SheetInfo,
    dir: &Path,
) -> Result<PathBuf> {
    let page = build_report(trace, models, first, info)?;
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create report directory {}", dir.display()))?;
    let path = dir.join(REPORT_PAGE);
    page.write(&path)?;
    Ok(path)
}

/// The page: the QC sheet of the first model's compensation (`qc_sheet`), then each
/// model's diagnosis. `info`: the input as a coefficient file would record it, the noise band.
pub fn build_report(
    trace: &Trace,
    models: &[ModelSpec],
    first: Option<&Diagnosis>,
    info: &SheetInfo,
) -> Result<HtmlReport> {
    if models.is_empty() {
        bail!("give at least one --model");
    }
    let mut results = Vec::new();
    for (i, spec) in models.iter().enumerate() {
        let diag = match (i, first) {
            (0, Some(d)) => d.clone(),
            _ => diagnose(trace, spec, &DiagnoseOptions::default())
                .with_context(|| format!("model '{}'", spec.text()))?,
        };
        let flight = Flight::from_trace(trace, &spec.channels(), &spec.relative_channels())?;
        let run = &diag.run;
        let table = pattern_of(&flight).and_then(|(p, source)| {
            fom_table(
                &flight,
                &p,
                source,
                &run.compensated_nt,
                Some((&run.anomaly_nt, "kf anomaly")),
            )
        });
        results.push(ModelResult {
            // Labelled manoeuvres, else the detected pattern's table (the real boxes).
            fom_nt: fom(&flight, &run.compensated_nt)
                .map(|f| f.0)
                .or(table.as_ref().map(|t| t.fom_nt)),
            table,
            ir: improvement_ratio(&flight, &run.compensated_nt),
            error_nt: truth_error_nt(&flight, &run.interference_nt),
            spec: spec.clone(),
            diag,
        });
    }
    let flight = Flight::from_trace(trace, &[], &[])?;
    let mut page = HtmlReport::new(&super::calibration::page_title(
        trace,
        info.this_flight.as_ref(),
    ))
    .paragraph(&format!(
        "{} samples at {:.0} Hz, {:.0} s. Models: {}. The residual is what the model could \
         not predict (its one-step innovation); the model expects it to be white noise of the \
         shown ±2σ size. Red bands mark time windows where it is not.",
        flight.len(),
        flight.sample_rate_hz,
        flight.t_s.last().copied().unwrap_or(0.0) - flight.t_s[0],
        models
            .iter()
            .map(|m| m.text())
            .collect::<Vec<_>>()
            .join(" | ")
    ));
    if !flight.has_position() && flight.has_track() {
        page = page.paragraph(
            "The trace has no position: the anomaly is modelled in time, at the ground speed \
             given (--speed-mps, or the trace's ground_speed column; docs/trace-format.md).",
        );
    }
    // One line per model: what the diagnosis says, so the page answers the question first.
    for r in &results {
        let verdict = match r.diag.candidates.iter().find(|c| c.significant) {
            Some(c) if c.term != crate::diagnose::RECALIBRATE => format!(
                "missing effect: {} explains {:.0} % of the residual ({}); {}",
                c.term,
                100.0 * c.explained_fraction,
                c.effect,
                r.diag.verdict()
            ),
            _ => r.diag.verdict(),
        };
        let err = r
            .error_nt
            .map(|e| format!(", error against truth {e:.4} nT"))
            .unwrap_or_default();
        page = page.paragraph(&format!(
            "{}: residual rms {:.4} nT{err}; {} time window(s) stand out; {verdict}.",
            r.spec.text(),
            r.diag.residual_rms_nt,
            r.diag.failures.len()
        ));
    }
    let r0 = &results[0];
    let pattern = pattern_of(&flight).map(|p| p.0);
    let sheet = super::qc_sheet::Sheet {
        flight: &flight,
        compensated_nt: &r0.diag.run.compensated_nt,
        info,
        coefficients: None,
        compensation: format!(
            "kf, model {}, calibrated on this flight (the diagnosis's filter run)",
            r0.spec.text()
        ),
        pattern: pattern.as_ref(),
        table: r0.table.as_ref(),
        improvement_ratio: r0.ir,
    };
    for s in super::qc_sheet::sections(&sheet) {
        page = page.section(s);
    }
    if results.len() >= 2 {
        page = page.section(comparison(&flight, &results));
    }
    for (i, r) in results.iter().enumerate() {
        for s in model_sections(&flight, r, i) {
            page = page.section(s);
        }
        page = page.section(super::calibration::overlay_section(
            trace,
            &flight,
            &r.diag.run.compensated_nt,
            &r.diag.run.interference_nt,
            &format!("overlay-{i}"),
            &format!(
                "Model {}: uncompensated, compensated and interference",
                r.spec.text()
            ),
        ));
    }
    Ok(page)
}

fn comparison(flight: &Flight, results: &[ModelResult]) -> Section {
    let header = [
        "model",
        "residual rms (nT)",
        "FOM (nT)",
        "IR",
        "error vs truth (nT)",
        "best candidate",
    ];
    let rows: Vec<Vec<String>> = results
        .iter()
        .map(|r| {
            vec![
                r.spec.text(),
                format!("{:.4}", r.diag.residual_rms_nt),
                fmt_opt(r.fom_nt, 3),
                fmt_opt(r.ir, 1),
                fmt_opt(r.error_nt, 4),
                r.diag
                    .candidates
                    .iter()
                    .find(|c| c.significant)
                    .map(|c| format!("{} ({:.0}%)", c.term, 100.0 * c.explained_fraction))
                    .unwrap_or_else(|| "none significant".into()),
            ]
        })
        .collect();
    let labels: Vec<String> = results.iter().map(|r| r.spec.text()).collect();
    let lrefs: Vec<&str> = labels.iter().map(|s| s.as_str()).collect();
    let rms: Vec<f64> = results.iter().map(|r| r.diag.residual_rms_nt).collect();
    let mut s = Section::new("Before and after")
        .paragraph(
            "Each model on the same flight. Lower residual, FOM and error are better; \
             the improvement ratio IR (std before / after compensation) is better when higher.",
        )
        .table(&header, &rows)
        .plot_sized(
            Plot::new("compare-residual-rms", "Residual rms per model")
                .y_label("residual rms (nT)")
                .bars(&lrefs, &rms, None),
            960,
            300,
        );
    if results.iter().all(|r| r.error_nt.is_some()) {
        let err: Vec<f64> = results
            .iter()
            .map(|r| r.error_nt.unwrap_or(f64::NAN))
            .collect();
        s = s.plot_sized(
            Plot::new(
                "compare-error",
                "Compensation error against truth per model",
            )
            .y_label("error rms (nT)")
            .bars(&lrefs, &err, None)
            .bar_color(PALETTE[2]),
            960,
            300,
        );
    }
    let mut p = Plot::new("compare-residual", "Residual over time, all models")
        .x_label("time (s)")
        .y_label("residual (nT)");
    for (i, r) in results.iter().enumerate() {
        p = p.series(
            Series::line(
                &r.spec.text(),
                &r.diag.series.t_s,
                &r.diag.series.residual_nt,
            )
            .color(PALETTE[i % PALETTE.len()])
            .width_px(1.0),
        );
    }
    for (label, a, b) in flight.segment_runs() {
        if label.starts_with("cal_") {
            p = p.segment(flight.t_s[a], flight.t_s[b - 1], &short_label(&label));
        }
    }
    s.plot(p)
}

/// `cal_h045_roll` → `045 roll` (fits above a short segment).
fn short_label(label: &str) -> String {
    label
        .strip_prefix("cal_h")
        .map(|r| r.replace('_', " "))
        .unwrap_or_else(|| label.to_string())
}

/// A model's sections: compare and locate, the fluxgate and crossover checks when they
/// apply, spectra, figure of merit and coefficients.
fn model_sections(flight: &Flight, r: &ModelResult, i: usize) -> Vec<Section> {
    let run = &r.diag.run;
    let title = r.spec.text();
    let mut sections = vec![compare_section(flight, r, i, &title)];
    if let Some(f) = fluxgate_section(flight, run, i, &title) {
        sections.push(f);
    }
    if let Some(c) = crossover_section(flight, run, i, &title) {
        sections.push(c);
    }
    sections.push(super::evidence::evidence_section(
        flight, &r.diag, i, &title,
    ));
    sections.push(spectra_section(flight, r, i, &title));
    sections.push(fom_section(flight, r, i, &title));
    sections
}

/// Measured against modelled, the residual with the model's ±2σ and the windows where it
/// fails, and their table.
fn compare_section(flight: &Flight, r: &ModelResult, i: usize, title: &str) -> Section {
    let d = &r.diag;
    let run = &d.run;
    let sig = signal_plot(flight, r, i, title);
    let res = residual_plot(flight, r, i, title);
    let mut s = Section::new(&format!("Model {title}: compare and locate"))
        .paragraph(&format!(
            "Residual rms {:.4} nT; mean normalised innovation squared {:.2} (1 when the \
             model's own noise level explains the residual). σ1 = {:.3e} nT/m^2.5, anomaly \
             process: {}; noise {:.4} nT. {}",
            d.residual_rms_nt,
            d.nis,
            run.sigma1,
            run.field_process,
            run.noise_nt,
            match run.predicted_error_nt {
                Some(p) => format!(
                    "The flight determined the interference to {p:.4} nT rms by the \
                     filter's own covariance (no truth used)."
                ),
                None => String::new(),
            }
        ))
        .plot(sig)
        .plot(res);
    if !d.failures.is_empty() {
        let rows: Vec<Vec<String>> = d
            .failures
            .iter()
            .map(|f| {
                vec![
                    format!("{:.1}", f.t_start),
                    format!("{:.1}", f.t_end),
                    format!("{:.4}", f.rms_nt),
                    f.label.clone(),
                ]
            })
            .collect();
        s = s.table_with_caption(
            "Time windows where the residual exceeds the flight's typical level",
            &["start (s)", "end (s)", "rms (nT)", "segment"],
            &rows,
        );
    }
    s
}

/// The scalar as measured and as modelled (interference + field), and the interference.
fn signal_plot(flight: &Flight, r: &ModelResult, i: usize, title: &str) -> Plot {
    let run = &r.diag.run;
    let t = &flight.t_s;
    let measured = scalar_relative_nt(flight);
    let modelled: Vec<f64> = run
        .interference_nt
        .iter()
        .zip(&run.anomaly_nt)
        .map(|(a, b)| a + b)
        .collect();
    Plot::new(
        &format!("signal-{i}"),
        &format!("Measured vs modelled — {title}"),
    )
    .x_label("time (s)")
    .y_label("scalar − first sample − IGRF change (nT)")
    .series(
        Series::line("measured", t, &measured)
            .color(PALETTE[7])
            .width_px(2.0),
    )
    .series(
        Series::line("modelled (interference + field)", t, &modelled)
            .color(PALETTE[0])
            .dash("5 3")
            .width_px(1.2),
    )
    .series(
        Series::line("modelled interference", t, &run.interference_nt)
            .color(PALETTE[3])
            .width_px(1.0),
    )
}

/// The residual with the model's ±2σ, the failure windows and the flight's segments.
fn residual_plot(flight: &Flight, r: &ModelResult, i: usize, title: &str) -> Plot {
    let d = &r.diag;
    let t = &flight.t_s;
    let mut res = Plot::new(
        &format!("residual-{i}"),
        &format!("Residual and where the model fails — {title}"),
    )
    .x_label("time (s)")
    .y_label("residual (nT)")
    .series(
        Series::line("residual", &d.series.t_s, &d.series.residual_nt)
            .color(PALETTE[0])
            .width_px(1.0),
    );
    let two_sd_hi: Vec<f64> = d.series.predicted_sd_nt.iter().map(|s| 2.0 * s).collect();
    let two_sd_lo: Vec<f64> = two_sd_hi.iter().map(|s| -s).collect();
    res = res
        .series(
            Series::line("model ±2σ", &d.series.t_s, &two_sd_hi)
                .color("#111")
                .dash("4 3")
                .width_px(1.0),
        )
        .series(
            Series::line("", &d.series.t_s, &two_sd_lo)
                .color("#111")
                .dash("4 3")
                .width_px(1.0),
        );
    for f in &d.failures {
        res = res.window(f.t_start, f.t_end, &format!("{:.3} nT", f.rms_nt));
    }
    for (label, a, b) in flight.segment_runs() {
        if label.starts_with("cal_") || label.starts_with("line_") {
            res = res.segment(t[a], t[b - 1], &short_label(&label));
        }
    }
    res
}

/// The along-track spectrum against σ1²/k⁶, and the residual's spectrum against the
/// model's white innovations, with the bands in excess.
fn spectra_section(flight: &Flight, r: &ModelResult, i: usize, title: &str) -> Section {
    let d = &r.diag;
    let run = &d.run;
    let mut spec = Section::new(&format!("Model {title}: spectra"));
    if let Some(p) = along_track_plot(flight, run, i) {
        spec = spec
            .paragraph(
                "Along-track spectrum of the compensated signal against the model's: the \
                 anomaly model predicts σ1²/k⁶ (the straight line, as in the paper's figure) \
                 plus white sensor noise. Power above the line at short wavelengths is \
                 interference the model left in.",
            )
            .plot(p);
    }
    let e: Vec<f64> = d
        .series
        .residual_nt
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .collect();
    let (f, p) = residual_spectrum(&e, flight.sample_rate_hz);
    if f.len() > 2 {
        let sd: Vec<f64> = d
            .series
            .predicted_sd_nt
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .collect();
        let level = 2.0 * sd.iter().map(|s| s * s).sum::<f64>()
            / sd.len().max(1) as f64
            / flight.sample_rate_hz;
        let lv = vec![level; f.len()];
        spec = spec.plot(
            Plot::new(
                &format!("residual-psd-{i}"),
                &format!("Residual spectrum vs model — {title}"),
            )
            .log_log()
            .x_label("frequency (Hz)")
            .y_label("PSD (nT²/Hz)")
            .series(Series::line("residual", &f[1..], &p[1..]).color(PALETTE[0]))
            .series(
                Series::line("model (white innovations)", &f[1..], &lv[1..])
                    .color("#111")
                    .dash("6 3"),
            ),
        );
        for b in &d.bands {
            spec = spec.paragraph(&format!(
                "{:.3}–{:.3} Hz: residual power {:.1}× what the model predicts.",
                b.f_lo_hz, b.f_hi_hz, b.excess
            ));
        }
    }
    spec
}

/// FOM per manoeuvre, the coefficients ±1σ, and the candidate terms.
fn fom_section(flight: &Flight, r: &ModelResult, i: usize, title: &str) -> Section {
    let d = &r.diag;
    let run = &d.run;
    let mut q = Section::new(&format!("Model {title}: figure of merit and coefficients"));
    if let Some((total, parts)) = fom(flight, &run.compensated_nt) {
        let labels: Vec<String> = parts.iter().map(|p| short_label(&p.label)).collect();
        let lrefs: Vec<&str> = labels.iter().map(|s| s.as_str()).collect();
        let vals: Vec<f64> = parts.iter().map(|p| p.peak_to_peak_nt).collect();
        q = q
            .paragraph(&format!(
                "FOM (sum of the 12 manoeuvres' peak-to-peak, 0.1–0.9 Hz) = {total:.3} nT; IR = {}; error against truth = {} nT.",
                fmt_opt(r.ir, 1),
                fmt_opt(r.error_nt, 4)
            ))
            .plot_sized(
                Plot::new(&format!("fom-{i}"), &format!("Peak-to-peak per manoeuvre — {title}"))
                    .y_label("peak-to-peak (nT)")
                    .bars(&lrefs, &vals, None),
                960,
                300,
            );
    }
    if !run.coefficients.is_empty() {
        let labels: Vec<String> = run
            .coefficient_names
            .iter()
            .map(|(n, u)| format!("{n} ({u})"))
            .collect();
        let lrefs: Vec<&str> = labels.iter().map(|s| s.as_str()).collect();
        q = q.plot_sized(
            Plot::new(
                &format!("coefficients-{i}"),
                &format!("Coefficients ±1σ — {title}"),
            )
            .y_label("value (unit in label)")
            .bars(&lrefs, &run.coefficients, Some(&run.coefficient_sigmas))
            .bar_color(PALETTE[4]),
            960,
            360,
        );
        let rows: Vec<Vec<String>> = run
            .coefficient_names
            .iter()
            .zip(run.coefficients.iter().zip(&run.coefficient_sigmas))
            .map(|((n, u), (c, s))| vec![n.clone(), format!("{c:.4} ± {s:.4}"), u.clone()])
            .collect();
        q = q.table(&["coefficient", "value ± 1σ", "unit"], &rows);
    }
    q
}

/// The fluxgate against the scalar: `|B_F| − (scalar − interference)` before and after the
/// 9-parameter calibration (`fluxcal`), the check that exposes a bent fluxgate the TL fit
/// hides from the compensated scalar.
fn fluxgate_section(
    flight: &Flight,
    run: &crate::estimate::kf::KfRun,
    i: usize,
    title: &str,
) -> Option<Section> {
    let fit = crate::estimate::fluxcal::fit_flight(flight, &run.interference_nt).ok()?;
    let demeaned = |v: &[f64]| {
        let fin: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
        let m = fin.iter().sum::<f64>() / fin.len().max(1) as f64;
        v.iter().map(|x| x - m).collect::<Vec<f64>>()
    };
    let raw = demeaned(&fit.residual_before_nt);
    let cal = demeaned(&fit.residual_nt);
    let plot = Plot::new(
        &format!("fluxgate-{i}"),
        &format!("Fluxgate modulus against the scalar — {title}"),
    )
    .x_label("time (s)")
    .y_label("|B_fluxgate| − B, mean removed (nT)")
    .series(
        Series::line("raw fluxgate", &flight.t_s, &raw)
            .color(PALETTE[3])
            .width_px(1.0),
    )
    .series(
        Series::line("after 9-parameter calibration", &flight.t_s, &cal)
            .color(PALETTE[0])
            .width_px(1.0),
    );
    Some(
        Section::new(&format!("Model {title}: fluxgate check"))
            .paragraph(&format!(
                "A fluxgate's bias, scale and non-orthogonality bend the direction cosines \
                 every TL regressor is built from, and the TL fit hides most of it from the \
                 compensated scalar. Its modulus does not: sd {:.1} nT raw, {:.2} nT after a \
                 9-parameter calibration (white fluxgate noise is the floor). When the \
                 diagnosis marks `fluxcal` significant, add it to the model.",
                fit.modulus_sd_before_nt, fit.modulus_sd_after_nt
            ))
            .plot(plot),
    )
}

/// Crossover differences of the compensated field (heading pairs' means removed, as
/// levelling would), and what a crossover fit of the `rate` term would leave: the check for
/// what a single pass cannot show. Only on flights with enough crossings (survey + ties).
fn crossover_section(
    flight: &Flight,
    run: &crate::estimate::kf::KfRun,
    i: usize,
    title: &str,
) -> Option<Section> {
    use crate::estimate::crossover as xo;
    let crossings = xo::find_crossings(flight);
    if crossings.len() < xo::MIN_CROSSINGS {
        return None;
    }
    let value = flight.environment_corrected_nt(&run.compensated_nt);
    let now = xo::levelled_differences(flight, &value, &crossings);
    let (t, d): (Vec<f64>, Vec<f64>) = now.iter().copied().unzip();
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    let mut plot = Plot::new(
        &format!("crossovers-{i}"),
        &format!("Crossover differences — {title}"),
    )
    .x_label("time of the later pass (s)")
    .y_label("difference between the passes, levelled (nT)")
    .series(Series::scatter("as compensated", &t, &d).color(PALETTE[3]));
    let mut text = format!(
        "At {} crossings the same anomaly is read twice on different headings; after each heading pair's mean is removed (levelling), the differences are {:.3} nT rms.",
        now.len(),
        rms(&d)
    );
    let regs = xo::rate_regressors(flight);
    if let Some(fit) = xo::fit_rate(flight, &crossings, &run.compensated_nt, &regs) {
        let corr = fit.correction_nt(&regs);
        let after: Vec<f64> = value.iter().zip(&corr).map(|(v, c)| v - c).collect();
        let later = xo::levelled_differences(flight, &after, &crossings);
        let (t2, d2): (Vec<f64>, Vec<f64>) = later.iter().copied().unzip();
        plot = plot
            .series(Series::scatter("after a crossover fit of `rate`", &t2, &d2).color(PALETTE[0]));
        text.push_str(&format!(
            " A crossover fit of the `rate` term (eddy currents from flying through gradients) would leave {:.3} nT rms (F-test p = {:.1e}{}).",
            rms(&d2),
            fit.p_value,
            if fit.p_value < crate::estimate::kf::RATE_CROSSOVER_ALPHA {
                "; significant: add `rate` to the model"
            } else {
                ", not significant"
            }
        ));
    }
    Some(
        Section::new(&format!("Model {title}: crossovers"))
            .paragraph(&text)
            .plot(plot),
    )
}

/// The paper's figure: along-track periodogram of the compensated signal against σ1²/k⁶
/// plus the white-noise floor, on a uniform distance grid (third differences, so the
/// steep red spectrum does not leak), averaged in log-spaced wavenumber bins.
fn along_track_plot(flight: &Flight, run: &crate::estimate::kf::KfRun, i: usize) -> Option<Plot> {
    use rustfft::{num_complex::Complex, FftPlanner};
    let s = flight.along_track_m();
    let z: Vec<f64> = flight
        .mag_nt
        .iter()
        .zip(&run.interference_nt)
        .map(|(m, i)| m - i)
        .collect();
    let total = *s.last()?;
    let mut ds: Vec<f64> = s
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > 0.0)
        .collect();
    if ds.len() < 64 || total.is_nan() || total <= 0.0 {
        return None;
    }
    let mid = ds.len() / 2;
    ds.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    let step = ds[mid].max(1.0);
    // More grid points than samples would be interpolation sized by the distance (a bad
    // position): no plot rather than a grid no sample fills.
    if !(0.0..=4.0 * s.len() as f64).contains(&(total / step)) {
        return None;
    }
    let nb = (total / step) as usize;
    if nb < 64 {
        return None;
    }
    let mut grid = Vec::with_capacity(nb);
    let mut a = 0usize;
    for j in 0..nb {
        let sj = j as f64 * step;
        while a + 2 < s.len() && s[a + 1] < sj {
            a += 1;
        }
        let (sa, sb) = (s[a], s[a + 1]);
        let w = if sb > sa {
            ((sj - sa) / (sb - sa)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let v = z[a] + (z[a + 1] - z[a]) * w;
        grid.push(if v.is_finite() { v } else { 0.0 });
    }
    let d3 = step * step * step;
    let y: Vec<f64> = grid
        .windows(4)
        .map(|w| (w[3] - 3.0 * w[2] + 3.0 * w[1] - w[0]) / d3)
        .collect();
    let m = y.len();
    let mut buf: Vec<Complex<f64>> = y.iter().map(|v| Complex::new(*v, 0.0)).collect();
    FftPlanner::new().plan_fft_forward(m).process(&mut buf);
    let len = m as f64 * step;
    let mut k_all = Vec::new();
    let mut p_all = Vec::new();
    for (h, c) in buf.iter().enumerate().take(m / 2).skip(1) {
        let k = 2.0 * std::f64::consts::PI * h as f64 / len;
        let half = 0.5 * k * step;
        if half > 1.2 {
            break;
        }
        let p = step / m as f64 * c.norm_sqr() * (half / half.sin()).powi(6) / k.powi(6);
        k_all.push(k);
        p_all.push(p);
    }
    // Log-spaced averaging: 12 bins per decade.
    let (mut kb, mut pb) = (Vec::new(), Vec::new());
    let mut j = 0;
    while j < k_all.len() {
        let edge = k_all[j] * 10f64.powf(1.0 / 12.0);
        let (mut sk, mut sp, mut c) = (0.0, 0.0, 0.0);
        while j < k_all.len() && k_all[j] < edge {
            sk += k_all[j].ln();
            sp += p_all[j];
            c += 1.0;
            j += 1;
        }
        kb.push((sk / c).exp());
        pb.push(sp / c);
    }
    let s1 = run.sigma1;
    let floor = run.noise_nt * run.noise_nt * step;
    let model: Vec<f64> = kb.iter().map(|k| s1 * s1 / k.powi(6) + floor).collect();
    let line: Vec<f64> = kb.iter().map(|k| s1 * s1 / k.powi(6)).collect();
    Some(
        Plot::new(
            &format!("spectrum-{i}"),
            "Along-track spectrum of the compensated signal (paper's figure)",
        )
        .log_log()
        .x_label("wavenumber k (rad/m)")
        .y_label("power (nT²·m)")
        .series(Series::line("compensated signal", &kb, &pb).color(PALETTE[0]))
        .series(
            Series::line("model σ1²/k⁶ + noise", &kb, &model)
                .color("#111")
                .dash("6 3"),
        )
        .series(
            Series::line("σ1²/k⁶", &kb, &line)
                .color(PALETTE[7])
                .dash("2 3")
                .width_px(1.0),
        ),
    )
}
