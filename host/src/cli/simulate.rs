//! `magcomp simulate`: a calibration and/or survey flight with known truth, and with
//! `--capture` the raw bytes its sensors would have sent.

use crate::board::capture::{
    parse_time_of_day, write_capture_file, CaptureOptions, CaptureSummary, FluxFormat,
};
use crate::io::trace::Trace;
use crate::sim::{
    parse_hidden, EarthField, FlightKind, Geology, GeologyPreset, Physics, SimConfig,
};
use anyhow::{bail, Context, Result};
use clap::builder::PossibleValue;
use std::path::PathBuf;

/// Simulate an airborne magnetometer flight (calibration cloverleaf and/or survey lines,
/// or a take-off from the apron) with an exact physical model: buried dipole geology, exact field modulus, vector
/// Tolles–Lawson aircraft field with exact dB/dt, diurnal, and realistic sensor errors.
#[derive(clap::Args, Clone, Debug)]
pub struct SimulateArgs {
    /// Output trace file (CSV, or Geosoft XYZ for `.xyz`; see docs/trace-format.md).
    #[arg(
        short = 'o',
        long = "out",
        visible_alias = "output",
        value_name = "FILE"
    )]
    pub output: Option<PathBuf>,

    /// Scalar magnetometers on the aircraft (1–4): 1 = `mag` as always; 2–4 add `mag_1` (the
    /// stinger, = `mag`), `mag_2`/`mag_3` (wingtips 8 m out, 6 m ahead), `mag_4` (cabin, 9 m
    /// ahead), each its own interference, the geology evaluated at each
    /// (`truth_*_mag_K`, metadata `mag_K_position_m`; docs/trace-format.md "Several
    /// magnetometers").
    #[arg(long, default_value_t = 1, value_name = "N")]
    pub sensors: usize,

    /// What to fly: `calibration` (cloverleaf, 4 headings × roll/pitch/yaw), `survey`
    /// (parallel lines), `calibration+survey`, or `takeoff`: from power-up on the apron
    /// (60 s `ground`, engine off; 30 s `engine_start`: a 5–20 nT body field the model does
    /// not know, `truth_hidden_engine`, its current written with `--hidden engine:CH`),
    /// `taxi` at 6–8 m/s with two 90° turns past hangar steel and a parked vehicle (tens to
    /// hundreds of nT, in `truth_anomaly`), `takeoff` roll and rotation, `climb` at
    /// 3–4 m/s with one or two `climb_turn`s banked 15–25°, `level_off` at
    /// --survey-altitude-m, then `line_1001` (--line-length-m) and, with --lines ≥ 2, a
    /// `turn` onto its reciprocal `line_1002`; no calibration manoeuvres.
    #[arg(long, default_value = "calibration", value_name = "KIND")]
    pub flight: String,

    /// Random seed: the same seed gives the same flight, byte for byte.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,

    /// Physics profile: `classic`, or `broad` (issue 10: aircraft, fluxgate, navigation
    /// errors, heading order, geology strength, diurnal drawn per seed from wider ranges,
    /// no base station; README, simulator notes). Flags given explicitly override the
    /// profile's draws.
    #[arg(long, default_value = "classic", value_name = "PROFILE")]
    pub physics: String,

    /// Scalar magnetometer sample rate (Hz), 1–1000.
    #[arg(long, default_value_t = 10.0, value_name = "HZ")]
    pub rate_hz: f64,

    /// Ground speed (m/s).
    #[arg(long, default_value_t = 60.0, value_name = "M_PER_S")]
    pub speed_mps: f64,

    /// Start latitude (deg, WGS-84; the cloverleaf centre / survey origin is here).
    #[arg(long, default_value_t = 45.3, allow_negative_numbers = true)]
    pub lat_deg: f64,

    /// Start longitude (deg east; negative = west).
    #[arg(long, default_value_t = -75.7, allow_negative_numbers = true)]
    pub lon_deg: f64,

    /// Elevation of the (flat) ground above sea level (m).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub ground_elev_m: f64,

    /// Height above ground of the calibration cloverleaf (m). High = quiet anomaly.
    #[arg(long, default_value_t = 3000.0)]
    pub cal_altitude_m: f64,

    /// Height above ground of the survey lines (m).
    #[arg(long, default_value_t = 300.0)]
    pub survey_altitude_m: f64,

    /// Amplitude of smooth height undulations, e.g. a terrain drape (m, 0 = constant
    /// height). Wavelength is chosen so the climb slope stays ≤ 6 %.
    #[arg(long, default_value_t = 0.0)]
    pub altitude_swing_m: f64,

    /// Calibration leg headings (deg, comma separated) in the order flown; all legs
    /// cross one centre point. [default: 45,135,225,315; broad: drawn per seed]
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub cal_headings_deg: Option<Vec<f64>>,

    /// Roll manoeuvre amplitude (deg).
    #[arg(long, default_value_t = 8.0)]
    pub roll_amp_deg: f64,

    /// Pitch manoeuvre amplitude (deg).
    #[arg(long, default_value_t = 5.0)]
    pub pitch_amp_deg: f64,

    /// Yaw (heading) manoeuvre amplitude (deg).
    #[arg(long, default_value_t = 5.0)]
    pub yaw_amp_deg: f64,

    /// Period of the roll/pitch/yaw swings (s).
    #[arg(long, default_value_t = 6.0)]
    pub manoeuvre_period_s: f64,

    /// Number of cycles of each manoeuvre.
    #[arg(long, default_value_t = 3)]
    pub manoeuvre_cycles: u32,

    /// Straight-and-level part of each calibration leg (s), centred on the centre point.
    #[arg(long, default_value_t = 20.0)]
    pub level_s: f64,

    /// Maximum turn rate (deg/s) of the banked, coordinated turns (3 = standard rate).
    #[arg(long, default_value_t = 3.0)]
    pub turn_rate_deg_s: f64,

    /// Number of survey lines.
    #[arg(long, default_value_t = 10)]
    pub lines: usize,

    /// Survey line length (m).
    #[arg(long, default_value_t = 10_000.0)]
    pub line_length_m: f64,

    /// Survey line spacing (m).
    #[arg(long, default_value_t = 200.0)]
    pub line_spacing_m: f64,

    /// Heading of the odd lines (deg); even lines fly the reciprocal.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub line_heading_deg: f64,

    /// Tie lines flown across the survey lines after them (perpendicular, alternating
    /// direction, labelled `tie_2001`…): their crossings with the lines are what levelling
    /// and the `rate` term need.
    #[arg(long, default_value_t = 0)]
    pub tie_lines: usize,

    /// Tie line spacing along the survey lines (m).
    #[arg(long, default_value_t = 1000.0)]
    pub tie_spacing_m: f64,

    /// Survey block origin relative to the start point, `NORTH,EAST` (m); combined flights.
    #[arg(
        long,
        default_value = "0,8000",
        value_delimiter = ',',
        allow_negative_numbers = true
    )]
    pub survey_offset_m: Vec<f64>,

    /// Wind speed (m/s); its direction is random per seed and sets the crab angle.
    #[arg(long, default_value_t = 5.0)]
    pub wind_mps: f64,

    /// Rms of the turbulence on roll (pitch, yaw get 0.7×), deg.
    #[arg(long, default_value_t = 0.3)]
    pub turbulence_deg: f64,

    /// Use a uniform main field `F,I,D` (nT, deg, deg) instead of the IGRF-2020 dipole.
    #[arg(
        long,
        value_delimiter = ',',
        allow_negative_numbers = true,
        value_name = "F,I,D"
    )]
    pub earth_fid: Option<Vec<f64>>,

    /// Geology preset: `quiet` (deep basement: ~0.001–0.01 nT/m at 3000 m), `moderate`,
    /// `strong` (shallow magnetic rocks: hundreds of nT, 0.1–several nT/m at ≤400 m),
    /// or `none`. [default: quiet; takeoff: strong; broad: quiet scaled to
    /// --anomaly-pp-nt]
    #[arg(long)]
    pub geology: Option<String>,

    /// Scale the geology so the true anomaly spans this many nT peak to peak along the
    /// flight. [broad: 2–40 nT drawn per seed, unless --geology is given]
    #[arg(long, value_name = "NT")]
    pub anomaly_pp_nt: Option<f64>,

    /// Override: buried dipole sources per km².
    #[arg(long)]
    pub sources_per_km2: Option<f64>,

    /// Override: source depth range below ground `MIN,MAX` (m).
    #[arg(long, value_delimiter = ',')]
    pub source_depth_m: Option<Vec<f64>>,

    /// Override: induced moment range `MIN,MAX` (A·m², log-uniform). A sphere of radius
    /// 200 m with susceptibility 0.05 in 50 000 nT has ~7e7 A·m².
    #[arg(long, value_delimiter = ',')]
    pub source_moment_am2: Option<Vec<f64>>,

    /// Override: Koenigsberger ratio (remanent/induced moment, random remanent direction).
    #[arg(long)]
    pub remanence_q: Option<f64>,

    /// Rms of the slow diurnal variation (nT). [default: 2; broad: 0.5–2]
    #[arg(long)]
    pub diurnal_nt: Option<f64>,

    /// Record the diurnal at a base station (`base` column). [default: true; broad: false]
    #[arg(long, value_name = "BOOL")]
    pub base_station: Option<bool>,

    /// Multiplies the aircraft's K, L, M (1 = Cessna Caravan-like; 0 = magnetically clean).
    #[arg(long, default_value_t = 1.0)]
    pub interference_scale: f64,

    /// Scalar magnetometer white noise (nT rms).
    #[arg(long, default_value_t = 0.01)]
    pub scalar_noise_nt: f64,

    /// Fluxgate white noise (nT rms, per axis). [default: 0.5; broad: 0.5–2]
    #[arg(long)]
    pub flux_noise_nt: Option<f64>,

    /// INS attitude error (deg rms; correlated, τ = 100 s, plus 30 % white).
    /// [default: 0.03; broad: 0.02–0.05]
    #[arg(long)]
    pub ins_noise_deg: Option<f64>,

    /// GPS horizontal position error (m rms, Gauss–Markov).
    #[arg(long, default_value_t = 1.0)]
    pub gps_sigma_h_m: f64,

    /// GPS vertical position error (m rms, Gauss–Markov). [default: 1.5; broad: 2]
    #[arg(long)]
    pub gps_sigma_v_m: Option<f64>,

    /// Correlation time of the GPS errors (s).
    #[arg(long, default_value_t = 60.0)]
    pub gps_tau_s: f64,

    /// Add an effect the default model does not know (repeatable): `current:CH`,
    /// `current_rate:CH`, `lag:SECONDS`, `rate`, `diurnal`, `induced_high`, `fluxcal`,
    /// `periodic:CH`, `fluxtemp:CH[:K]` (the fluxgate drifts with the temperature written
    /// as CH, bias coefficients K/4…K nT/°C per axis, default K 0.8), `engine[:CH]` (takeoff
    /// only, where it is always present: CH records the generator current); suffix
    /// `@T0:T1` (s) limits it to a time window. Its contribution is written as
    /// `truth_hidden_<name>`.
    #[arg(long = "hidden", value_name = "SPEC")]
    pub hidden: Vec<String>,

    /// Add an auxiliary channel with a current-like waveform and no magnetic effect
    /// (repeatable), to test false detections; a name containing `temp` gets a
    /// temperature-like waveform instead.
    #[arg(long = "decoy", value_name = "CH")]
    pub decoys: Vec<String>,

    /// Standard deviation (nT) that hidden effects are scaled to inside their window
    /// (`rate` and `engine` are physical and not scaled; `periodic` gets half).
    #[arg(long, default_value_t = 2.0)]
    pub hidden_std_nt: f64,

    /// The fluxgate sees the hidden currents and periodic lines too, this many times as
    /// strong along the same direction (a cabin source nearer the fluxgate than the
    /// scalar; 0: it does not). Without the current's channel in the trace, only the
    /// fluxgate's modulus then witnesses it (`fluxmod`).
    #[arg(long, default_value_t = 0.0, value_name = "X")]
    pub hidden_at_fluxgate: f64,

    /// Stop the flight after this many seconds.
    #[arg(long)]
    pub max_duration_s: Option<f64>,
}

