//! The take-off flight (`--flight takeoff`): from standstill on the apron to the survey
//! altitude, with the apron's steel in the Earth-side field, the engine start in
//! `truth_hidden_engine` only after it happens, and every scalar an exact modulus.

use magcomp::sim::*;
use nalgebra::Vector3;

fn flight(seed: u64) -> (SimConfig, SimOutput) {
    let cfg = SimConfig::takeoff(seed);
    let out = simulate_detailed(&cfg).unwrap();
    (cfg, out)
}

fn col<'a>(out: &'a SimOutput, name: &str) -> &'a [f64] {
    out.trace
        .col(name)
        .unwrap_or_else(|| panic!("no column {name}"))
}

fn segments(out: &SimOutput) -> Vec<String> {
    out.trace
        .text_col("segment")
        .expect("segment column")
        .to_vec()
}

/// Consecutive runs of one label: (label, first row, last row).
fn runs(seg: &[String]) -> Vec<(String, usize, usize)> {
    let mut r: Vec<(String, usize, usize)> = Vec::new();
    for (i, s) in seg.iter().enumerate() {
        match r.last_mut() {
            Some(last) if last.0 == *s => last.2 = i,
            _ => r.push((s.clone(), i, i)),
        }
    }
    r
}

fn std_dev(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
}

/// Total-field anomaly of `a` at `p` over the exact main field there.
fn tmi(cfg: &SimConfig, out: &SimOutput, a: &Anomaly, p: &Vector3<f64>) -> f64 {
    let (lat, lon) = out.truth.frame.to_geo(p.x, p.y);
    let be = cfg.earth.field_ned_nt(lat, lon, -p.z);
    (be + a.field_ned_nt(p)).norm() - be.norm()
}

#[test]
fn rows_times_segments_and_no_nan() {
    let (cfg, out) = flight(1);
    let tr = &out.trace;
    let t = col(&out, "t");
    let n = (out.truth.plan.duration_s() * cfg.sample_rate_hz).floor() as usize;
    assert_eq!(tr.len(), n, "one row per sample");
    for (k, w) in t.windows(2).enumerate() {
        assert!(w[1] > w[0], "time not increasing at row {k}");
        assert!((w[1] - w[0] - 0.1).abs() < 1e-9);
    }
    for (name, v) in &tr.numeric {
        assert!(
            v.iter().all(|x| x.is_finite()),
            "non-finite value in {name}"
        );
    }
    for name in [
        "truth_interference",
        "truth_anomaly",
        "truth_diurnal",
        "truth_hidden_engine",
    ] {
        assert_eq!(col(&out, name).len(), n);
    }
    let seg = segments(&out);
    let r = runs(&seg);
    println!("segment timeline, seed 1:");
    for (s, a, b) in &r {
        println!(
            "  {s:13} {:6.1}–{:6.1} s ({:5.1} s)",
            t[*a],
            t[*b] + 0.1,
            t[*b] + 0.1 - t[*a]
        );
    }
    let order: Vec<&str> = r.iter().map(|x| x.0.as_str()).collect();
    assert_eq!(
        order[..4],
        ["ground", "engine_start", "taxi", "takeoff"],
        "{order:?}"
    );
    assert_eq!(
        order[order.len() - 4..],
        ["level_off", "line_1001", "turn", "line_1002"],
        "{order:?}"
    );
    let mid = &order[4..order.len() - 4];
    assert!(mid.first() == Some(&"climb") && mid.last() == Some(&"climb"));
    let turns = mid.iter().filter(|s| **s == "climb_turn").count();
    assert!((1..=2).contains(&turns), "{order:?}");
    let dur = |s: &str| {
        r.iter()
            .filter(|x| x.0 == s)
            .map(|x| t[x.2] + 0.1 - t[x.1])
            .sum::<f64>()
    };
    assert!((dur("ground") - 60.0).abs() < 0.05 && (dur("engine_start") - 30.0).abs() < 0.05);
    assert!(
        (60.0..=120.0).contains(&dur("taxi")),
        "taxi {}",
        dur("taxi")
    );
    // No calibration manoeuvre anywhere.
    assert!(seg.iter().all(|s| !s.starts_with("cal_")));
}

