//! Simulator settings: the flight kinds, `SimConfig` with its defaults, and their
//! validation (ranges a real aircraft and survey can have).

use super::*;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlightKind {
    Calibration,
    Survey,
    CalibrationSurvey,
    /// From the apron (engine off, engine start, taxi) through take-off and climb to a
    /// survey line and its reciprocal; no calibration manoeuvres (`takeoff.rs`).
    Takeoff,
}

impl FlightKind {
    pub fn name(&self) -> &'static str {
        match self {
            FlightKind::Calibration => "calibration",
            FlightKind::Survey => "survey",
            FlightKind::CalibrationSurvey => "calibration+survey",
            FlightKind::Takeoff => "takeoff",
        }
    }
    /// Flies the calibration cloverleaf.
    pub fn has_calibration(&self) -> bool {
        matches!(
            self,
            FlightKind::Calibration | FlightKind::CalibrationSurvey
        )
    }
    /// Flies a survey block (lines, tie lines).
    pub fn has_survey(&self) -> bool {
        matches!(self, FlightKind::Survey | FlightKind::CalibrationSurvey)
    }
    pub fn parse(s: &str) -> Result<Self> {
        Ok(match s {
            "calibration" | "cal" => FlightKind::Calibration,
            "survey" => FlightKind::Survey,
            "calibration+survey" | "cal+survey" => FlightKind::CalibrationSurvey,
            "takeoff" => FlightKind::Takeoff,
            other => anyhow::bail!(
                "unknown flight kind `{other}` (calibration, survey, calibration+survey, takeoff)"
            ),
        })
    }
}

/// Everything that defines a simulated flight. `Default` is a realistic high-altitude
/// (3000 m) cloverleaf calibration flight over quiet geology at 10 Hz.
#[derive(Clone, Debug, PartialEq)]
pub struct SimConfig {
    pub flight: FlightKind,
    pub seed: u64,
    pub sample_rate_hz: f64,
    /// Ground speed (m/s).
    pub speed_mps: f64,
    pub start_lat_deg: f64,
    pub start_lon_deg: f64,
    /// Ground elevation (flat ground), m above sea level.
    pub ground_elev_m: f64,
    /// Height above ground of the calibration cloverleaf and of the survey lines.
    pub cal_altitude_m: f64,
    pub survey_altitude_m: f64,
    /// Amplitude of smooth height undulations (terrain drape), 0 = none.
    pub altitude_swing_m: f64,
    pub cal_headings_deg: Vec<f64>,
    pub roll_amp_deg: f64,
    pub pitch_amp_deg: f64,
    pub yaw_amp_deg: f64,
    pub manoeuvre_period_s: f64,
    pub manoeuvre_cycles: u32,
    pub level_s: f64,
    /// Maximum turn rate (deg/s); 3 °/s is a standard-rate turn.
    pub turn_rate_deg_s: f64,
    pub survey_lines: usize,
    pub line_length_m: f64,
    pub line_spacing_m: f64,
    pub line_heading_deg: f64,
    /// Tie lines across the survey lines (perpendicular, flown after them) and their
    /// spacing along the lines (m).
    pub tie_lines: usize,
    pub tie_spacing_m: f64,
    /// Survey block origin relative to the start point (north, east, m), combined flights.
    pub survey_offset_m: [f64; 2],
    pub wind_mps: f64,
    pub turbulence_deg: f64,
    pub earth: EarthField,
    pub geology: Geology,
    /// Rms of the smooth diurnal variation (nT).
    pub diurnal_nt: f64,
    /// Multiplies the drawn K, L, M (1 = Cessna Caravan-like).
    pub interference_scale: f64,
    pub scalar_noise_nt: f64,
    pub flux_noise_nt: f64,
    pub ins_noise_deg: f64,
    pub gps_sigma_h_m: f64,
    pub gps_sigma_v_m: f64,
    pub gps_tau_s: f64,
    pub hidden: Vec<HiddenEffect>,
    pub decoys: Vec<String>,
    /// Target standard deviation (nT) of scaled hidden effects inside their window.
    pub hidden_std_nt: f64,
    /// The fluxgate sees the hidden vector effects too (currents, periodic lines), this
    /// many times as strong, along the same direction: a cabin source nearer the fluxgate
    /// than the scalar, which only the fluxgate's modulus then witnesses (`fluxmod`) when
    /// its channel is not recorded. 0 = the fluxgate does not see them (the default).
    pub hidden_at_fluxgate: f64,
    /// Truncate the flight (s); None = fly the whole plan.
    pub max_duration_s: Option<f64>,
    /// Aircraft and fluxgate physics (`physics.rs`): `Classic`, or the `Broad` profile of
    /// issue 10 (use [`SimConfig::broad`], which also draws the configuration's part).
    pub physics: Physics,
    /// Record the diurnal at a base station (`base` column).
    pub base_station: bool,
    /// Scale the geology so the true anomaly spans this many nT peak to peak along the
    /// flight (measured at the field knots); None = the population as drawn.
    pub anomaly_pp_nt: Option<f64>,
}

