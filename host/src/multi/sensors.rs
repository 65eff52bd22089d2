//! Which columns of a trace are which sensor (docs/trace-format.md, "Several
//! magnetometers"): `mag_1` … `mag_8`, each with its fluxgate and, when known, its position
//! on the aircraft.

use crate::io::trace::Trace;
use anyhow::{bail, Context, Result};

/// Most scalar sensors a trace may name (`mag_1` … `mag_8`).
pub const MAX_TRACE_SENSORS: usize = 8;

/// One scalar magnetometer of a trace, resolved to the trace's columns.
#[derive(Clone, Debug, PartialEq)]
pub struct SensorSpec {
    /// Canonical name: `mag_K`.
    pub name: String,
    /// The trace column holding its scalar.
    pub scalar_column: String,
    /// The three trace columns of its fluxgate (x, y, z).
    pub flux_columns: [String; 3],
    /// Position on the aircraft (x forward, y starboard, z down; metres), when known.
    pub position_m: Option<[f64; 3]>,
}

impl SensorSpec {
    /// Its fluxgate's name as the columns give it: `flux_b` for `flux_b_x/y/z`, `FLUXB` for
    /// `FLUXB_X/Y/Z` (what `calibrate`'s summary and the sensors page show).
    pub fn fluxgate_name(&self) -> &str {
        self.flux_columns[0]
            .trim_end_matches("_x")
            .trim_end_matches("_X")
    }
}

/// Besides a `mag_K` column, the names the public SGL data give sensor K: MagNav.jl's
/// HDF5/CSV `mag_K_uc`, the SGL XYZ `UNCOMPMAGK`.
fn scalar_aliases(k: usize) -> [String; 3] {
    [
        format!("mag_{k}"),
        format!("mag_{k}_uc"),
        format!("UNCOMPMAG{k}"),
    ]
}

/// A fluxgate named `flux_b`: the columns `flux_b_x/y/z` (MagNav), `FLUXB_X/Y/Z` (SGL XYZ),
/// or for sensor K's own `flux_K_x/y/z`.
fn flux_aliases(name: &str) -> Vec<[String; 3]> {
    let axes = |f: &dyn Fn(&str) -> String| ["x", "y", "z"].map(f);
    let mut v = vec![axes(&|a| format!("{name}_{a}"))];
    if let Some(letter) = name.strip_prefix("flux_") {
        v.push(axes(&|a| {
            format!("FLUX{}_{}", letter.to_uppercase(), a.to_uppercase())
        }));
    }
    v
}

fn has_all(trace: &Trace, cols: &[String; 3]) -> bool {
    cols.iter().all(|c| trace.col(c).is_some())
}

/// Parses `--sensors`: comma-separated `mag_K[:FLUX][@X/Y/Z]`, e.g.
/// `mag_3:flux_b,mag_4:flux_c@1.2/-0.3/0.1`, and resolves each against `trace`.
/// Without `:FLUX` the sensor's own fluxgate (`flux_K_x/y/z`) is used where the trace has
/// one, else the shared `flux_x/y/z`. Without `@` the position is the trace's metadata
/// `mag_K_position_m: X,Y,Z` when present, else unknown.
pub fn parse_sensors(text: &str, trace: &Trace) -> Result<Vec<SensorSpec>> {
    let mut out: Vec<SensorSpec> = Vec::new();
    for entry in text.split(',').map(str::trim).filter(|e| !e.is_empty()) {
        let (head, pos) = match entry.split_once('@') {
            Some((h, p)) => (h, Some(p)),
            None => (entry, None),
        };
        let (name, flux) = match head.split_once(':') {
            Some((n, f)) => (n.trim(), Some(f.trim())),
            None => (head.trim(), None),
        };
        let k: usize = name
            .strip_prefix("mag_")
            .and_then(|k| k.parse().ok())
            .filter(|k| (1..=MAX_TRACE_SENSORS).contains(k))
            .with_context(|| {
                format!("--sensors entry '{entry}': a sensor is mag_1 … mag_{MAX_TRACE_SENSORS}")
            })?;
        let name = format!("mag_{k}");
        if out.iter().any(|s| s.name == name) {
            bail!("--sensors names {name} twice");
        }
        let scalar_column = scalar_aliases(k)
            .into_iter()
            .find(|c| trace.col(c).is_some())
            .with_context(|| {
                format!(
                    "--sensors {name}: the trace has none of the columns {} (map one with --map {name}=COLUMN)",
                    scalar_aliases(k).join(", ")
                )
            })?;
        let flux_columns = match flux {
            Some(f) => flux_aliases(f)
                .into_iter()
                .find(|c| has_all(trace, c))
                .with_context(|| {
                    format!("--sensors {name}:{f}: the trace has no columns {f}_x/y/z")
                })?,
            None => flux_aliases(&format!("flux_{k}"))
                .into_iter()
                .chain(std::iter::once(
                    ["flux_x", "flux_y", "flux_z"].map(String::from),
                ))
                .find(|c| has_all(trace, c))
                .with_context(|| {
                    format!(
                        "--sensors {name}: no fluxgate: the trace has neither flux_{k}_x/y/z nor \
                         flux_x/y/z (name one: {name}:flux_b)"
                    )
                })?,
        };
        let position_m =
            match pos {
                Some(p) => Some(parse_position(p).with_context(|| {
                    format!("--sensors {name}@{p}: a position is X/Y/Z in metres")
                })?),
                None => trace
                    .meta(&format!("{name}_position_m"))
                    .map(|p| {
                        parse_position(p).with_context(|| {
                            format!("metadata {name}_position_m '{p}': expected X,Y,Z in metres")
                        })
                    })
                    .transpose()?,
            };
        out.push(SensorSpec {
            name,
            scalar_column,
            flux_columns,
            position_m,
        });
    }
    if out.is_empty() {
        bail!("--sensors names no sensor");
    }
    Ok(out)
}

