//! The coefficient file `calibrate` writes and `compensate`/`report`/`diagnose --coeffs`
//! read: its format, reading by name, and the rule that the file decides the method and model.

use crate::estimate::tl;
use crate::model::spec::ModelSpec;
use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Estimation method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// The Kalman filter of the paper: deviation coefficients and the anomaly together.
    Kf,
    /// Classic Tolles–Lawson: band-passed least squares (MagNav.jl conventions).
    Tl,
}

impl Method {
    /// The name on the command line and in files.
    pub fn name(self) -> &'static str {
        match self {
            Method::Kf => "kf",
            Method::Tl => "tl",
        }
    }
}

impl std::str::FromStr for Method {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "kf" => Ok(Method::Kf),
            "tl" => Ok(Method::Tl),
            _ => bail!("unknown method '{s}' (kf or tl)"),
        }
    }
}

/// One coefficient with its 1σ.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Coefficient {
    pub name: String,
    pub unit: String,
    pub value: f64,
    pub sigma: f64,
}

/// The file `calibrate` writes and `compensate --coeffs` reads.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CoefficientFile {
    pub format: String,
    pub model: String,
    pub method: Method,
    pub sample_rate_hz: f64,
    #[serde(default)]
    pub sigma1: Option<f64>,
    #[serde(default)]
    pub noise_nt: Option<f64>,
    /// KF: signal the model could not follow beyond the scalar's noise on the calibration
    /// flight (nT rms); `compensate --coeffs` counts it in the predicted error.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model_error_nt: Option<f64>,
    #[serde(default)]
    pub tl_config: Option<tl::TlConfig>,
    /// With `fluxcal`: the fluxgate calibration the coefficients were estimated with
    /// (`B = matrix·B_F + bias_nt`, body frame); apply the same on the board.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fluxgate_calibration: Option<crate::estimate::fluxcal::FluxgateCalibration>,
    /// With `lag`: the scalar's estimated delay behind the fluxgate/GPS (s) and its 1σ;
    /// `compensate --coeffs` re-aligns the scalar by it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scalar_lag: Option<crate::model::corrections::ScalarLag>,
    /// With `fluxtemp:CH`: the fluxgate's temperature coefficients (bias nT/°C, scale 1/°C,
    /// each with its 1σ) and reference temperature; applied before the direction cosines.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fluxgate_temperature: Option<crate::model::corrections::FluxgateTemperature>,
    /// The anomaly process the calibration used (KF; see `kf::FIELD_PROFILES`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub field_process: Option<String>,
    /// With `rate`: the coefficients fitted to the flight's crossovers (s, in
    /// `crossover::RATE_LABELS` order) with their test; applied by `compensate --coeffs`
    /// when `applied` (the fit was significant).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rate_crossover: Option<RateCrossover>,
    /// KF: how well the calibration flight determined the interference, by the filter's
    /// own covariance (`kf::RegressorSpread::sigma_nt`, nT rms).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub predicted_error_nt: Option<f64>,
    /// The range one flight's actual error falls in beside `predicted_error_nt` (nT, low
    /// and high, 90 %): the error of one flight is spread over few directions
    /// (`crate::qc::error_range`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub predicted_error_range_nt: Option<[f64; 2]>,
    /// The compensated output's high-frequency content beyond the scalar's own noise (nT
    /// rms; `crate::qc::high_frequency`): interference the model does not follow, counted
    /// in `predicted_error_nt` and its range.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unfollowed_high_frequency_nt: Option<f64>,
    /// KF: the coefficients' covariance (rows in the model's coefficient order, as
    /// `calibrate` writes `coefficients`; physical units), so
    /// that `compensate --coeffs` can predict the error on the flight it compensates.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub covariance: Option<Vec<Vec<f64>>>,
    /// KF on a trace without positions: the ground speed assumed for the anomaly process
    /// (m/s), reused by `compensate --coeffs` unless `--speed-mps` is given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub assumed_speed_mps: Option<f64>,
    /// Calibration: the manoeuvre-band rms (nT) the compensated signal is expected to show
    /// on another flight of this installation flown like this one: this flight's own
    /// compensated band rms with the band part of the jackknife error added
    /// (`crate::estimate::jackknife`). Real SGL boxes, box 1 → box 2 and back: measured / this =
    /// 0.90–1.32 for `mag_3`, `mag_4` and `mag_5`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub predicted_band_rms_nt: Option<f64>,
    /// KF calibration: the flight's own check of its coefficients (jackknife figures of the
    /// filter and of band-passed least squares, and which was used: `kf::crosscheck`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cross_check: Option<crate::estimate::jackknife::CrossCheck>,
    /// Where the coefficients came from (`calibrate` fills it; files written before it
    /// existed have none and still load).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub provenance: Option<super::provenance::Provenance>,
    /// Read from a file without a checksum (written before magcomp sealed its files): a
    /// change to its values cannot be detected. Not part of the file.
    #[serde(skip)]
    pub unsealed: bool,
    pub coefficients: Vec<Coefficient>,
}

