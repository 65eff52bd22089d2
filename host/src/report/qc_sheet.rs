//! The QC sheet at the top of every report page, as a calibration report a survey company
//! signs (RMS AARC/AADC-style): the flight's metadata and where the coefficients came from,
//! the FOM table of the 12 manoeuvres with the one IR, the heading error, overlays scaled to
//! what compensation left, and the 4th-difference noise.

use super::{fmt_opt, Plot, Section, Series, PALETTE};
use crate::calibration::fom::FomTable;
use crate::calibration::provenance::Provenance;
use crate::estimate::reciprocal::{detrended, same_ground_rows, SAME_GROUND_M};
use crate::flight::Flight;
use crate::qc::figures::{
    band_passed, fourth_difference_nt, noise_figure, FOURTH_DIFFERENCE_LIMIT_NT,
};
use crate::qc::manoeuvres::{Leg, Pattern};

/// What the page knows beyond the trace.
#[derive(Clone, Debug)]
pub struct SheetInfo {
    /// This flight as a coefficient file would record it (file, SHA-256, map, sensor,
    /// lines, window, date); None when the page is built without its input (a library call).
    pub this_flight: Option<Provenance>,
    /// The 4th-difference acceptance band (±nT; `report --d4-limit-nt`).
    pub d4_limit_nt: f64,
}

impl Default for SheetInfo {
    fn default() -> Self {
        SheetInfo {
            this_flight: None,
            d4_limit_nt: FOURTH_DIFFERENCE_LIMIT_NT,
        }
    }
}

/// What the sheet is drawn from.
pub struct Sheet<'a> {
    pub flight: &'a Flight,
    pub compensated_nt: &'a [f64],
    pub info: &'a SheetInfo,
    /// The applied coefficient file's provenance; None when fitted on this flight.
    pub coefficients: Option<&'a Provenance>,
    /// Method and model, and where the coefficients came from.
    pub compensation: String,
    /// The labelled or detected pattern and its FOM table.
    pub pattern: Option<&'a Pattern>,
    pub table: Option<&'a FomTable>,
    /// `qc::figures::improvement_ratio` of this compensation.
    pub improvement_ratio: Option<f64>,
}

/// The page title: the file, sensor, window and date when known.
pub fn title(p: Option<&Provenance>) -> String {
    let Some(p) = p else {
        return "QC sheet: flight".into();
    };
    let name = std::path::Path::new(&p.source_file)
        .file_name()
        .map_or(p.source_file.clone(), |f| f.to_string_lossy().into_owned());
    let mut t = format!("QC sheet: {name}, {}", p.sensor);
    if let Some(l) = &p.lines {
        t.push_str(&format!(", lines {l}"));
    }
    t.push_str(&format!(", t {:.1}–{:.1} s", p.t_first_s, p.t_last_s));
    if let Some(d) = &p.flight_date {
        t.push_str(&format!(", {d}"));
    }
    t
}

/// The sheet's sections, in page order.
pub fn sections(s: &Sheet) -> Vec<Section> {
    let mut out = vec![metadata_section(s)];
    match s.table {
        Some(t) => out.push(fom_section(t)),
        None => out.push(
            Section::new("Figure of merit per heading and manoeuvre").paragraph(
                "No calibration pattern found (no labelled manoeuvres, and none detected): no FOM.",
            ),
        ),
    }
    out.push(heading_section(s));
    out.push(overlay_section(s));
    out.push(noise_section(s));
    out
}

fn provenance_rows(prefix: &str, p: &Provenance) -> Vec<Vec<String>> {
    let mut rows = vec![
        vec![format!("{prefix}file"), p.source_file.clone()],
        vec![format!("{prefix}SHA-256"), p.source_sha256.clone()],
        vec![format!("{prefix}sensor (scalar column)"), p.sensor.clone()],
        vec![
            format!("{prefix}column map"),
            p.column_map.clone().unwrap_or_else(|| "–".into()),
        ],
        vec![
            format!("{prefix}lines"),
            p.lines.clone().unwrap_or_else(|| "all".into()),
        ],
        vec![
            format!("{prefix}window"),
            format!(
                "t {:.1}–{:.1} s{}",
                p.t_first_s,
                p.t_last_s,
                p.time_window
                    .as_ref()
                    .map(|w| format!(" (--time {w})"))
                    .unwrap_or_default()
            ),
        ],
        vec![
            format!("{prefix}flight date"),
            p.flight_date.clone().unwrap_or_else(|| "unknown".into()),
        ],
    ];
    if !prefix.is_empty() {
        rows.push(vec![format!("{prefix}model"), p.model.clone()]);
    }
    rows.push(vec![
        format!("{prefix}magcomp version"),
        p.magcomp_version.clone(),
    ]);
    rows
}