impl SimConfig {
    /// A box flown for crossovers, where the `rate` effect is observable: calibration on
    /// the survey's headings (0/90/180/270°), then 8 lines × 5 km 200 m apart and 10 tie
    /// lines 500 m apart (80 crossings), all at 300 m over strong geology, with DGPS-grade
    /// positions (0.3 m: the rate effect is mostly the anomaly read N·V ≈ 1–2 m late, so
    /// the crossings must place the two passes better than that).
    pub fn crossover_box(seed: u64) -> Self {
        SimConfig {
            seed,
            flight: FlightKind::CalibrationSurvey,
            cal_altitude_m: 300.0,
            survey_altitude_m: 300.0,
            cal_headings_deg: vec![0.0, 90.0, 180.0, 270.0],
            geology: Geology::preset(GeologyPreset::Strong),
            survey_lines: 8,
            line_length_m: 5000.0,
            tie_lines: 10,
            tie_spacing_m: 500.0,
            survey_offset_m: [0.0, 5000.0],
            gps_sigma_h_m: 0.3,
            ..SimConfig::default()
        }
    }

    /// The cloverleaf (`SimConfig::default()`'s) and then a straight leg at the pattern's
    /// altitude (a 180 s return turn, a 12 km line, 10 891 samples at 10 Hz): an in-flight
    /// calibration is judged once the pattern is over, and the board's `NOT_CONVERGED` waits
    /// for every heading to be flown and for the estimate to stop moving
    /// (`magcomp_core::compensator::health`).
    pub fn calibration_with_exit(seed: u64) -> Self {
        let d = SimConfig::default();
        SimConfig {
            seed,
            flight: FlightKind::CalibrationSurvey,
            survey_altitude_m: d.cal_altitude_m,
            survey_lines: 1,
            line_length_m: 12_000.0,
            survey_offset_m: [0.0, 0.0],
            ..d
        }
    }

