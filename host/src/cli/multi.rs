//! `calibrate --sensors` and `compensate --sensors` (and what `report --sensors` shares
//! with them): several magnetometers at once (docs/trace-format.md "Several
//! magnetometers"). With one sensor (or none) the commands are today's, unchanged. A
//! several-sensor `--coeffs` file brings its own sensors. The several-sensor calibration
//! itself is `multi_calibrate`.

use crate::calibration::coefficients::{coefficients_from_text, CoefficientFile};
use crate::calibration::result::Compensation;
use crate::calibration::summary::{summarise, Summary};
use crate::calibration::{compensate_trace, EstimatorSettings};
use crate::flight::Flight;
use crate::io::csv::rounded;
use crate::io::trace::Trace;
use crate::multi::joint::{apply_each, calibrate_joint};
use crate::multi::sensors::{parse_pairs, parse_sensors, sensor_trace, separation_m, SensorSpec};
use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use serde_json::value::RawValue;
use std::path::{Path, PathBuf};

/// The format tag of a several-sensor coefficient file.
pub const MULTI_FORMAT: &str = "magcomp-multi-coefficients-1";

/// The options both commands take.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct MultiArgs {
    /// Several scalar magnetometers at once (2–8): `mag_K[:FLUX][@X/Y/Z]`, comma
    /// separated, e.g. `mag_3:flux_b,mag_4:flux_c,mag_5:flux_d` or
    /// `mag_1@0/0/0,mag_2@6/-8/-0.5`. Scalars are the columns `mag_K` (or MagNav's
    /// `mag_K_uc`, SGL's `UNCOMPMAGK`); FLUX names a fluxgate (`flux_b`: columns
    /// `flux_b_x/y/z` or `FLUXB_X/Y/Z`; default the sensor's own `flux_K_*`, else the
    /// shared `flux_x/y/z`); X/Y/Z is the position on the aircraft (m, x forward, y
    /// starboard, z down; default the metadata `mag_K_position_m`). One anomaly, each
    /// sensor its own interference (docs/model.md §7). One sensor: today's command.
    #[arg(long, value_name = "mag_K[:FLUX][@X/Y/Z],...")]
    pub sensors: Option<String>,
    /// With `--sensors`: the gradient of each named pair in the output,
    /// `gradient_mag_A_mag_B` = (compensated B − compensated A) / separation (nT/m; both
    /// positions must be known).
    #[arg(long, value_name = "mag_A-mag_B,...")]
    pub gradients: Option<String>,
}

/// What `--sensors` asks of a command.
pub enum SensorPlan {
    /// No sensors named (or none found): today's command as given.
    Today,
    /// One sensor: today's command with this `--map` (`mag=` its scalar, `flux_x/y/z=` its
    /// fluxgate, after the map given), so one sensor is exactly today's run.
    One(String),
    /// Several: one anomaly, each sensor its own interference; with the several-sensor
    /// `--coeffs` file the plan read (once), whose sets the command applies.
    Several(Vec<SensorSpec>, Option<MultiCoefficients>),
}

/// A command taking `--sensors`: with one sensor it reruns as today's command, reading
/// that sensor through the `--map` its plan gives ([`SensorPlan::One`]).
pub trait OneSensorRerun: Clone {
    /// The command's own `--map`.
    fn map_mut(&mut self) -> &mut Option<String>;
    fn multi_mut(&mut self) -> &mut MultiArgs;

    /// These arguments as today's command on the one sensor `map` reads: the map
    /// replaced, `--sensors` dropped (so the rerun does not plan again).
    fn as_one_sensor(&self, map: String) -> Self {
        let mut one = self.clone();
        *one.map_mut() = Some(map);
        *one.multi_mut() = MultiArgs::default();
        one
    }
}

impl MultiArgs {
    /// Whether the command must plan its sensors: `--sensors`/`--gradients` given, or
    /// `--coeffs` naming a several-sensor file (`multi`, from [`load_multi`]: it holds its
    /// sensors).
    pub fn applies(&self, multi: Option<&MultiCoefficients>) -> bool {
        self.sensors.is_some() || self.gradients.is_some() || multi.is_some()
    }

