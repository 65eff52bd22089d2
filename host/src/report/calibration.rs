//! The report of one compensation as applied to a flight: a coefficient file (`report
//! --coeffs`), or a method fitted on the flight itself (`--method tl`, or the Kalman filter
//! at an assumed ground speed). The implausible-coefficients warnings (`calibration::applied`) come
//! first, then the figures, MagNav's `plot_mag_c` overlay per line (uncompensated,
//! compensated and interference against time), the FOM table and the coefficients.

use super::{fmt_opt, HtmlReport, Plot, Section, Series, PALETTE};
use crate::calibration::result::Compensation;
use crate::calibration::summary::Summary;
use crate::flight::Flight;
use crate::io::trace::Trace;

/// Most lines drawn, one plot each; the rest are named but not drawn (the page would
/// weigh megabytes on a whole survey).
pub const MAX_LINE_PLOTS: usize = 40;

/// Names the line column may have (as `input` selects `--lines` by).
const LINE_COLUMNS: &[&str] = &["line", "LINE"];

/// One compensation of a flight and what the page says about where it came from.
pub struct Evaluation<'a> {
    pub flight: &'a Flight,
    pub comp: &'a Compensation,
    pub summary: &'a Summary,
    /// E.g. "coefficients from cal.json" or "fitted on this flight".
    pub source: String,
    /// This flight as a coefficient file would record it (the QC sheet's metadata).
    pub info: &'a super::qc_sheet::SheetInfo,
    /// The applied coefficient file's provenance; None when fitted on this flight.
    pub coefficient_provenance: Option<&'a crate::calibration::provenance::Provenance>,
}

/// The page title: the QC sheet's (file, sensor, window, date) when the input is known,
/// else the trace's site or source.
pub fn page_title(
    trace: &Trace,
    this_flight: Option<&crate::calibration::provenance::Provenance>,
) -> String {
    match this_flight {
        Some(_) => super::qc_sheet::title(this_flight),
        None => format!(
            "QC sheet: {}",
            trace
                .meta("site")
                .or(trace.meta("source"))
                .unwrap_or("flight")
        ),
    }
}

/// The whole page for one compensation.
pub fn build(trace: &Trace, ev: &Evaluation) -> HtmlReport {
    let s = ev.summary;
    let flight = ev.flight;
    let mut page = HtmlReport::new(&page_title(trace, ev.info.this_flight.as_ref()));
    for w in &s.warnings {
        page = page.warning(w);
    }
    let duration_s = match (flight.t_s.first(), flight.t_s.last()) {
        (Some(a), Some(b)) => b - a,
        _ => 0.0,
    };
    page = page.paragraph(&format!(
        "{} samples at {:.0} Hz, {:.0} s. Method {}, model {}: {}. Compensated = scalar − \
         interference (docs/trace-format.md); the compensated rms in the manoeuvre band \
         (0.1–0.9 Hz) is what is left where aircraft interference lives.",
        flight.len(),
        flight.sample_rate_hz,
        duration_s,
        s.method.name(),
        s.model,
        ev.source
    ));
    let pattern = crate::calibration::fom::pattern_of(flight).map(|p| p.0);
    let compensation = format!("{}, model {}, {}", s.method.name(), s.model, ev.source);
    let sheet = super::qc_sheet::Sheet {
        flight,
        compensated_nt: &ev.comp.compensated_nt,
        info: ev.info,
        coefficients: ev.coefficient_provenance,
        compensation,
        pattern: pattern.as_ref(),
        table: s.fom_table.as_ref(),
        improvement_ratio: s.improvement_ratio,
    };
    for sec in super::qc_sheet::sections(&sheet) {
        page = page.section(sec);
    }
    page = page.section(figures_section(s));
    page = page.section(overlay_section(
        trace,
        flight,
        &ev.comp.compensated_nt,
        &ev.comp.interference_nt,
        "overlay",
        "Uncompensated, compensated and interference",
    ));
    if let Some(c) = &ev.comp.coefficients {
        let labels: Vec<String> = c
            .coefficients
            .iter()
            .map(|c| format!("{} ({})", c.name, c.unit))
            .collect();
        let lrefs: Vec<&str> = labels.iter().map(String::as_str).collect();
        let values: Vec<f64> = c.coefficients.iter().map(|c| c.value).collect();
        let sigmas: Vec<f64> = c.coefficients.iter().map(|c| c.sigma).collect();
        let plot = Plot::new("coefficients", "Coefficients ±1σ")
            .y_label("value (unit in label)")
            .bars(&lrefs, &values, Some(&sigmas))
            .bar_color(PALETTE[4]);
        let rows: Vec<Vec<String>> = c
            .coefficients
            .iter()
            .map(|c| {
                vec![
                    c.name.clone(),
                    format!("{:.4} ± {:.4}", c.value, c.sigma),
                    c.unit.clone(),
                ]
            })
            .collect();
        page = page.section(
            Section::new("Coefficients")
                .plot_sized(plot, 960, 360)
                .table(&["coefficient", "value ± 1σ", "unit"], &rows),
        );
    }
    page
}

