//! `magcomp replay CAPTURE`: run a raw sensor capture through the board's parsers, aligner
//! and filter (`crate::board::replay`), writing the records it would send.

use crate::board::capture::FluxFormat;
use crate::board::flagged_share::FlagTally;
use crate::board::monitor::FLAG_NAMES;
use crate::board::replay::{
    csv_row, multi_csv_header, multi_csv_row, read_coefficients_for, read_flux_calibration,
    read_flux_temperature, read_scalar_lag, replay_capture_any, ReplayOptions, ReplayStats,
    CSV_HEADER,
};
use crate::io::output::AtomicFile;
use crate::model::spec::{InputCorrection, ModelSpec, BOARD_MODEL};
use crate::qc::live_readout::LiveReadout;
use anyhow::{bail, Context, Result};
use magcomp_core::acquisition::AcqRecord;
use magcomp_core::model::TermKind;
use magcomp_core::protocol::multi_raw::MAX_MULTI_RAW_LEN;
use magcomp_core::protocol::multi_record::MAX_MULTI_RECORD_LEN;
use std::io::{BufReader, Write};
use std::path::{Path, PathBuf};

/// Replay a raw sensor capture through the board's acquisition code (parsers, aligner,
/// time base, compensator) and write the output records.
#[derive(clap::Args, Clone, Debug)]
pub struct ReplayArgs {
    /// Capture file (`# magcomp-capture v1`, e.g. from `magcomp simulate --capture`).
    #[arg(value_name = "CAPTURE")]
    pub capture: PathBuf,

    /// Model spec (terms joined by `+`). Channel terms see no channels in a capture and
    /// are flagged AUX_MISSING. Default: a `calibrate` coefficient file's model (as
    /// `compensate --coeffs` takes it), else the board's; a model named here that is not
    /// the file's is an error.
    #[arg(long, default_value = DEFAULT_MODEL_CHOICE, value_name = "SPEC", value_parser = parse_model_choice)]
    pub model: ModelChoice,

    /// Apply these coefficients (survey mode): a `calibrate` JSON file (entries matched
    /// to the model by `name`) or plain numbers in the model's order, separated by
    /// commas/whitespace.
    #[arg(long, value_name = "FILE")]
    pub coeffs: Option<PathBuf>,

    /// The scalar's delay τ behind the fluxgate (s, 0–0.5), as the board's `SETLAG`: each
    /// scalar sample is paired with the fluxgate at t − τ. Default: the coefficient file's
    /// `scalar_lag` when the model has `lag` (docs/firmware.md).
    #[arg(long, value_name = "SECONDS")]
    pub lag_s: Option<f32>,

    /// Scalar sample rate (Hz) of the time base; default from the capture header.
    #[arg(long, value_name = "HZ")]
    pub rate: Option<f64>,

    /// Fluxgate frame rate (Hz; staleness limit 2.5 periods); default from the capture.
    #[arg(long, value_name = "HZ")]
    pub flux_rate: Option<f64>,

    /// GPS epoch rate (Hz; staleness limit 2.5 periods); default from the capture.
    #[arg(long, value_name = "HZ")]
    pub gps_rate: Option<f64>,

    /// Fluxgate bytes are ASCII lines or SPI frames; default from the capture.
    #[arg(long, value_enum, value_name = "FORMAT")]
    pub flux: Option<FluxFormat>,

