//! The classic figure-of-merit table (AARC-style): per heading × manoeuvre, the
//! peak-to-peak of the manoeuvre-band scalar before and after compensation, their sums
//! and the improvement ratio of the sums.
//!
//! The compensated signal still holds the anomaly (and the sensor's noise) in the band,
//! so the plain FOM measures the field as much as the aircraft: a method that fits the
//! band more closely (least-squares TL) scores better even when its interference is
//! further from the truth. The `aircraft` columns take the Kalman filter's anomaly
//! estimate out first (compensated − anomaly), leaving what the aircraft left; they are
//! as good as that estimate, and the same estimate should be used to compare methods.

use super::result::Compensation;
use crate::estimate::kf::KfOptions;
use crate::flight::Flight;
use crate::model::spec::ModelSpec;
use crate::qc::figures::{band_passed, improvement_ratio_of_bands, is_manoeuvre, peak_to_peak};
use crate::qc::manoeuvres::{Leg, Manoeuvre, Pattern};
use serde::{Deserialize, Serialize};

/// One manoeuvre's figures (nT, peak-to-peak in the manoeuvre band).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FomCell {
    pub label: String,
    pub kind: String,
    pub t_start: f64,
    pub t_end: f64,
    pub uncompensated_nt: f64,
    pub compensated_nt: f64,
    /// Compensated minus the field estimate.
    pub aircraft_nt: Option<f64>,
}

/// One heading (leg).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FomRow {
    pub heading: String,
    pub heading_deg: f64,
    pub cells: Vec<FomCell>,
    pub uncompensated_sum_nt: f64,
    pub compensated_sum_nt: f64,
    pub aircraft_sum_nt: Option<f64>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FomTable {
    /// `labels` (the trace's `segment` column) or `detected` (`qc::manoeuvres`).
    pub source: String,
    pub heading_source: String,
    pub manoeuvre_source: String,
    pub rows: Vec<FomRow>,
    pub manoeuvres: usize,
    /// Σ uncompensated peak-to-peak (nT).
    pub uncompensated_nt: f64,
    /// Σ compensated peak-to-peak: the FOM (nT).
    pub fom_nt: f64,
    /// The improvement ratio over the table's manoeuvres (`qc::figures::improvement_ratio`'s
    /// definition: band-passed standard deviations, not the peak-to-peak sums).
    pub improvement_ratio: f64,
    /// Σ uncompensated / Σ compensated peak-to-peak (not the IR).
    #[serde(default)]
    pub peak_to_peak_ratio: f64,
    /// Σ peak-to-peak of (compensated − field estimate): what the aircraft left (nT).
    pub aircraft_fom_nt: Option<f64>,
    /// What the field estimate was (e.g. `kf anomaly`).
    pub field_estimate: Option<String>,
}

/// The labelled manoeuvres (`cal_hNNN_roll|pitch|yaw` in `segment`) as a pattern.
pub fn labelled_pattern(flight: &Flight) -> Option<Pattern> {
    let mut legs: Vec<Leg> = Vec::new();
    for (label, a, b) in flight.segment_runs() {
        if !is_manoeuvre(&label) {
            continue;
        }
        let rest = &label["cal_".len()..];
        let (tag, kind) = rest.rsplit_once('_').unwrap_or((rest, ""));
        let m = Manoeuvre {
            kind: kind.to_string(),
            label: label.clone(),
            start: a,
            end: b,
            t_start: flight.t_s[a],
            t_end: flight.t_s[b - 1],
            amplitude_deg: f64::NAN,
        };
        match legs.last_mut() {
            Some(l) if l.tag == tag => {
                l.end = b;
                l.manoeuvres.push(m);
            }
            _ => legs.push(Leg {
                heading_deg: tag
                    .trim_start_matches(['h', 'r'])
                    .parse()
                    .unwrap_or(f64::NAN),
                tag: tag.to_string(),
                start: a,
                end: b,
                manoeuvres: vec![m],
            }),
        }
    }
    (!legs.is_empty()).then(|| Pattern {
        heading_source: "labels".into(),
        manoeuvre_source: "labels".into(),
        legs,
    })
}