fn metadata_section(s: &Sheet) -> Section {
    let f = s.flight;
    let mut rows = match &s.info.this_flight {
        Some(p) => provenance_rows("", p),
        None => vec![vec![
            "magcomp version".into(),
            crate::calibration::provenance::magcomp_version(),
        ]],
    };
    rows.push(vec![
        "samples".into(),
        format!("{} at {:.0} Hz", f.len(), f.sample_rate_hz),
    ]);
    rows.push(vec!["compensation".into(), s.compensation.clone()]);
    match s.coefficients {
        Some(p) => rows.extend(provenance_rows("coefficients: ", p)),
        None => rows.push(vec![
            "coefficient provenance".into(),
            "none recorded: calibrated on this flight, or a file written before provenance".into(),
        ]),
    }
    Section::new("Flight and coefficients").table(&["item", "value"], &rows)
}

/// Mean of `x` over rows `a..b` (finite values).
fn mean_over(x: &[f64], a: usize, b: usize) -> f64 {
    let f: Vec<f64> = x[a..b].iter().copied().filter(|v| v.is_finite()).collect();
    f.iter().sum::<f64>() / f.len() as f64
}

/// Per-heading means (uncompensated, compensated) minus their mean over the headings, and
/// the differences of reciprocal pairs.
fn heading_section(s: &Sheet) -> Section {
    let sec = Section::new("Heading error");
    let Some(p) = s.pattern.filter(|p| p.legs.len() >= 2) else {
        return sec.paragraph("Heading error: not flown (fewer than two headings found).");
    };
    let f = s.flight;
    let means: Vec<(f64, f64)> = p
        .legs
        .iter()
        .map(|l| {
            (
                mean_over(&f.mag_nt, l.start, l.end),
                mean_over(s.compensated_nt, l.start, l.end),
            )
        })
        .collect();
    let k = means.len() as f64;
    let (mu, mc) = means
        .iter()
        .fold((0.0, 0.0), |(a, b), m| (a + m.0 / k, b + m.1 / k));
    let rows: Vec<Vec<String>> = p
        .legs
        .iter()
        .zip(&means)
        .map(|(l, m)| {
            vec![
                l.tag.clone(),
                format!("{:.1}–{:.1}", f.t_s[l.start], f.t_s[l.end - 1]),
                format!("{:.2}", m.0 - mu),
                format!("{:.2}", m.1 - mc),
            ]
        })
        .collect();
    let mut sec = sec
        .paragraph(
            "Each heading's mean over its leg minus the mean of the headings' means (nT). On \
             a calibration box the legs lie over different ground, so the anomaly between \
             them is in both columns; what compensation removes is the aircraft's heading \
             effect.",
        )
        .table(
            &[
                "heading",
                "leg (s)",
                "uncompensated − mean (nT)",
                "compensated − mean (nT)",
            ],
            &rows,
        );
    let mut pairs = Vec::new();
    for i in 0..p.legs.len() {
        for j in i + 1..p.legs.len() {
            let d = (p.legs[j].heading_deg - p.legs[i].heading_deg).rem_euclid(360.0);
            if (d - 180.0).abs() < 20.0 {
                let (ground, raw_nt, comp_nt) = reciprocal(s, &p.legs[i], &p.legs[j]);
                pairs.push(vec![
                    format!("{} − {}", p.legs[i].tag, p.legs[j].tag),
                    ground,
                    format!("{raw_nt:.2}"),
                    format!("{comp_nt:.2}"),
                ]);
            }
        }
    }
    if pairs.is_empty() {
        return sec.paragraph("Reciprocal passes: not flown.");
    }
    sec = sec.table_with_caption(
        "Reciprocal passes (headings 180 ± 20° apart): over the same ground, the means \
         over the part each pass has within 200 m of the other (the anomaly cancels); \
         else the legs' means",
        &[
            "pair",
            "ground",
            "uncompensated difference (nT)",
            "compensated difference (nT)",
        ],
        &pairs,
    );
    sec
}

