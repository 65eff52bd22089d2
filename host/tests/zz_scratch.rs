use magcomp::flight::Flight;
use magcomp::model_spec::ModelSpec;
use magcomp::pipeline::{run_kf, KfOptions};
use magcomp::trace::{read_trace, ColumnMap};

fn err(run: &[f64], truth: &[f64]) -> f64 {
    let d: Vec<f64> = run.iter().zip(truth).map(|(a, b)| a - b).collect();
    let m = d.iter().sum::<f64>() / d.len() as f64;
    (d.iter().map(|v| (v - m).powi(2)).sum::<f64>() / d.len() as f64).sqrt()
}

#[test]
fn scratch() {
    let path = std::env::var("SCRATCH").unwrap();
    let model = std::env::var("MODEL").unwrap_or("tl16+field".into());
    let t = read_trace(std::path::Path::new(&path), &ColumnMap::new()).unwrap();
    let spec = ModelSpec::parse(&model).unwrap();
    let f = Flight::from_trace(&t, &spec.channels(), &spec.relative_channels()).unwrap();
    let truth = f.truth_interference_nt.clone().unwrap();
    let variants: Vec<(&str, Box<dyn Fn(&mut KfOptions)>)> = vec![
        ("default", Box::new(|_| {})),
        ("no ties", Box::new(|o| o.tie_points = false)),
        ("no profiles", Box::new(|o| o.field_profiles = false)),
        ("no ties no profiles", Box::new(|o| { o.tie_points = false; o.field_profiles = false; })),
        ("turn noise x3", Box::new(|o| o.turn_noise_scale = 3.0)),
        ("turn noise x10", Box::new(|o| o.turn_noise_scale = 10.0)),
        ("turn noise x100", Box::new(|o| o.turn_noise_scale = 100.0)),
    ];
    {
        let o = KfOptions::new(spec.clone());
        let run = run_kf(&f, &o).unwrap();
        for (s1, s2) in [(1e-10, 1e-11), (1e-9, 1e-10), (1e-8, 1e-9), (1e-8, 1e-14), (3e-8, 3e-9)] {
            for noise in [run.noise_nt, 0.01, 0.1] {
                let rf = magcomp::reference_kf::run_reference(&f, &spec, s1, s2, noise).unwrap();
                let interf: Vec<f64> = run.regressors.iter().map(|r| r.iter().zip(&rf.coefficients).map(|(a, c)| *a as f64 * c).sum()).collect();
                eprintln!("reference s1 {s1:.0e} s2 {s2:.0e} noise {noise:.3}: err {:.4}", err(&interf, &truth));
            }
        }
    }
    if std::env::var("ONLYREF").is_ok() { return; }
    for (name, f_opt) in variants {
        let mut o = KfOptions::new(spec.clone());
        f_opt(&mut o);
        let run = run_kf(&f, &o).unwrap();
        eprintln!("{name:>22}: err {:.4} pred {:?} sigma1 {:.2e} noise {:.4}", err(&run.interference_nt, &truth), run.predicted_error_nt, run.sigma1, run.noise_nt);
    }
}
