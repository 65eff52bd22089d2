//! The overview page of a several-magnetometer report (`report --sensors`, or `--coeffs`
//! naming a several-sensor file): one row per sensor with its figures and a link to its own
//! page (the single-sensor calibration page, written beside this one), the compensated
//! fields of all sensors on one time axis, and their differences, where the anomaly they
//! share cancels and what is left is the gradient times the separation plus what each
//! sensor's compensation left (docs/model.md §7).

use super::{fmt_opt, HtmlReport, Plot, Section, PALETTE};
use crate::calibration::result::Compensation;
use crate::flight::Flight;
use crate::qc::figures::{band_rms_nt, improvement_ratio};
use crate::signal::stats::finite_mean;

/// One sensor of the page: what identifies it and its compensation on this flight.
pub struct SensorRow<'a> {
    /// `mag_K`.
    pub name: &'a str,
    pub scalar_column: &'a str,
    /// The fluxgate's name (its column stem).
    pub fluxgate: &'a str,
    pub position_m: Option<[f64; 3]>,
    /// Whether its coefficients are the joint estimate's (None: not known, e.g. a file
    /// written by hand).
    pub joint: Option<bool>,
    pub flight: &'a Flight,
    pub comp: &'a Compensation,
    /// Its own page, relative to this one.
    pub href: String,
}

/// The several-sensor page.
pub struct SensorsPage<'a> {
    /// Where the coefficients came from.
    pub source: String,
    pub sensors: Vec<SensorRow<'a>>,
    /// The pairs whose gradient is drawn: (a, b, separation in m).
    pub gradients: Vec<(usize, usize, f64)>,
}

/// One sensor's figures on this flight, as the page states them (and as `data-*`
/// attributes on the overview plot, for a reader that checks them).
pub struct SensorFigures {
    /// Band-passed (manoeuvre band) rms of the raw and of the compensated field (nT).
    pub band_raw_nt: f64,
    pub band_compensated_nt: f64,
    pub improvement_ratio: Option<f64>,
    pub predicted_error_nt: Option<f64>,
}

impl SensorFigures {
    pub fn of(row: &SensorRow) -> Self {
        SensorFigures {
            band_raw_nt: band_rms_nt(row.flight, &row.flight.mag_nt),
            band_compensated_nt: band_rms_nt(row.flight, &row.comp.compensated_nt),
            improvement_ratio: improvement_ratio(row.flight, &row.comp.compensated_nt),
            predicted_error_nt: row
                .comp
                .coefficients
                .as_ref()
                .and_then(|c| c.predicted_error_nt),
        }
    }
}

/// The overview page.
pub fn build(page: &SensorsPage) -> HtmlReport {
    let figures: Vec<SensorFigures> = page.sensors.iter().map(SensorFigures::of).collect();
    let names: Vec<&str> = page.sensors.iter().map(|s| s.name).collect();
    HtmlReport::new(&format!(
        "{} magnetometers: {}",
        names.len(),
        names.join(", ")
    ))
    .paragraph(&format!(
        "{}. One anomaly is shared by every sensor; each has its own interference \
             (docs/model.md §7). Each sensor's own page (linked below) is the single-sensor \
             calibration page of its coefficients on this flight.",
        page.source
    ))
    .section(table_section(page, &figures))
    .section(fields_section(page, &figures))
    .section(differences_section(page))
}

fn table_section(page: &SensorsPage, figures: &[SensorFigures]) -> Section {
    let rows: Vec<Vec<String>> = page
        .sensors
        .iter()
        .zip(figures)
        .map(|(s, f)| {
            vec![
                s.name.to_string(),
                s.scalar_column.to_string(),
                s.fluxgate.to_string(),
                s.position_m.map_or("unknown".into(), |p| {
                    format!("{:.2} / {:.2} / {:.2}", p[0], p[1], p[2])
                }),
                match s.joint {
                    Some(true) => "joint".into(),
                    Some(false) => "alone".into(),
                    None => "–".into(),
                },
                s.comp.model.clone(),
                fmt_opt(f.predicted_error_nt, 4),
                format!("{:.3}", f.band_raw_nt),
                format!("{:.3}", f.band_compensated_nt),
                fmt_opt(f.improvement_ratio, 2),
            ]
        })
        .collect();
    let links: Vec<(String, String)> = page
        .sensors
        .iter()
        .map(|s| (format!("{}: its calibration page", s.name), s.href.clone()))
        .collect();
    Section::new("Sensors")
        .table(
            &[
                "sensor",
                "scalar",
                "fluxgate",
                "position x / y / z (m)",
                "coefficients",
                "model",
                "predicted error (nT)",
                "band rms raw (nT)",
                "band rms compensated (nT)",
                "IR",
            ],
            &rows,
        )
        .paragraph(
            "Band rms: the 0.1–0.9 Hz band (the manoeuvres'), where the interference is and \
             the anomaly at survey height mostly is not. The joint estimate is kept for a \
             sensor only where its predicted error is at most the sensor's own calibration's.",
        )
        .links(&links)
}

