//! The environment field along the path: the geology drawn under the flight, the main
//! field and the anomaly at the knots (scaled to `anomaly_pp_nt` when asked), and the
//! take-off apron's steel.

use super::anomaly::Anomaly;
use super::config::SimConfig;
use super::flight::Plan;
use super::geo::LocalFrame;
use super::rng_for;
use super::takeoff;
use super::trajectory::Clock;
use super::world::FieldTrack;
use nalgebra::Vector3;

/// The Earth side of a flight (its field along the path is the [`FieldTrack`] returned with
/// it).
pub(super) struct Environment {
    /// Every Earth-side source: the geology, then the apron's.
    pub(super) anomaly: Anomaly,
    /// The apron's steel (take-off; empty otherwise).
    pub(super) apron: Anomaly,
    /// Direction of the main field at the start: induced magnetisation and diurnal.
    pub(super) e0: Vector3<f64>,
}

/// The geology under the flight and the field along its path: main field + anomaly
/// (geology and apron) at the knots.
pub(super) fn environment(
    cfg: &SimConfig,
    frame: &LocalFrame,
    plan: &Plan,
    clock: &Clock,
    pos_ned: &[Vector3<f64>],
) -> (Environment, FieldTrack) {
    let be0 = cfg
        .earth
        .field_ned_nt(cfg.start_lat_deg, cfg.start_lon_deg, cfg.ground_elev_m);
    let e0 = be0.normalize();
    let mut anomaly = geology_under(cfg, pos_ned, e0);
    let knots = Knots::of(cfg, clock);
    let mut field = field_at_knots(cfg, frame, plan, clock, pos_ned, &knots, &anomaly);
    scale_to_peak_to_peak(cfg, &mut field, &mut anomaly);
    let apron = takeoff::add_apron(&mut field, &mut anomaly, plan, &knots.idx, pos_ned, e0, cfg);
    (Environment { anomaly, apron, e0 }, field)
}

/// Geology under the flight, with a margin that reaches the sources that matter.
fn geology_under(cfg: &SimConfig, pos_ned: &[Vector3<f64>], e0: Vector3<f64>) -> Anomaly {
    let (mut n0, mut n1, mut e0m, mut e1m) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    let mut hmax: f64 = 0.0;
    for p in pos_ned {
        n0 = n0.min(p.x);
        n1 = n1.max(p.x);
        e0m = e0m.min(p.y);
        e1m = e1m.max(p.y);
        hmax = hmax.max(-p.z - cfg.ground_elev_m);
    }
    let margin = (2.0 * (hmax + cfg.geology.depth_max_m)).clamp(2000.0, 15_000.0);
    Anomaly::generate(
        &cfg.geology,
        ([n0 - margin, n1 + margin], [e0m - margin, e1m + margin]),
        cfg.ground_elev_m,
        e0,
        &mut rng_for(cfg.seed, 2),
    )
}

/// The samples where the field is evaluated exactly: every `every`-th, and the last one.
struct Knots {
    every: usize,
    idx: Vec<usize>,
}

impl Knots {
    fn of(cfg: &SimConfig, clock: &Clock) -> Self {
        let q = (clock.rate / takeoff::knot_rate_hz(cfg)).ceil().max(1.0) as usize;
        let mut knots: Vec<usize> = (0..clock.n).step_by(q).collect();
        if *knots.last().unwrap_or(&0) != clock.n - 1 {
            knots.push(clock.n - 1);
        }
        Knots {
            every: q,
            idx: knots,
        }
    }
}

/// Main field and anomaly, with their exact time derivatives, at the knots.
fn field_at_knots(
    cfg: &SimConfig,
    frame: &LocalFrame,
    plan: &Plan,
    clock: &Clock,
    pos_ned: &[Vector3<f64>],
    knots: &Knots,
    anomaly: &Anomaly,
) -> FieldTrack {
    let knots_every = knots.every;
    let knots = &knots.idx;
    let mut field = FieldTrack {
        t: Vec::with_capacity(knots.len()),
        be: Vec::with_capacity(knots.len()),
        dbe: Vec::with_capacity(knots.len()),
        ba: Vec::with_capacity(knots.len()),
        dba: Vec::with_capacity(knots.len()),
        dt_knot: knots_every as f64 * clock.dt,
    };
    let earth_at = |p: &Vector3<f64>| {
        let (lat, lon) = frame.to_geo(p.x, p.y);
        cfg.earth.field_ned_nt(lat, lon, -p.z)
    };
    for &k in knots {
        let t = clock.times[k];
        let p = pos_ned[k];
        let v = plan.velocity(t);
        let v_ned = Vector3::new(v[0], v[1], -v[2]);
        // The main field changes over thousands of km: a ±0.5 s difference is exact.
        let dbe = (earth_at(&(p + v_ned * 0.5)) - earth_at(&(p - v_ned * 0.5))) / 1.0;
        let (ba, ga) = anomaly.field_and_gradient(&p);
        field.t.push(t);
        field.be.push(earth_at(&p));
        field.dbe.push(dbe);
        field.ba.push(ba);
        field.dba.push(ga * v_ned);
    }
    field
}

/// Scales the geology so its anomaly spans `anomaly_pp_nt` peak to peak at the knots. The
/// field is linear in the moments, so scaling them scales the track exactly.
fn scale_to_peak_to_peak(cfg: &SimConfig, field: &mut FieldTrack, anomaly: &mut Anomaly) {
    let Some(target) = cfg.anomaly_pp_nt else {
        return;
    };
    let tmi = |k: usize| (field.be[k] + field.ba[k]).norm() - field.be[k].norm();
    let (lo, hi) = (0..field.t.len()).fold((f64::MAX, f64::MIN), |(a, b), k| {
        let v = tmi(k);
        (a.min(v), b.max(v))
    });
    if hi > lo {
        let f = target / (hi - lo);
        field.ba.iter_mut().for_each(|v| *v *= f);
        field.dba.iter_mut().for_each(|v| *v *= f);
        anomaly.sources.iter_mut().for_each(|s| s.moment_am2 *= f);
    }
}