fn pair(v: &Option<Vec<f64>>, what: &str) -> Result<Option<(f64, f64)>> {
    match v {
        None => Ok(None),
        Some(v) if v.len() == 2 => Ok(Some((v[0], v[1]))),
        Some(_) => bail!("{what} needs two values MIN,MAX"),
    }
}

impl SimulateArgs {
    pub fn to_config(&self) -> Result<SimConfig> {
        // The profile gives what the flags below leave unset.
        let flight = FlightKind::parse(&self.flight)?;
        let profile = match Physics::parse(&self.physics)? {
            Physics::Classic if flight == FlightKind::Takeoff => SimConfig::takeoff(self.seed),
            Physics::Classic => SimConfig::default(),
            Physics::Broad => SimConfig::broad(self.seed),
        };
        let (mut geology, mut anomaly_pp_nt) = match self.geology.as_deref() {
            None => (profile.geology.clone(), profile.anomaly_pp_nt),
            Some(g) => {
                let preset = match g {
                    "quiet" => GeologyPreset::Quiet,
                    "moderate" => GeologyPreset::Moderate,
                    "strong" => GeologyPreset::Strong,
                    "none" => GeologyPreset::None,
                    other => bail!("unknown geology `{other}` (quiet, moderate, strong, none)"),
                };
                (Geology::preset(preset), None)
            }
        };
        if self.anomaly_pp_nt.is_some() {
            anomaly_pp_nt = self.anomaly_pp_nt;
        }
        if let Some(d) = self.sources_per_km2 {
            geology.sources_per_km2 = d;
        }
        if let Some((a, b)) = pair(&self.source_depth_m, "--source-depth-m")? {
            geology.depth_min_m = a;
            geology.depth_max_m = b;
        }
        if let Some((a, b)) = pair(&self.source_moment_am2, "--source-moment-am2")? {
            geology.moment_min_am2 = a;
            geology.moment_max_am2 = b;
        }
        if let Some(q) = self.remanence_q {
            geology.remanence_q = q;
        }
        let earth = match &self.earth_fid {
            None => EarthField::Dipole,
            Some(v) if v.len() == 3 => EarthField::Fixed {
                f_nt: v[0],
                inc_deg: v[1],
                dec_deg: v[2],
            },
            Some(_) => bail!("--earth-fid needs three values F,I,D"),
        };
        let survey_offset_m = match self.survey_offset_m.as_slice() {
            [n, e] => [*n, *e],
            _ => bail!("--survey-offset-m needs two values NORTH,EAST"),
        };
        let hidden = self
            .hidden
            .iter()
            .map(|s| parse_hidden(s).with_context(|| format!("--hidden {s}")))
            .collect::<Result<Vec<_>>>()?;
        let cfg = SimConfig {
            flight,
            seed: self.seed,
            sample_rate_hz: self.rate_hz,
            speed_mps: self.speed_mps,
            start_lat_deg: self.lat_deg,
            start_lon_deg: self.lon_deg,
            ground_elev_m: self.ground_elev_m,
            cal_altitude_m: self.cal_altitude_m,
            survey_altitude_m: self.survey_altitude_m,
            altitude_swing_m: self.altitude_swing_m,
            cal_headings_deg: self
                .cal_headings_deg
                .clone()
                .unwrap_or(profile.cal_headings_deg.clone()),
            roll_amp_deg: self.roll_amp_deg,
            pitch_amp_deg: self.pitch_amp_deg,
            yaw_amp_deg: self.yaw_amp_deg,
            manoeuvre_period_s: self.manoeuvre_period_s,
            manoeuvre_cycles: self.manoeuvre_cycles,
            level_s: self.level_s,
            turn_rate_deg_s: self.turn_rate_deg_s,
            survey_lines: self.lines,
            line_length_m: self.line_length_m,
            line_spacing_m: self.line_spacing_m,
            line_heading_deg: self.line_heading_deg,
            tie_lines: self.tie_lines,
            tie_spacing_m: self.tie_spacing_m,
            survey_offset_m,
            wind_mps: self.wind_mps,
            turbulence_deg: self.turbulence_deg,
            earth,
            geology,
            diurnal_nt: self.diurnal_nt.unwrap_or(profile.diurnal_nt),
            interference_scale: self.interference_scale,
            scalar_noise_nt: self.scalar_noise_nt,
            flux_noise_nt: self.flux_noise_nt.unwrap_or(profile.flux_noise_nt),
            ins_noise_deg: self.ins_noise_deg.unwrap_or(profile.ins_noise_deg),
            gps_sigma_h_m: self.gps_sigma_h_m,
            gps_sigma_v_m: self.gps_sigma_v_m.unwrap_or(profile.gps_sigma_v_m),
            gps_tau_s: self.gps_tau_s,
            hidden,
            decoys: self.decoys.clone(),
            hidden_std_nt: self.hidden_std_nt,
            hidden_at_fluxgate: self.hidden_at_fluxgate,
            max_duration_s: self.max_duration_s,
            physics: profile.physics,
            base_station: self.base_station.unwrap_or(profile.base_station),
            anomaly_pp_nt,
        };
        cfg.validate()?;
        Ok(cfg)
    }
}