    /// Records as CSV: seq,t,mag,interference,compensated,anomaly,innovation,sigma,flags;
    /// a counter of several magnetometers (`$MCMREC`): seq,t, per channel K mag_K,
    /// interference_mag_K, compensated_mag_K, sigma_mag_K, flags_mag_K, then
    /// difference_mag_A_mag_B per pair (compensated B − A).
    #[arg(
        short = 'o',
        long = "out",
        visible_alias = "output",
        value_name = "OUT.csv"
    )]
    pub output: Option<PathBuf>,

    /// Records as the board sends them (`$MCREC,…*CRC` lines).
    #[arg(long, value_name = "OUT.txt")]
    pub records: Option<PathBuf>,

    /// The coefficients the filter holds at the end of the capture (what the board's
    /// `GETCOEF` would read then), one number per line in the model's order: a flight's
    /// in-flight calibration, to be applied to another (`replay --coeffs`).
    #[arg(long, value_name = "OUT.txt")]
    pub coeffs_out: Option<PathBuf>,

    /// As the board with `RAW,ON`: a `$MCRAW` line per scalar sample (scalar, fluxgate,
    /// position, time, flags) in `--records` before its record, so the log reads back as
    /// a trace for calibration after landing (`magcomp calibrate OUT.txt`;
    /// docs/protocols.md).
    #[arg(long, requires = "records")]
    pub raw: bool,

    /// Run beside the model its form with the fluxgate as a witness (`+fluxmod`), as the
    /// board runs its own: each record is the witnessed filter's (flag WITNESS) once that
    /// filter has converged and its stated bound is 1.46× tighter; `--coeffs` may then be
    /// either model's set (docs/firmware.md, "Fluxgate witness"). Default: on for the
    /// board's model (`tl16+field`, input corrections aside, or its witnessed form), off
    /// for others.
    #[arg(long, conflicts_with = "no_witness")]
    pub witness: bool,

    /// The model's filter alone, without the witness beside it.
    #[arg(long)]
    pub no_witness: bool,
}