    /// Whether the plan will be [`SensorPlan::Several`], known before the trace is read:
    /// `--sensors` naming two or more, or a several-sensor `--coeffs` file without
    /// `--sensors`.
    pub fn names_several(&self, multi: Option<&MultiCoefficients>) -> bool {
        match &self.sensors {
            Some(text) => text.split(',').filter(|e| !e.trim().is_empty()).count() > 1,
            None => multi.is_some(),
        }
    }

    /// The plan for `trace` with `--coeffs` `coeffs`, `multi` its several-sensor file when
    /// it is one ([`load_multi`], read once: the plan carries it on): without `--sensors`,
    /// a several-sensor file's own sensors (so `compensate --coeffs joint.json` needs
    /// nothing more). Several sensors with a one-sensor `--coeffs` file are refused.
    pub fn plan_with(
        &self,
        trace: &Trace,
        map: Option<&str>,
        (coeffs, multi): (Option<&Path>, Option<MultiCoefficients>),
    ) -> Result<SensorPlan> {
        let plan = match &multi {
            Some(m) if self.sensors.is_none() => {
                let sensors = sensors_of_file(&m.file, trace, &m.path)?;
                if sensors.len() == 1 && self.gradients.is_some() {
                    bail!("--gradients needs two sensors or more");
                }
                SensorPlan::Several(sensors, None)
            }
            _ => self.plan(trace, map)?,
        };
        Ok(match plan {
            SensorPlan::Several(sensors, _) => {
                if let (Some(path), None) = (coeffs, &multi) {
                    bail!(
                        "{} is not a magcomp several-sensor file: several sensors take the \
                         file `calibrate --sensors` writes",
                        path.display()
                    );
                }
                SensorPlan::Several(sensors, multi)
            }
            other => other,
        })
    }

    /// The plan for `trace`, whose own `--map` is `map`; the sensors are parsed once.
    pub fn plan(&self, trace: &Trace, map: Option<&str>) -> Result<SensorPlan> {
        let Some(text) = &self.sensors else {
            if self.gradients.is_some() {
                bail!("--gradients needs --sensors");
            }
            return Ok(SensorPlan::Today);
        };
        let mut s = parse_sensors(text, trace)?;
        match s.len() {
            0 => Ok(SensorPlan::Today),
            1 if self.gradients.is_some() => bail!("--gradients needs two sensors or more"),
            1 => Ok(SensorPlan::One(single_map(&s.remove(0), map, trace))),
            _ => Ok(SensorPlan::Several(s, None)),
        }
    }
}

/// The `--map` that makes today's command read sensor `s`, after the map given.
fn single_map(s: &SensorSpec, map: Option<&str>, trace: &Trace) -> String {
    let mut entries: Vec<String> = map
        .into_iter()
        .flat_map(|m| m.split(','))
        .filter(|e| {
            let c = e.split('=').next().unwrap_or("").trim();
            !["mag", "flux_x", "flux_y", "flux_z"].contains(&c)
        })
        .map(String::from)
        .collect();
    let pairs = [
        ("mag", s.scalar_column.as_str()),
        ("flux_x", s.flux_columns[0].as_str()),
        ("flux_y", s.flux_columns[1].as_str()),
        ("flux_z", s.flux_columns[2].as_str()),
    ];
    for (c, f) in pairs {
        if c != f {
            entries.push(format!("{c}={f}"));
            // A file column already named `c` (a simulated several-sensor file's `mag`,
            // the stinger's copy) would clash with the mapped one: it is read as `c_file`.
            if trace.col(c).is_some() {
                entries.push(format!("{c}_file={c}"));
            }
        }
    }
    entries.join(",")
}

/// One sensor in a several-sensor coefficient file.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SensorEntry {
    pub name: String,
    pub scalar_column: String,
    pub flux_columns: [String; 3],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position_m: Option<[f64; 3]>,
    /// Whether these are the joint estimate's coefficients (else the sensor's own
    /// calibration's: the joint one predicted a larger error).
    pub joint: bool,
    /// The joint and the alone calibration's predicted errors (nT).
    pub joint_predicted_error_nt: Option<f64>,
    pub alone_predicted_error_nt: Option<f64>,
    /// The alone figure is a lower bound: the sensor's lever arm makes more signal than
    /// its calibration's noise (`multi::lever`).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub alone_predicted_is_lower_bound: bool,
    /// The sensor's coefficient file, as `calibrate` writes it for one sensor (sealed),
    /// kept as written: its checksum is checked on these very characters (a number read
    /// and written again may come back one unit in the last place off).
    pub coefficients: Box<RawValue>,
}