/// A reciprocal pair: where the ground is the same (positions), the difference of the two
/// passes' means over the samples each has within SAME_GROUND_M of the other's track, so
/// the anomaly cancels and what is left is heading error; else the legs' mean difference.
/// Returns (ground, uncompensated difference, compensated difference).
fn reciprocal(s: &Sheet, a: &Leg, b: &Leg) -> (String, f64, f64) {
    let f = s.flight;
    // The core field's change and the recorded diurnal differ between the passes too.
    let raw = f.environment_corrected_nt(&f.mag_nt);
    let comp = f.environment_corrected_nt(s.compensated_nt);
    let whole = |x: &[f64]| mean_over(x, a.start, a.end) - mean_over(x, b.start, b.end);
    let legs_mean = (whole(&raw), whole(&comp));
    if !f.has_position() {
        return ("unknown (no positions)".into(), legs_mean.0, legs_mean.1);
    }
    let ne = f.local_ne_m();
    let (on_a, on_b) = (
        same_ground_rows(&ne, (a.start, a.end), (b.start, b.end), 1),
        same_ground_rows(&ne, (b.start, b.end), (a.start, a.end), 1),
    );
    let min_rows = (10.0 * f.sample_rate_hz) as usize;
    if on_a.len() < min_rows || on_b.len() < min_rows {
        return ("different".into(), legs_mean.0, legs_mean.1);
    }
    let mean_at = |x: &[f64], rows: &[usize]| {
        let v: Vec<f64> = rows
            .iter()
            .map(|&i| x[i])
            .filter(|v| v.is_finite())
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    let diff = |x: &[f64]| mean_at(x, &on_a) - mean_at(x, &on_b);
    let overlap_s = on_a.len().min(on_b.len()) as f64 / f.sample_rate_hz;
    (
        format!("same ({overlap_s:.0} s within {SAME_GROUND_M:.0} m)"),
        diff(&raw),
        diff(&comp),
    )
}

/// The y-range that holds `x` (0.5–99.5 % of its finite values, 20 % margin): the axis is
/// scaled to what compensation left, not to the interference it removed.
pub(super) fn range_of(x: &[f64]) -> Option<(f64, f64)> {
    let mut f: Vec<f64> = x.iter().copied().filter(|v| v.is_finite()).collect();
    if f.len() < 2 {
        return None;
    }
    f.sort_by(|a, b| a.total_cmp(b));
    let q = |p: f64| f[((f.len() - 1) as f64 * p).round() as usize];
    let (lo, hi) = (q(0.005), q(0.995));
    let pad = 0.2 * (hi - lo).max(1e-3);
    Some((lo - pad, hi + pad))
}

fn overlay_plot(id: &str, title: &str, t: &[f64], raw: &[f64], comp: &[f64]) -> (Plot, String) {
    let mut p = Plot::new(id, title)
        .x_label("time (s)")
        .y_label("nT")
        .series(
            Series::line("uncompensated", t, raw)
                .color(PALETTE[7])
                .width_px(1.0),
        )
        .series(
            Series::line("compensated", t, comp)
                .color(PALETTE[0])
                .width_px(1.2),
        );
    let (Some((lo, hi)), Some(r)) = (range_of(comp), range_of(raw)) else {
        return (p, String::new());
    };
    p = p.y_range(lo, hi);
    let note = format!(
        "{title}: axis {lo:.2} to {hi:.2} nT (the compensated signal's range); the \
         uncompensated one spans {:.1} to {:.1} nT and runs off it.",
        r.0, r.1
    );
    (p, note)
}

/// Detrended and band-passed overlays, each on an axis scaled to the compensated signal.
fn overlay_section(s: &Sheet) -> Section {
    let f = s.flight;
    let mut sec = Section::new("What compensation left: detrended and band-passed");
    let (p, note) = overlay_plot(
        "qc-detrended",
        "Detrended (a straight line over the flight removed)",
        &f.t_s,
        &detrended(&f.t_s, &f.mag_nt),
        &detrended(&f.t_s, s.compensated_nt),
    );
    sec = sec.paragraph(&note).plot(p);
    if let (Some(raw), Some(comp)) = (band_passed(f, &f.mag_nt), band_passed(f, s.compensated_nt)) {
        let (p, note) = overlay_plot(
            "qc-bandpassed",
            "Band-passed 0.1–0.9 Hz (the manoeuvre band the IR and FOM are taken in)",
            &f.t_s,
            &raw,
            &comp,
        );
        sec = sec.paragraph(&note).plot(p);
    }
    sec
}

/// The 4th-difference panel and figures, uncompensated beside compensated.
fn noise_section(s: &Sheet) -> Section {
    let f = s.flight;
    let limit = s.info.d4_limit_nt;
    let sensor = s
        .info
        .this_flight
        .as_ref()
        .map_or("mag", |p| p.sensor.as_str());
    let d4_raw = fourth_difference_nt(f, &f.mag_nt);
    let d4_comp = fourth_difference_nt(f, s.compensated_nt);
    let mut rows = Vec::new();
    for (what, d4) in [("uncompensated", &d4_raw), ("compensated", &d4_comp)] {
        if let Some(n) = noise_figure(d4, limit) {
            rows.push(vec![
                format!("{sensor} {what}"),
                format!("{:.4}", n.rms_nt),
                format!("{:.4}", n.peak_nt),
                format!("{:.1}", 100.0 * n.within_limit),
            ]);
        }
    }
    let band = vec![limit; f.len()];
    let neg: Vec<f64> = band.iter().map(|v| -v).collect();
    let peak = noise_figure(&d4_comp, limit).map_or(limit, |n| n.peak_nt);
    let y = peak.max(2.0 * limit) * 1.1;
    let plot = Plot::new(
        "qc-fourth-difference",
        "4th difference of the compensated signal",
    )
    .x_label("time (s)")
    .y_label("d4 (nT, /16)")
    .y_range(-y, y)
    .series(
        Series::line(&format!("{sensor} compensated"), &f.t_s, &d4_comp)
            .color(PALETTE[0])
            .width_px(1.0),
    )
    .series(
        Series::line(&format!("±{limit} nT"), &f.t_s, &band)
            .color("#c0392b")
            .dash("5 3")
            .width_px(1.0),
    )
    .series(
        Series::line("", &f.t_s, &neg)
            .color("#c0392b")
            .dash("5 3")
            .width_px(1.0),
    );
    Section::new("Noise: 4th difference")
        .paragraph(&format!(
            "d4[i] = (x[i−2] − 4x[i−1] + 6x[i] − 4x[i+1] + x[i+2]) / 16 (normalised by 16, \
             the aeromagnetic convention: white noise of σ gives √70/16 ≈ 0.52σ). The \
             acceptance band ±{limit} nT (`--d4-limit-nt`; 0.05 nT by default, a common \
             survey-contract figure for the noise envelope: the contract's own applies; \
             docs/model.md §6a)."
        ))
        .table(
            &[
                "signal",
                "rms d4 (nT)",
                "peak |d4| (nT)",
                &format!("within ±{limit} nT (%)"),
            ],
            &rows,
        )
        .plot(plot)
}

/// The AARC-style FOM table (`calibration::fom`), one row per heading × manoeuvre.
fn fom_section(t: &FomTable) -> Section {
    let mut rows = Vec::new();
    for r in &t.rows {
        for c in &r.cells {
            rows.push(vec![
                r.heading.clone(),
                c.kind.clone(),
                format!("{:.1}–{:.1}", c.t_start, c.t_end),
                format!("{:.3}", c.uncompensated_nt),
                format!("{:.3}", c.compensated_nt),
                fmt_opt(c.aircraft_nt, 3),
            ]);
        }
        rows.push(vec![
            r.heading.clone(),
            "Σ".into(),
            String::new(),
            format!("{:.3}", r.uncompensated_sum_nt),
            format!("{:.3}", r.compensated_sum_nt),
            fmt_opt(r.aircraft_sum_nt, 3),
        ]);
    }
    let labels: Vec<String> = t
        .rows
        .iter()
        .flat_map(|r| {
            r.cells
                .iter()
                .map(move |c| format!("{} {}", r.heading, c.kind))
        })
        .collect();
    let lrefs: Vec<&str> = labels.iter().map(String::as_str).collect();
    let comp: Vec<f64> = t
        .rows
        .iter()
        .flat_map(|r| r.cells.iter().map(|c| c.compensated_nt))
        .collect();
    let bars = Plot::new("fom", "Compensated peak-to-peak per manoeuvre")
        .y_label("peak-to-peak (nT)")
        .bars(&lrefs, &comp, None);
    Section::new("Figure of merit per heading and manoeuvre")
        .plot_sized(bars, 960, 300)
        .paragraph(&format!(
            "{} manoeuvres ({}; headings from {}, manoeuvres from {}). FOM: the sum of the \
             manoeuvres' peak-to-peak of the 0.1–0.9 Hz band-passed compensated signal. \
             Uncompensated {:.3} nT, FOM {:.3} nT (ratio of the sums {:.2}); IR {:.2} (band \
             standard deviations over these manoeuvres){}.",
            t.manoeuvres,
            t.source,
            t.heading_source,
            t.manoeuvre_source,
            t.uncompensated_nt,
            t.fom_nt,
            t.peak_to_peak_ratio,
            t.improvement_ratio,
            t.aircraft_fom_nt
                .map(|a| format!(
                    "; aircraft-only FOM {a:.3} nT (compensated − {})",
                    t.field_estimate.as_deref().unwrap_or("the field estimate")
                ))
                .unwrap_or_default()
        ))
        .table_with_caption(
            "FOM table",
            &[
                "heading",
                "manoeuvre",
                "time (s)",
                "uncompensated p-p (nT)",
                "compensated p-p (nT)",
                "aircraft-only p-p (nT)",
            ],
            &rows,
        )
}
