//! The report's evidence section (issue 20): the verdict, each candidate's witnesses
//! (innovations held out, the band-passed measurement regressed directly, the reference
//! difference, the whole-model refit) and the band-passed measurement with the direct fit
//! of the model's terms and the named term over it; then reciprocal passes over the same
//! ground (`reciprocal.rs`), where a lag shows as a shift and a heading error as an offset.

use super::{Plot, Section, Series, PALETTE};
use crate::diagnose::{evidence::DIRECT_BAND_HZ, Diagnosis};
use crate::flight::Flight;

fn pct(v: Option<f64>) -> String {
    v.map_or("—".into(), |x| format!("{:.1} %", 100.0 * x))
}

/// The section, for the model titled `title` (the `i`-th on the page).
pub(super) fn evidence_section(flight: &Flight, d: &Diagnosis, i: usize, title: &str) -> Section {
    let mut s = Section::new(&format!("Model {title}: evidence for each candidate"))
        .paragraph(&format!("Verdict: {}.", d.verdict()))
        .paragraph(
            "The filter's innovations are one witness; an effect the anomaly states can \
             absorb leaves them almost untouched. The band witness regresses the \
             band-passed measurement directly on the terms (no anomaly states, as \
             Tolles–Lawson does); the reference witness does so on the measurement minus \
             the --reference channel, where the anomaly cancels; the refit calibrates the \
             whole model again with the candidate: a missing effect makes the calibration's \
             parts disagree (a large predicted error) until it is added, and a term whose \
             refit raises the predicted error is not recommended. Shares are held out: \
             each piece of the flight scored with a fit on the others.",
        );
    let rows: Vec<Vec<String>> = d
        .candidates
        .iter()
        .take(12)
        .map(|c| {
            vec![
                c.term.clone(),
                pct(c.heldout_explained_fraction.or(Some(c.explained_fraction))),
                pct(c.band_heldout_fraction),
                pct(c.reference_heldout_fraction),
                c.refit.as_ref().map_or("—".into(), |r| {
                    format!(
                        "{:.4} → {:.4} nT (output moves {:.4})",
                        r.predicted_before_nt, r.predicted_after_nt, r.output_change_nt
                    )
                }),
                format!("{:.1e}", c.p_value),
                if c.evidence.is_empty() {
                    "—".into()
                } else {
                    c.evidence.join(" + ")
                },
                if c.significant { "yes" } else { "no" }.into(),
                c.effect.clone(),
            ]
        })
        .collect();
    s = s.table_with_caption(
        "Candidates and their witnesses (a share ≥ the materiality bar, or a refit that \
         halves the predicted error and moves the output, makes a witness)",
        &[
            "term",
            "innovations",
            "band",
            "reference",
            "refit: predicted error",
            "p",
            "rests on",
            "named",
            "physical effect",
        ],
        &rows,
    );
    if let Some(fit) = &d.series.direct_fit {
        let label = match &fit.term {
            Some(t) => format!("model's terms + {t}, fitted directly"),
            None => "model's terms, fitted directly".into(),
        };
        let left: Vec<f64> = fit
            .target_nt
            .iter()
            .zip(&fit.fitted_nt)
            .map(|(a, b)| a - b)
            .collect();
        let plot = Plot::new(
            &format!("direct-{i}"),
            &format!(
                "Band-passed measurement ({:.1}–{:.1} Hz) and its direct fit — {title}",
                DIRECT_BAND_HZ.0, DIRECT_BAND_HZ.1
            ),
        )
        .x_label("time (s)")
        .y_label("nT")
        .series(
            Series::line("band-passed measurement", &flight.t_s, &fit.target_nt)
                .color(PALETTE[7])
                .width_px(1.5),
        )
        .series(
            Series::line(&label, &flight.t_s, &fit.fitted_nt)
                .color(PALETTE[0])
                .dash("5 3")
                .width_px(1.2),
        )
        .series(
            Series::line("left", &flight.t_s, &left)
                .color(PALETTE[3])
                .width_px(1.0),
        );
        s = s.plot(plot);
    }
    super::reciprocal::reciprocal_part(s, flight, &d.run.compensated_nt, i, title)
}
