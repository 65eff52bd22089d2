//! The trace a simulated flight writes: the recorded columns (sensors, navigation, base
//! station, core field), the truth columns, the segment labels and the metadata.

use super::aircraft::Aircraft;
use super::config::{FlightKind, SimConfig};
use super::effects::{Effects, ScalarTrack};
use super::environment::Environment;
use super::geo::{EarthField, LocalFrame};
use super::hidden::HiddenKind;
use super::physics::Physics;
use super::rng_for;
use super::sensors::FluxgateTrack;
use super::takeoff;
use super::trajectory::Clock;
use super::world::{json_mat, json_vec, trace_col, Inst, World};
use crate::io::trace::Trace;
use nalgebra::Vector3;
use rand::Rng;
use rand_distr::StandardNormal;

/// What the instruments recorded, in the trace's column order.
pub(super) struct Recorded {
    pub(super) mag: Vec<f64>,
    pub(super) flux: [Vec<f64>; 3],
    pub(super) gps: [(&'static str, Vec<f64>); 6],
    /// INS attitude errors (deg) of roll, pitch, yaw.
    pub(super) ins_err_deg: Vec<Vec<f64>>,
}

/// The recorded columns: `t`, `mag`, `flux_*`, GPS, attitude, `base`, `igrf` (and
/// `truth_core` under broad physics).
pub(super) fn recorded_columns(
    cfg: &SimConfig,
    clock: &Clock,
    insts: &[Inst],
    rec: Recorded,
) -> Vec<(&'static str, Vec<f64>)> {
    let n = clock.n;
    let [flux_x, flux_y, flux_z] = rec.flux;
    let mut cols: Vec<(&str, Vec<f64>)> = vec![
        ("t", clock.times.clone()),
        ("mag", rec.mag),
        ("flux_x", flux_x),
        ("flux_y", flux_y),
        ("flux_z", flux_z),
    ];
    cols.extend(rec.gps);
    for (ax, name) in ["roll", "pitch", "yaw"].iter().enumerate() {
        let v: Vec<f64> = insts
            .iter()
            .zip(&rec.ins_err_deg[ax])
            .map(|(i, e)| {
                let d = i.att[ax].to_degrees() + e;
                if ax == 2 {
                    d.rem_euclid(360.0)
                } else {
                    d
                }
            })
            .collect();
        cols.push((name, v));
    }
    let mut rb = rng_for(cfg.seed, 10);
    let base: Vec<f64> = insts
        .iter()
        .map(|i| i.d_nt + i.d_micro_nt + 0.01 * rb.sample::<f64, _>(StandardNormal))
        .collect();
    if cfg.base_station {
        cols.push(("base", base));
    }
    let core_exact: Vec<f64> = insts.iter().map(|i| i.be.norm()).collect();
    if cfg.physics == Physics::Broad {
        // As a user computes it: the core-field model at the GPS position, whose slow
        // altitude error (2 m, 60 s) moves it by a few hundredths of a nT; the exact value
        // goes to `truth_core`.
        let (lat, lon, alt) = (
            trace_col(&cols, "lat"),
            trace_col(&cols, "lon"),
            trace_col(&cols, "alt"),
        );
        let igrf = (0..n)
            .map(|k| cfg.earth.field_ned_nt(lat[k], lon[k], alt[k]).norm())
            .collect();
        cols.push(("igrf", igrf));
        cols.push(("truth_core", core_exact));
    } else {
        cols.push(("igrf", core_exact));
    }
    cols
}

/// The truth columns after the recorded and auxiliary ones: interference, anomaly,
/// diurnal, then each hidden effect's contribution.
pub(super) fn set_truth_columns(
    trace: &mut Trace,
    cfg: &SimConfig,
    insts: &[Inst],
    e0: Vector3<f64>,
    effects: &Effects,
    scalar: &mut ScalarTrack,
    flux: &mut FluxgateTrack,
) {
    let truth_anom: Vec<f64> = insts
        .iter()
        .map(|i| (i.be + i.ba).norm() - i.be.norm())
        .collect();
    let truth_diurnal: Vec<f64> = insts
        .iter()
        .map(|i| (i.be + i.ba + e0 * (i.d_nt + i.d_micro_nt)).norm() - (i.be + i.ba).norm())
        .collect();
    let truth_interf: Vec<f64> = scalar
        .mag_clean
        .iter()
        .zip(insts)
        .map(|(m, i)| m - i.b_body.norm())
        .collect();
    trace.set_col("truth_interference", truth_interf);
    trace.set_col("truth_anomaly", truth_anom);
    trace.set_col("truth_diurnal", truth_diurnal);
    for (slot, (hi, _, _)) in effects.vector.iter().enumerate() {
        trace.set_col(
            &cfg.hidden[*hi].column(),
            std::mem::take(&mut scalar.hidden_cols[slot]),
        );
    }
    if let Some((hi, _)) = effects.lag {
        trace.set_col(
            &cfg.hidden[hi].column(),
            std::mem::take(&mut scalar.lag_col),
        );
    }
    if let Some(hi) = effects.fluxcal {
        trace.set_col(
            &cfg.hidden[hi].column(),
            std::mem::take(&mut flux.fluxcal_col),
        );
    }
    if let Some((hi, _)) = &effects.fluxtemp {
        trace.set_col(
            &cfg.hidden[*hi].column(),
            std::mem::take(&mut flux.fluxtemp_col),
        );
    }
    if let Some(h) = cfg.hidden.iter().find(|h| h.kind == HiddenKind::Diurnal) {
        let v: Vec<f64> = insts
            .iter()
            .map(|i| {
                let b0 = i.be + i.ba + e0 * i.d_nt;
                (b0 + e0 * i.d_micro_nt).norm() - b0.norm()
            })
            .collect();
        trace.set_col(&h.column(), v);
    }
}

/// The trace's metadata: how it was simulated, then the truth behind it.
pub(super) fn metadata(
    cfg: &SimConfig,
    clock: &Clock,
    frame: &LocalFrame,
    world: &World,
    env: &Environment,
    aircraft: &Aircraft,
    effects: Effects,
) -> Vec<(String, String)> {
    let mut meta = run_metadata(cfg, clock, world, env, aircraft);
    flight_metadata(cfg, frame, world, &mut meta);
    if !cfg.hidden.is_empty() {
        let specs: Vec<String> = cfg
            .hidden
            .iter()
            .map(|h| match h.window_s {
                Some((a, b)) => format!("{}@{a}:{b}", h.name()),
                None => h.name(),
            })
            .collect();
        meta.push(("hidden".into(), specs.join(" ")));
    }
    if !cfg.decoys.is_empty() {
        meta.push(("decoys".into(), cfg.decoys.join(" ")));
    }
    if let Some((_, lag_s)) = effects.lag {
        meta.push(("truth_lag_s".into(), format!("{lag_s}")));
    }
    meta.extend(takeoff::apron_meta(&env.apron, frame, cfg.ground_elev_m));
    meta.extend(effects.meta);
    meta
}

/// Source, rate, seed, references, earth field model and the aircraft's truth.
fn run_metadata(
    cfg: &SimConfig,
    clock: &Clock,
    world: &World,
    env: &Environment,
    aircraft: &Aircraft,
) -> Vec<(String, String)> {
    let mut meta: Vec<(String, String)> =
        vec![
        ("source".into(), "magcomp simulate".into()),
        ("sample_rate_hz".into(), format!("{}", clock.rate)),
        ("seed".into(), format!("{}", cfg.seed)),
        ("flight".into(), cfg.flight.name().into()),
        ("altitude_m".into(), format!("{}", world.plan.h0_agl_m)),
        ("duration_s".into(), format!("{}", clock.n as f64 * clock.dt)),
        ("speed_mps".into(), format!("{}", cfg.speed_mps)),
        ("ground_elev_m".into(), format!("{}", cfg.ground_elev_m)),
        (
            "alt_reference".into(),
            "height above sea level; flat ground at ground_elev_m".into(),
        ),
        (
            "base_reference".into(),
            "base column = diurnal variation recorded at the base station (nT, reference removed)"
                .into(),
        ),
        ("earth_field_model".into(), earth_field_model(&cfg.earth)),
        (
            "anomaly_sources".into(),
            format!("{}", env.anomaly.sources.len()),
        ),
        ("truth_K_nt".into(), json_vec(&aircraft.k)),
        ("truth_L".into(), json_mat(&aircraft.l)),
        ("truth_M_s".into(), json_mat(&aircraft.m)),
    ];
    if cfg.physics != Physics::Classic {
        meta.push(("physics".into(), cfg.physics.name().into()));
    }
    if !cfg.base_station {
        meta.retain(|(k, _)| k != "base_reference");
    }
    if let Some(a) = cfg.anomaly_pp_nt {
        meta.push(("anomaly_pp_nt".into(), format!("{a}")));
    }
    meta
}

fn earth_field_model(earth: &EarthField) -> String {
    match *earth {
        EarthField::Dipole => {
            "tilted centred dipole, IGRF-2020 degree 1 (g10, g11, h11), spherical Earth".into()
        }
        EarthField::Fixed {
            f_nt,
            inc_deg,
            dec_deg,
        } => {
            format!("uniform F={f_nt} nT I={inc_deg} deg D={dec_deg} deg")
        }
    }
}

/// The flight's geometry: altitudes, survey lines, calibration centre, height swing.
fn flight_metadata(
    cfg: &SimConfig,
    frame: &LocalFrame,
    world: &World,
    meta: &mut Vec<(String, String)>,
) {
    if cfg.flight.has_calibration() {
        meta.push(("cal_altitude_m".into(), format!("{}", cfg.cal_altitude_m)));
    }
    if cfg.flight != FlightKind::Calibration {
        meta.push((
            "survey_altitude_m".into(),
            format!("{}", cfg.survey_altitude_m),
        ));
    }
    if cfg.flight.has_survey() {
        meta.push(("line_spacing_m".into(), format!("{}", cfg.line_spacing_m)));
        if cfg.tie_lines > 0 {
            meta.push(("tie_spacing_m".into(), format!("{}", cfg.tie_spacing_m)));
        }
        meta.push((
            "line_heading_deg".into(),
            format!("{}", cfg.line_heading_deg),
        ));
    }
    if let Some(c) = world.plan.cal_centre_ne_m {
        let (la, lo) = frame.to_geo(c[0], c[1]);
        meta.push(("cal_centre_lat".into(), format!("{la:.9}")));
        meta.push(("cal_centre_lon".into(), format!("{lo:.9}")));
    }
    if cfg.altitude_swing_m > 0.0 {
        meta.push((
            "altitude_swing_m".into(),
            format!("{}", cfg.altitude_swing_m),
        ));
    }
}
