//! The flight plan: cloverleaf calibration pattern, survey lines, tie lines and the
//! turns and transits between them; the take-off's is in `takeoff.rs`.

use super::*;

pub(super) fn build_plan(cfg: &SimConfig, rng: &mut ChaCha8Rng) -> Result<Plan> {
    match cfg.flight {
        FlightKind::Takeoff => takeoff::build_plan(cfg, rng),
        _ => pattern_plan(cfg, rng),
    }
}

/// Cloverleaf and/or survey block at constant speed: the legs are flown in order
/// (calibration cloverleaf, survey lines, tie lines), then the plan's random parts drawn
/// (height drape, turbulence, trim, wind).
fn pattern_plan(cfg: &SimConfig, rng: &mut ChaCha8Rng) -> Result<Plan> {
    let pat = Pattern::of(cfg);
    let v = pat.v;
    let per = pat.per;
    let start = pat.start();
    let mut alt_ramps = Vec::new();
    let mut b = Builder::new(start, pat.first_course, v, pat.rate);
    b.straight(pat.lead_m / v, Manoeuvre::Level, 0.0, per, "turn");
    if pat.do_cal {
        fly_cloverleaf(&mut b, cfg, &pat)?;
    }
    if pat.do_survey {
        fly_survey_lines(&mut b, cfg, &pat, &mut alt_ramps)?;
        fly_tie_lines(&mut b, cfg, &pat)?;
        b.straight(10.0, Manoeuvre::Level, 0.0, per, "turn");
    }
    let swing = (cfg.altitude_swing_m > 0.0).then(|| {
        // Keep the drape slope ≤ ~6 % (climb ≤ 4 m/s at 60 m/s), like a real drape.
        let wl = (TAU * cfg.altitude_swing_m / 0.06).max(3000.0) * rng.gen_range(0.9..1.2);
        (cfg.altitude_swing_m, wl, rng.gen_range(0.0..TAU))
    });
    let turb_rad = cfg.turbulence_deg.to_radians();
    let turb = [
        SineSum::random(3, 2.0, 15.0, turb_rad, rng),
        SineSum::random(3, 2.0, 15.0, turb_rad * 0.7, rng),
        SineSum::random(3, 3.0, 20.0, turb_rad * 0.7, rng),
    ];
    Ok(Plan {
        pieces: b.pieces,
        speed_mps: v,
        start_ne_m: start,
        start_course_rad: pat.first_course,
        h0_agl_m: if pat.do_cal {
            cfg.cal_altitude_m
        } else {
            cfg.survey_altitude_m
        },
        alt_ramps,
        swing,
        trim_pitch_rad: rng.gen_range(1.5f64..3.0).to_radians(),
        turb,
        wind: (cfg.wind_mps, rng.gen_range(0.0..TAU)),
        cal_centre_ne_m: pat.do_cal.then_some(pat.centre),
        takeoff: None,
    })
}

/// The geometry of a pattern flight, fixed by the configuration.
struct Pattern {
    /// Ground speed (m/s), maximum turn rate (rad/s).
    v: f64,
    rate: f64,
    /// Manoeuvre period and one manoeuvre's duration (s).
    per: f64,
    man_s: f64,
    /// Straight run-in before a leg or line (m).
    lead_m: f64,
    /// The cloverleaf's centre (local NE, m) and leg courses (rad).
    centre: [f64; 2],
    cal_course: Vec<f64>,
    /// Course of the odd survey lines (rad) and the block's origin (local NE, m).
    line_course: f64,
    survey_origin: [f64; 2],
    do_cal: bool,
    do_survey: bool,
    first_course: f64,
    /// Distance flown on a leg before reaching the centre: roll + half the level part.
    pre_m: f64,
}

impl Pattern {
    fn of(cfg: &SimConfig) -> Self {
        let v = cfg.speed_mps;
        let per = cfg.manoeuvre_period_s;
        let man_s = per * cfg.manoeuvre_cycles as f64;
        let cal_course: Vec<f64> = cfg
            .cal_headings_deg
            .iter()
            .map(|h| h.to_radians().rem_euclid(TAU))
            .collect();
        let line_course = cfg.line_heading_deg.to_radians().rem_euclid(TAU);
        let do_cal = cfg.flight.has_calibration();
        let first_course = if do_cal { cal_course[0] } else { line_course };
        Pattern {
            v,
            rate: cfg.turn_rate_deg_s.to_radians(),
            per,
            man_s,
            lead_m: 600.0,
            centre: [0.0, 0.0],
            cal_course,
            line_course,
            survey_origin: if do_cal {
                cfg.survey_offset_m
            } else {
                [0.0, 0.0]
            },
            do_cal,
            do_survey: cfg.flight.has_survey(),
            first_course,
            pre_m: (man_s + cfg.level_s / 2.0) * v,
        }
    }

    /// Where the flight starts: the run-in to the first leg or line.
    fn start(&self) -> [f64; 2] {
        let (lead_m, c) = (self.lead_m, self.first_course);
        if self.do_cal {
            [
                self.centre[0] - (self.pre_m + lead_m) * c.cos(),
                self.centre[1] - (self.pre_m + lead_m) * c.sin(),
            ]
        } else {
            [
                self.survey_origin[0] - lead_m * c.cos(),
                self.survey_origin[1] - lead_m * c.sin(),
            ]
        }
    }

    /// Unit vectors along the odd lines and across the block, and the across course.
    fn block_axes(&self) -> ([f64; 2], [f64; 2], f64) {
        let perp = self.line_course + TAU / 4.0;
        (
            [self.line_course.cos(), self.line_course.sin()],
            [perp.cos(), perp.sin()],
            perp,
        )
    }
}

