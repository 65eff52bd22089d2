//! The worked example of docs/adding-an-effect.md, end to end: the scalar sensor's reading
//! depends on its own temperature, `ΔB = κ·(T − T0)`, and the sensor head's thermostat
//! makes the temperature (recorded as `temp_mag`) cycle by ±1 °C every ~40 s. Nothing in
//! the catalogue has that form: the nearest, `current:temp_mag`, is a field *vector*
//! proportional to the channel (`T·e_i`), and the field states cannot follow a ~40 s
//! sawtooth at 3000 m. The new `sensor_temp` term (written here exactly as it is to be
//! pasted into core/src/model/terms.rs) is diagnosed as the missing effect, added, and the
//! compensation error against truth falls ≥ 5× or to ≤ 0.1 nT.
//!
//! The flight is the simulator's, with the effect added here (no simulator change): the
//! effect's contribution is added to `mag` and `truth_interference`, and the driver is
//! written as a `temp_mag` column.
//! Run in release: `cargo test --release -p magcomp --test diagnose_new_effect`.

use magcomp::diagnose::custom::post_flight_with_terms;
use magcomp::diagnose::{diagnose, diagnose_with, DiagnoseOptions, ExtraTerm};
use magcomp::estimate::corrections::run_kf;
use magcomp::estimate::kf::KfOptions;
use magcomp::flight::Flight;
use magcomp::io::trace::Trace;
use magcomp::model::spec::ModelSpec;
use magcomp::qc::truth::error_rms_nt;
use magcomp::sim::{simulate, SimConfig};
use magcomp_core::epoch::Epoch;
use magcomp_core::model::{Eddy, Induced, Permanent, Term};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

// ---- the example term: paste into core/src/model/terms.rs -------------------------------
/// Temperature coefficient of the scalar sensor: its reading shifts by `κ·(T − T0)` with
/// the sensor head's temperature `T` (a temperature channel, relative to its first value).
/// A sensor error, not a field: it does not depend on the field direction (1, nT/°C).
#[derive(Clone, Copy, Debug)]
pub struct SensorTemp {
    pub channel: usize,
}

impl Term for SensorTemp {
    fn name(&self) -> &'static str {
        "sensor_temp"
    }
    fn len(&self) -> usize {
        1
    }
    fn regressors(&self, ep: &Epoch, out: &mut [f32]) -> bool {
        // In terms.rs: `match aux_value(ep, self.channel) { … }`.
        match ep.aux.get(self.channel).copied().filter(|v| v.is_finite()) {
            Some(t) => {
                out[0] = t;
                true
            }
            None => {
                out[0] = 0.0; // missing input: zero regressor, the epoch is flagged
                false
            }
        }
    }
    fn prior_sigma(&self, _: usize) -> f32 {
        2.0 // nT/°C: prior 1σ, also the coefficient's scale inside the filter
    }
    fn label(&self, _: usize) -> &'static str {
        "T"
    }
    fn unit(&self, _: usize) -> &'static str {
        "nT/degC"
    }
    fn channel(&self) -> Option<usize> {
        Some(self.channel)
    }
}
// -------------------------------------------------------------------------------------------

const SENSOR_TEMP: ExtraTerm = ExtraTerm {
    name: "sensor_temp",
    effect: "temperature coefficient of the scalar sensor: κ·(T − T0) of a temperature channel, independent of the field direction",
    needs_channel: true,
    make: |ch| Box::new(SensorTemp { channel: ch }),
};

