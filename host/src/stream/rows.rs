//! One trace row turned into what the core consumes, exactly as `Flight::from_trace`
//! builds a sample, and the row selection of `--lines`/`--time`.
use crate::flight::input::Selection;
use crate::io::trace::rows::{Kind, Row, RowsHeader};
use anyhow::{bail, Result};
use magcomp_core::{AlignedSample, MagCounts};

/// Column indices the streaming path reads (found by canonical name).
#[derive(Clone, Debug, Default)]
pub struct Cols {
    pub t: usize,
    pub mag: usize,
    pub flux: [usize; 3],
    pub lat: Option<usize>,
    pub lon: Option<usize>,
    pub alt: Option<usize>,
    pub igrf: Option<usize>,
    pub base: Option<usize>,
    pub vn: Option<usize>,
    pub ve: Option<usize>,
    pub att: Option<[usize; 3]>,
    pub channels: Vec<usize>,
    pub truth_interference: Option<usize>,
    pub date: Option<usize>,
    pub year_doy: Vec<(usize, usize, String)>,
    pub line: Option<usize>,
}

/// The columns one sensor is read from: `mag`, `flux_x/y/z` and `truth_interference` for
/// a one-sensor run; `mag_K`, its fluxgate and `truth_interference_mag_K` (else the shared
/// one) for each of several (as `multi::sensors::sensor_trace` gives them to the
/// in-memory path).
#[derive(Clone, Debug)]
pub struct SensorColumns {
    pub scalar: String,
    pub flux: [String; 3],
    /// The simulated truth: the first of these the trace has.
    pub truth: Vec<String>,
}

impl SensorColumns {
    /// One sensor: the canonical columns.
    pub fn canonical() -> Self {
        Self {
            scalar: "mag".into(),
            flux: ["flux_x", "flux_y", "flux_z"].map(String::from),
            truth: vec!["truth_interference".into()],
        }
    }
}

impl Cols {
    /// From the header of the first row; required columns must be present (their kind is
    /// checked after the first pass, [`Cols::check_kinds`]).
    pub fn resolve(names: &[String], channels: &[String]) -> Result<Self> {
        Self::resolve_sensor(names, channels, &SensorColumns::canonical())
    }

    /// [`Cols::resolve`] for the sensor read from `sensor`'s columns.
    pub fn resolve_sensor(
        names: &[String],
        channels: &[String],
        sensor: &SensorColumns,
    ) -> Result<Self> {
        let find = |n: &str| names.iter().position(|c| c == n);
        let need = |n: &str| -> Result<usize> {
            find(n).ok_or_else(|| {
                anyhow::anyhow!(
                    "the trace has no numeric column '{n}' (it has: {}); use --map {n}=COLUMN to name it",
                    names.join(", ")
                )
            })
        };
        let mut channel_idx = Vec::new();
        for c in channels {
            channel_idx
                .push(need(c).map_err(|e| e.context(format!("the model reads channel '{c}'")))?);
        }
        Ok(Cols {
            t: need("t")?,
            mag: need(&sensor.scalar)?,
            flux: [
                need(&sensor.flux[0])?,
                need(&sensor.flux[1])?,
                need(&sensor.flux[2])?,
            ],
            lat: find("lat"),
            lon: find("lon"),
            alt: find("alt"),
            igrf: find("igrf"),
            base: find("base"),
            vn: find("vn"),
            ve: find("ve"),
            att: match (find("roll"), find("pitch"), find("yaw")) {
                (Some(r), Some(p), Some(y)) => Some([r, p, y]),
                _ => None,
            },
            channels: channel_idx,
            truth_interference: sensor.truth.iter().find_map(|n| find(n)),
            date: find("date"),
            year_doy: [("year", "doy"), ("YEAR", "DOY")]
                .iter()
                .filter_map(|(y, d)| Some((find(y)?, find(d)?, format!("{y}/{d}"))))
                .collect(),
            line: ["line", "LINE"].iter().find_map(|n| find(n)),
        })
    }

    /// After the first pass: a channel the model reads must be numeric; `date` counts only
    /// as text, year/day-of-year only as numbers (what the in-memory reader would see).
    pub fn check_kinds(&mut self, head: &RowsHeader, channels: &[String]) -> Result<()> {
        for (c, &i) in channels.iter().zip(&self.channels) {
            if head.kinds[i] == Kind::Text {
                bail!(
                    "the model reads channel '{c}': the trace has no numeric column '{c}' (it is text)"
                );
            }
        }
        self.date = self.date.filter(|&i| head.kinds[i] == Kind::Text);
        self.year_doy
            .retain(|(y, d, _)| head.kinds[*y] != Kind::Text && head.kinds[*d] != Kind::Text);
        for opt in [&mut self.lat, &mut self.lon, &mut self.alt, &mut self.igrf] {
            *opt = opt.filter(|&i| head.kinds[i] != Kind::Text);
        }
        Ok(())
    }
}