pub fn run(args: &ReplayArgs) -> Result<ReplayStats> {
    let inputs: Vec<&Path> = std::iter::once(args.capture.as_path())
        .chain(args.coeffs.as_deref())
        .collect();
    let outputs: Vec<&Path> = args
        .output
        .as_deref()
        .into_iter()
        .chain(args.records.as_deref())
        .chain(args.coeffs_out.as_deref())
        .collect();
    crate::io::output::check_outputs(&inputs, &outputs)?;
    let model_text = match args.coeffs.as_deref() {
        Some(p) if !args.model.explicit => {
            file_model(p)?.unwrap_or_else(|| args.model.text.clone())
        }
        _ => args.model.text.clone(),
    };
    let (model, witness) = models_of(args, &model_text)?;
    let coefficients = args
        .coeffs
        .as_deref()
        .map(|p| match &witness {
            Some(w) => read_coefficients_for(p, Some(&model))
                .or_else(|_| read_coefficients_for(p, Some(w))),
            None => read_coefficients_for(p, Some(&model)),
        })
        .transpose()?;
    let model_has_lag = model.corrects(InputCorrection::Lag);
    let model_has_fluxtemp = model.corrects(InputCorrection::FluxTemp);
    let mut opts = ReplayOptions::new(model);
    opts.witness = witness;
    opts.coefficients = coefficients;
    opts.flux_calibration = args
        .coeffs
        .as_deref()
        .map(read_flux_calibration)
        .transpose()?
        .flatten();
    let file_lag = match args.coeffs.as_deref() {
        Some(p) if model_has_lag => read_scalar_lag(p)?,
        _ => None,
    };
    opts.lag_s = args.lag_s.or(file_lag.map(|l| l as f32));
    if model_has_lag && opts.lag_s.is_none() {
        anyhow::bail!(
            "model '{}' has `lag` but no τ is given: pass --lag-s or a coefficient file with scalar_lag",
            model_text
        );
    }
    // Like the fluxgate calibration: applied whenever the file holds one (upload sends it).
    opts.flux_temp = args
        .coeffs
        .as_deref()
        .map(read_flux_temperature)
        .transpose()?
        .flatten();
    if model_has_fluxtemp && opts.flux_temp.is_none() {
        anyhow::bail!(
            "model '{}' has `fluxtemp` but no correction is given: pass a coefficient file with fluxgate_temperature",
            model_text
        );
    }
    opts.rate_hz = args.rate;
    opts.flux_rate_hz = args.flux_rate;
    opts.gps_rate_hz = args.gps_rate;
    opts.flux = args.flux;
    let f = std::fs::File::open(&args.capture)
        .with_context(|| format!("opening {}", args.capture.display()))?;
    let mut csv = args.output.as_deref().map(AtomicFile::create).transpose()?;
    // The record and raw sinks both write the board's text stream, in the board's order.
    let txt = std::cell::RefCell::new(
        args.records
            .as_deref()
            .map(AtomicFile::create)
            .transpose()?,
    );
    // The CSV's columns follow the first record: one sensor's, or every channel's.
    let mut csv_channels: Option<u8> = None;
    let mut buf = [0u8; MAX_MULTI_RECORD_LEN];
    let mut raw_buf = [0u8; MAX_MULTI_RAW_LEN];
    let mut tally = FlagTally::default();
    // What the operator saw, per magnetometer.
    let mut live: Vec<LiveReadout> = Vec::new();
    opts.raw = args.raw;
    let stats = replay_capture_any(
        BufReader::new(f),
        &opts,
        |rec| {
            match rec {
                AcqRecord::One(r) => {
                    tally.push(r.flags);
                    live.resize_with(1, LiveReadout::default);
                    live[0].push(r.t_s, r.flags.0);
                    if let Some(w) = csv.as_mut() {
                        csv_header(w, &mut csv_channels, 1, r.seq)?;
                        writeln!(w, "{}", csv_row(r))
                            .with_context(|| format!("writing {}", w.path().display()))?;
                    }
                }
                AcqRecord::Multi(r) => {
                    let channels = &r.ch[..usize::from(r.channels)];
                    channels.iter().for_each(|c| tally.push(c.flags));
                    if live.len() < channels.len() {
                        live.resize_with(channels.len(), LiveReadout::default);
                    }
                    for (l, c) in live.iter_mut().zip(channels) {
                        l.push(r.t_s, c.flags.0);
                    }
                    if let Some(w) = csv.as_mut() {
                        csv_header(w, &mut csv_channels, r.channels, r.seq)?;
                        writeln!(w, "{}", multi_csv_row(r))
                            .with_context(|| format!("writing {}", w.path().display()))?;
                    }
                }
            }
            if let Some(w) = txt.borrow_mut().as_mut() {
                let n = rec.encode(&mut buf).map_err(|_| {
                    anyhow::anyhow!("record {} does not fit a board record line", rec.seq())
                })?;
                w.write_all(&buf[..n])
                    .with_context(|| format!("writing {}", w.path().display()))?;
            }
            Ok(())
        },
        |raw| {
            if let Some(w) = txt.borrow_mut().as_mut() {
                let n = raw
                    .encode(&mut raw_buf)
                    .map_err(|_| anyhow::anyhow!("sample {} does not fit a raw line", raw.k()))?;
                w.write_all(&raw_buf[..n])
                    .with_context(|| format!("writing {}", w.path().display()))?;
            }
            Ok(())
        },
    )
    .with_context(|| format!("replaying {}", args.capture.display()))?;
    if let (Some(w), None) = (csv.as_mut(), csv_channels) {
        writeln!(w, "{CSV_HEADER}").with_context(|| format!("writing {}", w.path().display()))?;
    }
    for w in [csv, txt.into_inner()].into_iter().flatten() {
        w.commit()?;
    }
    crate::errln!("replay: {stats}");
    for (k, l) in live.iter().enumerate() {
        match live.len() {
            1 => crate::errln!("replay: {}", l.text()),
            _ => crate::errln!("replay: mag_{}: {}", k + 1, l.text()),
        }
    }
    if let Some(w) = stats.dropped_warning() {
        crate::errln!("warning: {}: {w}", args.capture.display());
    }
    if let Some(w) = tally.warning(&FLAG_NAMES) {
        crate::errln!("warning: {}: {w}", args.capture.display());
    }
    if let Some(p) = args.coeffs_out.as_deref() {
        write_held_coefficients(p, &stats.final_coefficients)?;
    }
    Ok(stats)
}

/// The CSV's header before its first record (`n` magnetometers: 1 is `$MCREC`'s columns);
/// a record of another count later is refused: one CSV cannot hold both.
fn csv_header(w: &mut AtomicFile, written: &mut Option<u8>, n: u8, seq: u32) -> Result<()> {
    match *written {
        None => {
            let h = match n {
                1 => CSV_HEADER.to_string(),
                n => multi_csv_header(n.into()),
            };
            writeln!(w, "{h}").with_context(|| format!("writing {}", w.path().display()))?;
            *written = Some(n);
            Ok(())
        }
        Some(k) if k == n => Ok(()),
        Some(k) => bail!(
            "record {seq}: the capture goes from {k} to {n} magnetometers per record; one CSV \
             cannot hold both (write the records with --records)"
        ),
    }
}

