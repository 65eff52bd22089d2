//! The bar chart of a [`Plot`] (one bar per label, optional symmetric error bars).
use super::geometry::{text_w, tick_step, widen};
use super::{Bars, Plot, FONT_PX};
use crate::report::escape;
use crate::report::ticks::{format_tick, nice_ticks};
use std::fmt::Write;

impl Plot {
    pub(super) fn bar_chart(&self, out: &mut String, bars: &Bars, w: f64, h: f64) {
        let n = bars.labels.len().min(bars.values.len());
        let err = |i: usize| {
            bars.errors
                .as_ref()
                .and_then(|e| e.get(i))
                .copied()
                .filter(|e| e.is_finite())
                .unwrap_or(0.0)
                .abs()
        };
        let mut lo: f64 = 0.0;
        let mut hi: f64 = 0.0;
        for i in 0..n {
            let v = bars.values[i];
            if v.is_finite() {
                lo = lo.min(v - err(i));
                hi = hi.max(v + err(i));
            }
        }
        let (lo, hi) = self.y_range.unwrap_or_else(|| {
            let pad = 0.06 * (hi - lo);
            (
                if lo < 0.0 { lo - pad } else { 0.0 },
                if hi > 0.0 { hi + pad } else { 0.0 },
            )
        });
        let (lo, hi) = widen((lo, hi), false);
        let y_ticks = nice_ticks(lo, hi, ((h / 60.0) as usize).clamp(3, 10));
        let step = Some(tick_step(&y_ticks));
        let y_labels: Vec<String> = y_ticks.iter().map(|&v| format_tick(v, step)).collect();
        let y_label_w = y_labels
            .iter()
            .map(|s| text_w(s, FONT_PX))
            .fold(0.0, f64::max);
        let left = 8.0 + if self.y_label.is_empty() { 0.0 } else { 20.0 } + y_label_w + 8.0;
        let right = w - 16.0;
        let slot = (right - left) / n.max(1) as f64;
        let longest = bars
            .labels
            .iter()
            .map(|l| text_w(l, FONT_PX))
            .fold(0.0, f64::max);
        // Rotate category labels when they do not fit side by side.
        let rotate = longest > slot - 4.0;
        let label_h = if rotate {
            (longest * 0.64 + 8.0).min(h * 0.35)
        } else {
            16.0
        };
        let top = 34.0;
        let bottom =
            (h - 8.0 - label_h - if self.x_label.is_empty() { 0.0 } else { 18.0 }).max(top + 20.0);
        let sy = |v: f64| bottom - (v - lo) / (hi - lo) * (bottom - top);

        out.push_str(r##"<g stroke="#e4e4e4">"##);
        for &v in &y_ticks {
            let _ = write!(
                out,
                r#"<line x1="{left:.1}" y1="{y:.1}" x2="{right:.1}" y2="{y:.1}"/>"#,
                y = sy(v)
            );
        }
        out.push_str("</g>");
        let zero = sy(0.0_f64.clamp(lo, hi));
        for i in 0..n {
            let v = bars.values[i];
            let cx = left + slot * (i as f64 + 0.5);
            let bw = (slot * 0.7).max(1.0);
            if v.is_finite() {
                let y = sy(v.clamp(lo, hi));
                let e = err(i);
                let tip = if e > 0.0 {
                    format!("{}: {} ± {}", bars.labels[i], v, e)
                } else {
                    format!("{}: {}", bars.labels[i], v)
                };
                let _ = write!(
                    out,
                    r#"<rect class="bar" x="{:.1}" y="{:.1}" width="{bw:.1}" height="{:.1}" fill="{}"><title>{}</title></rect>"#,
                    cx - bw / 2.0,
                    y.min(zero),
                    (y - zero).abs().max(0.5),
                    escape(&bars.color),
                    escape(&tip)
                );
                if e > 0.0 {
                    let (y0, y1) = (sy((v - e).clamp(lo, hi)), sy((v + e).clamp(lo, hi)));
                    let cap = (bw * 0.3).min(8.0);
                    let _ = write!(
                        out,
                        r##"<path class="error-bar" d="M{cx:.1} {y0:.1}V{y1:.1}M{:.1} {y0:.1}H{:.1}M{:.1} {y1:.1}H{:.1}" stroke="#222" stroke-width="1.2" fill="none"/>"##,
                        cx - cap,
                        cx + cap,
                        cx - cap,
                        cx + cap
                    );
                }
            } else {
                let _ = write!(
                    out,
                    r##"<text x="{cx:.1}" y="{:.1}" text-anchor="middle" font-size="10" fill="#888">n/a</text>"##,
                    zero - 3.0
                );
            }
            let label = escape(&bars.labels[i]);
            if rotate {
                let y = bottom + 12.0;
                let _ = write!(
                    out,
                    r##"<text x="{cx:.1}" y="{y:.1}" text-anchor="end" transform="rotate(-40 {cx:.1} {y:.1})" fill="#333">{label}</text>"##
                );
            } else {
                let _ = write!(
                    out,
                    r##"<text x="{cx:.1}" y="{:.1}" text-anchor="middle" fill="#333">{label}</text>"##,
                    bottom + 16.0
                );
            }
        }
        let _ = write!(
            out,
            r##"<line x1="{left:.1}" y1="{zero:.1}" x2="{right:.1}" y2="{zero:.1}" stroke="#444"/>"##
        );
        let _ = write!(
            out,
            r##"<rect x="{left:.1}" y="{top:.1}" width="{:.1}" height="{:.1}" fill="none" stroke="#444"/>"##,
            right - left,
            bottom - top
        );
        self.y_ticks_and_labels(out, &y_ticks, &y_labels, &sy, [left, right, top, bottom], h);
    }
}