#[test]
fn from_standstill_on_the_apron_to_the_survey_altitude() {
    let (cfg, out) = flight(1);
    let (plan, truth) = (&out.truth.plan, &out.truth);
    let t = col(&out, "t");
    let seg = segments(&out);
    let (vn, ve) = (col(&out, "vn"), col(&out, "ve"));
    let yaw = col(&out, "yaw");
    let h = |i: usize| -truth.pos_ned_m[i].z - cfg.ground_elev_m;
    // Standing: speed exactly 0, the track does not move, the GPS says ~0 m/s, the INS is
    // level-ish on the parked heading.
    let parked: Vec<usize> = (0..t.len())
        .filter(|&i| seg[i] == "ground" || seg[i] == "engine_start")
        .collect();
    assert_eq!(parked.len(), 900);
    let course0 = plan.course(0.0).0.to_degrees();
    for &i in &parked {
        assert_eq!(plan.speed(t[i]), 0.0);
        assert_eq!(truth.pos_ned_m[i], truth.pos_ned_m[0]);
        assert!(
            vn[i].hypot(ve[i]) < 0.2,
            "GPS speed {} at rest",
            vn[i].hypot(ve[i])
        );
        let [r, p, _] = truth.att_rad[i];
        assert!(r.abs() < 1f64.to_radians() && p.abs() < 1.5f64.to_radians());
        let dy = (yaw[i] - course0 + 540.0).rem_euclid(360.0) - 180.0;
        assert!(
            dy.abs() < 0.3,
            "INS yaw {} vs parked heading {course0}",
            yaw[i]
        );
    }
    assert_eq!(h(0), 2.0, "sensor 2 m above the ground at the start");
    // Taxi 5–10 m/s on the ground, no bank in its turns.
    let taxi: Vec<usize> = (0..t.len()).filter(|&i| seg[i] == "taxi").collect();
    let v_taxi = taxi.iter().map(|&i| plan.speed(t[i])).fold(0.0, f64::max);
    assert!((5.0..=10.0).contains(&v_taxi), "taxi speed {v_taxi}");
    assert!(taxi.iter().all(|&i| h(i) == 2.0));
    let taxi_roll = taxi
        .iter()
        .map(|&i| truth.att_rad[i][0].to_degrees().abs())
        .fold(0.0, f64::max);
    assert!(taxi_roll < 1.0, "roll {taxi_roll}° on the ground");
    // Take-off: from 0 to flying speed; the nose comes up to 8–10°.
    let first = |s: &str| seg.iter().position(|x| x == s).unwrap();
    let i_to = first("takeoff");
    assert!(
        plan.speed(t[i_to]) < 0.01,
        "the roll starts from standstill"
    );
    let v_max = (0..t.len()).map(|i| plan.speed(t[i])).fold(0.0, f64::max);
    let gps_max = (0..t.len()).map(|i| vn[i].hypot(ve[i])).fold(0.0, f64::max);
    assert!((v_max - cfg.speed_mps).abs() < 1e-9 && (gps_max - cfg.speed_mps).abs() < 0.2);
    let climbing: Vec<usize> = (i_to..first("line_1001"))
        .filter(|&i| seg[i] != "level_off")
        .collect();
    let pitch_max = climbing
        .iter()
        .map(|&i| truth.att_rad[i][1].to_degrees())
        .fold(f64::MIN, f64::max);
    let climb_max = climbing
        .iter()
        .map(|&i| plan.state(t[i]).climb_mps)
        .fold(f64::MIN, f64::max);
    let bank_max = (0..t.len())
        .filter(|&i| seg[i] == "climb_turn")
        .map(|i| truth.att_rad[i][0].to_degrees().abs())
        .fold(0.0, f64::max);
    let lift_off = climbing.iter().find(|&&i| h(i) > 2.0).unwrap();
    println!(
        "parked heading {course0:.1}°, taxi {v_taxi:.2} m/s, lift-off at {:.1} s at {:.1} m/s, pitch up to {pitch_max:.1}°, climb {climb_max:.2} m/s, climbing-turn bank {bank_max:.1}°",
        t[*lift_off],
        plan.speed(t[*lift_off])
    );
    assert!((7.0..=11.0).contains(&pitch_max), "pitch {pitch_max}");
    assert!((3.0..=5.0).contains(&climb_max), "climb {climb_max}");
    assert!((14.0..=26.0).contains(&bank_max), "bank {bank_max}");
    // Level at the survey altitude on the lines.
    for i in (first("line_1001")..t.len()).filter(|&i| seg[i].starts_with("line_")) {
        assert!(
            (h(i) - cfg.survey_altitude_m).abs() < 1e-6,
            "h {} at row {i}",
            h(i)
        );
        assert!((plan.speed(t[i]) - cfg.speed_mps).abs() < 1e-6);
    }
}

