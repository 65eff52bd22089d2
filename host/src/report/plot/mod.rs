//! A small SVG plot builder: line/scatter series on linear or log axes, shaded windows,
//! segment labels, bar charts with error bars, legend. Output is plain SVG 1.1 text that
//! needs no fonts or scripts (text uses the viewer's sans-serif).
use super::escape;
pub use geometry::downsample_minmax;
use geometry::text_w;
use std::fmt::Write;

mod bars;
mod geometry;
mod xy;

/// Default series colours (Tableau 10: distinct, print well, mostly colour-blind safe).
pub const PALETTE: [&str; 10] = [
    "#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
    "#bcbd22", "#17becf",
];

const FONT_PX: f64 = 12.0;
/// Mean glyph advance of a sans-serif font, as a fraction of its size (no font metrics
/// available; used only to leave room for labels).
const CHAR_W: f64 = 0.6;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SeriesStyle {
    Line,
    Scatter,
}

/// One data series. Non-finite y (missing values) break the line; they are never joined
/// across or drawn as zero.
#[derive(Clone, Debug)]
pub struct Series {
    pub name: String,
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    pub style: SeriesStyle,
    /// CSS colour; None takes the next palette colour.
    pub color: Option<String>,
    /// SVG `stroke-dasharray`, e.g. "6 3".
    pub dash: Option<String>,
    pub width_px: f64,
    /// Also write the values as `data-x`/`data-y` (comma-separated) on the element, so a
    /// test or a reader can take the plotted numbers back; for short series only.
    pub values_attr: bool,
}

impl Series {
    pub fn line(name: &str, x: &[f64], y: &[f64]) -> Self {
        Series {
            name: name.into(),
            x: x.to_vec(),
            y: y.to_vec(),
            style: SeriesStyle::Line,
            color: None,
            dash: None,
            width_px: 1.4,
            values_attr: false,
        }
    }
    pub fn scatter(name: &str, x: &[f64], y: &[f64]) -> Self {
        Series {
            style: SeriesStyle::Scatter,
            ..Series::line(name, x, y)
        }
    }
    pub fn color(mut self, css: &str) -> Self {
        self.color = Some(css.into());
        self
    }
    pub fn dash(mut self, dasharray: &str) -> Self {
        self.dash = Some(dasharray.into());
        self
    }
    pub fn width_px(mut self, w: f64) -> Self {
        self.width_px = w;
        self
    }
    /// Writes the values on the element (`data-x`, `data-y`).
    pub fn with_values(mut self) -> Self {
        self.values_attr = true;
        self
    }
}

/// A bar chart: one bar per label, optional symmetric error bars (e.g. 1σ).
#[derive(Clone, Debug)]
pub struct Bars {
    pub labels: Vec<String>,
    pub values: Vec<f64>,
    pub errors: Option<Vec<f64>>,
    pub color: String,
}

#[derive(Clone, Debug)]
struct Window {
    x0: f64,
    x1: f64,
    label: String,
    color: String,
}

#[derive(Clone, Debug)]
struct Segment {
    x0: f64,
    x1: f64,
    label: String,
}

/// Plot builder. `id` becomes the SVG's `data-plot` attribute.
#[derive(Clone, Debug)]
pub struct Plot {
    id: String,
    title: String,
    x_label: String,
    y_label: String,
    x_log: bool,
    y_log: bool,
    x_range: Option<(f64, f64)>,
    y_range: Option<(f64, f64)>,
    series: Vec<Series>,
    windows: Vec<Window>,
    segments: Vec<Segment>,
    bars: Option<Bars>,
    legend: Option<bool>,
    /// Extra `data-KEY="VALUE"` attributes on the `<svg>` (figures the chart states).
    data: Vec<(String, String)>,
}

