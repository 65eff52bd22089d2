//! The line/scatter chart of the plot builder: its layout (ranges, ticks, margins, legend
//! and segment rows), then its layers drawn back to front: grid, segment bands and
//! windows, data, frame and ticks, axis labels, legend, segment labels.
use super::super::ticks::{format_tick, log_minor_ticks, log_ticks, nice_ticks};
use super::escape;
use super::geometry::{
    legend_layout, minmax_by_bucket, path_data, sanitize_id, text_w, tick_step, widen,
};
use super::{Plot, Series, SeriesStyle, FONT_PX};
use std::collections::HashSet;
use std::fmt::Write;

/// Where everything of an x/y chart goes (SVG pixels), and the data → pixel mapping.
struct XyLayout {
    /// Axis ranges (widened, data units) and whether any data set them.
    xr: (f64, f64),
    yr: (f64, f64),
    has_data: bool,
    x_log: bool,
    y_log: bool,
    /// Plot area.
    left: f64,
    right: f64,
    top: f64,
    bottom: f64,
    plot_w: f64,
    plot_h: f64,
    /// The ranges on the (log-)transformed axes.
    tx0: f64,
    tx1: f64,
    ty0: f64,
    ty1: f64,
    /// Legend entries (series index, row, x) from `legend_top`; segment label rows from
    /// `seg_top`.
    legend_top: f64,
    legend_rows: Vec<(usize, usize, f64)>,
    seg_top: f64,
    seg_rows: Vec<Option<usize>>,
    x_ticks: Vec<f64>,
    x_step: Option<f64>,
    y_ticks: Vec<f64>,
    y_labels: Vec<String>,
    /// Id of the plot area's clip path.
    clip: String,
}

impl XyLayout {
    fn tx(&self, v: f64) -> f64 {
        if self.x_log {
            v.log10()
        } else {
            v
        }
    }

    fn ty(&self, v: f64) -> f64 {
        if self.y_log {
            v.log10()
        } else {
            v
        }
    }

    /// Pixel x of data x.
    fn sx(&self, v: f64) -> f64 {
        self.left + (self.tx(v) - self.tx0) / (self.tx1 - self.tx0) * self.plot_w
    }

    /// Pixel y of data y.
    fn sy(&self, v: f64) -> f64 {
        self.bottom - (self.ty(v) - self.ty0) / (self.ty1 - self.ty0) * self.plot_h
    }
}

/// ` stroke-dasharray="…"` for a dashed series, else nothing.
/// ` data-x="…" data-y="…"` when the series asks for its values on the element.
fn values_attr(s: &Series) -> String {
    if !s.values_attr {
        return String::new();
    }
    let join = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:.3}"))
            .collect::<Vec<_>>()
            .join(",")
    };
    format!(r#" data-x="{}" data-y="{}""#, join(&s.x), join(&s.y))
}