fn window(v: &Option<Vec<f64>>, what: &str) -> Result<Option<(f64, f64)>> {
    match v.as_deref() {
        None => Ok(None),
        Some([a, b]) => Ok(Some((*a, *b))),
        Some(other) => bail!("{what} needs START:END in seconds, got {other:?}"),
    }
}

/// Flags for `magcomp simulate --capture FILE` (flattened into `SimulateArgs` or the
/// simulate subcommand by the CLI).
#[derive(clap::Args, Clone, Debug, Default)]
pub struct CaptureArgs {
    /// Also write the flight as a raw sensor capture (`docs/protocols.md` §7): scalar
    /// lines, fluxgate frames and GPS NMEA as the sensors would send them.
    #[arg(long, value_name = "FILE")]
    pub capture: Option<PathBuf>,

    /// Fluxgate format in the capture: serial ASCII lines or ADS131M03 SPI frames.
    #[arg(long, value_enum, default_value = "ascii", value_name = "FORMAT")]
    pub capture_flux: FluxFormat,

    /// GPS epoch rate in the capture (Hz): GGA + RMC + VTG per epoch.
    #[arg(long, default_value_t = 5.0, value_name = "HZ")]
    pub capture_gps_hz: f64,

    /// UTC time of day at the start of the flight, `HH:MM:SS` (the GPS sentences' time).
    #[arg(long, default_value = "12:00:00", value_name = "HH:MM:SS")]
    pub capture_start: String,

