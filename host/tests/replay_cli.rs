//! The clap structs the CLI flattens: flags parse to the documented options.

use clap::Parser;
use magcomp::board::capture::FluxFormat;
use magcomp::cli::monitor::MonitorArgs;
use magcomp::cli::replay::ReplayArgs;
use magcomp::cli::simulate::CaptureArgs;

#[derive(Parser)]
struct Sim {
    #[command(flatten)]
    cap: CaptureArgs,
}

#[derive(Parser)]
struct Replay {
    #[command(flatten)]
    a: ReplayArgs,
}

#[derive(Parser)]
struct Monitor {
    #[command(flatten)]
    a: MonitorArgs,
}

#[test]
fn capture_flags() {
    let s = Sim::try_parse_from([
        "x",
        "--capture",
        "f.cap",
        "--capture-flux",
        "spi",
        "--capture-gps-hz",
        "10",
        "--capture-start",
        "08:30:00",
        "--capture-flux-dropout",
        "40:45",
        "--capture-gps-outage",
        "80:90.5",
        "--capture-corrupt",
        "0.01",
        "--capture-seed",
        "9",
    ])
    .unwrap();
    let o = s.cap.to_options().unwrap();
    assert_eq!(o.flux_format, FluxFormat::Spi);
    assert_eq!(o.gps_rate_hz, 10.0);
    assert_eq!(o.start_tod_s, 8.5 * 3600.0);
    assert_eq!(o.flux_dropout_s, Some((40.0, 45.0)));
    assert_eq!(o.gps_outage_s, Some((80.0, 90.5)));
    assert_eq!((o.corrupt_fraction, o.seed), (0.01, 9));
    // Defaults, and bad values rejected with an error (not a panic).
    let d = Sim::try_parse_from(["x"]).unwrap().cap;
    assert!(d.capture.is_none());
    assert_eq!(d.to_options().unwrap().gps_rate_hz, 5.0);
    for bad in [
        vec!["x", "--capture-flux-dropout", "45:40"],
        vec!["x", "--capture-gps-outage", "1:2:3"],
        vec!["x", "--capture-corrupt", "0.9"],
        vec!["x", "--capture-start", "25:00:00"],
        vec!["x", "--capture-gps-hz", "100"],
    ] {
        let r = Sim::try_parse_from(bad.clone()).map(|s| s.cap.to_options());
        assert!(!matches!(r, Ok(Ok(_))), "{bad:?}");
    }
}

#[test]
fn replay_and_monitor_flags() {
    let r = Replay::try_parse_from([
        "x",
        "f.cap",
        "--model",
        "tl16",
        "--rate",
        "20",
        "--gps-rate",
        "1",
        "--flux",
        "spi",
        "-o",
        "r.csv",
        "--records",
        "r.txt",
    ])
    .unwrap()
    .a;
    assert_eq!(r.model, "tl16");
    assert_eq!(
        (r.rate, r.gps_rate, r.flux_rate),
        (Some(20.0), Some(1.0), None)
    );
    assert_eq!(r.flux, Some(FluxFormat::Spi));
    assert!(r.output.is_some() && r.records.is_some() && r.coeffs.is_none());
    assert_eq!(
        Replay::try_parse_from(["x", "f.cap"]).unwrap().a.model,
        "tl16+field"
    );
    let m = Monitor::try_parse_from(["x", "-", "--save", "t.csv", "--interval-s", "5"])
        .unwrap()
        .a;
    assert_eq!(m.input, "-");
    assert_eq!(m.interval_s, 5.0);
    assert!(!m.quiet);
}
