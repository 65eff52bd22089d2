//! `magcomp compensate`: remove the aircraft interference from a flight (calibrating on it,
//! or applying a coefficient file), write the output CSV and print the summary.

use super::args::{EstimatorArgs, LongFlightArgs, TraceInput};
use super::multi::{MultiArgs, OneSensorRerun, SensorPlan};
use super::summary_text::{print_summary, print_warnings, with_printed_warnings};
use crate::calibration::coefficients::CoefficientFile;
use crate::calibration::summary::{summarise, write_output_csv};
use crate::calibration::{compensate_trace, EstimatorSettings};
use crate::flight::input::Decimation;
use crate::io::output::check_outputs;
use crate::io::progress::quiet_progress;
use crate::io::trace::Trace;
use crate::stream::{compensate, unstreamable, StreamSummary, AUTO_STREAM_BYTES};
use anyhow::{bail, Context, Result};
use std::path::PathBuf;

#[derive(clap::Args, Clone, Debug)]
pub struct CompensateArgs {
    #[command(flatten)]
    pub input: TraceInput,
    #[command(flatten)]
    pub est: EstimatorArgs,
    #[command(flatten)]
    pub long: LongFlightArgs,
    #[command(flatten)]
    pub multi: super::multi::MultiArgs,
    /// Apply these coefficients (from `calibrate`) instead of calibrating on this trace.
    #[arg(long, value_name = "COEFFS.json")]
    pub coeffs: Option<PathBuf>,
    /// The causal filter's output sample by sample, with the board's checks, but its σ1 and
    /// noise tuned on the whole flight (the board adapts its noise as it flies: `capture`
    /// then `replay` gives the board's own records). Default: post-flight — calibrate on
    /// the whole trace, then apply the final coefficients.
    #[arg(long)]
    pub realtime: bool,
    /// With `--realtime`: switch to survey mode at this time (s, the trace's `t`), as the
    /// operator's `MODE,SURVEY` would. The coefficients held then are kept for the rest of
    /// the flight; its records carry `SURVEY_MODE`.
    #[arg(
        long,
        value_name = "T_S",
        requires = "realtime",
        conflicts_with = "coeffs"
    )]
    pub survey_from: Option<f64>,
    /// With `--realtime`: the model's filter alone. By default, calibrating in flight with
    /// the default estimator, the model's form with the fluxgate as a witness (`+fluxmod`)
    /// runs beside it and each record is the shown filter's (flag WITNESS), as on the board
    /// and in `replay` (docs/firmware.md, "Fluxgate witness").
    #[arg(long, requires = "realtime")]
    pub no_witness: bool,
    /// Output CSV: t,mag,interference,compensated[,anomaly,innovation,flags], then `igrf`
    /// and every other input column (lat, lon, LINE, X, Y, …; the input `mag` as
    /// `in_mag`), row for row; `OUT.xyz` writes Geosoft XYZ; docs/trace-format.md.
    #[arg(
        short = 'o',
        long = "out",
        visible_alias = "output",
        value_name = "OUT.csv"
    )]
    pub out: PathBuf,
    /// Print one JSON object with the summary on stdout.
    #[arg(long)]
    pub json: bool,
    /// Stream the flight (memory bounded by a window, not by the flight): `auto` streams
    /// `--coeffs` runs on inputs ≥ 256 MiB, `always` streams or says why it cannot,
    /// `never` reads the flight into memory (and, without --coeffs, does not decimate a
    /// long flight either). Streaming covers --coeffs (KF survey mode
    /// without lag/fluxtemp/rate, or --method tl; several sensors with a several-sensor
    /// file, each by its own KF or TL set); its summary leaves out the
    /// band-passed figures (residual, IR, FOM) and the applied-coefficient checks
    /// (docs/streaming.md).
    #[arg(long, value_enum, default_value_t = StreamMode::Auto)]
    pub stream: StreamMode,
}

/// When `compensate` streams.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Default)]
pub enum StreamMode {
    /// Stream when the run can be streamed and the input is ≥ 256 MiB.
    #[default]
    Auto,
    /// Stream (an error says why when the run cannot be streamed).
    Always,
    /// Read the whole flight into memory.
    Never,
}

impl OneSensorRerun for CompensateArgs {
    fn map_mut(&mut self) -> &mut Option<String> {
        &mut self.input.map
    }
    fn multi_mut(&mut self) -> &mut MultiArgs {
        &mut self.multi
    }
}