/// A row as a core sample plus the raw values the first pass needs.
pub struct RowSample {
    pub line: u64,
    pub sample: AlignedSample,
    /// `mag` as read (the despiker may take it as missing later).
    pub mag_nt: f64,
    pub raw_flux: [f64; 3],
    pub raw_attitude: Option<[f64; 3]>,
    pub raw_channels: Vec<f64>,
    pub raw_base: f64,
    pub truth_interference_nt: f64,
}

/// `Flight::from_trace` for one row: `base0` and the channel offsets are the first finite
/// values (known after the first pass; `None`/0 in it).
pub fn row_sample(row: &Row, cols: &Cols, base0: Option<f64>, offsets: &[f64]) -> RowSample {
    let get = |c: Option<usize>| c.map_or(f64::NAN, |i| row.num(i));
    let t = row.num(cols.t);
    let mag = row.num(cols.mag);
    let fx = cols.flux.map(|i| row.num(i));
    let mut s = AlignedSample::empty(t);
    s.mag = MagCounts::from_nt_f64(mag);
    s.flux_nt = [fx[0] as f32, fx[1] as f32, fx[2] as f32];
    s.lat_deg = get(cols.lat);
    s.lon_deg = get(cols.lon);
    s.alt_m = get(cols.alt) as f32;
    let raw_base = get(cols.base);
    if let (Some(_), Some(b0)) = (cols.base, base0) {
        s.base_nt = (raw_base - b0) as f32;
    }
    if let Some(g) = cols.igrf {
        s.igrf_nt = row.num(g);
    }
    if let (Some(vn), Some(ve)) = (cols.vn, cols.ve) {
        s.ground_speed_mps = row.num(vn).hypot(row.num(ve)) as f32;
    }
    let raw_attitude = cols.att.map(|a| a.map(|i| row.num(i)));
    if let Some(a) = raw_attitude {
        s.attitude_deg = [a[0] as f32, a[1] as f32, a[2] as f32];
    }
    let raw_channels: Vec<f64> = cols.channels.iter().map(|&i| row.num(i)).collect();
    for (k, v) in raw_channels.iter().enumerate() {
        s.aux[k] = (v - offsets.get(k).copied().unwrap_or(0.0)) as f32;
    }
    RowSample {
        line: row.line,
        sample: s,
        mag_nt: mag,
        raw_flux: fx,
        raw_attitude,
        raw_channels,
        raw_base,
        truth_interference_nt: get(cols.truth_interference),
    }
}

/// `Selection::rows` one row at a time. The line column's values are numbers or text by
/// the reader's typing rule; a numeric one is matched by value.
pub struct RowFilter {
    sel: Selection,
    wanted: Vec<Option<f64>>,
    pub matched_lines: bool,
    pub kept: usize,
}

impl RowFilter {
    pub fn new(sel: Selection) -> Self {
        let wanted = sel.lines.iter().map(|l| l.parse::<f64>().ok()).collect();
        Self {
            sel,
            wanted,
            matched_lines: false,
            kept: 0,
        }
    }

    pub fn keep(&mut self, row: &Row, cols: &Cols) -> Result<bool> {
        let mut keep = true;
        if !self.sel.lines.is_empty() {
            let Some(lc) = cols.line else {
                bail!(
                    "--lines needs a line column (`line` or `LINE`; name yours with --map line=COLUMN); the trace has: {}",
                    row.names.join(", ")
                );
            };
            let (v, text) = (row.num(lc), row.text(lc));
            let hit = (v.is_finite() && self.wanted.contains(&Some(v)))
                || (!text.is_empty() && self.sel.lines.iter().any(|l| l == text));
            self.matched_lines |= hit;
            keep &= hit;
        }
        if let Some((a, b)) = self.sel.time_s {
            let t = row.num(cols.t);
            keep &= t >= a && t <= b;
        }
        self.kept += keep as usize;
        Ok(keep)
    }

    /// The in-memory path's errors for a selection that keeps nothing, or a line that is
    /// not a number on a numeric line column.
    pub fn finish(&self, head: &RowsHeader, cols: &Cols) -> Result<()> {
        if let Some(lc) = cols.line.filter(|_| !self.sel.lines.is_empty()) {
            if head.kinds[lc] != Kind::Text {
                if let Some(bad) = self
                    .sel
                    .lines
                    .iter()
                    .zip(&self.wanted)
                    .find(|(_, w)| w.is_none())
                {
                    bail!("--lines: '{}' is not a line number", bad.0);
                }
            }
            if !self.matched_lines {
                bail!(
                    "--lines {}: no row of column '{}' has these lines",
                    self.sel.lines.join(","),
                    head.names[lc]
                );
            }
        }
        if self.kept == 0 {
            bail!("the selection (--lines/--time) keeps no row");
        }
        Ok(())
    }
}
