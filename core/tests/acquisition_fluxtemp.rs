//! The fluxgate's temperature drift on the board (`fluxtemp`, `SETFTEMP`): the ASCII line's
//! optional 4th field, `B = B_F + (T − T_ref)·(b + s∘B_F)` before `fluxcal`, a set
//! correction without a temperature flagged `FLUX_STALE`, never passed uncorrected.

#[path = "common/acq_run.rs"]
mod acq_run;
use acq_run::run;

use magcomp_core::acquisition::{compensator_config, AcqConfig, Acquisition};
use magcomp_core::model::Model;
use magcomp_core::protocol::capture::Port;
use magcomp_core::protocol::command::{encode_command, parse_command, Command, FLUX_TEMP_LEN};
use magcomp_core::protocol::fluxgate::{
    parse_ascii_frame, parse_ascii_line, FluxAsciiReader, FluxCalibration, FluxError, FluxTempCal,
};
use magcomp_core::{Compensator, Flags};

const RATE_HZ: f64 = 10.0;

type Acq<'a> = Acquisition<'a, 32, 16>;

fn acq<'a>() -> Acq<'a> {
    let comp = Compensator::new(Model::paper(), compensator_config(RATE_HZ as f32, 16)).unwrap();
    let mut a = Acquisition::new(AcqConfig::new(RATE_HZ, RATE_HZ, 1.0), comp).unwrap();
    a.set_coefficients(&core::array::from_fn::<f32, 16, _>(|i| {
        (i as f32 - 7.5) * 200.0
    }))
    .unwrap();
    a
}

const CAL: FluxTempCal = FluxTempCal {
    t_ref_degc: 20.0,
    bias_nt_per_degc: [0.8, -0.5, 0.3],
    scale_per_degc: [2e-5, -1e-5, 3e-5],
};

/// Field of a manoeuvring aircraft (body frame, nT) and a sensor warming 10 → 30 °C.
fn frame_at(k: usize) -> ([f64; 3], f64) {
    (field_at(k as f64), 10.0 + 20.0 * k as f64 / 200.0)
}

/// The field of [`frame_at`] at frame `k` (before the first frame too).
fn field_at(k: f64) -> [f64; 3] {
    let a = k * 0.3;
    [
        20_000.0 + 3000.0 * a.sin(),
        1000.0 * (0.7 * a).cos(),
        45_000.0 - 1000.0 * a.sin(),
    ]
}

/// `n` epochs of fluxgate then scalar. `line(k)` writes the fluxgate's line.
fn stream(n: usize, line: impl Fn(usize) -> String) -> Vec<(Port, Vec<u8>)> {
    let mut chunks = Vec::new();
    for k in 0..n {
        chunks.push((Port::Flux, format!("{}\r\n", line(k)).into_bytes()));
        let m = 536_200_000 + (k as i64 * 37) % 5000;
        chunks.push((
            Port::Scalar,
            format!("{}.{:04}\r\n", m / 10_000, m % 10_000).into_bytes(),
        ));
    }
    chunks
}

/// The host's formula in f64 (host/src/preprocess/fluxtemp.rs).
fn corrected(b: [f64; 3], t: f64) -> [f64; 3] {
    let d = t - CAL.t_ref_degc as f64;
    std::array::from_fn(|i| {
        b[i] + d * (CAL.bias_nt_per_degc[i] as f64 + CAL.scale_per_degc[i] as f64 * b[i])
    })
}

#[test]
fn ascii_line_with_and_without_temperature() {
    let (v, t) = parse_ascii_frame(b"100.5,-200.25,300,23.75").unwrap();
    assert_eq!((v, t), ([100.5, -200.25, 300.0], 23.75));
    let (v, t) = parse_ascii_frame(b"100.5,-200.25,300\r\n").unwrap();
    assert_eq!(v, [100.5, -200.25, 300.0]);
    assert!(t.is_nan());
    assert_eq!(parse_ascii_line(b"1,2,3,-4.5").unwrap(), [1.0, 2.0, 3.0]);
    assert_eq!(parse_ascii_frame(b"1,2,3,4,5"), Err(FluxError::BadLength));
    assert_eq!(parse_ascii_frame(b"1,2"), Err(FluxError::BadLength));
    assert_eq!(parse_ascii_frame(b"1,2,3,250"), Err(FluxError::OutOfRange));
    assert_eq!(parse_ascii_frame(b"1,2,3,x"), Err(FluxError::BadNumber));
    // The checksum covers the temperature too.
    let body = b"1,2,3,21.5";
    let cs = body.iter().fold(0u8, |a, b| a ^ b);
    let good = format!("1,2,3,21.5*{cs:02X}");
    assert_eq!(parse_ascii_frame(good.as_bytes()).unwrap().1, 21.5);
    let bad = format!("1,2,3,21.6*{cs:02X}");
    assert_eq!(parse_ascii_frame(bad.as_bytes()), Err(FluxError::Checksum));
    let mut rd = FluxAsciiReader::new();
    let got: Vec<_> = b"1,2,3,4\n5,6,7\n"
        .iter()
        .filter_map(|&b| rd.push_frame(b))
        .collect();
    assert_eq!(got.len(), 2);
    assert_eq!(got[0], Ok(([1.0, 2.0, 3.0], 4.0)));
    assert!(got[1].unwrap().1.is_nan());
}

