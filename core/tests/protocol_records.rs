//! Output record, command protocol, coefficient blob and capture format round trips.

use magcomp_core::protocol::capture::{self, Port};
use magcomp_core::protocol::command::*;
use magcomp_core::protocol::record::*;
use magcomp_core::{Flags, MagCounts};

fn rec(mag: i64, interf: f32, anom: f32, innov: f32, t_s: f64, flags: u16) -> Record {
    let m = Some(MagCounts(mag));
    Record {
        seq: 4_000_000_000,
        t_s,
        mag: m,
        interference_nt: interf,
        compensated: Record::compensate(m, interf),
        anomaly_nt: anom,
        innovation_nt: innov,
        sigma_nt: 0.25,
        flags: Flags(flags),
    }
}

fn roundtrip(r: &Record) -> (String, Record) {
    let mut buf = [0u8; MAX_RECORD_LEN];
    let n = encode_record(r, &mut buf).unwrap();
    let line = std::str::from_utf8(&buf[..n]).unwrap().to_string();
    (line.clone(), decode_record(line.as_bytes()).unwrap())
}

#[test]
fn record_format_and_roundtrip() {
    let r = rec(536_204_401, 12.3456, -3.21, 0.0123, 1234.5, 0x0104);
    let (line, back) = roundtrip(&r);
    assert!(
        line.starts_with(
            "$MCREC,4000000000,1234.500000,53620.4401,12.3456,53608.0945,-3.2100,0.0123,0.2500,0104*"
        ),
        "{line}"
    );
    assert!(line.ends_with("\r\n"));
    assert_eq!(back.compensated, Some(MagCounts(536_080_945)));
    assert_eq!(back.mag, r.mag);
    assert_eq!(back.seq, r.seq);
    assert_eq!(back.flags, r.flags);
    // Negative values and sub-count fractions.
    let r = rec(
        100_000_000,
        -0.00004,
        -1234.5679,
        -0.00005,
        0.000001,
        0xFFFF,
    );
    let (line, back) = roundtrip(&r);
    assert!(
        line.contains(",-0.0000,") || line.contains(",0.0000,"),
        "{line}"
    );
    assert_eq!(back.anomaly_nt, -1234.5679);
    assert_eq!(back.t_s, 0.000001);
    assert_eq!(back.compensated, Some(MagCounts(100_000_000)));
}

#[test]
fn record_nan_and_huge() {
    let mut r = rec(
        536_204_401,
        f32::NAN,
        3.0e30,
        f32::NEG_INFINITY,
        f64::NAN,
        0,
    );
    r.mag = None;
    let (line, back) = roundtrip(&r);
    assert!(
        line.starts_with("$MCREC,4000000000,,,,,299999989E22,-INF,0.2500,0000*"),
        "{line}"
    );
    assert!(back.t_s.is_nan() && back.interference_nt.is_nan());
    assert_eq!(back.mag, None);
    assert_eq!(back.compensated, None);
    assert_eq!(back.anomaly_nt, 3.0e30);
    assert_eq!(back.innovation_nt, f32::NEG_INFINITY);
    // Every f32 magnitude round-trips to f32 precision.
    let mut v = 1.0e-3f32;
    while v < 1.0e38 {
        for s in [v, -v] {
            let (_, b) = roundtrip(&rec(536_204_401, 0.0, s, 0.0, 0.0, 0));
            let tol = if s.abs() < 1e11 { 5e-5 } else { s.abs() * 1e-7 };
            assert!((b.anomaly_nt - s).abs() <= tol, "{s} -> {}", b.anomaly_nt);
        }
        v *= 7.3;
    }
}