pub fn run(a: &CompensateArgs) -> Result<()> {
    let inputs: Vec<&std::path::Path> = std::iter::once(a.input.trace.as_path())
        .chain(a.coeffs.as_deref())
        .collect();
    check_outputs(&inputs, &[&a.out])?;
    crate::io::progress::force_progress(a.long.progress);
    // `--gradients` alone is refused by the plan, as `calibrate` refuses it.
    // A several-sensor --coeffs file is read (and each sensor's set checked) once, here.
    let multi = match a.coeffs.as_deref() {
        Some(path) => super::multi::load_multi(path)?,
        None => None,
    };
    if a.multi.applies(multi.as_ref()) {
        if a.multi.names_several(multi.as_ref()) && stream_several_if_asked(a, multi.as_ref())? {
            return Ok(());
        }
        let trace = a.input.read()?;
        match a
            .multi
            .plan_with(&trace, a.input.map.as_deref(), (a.coeffs.as_deref(), multi))?
        {
            SensorPlan::Today => {}
            SensorPlan::One(map) => return run(&a.as_one_sensor(map)),
            SensorPlan::Several(sensors, multi) => {
                let est = EstimatorSettings {
                    survey_from_s: a.survey_from,
                    ..a.est.settings()
                };
                let how = super::multi::HowToCompensate {
                    realtime: a.realtime,
                    json: a.json,
                };
                return super::multi::compensate(
                    &trace,
                    &est,
                    (&sensors, a.multi.gradients.as_deref()),
                    multi.as_ref(),
                    how,
                    &a.out,
                );
            }
        }
    }
    let coeffs = a.est.coefficients(a.coeffs.as_deref())?;
    if run_if_streamed(a, coeffs.as_ref())? {
        return Ok(());
    }
    // Post-flight on a long, fast flight: calibrated on a decimated copy, then applied to
    // every row streamed (the second pass over the file).
    let trace = if coeffs.is_none() && !a.realtime && a.stream != StreamMode::Never {
        let (trace, decimated) = a.input.read_for_calibration(&a.long)?;
        match decimated {
            Some(d) => return compensate_decimated(a, trace, d),
            None => trace,
        }
    } else {
        a.input.read()?
    };
    let stage = crate::io::progress::Stage::new("compensation (all filter passes)");
    let est = EstimatorSettings {
        survey_from_s: a.survey_from,
        live_witness: !a.no_witness,
        ..a.est.settings()
    };
    let (flight, comp) = compensate_trace(&trace, &est, coeffs.as_ref(), a.realtime)?;
    drop(stage);
    let carried = crate::flight::input::carried_columns(&trace);
    {
        let _stage = crate::io::progress::Stage::new("writing the output");
        write_output_csv(&a.out, &flight, &comp, &carried)?;
    }
    let stage = crate::io::progress::Stage::new("summary figures (FOM, IR, oracle floor)");
    let mut s = summarise(&flight, &comp);
    drop(stage);
    if let Some(c) = &coeffs {
        s.warnings
            .extend(a.input.provenance_warnings(Some(&trace), c));
    }
    if a.json {
        let mut v = serde_json::to_value(&s)?;
        // Where the core field came from: the file, or the model and epoch used.
        for key in [
            crate::flight::input::META_CORE_FIELD,
            crate::flight::input::META_CORE_FIELD_EPOCH,
        ] {
            if let (Some(m), Some(obj)) = (trace.meta(key), v.as_object_mut()) {
                obj.insert(key.into(), m.parse::<f64>().map_or(m.into(), Into::into));
            }
        }
        crate::outln!("{}", with_printed_warnings(v));
    } else {
        print_summary(&s);
        crate::errln!("wrote {}", a.out.display());
    }
    print_warnings(&s);
    Ok(())
}

/// Whether `compensate` streams, given `--stream mode`, why the run cannot be streamed
/// (`why_not`, None: it can) and the input's `size` (bytes): `never` does not; `always`
/// does, or refuses saying why; `auto` streams an input of 256 MiB or more, and such an
/// input read into memory gets a note saying why (returned), `per_row` its memory.
pub fn stream_decision(
    mode: StreamMode,
    why_not: Option<&str>,
    size: u64,
    input: &std::path::Path,
    per_row: &str,
) -> Result<(bool, Option<String>)> {
    Ok(match (mode, why_not) {
        (StreamMode::Never, _) => (false, None),
        (StreamMode::Always, Some(w)) => {
            bail!("--stream always: this run cannot be streamed: {w}")
        }
        (StreamMode::Always, None) => (true, None),
        (StreamMode::Auto, _) if size < AUTO_STREAM_BYTES => (false, None),
        (StreamMode::Auto, Some(w)) => (
            false,
            Some(format!(
                "note: {} is read into memory ({per_row}), not streamed: {w}",
                input.display()
            )),
        ),
        (StreamMode::Auto, None) => (true, None),
    })
}