#[test]
fn correction_is_the_host_formula_and_refuses_the_absurd() {
    for k in [0, 37, 199] {
        let (b, t) = frame_at(k);
        let got = CAL.apply(b.map(|v| v as f32), t as f32);
        let want = corrected(b, t);
        for i in 0..3 {
            // f32 on a ~50 000 nT vector: a few ulp (4 mnT each).
            assert!(
                (got[i] as f64 - want[i]).abs() < 0.02,
                "{k}/{i}: {got:?} {want:?}"
            );
        }
    }
    // Missing temperature with a correction set: NaN (→ FLUX_STALE), without one: unchanged.
    assert!(CAL.apply([1.0, 2.0, 3.0], f32::NAN)[0].is_nan());
    assert_eq!(
        FluxTempCal::NONE.apply([1.0, 2.0, 3.0], f32::NAN),
        [1.0, 2.0, 3.0]
    );
    assert_eq!(FluxTempCal::from_array(&CAL.to_array()), Some(CAL));
    let refuse = |i: usize, v: f32| {
        let mut a = CAL.to_array();
        a[i] = v;
        assert_eq!(FluxTempCal::from_array(&a), None, "index {i} = {v}");
    };
    refuse(0, f32::NAN);
    refuse(0, 500.0);
    refuse(2, 1500.0);
    refuse(6, 0.02);
    refuse(4, f32::INFINITY);
}

/// Lines with T and the correction set give, record for record, the interference of the
/// host-corrected vectors sent without T and no correction (to f32 rounding of the line).
#[test]
fn board_correction_equals_a_corrected_fluxgate() {
    let n = 200;
    let mut a = acq();
    a.set_flux_temp_calibration(CAL);
    let with_t = run(
        &mut a,
        &stream(n, |k| {
            let (b, t) = frame_at(k);
            format!("{:.3},{:.3},{:.3},{:.4}", b[0], b[1], b[2], t)
        }),
    );
    let mut b = acq();
    let pre = run(
        &mut b,
        &stream(n, |k| {
            let (v, t) = frame_at(k);
            let c = corrected(v, t);
            format!("{:.3},{:.3},{:.3}", c[0], c[1], c[2])
        }),
    );
    let mut c = acq();
    let plain = run(
        &mut c,
        &stream(n, |k| {
            let (b, _) = frame_at(k);
            format!("{:.3},{:.3},{:.3}", b[0], b[1], b[2])
        }),
    );
    assert_eq!((with_t.len(), pre.len(), plain.len()), (n, n, n));
    let (mut worst, mut worst_plain) = (0f32, 0f32);
    for k in 2..n {
        assert!(!with_t[k].flags.contains(Flags::FLUX_STALE), "record {k}");
        worst = worst.max((with_t[k].interference_nt - pre[k].interference_nt).abs());
        worst_plain = worst_plain.max((plain[k].interference_nt - pre[k].interference_nt).abs());
    }
    eprintln!("board vs host-corrected {worst} nT, uncorrected {worst_plain} nT");
    assert!(worst < 2e-3, "board vs host-corrected: {worst} nT");
    assert!(
        worst_plain > 0.05,
        "uncorrected differs by {worst_plain} nT only"
    );
}

/// With a correction set, 3-field lines (no temperature) make FLUX_STALE records, one per
/// scalar line; clearing the correction makes them usable again. Before `fluxcal`: the
/// temperature term sees the raw vector.
#[test]
fn missing_temperature_is_flagged_never_uncorrected() {
    let n = 60;
    let line = |k: usize| {
        let (b, t) = frame_at(k);
        if (20..30).contains(&k) {
            format!("{:.3},{:.3},{:.3}", b[0], b[1], b[2])
        } else {
            format!("{:.3},{:.3},{:.3},{:.4}", b[0], b[1], b[2], t)
        }
    };
    let mut a = acq();
    a.set_flux_temp_calibration(CAL);
    let recs = run(&mut a, &stream(n, line));
    assert_eq!(recs.len(), n);
    let stale: Vec<usize> = (0..n)
        .filter(|&k| recs[k].flags.contains(Flags::FLUX_STALE))
        .collect();
    assert_eq!(stale, (20..30).collect::<Vec<_>>());
    assert!(recs.iter().all(|r| r.interference_nt.is_finite()));
    assert_eq!(a.counters().flux_errors, 0);
    let mut b = acq();
    let recs = run(&mut b, &stream(n, line));
    assert!(recs.iter().all(|r| !r.flags.contains(Flags::FLUX_STALE)));

    // Order: fluxtemp on the raw vector, then fluxcal (host: preprocess, then calibrate).
    let cal = FluxCalibration {
        matrix: [[1.01, 0.002, 0.0], [0.0, 0.99, 0.001], [0.003, 0.0, 1.02]],
        bias_nt: [50.0, -30.0, 10.0],
    };
    let mut c = acq();
    c.set_flux_temp_calibration(CAL);
    c.set_flux_calibration(cal);
    let both = run(
        &mut c,
        &stream(n, |k| {
            let (b, t) = frame_at(k);
            format!("{:.3},{:.3},{:.3},{:.4}", b[0], b[1], b[2], t)
        }),
    );
    let mut d = acq();
    let host = run(
        &mut d,
        &stream(n, |k| {
            let (b, t) = frame_at(k);
            let v = cal.apply(corrected(b, t).map(|x| x as f32));
            format!("{:.3},{:.3},{:.3}", v[0], v[1], v[2])
        }),
    );
    for k in 2..n {
        let e = (both[k].interference_nt - host[k].interference_nt).abs();
        assert!(e < 2e-3, "record {k}: {e} nT");
    }
}

