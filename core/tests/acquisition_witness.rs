//! `Acquisition` with the fluxgate witness beside the paper model (`attach_witness`): one
//! record per sample whichever filter is shown, the paper filter's records unchanged until
//! the witness is shown, a witnessed set shown with `WITNESS`, and channel 1's compensator
//! given back to a second magnetometer honestly.

use magcomp_core::acquisition::{compensator_config, AcqConfig, Acquisition};
use magcomp_core::model::Model;
use magcomp_core::protocol::capture::Port;
use magcomp_core::protocol::record::Record;
use magcomp_core::{Compensator, Flags};

const RATE_HZ: f64 = 10.0;

type Acq = Acquisition<'static, 32, 16>;

fn acq(witness: bool) -> Acq {
    let comp = Compensator::new(Model::paper(), compensator_config(RATE_HZ as f32, 16)).unwrap();
    let mut a = Acquisition::new(AcqConfig::new(RATE_HZ, RATE_HZ, 1.0), comp).unwrap();
    if witness {
        a.attach_witness(Model::paper_with_fluxgate_witness())
            .unwrap();
    }
    a
}

/// `n` samples from `k0`: a fluxgate line, then a scalar line.
fn run(a: &mut Acq, k0: usize, n: usize) -> Vec<Record> {
    let mut out = Vec::new();
    for k in k0..k0 + n {
        let t = k as f64 * 0.05;
        let flux = format!(
            "{:.3},{:.3},{:.3}\r\n",
            20_000.0 + 3000.0 * t.sin(),
            1000.0 * t.cos(),
            45_000.0 - 1000.0 * t.sin()
        );
        a.push_bytes(Port::Flux, flux.as_bytes(), |r| out.push(r));
        let scalar = format!("{:.4}\r\n", 53_620.0 + (k % 500) as f64 * 0.37);
        a.push_bytes(Port::Scalar, scalar.as_bytes(), |r| out.push(r));
    }
    out
}

fn witnessed_set() -> [f32; 17] {
    let mut c = [0.0f32; 17];
    c[3] = 0.02;
    c[16] = 0.5;
    c
}

#[test]
fn the_witness_beside_changes_no_record_until_it_is_shown() {
    let (mut with, mut without) = (acq(true), acq(false));
    let (a, b) = (run(&mut with, 0, 200), run(&mut without, 0, 200));
    assert_eq!(a.len(), b.len());
    assert!(
        a.len() >= 190,
        "one record per sample, {} held",
        200 - a.len()
    );
    assert!(a.iter().all(|r| !r.flags.contains(Flags::WITNESS)));
    let bytes = |r: &Record| format!("{r:?}");
    assert_eq!(
        a.iter().map(bytes).collect::<Vec<_>>(),
        b.iter().map(bytes).collect::<Vec<_>>()
    );
}

#[test]
fn a_witnessed_set_is_shown_and_read_back_and_a_paper_set_is_not() {
    let mut a = acq(true);
    a.set_coefficients(&witnessed_set()).unwrap();
    let recs = run(&mut a, 0, 60);
    assert!(recs
        .iter()
        .all(|r| r.flags.contains(Flags::WITNESS) && r.flags.contains(Flags::SURVEY_MODE)));
    let mut back = [0.0f32; 17];
    assert_eq!(a.coefficients(&mut back), 17);
    assert_eq!(back, witnessed_set());

    let mut p = acq(true);
    p.set_coefficients(&witnessed_set()[..16]).unwrap();
    let recs = run(&mut p, 0, 60);
    assert!(recs
        .iter()
        .all(|r| !r.flags.contains(Flags::WITNESS) && r.flags.contains(Flags::SURVEY_MODE)));
    assert_eq!(p.coefficients(&mut back), 16);
}

#[test]
fn taking_channel_1_for_a_sensor_stops_the_witness_and_nothing_unlearnt_is_shown_good() {
    let mut a = acq(true);
    a.set_coefficients(&witnessed_set()).unwrap();
    run(&mut a, 0, 40);
    // while the witness runs in it, channel 1 has no filter of its own to read
    assert!(a.sensor(1).is_none());
    // a set for sensor 1: an installation of several magnetometers
    let c1 = [0.01f32; 16];
    a.sensor_mut(1).unwrap().set_coefficients(&c1).unwrap();
    assert!(a.witness().is_none());
    let mut back = [0.0f32; 16];
    a.sensor(1).unwrap().coefficients(&mut back);
    assert_eq!(back, c1);
    // sensor 0's records are the paper filter's, started afresh: not converged, not frozen
    let recs = run(&mut a, 40, 40);
    assert!(recs.iter().all(|r| !r.flags.contains(Flags::WITNESS)
        && r.flags.contains(Flags::NOT_CONVERGED)
        && !r.flags.contains(Flags::SURVEY_MODE)));
}

#[test]
fn counter_lines_stop_the_witness() {
    let mut a = acq(true);
    run(&mut a, 0, 30);
    for b in b"M,53620.0000,53621.0000\r\n" {
        let _ = a.push_byte_any(Port::Scalar, *b);
    }
    assert!(a.witness().is_none());
    assert_eq!(a.channels(), 2);
    assert!(a
        .attach_witness(Model::paper_with_fluxgate_witness())
        .is_err());
}