impl Plot {
    pub fn new(id: &str, title: &str) -> Self {
        Plot {
            id: id.into(),
            title: title.into(),
            x_label: String::new(),
            y_label: String::new(),
            x_log: false,
            y_log: false,
            x_range: None,
            y_range: None,
            series: Vec::new(),
            windows: Vec::new(),
            segments: Vec::new(),
            bars: None,
            legend: None,
            data: Vec::new(),
        }
    }
    pub fn id(&self) -> &str {
        &self.id
    }
    pub fn title(&self) -> &str {
        &self.title
    }
    /// Axis label with its unit, e.g. "time (s)".
    pub fn x_label(mut self, label: &str) -> Self {
        self.x_label = label.into();
        self
    }
    pub fn y_label(mut self, label: &str) -> Self {
        self.y_label = label.into();
        self
    }
    /// Log x axis; points with x <= 0 are not drawn.
    pub fn log_x(mut self) -> Self {
        self.x_log = true;
        self
    }
    /// Log y axis; points with y <= 0 are not drawn.
    pub fn log_y(mut self) -> Self {
        self.y_log = true;
        self
    }
    pub fn log_log(self) -> Self {
        self.log_x().log_y()
    }
    /// Fixes the x range (data outside is clipped); default: the data extent.
    pub fn x_range(mut self, lo: f64, hi: f64) -> Self {
        self.x_range = Some((lo, hi));
        self
    }
    /// Fixes the y range (data outside is clipped); default: the data extent plus 5 %.
    pub fn y_range(mut self, lo: f64, hi: f64) -> Self {
        self.y_range = Some((lo, hi));
        self
    }
    pub fn series(mut self, s: Series) -> Self {
        self.series.push(s);
        self
    }
    /// Adds a line series in the next palette colour.
    pub fn line(self, name: &str, x: &[f64], y: &[f64]) -> Self {
        self.series(Series::line(name, x, y))
    }
    pub fn scatter(self, name: &str, x: &[f64], y: &[f64]) -> Self {
        self.series(Series::scatter(name, x, y))
    }
    /// A shaded vertical window [x0, x1] (e.g. a failure window) with a label at its top.
    pub fn window(self, x0: f64, x1: f64, label: &str) -> Self {
        self.window_colored(x0, x1, label, "#d62728")
    }
    pub fn window_colored(mut self, x0: f64, x1: f64, label: &str, color: &str) -> Self {
        self.windows.push(Window {
            x0,
            x1,
            label: label.into(),
            color: color.into(),
        });
        self
    }
    /// A labelled span along the x axis (flight phase), drawn in a strip above the plot
    /// with a faint band in the plot.
    pub fn segment(mut self, x0: f64, x1: f64, label: &str) -> Self {
        self.segments.push(Segment {
            x0,
            x1,
            label: label.into(),
        });
        self
    }
    /// Makes this a bar chart (line/scatter series are then not drawn).
    pub fn bars(mut self, labels: &[&str], values: &[f64], errors: Option<&[f64]>) -> Self {
        self.bars = Some(Bars {
            labels: labels.iter().map(|s| s.to_string()).collect(),
            values: values.to_vec(),
            errors: errors.map(|e| e.to_vec()),
            color: PALETTE[0].into(),
        });
        self
    }
    pub fn bar_color(mut self, css: &str) -> Self {
        if let Some(b) = self.bars.as_mut() {
            b.color = css.into();
        }
        self
    }
    /// Adds `data-KEY="VALUE"` to the `<svg>` element.
    pub fn data(mut self, key: &str, value: &str) -> Self {
        self.data.push((key.into(), value.into()));
        self
    }
    /// Forces the legend on or off (default: shown when a series has a name).
    pub fn legend(mut self, show: bool) -> Self {
        self.legend = Some(show);
        self
    }

