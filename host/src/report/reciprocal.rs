//! Reciprocal passes on the evidence page (issue 20 item 6): two straight legs flown over
//! the same ground in opposite directions, drawn against one ground coordinate. A scalar
//! lag τ reads the anomaly V·τ behind the aircraft on each pass, so the two overlays are
//! shifted by 2·V·τ and their difference looks like the anomaly's derivative; a heading
//! error is a constant offset between them.

use super::qc_sheet::range_of;
use super::{Plot, Section, Series, PALETTE};
pub use crate::estimate::reciprocal::ReciprocalPair;
use crate::estimate::reciprocal::SAME_GROUND_M;
use crate::flight::Flight;
use crate::signal::stats::finite_mean;

/// Pairs drawn per model (the longest overlaps).
const MAX_PAIRS: usize = 3;

/// Why a flight has no pair to show, or the pairs drawn (`estimate::reciprocal`).
pub fn reciprocal_pairs(
    flight: &Flight,
    compensated_nt: &[f64],
) -> Result<Vec<ReciprocalPair>, String> {
    crate::estimate::reciprocal::reciprocal_pairs(flight, compensated_nt, MAX_PAIRS)
}

fn signed(v: Option<f64>, digits: usize) -> String {
    v.map_or("–".into(), |x| format!("{x:+.digits$}"))
}

/// The evidence section's reciprocal-pass part for the model titled `title` (`i`-th).
pub(super) fn reciprocal_part(
    mut s: Section,
    flight: &Flight,
    compensated_nt: &[f64],
    i: usize,
    title: &str,
) -> Section {
    let pairs = match reciprocal_pairs(flight, compensated_nt) {
        Ok(p) => p,
        Err(why) => return s.paragraph(&format!("Reciprocal passes: none to plot ({why}).")),
    };
    s = s.paragraph(
        "Reciprocal passes: two straight legs over the same ground in opposite directions, \
         against the distance along the first leg's course. A scalar lag τ reads the \
         anomaly V·τ behind the aircraft on each pass: the two compensated lines are \
         shifted by 2·V·τ (the second pass read at x − shift matches the first) and their \
         difference has the shape of the anomaly's slope. A heading error is a constant \
         offset: the mean difference. The uncompensated passes are drawn faded, moved as a \
         whole to the compensated level.",
    );
    for (k, p) in pairs.iter().enumerate() {
        s = pair_plots(s, p, i, k, title);
    }
    s
}

fn pair_plots(mut s: Section, p: &ReciprocalPair, i: usize, k: usize, title: &str) -> Section {
    let name = format!(
        "{:03.0}° (t {:.0}–{:.0} s) and {:03.0}° (t {:.0}–{:.0} s)",
        p.heading_a_deg, p.t_a_s.0, p.t_a_s.1, p.heading_b_deg, p.t_b_s.0, p.t_b_s.1
    );
    let span_m = p.x_m.last().unwrap_or(&0.0) - p.x_m.first().unwrap_or(&0.0);
    s = s.paragraph(&format!(
        "Pair {}: {name}, {:.1} km of shared ground (within {SAME_GROUND_M:.0} m). \
         Difference rms {:.2} → {:.3} nT (uncompensated → compensated), mean {:+.3} nT \
         (the heading error). Best-aligning shift {} m: τ = shift / (2·V) = {} s at \
         V = {:.1} m/s.",
        k + 1,
        span_m / 1000.0,
        p.rms_raw_nt,
        p.rms_comp_nt,
        p.mean_comp_nt,
        signed(p.shift_m, 1),
        signed(p.tau_s, 3),
        p.speed_mps
    ));
    // The raw passes carry the aircraft's heading effect (tens to hundreds of nT): moved
    // as a whole to the compensated level so both fit one axis.
    let level = finite_mean(&[finite_mean(&p.comp_a_nt), finite_mean(&p.comp_b_nt)])
        - finite_mean(&[finite_mean(&p.raw_a_nt), finite_mean(&p.raw_b_nt)]);
    let moved = |v: &[f64]| -> Vec<f64> { v.iter().map(|x| x + level).collect() };
    let data = |plot: Plot| {
        plot.data("heading-a-deg", &format!("{:.1}", p.heading_a_deg))
            .data("heading-b-deg", &format!("{:.1}", p.heading_b_deg))
            .data("rms-raw-nt", &format!("{:.4}", p.rms_raw_nt))
            .data("rms-comp-nt", &format!("{:.4}", p.rms_comp_nt))
            .data("speed-mps", &format!("{:.3}", p.speed_mps))
            .data(
                "shift-m",
                &p.shift_m.map_or("NaN".into(), |v| format!("{v:.3}")),
            )
            .data(
                "tau-s",
                &p.tau_s.map_or("NaN".into(), |v| format!("{v:.4}")),
            )
    };
    let overlay = Plot::new(
        &format!("reciprocal-{i}-{k}"),
        &format!("Reciprocal passes {name} — {title}"),
    )
    .x_label("ground along the first pass's course (m)")
    .y_label("field, core and diurnal removed (nT)")
    .series(
        Series::line("uncompensated, first", &p.x_m, &moved(&p.raw_a_nt))
            .color("#9ecae1")
            .width_px(1.0),
    )
    .series(
        Series::line("uncompensated, second", &p.x_m, &moved(&p.raw_b_nt))
            .color("#fcbba1")
            .width_px(1.0),
    )
    .series(
        Series::line("compensated, first", &p.x_m, &p.comp_a_nt)
            .color(PALETTE[0])
            .width_px(1.5)
            .with_values(),
    )
    .series(
        Series::line("compensated, second", &p.x_m, &p.comp_b_nt)
            .color(PALETTE[1])
            .width_px(1.5)
            .dash("5 3")
            .with_values(),
    );
    s = s.plot(data(overlay));
    let mut diff = Plot::new(
        &format!("reciprocal-diff-{i}-{k}"),
        &format!("First minus second pass — {title}"),
    )
    .x_label("ground along the first pass's course (m)")
    .y_label("difference (nT)")
    .series(
        Series::line(
            "uncompensated (may run off the axis)",
            &p.x_m,
            &p.diff_raw_nt,
        )
        .color("#c7c7c7")
        .width_px(1.0),
    )
    .series(
        Series::line("compensated", &p.x_m, &p.diff_comp_nt)
            .color(PALETTE[2])
            .width_px(1.5)
            .with_values(),
    );
    // The uncompensated difference can be far larger: the axis holds the compensated one
    // and 0, and the uncompensated only when it is within 3× of that.
    let comp = range_of(&p.diff_comp_nt);
    let both = range_of(&[p.diff_comp_nt.as_slice(), &p.diff_raw_nt].concat());
    if let (Some((lo, hi)), Some((blo, bhi))) = (comp, both) {
        let (lo, hi) = if bhi - blo <= 3.0 * (hi - lo) {
            (blo, bhi)
        } else {
            (lo, hi)
        };
        diff = diff.y_range(lo.min(0.0), hi.max(0.0));
    }
    s.plot(data(diff))
}
