//! `Acquisition` with several magnetometers: a multi-channel counter line per sample runs
//! one compensator per channel and yields one `$MCMREC` record per line; single-field
//! lines keep the single-sensor records byte for byte.

use magcomp_core::acquisition::{compensator_config, AcqConfig, AcqRecord, Acquisition};
use magcomp_core::model::Model;
use magcomp_core::protocol::capture::Port;
use magcomp_core::protocol::multi_record::MAX_MULTI_RECORD_LEN;
use magcomp_core::{Compensator, Flags, MagCounts};

const RATE_HZ: f64 = 10.0;

type Acq = Acquisition<'static, 32, 16>;

fn acq() -> Acq {
    let comp = Compensator::new(Model::paper(), compensator_config(RATE_HZ as f32, 16)).unwrap();
    Acquisition::new(AcqConfig::new(RATE_HZ, RATE_HZ, 1.0), comp).unwrap()
}

fn flux_line(k: usize) -> Vec<u8> {
    let a = k as f64 * 0.05;
    format!(
        "{:.3},{:.3},{:.3}\r\n",
        20_000.0 + 3000.0 * a.sin(),
        1000.0 * a.cos(),
        45_000.0 - 1000.0 * a.sin()
    )
    .into_bytes()
}

fn mag(k: usize, ch: usize) -> i64 {
    536_200_000 + (k as i64 * 37) % 5000 + 12_345 * ch as i64
}

/// `n` samples: a fluxgate line, then the scalar line `line(k)`.
fn run(a: &mut Acq, n: usize, line: impl Fn(usize) -> String) -> Vec<AcqRecord> {
    let mut out = Vec::new();
    for k in 0..n {
        for &b in &flux_line(k) {
            assert!(a.push_byte_any(Port::Flux, b).is_none());
        }
        for b in line(k).bytes() {
            out.extend(a.push_byte_any(Port::Scalar, b));
        }
    }
    while let Some(r) = a.flush_any() {
        out.push(r);
    }
    out
}

fn nt(c: i64) -> String {
    format!("{}.{:04}", c / 10_000, c % 10_000)
}

#[test]
fn single_field_lines_keep_the_single_sensor_records() {
    let line = |k| format!("{}\r\n", nt(mag(k, 0)));
    let mut a = acq();
    let any = run(&mut a, 120, line);
    let mut b = acq();
    let mut one = Vec::new();
    for k in 0..120 {
        b.push_bytes(Port::Flux, &flux_line(k), |r| one.push(r));
        b.push_bytes(Port::Scalar, line(k).as_bytes(), |r| one.push(r));
    }
    while let Some(r) = b.flush() {
        one.push(r);
    }
    assert_eq!(any.len(), 120);
    // the lines the board sends, byte for byte (a NaN bound never equals itself)
    let text = |r: &AcqRecord| {
        let mut buf = [0u8; MAX_MULTI_RECORD_LEN];
        let n = r.encode(&mut buf).unwrap();
        buf[..n].to_vec()
    };
    assert!(any.iter().all(|r| matches!(r, AcqRecord::One(_))));
    let one: Vec<_> = one.into_iter().map(|r| text(&AcqRecord::One(r))).collect();
    assert_eq!(any.iter().map(text).collect::<Vec<_>>(), one);
    assert_eq!(a.channels(), 1);
}