/// The summary figures as a table (labels as `compensate` prints them).
pub fn figures_section(s: &Summary) -> Section {
    let rows = vec![
        vec![
            "compensated rms in the manoeuvre band (nT)".into(),
            format!("{:.4}", s.compensated_band_rms_nt),
        ],
        vec![
            "improvement ratio (IR)".into(),
            fmt_opt(s.improvement_ratio, 2),
        ],
        vec!["figure of merit, FOM (nT)".into(), fmt_opt(s.fom_nt, 3)],
        vec![
            "aircraft-only FOM (nT)".into(),
            fmt_opt(s.aircraft_fom_nt, 3),
        ],
        vec![
            "predicted error: coefficient covariance and model error (nT rms)".into(),
            fmt_opt(s.predicted_error_nt, 4),
        ],
        vec![
            "this flight's error, 90 % range (nT rms)".into(),
            s.predicted_error_range_nt
                .map_or_else(|| "–".into(), |[lo, hi]| format!("{lo:.4}–{hi:.4}")),
        ],
        vec![
            "high-frequency residual beyond the scalar's noise, in the predicted error (nT rms)"
                .into(),
            fmt_opt(s.unfollowed_high_frequency_nt, 4),
        ],
        // Six decimals: the figure is compared with `compensate --json`'s.
        vec!["error vs truth (nT rms)".into(), fmt_opt(s.error_rms_nt, 6)],
        vec![
            "oracle floor of the model (nT rms)".into(),
            fmt_opt(s.oracle_floor_nt, 4),
        ],
    ];
    Section::new("Figures")
        .paragraph(
            "IR (improvement ratio): the standard deviation of the 0.1–0.9 Hz band-passed \
             uncompensated scalar over that of the band-passed compensated one, over the \
             calibration pattern (labelled or detected manoeuvres; the whole flight when none \
             is found); > 1: compensation removed interference. The one IR magcomp prints \
             (docs/model.md §6a). The error against truth is shown only for simulated flights.",
        )
        .table(&["figure", "value"], &rows)
}

/// The rows of each line (by the `line`/`LINE` column, in order of first appearance), or
/// the whole flight as one group.
fn line_groups(trace: &Trace, n: usize) -> Vec<(String, Vec<usize>)> {
    let mut groups: Vec<(String, Vec<usize>)> = Vec::new();
    let mut add = |label: String, i: usize| match groups.iter_mut().find(|g| g.0 == label) {
        Some(g) => g.1.push(i),
        None => groups.push((label, vec![i])),
    };
    if trace.len() == n {
        if let Some(v) = LINE_COLUMNS.iter().find_map(|c| trace.col(c)) {
            for (i, x) in v.iter().enumerate() {
                add(
                    if x.is_finite() {
                        x.to_string()
                    } else {
                        "–".into()
                    },
                    i,
                );
            }
        } else if let Some(v) = LINE_COLUMNS.iter().find_map(|c| trace.text_col(c)) {
            for (i, x) in v.iter().enumerate() {
                add(x.clone(), i);
            }
        }
    }
    if groups.is_empty() {
        groups.push(("".into(), (0..n).collect()));
    }
    groups
}

/// `v` at `idx` minus its mean over them; NaN between rows that are not consecutive so a
/// line is not drawn across a gap.
fn demeaned_at(v: &[f64], idx: &[usize]) -> Vec<f64> {
    let fin: Vec<f64> = idx
        .iter()
        .map(|&i| v[i])
        .filter(|x| x.is_finite())
        .collect();
    let mean = fin.iter().sum::<f64>() / fin.len().max(1) as f64;
    with_breaks(idx, |i| v[i] - mean)
}

fn with_breaks(idx: &[usize], f: impl Fn(usize) -> f64) -> Vec<f64> {
    let mut out = Vec::with_capacity(idx.len() + 8);
    for (k, &i) in idx.iter().enumerate() {
        if k > 0 && i != idx[k - 1] + 1 {
            out.push(f64::NAN);
        }
        out.push(f(i));
    }
    out
}

/// MagNav `plot_mag_c`-style overlay, one plot per line (ids `{id}-{k}`): uncompensated,
/// compensated and interference against time, each minus its mean over the line.
pub fn overlay_section(
    trace: &Trace,
    flight: &Flight,
    compensated_nt: &[f64],
    interference_nt: &[f64],
    id: &str,
    heading: &str,
) -> Section {
    let n = flight.len();
    let groups = line_groups(trace, n);
    let mut s = Section::new(heading).paragraph(
        "As MagNav's plot_mag_c: the scalar before and after compensation and the interference \
         removed, each minus its mean over the line, so their shapes overlay. What the \
         compensated trace keeps of the uncompensated one's manoeuvre-synchronous swings is \
         interference left in.",
    );
    if compensated_nt.len() != n || interference_nt.len() != n {
        return s.paragraph("no compensated signal to show");
    }
    if groups.len() > MAX_LINE_PLOTS {
        s = s.paragraph(&format!(
            "{} lines: the first {MAX_LINE_PLOTS} are drawn (select others with --lines).",
            groups.len()
        ));
    }
    for (k, (label, idx)) in groups.iter().take(MAX_LINE_PLOTS).enumerate() {
        let t = with_breaks(idx, |i| flight.t_s[i]);
        let title = if label.is_empty() {
            "Whole flight".to_string()
        } else {
            format!("Line {label}")
        };
        let p = Plot::new(&format!("{id}-{k}"), &title)
            .x_label("time (s)")
            .y_label("nT, minus the line's mean")
            .series(
                Series::line("uncompensated", &t, &demeaned_at(&flight.mag_nt, idx))
                    .color(PALETTE[7])
                    .width_px(1.4),
            )
            .series(
                Series::line("compensated", &t, &demeaned_at(compensated_nt, idx))
                    .color(PALETTE[0])
                    .width_px(1.2),
            )
            .series(
                Series::line("interference", &t, &demeaned_at(interference_nt, idx))
                    .color(PALETTE[3])
                    .dash("5 3")
                    .width_px(1.0),
            );
        s = s.plot(p);
    }
    s
}