    /// Fluxgate dropout: no fluxgate frames in `START:END` (s from the start).
    #[arg(long, value_delimiter = ':', num_args = 1, value_name = "START:END")]
    pub capture_flux_dropout: Option<Vec<f64>>,

    /// GPS outage: the receiver reports no fix in `START:END` (s from the start).
    #[arg(long, value_delimiter = ':', num_args = 1, value_name = "START:END")]
    pub capture_gps_outage: Option<Vec<f64>>,

    /// Fraction of bytes corrupted at random on every port (e.g. 0.01); line ends kept.
    #[arg(long, default_value_t = 0.0, value_name = "FRACTION")]
    pub capture_corrupt: f64,

    /// Seed of the corruption.
    #[arg(long, default_value_t = 1)]
    pub capture_seed: u64,
}

impl CaptureArgs {
    pub fn to_options(&self) -> Result<CaptureOptions> {
        let o = CaptureOptions {
            flux_format: self.capture_flux,
            gps_rate_hz: self.capture_gps_hz,
            start_tod_s: parse_time_of_day(&self.capture_start)?,
            flux_dropout_s: window(&self.capture_flux_dropout, "--capture-flux-dropout")?,
            gps_outage_s: window(&self.capture_gps_outage, "--capture-gps-outage")?,
            corrupt_fraction: self.capture_corrupt,
            seed: self.capture_seed,
            ..CaptureOptions::default()
        };
        o.validate()?;
        Ok(o)
    }