#[test]
fn record_rejects_corruption() {
    let r = rec(536_204_401, 12.3456, -3.21, 0.0123, 1234.5, 0x0104);
    let mut buf = [0u8; MAX_RECORD_LEN];
    let n = encode_record(&r, &mut buf).unwrap();
    for i in 1..n - 2 {
        let mut b = buf[..n].to_vec();
        b[i] ^= 0x04;
        assert!(decode_record(&b).is_err(), "byte {i}");
    }
    // Swapped adjacent digits (XOR would miss this; CRC-16 does not).
    let mut b = buf[..n].to_vec();
    let p = b.iter().position(|&c| c == b'5').unwrap();
    b.swap(p, p + 1);
    assert!(matches!(decode_record(&b), Err(RecordError::Crc { .. })));
    let mut small = [0u8; 20];
    assert_eq!(encode_record(&r, &mut small), Err(RecordError::BufferFull));
}

fn cmd_line(body: &str) -> String {
    let x = body.bytes().fold(0u8, |a, b| a ^ b);
    format!("${body}*{x:02X}\r\n")
}

#[test]
fn commands() {
    let p = |b: &str| parse_command(cmd_line(b).as_bytes(), 21);
    assert_eq!(p("MCCMD,MODE,SURVEY"), Ok(Command::Mode(Mode::Survey)));
    assert_eq!(p("MCCMD,MODE,CAL"), Ok(Command::Mode(Mode::Cal)));
    assert_eq!(p("MCCMD,STATUS"), Ok(Command::Status));
    assert_eq!(p("MCCMD,GETCOEF"), Ok(Command::GetCoef(None)));
    assert_eq!(p("MCCMD,GETCOEF,20"), Ok(Command::GetCoef(Some(20))));
    assert_eq!(
        p("MCCMD,SETCOEF,3,-1.25E-2"),
        Ok(Command::SetCoef {
            index: 3,
            value: -0.0125
        })
    );
    assert_eq!(
        p("MCCMD,SETCOEF,3,999999.9"),
        Ok(Command::SetCoef {
            index: 3,
            value: 999_999.9
        })
    );
    assert_eq!(p("MCCMD,GETFLUX"), Ok(Command::GetFlux(None)));
    assert_eq!(p("MCCMD,GETFLUX,11"), Ok(Command::GetFlux(Some(11))));
    assert_eq!(
        p("MCCMD,SETFLUX,9,-312.5"),
        Ok(Command::SetFlux {
            index: 9,
            value: -312.5
        })
    );
    // the fluxgate calibration has 12 values whatever the model's coefficient count
    assert_eq!(p("MCCMD,SETFLUX,12,1"), Err(CommandError::IndexOutOfBounds));
    assert_eq!(p("MCCMD,GETFLUX,12"), Err(CommandError::IndexOutOfBounds));
    assert_eq!(p("MCCMD,SETFLUX,0,NaN"), Err(CommandError::BadArgument));
    // The scalar's delay τ (s): one value in [0, 0.51]; GETLAG takes none.
    assert_eq!(p("MCCMD,GETLAG"), Ok(Command::GetLag));
    assert_eq!(p("MCCMD,SETLAG,0.205"), Ok(Command::SetLag(0.205)));
    assert_eq!(p("MCCMD,SETLAG,0"), Ok(Command::SetLag(0.0)));
    assert_eq!(p("MCCMD,SETLAG,0.5"), Ok(Command::SetLag(0.5)));
    assert_eq!(p("MCCMD,SETLAG,0.51"), Ok(Command::SetLag(0.51)));
    assert_eq!(
        p("MCCMD,SETLAG,0.5101"),
        Err(CommandError::ValueOutOfBounds)
    );
    assert_eq!(p("MCCMD,SETLAG,-0.01"), Err(CommandError::ValueOutOfBounds));
    assert_eq!(p("MCCMD,SETLAG"), Err(CommandError::BadArgument));
    assert_eq!(p("MCCMD,SETLAG,0,1"), Err(CommandError::BadArgument));
    assert_eq!(p("MCCMD,SETLAG,x"), Err(CommandError::BadArgument));
    assert_eq!(p("MCCMD,GETLAG,0"), Err(CommandError::BadArgument));
    assert_eq!(p("MCCMD,SAVE"), Ok(Command::Save));
    assert_eq!(p("MCCMD,RESET"), Ok(Command::Reset));
    assert_eq!(p("MCCMD,FLUSH"), Ok(Command::Flush));
    use CommandError::*;
    assert_eq!(p("MCCMD,SETCOEF,21,1.0"), Err(IndexOutOfBounds));
    assert_eq!(p("MCCMD,GETCOEF,99"), Err(IndexOutOfBounds));
    assert_eq!(p("MCCMD,SETCOEF,3,1000000"), Err(ValueOutOfBounds));
    assert_eq!(p("MCCMD,SETCOEF,3,1E40"), Err(ValueOutOfBounds));
    assert_eq!(p("MCCMD,SETCOEF,3,INF"), Err(ValueOutOfBounds));
    assert_eq!(p("MCCMD,SETCOEF,3,"), Err(BadArgument));
    assert_eq!(p("MCCMD,SETCOEF,x,1"), Err(BadArgument));
    assert_eq!(p("MCCMD,MODE,FLY"), Err(BadArgument));
    assert_eq!(p("MCCMD,SAVE,NOW"), Err(BadArgument));
    assert_eq!(p("MCCMD,LAUNCH"), Err(UnknownCommand));
    assert_eq!(p("XXCMD,SAVE"), Err(Framing));
    assert_eq!(parse_command(b"$MCCMD,SAVE*00", 21), Err(BadChecksum));
    assert_eq!(parse_command(b"$MCCMD,SAVE", 21), Err(BadChecksum));
    // Encoder ↔ parser round trip, including the CRC-16 form.
    for c in [
        Command::Mode(Mode::Survey),
        Command::GetCoef(Some(7)),
        Command::SetCoef {
            index: 20,
            value: -1.234_567_8e-5,
        },
        Command::SetCoef {
            index: 0,
            value: 123_456.79,
        },
        Command::Flush,
        Command::GetLag,
        Command::SetLag(0.2),
        Command::SetLag(0.499_99),
        Command::GetFlux(Some(4)),
        Command::SetFlux {
            index: 2,
            value: -1.5e-3,
        },
        Command::GetFluxTemp(None),
        Command::SetFluxTemp {
            index: 6,
            value: 2.5e-5,
        },
    ] {
        let mut b = [0u8; 96];
        let n = encode_command(&c, &mut b).unwrap();
        assert_eq!(
            parse_command(&b[..n], 21),
            Ok(c),
            "{}",
            String::from_utf8_lossy(&b[..n])
        );
    }
    let body = b"MCCMD,STATUS";
    let crc = magcomp_core::protocol::common::crc16_ccitt(body);
    let l = format!("${}*{crc:04X}", std::str::from_utf8(body).unwrap());
    assert_eq!(parse_command(l.as_bytes(), 21), Ok(Command::Status));
    // Reader: garbage then a command.
    let mut r = CommandReader::new(21);
    let input = format!("hello\n{}", cmd_line("MCCMD,SAVE"));
    let out: Vec<_> = input.bytes().filter_map(|b| r.push(b)).collect();
    assert_eq!(out, vec![Err(Framing), Ok(Command::Save)]);
}