/// A thermostat-controlled sensor head: heater on below `set − 0.5 °C`, off above
/// `set + 0.5 °C`; first-order thermal response (τ = 60 s, a small head) toward the heater
/// temperature or the slowly drifting air in the pod. Gives a ±0.5 °C sawtooth with a
/// period of ~8–10 s. Returns the recorded temperature (°C, noise 0.01 °C) and its truth.
fn thermostat(t: &[f64], rng: &mut ChaCha8Rng) -> (Vec<f64>, Vec<f64>) {
    let set = rng.gen_range(30.0..40.0);
    let hot = set + rng.gen_range(8.0..12.0);
    let air0 = rng.gen_range(0.0..15.0);
    let air_amp = rng.gen_range(2.0..5.0);
    let air_period = rng.gen_range(1200.0..3000.0);
    let tau = 60.0;
    let hyst = 0.5;
    let mut temp = set + rng.gen_range(-1.0..1.0);
    let mut on = rng.gen_bool(0.5);
    let mut truth = Vec::with_capacity(t.len());
    let mut rec = Vec::with_capacity(t.len());
    let mut prev_t = t[0];
    for &tk in t {
        // Integrate with 10 ms sub-steps (exact enough for a 300 s time constant).
        let steps = (((tk - prev_t) / 0.01).ceil() as usize).max(1);
        let h = (tk - prev_t) / steps as f64;
        for j in 0..steps {
            let ts = prev_t + j as f64 * h;
            if temp < set - hyst {
                on = true;
            } else if temp > set + hyst {
                on = false;
            }
            let air = air0 + air_amp * (std::f64::consts::TAU * ts / air_period).sin();
            let target = if on { hot } else { air };
            temp += h * (target - temp) / tau;
        }
        prev_t = tk;
        truth.push(temp);
        let noise: f64 = rng.sample(rand_distr::StandardNormal);
        rec.push(temp + 0.01 * noise);
    }
    (rec, truth)
}

/// The simulator's calibration flight plus the hidden sensor-temperature effect.
/// Returns the trace and κ (nT/°C).
fn flight_with_sensor_temp(seed: u64, site: (f64, f64)) -> (Trace, f64) {
    let cfg = SimConfig {
        seed,
        decoys: vec!["cur_fan".into()],
        start_lat_deg: site.0,
        start_lon_deg: site.1,
        ..SimConfig::default()
    };
    let mut trace = simulate(&cfg).expect("simulate");
    let mut rng = ChaCha8Rng::seed_from_u64(1000 + seed);
    let t = trace.col("t").expect("t").to_vec();
    let (recorded, true_temp) = thermostat(&t, &mut rng);
    let sign = if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
    let kappa = sign * rng.gen_range(0.5..1.0);
    let t0 = true_temp[0];
    let effect: Vec<f64> = true_temp.iter().map(|v| kappa * (v - t0)).collect();
    for col in ["mag", "truth_interference"] {
        let v: Vec<f64> = trace
            .col(col)
            .expect("column")
            .iter()
            .zip(&effect)
            .map(|(a, b)| a + b)
            .collect();
        trace.set_col(col, v);
    }
    trace.set_col("truth_hidden_sensor_temp", effect);
    trace.set_col("temp_mag", recorded);
    (trace, kappa)
}