/// A several-sensor coefficient file.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MultiFile {
    pub format: String,
    /// The anomaly's σ1 the joint calibration shared (none when each sensor was calibrated
    /// on its own, as Tolles–Lawson sets are).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma1: Option<f64>,
    pub sensors: Vec<SensorEntry>,
}

/// A several-sensor coefficient file, read and checked once: each sensor's set as a
/// one-sensor file is checked (checksum, plausibility: `coefficients_from_text`).
#[derive(Clone, Debug)]
pub struct MultiCoefficients {
    pub path: PathBuf,
    pub file: MultiFile,
    /// Each sensor's set, in the file's order.
    pub sets: Vec<CoefficientFile>,
}

/// Reads `path` once: `None` when it is no several-sensor file (a one-sensor file, or
/// one not read at all: the one-sensor reader says what is wrong with it).
pub fn load_multi(path: &Path) -> Result<Option<MultiCoefficients>> {
    #[derive(Deserialize)]
    struct Format {
        format: Option<String>,
    }
    let limit = crate::io::bounded::MAX_COEFFICIENT_FILE_BYTES
        * crate::multi::sensors::MAX_TRACE_SENSORS as u64;
    let Ok(text) =
        crate::io::bounded::read_to_string_bounded(path, limit, "magcomp coefficient file")
    else {
        return Ok(None);
    };
    let is_multi = |t: &str| {
        serde_json::from_str::<Format>(t).is_ok_and(|f| f.format.as_deref() == Some(MULTI_FORMAT))
    };
    let file: MultiFile = match serde_json::from_str::<MultiFile>(&text) {
        Ok(m) if m.format == MULTI_FORMAT => m,
        Ok(_) => return Ok(None),
        Err(_) if !is_multi(&text) => return Ok(None),
        Err(e) => {
            return Err(e).with_context(|| {
                format!("{} is not a magcomp several-sensor file", path.display())
            })
        }
    };
    let sets = file
        .sensors
        .iter()
        .map(|s| {
            let label = format!("{}: sensor {}", path.display(), s.name);
            coefficients_from_text(s.coefficients.get(), &label)
        })
        .collect::<Result<_>>()?;
    Ok(Some(MultiCoefficients {
        path: path.to_path_buf(),
        file,
        sets,
    }))
}

/// Whether `path` holds a several-sensor coefficient file (read whole: [`load_multi`]
/// reads it once for a command).
pub fn is_multi_file(path: &Path) -> bool {
    load_multi(path).is_ok_and(|m| m.is_some())
}

/// Reads a several-sensor file ([`load_multi`]); a file of another kind is an error.
pub fn read_multi(path: &Path) -> Result<(MultiFile, Vec<CoefficientFile>)> {
    let m = load_multi(path)?
        .with_context(|| format!("{} is not a magcomp several-sensor file", path.display()))?;
    Ok((m.file, m.sets))
}

/// The sensors a several-sensor file was calibrated on, resolved to `trace`'s columns.
pub fn sensors_of_file(m: &MultiFile, trace: &Trace, path: &Path) -> Result<Vec<SensorSpec>> {
    m.sensors
        .iter()
        .map(|e| {
            let columns = std::iter::once(&e.scalar_column).chain(&e.flux_columns);
            if let Some(missing) = columns.into_iter().find(|c| trace.col(c).is_none()) {
                bail!(
                    "{} holds sensor {} read from column {missing}, which this trace lacks \
                     (name its columns with --sensors)",
                    path.display(),
                    e.name
                );
            }
            Ok(SensorSpec {
                name: e.name.clone(),
                scalar_column: e.scalar_column.clone(),
                flux_columns: e.flux_columns.clone(),
                position_m: e.position_m,
            })
        })
        .collect()
}

