//! IGRF-14 synthesis against a reference implementation: `ppigrf` 2.1.0 evaluated at 14
//! points (equator, poles, both hemispheres, 0–10 km, 1995–2029 including the secular
//! variation extrapolation past 2025); `tests/data/igrf14_reference.py` regenerates them.
//! And at 3,000 points worldwide (`tests/data/igrf14_worldwide.py`).
use magcomp::flight::igrf::{decimal_year, parse_date, Igrf};

#[test]
fn igrf14_matches_ppigrf_within_1nt() {
    let text = include_str!("data/igrf14_reference.csv");
    let mut worst = 0.0f64;
    let mut rows = 0;
    for line in text.lines().filter(|l| !l.starts_with('#')).skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let num = |i: usize| f[i].parse::<f64>().unwrap();
        let (year, doy) = parse_date(f[3]).unwrap();
        let c = Igrf::igrf14()
            .coefficients_at(decimal_year(year, doy, 0.0))
            .unwrap();
        let b = c.field(num(0), num(1), num(2));
        for (got, want, what) in [
            (b.north_nt, num(4), "north"),
            (b.east_nt, num(5), "east"),
            (b.down_nt, num(6), "down"),
            (b.total_nt, num(7), "total"),
        ] {
            let d = (got - want).abs();
            assert!(d < 1.0, "{line}: {what} {got:.3} vs {want:.3} nT");
            worst = worst.max(d);
        }
        rows += 1;
    }
    assert_eq!(rows, 14);
    eprintln!("IGRF-14 vs ppigrf: worst component difference {worst:.4} nT over {rows} points");
}

#[test]
fn igrf14_matches_ppigrf_on_3000_points_worldwide() {
    // `tests/data/igrf14_worldwide.py`: 3,000 points, poles (exactly ±90° among them) and
    // the dateline included, 0–10 km, 1995–2029. ppigrf leaves north/east NaN at +90°.
    let text = include_str!("data/igrf14_worldwide.csv");
    let m = Igrf::igrf14();
    let (mut worst, mut rows) = (0.0f64, 0);
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let num = |i: usize| f[i].parse::<f64>().unwrap();
        let (year, doy) = parse_date(f[3]).unwrap();
        let c = m.coefficients_at(decimal_year(year, doy, 0.0)).unwrap();
        let b = c.field(num(0), num(1), num(2));
        for (got, want) in [
            (b.north_nt, num(4)),
            (b.east_nt, num(5)),
            (b.down_nt, num(6)),
            (b.total_nt, num(7)),
        ] {
            if want.is_finite() {
                assert!((got - want).abs() < 0.5, "{line}: {got:.3} vs {want:.3} nT");
                worst = worst.max((got - want).abs());
            }
        }
        rows += 1;
    }
    assert_eq!(rows, 3000);
    eprintln!("IGRF-14 vs ppigrf worldwide: worst component difference {worst:.4} nT");
}

#[test]
fn geodetic_conversion_matters() {
    // At 45° the geocentric latitude is 0.19° lower: treating the geodetic latitude as
    // geocentric moves the total field by far more than 1 nT, so the test above would
    // catch a missing conversion.
    let c = Igrf::igrf14().coefficients_at(2020.5).unwrap();
    let a = c.field(45.0, -75.0, 0.0).total_nt;
    let b = c.field(45.0 - 0.1924, -75.0, 0.0).total_nt;
    assert!((a - b).abs() > 20.0, "{a} vs {b}");
}

#[test]
fn dates_outside_the_model_are_refused() {
    let m = Igrf::igrf14();
    assert_eq!(m.valid_years(), (1900.0, 2030.0));
    let e = m.coefficients_at(2031.0).unwrap_err().to_string();
    assert!(e.contains("IGRF-14") && e.contains("2030"), "{e}");
}