#[test]
fn replies() {
    let mut b = [0u8; 96];
    let n = encode_ack_coef(3, -0.0125, &mut b).unwrap();
    let line = std::str::from_utf8(&b[..n]).unwrap();
    // 9 significant digits of the f32 (-0.0125f32 = -0.012500000186...).
    assert!(
        line.starts_with("$MCACK,GETCOEF,3,-125000002E-10*"),
        "{line}"
    );
    let payload = check_reply(&b[..n]).unwrap();
    let v = std::str::from_utf8(&payload[16..])
        .unwrap()
        .parse::<f64>()
        .unwrap() as f32;
    assert_eq!(v, -0.0125f32);
    let n = encode_error(CommandError::IndexOutOfBounds, &mut b).unwrap();
    assert!(std::str::from_utf8(&b[..n])
        .unwrap()
        .starts_with("$MCERR,5,INDEX*"));
    assert!(check_reply(&b[..n]).is_some());
    let n = encode_ack(b"MODE", &[b"SURVEY"], &mut b).unwrap();
    assert!(std::str::from_utf8(&b[..n])
        .unwrap()
        .starts_with("$MCACK,MODE,SURVEY*"));
    b[8] ^= 1;
    assert!(check_reply(&b[..n]).is_none());
}

/// What a sender reads from a reply: ACK payload, the board's verdict, or a transport error
/// (resend), for every error code; records and damaged replies are not replies.
#[test]
fn replies_classified_for_the_sender() {
    let mut b = [0u8; 96];
    let all = [
        CommandError::Framing,
        CommandError::BadChecksum,
        CommandError::UnknownCommand,
        CommandError::BadArgument,
        CommandError::IndexOutOfBounds,
        CommandError::ValueOutOfBounds,
        CommandError::Overlong,
    ];
    for e in all {
        let n = encode_error(e, &mut b).unwrap();
        assert_eq!(parse_reply(&b[..n]), Some(Reply::Refused(e)));
        assert_eq!(CommandError::from_code(e.code()), Some(e));
    }
    let transport: Vec<_> = all.into_iter().filter(|e| e.is_transport()).collect();
    assert_eq!(
        transport,
        [
            CommandError::Framing,
            CommandError::BadChecksum,
            CommandError::Overlong
        ]
    );
    assert_eq!(CommandError::from_code(0), None);
    assert_eq!(CommandError::from_code(8), None);
    let n = encode_ack(b"SETLAG", &[b"0.3"], &mut b).unwrap();
    assert_eq!(parse_reply(&b[..n]), Some(Reply::Ack(&b"SETLAG,0.3"[..])));
    b[9] ^= 1;
    assert_eq!(parse_reply(&b[..n]), None, "CRC fails: not a reply");
    let storage = b"$MCERR,8,STORAGE";
    let line = format!(
        "{}*{:04X}",
        std::str::from_utf8(storage).unwrap(),
        magcomp_core::protocol::common::crc16_ccitt(&storage[1..])
    );
    assert_eq!(
        parse_reply(line.as_bytes()),
        Some(Reply::BoardError(&b"8,STORAGE"[..]))
    );
    let mut b = [0u8; MAX_RECORD_LEN];
    let n = encode_record(&rec(1, 0.5, 0.0, 0.0, 1.0, 0), &mut b).unwrap();
    assert_eq!(parse_reply(&b[..n]), None, "a record is not a reply");
}