/// The model replayed, and the witness beside it (`--witness`, `--no-witness`, else as
/// the board does).
fn models_of(args: &ReplayArgs, model_text: &str) -> Result<(ModelSpec, Option<ModelSpec>)> {
    let parsed = ModelSpec::parse(model_text)?;
    let wanted = match (args.witness, args.no_witness) {
        (true, _) => true,
        (_, true) => false,
        _ => runs_on_board_with_witness(&parsed)?,
    };
    witness_pair(parsed, wanted)
}

/// Whether the board runs `model` with the witness beside it: its own model, input
/// corrections aside, or that model's witnessed form.
fn runs_on_board_with_witness(model: &ModelSpec) -> Result<bool> {
    let board = ModelSpec::parse(BOARD_MODEL)?;
    let filter = model.without_input_corrections().text();
    Ok(filter == board.text() || filter == board.with(TermKind::FluxMod.name())?.text())
}

/// `--witness`: the model without `fluxmod` and the model with it (a coefficient file of
/// the witnessed model names the pair as well as the paper model does).
fn witness_pair(model: ModelSpec, witness: bool) -> Result<(ModelSpec, Option<ModelSpec>)> {
    if !witness {
        return Ok((model, None));
    }
    if !model.has(TermKind::FluxMod) {
        let with = model.with(TermKind::FluxMod.name())?;
        return Ok((model, Some(with)));
    }
    let text = model.text();
    let without: Vec<&str> = text
        .split('+')
        .filter(|t| *t != TermKind::FluxMod.name())
        .collect();
    let base = ModelSpec::parse(&without.join("+"))?;
    Ok((base, Some(model)))
}

/// `--coeffs-out`: one coefficient per line (f32 written exactly, so it reads back as is).
fn write_held_coefficients(path: &Path, coefficients: &[f32]) -> Result<()> {
    let mut f = AtomicFile::create(path)?;
    for c in coefficients {
        writeln!(f, "{c:e}").with_context(|| format!("writing {}", path.display()))?;
    }
    f.commit()
}

/// `--model`: the spec, and whether it was named (by the user or a caller) rather than
/// left to the default, which gives way to a coefficient file's model.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ModelChoice {
    pub text: String,
    pub explicit: bool,
}

/// The default as clap shows it in `--help`; parsed to the board's model, not explicit.
const DEFAULT_MODEL_CHOICE: &str = "tl16+field (or the coefficient file's)";

fn parse_model_choice(s: &str) -> Result<ModelChoice, String> {
    Ok(if s == DEFAULT_MODEL_CHOICE {
        ModelChoice {
            text: BOARD_MODEL.into(),
            explicit: false,
        }
    } else {
        ModelChoice::from(s)
    })
}

impl From<&str> for ModelChoice {
    fn from(s: &str) -> Self {
        ModelChoice {
            text: s.into(),
            explicit: true,
        }
    }
}

impl PartialEq<&str> for ModelChoice {
    fn eq(&self, other: &&str) -> bool {
        self.text == *other
    }
}

/// The `model` of a `calibrate` JSON coefficient file; none for plain numbers.
fn file_model(path: &Path) -> Result<Option<String>> {
    let text = crate::io::bounded::read_to_string_bounded(
        path,
        crate::io::bounded::MAX_COEFFICIENT_FILE_BYTES,
        "coefficient file",
    )?;
    let Ok(v) = serde_json::from_str::<serde_json::Value>(&text) else {
        return Ok(None);
    };
    Ok(v.get("model").and_then(|m| m.as_str()).map(String::from))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_model_choice_is_the_boards() {
        let d = parse_model_choice(DEFAULT_MODEL_CHOICE).unwrap();
        assert!(DEFAULT_MODEL_CHOICE.starts_with(BOARD_MODEL));
        assert_eq!((d.text.as_str(), d.explicit), (BOARD_MODEL, false));
        assert!(parse_model_choice(BOARD_MODEL).unwrap().explicit);
    }
}
