//! Crossover rate fit on a calibration + survey flight with tie lines (experiment driver).
use magcomp::crossover::{fit_rate, levelled_nt, rate_regressors};
use magcomp::flight::Flight;
use magcomp::metrics::error_rms_nt;
use magcomp::model_spec::ModelSpec;
use magcomp::pipeline::{run_kf, KfOptions};
use magcomp::sim::{parse_hidden, simulate, FlightKind, Geology, GeologyPreset, SimConfig};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let seed: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(1);
    let hidden = args.get(2).cloned().unwrap_or_default();
    let model = args.get(3).cloned().unwrap_or("tl16+field".into());
    let envf = |k: &str| std::env::var(k).ok().and_then(|v| v.parse::<f64>().ok());
    let cfg = SimConfig {
        seed,
        flight: FlightKind::CalibrationSurvey,
        cal_altitude_m: 300.0,
        survey_altitude_m: 300.0,
        cal_headings_deg: vec![0.0, 90.0, 180.0, 270.0],
        geology: Geology::preset(GeologyPreset::Strong),
        survey_lines: envf("LINES").unwrap_or(8.0) as usize,
        line_length_m: 5000.0,
        tie_lines: envf("TIES").unwrap_or(5.0) as usize,
        survey_offset_m: [0.0, 5000.0],
        hidden: if hidden.is_empty() || hidden == "-" {
            vec![]
        } else {
            vec![parse_hidden(&hidden)?]
        },
        gps_sigma_h_m: envf("GPSH").unwrap_or(0.3),
        tie_spacing_m: 5000.0 / envf("TIES").unwrap_or(5.0),
        ..Default::default()
    };
    let trace = simulate(&cfg)?;
    let spec = ModelSpec::parse(&model)?;
    let flight = Flight::from_trace(&trace, &spec.channels(), &spec.relative_channels())?;
    let truth = flight.truth_interference_nt.clone().unwrap();
    let mut o = KfOptions::new(spec.clone());
    o.rate_crossovers = false;
    let run = run_kf(&flight, &o)?;
    let before = error_rms_nt(&run.interference_nt, &truth, None);
    let regs = rate_regressors(&flight);
    let lev = levelled_nt(&flight, &run.compensated_nt);
    let Some(fit) = fit_rate(&flight, &lev, &regs) else {
        println!("no fit");
        return Ok(());
    };
    let corr = fit.correction_nt(&regs);
    let after_i: Vec<f64> = run
        .interference_nt
        .iter()
        .zip(&corr)
        .map(|(a, b)| a + b)
        .collect();
    let after = error_rms_nt(&after_i, &truth, None);
    println!(
        "seed {seed} {hidden:?} {model}: crossings {} rms {:.4} -> {:.4}, F {:.1} p {:.2e} q {}",
        fit.crossings,
        fit.rms_before_nt,
        fit.rms_after_nt,
        fit.f_statistic,
        fit.p_value,
        fit.added_parameters
    );
    println!(
        "  coefficients {:?}",
        fit.coefficients.map(|v| (v * 1e4).round() / 1e4)
    );
    println!(
        "  sigmas       {:?}",
        fit.sigmas.map(|v| (v * 1e4).round() / 1e4)
    );
    if let Some(n) = trace.meta("truth_N_s") {
        println!("  truth N {n}");
    }
    println!(
        "  error vs truth: {before:.4} -> {after:.4} nT; correction rms {:.4}",
        magcomp::metrics::rms_demeaned(&corr)
    );
    Ok(())
}