#[test]
fn coefficient_blob() {
    let coef: Vec<f32> = (0..21).map(|i| (i as f32 - 10.0) * 0.37e-3).collect();
    let h = model_hash(b"tl16+field");
    let mut buf = [0u8; 256];
    let n = encode_blob(h, &coef, &mut buf).unwrap();
    assert_eq!(n, blob_len(21));
    assert_eq!(&buf[..4], b"MCCF");
    let mut out = [0f32; 21];
    decode_blob(&buf[..n], h, &mut out).unwrap();
    assert_eq!(&out[..], &coef[..]);
    let mut wrong = [0f32; 16];
    assert_eq!(
        decode_blob(&buf[..n], h, &mut wrong),
        Err(BlobError::WrongCount {
            expected: 16,
            found: 21
        })
    );
    assert!(matches!(
        decode_blob(&buf[..n], h ^ 1, &mut out),
        Err(BlobError::ModelMismatch { .. })
    ));
    for i in 0..n {
        let mut c = buf;
        c[i] ^= 0x10;
        let e = decode_blob(&c[..n], h, &mut out).unwrap_err();
        assert!(
            matches!(
                e,
                BlobError::BadCrc | BlobError::BadMagic | BlobError::Truncated
            ),
            "byte {i}: {e:?}"
        );
    }
    // A version bump with a valid CRC is reported as such.
    let mut c = buf;
    c[4] = 2;
    let crc = magcomp_core::protocol::common::crc32(&c[..n - 4]);
    c[n - 4..n].copy_from_slice(&crc.to_le_bytes());
    assert_eq!(
        decode_blob(&c[..n], h, &mut out),
        Err(BlobError::WrongVersion(2))
    );
    assert_eq!(
        decode_blob(&buf[..10], h, &mut out),
        Err(BlobError::Truncated)
    );
    assert_eq!(
        encode_blob(h, &coef, &mut [0u8; 40]),
        Err(BlobError::BufferTooSmall)
    );
}