    /// Renders the plot as a standalone `<svg class="plot" data-plot="id">` element.
    pub fn to_svg(&self, width_px: u32, height_px: u32) -> String {
        let w = f64::from(width_px.max(120));
        let h = f64::from(height_px.max(100));
        let mut out = String::with_capacity(16 * 1024);
        let _ = write!(
            out,
            r#"<svg xmlns="http://www.w3.org/2000/svg" class="plot" data-plot="{id}" width="{w}" height="{h}" viewBox="0 0 {w} {h}" role="img" aria-label="{t}" font-family="sans-serif" font-size="{FONT_PX}">"#,
            id = escape(&self.id),
            t = escape(&self.title),
        );
        if !self.data.is_empty() {
            // Splice the extra attributes into the opening tag, before its closing `>`.
            out.pop();
            for (k, v) in &self.data {
                let _ = write!(out, r#" data-{}="{}""#, escape(k), escape(v));
            }
            out.push('>');
        }
        let _ = write!(out, "<title>{}</title>", escape(&self.title));
        let _ = write!(out, r##"<rect width="{w}" height="{h}" fill="#ffffff"/>"##);
        let _ = write!(
            out,
            r##"<text x="{:.1}" y="18" text-anchor="middle" font-size="14" font-weight="bold" fill="#222">{}</text>"##,
            w / 2.0,
            escape(&self.title)
        );
        if let Some(bars) = &self.bars {
            self.bar_chart(&mut out, bars, w, h);
        } else {
            self.xy_chart(&mut out, w, h);
        }
        out.push_str("</svg>");
        out
    }

    fn colors(&self) -> Vec<String> {
        let mut next = 0;
        self.series
            .iter()
            .map(|s| {
                s.color.clone().unwrap_or_else(|| {
                    let c = PALETTE[next % PALETTE.len()];
                    next += 1;
                    c.to_string()
                })
            })
            .collect()
    }

    fn data_extent(&self, axis_x: bool) -> Option<(f64, f64)> {
        let log = if axis_x { self.x_log } else { self.y_log };
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for s in &self.series {
            for (&x, &y) in s.x.iter().zip(&s.y) {
                let ok = x.is_finite()
                    && y.is_finite()
                    && (!self.x_log || x > 0.0)
                    && (!self.y_log || y > 0.0);
                if ok {
                    let v = if axis_x { x } else { y };
                    lo = lo.min(v);
                    hi = hi.max(v);
                }
            }
        }
        if axis_x && lo > hi {
            // No data: fall back on windows and segments so they still show.
            for (a, b) in self
                .windows
                .iter()
                .map(|w| (w.x0, w.x1))
                .chain(self.segments.iter().map(|s| (s.x0, s.x1)))
            {
                for v in [a, b] {
                    if v.is_finite() && (!log || v > 0.0) {
                        lo = lo.min(v);
                        hi = hi.max(v);
                    }
                }
            }
        }
        (lo <= hi).then_some((lo, hi))
    }

    /// Greedy row assignment for segment labels (at most 3 rows; a label that fits in none
    /// keeps its bracket in row 0 but loses its text, instead of overprinting).
    fn segment_rows(&self, xr: (f64, f64), left: f64, right: f64) -> (Vec<Option<usize>>, usize) {
        let tx = |v: f64| {
            if self.x_log {
                v.max(f64::MIN_POSITIVE).log10()
            } else {
                v
            }
        };
        let span = tx(xr.1) - tx(xr.0);
        let sx = |v: f64| left + (tx(v) - tx(xr.0)) / span * (right - left);
        let mut row_end = [f64::NEG_INFINITY; 3];
        let mut used = 0;
        let rows = self
            .segments
            .iter()
            .map(|s| {
                let (a, b) = (sx(s.x0).max(left), sx(s.x1).min(right));
                let tw = text_w(&s.label, 11.0);
                let c = (a + b) / 2.0;
                // Only the texts must not collide; brackets of adjacent segments may touch.
                let (l, r) = (c - tw / 2.0, c + tw / 2.0);
                let row = row_end.iter().position(|&e| e + 4.0 <= l);
                if let Some(k) = row {
                    row_end[k] = r;
                    used = used.max(k + 1);
                }
                row
            })
            .collect();
        (rows, used)
    }

    /// Y tick labels at the left edge, then the axis titles (the part the line and bar
    /// plots share).
    fn y_ticks_and_labels(
        &self,
        out: &mut String,
        y_ticks: &[f64],
        y_labels: &[String],
        sy: &dyn Fn(f64) -> f64,
        [left, right, top, bottom]: [f64; 4],
        h: f64,
    ) {
        out.push_str(r##"<g class="y-ticks" fill="#333" text-anchor="end">"##);
        for (&v, label) in y_ticks.iter().zip(y_labels) {
            let _ = write!(
                out,
                r#"<text x="{:.1}" y="{:.1}">{}</text>"#,
                left - 7.0,
                sy(v) + 4.0,
                escape(label)
            );
        }
        out.push_str("</g>");
        self.axis_labels(out, left, right, top, bottom, h);
    }

    fn axis_labels(&self, out: &mut String, left: f64, right: f64, top: f64, bottom: f64, h: f64) {
        if !self.x_label.is_empty() {
            let _ = write!(
                out,
                r##"<text class="x-label" x="{:.1}" y="{:.1}" text-anchor="middle" fill="#222">{}</text>"##,
                (left + right) / 2.0,
                h - 8.0,
                escape(&self.x_label)
            );
        }
        if !self.y_label.is_empty() {
            let cy = (top + bottom) / 2.0;
            let _ = write!(
                out,
                r##"<text class="y-label" x="14" y="{cy:.1}" transform="rotate(-90 14 {cy:.1})" text-anchor="middle" fill="#222">{}</text>"##,
                escape(&self.y_label)
            );
        }
    }
}