    /// The take-off (`takeoff.rs`): apron, engine start, taxi, take-off, climb through the
    /// low-altitude anomaly to `survey_altitude_m`, a line and its reciprocal, over the
    /// strong geology: the only preset with sources shallow enough (from 150 m) for the
    /// field over the airfield to be several times rougher at 2 m than at 300 m (seeds
    /// 1–4: horizontal gradient 2–8× at the same places; quiet and moderate 1.3–2.2×).
    pub fn takeoff(seed: u64) -> Self {
        SimConfig {
            seed,
            flight: FlightKind::Takeoff,
            geology: Geology::preset(GeologyPreset::Strong),
            ..SimConfig::default()
        }
    }
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            flight: FlightKind::Calibration,
            seed: 1,
            sample_rate_hz: 10.0,
            speed_mps: 60.0,
            start_lat_deg: 45.3,
            start_lon_deg: -75.7,
            ground_elev_m: 0.0,
            cal_altitude_m: 3000.0,
            survey_altitude_m: 300.0,
            altitude_swing_m: 0.0,
            cal_headings_deg: vec![45.0, 135.0, 225.0, 315.0],
            roll_amp_deg: 8.0,
            pitch_amp_deg: 5.0,
            yaw_amp_deg: 5.0,
            manoeuvre_period_s: 6.0,
            manoeuvre_cycles: 3,
            level_s: 20.0,
            turn_rate_deg_s: 3.0,
            survey_lines: 10,
            line_length_m: 10_000.0,
            line_spacing_m: 200.0,
            line_heading_deg: 0.0,
            tie_lines: 0,
            tie_spacing_m: 1000.0,
            survey_offset_m: [0.0, 8000.0],
            wind_mps: 5.0,
            turbulence_deg: 0.3,
            earth: EarthField::Dipole,
            geology: Geology::preset(GeologyPreset::Quiet),
            diurnal_nt: 2.0,
            interference_scale: 1.0,
            scalar_noise_nt: 0.01,
            flux_noise_nt: 0.5,
            ins_noise_deg: 0.03,
            gps_sigma_h_m: 1.0,
            gps_sigma_v_m: 1.5,
            gps_tau_s: 60.0,
            hidden: Vec::new(),
            decoys: Vec::new(),
            hidden_std_nt: 2.0,
            hidden_at_fluxgate: 0.0,
            max_duration_s: None,
            physics: Physics::Classic,
            base_station: true,
            anomaly_pp_nt: None,
        }
    }
}

fn finite_in(v: f64, lo: f64, hi: f64, what: &str) -> Result<()> {
    ensure!(
        v.is_finite() && v >= lo && v <= hi,
        "{what} = {v} is outside [{lo}, {hi}]"
    );
    Ok(())
}

