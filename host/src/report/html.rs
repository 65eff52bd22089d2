//! A self-contained HTML page: headings, paragraphs, tables and inline SVG plots, with a
//! small inline stylesheet. All text is escaped; nothing is loaded from elsewhere.
use super::{escape, Plot};
use std::fmt::Write;

const CSS: &str = "\
body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,sans-serif;color:#222;margin:0;background:#f6f6f4}
main{max-width:1100px;margin:0 auto;padding:24px 32px;background:#fff}
h1{font-size:1.6em;margin:0.2em 0 0.6em}
h2{font-size:1.25em;margin:1.6em 0 0.5em;padding-bottom:0.2em;border-bottom:1px solid #ddd}
p{line-height:1.45;max-width:75ch}
nav ol{margin:0 0 1em;padding-left:1.4em}
table{border-collapse:collapse;margin:0.8em 0;font-size:0.92em}
th,td{border:1px solid #d0d0d0;padding:4px 9px;text-align:left}
th{background:#f0f0ee}
td.num{text-align:right;font-variant-numeric:tabular-nums}
caption{caption-side:top;text-align:left;font-weight:bold;padding:4px 0}
figure{margin:1em 0}
svg.plot{max-width:100%;height:auto;display:block}
p.warning{border-left:5px solid #c0392b;background:#fdecea;padding:8px 12px;font-weight:600}
";

enum Block {
    Paragraph(String),
    /// Shown in red: what the reader must not miss (e.g. implausible coefficients).
    Warning(String),
    Table {
        caption: Option<String>,
        header: Vec<String>,
        rows: Vec<Vec<String>>,
    },
    Plot {
        plot: Box<Plot>,
        width_px: u32,
        height_px: u32,
    },
    /// Relative links to pages written beside this one: (text, href).
    Links(Vec<(String, String)>),
}

/// A titled section of a report.
pub struct Section {
    heading: String,
    blocks: Vec<Block>,
}

impl Section {
    pub fn new(heading: &str) -> Self {
        Section {
            heading: heading.into(),
            blocks: Vec::new(),
        }
    }
    /// Plain text (escaped); blank lines are not interpreted.
    pub fn paragraph(mut self, text: &str) -> Self {
        self.blocks.push(Block::Paragraph(text.into()));
        self
    }
    /// A table; cells that look like numbers are right-aligned.
    pub fn table<S: AsRef<str>>(mut self, header: &[S], rows: &[Vec<String>]) -> Self {
        self.blocks.push(Block::Table {
            caption: None,
            header: header.iter().map(|s| s.as_ref().to_string()).collect(),
            rows: rows.to_vec(),
        });
        self
    }
    pub fn table_with_caption<S: AsRef<str>>(
        mut self,
        caption: &str,
        header: &[S],
        rows: &[Vec<String>],
    ) -> Self {
        self = self.table(header, rows);
        if let Some(Block::Table { caption: c, .. }) = self.blocks.last_mut() {
            *c = Some(caption.into());
        }
        self
    }
    /// A plot at the default size (960 × 380 px; scales down with the page).
    pub fn plot(self, plot: Plot) -> Self {
        self.plot_sized(plot, 960, 380)
    }
    /// A list of links to pages written beside this one (relative `href`s).
    pub fn links(mut self, links: &[(String, String)]) -> Self {
        self.blocks.push(Block::Links(links.to_vec()));
        self
    }
    pub fn plot_sized(mut self, plot: Plot, width_px: u32, height_px: u32) -> Self {
        self.blocks.push(Block::Plot {
            plot: Box::new(plot),
            width_px,
            height_px,
        });
        self
    }
}

/// Report builder: a title, optional intro paragraphs, then sections in order.
pub struct HtmlReport {
    title: String,
    intro: Vec<Block>,
    sections: Vec<Section>,
}

impl HtmlReport {
    pub fn new(title: &str) -> Self {
        HtmlReport {
            title: title.into(),
            intro: Vec::new(),
            sections: Vec::new(),
        }
    }
    /// A paragraph under the title, before any section.
    pub fn paragraph(mut self, text: &str) -> Self {
        self.intro.push(Block::Paragraph(text.into()));
        self
    }
    /// A warning under the title (red box), before any section.
    pub fn warning(mut self, text: &str) -> Self {
        self.intro.push(Block::Warning(text.into()));
        self
    }
    pub fn section(mut self, section: Section) -> Self {
        self.sections.push(section);
        self
    }
    /// Ids of every plot, in page order (what the `data-plot` attributes will hold).
    pub fn plot_ids(&self) -> Vec<String> {
        self.intro
            .iter()
            .chain(self.sections.iter().flat_map(|s| s.blocks.iter()))
            .filter_map(|b| match b {
                Block::Plot { plot, .. } => Some(plot.id().to_string()),
                _ => None,
            })
            .collect()
    }

    /// The whole page as one string.
    pub fn to_html(&self) -> String {
        let mut out = String::with_capacity(64 * 1024);
        let title = escape(&self.title);
        let _ = write!(
            out,
            "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
             <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n\
             <title>{title}</title>\n<style>\n{CSS}</style>\n</head>\n<body>\n<main>\n<h1>{title}</h1>\n"
        );
        for b in &self.intro {
            render_block(&mut out, b);
        }
        if self.sections.len() > 2 {
            out.push_str("<nav><ol>\n");
            for (i, s) in self.sections.iter().enumerate() {
                let _ = writeln!(
                    out,
                    "<li><a href=\"#section-{}\">{}</a></li>",
                    i + 1,
                    escape(&s.heading)
                );
            }
            out.push_str("</ol></nav>\n");
        }
        for (i, s) in self.sections.iter().enumerate() {
            let _ = writeln!(
                out,
                "<section id=\"section-{}\">\n<h2>{}</h2>",
                i + 1,
                escape(&s.heading)
            );
            for b in &s.blocks {
                render_block(&mut out, b);
            }
            out.push_str("</section>\n");
        }
        out.push_str("</main>\n</body>\n</html>\n");
        out
    }

    /// Writes the page to a file (atomically, [`crate::io::output`]).
    pub fn write(&self, path: &std::path::Path) -> anyhow::Result<()> {
        crate::io::output::write_file(path, self.to_html())
    }
}

fn looks_numeric(s: &str) -> bool {
    let t = s.trim().trim_end_matches('%');
    let t = t.split_once(" ± ").map(|(a, _)| a).unwrap_or(t);
    !t.is_empty() && t.parse::<f64>().is_ok()
}

fn render_block(out: &mut String, b: &Block) {
    match b {
        Block::Paragraph(text) => {
            let _ = writeln!(out, "<p>{}</p>", escape(text));
        }
        Block::Warning(text) => {
            let _ = writeln!(out, "<p class=\"warning\">warning: {}</p>", escape(text));
        }
        Block::Links(links) => {
            out.push_str("<ul>\n");
            for (text, href) in links {
                let _ = writeln!(
                    out,
                    "<li><a href=\"{}\">{}</a></li>",
                    escape(href),
                    escape(text)
                );
            }
            out.push_str("</ul>\n");
        }
        Block::Table {
            caption,
            header,
            rows,
        } => {
            out.push_str("<table>\n");
            if let Some(c) = caption {
                let _ = writeln!(out, "<caption>{}</caption>", escape(c));
            }
            out.push_str("<thead><tr>");
            for h in header {
                let _ = write!(out, "<th>{}</th>", escape(h));
            }
            out.push_str("</tr></thead>\n<tbody>\n");
            for row in rows {
                out.push_str("<tr>");
                for cell in row {
                    let class = if looks_numeric(cell) {
                        " class=\"num\""
                    } else {
                        ""
                    };
                    let _ = write!(out, "<td{class}>{}</td>", escape(cell));
                }
                out.push_str("</tr>\n");
            }
            out.push_str("</tbody>\n</table>\n");
        }
        Block::Plot {
            plot,
            width_px,
            height_px,
        } => {
            out.push_str("<figure>\n");
            out.push_str(&plot.to_svg(*width_px, *height_px));
            out.push_str("\n</figure>\n");
        }
    }
}