/// The crossover fit as the coefficient file and the JSON summary carry it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RateCrossover {
    pub labels: Vec<String>,
    #[serde(flatten)]
    pub fit: crate::estimate::crossover::RateFit,
    pub applied: bool,
}

pub const COEFF_FORMAT: &str = "magcomp-coefficients-v1";

/// SHA-256 (hex) of a coefficient file's JSON without its `checksum` and `provenance`
/// members, re-serialised compactly with sorted keys and the coefficients sorted by name:
/// layout, indentation, member order and the order of the entries do not change it (files
/// are read by name), any value does. `provenance` says where the file came from, not what
/// is applied, and may be stripped from a file that is passed on. Computed from the parsed
/// text on both sides, so that writer and reader hash the same numbers whatever the float
/// parser's last digit.
pub fn canonical_sha256(json: &str) -> Result<String> {
    use sha2::{Digest, Sha256};
    let mut v: serde_json::Value = serde_json::from_str(json)?;
    if let Some(o) = v.as_object_mut() {
        o.remove("checksum");
        o.remove("provenance");
        if let Some(c) = o.get_mut("coefficients").and_then(|c| c.as_array_mut()) {
            c.sort_by(|a, b| {
                let name = |v: &serde_json::Value| v["name"].as_str().unwrap_or("").to_string();
                name(a).cmp(&name(b))
            });
        }
    }
    let text = serde_json::to_string(&sorted(v))?;
    Ok(Sha256::digest(text.as_bytes())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect())
}

/// `v` with every object's keys in sorted order (independent of serde_json's features).
fn sorted(v: serde_json::Value) -> serde_json::Value {
    use serde_json::Value;
    match v {
        Value::Object(o) => {
            let mut pairs: Vec<(String, Value)> = o.into_iter().collect();
            pairs.sort_by(|a, b| a.0.cmp(&b.0));
            Value::Object(pairs.into_iter().map(|(k, v)| (k, sorted(v))).collect())
        }
        Value::Array(a) => Value::Array(a.into_iter().map(sorted).collect()),
        other => other,
    }
}

/// The file as `calibrate` writes it: pretty JSON with its [`canonical_sha256`].
/// The member is kept out of [`CoefficientFile`] (read beside it, in [`read_coefficients`])
/// so that the files' builders need not know of it.
pub fn to_sealed_json(file: &CoefficientFile) -> Result<String> {
    let text = serde_json::to_string_pretty(file)?;
    let sum = canonical_sha256(&text)?;
    // Appended as the last member, the rest of the layout as before.
    let body = text
        .trim_end()
        .strip_suffix('}')
        .context("a coefficient file serialises to a JSON object")?
        .trim_end();
    Ok(format!("{body},\n  \"checksum\": \"{sum}\"\n}}"))
}

/// Values no calibration can produce, in words: a sample rate, noise or σ1 that is not a
/// positive number, a covariance that is not symmetric positive semi-definite. Such files
/// used to be applied and to print a predicted error of 0.0.
pub fn plausibility_problem(c: &CoefficientFile) -> Option<String> {
    let positive = |v: f64| v.is_finite() && v > 0.0;
    if !positive(c.sample_rate_hz) {
        return Some(format!(
            "the sample rate is {} Hz: it must be a positive number",
            c.sample_rate_hz
        ));
    }
    if let Some(n) = c.noise_nt.filter(|n| !positive(*n)) {
        return Some(format!(
            "the scalar noise is {n} nT: it must be a positive number"
        ));
    }
    if let Some(s) = c.sigma1.filter(|s| !positive(*s)) {
        return Some(format!(
            "σ1 (the anomaly's along-track roughness, sigma1) is {s}: it must be a positive number"
        ));
    }
    if let Some(bad) = c
        .coefficients
        .iter()
        .find(|c| c.sigma.is_nan() || c.sigma < 0.0)
    {
        return Some(format!(
            "coefficient '{}' has a 1σ of {}: it must be zero or positive",
            bad.name, bad.sigma
        ));
    }
    let cov = c.covariance.as_ref()?;
    let k = cov.len();
    if cov.iter().any(|r| r.len() != k) || cov.iter().flatten().any(|v| !v.is_finite()) {
        return Some("the covariance is not a square matrix of numbers".into());
    }
    let m = nalgebra::DMatrix::from_fn(k, k, |i, j| cov[i][j]);
    let scale = (0..k).map(|i| m[(i, i)].abs()).fold(0.0, f64::max);
    // Relative tolerances: the file holds decimal renderings of f64 values.
    for i in 0..k {
        for j in 0..i {
            if (m[(i, j)] - m[(j, i)]).abs() > 1e-9 * scale + 1e-300 {
                return Some(format!(
                    "the covariance is not symmetric: entry ({}, {}) is {} but ({}, {}) is {}",
                    i + 1,
                    j + 1,
                    m[(i, j)],
                    j + 1,
                    i + 1,
                    m[(j, i)]
                ));
            }
        }
    }
    let min_eig = m.symmetric_eigen().eigenvalues.min();
    if min_eig < -1e-9 * scale {
        return Some(format!(
            "the covariance is not positive semi-definite (smallest eigenvalue {min_eig:.3e}, \
             largest variance {scale:.3e}): it cannot be a coefficient covariance"
        ));
    }
    None
}