impl SimConfig {
    pub fn validate(&self) -> Result<()> {
        finite_in(self.sample_rate_hz, 1.0, 1000.0, "sample rate (Hz)")?;
        finite_in(self.speed_mps, 20.0, 150.0, "speed (m/s)")?;
        finite_in(self.start_lat_deg, -80.0, 80.0, "start latitude (deg)")?;
        finite_in(self.start_lon_deg, -180.0, 360.0, "start longitude (deg)")?;
        finite_in(self.ground_elev_m, -500.0, 5000.0, "ground elevation (m)")?;
        finite_in(
            self.cal_altitude_m,
            30.0,
            10_000.0,
            "calibration altitude (m)",
        )?;
        finite_in(
            self.survey_altitude_m,
            30.0,
            10_000.0,
            "survey altitude (m)",
        )?;
        finite_in(self.altitude_swing_m, 0.0, 500.0, "altitude swing (m)")?;
        let min_alt = match self.flight {
            FlightKind::Calibration => self.cal_altitude_m,
            FlightKind::Survey | FlightKind::Takeoff => self.survey_altitude_m,
            FlightKind::CalibrationSurvey => self.cal_altitude_m.min(self.survey_altitude_m),
        };
        ensure!(
            self.altitude_swing_m < min_alt - 20.0,
            "altitude swing must keep the aircraft at least 20 m above ground"
        );
        ensure!(
            self.flight != FlightKind::Takeoff || self.altitude_swing_m == 0.0,
            "a take-off flies no altitude swing (terrain drape)"
        );
        for h in &self.hidden {
            if let HiddenKind::Engine { .. } = h.kind {
                ensure!(
                    self.flight == FlightKind::Takeoff,
                    "the `engine` effect starts with the engine: it belongs to the takeoff flight"
                );
                ensure!(
                    h.window_s.is_none(),
                    "`engine` takes no time window: it starts with the engine"
                );
            }
        }
        ensure!(
            !self.cal_headings_deg.is_empty(),
            "need at least one calibration heading"
        );
        for h in &self.cal_headings_deg {
            finite_in(*h, -360.0, 720.0, "calibration heading (deg)")?;
        }
        finite_in(self.roll_amp_deg, 0.0, 30.0, "roll amplitude (deg)")?;
        finite_in(self.pitch_amp_deg, 0.0, 15.0, "pitch amplitude (deg)")?;
        finite_in(self.yaw_amp_deg, 0.0, 15.0, "yaw amplitude (deg)")?;
        finite_in(self.manoeuvre_period_s, 1.0, 60.0, "manoeuvre period (s)")?;
        ensure!(
            (1..=50).contains(&self.manoeuvre_cycles),
            "manoeuvre cycles must be 1–50"
        );
        finite_in(self.level_s, 0.0, 600.0, "level segment duration (s)")?;
        finite_in(self.turn_rate_deg_s, 0.5, 10.0, "turn rate (deg/s)")?;
        ensure!(
            (1..=500).contains(&self.survey_lines),
            "survey lines must be 1–500"
        );
        finite_in(self.line_length_m, 100.0, 500_000.0, "line length (m)")?;
        finite_in(self.line_spacing_m, 10.0, 50_000.0, "line spacing (m)")?;
        finite_in(self.line_heading_deg, -360.0, 720.0, "line heading (deg)")?;
        ensure!(self.tie_lines <= 500, "tie lines must be 0–500");
        finite_in(self.tie_spacing_m, 10.0, 50_000.0, "tie line spacing (m)")?;
        for v in self.survey_offset_m {
            finite_in(v, -1e6, 1e6, "survey offset (m)")?;
        }
        finite_in(self.wind_mps, 0.0, 0.4 * self.speed_mps, "wind (m/s)")?;
        finite_in(self.turbulence_deg, 0.0, 5.0, "turbulence (deg)")?;
        if let EarthField::Fixed {
            f_nt,
            inc_deg,
            dec_deg,
        } = self.earth
        {
            finite_in(f_nt, 20_000.0, 70_000.0, "field intensity F (nT)")?;
            finite_in(inc_deg, -90.0, 90.0, "inclination (deg)")?;
            finite_in(dec_deg, -180.0, 360.0, "declination (deg)")?;
        }
        self.geology.validate()?;
        finite_in(self.diurnal_nt, 0.0, 100.0, "diurnal rms (nT)")?;
        finite_in(self.interference_scale, 0.0, 100.0, "interference scale")?;
        finite_in(self.scalar_noise_nt, 0.0, 10.0, "scalar noise (nT)")?;
        finite_in(self.flux_noise_nt, 0.0, 100.0, "fluxgate noise (nT)")?;
        finite_in(self.ins_noise_deg, 0.0, 5.0, "INS noise (deg)")?;
        finite_in(self.gps_sigma_h_m, 0.0, 100.0, "GPS horizontal error (m)")?;
        finite_in(self.gps_sigma_v_m, 0.0, 100.0, "GPS vertical error (m)")?;
        finite_in(self.gps_tau_s, 1.0, 10_000.0, "GPS correlation time (s)")?;
        finite_in(self.hidden_std_nt, 0.0, 1000.0, "hidden effect std (nT)")?;
        finite_in(
            self.hidden_at_fluxgate,
            0.0,
            100.0,
            "hidden effect at the fluxgate (×)",
        )?;
        if let Some(d) = self.max_duration_s {
            finite_in(d, 1.0, 1e6, "maximum duration (s)")?;
        }
        if let Some(a) = self.anomaly_pp_nt {
            finite_in(a, 0.01, 10_000.0, "anomaly peak to peak (nT)")?;
        }
        let mut names: Vec<String> = self.hidden.iter().map(|h| h.name()).collect();
        let mut chans: Vec<&str> = self.hidden.iter().filter_map(|h| h.channel()).collect();
        for d in &self.decoys {
            hidden::check_channel(d)?;
            chans.push(d);
        }
        names.sort();
        let n0 = names.len();
        names.dedup();
        ensure!(names.len() == n0, "the same hidden effect is given twice");
        chans.sort();
        let c0 = chans.len();
        chans.dedup();
        ensure!(chans.len() == c0, "an auxiliary channel name is used twice");
        Ok(())
    }
}
