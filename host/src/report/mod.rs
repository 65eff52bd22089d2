//! Report rendering: hand-written SVG plots ([`Plot`]) and a self-contained HTML page
//! ([`HtmlReport`]) for the `magcomp report` command. No fonts, no scripts, no external
//! files: the page opens anywhere and can be mailed as one file.
//!
//! ```text
//! let plot = Plot::new("mag", "Total field")
//!     .x_label("time (s)").y_label("B (nT)")
//!     .line("uncompensated", &t_s, &mag_nt)
//!     .series(Series::line("compensated", &t_s, &comp_nt).color("#111").dash("6 3"))
//!     .window(t0_s, t1_s, "fluxgate dropout")
//!     .segment(0.0, 600.0, "cal_h000");
//! let html = HtmlReport::new("Flight 1003")
//!     .section(Section::new("Time series").paragraph("...").plot(plot))
//!     .to_html();
//! ```
//! Every plot is `<svg class="plot" data-plot="ID">`; long series are reduced to the
//! min and max sample per pixel column, so a 1 h 10 Hz line is a few tens of kB.

pub mod calibration;
mod evidence;
pub mod flight_report;
mod html;
mod plot;
pub mod qc_sheet;
pub mod reciprocal;
pub mod sensors;
mod ticks;

pub use html::{HtmlReport, Section};
pub use plot::{downsample_minmax, Bars, Plot, Series, SeriesStyle, PALETTE};
pub use ticks::{format_tick, log_minor_ticks, log_ticks, nice_ticks};

/// Escapes text for HTML/SVG element content and attribute values.
pub fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            // Control characters are not allowed in XML; drop them rather than emit invalid SVG.
            c if (c as u32) < 0x20 && c != '\n' && c != '\t' => {}
            c => out.push(c),
        }
    }
    out
}

/// A figure with `digits` decimals, or "–" when absent or not finite.
pub(crate) fn fmt_opt(v: Option<f64>, digits: usize) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{x:.digits$}"),
        _ => "–".into(),
    }
}
