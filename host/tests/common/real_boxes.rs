//! The two calibration boxes of SGL 2020 flight 1002 (`data/reference/
//! sgl2020-flt1002-cal/`): no time, position or attitude; rows are 10 Hz samples, box 1 is
//! rows 0–6499, box 2 the rest. Shared by the tests that fly them.
#![allow(dead_code)] // each test binary uses the part it needs

use magcomp::io::trace::Trace;
use std::path::PathBuf;

pub const BOX1_ROWS: usize = 6500;
pub const FS_HZ: f64 = 10.0;
/// A Caravan surveys at ~60 m/s; the file has no positions.
pub const SPEED_MPS: f64 = 60.0;

pub struct Boxes {
    pub columns: Vec<String>,
    pub rows: Vec<Vec<f64>>,
}

/// The file, or `None` (saying so) where the shared data are absent.
pub fn boxes() -> Option<Boxes> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../data/reference/sgl2020-flt1002-cal/flt1002_line1002.02.csv");
    let Ok(text) = std::fs::read_to_string(&path) else {
        eprintln!(
            "SKIPPED: {} is absent (shared reference data)",
            path.display()
        );
        return None;
    };
    let mut lines = text.lines();
    let columns = lines.next()?.split(',').map(String::from).collect();
    let rows = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    Some(Boxes { columns, rows })
}

impl Boxes {
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// Column `name` over `range`.
    pub fn column(&self, name: &str, range: std::ops::Range<usize>) -> Vec<f64> {
        let j = self.columns.iter().position(|c| c == name).expect(name);
        range.map(|i| self.rows[i][j]).collect()
    }

    /// Rows `range` as a positionless trace (`t` = row/10 s, `mag`, `flux_*`) of scalar
    /// `mag` and fluxgate `flux` (e.g. `mag_4_uc`, `flux_d`).
    pub fn trace(&self, range: std::ops::Range<usize>, mag: &str, flux: &str) -> Trace {
        Trace {
            numeric: vec![
                (
                    "t".into(),
                    range.clone().map(|i| i as f64 / FS_HZ).collect(),
                ),
                ("mag".into(), self.column(mag, range.clone())),
                (
                    "flux_x".into(),
                    self.column(&format!("{flux}_x"), range.clone()),
                ),
                (
                    "flux_y".into(),
                    self.column(&format!("{flux}_y"), range.clone()),
                ),
                ("flux_z".into(), self.column(&format!("{flux}_z"), range)),
            ],
            ..Default::default()
        }
    }
}

/// Standard deviation of the 0.1–0.9 Hz band (20 samples trimmed at each end, as MagNav).
pub fn band_std_nt(x: &[f64]) -> f64 {
    let bp = magcomp::signal::bandpass::bandpass(x, 4, 0.1, 0.9, FS_HZ).unwrap();
    let v = &bp[20..bp.len() - 20];
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / v.len() as f64).sqrt()
}