/// The `compensate` hook: streams when `mode` (and, for `auto`, the input's size) says
/// so, prints the summary and returns true; false leaves the run to the in-memory path.
fn run_if_streamed(a: &CompensateArgs, coeffs: Option<&CoefficientFile>) -> Result<bool> {
    let (est, out, json) = (a.est.settings(), a.out.as_path(), a.json);
    let input = a.input.stream_input();
    let why_not = unstreamable(coeffs, &est, a.realtime).or_else(|| why_read_whole(a));
    let size = std::fs::metadata(input.trace).map_or(0, |m| m.len());
    let (stream, note) = stream_decision(
        a.stream,
        why_not.as_deref(),
        size,
        input.trace,
        "~1 KB per row",
    )?;
    if let Some(note) = note {
        crate::errln!("{note}");
    }
    let Some(coeffs) = coeffs.filter(|_| stream) else {
        return Ok(false);
    };
    let mut s = compensate(&input, &est, coeffs, out, quiet_progress(a.long.progress))?;
    s.warnings.extend(a.input.provenance_warnings(None, coeffs));
    print_stream_summary(&s, json, out)?;
    Ok(true)
}

/// Inputs every streamed run reads into memory, whatever it computes.
fn why_read_whole(a: &CompensateArgs) -> Option<String> {
    if crate::io::trace::is_hdf5_path(&a.input.trace) {
        Some("HDF5 files are read into memory".to_string())
    } else if a.input.rate_hz.is_some() {
        Some("a trace without time (--rate-hz) is read into memory".to_string())
    } else {
        None
    }
}

/// Several magnetometers: streams them when `--stream` (and the input's size) says so
/// (`super::multi_stream`) and returns true; false leaves them to the in-memory path.
fn stream_several_if_asked(
    a: &CompensateArgs,
    multi: Option<&super::multi::MultiCoefficients>,
) -> Result<bool> {
    let run = super::multi_stream::SeveralStreamed {
        input: &a.input,
        multi: &a.multi,
        coeffs: a.coeffs.as_deref(),
        est: EstimatorSettings {
            survey_from_s: a.survey_from,
            ..a.est.settings()
        },
        realtime: a.realtime,
        json: a.json,
        out: &a.out,
        quiet: quiet_progress(a.long.progress),
    };
    let why_not = run.why_not(multi);
    let size = std::fs::metadata(&a.input.trace).map_or(0, |m| m.len());
    let (stream, note) = stream_decision(
        a.stream,
        why_not.as_deref(),
        size,
        &a.input.trace,
        "~1 KB per row per sensor",
    )?;
    if let Some(note) = note {
        crate::errln!("{note}");
    }
    match multi.filter(|_| stream) {
        Some(m) => run.run(m).map(|()| true),
        None => Ok(false),
    }
}

/// Calibrates on the decimated copy, then applies the coefficients to the full-rate file
/// streamed: every input row gets its output row.
fn compensate_decimated(a: &CompensateArgs, trace: Trace, d: Decimation) -> Result<()> {
    let est = a.est.settings();
    // Said before the long calibration, not after it.
    if est.method == crate::calibration::coefficients::Method::Kf {
        let spec = crate::model::spec::ModelSpec::parse(&est.model)?;
        if crate::estimate::corrections::needed(&spec)
            || spec.has(magcomp_core::model::TermKind::Rate)
        {
            bail!(
                "{}; model '{}' cannot be applied streamed to the full-rate file \
                 (`lag`/`fluxtemp` pre-process the whole flight, `rate` needs its crossovers): \
                 --full-rate runs the whole flight in memory",
                d.message(),
                est.model
            );
        }
    }
    let stage = crate::io::progress::Stage::new("calibration on the decimated copy");
    let (flight, comp) = compensate_trace(&trace, &est, None, false)?;
    drop(stage);
    let file = comp
        .coefficients
        .clone()
        .context("the calibration gave no coefficients")?;
    let stage = crate::io::progress::Stage::new("summary figures of the decimated copy");
    let calibration = summarise(&flight, &comp);
    drop(stage);
    // The copy's memory is not needed for the streamed pass.
    drop((trace, flight, comp));
    if let Some(why) = unstreamable(Some(&file), &est, false) {
        bail!(
            "{}; its coefficients cannot be applied streamed to the full-rate file: {why}. \
             --full-rate runs the whole flight in memory",
            d.message()
        );
    }
    let mut s = compensate(
        &a.input.stream_input(),
        &est,
        &file,
        &a.out,
        quiet_progress(a.long.progress),
    )?;
    s.warnings.splice(0..0, calibration.warnings);
    s.decimated = Some(d);
    print_stream_summary(&s, a.json, &a.out)
}

fn print_stream_summary(s: &StreamSummary, json: bool, out: &std::path::Path) -> Result<()> {
    if json {
        crate::outln!("{}", with_printed_warnings(serde_json::to_value(s)?));
    } else {
        super::summary_text::print_stream_text(s);
        crate::errln!("wrote {}", out.display());
    }
    for w in &s.warnings {
        crate::errln!("warning: {w}");
    }
    Ok(())
}