/// `--coeffs` decides the method and the model: a `--method` or `--model` given beside
/// it that says otherwise is an error, not silently overridden.
pub fn refuse_conflicting_settings(
    coeffs: &CoefficientFile,
    method: Option<Method>,
    model: Option<&str>,
) -> Result<()> {
    let name = |m: Method| m.name();
    if let Some(m) = method.filter(|m| *m != coeffs.method) {
        bail!(
            "--method {} conflicts with the coefficient file, which holds {} coefficients: drop --method (the file decides) or give a {} coefficient file",
            name(m),
            name(coeffs.method),
            name(m)
        );
    }
    if let Some(m) = model {
        let same = coeffs.method == Method::Kf
            && ModelSpec::parse(m).map(|s| s.text()).ok().as_deref() == Some(coeffs.model.as_str());
        if !same {
            bail!(
                "--model {m} conflicts with the coefficient file's model '{}': drop --model (the file decides) or calibrate that model",
                coeffs.model
            );
        }
    }
    Ok(())
}

/// What a file without a checksum cannot promise (stderr at load; `--json` and the page
/// through the applied-coefficient warnings).
pub const UNSEALED_NOTE: &str = "no checksum (written before magcomp recorded one): a change \
     to its values after calibration cannot be detected";

/// Reads a coefficient file written by `calibrate`. Coefficients are matched to the
/// file's model by name, whatever their order in the file, and returned in the model's
/// order (the covariance is in the model's order already); a name the model lacks, one
/// it needs that is
/// missing, or one given twice is an error naming it.
pub fn read_coefficients(path: &Path) -> Result<CoefficientFile> {
    let text = crate::io::bounded::read_to_string_bounded(
        path,
        crate::io::bounded::MAX_COEFFICIENT_FILE_BYTES,
        "magcomp coefficient file",
    )?;
    coefficients_from_text(&text, &path.display())
}

/// [`read_coefficients`] on a file's text, already read (a several-sensor file's sets);
/// `path` names it in the messages.
pub fn coefficients_from_text(text: &str, path: &dyn std::fmt::Display) -> Result<CoefficientFile> {
    let c: CoefficientFile = serde_json::from_str(text)
        .with_context(|| format!("{path} is not a magcomp coefficient file"))?;
    if c.format != COEFF_FORMAT {
        bail!("{}: unknown format '{}'", path, c.format);
    }
    if let Some(bad) = c.coefficients.iter().find(|c| !c.value.is_finite()) {
        bail!("{}: coefficient '{}' is not finite", path, bad.name);
    }
    let names = c
        .model_coefficient_names()
        .with_context(|| path.to_string())?;
    let mut ordered = c
        .in_order_of(&names)
        .with_context(|| format!("{} (model '{}')", path, c.model))?;
    // After the names: a renamed, missing or extra coefficient is said as such.
    // A value changed after `calibrate` (two coefficients swapped: 2.43 nT; the sign of
    // `permanent.e3` flipped: 2.24 nT) was applied with exit 0 before the checksum.
    let checksum = serde_json::from_str::<serde_json::Value>(text)
        .ok()
        .and_then(|v| v.get("checksum").map(|s| s.as_str().map(str::to_string)));
    match checksum {
        Some(None) => bail!("{}: the checksum is not a string", path),
        Some(Some(sum)) => {
            if canonical_sha256(text)? != sum.to_ascii_lowercase() {
                bail!(
                    "{}: the content does not match its checksum: a value was changed after \
                     `calibrate` wrote the file (or it is damaged); recalibrate, or restore \
                     the original file",
                    path
                );
            }
        }
        None => {
            crate::errln!("note: {}: {}", path, UNSEALED_NOTE);
            ordered.unsealed = true;
        }
    }
    if let Some(p) = plausibility_problem(&c) {
        bail!("{}: {p}", path);
    }
    Ok(ordered)
}

