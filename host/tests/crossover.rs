//! Crossings of a simulated survey: lines × tie lines, found where they are, each once.

use magcomp::estimate::crossover::find_crossings;
use magcomp::flight::Flight;
use magcomp::model::spec::ModelSpec;
use magcomp::sim::{simulate, FlightKind, SimConfig};

#[test]
fn every_line_crosses_every_tie_once_where_planned() {
    for rate_hz in [10.0, 400.0] {
        check_survey(rate_hz);
    }
}

fn check_survey(rate_hz: f64) {
    let cfg = SimConfig {
        sample_rate_hz: rate_hz,
        flight: FlightKind::Survey,
        survey_lines: 4,
        line_length_m: 3000.0,
        line_spacing_m: 250.0,
        tie_lines: 3,
        tie_spacing_m: 1000.0,
        survey_altitude_m: 300.0,
        ..SimConfig::default()
    };
    let trace = simulate(&cfg).expect("simulate");
    let spec = ModelSpec::parse("tl16+field").unwrap();
    let f = Flight::from_trace(&trace, &spec.channels(), &spec.relative_channels()).unwrap();
    let seg = trace.text_col("segment").expect("segments");
    let crossings = find_crossings(&f);
    assert_eq!(crossings.len(), 4 * 3, "{rate_hz} Hz: {crossings:?}");
    // Planned grid: lines north (heading 0) at east = 250·k, ties at north = 500 + 1000·j
    // from the survey origin (the start latitude/longitude).
    let lat_of = |c: (usize, f64)| {
        let (a, b) = (&f.samples[c.0], &f.samples[c.0 + 1]);
        (
            a.lat_deg + (b.lat_deg - a.lat_deg) * c.1,
            a.lon_deg + (b.lon_deg - a.lon_deg) * c.1,
        )
    };
    let (lat0, lon0) = (cfg.start_lat_deg, cfg.start_lon_deg);
    let mut pairs = std::collections::HashSet::new();
    for c in &crossings {
        let (la, lb) = (&seg[c.a.0], &seg[c.b.0]);
        assert!(
            la.starts_with("line_") && lb.starts_with("tie_"),
            "crossing of {la} and {lb}"
        );
        assert!(pairs.insert((la.clone(), lb.clone())), "{la} × {lb} twice");
        // The two passes meet: at 10 Hz the interpolated positions agree to centimetres; above,
        // the search runs on 0.1 s chords and the samples carry the position noise.
        let (pa, pb) = (lat_of(c.a), lat_of(c.b));
        let dn = (pa.0 - pb.0).to_radians() * 6_371_000.0;
        let de = (pa.1 - pb.1).to_radians() * 6_371_000.0 * pa.0.to_radians().cos();
        let tolerance_m = if rate_hz <= 10.0 { 0.05 } else { 0.5 };
        assert!(
            dn.hypot(de) < tolerance_m,
            "{rate_hz} Hz, {la} × {lb}: {dn:.3} / {de:.3} m apart"
        );
        // Where planned, to the recorded positions' error (GPS: 1 m).
        let north = (pa.0 - lat0).to_radians() * 6_371_000.0;
        let east = (pa.1 - lon0).to_radians() * 6_371_000.0 * lat0.to_radians().cos();
        let k = (east / 250.0).round();
        let j = ((north - 500.0) / 1000.0).round();
        assert!(
            (east - 250.0 * k).abs() < 5.0 && (north - 500.0 - 1000.0 * j).abs() < 5.0,
            "{la} × {lb} at {north:.1} N {east:.1} E"
        );
        let dc = (c.course_a_rad - c.course_b_rad).rem_euclid(std::f64::consts::PI);
        assert!((dc - std::f64::consts::FRAC_PI_2).abs() < 5f64.to_radians());
    }
}