/// The FOM table of `compensated_nt` over `pattern`; `field` is an anomaly estimate
/// (e.g. the KF's) whose removal gives the aircraft-only columns, `field_name` says what
/// it is. None when the band-pass cannot run.
pub fn fom_table(
    flight: &Flight,
    pattern: &Pattern,
    source: &str,
    compensated_nt: &[f64],
    field: Option<(&[f64], &str)>,
) -> Option<FomTable> {
    let raw = band_passed(flight, &flight.mag_nt)?;
    let comp = band_passed(flight, compensated_nt)?;
    let aircraft = match field {
        Some((f, _)) => {
            // The core-field change and the recorded diurnal are the field's too.
            let corrected = flight.environment_corrected_nt(compensated_nt);
            let d: Vec<f64> = corrected.iter().zip(f).map(|(c, a)| c - a).collect();
            Some(band_passed(flight, &d)?)
        }
        None => None,
    };
    let mut rows = Vec::new();
    for leg in &pattern.legs {
        let cells: Vec<FomCell> = leg
            .manoeuvres
            .iter()
            .map(|m| FomCell {
                label: m.label.clone(),
                kind: m.kind.clone(),
                t_start: m.t_start,
                t_end: m.t_end,
                uncompensated_nt: peak_to_peak(&raw[m.start..m.end]),
                compensated_nt: peak_to_peak(&comp[m.start..m.end]),
                aircraft_nt: aircraft.as_ref().map(|a| peak_to_peak(&a[m.start..m.end])),
            })
            .collect();
        rows.push(FomRow::of(leg.tag.clone(), leg.heading_deg, cells));
    }
    let mut table = FomTable {
        source: source.into(),
        heading_source: pattern.heading_source.clone(),
        manoeuvre_source: pattern.manoeuvre_source.clone(),
        manoeuvres: 0,
        uncompensated_nt: f64::NAN,
        fom_nt: f64::NAN,
        improvement_ratio: {
            let rows: Vec<usize> = pattern.manoeuvres().flat_map(|m| m.start..m.end).collect();
            improvement_ratio_of_bands(&raw, &comp, &rows).unwrap_or(f64::NAN)
        },
        peak_to_peak_ratio: f64::NAN,
        aircraft_fom_nt: None,
        field_estimate: field.map(|(_, n)| n.to_string()),
        rows,
    };
    table.total();
    Some(table)
}

impl FomRow {
    /// A heading's row: its cells and their sums.
    fn of(heading: String, heading_deg: f64, cells: Vec<FomCell>) -> Self {
        let with_aircraft = cells.iter().any(|c| c.aircraft_nt.is_some());
        Self {
            heading,
            heading_deg,
            uncompensated_sum_nt: cells.iter().map(|c| c.uncompensated_nt).sum(),
            compensated_sum_nt: cells.iter().map(|c| c.compensated_nt).sum(),
            aircraft_sum_nt: with_aircraft
                .then(|| cells.iter().filter_map(|c| c.aircraft_nt).sum()),
            cells,
        }
    }
}

impl FomTable {
    /// The totals over the rows (the improvement ratio is the band's, kept).
    fn total(&mut self) {
        self.manoeuvres = self.rows.iter().map(|r| r.cells.len()).sum();
        self.uncompensated_nt = self.rows.iter().map(|r| r.uncompensated_sum_nt).sum();
        self.fom_nt = self.rows.iter().map(|r| r.compensated_sum_nt).sum();
        self.peak_to_peak_ratio = self.uncompensated_nt / self.fom_nt;
        let with_aircraft = self.rows.iter().any(|r| r.aircraft_sum_nt.is_some());
        self.aircraft_fom_nt =
            with_aircraft.then(|| self.rows.iter().filter_map(|r| r.aircraft_sum_nt).sum());
    }

    /// The manoeuvres with figures (a real-time run's output shown converged over part of
    /// them), the totals over those; None when no manoeuvre has any.
    pub fn measured_only(self) -> Option<Self> {
        let measured = |c: &FomCell| c.uncompensated_nt.is_finite() && c.compensated_nt.is_finite();
        let rows: Vec<FomRow> = self
            .rows
            .iter()
            .filter_map(|r| {
                let cells: Vec<FomCell> = r.cells.iter().filter(|c| measured(c)).cloned().collect();
                (!cells.is_empty()).then(|| FomRow::of(r.heading.clone(), r.heading_deg, cells))
            })
            .collect();
        if rows.is_empty() {
            return None;
        }
        let mut table = Self { rows, ..self };
        table.total();
        Some(table)
    }
}