#[test]
fn ftemp_commands_round_trip() {
    let p = |s: &str| {
        let cs = s.bytes().fold(0u8, |a, b| a ^ b);
        parse_command(format!("${s}*{cs:02X}").as_bytes(), 16)
    };
    assert_eq!(p("MCCMD,GETFTEMP"), Ok(Command::GetFluxTemp(None)));
    assert_eq!(p("MCCMD,GETFTEMP,6"), Ok(Command::GetFluxTemp(Some(6))));
    assert_eq!(
        p("MCCMD,SETFTEMP,1,4.0E-1"),
        Ok(Command::SetFluxTemp {
            index: 1,
            value: 0.4
        })
    );
    assert!(p(&format!("MCCMD,SETFTEMP,{FLUX_TEMP_LEN},1")).is_err());
    assert!(p("MCCMD,SETFTEMP,1,nan").is_err());
    assert!(p("MCCMD,SETFTEMP,1").is_err());
    for cmd in [
        Command::GetFluxTemp(None),
        Command::GetFluxTemp(Some(3)),
        Command::SetFluxTemp {
            index: 0,
            value: 21.25,
        },
        Command::SetFluxTemp {
            index: 5,
            value: -1.5e-5,
        },
    ] {
        let mut out = [0u8; 96];
        let n = encode_command(&cmd, &mut out).unwrap();
        assert_eq!(parse_command(&out[..n], 16), Ok(cmd));
    }
}

/// Through the delay line (`SETLAG`) the corrected vectors are delayed with their frames:
/// τ = 2 periods shifts the FLUX_STALE records of the frames without T by 2 and gives the
/// interference of a corrected fluxgate sent 2 periods late.
#[test]
fn correction_goes_through_the_delay_line() {
    use magcomp_core::protocol::lag_line::LagLine;
    let n = 80;
    let line = |delay: usize, with_t: bool| {
        move |k: usize| {
            let Some(k) = k.checked_sub(delay) else {
                // The same field earlier, at the reference temperature: continuous with
                // the frames after it (a jump would be a suspect frame on the board).
                let b = field_at(k as f64 - delay as f64);
                return format!("{:.3},{:.3},{:.3},20.0000", b[0], b[1], b[2]);
            };
            let (b, t) = frame_at(k);
            if (20..30).contains(&k) || !with_t {
                let b = if with_t { b } else { corrected(b, t) };
                format!("{:.3},{:.3},{:.3}", b[0], b[1], b[2])
            } else {
                format!("{:.3},{:.3},{:.3},{:.4}", b[0], b[1], b[2], t)
            }
        }
    };
    let mut lag = LagLine::new();
    let mut a = acq();
    a.attach_lag_line(&mut lag);
    a.set_lag_s((2.0 / RATE_HZ) as f32).unwrap();
    a.set_flux_temp_calibration(CAL);
    let recs = run(&mut a, &stream(n, line(0, true)));
    assert_eq!(recs.len(), n);
    let stale: Vec<usize> = (0..n)
        .filter(|&k| recs[k].flags.contains(Flags::FLUX_STALE))
        .collect();
    let want: Vec<usize> = (0..2).chain(22..32).collect();
    assert_eq!(stale, want);
    // Against a host-corrected fluxgate sent 2 periods late, no delay on the board.
    let mut b = acq();
    let late = run(&mut b, &stream(n, line(2, false)));
    let half = compensator_config(RATE_HZ as f32, 16).epoch.half_width;
    for k in (2 + half + 1..n).filter(|k| !(22 - half..32 + half + 1).contains(k)) {
        let e = (recs[k].interference_nt - late[k].interference_nt).abs();
        assert!(e < 2e-3, "record {k}: {e} nT");
    }
}