#[test]
fn three_channels_one_record_per_line_each_channel_its_own_filter() {
    let line = |k: usize| {
        // channel 1 dead for samples 40–59, channel 2 unreadable at 70
        let c1 = if (40..60).contains(&k) {
            String::new()
        } else {
            nt(mag(k, 1))
        };
        let c2 = if k == 70 {
            "5362X.0".into()
        } else {
            nt(mag(k, 2))
        };
        format!("M,{},{c1},{c2}\r\n", nt(mag(k, 0)))
    };
    let mut a = acq();
    let recs = run(&mut a, 120, line);
    assert_eq!(recs.len(), 120, "one record per line");
    assert_eq!(a.channels(), 3);
    let c = a.counters();
    assert_eq!((c.scalar_lines, c.records, c.scalar_errors), (120, 120, 1));
    for (k, r) in recs.iter().enumerate() {
        let AcqRecord::Multi(r) = r else {
            panic!("record {k} is a single-sensor one")
        };
        assert_eq!((r.seq as usize, r.channels), (k, 3));
        assert!(
            (r.t_s - k as f64 / RATE_HZ).abs() < 1e-9,
            "{k}: one time base"
        );
        let dead = (40..60).contains(&k);
        assert_eq!(r.ch[0].mag, Some(MagCounts(mag(k, 0))));
        assert_eq!(r.ch[1].mag, (!dead).then_some(MagCounts(mag(k, 1))), "{k}");
        assert_eq!(r.ch[1].flags.contains(Flags::MAG_MISSING), dead, "{k}");
        assert!(
            !r.ch[1].flags.contains(Flags::PARSE_ERROR),
            "{k}: a dead channel is missing"
        );
        assert_eq!(r.ch[2].flags.contains(Flags::PARSE_ERROR), k == 70, "{k}");
        assert!(
            !r.ch[0]
                .flags
                .contains(Flags::MAG_MISSING | Flags::PARSE_ERROR),
            "{k}"
        );
        // the differences are exact, from counts
        let d =
            |i: usize, j: usize| Some(MagCounts(r.ch[j].compensated?.0 - r.ch[i].compensated?.0));
        assert_eq!(r.diff, [d(0, 1), d(0, 2), d(1, 2)], "{k}");
        assert_eq!(r.diff[0].is_none(), dead, "{k}");
    }
    // the three channels' filters are independent: the same readings, 1.2345 nT apart,
    // give interference estimates that differ (their constant is each sensor's own)
    let AcqRecord::Multi(last) = recs[119] else {
        panic!()
    };
    assert_eq!(
        last.ch[1].mag.unwrap().0 - last.ch[0].mag.unwrap().0,
        12_345
    );
    let mut buf = [0u8; MAX_MULTI_RECORD_LEN];
    for r in &recs {
        let n = r.encode(&mut buf).unwrap();
        assert!(buf[..n].starts_with(b"$MCMREC,"));
    }
}

#[test]
fn a_sensor_coefficients_are_its_own() {
    let mut a = acq();
    let mut c = [0.0f32; 16];
    c[0] = 25.0;
    a.sensor_mut(2).unwrap().set_coefficients(&c).unwrap();
    assert!(a.sensor_mut(3).is_none());
    let line = |k| {
        format!(
            "M,{},{},{}\r\n",
            nt(mag(k, 0)),
            nt(mag(k, 0)),
            nt(mag(k, 0))
        )
    };
    let recs = run(&mut a, 60, line);
    let AcqRecord::Multi(r) = recs[59] else {
        panic!()
    };
    assert!(r.ch[2].flags.contains(Flags::SURVEY_MODE));
    assert!(!r.ch[0].flags.contains(Flags::SURVEY_MODE));
    assert!(!r.ch[1].flags.contains(Flags::SURVEY_MODE));
    // the same reading on channels 0 and 1 (same filter, same inputs): the same output
    let key = |c: &magcomp_core::protocol::multi_record::ChannelRecord| {
        (
            c.interference_nt.to_bits(),
            c.compensated,
            c.flags,
            c.sigma_nt.to_bits(),
        )
    };
    assert_eq!(key(&r.ch[0]), key(&r.ch[1]));
    let mut held = [0.0f32; 16];
    a.sensor(2).unwrap().coefficients(&mut held);
    assert_eq!(held[0], 25.0);
    a.sensor(0).unwrap().coefficients(&mut held);
    assert_ne!(held[0], 25.0);
}

#[test]
fn a_counter_appearing_mid_stream_adds_channels_flagged_until_their_filters_catch_up() {
    let mut a = acq();
    let line = |k: usize| match k {
        0..30 => format!("{}\r\n", nt(mag(k, 0))),
        _ => format!("M,{},{}\r\n", nt(mag(k, 0)), nt(mag(k, 1))),
    };
    let recs = run(&mut a, 60, line);
    assert_eq!(recs.len(), 60);
    let first_multi = recs
        .iter()
        .position(|r| matches!(r, AcqRecord::Multi(_)))
        .unwrap();
    // the records held when the first counter line came are multi records: channel 1 missing
    assert!(first_multi < 30, "{first_multi}");
    for (k, r) in recs.iter().enumerate() {
        assert_eq!(r.seq() as usize, k);
        if let AcqRecord::Multi(m) = r {
            assert_eq!(m.ch[1].mag.is_none(), k < 30, "{k}");
        }
    }
}