impl CoefficientFile {
    /// A file of `model`'s coefficients with nothing else known: every optional member
    /// (calibrations, τ, covariance, …) absent, to be filled by who knows it.
    pub fn new(
        model: impl Into<String>,
        method: Method,
        sample_rate_hz: f64,
        coefficients: Vec<Coefficient>,
    ) -> Self {
        Self {
            format: COEFF_FORMAT.into(),
            model: model.into(),
            method,
            sample_rate_hz,
            sigma1: None,
            noise_nt: None,
            model_error_nt: None,
            tl_config: None,
            fluxgate_calibration: None,
            scalar_lag: None,
            fluxgate_temperature: None,
            field_process: None,
            rate_crossover: None,
            predicted_error_nt: None,
            predicted_error_range_nt: None,
            unfollowed_high_frequency_nt: None,
            covariance: None,
            assumed_speed_mps: None,
            cross_check: None,
            predicted_band_rms_nt: None,
            provenance: None,
            unsealed: false,
            coefficients,
        }
    }

    /// A Tolles–Lawson fit holding this file's coefficients (what `tl::interference` applies).
    pub fn tl_fit(&self, config: crate::estimate::tl::TlConfig) -> crate::estimate::tl::TlFit {
        crate::estimate::tl::TlFit {
            coefficients: self.coefficients.iter().map(|c| c.value).collect(),
            sigma: self.coefficients.iter().map(|c| c.sigma).collect(),
            names: self.coefficients.iter().map(|c| c.name.clone()).collect(),
            config,
            rows_used: 0,
            rows_nonfinite: 0,
            rows_short_runs: 0,
            runs_used: 0,
            residual_std_nt: f64::NAN,
            cond_normal: f64::NAN,
            rank: 0,
            noise_gain: 1.0,
        }
    }

    /// The names of the coefficients the file's model has, in the model's order: the KF
    /// model's `term.label`s, or the Tolles–Lawson terms of its configuration.
    pub fn model_coefficient_names(&self) -> Result<Vec<String>> {
        Ok(match self.method {
            Method::Kf => ModelSpec::parse(&self.model)?
                .coefficient_names()
                .into_iter()
                .map(|(n, _)| n)
                .collect(),
            Method::Tl => self
                .tl_config
                .as_ref()
                .context("the coefficient file has no Tolles–Lawson configuration")?
                .terms
                .names(),
        })
    }

    /// The same file with its coefficients (and the crossover fit's coefficients) in the
    /// order of `names`, matched by name; the covariance's size is checked.
    pub fn in_order_of(&self, names: &[String]) -> Result<CoefficientFile> {
        let order = order_by_name(
            self.coefficients.iter().map(|c| c.name.as_str()),
            names,
            "coefficient",
        )?;
        let mut out = self.clone();
        out.coefficients = order
            .iter()
            .map(|&i| self.coefficients[i].clone())
            .collect();
        if let Some(cov) = &self.covariance {
            // Unnamed rows: in the model's order, whatever the order of the entries.
            let k = names.len();
            if cov.len() != k || cov.iter().any(|r| r.len() != k) {
                bail!("the covariance is not {k} × {k} (one row and column per coefficient of the model)");
            }
        }
        if let Some(r) = &self.rate_crossover {
            let want = crate::estimate::crossover::RATE_LABELS.map(String::from);
            let o = order_by_name(
                r.labels.iter().map(String::as_str),
                &want,
                "rate_crossover label",
            )?;
            let mut r2 = r.clone();
            for (k, &i) in o.iter().enumerate() {
                r2.fit.coefficients[k] = r.fit.coefficients[i];
                r2.fit.sigmas[k] = r.fit.sigmas[i];
            }
            r2.labels = want.to_vec();
            out.rate_crossover = Some(r2);
        }
        Ok(out)
    }
}

/// For each of `want`, the index of the entry of `have` with that name; an entry that is
/// not wanted, a wanted one that is missing, or a name given twice is an error naming it.
pub(crate) fn order_by_name<'a>(
    have: impl Iterator<Item = &'a str>,
    want: &[String],
    what: &str,
) -> Result<Vec<usize>> {
    let have: Vec<&str> = have.collect();
    for (i, n) in have.iter().enumerate() {
        if !want.iter().any(|w| w == n) {
            bail!(
                "unknown {what} '{n}' (the model's are: {})",
                want.join(", ")
            );
        }
        if have[..i].contains(n) {
            bail!("{what} '{n}' is given twice");
        }
    }
    want.iter()
        .map(|w| {
            have.iter().position(|n| n == w).with_context(|| {
                format!(
                    "{what} '{w}' is missing ({} of {} given)",
                    have.len(),
                    want.len()
                )
            })
        })
        .collect()
}