fn dash_attr(s: &Series) -> String {
    s.dash
        .as_deref()
        .map(|d| format!(r#" stroke-dasharray="{}""#, escape(d)))
        .unwrap_or_default()
}

impl Plot {
    pub(super) fn xy_chart(&self, out: &mut String, w: f64, h: f64) {
        let colors = self.colors();
        let lay = self.xy_layout(w, h);
        let _ = write!(
            out,
            r#"<defs><clipPath id="{clip}"><rect x="{left:.1}" y="{top:.1}" width="{plot_w:.1}" height="{plot_h:.1}"/></clipPath></defs>"#,
            clip = lay.clip,
            left = lay.left,
            top = lay.top,
            plot_w = lay.plot_w,
            plot_h = lay.plot_h,
        );
        self.xy_grid(out, &lay);
        self.xy_bands(out, &lay);
        self.xy_data(out, &lay, &colors);
        if !lay.has_data {
            let _ = write!(
                out,
                r##"<text x="{:.1}" y="{:.1}" text-anchor="middle" fill="#888">no data</text>"##,
                lay.left + lay.plot_w / 2.0,
                lay.top + lay.plot_h / 2.0
            );
        }
        self.xy_frame_and_x_ticks(out, &lay);
        self.y_ticks_and_labels(
            out,
            &lay.y_ticks,
            &lay.y_labels,
            &|v| lay.sy(v),
            [lay.left, lay.right, lay.top, lay.bottom],
            h,
        );
        self.xy_legend(out, &lay, &colors);
        self.xy_segment_labels(out, &lay);
    }

    /// Ranges (explicit, else data padded on y, else a placeholder), ticks, and the
    /// vertical layout, top to bottom: title, legend rows, segment strip, plot, ticks,
    /// x label.
    fn xy_layout(&self, w: f64, h: f64) -> XyLayout {
        let x_ext = self.x_range.or_else(|| self.data_extent(true));
        let y_ext = self.y_range.or_else(|| {
            self.data_extent(false).map(|(lo, hi)| {
                if self.y_log {
                    let pad = (hi / lo).powf(0.05);
                    (lo / pad, hi * pad)
                } else {
                    let pad = 0.05 * (hi - lo);
                    (lo - pad, hi + pad)
                }
            })
        });
        let has_data = x_ext.is_some() && y_ext.is_some();
        let xr = widen(
            x_ext.unwrap_or(if self.x_log { (1.0, 10.0) } else { (0.0, 1.0) }),
            self.x_log,
        );
        let yr = widen(
            y_ext.unwrap_or(if self.y_log { (1.0, 10.0) } else { (0.0, 1.0) }),
            self.y_log,
        );

        let names: Vec<(usize, &Series)> = self
            .series
            .iter()
            .enumerate()
            .filter(|(_, s)| !s.name.is_empty())
            .collect();
        let show_legend = self.legend.unwrap_or(!names.is_empty()) && !names.is_empty();
        let y_ticks = if self.y_log {
            log_ticks(yr.0, yr.1)
        } else {
            nice_ticks(yr.0, yr.1, ((h / 60.0) as usize).clamp(3, 10))
        };
        let y_step = (!self.y_log).then(|| tick_step(&y_ticks));
        let y_labels: Vec<String> = y_ticks.iter().map(|&v| format_tick(v, y_step)).collect();
        let y_label_w = y_labels
            .iter()
            .map(|s| text_w(s, FONT_PX))
            .fold(0.0, f64::max);
        let left = 8.0 + if self.y_label.is_empty() { 0.0 } else { 20.0 } + y_label_w + 8.0;
        let right = w - 16.0;

        let mut top = 30.0;
        let legend_rows = if show_legend {
            legend_layout(&names, left, right)
        } else {
            Vec::new()
        };
        let legend_top = top;
        if !legend_rows.is_empty() {
            top += 18.0 * (legend_rows.iter().map(|r| r.1).max().unwrap_or(0) + 1) as f64;
        }
        let seg_top = top;
        let (seg_rows, n_seg_rows) = self.segment_rows(xr, left, right);
        top += 15.0 * n_seg_rows as f64 + if n_seg_rows > 0 { 4.0 } else { 0.0 };
        top += 6.0;
        let bottom = h - 22.0 - if self.x_label.is_empty() { 0.0 } else { 18.0 };
        let bottom = bottom.max(top + 20.0);
        let plot_w = right - left;
        let plot_h = bottom - top;

        let x_ticks = if self.x_log {
            log_ticks(xr.0, xr.1)
        } else {
            nice_ticks(xr.0, xr.1, ((plot_w / 90.0) as usize).clamp(2, 12))
        };
        let x_step = (!self.x_log).then(|| tick_step(&x_ticks));
        let mut lay = XyLayout {
            xr,
            yr,
            has_data,
            x_log: self.x_log,
            y_log: self.y_log,
            left,
            right,
            top,
            bottom,
            plot_w,
            plot_h,
            tx0: 0.0,
            tx1: 0.0,
            ty0: 0.0,
            ty1: 0.0,
            legend_top,
            legend_rows,
            seg_top,
            seg_rows,
            x_ticks,
            x_step,
            y_ticks,
            y_labels,
            clip: format!("clip-{}", sanitize_id(&self.id)),
        };
        (lay.tx0, lay.tx1, lay.ty0, lay.ty1) =
            (lay.tx(xr.0), lay.tx(xr.1), lay.ty(yr.0), lay.ty(yr.1));
        lay
    }

    /// Grid lines at the ticks.
    fn xy_grid(&self, out: &mut String, lay: &XyLayout) {
        let (top, bottom, left, right) = (lay.top, lay.bottom, lay.left, lay.right);
        out.push_str(r##"<g stroke="#e4e4e4" stroke-width="1">"##);
        for &v in &lay.x_ticks {
            let _ = write!(
                out,
                r#"<line x1="{x:.1}" y1="{top:.1}" x2="{x:.1}" y2="{bottom:.1}"/>"#,
                x = lay.sx(v)
            );
        }
        for &v in &lay.y_ticks {
            let _ = write!(
                out,
                r#"<line x1="{left:.1}" y1="{y:.1}" x2="{right:.1}" y2="{y:.1}"/>"#,
                y = lay.sy(v)
            );
        }
        out.push_str("</g>");
    }

    /// Segment bands (every other segment shaded) and windows, behind the data.
    fn xy_bands(&self, out: &mut String, lay: &XyLayout) {
        let (top, left, right, plot_h) = (lay.top, lay.left, lay.right, lay.plot_h);
        let _ = write!(out, r#"<g clip-path="url(#{})">"#, lay.clip);
        for (i, s) in self.segments.iter().enumerate() {
            if i % 2 == 0 {
                let (a, b) = (lay.sx(s.x0).max(left), lay.sx(s.x1).min(right));
                if b > a {
                    let _ = write!(
                        out,
                        r##"<rect x="{a:.1}" y="{top:.1}" width="{:.1}" height="{plot_h:.1}" fill="#000000" fill-opacity="0.035"/>"##,
                        b - a
                    );
                }
            }
        }
        for win in &self.windows {
            if win.x0.is_nan() || win.x1.is_nan() {
                continue;
            }
            let (x0, x1) = (win.x0.min(win.x1), win.x0.max(win.x1));
            let (a, b) = (lay.sx(x0).max(left), lay.sx(x1).min(right));
            if b.is_finite() && a.is_finite() && b >= a {
                let _ = write!(
                    out,
                    r#"<rect class="window" x="{a:.1}" y="{top:.1}" width="{:.1}" height="{plot_h:.1}" fill="{c}" fill-opacity="0.14" stroke="{c}" stroke-opacity="0.5"><title>{t}</title></rect>"#,
                    (b - a).max(1.0),
                    c = escape(&win.color),
                    t = escape(&win.label)
                );
                let _ = write!(
                    out,
                    r#"<text x="{:.1}" y="{:.1}" font-size="11" fill="{c}">{t}</text>"#,
                    a + 3.0,
                    top + 13.0,
                    c = escape(&win.color),
                    t = escape(&win.label)
                );
            }
        }
        out.push_str("</g>");
    }

    /// The series: lines (min/max-decimated when denser than the pixels) and scatter dots.
    fn xy_data(&self, out: &mut String, lay: &XyLayout, colors: &[String]) {
        let _ = write!(out, r#"<g clip-path="url(#{})" fill="none">"#, lay.clip);
        for (s, color) in self.series.iter().zip(colors) {
            let (px, py) = self.to_pixels(s, lay);
            match s.style {
                SeriesStyle::Line => {
                    let n = s.x.len().min(s.y.len());
                    let (dx, dy) = if n > 2 * lay.plot_w as usize {
                        minmax_by_bucket(&px, &py, 0.0, 1.0)
                    } else {
                        (px, py)
                    };
                    let d = path_data(&dx, &dy);
                    if !d.is_empty() {
                        let _ = write!(
                            out,
                            r#"<path class="series" data-name="{}"{values} d="{d}" stroke="{}" stroke-width="{}" stroke-linejoin="round" stroke-linecap="round"{dash}/>"#,
                            escape(&s.name),
                            escape(color),
                            s.width_px,
                            values = values_attr(s),
                            dash = dash_attr(s)
                        );
                    }
                }
                SeriesStyle::Scatter => {
                    let _ = write!(
                        out,
                        r#"<g class="series" data-name="{}" fill="{}" fill-opacity="0.75">"#,
                        escape(&s.name),
                        escape(color)
                    );
                    // One dot per (rounded) pixel keeps dense clouds small.
                    let mut seen = HashSet::new();
                    for (&x, &y) in px.iter().zip(&py) {
                        if x.is_finite()
                            && y.is_finite()
                            && seen.insert(((x * 2.0) as i64, (y * 2.0) as i64))
                        {
                            let _ = write!(out, r#"<circle cx="{x:.1}" cy="{y:.1}" r="2.5"/>"#);
                        }
                    }
                    out.push_str("</g>");
                }
            }
        }
        out.push_str("</g>");
    }

    /// A series in pixels; unusable points become gaps (NaN).
    fn to_pixels(&self, s: &Series, lay: &XyLayout) -> (Vec<f64>, Vec<f64>) {
        let n = s.x.len().min(s.y.len());
        let mut px = Vec::with_capacity(n);
        let mut py = Vec::with_capacity(n);
        for i in 0..n {
            let (x, y) = (s.x[i], s.y[i]);
            let ok = x.is_finite()
                && y.is_finite()
                && (!self.x_log || x > 0.0)
                && (!self.y_log || y > 0.0);
            // Far off-plot points are pinned so coordinates stay short numbers.
            px.push(if ok {
                lay.sx(x).clamp(-1e6, 1e6)
            } else {
                f64::NAN
            });
            py.push(if ok {
                lay.sy(y).clamp(-1e6, 1e6)
            } else {
                f64::NAN
            });
        }
        (px, py)
    }

    /// The plot's frame, tick marks (and log minor ticks), and the x tick labels.
    fn xy_frame_and_x_ticks(&self, out: &mut String, lay: &XyLayout) {
        let (top, bottom, left) = (lay.top, lay.bottom, lay.left);
        let (plot_w, plot_h) = (lay.plot_w, lay.plot_h);
        let _ = write!(
            out,
            r##"<rect x="{left:.1}" y="{top:.1}" width="{plot_w:.1}" height="{plot_h:.1}" fill="none" stroke="#444"/>"##
        );
        out.push_str(r##"<g stroke="#444">"##);
        if self.x_log {
            for v in log_minor_ticks(lay.xr.0, lay.xr.1) {
                let _ = write!(
                    out,
                    r#"<line x1="{x:.1}" y1="{bottom:.1}" x2="{x:.1}" y2="{:.1}"/>"#,
                    bottom + 3.0,
                    x = lay.sx(v)
                );
            }
        }
        if self.y_log {
            for v in log_minor_ticks(lay.yr.0, lay.yr.1) {
                let _ = write!(
                    out,
                    r#"<line x1="{:.1}" y1="{y:.1}" x2="{left:.1}" y2="{y:.1}"/>"#,
                    left - 3.0,
                    y = lay.sy(v)
                );
            }
        }
        for &v in &lay.x_ticks {
            let _ = write!(
                out,
                r#"<line x1="{x:.1}" y1="{bottom:.1}" x2="{x:.1}" y2="{:.1}"/>"#,
                bottom + 5.0,
                x = lay.sx(v)
            );
        }
        for &v in &lay.y_ticks {
            let _ = write!(
                out,
                r#"<line x1="{:.1}" y1="{y:.1}" x2="{left:.1}" y2="{y:.1}"/>"#,
                left - 5.0,
                y = lay.sy(v)
            );
        }
        out.push_str("</g>");
        out.push_str(r##"<g class="x-ticks" fill="#333" text-anchor="middle">"##);
        for &v in &lay.x_ticks {
            let _ = write!(
                out,
                r#"<text x="{:.1}" y="{:.1}">{}</text>"#,
                lay.sx(v),
                bottom + 17.0,
                escape(&format_tick(v, lay.x_step))
            );
        }
        out.push_str("</g>");
    }

    /// The legend: a line or dot sample and the series' name per entry.
    fn xy_legend(&self, out: &mut String, lay: &XyLayout, colors: &[String]) {
        for &(i, row, col) in &lay.legend_rows {
            let s = &self.series[i];
            let y = lay.legend_top + 18.0 * row as f64 + 8.0;
            let x = col;
            let color = escape(&colors[i]);
            match s.style {
                SeriesStyle::Line => {
                    let _ = write!(
                        out,
                        r#"<line x1="{x:.1}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="{color}" stroke-width="2"{dash}/>"#,
                        x + 22.0,
                        dash = dash_attr(s)
                    );
                }
                SeriesStyle::Scatter => {
                    let _ = write!(
                        out,
                        r#"<circle cx="{:.1}" cy="{y:.1}" r="3.5" fill="{color}"/>"#,
                        x + 11.0
                    );
                }
            }
            let _ = write!(
                out,
                r##"<text class="legend" x="{:.1}" y="{:.1}" fill="#222">{}</text>"##,
                x + 27.0,
                y + 4.0,
                escape(&s.name)
            );
        }
    }

    /// Segment brackets and labels above the plot.
    fn xy_segment_labels(&self, out: &mut String, lay: &XyLayout) {
        for (s, row) in self.segments.iter().zip(&lay.seg_rows) {
            let Some(row) = row else { continue };
            // Inset so the brackets of adjacent segments stay distinct.
            let (a, b) = (
                lay.sx(s.x0).max(lay.left) + 1.5,
                lay.sx(s.x1).min(lay.right) - 1.5,
            );
            if b.is_nan() || a.is_nan() || b <= a {
                continue;
            }
            let y = lay.seg_top + 15.0 * *row as f64 + 11.0;
            let _ = write!(
                out,
                r##"<g class="segment"><path d="M{a:.1} {:.1}V{:.1}H{b:.1}V{:.1}" fill="none" stroke="#888"/><text x="{:.1}" y="{:.1}" text-anchor="middle" font-size="11" fill="#444">{}</text></g>"##,
                y - 6.0,
                y + 2.0,
                y - 6.0,
                (a + b) / 2.0,
                y - 1.0,
                escape(&s.label)
            );
        }
    }
}