/// Each sensor's compensated field, its mean removed so sensors at different levels share
/// one axis.
fn fields_section(page: &SensorsPage, figures: &[SensorFigures]) -> Section {
    let mut plot = Plot::new(
        "sensor-fields",
        "Compensated field of each sensor (mean removed)",
    )
    .x_label("time (s)")
    .y_label("nT");
    for (k, (s, f)) in page.sensors.iter().zip(figures).enumerate() {
        let c = &s.comp.compensated_nt;
        let mean = finite_mean(c);
        let y: Vec<f64> = c.iter().map(|v| v - mean).collect();
        plot = plot
            .series(
                super::Series::line(s.name, &s.flight.t_s, &y).color(PALETTE[k % PALETTE.len()]),
            )
            .data(
                &format!("band-compensated-{}", s.name),
                &format!("{:.6}", f.band_compensated_nt),
            )
            .data(
                &format!("band-raw-{}", s.name),
                &format!("{:.6}", f.band_raw_nt),
            );
    }
    Section::new("Compensated fields")
        .paragraph(
            "The anomaly is common to every sensor (to first order in their separation): the \
             curves should lie on each other, offset only by what the gradient makes of the \
             separation. A curve that moves alone at the manoeuvres is interference that \
             sensor's compensation left.",
        )
        .plot(plot)
}

/// Differences of the compensated fields (sensor b − sensor a): the anomaly cancels.
fn differences_section(page: &SensorsPage) -> Section {
    let section = Section::new("Differences between sensors");
    let Some(first) = page.sensors.first() else {
        return section;
    };
    let mut plot = Plot::new(
        "sensor-differences",
        "Compensated difference between sensors (mean removed)",
    )
    .x_label("time (s)")
    .y_label("nT");
    let pairs: Vec<(usize, usize)> = if page.gradients.is_empty() {
        (1..page.sensors.len()).map(|b| (0, b)).collect()
    } else {
        page.gradients.iter().map(|&(a, b, _)| (a, b)).collect()
    };
    let mut rows = Vec::new();
    for (k, &(a, b)) in pairs.iter().enumerate() {
        let (sa, sb) = (&page.sensors[a], &page.sensors[b]);
        let d = difference(&sa.comp.compensated_nt, &sb.comp.compensated_nt);
        let raw = difference(&sa.flight.mag_nt, &sb.flight.mag_nt);
        let name = format!("{} − {}", sb.name, sa.name);
        let band = band_rms_nt(first.flight, &d);
        let band_raw = band_rms_nt(first.flight, &raw);
        let separation = page
            .gradients
            .iter()
            .find(|g| (g.0, g.1) == (a, b))
            .map(|g| g.2);
        rows.push(vec![
            name.clone(),
            fmt_opt(separation, 2),
            format!("{band_raw:.3}"),
            format!("{band:.3}"),
            fmt_opt(separation.map(|m| band / m), 4),
        ]);
        plot = plot
            .series(
                super::Series::line(&name, &first.flight.t_s, &d).color(PALETTE[k % PALETTE.len()]),
            )
            .data(
                &format!("band-difference-{}-{}", sb.name, sa.name),
                &format!("{band:.6}"),
            );
    }
    section
        .paragraph(
            "Where the anomaly cancels, what is left is the gradient times the separation and \
             the interference the two compensations left. A difference that follows the \
             manoeuvres names a sensor whose compensation is incomplete (`magcomp diagnose \
             --sensors` tests candidate terms against it).",
        )
        .table(
            &[
                "pair",
                "separation (m)",
                "band rms raw (nT)",
                "band rms compensated (nT)",
                "band rms gradient (nT/m)",
            ],
            &rows,
        )
        .plot(plot)
}

/// `b − a` with the mean of its finite values removed.
fn difference(a: &[f64], b: &[f64]) -> Vec<f64> {
    let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| y - x).collect();
    let mean = finite_mean(&d);
    d.iter().map(|v| v - mean).collect()
}