#[test]
fn capture_roundtrip() {
    let mut b = [0u8; capture::MAX_LINE];
    let n = capture::encode_header(&mut b).unwrap();
    assert_eq!(&b[..n], b"# magcomp-capture v1\n");
    let mut data = [0u8; capture::MAX_CHUNK];
    assert_eq!(capture::decode_line(&b[..n], &mut data), Ok(None));
    let payload = b"53620.4401\r\n";
    let n = capture::encode_line(1_000_250, Port::Scalar, payload, &mut b).unwrap();
    assert_eq!(&b[..n], b"1000250 scalar 35333632302E343430310D0A\n");
    let l = capture::decode_line(&b[..n], &mut data).unwrap().unwrap();
    assert_eq!((l.t_us, l.port), (1_000_250, Port::Scalar));
    assert_eq!(&data[..l.len], payload);
    for p in Port::ALL {
        let n = capture::encode_line(u64::MAX, p, &[0, 255, 36], &mut b).unwrap();
        let l = capture::decode_line(&b[..n], &mut data).unwrap().unwrap();
        assert_eq!(
            (l.t_us, l.port, &data[..l.len]),
            (u64::MAX, p, &[0u8, 255, 36][..])
        );
    }
    use capture::CaptureError::*;
    let mut d = |s: &str| capture::decode_line(s.as_bytes(), &mut data);
    assert_eq!(d("# magcomp-capture v2"), Err(UnsupportedVersion));
    assert_eq!(d("12 radar 00"), Err(UnknownPort));
    assert_eq!(d("1x2 gps 00"), Err(BadTime));
    assert_eq!(d("12 gps 0"), Err(BadHex));
    assert_eq!(d("12 gps 0g"), Err(BadHex));
    assert_eq!(d("12"), Err(BadLine));
    assert_eq!(
        capture::decode_line(b"1 gps 000000", &mut [0u8; 2]),
        Err(BufferFull)
    );
    assert_eq!(
        d("7 out"),
        Ok(Some(capture::CaptureLine {
            t_us: 7,
            port: Port::Out,
            len: 0
        }))
    );
}

#[test]
fn documented_examples_decode() {
    // docs/protocols.md §4.
    let r = decode_record(
        b"$MCREC,42,1234.500000,53620.4401,12.3456,53608.0945,-3.2100,0.0123,0.0400,0000*3C1B\r\n",
    )
    .unwrap();
    assert_eq!(
        (r.seq, r.mag, r.sigma_nt, r.flags),
        (42, Some(MagCounts(536_204_401)), 0.04, Flags(0))
    );
    let r = decode_record(b"$MCREC,43,1234.600000,,,,,,,0008*C599").unwrap();
    assert!(r.mag.is_none() && r.interference_nt.is_nan() && r.sigma_nt.is_nan());
    assert_eq!(r.flags, Flags(Flags::MAG_MISSING));
    // A stream from firmware before `sigma_nt` (8 data fields) still decodes, bound unknown.
    let r = decode_record(
        b"$MCREC,42,1234.500000,53620.4401,12.3456,53608.0945,-3.2100,0.0123,0104*CB4A\r\n",
    )
    .unwrap();
    assert_eq!(
        (r.seq, r.mag, r.flags),
        (42, Some(MagCounts(536_204_401)), Flags(0x0104))
    );
    assert!(r.sigma_nt.is_nan());
    let r = decode_record(b"$MCREC,43,1234.600000,,,,,,0008*5FDF").unwrap();
    assert!(r.mag.is_none() && r.interference_nt.is_nan() && r.flags == Flags(8));
    // 7 or 10 data fields are neither format.
    let seven = b"MCREC,43,1234.600000,,,,,0008";
    let ten = b"MCREC,43,1234.600000,,,,,,,,0008";
    for body in [&seven[..], &ten[..]] {
        let crc = magcomp_core::protocol::common::crc16_ccitt(body);
        let line = format!("${}*{crc:04X}", std::str::from_utf8(body).unwrap());
        assert_eq!(
            decode_record(line.as_bytes()),
            Err(RecordError::FieldCount),
            "{line}"
        );
    }
    assert_eq!(
        parse_command(b"$MCCMD,SETCOEF,3,-1.25E-2*79", 21),
        Ok(Command::SetCoef {
            index: 3,
            value: -0.0125
        })
    );
    assert_eq!(parse_command(b"$MCCMD,FLUSH*2C", 21), Ok(Command::Flush));
    assert!(check_reply(b"$MCERR,5,INDEX*376F").is_some());
    let f = magcomp_core::protocol::fluxgate::decode_spi_frame(&[
        0x00, 0x07, 0x00, 0x00, 0x00, 0x01, 0xFF, 0xFF, 0xFF, 0x40, 0x00, 0x00, 0x4D, 0x3B, 0x00,
    ])
    .unwrap();
    assert_eq!(f.counts, [1, -1, 4_194_304]);
}