/// The calibration cloverleaf: per heading, through the centre, roll, level, pitch and
/// yaw manoeuvres.
fn fly_cloverleaf(b: &mut Builder, cfg: &SimConfig, pat: &Pattern) -> Result<()> {
    let (v, per, man_s, pre_m) = (pat.v, pat.per, pat.man_s, pat.pre_m);
    for (i, &c) in pat.cal_course.iter().enumerate() {
        if i > 0 {
            let d = b.connect(pat.centre, c, pre_m + 300.0)?;
            b.straight((d - pre_m) / v, Manoeuvre::Level, 0.0, per, "turn");
        }
        let tag = heading_tag(c);
        let (r, p, y) = (
            cfg.roll_amp_deg.to_radians(),
            cfg.pitch_amp_deg.to_radians(),
            cfg.yaw_amp_deg.to_radians(),
        );
        b.straight(man_s, Manoeuvre::Roll, r, per, &format!("cal_{tag}_roll"));
        b.straight(
            cfg.level_s,
            Manoeuvre::Level,
            0.0,
            per,
            &format!("cal_{tag}_level"),
        );
        b.straight(man_s, Manoeuvre::Pitch, p, per, &format!("cal_{tag}_pitch"));
        b.straight(man_s, Manoeuvre::Yaw, y, per, &format!("cal_{tag}_yaw"));
    }
    b.straight(10.0, Manoeuvre::Level, 0.0, per, "turn");
    Ok(())
}

/// The survey lines, alternating direction, with the height change from the cloverleaf
/// flown on the way to the first.
fn fly_survey_lines(
    b: &mut Builder,
    cfg: &SimConfig,
    pat: &Pattern,
    alt_ramps: &mut Vec<flight::AltRamp>,
) -> Result<()> {
    let (v, per, rate, lead_m) = (pat.v, pat.per, pat.rate, pat.lead_m);
    let (line_course, survey_origin) = (pat.line_course, pat.survey_origin);
    let (u, w, _) = pat.block_axes();
    for k in 0..cfg.survey_lines {
        let off = k as f64 * cfg.line_spacing_m;
        let along = if k % 2 == 0 { 0.0 } else { cfg.line_length_m };
        let s = [
            survey_origin[0] + off * w[0] + along * u[0],
            survey_origin[1] + off * w[1] + along * u[1],
        ];
        let c = if k % 2 == 0 {
            line_course
        } else {
            (line_course + TAU / 2.0).rem_euclid(TAU)
        };
        if k > 0 || pat.do_cal {
            // Height change cal → survey: a smooth climb/descent peaking at 6 m/s,
            // started over the cloverleaf; when it outlasts the transit the aircraft
            // spirals (full orbits, labelled `turn`) before heading for the block.
            let dh = if k == 0 {
                cfg.survey_altitude_m - cfg.cal_altitude_m
            } else {
                0.0
            };
            let ramp_s = std::f64::consts::FRAC_PI_2 * dh.abs() / 6.0;
            let ramp_end = b.t_s + ramp_s;
            if dh != 0.0 {
                alt_ramps.push(flight::AltRamp {
                    t0_s: b.t_s,
                    dur_s: ramp_s,
                    dh_m: dh,
                });
                let dist = ((s[0] - b.pos[0]).powi(2) + (s[1] - b.pos[1]).powi(2)).sqrt();
                let orbit_s = TAU / rate + 3.0;
                let n_orb = ((ramp_s - dist / v) / orbit_s).floor().max(0.0) as usize;
                for _ in 0..n_orb {
                    b.turn(-TAU);
                }
            }
            let left_s = (ramp_end - b.t_s).max(0.0);
            let d = b.connect(s, c, lead_m + left_s * v)?;
            b.straight(d / v, Manoeuvre::Level, 0.0, per, "turn");
        }
        b.straight(
            cfg.line_length_m / v,
            Manoeuvre::Level,
            0.0,
            per,
            &format!("line_{}", 1001 + k),
        );
    }
    Ok(())
}

/// Tie lines: across the block, 300 m beyond the outer lines, alternating direction.
fn fly_tie_lines(b: &mut Builder, cfg: &SimConfig, pat: &Pattern) -> Result<()> {
    let (v, per, lead_m, survey_origin) = (pat.v, pat.per, pat.lead_m, pat.survey_origin);
    let (u, w, perp) = pat.block_axes();
    let width = (cfg.survey_lines.max(1) - 1) as f64 * cfg.line_spacing_m;
    let tie_len = width + 600.0;
    for k in 0..cfg.tie_lines {
        let along = ((k as f64 + 0.5) * cfg.tie_spacing_m).min(cfg.line_length_m);
        let across = if k % 2 == 0 { -300.0 } else { width + 300.0 };
        let s = [
            survey_origin[0] + along * u[0] + across * w[0],
            survey_origin[1] + along * u[1] + across * w[1],
        ];
        let c = if k % 2 == 0 {
            perp.rem_euclid(TAU)
        } else {
            (perp + TAU / 2.0).rem_euclid(TAU)
        };
        let d = b.connect(s, c, lead_m)?;
        b.straight(d / v, Manoeuvre::Level, 0.0, per, "turn");
        b.straight(
            tie_len / v,
            Manoeuvre::Level,
            0.0,
            per,
            &format!("tie_{}", 2001 + k),
        );
    }
    Ok(())
}