    /// Writes the capture when `--capture` was given; returns what was written.
    pub fn write_if_requested(&self, trace: &Trace) -> Result<Option<CaptureSummary>> {
        let Some(path) = &self.capture else {
            return Ok(None);
        };
        write_capture_file(trace, &self.to_options()?, path).map(Some)
    }
}

impl clap::ValueEnum for FluxFormat {
    fn value_variants<'a>() -> &'a [Self] {
        &[FluxFormat::Ascii, FluxFormat::Spi]
    }
    fn to_possible_value(&self) -> Option<PossibleValue> {
        Some(PossibleValue::new(self.name()).help(match self {
            FluxFormat::Ascii => "serial ASCII lines `X,Y,Z*hh`",
            FluxFormat::Spi => "15-byte ADS131M03 SPI frames (one capture line each)",
        }))
    }
}

/// Writes the flight (and the capture when asked).
pub fn run(sim: &SimulateArgs, capture: &CaptureArgs) -> Result<()> {
    let out = sim
        .output
        .clone()
        .unwrap_or_else(|| PathBuf::from("flight.csv"));
    let outputs: Vec<&std::path::Path> = std::iter::once(out.as_path())
        .chain(capture.capture.as_deref())
        .collect();
    crate::io::output::check_outputs(&[], &outputs)?;
    let cfg = sim.to_config()?;
    let trace = match sim.sensors {
        0 | 1 => crate::sim::simulate(&cfg)?,
        n @ 2..=4 => crate::sim::multi::simulate_multi(
            &cfg,
            &crate::sim::multi::STINGER_WINGTIPS_CABIN_M[..n],
        )?,
        n => bail!("--sensors {n}: 1 to 4"),
    };
    crate::io::trace::write_trace(&out, &trace)?;
    crate::errln!("wrote {} rows to {}", trace.len(), out.display());
    if let (Some(c), Some(p)) = (capture.write_if_requested(&trace)?, &capture.capture) {
        crate::errln!(
            "wrote the capture {}: {} scalar lines ({} Hz), {} fluxgate frames ({} Hz), {} GPS sentences ({} Hz), {} bytes ({} corrupted)",
            p.display(),
            c.scalar_lines,
            c.scalar_hz,
            c.flux_frames,
            c.flux_hz,
            c.gps_sentences,
            c.gps_hz,
            c.total_bytes,
            c.corrupted_bytes
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(clap::Parser)]
    struct Cli {
        #[command(flatten)]
        args: SimulateArgs,
    }

    #[test]
    fn help_renders() {
        use clap::CommandFactory;
        let help = Cli::command().render_long_help().to_string();
        assert!(help.contains("--hidden <SPEC>") && help.contains("--cal-altitude-m"));
    }

    #[test]
    fn defaults_match_config_default() {
        let cli = Cli::try_parse_from(["x"]).unwrap();
        assert_eq!(cli.args.to_config().unwrap(), SimConfig::default());
    }

    #[test]
    fn takeoff_matches_its_constructor() {
        let cli = Cli::try_parse_from(["x", "--flight", "takeoff", "--seed", "4"]).unwrap();
        assert_eq!(cli.args.to_config().unwrap(), SimConfig::takeoff(4));
        for bad in [
            vec!["x", "--hidden", "engine"],
            vec!["x", "--flight", "takeoff", "--hidden", "engine@1:2"],
            vec!["x", "--flight", "takeoff", "--altitude-swing-m", "20"],
        ] {
            let r = Cli::try_parse_from(bad.clone()).map(|c| c.args.to_config());
            assert!(!matches!(r, Ok(Ok(_))), "{bad:?}");
        }
    }

    #[test]
    fn broad_profile_and_explicit_flags_over_it() {
        let cli = Cli::try_parse_from(["x", "--physics", "broad", "--seed", "4"]).unwrap();
        assert_eq!(cli.args.to_config().unwrap(), SimConfig::broad(4));
        let cli = Cli::try_parse_from([
            "x",
            "--physics",
            "broad",
            "--seed",
            "4",
            "--diurnal-nt",
            "3",
            "--geology",
            "strong",
            "--cal-headings-deg",
            "0,90",
            "--base-station",
            "true",
        ])
        .unwrap();
        let c = cli.args.to_config().unwrap();
        assert_eq!(c.diurnal_nt, 3.0);
        assert_eq!(c.geology, Geology::preset(GeologyPreset::Strong));
        assert_eq!(c.anomaly_pp_nt, None);
        assert_eq!(c.cal_headings_deg, vec![0.0, 90.0]);
        assert!(c.base_station);
        assert_eq!(c.physics, Physics::Broad);
        assert_eq!(c.flux_noise_nt, SimConfig::broad(4).flux_noise_nt);
        assert!(Cli::try_parse_from(["x", "--physics", "wide"])
            .map(|c| c.args.to_config())
            .is_ok_and(|r| r.is_err()));
    }

    #[test]
    fn flags_parse_and_bad_values_error() {
        let cli = Cli::try_parse_from([
            "x",
            "--flight",
            "survey",
            "--hidden",
            "current:cur_pump@10:20",
            "--decoy",
            "cur_x",
            "--earth-fid",
            "50000,70,-12",
            "--lon-deg",
            "-10",
        ])
        .unwrap();
        let c = cli.args.to_config().unwrap();
        assert_eq!(c.flight, FlightKind::Survey);
        assert_eq!(c.hidden.len(), 1);
        for bad in [
            vec!["x", "--rate-hz", "5000"],
            vec!["x", "--flight", "loop"],
            vec!["x", "--geology", "granite"],
            vec!["x", "--hidden", "nonsense"],
            vec!["x", "--decoy", "mag"],
            vec!["x", "--source-depth-m", "100"],
            vec!["x", "--speed-mps", "NaN"],
            vec!["x", "--source-depth-m", "100,inf"],
            vec!["x", "--source-moment-am2", "1e9,1e6"],
            vec!["x", "--survey-offset-m", "1"],
        ] {
            let r = Cli::try_parse_from(bad.clone()).map(|c| c.args.to_config());
            assert!(!matches!(r, Ok(Ok(_))), "{bad:?}");
        }
    }
}