#[test]
fn commands_address_a_sensor_with_one_more_argument() {
    let p = |b: &str| parse_command(cmd_line(b).as_bytes(), 16);
    use CommandError::*;
    assert_eq!(
        p("MCCMD,SETCOEF,2,3,-1.25E-2"),
        Ok(Command::SetSensorCoef {
            sensor: 2,
            index: 3,
            value: -0.0125
        })
    );
    // sensor 0 is the single sensor's form
    assert_eq!(
        p("MCCMD,SETCOEF,0,3,-1.25E-2"),
        Ok(Command::SetCoef {
            index: 3,
            value: -0.0125
        })
    );
    assert_eq!(
        p("MCCMD,GETCOEF,1,15"),
        Ok(Command::GetSensorCoef {
            sensor: 1,
            index: Some(15)
        })
    );
    assert_eq!(
        p("MCCMD,GETCOEF,2,ALL"),
        Ok(Command::GetSensorCoef {
            sensor: 2,
            index: None
        })
    );
    assert_eq!(p("MCCMD,GETCOEF,0,ALL"), Ok(Command::GetCoef(None)));
    assert_eq!(p("MCCMD,GETCOEF,0,4"), Ok(Command::GetCoef(Some(4))));
    assert_eq!(p("MCCMD,SETCOEF,3,3,1.0"), Err(IndexOutOfBounds));
    assert_eq!(p("MCCMD,SETCOEF,1,16,1.0"), Err(IndexOutOfBounds));
    assert_eq!(p("MCCMD,GETCOEF,1,16"), Err(IndexOutOfBounds));
    assert_eq!(p("MCCMD,SETCOEF,1,ALL,1.0"), Err(BadArgument));
    assert_eq!(p("MCCMD,SETCOEF,1,2,INF"), Err(ValueOutOfBounds));
    assert_eq!(p("MCCMD,GETCOEF,1,2,3"), Err(BadArgument));
    assert_eq!(p("MCCMD,SETFLUX,1,2,3"), Err(BadArgument));
    assert_eq!(p("MCCMD,SETCOEF,1,2,3,4"), Err(BadArgument));
    let mut out = [0u8; 96];
    for c in [
        Command::SetSensorCoef {
            sensor: 1,
            index: 15,
            value: -1.234_567_8e-5,
        },
        Command::GetSensorCoef {
            sensor: 2,
            index: None,
        },
        Command::GetSensorCoef {
            sensor: 2,
            index: Some(0),
        },
    ] {
        let n = encode_command(&c, &mut out).unwrap();
        assert_eq!(parse_command(&out[..n], 16), Ok(c));
    }
    let n = encode_command(
        &Command::SetSensorCoef {
            sensor: 2,
            index: 3,
            value: -0.0125,
        },
        &mut out,
    )
    .unwrap();
    let line = String::from_utf8_lossy(&out[..n]);
    assert!(
        line.starts_with("$MCCMD,SETCOEF,2,3,-125000002E-10*"),
        "{line}"
    );
}