/// Each sensor's coefficients: a several-sensor file's (matched by name), or the joint
/// calibration's on this flight; and whether each is the joint estimate's.
pub fn coefficient_sets(
    trace: &Trace,
    est: &EstimatorSettings,
    sensors: &[SensorSpec],
    coeffs: Option<&Path>,
) -> Result<(Vec<CoefficientFile>, Vec<bool>)> {
    let multi = match coeffs {
        Some(path) => {
            let (file, sets) = read_multi(path)?;
            Some(MultiCoefficients {
                path: path.to_path_buf(),
                file,
                sets,
            })
        }
        None => None,
    };
    sets_of(trace, est, sensors, multi.as_ref())
}

/// [`coefficient_sets`] from a file already read (`multi`), or calibrated jointly.
pub fn sets_of(
    trace: &Trace,
    est: &EstimatorSettings,
    sensors: &[SensorSpec],
    multi: Option<&MultiCoefficients>,
) -> Result<(Vec<CoefficientFile>, Vec<bool>)> {
    match multi {
        Some(m) => sensors
            .iter()
            .map(|s| {
                m.file
                    .sensors
                    .iter()
                    .position(|e| e.name == s.name)
                    .map(|i| (m.sets[i].clone(), m.file.sensors[i].joint))
                    .with_context(|| format!("{} has no sensor {}", m.path.display(), s.name))
            })
            .collect::<Result<Vec<_>>>()
            .map(|v| v.into_iter().unzip()),
        None => calibrate_joint(trace, est, sensors)?
            .sensors
            .iter()
            .map(|s| {
                let file = s.chosen().coefficients.clone();
                file.map(|f| (f, s.joint_chosen))
                    .with_context(|| format!("{}: no coefficients", s.spec.name))
            })
            .collect::<Result<Vec<_>>>()
            .map(|v| v.into_iter().unzip()),
    }
}

/// How `compensate --sensors` runs and reports.
#[derive(Clone, Copy, Debug, Default)]
pub struct HowToCompensate {
    /// Each sensor's causal filter, as the board runs one per sensor (`--realtime`).
    pub realtime: bool,
    /// The summary as JSON on stdout, one entry per sensor (`--json`).
    pub json: bool,
}

/// `compensate --sensors`: calibrates jointly (or applies a several-sensor file) and
/// writes each sensor's compensated field and interference and the named gradients.
/// `--realtime` runs each sensor's own causal filter (from its file's coefficients with
/// `--coeffs`): the board flies one filter per sensor, not the joint one.
pub fn compensate(
    trace: &Trace,
    est: &EstimatorSettings,
    (sensors, gradients): (&[SensorSpec], Option<&str>),
    coeffs: Option<&MultiCoefficients>,
    how: HowToCompensate,
    out: &Path,
) -> Result<()> {
    let runs: Vec<(Flight, Compensation)> = match (coeffs, how.realtime) {
        (_, true) => {
            let files = match coeffs {
                Some(m) => sets_of(trace, est, sensors, Some(m))?
                    .0
                    .into_iter()
                    .map(Some)
                    .collect(),
                None => vec![None; sensors.len()],
            };
            sensors
                .iter()
                .zip(&files)
                .map(|(s, f)| {
                    compensate_trace(&sensor_trace(trace, s), est, f.as_ref(), true)
                        .with_context(|| format!("{} in real time", s.name))
                })
                .collect::<Result<_>>()?
        }
        (Some(m), false) => {
            let (files, _) = sets_of(trace, est, sensors, Some(m))?;
            apply_each(trace, est, sensors, &files)?
        }
        (None, false) => {
            let r = calibrate_joint(trace, est, sensors)?;
            r.flights
                .into_iter()
                .zip(r.sensors.iter().map(|s| s.chosen().clone()))
                .collect()
        }
    };
    let pairs = match gradients {
        Some(g) => parse_pairs(g, sensors)?,
        None => Vec::new(),
    };
    let (flights, results): (Vec<Flight>, Vec<Compensation>) = runs.into_iter().unzip();
    let table = output_table(trace, sensors, &results, &pairs)?;
    crate::io::trace::write_trace(out, &table)?;
    let summaries: Vec<(String, Summary)> = sensors
        .iter()
        .zip(flights.iter().zip(&results))
        .map(|(s, (flight, comp))| (s.name.clone(), summarise(flight, comp)))
        .collect();
    if how.json {
        let entries = summaries
            .iter()
            .map(|(name, summary)| {
                let mut v = serde_json::to_value(summary)?;
                if let Some(o) = v.as_object_mut() {
                    o.insert("sensor".into(), name.clone().into());
                }
                Ok(v)
            })
            .collect::<Result<Vec<_>>>()?;
        crate::outln!("{}", serde_json::json!({ "sensors": entries }));
    }
    for (name, summary) in &summaries {
        if !how.json {
            crate::outln!("{name}:");
            super::summary_text::print_summary(summary);
        }
        for w in &summary.warnings {
            if w.starts_with(&format!("{name}:")) {
                crate::errln!("warning: {w}");
            } else {
                crate::errln!("warning: {name}: {w}");
            }
        }
    }
    crate::errln!("wrote {}", out.display());
    Ok(())
}