/// Diagnoses, adds and compensates on one flight. Returns (error before, after, with the
/// catalogue's nearest term `current:temp_mag`) in nT.
fn check(seed: u64, site: (f64, f64)) -> (f64, f64, f64) {
    let (trace, kappa) = flight_with_sensor_temp(seed, site);
    let model = ModelSpec::parse("tl16+field").expect("spec");

    // With the new term tested alongside the catalogue, it is named first.
    let d = diagnose_with(&trace, &model, &DiagnoseOptions::default(), &[SENSOR_TEMP])
        .expect("diagnose");
    if seed == 1 {
        // The catalogue alone names its nearest proxy, a current-like vector on temp_mag.
        let d0 = diagnose(&trace, &model, &DiagnoseOptions::default()).expect("diagnose");
        eprintln!("site {site:?}, catalogue only:\n{}", d0.table());
    }
    eprintln!(
        "site {site:?} seed {seed}, with sensor_temp:\n{}",
        d.table()
    );
    assert_eq!(
        d.candidates[0].term,
        "sensor_temp:temp_mag",
        "seed {seed}\n{}",
        d.table()
    );
    assert!(d.candidates[0].significant, "seed {seed}\n{}", d.table());
    // Recalibrating the fluxgate against a scalar that holds the hidden effect moves the
    // compensation without explaining it. Credited by that change against the residual,
    // `fluxcal` was material at 10° N (16.3 % and 55.9 %, seeds 1 and 2); from the model
    // refitted with it (predicted error 0.7669 → 0.7540 and 0.6101 → 0.6145 nT) it is not.
    let fluxcal = d
        .candidates
        .iter()
        .find(|c| c.term == "fluxcal")
        .expect("fluxcal tested");
    assert!(
        !fluxcal.material
            && fluxcal.explained_fraction < DiagnoseOptions::default().min_explained
            && fluxcal.explained_fraction < d.candidates[0].explained_fraction,
        "seed {seed}: fluxcal credited {:.3}\n{}",
        fluxcal.explained_fraction,
        d.table()
    );
    assert!(
        d.candidates
            .iter()
            .all(|c| c.term != "sensor_temp:cur_fan" || !c.significant),
        "seed {seed}: the decoy channel is significant\n{}",
        d.table()
    );

    let chans = ["temp_mag".to_string()];
    let flight = Flight::from_trace(&trace, &chans, &chans).expect("flight");
    let truth = flight.truth_interference_nt.clone().expect("truth");
    let base = run_kf(&flight, &KfOptions::new(model.clone())).expect("kf");
    let before = error_rms_nt(&base.interference_nt, &truth, None);
    // The catalogue's nearest term, for comparison.
    let proxy_spec = model.with("current:temp_mag").expect("spec");
    let proxy_flight = Flight::from_trace(
        &trace,
        &proxy_spec.channels(),
        &proxy_spec.relative_channels(),
    )
    .expect("flight");
    let proxy = run_kf(&proxy_flight, &KfOptions::new(proxy_spec)).expect("kf");
    let with_proxy = error_rms_nt(&proxy.interference_nt, &truth, None);
    // The new term, through the same post-flight passes as `run_kf`.
    let st = SensorTemp { channel: 0 };
    let terms: [&dyn Term; 4] = [&Permanent, &Induced, &Eddy, &st];
    let (interference, coefficients) =
        post_flight_with_terms(&flight, true, &terms, base.sigma1, base.sensor_noise_nt())
            .expect("compensate");
    let after = error_rms_nt(&interference, &truth, None);
    let kappa_hat = coefficients[16];
    eprintln!(
        "site {site:?} seed {seed}: error {before:.4} → {after:.4} nT ({:.0}×; with current:temp_mag {with_proxy:.4} nT, {:.1}×); κ {kappa:.4}, estimated {kappa_hat:.4} nT/°C",
        before / after,
        before / with_proxy,
    );
    assert!(
        after <= 0.1 || before / after >= 5.0,
        "seed {seed}: error {before:.4} → {after:.4} nT"
    );
    assert!(
        (kappa_hat - kappa).abs() < 0.05 * kappa.abs(),
        "seed {seed}: κ {kappa} estimated {kappa_hat}"
    );
    (before, after, with_proxy)
}

/// The simulator's default site (45.3° N, inclination ≈ 70°). Here the field is steep, so
/// the catalogue's proxy comes close (within ~0.005 nT; on some seeds level with it).
#[test]
fn sensor_temp_is_found_added_and_the_error_falls() {
    for seed in [1u64, 2, 3] {
        check(seed, (45.3, -75.7));
    }
}

/// Near the magnetic equator (10° N 10° E, inclination ≈ 21°) the field direction in the
/// airframe swings with heading, so the catalogue's vector proxy `T·e_i` cannot stand in
/// for a scalar offset; the new term still meets the bar. Measured: 0.383 → 0.041 nT
/// (proxy 0.107) and 0.292 → 0.086 nT (proxy 0.167). Seed 2 had regressed to 0.163 nT while
/// the custom filter ran with the base run's adapted noise, which counts the drift itself.
#[test]
fn sensor_temp_at_low_magnetic_latitude() {
    for seed in [1u64, 2] {
        let (before, after, with_proxy) = check(seed, (10.0, 10.0));
        assert!(
            after < 0.6 * with_proxy,
            "seed {seed}: error {before:.4} → {after:.4} nT, with current:temp_mag {with_proxy:.4} nT"
        );
    }
}