#[test]
fn apron_steel_near_the_taxi_and_nothing_of_it_at_altitude() {
    let (cfg, out) = flight(1);
    let truth = &out.truth;
    let seg = segments(&out);
    let apron = &truth.apron;
    assert_eq!(apron.sources.len(), 2);
    // They are Earth-side sources: part of the anomaly the scalar sees.
    let n = truth.anomaly.sources.len();
    assert_eq!(truth.anomaly.sources[n - 2..], apron.sources[..]);
    let an = col(&out, "truth_anomaly");
    for (k, s) in apron.sources.iter().enumerate() {
        let one = Anomaly {
            sources: vec![s.clone()],
        };
        let mut peak = (0.0f64, 0usize);
        let mut closest = f64::MAX;
        for (i, p) in truth.pos_ned_m.iter().enumerate() {
            let v = tmi(&cfg, &out, &one, p);
            if v.abs() > peak.0.abs() {
                peak = (v, i);
            }
            closest = closest.min((p - s.pos_ned_m).norm());
        }
        let i = peak.1;
        // Its share of the exact anomaly column where it peaks (the modulus is not linear
        // in the sources: equal to a few per mille).
        let others = Anomaly {
            sources: (truth.anomaly.sources.iter())
                .filter(|x| *x != s)
                .cloned()
                .collect(),
        };
        let with = an[i] - tmi(&cfg, &out, &others, &truth.pos_ned_m[i]);
        // It falls off within tens of metres: wherever the sensor is 100 m or more from it.
        let at_100m = (0..truth.pos_ned_m.len())
            .filter(|&j| (truth.pos_ned_m[j] - s.pos_ned_m).norm() >= 100.0)
            .map(|j| tmi(&cfg, &out, &one, &truth.pos_ned_m[j]).abs())
            .fold(0.0, f64::max);
        let high = (0..truth.pos_ned_m.len())
            .filter(|&j| seg[j].starts_with("line_"))
            .map(|j| tmi(&cfg, &out, &one, &truth.pos_ned_m[j]).abs())
            .fold(0.0, f64::max);
        println!(
            "apron source {k}: |m| {:.0} A·m², {:.1} m above ground, closest {closest:.1} m; peak {:.1} nT at {:.1} s ({}), ≥ 100 m away ≤ {at_100m:.2} nT, at 300 m ≤ {high:.5} nT",
            s.moment_am2.norm(),
            -s.pos_ned_m.z - cfg.ground_elev_m,
            peak.0,
            col(&out, "t")[i],
            seg[i]
        );
        assert!(peak.0.abs() >= 20.0, "source {k} peaks at {} nT", peak.0);
        assert!((with / peak.0 - 1.0).abs() < 0.02, "{with} vs {}", peak.0);
        assert!(closest > 5.0);
        assert!(at_100m < 0.15 * peak.0.abs(), "{at_100m} vs {}", peak.0);
        assert!(high < 1.0, "source {k}: {high} nT at the survey altitude");
    }
}