/// The separation of `--gradients` pair `a`-`b` (m): both positions known, not one place.
pub fn gradient_separation_m(sensors: &[SensorSpec], a: usize, b: usize) -> Result<f64> {
    let sep = separation_m(&sensors[a], &sensors[b]).with_context(|| {
        format!(
            "--gradients {}-{}: both positions must be known (`@X/Y/Z` or metadata)",
            sensors[a].name, sensors[b].name
        )
    })?;
    if sep <= 0.0 {
        bail!(
            "--gradients {}-{}: the sensors are at one place",
            sensors[a].name,
            sensors[b].name
        );
    }
    Ok(sep)
}

/// The output: `t`, per sensor `mag_K`, `interference_mag_K`, `compensated_mag_K`,
/// `anomaly_mag_K`, `flags_mag_K` and `interference_sigma_mag_K` (KF), then `gradient_mag_A_mag_B` per pair, then the trace's position
/// and line columns when it has them.
pub fn output_table(
    trace: &Trace,
    sensors: &[SensorSpec],
    results: &[Compensation],
    pairs: &[(usize, usize)],
) -> Result<Trace> {
    let mut out = Trace {
        meta: trace.meta.clone(),
        ..Default::default()
    };
    if let Some(t) = trace.col("t") {
        out.set_col("t", t.to_vec());
    }
    for (s, c) in sensors.iter().zip(results) {
        let mag = trace.col(&s.scalar_column).context("sensor column")?;
        out.set_col(&s.name, mag.to_vec());
        // Estimates to 0.1 pT, the compensated field's own grid (the one-sensor table's 4
        // decimals): beyond it an f32 filter's digits are noise.
        let to_grid = |v: &[f64]| v.iter().map(|&x| rounded(x, 4)).collect::<Vec<f64>>();
        out.set_col(
            &format!("interference_{}", s.name),
            to_grid(&c.interference_nt),
        );
        out.set_col(&format!("compensated_{}", s.name), c.compensated_nt.clone());
        if let Some(a) = &c.anomaly_nt {
            out.set_col(&format!("anomaly_{}", s.name), to_grid(a));
        }
        // The record's flags and bound: in real time they say which outputs are not yet
        // compensated (`NOT_CONVERGED`: the raw field) and how far each can be trusted.
        if let Some(f) = &c.flags {
            let flags = f.iter().map(|&v| f64::from(v)).collect();
            out.set_col(&format!("flags_{}", s.name), flags);
        }
        if let Some(b) = &c.interference_sigma_nt {
            out.set_col(&format!("interference_sigma_{}", s.name), to_grid(b));
        }
    }
    for &(a, b) in pairs {
        let sep = gradient_separation_m(sensors, a, b)?;
        let (ca, cb) = (&results[a].compensated_nt, &results[b].compensated_nt);
        out.set_col(
            &format!("gradient_{}_{}", sensors[a].name, sensors[b].name),
            ca.iter().zip(cb).map(|(x, y)| (y - x) / sep).collect(),
        );
    }
    for c in ["lat", "lon", "alt", "line", "LINE"] {
        if let Some(v) = trace.col(c) {
            out.set_col(c, v.to_vec());
        }
    }
    Ok(out)
}