/// The model whose Kalman-filter anomaly estimate is the field estimate of a compensation
/// that has none of its own (Tolles–Lawson): the default model, fitted on this flight.
pub const FIELD_ESTIMATE_MODEL: &str = crate::model::spec::DEFAULT_MODEL;

/// The FOM table of a compensation with its aircraft-only columns. The Kalman filter's own
/// anomaly estimate is the field estimate; a compensation without one (Tolles–Lawson) gets
/// that of the default model's filter fitted on this flight, so that both methods' aircraft
/// figures separate the field the same way (without it TL could only be ranked by the plain
/// FOM, which favours the method that fits the band, not the aircraft). The filter runs only
/// when there is a pattern to tabulate and the flight has a track (its anomaly model needs the
/// along-track distance) and `fit_field_estimate` allows the extra filter pass (`calibrate
/// --method tl` asks for it only with `--aircraft-fom`: it costs more than the TL fit);
/// otherwise the aircraft columns are absent.
pub fn compensation_fom_table(
    flight: &Flight,
    comp: &Compensation,
    fit_field_estimate: bool,
) -> Option<FomTable> {
    let (pattern, source) = pattern_of(flight)?;
    let own = comp
        .anomaly_nt
        .as_deref()
        .map(|a| (a.to_vec(), "kf anomaly"));
    let field = own.or_else(|| {
        fit_field_estimate
            .then(|| field_estimate_nt(flight))
            .flatten()
            .map(|a| (a, "kf anomaly (default model fitted on this flight)"))
    });
    fom_table(
        flight,
        &pattern,
        source,
        &comp.compensated_nt,
        field.as_ref().map(|(a, n)| (a.as_slice(), *n)),
    )
}

/// The anomaly estimate of [`FIELD_ESTIMATE_MODEL`]'s filter calibrated on `flight`; None
/// without a track or when the filter fails (the aircraft figures are then not shown).
pub fn field_estimate_nt(flight: &Flight) -> Option<Vec<f64>> {
    if !flight.has_track() {
        return None;
    }
    let spec = ModelSpec::parse(FIELD_ESTIMATE_MODEL).ok()?;
    if !spec.channels().is_empty() {
        return None;
    }
    let run = crate::estimate::corrections::run_kf(flight, &KfOptions::new(spec)).ok()?;
    Some(run.anomaly_nt)
}

/// The labelled pattern when the trace has one, else the detected one.
pub fn pattern_of(flight: &Flight) -> Option<(Pattern, &'static str)> {
    match labelled_pattern(flight) {
        Some(p) => Some((p, "labels")),
        None => Some((crate::qc::manoeuvres::detect(flight)?, "detected")),
    }
}

/// The table as text, one line per heading: `heading  man: unc/comp …  Σ unc/comp`.
pub fn format_table(t: &FomTable) -> String {
    let mut s = format!(
        "FOM table ({} manoeuvres, {}; headings from {}), peak-to-peak nT in the manoeuvre band, uncompensated / compensated{}:\n",
        t.manoeuvres,
        t.source,
        t.heading_source,
        if t.aircraft_fom_nt.is_some() {
            " [aircraft only]"
        } else {
            ""
        }
    );
    for r in &t.rows {
        s.push_str(&format!("  {:<6}", r.heading));
        for c in &r.cells {
            s.push_str(&format!(
                "  {}: {:.2}/{:.3}",
                c.kind, c.uncompensated_nt, c.compensated_nt
            ));
            if let Some(a) = c.aircraft_nt {
                s.push_str(&format!(" [{a:.3}]"));
            }
        }
        s.push_str(&format!(
            "   Σ {:.2}/{:.3}\n",
            r.uncompensated_sum_nt, r.compensated_sum_nt
        ));
    }
    s.push_str(&format!(
        "  total: uncompensated {:.2}, FOM {:.3}, IR {:.2}",
        t.uncompensated_nt, t.fom_nt, t.improvement_ratio
    ));
    if let Some(a) = t.aircraft_fom_nt {
        s.push_str(&format!(", aircraft-only FOM {a:.3}"));
    }
    s
}