#[test]
fn geology_is_rougher_on_the_airfield_than_300_m_above_it() {
    let (cfg, out) = flight(1);
    let truth = &out.truth;
    let seg = segments(&out);
    let n = truth.anomaly.sources.len();
    let geology = Anomaly {
        sources: truth.anomaly.sources[..n - 2].to_vec(),
    };
    // Horizontal gradient of the geology's field (nT/m, the two horizontal columns of the
    // gradient tensor) where the aircraft rolls on the airfield, and at the same places
    // 300 m up.
    let grad = |p: &Vector3<f64>| {
        let (_, g) = geology.field_and_gradient(p);
        g.column(0).norm().hypot(g.column(1).norm())
    };
    let low: Vec<Vector3<f64>> = (0..seg.len())
        .filter(|&i| ["ground", "taxi", "takeoff"].contains(&seg[i].as_str()))
        .map(|i| truth.pos_ned_m[i])
        .collect();
    let up: Vec<Vector3<f64>> = low
        .iter()
        .map(|p| Vector3::new(p.x, p.y, -(cfg.ground_elev_m + cfg.survey_altitude_m)))
        .collect();
    let rms = |v: &[Vector3<f64>]| {
        (v.iter().map(|p| grad(p).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
    };
    let tmi_ptp = |v: &[Vector3<f64>]| {
        let a: Vec<f64> = v.iter().map(|p| tmi(&cfg, &out, &geology, p)).collect();
        a.iter().cloned().fold(f64::MIN, f64::max) - a.iter().cloned().fold(f64::MAX, f64::min)
    };
    // What the sensor meets: the anomaly's rate of change on the roll and the climb below
    // 100 m against the lines.
    let an = col(&out, "truth_anomaly");
    let rate_max = |f: &dyn Fn(usize) -> bool| {
        (0..an.len() - 1)
            .filter(|&i| f(i))
            .map(|i| ((an[i + 1] - an[i]) / 0.1).abs())
            .fold(0.0, f64::max)
    };
    let h = |i: usize| -truth.pos_ned_m[i].z - cfg.ground_elev_m;
    let r_low = rate_max(&|i| (seg[i] == "takeoff" || seg[i].starts_with("climb")) && h(i) < 100.0);
    let r_line = rate_max(&|i| seg[i].starts_with("line_"));
    let (g_low, g_up) = (rms(&low), rms(&up));
    println!(
        "geology {:?} over the airfield: horizontal gradient rms {g_low:.3} nT/m at 2 m, {g_up:.3} nT/m 300 m above (×{:.1}); anomaly p-p {:.1} nT vs {:.1} nT; |d anomaly/dt| up to {r_low:.1} nT/s on the roll and climb below 100 m, {r_line:.1} nT/s on the lines",
        cfg.geology.preset,
        g_low / g_up,
        tmi_ptp(&low),
        tmi_ptp(&up)
    );
    assert!(g_low > 3.0 * g_up);
}

#[test]
fn engine_start_shows_only_after_the_engine_starts() {
    let (_, out) = flight(1);
    let tr = &out.trace;
    let t = col(&out, "t");
    let hid = col(&out, "truth_hidden_engine");
    let ti = col(&out, "truth_interference");
    let t_on: f64 = tr.meta("truth_engine_start_s").unwrap().parse().unwrap();
    let eng = out
        .truth
        .engine
        .clone()
        .expect("a take-off starts its engine");
    assert_eq!(t_on, 60.0);
    assert_eq!(eng.t_on_s, t_on);
    let dc = eng.dc_nt.norm();
    assert!((5.0..=20.0).contains(&dc), "DC field {dc} nT");
    let before: Vec<usize> = (0..t.len()).filter(|&i| t[i] <= t_on).collect();
    assert!(before.iter().all(|&i| hid[i] == 0.0));
    let parked_after: Vec<usize> = (0..t.len())
        .filter(|&i| t[i] >= t_on + 1.0 && t[i] < 90.0)
        .collect();
    assert!(parked_after.iter().all(|&i| hid[i].abs() > 2.0));
    let peak = parked_after
        .iter()
        .map(|&i| hid[i].abs())
        .fold(0.0, f64::max);
    let settled = hid[parked_after.last().copied().unwrap()];
    // The interference steps by the same amount while the aircraft stands still.
    let i0 = before.last().copied().unwrap();
    let i1 = parked_after.last().copied().unwrap();
    let step = ti[i1] - ti[i0];
    println!(
        "engine start at {t_on} s: |DC| {dc:.2} nT (body), on the scalar peak {peak:.2} nT, {settled:.2} nT at 90 s; truth_interference step {step:.2} nT; DC current {:.1} A, overshoot {:.2}, τ {:.1} s",
        eng.amps, eng.overshoot, eng.tau_s
    );
    assert!((step - settled).abs() < 0.05, "{step} vs {settled}");
    // With a logged current channel the effect is the same; the channel is 0 before.
    let mut cfg = SimConfig::takeoff(1);
    cfg.hidden = vec![parse_hidden("engine:cur_alt").unwrap()];
    let with = simulate_detailed(&cfg).unwrap();
    assert_eq!(with.trace.col("truth_hidden_engine").unwrap(), hid);
    let cur = with.trace.col("cur_alt").unwrap();
    assert!(before.iter().all(|&i| cur[i] == 0.0));
    assert!((cur[i1] / eng.amps - 1.0).abs() < 0.05);
    // A plain `SimConfig { flight: Takeoff, .. }` has it too.
    let plain = SimConfig {
        flight: FlightKind::Takeoff,
        ..SimConfig::default()
    };
    let o = simulate_detailed(&plain).unwrap();
    let h = o.trace.col("truth_hidden_engine").unwrap();
    assert!(h[..600].iter().all(|x| *x == 0.0) && h[700].abs() > 1.0);
}

#[test]
fn scalar_is_the_exact_modulus_of_earth_and_aircraft_fields() {
    let (cfg, out) = flight(1);
    let (tr, truth) = (&out.trace, &out.truth);
    let t = col(&out, "t");
    let (mag, igrf) = (col(&out, "mag"), col(&out, "igrf"));
    let (an, di, ti) = (
        col(&out, "truth_anomaly"),
        col(&out, "truth_diurnal"),
        col(&out, "truth_interference"),
    );
    let eng = truth.engine.clone().unwrap();
    let mut worst: f64 = 0.0;
    for i in 0..tr.len() {
        let p = truth.pos_ned_m[i];
        let (lat, lon) = truth.frame.to_geo(p.x, p.y);
        let be = cfg.earth.field_ned_nt(lat, lon, -p.z);
        // Earth side: exact main field and exact dipole sum (geology + apron).
        let exact_an = (be + truth.anomaly.field_ned_nt(&p)).norm() - be.norm();
        worst = worst.max((exact_an - an[i]).abs());
        worst = worst.max((be.norm() - igrf[i]).abs());
        // |B| in the body frame = main + anomaly + diurnal.
        let b = truth.b_body_nt[i];
        worst = worst.max((b.norm() - (igrf[i] + an[i] + di[i])).abs());
        // Aircraft: Tolles–Lawson field (K + L·B + M·dB/dt) plus the engine's.
        let db = truth.db_body_nt_s[i];
        let tl = truth.k_nt + truth.l * b + truth.m_s * db;
        assert!((tl - truth.delta_b_nt[i]).norm() < 1e-9);
        let want = (b + tl + eng.field(t[i])).norm() - b.norm();
        worst = worst.max((want - ti[i]).abs());
        worst = worst.max((truth.mag_clean_nt[i] - (b + tl + eng.field(t[i])).norm()).abs());
    }
    assert!(worst < 1e-6, "worst {worst} nT");
    let resid: Vec<f64> = (0..tr.len())
        .map(|i| mag[i] - igrf[i] - an[i] - di[i] - ti[i])
        .collect();
    let sd = std_dev(&resid);
    assert!((0.008..0.012).contains(&sd), "scalar noise sd {sd}");
    // Without diurnal the body field is main + anomaly (geology and apron) at the true
    // position turned by the true attitude, and the noise-free scalar its modulus with the
    // aircraft's field added, on the apron as in the air.
    let cfg0 = SimConfig {
        diurnal_nt: 0.0,
        ..cfg.clone()
    };
    let o = simulate_detailed(&cfg0).unwrap();
    let eng0 = o.truth.engine.clone().unwrap();
    let mut worst0: f64 = 0.0;
    for (i, &p) in o.truth.pos_ned_m.iter().enumerate() {
        let (lat, lon) = o.truth.frame.to_geo(p.x, p.y);
        let b_ned = cfg0.earth.field_ned_nt(lat, lon, -p.z) + o.truth.anomaly.field_ned_nt(&p);
        let [r, pi, y] = o.truth.att_rad[i];
        let b = dcm_ned_to_body(r, pi, y) * b_ned;
        worst0 = worst0.max((b - o.truth.b_body_nt[i]).norm());
        let aircraft = o.truth.delta_b_nt[i] + eng0.field(t[i]);
        worst0 = worst0.max(((b + aircraft).norm() - o.truth.mag_clean_nt[i]).abs());
    }
    println!(
        "exact modulus: worst {worst:.2e} nT over {} rows; mag residual sd {sd:.4} nT (scalar noise 0.01); body field and |B_e + aircraft| rebuilt without diurnal: worst {worst0:.2e} nT",
        tr.len()
    );
    assert!(worst0 < 1e-6, "worst {worst0} nT");
}

#[test]
fn anomaly_and_its_rate_exact_at_1_khz_through_the_taxi() {
    // At 1 kHz the environment field is Hermite-interpolated between knots: the apron's
    // steel a few metres away must still come out exact.
    let cfg = SimConfig {
        sample_rate_hz: 1000.0,
        max_duration_s: Some(230.0),
        ..SimConfig::takeoff(2)
    };
    let out = simulate_detailed(&cfg).unwrap();
    let an = col(&out, "truth_anomaly");
    let mut worst: f64 = 0.0;
    for i in (0..an.len()).step_by(13) {
        let p = out.truth.pos_ned_m[i];
        worst = worst.max((tmi(&cfg, &out, &out.truth.anomaly, &p) - an[i]).abs());
    }
    // The take-off's kinematics (speed steps, rotation, ground turns) are smooth: the
    // exact dB/dt matches the finite difference of the body field.
    let (b, db) = (&out.truth.b_body_nt, &out.truth.db_body_nt_s);
    let mut worst_rate: f64 = 0.0;
    for i in 1..b.len() - 1 {
        let fd = (b[i + 1] - b[i - 1]) / 2e-3;
        worst_rate = worst_rate.max((fd - db[i]).norm() / (db[i].norm() + 1.0));
    }
    println!("1 kHz: worst interpolated anomaly error {worst:.2e} nT, worst relative dB/dt error {worst_rate:.1e}");
    assert!(worst < 1e-4, "worst {worst} nT");
    assert!(worst_rate < 1e-3, "worst relative dB/dt error {worst_rate}");
}