fn parse_position(p: &str) -> Result<[f64; 3]> {
    let v: Vec<f64> = p
        .split(['/', ',', ' '])
        .filter(|s| !s.is_empty())
        .map(|s| s.trim().parse::<f64>())
        .collect::<Result<_, _>>()?;
    match v.as_slice() {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([*x, *y, *z]),
        _ => bail!("three finite numbers expected"),
    }
}

/// Gradient pairs (`--gradients mag_3-mag_4,mag_4-mag_5`) as indices into `sensors`.
pub fn parse_pairs(text: &str, sensors: &[SensorSpec]) -> Result<Vec<(usize, usize)>> {
    let idx = |n: &str| {
        sensors
            .iter()
            .position(|s| s.name == n.trim())
            .with_context(|| format!("--gradients: {} is not one of --sensors", n.trim()))
    };
    text.split(',')
        .map(str::trim)
        .filter(|e| !e.is_empty())
        .map(|e| {
            let (a, b) = e
                .split_once('-')
                .with_context(|| format!("--gradients entry '{e}': expected mag_A-mag_B"))?;
            let (a, b) = (idx(a)?, idx(b)?);
            if a == b {
                bail!("--gradients entry '{e}': a sensor with itself");
            }
            Ok((a, b))
        })
        .collect()
}

/// The trace as one sensor sees it: `mag` and `flux_x/y/z` are that sensor's columns
/// (whatever they were before is dropped), and its simulated truths
/// (`truth_interference_mag_K`, `truth_anomaly_mag_K`) become `truth_interference` and
/// `truth_anomaly`. Everything else is as in `trace`, so the single-sensor pipeline runs on
/// it unchanged.
pub fn sensor_trace(trace: &Trace, s: &SensorSpec) -> Trace {
    let col = |c: &str| trace.col(c).map(<[f64]>::to_vec);
    let mut own: Vec<(String, Vec<f64>)> = vec![(
        "mag".into(),
        col(&s.scalar_column).expect("resolved column"),
    )];
    for (axis, c) in ["flux_x", "flux_y", "flux_z"].iter().zip(&s.flux_columns) {
        own.push((axis.to_string(), col(c).expect("resolved column")));
    }
    for what in ["truth_interference", "truth_anomaly"] {
        if let Some(v) = col(&format!("{what}_{}", s.name)) {
            own.push((what.to_string(), v));
        }
    }
    let mut out = trace.clone();
    out.numeric
        .retain(|(n, _)| !own.iter().any(|(o, _)| o == n));
    // The sensor's columns first, where the reader puts the canonical ones.
    let rest = std::mem::take(&mut out.numeric);
    out.numeric = own.into_iter().chain(rest).collect();
    out
}

/// Separation of two sensors (m), when both positions are known.
pub fn separation_m(a: &SensorSpec, b: &SensorSpec) -> Option<f64> {
    let (pa, pb) = (a.position_m?, b.position_m?);
    Some(((pa[0] - pb[0]).powi(2) + (pa[1] - pb[1]).powi(2) + (pa[2] - pb[2]).powi(2)).sqrt())
}
